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
//! so are the errors; `tests/suite/obj_reader.rs` checks), plus line continuations:
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
//!   …. Faces with fewer than 3 vertices give no triangle: they are skipped with one warning
//!   ([`crate::io::warnings`]: their count and the first one's line). A file that gives no triangle
//!   otherwise (no face at all, or no `v` or `f` line: not an OBJ file, perhaps) is warned about
//!   once too.
//! - A `v` or `f` line whose last character before any comment (spaces aside) is `\` continues
//!   on the next line: the `\` counts as a space. Errors name the first line of the joined
//!   ones. Other lines are ignored whole, so a `\` at their end joins nothing.
//! - The mesh's vertices are the ones the triangles use, numbered in order of first use.
//!
//! Errors are [`Error::Parse`] naming the file and the 1-based line; the first error in the file
//! is reported.
//!
//! Memory: loading peaks near the mesh's own size (1.2× on an 810k-triangle file; see
//! [`parse_with`] and [`build_mesh`] for how), never the file plus the mesh.

use std::ops::Range;
use std::path::Path;

use glam::DVec3;
use rayon::prelude::*;

use crate::budget::quote;
use crate::error::Error;
use crate::io::mapped::Pages;
use crate::scene::Mesh;

/// Chunks are about this long at least: below it, a thread costs more than it saves.
const MIN_CHUNK_BYTES: usize = 256 << 10;
/// Chunks are at most this long: the file's pages in flight stay few, and a chunk's vectors
/// (sized for it at once) stay under a huge page, so untouched capacity is never resident.
const MAX_CHUNK_BYTES: usize = 1 << 20;

/// Loads the triangle mesh of the OBJ file at `path`.
///
/// A file with no faces gives an empty mesh, with one warning ([`crate::io::warnings`]) (that no vertex
/// or face was read, or how many vertices but no face). Malformed content (unparseable or non-finite
/// coordinates, face indices that are 0, out of range or not integers) is an [`Error::Parse`]
/// naming the file and the line. The file must be a regular file whose length fits the memory
/// budget ([`crate::budget`]).
pub fn load_obj(path: &Path) -> Result<Mesh, Error> {
    let name = path.display().to_string();
    let bytes = read_file(path)?;
    let (pages, file) = match &bytes {
        FileBytes::Mapped(map, file) => (Pages(Some(map)), Some(file)),
        FileBytes::Read(_) => (Pages(None), None),
    };
    let chunk_bytes = chunk_bytes_for(bytes.len());
    let (mesh, short, vertices) = parse_with(&name, &bytes, chunk_bytes, file, &pages)?;
    if let Some(short) = short {
        crate::io::warnings::warn(format!("{name}: {}", short.describe()));
    } else if mesh.triangles.is_empty() {
        crate::io::warnings::warn(format!("{name}: {}", nothing_read(vertices)));
    }
    Ok(mesh)
}

/// The warning for a file that gave no triangle (and no face too short to give one), having
/// read `vertices` vertices.
fn nothing_read(vertices: u64) -> String {
    match vertices {
        0 => "no vertex or face was read (no line is a 'v' or 'f' statement), so its object is \
              empty"
            .to_owned(),
        1 => "1 vertex but no face was read, so its object is empty".to_owned(),
        n => format!("{n} vertices but no face were read, so its object is empty"),
    }
}

/// Parses the OBJ text `bytes` (named `name` in errors) into a mesh, and says which faces had
/// fewer than 3 vertices, if any. [`load_obj`] without the file and the warning.
pub fn parse_obj(name: &str, bytes: &[u8]) -> Result<(Mesh, Option<ShortFaces>), Error> {
    parse_obj_in_chunks(name, bytes, chunk_bytes_for(bytes.len()))
}

