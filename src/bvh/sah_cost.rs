//! The surface-area-heuristic cost model: the expected work of one ray through a tree, counted
//! in triangle tests, when a ray reaches each node with a probability proportional to the
//! node box's surface area. The binned-SAH builder minimises it node by node; [`sah_cost`]
//! scores any built tree with it, so median-cut and SAH trees compare on one number.

use super::Bvh;
use crate::layout::GpuNode;
use glam::Vec3;

/// Cost of one traversal step into an inner node, relative to one triangle test. In our kernel
/// a step is two child-box tests, and a box test costs about a triangle test (both a few f32
/// operations on ~32 bytes fetched). Measured against 1 and 4 on bunny, dragon, terrain and soup
/// (leaf size 4): 1 gives 1.5× the nodes and more box tests, 4 the same box and triangle tests
/// as 2 within a few percent.
pub const TRAVERSAL_COST: f64 = 2.0;
/// Cost of one ray/triangle test: the unit of the model.
pub const TRIANGLE_COST: f64 = 1.0;

/// Half the surface area of the box `min ..= max` (the factor 2 cancels in every ratio).
pub fn half_area(min: Vec3, max: Vec3) -> f32 {
    let d = (max - min).max(Vec3::ZERO);
    d.x * d.y + d.y * d.z + d.z * d.x
}

fn node_half_area(node: &GpuNode) -> f64 {
    f64::from(half_area(node.min.into(), node.max.into()))
}

/// The SAH cost of `bvh`: over inner nodes, area(node) / area(root) · [`TRAVERSAL_COST`], plus
/// over leaves, area(leaf) / area(root) · triangles · [`TRIANGLE_COST`]. 0 for an empty tree. A
/// root box with no area (no real tree has one) counts every node as reached.
pub fn sah_cost(bvh: &Bvh) -> f64 {
    let Some(root) = bvh.nodes.first() else {
        return 0.0;
    };
    let root_area = node_half_area(root);
    let reach = |node: &GpuNode| {
        if root_area > 0.0 {
            node_half_area(node) / root_area
        } else {
            1.0
        }
    };
    bvh.nodes
        .iter()
        .map(|node| {
            if node.is_leaf() {
                reach(node) * f64::from(node.kind()) * TRIANGLE_COST
            } else {
                reach(node) * TRAVERSAL_COST
            }
        })
        .sum()
}
