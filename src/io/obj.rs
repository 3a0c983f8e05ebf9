//! Loading triangle meshes from Wavefront OBJ files.
//!
//! This module owns the OBJ reader. It cuts the file into chunks at line boundaries, parses the
//! chunks in parallel (rayon) with a hand-written byte scanner, and joins them in file order into
//! one [`Mesh`] whose triangle numbering is the file's face order. Every `o`/`g` group is part of
//! that one mesh.
//!
//! Only positions (`v`) and faces (`f`) are read. Texture coordinates, normals, materials
//! (`mtllib`, `usemtl`), smoothing groups, vertex colours, `l` (polyline) and `p` (point)
//! elements are ignored. The rules are those of the `tobj`-based reader this one replaced (on
//! every file that reader read, the vertex values and triangles are the same, bit for bit, and
//! so are the errors; `tests/obj_reader.rs` checks), plus line continuations:
//!
//! - A `#` starts a comment, to the end of the line; a byte-order mark at the start is skipped;
//!   lines end with `\n` or `\r\n`.
//! - `v x y z`, `v x y z w` (the position is `(x/w, y/w, z/w)`) or `v x y z r g b` (the colour is
//!   checked, then dropped). Numbers are Rust's `f64` syntax, read correctly rounded; every one
//!   must be finite.
//! - `f` corners are `i`, `i/t`, `i//n` or `i/t/n`; only the position index `i` is used, and
//!   `t`, `n` must be integers when present. Indices start at 1; a negative index counts back
//!   from the last vertex read so far (`-1` is the latest). A face may only use vertices defined
//!   before it.
//! - A face with k ≥ 3 corners (i0 … i(k−1)) is fan-triangulated as (i0, i1, i2), (i0, i2, i3),
//!   …. Faces with fewer than 3 vertices give no triangle: they are skipped with one warning on
//!   standard error (their count and the first one's line).
//! - A `v` or `f` line whose last character before any comment (spaces aside) is `\` continues
//!   on the next line: the `\` counts as a space. Errors name the first line of the joined
//!   ones. Other lines are ignored whole, so a `\` at their end joins nothing.
//! - The mesh's vertices are the ones the triangles use, numbered in order of first use.
//!
//! Errors are [`Error::Parse`] naming the file and the 1-based line; the first error in the file
//! is reported.

use std::ops::Range;
use std::path::Path;

use glam::DVec3;
use rayon::prelude::*;

use crate::budget::quote;
use crate::error::Error;
use crate::scene::Mesh;

/// Chunks are about this long at least: below it, a thread costs more than it saves.
const MIN_CHUNK_BYTES: usize = 256 << 10;

/// Loads the triangle mesh of the OBJ file at `path`.
///
/// A file with no faces gives an empty mesh. Malformed content (unparseable or non-finite
/// coordinates, face indices that are 0, out of range or not integers) is an [`Error::Parse`]
/// naming the file and the line. The file must be a regular file whose length fits the memory
/// budget ([`crate::budget`]).
pub fn load_obj(path: &Path) -> Result<Mesh, Error> {
    let name = path.display().to_string();
    let bytes = read_file(path)?;
    let (mesh, short) = parse_obj(&name, &bytes)?;
    if let Some(short) = short {
        eprintln!("warning: {name}: {}", short.describe());
    }
    Ok(mesh)
}

/// Parses the OBJ text `bytes` (named `name` in errors) into a mesh, and says which faces had
/// fewer than 3 vertices, if any. [`load_obj`] without the file and the warning.
pub fn parse_obj(name: &str, bytes: &[u8]) -> Result<(Mesh, Option<ShortFaces>), Error> {
    let threads = rayon::current_num_threads().max(1);
    let chunk = (bytes.len() / (8 * threads)).max(MIN_CHUNK_BYTES);
    parse_obj_in_chunks(name, bytes, chunk)
}

/// [`parse_obj`] with chunks of about `chunk_bytes` (at least 1), for tests of the chunk seams.
#[doc(hidden)]
pub fn parse_obj_in_chunks(
    name: &str,
    bytes: &[u8],
    chunk_bytes: usize,
) -> Result<(Mesh, Option<ShortFaces>), Error> {
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    let ranges = split(bytes, chunk_bytes.max(1));
    let outcomes: Vec<Outcome> = if ranges.len() == 1 {
        vec![parse_chunk(bytes, Some(0))]
    } else {
        ranges
            .par_iter()
            .enumerate()
            .map(|(k, r)| parse_chunk(&bytes[r.clone()], (k == 0).then_some(0)))
            .collect()
    };
    join(name, bytes, &ranges, outcomes)
}

