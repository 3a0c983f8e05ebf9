//! Refitting a built tree after an object's vertices moved (the same triangles, new
//! positions): the object's leaf-order f32 triangles are rewritten from the new f64 positions
//! and every box is recomputed bottom-up, in one pass (each leaf's triangles where the leaf is
//! refitted); the tree's shape, its leaf order and its origin stay.
//! Boxes are the min/max of their triangles' f32 corners, exactly as the builders make them, so
//! the refitted tree holds the same triangles in boxes that are exact for them. Only when a
//! triangle's traceability changes (it becomes degenerate, or stops being so) does the tree
//! need building again ([`Bvh::refit`] says so), or when an offset leaves f32's range.

use super::{Bvh, traceable_corners};
use crate::layout::{GpuNode, GpuTriangle, KIND_INNER};
use crate::scene::Scene;
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};

impl Bvh {
    /// Refits the tree for object `object` of `scene` moved to `positions` (one per vertex of
    /// the object, in its vertex order, checked by `Scene::check_object_positions`; `scene`
    /// still holds the old ones and is the scene the tree was built over). Returns `false` when
    /// one of the object's triangles became traceable or stopped being so (zero area in f64 or
    /// in f32): the tree must then be built again, and may have been partly rewritten.
    pub fn refit(&mut self, scene: &Scene, object: u32, positions: &[DVec3]) -> bool {
        let leaf_vertices = self.leaf_vertices(scene);
        self.refit_with(scene, object, positions, &leaf_vertices)
    }

    /// Each leaf-order triangle's three scene vertex indices, in leaf order: what a refit reads
    /// there. Kept across refits by those who refit again ([`crate::BuiltScene`], an
    /// instanced scene's meshes), so a refit does not look each triangle up in the scene
    /// through `triangle_ids` (a random read per triangle: a fifth of a refit's time).
    pub fn leaf_vertices(&self, scene: &Scene) -> Vec<[u32; 3]> {
        self.triangle_ids
            .par_iter()
            .with_min_len(4096)
            .map(|&id| scene.triangle_vertices(id as usize))
            .collect()
    }

