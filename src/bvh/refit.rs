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
            let world = |i: u32| {
                scene
                    .triangle_vertices(i as usize)
                    .map(|v| positions[(v - first_vertex) as usize])
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

/// Recomputes every node's box from its triangles: the leaves' in parallel, then the inner
/// nodes' children before parents (a child's index is above its parent's in depth-first order).
fn refit_boxes(nodes: &mut [GpuNode], triangles: &[GpuTriangle]) {
    nodes
        .par_iter_mut()
        .with_min_len(1024)
        .filter(|node| node.kind() < KIND_INNER)
        .for_each(|node| {
            let first = node.first as usize;
            let (min, max) = bounds(&triangles[first..first + node.kind() as usize]);
            node.min = min.into();
            node.max = max.into();
        });
    for i in (0..nodes.len()).rev() {
        let node = nodes[i];
        if node.kind() >= KIND_INNER {
            let (left, right) = (nodes[i + 1], nodes[node.first as usize]);
            nodes[i].min = Vec3::from(left.min).min(Vec3::from(right.min)).into();
            nodes[i].max = Vec3::from(left.max).max(Vec3::from(right.max)).into();
        }
    }
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