/// Reads the regular file at `path` after checking its length against the memory budget: in
/// parallel pieces where the platform reads at an offset, as the copy out of the page cache is a
/// fair part of the load time.
fn read_file(path: &Path) -> Result<Vec<u8>, Error> {
    let (file, length) = crate::io::open_regular(path)?;
    crate::budget::check(&format!("reading {}", path.display()), length, 1)?;
    let io = |source| Error::Io {
        path: path.display().to_string(),
        source,
    };
    let length = usize::try_from(length).map_err(|_| io(std::io::ErrorKind::OutOfMemory.into()))?;
    let mut bytes = vec![0u8; length];
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileExt;
        const PIECE: usize = 4 << 20;
        bytes
            .par_chunks_mut(PIECE)
            .enumerate()
            .try_for_each(|(k, piece)| file.read_exact_at(piece, (k * PIECE) as u64))
            .map_err(io)?;
    }
    #[cfg(not(unix))]
    {
        std::io::Read::read_exact(&mut &file, &mut bytes).map_err(io)?;
    }
    Ok(bytes)
}

fn parse_error(path: &str, line: Option<usize>, message: String) -> Error {
    Error::Parse {
        path: path.to_owned(),
        line,
        message,
    }
}

/// Faces with fewer than 3 vertices (`f 1 2`): they give no triangle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ShortFaces {
    /// How many.
    pub count: usize,
    /// The 1-based line of the first.
    pub first_line: usize,
}

impl ShortFaces {
    /// The warning, as a sentence.
    pub fn describe(&self) -> String {
        format!(
            "{} face(s) with fewer than 3 vertices give no triangle and were skipped (the first \
             on line {})",
            self.count, self.first_line
        )
    }
}

// ---------------------------------------------------------------------------------------------
// Chunks

/// Cuts `bytes` into ranges of about `target` bytes that start at line starts. A cut never
/// follows a line holding a `\` (which might continue onto the next line).
fn split(bytes: &[u8], target: usize) -> Vec<Range<usize>> {
    let mut ranges = Vec::new();
    let mut start = 0;
    while start < bytes.len() {
        let mut end = start.saturating_add(target).min(bytes.len());
        while end < bytes.len() {
            let Some(newline) = find(bytes, end, b'\n') else {
                end = bytes.len();
                break;
            };
            end = newline + 1;
            let line_start = bytes[start..newline]
                .iter()
                .rposition(|&b| b == b'\n')
                .map_or(start, |i| start + i + 1);
            if !bytes[line_start..newline].contains(&b'\\') {
                break;
            }
        }
        ranges.push(start..end);
        start = end;
    }
    if ranges.is_empty() {
        ranges.push(0..0);
    }
    ranges
}

/// The first `needle` at or after `from`.
fn find(bytes: &[u8], from: usize, needle: u8) -> Option<usize> {
    bytes
        .get(from..)?
        .iter()
        .position(|&b| b == needle)
        .map(|i| from + i)
}

/// `\n` bytes in `bytes`.
fn count_lines(bytes: &[u8]) -> usize {
    bytes.iter().filter(|&&b| b == b'\n').count()
}

/// Face corners are stored per chunk as `i64`: `i − 1 ≥ 0` for a positive index `i` (already
/// global), and `local + i − TAG < 0` for a negative one (`local`: the chunk's vertices before
/// the face), which becomes global once the chunk's first vertex number is known.
const TAG: i64 = 1 << 62;

/// What parsing one chunk gave.
struct Outcome {
    vertices: Vec<DVec3>,
    triangles: Vec<[i64; 3]>,
    /// The chunk's `\n` count when it was parsed to its end.
    lines: Option<usize>,
    /// The vertices the chunk needs before it: an index `i` on a line after `local` of the
    /// chunk's vertices needs `|i| − local` of them. Known only when the chunk's first vertex
    /// number was not.
    deficit: u64,
    /// (count, 0-based line in the chunk of the first).
    short: Option<(usize, usize)>,
    /// The first error: 0-based line in the chunk, and the message.
    error: Option<(usize, String)>,
    /// The chunk is not UTF-8: the 0-based line of the first bad byte.
    not_utf8: Option<usize>,
}

