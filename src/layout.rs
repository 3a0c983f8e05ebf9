//! The byte layouts shared by the host and `wgsl/pick.wgsl`.
//!
//! These `#[repr(C)]` Pod structs are the only way bytes reach the GPU. Each one has a WGSL twin
//! with the same name; the asserts below pin sizes and offsets at compile time, and
//! `tests/suite/layout.rs` parses the shader with naga and checks the WGSL side against the same numbers.

use bytemuck::{Pod, Zeroable};
use std::mem::{offset_of, size_of};

/// Node kinds `0..=MAX_LEAF_SIZE` are leaves holding that many triangles; `KIND_INNER + axis` is an
/// inner node split along `axis` (0 = x, 1 = y, 2 = z).
pub const KIND_INNER: u32 = 16;
/// The largest leaf the node encoding can hold.
pub const MAX_LEAF_SIZE: u32 = 15;
/// Bits of `parent_kind` that hold the kind; the parent index sits above them.
pub const KIND_BITS: u32 = 5;
/// The largest node index that still fits beside the kind bits.
pub const MAX_NODES: u32 = u32::MAX >> KIND_BITS;
/// `GpuHit::prim` of a ray that hit nothing.
pub const NO_HIT: u32 = u32::MAX;
/// `GpuHit::prim` of a ray whose traversal reached its iteration cap (a corrupted tree).
pub const CAP_REACHED: u32 = u32::MAX - 1;
/// `GpuHit::prim` the kernel writes for a ray whose walk was cut short by the driver, not by
/// the kernel: Mesa's llvmpipe ends every loop of a shader invocation once its lanes together
/// have run 65,535 iterations (`LP_MAX_TGSI_LOOP_ITERATIONS`, shared by all its loops), so
/// several long walks side by side in one group of lanes stopped part way, and their rays
/// missed or hit another triangle. The GPU picker traces such rays again on the twin
/// (`cpu::traverse`), whose answers are the kernel's bit for bit. Hit ids stay below it.
pub const UNFINISHED: u32 = u32::MAX - 2;

/// One node of the flattened median-cut tree, in depth-first order.
///
/// An inner node's left child is the next node (`index + 1`); its right child is `first`.
/// A leaf's triangles are `first .. first + kind` in the triangle buffer. The root is node 0 and
/// is its own parent.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuNode {
    /// Box minimum corner, in scene-local f32 coordinates.
    pub min: [f32; 3],
    /// `parent << KIND_BITS | kind`.
    pub parent_kind: u32,
    /// Box maximum corner.
    pub max: [f32; 3],
    /// Right child (inner node) or first triangle (leaf).
    pub first: u32,
}

/// One triangle, its three vertices as f32 offsets from the scene origin, in leaf order.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuTriangle {
    /// First vertex.
    pub v0: [f32; 3],
    /// Second vertex.
    pub v1: [f32; 3],
    /// Third vertex.
    pub v2: [f32; 3],
}

/// `GpuRay::flags` bits 0–1: the query mode.
pub const MODE_CLOSEST: u32 = 0;
/// Any-hit: stop at the first hit found.
pub const MODE_ANY: u32 = 1;
/// All hits along the ray, nearest first, up to `GpuParams::max_hits`.
pub const MODE_ALL: u32 = 2;
/// `GpuRay::flags` bits 2–3: face culling (shifted by `CULL_SHIFT`).
pub const CULL_SHIFT: u32 = 2;
/// No culling.
pub const CULL_NONE: u32 = 0;
/// Skip back faces (clockwise as seen from the ray).
pub const CULL_BACK: u32 = 1;
/// Skip front faces (counter-clockwise as seen from the ray).
pub const CULL_FRONT: u32 = 2;

