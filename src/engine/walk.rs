//! Rays through the wide tree: eight child boxes per SIMD test, children visited nearest
//! first from a small stack, leaves tested eight triangles at a time. Incoherent rays walk
//! [`INTERLEAVED`] at a time, a node each in turn, each ray's next node prefetched, so one thread
//! waits on several cache misses at once; coherent groups of [`PACKET`] rays share one walk.
//!
//! The answers are the twin's (`cpu::traverse`) bit for bit: each box test is `box_interval`
//! and `meets`'s arithmetic in lanes, each triangle test is `ray_triangle` / `ray_triangle_watertight`'s, and
//! hits are accepted by the same rules, ties included (`cpu::traverse::accepts`), so the order in
//! which the tree is walked never shows in an answer. Only the b and i statistics differ: they
//! count this walk's box and triangle tests.
#![allow(
    clippy::neg_cmp_op_on_partial_ord,
    reason = "as in the twin: `!(a <= b)` also rejects NaN"
)]

use super::lanes8::{LANES, Lanes8};
use super::wide::{EMPTY, INNER, WIDTH, WideNode};
use crate::cpu::ray_box::{BOX_PAD, HUGE, MIN_DIR, safe_inverse};
use crate::cpu::ray_triangle::{shear_for, shear_rows};
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
    /// Whether coherent groups of rays are traced as packets.
    pub packets: bool,
    /// The largest side of the root's box, for the packet test ([`group_of`]).
    pub size: f32,
    /// Whether incoherent rays walk interleaved ([`trace_interleaved`], the engine's default)
    /// rather than one by one ([`trace`]). Interleaved walks were 20–46% faster on the dragon
    /// and the Jacksboro DEM, whose walks wait on the L3 and memory, and 10% slower on the bunny
    /// while a node's children were sorted with branches; with the sorting network
    /// ([`push_children`]) they are faster on every scene measured, the bunny (+11%) and a
    /// 96 × 96 grid (+20%) included (BENCHMARKS.md).
    pub interleave: bool,
}

/// A pushed child: what it is, the node and slot that hold its box (the frustum walk tests a
/// leaf's box again ray by ray), and the near end of its box interval (padded, at least tmin).
/// Sixteen bytes, as [`Lanes8::far_first`] writes them.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Entry {
    child: u32,
    kind: u8,
    lane: u8,
    reserved: u16,
    near: f32,
    node: u32,
}

/// A pushed child of the single-ray walks: the child and its kind in one word (`child << 4 |
/// kind`, an inner child's kind written as 0), and the near end of its box interval (padded, at
/// least tmin). Eight bytes, as [`Lanes8::far_first_packed`] writes them: half an [`Entry`],
/// whose node and lane only the frustum walk reads. Measured A/B (BENCHMARKS.md): the
/// interleaved walks of incoherent rays ran 5–7% faster than on sixteen-byte entries.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Pushed {
    word: u32,
    near: f32,
}

/// Children (node indices, leaves' first triangles, instances) a [`Pushed`] word holds: below
/// 2^28 ([`crate::engine::wide::WideBvh::collapse`] refuses larger trees).
pub const MAX_CHILDREN: u64 = 1 << 28;

const _: () = assert!(
    INNER == 16 && (crate::layout::MAX_LEAF_SIZE as u8) < 16,
    "a leaf's count fits four bits, and an inner child's kind is 16 (written as 0)"
);

impl Pushed {
    #[inline(always)]
    fn new(child: u32, kind: u8, near: f32) -> Self {
        Pushed {
            word: child << 4 | u32::from(kind & 15),
            near,
        }
    }

    #[inline(always)]
    fn child(self) -> u32 {
        self.word >> 4
    }

    #[inline(always)]
    fn kind(self) -> u8 {
        let code = (self.word & 15) as u8;
        code | u8::from(code == 0) << 4
    }
}

/// Stack entries needed for a tree `depth` wide levels deep (at most `WIDTH - 1` children pushed
/// per level, the nearest being visited next, plus one).
pub fn stack_size(depth: usize) -> usize {
    // `WIDTH` more: a sorted node writes all its lanes ([`Lanes8::far_first`]).
    (WIDTH - 1) * depth + 1 + WIDTH
}

/// What the box test needs of a ray, set up once: its origin and inverse direction in lanes
/// (loaded at every node; broadcasting them there measured 4% slower on the bunny), the rest as
/// scalars.
struct RayLanes<L: Lanes8> {
    origin: [L; 3],
    inv: [L; 3],
    /// Per axis: the direction is below `MIN_DIR`, so the slab may leave the ray free.
    parallel: [bool; 3],
    tmin: f32,
}

impl<L: Lanes8> RayLanes<L> {
    /// `ray`'s box-test set-up, with its inverse direction `inv` (`safe_inverse`'s, or
    /// [`Eight`]'s lanes of it): what its walk state holds, and the packet walk's root test
    /// made before the states (the same bits either way).
    #[inline(always)]
    fn new(ray: &GpuRay, inv: Vec3) -> Self {
        let origin = Vec3::from(ray.origin);
        let dir = Vec3::from(ray.dir);
        // Written out lane by lane (not `array::map`, which is not always inlined here).
        let splat3 = |v: Vec3| [L::splat(v.x), L::splat(v.y), L::splat(v.z)];
        RayLanes {
            origin: splat3(origin),
            inv: splat3(inv),
            parallel: [
                dir.x.abs() < MIN_DIR,
                dir.y.abs() < MIN_DIR,
                dir.z.abs() < MIN_DIR,
            ],
            tmin: ray.tmin,
        }
    }
}

/// The twin's box test (`box_interval`, `meets`) for a node's eight boxes: which children the ray meets within
/// `[tmin, limit]`, and each one's padded near distance.
#[inline(always)]
fn boxes<L: Lanes8>(node: &WideNode, r: &RayLanes<L>, limit: f32) -> (u32, L) {
    let (met, lo) = boxes_met(node, r, limit);
    (L::bits(met), lo)
}

/// [`boxes`] with the children met as a lane mask.
#[inline(always)]
fn boxes_met<L: Lanes8>(node: &WideNode, r: &RayLanes<L>, limit: f32) -> (L::Mask, L) {
    // Written out (not `array::map`, whose closure is not always inlined here).
    let min = [
        L::load(&node.min[0]),
        L::load(&node.min[1]),
        L::load(&node.min[2]),
    ];
    let max = [
        L::load(&node.max[0]),
        L::load(&node.max[1]),
        L::load(&node.max[2]),
    ];
    let (lo, hi) = intervals(min, max, r);
    let lo = lo.max(L::splat(r.tmin));
    let hi = hi.min(L::splat(limit));
    (lo.le(hi), lo)
}

/// The twin's `box_interval` for eight boxes: the ray's padded slab interval over each, before
/// `tmin` and the limit cut it.
#[inline(always)]
fn intervals<L: Lanes8>(min: [L; 3], max: [L; 3], r: &RayLanes<L>) -> (L, L) {
    let mut near = [L::splat(0.0); 3];
    let mut far = [L::splat(0.0); 3];
    for a in 0..3 {
        let (min, max) = (min[a], max[a]);
        let (o, inv) = (r.origin[a], r.inv[a]);
        let t0 = min.sub(o).mul(inv);
        let t1 = max.sub(o).mul(inv);
        near[a] = t0.min(t1);
        far[a] = t0.max(t1);
        if r.parallel[a] {
            let free = L::and(o.ge(min), o.le(max));
            near[a] = L::select(free, L::splat(-HUGE), near[a]);
            far[a] = L::select(free, L::splat(HUGE), far[a]);
        }
    }
    let t_near = near[0].max(near[1]).max(near[2]);
    let t_far = far[0].min(far[1]).min(far[2]);
    let pad = L::splat(BOX_PAD);
    (
        t_near.sub(t_near.abs().mul(pad)),
        t_far.add(t_far.abs().mul(pad)),
    )
}

#[inline(always)]
fn dot<L: Lanes8>(a: [L; 3], b: [L; 3]) -> L {
    a[0].mul(b[0]).add(a[1].mul(b[1])).add(a[2].mul(b[2]))
}

#[inline(always)]
fn cross<L: Lanes8>(a: [L; 3], b: [L; 3]) -> [L; 3] {
    [
        a[1].mul(b[2]).sub(b[1].mul(a[2])),
        a[2].mul(b[0]).sub(b[2].mul(a[0])),
        a[0].mul(b[1]).sub(b[0].mul(a[1])),
    ]
}

#[inline(always)]
fn sub3<L: Lanes8>(a: [L; 3], b: [L; 3]) -> [L; 3] {
    [a[0].sub(b[0]), a[1].sub(b[1]), a[2].sub(b[2])]
}

/// Eight triangle tests' results: lanes that hit, and t, u, v, det per lane.
struct Hits<L: Lanes8> {
    /// Bit `i` set when lane `i` hit.
    hit: u32,
    t: L,
    u: L,
    v: L,
    det: L,
}

/// The twin's `ray_triangle_watertight` in lanes; `None` when none of the `lanes` passes the
/// edge tests (then no division is made: most leaf tests of a ray miss every triangle).
#[inline(always)]
fn watertight<L: Lanes8>(
    v: [[L; 3]; 3],
    origin: [L; 3],
    shear: &[[L; 3]; 3],
    lanes: u32,
) -> Option<Hits<L>> {
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
    let hit = !L::bits(miss) & lanes;
    if hit == 0 {
        return None;
    }
    let t_scaled = u_edge
        .mul(dot(a, *sz))
        .add(v_edge.mul(dot(b, *sz)))
        .add(w_edge.mul(dot(c, *sz)));
    let inv_det = L::splat(1.0).div(det);
    Some(Hits {
        hit,
        t: t_scaled.mul(inv_det),
        u: v_edge.mul(inv_det),
        v: w_edge.mul(inv_det),
        det,
    })
}

/// The twin's `ray_triangle` (Möller–Trumbore) in lanes.
#[inline(always)]
fn moller_trumbore<L: Lanes8>(v: [[L; 3]; 3], origin: [L; 3], dir: [L; 3]) -> Hits<L> {
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
    Hits {
        hit: L::bits(L::andnot(inside, det.eq(zero))),
        t,
        u,
        v: v_,
        det,
    }
}

/// The lanes of a group of `group` leaf-order triangles from `first` that a ray with layer
/// `mask` may hit (bit `i`: triangle `first + i`).
#[inline(always)]
fn lanes_for(scene: &Scene<'_>, mask: u32, first: usize, group: usize) -> u32 {
    let mut lanes = (1u32 << group) - 1;
    if !scene.triangle_masks.is_empty() {
        for i in 0..group {
            if scene.triangle_masks[first + i] & mask == 0 {
                lanes &= !(1 << i);
            }
        }
    }
    lanes
}

/// One ray's walk state: the ray set up for the box and triangle tests, its best hit so far and
/// its current limit.
pub struct RayState<'r, L: Lanes8> {
    ray: &'r GpuRay,
    r: RayLanes<L>,
    dir: [f32; 3],
    /// The watertight test's shear rows (zero for Möller–Trumbore).
    shear: [[f32; 3]; 3],
    /// In an instance's mesh: the world ray's interval over the instance's leaf box in the
    /// top tree, which bounds its hits' t as the triangles' own boxes do (`ray_box::clip`).
    clip: Clip<'r>,
    mode: u32,
    cull: u32,
    /// The answer so far (and this walk's b and i).
    pub best: GpuHit,
    /// Hits need t in (tmin, limit]; the limit shrinks to the nearest hit (closest), or to the
    /// farthest kept hit once the all-hits list is full and has overflowed.
    pub limit: f32,
    /// Any-hit mode found its hit: the walk is over for this ray.
    pub done: bool,
}

