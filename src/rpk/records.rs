//! The byte encodings of the format's fixed-size records, little-endian field by field: the
//! file header, the section header, the summary, an object and a terrain block.
//! [`super::write`] and [`super::read`] both go through these, so the two sides cannot drift.
//! (Arrays of Pod elements — vertices, triangles, nodes, ids, masks and wide nodes — are
//! stored as they lie in memory.)

use super::{HEADER_BYTES, MAGIC, SECTION_HEADER_BYTES};
use crate::bvh::Block;
use crate::engine::wide::WideNode;
use glam::DVec3;

/// Bytes of the summary record.
pub const SUMMARY_BYTES: usize = 128;
/// Bytes of an object record.
pub const OBJECT_BYTES: usize = 40;
/// Bytes of a block record.
pub const BLOCK_BYTES: usize = 104;
/// Bytes of a wide node ([`WideNode`], stored as it lies in memory).
pub const WIDE_NODE_BYTES: usize = 256;

/// Appends little-endian fields to a byte vector.
#[derive(Debug, Default)]
pub struct Out(pub Vec<u8>);

impl Out {
    /// Appends a u32.
    pub fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    /// Appends a u64.
    pub fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    /// Appends x, y, z as f64.
    pub fn dvec3(&mut self, v: DVec3) {
        for c in v.to_array() {
            self.0.extend_from_slice(&c.to_le_bytes());
        }
    }
}

/// Reads little-endian fields from a record whose length was checked first.
#[derive(Debug)]
pub struct In<'a>(pub &'a [u8]);

impl In<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let (head, rest) = self.0.split_at(N);
        self.0 = rest;
        head.try_into().expect("split_at gave N bytes")
    }
    /// Reads a u32.
    pub fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    /// Reads a u64.
    pub fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }
    /// Reads x, y, z as f64.
    pub fn dvec3(&mut self) -> DVec3 {
        let mut c = [0.0; 3];
        for v in &mut c {
            *v = f64::from_le_bytes(self.take());
        }
        DVec3::from_array(c)
    }
}

/// The file header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    /// Format version.
    pub version: u32,
    /// Number of sections.
    pub sections: u32,
    /// Length of the whole file.
    pub file_length: u64,
}

impl Header {
    /// The header's 32 bytes, checksum included.
    pub fn encode(&self) -> [u8; HEADER_BYTES] {
        let mut out = Out(Vec::with_capacity(HEADER_BYTES));
        out.0.extend_from_slice(&MAGIC);
        out.u32(self.version);
        out.u32(self.sections);
        out.u64(self.file_length);
        out.u32(0);
        let crc = crc32fast::hash(&out.0);
        out.u32(crc);
        out.0.try_into().expect("32 header bytes")
    }

    /// Reads a header whose magic was checked: the header, or `None` when its checksum or its
    /// reserved field is wrong.
    pub fn decode(bytes: &[u8; HEADER_BYTES]) -> Option<Header> {
        let mut r = In(&bytes[MAGIC.len()..]);
        let header = Header {
            version: r.u32(),
            sections: r.u32(),
            file_length: r.u64(),
        };
        let reserved = r.u32();
        let crc = r.u32();
        (reserved == 0 && crc == crc32fast::hash(&bytes[..HEADER_BYTES - 4])).then_some(header)
    }
}

/// A section header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SectionHeader {
    /// The section's kind.
    pub tag: [u8; 4],
    /// CRC-32 of the payload.
    pub crc: u32,
    /// Payload bytes (padding not included).
    pub length: u64,
}

impl SectionHeader {
    /// The section header's 16 bytes.
    pub fn encode(&self) -> [u8; SECTION_HEADER_BYTES] {
        let mut out = Out(Vec::with_capacity(SECTION_HEADER_BYTES));
        out.0.extend_from_slice(&self.tag);
        out.u32(self.crc);
        out.u64(self.length);
        out.0.try_into().expect("16 section header bytes")
    }

    /// Reads a section header.
    pub fn decode(bytes: &[u8; SECTION_HEADER_BYTES]) -> SectionHeader {
        let mut r = In(bytes);
        SectionHeader {
            tag: r.take(),
            crc: r.u32(),
            length: r.u64(),
        }
    }
}

/// The summary: every count and the two origins.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Summary {
    /// Scene vertices.
    pub vertices: u64,
    /// Scene triangles.
    pub triangles: u64,
    /// Objects.
    pub objects: u64,
    /// Bytes of all object names.
    pub name_bytes: u64,
    /// Nodes of the kernel's tree.
    pub nodes: u64,
    /// Leaf-order triangles (and scene triangle ids).
    pub leaf_triangles: u64,
    /// Terrain blocks.
    pub blocks: u64,
    /// Nodes of the wide tree.
    pub wide_nodes: u64,
    /// Depth of the wide tree.
    pub wide_depth: u64,
    /// Per-triangle masks (0, or one per leaf-order triangle).
    pub masks: u64,
    /// The scene's origin (the centre of its bounds).
    pub scene_origin: DVec3,
    /// The tree's origin.
    pub tree_origin: DVec3,
}

