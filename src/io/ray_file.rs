//! Reading ray files (one ray per line, `ox oy oz dx dy dz [tmax]`), and the point (`x y z`)
//! and pair (`x1 y1 z1 x2 y2 z2`) files of the line-of-sight commands.
//!
//! [`load_rays`] reads a whole ray file; [`RayReader`] reads one a chunk at a time, so memory
//! stays bounded whatever the number of rays ([`count_rays`] checks a file and counts its rays
//! first, in constant memory).
//!
//! Numbers are whitespace separated, `#` starts a comment anywhere on a line
//! and blank lines are skipped. The parser accepts any value Rust parses as
//! an `f64`, including `nan` and `inf`: deciding what such rays mean (they
//! come back flagged invalid) is the picker's job, not the reader's.

use std::path::Path;

use glam::DVec3;

use crate::budget::quote;
use crate::error::Error;

/// One ray read from a ray file.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayLine {
    /// The ray's origin `(ox, oy, oz)`.
    pub origin: DVec3,
    /// The ray's direction `(dx, dy, dz)`, as written (not normalized).
    pub dir: DVec3,
    /// The optional seventh number: the largest ray parameter to accept
    /// (`inf` is allowed and means unbounded).
    pub tmax: Option<f64>,
}

/// Parses the text of a ray file; `path` is only used in error messages.
///
/// A line with fewer than 6 or more than 7 numbers, or with a token that is
/// not a number, is an [`Error::Parse`] naming `path` and the 1-based line.
pub fn parse_rays(path: &str, text: &str) -> Result<Vec<RayLine>, Error> {
    let lines = parse_number_lines(path, text, &[6, 7], RAY_NUMBERS)?;
    Ok(lines
        .iter()
        .map(|(_, v)| RayLine {
            origin: DVec3::new(v[0], v[1], v[2]),
            dir: DVec3::new(v[3], v[4], v[5]),
            tmax: v.get(6).copied(),
        })
        .collect())
}

/// Parses a point file: one `x y z` per line, same comment rules as ray files.
pub fn parse_points(path: &str, text: &str) -> Result<Vec<DVec3>, Error> {
    let lines = parse_number_lines(path, text, &[3], "3 numbers (x y z)")?;
    Ok(lines
        .iter()
        .map(|(_, v)| DVec3::new(v[0], v[1], v[2]))
        .collect())
}

/// Parses a pair file: one `x1 y1 z1 x2 y2 z2` per line, same comment rules as ray files.
pub fn parse_pairs(path: &str, text: &str) -> Result<Vec<(DVec3, DVec3)>, Error> {
    let lines = parse_number_lines(path, text, &[6], "6 numbers (x1 y1 z1 x2 y2 z2)")?;
    Ok(lines
        .iter()
        .map(|(_, v)| (DVec3::new(v[0], v[1], v[2]), DVec3::new(v[3], v[4], v[5])))
        .collect())
}

/// What a line of a number file takes once parsed: its line number and numbers (a vector of
/// up to eight, with the allocator's share), then the ray, point pair or pixel made of them.
const PARSED_LINE_BYTES: u64 = 160;

/// The numbers of each non-blank line with its 1-based line number; each line must hold one of
/// `counts` numbers. `#` starts a comment; a leading byte-order mark is skipped.
pub(crate) fn parse_number_lines(
    path: &str,
    text: &str,
    counts: &[usize],
    expected: &str,
) -> Result<Vec<(usize, Vec<f64>)>, Error> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    // Each line's numbers, and what its caller makes of them, checked against the budget
    // before they are made: a file of short lines parses into ten times its size.
    let count = text.bytes().filter(|&b| b == b'\n').count() as u64
        + u64::from(!text.is_empty() && !text.ends_with('\n'));
    crate::budget::check(
        &format!("the {count} lines of {path}"),
        count,
        PARSED_LINE_BYTES,
    )?;
    let mut lines = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        if let Some(numbers) = parse_line(path, i + 1, raw.as_bytes(), counts, expected)? {
            lines.push((i + 1, numbers.values().to_vec()));
        }
    }
    Ok(lines)
}

/// The numbers of one line (up to [`Numbers::MOST`] kept).
struct Numbers {
    values: [f64; Numbers::MOST],
    len: usize,
}

impl Numbers {
    const MOST: usize = 8;

    fn values(&self) -> &[f64] {
        &self.values[..self.len.min(Self::MOST)]
    }
}

