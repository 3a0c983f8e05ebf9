//! Reading a `.rpk` file: map it, check the header (magic, version, length), walk the section
//! headers (kinds, order, lengths against the summary's counts, padding), and take each
//! section while checking its CRC-32, on all cores. The result is the sections as typed arrays
//! ([`Parts`]), each one exactly the bytes its checksum covers; [`super::validate`] checks them
//! against each other.
//!
//! An array section is taken in one of two ways: copied out of the map, the
//! checksum computed over the copy ([`read`]: nothing that happens to the file later reaches
//! the scene), or viewed in place in the map ([`read_in_place`]: no fresh memory, the file's
//! pages shared with the page cache; the file must then not change while the scene lives).

use super::records::{self, Header, ObjectRecord, SectionHeader, Summary};
use super::{
    ALIGN, BLKS, HEADER_BYTES, Kind, LTRI, MAGIC, MASK, NAME, NODE, OBJS, SECTION_HEADER_BYTES,
    SECTIONS, SUMM, TIDS, TRIS, VERSION, VERT, WIDE,
};
use crate::bvh::Block;
use crate::engine::wide::WideNode;
use crate::error::{Error, Result};
use crate::io::mapped::Pages;
use crate::layout::{GpuNode, GpuTriangle};
use crate::store::Store;
use bytemuck::Pod;
use glam::DVec3;
use rayon::prelude::*;
use std::ops::Range;
use std::path::Path;
use std::sync::Arc;

/// The sections of a file whose header, lengths and checksums are right.
#[derive(Debug, Default)]
pub struct Parts {
    /// The summary.
    pub summary: Summary,
    /// Scene vertices.
    pub positions: Store<DVec3>,
    /// Scene triangles.
    pub triangles: Store<[u32; 3]>,
    /// Objects, as stored.
    pub objects: Vec<ObjectRecord>,
    /// The objects' names, one after another.
    pub names: Vec<u8>,
    /// The kernel's nodes.
    pub nodes: Store<GpuNode>,
    /// Leaf-order triangles.
    pub leaf_triangles: Store<GpuTriangle>,
    /// Scene triangle of each leaf-order triangle.
    pub triangle_ids: Store<u32>,
    /// Per-triangle masks.
    pub masks: Store<u32>,
    /// Terrain blocks.
    pub blocks: Vec<Block>,
    /// Wide nodes.
    pub wide: Store<WideNode>,
}