/// Eight rays' inverse directions and watertight shear rows, one ray a lane, made in lanes:
/// `safe_inverse`'s and `shear_for`'s operations, lane for lane, so bit for bit theirs (the
/// choice of axes by selects, as in [`shear_rows`]), with one eight-lane division where each
/// ray took its own. Measured A/B (BENCHMARKS.md): the divisions and `shear_for` were half of
/// a camera packet's set-up.
pub struct Eight {
    /// Per axis, each ray's inverse direction.
    inv: [[f32; LANES]; 3],
    /// Per shear row and component, each ray's value (zero for Möller–Trumbore).
    rows: [[[f32; LANES]; 3]; 3],
}

impl Eight {
    /// Sets up the first [`LANES`] of `rays`, their directions gathered a float at a time: the
    /// interleaved single-ray walks' set-up. With the rays read in by one transpose
    /// ([`Lanes8::rays`]) as the packets are, the bunny's incoherent rays traced 3–4% slower
    /// (BENCHMARKS.md, 2026-11-27 late morning).
    #[inline(always)]
    fn new<L: Lanes8>(scene: &Scene<'_>, rays: &[GpuRay]) -> Self {
        let mut d = [[0.0f32; LANES]; 3];
        for (i, ray) in rays[..LANES].iter().enumerate() {
            for (a, axis) in d.iter_mut().enumerate() {
                axis[i] = ray.dir[a];
            }
        }
        Self::of_directions::<L>(scene, [L::load(&d[0]), L::load(&d[1]), L::load(&d[2])])
    }

    /// [`Eight::new`] for a group whose rays are in lanes ([`Lanes8::rays`]): the packet and
    /// frustum walks, whose group [`group_of`] read in the same way.
    #[inline(always)]
    fn of_columns<L: Lanes8>(scene: &Scene<'_>, columns: &[L; 8]) -> Self {
        Self::of_directions::<L>(scene, [columns[4], columns[5], columns[6]])
    }

    /// [`Eight::new`] for the directions `d` in lanes.
    #[inline(always)]
    fn of_directions<L: Lanes8>(scene: &Scene<'_>, d: [L; 3]) -> Self {
        let (zero, one) = (L::splat(0.0), L::splat(1.0));
        // `safe_inverse`: sign / max(|d|, MIN_DIR).
        let inverse = |d: L| {
            let sign = L::select(d.ge(zero), one, L::splat(-1.0));
            sign.div(d.abs().max(L::splat(MIN_DIR))).to_array()
        };
        let inv = [inverse(d[0]), inverse(d[1]), inverse(d[2])];
        let mut rows = [[[0.0f32; LANES]; 3]; 3];
        if scene.watertight {
            let [ax, ay, az] = [d[0].abs(), d[1].abs(), d[2].abs()];
            // `shear_for`'s axis: x when |x| is at least |y| and |z|, else y when |y| >= |z|.
            let x_first = L::and(ax.ge(ay), ax.ge(az));
            let y_first = L::andnot(ay.ge(az), x_first);
            let pick = |x: L, y: L, z: L| L::select(x_first, x, L::select(y_first, y, z));
            let dz = pick(d[0], d[1], d[2]);
            // The next two axes after it, cyclically; swapped when `d[kz] < 0`.
            let negative = dz.lt(zero);
            let (dx0, dy0) = (pick(d[1], d[2], d[0]), pick(d[2], d[0], d[1]));
            let qx = L::select(negative, dy0, dx0).div(dz);
            let qy = L::select(negative, dx0, dy0).div(dz);
            let (q0, q1) = (zero.div(dz), one.div(dz));
            // Per component j: whether it is kz, and the unit vectors e_kz, e_kx, e_ky.
            let all = zero.eq(zero);
            let is_kz = [
                x_first,
                y_first,
                L::andnot(L::andnot(all, x_first), y_first),
            ];
            let ez = [
                L::select(is_kz[0], one, zero),
                L::select(is_kz[1], one, zero),
                L::select(is_kz[2], one, zero),
            ];
            // kx follows kz cyclically and ky follows kx, unless swapped.
            let ex = [
                L::select(negative, ez[1], ez[2]),
                L::select(negative, ez[2], ez[0]),
                L::select(negative, ez[0], ez[1]),
            ];
            let ey = [
                L::select(negative, ez[2], ez[1]),
                L::select(negative, ez[0], ez[2]),
                L::select(negative, ez[1], ez[0]),
            ];
            for j in 0..3 {
                rows[0][j] = ex[j].sub(qx.mul(ez[j])).to_array();
                rows[1][j] = ey[j].sub(qy.mul(ez[j])).to_array();
                rows[2][j] = L::select(is_kz[j], q1, q0).to_array();
            }
        }
        Eight { inv, rows }
    }
}

impl<'r, L: Lanes8> RayState<'r, L> {
    /// Sets `ray` up; `None` when it is never traced (an empty scene, an empty range).
    /// `coherent`: the ray is one of a group whose branches predict (packets, camera rays),
    /// whose shear rows are made by `shear_for`'s branches; incoherent rays take
    /// [`shear_rows`], without them. Measured A/B (BENCHMARKS.md): branch-free, incoherent
    /// rays traced 3–6% faster and camera rays 5% slower.
    #[inline(always)]
    pub fn new(scene: &Scene<'_>, ray: &'r GpuRay, coherent: bool) -> (GpuHit, Option<Self>) {
        let mut state = None;
        let miss = Self::new_in(scene, ray, coherent, &mut state);
        (miss, state)
    }

    /// The answer `ray` starts with (a miss at its `tmax`), and whether it is traced at all
    /// (not in an empty scene, nor with an empty range: `tmin <= tmax` also rejects NaN).
    #[inline(always)]
    fn first_answer(scene: &Scene<'_>, ray: &GpuRay) -> (GpuHit, bool) {
        let best = GpuHit {
            t: ray.tmax,
            prim: NO_HIT,
            ..GpuHit::default()
        };
        (best, !scene.nodes.is_empty() && ray.tmin <= ray.tmax)
    }

    /// [`RayState::new`] written into `slot` (left `None` for a ray never traced), returning
    /// the ray's answer so far: made in its place, where a returned state was built aside and
    /// copied (a packet's eight: `memmove` was 3% of a camera pick's samples).
    #[inline(always)]
    pub fn new_in(
        scene: &Scene<'_>,
        ray: &'r GpuRay,
        coherent: bool,
        slot: &mut Option<Self>,
    ) -> GpuHit {
        let (best, traced) = Self::first_answer(scene, ray);
        if !traced {
            *slot = None;
            return best;
        }
        let dir = Vec3::from(ray.dir);
        let shear = if !scene.watertight {
            [[0.0; 3]; 3]
        } else if coherent {
            let [x, y, z] = shear_for(dir).rows();
            [x.to_array(), y.to_array(), z.to_array()]
        } else {
            shear_rows(dir)
        };
        Self::fill(ray, safe_inverse(dir), shear, best, slot);
        best
    }

    /// Writes the state of `ray`, whose inverse direction and shear rows are made, into `slot`.
    #[inline(always)]
    fn fill(
        ray: &'r GpuRay,
        inv: Vec3,
        shear: [[f32; 3]; 3],
        best: GpuHit,
        slot: &mut Option<Self>,
    ) {
        *slot = Some(Self {
            ray,
            r: RayLanes::new(ray, inv),
            dir: Vec3::from(ray.dir).to_array(),
            shear,
            clip: Clip::None,
            mode: ray.flags & 3,
            cull: (ray.flags >> crate::layout::CULL_SHIFT) & 3,
            best,
            limit: ray.tmax,
            done: false,
        });
    }

    /// [`RayState::new_in`] for eight rays at once, whose [`Eight`] is made, into `slots`,
    /// their answers so far into `out`; returns the rays traced (bit `i`: ray `i`).
    #[inline(always)]
    fn new_eight(
        scene: &Scene<'_>,
        rays: &'r [GpuRay],
        eight: &Eight,
        slots: &mut [Option<Self>; LANES],
        out: &mut [GpuHit],
    ) -> u32 {
        let mut alive = 0;
        for (i, ray) in rays[..LANES].iter().enumerate() {
            out[i] = Self::from_eight(scene, ray, eight, i, &mut slots[i]);
            alive |= u32::from(slots[i].is_some()) << i;
        }
        alive
    }

    /// [`RayState::new_in`] for lane `i` of `eight`, which set `ray` up.
    #[inline(always)]
    fn from_eight(
        scene: &Scene<'_>,
        ray: &'r GpuRay,
        eight: &Eight,
        i: usize,
        slot: &mut Option<Self>,
    ) -> GpuHit {
        let (best, traced) = Self::first_answer(scene, ray);
        if !traced {
            *slot = None;
            return best;
        }
        let (inv, rows) = (&eight.inv, &eight.rows);
        let at = |row: &[[f32; LANES]; 3]| [row[0][i], row[1][i], row[2][i]];
        let inv_i = Vec3::new(inv[0][i], inv[1][i], inv[2][i]);
        Self::fill(
            ray,
            inv_i,
            [at(&rows[0]), at(&rows[1]), at(&rows[2])],
            best,
            slot,
        );
        best
    }

    /// The ray being walked.
    #[inline(always)]
    pub fn ray(&self) -> &'r GpuRay {
        self.ray
    }

    /// Tests the leaf's `count` triangles from leaf-order `first`, eight at a time, accepting
    /// hits by the twin's rules (ties included).
    #[inline(always)]
    pub fn leaf(
        &mut self,
        scene: &Scene<'_>,
        first: usize,
        count: usize,
        hit_list: &mut [GpuHitEntry],
    ) {
        let mut k = 0;
        while k < count {
            let group = (count - k).min(LANES);
            let lanes = lanes_for(scene, self.ray.mask, first + k, group);
            if lanes != 0 {
                let v = L::gather(scene.triangles, first + k, group);
                self.group(scene, &v, first + k, lanes, hit_list);
                if self.done {
                    return;
                }
            }
            k += group;
        }
    }

    /// Tests one gathered group of up to eight triangles (lane `i` is leaf-order triangle
    /// `first + i`; only `lanes` count), accepting hits by the twin's rules (ties included).
    #[inline(always)]
    fn group(
        &mut self,
        scene: &Scene<'_>,
        v: &[[L; 3]; 3],
        first: usize,
        lanes: u32,
        hit_list: &mut [GpuHitEntry],
    ) {
        let ray = self.ray;
        self.best.triangle_tests += lanes.count_ones();
        // Written out lane by lane (not `array::map`, which is not always inlined here).
        let splat3 = |v: &[f32; 3]| [L::splat(v[0]), L::splat(v[1]), L::splat(v[2])];
        let origin = self.r.origin;
        let h = if scene.watertight {
            let [x, y, z] = &self.shear;
            watertight(*v, origin, &[splat3(x), splat3(y), splat3(z)], lanes)
        } else {
            Some(moller_trumbore(*v, origin, splat3(&self.dir)))
        };
        let Some(h) = h else {
            return;
        };
        // Each lane's t kept within the ray's interval over its triangle's own box (cut by the
        // instance's leaf box in a mesh), as the twin's `ray_box::hit_t` keeps it; a lane whose
        // interval is empty does not hit. In lanes for the whole group: taken lane by lane with
        // the twin's functions, for the lanes that pass the edge tests, the walk was 8–12% slower.
        let low = |a: usize| v[0][a].min(v[1][a]).min(v[2][a]);
        let high = |a: usize| v[0][a].max(v[1][a]).max(v[2][a]);
        let (min, max) = ([low(0), low(1), low(2)], [high(0), high(1), high(2)]);
        let (mut lo, mut hi) = intervals(min, max, &self.r);
        if let Some((clip_lo, clip_hi)) = self.clip.interval() {
            // `ray_box::clip`: where the two meet, both; else the leaf's; an empty one stays.
            let (clip_lo, clip_hi) = (L::splat(clip_lo), L::splat(clip_hi));
            let both_lo = L::select(clip_lo.gt(lo), clip_lo, lo);
            let both_hi = L::select(clip_hi.lt(hi), clip_hi, hi);
            let meet = both_lo.le(both_hi);
            let own = lo.le(hi);
            lo = L::select(meet, both_lo, L::select(own, clip_lo, lo));
            hi = L::select(meet, both_hi, L::select(own, clip_hi, hi));
        }
        // `ray_box::hit_t`: a zero lower end as +0.
        let zero = L::splat(0.0);
        let lower = L::select(lo.eq(zero), zero, lo);
        let t = L::select(h.t.lt(lo), lower, L::select(h.t.gt(hi), hi, h.t));
        let in_range = L::and(
            lo.le(hi),
            L::and(t.gt(L::splat(self.r.tmin)), t.le(L::splat(self.limit))),
        );
        let mut hits = h.hit & L::bits(in_range) & lanes;
        if hits == 0 {
            return;
        }
        let (t, u, v, det) = (
            t.to_array(),
            h.u.to_array(),
            h.v.to_array(),
            h.det.to_array(),
        );
        while hits != 0 {
            let lane = hits.trailing_zeros() as usize;
            hits &= hits - 1;
            let prim = (first + lane) as u32;
            let t = t[lane];
            if !facing_allowed(det[lane], self.cull) || !(t <= self.limit) {
                continue;
            }
            if self.mode == MODE_ALL {
                let e = GpuHitEntry {
                    t,
                    prim,
                    u: u[lane],
                    v: v[lane],
                };
                self.limit = insert_hit(&mut self.best, hit_list, e, ray.tmax, scene.triangle_ids);
            } else {
                if !closest_accepts(&self.best, t, prim, scene.triangle_ids) {
                    continue;
                }
                self.best.t = t;
                self.best.prim = prim;
                self.best.u = u[lane];
                self.best.v = v[lane];
                self.limit = t;
                if self.mode == MODE_ANY {
                    self.done = true;
                    return;
                }
            }
        }
    }

    /// The answer: in all-hits mode the record carries the list's first entry.
    #[inline(always)]
    pub fn finish(mut self, hit_list: &[GpuHitEntry]) -> GpuHit {
        if self.mode == MODE_ALL && self.best.count > 0 {
            let nearest = hit_list[0];
            self.best.t = nearest.t;
            self.best.prim = nearest.prim;
            self.best.u = nearest.u;
            self.best.v = nearest.v;
        }
        self.best
    }
}