/// Parses line `number` (1-based) of a number file: `None` when it is blank or a comment,
/// otherwise its numbers, which must be one of `counts` (each at most [`Numbers::MOST`]). A
/// line that is not valid UTF-8 is an error.
fn parse_line(
    path: &str,
    number: usize,
    raw: &[u8],
    counts: &[usize],
    expected: &str,
) -> Result<Option<Numbers>, Error> {
    // A plain line is ASCII but for a comment, which it checks: valid UTF-8.
    if let Some(numbers) = plain_line(raw, counts) {
        return Ok(numbers);
    }
    let error = |message: String| Error::Parse {
        path: path.to_owned(),
        line: Some(number),
        message,
    };
    let raw = std::str::from_utf8(raw)
        .map_err(|_| error("the file is not valid UTF-8 text".to_owned()))?;
    let content = raw.split('#').next().unwrap_or_default();
    let mut numbers = Numbers {
        values: [0.0; Numbers::MOST],
        len: 0,
    };
    let mut push = |token: &str| -> Result<(), Error> {
        let value = token
            .parse::<f64>()
            .map_err(|_| error(format!("'{}' is not a number", quote(token))))?;
        if let Some(slot) = numbers.values.get_mut(numbers.len) {
            *slot = value;
        }
        numbers.len += 1;
        Ok(())
    };
    if content.is_ascii() {
        // The same tokens as `split_whitespace`, without decoding characters: that decoding
        // was a third of a ray file's parse.
        let tokens = content.as_bytes().split(|&b| super::is_space(b));
        for token in tokens.filter(|t| !t.is_empty()) {
            // SAFETY: a run of ASCII bytes is UTF-8.
            push(unsafe { std::str::from_utf8_unchecked(token) })?;
        }
    } else {
        for token in content.split_whitespace() {
            push(token)?;
        }
    }
    if numbers.len == 0 {
        return Ok(None);
    }
    if !counts.contains(&numbers.len) {
        return Err(error(format!("expected {expected}, found {}", numbers.len)));
    }
    Ok(Some(numbers))
}

/// The numbers of a line whose tokens are all finite numbers that `fast-float2` reads whole,
/// separated by ASCII white space, as many as one of `counts` (`Some(None)` for a blank or
/// comment line); `None` sends the line to [`parse_line`]'s own reading, which reads every
/// such token as the same number (`str::parse` and `fast-float2` both round correctly, and
/// accept the same finite decimals: `fast_lines_read_what_str_parse_reads`) and says what is
/// wrong with the rest.
#[inline]
fn plain_line(line: &[u8], counts: &[usize]) -> Option<Option<Numbers>> {
    let mut numbers = Numbers {
        values: [0.0; Numbers::MOST],
        len: 0,
    };
    let ends = |b: u8| super::is_space(b) || b == b'#';
    let mut p = 0;
    loop {
        while line.get(p).copied().is_some_and(super::is_space) {
            p += 1;
        }
        if p == line.len() {
            break;
        }
        if line[p] == b'#' {
            // A comment's text must be UTF-8 too (else the line's error says it is not).
            if std::str::from_utf8(&line[p..]).is_err() {
                return None;
            }
            break;
        }
        let (value, used) = fast_float2::parse_partial::<f64, _>(&line[p..]).ok()?;
        p += used;
        if used == 0 || !value.is_finite() || !line.get(p).is_none_or(|&b| ends(b)) {
            return None;
        }
        *numbers.values.get_mut(numbers.len)? = value;
        numbers.len += 1;
    }
    match numbers.len {
        0 => Some(None),
        n if counts.contains(&n) => Some(Some(numbers)),
        _ => None,
    }
}

/// Reads and parses the ray file at `path` (see [`parse_rays`]; read as [`RayReader`] reads,
/// a block at a time on all cores).
pub fn load_rays(path: &Path) -> Result<Vec<RayLine>, Error> {
    load_rays_as(path, |ray| *ray)
}

/// [`load_rays`], each ray made into what `make` makes of it as it is read (the file's rays
/// are never all held twice). What they take is checked against the memory budget as they
/// come.
pub fn load_rays_as<T: Send>(
    path: &Path,
    make: impl Fn(&RayLine) -> T + Sync,
) -> Result<Vec<T>, Error> {
    read_rays_as(RayReader::open(path)?, make)
}

/// [`load_rays_as`] from `reader` (a file opened by [`RayReader::open`], standard input by
/// [`RayReader::stdin`]), to its end.
pub fn read_rays_as<T: Send, R: std::io::BufRead>(
    mut reader: RayReader<R>,
    make: impl Fn(&RayLine) -> T + Sync,
) -> Result<Vec<T>, Error> {
    use rayon::prelude::*;
    let (mut all, mut chunk) = (Vec::new(), Vec::new());
    while reader.read_chunk(&mut chunk, 1 << 18)? > 0 {
        crate::budget::check(
            &format!("the rays of {}", reader.name),
            (all.len() + chunk.len()) as u64,
            size_of::<T>() as u64,
        )?;
        all.par_extend(chunk.par_iter().with_min_len(4096).map(&make));
    }
    Ok(all)
}

/// The rays of the ray file at `path` in chunks of `max` rays (the last one shorter), each read
/// into memory of its final size (no chunk grows by copying), checked against the memory budget
/// as they come.
pub fn load_ray_chunks(path: &Path, max: usize) -> Result<Vec<Vec<RayLine>>, Error> {
    let max = max.max(1);
    let mut reader = RayReader::open(path)?;
    let most = std::fs::metadata(path)
        .ok()
        .filter(|m| m.is_file())
        .map_or(usize::MAX, |m| {
            usize::try_from(m.len() / MIN_RAY_LINE + 1).unwrap_or(usize::MAX)
        });
    let (mut chunks, mut total) = (Vec::new(), 0usize);
    loop {
        let mut chunk = Vec::with_capacity(max.min(most.saturating_sub(total).max(1)));
        if reader.read_chunk(&mut chunk, max)? == 0 {
            return Ok(chunks);
        }
        total += chunk.len();
        crate::budget::check(
            &format!("the rays of {}", path.display()),
            (total + max) as u64,
            size_of::<RayLine>() as u64,
        )?;
        chunks.push(chunk);
    }
}