/// One ray as the kernel sees it: scene-local origin, unit direction and the (tmin, tmax] range in
/// that unit-direction parameter, its layer mask and its query flags.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuRay {
    /// Origin, relative to the scene origin.
    pub origin: [f32; 3],
    /// Hits must have t > tmin.
    pub tmin: f32,
    /// Unit direction.
    pub dir: [f32; 3],
    /// Hits must have t <= tmax. A ray with tmax < tmin is never tested (invalid rays).
    pub tmax: f32,
    /// Layer mask: only triangles whose object mask shares a bit are hit (when masks are on).
    pub mask: u32,
    /// Query mode (bits 0–1) and culling (bits 2–3).
    pub flags: u32,
    /// What rounding the origin to f32 left off, as three IEEE half floats packed low half
    /// first (`[x | y << 16, z]`): read only in an instanced scene, where each instance's
    /// frame is entered from the origin taken in two parts ([`GpuInstance`]); zero otherwise.
    pub origin_lo: [u32; 2],
}

/// One entry of an all-hits list.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuHitEntry {
    /// Ray parameter.
    pub t: f32,
    /// Leaf-order triangle.
    pub prim: u32,
    /// Barycentric u.
    pub u: f32,
    /// Barycentric v.
    pub v: f32,
}

/// What traversal found for one ray: the nearest triangle (leaf order) and the work it took.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuHit {
    /// Ray parameter of the hit, along the unit direction.
    pub t: f32,
    /// Index into the leaf-ordered triangle buffer, or `NO_HIT` / `CAP_REACHED`.
    pub prim: u32,
    /// Barycentric u (weight of v1).
    pub u: f32,
    /// Barycentric v (weight of v2).
    pub v: f32,
    /// Ray/box tests made (the paper's b).
    pub box_tests: u32,
    /// Ray/triangle tests made (the paper's i).
    pub triangle_tests: u32,
    /// All-hits mode: entries written to this ray's list (at most `max_hits`).
    pub count: u32,
    /// All-hits mode: 1 when the ray had more than `max_hits` hits (the nearest are kept).
    pub overflow: u32,
}

/// Per-dispatch constants.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuParams {
    /// Rays in this dispatch.
    pub ray_count: u32,
    /// Nodes in the tree (0 for an empty scene).
    pub node_count: u32,
    /// Loop iterations after which traversal gives up with `CAP_REACHED`.
    pub iteration_cap: u32,
    /// Rays per row of the 2D dispatch grid (workgroups in x times the workgroup size).
    pub row_pitch: u32,
    /// All-hits list length per ray (0 when no ray uses `MODE_ALL`).
    pub max_hits: u32,
    /// 1 when the triangle mask buffer holds real masks (0: every triangle matches every ray).
    pub use_masks: u32,
    /// 1 for the watertight ray/triangle test (Woop, Benthin, Wald 2013), 0 for Möller–Trumbore.
    pub watertight: u32,
    /// Nodes of the top tree over instances, at the start of the node buffer (0: a scene
    /// without instances, one tree over its triangles).
    pub top_nodes: u32,
    /// Zeros, which the shader compiler cannot see: the kernel ORs each product that meets an
    /// add with them (through its bits), so no product is fused into a multiply-add and every
    /// answer keeps the twin's rounding (`mul` in `wgsl/pick.wgsl`). WGSL: a `vec3<u32>`.
    pub opaque: [u32; 3],
    /// Padding to 16 bytes.
    pub pad: u32,
}

/// `GpuInstance::flags` bit 0: the instance's transform mirrors (a negative determinant). The
/// kernel culls in the mesh's frame as it is (what is front there is front in the world, once
/// the world winding is swapped back, as the host does when it refines the hit).
pub const INSTANCE_MIRRORED: u32 = 1;

