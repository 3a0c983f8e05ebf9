//! The flattened tree: nodes, leaf-ordered triangles, the map back to scene triangles, and the
//! pieces every builder shares.
//!
//! Data flow: [`crate::Scene`] -> a builder ([`median_cut`], [`binned_sah`], or
//! [`terrain_blocks`] for a height grid; [`sah_cost`] rates any tree) -> [`Bvh`] (these exact bytes go to the GPU and to the CPU traversal alike) ->
//! [`validate`] checks the invariants.

pub mod binned_sah;
pub mod lost;
pub mod median_cut;
pub mod options;
mod refit;
pub(crate) use refit::bounds;
pub mod sah_cost;
pub mod terrain_blocks;
mod top_down;
pub mod validate;

pub use lost::{Lost, lost_triangles};
pub use options::{BuildOptions, Builder, SplitAxis};
pub use terrain_blocks::Block;

use crate::error::{Error, Result};
use crate::layout::{GpuNode, GpuTriangle, KIND_BITS, KIND_INNER, MAX_LEAF_SIZE, MAX_NODES};
use crate::scene::Scene;
use crate::store::Store;
use glam::{DVec3, Vec3};

/// A built, flattened bounding-volume hierarchy over a scene's triangles.
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    /// The f64 world point all f32 coordinates are offsets from.
    pub origin: DVec3,
    /// Nodes in depth-first order; node 0 is the root. Empty for a scene with no hittable triangle.
    pub nodes: Store<GpuNode>,
    /// Triangles in leaf order.
    pub triangles: Store<GpuTriangle>,
    /// For each leaf-ordered triangle, its index in the scene's triangle list.
    pub triangle_ids: Store<u32>,
    /// The terrain blocks the top of the tree is built over (grid builder only; empty otherwise).
    pub blocks: Vec<Block>,
}

/// What a build holds at its peak, per triangle, beyond the scene: the builder's working
/// arrays, the flattened tree and its leaf-order triangles, the engine's collapse. Measured as
/// the peak resident memory of `raypick pick` over 4.5M and 10M triangles, less the scene and
/// the file, rounded up (grid 67, median cut 119–132, binned SAH 166 bytes): checked against the
/// memory budget before a build, which on a 4000 × 4000 grid (32M triangles) aborted the
/// process when an allocation failed, `--max-memory` or not.
const BUILD_BYTES_GRID: u64 = 80;
/// [`BUILD_BYTES_GRID`] for median cut.
const BUILD_BYTES_MEDIAN_CUT: u64 = 144;
/// [`BUILD_BYTES_GRID`] for binned SAH.
const BUILD_BYTES_SAH: u64 = 176;

impl Bvh {
    /// Builds the tree over every traceable triangle of `scene` with the builder `options` name.
    /// An [`Error::OverBudget`](crate::Error::OverBudget) when what the build holds at its peak
    /// ([`BUILD_BYTES_GRID`] and the others, per triangle) is over the memory budget
    /// ([`crate::budget`]), after the options themselves are checked.
    pub fn build(scene: &Scene, options: &BuildOptions) -> Result<Bvh> {
        // What is wrong with the options is said first (a grid builder asked of a scene that
        // is not one grid, a leaf size out of range).
        check_leaf_size(options)?;
        let one_grid = terrain_blocks::single_grid(scene).is_some();
        if options.builder == Builder::Grid && !one_grid {
            return terrain_blocks::build(scene, options);
        }
        let grid = match options.builder {
            Builder::Grid => true,
            Builder::Auto => one_grid,
            Builder::MedianCut | Builder::BinnedSah => false,
        };
        let bytes = match options.builder {
            _ if grid => BUILD_BYTES_GRID,
            Builder::BinnedSah => BUILD_BYTES_SAH,
            _ => BUILD_BYTES_MEDIAN_CUT,
        };
        let what = match scene.objects() {
            [] => "building the tree".to_owned(),
            [one] => format!("building the tree over the triangles of {}", one.name),
            [first, other] => format!(
                "building the tree over the triangles of {} and {}",
                first.name, other.name
            ),
            [first, rest @ ..] => format!(
                "building the tree over the triangles of {} and {} other objects",
                first.name,
                rest.len()
            ),
        };
        crate::budget::check(&what, scene.triangle_count() as u64, bytes)?;
        match options.builder {
            _ if grid => terrain_blocks::build(scene, options),
            Builder::BinnedSah => binned_sah::build(scene, options),
            _ => median_cut::build(scene, options),
        }
    }

    /// Loop iterations the stackless walk may take before it is declared stuck: each node is
    /// entered at most once going down and once coming back up.
    pub fn iteration_cap(&self) -> u32 {
        (self.nodes.len() as u32)
            .saturating_mul(2)
            .saturating_add(2)
    }

    /// Bytes this tree occupies on the GPU (nodes, triangles, and the scene triangle ids the
    /// kernel's tie rule reads).
    pub fn gpu_bytes(&self) -> u64 {
        (std::mem::size_of_val(self.nodes.as_slice())
            + std::mem::size_of_val(self.triangles.as_slice())
            + std::mem::size_of_val(self.triangle_ids.as_slice())) as u64
    }

    /// Tree depth (a single leaf has depth 1); 0 for an empty tree.
    pub fn depth(&self) -> usize {
        fn walk(nodes: &[GpuNode], i: usize) -> usize {
            let n = &nodes[i];
            if n.kind() < KIND_INNER {
                1
            } else {
                1 + walk(nodes, i + 1).max(walk(nodes, n.first as usize))
            }
        }
        if self.nodes.is_empty() {
            0
        } else {
            walk(&self.nodes, 0)
        }
    }