/// Reads and parses the point file at `path` (see [`parse_points`]).
pub fn load_points(path: &Path) -> Result<Vec<DVec3>, Error> {
    let name = path.display().to_string();
    parse_points(&name, &read_text(path)?)
}

/// Reads and parses the pair file at `path` (see [`parse_pairs`]).
pub fn load_pairs(path: &Path) -> Result<Vec<(DVec3, DVec3)>, Error> {
    let name = path.display().to_string();
    parse_pairs(&name, &read_text(path)?)
}

/// Reads a whole number file (rays, points, pairs, pixels), naming it (and the line of the
/// first invalid UTF-8) on failure. A file longer than the memory budget, or with a line longer
/// than [`MAX_LINE_BYTES`], is refused as soon as the reading gets there (a device or a pipe says
/// nothing of its length beforehand).
pub(crate) fn read_text(path: &Path) -> Result<String, Error> {
    let (most, why) = crate::budget::limit_and_why();
    read_text_within(
        path,
        most,
        &format!("the memory budget ({why})"),
        Some(MAX_LINE_BYTES),
    )
}

/// [`read_text`] for a file of at most `most` bytes (`limit` says what sets that), and lines of
/// at most `longest_line` bytes when given.
pub(crate) fn read_text_within(
    path: &Path,
    most: u64,
    limit: &str,
    longest_line: Option<usize>,
) -> Result<String, Error> {
    use std::io::Read;
    let name = path.display().to_string();
    let io = |source| Error::Io {
        path: name.clone(),
        source,
    };
    let too_long = || {
        Error::Invalid(format!(
            "{name} is longer than {}, {limit}",
            crate::budget::human(most)
        ))
    };
    let overlong = |line: usize, longest: usize| Error::Parse {
        path: name.clone(),
        line: Some(line),
        message: format!(
            "the line is longer than {longest} bytes; a line of this file holds a few numbers"
        ),
    };
    let mut file = std::fs::File::open(path).map_err(io)?;
    // A regular file's length is known: refused before reading, read without regrowing.
    let length = file
        .metadata()
        .ok()
        .filter(|m| m.is_file())
        .map(|m| m.len());
    if length.is_some_and(|n| n > most) {
        return Err(too_long());
    }
    let mut bytes = Vec::with_capacity(length.unwrap_or(0) as usize);
    let (mut block, mut line_start, mut lines) = (vec![0u8; 64 << 10], 0usize, 1usize);
    loop {
        let n = match file.read(&mut block) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(io(e)),
        };
        if (bytes.len() + n) as u64 > most {
            return Err(too_long());
        }
        let base = bytes.len();
        bytes.extend_from_slice(&block[..n]);
        if let Some(longest) = longest_line {
            // Each line ended in this block, then the one it leaves open, by the length of its
            // text ([`text_bytes`], as `RayReader` counts).
            let ends =
                memchr::memchr_iter(b'\n', &block[..n]).map(|k| (base + k + 1, LineEnd::Break));
            for (end, how) in ends.chain(std::iter::once((bytes.len(), LineEnd::Open))) {
                if text_bytes(&bytes[line_start..end], how) > longest {
                    return Err(overlong(lines, longest));
                }
                if matches!(how, LineEnd::Break) {
                    (line_start, lines) = (end, lines + 1);
                }
            }
        }
    }
    if let Some(longest) = longest_line
        && text_bytes(&bytes[line_start..], LineEnd::Last) > longest
    {
        return Err(overlong(lines, longest));
    }
    String::from_utf8(bytes).map_err(|e| {
        let bytes = e.as_bytes();
        let valid = bytes
            .get(..e.utf8_error().valid_up_to())
            .unwrap_or_default();
        Error::Parse {
            path: name,
            line: Some(1 + valid.iter().filter(|&&b| b == b'\n').count()),
            message: "the file is not valid UTF-8 text".to_owned(),
        }
    })
}

/// The longest line a [`RayReader`] accepts, in bytes: a ray line holds 6 or 7 numbers, so a
/// longer line is not a ray file, and refusing it keeps the reader's memory bounded.
/// A line's length is its text's, without its break (`\n` or `\r\n`), however the line ends
/// ([`text_bytes`]); line 1's byte-order mark, if any, counts.
pub const MAX_LINE_BYTES: usize = 1 << 20;

/// How a line read so far ends, for [`text_bytes`].
#[derive(Clone, Copy)]
enum LineEnd {
    /// With its break (`\n` or `\r\n`).
    Break,
    /// Not yet: more may follow, and a last `\r` may be the start of its break.
    Open,
    /// At the end of the file, with no break: all of it is text.
    Last,
}

/// The bytes of `line`'s text, without its break; for a line still [`LineEnd::Open`], the least
/// its text can be.
fn text_bytes(line: &[u8], end: LineEnd) -> usize {
    let line = match end {
        LineEnd::Break => line.strip_suffix(b"\n").unwrap_or(line),
        LineEnd::Open => line,
        LineEnd::Last => return line.len(),
    };
    line.strip_suffix(b"\r").unwrap_or(line).len()
}

