//! The ESRI ASCII grid reader (`src/dem/asc.rs`, issue 14 item 5) against the sequential reader
//! it replaced, kept here as `old`: the same grids, bit for bit, and the same errors, on the
//! `.asc` files under `tests/data` and `../shared/data`, on seeded random grids (values wrapped
//! across lines in any way, CRLF, NODATA, odd whitespace and number forms) read in blocks and
//! pieces of many sizes, and on those grids mutated byte by byte.
//!
//! Throughput, old against new (median of 5 loads of a generated 2049 × 2049 grid), and the
//! GeoTIFF load rates:
//! `cargo test --release --test suite -- --ignored --nocapture asc_reader::`.

use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};
use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use raypick::Error;
use raypick::dem::{ElevationGrid, load_asc, load_geotiff, read_asc};

/// The reader as it was before issue 14 item 5 (`git show d55c502:src/dem/asc.rs`), verbatim
/// but for the crate-private helpers it used, copied here too.
mod old {
    use std::fs::File;
    use std::io::{BufRead, BufReader};
    use std::path::Path;

    use raypick::Error;
    use raypick::budget::quote;
    use raypick::dem::{ElevationGrid, MAX_SAMPLES};

    /// Header keys this loader understands (lower case).
    const KEYS: [&str; 10] = [
        "ncols",
        "nrows",
        "xllcorner",
        "xllcenter",
        "yllcorner",
        "yllcenter",
        "cellsize",
        "dx",
        "dy",
        "nodata_value",
    ];

    pub fn load_asc(path: impl AsRef<Path>) -> Result<ElevationGrid, Error> {
        let path = path.as_ref();
        let name = path.display().to_string();
        let file = File::open(path).map_err(|e| io_error(&name, e))?;
        let size_hint = file.metadata().ok().map(|m| m.len());
        parse(BufReader::new(file), &name, size_hint)
    }

    pub fn read_asc(reader: impl BufRead, name: &str) -> Result<ElevationGrid, Error> {
        parse(reader, name, None)
    }

    fn io_error(path: &str, source: std::io::Error) -> Error {
        Error::Io {
            path: path.to_owned(),
            source,
        }
    }

    fn parse_error(path: &str, line: Option<usize>, message: impl Into<String>) -> Error {
        Error::Parse {
            path: path.to_owned(),
            line,
            message: message.into(),
        }
    }

    fn checked_sample_count(path: &str, ncols: u64, nrows: u64) -> Result<usize, Error> {
        if ncols == 0 || nrows == 0 {
            return Err(parse_error(
                path,
                None,
                format!("empty grid ({ncols} columns x {nrows} rows)"),
            ));
        }
        let too_big = || {
            parse_error(
                path,
                None,
                format!(
                    "grid of {ncols} columns x {nrows} rows is too large \
                     (more than {MAX_SAMPLES} samples); refusing to allocate it"
                ),
            )
        };
        let n = ncols.checked_mul(nrows).ok_or_else(too_big)?;
        match usize::try_from(n) {
            Ok(n) if n <= MAX_SAMPLES => Ok(n),
            _ => Err(too_big()),
        }
    }

    fn alloc_heights(path: &str, capacity: usize) -> Result<Vec<Option<f64>>, Error> {
        raypick::budget::check(
            &format!("{path}: the grid's heights"),
            capacity as u64,
            std::mem::size_of::<Option<f64>>() as u64,
        )?;
        let mut heights = Vec::new();
        heights.try_reserve_exact(capacity).map_err(|_| {
            parse_error(
                path,
                None,
                format!("cannot allocate memory for {capacity} samples"),
            )
        })?;
        Ok(heights)
    }

    /// A header value as written, with the line it came from.
    #[derive(Clone)]
    struct Entry {
        text: String,
        line: usize,
    }

    /// Header entries collected so far, indexed like [`KEYS`].
    struct Header {
        path: String,
        entries: [Option<Entry>; KEYS.len()],
    }

    /// The header turned into numbers.
    struct Geometry {
        ncols: usize,
        nrows: usize,
        x0: f64,
        y0: f64,
        dx: f64,
        dy: f64,
        nodata: Option<f64>,
        count: usize,
    }

    impl Header {
        fn get(&self, key: &str) -> Option<&Entry> {
            let i = KEYS.iter().position(|k| *k == key)?;
            self.entries[i].as_ref()
        }