/// How the arrays of a mapped file are taken (see the module docs).
enum Placement<'a> {
    /// Copied out of the bytes, checksummed over the copy; the map's pages follow the hints.
    Copied(Pages<'a>),
    /// Viewed in place in this map, checksummed there.
    InPlace(&'a Arc<memmap2::Mmap>),
}

/// An [`Error::Parse`] naming `path`: "the file is corrupted: …" and the like.
pub(crate) fn problem(path: &Path, message: impl Into<String>) -> Error {
    Error::Parse {
        path: path.display().to_string(),
        line: None,
        message: message.into(),
    }
}

/// The file at `path`, mapped after the checks every map needs: the platform, a regular file,
/// the memory budget, a length that holds a header (a shorter file is read and refused here).
pub(crate) fn map_file(path: &Path) -> Result<memmap2::Mmap> {
    super::write::refuse_big_endian()?;
    let (file, length) = crate::io::open_regular(path)?;
    crate::budget::check(&format!("loading {}", path.display()), length, 1)?;
    let io = |source| Error::Io {
        path: path.display().to_string(),
        source,
    };
    if length < HEADER_BYTES as u64 {
        // Too short to map usefully (and a zero-length map is refused): read the few bytes.
        let bytes = std::fs::read(path).map_err(io)?;
        return Err(short_file(path, &bytes));
    }
    // SAFETY: mapping a file is sound; what the callers do with the bytes is theirs to justify
    // (`read` copies every section before use; `read_in_place` passes the duty to its caller).
    unsafe { memmap2::Mmap::map(&file) }.map_err(io)
}

/// Reads the file at `path`, mapped as `map` ([`map_file`]), copying every section (see the
/// module docs).
pub fn read(path: &Path, map: &memmap2::Mmap) -> Result<Parts> {
    // The map is read only while this function runs and every section is copied out (and
    // checksummed) before use, so nothing acts on bytes that change underneath. A file
    // truncated by another process while it is mapped raises SIGBUS, as for any mapped file.
    parse_from(path, map, Placement::Copied(Pages(Some(map))))
}

/// Reads the file at `path`, mapped as `map` ([`map_file`]), viewing every array section in
/// place in the map (see the module docs).
///
/// # Safety
/// Nothing may write into the file, or shorten it, while the returned parts or anything made of
/// them exist: their arrays are checked once, on load, and then trusted (see
/// [`super::load_in_place`]).
pub unsafe fn read_in_place(path: &Path, map: Arc<memmap2::Mmap>) -> Result<Parts> {
    // The whole file is read at least once (the checksums): fault every page in at once.
    #[cfg(target_os = "linux")]
    let _ = map.advise(memmap2::Advice::PopulateRead);
    parse_from(path, &map, Placement::InPlace(&map))
}

/// The error for a file shorter than the header.
fn short_file(path: &Path, bytes: &[u8]) -> Error {
    let n = bytes.len().min(MAGIC.len());
    if bytes[..n] == MAGIC[..n] {
        problem(
            path,
            format!(
                "the file is truncated: it has {} bytes, fewer than the {HEADER_BYTES}-byte header",
                bytes.len()
            ),
        )
    } else {
        not_rpk(path)
    }
}

fn not_rpk(path: &Path) -> Error {
    problem(
        path,
        "the file is not a raypick saved scene (.rpk): it does not start with the .rpk magic bytes",
    )
}

/// Reads a whole file's bytes (see the module docs).
pub fn parse(path: &Path, bytes: &[u8]) -> Result<Parts> {
    parse_from(path, bytes, Placement::Copied(Pages(None)))
}

fn parse_from(path: &Path, bytes: &[u8], placement: Placement<'_>) -> Result<Parts> {
    let header = header(path, bytes)?;
    if header.sections as usize != SECTIONS.len() {
        return Err(problem(
            path,
            format!(
                "the file is corrupted: its header lists {} sections, but version {VERSION} has {}",
                header.sections,
                SECTIONS.len()
            ),
        ));
    }
    let table = section_table(path, bytes, &SECTIONS)?;
    let summary_bytes = checked(
        path,
        SUMM,
        &bytes[table[0].clone()],
        table_crc(bytes, &table, 0),
    )?;
    if summary_bytes.len() != SUMM.element {
        return Err(problem(
            path,
            format!(
                "the file is corrupted: section {} holds {} bytes, not {}",
                name(SUMM),
                summary_bytes.len(),
                SUMM.element
            ),
        ));
    }
    let summary = Summary::decode(summary_bytes);
    check_lengths(path, &summary, &table)?;
    take_sections(path, bytes, &table, summary, &placement)
}

/// The file's header, after checking the magic, its checksum, the version and the file's
/// length against it.
pub(crate) fn header(path: &Path, bytes: &[u8]) -> Result<Header> {
    if bytes.len() < HEADER_BYTES {
        return Err(short_file(path, bytes));
    }
    if bytes[..MAGIC.len()] != MAGIC {
        return Err(not_rpk(path));
    }
    let header_bytes: &[u8; HEADER_BYTES] = bytes[..HEADER_BYTES].try_into().expect("32 bytes");
    let Some(header) = Header::decode(header_bytes) else {
        return Err(problem(
            path,
            "the file is corrupted: its header fails its checksum",
        ));
    };
    if header.version != VERSION {
        return Err(problem(
            path,
            format!(
                "the file is in .rpk format version {}, but this raypick reads version {VERSION} \
                 only; save the scene again with this raypick",
                header.version
            ),
        ));
    }
    let actual = bytes.len() as u64;
    if actual < header.file_length {
        return Err(problem(
            path,
            format!(
                "the file is truncated: it has {actual} bytes, but its header says {}",
                header.file_length
            ),
        ));
    }
    if actual > header.file_length {
        return Err(problem(
            path,
            format!(
                "the file is corrupted: it has {actual} bytes, more than the {} its header says",
                header.file_length
            ),
        ));
    }
    Ok(header)
}

/// The CRC-32 stored in section `k`'s header.
pub(crate) fn table_crc(bytes: &[u8], table: &[Range<usize>], k: usize) -> u32 {
    let at = table[k].start - SECTION_HEADER_BYTES;
    let header: &[u8; SECTION_HEADER_BYTES] =
        bytes[at..table[k].start].try_into().expect("16 bytes");
    SectionHeader::decode(header).crc
}

/// The payload range of each section, in order, after checking that they are `kinds`, their
/// bounds and padding.
pub(crate) fn section_table(
    path: &Path,
    bytes: &[u8],
    kinds: &[Kind],
) -> Result<Vec<Range<usize>>> {
    let mut table = Vec::with_capacity(kinds.len());
    let mut at = HEADER_BYTES;
    for &kind in kinds {
        let corrupted = |why: String| problem(path, format!("the file is corrupted: {why}"));
        let start = super::payload_start(at);
        let Some(header) = bytes.get(start - SECTION_HEADER_BYTES..start) else {
            return Err(corrupted(format!(
                "section {} would start at byte {}, past its end",
                name(kind),
                start - SECTION_HEADER_BYTES
            )));
        };
        if bytes[at..start - SECTION_HEADER_BYTES]
            .iter()
            .any(|&b| b != 0)
        {
            return Err(corrupted(format!(
                "the padding before section {} is not zero",
                name(kind)
            )));
        }
        let header = SectionHeader::decode(header.try_into().expect("16 bytes"));
        if header.tag != kind.tag {
            return Err(corrupted(format!(
                "section {} has the kind {:?} where {} belongs",
                table.len() + 1,
                String::from_utf8_lossy(&header.tag),
                name(kind)
            )));
        }
        let room = (bytes.len() - start) as u64;
        let padded = header.length.checked_next_multiple_of(ALIGN as u64);
        let Some(padded) = padded.filter(|&p| p <= room) else {
            return Err(corrupted(format!(
                "section {} says it holds {} bytes, but only {room} follow it",
                name(kind),
                header.length
            )));
        };
        let end = start + header.length as usize;
        at = start + padded as usize;
        if bytes[end..at].iter().any(|&b| b != 0) {
            return Err(corrupted(format!(
                "the padding after section {} is not zero",
                name(kind)
            )));
        }
        table.push(start..end);
    }
    if at != bytes.len() {
        return Err(problem(
            path,
            format!(
                "the file is corrupted: its sections end at byte {at}, but the file has {} bytes",
                bytes.len()
            ),
        ));
    }
    Ok(table)
}

pub(crate) fn name(kind: Kind) -> String {
    format!("{} ({})", String::from_utf8_lossy(&kind.tag), kind.what)
}

/// Checks `payload` against `crc`.
pub(crate) fn checked<'a>(
    path: &Path,
    kind: Kind,
    payload: &'a [u8],
    crc: u32,
) -> Result<&'a [u8]> {
    if crc_of(payload) != crc {
        return Err(checksum_error(path, kind));
    }
    Ok(payload)
}