/// Reads a ray file a chunk of rays at a time, so memory stays bounded whatever the number of
/// rays: the reader holds the lines of one block (about [`BLOCK_BYTES`], and at most one line
/// more), the caller one chunk. A block's lines are parsed on all cores.
///
/// It reads the format of [`parse_rays`], with the same errors (file, 1-based line, message),
/// found in file order: an error on a later line is only reported when the reading gets there,
/// after the chunks before it were returned. A line that is not valid UTF-8 is reported with
/// its number, as [`load_rays`] does; a line longer than [`MAX_LINE_BYTES`] is an error.
///
/// ```
/// use raypick::io::ray_file::RayReader;
///
/// let text = "0 0 5 0 0 -1\n# a comment\n1 1 5 0 0 -1 2.5\n3 3 5 0 0 -1\n";
/// let mut reader = RayReader::new("rays.txt", text.as_bytes());
/// let first = reader.next_chunk(2)?;
/// assert_eq!(first.len(), 2);
/// assert_eq!(first[1].tmax, Some(2.5));
/// assert_eq!(reader.next_chunk(2)?.len(), 1);
/// assert!(reader.next_chunk(2)?.is_empty()); // the end
/// # Ok::<(), raypick::Error>(())
/// ```
pub struct RayReader<R> {
    name: String,
    reader: R,
    /// Lines read so far (the number of the last line read).
    line: usize,
    /// The bytes of the lines read and not yet parsed, one after another.
    buf: Vec<u8>,
    /// Where each of those lines lies in `buf` (after a byte-order mark on line 1).
    spans: Vec<(usize, usize)>,
    /// Set after the end of the input, or after an error (which ends the reading).
    done: bool,
}

/// The bytes of lines a [`RayReader`] reads before it parses them (it reads on to the end of
/// the line that crosses this).
pub const BLOCK_BYTES: usize = 8 << 20;

/// Lines parsed as one piece of work: a block of fewer is parsed on the calling thread.
const PIECE_LINES: usize = 4096;

/// The fewest bytes a ray line takes (`0 0 0 1 0 0` and its line break): a file holds at most
/// one ray for each.
pub const MIN_RAY_LINE: u64 = 12;

/// What a ray line must hold, as the errors say it.
const RAY_NUMBERS: &str = "6 or 7 numbers (ox oy oz dx dy dz [tmax])";

impl RayReader<std::io::BufReader<std::fs::File>> {
    /// Opens the ray file at `path` (a regular file, or a pipe such as `/dev/stdin`; a folder
    /// is an error).
    pub fn open(path: &Path) -> Result<Self, Error> {
        let name = path.display().to_string();
        let io = |source| Error::Io {
            path: name.clone(),
            source,
        };
        // A folder opens, and fails only at the first read: after the output has begun.
        if std::fs::metadata(path).is_ok_and(|m| m.is_dir()) {
            return Err(io(std::io::Error::new(
                std::io::ErrorKind::IsADirectory,
                "is a folder, not a ray file",
            )));
        }
        let file = std::fs::File::open(path).map_err(io)?;
        Ok(Self::new(
            name,
            std::io::BufReader::with_capacity(1 << 16, file),
        ))
    }
}

/// What errors call standard input, read as a ray file ([`RayReader::stdin`]).
pub const STDIN_NAME: &str = "standard input";

impl RayReader<std::io::StdinLock<'static>> {
    /// A reader of the rays on standard input, named [`STDIN_NAME`] in errors (the command
    /// line's `-` for a ray file).
    pub fn stdin() -> Self {
        Self::new(STDIN_NAME, std::io::stdin().lock())
    }
}

impl<R: std::io::BufRead> RayReader<R> {
    /// A reader of the ray file `reader`; `name` is the file named in errors.
    pub fn new(name: impl Into<String>, reader: R) -> Self {
        Self {
            name: name.into(),
            reader,
            line: 0,
            buf: Vec::new(),
            spans: Vec::new(),
            done: false,
        }
    }

    /// The number of the last line read (1-based; 0 before the first).
    pub fn line(&self) -> usize {
        self.line
    }

    /// The next ray, or `None` at the end of the file.
    pub fn next_ray(&mut self) -> Result<Option<RayLine>, Error> {
        let mut one = Vec::with_capacity(1);
        self.read_chunk(&mut one, 1)?;
        Ok(one.pop())
    }

    /// The next at most `max` rays (at least 1); an empty vector at the end of the file.
    pub fn next_chunk(&mut self, max: usize) -> Result<Vec<RayLine>, Error> {
        let mut chunk = Vec::new();
        self.read_chunk(&mut chunk, max)?;
        Ok(chunk)
    }

