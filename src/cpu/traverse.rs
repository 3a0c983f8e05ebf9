//! Stackless, ordered closest-hit traversal: the CPU twin of `trace` in `wgsl/pick.wgsl`.
//!
//! Read it beside the shader: same states, same order of tests, same buffers. In an instanced
//! scene the same automaton walks two levels with no stack: at a leaf of the top tree it moves
//! the ray into the instance's frame and descends into the mesh's bottom tree; leaving the
//! bottom root, it climbs back to the instance's leaf and the world ray.
#![allow(
    clippy::needless_range_loop,
    reason = "keeps the code comparable to the WGSL"
)]

use super::ray_box::{box_interval, clip, hit_t, meets, safe_inverse, triangle_interval};
use super::ray_triangle::Shear;
use super::ray_triangle::{TriangleHit, ray_triangle, ray_triangle_watertight, shear_for};
use crate::layout::{
    CAP_REACHED, CULL_BACK, CULL_FRONT, CULL_SHIFT, GpuHit, GpuHitEntry, GpuInstance, GpuNode,
    GpuRay, GpuTriangle, KIND_BITS, KIND_INNER, MODE_ALL, MODE_ANY, NO_HIT,
};
use glam::Vec3;

// Traversal states: how we arrived at `current`.
const FROM_PARENT: u32 = 0; // descending into the near child
const FROM_SIBLING: u32 = 1; // moving across to the far child
const FROM_CHILD: u32 = 2; // climbing back up after a subtree is done
// `inside` while the walk is in the top tree (or the scene has no instances).
const NO_INSTANCE: u32 = u32::MAX;

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

/// The rest of the ray's origin after rounding to f32 ([`GpuRay::origin_lo`]): three half
/// floats, each normal, subnormal or 0 (`frame::put_origin_lo`), decoded exactly (the kernel's
/// `half_to_f32`).
#[inline]
pub fn origin_lo(ray: &GpuRay) -> Vec3 {
    Vec3::new(
        half_to_f32(ray.origin_lo[0] & 0xffff),
        half_to_f32(ray.origin_lo[0] >> 16),
        half_to_f32(ray.origin_lo[1] & 0xffff),
    )
}

/// The spacing of subnormal half floats, 2^-24.
pub const HALF_SUBNORMAL_STEP: f32 = 5.960_464_5e-8;

/// A finite half float (what `frame::put_origin_lo` writes), exactly in f32: the kernel's
/// `half_to_f32`, line for line. A subnormal's mantissa times 2^-24 is exact (a power of two,
/// and a normal f32).
#[inline]
fn half_to_f32(h: u32) -> f32 {
    let e = (h >> 10) & 31;
    if e == 0 {
        let m = (h & 0x3ff) as f32 * HALF_SUBNORMAL_STEP;
        return if h & 0x8000 != 0 { -m } else { m };
    }
    f32::from_bits(((h & 0x8000) << 16) | ((e + 112) << 23) | ((h & 0x3ff) << 13))
}

/// `dot(a, b)` as the kernel writes it.
fn dot3(a: [f32; 3], b: Vec3) -> f32 {
    Vec3::from(a).dot(b)
}