/// What the walk does at a leaf: `visit(state, first, count, list)` for the leaf child
/// `first` of `count` (a trait, not a closure: its `#[inline(always)]` method is compiled into
/// the caller with the caller's target features, where a closure would be a call).
pub trait Leaves<L: Lanes8> {
    /// Visits one leaf; may lower `state.limit`, set `state.best` and `state.done`.
    fn visit(
        &mut self,
        state: &mut RayState<'_, L>,
        first: u32,
        count: usize,
        list: &mut [GpuHitEntry],
    );
}

/// The leaves of a triangle tree: each tested eight triangles at a time.
struct Triangles<'s, 'a>(&'s Scene<'a>);

impl<L: Lanes8> Leaves<L> for Triangles<'_, '_> {
    #[inline(always)]
    fn visit(
        &mut self,
        st: &mut RayState<'_, L>,
        first: u32,
        count: usize,
        list: &mut [GpuHitEntry],
    ) {
        st.leaf(self.0, first as usize, count, list);
    }
}

/// One ray's walk, resumable a node at a time ([`Walk::step`]), which [`trace_interleaved`] runs
/// for several rays in turn.
struct Walk<'r, L: Lanes8> {
    st: RayState<'r, L>,
    /// The node or leaf visited next: the root, then the nearest child met (kept out of the
    /// stack, so a descent costs no push and pop), then the nearest pushed entry still in range.
    child: u32,
    kind: u8,
    /// Entries on this ray's stack.
    top: usize,
}

/// Asks the cache for the start of what visiting `child` will read: a node's first three
/// lines (its boxes), or a leaf's first three lines of triangles. Three measured faster than the
/// whole node or leaf, and than one or two lines (BENCHMARKS.md, "What changed").
#[inline(always)]
fn prefetch(scene: &Scene<'_>, child: u32, kind: u8) {
    let start = if kind == INNER {
        scene.nodes.as_ptr().wrapping_add(child as usize) as *const u8
    } else {
        scene.triangles.as_ptr().wrapping_add(child as usize) as *const u8
    };
    crate::prefetch::bytes(start, 129);
}

/// The children a node's test met, in the order they are walked: the nearest is visited next
/// (kept out of the stack, so a descent costs no push and pop), the others pushed farthest first.
struct Order {
    /// The lanes to push, farthest first (equal distances in lane order).
    push: [u8; WIDTH],
    /// How many of `push` are used.
    count: usize,
    /// The lane visited next.
    next: usize,
}

/// Orders the children met, `met` (lane bits, at least one set), by their `near` distances.
#[inline(always)]
fn nearest_first(mut met: u32, near: &[f32; WIDTH]) -> Order {
    debug_assert!(met != 0 && met < 1 << WIDTH);
    // Lanes are below `WIDTH`; the masks tell the compiler, so no bounds checks remain.
    let lane_of = |bits: u32| (bits.trailing_zeros() as usize) & (WIDTH - 1);
    let mut order = Order {
        push: [0; WIDTH],
        count: 0,
        next: lane_of(met),
    };
    met &= met - 1;
    if met == 0 {
        // One met: go straight down.
        return order;
    }
    let (first, second) = (order.next, lane_of(met));
    met &= met - 1;
    if met == 0 {
        // Two met, the commonest case after one: what the sort below gives two.
        (order.push[0], order.next) = if near[first] < near[second] {
            (second as u8, first)
        } else {
            (first as u8, second)
        };
        order.count = 1;
        return order;
    }
    // An insertion sort, farthest first; the last is visited next.
    let mut sorted = [0u8; WIDTH];
    sorted[0] = first as u8;
    let mut n = 1;
    met |= 1 << second;
    while met != 0 {
        let lane = lane_of(met);
        met &= met - 1;
        let mut j = n;
        while j > 0 && near[usize::from(sorted[j - 1])] < near[lane] {
            sorted[j] = sorted[j - 1];
            j -= 1;
        }
        sorted[j] = lane as u8;
        n += 1;
    }
    order.next = usize::from(sorted[n - 1]);
    order.push = sorted;
    order.count = n - 1;
    order
}

/// Pushes the children `met` (lane bits, at least one set) of node `at` onto `stack` above
/// `top`, farthest first by their `near` distances, all but the nearest, which is returned with
/// the new top: by a sorting network where the lanes have one ([`Lanes8::far_first`]: no
/// branches), else by [`nearest_first`]. `stack` has `WIDTH` entries to spare above `top`.
///
/// With `one_by_branch`, a lone child met goes straight down by a branch first. Measured A/B
/// (BENCHMARKS.md): the network traced incoherent rays 20–55% faster than the insertion sort on
/// the dragon and the soup, and the branch costs the interleaved walks of such rays 5–9%, so
/// they go without it; rays whose branches predict want it: camera rays walked one at a time
/// through an instanced field were 15% slower with the network alone and are level with it,
/// and frustum packets trace 3–4% faster with it.
#[inline(always)]
fn push_children<L: Lanes8, E: StackEntry>(
    stack: &mut [E],
    top: usize,
    node: &WideNode,
    at: u32,
    met: u32,
    near: L,
    one_by_branch: bool,
) -> (usize, usize) {
    if one_by_branch && met & (met - 1) == 0 {
        return (top, (met.trailing_zeros() as usize) & (WIDTH - 1));
    }
    let spare: &mut [E; WIDTH] = (&mut stack[top..top + WIDTH])
        .try_into()
        .expect("WIDTH entries");
    if let Some(next) = E::far_first(near, met, node, at, spare) {
        return (top + met.count_ones() as usize - 1, next);
    }
    let near = near.to_array();
    let order = nearest_first(met, &near);
    for (slot, &lane) in spare.iter_mut().zip(&order.push[..order.count]) {
        let lane = usize::from(lane);
        *slot = E::of(node, lane, near[lane], at);
    }
    (top + order.count, order.next)
}

/// What a walk's stack holds: the frustum walk's [`Entry`] or the single-ray walks' [`Pushed`].
trait StackEntry: Copy {
    /// Child slot `lane` of `node` (node index `at`), met at `near`.
    fn of(node: &WideNode, lane: usize, near: f32, at: u32) -> Self;
    /// [`Lanes8::far_first`] or [`Lanes8::far_first_packed`], into these entries.
    fn far_first<L: Lanes8>(
        near: L,
        met: u32,
        node: &WideNode,
        at: u32,
        out: &mut [Self; WIDTH],
    ) -> Option<usize>;
}

impl StackEntry for Entry {
    #[inline(always)]
    fn of(node: &WideNode, lane: usize, near: f32, at: u32) -> Self {
        Entry {
            child: node.child[lane],
            kind: node.kind[lane],
            lane: lane as u8,
            reserved: 0,
            near,
            node: at,
        }
    }

    #[inline(always)]
    fn far_first<L: Lanes8>(
        near: L,
        met: u32,
        node: &WideNode,
        at: u32,
        out: &mut [Self; WIDTH],
    ) -> Option<usize> {
        L::far_first(near, met, node, at, bytemuck::cast_mut(out))
    }
}

impl StackEntry for Pushed {
    #[inline(always)]
    fn of(node: &WideNode, lane: usize, near: f32, _: u32) -> Self {
        Pushed::new(node.child[lane], node.kind[lane], near)
    }

    #[inline(always)]
    fn far_first<L: Lanes8>(
        near: L,
        met: u32,
        node: &WideNode,
        _: u32,
        out: &mut [Self; WIDTH],
    ) -> Option<usize> {
        L::far_first_packed(near, met, node, bytemuck::cast_mut(out))
    }
}

impl<'r, L: Lanes8> Walk<'r, L> {
    /// Visits the next node or leaf and chooses the one after it (prefetched when `AHEAD`: the
    /// interleaved walks visit it a while later); `false` when the walk is over.
    #[inline(always)]
    fn step<const AHEAD: bool>(
        &mut self,
        scene: &Scene<'_>,
        stack: &mut [Pushed],
        hit_list: &mut [GpuHitEntry],
        leaf: &mut impl Leaves<L>,
        one_by_branch: bool,
    ) -> bool {
        let st = &mut self.st;
        if self.kind == INNER {
            let node = &scene.nodes[self.child as usize];
            let occupied = u32::from(node.occupied);
            st.best.box_tests += occupied.count_ones();
            let (bits, near) = boxes(node, &st.r, st.limit);
            let bits = bits & occupied;
            if bits != 0 {
                let next;
                (self.top, next) =
                    push_children(stack, self.top, node, self.child, bits, near, one_by_branch);
                (self.child, self.kind) = (node.child[next], node.kind[next]);
                if AHEAD {
                    prefetch(scene, self.child, self.kind);
                }
                return true;
            }
        } else {
            debug_assert!(self.kind != EMPTY);
            leaf.visit(st, self.child, usize::from(self.kind), hit_list);
            if st.done {
                return false;
            }
        }
        // Pop the nearest pushed entry the ray can still reach.
        while self.top > 0 {
            self.top -= 1;
            let entry = stack[self.top];
            if entry.near <= st.limit {
                (self.child, self.kind) = (entry.child(), entry.kind());
                if AHEAD {
                    prefetch(scene, self.child, self.kind);
                }
                return true;
            }
        }
        false
    }
}

