//! Refitting a built tree after an object's vertices moved (the same triangles, new
//! positions): the object's leaf-order f32 triangles are rewritten from the new f64 positions
//! and every box is recomputed bottom-up; the tree's shape, its leaf order and its origin stay.
//! Boxes are the min/max of their triangles' f32 corners, exactly as the builders make them, so
//! the refitted tree holds the same triangles in boxes that are exact for them. Only when a
//! triangle's traceability changes (it becomes degenerate, or stops being so) does the tree
//! need building again ([`Bvh::refit`] says so).

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
        let o = &scene.objects()[object as usize];
        let (first, count) = (o.first_triangle, o.triangle_count as usize);
        let first_vertex = o.first_vertex;
        let origin = self.origin;
        // Each vertex rounded once, as `bvh::local_positions` rounds it.
        let local: Vec<Vec3> = positions
            .par_iter()
            .with_min_len(4096)
            .map(|&p| (p - origin).as_vec3())
            .collect();
        let corners = |id: u32| {
            let corners = scene
                .triangle_vertices(id as usize)
                .map(|v| (v - first_vertex) as usize);
            (corners.map(|v| positions[v]), corners.map(|v| local[v]))
        };
        let moved = |id: u32| id.wrapping_sub(first) < count as u32;
        // Leaf order: each moved triangle rewritten; each must still be traceable.
        let lost = AtomicBool::new(false);
        let in_tree: usize = self
            .triangles
            .to_mut()
            .par_iter_mut()
            .zip(self.triangle_ids.par_iter())
            .with_min_len(4096)
            .map(|(triangle, &id)| {
                if !moved(id) {
                    return 0;
                }
                let (world, f32) = corners(id);
                if !traceable_corners(world, f32) {
                    lost.store(true, Ordering::Relaxed);
                }
                let [v0, v1, v2] = f32.map(<[f32; 3]>::from);
                *triangle = GpuTriangle { v0, v1, v2 };
                1
            })
            .sum();
        if lost.load(Ordering::Relaxed) {
            return false;
        }
        // The moved triangles left out of the tree (degenerate ones) must still be left out.
        if in_tree < count {
            let mut present = vec![false; count];
            for &id in self.triangle_ids.iter().filter(|&&id| moved(id)) {
                present[(id - first) as usize] = true;
            }
            let found = present.par_iter().enumerate().any(|(k, &present)| {
                let (world, f32) = corners(first + k as u32);
                !present && traceable_corners(world, f32)
            });
            if found {
                return false;
            }
        }
        refit_boxes(self.nodes.to_mut(), &self.triangles);
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

/// Subtrees smaller than this are refitted by one task.
const SERIAL_NODES: usize = 4096;

/// Recomputes every node's box from its triangles, children before parents (links point
/// forward). The builders lay a subtree out as a contiguous run of nodes (the root, its left
/// subtree, then its right one from the root's `first`), so the two subtrees of a large one are
/// refitted as two tasks on disjoint slices. A tree laid out otherwise (a saved one may be:
/// `Bvh::validate` asks only for forward links) has a link leave its task's slice, which the
/// task notices; the whole tree is then refitted in one pass.
fn refit_boxes(nodes: &mut [GpuNode], triangles: &[GpuTriangle]) {
    if !refit_subtree(nodes, 0, triangles) {
        refit_serially(nodes, 0, triangles);
    }
}

/// Refits the subtree rooted at `nodes[0]` (node `base` of the tree), which should span
/// `nodes`; `false` when a link leaves `nodes`.
fn refit_subtree(nodes: &mut [GpuNode], base: usize, triangles: &[GpuTriangle]) -> bool {
    let Some(&root) = nodes.first() else {
        return true;
    };
    let right = (root.first as usize).wrapping_sub(base);
    let split =
        root.kind() >= KIND_INNER && nodes.len() > SERIAL_NODES && right > 1 && right < nodes.len();
    if !split {
        return refit_serially(nodes, base, triangles);
    }
    let (top, rest) = nodes.split_at_mut(1);
    let (left, right_half) = rest.split_at_mut(right - 1);
    let (l_ok, r_ok) = rayon::join(
        || refit_subtree(left, base + 1, triangles),
        || refit_subtree(right_half, base + right, triangles),
    );
    let (l, r) = (left[0], right_half[0]);
    top[0].min = Vec3::from(l.min).min(Vec3::from(r.min)).into();
    top[0].max = Vec3::from(l.max).max(Vec3::from(r.max)).into();
    l_ok && r_ok
}

/// Refits `nodes` (node `base` onwards) in reverse order, children before parents; `false`,
/// stopping, at a link that leaves `nodes`.
fn refit_serially(nodes: &mut [GpuNode], base: usize, triangles: &[GpuTriangle]) -> bool {
    for i in (0..nodes.len()).rev() {
        let node = nodes[i];
        let (min, max) = if node.kind() < KIND_INNER {
            let first = node.first as usize;
            bounds(&triangles[first..first + node.kind() as usize])
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
        .flat_map(|t| [t.v0, t.v1, t.v2])
        .map(Vec3::from)
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p), hi.max(p))
        })
}