    /// Replaces the content of `chunk` with the next at most `max` rays (at least 1), reusing
    /// its memory; returns how many were read (0 at the end of the file). On an error, `chunk`
    /// holds the rays read before it. The reading stops at the line of the last ray returned.
    pub fn read_chunk(&mut self, chunk: &mut Vec<RayLine>, max: usize) -> Result<usize, Error> {
        chunk.clear();
        let max = max.max(1);
        while chunk.len() < max && !self.done {
            // At most one line for each ray still wanted (a line gives at most one), so the
            // reading never passes the last ray returned; and about a block's bytes.
            self.buf.clear();
            self.spans.clear();
            let mut failure = None;
            while self.spans.len() < max - chunk.len() && self.buf.len() < BLOCK_BYTES {
                match self.next_line() {
                    Ok(Some(span)) => self.spans.push(span),
                    Ok(None) => {
                        self.done = true;
                        break;
                    }
                    Err(e) => {
                        failure = Some(e);
                        break;
                    }
                }
            }
            let first = self.line + 1 - self.spans.len();
            // An error on one of the lines read comes before the one that stopped the reading.
            if let Err(e) = parse_lines(&self.name, &self.buf, &self.spans, first, chunk) {
                failure = Some(e);
            }
            if let Some(e) = failure {
                self.done = true;
                return Err(e);
            }
        }
        Ok(chunk.len())
    }

    /// Reads the rest of the file, checking every line, and returns how many rays it holds.
    pub fn count_rest(&mut self) -> Result<u64, Error> {
        let (mut chunk, mut count) = (Vec::new(), 0);
        loop {
            match self.read_chunk(&mut chunk, 1 << 16)? {
                0 => return Ok(count),
                n => count += n as u64,
            }
        }
    }

    /// Reads the next line onto the end of `buf` and returns where its text lies there (after
    /// a byte-order mark on line 1), or `None` at the end.
    fn next_line(&mut self) -> Result<Option<(usize, usize)>, Error> {
        let start = self.buf.len();
        let io = |source| Error::Io {
            path: self.name.clone(),
            source,
        };
        loop {
            let available = match self.reader.fill_buf() {
                Ok(available) => available,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(io(e)),
            };
            if available.is_empty() {
                if self.buf.len() == start {
                    return Ok(None);
                }
                if text_bytes(&self.buf[start..], LineEnd::Last) > MAX_LINE_BYTES {
                    return Err(self.overlong());
                }
                break;
            }
            let (take, complete) = match memchr::memchr(b'\n', available) {
                Some(i) => (i + 1, true),
                None => (available.len(), false),
            };
            self.buf.extend_from_slice(&available[..take]);
            self.reader.consume(take);
            let end = if complete {
                LineEnd::Break
            } else {
                LineEnd::Open
            };
            if text_bytes(&self.buf[start..], end) > MAX_LINE_BYTES {
                return Err(self.overlong());
            }
            if complete {
                break;
            }
        }
        self.line += 1;
        let bom = self.line == 1 && self.buf[start..].starts_with(b"\xEF\xBB\xBF");
        Ok(Some((if bom { start + 3 } else { start }, self.buf.len())))
    }

    /// The error for the next line: longer than [`MAX_LINE_BYTES`].
    fn overlong(&self) -> Error {
        Error::Parse {
            path: self.name.clone(),
            line: Some(self.line + 1),
            message: format!(
                "the line is longer than {MAX_LINE_BYTES} bytes; a ray line holds 6 or 7 numbers"
            ),
        }
    }
}

/// Parses the lines at `spans` of `buf`, numbered from `first`, onto the end of `chunk`: their
/// rays in order, up to the first error, which is returned. Pieces of [`PIECE_LINES`] lines
/// are parsed in parallel, each into its own stretch of `chunk`, then closed up.
fn parse_lines(
    name: &str,
    buf: &[u8],
    spans: &[(usize, usize)],
    first: usize,
    chunk: &mut Vec<RayLine>,
) -> Result<(), Error> {
    use rayon::prelude::*;
    let parse = |line: usize, (start, end): (usize, usize)| -> Result<Option<RayLine>, Error> {
        let numbers = parse_line(name, line, &buf[start..end], &[6, 7], RAY_NUMBERS)?;
        Ok(numbers.map(|numbers| {
            let v = numbers.values();
            RayLine {
                origin: DVec3::new(v[0], v[1], v[2]),
                dir: DVec3::new(v[3], v[4], v[5]),
                tmax: v.get(6).copied(),
            }
        }))
    };
    // Piece `p`'s rays into `slots`: how many, and the error that ended it.
    let piece = |p: usize, slots: &mut [RayLine], spans: &[(usize, usize)]| {
        let mut n = 0;
        for (k, &span) in spans.iter().enumerate() {
            match parse(first + p * PIECE_LINES + k, span) {
                Ok(Some(ray)) => {
                    slots[n] = ray;
                    n += 1;
                }
                Ok(None) => {}
                Err(e) => return (n, Some(e)),
            }
        }
        (n, None)
    };
    let base = chunk.len();
    let blank = RayLine {
        origin: DVec3::ZERO,
        dir: DVec3::ZERO,
        tmax: None,
    };
    chunk.resize(base + spans.len(), blank);
    let pieces: Vec<(usize, Option<Error>)> = if spans.len() <= PIECE_LINES {
        vec![piece(0, &mut chunk[base..], spans)]
    } else {
        chunk[base..]
            .par_chunks_mut(PIECE_LINES)
            .zip(spans.par_chunks(PIECE_LINES))
            .enumerate()
            .map(|(p, (slots, spans))| piece(p, slots, spans))
            .collect()
    };
    let mut len = base;
    for (p, (n, error)) in pieces.into_iter().enumerate() {
        let from = base + p * PIECE_LINES;
        if from != len {
            chunk.copy_within(from..from + n, len);
        }
        len += n;
        if let Some(e) = error {
            chunk.truncate(len);
            return Err(e);
        }
    }
    chunk.truncate(len);
    Ok(())
}