        fn err(&self, line: Option<usize>, message: impl Into<String>) -> Error {
            parse_error(&self.path, line, message)
        }

        fn insert(&mut self, key: &str, text: &str, line: usize) -> Result<(), Error> {
            let lower = key.to_ascii_lowercase();
            let Some(i) = KEYS.iter().position(|k| *k == lower) else {
                return Err(self.err(Some(line), format!("unknown header key '{}'", quote(key))));
            };
            if let Some(previous) = &self.entries[i] {
                return Err(self.err(
                    Some(line),
                    format!(
                        "header key '{lower}' repeated (first given on line {})",
                        previous.line
                    ),
                ));
            }
            self.entries[i] = Some(Entry {
                text: text.to_owned(),
                line,
            });
            Ok(())
        }

        /// A required positive integer (ncols, nrows).
        fn count(&self, key: &str) -> Result<u64, Error> {
            let e = self
                .get(key)
                .ok_or_else(|| self.err(None, format!("missing header key '{key}'")))?;
            let bad = || {
                self.err(
                    Some(e.line),
                    format!("{key} must be a positive integer, got '{}'", quote(&e.text)),
                )
            };
            let n = match e.text.parse::<u64>() {
                Ok(n) => n,
                // Some writers emit "403.0"; accept integral floats.
                Err(_) => match e.text.parse::<f64>() {
                    Ok(f) if f.is_finite() && f >= 1.0 && f.fract() == 0.0 && f <= 9.0e15 => {
                        f as u64
                    }
                    _ => return Err(bad()),
                },
            };
            if n == 0 {
                return Err(bad());
            }
            Ok(n)
        }

        /// An optional finite number.
        fn finite(&self, key: &str) -> Result<Option<(f64, usize)>, Error> {
            let Some(e) = self.get(key) else {
                return Ok(None);
            };
            match e.text.parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(Some((v, e.line))),
                _ => Err(self.err(
                    Some(e.line),
                    format!("{key} must be a finite number, got '{}'", quote(&e.text)),
                )),
            }
        }

        /// An optional spacing, which must be finite and positive.
        fn spacing(&self, key: &str) -> Result<Option<f64>, Error> {
            match self.finite(key)? {
                Some((v, _)) if v > 0.0 => Ok(Some(v)),
                Some((_, line)) => Err(self.err(
                    Some(line),
                    format!(
                        "{key} must be positive, got '{}'",
                        quote(self.get(key).map_or("", |e| e.text.as_str()))
                    ),
                )),
                None => Ok(None),
            }
        }

        /// Exactly one of `corner` / `center`: (value, is_center).
        fn origin(&self, corner: &str, center: &str) -> Result<(f64, bool), Error> {
            match (self.finite(corner)?, self.finite(center)?) {
                (Some((v, _)), None) => Ok((v, false)),
                (None, Some((v, _))) => Ok((v, true)),
                (Some(_), Some((_, line))) => Err(self.err(
                    Some(line),
                    format!("both '{corner}' and '{center}' given; expected one"),
                )),
                (None, None) => Err(self.err(
                    None,
                    format!("missing header key '{corner}' (or '{center}')"),
                )),
            }
        }

