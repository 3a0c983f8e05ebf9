//! The paper's top-down median-cut builder: split each node at the midplane of its box, axes
//! cycling x -> y -> z by depth (or the longest axis), primitives going left or right by centroid,
//! falling back to the centroid median when one side would be empty. The recursion it runs in is
//! `top_down`'s, shared with binned SAH.

use super::top_down::{PrimRef, Split, build_with, median_split, partition};
use super::{BuildOptions, Bvh, SplitAxis};
use crate::error::Result;
use crate::scene::Scene;
use glam::Vec3;

/// Builds the tree over every traceable triangle of `scene` (see [`super::traceable_triangle`]).
pub fn build(scene: &Scene, options: &BuildOptions) -> Result<Bvh> {
    build_with(scene, options, |prims, min, max, depth| {
        (prims.len() > options.leaf_size as usize)
            .then(|| midplane(prims, min, max, depth, options))
    })
}

/// Chooses the axis, partitions `prims` at the midplane of the box, and returns the split (the
/// left part never empty nor everything).
fn midplane(
    prims: &mut [PrimRef],
    min: Vec3,
    max: Vec3,
    depth: u32,
    options: &BuildOptions,
) -> Split {
    let axis = match options.split_axis {
        SplitAxis::Cycle => (depth % 3) as usize,
        SplitAxis::Longest => (max - min).max_position(),
    };
    let mid = 0.5 * (min[axis] + max[axis]);
    let (left, boxes) = partition(prims, |p| p.centroid[axis] < mid);
    if left != 0 && left != prims.len() {
        return Split {
            axis,
            left,
            boxes: Some(boxes),
        };
    }
    // One side is empty: split at the centroid median.
    Split {
        axis,
        left: median_split(prims, axis),
        boxes: None,
    }
}
