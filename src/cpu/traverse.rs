//! Stackless, ordered closest-hit traversal: the CPU twin of `trace` in `wgsl/pick.wgsl`.
//!
//! Read it beside the shader: same states, same order of tests, same buffers.
#![allow(
    clippy::needless_range_loop,
    reason = "keeps the code comparable to the WGSL"
)]

use super::ray_box::{ray_box, safe_inverse};
use super::ray_triangle::{TriangleHit, ray_triangle, ray_triangle_watertight, shear_for};
use crate::layout::{
    CAP_REACHED, CULL_BACK, CULL_FRONT, CULL_SHIFT, GpuHit, GpuHitEntry, GpuNode, GpuRay,
    GpuTriangle, KIND_BITS, KIND_INNER, MODE_ALL, MODE_ANY, NO_HIT,
};
use glam::Vec3;

// Traversal states: how we arrived at `current`.
const FROM_PARENT: u32 = 0; // descending into the near child
const FROM_SIBLING: u32 = 1; // moving across to the far child
const FROM_CHILD: u32 = 2; // climbing back up after a subtree is done

fn kind_of(node: &GpuNode) -> u32 {
    node.kind()
}

fn parent_of(node: &GpuNode) -> u32 {
    node.parent_kind >> KIND_BITS
}

/// The child the ray reaches first: the left (lower) one unless the ray runs down the split axis.
fn near_child(index: u32, node: &GpuNode, dir: Vec3) -> u32 {
    let axis = kind_of(node) - KIND_INNER;
    if dir[axis as usize] < 0.0 {
        return node.first;
    }
    index + 1
}

fn sibling(index: u32, parent: u32, parent_node: &GpuNode) -> u32 {
    if index == parent + 1 {
        return parent_node.first;
    }
    parent + 1
}

pub(crate) fn facing_allowed(det: f32, cull: u32) -> bool {
    if cull == CULL_BACK {
        return det > 0.0;
    }
    if cull == CULL_FRONT {
        return det < 0.0;
    }
    true
}

/// Where the walk reads nodes: the flat array the kernel binds, or another encoding of the same
/// tree (the layout experiments in `benches/layouts.rs` decode quantised boxes here).
pub trait NodeSource: Sync {
    /// Number of nodes.
    fn node_count(&self) -> usize;
    /// Node `index`, decoded to the kernel's layout.
    fn node(&self, index: u32) -> GpuNode;
}

/// Where the walk reads triangles: the leaf-order array the kernel binds, or another encoding.
pub trait TriangleSource: Sync {
    /// Leaf-order triangle `index`.
    fn triangle(&self, index: u32) -> GpuTriangle;
}

impl NodeSource for [GpuNode] {
    fn node_count(&self) -> usize {
        self.len()
    }

    #[inline(always)]
    fn node(&self, index: u32) -> GpuNode {
        self[index as usize]
    }
}

impl TriangleSource for [GpuTriangle] {
    #[inline(always)]
    fn triangle(&self, index: u32) -> GpuTriangle {
        self[index as usize]
    }
}

/// The tree and per-dispatch settings, as the kernel's bindings hold them.
#[derive(Debug)]
pub struct Buffers<'a, N: ?Sized = [GpuNode], T: ?Sized = [GpuTriangle]> {
    /// Nodes, depth-first, root at 0.
    pub nodes: &'a N,
    /// Triangles in leaf order.
    pub triangles: &'a T,
    /// Scene triangle id of each leaf-order triangle (`Bvh::triangle_ids`): the tie rule.
    pub triangle_ids: &'a [u32],
    /// Layer mask of each leaf-order triangle (ignored when empty).
    pub triangle_masks: &'a [u32],
    /// Iterations after which the walk gives up with `CAP_REACHED`.
    pub iteration_cap: u32,
    /// Length of each ray's all-hits list.
    pub max_hits: u32,
    /// Use the watertight triangle test instead of Möller–Trumbore.
    pub watertight: bool,
}

impl<N: ?Sized, T: ?Sized> Clone for Buffers<'_, N, T> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<N: ?Sized, T: ?Sized> Copy for Buffers<'_, N, T> {}