        fn geometry(&self) -> Result<Geometry, Error> {
            let ncols = self.count("ncols")?;
            let nrows = self.count("nrows")?;
            let count = checked_sample_count(&self.path, ncols, nrows)?;
            // Both fit in usize because their product does.
            let (ncols, nrows) = (ncols as usize, nrows as usize);

            let cellsize = self.spacing("cellsize")?;
            let (dx, dy) = match (cellsize, self.spacing("dx")?, self.spacing("dy")?) {
                (Some(cs), None, None) => (cs, cs),
                (None, Some(dx), Some(dy)) => (dx, dy),
                (Some(_), _, _) => {
                    let line = self.get("dx").or(self.get("dy")).map(|e| e.line);
                    return Err(self.err(line, "both 'cellsize' and 'dx'/'dy' given; expected one"));
                }
                (None, Some(_), None) => return Err(self.err(None, "'dx' given without 'dy'")),
                (None, None, Some(_)) => return Err(self.err(None, "'dy' given without 'dx'")),
                (None, None, None) => {
                    return Err(self.err(None, "missing header key 'cellsize' (or 'dx' and 'dy')"));
                }
            };

            let (xll, x_center) = self.origin("xllcorner", "xllcenter")?;
            let (yll, y_center) = self.origin("yllcorner", "yllcenter")?;
            let x0 = if x_center { xll } else { xll + 0.5 * dx };
            let y0 = if y_center {
                yll + (nrows - 1) as f64 * dy
            } else {
                yll + (nrows as f64 - 0.5) * dy
            };
            // The far corner must be representable too.
            let x1 = x0 + (ncols - 1) as f64 * dx;
            let y1 = y0 - (nrows - 1) as f64 * dy;
            if ![x0, y0, x1, y1].iter().all(|v| v.is_finite()) {
                return Err(self.err(None, "grid extent overflows the range of f64"));
            }

            let nodata = match self.get("nodata_value") {
                None => None,
                Some(e) => Some(e.text.parse::<f64>().map_err(|_| {
                    self.err(
                        Some(e.line),
                        format!("nodata_value must be a number, got '{}'", quote(&e.text)),
                    )
                })?),
            };

            Ok(Geometry {
                ncols,
                nrows,
                x0,
                y0,
                dx,
                dy,
                nodata,
                count,
            })
        }
    }

    fn parse(
        mut reader: impl BufRead,
        path: &str,
        size_hint: Option<u64>,
    ) -> Result<ElevationGrid, Error> {
        let mut header = Header {
            path: path.to_owned(),
            entries: Default::default(),
        };
        let mut geometry: Option<Geometry> = None;
        let mut heights = Vec::new();
        let mut buf = Vec::new();
        let mut line_no = 0usize;

        loop {
            buf.clear();
            let read = reader
                .read_until(b'\n', &mut buf)
                .map_err(|e| io_error(path, e))?;
            if read == 0 {
                break;
            }
            line_no += 1;
            let mut text = std::str::from_utf8(&buf)
                .map_err(|_| parse_error(path, Some(line_no), "line is not valid UTF-8 text"))?;
            if line_no == 1 {
                text = text.strip_prefix('\u{feff}').unwrap_or(text);
            }
            let mut tokens = text.split_whitespace().peekable();

            if geometry.is_none() {
                let Some(first) = tokens.peek().copied() else {
                    continue; // blank header line
                };
                if first.parse::<f64>().is_err() {
                    tokens.next();
                    let value = tokens.next().ok_or_else(|| {
                        parse_error(
                            path,
                            Some(line_no),
                            format!("header key '{}' has no value", quote(first)),
                        )
                    })?;
                    if let Some(extra) = tokens.next() {
                        return Err(parse_error(
                            path,
                            Some(line_no),
                            format!(
                                "unexpected '{}' after header value '{} {}'",
                                quote(extra),
                                quote(first),
                                quote(value)
                            ),
                        ));
                    }
                    header.insert(first, value, line_no)?;
                    continue;
                }
                // First data line: the header is complete.
                let g = header.geometry()?;
                // Each value takes at least two bytes (digit + separator), so a
                // file cannot justify more capacity than half its size.
                let plausible = size_hint.map_or(1 << 20, |s| {
                    usize::try_from(s / 2 + 1).unwrap_or(usize::MAX)
                });
                heights = alloc_heights(path, g.count.min(plausible))?;
                geometry = Some(g);
            }
            let Some(g) = geometry.as_ref() else {
                continue;
            };

            for token in tokens {
                let value = token.parse::<f64>().map_err(|_| {
                    parse_error(
                        path,
                        Some(line_no),
                        format!("bad number '{}'", quote(token)),
                    )
                })?;
                if heights.len() == g.count {
                    return Err(parse_error(
                        path,
                        Some(line_no),
                        format!(
                            "too many values: expected {} ({} columns x {} rows)",
                            g.count, g.ncols, g.nrows
                        ),
                    ));
                }
                let is_nodata = g
                    .nodata
                    .is_some_and(|nd| nd == value || (nd.is_nan() && value.is_nan()));
                if is_nodata {
                    heights.push(None);
                } else if value.is_finite() {
                    heights.push(Some(value));
                } else {
                    return Err(parse_error(
                        path,
                        Some(line_no),
                        format!("non-finite value '{}' (not the nodata_value)", quote(token)),
                    ));
                }
            }
        }

        let g = match geometry {
            Some(g) => g,
            None => header.geometry()?,
        };
        if heights.len() < g.count {
            return Err(parse_error(
                path,
                (line_no > 0).then_some(line_no),
                format!(
                    "too few values: file ends after {} of {} ({} columns x {} rows)",
                    heights.len(),
                    g.count,
                    g.ncols,
                    g.nrows
                ),
            ));
        }
        Ok(ElevationGrid {
            ncols: g.ncols,
            nrows: g.nrows,
            x0: g.x0,
            y0: g.y0,
            dx: g.dx,
            dy: g.dy,
            heights,
        })
    }
}

