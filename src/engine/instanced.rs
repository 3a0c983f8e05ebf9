//! The engine over an instanced scene: the top tree walked nearest child first (its binary
//! nodes, as the kernel holds them), and at each instance leaf the ray moved into the
//! instance's frame (`cpu::traverse::enter_instance`, the same bits as the kernel) and traced
//! through the mesh's wide tree by the single-ray walk ([`walk::trace`]), its limit the best hit
//! so far. Each instance's answer is merged under the twin's tie rule (hit ids
//! `prim_base + file-order triangle` are their own keys), so the answers are the twin's bit for
//! bit in closest and all-hits mode; any-hit mode, as everywhere, returns some hit when there is
//! one.
#![allow(
    clippy::neg_cmp_op_on_partial_ord,
    reason = "as in the twin: `!(a <= b)` also rejects NaN"
)]

use super::lanes8::Lanes8;
use super::walk::{self, Entry};
use crate::cpu::ray_box::{ray_box, safe_inverse};
use crate::cpu::traverse::{closest_accepts, enter_instance, insert_hit, origin_lo};
use crate::instance::Instances;
use crate::layout::{GpuHit, GpuHitEntry, GpuNode, GpuRay, KIND_INNER, MODE_ALL, MODE_ANY, NO_HIT};
use glam::Vec3;

/// What the instanced walk reads: the top tree, the instances, and each mesh's wide walk.
pub struct TopScene<'a> {
    /// The top tree's nodes (the combined tree's first `top_nodes`).
    pub nodes: &'a [GpuNode],
    /// The instances (records and meshes).
    pub instances: &'a Instances,
    /// Each mesh's wide tree and triangles, as the single-ray walk reads them.
    pub meshes: Vec<walk::Scene<'a>>,
    /// Stack entries the deepest mesh's walk needs.
    pub stack: usize,
    /// Levels of the top tree.
    pub depth: usize,
}

/// The near child of top node `index` (the left one unless the ray runs down the split axis)
/// and the far one.
fn children(index: u32, node: &GpuNode, dir: Vec3) -> (u32, u32) {
    let axis = (node.kind() - KIND_INNER) as usize;
    if dir[axis] < 0.0 {
        (node.first, index + 1)
    } else {
        (index + 1, node.first)
    }
}

/// Traces one scene-frame ray through the instances. `list` is the ray's all-hits list (empty
/// outside all-hits mode), `scratch` as long, for one instance's list; `top` holds
/// `TopScene::depth + 1` entries and `stack` `TopScene::stack`.
#[inline(always)]
pub fn trace<L: Lanes8>(
    scene: &TopScene<'_>,
    ray: &GpuRay,
    list: &mut [GpuHitEntry],
    scratch: &mut [GpuHitEntry],
    top: &mut [u32],
    stack: &mut [Entry],
) -> GpuHit {
    let mut best = GpuHit {
        t: ray.tmax,
        prim: NO_HIT,
        ..GpuHit::default()
    };
    if scene.nodes.is_empty() || !(ray.tmin <= ray.tmax) {
        return best;
    }
    let mode = ray.flags & 3;
    let origin = Vec3::from(ray.origin);
    let dir = Vec3::from(ray.dir);
    let inv_dir = safe_inverse(dir);
    let lo = origin_lo(ray);
    let records = scene.instances.records();
    let mut limit = ray.tmax;
    let mut sp = 1;
    top[0] = 0;
    while sp > 0 {
        sp -= 1;
        let index = top[sp];
        let node = &scene.nodes[index as usize];
        best.box_tests += 1;
        if !ray_box(node, origin, dir, inv_dir, ray.tmin, limit) {
            continue;
        }
        if node.kind() >= KIND_INNER {
            let (near, far) = children(index, node, dir);
            top[sp] = far;
            top[sp + 1] = near;
            sp += 2;
            continue;
        }
        let k = node.first as usize;
        let r = &records[k];
        if (r.mask & ray.mask) == 0 {
            continue;
        }
        let (o, d) = enter_instance(r, origin, lo, dir);
        let local = GpuRay {
            origin: o.to_array(),
            tmin: ray.tmin,
            dir: d.to_array(),
            tmax: limit,
            mask: ray.mask,
            flags: ray.flags,
            origin_lo: [0; 2],
        };
        let mesh = &scene.meshes[scene.instances.instances()[k].mesh as usize];
        let h = walk::trace::<L>(mesh, &local, scratch, stack);
        best.box_tests += h.box_tests;
        best.triangle_tests += h.triangle_tests;
        let id = |leaf: u32| r.prim_base + mesh.triangle_ids[leaf as usize];
        if mode == MODE_ALL {
            for e in &scratch[..h.count as usize] {
                let entry = GpuHitEntry {
                    prim: id(e.prim),
                    ..*e
                };
                limit = insert_hit(&mut best, list, entry, ray.tmax, &[]);
            }
            if h.overflow != 0 {
                best.overflow = 1;
            }
            if best.overflow != 0 {
                limit = list[list.len() - 1].t;
            }
            continue;
        }
        if h.prim == NO_HIT || !closest_accepts(&best, h.t, id(h.prim), &[]) {
            continue;
        }
        best.t = h.t;
        best.prim = id(h.prim);
        best.u = h.u;
        best.v = h.v;
        limit = h.t;
        if mode == MODE_ANY {
            break;
        }
    }
    if mode == MODE_ALL && best.count > 0 {
        let nearest = list[0];
        best.t = nearest.t;
        best.prim = nearest.prim;
        best.u = nearest.u;
        best.v = nearest.v;
    }
    best
}
