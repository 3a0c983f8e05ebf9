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
    local_positions, local_triangle, traceable_triangle,
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

/// A node's split: the axis, the size of the left part (never 0 or the node's size), and the
/// two parts' boxes when the rule found them while partitioning (`None`: the recursion computes
/// them).
pub(super) struct Split {
    pub(super) axis: usize,
    pub(super) left: usize,
    pub(super) boxes: Option<[(Vec3, Vec3); 2]>,
}

/// How a triangle builder decides a node over `prims` (box `min ..= max`, at `depth`): `None`
/// keeps it a leaf (it must then hold at most the leaf size); otherwise it partitions `prims` and
/// returns the split.
pub(super) trait SplitRule:
    Fn(&mut [PrimRef], Vec3, Vec3, u32) -> Option<Split> + Sync
{
}

impl<F: Fn(&mut [PrimRef], Vec3, Vec3, u32) -> Option<Split> + Sync> SplitRule for F {}

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
    // One indexed parallel pass straight into the vector (no per-task pieces to join), then
    // the untraceable triangles (rare) taken out in order.
    const LEFT_OUT: u32 = u32::MAX;
    let local = local_positions(scene, origin);
    let holds = super::frame_holds(scene, origin);
    let mut prims: Vec<PrimRef> = Vec::new();
    (0..scene.triangle_count())
        .into_par_iter()
        .map(|i| match traceable_triangle(scene, &local, i, holds) {
            Some([a, b, c]) => PrimRef {
                min: a.min(b).min(c),
                max: a.max(b).max(c),
                centroid: (a + b + c) / 3.0,
                scene_index: i as u32,
            },
            None => PrimRef {
                min: Vec3::ZERO,
                max: Vec3::ZERO,
                centroid: Vec3::ZERO,
                scene_index: LEFT_OUT,
            },
        })
        .collect_into_vec(&mut prims);
    if prims.par_iter().any(|p| p.scene_index == LEFT_OUT) {
        prims.retain(|p| p.scene_index != LEFT_OUT);
    }
    if prims.is_empty() {
        return Ok(Bvh {
            origin,
            ..Bvh::default()
        });
    }
    let root_bounds = bounds(&prims);
    let top = build_subtree(&mut prims, root_bounds, 0, 0, &rule, options.leaf_size);
    let mut nodes = Vec::with_capacity(top.len());
    top.flatten_into(&mut nodes);
    drop(top);
    check_node_count(nodes.len())?;
    link_parents(&mut nodes);
    let mut triangles = Vec::new();
    prims
        .par_iter()
        .map(|p| local_triangle(scene, &local, p.scene_index as usize))
        .collect_into_vec(&mut triangles);
    let triangle_ids = prims.iter().map(|p| p.scene_index).collect();
    Ok(Bvh {
        origin,
        nodes: nodes.into(),
        triangles: triangles.into(),
        triangle_ids,
        blocks: Vec::new(),
    })
}

/// A subtree as the parallel recursion leaves it: either finished nodes (depth-first, links
/// relative to the first), or an inner node over two such pieces. Flattened once at the end,
/// so the nodes are copied once, not once per parallel level.
enum Piece {
    Nodes(Vec<GpuNode>),
    Inner {
        min: Vec3,
        max: Vec3,
        axis: usize,
        len: usize,
        children: Box<(Piece, Piece)>,
    },
}

impl Piece {
    /// Nodes in this piece.
    fn len(&self) -> usize {
        match self {
            Piece::Nodes(nodes) => nodes.len(),
            Piece::Inner { len, .. } => *len,
        }
    }

    /// Appends the piece's nodes depth-first, links made absolute.
    fn flatten_into(&self, out: &mut Vec<GpuNode>) {
        match self {
            Piece::Nodes(nodes) => append_shifted(out, nodes),
            Piece::Inner {
                min,
                max,
                axis,
                children,
                ..
            } => {
                let here = out.len();
                out.push(inner_node(
                    *min,
                    *max,
                    *axis,
                    (here + 1 + children.0.len()) as u32,
                ));
                children.0.flatten_into(out);
                children.1.flatten_into(out);
            }
        }
    }
}

/// The two parts' boxes of `split` (over `prims`, already partitioned): the rule's, or computed.
fn part_bounds(prims: &[PrimRef], split: &Split) -> [(Vec3, Vec3); 2] {
    split.boxes.unwrap_or_else(|| {
        let (left, right) = prims.split_at(split.left);
        [bounds(left), bounds(right)]
    })
}