const NAME: &str = "r.asc";

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

fn shared(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data")
        .join(name)
}

/// A grid's heights as bits, so that -0.0 and 0.0 differ.
fn bits(grid: &ElevationGrid) -> Vec<Option<u64>> {
    grid.heights.iter().map(|h| h.map(f64::to_bits)).collect()
}

/// Panics unless both readers gave the same grid, bit for bit, or the same error message.
fn assert_same(what: &str, old: &Result<ElevationGrid, Error>, new: &Result<ElevationGrid, Error>) {
    match (old, new) {
        (Ok(a), Ok(b)) => {
            let shape = |g: &ElevationGrid| {
                (
                    g.ncols,
                    g.nrows,
                    g.x0.to_bits(),
                    g.y0.to_bits(),
                    g.dx.to_bits(),
                    g.dy.to_bits(),
                )
            };
            assert_eq!(shape(a), shape(b), "{what}: grid shapes differ");
            let (a, b) = (bits(a), bits(b));
            if let Some(k) = (0..a.len()).find(|&k| a[k] != b[k]) {
                let show = |h: Option<u64>| h.map(f64::from_bits);
                panic!(
                    "{what}: heights differ first at {k}: old {:?}, new {:?}",
                    show(a[k]),
                    show(b[k])
                );
            }
        }
        (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string(), "{what}: errors differ"),
        (a, b) => panic!("{what}: old gave {}, new gave {}", describe(a), describe(b)),
    }
}

fn describe(result: &Result<ElevationGrid, Error>) -> String {
    match result {
        Ok(g) => format!("a {} x {} grid", g.ncols, g.nrows),
        Err(e) => format!("the error {e:?}"),
    }
}

/// Reads `bytes` with the old reader and with the new one, whole and in blocks and pieces of
/// random sizes (small, so that the seams fall everywhere); returns the grid, if it is one.
fn check_bytes(what: &str, bytes: &[u8], rng: &mut Pcg64) -> Option<ElevationGrid> {
    let old = old::read_asc(bytes, NAME);
    assert_same(what, &old, &read_asc(bytes, NAME));
    for _ in 0..3 {
        let block = rng.random_range(1..300);
        let piece = rng.random_range(1..120);
        let new = raypick::dem::asc::read_asc_in_pieces(bytes, NAME, block, piece);
        assert_same(
            &format!("{what} (blocks of {block}, pieces of {piece})"),
            &old,
            &new,
        );
    }
    old.ok()
}

#[test]
fn the_jacksboro_grids_read_the_same() {
    let mut paths = vec![data("jacksboro_fault_dem_utm.asc")];
    let shared_copy = shared("jacksboro_fault_dem_utm.asc");
    if shared_copy.exists() {
        paths.push(shared_copy);
    } else {
        eprintln!(
            "note: {} is absent; read tests/data only",
            shared_copy.display()
        );
    }
    let mut rng = Pcg64::seed_from_u64(5);
    for path in paths {
        let what = path.display().to_string();
        let old = old::load_asc(&path);
        let new = load_asc(&path);
        assert_same(&what, &old, &new);
        assert_eq!(new.expect("jacksboro").heights.len(), 403 * 344);

        let bytes = std::fs::read(&path).expect("read the grid");
        check_bytes(&what, &bytes, &mut rng);
        // Cut anywhere: in the header, mid-number, mid-line, at line ends.
        for _ in 0..200 {
            let cut = rng.random_range(0..=bytes.len());
            check_bytes(&format!("{what} cut at {cut}"), &bytes[..cut], &mut rng);
        }
    }
}

