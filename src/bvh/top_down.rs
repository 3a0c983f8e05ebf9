//! What the triangle builders share, so that each is just a split rule: the primitive they
//! sort (`PrimRef`), the rule's signature (`SplitRule`), the top-down recursion that builds
//! depth-first nodes with large ranges as parallel rayon tasks and stitches them in a fixed
//! order (`build_with`), the in-place partition and the centroid-median fallback. Median cut
//! (`median_cut`) and binned SAH (`binned_sah`) are peers over it.
//!
//! The result is deterministic: the partition depends only on the input order, and parallel
//! subtrees are stitched together in a fixed order.

use super::{
    BuildOptions, Bvh, check_leaf_size, check_node_count, inner_node, leaf_node, link_parents,
    local_triangle, traceable_triangle,
};
use crate::error::Result;
use crate::layout::GpuNode;
use crate::scene::Scene;
use glam::Vec3;
use rayon::prelude::*;

/// Ranges at least this long are split into two parallel tasks.
pub(super) const PARALLEL_MIN: usize = 8 * 1024;

/// One triangle as the builder sorts it.
#[derive(Clone, Copy, Debug)]
pub(super) struct PrimRef {
    pub(super) min: Vec3,
    pub(super) max: Vec3,
    pub(super) centroid: Vec3,
    pub(super) scene_index: u32,
}

/// How a triangle builder decides a node over `prims` (box `min ..= max`, at `depth`): `None`
/// keeps it a leaf (it must then hold at most the leaf size); otherwise it partitions `prims` and
/// returns the split axis and the size of the left part (never 0 or `prims.len()`).
pub(super) trait SplitRule:
    Fn(&mut [PrimRef], Vec3, Vec3, u32) -> Option<(usize, usize)> + Sync
{
}

impl<F: Fn(&mut [PrimRef], Vec3, Vec3, u32) -> Option<(usize, usize)> + Sync> SplitRule for F {}

/// What the triangle builders (median cut, binned SAH) share: checks the leaf size, gathers the
/// traceable triangles, builds the depth-first nodes top down with `rule` deciding each node
/// (large ranges as parallel tasks), then checks the node limit, links parents and lays out the
/// leaf-ordered triangles.
pub(super) fn build_with(
    scene: &Scene,
    options: &BuildOptions,
    rule: impl SplitRule,
) -> Result<Bvh> {
    check_leaf_size(options)?;
    let origin = scene.origin();
    let mut prims: Vec<PrimRef> = (0..scene.triangle_count())
        .into_par_iter()
        .filter_map(|i| {
            let [a, b, c] = traceable_triangle(scene, origin, i)?;
            Some(PrimRef {
                min: a.min(b).min(c),
                max: a.max(b).max(c),
                centroid: (a + b + c) / 3.0,
                scene_index: i as u32,
            })
        })
        .collect();
    if prims.is_empty() {
        return Ok(Bvh {
            origin,
            ..Bvh::default()
        });
    }
    let mut nodes = build_subtree(&mut prims, 0, 0, &rule, options.leaf_size);
    check_node_count(nodes.len())?;
    link_parents(&mut nodes);
    let triangles = prims
        .par_iter()
        .map(|p| local_triangle(scene, origin, p.scene_index as usize))
        .collect();
    let triangle_ids = prims.iter().map(|p| p.scene_index).collect();
    Ok(Bvh {
        origin,
        nodes,
        triangles,
        triangle_ids,
        blocks: Vec::new(),
    })
}

/// Builds the subtree over `prims` (which start at leaf-order index `first`) in depth-first order,
/// with child links relative to the subtree's root. Large ranges split into parallel tasks.
fn build_subtree(
    prims: &mut [PrimRef],
    first: u32,
    depth: u32,
    rule: &impl SplitRule,
    leaf_size: u32,
) -> Vec<GpuNode> {
    if prims.len() < PARALLEL_MIN {
        let mut nodes = Vec::with_capacity(2 * prims.len() / leaf_size as usize + 1);
        build_into(&mut nodes, prims, first, depth, rule);
        return nodes;
    }
    let (min, max) = bounds(prims);
    let Some((axis, left_count)) = rule(prims, min, max, depth) else {
        return vec![leaf_node(min, max, prims.len() as u32, first)];
    };
    let (left_prims, right_prims) = prims.split_at_mut(left_count);
    let (left, right) = rayon::join(
        || build_subtree(left_prims, first, depth + 1, rule, leaf_size),
        || {
            build_subtree(
                right_prims,
                first + left_count as u32,
                depth + 1,
                rule,
                leaf_size,
            )
        },
    );
    let mut nodes = Vec::with_capacity(1 + left.len() + right.len());
    nodes.push(inner_node(min, max, axis, 1 + left.len() as u32));
    append_shifted(&mut nodes, &left);
    append_shifted(&mut nodes, &right);
    nodes
}

/// Sequential build of one subtree, appended to `nodes` with links relative to `nodes[0]`.
fn build_into(
    nodes: &mut Vec<GpuNode>,
    prims: &mut [PrimRef],
    first: u32,
    depth: u32,
    rule: &impl SplitRule,
) {
    let (min, max) = bounds(prims);
    let Some((axis, left_count)) = rule(prims, min, max, depth) else {
        nodes.push(leaf_node(min, max, prims.len() as u32, first));
        return;
    };
    let here = nodes.len();
    nodes.push(inner_node(min, max, axis, 0));
    let (left, right) = prims.split_at_mut(left_count);
    build_into(nodes, left, first, depth + 1, rule);
    nodes[here].first = nodes.len() as u32;
    build_into(nodes, right, first + left_count as u32, depth + 1, rule);
}

/// Partitions `prims` at the centroid median along `axis`, ties broken by scene index so the
/// result does not depend on the selection algorithm; returns the left part's size (half).
pub(super) fn median_split(prims: &mut [PrimRef], axis: usize) -> usize {
    let half = prims.len() / 2;
    prims.select_nth_unstable_by(half, |a, b| {
        a.centroid[axis]
            .total_cmp(&b.centroid[axis])
            .then(a.scene_index.cmp(&b.scene_index))
    });
    half
}

/// In-place partition: moves the elements satisfying `goes_left` to the front, returns their count.
pub(super) fn partition(prims: &mut [PrimRef], goes_left: impl Fn(&PrimRef) -> bool) -> usize {
    let mut left = 0;
    for i in 0..prims.len() {
        if goes_left(&prims[i]) {
            prims.swap(left, i);
            left += 1;
        }
    }
    left
}

/// The box around `prims`.
fn bounds(prims: &[PrimRef]) -> (Vec3, Vec3) {
    prims
        .iter()
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p.min), hi.max(p.max))
        })
}

/// Appends a subtree built with root-relative links, shifting its inner links by its new position.
fn append_shifted(nodes: &mut Vec<GpuNode>, subtree: &[GpuNode]) {
    let shift = nodes.len() as u32;
    nodes.extend(subtree.iter().map(|n| {
        let mut n = *n;
        if !n.is_leaf() {
            n.first += shift;
        }
        n
    }));
}