/// Parses one chunk; `base` is the number of vertices before it, when known (range errors
/// are then found here, else [`Outcome::deficit`] says what the chunk needs).
fn parse_chunk(bytes: &[u8], base: Option<u64>) -> Outcome {
    let mut parser = Parser {
        base,
        vertices: Vec::new(),
        triangles: Vec::new(),
        deficit: 0,
        short: None,
        corners: Vec::new(),
    };
    let (lines, error, not_utf8) = match std::str::from_utf8(bytes) {
        Err(e) => (None, None, Some(count_lines(&bytes[..e.valid_up_to()]))),
        Ok(text) => match parser.run(text) {
            Ok(lines) => (Some(lines), None, None),
            Err(error) => (None, Some(error), None),
        },
    };
    Outcome {
        vertices: parser.vertices,
        triangles: parser.triangles,
        lines,
        deficit: parser.deficit,
        short: parser.short,
        error,
        not_utf8,
    }
}

/// Joins the chunks' outcomes, in order, into one mesh, or reports the file's first error.
fn join(
    name: &str,
    bytes: &[u8],
    ranges: &[Range<usize>],
    outcomes: Vec<Outcome>,
) -> Result<(Mesh, Option<ShortFaces>), Error> {
    let lines = |k: usize| {
        outcomes[k]
            .lines
            .unwrap_or_else(|| count_lines(&bytes[ranges[k].clone()]))
    };
    // The whole file must be UTF-8 before any line is judged.
    let mut before = 0;
    for (k, outcome) in outcomes.iter().enumerate() {
        if let Some(line) = outcome.not_utf8 {
            return Err(parse_error(
                name,
                Some(1 + before + line),
                "the file is not valid UTF-8 text".to_owned(),
            ));
        }
        before += lines(k);
    }

    // Vertex numbering: each chunk's base, and the first error in file order.
    let mut bases = Vec::with_capacity(outcomes.len());
    let mut base = 0u64;
    let mut before = 0;
    let mut short: Option<ShortFaces> = None;
    for (k, outcome) in outcomes.iter().enumerate() {
        let mut error = outcome.error.clone();
        if outcome.deficit > base {
            // Some index is out of range: parse again knowing the base, to find which.
            let again = parse_chunk(&bytes[ranges[k].clone()], Some(base)).error;
            error =
                Some(again.unwrap_or_else(|| {
                    (0, "the OBJ reader lost track of a face index".to_owned())
                }));
        }
        if let Some((line, message)) = error {
            return Err(parse_error(name, Some(1 + before + line), message));
        }
        if let Some((count, line)) = outcome.short {
            let s = short.get_or_insert(ShortFaces {
                count: 0,
                first_line: 1 + before + line,
            });
            s.count += count;
        }
        bases.push(base);
        base += outcome.vertices.len() as u64;
        before += lines(k);
    }
    let mesh = build_mesh(name, &outcomes, &bases)?;
    Ok((mesh, short))
}

/// Concatenates the chunks' triangles, numbering the vertices in order of first use (as the
/// `tobj` reader did): the corners are made global in parallel, numbered in one pass, and the
/// used vertices gathered in parallel.
fn build_mesh(name: &str, outcomes: &[Outcome], bases: &[u64]) -> Result<Mesh, Error> {
    let vertex_count: usize = outcomes.iter().map(|o| o.vertices.len()).sum();
    let triangle_count: usize = outcomes.iter().map(|o| o.triangles.len()).sum();
    if triangle_count == 0 {
        return Ok(Mesh::default());
    }
    // Global vertex numbers are u32 here (so below `UNUSED`); the mesh's can only be fewer.
    if u32::try_from(vertex_count).is_err() {
        return Err(parse_error(
            name,
            None,
            "the mesh has too many vertices".to_owned(),
        ));
    }
    // The numbering table, the first-use order and the mesh's vertices; the triangles.
    crate::budget::check(
        &format!("{name}: the vertices"),
        vertex_count as u64,
        4 + 4 + 24,
    )?;
    crate::budget::check(&format!("{name}: the triangles"), triangle_count as u64, 12)?;

    // Global corners, each chunk into its own run of the triangles.
    let mut triangles = vec![[0u32; 3]; triangle_count];
    let mut runs = Vec::with_capacity(outcomes.len());
    let mut rest = triangles.as_mut_slice();
    for outcome in outcomes {
        let (run, tail) = rest.split_at_mut(outcome.triangles.len());
        runs.push(run);
        rest = tail;
    }
    let in_range = runs
        .into_par_iter()
        .zip(outcomes)
        .zip(bases)
        .all(|((run, outcome), &base)| {
            let mut ok = true;
            for (out, corners) in run.iter_mut().zip(&outcome.triangles) {
                for (slot, &c) in out.iter_mut().zip(corners) {
                    let global = if c >= 0 { c } else { c + TAG + base as i64 };
                    // In range: the chunk was checked against its base.
                    ok &= (0..vertex_count as i64).contains(&global);
                    *slot = global as u32;
                }
            }
            ok
        });
    if !in_range {
        return Err(parse_error(
            name,
            None,
            "the OBJ reader lost track of a face index".to_owned(),
        ));
    }

    // Numbers in order of first use.
    const UNUSED: u32 = u32::MAX;
    let mut number = vec![UNUSED; vertex_count];
    let mut order: Vec<u32> = Vec::new();
    for corner in triangles.as_flattened_mut() {
        let global = *corner as usize;
        let mut n = number[global];
        if n == UNUSED {
            n = order.len() as u32;
            number[global] = n;
            order.push(global as u32);
        }
        *corner = n;
    }
    drop(number);

    let positions = order
        .par_iter()
        .map(|&global| {
            let k = bases.partition_point(|&b| b <= u64::from(global)) - 1;
            outcomes[k].vertices[(u64::from(global) - bases[k]) as usize]
        })
        .collect();
    Ok(Mesh {
        positions,
        triangles,
    })
}