/// A number as some writer might spell it (every one finite and accepted by `str::parse`).
fn number(rng: &mut Pcg64) -> String {
    let x: f64 = rng.random_range(-1000.0..5000.0);
    match rng.random_range(0..20) {
        0 => format!("{x}"),
        1 => format!("{}", x.round() as i64),
        2 => format!("{x:e}"),
        3 => format!(".{}", rng.random_range(0..100_000)),
        4 => format!("{}.", rng.random_range(0..1000)),
        5 => format!("+{:.3}", x.abs()),
        6 => format!("{x:.3}E+{}", rng.random_range(0..5)),
        7 => format!("{x:.25}"),
        8 => ["-0", "0.000", "-0.0", "+0", "0e0", "00012.5000"][rng.random_range(0..6)].to_owned(),
        9 => format!("{}", rng.random::<u64>()),
        10 => format!("{:.1}e-{}", x, rng.random_range(0..330)),
        11 => {
            let digits: String = (0..rng.random_range(1..40))
                .map(|_| char::from(b'0' + rng.random_range(0..10u8)))
                .collect();
            let dot = rng.random_range(0..=digits.len());
            format!(
                "{}.{}e{}",
                &digits[..dot],
                &digits[dot..],
                rng.random_range(-40..40)
            )
        }
        12 => [
            "1e308",
            "1.7976931348623157e308",
            "4.9e-324",
            "2.2250738585072011e-308",
            "2.2250738585072012e-308",
            "9007199254740993",
            "1.00000000000000011102230246251565404236316680908203125",
            "7.3177701707893310e+15",
            "1e-400",
        ][rng.random_range(0..9)]
        .to_owned(),
        13 => f64::from_bits(rng.random::<u64>() >> 2).to_string(),
        _ => format!("{x:.2}"),
    }
}

/// How NODATA is written in the header, and spellings of it in the values.
const NODATA: [(&str, &[&str]); 4] = [
    ("-9999", &["-9999", "-9999.0", "-9.999e3", "-9999.000"]),
    ("nan", &["nan", "NaN", "-nan", "NAN"]),
    ("0", &["0", "-0", "0.0"]),
    (
        "1e30",
        &["1e30", "1E+30", "1000000000000000000000000000000"],
    ),
];

/// A seeded random grid: keys in any case and order, blank header lines, maybe a BOM and CRLF,
/// corner or centre, cellsize or dx/dy, maybe NODATA; values (now and then one too few or too
/// many) wrapped across lines at random, with odd whitespace.
fn random_grid(rng: &mut Pcg64) -> Vec<u8> {
    let newline = if rng.random_bool(0.3) { "\r\n" } else { "\n" };
    let (ncols, nrows) = (rng.random_range(1..30usize), rng.random_range(1..30usize));
    let nodata = rng
        .random_bool(0.6)
        .then(|| NODATA[rng.random_range(0..NODATA.len())]);
    let mut keys = vec![
        format!("ncols {ncols}"),
        format!("nrows {nrows}"),
        format!(
            "{} 1000.5",
            ["xllcorner", "xllcenter"][rng.random_range(0..2)]
        ),
        format!("{} -20", ["yllcorner", "yllcenter"][rng.random_range(0..2)]),
    ];
    if rng.random_bool(0.7) {
        keys.push("cellsize 30".to_owned());
    } else {
        keys.push("dx 2.5".to_owned());
        keys.push("dy 4".to_owned());
    }
    if let Some((value, _)) = nodata {
        keys.push(format!("NODATA_value {value}"));
    }
    for i in (1..keys.len()).rev() {
        keys.swap(i, rng.random_range(0..=i));
    }
    let mut text = String::new();
    if rng.random_bool(0.1) {
        text.push('\u{feff}');
    }
    for key in keys {
        let (name, value) = key.split_once(' ').expect("key value");
        let name: String = name
            .chars()
            .map(|c| {
                if rng.random_bool(0.3) {
                    c.to_ascii_uppercase()
                } else {
                    c
                }
            })
            .collect();
        let gap = ["\t", "  ", " "][rng.random_range(0..3)];
        text += &format!("{name}{gap}{value}{newline}");
        if rng.random_bool(0.1) {
            text += newline;
        }
    }
    let count = match rng.random_range(0..20) {
        0 => (ncols * nrows).saturating_sub(1),
        1 => ncols * nrows + 1,
        _ => ncols * nrows,
    };
    let wrap = [1, ncols, ncols * 2, 7, count.max(1)][rng.random_range(0..5)];
    for k in 0..count {
        let value = match nodata {
            Some((_, spellings)) if rng.random_bool(0.1) => {
                spellings[rng.random_range(0..spellings.len())].to_owned()
            }
            _ => number(rng),
        };
        text += &value;
        let sep = if (k + 1) % wrap == 0 || rng.random_bool(0.02) {
            newline
        } else {
            [
                " ", " ", " ", " ", "\t", "  ", "\x0b", "\x0c", "\u{a0}", " \r ",
            ][rng.random_range(0..10)]
        };
        text += sep;
        if rng.random_bool(0.01) {
            text += newline; // a blank line
        }
    }
    if rng.random_bool(0.2) {
        text = text.trim_end().to_owned();
    }
    text.into_bytes()
}

