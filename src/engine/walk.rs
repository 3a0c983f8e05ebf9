//! One ray through the wide tree: four child boxes per SIMD test, children visited nearest first
//! from a small stack, leaves tested four triangles at a time.
//!
//! The answers are the twin's (`cpu::traverse`) bit for bit: each box test is `ray_box`'s
//! arithmetic in lanes, each triangle test is `ray_triangle` / `ray_triangle_watertight`'s, and
//! hits are accepted by the same rules, ties included (`cpu::traverse::accepts`), so the order in
//! which the tree is walked never shows in an answer. Only the b and i statistics differ: they
//! count this walk's box and triangle tests.

use super::lanes::Lanes;
use super::wide::{EMPTY, INNER, WIDTH, WideNode};
use crate::cpu::ray_box::{BOX_PAD, HUGE, MIN_DIR, safe_inverse};
use crate::cpu::ray_triangle::shear_for;
use crate::cpu::traverse::{closest_accepts, facing_allowed, insert_hit};
use crate::layout::{GpuHit, GpuHitEntry, GpuRay, GpuTriangle, MODE_ALL, MODE_ANY, NO_HIT};
use glam::Vec3;

/// What the walk reads: the wide nodes and the shared leaf-order triangle arrays.
#[derive(Clone, Copy, Debug)]
pub struct Scene<'a> {
    /// Wide nodes, root at 0 (empty for an empty scene).
    pub nodes: &'a [WideNode],
    /// Triangles in leaf order (`Bvh::triangles`).
    pub triangles: &'a [GpuTriangle],
    /// Scene triangle id of each leaf-order triangle (`Bvh::triangle_ids`), for the tie rule.
    pub triangle_ids: &'a [u32],
    /// Layer mask of each leaf-order triangle (ignored when empty).
    pub triangle_masks: &'a [u32],
    /// Watertight test instead of Möller–Trumbore.
    pub watertight: bool,
}

/// A pushed child: what it is and the near end of its box interval (padded, at least tmin).
#[derive(Clone, Copy, Debug, Default)]
pub struct Entry {
    child: u32,
    kind: u8,
    near: f32,
}

/// Stack entries needed for a tree `depth` wide levels deep (three pushed per level, plus one).
pub fn stack_size(depth: usize) -> usize {
    (WIDTH - 1) * depth + 1
}

/// The ray in lanes, set up once.
struct RayLanes<L: Lanes> {
    origin: [L; 3],
    inv: [L; 3],
    /// Per axis: the direction is below `MIN_DIR`, so the slab may leave the ray free.
    parallel: [bool; 3],
    origin_scalar: Vec3,
    tmin: L,
}

/// The twin's `ray_box` for four boxes: which children the ray meets within `[tmin, limit]`, and
/// each one's padded near distance.
#[inline(always)]
fn boxes4<L: Lanes>(node: &WideNode, r: &RayLanes<L>, limit: f32) -> (u32, L) {
    let mut near = [L::splat(0.0); 3];
    let mut far = [L::splat(0.0); 3];
    for a in 0..3 {
        let min = L::from_array(node.min[a]);
        let max = L::from_array(node.max[a]);
        let t0 = min.sub(r.origin[a]).mul(r.inv[a]);
        let t1 = max.sub(r.origin[a]).mul(r.inv[a]);
        near[a] = t0.min(t1);
        far[a] = t0.max(t1);
        if r.parallel[a] {
            let o = L::splat(r.origin_scalar[a]);
            let free = L::and(o.ge(min), o.le(max));
            near[a] = L::select(free, L::splat(-HUGE), near[a]);
            far[a] = L::select(free, L::splat(HUGE), far[a]);
        }
    }
    let t_near = near[0].max(near[1]).max(near[2]);
    let t_far = far[0].min(far[1]).min(far[2]);
    let pad = L::splat(BOX_PAD);
    let lo = t_near.sub(t_near.abs().mul(pad)).max(r.tmin);
    let hi = t_far.add(t_far.abs().mul(pad)).min(L::splat(limit));
    (L::bits(lo.le(hi)), lo)
}

/// Four triangles' vertices, lane `i` from triangle `first + i` (the last one repeated past
/// `count`).
#[inline(always)]
fn gather<L: Lanes>(triangles: &[GpuTriangle], first: usize, count: usize) -> [[L; 3]; 3] {
    let tri = |i: usize| &triangles[first + i.min(count - 1)];
    let (t0, t1, t2, t3) = (tri(0), tri(1), tri(2), tri(3));
    let lane = |f: fn(&GpuTriangle) -> [f32; 3], a: usize| {
        L::from_array([f(t0)[a], f(t1)[a], f(t2)[a], f(t3)[a]])
    };
    let vertex = |f: fn(&GpuTriangle) -> [f32; 3]| [lane(f, 0), lane(f, 1), lane(f, 2)];
    [vertex(|t| t.v0), vertex(|t| t.v1), vertex(|t| t.v2)]
}