fn checksum_error(path: &Path, kind: Kind) -> Error {
    problem(
        path,
        format!(
            "the file is corrupted: section {} fails its checksum",
            name(kind)
        ),
    )
}

/// Checks every section's length against the summary's count for it.
fn check_lengths(path: &Path, s: &Summary, table: &[Range<usize>]) -> Result<()> {
    let counts = [
        1,
        s.vertices,
        s.triangles,
        s.objects,
        s.name_bytes,
        s.nodes,
        s.leaf_triangles,
        s.leaf_triangles,
        s.masks,
        s.blocks,
        s.wide_nodes,
    ];
    for ((kind, count), range) in SECTIONS.iter().zip(counts).zip(table) {
        let length = range.len() as u64;
        if count.checked_mul(kind.element as u64) != Some(length) {
            return Err(problem(
                path,
                format!(
                    "the file is corrupted: section {} holds {length} bytes, but the summary's \
                     count of {count} needs {count} × {} bytes",
                    name(*kind),
                    kind.element
                ),
            ));
        }
    }
    Ok(())
}

/// Takes every section of `bytes` as its typed array, checking its CRC-32 (see the module docs
/// and [`Placement`]); large sections are copied and checksummed in parallel pieces.
fn take_sections(
    path: &Path,
    bytes: &[u8],
    table: &[Range<usize>],
    summary: Summary,
    placement: &Placement<'_>,
) -> Result<Parts> {
    let range = |kind: Kind| {
        let k = SECTIONS
            .iter()
            .position(|&s| s == kind)
            .expect("a section of this version");
        (table[k].clone(), table_crc(bytes, table, k))
    };
    let record_bytes = |kind: Kind| {
        let (r, crc) = range(kind);
        checked(path, kind, &bytes[r], crc)
    };
    macro_rules! array {
        ($kind:expr) => {
            take_checked(path, $kind, bytes, range($kind), placement)
        };
    }
    let wide: Store<WideNode> = array!(WIDE)?;
    if wide
        .par_iter()
        .any(|node| node.reserved.iter().any(|&b| b != 0))
    {
        return Err(reserved_error(path, WIDE));
    }
    Ok(Parts {
        summary,
        positions: array!(VERT)?,
        triangles: array!(TRIS)?,
        objects: record_bytes(OBJS)?
            .chunks_exact(OBJS.element)
            .map(ObjectRecord::decode)
            .collect(),
        names: record_bytes(NAME)?.to_vec(),
        nodes: array!(NODE)?,
        leaf_triangles: array!(LTRI)?,
        triangle_ids: array!(TIDS)?,
        masks: array!(MASK)?,
        blocks: record_bytes(BLKS)?
            .chunks_exact(BLKS.element)
            .map(records::decode_block)
            .collect::<Option<_>>()
            .ok_or_else(|| reserved_error(path, BLKS))?,
        wide,
    })
}