#[test]
fn random_grids_read_the_same() {
    let mut rng = Pcg64::seed_from_u64(14);
    let mut read = 0;
    for k in 0..3000 {
        let bytes = random_grid(&mut rng);
        read += check_bytes(&format!("random grid {k}"), &bytes, &mut rng).is_some() as usize;
    }
    assert!(read > 2000, "only {read} of the random grids are valid");
}

/// Byte strings a mutation puts into a file.
const INSERTS: [&[u8]; 26] = [
    b"nan",
    b"inf",
    b"-inf",
    b"infinity",
    b"+Infinity",
    b"1e",
    b"e5",
    b".",
    b"-",
    b"+",
    b"1e400",
    b"-1e400",
    "\u{a0}".as_bytes(),
    "\u{2003}".as_bytes(),
    b"\xff",
    b"\xc2",
    b"\n",
    b"\n\n",
    b" 7",
    b"1.2.3",
    b"--1",
    b"0x10",
    b"1_000",
    b"\0",
    b"\r",
    b" 1e-400",
];

/// `bytes` with one to three random edits: a byte replaced, a string inserted, a range cut out.
fn mutate(bytes: &[u8], rng: &mut Pcg64) -> Vec<u8> {
    let mut out = bytes.to_vec();
    for _ in 0..rng.random_range(1..4) {
        let at = rng.random_range(0..=out.len());
        match rng.random_range(0..3) {
            0 if at < out.len() => {
                out[at] = b"0123456789.+-eEx \n\r\t\x0b\x0cnaifNI#\xff\0"[rng.random_range(0..31)];
            }
            1 => {
                let insert = INSERTS[rng.random_range(0..INSERTS.len())];
                out.splice(at..at, insert.iter().copied());
            }
            _ => {
                let end = (at + rng.random_range(1..20)).min(out.len());
                out.drain(at..end);
            }
        }
    }
    out
}

#[test]
fn mutated_grids_fail_or_read_the_same() {
    let mut rng = Pcg64::seed_from_u64(1405);
    let mut read = 0;
    for k in 0..4000 {
        let bytes = random_grid(&mut rng);
        let mutated = mutate(&bytes, &mut rng);
        read += check_bytes(&format!("mutated grid {k}"), &mutated, &mut rng).is_some() as usize;
    }
    // Both outcomes, often.
    assert!(
        (400..3600).contains(&read),
        "{read} of 4000 mutated grids read"
    );
    let jacksboro = std::fs::read(data("jacksboro_fault_dem_utm.asc")).expect("jacksboro");
    for k in 0..100 {
        let mutated = mutate(&jacksboro, &mut rng);
        check_bytes(&format!("mutated jacksboro {k}"), &mutated, &mut rng);
    }
}

#[test]
fn odd_tokens_read_the_same() {
    const PIECES: [&str; 24] = [
        "0",
        "1",
        "5",
        "9",
        ".",
        "+",
        "-",
        "e",
        "E",
        "e-",
        "e+",
        "inf",
        "INF",
        "infinity",
        "Infinity",
        "nan",
        "NaN",
        "in",
        "n",
        "00",
        "123456789",
        "x",
        "_",
        "1e400",
    ];
    let mut rng = Pcg64::seed_from_u64(7);
    let mut read = 0;
    for k in 0..20_000 {
        let token: String = (0..rng.random_range(1..6))
            .map(|_| PIECES[rng.random_range(0..PIECES.len())])
            .collect();
        let nodata = ["-9999", "nan", "inf"][k % 3];
        let text = format!(
            "ncols 2\nnrows 1\nxllcorner 0\nyllcorner 0\ncellsize 1\nnodata_value {nodata}\n\
             {token} 1\n"
        );
        read +=
            check_bytes(&format!("token {token:?}"), text.as_bytes(), &mut rng).is_some() as usize;
    }
    assert!(
        (2000..18_000).contains(&read),
        "{read} of 20000 odd tokens read"
    );
}