/// The ray in instance `r`'s frame: its origin (taken in two parts, `hi + lo`) and direction
/// mapped by the inverse linear part, from the mesh origin's place `c`.
pub(crate) fn enter_instance(r: &GpuInstance, hi: Vec3, lo: Vec3, dir: Vec3) -> (Vec3, Vec3) {
    let c_hi = Vec3::new(r.cx, r.cy, r.cz);
    let d = (hi - c_hi) + (lo - Vec3::from(r.c_lo));
    (
        Vec3::new(dot3(r.l0, d), dot3(r.l1, d), dot3(r.l2, d)),
        Vec3::new(dot3(r.l0, dir), dot3(r.l1, dir), dot3(r.l2, dir)),
    )
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
    /// Scene triangle id of each leaf-order triangle (`Bvh::triangle_ids`): the tie rule. In an
    /// instanced scene, each mesh's file-order triangle id (a hit reports
    /// `prim_base + id`).
    pub triangle_ids: &'a [u32],
    /// Instance records (empty: a scene without instances).
    pub instances: &'a [GpuInstance],
    /// Nodes of the top tree over the instances (0: a scene without instances).
    pub top_nodes: u32,
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
    let world_origin = Vec3::from(ray.origin);
    let world_dir = Vec3::from(ray.dir);
    let mut best = GpuHit {
        t: ray.tmax,
        prim: NO_HIT,
        ..GpuHit::default()
    };
    if nodes.node_count() == 0 || !(ray.tmin <= ray.tmax) {
        return best;
    }
    let mode = ray.flags & 3;
    // Culling needs no change in an instance's frame: a mirroring instance's faces are stored
    // so that front faces stay front faces in the world (`crate::instance`).
    let cull = (ray.flags >> CULL_SHIFT) & 3;
    let instanced = buffers.top_nodes != 0;
    // Hit ids are their own tie keys in an instanced scene.
    let tie_ids: &[u32] = if instanced { &[] } else { buffers.triangle_ids };
    // The ray as the current tree sees it: the world's, or an instance's.
    let world_inv_dir = safe_inverse(world_dir);
    let world_shear: Shear = shear_for(world_dir);
    let mut origin = world_origin;
    let mut dir = world_dir;
    let mut inv_dir = world_inv_dir;
    let mut shear = world_shear;
    let mut inside = NO_INSTANCE;
    let mut instance = GpuInstance::default();
    let mut instance_leaf = 0u32;
    // The world ray's interval over the entered instance's leaf box (scene frame): its hits'
    // t are kept within it ([`hit_t`]), so the top tree never prunes a box holding one.
    let mut leaf_interval = (0.0f32, 0.0f32);
    // Hits need t in (tmin, limit]; limit shrinks to the nearest hit (closest), or to the
    // farthest kept hit once the all-hits list is full and has overflowed.
    let mut limit = ray.tmax;
    let mut done = false;
    let mut current = 0u32;
    let mut state = FROM_PARENT;
    let mut iterations = 0u32;
    // (After the loop the kernel tells its own ends, at the root, done or at the cap, from a
    // driver's cut (`UNFINISHED`), for which the GPU picker asks this walk instead.)
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
            if inside != NO_INSTANCE && current == instance.root {
                // The instance's tree is done: back to its leaf and the world ray.
                current = instance_leaf;
                inside = NO_INSTANCE;
                (origin, dir, inv_dir, shear) =
                    (world_origin, world_dir, world_inv_dir, world_shear);
                continue;
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
        let node_interval = box_interval(node.min.into(), node.max.into(), origin, dir, inv_dir);
        if meets(node_interval, ray.tmin, limit) {
            let kind = kind_of(node);
            if kind >= KIND_INNER {
                descend = true;
            } else if instanced && inside == NO_INSTANCE {
                // A leaf of the top tree: enter its instance, unless the masks share no bit.
                let r = buffers.instances[node.first as usize];
                if (r.mask & ray.mask) != 0 {
                    instance = r;
                    inside = node.first;
                    instance_leaf = current;
                    // In the top tree the ray is the world's: its interval over this leaf.
                    leaf_interval = node_interval;
                    (origin, dir) = enter_instance(&r, world_origin, origin_lo(ray), world_dir);
                    inv_dir = safe_inverse(dir);
                    shear = shear_for(dir);
                    current = r.root;
                    state = FROM_PARENT;
                    continue;
                }
            } else {
                for i in 0..kind {
                    let leaf_prim = node.first + i;
                    if !buffers.triangle_masks.is_empty()
                        && (buffers.triangle_masks[leaf_prim as usize] & ray.mask) == 0
                    {
                        continue;
                    }
                    best.triangle_tests += 1;
                    let tri = triangles.triangle(leaf_prim);
                    let h: TriangleHit<f32> = if buffers.watertight {
                        ray_triangle_watertight(&tri, origin, &shear)
                    } else {
                        ray_triangle(&tri, origin, dir)
                    };
                    if !h.hit || !facing_allowed(h.det, cull) {
                        continue;
                    }
                    let mut interval = triangle_interval(&tri, origin, dir, inv_dir);
                    if inside != NO_INSTANCE {
                        interval = clip(interval, leaf_interval);
                    }
                    let Some(t) = hit_t(h.t, interval) else {
                        continue;
                    };
                    if !(t > ray.tmin) || !(t <= limit) {
                        continue;
                    }
                    let prim = if inside != NO_INSTANCE {
                        instance.prim_base + buffers.triangle_ids[leaf_prim as usize]
                    } else {
                        leaf_prim
                    };
                    if mode == MODE_ALL {
                        limit = insert_hit(
                            &mut best,
                            hit_list,
                            GpuHitEntry {
                                t,
                                prim,
                                u: h.u,
                                v: h.v,
                            },
                            ray.tmax,
                            tie_ids,
                        );
                    } else {
                        if !closest_accepts(&best, t, prim, tie_ids) {
                            continue;
                        }
                        best.t = t;
                        best.prim = prim;
                        best.u = h.u;
                        best.v = h.v;
                        limit = t;
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
        } else if inside != NO_INSTANCE && current == instance.root {
            // Missed the instance's root box: back to its leaf and the world ray.
            current = instance_leaf;
            inside = NO_INSTANCE;
            (origin, dir, inv_dir, shear) = (world_origin, world_dir, world_inv_dir, world_shear);
            state = FROM_CHILD;
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
/// `triangle_ids` maps a prim to its tie key; empty, each prim is its own key (an instanced
/// scene's hit ids run in tie order).
#[inline(always)]
pub(crate) fn comes_before(a: &GpuHitEntry, b: &GpuHitEntry, triangle_ids: &[u32]) -> bool {
    a.t < b.t || (a.t == b.t && tie_key(a.prim, triangle_ids) < tie_key(b.prim, triangle_ids))
}

/// Prim `prim`'s place in the tie order (see [`comes_before`]).
#[inline(always)]
fn tie_key(prim: u32, triangle_ids: &[u32]) -> u32 {
    if triangle_ids.is_empty() {
        return prim;
    }
    triangle_ids[prim as usize]
}

/// Closest and any-hit modes: whether a hit at `t <= limit` on leaf-order triangle `prim`
/// replaces `best` under the tie rule.
#[inline(always)]
pub(crate) fn closest_accepts(best: &GpuHit, t: f32, prim: u32, triangle_ids: &[u32]) -> bool {
    best.prim == NO_HIT
        || t < best.t
        || tie_key(prim, triangle_ids) < tie_key(best.prim, triangle_ids)
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The kernel's decoding gives every half float `put_origin_lo` can write (normal, or
    /// zero) exactly, the same bits as a general decoder.
    #[test]
    fn half_decoding_is_exact_for_normal_halves_and_zero() {
        for bits in 0..=u16::MAX {
            let h = half::f16::from_bits(bits);
            if h.is_normal() {
                assert_eq!(
                    half_to_f32(u32::from(bits)).to_bits(),
                    h.to_f32().to_bits(),
                    "{bits:#06x}"
                );
            }
        }
        assert_eq!(half_to_f32(0).to_bits(), 0.0f32.to_bits());
    }
}