/// Checks every line of the ray file at `path` and returns how many rays it holds, holding one
/// block of lines and their rays in memory (see [`RayReader`]).
pub fn count_rays(path: &Path) -> Result<u64, Error> {
    RayReader::open(path)?.count_rest()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse_err(result: Result<Vec<RayLine>, Error>) -> (String, Option<usize>, String) {
        match result {
            Err(Error::Parse {
                path,
                line,
                message,
            }) => (path, line, message),
            other => panic!("expected a parse error, got {other:?}"),
        }
    }

    #[test]
    fn six_and_seven_numbers() {
        let rays = parse_rays("r.txt", "0 0 -5 0 0 1\n1 2 3\t4 5 6 7.5\n").unwrap();
        assert_eq!(
            rays,
            vec![
                RayLine {
                    origin: DVec3::new(0.0, 0.0, -5.0),
                    dir: DVec3::Z,
                    tmax: None,
                },
                RayLine {
                    origin: DVec3::new(1.0, 2.0, 3.0),
                    dir: DVec3::new(4.0, 5.0, 6.0),
                    tmax: Some(7.5),
                },
            ]
        );
    }

    #[test]
    fn comments_and_blank_lines_are_skipped() {
        let text = "# header\n\n   \n0 0 0 1 0 0 # trailing\n0 0 0 0 1 0 2#glued\n  # indented\n";
        let rays = parse_rays("r.txt", text).unwrap();
        assert_eq!(rays.len(), 2);
        assert_eq!(rays[0].dir, DVec3::X);
        assert_eq!(rays[1].tmax, Some(2.0));
    }

    #[test]
    fn crlf_and_empty_input() {
        assert!(parse_rays("r.txt", "").unwrap().is_empty());
        let rays = parse_rays("r.txt", "0 0 0 1 0 0\r\n0 0 0 0 0 1 3\r\n").unwrap();
        assert_eq!(rays.len(), 2);
        assert_eq!(rays[1].tmax, Some(3.0));
    }

    #[test]
    fn too_few_numbers() {
        let text = "0 0 0 1 0 0\n# c\n1 2 3 4 5\n";
        let (path, line, message) = parse_err(parse_rays("rays.txt", text));
        assert_eq!((path.as_str(), line), ("rays.txt", Some(3)));
        assert_eq!(
            message,
            "expected 6 or 7 numbers (ox oy oz dx dy dz [tmax]), found 5"
        );
        let err = parse_rays("rays.txt", text).unwrap_err();
        assert_eq!(
            err.to_string(),
            "rays.txt:3: expected 6 or 7 numbers (ox oy oz dx dy dz [tmax]), found 5"
        );
    }

    #[test]
    fn too_many_numbers() {
        let (_, line, message) = parse_err(parse_rays("r.txt", "1 2 3 4 5 6 7 8\n"));
        assert_eq!(line, Some(1));
        assert!(message.ends_with("found 8"), "{message}");
    }

    #[test]
    fn bad_token_is_named() {
        let (_, line, message) = parse_err(parse_rays("r.txt", "\n0 0 0 1 0 0\n0 0 x 1 0 0\n"));
        assert_eq!(line, Some(3));
        assert_eq!(message, "'x' is not a number");
        let (_, _, message) = parse_err(parse_rays("r.txt", "0 0 0 1 0 0 1,5\n"));
        assert_eq!(message, "'1,5' is not a number");
    }

    #[test]
    fn ascii_lines_split_where_split_whitespace_splits() {
        // Every ASCII byte between two numbers, and around them.
        for b in 0u8..128 {
            let c = b as char;
            let line = format!("{c}1{c}2{c}3{c}4{c}5{c}6{c}");
            let by_chars: Vec<&str> = line.split_whitespace().collect();
            let parsed = parse_line("rays.txt", 1, line.as_bytes(), &[6, 7], "6 or 7 numbers");
            match parsed {
                Ok(Some(numbers)) => {
                    assert_eq!(by_chars.len(), 6, "byte {b}");
                    assert_eq!(numbers.values(), [1.0, 2.0, 3.0, 4.0, 5.0, 6.0], "byte {b}");
                }
                _ => assert!(by_chars.len() != 6 || c == '#', "byte {b}"),
            }
            assert_eq!(c.is_whitespace(), by_chars.len() == 6, "byte {b}");
        }
        // A line with other characters splits as before, at Unicode white space too.
        let line = "1\u{a0}2\u{2003}3 4 5 6";
        let numbers = parse_line("rays.txt", 1, line.as_bytes(), &[6, 7], "6 or 7 numbers");
        assert_eq!(
            numbers.ok().flatten().map(|n| n.values().to_vec()),
            Some(vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
        );
    }

    /// Every token of up to six characters from digits, points, exponents, signs and a
    /// letter, alone on a line or between numbers: the fast reading takes a line only where
    /// `str::parse` reads each token as the same bits.
    #[test]
    fn fast_lines_read_what_str_parse_reads() {
        const ALPHABET: &[u8] = b"09.eE+-n";
        let mut token = Vec::new();
        let mut checked = 0usize;
        for len in 1..=6u32 {
            for mut code in 0..ALPHABET.len().pow(len) {
                token.clear();
                for _ in 0..len {
                    token.push(ALPHABET[code % ALPHABET.len()]);
                    code /= ALPHABET.len();
                }
                for line in [
                    token.clone(),
                    [b"1 ".as_slice(), &token, b"\t2\r\n"].concat(),
                ] {
                    let Some(fast) = plain_line(&line, &[1, 3]) else {
                        continue;
                    };
                    let text = std::str::from_utf8(&line).unwrap();
                    let expected: Vec<f64> = text
                        .split_whitespace()
                        .map(|t| t.parse::<f64>().unwrap_or_else(|_| panic!("{text:?}")))
                        .collect();
                    let got = fast.map_or(Vec::new(), |n| n.values().to_vec());
                    assert_eq!(got.len(), expected.len(), "{text:?}");
                    for (a, b) in got.iter().zip(&expected) {
                        assert_eq!(a.to_bits(), b.to_bits(), "{text:?}");
                    }
                    checked += 1;
                }
            }
        }
        assert!(checked > 5_000, "{checked}");
        // Long and extreme decimals: the same bits.
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..200_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let digits = format!("{}{:019}", x % 1000, x >> 3);
            let exponent = (x % 700) as i64 - 350;
            let (point, sign) = (
                (x >> 40) as usize % digits.len(),
                ["", "-", "+"][(x >> 50) as usize % 3],
            );
            for text in [
                format!("{sign}{}.{}e{exponent}", &digits[..point], &digits[point..]),
                format!("{sign}{digits}"),
                format!("{sign}0.{digits}"),
            ] {
                let line = format!("{text} {text} {text}");
                let expected = text.parse::<f64>().unwrap();
                match plain_line(line.as_bytes(), &[3]) {
                    Some(Some(n)) => assert!(
                        n.values().iter().all(|v| v.to_bits() == expected.to_bits()),
                        "{text}"
                    ),
                    other => assert!(!expected.is_finite(), "{text}: {}", other.is_some()),
                }
            }
        }
    }

    #[test]
    fn nan_and_inf_are_accepted() {
        let rays = parse_rays(
            "r.txt",
            "nan 0 0 inf -inf 0\n0 0 0 1 0 0 inf\n0 0 0 1 0 0 NaN\n",
        )
        .unwrap();
        assert!(rays[0].origin.x.is_nan());
        assert_eq!(rays[0].dir.x, f64::INFINITY);
        assert_eq!(rays[0].dir.y, f64::NEG_INFINITY);
        assert_eq!(rays[1].tmax, Some(f64::INFINITY));
        assert!(rays[2].tmax.is_some_and(f64::is_nan));
    }

    #[test]
    fn load_rays_reads_a_file() {
        let path =
            std::env::temp_dir().join(format!("raypick-rays-test-{}.txt", std::process::id()));
        std::fs::write(&path, "0 0 0 1 0 0 # r\n0 0\n").unwrap();
        let result = load_rays(&path);
        let _ = std::fs::remove_file(&path);
        let (name, line, _) = parse_err(result);
        assert_eq!(name, path.display().to_string());
        assert_eq!(line, Some(2));
    }

    #[test]
    fn missing_file_names_the_path() {
        let path = std::env::temp_dir().join("raypick-rays-test-does-not-exist.txt");
        let err = load_rays(&path).unwrap_err();
        assert!(matches!(err, Error::Io { .. }));
        assert!(err.to_string().contains(&path.display().to_string()));
    }

    /// Every chunk size gives the rays and errors of `parse_rays`.
    fn streamed(text: &[u8], max: usize) -> Result<Vec<RayLine>, Error> {
        let mut reader = RayReader::new("r.txt", text);
        let mut all = Vec::new();
        loop {
            let chunk = reader.next_chunk(max)?;
            if chunk.is_empty() {
                return Ok(all);
            }
            assert!(chunk.len() <= max.max(1));
            all.extend(chunk);
        }
    }

    #[test]
    fn streaming_reads_what_parse_rays_reads_with_the_same_errors() {
        let texts: &[&str] = &[
            "",
            "\n\n",
            "0 0 -5 0 0 1\n1 2 3\t4 5 6 7.5\n",
            "# header\n\n   \n0 0 0 1 0 0 # trailing\n0 0 0 0 1 0 2#glued\n  # indented\n",
            "0 0 0 1 0 0\r\n0 0 0 0 0 1 3\r\n",
            "0 0 0 1 0 0\n0 0 0 0 0 1 3",
            "\u{feff}0 0 0 1 0 0\n",
            "0 0 0 1 0 0\n# c\n1 2 3 4 5\n",
            "1 2 3 4 5 6 7 8\n",
            "1 2 3 4 5 6 7 8 x\n",
            "\n0 0 0 1 0 0\n0 0 x 1 0 0\n",
            "0 0 0 1 0 0 1,5\n",
            "nan 0 0 inf -inf 0\n0 0 0 1 0 0 inf\n",
            "0 0 0 1 0 0\n0 0 0 1 0 0\n0 0 0 1 0 0\n0 0 0 1 0 0\n0 0 0 1 0 0\n",
            "0 0 0 1\r0 0\n",
        ];
        for text in texts {
            let expected = parse_rays("r.txt", text);
            for max in [0, 1, 2, 3, 1000] {
                let got = streamed(text.as_bytes(), max);
                match (&expected, &got) {
                    (Ok(a), Ok(b)) => {
                        assert_eq!(a.len(), b.len(), "{text:?}");
                        for (x, y) in a.iter().zip(b) {
                            assert_eq!(format!("{x:?}"), format!("{y:?}"), "{text:?}");
                        }
                    }
                    (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string(), "{text:?}"),
                    _ => panic!("{text:?} (chunks of {max}): {expected:?} vs {got:?}"),
                }
            }
        }
    }

    #[test]
    fn streaming_names_the_line_of_bad_utf8_and_of_overlong_lines() {
        let e = streamed(b"0 0 0 1 0 0\n0 0 0 1 0 0 \xff\n", 1).unwrap_err();
        assert_eq!(e.to_string(), "r.txt:2: the file is not valid UTF-8 text");
        let e = streamed(b"0 0 0 1 0 0 # \xc3\n", 1).unwrap_err();
        assert_eq!(e.to_string(), "r.txt:1: the file is not valid UTF-8 text");
        assert_eq!(
            streamed("0 0 0 1 0 0 # é\n".as_bytes(), 1).unwrap().len(),
            1
        );
        let mut long = b"0 0 0 1 0 0\n".to_vec();
        long.extend(std::iter::repeat_n(b' ', MAX_LINE_BYTES + 10));
        long.extend(b"\n0 0 0 1 0 0\n");
        let e = streamed(&long, 4).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("r.txt:2: the line is longer than"),
            "{e}"
        );
        // A line of exactly the limit is fine.
        let mut edge = vec![b' '; MAX_LINE_BYTES - 11];
        edge.extend(b"0 0 0 1 0 0\n");
        assert_eq!(streamed(&edge, 4).unwrap().len(), 1);
    }

    /// A line's text of the limit, and one byte more, after a line and before one, with each
    /// break and as the last line with none: both readers take the first and refuse the second,
    /// naming its line, however the line ends.
    #[test]
    fn the_line_limit_counts_text_not_its_break() {
        let dir = std::env::temp_dir().join(format!("raypick-limit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for (text_len, fits) in [(MAX_LINE_BYTES, true), (MAX_LINE_BYTES + 1, false)] {
            let mut line = vec![b' '; text_len - 11];
            line.extend(b"0 0 0 1 0 0");
            for end in [&b"\n"[..], b"\r\n", b""] {
                let mut file = b"1 0 0 1 0 0\n".to_vec();
                file.extend(&line);
                file.extend(end);
                if !end.is_empty() {
                    file.extend(b"2 0 0 1 0 0\n");
                }
                let path = dir.join("r.txt");
                std::fs::write(&path, &file).unwrap();
                let whole = read_text_within(&path, u64::MAX, "", Some(MAX_LINE_BYTES));
                for (reader, result) in [
                    ("stream", streamed(&file, 3).map(|r| r.len())),
                    ("whole", whole.map(|t| t.len())),
                ] {
                    let case = format!("{reader}, {text_len} bytes, break {end:?}");
                    match result {
                        Ok(_) => assert!(fits, "{case}: taken"),
                        Err(e) => {
                            assert!(!fits, "{case}: {e}");
                            assert!(
                                e.to_string().contains(":2: the line is longer"),
                                "{case}: {e}"
                            );
                        }
                    }
                }
            }
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn chunks_come_in_order_and_an_error_ends_the_reading() {
        let mut text = String::new();
        for i in 0..10 {
            text.push_str(&format!("{i} 0 0 1 0 0\n"));
        }
        text.push_str("bad\n0 0 0 1 0 0\n");
        let mut reader = RayReader::new("r.txt", text.as_bytes());
        let mut chunk = Vec::new();
        assert_eq!(reader.read_chunk(&mut chunk, 4).unwrap(), 4);
        assert_eq!(chunk[3].origin.x, 3.0);
        assert_eq!(reader.read_chunk(&mut chunk, 4).unwrap(), 4);
        assert_eq!(chunk[0].origin.x, 4.0);
        assert_eq!(reader.line(), 8);
        let e = reader.read_chunk(&mut chunk, 4).unwrap_err();
        assert_eq!(
            e.to_string(),
            "r.txt:11: '' is not a number".replace("''", "'bad'")
        );
        assert!(
            reader.next_chunk(4).unwrap().is_empty(),
            "no rays after an error"
        );
    }

    #[test]
    fn count_rays_checks_every_line() {
        let path =
            std::env::temp_dir().join(format!("raypick-rays-count-{}.txt", std::process::id()));
        std::fs::write(&path, "0 0 0 1 0 0\n# c\n0 0 0 1 0 0 5\n").unwrap();
        assert_eq!(count_rays(&path).unwrap(), 2);
        std::fs::write(&path, "0 0 0 1 0 0\n0 0\n").unwrap();
        let e = count_rays(&path).unwrap_err();
        let _ = std::fs::remove_file(&path);
        assert!(
            e.to_string()
                .ends_with(":2: expected 6 or 7 numbers (ox oy oz dx dy dz [tmax]), found 2"),
            "{e}"
        );
    }
}
