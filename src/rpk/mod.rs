//! A saved built scene (`.rpk`): the scene and every tree the backends walk, written once by
//! [`save`] and loaded by [`load`] with no rebuild, so a mesh is parsed and built once and then
//! picked from any number of processes.
//!
//! ```
//! use std::sync::Arc;
//! use raypick::{BuildOptions, BuiltScene, CpuPicker, Picker, Ray, check::synthetic, rpk};
//! use glam::DVec3;
//!
//! let built = BuiltScene::new(synthetic::example_scene(), &BuildOptions::default()).unwrap();
//! let path = std::env::temp_dir().join(format!("doc-{}.rpk", std::process::id()));
//! rpk::save(&built, &path).unwrap();
//! assert!(rpk::is_rpk(&path));
//! let loaded = Arc::new(rpk::load(&path).unwrap());
//! let ray = Ray::new(DVec3::new(34.0, 44.0, 100.0), DVec3::NEG_Z);
//! assert_eq!(CpuPicker::new(loaded).pick(&[ray]).unwrap()[0].object, 1);
//! # std::fs::remove_file(&path).unwrap();
//! ```
//!
//! An instanced scene ([`BuiltScene::instanced`]) is saved in the same framing with other
//! sections: the instances and each mesh as a whole saved scene of its own ([`instanced`]).
//!
//! The module is the format: [`records`] encodes its fixed-size records,
//! [`write`](mod@write) writes a file, [`read`] maps one and checks its header, sections and
//! checksums, and [`validate`] checks what the sections say against each other before a
//! [`BuiltScene`] is made of them.
//!
//! # Format, version 3
//!
//! Everything is little-endian. A file is a 32-byte header followed by sections. Each section
//! is zero bytes up to 16 bytes before the next 64-byte boundary of the file, a 16-byte section
//! header, and a payload, which therefore starts on a 64-byte boundary ([`payload_start`]) and
//! is followed by zero bytes up to the next 64-byte boundary. With the file mapped at a page
//! boundary, every payload can be viewed in place as an array of its elements (`f64`, `u32`,
//! the Pod [`GpuNode`](crate::layout::GpuNode), [`GpuTriangle`](crate::layout::GpuTriangle) and
//! the cache-line aligned [`WideNode`](crate::engine::wide::WideNode)), which [`load_in_place`]
//! does. (Version 1 padded to 16 bytes, so wide nodes had to be copied to be aligned; it is
//! refused with a message to save the scene again; so is version 2, whose wide nodes were
//! 4-wide.)
//!
//! **Header** (its layout is the same in every version, so any version's file is told apart
//! from a corrupted one):
//!
//! | offset | field |
//! |---|---|
//! | 0 | magic, the 8 bytes `89 52 50 4B 0D 0A 1A 0A` (`\x89RPK\r\n\x1a\n`, as PNG's) |
//! | 8 | format version, u32 ([`VERSION`]) |
//! | 12 | number of sections, u32 (11 in version 3) |
//! | 16 | length of the whole file in bytes, u64 |
//! | 24 | reserved, u32, zero |
//! | 28 | CRC-32 (IEEE, as zlib and `crc32fast`) of bytes 0..28 |
//!
//! **Section header:** the kind (4 ASCII bytes), the CRC-32 of the payload (u32), the payload's
//! length in bytes (u64). Version 3 has these eleven sections, each once, in this order (element
//! sizes in bytes):
//!
//! | kind | what | element |
//! |---|---|---|
//! | `SUMM` | the counts below and the two origins ([`records::Summary`]) | one record of 128 |
//! | `VERT` | scene vertex positions, world f64 x, y, z | 24 |
//! | `TRIS` | scene triangles: three u32 vertex indices, in scene (file) order | 12 |
//! | `OBJS` | objects: id, first triangle, triangle count, first vertex, mask, has-grid (0/1), grid columns, grid rows, name length, flags (bit 0: mirrored by its transform; other bits zero; files written before it was defined hold 0) (u32 each) | 40 |
//! | `NAME` | the objects' names, UTF-8, one after another (lengths in `OBJS`) | 1 |
//! | `NODE` | the kernel's tree: [`GpuNode`](crate::layout::GpuNode)s, depth-first | 32 |
//! | `LTRI` | the tree's triangles in leaf order: [`GpuTriangle`](crate::layout::GpuTriangle)s, f32 offsets from the tree's origin | 36 |
//! | `TIDS` | for each leaf-order triangle, its scene triangle (u32) | 4 |
//! | `MASK` | layer mask of each leaf-order triangle (u32); empty when every object's mask is all ones | 4 |
//! | `BLKS` | terrain blocks (grid builder only): cell rows (start, end), cell columns (start, end), root node, leaf-order triangles (start, end), a zero (u32 each), then the world min, max and origin (f64 x, y, z each) | 104 |
//! | `WIDE` | the CPU engine's 8-wide tree, depth-first ([`WideNode`](crate::engine::wide::WideNode)): per node the children's min x, y, z and max x, y, z (f32 × 8 each), child index (u32 × 8), kind (u8 × 8), occupied bits (u8), 23 zero bytes | 256 |
//!
//! `SUMM` holds, as u64: the numbers of vertices, scene triangles, objects, name bytes, nodes,
//! leaf-order triangles, blocks and wide nodes, the wide tree's depth, the number of masks;
//! then the scene origin (the centre of the vertices' bounds) and the tree's origin, f64 x, y,
//! z each.
//!
//! # What loading checks
//!
//! A file is refused, with one sentence naming it and the problem, when its magic, version,
//! length or any checksum is wrong, when a section is missing, out of order or of a length its
//! count does not give, when it is larger than the memory budget ([`crate::budget`]), or when
//! the sections disagree: a non-finite vertex; a vertex index, object range, scene triangle id,
//! mask, block or tree link out of range; a scene triangle in the tree twice; a tree that is
//! not a tree, or a triangle in two leaves or none ([`validate::tree_links`],
//! [`WideBvh::validate`](crate::engine::WideBvh::validate)). A file that passes is safe to walk
//! on every backend (no read out of range, no walk that does not end), and the checksums make
//! any accidental change an error. The checks take time linear in the file, mostly in
//! parallel; the geometric invariants of [`Bvh::validate`](crate::Bvh::validate) (nested boxes)
//! are not checked again on load, so a file edited on purpose and checksummed again can pass
//! with other boxes and give other answers: the checks keep the program safe, not the file
//! honest.
//!
//! # Copied or in place
//!
//! [`load`] copies every section into memory of its own and checks the copy: what happens to
//! the file afterwards cannot reach the scene. [`load_in_place`] checks the sections where they
//! lie in the mapped file and picks from there, touching no fresh memory (on the project's
//! virtual machine a 70 MB scene loads in a few milliseconds instead of tens); it is `unsafe`
//! because the file must not be changed in place while the scene lives. The command-line
//! tool's one-shot commands load in place; `raypick serve` and `soak` copy.
//!
//! [`BuiltScene`]: crate::BuiltScene