/// Traces `ray`: the same answer the GPU kernel computes. `hit_list` (length `max_hits`) receives
/// the all-hits list in `MODE_ALL`.
#[allow(
    clippy::neg_cmp_op_on_partial_ord,
    reason = "as in the WGSL: `!(tmin <= tmax)` also rejects NaN"
)]
pub fn trace<N: NodeSource + ?Sized, T: TriangleSource + ?Sized>(
    buffers: Buffers<'_, N, T>,
    ray: &GpuRay,
    hit_list: &mut [GpuHitEntry],
) -> GpuHit {
    let nodes = buffers.nodes;
    let triangles = buffers.triangles;
    let origin = Vec3::from(ray.origin);
    let dir = Vec3::from(ray.dir);
    let mut best = GpuHit {
        t: ray.tmax,
        prim: NO_HIT,
        ..GpuHit::default()
    };
    if nodes.node_count() == 0 || !(ray.tmin <= ray.tmax) {
        return best;
    }
    let mode = ray.flags & 3;
    let cull = (ray.flags >> CULL_SHIFT) & 3;
    let inv_dir = safe_inverse(dir);
    let shear = shear_for(dir);
    // Hits need t in (tmin, limit]; limit shrinks to the nearest hit (closest), or to the
    // farthest kept hit once the all-hits list is full and has overflowed.
    let mut limit = ray.tmax;
    let mut done = false;
    let mut current = 0u32;
    let mut state = FROM_PARENT;
    let mut iterations = 0u32;
    loop {
        if iterations == buffers.iteration_cap {
            best.prim = CAP_REACHED;
            break;
        }
        iterations += 1;
        let node = &nodes.node(current);
        if state == FROM_CHILD {
            if current == 0 {
                break;
            }
            let parent = parent_of(node);
            let parent_node = &nodes.node(parent);
            if current == near_child(parent, parent_node, dir) {
                current = sibling(current, parent, parent_node);
                state = FROM_SIBLING;
            } else {
                current = parent;
                state = FROM_CHILD;
            }
            continue;
        }
        // Arrived from the parent or the sibling: test this node's box.
        best.box_tests += 1;
        let mut descend = false;
        if ray_box(node, origin, dir, inv_dir, ray.tmin, limit) {
            let kind = kind_of(node);
            if kind >= KIND_INNER {
                descend = true;
            } else {
                for i in 0..kind {
                    let prim = node.first + i;
                    if !buffers.triangle_masks.is_empty()
                        && (buffers.triangle_masks[prim as usize] & ray.mask) == 0
                    {
                        continue;
                    }
                    best.triangle_tests += 1;
                    let h: TriangleHit<f32> = if buffers.watertight {
                        ray_triangle_watertight(&triangles.triangle(prim), origin, &shear)
                    } else {
                        ray_triangle(&triangles.triangle(prim), origin, dir)
                    };
                    if !h.hit
                        || !facing_allowed(h.det, cull)
                        || !(h.t > ray.tmin)
                        || !(h.t <= limit)
                    {
                        continue;
                    }
                    if mode == MODE_ALL {
                        limit = insert_hit(
                            &mut best,
                            hit_list,
                            GpuHitEntry {
                                t: h.t,
                                prim,
                                u: h.u,
                                v: h.v,
                            },
                            ray.tmax,
                            buffers.triangle_ids,
                        );
                    } else {
                        if !closest_accepts(&best, h.t, prim, buffers.triangle_ids) {
                            continue;
                        }
                        best.t = h.t;
                        best.prim = prim;
                        best.u = h.u;
                        best.v = h.v;
                        limit = h.t;
                        if mode == MODE_ANY {
                            done = true;
                            break;
                        }
                    }
                }
            }
        }
        if done {
            break;
        }
        if descend {
            current = near_child(current, node, dir);
            state = FROM_PARENT;
        } else if current == 0 {
            break;
        } else if state == FROM_PARENT {
            let parent = parent_of(node);
            current = sibling(current, parent, &nodes.node(parent));
            state = FROM_SIBLING;
        } else {
            current = parent_of(node);
            state = FROM_CHILD;
        }
    }
    if mode == MODE_ALL && best.count > 0 && best.prim != CAP_REACHED {
        let nearest = hit_list[0];
        best.t = nearest.t;
        best.prim = nearest.prim;
        best.u = nearest.u;
        best.v = nearest.v;
    }
    best
}

/// The tie rule, so that no answer depends on the walk or the tree: hit `a` comes before hit `b`
/// when its t is smaller, or the t are equal and its scene triangle id (objects in order, then
/// triangles in file order) is lower.
#[inline(always)]
pub(crate) fn comes_before(a: &GpuHitEntry, b: &GpuHitEntry, triangle_ids: &[u32]) -> bool {
    a.t < b.t || (a.t == b.t && triangle_ids[a.prim as usize] < triangle_ids[b.prim as usize])
}

/// Closest and any-hit modes: whether a hit at `t <= limit` on leaf-order triangle `prim`
/// replaces `best` under the tie rule.
#[inline(always)]
pub(crate) fn closest_accepts(best: &GpuHit, t: f32, prim: u32, triangle_ids: &[u32]) -> bool {
    best.prim == NO_HIT
        || t < best.t
        || triangle_ids[prim as usize] < triangle_ids[best.prim as usize]
}

/// Inserts a hit into the ray's list, kept sorted under the tie rule; when the list is full the
/// last entry is dropped and the ray is flagged as overflowing. Returns the new limit for t.
#[inline(always)]
pub(crate) fn insert_hit(
    best: &mut GpuHit,
    list: &mut [GpuHitEntry],
    entry: GpuHitEntry,
    tmax: f32,
    triangle_ids: &[u32],
) -> f32 {
    let max_hits = list.len();
    let mut slot = best.count as usize;
    if slot == max_hits {
        best.overflow = 1;
        slot = max_hits - 1;
        if !comes_before(&entry, &list[slot], triangle_ids) {
            return list[slot].t;
        }
    } else {
        best.count += 1;
    }
    while slot > 0 && comes_before(&entry, &list[slot - 1], triangle_ids) {
        list[slot] = list[slot - 1];
        slot -= 1;
    }
    list[slot] = entry;
    if best.overflow != 0 {
        return list[max_hits - 1].t;
    }
    tmax
}