// ---------------------------------------------------------------------------------------------
// The parser of one chunk

/// Blanks inside a line: what `char::is_whitespace` says of ASCII bytes other than `\n`.
#[inline(always)]
fn is_blank(b: u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\r' | 0x0B | 0x0C)
}

/// What may follow a token: a blank, the end of the line or a comment.
#[inline(always)]
fn ends_token(b: u8) -> bool {
    is_blank(b) || b == b'\n' || b == b'#'
}

struct Parser {
    /// Vertices before the chunk, when known.
    base: Option<u64>,
    vertices: Vec<DVec3>,
    triangles: Vec<[i64; 3]>,
    deficit: u64,
    short: Option<(usize, usize)>,
    /// The corners of the face being read.
    corners: Vec<i64>,
}

impl Parser {
    /// Parses `text` line by line; returns its `\n` count, or the first error's 0-based line
    /// and message. Each line is tried on the fast path (plain ASCII, well formed); anything
    /// else (errors, continuations, other Unicode blanks) is read again on the slow path,
    /// which has the reference rules.
    fn run(&mut self, text: &str) -> Result<usize, (usize, String)> {
        let b = text.as_bytes();
        let n = b.len();
        let mut p = 0;
        let mut line = 0;
        while p < n {
            let start = p;
            while p < n && is_blank(b[p]) {
                p += 1;
            }
            if p == n {
                break;
            }
            let keyword_alone = b.get(p + 1).is_none_or(|&c| ends_token(c));
            let fast = match b[p] {
                b'\n' => {
                    p += 1;
                    line += 1;
                    continue;
                }
                b'#' => Some(p),
                b'v' if keyword_alone => self.fast_vertex(b, p + 1),
                b'f' if keyword_alone => self.fast_face(b, p + 1, line),
                _ => {
                    // Another keyword, ignored, unless Unicode blanks might make it `v` or `f`.
                    let mut q = p;
                    while q < n && !ends_token(b[q]) && b[q].is_ascii() {
                        q += 1;
                    }
                    (q == n || b[q].is_ascii()).then_some(q)
                }
            };
            match fast {
                Some(q) => {
                    p = find(b, q, b'\n').map_or(n, |e| {
                        line += 1;
                        e + 1
                    });
                }
                None => {
                    let (next, joined) =
                        self.slow_line(text, start, line).map_err(|m| (line, m))?;
                    p = next;
                    line += joined;
                }
            }
        }
        Ok(line)
    }

    /// The numbers of a `v` line from `p` (after the keyword); returns where they end, or
    /// `None` for the slow path.
    #[inline]
    fn fast_vertex(&mut self, b: &[u8], mut p: usize) -> Option<usize> {
        let n = b.len();
        let mut values = [0.0f64; 6];
        let mut k = 0;
        loop {
            while p < n && is_blank(b[p]) {
                p += 1;
            }
            if p == n || b[p] == b'\n' || b[p] == b'#' {
                break;
            }
            if k == values.len() {
                return None; // seven numbers or more: the slow path says so
            }
            let (value, used) = fast_float2::parse_partial::<f64, _>(&b[p..]).ok()?;
            p += used;
            if used == 0 || (p < n && !ends_token(b[p])) || !value.is_finite() {
                return None;
            }
            values[k] = value;
            k += 1;
        }
        let position = match k {
            3 | 6 => DVec3::new(values[0], values[1], values[2]),
            4 => {
                let w = values[3];
                let position = DVec3::new(values[0] / w, values[1] / w, values[2] / w);
                if w == 0.0 || !position.is_finite() {
                    return None;
                }
                position
            }
            _ => return None,
        };
        self.vertices.push(position);
        Some(p)
    }