/// One instance of a mesh, as the kernel enters it from a leaf of the top tree (whose `first`
/// is the instance's index): the map from the scene frame into the mesh's own f32 frame, the
/// mesh's bottom tree, and what hits on it report.
///
/// A scene-frame point `p` (split as `p_hi + p_lo`, [`GpuRay::origin_lo`]) goes to the mesh
/// frame as `L·((p_hi − c_hi) + (p_lo − c_lo))`, a direction `d` as `L·d`, where `L` (rows
/// `l0`, `l1`, `l2`) is the inverse of the instance's linear part and `c = c_hi + c_lo` is
/// where the mesh's origin lands in the scene frame, both worked out in f64 on the host. The
/// ray parameter `t` is the same in both frames.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuInstance {
    /// First row of `L`.
    pub l0: [f32; 3],
    /// `c_hi.x`.
    pub cx: f32,
    /// Second row of `L`.
    pub l1: [f32; 3],
    /// `c_hi.y`.
    pub cy: f32,
    /// Third row of `L`.
    pub l2: [f32; 3],
    /// `c_hi.z`.
    pub cz: f32,
    /// `c_lo`.
    pub c_lo: [f32; 3],
    /// The bottom tree's root node, in the shared node buffer.
    pub root: u32,
    /// The hit id of the instance's triangle 0: a hit on file-order triangle `k` of the mesh
    /// reports `prim = prim_base + k` (ids run on instance after instance, so the tie rule
    /// needs no lookup).
    pub prim_base: u32,
    /// Layer mask: rays hit the instance only when their mask shares a bit with it.
    pub mask: u32,
    /// [`INSTANCE_MIRRORED`].
    pub flags: u32,
    /// The mesh it places (an index into the scene's meshes): the CPU engine walks that mesh's
    /// wide tree from it. The kernel and the twin start from `root` instead.
    pub mesh: u32,
}