/// Traces one kernel-frame ray: the twin's answer (and, in all-hits mode, its list), with this
/// walk's own b and i. `stack` holds at least [`stack_size`] entries.
#[inline(always)]
pub fn trace<L: Lanes8>(
    scene: &Scene<'_>,
    ray: &GpuRay,
    hit_list: &mut [GpuHitEntry],
    stack: &mut [Pushed],
) -> GpuHit {
    trace_leaves::<L>(scene, ray, hit_list, stack, &mut Triangles(scene))
}

/// What bounds the hits' t of a ray in an instance's mesh besides their triangles' own boxes.
pub enum Clip<'r> {
    /// Nothing (a ray in a scene without instances).
    None,
    /// The world ray's interval over this box (an instance's leaf in the top tree), worked out
    /// at the first group of triangles one of whose lanes passes the edge tests (every group
    /// under Möller–Trumbore): most instance entries meet none (read at every entry, the field
    /// of 10,000 bunnies picked at 0.450 of one bunny in one run on a busy VM).
    Leaf(&'r crate::layout::GpuNode, &'r GpuRay),
    /// That interval, worked out.
    Ready(f32, f32),
}

impl Clip<'_> {
    /// The interval, worked out once.
    #[inline(always)]
    fn interval(&mut self) -> Option<(f32, f32)> {
        match *self {
            Clip::None => None,
            Clip::Ready(lo, hi) => Some((lo, hi)),
            Clip::Leaf(leaf, world) => {
                let dir = Vec3::from(world.dir);
                let (lo, hi) = crate::cpu::ray_box::box_interval(
                    leaf.min.into(),
                    leaf.max.into(),
                    Vec3::from(world.origin),
                    dir,
                    safe_inverse(dir),
                );
                *self = Clip::Ready(lo, hi);
                Some((lo, hi))
            }
        }
    }
}

/// [`trace`] for a ray moved into an instance's mesh, its hits' t kept within `clip` (the world
/// ray's interval over the instance's leaf box, `ray_box::box_interval`), as the kernel and the
/// twin keep them.
#[inline(always)]
pub fn trace_clipped<'r, L: Lanes8>(
    scene: &Scene<'_>,
    ray: &'r GpuRay,
    hit_list: &mut [GpuHitEntry],
    stack: &mut [Pushed],
    clip: Clip<'r>,
) -> GpuHit {
    let (miss, state) = RayState::<L>::new(scene, ray, true);
    let Some(mut st) = state else {
        return miss;
    };
    st.clip = clip;
    walk_whole(scene, st, hit_list, stack, &mut Triangles(scene))
}

/// [`trace`]'s walk with each leaf met visited by `leaf`, nearest first, which may lower
/// `state.limit` (pruning what is left), set `state.best` and `state.done` (triangles for
/// [`trace`]; the instanced walk's top tree visits instances, interleaved:
/// [`trace_interleaved_leaves`]).
#[inline(always)]
pub fn trace_leaves<L: Lanes8>(
    scene: &Scene<'_>,
    ray: &GpuRay,
    hit_list: &mut [GpuHitEntry],
    stack: &mut [Pushed],
    leaf: &mut impl Leaves<L>,
) -> GpuHit {
    let (miss, state) = RayState::<L>::new(scene, ray, true);
    let Some(st) = state else {
        return miss;
    };
    walk_whole(scene, st, hit_list, stack, leaf)
}

/// Walks one ray whose state is made, one node after another, to its answer.
#[inline(always)]
fn walk_whole<L: Lanes8>(
    scene: &Scene<'_>,
    st: RayState<'_, L>,
    hit_list: &mut [GpuHitEntry],
    stack: &mut [Pushed],
    leaf: &mut impl Leaves<L>,
) -> GpuHit {
    let mut walk = Walk {
        st,
        child: 0,
        kind: INNER,
        top: 0,
    };
    while walk.step::<false>(scene, stack, hit_list, leaf, true) {}
    walk.st.finish(hit_list)
}

/// Rays walked in turn by [`trace_interleaved`]. Sixteen, measured A/B against 32 and 24
/// (BENCHMARKS.md): level on the bunny and the soup, +3–5% on the dragon, +4–7% on the DEM and
/// +15–19% on the 2M terrain, whose walks miss the caches most (32 stacks, states and prefetched
/// lines crowd the 48 KiB L1 out of what they prefetched).
pub const INTERLEAVED: usize = 16;

const _: () = assert!(
    PACKET <= INTERLEAVED && INTERLEAVED <= 32,
    "a run holds at least a group of PACKET rays, and its walks fit a u32 mask"
);

/// Traces up to [`INTERLEAVED`] kernel-frame rays, each by [`trace`]'s walk (the same answers
/// and statistics), but a node at a time in turn, each ray's next node or leaf
/// prefetched when it is chosen: while one ray waits for memory the others compute, so a
/// thread keeps several cache misses in flight instead of one. `lists` holds each ray's
/// all-hits list in turn; `stacks` holds [`INTERLEAVED`] stacks of [`stack_size`] entries.
#[inline(always)]
pub fn trace_interleaved<L: Lanes8>(
    scene: &Scene<'_>,
    rays: &[GpuRay],
    lists: &mut [GpuHitEntry],
    stacks: &mut [Pushed],
    out: &mut [GpuHit],
) {
    let leaf = &mut Triangles(scene);
    trace_interleaved_leaves::<L>(scene, rays, lists, stacks, out, leaf, false);
}