    /// The corners of an `f` line from `p` (after the keyword); returns where they end, or
    /// `None` for the slow path.
    #[inline]
    fn fast_face(&mut self, b: &[u8], mut p: usize, line: usize) -> Option<usize> {
        let n = b.len();
        let local = self.vertices.len() as u64;
        let mut deficit = self.deficit;
        self.corners.clear();
        loop {
            while p < n && is_blank(b[p]) {
                p += 1;
            }
            if p == n || b[p] == b'\n' || b[p] == b'#' {
                break;
            }
            let negative = b[p] == b'-';
            p += usize::from(negative);
            let (index, end) = digits(b, p)?;
            p = end;
            if index == 0 {
                return None;
            }
            // `/t`, `/t/n`, `//n`: integers or empty.
            for _ in 0..2 {
                if p < n && b[p] == b'/' {
                    p += 1;
                    if p < n && b[p] == b'-' {
                        p = digits(b, p + 1)?.1;
                    } else if let Some((_, end)) = digits(b, p) {
                        p = end;
                    }
                }
            }
            if p < n && !ends_token(b[p]) {
                return None;
            }
            match self.base {
                Some(base) if index > base + local => return None,
                Some(_) => {}
                None => deficit = deficit.max(index.saturating_sub(local)),
            }
            self.corners.push(if negative {
                local as i64 - index as i64 - TAG
            } else {
                index as i64 - 1
            });
        }
        if self.corners.is_empty() {
            return None;
        }
        self.deficit = deficit;
        self.commit_face(line);
        Some(p)
    }

    /// Turns the corners read into triangles (a fan), or counts a short face.
    #[inline]
    fn commit_face(&mut self, line: usize) {
        let c = &self.corners;
        if c.len() < 3 {
            self.short.get_or_insert((0, line)).0 += 1;
            return;
        }
        for k in 1..c.len() - 1 {
            self.triangles.push([c[0], c[k], c[k + 1]]);
        }
    }

    /// Reads the line at `start` (with the lines it continues onto) by the reference rules;
    /// returns where the next line starts and how many `\n` were passed.
    fn slow_line(
        &mut self,
        text: &str,
        start: usize,
        line: usize,
    ) -> Result<(usize, usize), String> {
        let (first, mut next) = physical_line(text, start);
        let mut newlines = usize::from(text.as_bytes().get(next.wrapping_sub(1)) == Some(&b'\n'));
        let keyword = first.split_whitespace().next();
        if !matches!(keyword, Some("v" | "f")) {
            return Ok((next, newlines));
        }
        // The joined lines, grown in place (a chain of continuations costs its length).
        let mut joined: Option<String> = None;
        loop {
            let so_far = joined.as_deref().unwrap_or(first);
            let Some(body) = so_far.trim_end().strip_suffix('\\') else {
                break;
            };
            let keep = body.len();
            let line = joined.get_or_insert_with(|| first.to_owned());
            line.truncate(keep);
            line.push(' ');
            if next < text.len() {
                let (content, after) = physical_line(text, next);
                line.push_str(content);
                newlines += usize::from(text.as_bytes()[after - 1] == b'\n');
                next = after;
            }
        }
        let logical = joined.as_deref().unwrap_or(first);
        let mut words = logical.split_whitespace();
        match words.next() {
            Some("v") => {
                let position = check_vertex(words)?;
                self.vertices.push(position);
            }
            Some(_) => self.slow_face(words, line)?,
            None => {}
        }
        Ok((next, newlines))
    }