/// Section `range` of `bytes` as an array, copied or in place as `placement` says.
fn take_checked<T: Pod + Send + Sync>(
    path: &Path,
    kind: Kind,
    bytes: &[u8],
    (range, crc): (Range<usize>, u32),
    placement: &Placement<'_>,
) -> Result<Store<T>> {
    let payload = &bytes[range.clone()];
    match placement {
        Placement::InPlace(map) => {
            if crc_of(payload) != crc {
                return Err(checksum_error(path, kind));
            }
            // SAFETY: `read_in_place`'s caller promises that nothing changes the file while
            // the view lives.
            match unsafe { Store::mapped(map, range) } {
                Some(view) => Ok(view),
                // Not aligned (never on the platforms raypick runs on): a checked copy.
                None => copy_checked(path, kind, payload, crc).map(Store::from),
            }
        }
        Placement::Copied(pages) => {
            pages.need(payload);
            let copy = copy_checked(path, kind, payload, crc);
            pages.done(payload);
            copy.map(Store::from)
        }
    }
}

fn reserved_error(path: &Path, kind: Kind) -> Error {
    problem(
        path,
        format!(
            "the file is corrupted: a record of section {} has a reserved field that is not zero",
            name(kind)
        ),
    )
}

/// Bytes per parallel piece of [`copy_checked`].
const PIECE: usize = 1 << 20;

/// `payload` (a whole number of `T`s) copied into a vector of `T`, in parallel, then its
/// CRC-32 computed over the copy, in parallel pieces combined in order, and checked against
/// `crc`.
fn copy_checked<T: Pod + Send + Sync>(
    path: &Path,
    kind: Kind,
    payload: &[u8],
    crc: u32,
) -> Result<Vec<T>> {
    let size = size_of::<T>();
    debug_assert_eq!(size, kind.element);
    let n = payload.len() / size;
    // Fresh memory on huge pages where the OS offers them: 4 KiB page faults would cost more
    // than the copy.
    let mut out: Vec<T> = crate::huge_pages::vec_with_capacity(n);
    match bytemuck::try_cast_slice::<u8, T>(payload) {
        Ok(items) => out.par_extend(items.par_iter().with_min_len(PIECE / size).copied()),
        // Only for a map that is not aligned (never on the platforms raypick runs on): read
        // item by item.
        Err(_) => out.extend(
            payload
                .chunks_exact(size)
                .map(bytemuck::pod_read_unaligned::<T>),
        ),
    }
    if crc_of(bytemuck::cast_slice::<T, u8>(&out)) != crc {
        return Err(checksum_error(path, kind));
    }
    Ok(out)
}

/// The CRC-32 of `bytes`, computed in parallel pieces combined in order.
fn crc_of(bytes: &[u8]) -> u32 {
    bytes
        .par_chunks(PIECE)
        .map(|piece| {
            let mut h = crc32fast::Hasher::new();
            h.update(piece);
            h
        })
        .reduce(crc32fast::Hasher::new, |mut a, b| {
            a.combine(&b);
            a
        })
        .finalize()
}