/// The `len` bytes of `file` from `offset`, read into `buffer`; `None` without a file or when
/// the read fails (the caller reads the map instead).
fn read_chunk<'b>(
    file: Option<&std::fs::File>,
    buffer: &'b mut Vec<u8>,
    offset: u64,
    len: usize,
) -> Option<&'b [u8]> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileExt;
        if buffer.len() < len {
            buffer.resize(len, 0);
        }
        let buffer = &mut buffer[..len];
        file?.read_exact_at(buffer, offset).ok()?;
        Some(buffer)
    }
    #[cfg(not(unix))]
    {
        let _ = (file, buffer, offset, len);
        None
    }
}

/// The chunk length for `bytes` of text: 32 chunks per thread, for balance and so that the
/// file's pages in flight (a chunk per thread) stay few; at most `MAX_CHUNK_BYTES`.
fn chunk_bytes_for(bytes: usize) -> usize {
    let threads = rayon::current_num_threads().max(1);
    (bytes / (32 * threads)).clamp(MIN_CHUNK_BYTES, MAX_CHUNK_BYTES)
}

/// [`parse_obj`] with chunks of about `chunk_bytes` (at least 1), for tests of the chunk seams.
#[doc(hidden)]
pub fn parse_obj_in_chunks(
    name: &str,
    bytes: &[u8],
    chunk_bytes: usize,
) -> Result<(Mesh, Option<ShortFaces>), Error> {
    parse_with(name, bytes, chunk_bytes, None, &Pages(None)).map(|(mesh, short, _)| (mesh, short))
}

/// [`parse_obj_in_chunks`] of bytes that may lie in a map of `file`. Then each chunk is read
/// from the file into a buffer that each thread reuses, and the map is only touched where
/// chunks are cut (and again on error paths), its pages let go at once: the file is never
/// resident whole beside the mesh. (Parsing straight from the map let the kernel map whole
/// page-cache folios around each chunk, and kept them mapped: a third of the file, at times.)
/// Also returns the number of vertices read, used by a face or not.
fn parse_with(
    name: &str,
    whole: &[u8],
    chunk_bytes: usize,
    file: Option<&std::fs::File>,
    pages: &Pages<'_>,
) -> Result<(Mesh, Option<ShortFaces>, u64), Error> {
    let bytes = whole.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(whole);
    let skipped = whole.len() - bytes.len();
    // Each chunk's pages are let go as soon as it is cut: a touch can map a whole page-cache
    // folio (2 MiB) of a mapped file, and cutting touches every chunk.
    let ranges = split(bytes, chunk_bytes.max(1), |chunk| pages.done(chunk));
    // One buffer per thread of the pool (and one for a caller outside it), for this load only.
    let buffers: Vec<std::sync::Mutex<Vec<u8>>> = (0..=rayon::current_num_threads())
        .map(|_| std::sync::Mutex::new(Vec::new()))
        .collect();
    let parse = |k: usize, r: &Range<usize>| {
        let slot = rayon::current_thread_index().map_or(0, |i| (i + 1) % buffers.len());
        let mut buffer = buffers[slot].lock().unwrap_or_else(|e| e.into_inner());
        let chunk = read_chunk(file, &mut buffer, (skipped + r.start) as u64, r.len())
            .unwrap_or(&bytes[r.clone()]);
        parse_chunk(chunk, (k == 0).then_some(0))
    };
    let outcomes: Vec<Outcome> = if ranges.len() == 1 {
        vec![parse(0, &ranges[0])]
    } else {
        ranges
            .par_iter()
            .enumerate()
            .map(|(k, r)| parse(k, r))
            .collect()
    };
    drop(buffers);
    join(name, bytes, &ranges, outcomes)
}

/// The bytes of an OBJ file: mapped when large, read when small.
enum FileBytes {
    /// The map, and the file for reading chunks.
    Mapped(memmap2::Mmap, std::fs::File),
    Read(Vec<u8>),
}

impl std::ops::Deref for FileBytes {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            FileBytes::Mapped(map, _) => map,
            FileBytes::Read(bytes) => bytes,
        }
    }
}