    /// Checks the corners of an `f` line, token by token, and keeps the face.
    fn slow_face<'a>(
        &mut self,
        words: impl Iterator<Item = &'a str>,
        line: usize,
    ) -> Result<(), String> {
        self.corners.clear();
        let local = self.vertices.len() as u64;
        for token in words {
            let mut parts = token.split('/');
            let position = parts.next().unwrap_or_default();
            let rest: Vec<&str> = parts.collect();
            if rest.len() > 2
                || rest
                    .iter()
                    .any(|p| !p.is_empty() && p.parse::<isize>().is_err())
            {
                return Err(format!(
                    "face vertex '{}' is malformed (expected v, v/vt, v//vn or v/vt/vn)",
                    quote(token)
                ));
            }
            if position.is_empty() {
                return Err(format!(
                    "face vertex '{}' has no position index",
                    quote(token)
                ));
            }
            let index: isize = position
                .parse()
                .map_err(|_| format!("face index '{}' is not an integer", quote(position)))?;
            if index == 0 {
                return Err("face index 0 is invalid (OBJ indices start at 1)".to_owned());
            }
            let size = index.unsigned_abs() as u64;
            match self.base {
                Some(base) if size > base + local => {
                    return Err(format!(
                        "face index {index} is out of range (the file has {} vertices so far)",
                        base + local
                    ));
                }
                Some(_) => {}
                None => self.deficit = self.deficit.max(size.saturating_sub(local)),
            }
            self.corners.push(if index < 0 {
                (local as i64).wrapping_sub(size as i64).wrapping_sub(TAG)
            } else {
                size as i64 - 1
            });
        }
        if self.corners.is_empty() {
            return Err("face has no vertex indices".to_owned());
        }
        self.commit_face(line);
        Ok(())
    }
}

/// At most 18 decimal digits from `p` (so the value fits any index check without overflow):
/// the value and where the digits end; `None` when there are none, or more.
#[inline(always)]
fn digits(b: &[u8], mut p: usize) -> Option<(u64, usize)> {
    let start = p;
    let mut value = 0u64;
    while p < b.len() && b[p].is_ascii_digit() {
        value = value * 10 + u64::from(b[p] - b'0');
        p += 1;
        if p - start > 18 {
            return None;
        }
    }
    (p > start).then_some((value, p))
}

/// The line at `start`, up to its comment, and where the next line starts.
fn physical_line(text: &str, start: usize) -> (&str, usize) {
    let end = find(text.as_bytes(), start, b'\n');
    let line = &text[start..end.unwrap_or(text.len())];
    let content = line.split('#').next().unwrap_or_default();
    (content, end.map_or(text.len(), |e| e + 1))
}