#[inline(always)]
fn dot<L: Lanes>(a: [L; 3], b: [L; 3]) -> L {
    a[0].mul(b[0]).add(a[1].mul(b[1])).add(a[2].mul(b[2]))
}

#[inline(always)]
fn cross<L: Lanes>(a: [L; 3], b: [L; 3]) -> [L; 3] {
    [
        a[1].mul(b[2]).sub(b[1].mul(a[2])),
        a[2].mul(b[0]).sub(b[2].mul(a[0])),
        a[0].mul(b[1]).sub(b[0].mul(a[1])),
    ]
}

#[inline(always)]
fn sub3<L: Lanes>(a: [L; 3], b: [L; 3]) -> [L; 3] {
    [a[0].sub(b[0]), a[1].sub(b[1]), a[2].sub(b[2])]
}

/// Four triangle tests' results: lanes that hit, and t, u, v, det per lane.
struct Hits4<L: Lanes> {
    hit: L::Mask,
    t: L,
    u: L,
    v: L,
    det: L,
}

/// The twin's `ray_triangle_watertight` in lanes.
#[inline(always)]
fn watertight4<L: Lanes>(v: [[L; 3]; 3], origin: [L; 3], shear: &[[L; 3]; 3]) -> Hits4<L> {
    let a = sub3(v[0], origin);
    let b = sub3(v[1], origin);
    let c = sub3(v[2], origin);
    let [sx, sy, sz] = shear;
    let (ax, ay) = (dot(a, *sx), dot(a, *sy));
    let (bx, by) = (dot(b, *sx), dot(b, *sy));
    let (cx, cy) = (dot(c, *sx), dot(c, *sy));
    let u_edge = cx.mul(by).sub(cy.mul(bx));
    let v_edge = ax.mul(cy).sub(ay.mul(cx));
    let w_edge = bx.mul(ay).sub(by.mul(ax));
    let zero = L::splat(0.0);
    let negative = L::or(L::or(u_edge.lt(zero), v_edge.lt(zero)), w_edge.lt(zero));
    let positive = L::or(L::or(u_edge.gt(zero), v_edge.gt(zero)), w_edge.gt(zero));
    let det = u_edge.add(v_edge).add(w_edge);
    let miss = L::or(L::and(negative, positive), det.eq(zero));
    let t_scaled = u_edge
        .mul(dot(a, *sz))
        .add(v_edge.mul(dot(b, *sz)))
        .add(w_edge.mul(dot(c, *sz)));
    let inv_det = L::splat(1.0).div(det);
    Hits4 {
        hit: L::andnot(L::mask_from_bits(0xF), miss),
        t: t_scaled.mul(inv_det),
        u: v_edge.mul(inv_det),
        v: w_edge.mul(inv_det),
        det,
    }
}

/// The twin's `ray_triangle` (Möller–Trumbore) in lanes.
#[inline(always)]
fn moller_trumbore4<L: Lanes>(v: [[L; 3]; 3], origin: [L; 3], dir: [L; 3]) -> Hits4<L> {
    let e1 = sub3(v[1], v[0]);
    let e2 = sub3(v[2], v[0]);
    let p = cross(dir, e2);
    let det = dot(p, e1);
    let zero = L::splat(0.0);
    let inv_det = L::splat(1.0).div(det);
    let to_origin = sub3(origin, v[0]);
    let u = dot(p, to_origin).mul(inv_det);
    let q = cross(to_origin, e1);
    let v_ = dot(q, dir).mul(inv_det);
    let t = dot(q, e2).mul(inv_det);
    let inside = L::and(L::and(u.ge(zero), v_.ge(zero)), u.add(v_).le(L::splat(1.0)));
    Hits4 {
        hit: L::andnot(inside, det.eq(zero)),
        t,
        u,
        v: v_,
        det,
    }
}