/// Files from this size are mapped rather than read.
const MAP_FROM_BYTES: u64 = 1 << 20;

/// The regular file at `path`, after checking its length against the memory budget. A large
/// file is mapped (memmap2) for finding where to cut it, and kept open for reading the chunks:
/// reading it whole into fresh memory cost the zeroing of as many new pages, a fair part of the
/// load time, and held the whole file beside the mesh.
fn read_file(path: &Path) -> Result<FileBytes, Error> {
    let (file, length) = crate::io::open_regular(path)?;
    crate::budget::check(&format!("reading {}", path.display()), length, 1)?;
    let io = |source| Error::Io {
        path: path.display().to_string(),
        source,
    };
    if length >= MAP_FROM_BYTES {
        // SAFETY: as for the `.rpk` reader's map, the file is assumed not to change while the
        // job reads it; the map is only read, by a parser that accepts any bytes. A file
        // truncated by another process meanwhile raises SIGBUS, as for any mapped file.
        let map = unsafe { memmap2::Mmap::map(&file) }.map_err(io)?;
        return Ok(FileBytes::Mapped(map, file));
    }
    let mut bytes = Vec::new();
    std::io::Read::read_to_end(&mut std::io::Read::take(&file, length), &mut bytes).map_err(io)?;
    Ok(FileBytes::Read(bytes))
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

/// Cuts `bytes` into ranges of about `target` bytes that start at line starts, handing each
/// range to `cut` once it is cut. A cut never follows a line holding a `\` (which might
/// continue onto the next line).
fn split(bytes: &[u8], target: usize, cut: impl Fn(&[u8])) -> Vec<Range<usize>> {
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
        cut(&bytes[start..end]);
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

/// Face corners are read as `i64`: `i − 1 ≥ 0` for a positive index `i` (already global), and
/// `local + i − TAG < 0` for a negative one (`local`: the chunk's vertices before the face),
/// which becomes global once the chunk's first vertex number (`base`) is known.
const TAG: i64 = 1 << 62;

/// Face corners are stored per chunk in 4 bytes each (the i64 of a whole file's corners once
/// held twice the mesh's memory): a value below `RELATIVE` is a global vertex number; a value
/// `v` from `RELATIVE` up to `FAR` is a negative index not yet global, `base + (v − RELATIVE) −
/// HALF`; `FAR` says the exact i64 corner is in the chunk's `far` list (only numbers no mesh
/// that fits in memory reaches).
const RELATIVE: u32 = 1 << 31;
const HALF: i64 = 1 << 30;
const FAR: u32 = u32::MAX;

/// What parsing one chunk gave.
struct Outcome {
    vertices: Vec<DVec3>,
    /// Corners as [`RELATIVE`] says.
    triangles: Vec<[u32; 3]>,
    /// (position among the chunk's corners, i64 corner) of each corner stored as [`FAR`].
    far: Vec<(usize, i64)>,
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
    // Room for the usual density at once (a vertex or face line is rarely under 16 bytes), so
    // the vectors seldom grow: each growth left the old copy behind in the thread's allocator
    // arena, and a whole file's worth raised the load's peak by half the mesh. Capacity never
    // written is never resident.
    let expected = bytes.len() / 16;
    let mut parser = Parser {
        base,
        vertices: Vec::with_capacity(expected),
        triangles: Vec::with_capacity(expected),
        far: Vec::new(),
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
        far: parser.far,
        lines,
        deficit: parser.deficit,
        short: parser.short,
        error,
        not_utf8,
    }
}

/// Joins the chunks' outcomes, in order, into one mesh (with the faces too short for a
/// triangle, and the number of vertices read), or reports the file's first error.
fn join(
    name: &str,
    bytes: &[u8],
    ranges: &[Range<usize>],
    outcomes: Vec<Outcome>,
) -> Result<(Mesh, Option<ShortFaces>, u64), Error> {
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
    let mesh = build_mesh(name, outcomes, &bases)?;
    Ok((mesh, short, base))
}

/// Concatenates the chunks' triangles, numbering the vertices in order of first use (as the
/// `tobj` reader did). Memory stays near the mesh's own: each chunk's corners are made global
/// in parallel straight into the mesh's triangles and freed, the vertices are moved into one
/// vector and put in first-use order in place.
fn build_mesh(name: &str, mut outcomes: Vec<Outcome>, bases: &[u64]) -> Result<Mesh, Error> {
    let vertex_count: usize = outcomes.iter().map(|o| o.vertices.len()).sum();
    let triangle_count: usize = outcomes.iter().map(|o| o.triangles.len()).sum();
    if triangle_count == 0 {
        return Ok(Mesh::default());
    }
    // Global vertex numbers are u32 here (below `UNUSED`); the mesh's can only be fewer.
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

    // Global corners, each chunk into its own run of the triangles, its own corners then freed.
    let mut triangles: Vec<[u32; 3]> = Vec::with_capacity(triangle_count);
    let mut runs = Vec::with_capacity(outcomes.len());
    let mut rest = &mut triangles.spare_capacity_mut()[..triangle_count];
    for outcome in &outcomes {
        let (run, tail) = rest.split_at_mut(outcome.triangles.len());
        runs.push(run);
        rest = tail;
    }
    let parts: Vec<_> = outcomes
        .iter_mut()
        .map(|o| (std::mem::take(&mut o.triangles), std::mem::take(&mut o.far)))
        .collect();
    // Every run is written whole (no early stop), as `set_len` below relies on.
    let in_range = runs
        .into_par_iter()
        .zip(parts)
        .zip(bases)
        .map(|((run, (corners, far)), &base)| {
            let mut far = far.into_iter().peekable();
            let mut ok = true;
            for (k, (out, stored)) in run.iter_mut().zip(corners).enumerate() {
                let mut global = [0u32; 3];
                for (j, (slot, c)) in global.iter_mut().zip(stored).enumerate() {
                    let g = match c {
                        c if c < RELATIVE => i64::from(c),
                        FAR => match far.next_if(|&(at, _)| at == 3 * k + j) {
                            Some((_, c)) if c >= 0 => c,
                            Some((_, c)) => c + TAG + base as i64,
                            None => -1,
                        },
                        c => base as i64 + i64::from(c - RELATIVE) - HALF,
                    };
                    // In range: the chunk was checked against its base.
                    ok &= (0..vertex_count as i64).contains(&g);
                    *slot = g as u32;
                }
                out.write(global);
            }
            ok
        })
        .reduce(|| true, |a, b| a & b);
    // SAFETY: the runs cover the first `triangle_count` slots, and each run's slots were all
    // written above (a run is as long as its chunk's corner triples, each written once).
    unsafe { triangles.set_len(triangle_count) };
    if !in_range {
        return Err(parse_error(
            name,
            None,
            "the OBJ reader lost track of a face index".to_owned(),
        ));
    }

    // Numbers in order of first use; then the unused vertices, so `order` is a permutation.
    const UNUSED: u32 = u32::MAX;
    let mut number = vec![UNUSED; vertex_count];
    let mut order: Vec<u32> = Vec::with_capacity(vertex_count);
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
    let used = order.len();
    order.extend((0..vertex_count as u32).filter(|&g| number[g as usize] == UNUSED));
    drop(number);

    // The vertices in file order, moved into one vector (chunk by chunk, each freed), then
    // put in first-use order in place.
    let mut positions = std::mem::take(&mut outcomes[0].vertices);
    positions.reserve_exact(vertex_count - positions.len());
    for outcome in &mut outcomes[1..] {
        positions.extend_from_slice(&std::mem::take(&mut outcome.vertices));
    }
    drop(outcomes);
    gather_in_place(&mut positions, &mut order);
    positions.truncate(used);
    Ok(Mesh {
        positions,
        triangles,
    })
}

/// Puts `values[order[n]]` at `values[n]` for every `n`, in place, by following the cycles of
/// the permutation `order` (of `0..values.len()`, each below `u32::MAX`); `order` is spent.
fn gather_in_place<T: Copy>(values: &mut [T], order: &mut [u32]) {
    const DONE: u32 = u32::MAX;
    for start in 0..values.len() {
        if order[start] == DONE {
            continue;
        }
        let first = values[start];
        let mut at = start;
        loop {
            let from = order[at] as usize;
            order[at] = DONE;
            if from == start {
                values[at] = first;
                break;
            }
            values[at] = values[from];
            at = from;
        }
    }
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
    triangles: Vec<[u32; 3]>,
    far: Vec<(usize, i64)>,
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
        let n = self.corners.len();
        if n < 3 {
            self.short.get_or_insert((0, line)).0 += 1;
            return;
        }
        for k in 1..n - 1 {
            let slot = self.triangles.len() * 3;
            let c = &self.corners;
            let corners = [c[0], c[k], c[k + 1]];
            let stored = [
                self.pack(slot, corners[0]),
                self.pack(slot + 1, corners[1]),
                self.pack(slot + 2, corners[2]),
            ];
            self.triangles.push(stored);
        }
    }

    /// The 4-byte form of the i64 `corner` at position `slot` of the chunk's corners.
    #[inline(always)]
    fn pack(&mut self, slot: usize, corner: i64) -> u32 {
        let global = match (corner >= 0, self.base) {
            (true, _) => Some(corner),
            (false, Some(base)) => Some(corner + TAG + base as i64),
            (false, None) => None,
        };
        match global {
            Some(g) if g < i64::from(RELATIVE) => return g as u32,
            None => {
                let relative = corner + TAG;
                if (-HALF..HALF - 1).contains(&relative) {
                    return RELATIVE + (relative + HALF) as u32;
                }
            }
            Some(_) => {}
        }
        self.far.push((slot, corner));
        FAR
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

    #[test]
    fn gathering_in_place_is_a_gather() {
        use rand::SeedableRng;
        use rand::seq::SliceRandom;
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        for n in [0usize, 1, 2, 3, 10, 1000] {
            let mut order: Vec<u32> = (0..n as u32).collect();
            order.shuffle(&mut rng);
            let values: Vec<u64> = (0..n as u64).map(|v| v * 31 + 5).collect();
            let expected: Vec<u64> = order.iter().map(|&k| values[k as usize]).collect();
            let mut in_place = values.clone();
            gather_in_place(&mut in_place, &mut order.clone());
            assert_eq!(in_place, expected, "n = {n}");
        }
    }

    #[test]
    fn corners_pack_into_four_bytes_and_back() {
        // Chunk 0 (base known) stores globals; a later chunk stores negative indices relative
        // to its base, and an index beyond every mesh in the far list (then an error).
        let text =
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n".repeat(40) + &"v 2 2 2\nf -1 -2 -4\n".repeat(40);
        let whole = parse_obj_in_chunks("m.obj", text.as_bytes(), usize::MAX).expect("whole");
        let chunked = parse_obj_in_chunks("m.obj", text.as_bytes(), 64).expect("chunked");
        assert_eq!(whole.0.positions, chunked.0.positions);
        assert_eq!(whole.0.triangles, chunked.0.triangles);
        assert_eq!(whole.0.triangles.len(), 80);
        let far = text.clone() + "f 1 2 3000000000\n";
        for chunk in [usize::MAX, 64] {
            let error = parse_obj_in_chunks("m.obj", far.as_bytes(), chunk)
                .expect_err("index out of range")
                .to_string();
            assert!(
                error.contains("m.obj:241:") && error.contains("3000000000"),
                "{error}"
            );
        }
    }

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