    /// [`Bvh::refit`] with `leaf_vertices`, this tree's [`Bvh::leaf_vertices`] over `scene`
    /// (when it is not, the scene's own triangles are read instead).
    pub(crate) fn refit_with(
        &mut self,
        scene: &Scene,
        object: u32,
        positions: &[DVec3],
        leaf_vertices: &[[u32; 3]],
    ) -> bool {
        let leaf_vertices = if leaf_vertices.len() == self.triangles.len() {
            leaf_vertices
        } else {
            &self.leaf_vertices(scene)
        };
        let o = &scene.objects()[object as usize];
        let (first, count) = (o.first_triangle, o.triangle_count as usize);
        let first_vertex = o.first_vertex;
        let origin = self.origin;
        // A vertex's f32 offset, rounded as `bvh::local_positions` rounds it (the same bits at
        // each corner it is), made where a triangle needs it: an array of them, made first,
        // was a third more memory for the gathers to wait on.
        let local = |p: DVec3| (p - origin).as_vec3();
        let vertices = |k: usize| {
            scene
                .triangle_vertices(first as usize + k)
                .map(|v| (v - first_vertex) as usize)
        };
        // The tree must hold as many of the object's triangles as are traceable at their new
        // places (not zero area in f64 or in f32), and each one it holds must be traceable (then
        // they are the same ones).
        let held = self
            .triangle_ids
            .par_iter()
            .with_min_len(4096)
            .filter(|&&id| (id.wrapping_sub(first) as usize) < count)
            .count();
        // When it holds them all (none was left out as degenerate: the common case), each is
        // checked where the tree pass rewrites it, from the corners it gathers there anyway.
        // Else, first in scene order (the vertices read in the order they lie), counted.
        let traceable: Option<Vec<bool>> = if held == count {
            None
        } else {
            let traceable: Vec<bool> = (0..count)
                .into_par_iter()
                .with_min_len(4096)
                .map(|k| {
                    let world = vertices(k).map(|v| positions[v]);
                    traceable_corners(world, world.map(local))
                })
                .collect();
            if traceable.par_iter().filter(|&&t| t).count() != held {
                return false;
            }
            Some(traceable)
        };
        let lost = AtomicBool::new(false);
        let moved = |j: usize, id: u32| {
            let k = id.wrapping_sub(first) as usize;
            if k >= count {
                return None;
            }
            // The corners of a triangle a few leaves on (leaves go in reverse order) asked for
            // now: the gathers below waited on memory one triangle after another.
            if let Some(ahead) = j.checked_sub(AHEAD) {
                for v in leaf_vertices[ahead] {
                    crate::prefetch::item(positions, v.wrapping_sub(first_vertex) as usize);
                }
            }
            let at = leaf_vertices[j].map(|v| v.wrapping_sub(first_vertex) as usize);
            let corners = at.map(|v| positions.get(v));
            let [Some(&pa), Some(&pb), Some(&pc)] = corners else {
                // Not this tree's vertices (a caller's mistake): rebuild rather than guess.
                lost.store(true, Ordering::Relaxed);
                return None;
            };
            let world = [pa, pb, pc];
            let [a, b, c] = world.map(local);
            let still = match &traceable {
                Some(traceable) => traceable[k],
                None => traceable_corners(world, [a, b, c]),
            };
            if !still {
                lost.store(true, Ordering::Relaxed);
            }
            let [v0, v1, v2] = [a, b, c].map(<[f32; 3]>::from);
            Some(GpuTriangle { v0, v1, v2 })
        };
        // Leaf order, in one pass with the boxes: each moved triangle rewritten where its leaf
        // is refitted.
        let leaves = Leaves {
            ids: &self.triangle_ids,
            moved: &moved,
        };
        let (nodes, triangles) = (self.nodes.to_mut(), self.triangles.to_mut());
        if !refit_subtree(nodes, 0, triangles, 0, &leaves) {
            refit_serially(nodes, 0, triangles, 0, &leaves);
        }
        if lost.load(Ordering::Relaxed) {
            return false;
        }
        // An offset past f32's range (the object moved too far for this frame) shows in the
        // root's box: such triangles cannot be traced (`bvh::is_traceable`), so build again.
        if let Some(root) = self.nodes.first()
            && !(Vec3::from(root.min).is_finite() && Vec3::from(root.max).is_finite())
        {
            return false;
        }
        let (ids, blocks) = (&self.triangle_ids, &mut self.blocks);
        blocks.par_iter_mut().for_each(|block| {
            let ids = &ids[block.triangles.start as usize..block.triangles.end as usize];
            // The moved object's vertices at their new positions, any other's where they are.
            let world = |i: u32| {
                scene.triangle_vertices(i as usize).map(|v| {
                    v.checked_sub(first_vertex)
                        .and_then(|k| positions.get(k as usize))
                        .copied()
                        .unwrap_or_else(|| scene.position(v as usize))
                })
            };
            let (min, max) = ids
                .iter()
                .flat_map(|&i| world(i))
                .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), p| {
                    (lo.min(p), hi.max(p))
                });
            block.min = min;
            block.max = max;
            block.origin = min + (max - min) * 0.5;
        });
        true
    }
}

/// What a refit does at a leaf: its leaf-order triangles' scene ids, and `moved`, which gives
/// a moved triangle's new f32 corners by leaf-order index and scene id (`None`: not moved,
/// left as it is).
struct Leaves<'a, F> {
    ids: &'a [u32],
    moved: &'a F,
}

impl<F: Fn(usize, u32) -> Option<GpuTriangle> + Sync> Leaves<'_, F> {
    /// Rewrites the moved ones of the `kind` leaf-order triangles from index `first`, which lie
    /// in `triangles` (leaf-order index `tri_base` onwards), and returns their bounds; `None`
    /// when they do not lie there.
    fn refit(
        &self,
        first: usize,
        kind: usize,
        triangles: &mut [GpuTriangle],
        tri_base: usize,
    ) -> Option<(Vec3, Vec3)> {
        let at = first.checked_sub(tri_base)?;
        let leaf = triangles.get_mut(at..at + kind)?;
        let ids = self.ids.get(first..first + kind)?;
        let mut b = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        for (j, (triangle, &id)) in leaf.iter_mut().zip(ids).enumerate() {
            // Bounded from the values written, not read back.
            let t = match (self.moved)(first + j, id) {
                Some(t) => {
                    *triangle = t;
                    t
                }
                None => *triangle,
            };
            b = grow(b, &t);
        }
        Some(b)
    }
}

/// How many leaf-order triangles back the refit's tree pass asks for a triangle's corners
/// (it walks the leaves last first). Dragon refit, medians of 15, alternated: none 1.90 / 1.83 /
/// 1.94 / 1.84 ms; 12 back 1.73 / 1.69 / 1.75; 24 back 1.64 / 1.72 / 1.64 / 1.61; 48 and 96
/// back 1.59–1.67 (BENCHMARKS.md).
const AHEAD: usize = 64;