/// [`trace_interleaved`] with each leaf met visited by `leaf` (as in [`trace_leaves`]):
/// triangles, or the instanced walk's instances. `one_by_branch` as in [`push_children`]: for
/// rays whose branches predict (the instanced walk's).
#[inline(always)]
pub fn trace_interleaved_leaves<L: Lanes8>(
    scene: &Scene<'_>,
    rays: &[GpuRay],
    lists: &mut [GpuHitEntry],
    stacks: &mut [Pushed],
    out: &mut [GpuHit],
    leaf: &mut impl Leaves<L>,
    one_by_branch: bool,
) {
    let k = lists.len() / rays.len().max(1);
    let depth = stacks.len() / INTERLEAVED;
    let mut walks: [Option<Walk<'_, L>>; INTERLEAVED] = Default::default();
    let mut going = 0u32;
    // Set up eight at a time ([`Eight`]), the last few one by one.
    let n = rays.len().min(INTERLEAVED);
    let mut i = 0;
    while i < n {
        let eight = (i + LANES <= n).then(|| Eight::new::<L>(scene, &rays[i..i + LANES]));
        let group = if eight.is_some() { LANES } else { 1 };
        for k in i..i + group {
            let mut state = None;
            out[k] = match &eight {
                Some(eight) => RayState::from_eight(scene, &rays[k], eight, k - i, &mut state),
                None => RayState::<L>::new_in(scene, &rays[k], one_by_branch, &mut state),
            };
            if let Some(st) = state {
                walks[k] = Some(Walk {
                    st,
                    child: 0,
                    kind: INNER,
                    top: 0,
                });
                going |= 1 << k;
            }
        }
        i += group;
    }
    while going != 0 {
        let mut left = going;
        while left != 0 {
            let i = left.trailing_zeros() as usize;
            left &= left - 1;
            let stack = &mut stacks[i * depth..(i + 1) * depth];
            let list = &mut lists[i * k..(i + 1) * k];
            if let Some(walk) = walks[i].as_mut()
                && !walk.step::<true>(scene, stack, list, leaf, one_by_branch)
            {
                going &= !(1 << i);
            }
        }
    }
    for (i, walk) in walks.iter_mut().enumerate() {
        if let Some(w) = walk.take() {
            out[i] = w.st.finish(&lists[i * k..(i + 1) * k]);
        }
    }
}

/// Rays per packet.
pub const PACKET: usize = 8;

const _: () = assert!(
    PACKET == 8 && WIDTH == 8,
    "transpose_bits works on 8 x 8 bits"
);

/// Transposes an 8 × 8 bit matrix held row by row in bytes: bit `8 i + j` moves to `8 j + i`.
#[inline(always)]
fn transpose_bits(mut x: u64) -> u64 {
    let t = (x ^ (x >> 7)) & 0x00AA_00AA_00AA_00AA;
    x ^= t ^ (t << 7);
    let t = (x ^ (x >> 14)) & 0x0000_CCCC_0000_CCCC;
    x ^= t ^ (t << 14);
    let t = (x ^ (x >> 28)) & 0x0000_0000_F0F0_F0F0;
    x ^ t ^ (t << 28)
}

/// A packet's rays, each set up for its own walk: its all-hits list and its state (`None`:
/// never traced, its answer already written). The packet and frustum walks share it (which
/// rays still walk they keep in a local mask: a register, not this struct); each ray's leaf
/// tests are its own, so its answer is its single-ray answer.
struct PacketRays<'r, 'l, L: Lanes8> {
    lists: [&'l mut [GpuHitEntry]; PACKET],
    states: [Option<RayState<'r, L>>; PACKET],
}

impl<'r, 'l, L: Lanes8> PacketRays<'r, 'l, L> {
    /// No rays yet: [`PacketRays::start`] sets them up in place.
    #[inline(always)]
    fn empty() -> Self {
        PacketRays {
            lists: Default::default(),
            states: Default::default(),
        }
    }

    /// Sets the [`PACKET`] `rays`, whose [`Eight`] is made, up in place, with `lists` holding
    /// each one's all-hits list in turn; a ray that is never traced gets its miss in `out` now.
    /// Returns the rays traced (bit `i`: ray `i`). In place, not built and returned: a packet's
    /// states are a few KiB, and returning them was a `memmove` of 3% of a camera trace's
    /// samples.
    #[inline(always)]
    fn start(
        &mut self,
        scene: &Scene<'_>,
        rays: &'r [GpuRay],
        eight: &Eight,
        lists: &'l mut [GpuHitEntry],
        out: &mut [GpuHit],
    ) -> u32 {
        let k = lists.len() / PACKET;
        if k > 0 {
            for (slot, part) in self.lists.iter_mut().zip(lists.chunks_mut(k)) {
                *slot = part;
            }
        }
        RayState::<L>::new_eight(scene, rays, eight, &mut self.states, out)
    }

    /// Tests the leaf's `count` triangles from leaf-order `first` for the rays in `testing`
    /// (layer `mask`), each group gathered once and tested by each of those rays in turn, in
    /// the order a ray alone would test them; returns the rays whose walk ended (any-hit
    /// mode).
    #[inline(always)]
    fn leaf(
        &mut self,
        scene: &Scene<'_>,
        mut testing: u32,
        mask: u32,
        first: usize,
        count: usize,
    ) -> u32 {
        let mut ended = 0;
        let mut g = 0;
        while g < count && testing != 0 {
            let group = (count - g).min(LANES);
            let lanes = lanes_for(scene, mask, first + g, group);
            if lanes != 0 {
                let v = L::gather(scene.triangles, first + g, group);
                let mut rays_left = testing;
                while rays_left != 0 {
                    let i = rays_left.trailing_zeros() as usize;
                    rays_left &= rays_left - 1;
                    if let Some(s) = self.states[i].as_mut() {
                        s.group(scene, &v, first + g, lanes, self.lists[i]);
                        if s.done {
                            ended |= 1 << i;
                        }
                    }
                }
                testing &= !ended;
            }
            g += group;
        }
        ended
    }

    /// Writes each traced ray's answer. The states are taken in place: a packet's states are
    /// a few KiB, and moving them out whole made camera traces 15% slower.
    #[inline(always)]
    fn finish(&mut self, out: &mut [GpuHit]) {
        for ((state, list), out) in self.states.iter_mut().zip(&mut self.lists).zip(out) {
            if let Some(s) = state.take() {
                *out = s.finish(list);
            }
        }
    }
}

/// Answers a packet none of whose rays meets the root's boxes (`root_boxes` of them tested)
/// without walking it: each ray's first answer, with the root's boxes counted for the rays
/// `traced` (the single walk's b and i: it too tests the root and stops).
#[inline(always)]
fn answer_at_root<L: Lanes8>(
    scene: &Scene<'_>,
    rays: &[GpuRay],
    traced: u32,
    root_boxes: u32,
    out: &mut [GpuHit],
) {
    for (i, (ray, out)) in rays[..PACKET].iter().zip(out.iter_mut()).enumerate() {
        *out = RayState::<L>::first_answer(scene, ray).0;
        if traced >> i & 1 == 1 {
            out.box_tests = root_boxes;
        }
    }
}

/// What a packet's rays made of one node's boxes, each by its own test: byte `i` of `met` the
/// children ray `i` meets, `union` the children any ray meets, per child in `key` the nearest
/// near distance among the rays that meet it, and each ray's near distances.
struct PacketNode<L: Lanes8> {
    met: u64,
    union: u32,
    key: L,
    near: [[f32; WIDTH]; PACKET],
}

impl<L: Lanes8> PacketNode<L> {
    #[inline(always)]
    fn new() -> Self {
        PacketNode {
            met: 0,
            union: 0,
            key: L::splat(f32::INFINITY),
            near: [[0.0; WIDTH]; PACKET],
        }
    }

    /// Adds ray `i`'s test of the node's boxes (`hit`, at `lo`; `occupied` children).
    #[inline(always)]
    fn add(&mut self, i: usize, (hit, lo): (L::Mask, L), occupied: u32) {
        let bits = L::bits(hit) & occupied;
        self.met |= u64::from(bits) << (8 * i);
        self.union |= bits;
        self.key = self.key.min(L::select(hit, lo, L::splat(f32::INFINITY)));
        self.near[i] = lo.to_array();
    }
}

/// A pushed child of the packet walk: which rays still need it and each one's near distance.
#[derive(Clone, Copy, Debug, Default)]
pub struct PacketEntry {
    child: u32,
    kind: u8,
    rays: u32,
    near: [f32; PACKET],
}

/// Traces [`PACKET`] coherent rays down the tree together, on one stack: at each node every ray
/// still in the packet tests the node's boxes in its own lanes (the single-ray test, bit for
/// bit), the children met by any ray are visited nearest first (by the nearest ray), and a leaf
/// is tested for each ray that still needs it by that ray's own leaf test. Answers are each
/// ray's single-ray answer, bit for bit; what the rays share is the walk's bookkeeping (one
/// stack, one order). `columns` holds the rays in lanes ([`group_of`]'s); `lists` holds each
/// ray's all-hits list in turn; `stack` holds at least [`stack_size`] entries. The root's boxes
/// are tested before any ray's state is made, so a packet of sky ends there (an orthographic
/// view of sky traced 1.57× faster: BENCHMARKS.md).
#[inline(always)]
pub fn trace_packet<L: Lanes8>(
    scene: &Scene<'_>,
    rays: &[GpuRay],
    columns: &[L; 8],
    lists: &mut [GpuHitEntry],
    stack: &mut [PacketEntry],
    out: &mut [GpuHit],
) {
    // The root's boxes first, each traced ray by its own test (the walk's first step, made
    // from the same inverse direction and origin its state would hold), before any ray's state:
    // a packet that meets none of them (a view's sky) ends here with each ray's first answer
    // (the root's boxes counted as tested); otherwise the walk starts from these results.
    let eight = Eight::of_columns::<L>(scene, columns);
    let mut traced = 0u32;
    for (i, ray) in rays[..PACKET].iter().enumerate() {
        traced |= u32::from(RayState::<L>::first_answer(scene, ray).1) << i;
    }
    let mut root = None;
    if traced != 0 {
        let node = &scene.nodes[0];
        let occupied = u32::from(node.occupied);
        let mut visit = PacketNode::<L>::new();
        let mut rays_left = traced;
        while rays_left != 0 {
            let i = rays_left.trailing_zeros() as usize;
            rays_left &= rays_left - 1;
            let ray = &rays[i];
            let inv = Vec3::new(eight.inv[0][i], eight.inv[1][i], eight.inv[2][i]);
            let r = RayLanes::new(ray, inv);
            visit.add(i, boxes_met(node, &r, ray.tmax), occupied);
        }
        if visit.union == 0 {
            answer_at_root::<L>(scene, rays, traced, occupied.count_ones(), out);
            return;
        }
        root = Some(visit);
    }
    let mut packet = PacketRays::<L>::empty();
    let mut alive = packet.start(scene, rays, &eight, lists, out);
    debug_assert_eq!(alive, traced, "the rays set up are those traced");
    if alive == 0 {
        return;
    }
    // The entry being visited: the root, then the nearest child met (kept out of the stack, so
    // a descent costs no push and pop; every ray it lists met its box within its limit), then
    // the nearest pushed entry some ray can still reach.
    let mut entry = PacketEntry {
        child: 0,
        kind: INNER,
        rays: alive,
        near: [0.0; PACKET],
    };
    let mut active = alive;
    let mut top = 0usize;
    loop {
        if entry.kind == INNER {
            let node = &scene.nodes[entry.child as usize];
            let occupied = u32::from(node.occupied);
            let tested = occupied.count_ones();
            // The rays' tests of the node's boxes (the root's made before the states).
            let visit = match root.take() {
                Some(root) => {
                    for s in packet.states.iter_mut().flatten() {
                        s.best.box_tests += tested;
                    }
                    root
                }
                None => {
                    let mut visit = PacketNode::<L>::new();
                    let mut rays_left = active;
                    while rays_left != 0 {
                        let i = rays_left.trailing_zeros() as usize;
                        rays_left &= rays_left - 1;
                        if let Some(s) = packet.states[i].as_mut() {
                            s.best.box_tests += tested;
                            visit.add(i, boxes_met(node, &s.r, s.limit), occupied);
                        }
                    }
                    visit
                }
            };
            let PacketNode {
                met,
                mut union,
                key,
                near,
            } = visit;
            if union != 0 {
                // Byte c: the rays that meet child c.
                let rays_of = transpose_bits(met);
                let keys = key.to_array();
                // The children met by any ray (`union`), farthest (by their nearest ray) first.
                let mut children = [(0u32, 0u32, 0.0f32); WIDTH];
                let mut n = 0;
                while union != 0 {
                    let c = union.trailing_zeros() as usize;
                    union &= union - 1;
                    let rays = (rays_of >> (8 * c)) as u32 & 0xFF;
                    let key = keys[c];
                    let mut j = n;
                    while j > 0 && children[j - 1].2 < key {
                        children[j] = children[j - 1];
                        j -= 1;
                    }
                    children[j] = (c as u32, rays, key);
                    n += 1;
                }
                let child_entry = |c: u32, rays: u32| {
                    let c = c as usize;
                    let mut child_near = [0.0; PACKET];
                    for (to, from) in child_near.iter_mut().zip(&near) {
                        *to = from[c];
                    }
                    PacketEntry {
                        child: node.child[c],
                        kind: node.kind[c],
                        rays,
                        near: child_near,
                    }
                };
                for &(c, rays, _) in &children[..n - 1] {
                    stack[top] = child_entry(c, rays);
                    top += 1;
                }
                let (c, rays, _) = children[n - 1];
                entry = child_entry(c, rays);
                active = rays;
                continue;
            }
        } else {
            // Tested by every ray that still needs it.
            let (first, count) = (entry.child as usize, usize::from(entry.kind));
            let mask = rays[active.trailing_zeros() as usize].mask;
            alive &= !packet.leaf(scene, active, mask, first, count);
            if alive == 0 {
                break;
            }
        }
        // Pop the nearest pushed entry that some ray still needs: alive, and not past it.
        active = 0;
        while active == 0 {
            if top == 0 {
                break;
            }
            top -= 1;
            entry = stack[top];
            let mut candidates = entry.rays & alive;
            while candidates != 0 {
                let i = candidates.trailing_zeros() as usize;
                candidates &= candidates - 1;
                if let Some(s) = &packet.states[i]
                    && entry.near[i] <= s.limit
                {
                    active |= 1 << i;
                }
            }
        }
        if active == 0 {
            break;
        }
    }
    packet.finish(out);
}

/// How a group of [`PACKET`] rays is traced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Group {
    /// Ray by ray (interleaved with other such rays).
    Single,
    /// As one packet ([`trace_packet`]): the same flags and mask, directions within about 6° of
    /// the first's, origins within 1% of the scene's size of the first's.
    Packet,
    /// As one frustum ([`trace_frustum`]): a packet whose rays also share their origin (the
    /// same bits: a pinhole camera's), whose direction components each keep one sign across the
    /// packet and are not parallel to an axis plane (`MIN_DIR`), within `FRUSTUM_COS` of the
    /// first. Where a component changes sign inside the packet (near a view's centre lines) the
    /// interval of its inverse has no bound, and the packet walks ray by ray instead.
    Frustum,
}

/// How the first [`PACKET`] of `rays` are traced ([`Group`]), decided for the eight rays at
/// once in lanes, where each was tested in turn (that was 5% of a camera trace's samples), the
/// rays read into lanes by one transpose ([`Lanes8::rays`]: eight loads and a few shuffles
/// where 48 floats were gathered one by one; the small bunny's camera trace 3% faster). The
/// angle's tests go without square roots or divisions: cos ≥ c as (d·d₀)² ≥ c²·|d|²·|d₀|² with
/// d·d₀ > 0 (normalising each direction was a third of a camera packet's set-up). The tests'
/// one-ray-at-a-time definitions give the same decisions (`tests::coherent`,
/// `tests::frustum_packet`). Returns the rays in lanes too, for the packet walks' set-up, which
/// would read them in again.
#[inline(always)]
pub fn group_of<L: Lanes8>(rays: &[GpuRay], scene_size: f32) -> (Group, [L; 8]) {
    let rays = &rays[..PACKET];
    let columns = L::rays(rays);
    (group_in_lanes(rays, &columns, scene_size), columns)
}

/// [`group_of`]'s decision, the rays read in (`columns`).
#[inline(always)]
fn group_in_lanes<L: Lanes8>(rays: &[GpuRay], columns: &[L; 8], scene_size: f32) -> Group {
    let first = &rays[0];
    let mut same = true;
    for r in rays {
        same &= (r.flags == first.flags) & (r.mask == first.mask);
    }
    if !same {
        return Group::Single;
    }
    let o = [columns[0], columns[1], columns[2]];
    let d = [columns[4], columns[5], columns[6]];
    let d0 = Vec3::from(first.dir);
    let dot = d[0]
        .mul(L::splat(d0.x))
        .add(d[1].mul(L::splat(d0.y)))
        .add(d[2].mul(L::splat(d0.z)));
    // A packet: directions within about 6°, origins within 1% of the scene's size.
    let reach = L::splat(0.01 * scene_size);
    let near = |a: usize| o[a].sub(L::splat(first.origin[a])).abs().le(reach);
    let coherent = L::and(
        L::and(dot.ge(L::splat(0.995)), near(0)),
        L::and(near(1), near(2)),
    );
    if L::bits(coherent) != (1 << PACKET) - 1 {
        return Group::Single;
    }
    let mut same_origin = (1 << PACKET) - 1;
    for (a, o) in o.iter().enumerate() {
        same_origin &= o.same_bits(L::splat(first.origin[a]));
    }
    if same_origin != (1 << PACKET) - 1 {
        return Group::Packet;
    }
    // A frustum: each component of the first ray's sign and not below `MIN_DIR`, and within
    // `FRUSTUM_COS` of the first.
    let zero = L::splat(0.0);
    let mut frustum = (1u32 << PACKET) - 1;
    for (a, d) in d.iter().enumerate() {
        let negative = L::bits(d.lt(zero));
        frustum &= L::bits(d.abs().ge(L::splat(MIN_DIR)));
        frustum &= if first.dir[a] < 0.0 {
            negative
        } else {
            !negative
        };
    }
    let length = d[0].mul(d[0]).add(d[1].mul(d[1])).add(d[2].mul(d[2]));
    let reach = L::splat(FRUSTUM_COS * FRUSTUM_COS * d0.length_squared());
    frustum &= L::bits(L::and(dot.gt(zero), dot.mul(dot).ge(reach.mul(length))));
    if frustum == (1 << PACKET) - 1 {
        Group::Frustum
    } else {
        Group::Packet
    }
}

/// The cosine of the widest angle between a frustum packet's first ray and another: about
/// 0.57°. A wider packet's frustum takes in nodes none of its rays meet: eight adjacent rays of
/// a 64 × 64 view (about 4.4° apart) traced several times slower as a frustum than ray by ray,
/// those of a 1000 × 1000 view (0.27°) 6% faster (BENCHMARKS.md, "three more levers").
const FRUSTUM_COS: f32 = 0.99995;

/// The packet's box test: for each child, whether some ray of a frustum from `origin` with
/// inverse directions between `inv_lo` and `inv_hi` per axis (each of one sign) may meet it
/// within `[tmin, reach]`, and the nearest such distance. Each ray's own slab distances are the
/// rounded products `(plane - origin) · inv` of the same differences, and rounding is monotonic,
/// so the products at the interval's ends bound every ray's own values exactly (not
/// approximately): a child any ray's own test ([`boxes_met`]) meets is met here.
#[inline(always)]
fn frustum_boxes<L: Lanes8>(
    node: &WideNode,
    origin: &[L; 3],
    inv_lo: &[L; 3],
    inv_hi: &[L; 3],
    tmin: f32,
    reach: f32,
) -> (u32, L) {
    let mut near = [L::splat(0.0); 3];
    let mut far = [L::splat(0.0); 3];
    for a in 0..3 {
        let d0 = L::load(&node.min[a]).sub(origin[a]);
        let d1 = L::load(&node.max[a]).sub(origin[a]);
        let (p00, p01) = (d0.mul(inv_lo[a]), d0.mul(inv_hi[a]));
        let (p10, p11) = (d1.mul(inv_lo[a]), d1.mul(inv_hi[a]));
        near[a] = p00.min(p01).min(p10.min(p11));
        far[a] = p00.max(p01).max(p10.max(p11));
    }
    let t_near = near[0].max(near[1]).max(near[2]);
    let t_far = far[0].min(far[1]).min(far[2]);
    let pad = L::splat(BOX_PAD);
    let lo = t_near.sub(t_near.abs().mul(pad)).max(L::splat(tmin));
    let hi = t_far.add(t_far.abs().mul(pad)).min(L::splat(reach));
    (L::bits(lo.le(hi)), lo)
}

/// Traces [`PACKET`] rays from one origin ([`Group::Frustum`]) as one frustum: each node's eight
/// boxes are tested once for the whole packet ([`frustum_boxes`], conservative), children
/// nearest first; at each leaf every ray still walking tests the leaf's box by its own test (the
/// eight rays in lanes, bit for bit [`boxes_met`]'s), and those that meet it test its
/// triangles, each by its own leaf test. Every ray thus tests every triangle its own walk
/// would, and only genuine hits of its own, so each answer is its single-ray answer, bit for
/// bit. Against [`trace_packet`], where every ray tests every node's boxes: camera rays traced
/// 6% faster on the bunny and the dragon, as fast on the DEM (BENCHMARKS.md). `lists` holds each
/// ray's all-hits list in turn; `stack` holds at least [`stack_size`] entries. A packet whose
/// frustum meets none of the root's boxes (a view's sky) ends before any ray's state is made:
/// all-sky camera rays traced 1.7× faster, a DEM view half sky 1.17× (BENCHMARKS.md).
#[inline(always)]
pub fn trace_frustum<L: Lanes8>(
    scene: &Scene<'_>,
    rays: &[GpuRay],
    columns: &[L; 8],
    lists: &mut [GpuHitEntry],
    stack: &mut [Entry],
    out: &mut [GpuHit],
) {
    // The rays' inverse directions and shear rows, and the frustum's interval of inverse
    // directions over the rays that are traced (`RayState::first_answer`), made before any
    // ray's state: a packet whose frustum meets none of the root's boxes ends here with each
    // ray's first answer (the root's boxes counted as tested), its states never made.
    let eight = Eight::of_columns::<L>(scene, columns);
    let inv_rays = &eight.inv;
    let (mut inv_lo, mut inv_hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    let (mut tmin, mut reach) = (f32::INFINITY, f32::NEG_INFINITY);
    let mut tmin_rays = [0.0f32; PACKET];
    let mut traced = 0u32;
    for (i, ray) in rays[..PACKET].iter().enumerate() {
        if RayState::<L>::first_answer(scene, ray).1 {
            traced |= 1 << i;
            let inv = Vec3::new(inv_rays[0][i], inv_rays[1][i], inv_rays[2][i]);
            inv_lo = inv_lo.min(inv);
            inv_hi = inv_hi.max(inv);
            tmin = tmin.min(ray.tmin);
            reach = reach.max(ray.tmax);
            tmin_rays[i] = ray.tmin;
        }
    }
    let splat3 = |v: Vec3| [L::splat(v.x), L::splat(v.y), L::splat(v.z)];
    let o = Vec3::from(rays[0].origin);
    let origin = splat3(o);
    let (inv_lo, inv_hi) = (splat3(inv_lo), splat3(inv_hi));
    if traced != 0 {
        let root = &scene.nodes[0];
        let occupied = u32::from(root.occupied);
        if frustum_boxes(root, &origin, &inv_lo, &inv_hi, tmin, reach).0 & occupied == 0 {
            answer_at_root::<L>(scene, rays, traced, occupied.count_ones(), out);
            return;
        }
    }
    let mut packet = PacketRays::<L>::empty();
    let mut alive = packet.start(scene, rays, &eight, lists, out);
    debug_assert_eq!(alive, traced, "the rays set up are those traced");
    if alive == 0 {
        return;
    }
    let inv_l = [
        L::load(&inv_rays[0]),
        L::load(&inv_rays[1]),
        L::load(&inv_rays[2]),
    ];
    let tmin_l = L::load(&tmin_rays);
    // The farthest any ray still walking may hit, and each one's limit (in lanes).
    let reach_of = |states: &[Option<RayState<'_, L>>; PACKET], alive: u32| {
        let mut reach = f32::NEG_INFINITY;
        let mut limits = [f32::NEG_INFINITY; PACKET];
        for (i, s) in states.iter().enumerate() {
            if alive >> i & 1 == 1
                && let Some(s) = s
            {
                reach = reach.max(s.limit);
                limits[i] = s.limit;
            }
        }
        (reach, limits)
    };
    let (mut reach, mut limits) = reach_of(&packet.states, alive);
    let mut entry = Entry {
        child: 0,
        kind: INNER,
        ..Entry::default()
    };
    let mut top = 0usize;
    'walk: loop {
        if entry.kind == INNER {
            let node = &scene.nodes[entry.child as usize];
            let occupied = u32::from(node.occupied);
            let tested = occupied.count_ones();
            for (i, s) in packet.states.iter_mut().enumerate() {
                if alive >> i & 1 == 1
                    && let Some(s) = s
                {
                    s.best.box_tests += tested;
                }
            }
            let (bits, near) = frustum_boxes(node, &origin, &inv_lo, &inv_hi, tmin, reach);
            let bits = bits & occupied;
            if bits != 0 {
                let next;
                (top, next) = push_children(stack, top, node, entry.child, bits, near, true);
                entry = Entry {
                    child: node.child[next],
                    kind: node.kind[next],
                    lane: next as u8,
                    reserved: 0,
                    near: near.to_array()[next],
                    node: entry.child,
                };
                continue;
            }
        } else {
            // Which rays meet the leaf's box, each by its own test, in lanes.
            let parent = &scene.nodes[entry.node as usize];
            let lane = entry.lane as usize;
            let mut t_near = L::splat(f32::NEG_INFINITY);
            let mut t_far = L::splat(f32::INFINITY);
            for a in 0..3 {
                let oa = L::splat(o[a]);
                let t0 = L::splat(parent.min[a][lane]).sub(oa).mul(inv_l[a]);
                let t1 = L::splat(parent.max[a][lane]).sub(oa).mul(inv_l[a]);
                let (nr, fr) = (t0.min(t1), t0.max(t1));
                t_near = if a == 0 { nr } else { t_near.max(nr) };
                t_far = if a == 0 { fr } else { t_far.min(fr) };
            }
            let pad = L::splat(BOX_PAD);
            let lo = t_near.sub(t_near.abs().mul(pad)).max(tmin_l);
            let hi = t_far.add(t_far.abs().mul(pad)).min(L::load(&limits));
            let leaf_rays = L::bits(lo.le(hi)) & alive;
            // Tested by those rays.
            let (first, count) = (entry.child as usize, usize::from(entry.kind));
            let mask = rays[alive.trailing_zeros() as usize].mask;
            alive &= !packet.leaf(scene, leaf_rays, mask, first, count);
            if alive == 0 {
                break;
            }
            (reach, limits) = reach_of(&packet.states, alive);
        }
        // Pop the nearest pushed entry some ray may still reach.
        while top > 0 {
            top -= 1;
            let e = stack[top];
            if e.near <= reach {
                entry = e;
                continue 'walk;
            }
        }
        break;
    }
    packet.finish(out);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::{BuildOptions, Bvh};
    use crate::check::synthetic::{RayKind, hills, rays, terrain};
    use crate::engine::lanes::Portable;
    use crate::engine::lanes8::Pair;
    use crate::engine::wide::WideBvh;
    use crate::layout::{CULL_SHIFT, MODE_CLOSEST};

    /// [`Group::Packet`]'s test, one ray at a time: the definition [`group_of`] is checked against.
    fn coherent(rays: &[GpuRay], scene_size: f32) -> bool {
        let first = &rays[0];
        let d0 = Vec3::from(first.dir);
        let o0 = Vec3::from(first.origin);
        let reach = 0.01 * scene_size;
        rays.len() == PACKET
            && rays[1..].iter().all(|r| {
                r.flags == first.flags
                    && r.mask == first.mask
                    && Vec3::from(r.dir).dot(d0) >= 0.995
                    && (Vec3::from(r.origin) - o0).abs().max_element() <= reach
            })
    }

    /// [`Group::Frustum`]'s test beyond [`Group::Packet`]'s, one ray at a time.
    fn frustum_packet(rays: &[GpuRay]) -> bool {
        let o = rays[0].origin.map(f32::to_bits);
        let signs = rays[0].dir.map(|d| d < 0.0);
        let d0 = Vec3::from(rays[0].dir);
        // The angle's test without square roots or divisions: cos >= FRUSTUM_COS as
        // (d · d0)² >= FRUSTUM_COS² |d|² |d0|² with d · d0 > 0 (normalising each direction was a
        // third of a camera packet's set-up).
        let reach = FRUSTUM_COS * FRUSTUM_COS * d0.length_squared();
        rays.iter().all(|r| {
            let d = Vec3::from(r.dir);
            let cos = d.dot(d0);
            r.origin.map(f32::to_bits) == o
                && r.dir
                    .iter()
                    .zip(signs)
                    .all(|(d, neg)| d.abs() >= MIN_DIR && (*d < 0.0) == neg)
                && cos > 0.0
                && cos * cos >= reach * d.length_squared()
        })
    }

    /// `group_of` in lanes decides as `coherent` and `frustum_packet` do, on camera groups (a
    /// narrow view and a wide one), random rays and groups with one ray changed.
    #[test]
    fn groups_in_lanes_are_the_scalar_tests() {
        let mesh = terrain(40, 30, 0.0, 0.0, 1.0, hills);
        let scene = crate::Scene::from_meshes([("hills".to_string(), mesh)]).unwrap();
        let bvh = Bvh::build(&scene, &BuildOptions::default()).unwrap();
        let size = WideBvh::collapse(&bvh).unwrap().size();
        let local = |kind, n| {
            crate::frame::local_rays(
                crate::frame::Frame::at(bvh.origin),
                &rays(&scene, kind, n, 7),
            )
        };
        let mut sets = vec![
            local(RayKind::Camera, 1 << 16),
            local(RayKind::Camera, 4096),
        ];
        sets.push(local(RayKind::Random, 4096));
        // A narrow view (drawn to a twentieth of its angle), whose groups walk as frustums.
        let mut narrow = local(RayKind::Camera, 1 << 16);
        let mean = narrow
            .iter()
            .fold(Vec3::ZERO, |m, r| m + Vec3::from(r.dir).normalize())
            .normalize();
        for r in &mut narrow {
            let d = Vec3::from(r.dir).normalize();
            r.dir = (mean + (d - mean) * 0.05).normalize().to_array();
        }
        sets.push(narrow.clone());
        let mut changed = narrow;
        for (j, group) in changed.chunks_exact_mut(PACKET).enumerate() {
            let r = &mut group[j % PACKET];
            match j % 5 {
                0 => r.flags ^= 1,
                1 => r.origin[j % 3] += 1e-3,
                2 => r.dir[j % 3] = -r.dir[j % 3],
                3 => r.mask = 2,
                _ => {}
            }
        }
        sets.push(changed);
        let mut seen = [0; 3];
        for set in &sets {
            for group in set.chunks_exact(PACKET) {
                let want = if !coherent(group, size) {
                    Group::Single
                } else if frustum_packet(group) {
                    Group::Frustum
                } else {
                    Group::Packet
                };
                assert_eq!(group_of::<Pair<Portable>>(group, size).0, want, "{group:?}");
                #[cfg(target_arch = "x86_64")]
                if crate::engine::Simd::Avx2.is_available() {
                    // SAFETY: the CPU has AVX2 (checked just above).
                    assert_eq!(unsafe { group_avx(group, size) }, want);
                }
                seen[want as usize] += 1;
            }
        }
        assert!(seen.iter().all(|&n| n > 100), "each kind met: {seen:?}");
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn group_avx(group: &[GpuRay], size: f32) -> Group {
        group_of::<crate::engine::lanes8::Avx>(group, size).0
    }

    /// A pushed word gives back its child and kind: every kind a child slot holds (leaf
    /// counts 1–15 and `INNER`), children up to the largest below [`MAX_CHILDREN`], and the
    /// near distance bit for bit.
    #[test]
    fn pushed_entries_give_back_child_kind_and_distance() {
        let kinds = (1..=crate::layout::MAX_LEAF_SIZE as u8).chain([INNER]);
        for kind in kinds {
            for child in [0, 1, 7, 12_345, (MAX_CHILDREN - 1) as u32] {
                for near in [0.0f32, -0.0, 1.5, -2.0, f32::MAX, 1e-40] {
                    let p = Pushed::new(child, kind, near);
                    assert_eq!((p.child(), p.kind()), (child, kind));
                    assert_eq!(p.near.to_bits(), near.to_bits());
                }
            }
        }
    }

    /// Eight rays set up together are each set up as alone, bit for bit: inverse, shear rows
    /// (the watertight test's and Möller–Trumbore's zeros), flags, range and first answer, over
    /// directions of special components (signed zeros, subnormals, huge, infinite, NaN) and
    /// random ones, on the portable lanes and on AVX where the CPU has it.
    fn eight_rays_set_up_as_one<L: Lanes8>() {
        let mesh = terrain(4, 4, 0.0, 0.0, 1.0, hills);
        let scene = crate::Scene::from_meshes([("hills".to_string(), mesh)]).unwrap();
        let bvh = Bvh::build(&scene, &BuildOptions::default()).unwrap();
        let wide = WideBvh::collapse(&bvh).unwrap();
        let special = crate::cpu::ray_triangle::SPECIAL_COMPONENTS;
        let mut dirs = Vec::new();
        for &x in &special {
            for &y in &special {
                for &z in &special {
                    dirs.push([x, y, z]);
                }
            }
        }
        dirs.extend(crate::cpu::ray_triangle::random_directions(20_000));
        let lane0 = |v: &[L; 3]| v.map(|l| l.to_array()[0].to_bits());
        for watertight in [true, false] {
            let walk = Scene {
                nodes: &wide.nodes,
                triangles: &bvh.triangles,
                triangle_ids: &bvh.triangle_ids,
                triangle_masks: &[],
                watertight,
                packets: true,
                size: wide.size(),
                interleave: false,
            };
            for (g, group) in dirs.chunks(LANES).enumerate() {
                let rays: Vec<GpuRay> = (0..LANES)
                    .map(|i| GpuRay {
                        origin: [0.25 * i as f32, -1.5, 2.0],
                        dir: group[i % group.len()],
                        tmin: if i == 3 { 2.0 } else { 0.0 },
                        tmax: if i == 5 && g % 2 == 0 { 1.0 } else { 1e30 },
                        flags: (i as u32 % 3) | ((i as u32 % 2) << CULL_SHIFT),
                        mask: u32::MAX,
                        ..GpuRay::default()
                    })
                    .collect();
                let mut slots: [Option<RayState<'_, L>>; LANES] = Default::default();
                let mut out = [GpuHit::default(); LANES];
                let eight = Eight::new::<L>(&walk, &rays);
                let alive = RayState::<L>::new_eight(&walk, &rays, &eight, &mut slots, &mut out);
                let inv = eight.inv;
                for (i, ray) in rays.iter().enumerate() {
                    let mut alone = None;
                    let first = RayState::<L>::new_in(&walk, ray, true, &mut alone);
                    assert_eq!(bytemuck::bytes_of(&out[i]), bytemuck::bytes_of(&first));
                    assert_eq!(alive >> i & 1 == 1, alone.is_some());
                    let (Some(a), Some(b)) = (&slots[i], &alone) else {
                        continue;
                    };
                    let why = format!("ray {ray:?}");
                    assert_eq!(lane0(&a.r.inv), lane0(&b.r.inv), "{why}");
                    assert_eq!(
                        lane0(&a.r.inv),
                        [0, 1, 2].map(|k| inv[k][i].to_bits()),
                        "{why}"
                    );
                    assert_eq!(lane0(&a.r.origin), lane0(&b.r.origin), "{why}");
                    let rows = |s: &RayState<'_, L>| s.shear.map(|r| r.map(f32::to_bits));
                    assert_eq!(rows(a), rows(b), "{why}");
                    assert_eq!(a.r.parallel, b.r.parallel, "{why}");
                    assert_eq!(a.r.tmin.to_bits(), b.r.tmin.to_bits(), "{why}");
                    assert_eq!(a.dir.map(f32::to_bits), b.dir.map(f32::to_bits), "{why}");
                    assert_eq!(
                        (a.mode, a.cull, a.limit.to_bits()),
                        (b.mode, b.cull, b.limit.to_bits())
                    );
                }
            }
        }
    }

    #[test]
    fn eight_rays_set_up_together_are_set_up_as_alone() {
        eight_rays_set_up_as_one::<Pair<Portable>>();
        #[cfg(target_arch = "x86_64")]
        if crate::engine::Simd::Avx2.is_available() {
            // SAFETY: the CPU has AVX2 (checked just above).
            unsafe { eight_avx() };
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn eight_avx() {
        eight_rays_set_up_as_one::<crate::engine::lanes8::Avx>();
    }

    /// The hills terrain and its trees, for the packet walks' tests.
    struct Hills {
        scene: crate::Scene,
        bvh: Bvh,
        wide: WideBvh,
    }

    impl Hills {
        fn new() -> Self {
            let mesh = terrain(40, 30, 0.0, 0.0, 1.0, hills);
            let scene = crate::Scene::from_meshes([("hills".to_string(), mesh)]).unwrap();
            let bvh = Bvh::build(&scene, &BuildOptions::default()).unwrap();
            let wide = WideBvh::collapse(&bvh).unwrap();
            Hills { scene, bvh, wide }
        }

        fn walk(&self) -> Scene<'_> {
            Scene {
                nodes: &self.wide.nodes,
                triangles: &self.bvh.triangles,
                triangle_ids: &self.bvh.triangle_ids,
                triangle_masks: &[],
                watertight: true,
                packets: true,
                size: self.wide.size(),
                interleave: false,
            }
        }
    }

    /// `group` (the `g`-th) with each ray's flags set; the 4th of every five stopped short
    /// (`tmax` 0.001), the 5th with a third of its rays not traced (an empty range).
    fn altered(group: &[GpuRay], g: usize, flags: u32) -> Vec<GpuRay> {
        let mut group: Vec<GpuRay> = group.iter().map(|r| GpuRay { flags, ..*r }).collect();
        for (i, r) in group.iter_mut().enumerate() {
            match g % 5 {
                3 => r.tmax = 1e-3,
                4 if i % 3 == 0 => (r.tmin, r.tmax) = (2.0, 1.0),
                _ => {}
            }
        }
        group
    }

    /// Checks `group`'s answers `out` (and all-hits `lists`, `k` entries a ray) against each
    /// ray's single walk: hit or miss in any-hit mode, else every bit; with `stats`, b and i
    /// too. Returns whether every single walk tested the root's boxes at most (a packet of sky).
    fn assert_single_ray_answers(
        walk: &Scene<'_>,
        group: &[GpuRay],
        (out, lists, k): (&[GpuHit], &[GpuHitEntry], usize),
        stack: &mut [Pushed],
        stats: bool,
    ) -> bool {
        let root = u32::from(walk.nodes[0].occupied).count_ones();
        let mut sky = true;
        for (i, ray) in group.iter().enumerate() {
            let mut list = vec![GpuHitEntry::default(); k];
            let (a, b) = (out[i], trace::<L8>(walk, ray, &mut list, stack));
            sky &= b.triangle_tests == 0 && (b.box_tests == 0 || b.box_tests == root);
            if stats {
                let stats = |h: &GpuHit| (h.box_tests, h.triangle_tests);
                assert_eq!(stats(&a), stats(&b), "ray {ray:?}");
            }
            if ray.flags & 3 == MODE_ANY {
                assert_eq!(a.prim == NO_HIT, b.prim == NO_HIT, "ray {ray:?}");
                continue;
            }
            let bits = |h: &GpuHit| (h.t.to_bits(), h.prim, h.u.to_bits(), h.v.to_bits(), h.count);
            assert_eq!(bits(&a), bits(&b), "flags {}, ray {ray:?}", ray.flags);
            let entries = |l: &[GpuHitEntry]| {
                l.iter()
                    .map(|e| (e.t.to_bits(), e.prim, e.u.to_bits(), e.v.to_bits()))
                    .collect::<Vec<_>>()
            };
            assert_eq!(entries(&lists[i * k..(i + 1) * k]), entries(&list));
        }
        sky
    }

    /// The lanes the packet walks' tests run on.
    type L8 = Pair<Portable>;

    const FLAGS: [u32; 4] = [
        MODE_CLOSEST,
        MODE_ANY,
        MODE_ALL,
        MODE_CLOSEST | (1 << CULL_SHIFT),
    ];

    /// Every camera packet that walks as one frustum gives each ray its single-ray answer, bit
    /// for bit (b and i aside: the walks differ), in every mode and with culling; turned away
    /// from the scene, stopped short of it, or with some rays not traced, packets that meet
    /// none of the root's boxes end before any ray's state is made, b and i included (the
    /// single walk too tests the root's boxes and nothing else).
    #[test]
    fn frustum_packets_give_each_ray_its_single_ray_answer() {
        let hills = Hills::new();
        let walk = hills.walk();
        // A narrow view (the camera's rays drawn to a twentieth of their angle from the mean),
        // so that packets of eight are within the frustum's cone.
        let rays = rays(&hills.scene, RayKind::Camera, 4096, 5);
        let mut camera = crate::frame::local_rays(crate::frame::Frame::at(hills.bvh.origin), &rays);
        let mean = camera
            .iter()
            .fold(Vec3::ZERO, |m, r| m + Vec3::from(r.dir).normalize())
            .normalize();
        for r in &mut camera {
            let d = Vec3::from(r.dir).normalize();
            r.dir = (mean + (d - mean) * 0.05).normalize().to_array();
        }
        let depth = stack_size(hills.wide.depth);
        let mut stack = vec![Pushed::default(); depth];
        let mut frustum_stack = vec![Entry::default(); depth];
        let (mut packets, mut ended) = (0, 0);
        for flags in FLAGS {
            let k = if flags & 3 == MODE_ALL { 4 } else { 0 };
            for (g, group) in camera.chunks_exact(PACKET).enumerate() {
                for away in [false, true] {
                    let mut group = altered(group, if away { g } else { 0 }, flags);
                    if away && g % 5 != 3 {
                        for r in &mut group {
                            r.dir = (-Vec3::from(r.dir)).to_array();
                        }
                    }
                    if !frustum_packet(&group) {
                        continue;
                    }
                    let mut lists = vec![GpuHitEntry::default(); PACKET * k];
                    let mut out = [GpuHit::default(); PACKET];
                    trace_frustum::<L8>(
                        &walk,
                        &group,
                        &L8::rays(&group),
                        &mut lists,
                        &mut frustum_stack,
                        &mut out,
                    );
                    let answers = (&out[..], &lists[..], k);
                    let sky = assert_single_ray_answers(&walk, &group, answers, &mut stack, away);
                    if away {
                        assert!(sky, "a packet turned away meets nothing");
                        ended += 1;
                    } else {
                        packets += 1;
                    }
                }
            }
        }
        assert!(packets > 1000, "only {packets} frustum packets");
        assert!(ended > 500, "only {ended} packets that meet nothing");
    }

    /// [`frustum_boxes`]'s promise, checked where it is tightest: every box a ray's own padded
    /// test ([`boxes_met`]) meets, the frustum meets too, for boxes with a corner or a face
    /// exactly on one of the packet's rays (grazed, their intervals a point before the pad).
    /// A frustum interval left unpadded passed every suite (a mutation test).
    #[test]
    fn frustums_meet_every_box_their_rays_graze() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let (mut met, mut checked) = (0usize, 0usize);
        for _ in 0..4000 {
            let origin = Vec3::new(
                rng.random_range(-50.0..50.0),
                rng.random_range(-50.0..50.0),
                rng.random_range(-50.0..50.0),
            );
            // Eight directions within a fraction of a degree of one another, of one sign per
            // axis (a pinhole camera's neighbouring pixels).
            let d0 = Vec3::new(
                rng.random_range(0.1..1.0),
                rng.random_range(0.1..1.0),
                rng.random_range(0.1..1.0),
            ) * Vec3::new(
                if rng.random_bool(0.5) { 1.0 } else { -1.0 },
                if rng.random_bool(0.5) { 1.0 } else { -1.0 },
                if rng.random_bool(0.5) { 1.0 } else { -1.0 },
            );
            let dirs: [Vec3; PACKET] = std::array::from_fn(|_| {
                let jitter = Vec3::new(
                    rng.random_range(-1e-3..1e-3),
                    rng.random_range(-1e-3..1e-3),
                    rng.random_range(-1e-3..1e-3),
                );
                (d0.normalize() + jitter).normalize()
            });
            let invs = dirs.map(safe_inverse);
            let splat3 = |v: Vec3| [L8::splat(v.x), L8::splat(v.y), L8::splat(v.z)];
            let (inv_lo, inv_hi) = invs
                .iter()
                .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), &v| {
                    (lo.min(v), hi.max(v))
                });
            // Each child box has a corner on a ray (a point `origin + d t`, rounded), and
            // reaches from it away from the ray or along an axis only (a face through it).
            let mut node = <WideNode as bytemuck::Zeroable>::zeroed();
            for lane in 0..WIDTH {
                let d = dirs[rng.random_range(0..PACKET)];
                let p = origin + d * rng.random_range(0.5f32..100.0);
                let extent = Vec3::new(
                    rng.random_range(0.0..2.0),
                    rng.random_range(0.0..2.0),
                    rng.random_range(0.0..2.0),
                ) * Vec3::from(std::array::from_fn::<f32, 3, _>(|_| {
                    if rng.random_bool(0.5) { 1.0 } else { 0.0 }
                }));
                let (lo, hi) = if rng.random_bool(0.5) {
                    (p, p + extent)
                } else {
                    (p - extent, p)
                };
                for a in 0..3 {
                    node.min[a][lane] = lo[a];
                    node.max[a][lane] = hi[a];
                }
            }
            let (frustum, _) = frustum_boxes::<L8>(
                &node,
                &splat3(origin),
                &splat3(inv_lo),
                &splat3(inv_hi),
                0.0,
                f32::INFINITY,
            );
            for (d, inv) in dirs.iter().zip(invs) {
                let ray = GpuRay {
                    origin: origin.to_array(),
                    dir: d.to_array(),
                    tmin: 0.0,
                    tmax: f32::INFINITY,
                    ..GpuRay::default()
                };
                let own = boxes::<L8>(&node, &RayLanes::new(&ray, inv), f32::INFINITY).0;
                assert_eq!(
                    own & !frustum,
                    0,
                    "a box the ray meets is not met by its frustum"
                );
                met += own.count_ones() as usize;
                checked += WIDTH;
            }
        }
        // Most grazed boxes are met by their own ray's padded test.
        assert!(
            met * 4 > checked / PACKET,
            "only {met} of {checked} boxes met"
        );
    }

    /// In a tree of one wide node (its children all leaves), a ray's box tests are the root's
    /// eight whatever walk it takes, so a packet that walks past the root gives each ray the
    /// single-ray walk's b. A packet walk that left the root's tests out of b passed every
    /// suite (a mutation test: b was compared only for packets that end at the root).
    #[test]
    fn packets_count_the_root_s_box_tests_in_b() {
        let mesh = terrain(4, 4, 0.0, 0.0, 1.0, hills);
        let scene = crate::Scene::from_meshes([("small".to_string(), mesh)]).unwrap();
        let bvh = Bvh::build(&scene, &BuildOptions::default()).unwrap();
        let wide = WideBvh::collapse(&bvh).unwrap();
        assert_eq!(wide.nodes.len(), 1, "one wide node");
        let walk = Scene {
            nodes: &wide.nodes,
            triangles: &bvh.triangles,
            triangle_ids: &bvh.triangle_ids,
            triangle_masks: &[],
            watertight: true,
            packets: true,
            size: wide.size(),
            interleave: false,
        };
        let root = u32::from(wide.nodes[0].occupied).count_ones();
        let depth = stack_size(wide.depth);
        let mut stack = vec![Pushed::default(); depth];
        let mut packet_stack = vec![PacketEntry::default(); depth];
        let mut walked = 0;
        for dir in [[0.0, 0.0, -1.0], [0.3, 0.2, -1.0]] {
            let mut world = Vec::new();
            for row in 0..16 {
                for i in 0..64 {
                    let origin = glam::DVec3::new(
                        0.25 * (row % 4) as f64 + 0.004 * i as f64,
                        0.25 * (row / 4) as f64,
                        10.0,
                    );
                    world.push(crate::Ray::new(origin, glam::DVec3::from_array(dir)));
                }
            }
            let local = crate::frame::local_rays(crate::frame::Frame::at(bvh.origin), &world);
            for flags in FLAGS {
                let k = if flags & 3 == MODE_ALL { 4 } else { 0 };
                for group in local.chunks_exact(PACKET) {
                    let group = altered(group, 0, flags);
                    if group_of::<L8>(&group, walk.size).0 != Group::Packet {
                        continue;
                    }
                    let mut lists = vec![GpuHitEntry::default(); PACKET * k];
                    let mut out = [GpuHit::default(); PACKET];
                    trace_packet::<L8>(
                        &walk,
                        &group,
                        &L8::rays(&group),
                        &mut lists,
                        &mut packet_stack,
                        &mut out,
                    );
                    for (ray, a) in group.iter().zip(&out) {
                        let mut list = vec![GpuHitEntry::default(); k];
                        let b = trace::<L8>(&walk, ray, &mut list, &mut stack);
                        assert_eq!(b.box_tests, root, "the single walk tests the root only");
                        assert_eq!(a.box_tests, b.box_tests, "ray {ray:?}");
                        walked += usize::from(b.triangle_tests > 0);
                    }
                }
            }
        }
        assert!(walked > 1000, "only {walked} rays went past the root");
    }

    /// Every packet of parallel rays (an orthographic view, straight down and tilted, over the
    /// terrain and beside it) gives each ray its single-ray answer, bit for bit, in every mode;
    /// packets that meet none of the root's boxes (beside the terrain, stopped short of it, or
    /// with some rays not traced) end before their states are made, with b and i as well.
    #[test]
    fn packets_give_each_ray_its_single_ray_answer() {
        let hills = Hills::new();
        let walk = hills.walk();
        let depth = stack_size(hills.wide.depth);
        let mut stack = vec![Pushed::default(); depth];
        let mut packet_stack = vec![PacketEntry::default(); depth];
        let (mut packets, mut ended) = (0, 0);
        for dir in [[0.0, 0.0, -1.0], [0.3, 0.2, -1.0]] {
            // Rows of 64 rays 0.05 apart (a packet's origins within 1% of the scene's size),
            // starting at x = -2 to 36 (beside the terrain's edge, and over it), every third row
            // off the terrain altogether.
            let mut world = Vec::new();
            for row in 0..120 {
                let x0 = if row % 3 == 2 {
                    -40.0
                } else {
                    -2.0 + (row % 20) as f64 * 2.0
                };
                for i in 0..64 {
                    let y = 0.25 * row as f64;
                    let origin = glam::DVec3::new(x0 + 0.05 * i as f64, y, 30.0);
                    world.push(crate::Ray::new(origin, glam::DVec3::from_array(dir)));
                }
            }
            let local = crate::frame::local_rays(crate::frame::Frame::at(hills.bvh.origin), &world);
            for flags in FLAGS {
                let k = if flags & 3 == MODE_ALL { 4 } else { 0 };
                for (g, group) in local.chunks_exact(PACKET).enumerate() {
                    let group = altered(group, g, flags);
                    if group_of::<L8>(&group, walk.size).0 != Group::Packet {
                        continue;
                    }
                    packets += 1;
                    let mut lists = vec![GpuHitEntry::default(); PACKET * k];
                    let mut out = [GpuHit::default(); PACKET];
                    trace_packet::<L8>(
                        &walk,
                        &group,
                        &L8::rays(&group),
                        &mut lists,
                        &mut packet_stack,
                        &mut out,
                    );
                    let answers = (&out[..], &lists[..], k);
                    if assert_single_ray_answers(&walk, &group, answers, &mut stack, false) {
                        // A packet none of whose rays went past the root: b and i too.
                        assert_single_ray_answers(&walk, &group, answers, &mut stack, true);
                        ended += 1;
                    }
                }
            }
        }
        assert!(packets > 500, "only {packets} packets");
        assert!(ended > 100, "only {ended} packets that meet nothing");
    }

    #[test]
    fn transpose_bits_moves_bit_8i_plus_j_to_8j_plus_i() {
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        for _ in 0..64 {
            let t = transpose_bits(x);
            for i in 0..8 {
                for j in 0..8 {
                    assert_eq!(x >> (8 * i + j) & 1, t >> (8 * j + i) & 1, "{x:#x} {i} {j}");
                }
            }
            x = x.rotate_left(13).wrapping_mul(0x2545_F491_4F6C_DD1D);
        }
    }
}