    /// Number of leaves.
    pub fn leaf_count(&self) -> usize {
        self.nodes.iter().filter(|n| n.is_leaf()).count()
    }
}

/// Every scene vertex as an f32 offset from `origin`, in scene order. Each vertex is rounded
/// once here, so a triangle's corners are the same bits in every triangle that shares them.
pub(crate) fn local_positions(scene: &Scene, origin: DVec3) -> Vec<Vec3> {
    use rayon::prelude::*;
    let mut local = Vec::new();
    (0..scene.vertex_count())
        .into_par_iter()
        .map(|i| (scene.position(i) - origin).as_vec3())
        .collect_into_vec(&mut local);
    local
}

/// Whether every vertex of `scene` has a finite f32 offset from `origin` (then no triangle
/// needs [`is_traceable`]'s check of its own offsets): the bounds' corners' offsets are, and
/// rounding is monotone.
pub(crate) fn frame_holds(scene: &Scene, origin: DVec3) -> bool {
    scene.bounds().is_none_or(|(lo, hi)| {
        (lo - origin)
            .abs()
            .max((hi - origin).abs())
            .as_vec3()
            .is_finite()
    })
}

/// Scene triangle `index` as f32 offsets (from [`local_positions`]), or `None` when it can
/// never be hit (see [`is_traceable`]; `holds`: [`frame_holds`]).
pub(crate) fn traceable_triangle(
    scene: &Scene,
    local_positions: &[Vec3],
    index: usize,
    holds: bool,
) -> Option<[Vec3; 3]> {
    let local = scene
        .triangle_vertices(index)
        .map(|v| local_positions[v as usize]);
    is_traceable(scene, index, local, holds).then_some(local)
}

/// Whether scene triangle `index`, whose f32 offsets are `local`, can be hit: not zero area in
/// f64 and not zero area once rounded to f32, its offsets finite (in a scene too wide for f32
/// offsets no ray could reach it; `holds`: the frame holds every offset, [`frame_holds`]).
/// Other triangles are left out of every tree and keep their ids.
pub(crate) fn is_traceable(scene: &Scene, index: usize, local: [Vec3; 3], holds: bool) -> bool {
    (holds || local.iter().all(|p| p.is_finite()))
        && traceable_corners(scene.world_triangle(index), local)
}

/// [`is_traceable`] for a triangle with world corners `world` and f32 offsets `local`: neither
/// has zero area (`Scene::is_degenerate`'s test on the world corners). Offsets that are not
/// finite are the caller's to find ([`is_traceable`]; the refit, in its root's box).
#[inline]
pub(crate) fn traceable_corners(world: [DVec3; 3], [a, b, c]: [Vec3; 3]) -> bool {
    // The edges are f32 differences, as the kernel forms them, widened for the cross product.
    let f32_area_zero = crate::scene::cross_is_zero((b - a).as_dvec3(), (c - a).as_dvec3());
    !f32_area_zero && !crate::scene::zero_area(world)
}

/// Scene triangle `index` as the kernel stores it: f32 offsets (from [`local_positions`]).
pub(crate) fn local_triangle(scene: &Scene, local_positions: &[Vec3], index: usize) -> GpuTriangle {
    let [v0, v1, v2] = scene
        .triangle_vertices(index)
        .map(|v| local_positions[v as usize]);
    GpuTriangle {
        v0: v0.into(),
        v1: v1.into(),
        v2: v2.into(),
    }
}

/// A leaf holding `count` triangles from leaf-order index `first`.
pub(crate) fn leaf_node(min: Vec3, max: Vec3, count: u32, first: u32) -> GpuNode {
    GpuNode {
        min: min.into(),
        parent_kind: count,
        max: max.into(),
        first,
    }
}

/// An inner node split along `axis` whose right child is node `right` (the left one is next).
pub(crate) fn inner_node(min: Vec3, max: Vec3, axis: usize, right: u32) -> GpuNode {
    GpuNode {
        min: min.into(),
        parent_kind: KIND_INNER + axis as u32,
        max: max.into(),
        first: right,
    }
}

/// Refuses a leaf size the node format cannot hold (every builder checks it first).
pub(crate) fn check_leaf_size(options: &BuildOptions) -> Result<()> {
    if !(1..=MAX_LEAF_SIZE).contains(&options.leaf_size) {
        return Err(Error::Invalid(format!(
            "leaf size {} is out of range; it must be 1 ..= {MAX_LEAF_SIZE}",
            options.leaf_size
        )));
    }
    Ok(())
}

/// Refuses a tree with more nodes than the 27-bit parent links can address.
pub(crate) fn check_node_count(nodes: usize) -> Result<()> {
    if nodes > MAX_NODES as usize {
        return Err(Error::Invalid(format!(
            "the tree needs {nodes} nodes, more than the {MAX_NODES} the node format can address; raise the leaf size"
        )));
    }
    Ok(())
}

/// Fills in each node's parent index (the root is its own parent).
pub(crate) fn link_parents(nodes: &mut [GpuNode]) {
    for i in 0..nodes.len() {
        let n = nodes[i];
        if !n.is_leaf() {
            for child in [i + 1, n.first as usize] {
                let kind = nodes[child].kind();
                nodes[child].parent_kind = (i as u32) << KIND_BITS | kind;
            }
        }
    }
}