/// Traces one kernel-frame ray: the twin's answer (and, in all-hits mode, its list), with this
/// walk's own b and i. `stack` holds at least [`stack_size`] entries.
#[inline(always)]
#[allow(
    clippy::neg_cmp_op_on_partial_ord,
    reason = "as in the twin: `!(tmin <= tmax)` also rejects NaN"
)]
pub fn trace<L: Lanes>(
    scene: &Scene<'_>,
    ray: &GpuRay,
    hit_list: &mut [GpuHitEntry],
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
    let cull = (ray.flags >> crate::layout::CULL_SHIFT) & 3;
    let origin = Vec3::from(ray.origin);
    let dir = Vec3::from(ray.dir);
    let inv = safe_inverse(dir);
    let r = RayLanes::<L> {
        origin: [0, 1, 2].map(|a| L::splat(origin[a])),
        inv: [0, 1, 2].map(|a| L::splat(inv[a])),
        parallel: [0, 1, 2].map(|a| dir[a].abs() < MIN_DIR),
        origin_scalar: origin,
        tmin: L::splat(ray.tmin),
    };
    let dir_lanes = [0, 1, 2].map(|a| L::splat(dir[a]));
    let shear = if scene.watertight {
        let s = shear_for(dir);
        s.rows().map(|row| [0, 1, 2].map(|a| L::splat(row[a])))
    } else {
        [[L::splat(0.0); 3]; 3]
    };
    let masks = scene.triangle_masks;
    let mut limit = ray.tmax;
    let mut top = 0usize;
    stack[0] = Entry {
        child: 0,
        kind: INNER,
        near: ray.tmin,
    };
    top += 1;
    'walk: while top > 0 {
        top -= 1;
        let entry = stack[top];
        if !(entry.near <= limit) {
            continue;
        }
        if entry.kind == INNER {
            let node = &scene.nodes[entry.child as usize];
            let occupied = node.occupied();
            best.box_tests += occupied.count_ones();
            let (bits, near) = boxes4(node, &r, limit);
            let mut bits = bits & occupied;
            if bits == 0 {
                continue;
            }
            let near = near.to_array();
            // Push the hit children farthest first, so the nearest is popped next.
            let mut order = [0usize; WIDTH];
            let mut n = 0;
            while bits != 0 {
                let lane = bits.trailing_zeros() as usize;
                bits &= bits - 1;
                let mut j = n;
                while j > 0 && near[order[j - 1]] < near[lane] {
                    order[j] = order[j - 1];
                    j -= 1;
                }
                order[j] = lane;
                n += 1;
            }
            for &lane in &order[..n] {
                stack[top] = Entry {
                    child: node.child[lane],
                    kind: node.kind[lane],
                    near: near[lane],
                };
                top += 1;
            }
            continue;
        }
        debug_assert!(entry.kind != EMPTY);
        // A leaf: its triangles, four at a time.
        let first = entry.child as usize;
        let count = usize::from(entry.kind);
        let mut k = 0;
        while k < count {
            let group = (count - k).min(WIDTH);
            let mut lanes = (1u32 << group) - 1;
            if !masks.is_empty() {
                for i in 0..group {
                    if masks[first + k + i] & ray.mask == 0 {
                        lanes &= !(1 << i);
                    }
                }
                if lanes == 0 {
                    k += group;
                    continue;
                }
            }
            best.triangle_tests += lanes.count_ones();
            let v = gather::<L>(scene.triangles, first + k, group);
            let h = if scene.watertight {
                watertight4(v, r.origin, &shear)
            } else {
                moller_trumbore4(v, r.origin, dir_lanes)
            };
            let in_range = L::and(h.t.gt(r.tmin), h.t.le(L::splat(limit)));
            let mut hits = L::bits(L::and(h.hit, in_range)) & lanes;
            if hits != 0 {
                let (t, u, v, det) = (
                    h.t.to_array(),
                    h.u.to_array(),
                    h.v.to_array(),
                    h.det.to_array(),
                );
                while hits != 0 {
                    let lane = hits.trailing_zeros() as usize;
                    hits &= hits - 1;
                    let prim = (first + k + lane) as u32;
                    if !facing_allowed(det[lane], cull) || !(t[lane] <= limit) {
                        continue;
                    }
                    if mode == MODE_ALL {
                        let e = GpuHitEntry {
                            t: t[lane],
                            prim,
                            u: u[lane],
                            v: v[lane],
                        };
                        limit = insert_hit(&mut best, hit_list, e, ray.tmax, scene.triangle_ids);
                    } else {
                        if !closest_accepts(&best, t[lane], prim, scene.triangle_ids) {
                            continue;
                        }
                        best.t = t[lane];
                        best.prim = prim;
                        best.u = u[lane];
                        best.v = v[lane];
                        limit = t[lane];
                        if mode == MODE_ANY {
                            break 'walk;
                        }
                    }
                }
            }
            k += group;
        }
    }
    if mode == MODE_ALL && best.count > 0 {
        let nearest = hit_list[0];
        best.t = nearest.t;
        best.prim = nearest.prim;
        best.u = nearest.u;
        best.v = nearest.v;
    }
    best
}
