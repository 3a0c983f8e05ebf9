//! ESRI ASCII grid (`.asc`) loader: header parsing, cell-centre sample
//! placement, NODATA handling and line-numbered errors.
//!
//! Header keys (case-insensitive, one `key value` pair per line, any order):
//! `ncols`, `nrows`, `xllcorner` | `xllcenter`, `yllcorner` | `yllcenter`,
//! `cellsize` (or both `dx` and `dy`), optional `nodata_value`. The header
//! ends at the first line that starts with a number; then come
//! `nrows * ncols` numbers, row 0 (north) first, wrapped across lines in any
//! way.
//!
//! Sample (r, c) is placed at the centre of its cell. With `xllcorner` /
//! `yllcorner`: x = xll + (c + ½)·dx, y = yll + (nrows − r − ½)·dy. With
//! `xllcenter` / `yllcenter` the given point is already the centre of the
//! lower-left cell: x = xllcenter + c·dx, y = yllcenter + (nrows − 1 − r)·dy.
//!
//! Cells equal to `nodata_value` become `None`. NaN or infinite cells are an
//! error, unless `nodata_value` is itself `nan` (then NaN cells are NODATA).

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::Path;

use super::grid::{ElevationGrid, alloc_heights, checked_sample_count};
use super::{io_error, parse_error};
use crate::budget::quote;
use crate::error::Error;

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

/// Loads an ESRI ASCII grid from `path`; see the module docs for the conventions.
///
/// # Errors
/// [`Error::Io`] if the file cannot be read; [`Error::Parse`] (with the line
/// where it applies) for a missing/repeated/unknown header key, a bad number,
/// too few or too many values, a non-positive cell size, NaN/infinite cells or
/// a grid larger than [`MAX_SAMPLES`](crate::dem::MAX_SAMPLES).
pub fn load_asc(path: impl AsRef<Path>) -> Result<ElevationGrid, Error> {
    let path = path.as_ref();
    let name = path.display().to_string();
    let file = File::open(path).map_err(|e| io_error(&name, e))?;
    let size_hint = file.metadata().ok().map(|m| m.len());
    parse(BufReader::new(file), &name, size_hint)
}