/// One shared struct's name, size and `(member, offset)` list.
pub type StructLayout = (&'static str, usize, &'static [(&'static str, usize)]);

/// Expected layout of each shared struct; `tests/suite/layout.rs` checks the WGSL against it.
pub const SHARED_LAYOUTS: &[StructLayout] = &[
    (
        "GpuNode",
        size_of::<GpuNode>(),
        &[
            ("min", offset_of!(GpuNode, min)),
            ("parent_kind", offset_of!(GpuNode, parent_kind)),
            ("max", offset_of!(GpuNode, max)),
            ("first", offset_of!(GpuNode, first)),
        ],
    ),
    (
        "GpuTriangle",
        size_of::<GpuTriangle>(),
        &[
            ("v0", offset_of!(GpuTriangle, v0)),
            ("v1", offset_of!(GpuTriangle, v1)),
            ("v2", offset_of!(GpuTriangle, v2)),
        ],
    ),
    (
        "GpuRay",
        size_of::<GpuRay>(),
        &[
            ("origin", offset_of!(GpuRay, origin)),
            ("tmin", offset_of!(GpuRay, tmin)),
            ("dir", offset_of!(GpuRay, dir)),
            ("tmax", offset_of!(GpuRay, tmax)),
            ("mask", offset_of!(GpuRay, mask)),
            ("flags", offset_of!(GpuRay, flags)),
            ("origin_lo", offset_of!(GpuRay, origin_lo)),
        ],
    ),
    (
        "GpuHitEntry",
        size_of::<GpuHitEntry>(),
        &[
            ("t", offset_of!(GpuHitEntry, t)),
            ("prim", offset_of!(GpuHitEntry, prim)),
            ("u", offset_of!(GpuHitEntry, u)),
            ("v", offset_of!(GpuHitEntry, v)),
        ],
    ),
    (
        "GpuHit",
        size_of::<GpuHit>(),
        &[
            ("t", offset_of!(GpuHit, t)),
            ("prim", offset_of!(GpuHit, prim)),
            ("u", offset_of!(GpuHit, u)),
            ("v", offset_of!(GpuHit, v)),
            ("box_tests", offset_of!(GpuHit, box_tests)),
            ("triangle_tests", offset_of!(GpuHit, triangle_tests)),
            ("count", offset_of!(GpuHit, count)),
            ("overflow", offset_of!(GpuHit, overflow)),
        ],
    ),
    (
        "GpuParams",
        size_of::<GpuParams>(),
        &[
            ("ray_count", offset_of!(GpuParams, ray_count)),
            ("node_count", offset_of!(GpuParams, node_count)),
            ("iteration_cap", offset_of!(GpuParams, iteration_cap)),
            ("row_pitch", offset_of!(GpuParams, row_pitch)),
            ("max_hits", offset_of!(GpuParams, max_hits)),
            ("use_masks", offset_of!(GpuParams, use_masks)),
            ("watertight", offset_of!(GpuParams, watertight)),
            ("top_nodes", offset_of!(GpuParams, top_nodes)),
            ("opaque", offset_of!(GpuParams, opaque)),
            ("pad", offset_of!(GpuParams, pad)),
        ],
    ),
    (
        "GpuInstance",
        size_of::<GpuInstance>(),
        &[
            ("l0", offset_of!(GpuInstance, l0)),
            ("cx", offset_of!(GpuInstance, cx)),
            ("l1", offset_of!(GpuInstance, l1)),
            ("cy", offset_of!(GpuInstance, cy)),
            ("l2", offset_of!(GpuInstance, l2)),
            ("cz", offset_of!(GpuInstance, cz)),
            ("c_lo", offset_of!(GpuInstance, c_lo)),
            ("root", offset_of!(GpuInstance, root)),
            ("prim_base", offset_of!(GpuInstance, prim_base)),
            ("mask", offset_of!(GpuInstance, mask)),
            ("flags", offset_of!(GpuInstance, flags)),
            ("mesh", offset_of!(GpuInstance, mesh)),
        ],
    ),
];

const _: () = {
    assert!(size_of::<GpuNode>() == 32);
    assert!(offset_of!(GpuNode, parent_kind) == 12);
    assert!(offset_of!(GpuNode, max) == 16);
    assert!(offset_of!(GpuNode, first) == 28);
    assert!(size_of::<GpuTriangle>() == 36);
    assert!(offset_of!(GpuTriangle, v1) == 12);
    assert!(offset_of!(GpuTriangle, v2) == 24);
    assert!(size_of::<GpuRay>() == 48);
    assert!(offset_of!(GpuRay, tmin) == 12);
    assert!(offset_of!(GpuRay, dir) == 16);
    assert!(offset_of!(GpuRay, tmax) == 28);
    assert!(offset_of!(GpuRay, mask) == 32);
    assert!(offset_of!(GpuRay, flags) == 36);
    assert!(size_of::<GpuHitEntry>() == 16);
    assert!(size_of::<GpuHit>() == 32);
    assert!(offset_of!(GpuHit, box_tests) == 16);
    assert!(offset_of!(GpuHit, count) == 24);
    assert!(size_of::<GpuParams>() == 48);
    assert!(offset_of!(GpuParams, pad) == 44);
    assert!(offset_of!(GpuParams, max_hits) == 16);
    assert!(size_of::<GpuInstance>() == 80);
    assert!(offset_of!(GpuInstance, c_lo) == 48);
    assert!(offset_of!(GpuInstance, prim_base) == 64);
    assert!(MAX_LEAF_SIZE < KIND_INNER);
    assert!(KIND_INNER + 2 < (1 << KIND_BITS));
};

impl GpuNode {
    /// The node's kind field: a leaf's triangle count, or `KIND_INNER + axis`.
    pub fn kind(&self) -> u32 {
        self.parent_kind & ((1 << KIND_BITS) - 1)
    }
    /// Index of the parent node (the root is its own parent).
    pub fn parent(&self) -> u32 {
        self.parent_kind >> KIND_BITS
    }
    /// Whether this node is a leaf.
    pub fn is_leaf(&self) -> bool {
        self.kind() < KIND_INNER
    }
}