/// Checks the numbers of a `v` line (`x y z`, `x y z w` or `x y z r g b`) and returns the
/// position.
fn check_vertex<'a>(words: impl Iterator<Item = &'a str>) -> Result<DVec3, String> {
    let tokens: Vec<&str> = words.collect();
    let n = tokens.len();
    if !matches!(n, 3 | 4 | 6) {
        return Err(format!(
            "expected 3, 4 or 6 numbers after 'v' (x y z [w] or x y z r g b), found {n}"
        ));
    }
    let mut values = [0.0f64; 6];
    for (value, token) in values.iter_mut().zip(&tokens) {
        *value = token
            .parse::<f64>()
            .map_err(|_| format!("vertex value '{}' is not a number", quote(token)))?;
        if !value.is_finite() {
            return Err(format!("vertex value '{}' is not finite", quote(token)));
        }
    }
    let position = DVec3::new(values[0], values[1], values[2]);
    if n == 4 {
        let w = values[3];
        if w == 0.0 {
            return Err("vertex weight w is zero".to_owned());
        }
        let position = position / w;
        if !position.is_finite() {
            return Err(format!(
                "vertex coordinates are not finite after dividing by w = {w}"
            ));
        }
        return Ok(position);
    }
    Ok(position)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// A temporary file removed on drop.
    struct TempFile(PathBuf);

    impl TempFile {
        fn new(text: &str) -> Self {
            static COUNTER: AtomicUsize = AtomicUsize::new(0);
            let n = COUNTER.fetch_add(1, Ordering::Relaxed);
            let path = std::env::temp_dir()
                .join(format!("raypick-obj-test-{}-{n}.obj", std::process::id()));
            std::fs::write(&path, text).expect("write temp file");
            Self(path)
        }
    }

    impl Drop for TempFile {
        fn drop(&mut self) {
            let _ = std::fs::remove_file(&self.0);
        }
    }

    fn load(text: &str) -> Result<Mesh, Error> {
        load_obj(&TempFile::new(text).0)
    }

    /// The corner positions of every triangle, for order checks that do not
    /// depend on the vertex numbering.
    fn corners(mesh: &Mesh) -> Vec<[DVec3; 3]> {
        mesh.triangles
            .iter()
            .map(|t| t.map(|i| mesh.positions[i as usize]))
            .collect()
    }

    /// Vertex `i` (1-based) of the test files: distinct, easy to name.
    fn v(i: u32) -> DVec3 {
        DVec3::new(f64::from(i), f64::from(i * i), 0.5)
    }

    fn vertex_lines(n: u32) -> String {
        (1..=n)
            .map(|i| {
                let p = v(i);
                format!("v {} {} {}\n", p.x, p.y, p.z)
            })
            .collect()
    }

    fn tris(list: &[[u32; 3]]) -> Vec<[DVec3; 3]> {
        list.iter().map(|t| t.map(v)).collect()
    }

    fn parse_err(result: Result<Mesh, Error>) -> (Option<usize>, String) {
        match result {
            Err(Error::Parse { line, message, .. }) => (line, message),
            other => panic!("expected a parse error, got {other:?}"),
        }
    }

    #[test]
    fn quad_and_pentagon_are_fan_triangulated_in_order() {
        let text = format!("{}f 1 2 3 4\nf 5 3 1 2 4\nf 2 4 5\n", vertex_lines(5));
        let mesh = load(&text).unwrap();
        assert_eq!(mesh.triangles.len(), 6);
        assert_eq!(
            corners(&mesh),
            tris(&[
                [1, 2, 3],
                [1, 3, 4],
                [5, 3, 1],
                [5, 1, 2],
                [5, 2, 4],
                [2, 4, 5],
            ])
        );
    }

    #[test]
    fn negative_indices_are_relative() {
        let text = format!(
            "{}f -3 -2 -1\n{}f -4 -3 -2 -1\nf 1 -1 2\n",
            vertex_lines(3),
            "v 4 16 0.5\nv 5 25 0.5\nv 6 36 0.5\nv 7 49 0.5\n"
        );
        let mesh = load(&text).unwrap();
        assert_eq!(
            corners(&mesh),
            tris(&[[1, 2, 3], [4, 5, 6], [4, 6, 7], [1, 7, 2]])
        );
    }

    #[test]
    fn comments_and_blank_lines_are_ignored() {
        let text = "# header\n\n  # indented\n#nospace\n\
                    v 1 1 0.5 # trailing\nv 2 4 0.5#glued\nv 3 9 0.5\n\
                    f 1 2 3 # a triangle\n# f 3 2 1\n";
        let mesh = load(text).unwrap();
        assert_eq!(corners(&mesh), tris(&[[1, 2, 3]]));
    }

    #[test]
    fn groups_keep_file_order() {
        let text = format!(
            "{}o a\nf 1 2 3\nf 2 3 4\no b\nf 4 1 2\ng c\nf 3 4 1\n",
            vertex_lines(4)
        );
        let mesh = load(&text).unwrap();
        assert_eq!(
            corners(&mesh),
            tris(&[[1, 2, 3], [2, 3, 4], [4, 1, 2], [3, 4, 1]])
        );
        // One model for the whole file: shared vertices are not duplicated.
        assert_eq!(mesh.positions.len(), 4);
    }

    #[test]
    fn degenerate_faces_are_kept() {
        let text = "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\n\
                    f 1 1 2\nf 1 2 3\nf 3 3 3\nf 1 2 4\n";
        let mesh = load(text).unwrap();
        assert_eq!(mesh.triangles.len(), 4);
        let c = corners(&mesh);
        assert_eq!(c[0][0], c[0][1]);
        assert_eq!(c[3], [DVec3::ZERO, DVec3::X, DVec3::Y]);
    }

    #[test]
    fn points_lines_and_polylines_give_no_triangles() {
        let text = format!("{}f 1\nf 1 2\nl 1 2 3\np 1\nf 1 2 3\n", vertex_lines(3));
        let mesh = load(&text).unwrap();
        assert_eq!(corners(&mesh), tris(&[[1, 2, 3]]));
    }

    #[test]
    fn texture_normal_and_weight_data_are_accepted() {
        let text = "v 2 2 2 2\nv 2 0 0 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n\
                    usemtl missing\nmtllib missing.mtl\n\
                    s 1\nf 1/1/1 2//1 3/1\n";
        let mesh = load(text).unwrap();
        assert_eq!(
            corners(&mesh),
            vec![[DVec3::ONE, DVec3::new(2.0, 0.0, 0.0), DVec3::Y]]
        );
    }

    #[test]
    fn crlf_and_byte_order_mark() {
        let text = "\u{feff}v 1 1 0.5\r\nv 2 4 0.5\r\nv 3 9 0.5\r\nf 1 2 3\r\nf 1 2 9\r\n";
        assert_eq!(parse_err(load(text)).0, Some(5));
        let mesh = load(&text.replace("f 1 2 9\r\n", "")).unwrap();
        assert_eq!(corners(&mesh), tris(&[[1, 2, 3]]));
    }

    #[test]
    fn file_without_faces_is_an_empty_mesh() {
        assert_eq!(load("").unwrap(), Mesh::default());
        let mesh = load("# nothing\nv 1 2 3\no empty\n").unwrap();
        assert!(mesh.triangles.is_empty());
    }

    #[test]
    fn out_of_range_index_names_the_line() {
        let text = format!("{}f 1 2 3\n# c\nf 1 2 17\n", vertex_lines(12));
        let (line, message) = parse_err(load(&text));
        assert_eq!(line, Some(15));
        assert_eq!(
            message,
            "face index 17 is out of range (the file has 12 vertices so far)"
        );
        let (line, message) = parse_err(load("v 0 0 0\nf 1 -2 1\n"));
        assert_eq!(line, Some(2));
        assert!(message.contains("-2 is out of range"), "{message}");
        // Forward references are rejected too.
        let (line, _) = parse_err(load("v 0 0 0\nf 1 2 3\nv 1 0 0\nv 0 1 0\n"));
        assert_eq!(line, Some(2));
    }

    #[test]
    fn bad_face_tokens_name_the_line() {
        let base = vertex_lines(3);
        for (face, expected) in [
            ("f 0 1 2", "face index 0 is invalid"),
            ("f 1 x 2", "face index 'x' is not an integer"),
            ("f 1 2/a 3", "is malformed"),
            ("f 1 2/1/1/1 3", "is malformed"),
            ("f 1 /1 3", "has no position index"),
            ("f", "face has no vertex indices"),
        ] {
            let (line, message) = parse_err(load(&format!("{base}{face}\n")));
            assert_eq!(line, Some(4), "{face}");
            assert!(message.contains(expected), "{face}: {message}");
        }
    }

    #[test]
    fn non_finite_or_bad_coordinates_name_the_line() {
        for (vertex, expected) in [
            ("v 0 nan 0", "'nan' is not finite"),
            ("v 0 0 -inf", "'-inf' is not finite"),
            ("v 1e999 0 0", "'1e999' is not finite"),
            ("v 0 zero 0", "'zero' is not a number"),
            ("v 0 0", "found 2"),
            ("v 0 0 0 1 1", "found 5"),
            ("v 0 0 0 0", "w is zero"),
            ("v 1e300 0 0 1e-300", "after dividing by w"),
        ] {
            // The vertex is unused: it is still checked.
            let text = format!("v 0 0 0\nv 1 0 0\n{vertex}\nv 0 1 0\nf 1 2 4\n");
            let (line, message) = parse_err(load(&text));
            assert_eq!(line, Some(3), "{vertex}");
            assert!(message.contains(expected), "{vertex}: {message}");
        }
    }

    #[test]
    fn error_display_names_file_and_line() {
        let file = TempFile::new("v 0 0 0\nf 1 1 2\n");
        let err = load_obj(&file.0).unwrap_err();
        let shown = err.to_string();
        assert!(
            shown.starts_with(&format!("{}:2: face index 2", file.0.display())),
            "{shown}"
        );
    }

    #[test]
    fn invalid_utf8_names_the_line() {
        let file = TempFile::new("");
        std::fs::write(&file.0, b"v 0 0 0\nv 1 \xff 0\n").unwrap();
        let (line, _) = parse_err(load_obj(&file.0));
        assert_eq!(line, Some(2));
    }

    #[test]
    fn missing_file_names_the_path() {
        let path = std::env::temp_dir().join("raypick-obj-test-does-not-exist.obj");
        let err = load_obj(&path).unwrap_err();
        assert!(matches!(err, Error::Io { .. }));
        assert!(err.to_string().contains(&path.display().to_string()));
    }

    #[test]
    fn bunny_loads() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/bunny.obj");
        let mesh = load_obj(&path).unwrap();
        assert_eq!(mesh.positions.len(), 1839);
        assert_eq!(mesh.triangles.len(), 3674);
        assert!(mesh.positions.iter().all(|p| p.is_finite()));
    }
}