/// Parses an ESRI ASCII grid from `reader`; `name` labels errors (usually the file path).
///
/// # Errors
/// As [`load_asc`].
pub fn read_asc(reader: impl BufRead, name: &str) -> Result<ElevationGrid, Error> {
    parse(reader, name, None)
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
                Ok(f) if f.is_finite() && f >= 1.0 && f.fract() == 0.0 && f <= 9.0e15 => f as u64,
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

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    const JACKSBORO: &str = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/jacksboro_fault_dem_utm.asc"
    );

    fn read(text: &str) -> Result<ElevationGrid, Error> {
        read_asc(text.as_bytes(), "t.asc")
    }

    fn err(text: &str) -> String {
        match read(text) {
            Ok(g) => panic!("expected an error, got {g:?}"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn real_jacksboro_grid() {
        let g = load_asc(JACKSBORO).unwrap();
        assert_eq!((g.ncols, g.nrows), (403, 344));
        assert_eq!(g.heights.len(), 403 * 344);
        assert_eq!((g.dx, g.dy), (30.0, 30.0));

        let text = std::fs::read_to_string(JACKSBORO).unwrap();
        let first: f64 = text
            .lines()
            .nth(5)
            .and_then(|l| l.split_whitespace().next())
            .unwrap()
            .parse()
            .unwrap();
        let p = g.sample_position(0, 0).unwrap();
        assert_eq!(
            p,
            DVec3::new(512745.0, 4032150.0 + 344.0 * 30.0 - 15.0, first)
        );
        // South-east sample: centre of the lower-right cell.
        let last = g.sample_position(343, 402).unwrap();
        assert_eq!(
            (last.x, last.y),
            (512730.0 + 402.5 * 30.0, 4032150.0 + 15.0)
        );
        assert!(g.heights.iter().all(Option::is_some));
    }

    #[test]
    fn corner_convention_places_samples_at_cell_centres() {
        let g = read("ncols 3\nnrows 2\nxllcorner 100\nyllcorner 200\ncellsize 10\n1 2 3\n4 5 6\n")
            .unwrap();
        assert_eq!((g.x0, g.y0, g.dx, g.dy), (105.0, 215.0, 10.0, 10.0));
        assert_eq!(g.sample_position(1, 2), Some(DVec3::new(125.0, 205.0, 6.0)));
    }

    #[test]
    fn center_convention_uses_the_given_point() {
        let g = read("ncols 3\nnrows 2\nxllcenter 100\nyllcenter 200\ncellsize 10\n1 2 3 4 5 6\n")
            .unwrap();
        assert_eq!((g.x0, g.y0), (100.0, 210.0));
        assert_eq!(g.sample_position(1, 0), Some(DVec3::new(100.0, 200.0, 4.0)));
    }

    #[test]
    fn dx_dy_case_insensitive_keys_wrapping_nodata_crlf_bom() {
        let text = "\u{feff}NCOLS 2\r\nNRows 3\r\nXLLCorner 0\r\nyllCORNER 0\r\nDX 2\r\ndy 4\r\n\
                    NODATA_value -9999\r\n1\r\n2 -9999\r\n3.5 4e1\r\n\r\n-9999.0\r\n";
        let g = read(text).unwrap();
        assert_eq!((g.ncols, g.nrows, g.dx, g.dy), (2, 3, 2.0, 4.0));
        assert_eq!((g.x0, g.y0), (1.0, 10.0));
        assert_eq!(
            g.heights,
            vec![Some(1.0), Some(2.0), None, Some(3.5), Some(40.0), None]
        );
        let g = read("ncols 1\nnrows 1\nxllcorner 0\nyllcorner 0\ncellsize 1\n")
            .err()
            .unwrap();
        assert!(g.to_string().contains("too few values"), "{g}");
    }

    #[test]
    fn nan_nodata_value_turns_nan_cells_into_nodata() {
        let g = read(
            "ncols 2\nnrows 1\nxllcorner 0\nyllcorner 0\ncellsize 1\nnodata_value nan\nNaN 3\n",
        )
        .unwrap();
        assert_eq!(g.heights, vec![None, Some(3.0)]);
    }

    #[test]
    fn missing_keys_are_named() {
        let e = err("nrows 1\nxllcorner 0\nyllcorner 0\ncellsize 1\n5\n");
        assert_eq!(e, "t.asc: missing header key 'ncols'");
        let e = err("ncols 1\nnrows 1\nyllcorner 0\ncellsize 1\n5\n");
        assert_eq!(e, "t.asc: missing header key 'xllcorner' (or 'xllcenter')");
        let e = err("ncols 1\nnrows 1\nxllcorner 0\nyllcorner 0\n5\n");
        assert!(e.contains("missing header key 'cellsize'"), "{e}");
        assert_eq!(err(""), "t.asc: missing header key 'ncols'");
    }

    #[test]
    fn bad_number_reports_its_line() {
        let e = err("ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2\n3 x4\n");
        assert_eq!(e, "t.asc:7: bad number 'x4'");
    }

    #[test]
    fn too_few_and_too_many_values() {
        let head = "ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n";
        let e = err(&format!("{head}1 2\n3\n"));
        assert_eq!(
            e,
            "t.asc:7: too few values: file ends after 3 of 4 (2 columns x 2 rows)"
        );
        let e = err(&format!("{head}1 2\n3 4\n5\n"));
        assert_eq!(
            e,
            "t.asc:8: too many values: expected 4 (2 columns x 2 rows)"
        );
    }

    #[test]
    fn absurd_and_overflowing_sizes_are_refused_before_allocating() {
        let e = err(
            "ncols 1000000000000\nnrows 1000000000000\nxllcorner 0\nyllcorner 0\ncellsize 1\n1\n",
        );
        assert!(e.contains("too large"), "{e}");
        let e = err("ncols 1000000000000\nnrows 5\nxllcorner 0\nyllcorner 0\ncellsize 1\n1\n");
        assert!(e.contains("too large"), "{e}");
        let e = err(
            "ncols 99999999999999999999999\nnrows 5\nxllcorner 0\nyllcorner 0\ncellsize 1\n1\n",
        );
        assert!(
            e.contains("t.asc:1: ncols must be a positive integer"),
            "{e}"
        );
        let e = err("ncols -3\nnrows 5\nxllcorner 0\nyllcorner 0\ncellsize 1\n1\n");
        assert!(
            e.contains("t.asc:1: ncols must be a positive integer"),
            "{e}"
        );
        let e = err("ncols 0\nnrows 5\nxllcorner 0\nyllcorner 0\ncellsize 1\n1\n");
        assert!(
            e.contains("t.asc:1: ncols must be a positive integer"),
            "{e}"
        );
    }

    #[test]
    fn non_positive_or_nan_cellsize() {
        let e = err("ncols 1\nnrows 1\nxllcorner 0\nyllcorner 0\ncellsize 0\n1\n");
        assert_eq!(e, "t.asc:5: cellsize must be positive, got '0'");
        let e = err("ncols 1\nnrows 1\nxllcorner 0\nyllcorner 0\ncellsize -30\n1\n");
        assert_eq!(e, "t.asc:5: cellsize must be positive, got '-30'");
        let e = err("ncols 1\nnrows 1\nxllcorner 0\nyllcorner 0\ncellsize NaN\n1\n");
        assert_eq!(e, "t.asc:5: cellsize must be a finite number, got 'NaN'");
        let e = err("ncols 1\nnrows 1\nxllcorner nan\nyllcorner 0\ncellsize 1\n1\n");
        assert_eq!(e, "t.asc:3: xllcorner must be a finite number, got 'nan'");
        let e = err("ncols 1\nnrows 2\nxllcorner 0\nyllcorner 1e308\ncellsize 1e308\n1 1\n");
        assert!(e.contains("overflows"), "{e}");
        let e = err("ncols 3\nnrows 1\nxllcorner 1e308\nyllcorner 0\ncellsize 1e308\n1 1 1\n");
        assert!(e.contains("overflows"), "{e}");
    }

    #[test]
    fn nan_and_infinite_values_are_errors() {
        let head = "ncols 2\nnrows 1\nxllcorner 0\nyllcorner 0\ncellsize 1\nnodata_value -9999\n";
        assert_eq!(
            err(&format!("{head}1 NaN\n")),
            "t.asc:7: non-finite value 'NaN' (not the nodata_value)"
        );
        assert!(err(&format!("{head}inf 1\n")).contains("non-finite value 'inf'"));
    }

    #[test]
    fn header_defects() {
        let e = err("ncols 1\nncols 1\nnrows 1\nxllcorner 0\nyllcorner 0\ncellsize 1\n1\n");
        assert_eq!(
            e,
            "t.asc:2: header key 'ncols' repeated (first given on line 1)"
        );
        let e = err("ncols 1\nnrows 1\nxllcorner 0\nxllcenter 0\nyllcorner 0\ncellsize 1\n1\n");
        assert!(
            e.starts_with("t.asc:4: both 'xllcorner' and 'xllcenter'"),
            "{e}"
        );
        let e = err("ncols 1\nnrows 1\nfoo 3\n");
        assert_eq!(e, "t.asc:3: unknown header key 'foo'");
        let e = err("ncols\n");
        assert_eq!(e, "t.asc:1: header key 'ncols' has no value");
        let e = err("ncols 1 2\n");
        assert!(e.starts_with("t.asc:1: unexpected '2'"), "{e}");
        let e = err("ncols 1\nnrows 1\nxllcorner 0\nyllcorner 0\ncellsize 1\ndx 1\ndy 1\n1\n");
        assert!(e.contains("both 'cellsize' and 'dx'/'dy'"), "{e}");
        let e = err("ncols 1\nnrows 1\nxllcorner 0\nyllcorner 0\ndx 1\n1\n");
        assert!(e.contains("'dx' given without 'dy'"), "{e}");
        let e = err("ncols 1\nnrows 1\nxllcorner 0\nyllcorner 0\ncellsize 1\nnodata_value x\n1\n");
        assert_eq!(e, "t.asc:6: nodata_value must be a number, got 'x'");
    }

    #[test]
    fn binary_garbage_and_missing_file() {
        let e = read_asc(&[0xff, 0xfe, 0x00, 0x41, b'\n'][..], "g.asc").unwrap_err();
        assert_eq!(e.to_string(), "g.asc:1: line is not valid UTF-8 text");
        let e = load_asc("/nonexistent/dir/x.asc").unwrap_err();
        assert!(matches!(e, Error::Io { .. }));
        assert!(e.to_string().starts_with("/nonexistent/dir/x.asc: "), "{e}");
    }

    #[test]
    fn truncated_real_file_is_an_error_with_a_line() {
        let text = std::fs::read(JACKSBORO).unwrap();
        for cut in [0, 10, 40, 90, text.len() / 2, text.len() - 5] {
            let e = read_asc(&text[..cut], "cut.asc").unwrap_err().to_string();
            assert!(e.starts_with("cut.asc"), "{e}");
        }
    }
}