/// Subtrees smaller than this are refitted by one task.
const SERIAL_NODES: usize = 4096;

/// Refits the subtree rooted at `nodes[0]` (node `base` of the tree), which should span
/// `nodes` and hold its triangles in `triangles` (leaf-order index `tri_base` onwards); `false`
/// when a link or a leaf leaves them. Children before parents (links point forward). The
/// builders lay a subtree out as a contiguous run of nodes (the root, its left subtree, then its
/// right one from the root's `first`) over a contiguous run of triangles, so the two subtrees of
/// a large one are refitted as two tasks on disjoint slices. A tree laid out otherwise (a saved
/// one may be: `Bvh::validate` asks only for forward links) has a link or a leaf leave its
/// task's slices, which the task notices; the caller then refits the whole tree in one pass.
fn refit_subtree<F: Fn(usize, u32) -> Option<GpuTriangle> + Sync>(
    nodes: &mut [GpuNode],
    base: usize,
    triangles: &mut [GpuTriangle],
    tri_base: usize,
    leaves: &Leaves<F>,
) -> bool {
    let Some(&root) = nodes.first() else {
        return true;
    };
    let right = (root.first as usize).wrapping_sub(base);
    let split =
        root.kind() >= KIND_INNER && nodes.len() > SERIAL_NODES && right > 1 && right < nodes.len();
    // The right subtree's triangles start at its leftmost leaf's.
    let mid = split
        .then(|| {
            let mut at = right;
            while nodes.get(at)?.kind() >= KIND_INNER {
                at += 1;
            }
            (nodes[at].first as usize).checked_sub(tri_base)
        })
        .flatten()
        .filter(|&mid| mid <= triangles.len());
    let Some(mid) = mid else {
        return refit_serially(nodes, base, triangles, tri_base, leaves);
    };
    let (top, rest) = nodes.split_at_mut(1);
    let (left, right_half) = rest.split_at_mut(right - 1);
    let (left_tris, right_tris) = triangles.split_at_mut(mid);
    let (l_ok, r_ok) = rayon::join(
        || refit_subtree(left, base + 1, left_tris, tri_base, leaves),
        || refit_subtree(right_half, base + right, right_tris, tri_base + mid, leaves),
    );
    let (l, r) = (left[0], right_half[0]);
    top[0].min = Vec3::from(l.min).min(Vec3::from(r.min)).into();
    top[0].max = Vec3::from(l.max).max(Vec3::from(r.max)).into();
    l_ok && r_ok
}

/// Refits `nodes` (node `base` onwards, their triangles in `triangles` from leaf-order index
/// `tri_base`) in reverse order, children before parents; `false`, stopping, at a link or a
/// leaf that leaves them.
fn refit_serially<F: Fn(usize, u32) -> Option<GpuTriangle> + Sync>(
    nodes: &mut [GpuNode],
    base: usize,
    triangles: &mut [GpuTriangle],
    tri_base: usize,
    leaves: &Leaves<F>,
) -> bool {
    for i in (0..nodes.len()).rev() {
        let node = nodes[i];
        let (min, max) = if node.kind() < KIND_INNER {
            let (first, kind) = (node.first as usize, node.kind() as usize);
            let Some(b) = leaves.refit(first, kind, triangles, tri_base) else {
                return false;
            };
            b
        } else {
            let right = (node.first as usize).wrapping_sub(base);
            let (Some(&left), Some(&right)) = (nodes.get(i + 1), nodes.get(right)) else {
                return false;
            };
            (
                Vec3::from(left.min).min(Vec3::from(right.min)),
                Vec3::from(left.max).max(Vec3::from(right.max)),
            )
        };
        nodes[i].min = min.into();
        nodes[i].max = max.into();
    }
    true
}

/// The min/max of `triangles`' corners.
#[inline]
pub(crate) fn bounds(triangles: &[GpuTriangle]) -> (Vec3, Vec3) {
    triangles
        .iter()
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), grow)
}

/// `(lo, hi)` grown by triangle `t`'s corners, in order (a plain loop: the `flat_map` over
/// corners it replaced took a third of a refit's time).
#[inline(always)]
fn grow((mut lo, mut hi): (Vec3, Vec3), t: &GpuTriangle) -> (Vec3, Vec3) {
    for p in [t.v0, t.v1, t.v2] {
        let p = Vec3::from(p);
        lo = lo.min(p);
        hi = hi.max(p);
    }
    (lo, hi)
}