impl Summary {
    /// The record's bytes.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Out(Vec::with_capacity(SUMMARY_BYTES));
        for n in self.counts() {
            out.u64(n);
        }
        out.dvec3(self.scene_origin);
        out.dvec3(self.tree_origin);
        debug_assert_eq!(out.0.len(), SUMMARY_BYTES);
        out.0
    }

    /// Reads the record (`bytes` is [`SUMMARY_BYTES`] long).
    pub fn decode(bytes: &[u8]) -> Summary {
        let mut r = In(bytes);
        Summary {
            vertices: r.u64(),
            triangles: r.u64(),
            objects: r.u64(),
            name_bytes: r.u64(),
            nodes: r.u64(),
            leaf_triangles: r.u64(),
            blocks: r.u64(),
            wide_nodes: r.u64(),
            wide_depth: r.u64(),
            masks: r.u64(),
            scene_origin: r.dvec3(),
            tree_origin: r.dvec3(),
        }
    }

    fn counts(&self) -> [u64; 10] {
        [
            self.vertices,
            self.triangles,
            self.objects,
            self.name_bytes,
            self.nodes,
            self.leaf_triangles,
            self.blocks,
            self.wide_nodes,
            self.wide_depth,
            self.masks,
        ]
    }
}

/// An object as stored: the scene's [`crate::scene::Object`] with its name's length in place
/// of the name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ObjectRecord {
    /// Object id.
    pub id: u32,
    /// First scene triangle.
    pub first_triangle: u32,
    /// Number of triangles.
    pub triangle_count: u32,
    /// First scene vertex.
    pub first_vertex: u32,
    /// Layer mask.
    pub mask: u32,
    /// 1 for a height grid, 0 otherwise (any other value is refused).
    pub has_grid: u32,
    /// Grid columns (0 without a grid).
    pub columns: u32,
    /// Grid rows (0 without a grid).
    pub rows: u32,
    /// Bytes of the name in the names section.
    pub name_length: u32,
    /// Bit 0: the object is mirrored (`Object::mirrored`); the other bits are zero.
    pub flags: u32,
}

impl ObjectRecord {
    /// Appends the record's bytes.
    pub fn encode(&self, out: &mut Out) {
        for v in [
            self.id,
            self.first_triangle,
            self.triangle_count,
            self.first_vertex,
            self.mask,
            self.has_grid,
            self.columns,
            self.rows,
            self.name_length,
            self.flags,
        ] {
            out.u32(v);
        }
    }

    /// Reads a record ([`OBJECT_BYTES`] long).
    pub fn decode(bytes: &[u8]) -> ObjectRecord {
        let mut r = In(bytes);
        ObjectRecord {
            id: r.u32(),
            first_triangle: r.u32(),
            triangle_count: r.u32(),
            first_vertex: r.u32(),
            mask: r.u32(),
            has_grid: r.u32(),
            columns: r.u32(),
            rows: r.u32(),
            name_length: r.u32(),
            flags: r.u32(),
        }
    }
}

/// Appends a terrain block's bytes.
pub fn encode_block(block: &Block, out: &mut Out) {
    for v in [
        block.rows.start,
        block.rows.end,
        block.cols.start,
        block.cols.end,
        block.node,
        block.triangles.start,
        block.triangles.end,
        0,
    ] {
        out.u32(v);
    }
    out.dvec3(block.min);
    out.dvec3(block.max);
    out.dvec3(block.origin);
}

/// Reads a terrain block ([`BLOCK_BYTES`] long); `None` when its reserved field is not zero.
pub fn decode_block(bytes: &[u8]) -> Option<Block> {
    let mut r = In(bytes);
    let (rows, cols) = (r.u32()..r.u32(), r.u32()..r.u32());
    let node = r.u32();
    let triangles = r.u32()..r.u32();
    let reserved = r.u32();
    let block = Block {
        rows,
        cols,
        node,
        triangles,
        min: r.dvec3(),
        max: r.dvec3(),
        origin: r.dvec3(),
    };
    (reserved == 0).then_some(block)
}

const _: () = assert!(size_of::<WideNode>() == WIDE_NODE_BYTES);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_round_trip_at_their_sizes() {
        let summary = Summary {
            vertices: 1,
            triangles: 2,
            objects: 3,
            name_bytes: 4,
            nodes: 5,
            leaf_triangles: 6,
            blocks: 7,
            wide_nodes: 8,
            wide_depth: 9,
            masks: 10,
            scene_origin: DVec3::new(1.5, -2.0, 3e9),
            tree_origin: DVec3::new(-0.0, 7.0, 8.0),
        };
        let bytes = summary.encode();
        assert_eq!(bytes.len(), SUMMARY_BYTES);
        assert_eq!(Summary::decode(&bytes), summary);

        let mut out = Out::default();
        let object = ObjectRecord {
            id: 1,
            first_triangle: 2,
            triangle_count: 3,
            first_vertex: 4,
            mask: 5,
            has_grid: 1,
            columns: 7,
            rows: 8,
            name_length: 9,
            flags: 1,
        };
        object.encode(&mut out);
        assert_eq!(out.0.len(), OBJECT_BYTES);
        assert_eq!(ObjectRecord::decode(&out.0), object);

        let block = Block {
            rows: 0..64,
            cols: 64..100,
            min: DVec3::splat(-1.0),
            max: DVec3::splat(2.0),
            origin: DVec3::splat(0.5),
            node: 17,
            triangles: 8..9000,
        };
        let mut out = Out::default();
        encode_block(&block, &mut out);
        assert_eq!(out.0.len(), BLOCK_BYTES);
        assert_eq!(decode_block(&out.0), Some(block));

        let header = Header {
            version: 1,
            sections: 11,
            file_length: 12345,
        };
        let bytes = header.encode();
        assert_eq!(&bytes[..8], &MAGIC);
        assert_eq!(Header::decode(&bytes), Some(header));
        let mut flipped = bytes;
        flipped[17] ^= 4;
        assert_eq!(Header::decode(&flipped), None);
    }
}
