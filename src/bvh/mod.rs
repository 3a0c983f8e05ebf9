//! The flattened tree: nodes, leaf-ordered triangles, and the map back to scene triangles.
//!
//! Data flow: [`crate::Scene`] -> [`median_cut`] builds -> [`Bvh`] (these exact bytes go to the GPU
//! and to the CPU traversal alike) -> [`validate`] checks the invariants.

pub mod median_cut;
pub mod validate;

pub use median_cut::{BuildOptions, SplitAxis};

use crate::layout::{GpuNode, GpuTriangle, KIND_INNER};
use glam::DVec3;

/// A built, flattened bounding-volume hierarchy over a scene's triangles.
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    /// The f64 world point all f32 coordinates are offsets from.
    pub origin: DVec3,
    /// Nodes in depth-first order; node 0 is the root. Empty for a scene with no hittable triangle.
    pub nodes: Vec<GpuNode>,
    /// Triangles in leaf order.
    pub triangles: Vec<GpuTriangle>,
    /// For each leaf-ordered triangle, its index in the scene's triangle list.
    pub triangle_ids: Vec<u32>,
}

impl Bvh {
    /// Loop iterations the stackless walk may take before it is declared stuck: each node is
    /// entered at most once going down and once coming back up.
    pub fn iteration_cap(&self) -> u32 {
        (self.nodes.len() as u32)
            .saturating_mul(2)
            .saturating_add(2)
    }

    /// Bytes this tree occupies on the GPU (nodes plus triangles).
    pub fn gpu_bytes(&self) -> u64 {
        (std::mem::size_of_val(self.nodes.as_slice())
            + std::mem::size_of_val(self.triangles.as_slice())) as u64
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
