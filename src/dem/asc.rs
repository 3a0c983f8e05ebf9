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
//!
//! The header is read a line at a time. The values are read in blocks of whole lines (8 MiB),
//! each cut into pieces at line ends and parsed in parallel (rayon); the pieces are joined in
//! file order. Numbers follow Rust's `f64` syntax and are read correctly rounded. A piece with
//! anything unusual in it (an error, a NaN or infinite value, non-ASCII text) is read again a
//! line at a time with `str::parse`, which finds the first error and its line, so the rules and
//! messages are those of the sequential reader this one replaced (`tests/suite/asc_reader.rs` checks).

use std::io::{BufRead, BufReader, Read};
use std::ops::Range;
use std::path::Path;

use rayon::prelude::*;

use super::grid::{ElevationGrid, alloc_heights, checked_sample_count};
use super::{io_error, parse_error};
use crate::budget::quote;
use crate::error::Error;
use crate::io::is_space;

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
/// The file must be a regular file. Its values are read a block of lines at a time and parsed
/// in parallel (rayon).
///
/// # Errors
/// [`Error::Io`] if the file cannot be read or is not a regular file; [`Error::Parse`] (with the
/// line where it applies) for a missing/repeated/unknown header key, a bad number, too few or
/// too many values, a non-positive cell size, NaN/infinite cells or a grid larger than
/// [`MAX_SAMPLES`](crate::dem::MAX_SAMPLES).
pub fn load_asc(path: impl AsRef<Path>) -> Result<ElevationGrid, Error> {
    let path = path.as_ref();
    let name = path.display().to_string();
    let (file, length) = crate::io::open_regular(path)?;
    parse(
        BufReader::new(file),
        &name,
        Some(length),
        (BLOCK_BYTES, PIECE_BYTES),
    )
}

/// Parses an ESRI ASCII grid from `reader`; `name` labels errors (usually the file path).
///
/// # Errors
/// As [`load_asc`].
pub fn read_asc(reader: impl BufRead, name: &str) -> Result<ElevationGrid, Error> {
    parse(reader, name, None, (BLOCK_BYTES, PIECE_BYTES))
}