#[test]
fn hard_to_round_numbers_read_the_same() {
    let mut rng = Pcg64::seed_from_u64(53);
    let mut text = String::from("ncols 100\nnrows 300\nxllcorner 0\nyllcorner 0\ncellsize 1\n");
    for k in 0..30_000 {
        let x = f64::from_bits(rng.random::<u64>() >> 1);
        let x = if x.is_finite() { x } else { 1.5 };
        let value = match k % 5 {
            0 => format!("{x:e}"),
            // Halfway between two doubles, or very near it.
            1 => format!("{:.30e}", x),
            2 => format!("{}", rng.random::<u64>() >> rng.random_range(0..12)),
            // Plain decimals of 14 to 21 digits, around the fast path's limits (2^53, 19 digits).
            3 => {
                let digits: String = (0..rng.random_range(14..22))
                    .map(|_| char::from(b'0' + rng.random_range(0..10u8)))
                    .collect();
                let point = rng.random_range(0..=digits.len());
                format!("-{}.{}", &digits[..point], &digits[point..])
            }
            _ => {
                let digits: String = (0..rng.random_range(16..30))
                    .map(|_| char::from(b'0' + rng.random_range(0..10u8)))
                    .collect();
                format!("0.{digits}e{}", rng.random_range(-320..300))
            }
        };
        text += &value;
        text.push(if k % 100 == 99 { '\n' } else { ' ' });
    }
    let grid = check_bytes("hard numbers", text.as_bytes(), &mut rng).expect("hard numbers");
    assert_eq!(grid.heights.len(), 30_000);
}

/// A reader that fails after `left` bytes.
struct FailAfter<'a> {
    bytes: &'a [u8],
    left: usize,
}

impl Read for FailAfter<'_> {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        if self.left == 0 {
            return Err(std::io::Error::other("the disk went away"));
        }
        let n = out.len().min(self.left).min(self.bytes.len());
        out[..n].copy_from_slice(&self.bytes[..n]);
        self.bytes = &self.bytes[n..];
        self.left -= n;
        Ok(n)
    }
}

#[test]
fn read_failures_and_errors_before_them_are_reported_the_same() {
    let mut rng = Pcg64::seed_from_u64(99);
    for k in 0..500 {
        let bytes = if k % 2 == 0 {
            random_grid(&mut rng)
        } else {
            mutate(&random_grid(&mut rng), &mut rng)
        };
        let left = rng.random_range(0..bytes.len() + 10);
        let capacity = rng.random_range(1..64);
        let reader = || {
            BufReader::with_capacity(
                capacity,
                FailAfter {
                    bytes: &bytes,
                    left,
                },
            )
        };
        let old = old::read_asc(reader(), NAME);
        assert_same(
            &format!("failing reader {k}"),
            &old,
            &read_asc(reader(), NAME),
        );
        let new = raypick::dem::asc::read_asc_in_pieces(reader(), NAME, 13, 5);
        assert_same(&format!("failing reader {k} in pieces"), &old, &new);
    }
}

/// A temporary file, removed on drop.
struct TempFile(PathBuf);

