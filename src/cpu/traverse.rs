//! Stackless, ordered closest-hit traversal: the CPU twin of `trace` in `wgsl/pick.wgsl`.
//!
//! Read it beside the shader: same states, same order of tests, same buffers.
#![allow(
    clippy::needless_range_loop,
    reason = "keeps the code comparable to the WGSL"
)]

use super::ray_box::{ray_box, safe_inverse};
use super::ray_triangle::ray_triangle;
use crate::layout::{
    CAP_REACHED, GpuHit, GpuNode, GpuRay, GpuTriangle, KIND_BITS, KIND_INNER, NO_HIT,
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

/// The tree, as the kernel's storage buffers hold it.
#[derive(Clone, Copy, Debug)]
pub struct Buffers<'a> {
    /// Nodes, depth-first, root at 0.
    pub nodes: &'a [GpuNode],
    /// Triangles in leaf order.
    pub triangles: &'a [GpuTriangle],
    /// Iterations after which the walk gives up with `CAP_REACHED`.
    pub iteration_cap: u32,
}

/// Finds the nearest triangle hit by `ray`; the same answer the GPU kernel computes.
#[allow(
    clippy::neg_cmp_op_on_partial_ord,
    reason = "as in the WGSL: `!(tmin <= tmax)` also rejects NaN"
)]
pub fn trace(buffers: Buffers<'_>, ray: &GpuRay) -> GpuHit {
    let nodes = buffers.nodes;
    let triangles = buffers.triangles;
    let origin = Vec3::from(ray.origin);
    let dir = Vec3::from(ray.dir);
    let mut best = GpuHit {
        t: ray.tmax,
        prim: NO_HIT,
        u: 0.0,
        v: 0.0,
        box_tests: 0,
        triangle_tests: 0,
    };
    if nodes.is_empty() || !(ray.tmin <= ray.tmax) {
        return best;
    }
    let inv_dir = safe_inverse(dir);
    let mut current = 0u32;
    let mut state = FROM_PARENT;
    let mut iterations = 0u32;
    loop {
        if iterations == buffers.iteration_cap {
            best.prim = CAP_REACHED;
            break;
        }
        iterations += 1;
        let node = &nodes[current as usize];
        if state == FROM_CHILD {
            if current == 0 {
                break;
            }
            let parent = parent_of(node);
            let parent_node = &nodes[parent as usize];
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
        if ray_box(node, origin, dir, inv_dir, ray.tmin, best.t) {
            let kind = kind_of(node);
            if kind >= KIND_INNER {
                descend = true;
            } else {
                for i in 0..kind {
                    let prim = node.first + i;
                    best.triangle_tests += 1;
                    let h = ray_triangle(&triangles[prim as usize], origin, dir);
                    if h.hit && h.t > ray.tmin && h.t <= best.t {
                        best.t = h.t;
                        best.prim = prim;
                        best.u = h.u;
                        best.v = h.v;
                    }
                }
            }
        }
        if descend {
            current = near_child(current, node, dir);
            state = FROM_PARENT;
        } else if current == 0 {
            break;
        } else if state == FROM_PARENT {
            let parent = parent_of(node);
            current = sibling(current, parent, &nodes[parent as usize]);
            state = FROM_SIBLING;
        } else {
            current = parent_of(node);
            state = FROM_CHILD;
        }
    }
    best
}