/// Builds the subtree over `prims` (box `min, max`; they start at leaf-order index `first`) in
/// depth-first order. Large ranges split into parallel tasks.
fn build_subtree(
    prims: &mut [PrimRef],
    (min, max): (Vec3, Vec3),
    first: u32,
    depth: u32,
    rule: &impl SplitRule,
    leaf_size: u32,
) -> Piece {
    if prims.len() < PARALLEL_MIN {
        let mut nodes = Vec::with_capacity(2 * prims.len() / leaf_size as usize + 1);
        build_into(&mut nodes, prims, (min, max), first, depth, rule);
        return Piece::Nodes(nodes);
    }
    let Some(split) = rule(prims, min, max, depth) else {
        return Piece::Nodes(vec![leaf_node(min, max, prims.len() as u32, first)]);
    };
    let [left_box, right_box] = part_bounds(prims, &split);
    let (axis, left_count) = (split.axis, split.left);
    let (left_prims, right_prims) = prims.split_at_mut(left_count);
    let children = rayon::join(
        || build_subtree(left_prims, left_box, first, depth + 1, rule, leaf_size),
        || {
            build_subtree(
                right_prims,
                right_box,
                first + left_count as u32,
                depth + 1,
                rule,
                leaf_size,
            )
        },
    );
    Piece::Inner {
        min,
        max,
        axis,
        len: 1 + children.0.len() + children.1.len(),
        children: Box::new(children),
    }
}

/// Sequential build of one subtree, appended to `nodes` with links relative to `nodes[0]`.
fn build_into(
    nodes: &mut Vec<GpuNode>,
    prims: &mut [PrimRef],
    (min, max): (Vec3, Vec3),
    first: u32,
    depth: u32,
    rule: &impl SplitRule,
) {
    let Some(split) = rule(prims, min, max, depth) else {
        nodes.push(leaf_node(min, max, prims.len() as u32, first));
        return;
    };
    let [left_box, right_box] = part_bounds(prims, &split);
    let (axis, left_count) = (split.axis, split.left);
    let here = nodes.len();
    nodes.push(inner_node(min, max, axis, 0));
    let (left, right) = prims.split_at_mut(left_count);
    build_into(nodes, left, left_box, first, depth + 1, rule);
    nodes[here].first = nodes.len() as u32;
    build_into(
        nodes,
        right,
        right_box,
        first + left_count as u32,
        depth + 1,
        rule,
    );
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

/// In-place partition: moves the elements satisfying `goes_left` to the front, returns their count
/// and the two sides' boxes (grown as each element finds its side, so the recursion need not
/// pass over the elements again for them). Hoare's scheme (from both ends, swapping only
/// misplaced pairs): about half the moves of a one-sided scan. The order inside each side
/// depends only on the input order.
pub(super) fn partition(
    prims: &mut [PrimRef],
    goes_left: impl Fn(&PrimRef) -> bool,
) -> (usize, [(Vec3, Vec3); 2]) {
    let empty = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    let grow = |(lo, hi): (Vec3, Vec3), p: &PrimRef| (lo.min(p.min), hi.max(p.max));
    let (mut left, mut right) = (empty, empty);
    let (mut i, mut j) = (0, prims.len());
    loop {
        while i < j && goes_left(&prims[i]) {
            left = grow(left, &prims[i]);
            i += 1;
        }
        while i < j && !goes_left(&prims[j - 1]) {
            right = grow(right, &prims[j - 1]);
            j -= 1;
        }
        if i == j {
            return (i, [left, right]);
        }
        prims.swap(i, j - 1);
        left = grow(left, &prims[i]);
        right = grow(right, &prims[j - 1]);
        i += 1;
        j -= 1;
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The boxes the partition grows are the two sides' boxes exactly, so the recursion's nodes
    /// are the same whether it takes them or computes them again.
    #[test]
    fn the_partition_returns_each_side_and_its_exact_box() {
        let mut rng = crate::check::synthetic::rng(7);
        use rand::Rng;
        for n in [0, 1, 2, 3, 17, 1000] {
            let mut prims: Vec<PrimRef> = (0..n)
                .map(|i| {
                    let a = Vec3::new(rng.random(), rng.random(), rng.random()) * 100.0;
                    let b = a + Vec3::new(rng.random(), rng.random(), rng.random());
                    PrimRef {
                        min: a,
                        max: b,
                        centroid: (a + b) * 0.5,
                        scene_index: i,
                    }
                })
                .collect();
            let before: Vec<u32> = prims.iter().map(|p| p.scene_index).collect();
            let goes_left = |p: &PrimRef| p.centroid.x < 50.0;
            let (left, [left_box, right_box]) = partition(&mut prims, goes_left);
            assert!(prims[..left].iter().all(goes_left));
            assert!(!prims[left..].iter().any(goes_left));
            let mut after: Vec<u32> = prims.iter().map(|p| p.scene_index).collect();
            after.sort_unstable();
            assert_eq!(after, before, "a permutation");
            let same = |a: (Vec3, Vec3), b: (Vec3, Vec3)| {
                a.0.to_array().map(f32::to_bits) == b.0.to_array().map(f32::to_bits)
                    && a.1.to_array().map(f32::to_bits) == b.1.to_array().map(f32::to_bits)
            };
            assert!(same(left_box, bounds(&prims[..left])), "left box, {n}");
            assert!(same(right_box, bounds(&prims[left..])), "right box, {n}");
        }
    }
}