impl TempFile {
    fn new(tag: &str, bytes: &[u8]) -> Self {
        let path = std::env::temp_dir().join(format!(
            "raypick-asc-reader-{}-{tag}.asc",
            std::process::id()
        ));
        std::fs::write(&path, bytes).expect("write a temporary grid");
        TempFile(path)
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

#[test]
fn files_load_the_same_and_only_regular_files_load() {
    let mut rng = Pcg64::seed_from_u64(3);
    for k in 0..50 {
        let bytes = mutate(&random_grid(&mut rng), &mut rng);
        let file = TempFile::new(&format!("file{k}"), &bytes);
        assert_same(
            &format!("file {k}"),
            &old::load_asc(&file.0),
            &load_asc(&file.0),
        );
    }
    let e = load_asc(std::env::temp_dir()).unwrap_err();
    assert!(matches!(e, Error::Io { .. }), "{e}");
    assert!(e.to_string().contains("not a regular file"), "{e}");
}

// ---------------------------------------------------------------------------------------------
// Throughput

/// The median of `runs` timings of `f`, in seconds, after one warm-up call.
fn median_seconds<T>(runs: usize, mut f: impl FnMut() -> T) -> f64 {
    std::hint::black_box(f());
    let mut times: Vec<f64> = (0..runs)
        .map(|_| {
            let start = Instant::now();
            std::hint::black_box(f());
            start.elapsed().as_secs_f64()
        })
        .collect();
    times.sort_by(f64::total_cmp);
    times[runs / 2]
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg").unwrap_or_else(|_| "unknown".to_owned())
}

/// A 2049 × 2049 grid of heights with two decimals, 2049 values a line (about 34 MB).
fn big_grid() -> Vec<u8> {
    use std::fmt::Write;
    let n = 2049;
    let mut rng = Pcg64::seed_from_u64(2049);
    let mut text = format!(
        "ncols {n}\nnrows {n}\nxllcorner 0\nyllcorner 0\ncellsize 30\nnodata_value -9999\n"
    );
    let mut z: f64 = 500.0;
    for _ in 0..n {
        for c in 0..n {
            z = (z + rng.random_range(-3.0..3.0)).clamp(100.0, 2000.0);
            write!(text, "{z:.2}").expect("write to a string");
            text.push(if c + 1 == n { '\n' } else { ' ' });
        }
    }
    text.into_bytes()
}

#[test]
#[ignore = "throughput: run with --release -- --ignored --nocapture"]
fn asc_load_rate_old_and_new() {
    let bytes = big_grid();
    let file = TempFile::new("big", &bytes);
    let mb = bytes.len() as f64 / 1e6;
    assert_same("big grid", &old::load_asc(&file.0), &load_asc(&file.0));
    println!(
        "ASCII grid: {} ({mb:.1} MB, 2049 x 2049 values), {} rayon threads, load average {}",
        file.0.display(),
        rayon::current_num_threads(),
        load_average().trim()
    );
    // Interleaved, so that both see the same load on a shared machine.
    let (mut old_times, mut new_times) = (Vec::new(), Vec::new());
    for _ in 0..5 {
        old_times.push(median_seconds(1, || old::load_asc(&file.0).expect("old")));
        new_times.push(median_seconds(1, || load_asc(&file.0).expect("new")));
    }
    for (name, times) in [("old", &mut old_times), ("new", &mut new_times)] {
        times.sort_by(f64::total_cmp);
        let median = times[2];
        println!(
            "  {name}: median {:.1} ms = {:.0} MB/s of text (runs: {})",
            median * 1e3,
            mb / median,
            times
                .iter()
                .map(|t| format!("{:.0}", mb / t))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    println!("  load average after: {}", load_average().trim());
}

#[test]
#[ignore = "throughput: run with --release -- --ignored --nocapture"]
fn geotiff_load_rate() {
    println!("GeoTIFF load average {}", load_average().trim());
    for name in [
        "jacksboro_fault_dem_utm_f32_deflate.tif",
        "jacksboro_fault_dem_utm_int16.tif",
    ] {
        let path = if shared(name).exists() {
            shared(name)
        } else {
            data(name)
        };
        let file_mb = std::fs::metadata(&path).expect("the GeoTIFF").len() as f64 / 1e6;
        let grid = load_geotiff(&path).expect("the GeoTIFF loads");
        let samples = grid.heights.len() as f64;
        // 20 loads a run: one takes about a millisecond.
        let per_load = median_seconds(5, || {
            for _ in 0..20 {
                std::hint::black_box(load_geotiff(&path).expect("load"));
            }
        }) / 20.0;
        println!(
            "  {}: {file_mb:.3} MB, {} x {} samples: {:.2} ms a load = {:.0} MB/s of file, \
             {:.0} M samples/s",
            path.display(),
            grid.ncols,
            grid.nrows,
            per_load * 1e3,
            file_mb / per_load,
            samples / per_load / 1e6
        );
    }
}