pub mod instanced;
pub mod read;
pub mod records;
pub mod validate;
pub mod write;

use crate::error::Result;
use crate::picker::BuiltScene;
use std::path::Path;

/// The 8 bytes every `.rpk` file starts with.
pub const MAGIC: [u8; 8] = *b"\x89RPK\r\n\x1a\n";
/// The format version this build writes and reads.
pub const VERSION: u32 = 3;
/// Bytes of the file header.
pub const HEADER_BYTES: usize = 32;
/// Bytes of a section header.
pub const SECTION_HEADER_BYTES: usize = 16;
/// Payloads start on, and are padded to, multiples of this many bytes (a cache line: the wide
/// nodes' alignment).
pub const ALIGN: usize = 64;

/// Where the payload of a section starts when the previous section (or the file header) ends
/// at byte `at`: the first 64-byte boundary with room for the section header before it.
pub const fn payload_start(at: usize) -> usize {
    (at + SECTION_HEADER_BYTES).next_multiple_of(ALIGN)
}

/// One kind of section: its tag in the file, its element size, and what it holds (for
/// messages).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Kind {
    /// The 4 ASCII bytes of the section header.
    pub tag: [u8; 4],
    /// Bytes per element (the payload is a whole number of elements).
    pub element: usize,
    /// What the section holds, for messages.
    pub what: &'static str,
}

/// The summary.
pub const SUMM: Kind = Kind {
    tag: *b"SUMM",
    element: records::SUMMARY_BYTES,
    what: "summary",
};
/// Scene vertices.
pub const VERT: Kind = Kind {
    tag: *b"VERT",
    element: 24,
    what: "vertices",
};
/// Scene triangles.
pub const TRIS: Kind = Kind {
    tag: *b"TRIS",
    element: 12,
    what: "triangles",
};
/// Objects.
pub const OBJS: Kind = Kind {
    tag: *b"OBJS",
    element: records::OBJECT_BYTES,
    what: "objects",
};
/// Object names.
pub const NAME: Kind = Kind {
    tag: *b"NAME",
    element: 1,
    what: "object names",
};
/// The kernel's nodes.
pub const NODE: Kind = Kind {
    tag: *b"NODE",
    element: 32,
    what: "tree nodes",
};
/// Leaf-order triangles.
pub const LTRI: Kind = Kind {
    tag: *b"LTRI",
    element: 36,
    what: "leaf-order triangles",
};
/// Scene triangle ids of the leaf-order triangles.
pub const TIDS: Kind = Kind {
    tag: *b"TIDS",
    element: 4,
    what: "triangle ids",
};
/// Per-triangle layer masks.
pub const MASK: Kind = Kind {
    tag: *b"MASK",
    element: 4,
    what: "triangle masks",
};
/// Terrain blocks.
pub const BLKS: Kind = Kind {
    tag: *b"BLKS",
    element: records::BLOCK_BYTES,
    what: "terrain blocks",
};
/// The CPU engine's wide nodes.
pub const WIDE: Kind = Kind {
    tag: *b"WIDE",
    element: records::WIDE_NODE_BYTES,
    what: "wide tree nodes",
};