/// [`read_asc`] reading the values `block_bytes` at a time (at least 1) in pieces of about
/// `piece_bytes`, for tests of the block and piece seams.
#[doc(hidden)]
pub fn read_asc_in_pieces(
    reader: impl BufRead,
    name: &str,
    block_bytes: usize,
    piece_bytes: usize,
) -> Result<ElevationGrid, Error> {
    parse(reader, name, None, (block_bytes.max(1), piece_bytes.max(1)))
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

/// Text read from the file at a time (plus the partial line left from the last read).
const BLOCK_BYTES: usize = 8 << 20;

/// Text one parallel task parses, about: below it, a task costs more than it saves.
const PIECE_BYTES: usize = 128 << 10;

/// The longest header line read (64 KiB; no header line needs more); the first data line,
/// which the header loop reads too, goes on past it in blocks.
const HEADER_LINE_BYTES: usize = 64 << 10;

/// A line read whole before it is cut at a blank, where blocks are smaller (tests' blocks of a
/// few bytes); a line longer than a block and this is parsed in parts (its error messages
/// then found part by part).
const LONG_LINE: usize = 1 << 20;

/// The error for a header line of more than [`HEADER_LINE_BYTES`].
fn long_line(path: &str, line: usize) -> Error {
    parse_error(
        path,
        Some(line),
        format!("a header line of more than {HEADER_LINE_BYTES} bytes"),
    )
}

/// Reads a grid from `reader` (`size_hint`: the file's length, when known), the values in
/// blocks of `sizes.0` bytes and pieces of about `sizes.1`.
fn parse(
    mut reader: impl BufRead,
    path: &str,
    size_hint: Option<u64>,
    sizes: (usize, usize),
) -> Result<ElevationGrid, Error> {
    let mut header = Header {
        path: path.to_owned(),
        entries: Default::default(),
    };
    let mut buf = Vec::new();
    let mut line_no = 0usize;

    // The header, a line at a time, up to the first line that starts with a number. A line is
    // read up to [`HEADER_LINE_BYTES`]: the first data line may be far longer (a whole grid on
    // one line), and goes on in the values' blocks; a header line may not.
    let g = loop {
        buf.clear();
        let read = (&mut reader)
            .take(HEADER_LINE_BYTES as u64)
            .read_until(b'\n', &mut buf)
            .map_err(|e| io_error(path, e))?;
        if read == 0 {
            // No data line: the header's defects first, then too few values.
            let g = header.geometry()?;
            return Err(too_few(path, &g, 0, line_no));
        }
        line_no += 1;
        // A line cut short: its tokens are those before its last blank (the rest of a cut
        // token follows in the blocks).
        let cut = read == HEADER_LINE_BYTES && !buf.ends_with(b"\n");
        let whole = match cut {
            false => buf.len(),
            true => buf.iter().rposition(|&b| is_space(b)).unwrap_or(0),
        };
        let mut text = std::str::from_utf8(&buf[..whole])
            .map_err(|_| parse_error(path, Some(line_no), "line is not valid UTF-8 text"))?;
        if line_no == 1 {
            text = text.strip_prefix('\u{feff}').unwrap_or(text);
        }
        let mut tokens = text.split_whitespace();
        let Some(first) = tokens.next() else {
            if cut {
                // One token of 64 KiB: no number, and no key.
                let token = String::from_utf8_lossy(&buf);
                let token = token.trim_start();
                if !token.is_empty() {
                    return Err(parse_error(
                        path,
                        Some(line_no),
                        format!("unknown header key '{}'", quote(token)),
                    ));
                }
                return Err(long_line(path, line_no));
            }
            continue; // blank header line
        };
        if first.parse::<f64>().is_ok() {
            break header.geometry()?;
        }
        if cut {
            return Err(long_line(path, line_no));
        }
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
    };

    // Each value takes at least two bytes (digit + separator), so a file cannot justify more
    // capacity than half its size.
    let plausible = size_hint.map_or(1 << 20, |s| {
        usize::try_from(s / 2 + 1).unwrap_or(usize::MAX)
    });
    let mut heights = alloc_heights(path, g.count.min(plausible))?;
    crate::huge_pages::advise(&mut heights);
    let mut values = Values {
        path,
        g: &g,
        heights,
        lines: line_no - 1,
        scratch: Vec::new(),
    };

    // The values, from the first data line on, a block of whole lines at a time.
    let (block_bytes, piece_bytes) = sizes;
    let mut text = buf;
    // The last byte parsed: whether the file's last line has its newline.
    let mut last = None;
    loop {
        let want = block_bytes as u64;
        let read = (&mut reader).take(want).read_to_end(&mut text);
        let at_end = match read {
            Ok(n) => (n as u64) < want,
            Err(e) => {
                // The whole lines before the failure are parsed first, as they were read.
                let whole = text.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
                values.parse_block(&text[..whole], piece_bytes)?;
                return Err(io_error(path, e));
            }
        };
        // Up to the last line's end; a line longer than a block (a grid on one line, up to the
        // file's whole size) up to its last blank, whole tokens a block at a time, not read
        // whole.
        let whole = if at_end {
            text.len()
        } else {
            match text.iter().rposition(|&b| b == b'\n') {
                Some(i) => i + 1,
                None if text.len() < block_bytes.max(LONG_LINE) => continue, // read on
                None => match text.iter().rposition(|&b| is_space(b)) {
                    Some(i) => i + 1,
                    None => {
                        return Err(parse_error(
                            path,
                            Some(values.lines + 1),
                            format!(
                                "a token of more than {} bytes, which is no number",
                                text.len()
                            ),
                        ));
                    }
                },
            }
        };
        values.parse_block(&text[..whole], piece_bytes)?;
        last = text[..whole].last().copied().or(last);
        if at_end {
            if last.is_some_and(|b| b != b'\n') {
                values.lines += 1; // the last line has no newline
            }
            break;
        }
        text.drain(..whole);
    }

    let Values { heights, lines, .. } = values;
    if heights.len() < g.count {
        return Err(too_few(path, &g, heights.len(), lines));
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

/// The error for a file that ends after `read` values, on line `lines` (0: an empty file).
fn too_few(path: &str, g: &Geometry, read: usize, lines: usize) -> Error {
    parse_error(
        path,
        (lines > 0).then_some(lines),
        format!(
            "too few values: file ends after {read} of {} ({} columns x {} rows)",
            g.count, g.ncols, g.nrows
        ),
    )
}

/// The values read so far.
struct Values<'a> {
    path: &'a str,
    g: &'a Geometry,
    heights: Vec<Option<f64>>,
    /// Lines of the file before the text still to parse.
    lines: usize,
    /// One buffer for the values of each piece of a block, kept from block to block: fresh
    /// buffers would cost a page fault every 4 KiB each time.
    scratch: Vec<Vec<Option<f64>>>,
}

/// What [`scan`] made of a piece of text (its values are in a scratch buffer).
struct Scanned {
    /// Its `\n` bytes.
    newlines: usize,
    /// False when the piece holds something other than ASCII whitespace and numbers that are
    /// finite or the NODATA value: an error, or non-ASCII text. [`Values::parse_lines`] reads it.
    clean: bool,
}

impl Values<'_> {
    /// Parses `text`, whole lines (the last one may lack its newline, or be a part of a line
    /// longer than a block, cut at a blank), in pieces of about
    /// `piece_bytes` in parallel; the pieces are joined in file order, and a piece that is not
    /// [`Scanned::clean`] or would overflow the grid is parsed again by [`Self::parse_lines`],
    /// which finds its first error.
    fn parse_block(&mut self, text: &[u8], piece_bytes: usize) -> Result<(), Error> {
        let pieces = split(text, piece_bytes.max(1));
        if self.scratch.len() < pieces.len() {
            self.scratch.resize_with(pieces.len(), Vec::new);
        }
        let nodata = self.g.nodata;
        // No piece keeps more values than the grid has room for (a 40 MB line of a 3 × 2 grid
        // held 16 bytes a value before its count was checked).
        let most = self.g.count - self.heights.len();
        let mut scratch = std::mem::take(&mut self.scratch);
        let scan_piece = |(r, values): (&Range<usize>, &mut Vec<Option<f64>>)| {
            values.clear();
            scan(&text[r.clone()], nodata, most, values)
        };
        let scanned: Vec<Scanned> = if pieces.len() == 1 {
            pieces.iter().zip(&mut scratch).map(scan_piece).collect()
        } else {
            pieces
                .par_iter()
                .zip(&mut scratch[..pieces.len()])
                .map(scan_piece)
                .collect()
        };
        // Clean pieces are appended in runs, in parallel; the others are parsed again in turn.
        let mut run = 0..0;
        let mut run_values = 0;
        let mut result = Ok(());
        for (k, s) in scanned.iter().enumerate() {
            let room = self.g.count - self.heights.len() - run_values;
            if s.clean && scratch[k].len() <= room {
                run.end = k + 1;
                run_values += scratch[k].len();
                self.lines += s.newlines;
                continue;
            }
            append(&mut self.heights, &scratch[run.clone()]);
            (run, run_values) = (k + 1..k + 1, 0);
            result = self.parse_lines(&text[pieces[k].clone()]);
            if result.is_err() {
                break;
            }
        }
        if result.is_ok() {
            append(&mut self.heights, &scratch[run]);
        }
        self.scratch = scratch;
        result
    }

    /// Parses whole lines one at a time with `str::parse`: the reference for every rule and
    /// message, used where [`scan`] finds something unusual.
    fn parse_lines(&mut self, text: &[u8]) -> Result<(), Error> {
        let (path, g) = (self.path, self.g);
        for line in text.split_inclusive(|&b| b == b'\n') {
            self.lines += 1;
            let line_no = self.lines;
            let text = std::str::from_utf8(line)
                .map_err(|_| parse_error(path, Some(line_no), "line is not valid UTF-8 text"))?;
            for token in text.split_whitespace() {
                let value = token.parse::<f64>().map_err(|_| {
                    parse_error(
                        path,
                        Some(line_no),
                        format!("bad number '{}'", quote(token)),
                    )
                })?;
                if self.heights.len() == g.count {
                    return Err(parse_error(
                        path,
                        Some(line_no),
                        format!(
                            "too many values: expected {} ({} columns x {} rows)",
                            g.count, g.ncols, g.nrows
                        ),
                    ));
                }
                match cell(value, g.nodata) {
                    Some(height) => self.heights.push(height),
                    None => {
                        return Err(parse_error(
                            path,
                            Some(line_no),
                            format!("non-finite value '{}' (not the nodata_value)", quote(token)),
                        ));
                    }
                }
            }
        }
        // A last line without its newline was counted, as one.
        if text.last().is_some_and(|&b| b != b'\n') {
            self.lines -= 1;
        }
        Ok(())
    }
}

/// A cell's height: `Some(None)` for NODATA, `Some(Some(v))` for a finite value, `None` for a
/// NaN or infinite value that is not the NODATA value (an error).
fn cell(value: f64, nodata: Option<f64>) -> Option<Option<f64>> {
    let is_nodata = nodata.is_some_and(|nd| nd == value || (nd.is_nan() && value.is_nan()));
    if is_nodata {
        Some(None)
    } else if value.is_finite() {
        Some(Some(value))
    } else {
        None
    }
}

/// Reads the values of an ASCII piece of text into `values`. A plain decimal (a sign, at most
/// 19 digits worth at most 2^53, a point anywhere) is read here; any other token with
/// `fast-float2`; one that it does not take whole, or reads as NaN or infinite, with
/// `str::parse`. All three give the correctly rounded value. A token that is not a number, a NaN
/// or infinite value that is not the NODATA value, or any non-ASCII byte, stops the scan with
/// `clean: false`.
fn scan(text: &[u8], nodata: Option<f64>, most: usize, values: &mut Vec<Option<f64>>) -> Scanned {
    let mut newlines = 0;
    let unclean = |newlines| Scanned {
        newlines,
        clean: false,
    };
    let mut i = 0;
    loop {
        while let Some(&b) = text.get(i) {
            match b {
                b'\n' => newlines += 1,
                b' ' | b'\t' | b'\r' | 0x0b | 0x0c => {}
                _ => break,
            }
            i += 1;
        }
        if i == text.len() {
            break;
        }
        let rest = &text[i..];
        let (value, used) = match plain_decimal(rest) {
            Some(found) => found,
            None => match fast_float2::parse_partial::<f64, _>(rest) {
                Ok((v, n)) if v.is_finite() && rest.get(n).is_none_or(|&b| is_space(b)) => (v, n),
                _ => {
                    let n = rest.iter().position(|&b| is_space(b)).unwrap_or(rest.len());
                    let token = &rest[..n];
                    let parsed = if token.is_ascii() {
                        // ASCII is UTF-8.
                        std::str::from_utf8(token)
                            .ok()
                            .and_then(|t| t.parse::<f64>().ok())
                    } else {
                        None
                    };
                    match parsed {
                        Some(v) => (v, n),
                        None => return unclean(newlines),
                    }
                }
            },
        };
        match cell(value, nodata) {
            // More values than the grid has room for: an error, found by the line parser.
            Some(_) if values.len() == most => return unclean(newlines),
            Some(height) => values.push(height),
            None => return unclean(newlines),
        }
        i += used;
    }
    Scanned {
        newlines,
        clean: true,
    }
}

/// Exact powers of ten, 10^0 to 10^22: every one is a double.
const POW10: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

/// The value and length of the token at the start of `text` when it is a plain decimal
/// (`[+-]digits[.digits]`, or with no digits on one side of the point) of at most 19 digits,
/// worth at most 2^53 without its point, and ends at whitespace or at the end of `text`.
///
/// Such a value is `m / 10^k` with `m` and `10^k` (k ≤ 19) exact doubles, so the one division,
/// correctly rounded, gives the correctly rounded decimal (Clinger's fast path; `str::parse` and
/// `fast-float2` take the same path for these tokens).
fn plain_decimal(text: &[u8]) -> Option<(f64, usize)> {
    let mut i = 0;
    let negative = match text.first() {
        Some(b'-') => {
            i = 1;
            true
        }
        Some(b'+') => {
            i = 1;
            false
        }
        _ => false,
    };
    let mut m = 0u64;
    let mut digits = 0usize;
    let mut point = None;
    while let Some(&b) = text.get(i) {
        match b {
            b'0'..=b'9' => {
                m = m.wrapping_mul(10).wrapping_add(u64::from(b - b'0'));
                digits += 1;
            }
            b'.' if point.is_none() => point = Some(digits),
            _ => break,
        }
        i += 1;
    }
    if digits == 0 || digits > 19 || m > 1 << 53 || text.get(i).is_some_and(|&b| !is_space(b)) {
        return None;
    }
    let fraction = digits - point.unwrap_or(digits);
    let magnitude = m as f64 / POW10[fraction];
    Some((if negative { -magnitude } else { magnitude }, i))
}

/// Appends `parts`, in order, to `heights`, copying them in parallel.
fn append(heights: &mut Vec<Option<f64>>, parts: &[Vec<Option<f64>>]) {
    let total: usize = parts.iter().map(Vec::len).sum();
    heights.reserve(total);
    let mut spare = &mut heights.spare_capacity_mut()[..total];
    let mut slots = Vec::with_capacity(parts.len());
    for part in parts {
        let (slot, rest) = spare.split_at_mut(part.len());
        slots.push(slot);
        spare = rest;
    }
    slots.into_par_iter().zip(parts).for_each(|(slot, part)| {
        for (to, from) in slot.iter_mut().zip(part) {
            to.write(*from);
        }
    });
    // SAFETY: the `total` slots after the length were all written just above (each slot has
    // the length of its part).
    unsafe { heights.set_len(heights.len() + total) };
}

/// Cuts `text` into ranges of about `target` bytes (at least 1) that end after a `\n` (or at the
/// end of `text`).
fn split(text: &[u8], target: usize) -> Vec<Range<usize>> {
    let mut ranges = Vec::new();
    let mut start = 0;
    while start < text.len() {
        let cut = start.saturating_add(target).min(text.len());
        let end = text[cut..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(text.len(), |i| cut + i + 1);
        ranges.push(start..end);
        start = end;
    }
    ranges
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

    /// A line longer than a block (a grid on one line) is read a block at a time, cut at
    /// blanks, and gives the grid read from short lines; too many values on such a line are
    /// found without holding the line or its values whole (a 3 × 2 grid's 40 MB line peaked at
    /// 2.2 GB); a header line past 64 KiB and a token past a block are refused.
    #[test]
    fn lines_longer_than_a_block_are_read_in_parts() {
        let header = "ncols 300\nnrows 2000\nxllcorner 0\nyllcorner 0\ncellsize 1\n";
        let values: Vec<String> = (0..600_000).map(|k| format!("{}.5", k % 977)).collect();
        let one_line = format!("{header}{}\n", values.join(" "));
        assert!(one_line.len() > LONG_LINE * 3);
        let short_lines = format!("{header}{}\n", values.join("\n"));
        let a = read_asc_in_pieces(one_line.as_bytes(), "a.asc", 1 << 16, 1 << 12).unwrap();
        let b = read(&short_lines).unwrap();
        assert_eq!(a.heights, b.heights);
        // Without its newline, and with a blank at the end.
        for end in ["", " "] {
            let text = format!("{header}{}{end}", values.join(" "));
            let g = read_asc_in_pieces(text.as_bytes(), "a.asc", 1 << 16, 1 << 12).unwrap();
            assert_eq!(g.heights, b.heights);
        }
        let small = "ncols 3\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n";
        let long = format!("{small}{}\n", "1 ".repeat(10 << 20));
        let e = read_asc_in_pieces(long.as_bytes(), "t.asc", 1 << 20, 1 << 16)
            .unwrap_err()
            .to_string();
        assert!(e.contains("t.asc:6: too many values: expected 6"), "{e}");
        let e = err(&format!("ncols 3{}\n", " ".repeat(70_000)));
        assert!(
            e.contains("t.asc:1: a header line of more than 65536 bytes"),
            "{e}"
        );
        let e = read_asc_in_pieces(
            format!("{small}1 {}", "7".repeat(3 << 20)).as_bytes(),
            "t.asc",
            1 << 20,
            1 << 16,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("t.asc:6: a token of more than"), "{e}");
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