/// Version 3's sections, in file order.
pub const SECTIONS: [Kind; 11] = [
    SUMM, VERT, TRIS, OBJS, NAME, NODE, LTRI, TIDS, MASK, BLKS, WIDE,
];

/// Writes `built` to `path` as a `.rpk` file: the scene, the kernel's tree and the CPU engine's
/// wide tree (collapsed now if it was not yet). The file is written beside `path` and renamed
/// into place, so `path` is never left half-written.
///
/// # Errors
/// [`crate::Error::Io`] naming the file when it cannot be written; an error for a corrupted
/// tree (the collapse refuses it).
pub fn save(built: &BuiltScene, path: &Path) -> Result<()> {
    write::save(built, path)
}

/// Memory-maps the `.rpk` file at `path`, checks it (see the [module docs](self)) and returns
/// the built scene it holds, ready to pick with no rebuild.
///
/// # Errors
/// [`crate::Error::Io`] when the file cannot be read; [`crate::Error::Parse`] naming the file
/// for another format version, a truncated or corrupted file; [`crate::Error::OverBudget`] when
/// it is larger than the memory budget.
pub fn load(path: &Path) -> Result<BuiltScene> {
    let map = read::map_file(path)?;
    if instanced::is_instanced(&map) {
        return instanced::decode(path, &map);
    }
    let parts = read::read(path, &map)?;
    validate::assemble(path, parts)
}

/// [`load`] without the copies: the scene's vertices and triangles and the kernel's tree are
/// viewed in place in the file's mapped pages ([`crate::store::Store`]), checked there once, and
/// shared with the page cache, so loading touches no fresh memory for them (only the CPU
/// engine's nodes, whose alignment the file cannot promise, are converted into memory of their
/// own). The same checks as [`load`]; for processes that pick from a file and exit, like the
/// command-line tool's one-shot commands. A process that lives on while the file may be
/// replaced (a server) should [`load`] instead. An instanced scene ([`instanced`]) is copied
/// out of the map, as [`load`] copies it.
///
/// # Safety
/// Nothing may write into the file in place, or shorten it, while the returned scene or
/// anything cloned from it exists: the in-place arrays are checked once and then trusted
/// (changed bytes could index out of range; a shortened file raises SIGBUS on the next read
/// of a lost page). Replacing the file is safe: `raypick build --out` and [`save`] write a new
/// file and rename it over the old one, whose pages the map keeps.
///
/// # Errors
/// As [`load`]'s.
pub unsafe fn load_in_place(path: &Path) -> Result<BuiltScene> {
    let map = std::sync::Arc::new(read::map_file(path)?);
    if instanced::is_instanced(&map) {
        // Its meshes are copied out of the map.
        return instanced::decode(path, &map);
    }
    // SAFETY: passed on to the caller (see above).
    let parts = unsafe { read::read_in_place(path, map) }?;
    validate::assemble(path, parts)
}

/// [`load`] for a file's bytes already in memory; `path` names it in messages.
///
/// # Errors
/// As [`load`]'s.
pub fn from_bytes(path: &Path, bytes: &[u8]) -> Result<BuiltScene> {
    if instanced::is_instanced(bytes) {
        return instanced::decode(path, bytes);
    }
    let parts = read::parse(path, bytes)?;
    validate::assemble(path, parts)
}

/// Whether the file at `path` starts with the `.rpk` magic bytes (false when it cannot be
/// read): a cheap test for loaders that dispatch on content.
pub fn is_rpk(path: &Path) -> bool {
    use std::io::Read;
    let mut head = [0u8; MAGIC.len()];
    crate::io::open_regular(path)
        .ok()
        .and_then(|(mut file, _)| file.read_exact(&mut head).ok())
        .is_some_and(|()| head == MAGIC)
}

/// Whether `path` has the `.rpk` extension (any case).
pub fn has_rpk_extension(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("rpk"))
}
