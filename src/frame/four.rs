//! The frame's f64 arithmetic four rays at a time: world rays into the scene frame
//! ([`local_rays_into`]) and hits refined ([`refine_four`]), each giving the very bits of the
//! one-ray functions, with the divisions and square roots in f64 lanes where the CPU has AVX.
//!
//! Converting a ray costs two divisions (by a power of two, then by the scaled length) and a
//! square root in f64; with six divisions it was about a tenth of the whole pick of 1M camera
//! rays (BENCHMARKS.md). The lanes do the same IEEE operations in the same order as the scalar
//! function (no fused multiply-add, the same comparisons for the clamps; a division by a
//! power of two as a product with its exact inverse), so each is rounded the same. A ray off
//! the common path (not finite, a subnormal or zero direction or one shorter than 2^-800,
//! `tmin >= tmax` once in f32, an origin beyond f32, layer mask 0) is handed to the scalar
//! function.
//!
//! The hits' f64 refinement goes four at a time too ([`refine_four`], bit for bit
//! [`super::refine`] on each hit): three divisions, a square root and one more division each.

use super::{FAR_REACHES, Frame, NEVER_TRACED, Refined, local_ray, refine};
use crate::exact::scales;
use crate::layout::GpuRay;
use crate::query::Query;
use crate::ray::Ray;
use glam::DVec3;

/// Fills `local[i]` and `lengths[i]` as `local_ray(frame, &rays[i], query)` would:
/// the scene-frame ray and the world direction's length, or [`NEVER_TRACED`] and NaN for an
/// invalid ray. The three slices have the same length.
pub fn local_rays_into(
    frame: Frame,
    rays: &[Ray],
    query: &Query,
    local: &mut [GpuRay],
    lengths: &mut [f64],
) {
    assert!(
        rays.len() == local.len() && rays.len() == lengths.len(),
        "one output per ray"
    );
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the CPU has AVX (checked just above).
        unsafe { avx::local_rays_into(frame, rays, query, local, lengths) };
        return;
    }
    scalar(frame, rays, query, local, lengths);
}

/// [`local_rays_into`] followed by [`put_origin_lo`](super::put_origin_lo) (what an instanced
/// scene's rays need), in one pass where the CPU has AVX2 and F16C: each origin's rest is taken
/// from the lanes that just rounded it to f32, instead of from the rays read and gathered again
/// (that second pass was 3% of a pick of the field of 10,000 bunnies). The same bits as the two
/// passes.
pub fn local_rays_with_rests_into(
    frame: Frame,
    rays: &[Ray],
    query: &Query,
    local: &mut [GpuRay],
    lengths: &mut [f64],
) {
    assert!(
        rays.len() == local.len() && rays.len() == lengths.len(),
        "one output per ray"
    );
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("f16c") {
        // SAFETY: the CPU has AVX2 and F16C (checked just above).
        unsafe { avx::local_rays_with_rests_into(frame, rays, query, local, lengths) };
        return;
    }
    local_rays_into(frame, rays, query, local, lengths);
    put_origin_lo_into(frame, rays, local);
}

/// `refine(triangles[i], rays[i], || traced(i))` for the four hits, bit for bit. The corners are
/// read where they lie (the scene's positions): the lanes load them straight into registers,
/// where whole triangles passed by value went through the stack, and loads that straddled
/// the stores made there stalled (a fifth of the refinement's time on the bunny). Never
/// inlined: inlined into `picker::refine_into` (as a change elsewhere in the crate once made
/// the compiler choose), its two paths' results met in a temporary copied out by `memmove`,
/// and the bunny's incoherent picks were 1–2% slower; out of line, the lanes write the answer
/// straight into the caller's slot.
#[inline(never)]
pub fn refine_four(
    triangles: [[&DVec3; 3]; 4],
    rays: [&Ray; 4],
    traced: impl Fn(usize) -> [f64; 3],
) -> [Refined; 4] {
    // A direction near an end of f64's range is scaled first, which the lanes leave out.
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") && !rays.iter().any(|r| scales(r.dir)) {
        // SAFETY: the CPU has AVX (checked just above).
        return unsafe { avx::refine_four(triangles, rays, traced) };
    }
    [0, 1, 2, 3].map(|i| refine(triangles[i].map(|v| *v), rays[i], || traced(i)))
}

/// [`super::put_origin_lo`] over `rays` and their scene-frame rays `local` (the same length),
/// four rays at a time in f64 lanes where the CPU has AVX2 and F16C: each rest rounded as
/// `half_bits` rounds it (the same products by powers of two and the same exact rounding to an
/// integer), the result, a half float already, converted exactly by F16C.
pub(super) fn put_origin_lo_into(frame: Frame, rays: &[Ray], local: &mut [GpuRay]) {
    assert_eq!(rays.len(), local.len(), "one scene-frame ray per ray");
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("f16c") {
        done = rays.len() / 4 * 4;
        // SAFETY: the CPU has AVX2 and F16C (checked just above).
        unsafe { avx::put_origin_lo_into(frame.origin, &rays[..done], &mut local[..done]) };
        // An origin the conversion moved ([`Frame::shift`]) has its rest taken where it went.
        for (ray, l) in rays[..done].iter().zip(&mut local[..done]) {
            if frame.shift(ray) != 0.0 {
                super::origin_lo_of(frame, ray, l);
            }
        }
    }
    for (ray, l) in rays[done..].iter().zip(&mut local[done..]) {
        super::origin_lo_of(frame, ray, l);
    }
}

/// [`local_rays_into`] one ray at a time.
fn scalar(frame: Frame, rays: &[Ray], query: &Query, local: &mut [GpuRay], lengths: &mut [f64]) {
    for ((ray, local), length) in rays.iter().zip(local).zip(lengths) {
        (*local, *length) = local_ray(frame, ray, query).unwrap_or((NEVER_TRACED, f64::NAN));
    }
}

/// The square of the distance from the frame's origin past which [`Frame::shift`] may move an
/// origin (infinite: none is moved), for the lanes' check: `offset.length_squared()` above it
/// sends a ray to the scalar function.
fn far_squared(frame: Frame) -> f64 {
    let limit = frame.reach * FAR_REACHES;
    limit * limit
}

#[cfg(target_arch = "x86_64")]
mod avx {
    use super::{Frame, GpuRay, Query, Ray, Refined, far_squared, scalar};
    use glam::DVec3;
    use std::arch::x86_64::*;

    /// [`super::local_rays_into`] on AVX lanes, four rays at a time.
    ///
    /// # Safety
    /// The CPU has AVX.
    #[target_feature(enable = "avx")]
    pub unsafe fn local_rays_into(
        frame: Frame,
        rays: &[Ray],
        query: &Query,
        local: &mut [GpuRay],
        lengths: &mut [f64],
    ) {
        let flags = query.flags();
        let far = far_squared(frame);
        let whole = rays.len() / 4 * 4;
        for g in (0..whole).step_by(4) {
            let r = &rays[g..g + 4];
            let (out, len) = (&mut local[g..g + 4], &mut lengths[g..g + 4]);
            four(frame.origin, far, r, flags, out, len, &mut Skip);
            for i in 0..4 {
                if out[i].origin_lo[0] != 0 {
                    // Off the common path: the scalar function decides.
                    scalar(
                        frame,
                        &r[i..i + 1],
                        query,
                        &mut out[i..i + 1],
                        &mut len[i..i + 1],
                    );
                }
            }
        }
        scalar(
            frame,
            &rays[whole..],
            query,
            &mut local[whole..],
            &mut lengths[whole..],
        );
    }

    /// [`super::local_rays_with_rests_into`] on AVX2 and F16C lanes, four rays at a time: the
    /// rests are `put_origin_lo_into`'s (`half_lanes` of the f64 offset less its f32 rounding),
    /// made from the conversion's own lanes.
    ///
    /// # Safety
    /// The CPU has AVX2 and F16C.
    #[target_feature(enable = "avx2,f16c")]
    pub unsafe fn local_rays_with_rests_into(
        frame: Frame,
        rays: &[Ray],
        query: &Query,
        local: &mut [GpuRay],
        lengths: &mut [f64],
    ) {
        let flags = query.flags();
        let far = far_squared(frame);
        let whole = rays.len() / 4 * 4;
        for g in (0..whole).step_by(4) {
            let r = &rays[g..g + 4];
            let (out, len) = (&mut local[g..g + 4], &mut lengths[g..g + 4]);
            let mut lanes = Keep {
                offset: [_mm256_setzero_pd(); 3],
                origin: [_mm_setzero_ps(); 3],
            };
            four(frame.origin, far, r, flags, out, len, &mut lanes);
            // `(ray.origin - scene_origin) - l.origin as f64`: the offset's f64 lanes less their
            // f32 rounding (the origin `four` wrote). Written out, without `array::map`.
            let mut halves = [[0u16; 8]; 3];
            for ((h, offset), origin) in halves.iter_mut().zip(lanes.offset).zip(lanes.origin) {
                let rest = _mm256_sub_pd(offset, _mm256_cvtps_pd(origin));
                // SAFETY: `h` is eight u16s; storeu has no alignment need.
                unsafe { _mm_storeu_si128(h.as_mut_ptr().cast(), half_lanes(rest)) };
            }
            for i in 0..4 {
                if out[i].origin_lo[0] == 0 {
                    // On the common path the ray is traced (`gets_origin_rest`).
                    let (x, y, z) = (halves[0][i], halves[1][i], halves[2][i]);
                    out[i].origin_lo = [u32::from(x) | u32::from(y) << 16, u32::from(z)];
                } else {
                    // Off it: the scalar functions decide.
                    scalar(
                        frame,
                        &r[i..i + 1],
                        query,
                        &mut out[i..i + 1],
                        &mut len[i..i + 1],
                    );
                    super::super::origin_lo_of(frame, &r[i], &mut out[i]);
                }
            }
        }
        scalar(
            frame,
            &rays[whole..],
            query,
            &mut local[whole..],
            &mut lengths[whole..],
        );
        for (ray, l) in rays[whole..].iter().zip(&mut local[whole..]) {
            super::super::origin_lo_of(frame, ray, l);
        }
    }

    /// Four f64 lanes from four values.
    #[inline(always)]
    fn lanes(v: [f64; 4]) -> __m256d {
        // SAFETY: the CPU has AVX (callers are AVX functions); loadu reads the four values.
        unsafe { _mm256_loadu_pd(v.as_ptr()) }
    }

    #[inline(always)]
    fn values(v: __m256d) -> [f64; 4] {
        let mut out = [0.0; 4];
        // SAFETY: as in `lanes`; storeu writes the four values.
        unsafe { _mm256_storeu_pd(out.as_mut_ptr(), v) };
        out
    }

    /// Three f64 lanes sets: x, y and z of four vectors.
    type V3 = [__m256d; 3];

    const _: () = assert!(
        size_of::<DVec3>() == 24
            && std::mem::offset_of!(DVec3, y) == 8
            && std::mem::offset_of!(DVec3, z) == 16,
        "points() reads a DVec3 as three f64 in a row"
    );

    /// x, y and z of four points, loaded where they lie and transposed in registers: each
    /// point's x and y as one pair, its z alone.
    #[inline]
    #[target_feature(enable = "avx")]
    fn points([p0, p1, p2, p3]: [&DVec3; 4]) -> V3 {
        // SAFETY: each pointer is a whole DVec3, three f64 x, y, z in order (asserted below);
        // the pair loads read x and y, the single loads z.
        unsafe {
            let at = |p: &DVec3| (p as *const DVec3).cast::<f64>();
            let xy = |p: &DVec3| _mm_loadu_pd(at(p));
            let z = |p: &DVec3| _mm_load_sd(at(p).add(2));
            // [x0 y0 | x2 y2] and [x1 y1 | x3 y3]: unpacking within the halves gives x and y.
            let even = _mm256_insertf128_pd::<1>(_mm256_castpd128_pd256(xy(p0)), xy(p2));
            let odd = _mm256_insertf128_pd::<1>(_mm256_castpd128_pd256(xy(p1)), xy(p3));
            let z01 = _mm_unpacklo_pd(z(p0), z(p1));
            let z23 = _mm_unpacklo_pd(z(p2), z(p3));
            [
                _mm256_unpacklo_pd(even, odd),
                _mm256_unpackhi_pd(even, odd),
                _mm256_insertf128_pd::<1>(_mm256_castpd128_pd256(z01), z23),
            ]
        }
    }

    #[inline]
    #[target_feature(enable = "avx")]
    fn sub(a: V3, b: V3) -> V3 {
        [
            _mm256_sub_pd(a[0], b[0]),
            _mm256_sub_pd(a[1], b[1]),
            _mm256_sub_pd(a[2], b[2]),
        ]
    }

    /// glam's `cross`: `(a.y * b.z - b.y * a.z, a.z * b.x - b.z * a.x, a.x * b.y - b.x * a.y)`.
    #[inline]
    #[target_feature(enable = "avx")]
    fn cross(a: V3, b: V3) -> V3 {
        let m = _mm256_mul_pd;
        [
            _mm256_sub_pd(m(a[1], b[2]), m(b[1], a[2])),
            _mm256_sub_pd(m(a[2], b[0]), m(b[2], a[0])),
            _mm256_sub_pd(m(a[0], b[1]), m(b[0], a[1])),
        ]
    }

    /// glam's `dot`: `(a.x * b.x + a.y * b.y) + a.z * b.z`.
    #[inline]
    #[target_feature(enable = "avx")]
    fn dot(a: V3, b: V3) -> __m256d {
        let m = _mm256_mul_pd;
        _mm256_add_pd(_mm256_add_pd(m(a[0], b[0]), m(a[1], b[1])), m(a[2], b[2]))
    }

    /// [`super::refine_four`] on AVX lanes: `exact::ray_triangle_f64`, the fallback, `Ray::at`
    /// and `normalize_or_zero`, operation for operation.
    ///
    /// # Safety
    /// The CPU has AVX.
    #[target_feature(enable = "avx")]
    pub unsafe fn refine_four(
        triangles: [[&DVec3; 3]; 4],
        rays: [&Ray; 4],
        traced: impl Fn(usize) -> [f64; 3],
    ) -> [Refined; 4] {
        let [a, b, c, d] = triangles;
        let v0 = points([a[0], b[0], c[0], d[0]]);
        let v1 = points([a[1], b[1], c[1], d[1]]);
        let v2 = points([a[2], b[2], c[2], d[2]]);
        let [a, b, c, d] = rays;
        let origin = points([&a.origin, &b.origin, &c.origin, &d.origin]);
        let dir = points([&a.dir, &b.dir, &c.dir, &d.dir]);
        // ray_triangle_f64.
        let e1 = sub(v1, v0);
        let e2 = sub(v2, v0);
        let p = cross(dir, e2);
        let det = dot(p, e1);
        let to_origin = sub(origin, v0);
        let u = _mm256_div_pd(dot(p, to_origin), det);
        let q = cross(to_origin, e1);
        let v = _mm256_div_pd(dot(q, dir), det);
        let t = _mm256_div_pd(dot(q, e2), det);
        // The exact values where det != 0, t, u and v are finite and t != 0, and they are
        // plausible (`super::plausible`): u, v ≥ −1 and u + v ≤ 2.
        let splat = _mm256_set1_pd;
        let abs = |x: __m256d| _mm256_andnot_pd(splat(-0.0), x);
        let finite = |x: __m256d| _mm256_cmp_pd::<_CMP_LT_OQ>(abs(x), splat(f64::INFINITY));
        let exact = _mm256_and_pd(
            _mm256_and_pd(
                _mm256_cmp_pd::<_CMP_NEQ_OQ>(det, splat(0.0)),
                _mm256_cmp_pd::<_CMP_NEQ_OQ>(t, splat(0.0)),
            ),
            _mm256_and_pd(_mm256_and_pd(finite(t), finite(u)), finite(v)),
        );
        let within = _mm256_and_pd(
            _mm256_and_pd(
                _mm256_cmp_pd::<_CMP_GE_OQ>(u, splat(-1.0)),
                _mm256_cmp_pd::<_CMP_GE_OQ>(v, splat(-1.0)),
            ),
            _mm256_cmp_pd::<_CMP_LE_OQ>(_mm256_add_pd(u, v), splat(2.0)),
        );
        let exact = _mm256_and_pd(exact, within);
        // The traversal's values, asked for only where a lane needs them.
        let traced = match _mm256_movemask_pd(exact) {
            0b1111 => [[0.0; 3]; 4],
            _ => [traced(0), traced(1), traced(2), traced(3)],
        };
        let pick = |x: __m256d, k: usize| _mm256_blendv_pd(lanes(traced.map(|f| f[k])), x, exact);
        let (t, u, v) = (pick(t, 0), pick(u, 1), pick(v, 2));
        // Ray::at: origin + dir * t.
        let position = [0, 1, 2].map(|a| _mm256_add_pd(origin[a], _mm256_mul_pd(dir[a], t)));
        // normalize_or_zero of (b - a) x (c - a): times 1 / sqrt(n . n) when that is finite
        // and positive, else zero.
        let n = cross(e1, e2);
        let rcp = _mm256_div_pd(splat(1.0), _mm256_sqrt_pd(dot(n, n)));
        let keep = _mm256_and_pd(finite(rcp), _mm256_cmp_pd::<_CMP_GT_OQ>(rcp, splat(0.0)));
        let normal = [0, 1, 2].map(|a| _mm256_and_pd(_mm256_mul_pd(n[a], rcp), keep));
        let (t, u, v) = (values(t), values(u), values(v));
        let position = position.map(values);
        let normal = normal.map(values);
        // Written out (not `[0, 1, 2, 3].map`, whose closure a build of the instances bench
        // left as a call, four per refinement, with its results through memory: the
        // one-bunny pick there 6% slower than where it was inlined).
        [
            refined_at(&t, &u, &v, &position, &normal, 0),
            refined_at(&t, &u, &v, &position, &normal, 1),
            refined_at(&t, &u, &v, &position, &normal, 2),
            refined_at(&t, &u, &v, &position, &normal, 3),
        ]
    }

    /// Hit `i`'s [`Refined`] from the four hits' lanes, as values.
    #[inline(always)]
    fn refined_at(
        t: &[f64; 4],
        u: &[f64; 4],
        v: &[f64; 4],
        position: &[[f64; 4]; 3],
        normal: &[[f64; 4]; 3],
        i: usize,
    ) -> Refined {
        Refined {
            t: t[i],
            u: u[i],
            v: v[i],
            position: DVec3::new(position[0][i], position[1][i], position[2][i]),
            normal: DVec3::new(normal[0][i], normal[1][i], normal[2][i]),
        }
    }

    /// [`super::put_origin_lo_into`] on lanes, four rays at a time (`rays.len()` a multiple
    /// of four).
    ///
    /// # Safety
    /// The CPU has AVX2 and F16C.
    #[target_feature(enable = "avx2,f16c")]
    pub(super) unsafe fn put_origin_lo_into(
        scene_origin: DVec3,
        rays: &[Ray],
        local: &mut [GpuRay],
    ) {
        let so = [
            _mm256_set1_pd(scene_origin.x),
            _mm256_set1_pd(scene_origin.y),
            _mm256_set1_pd(scene_origin.z),
        ];
        // Written out, without `array::map` closures: the instances bench's build left one as
        // a call per axis and ray.
        for (r, l) in rays.chunks_exact(4).zip(local.chunks_exact_mut(4)) {
            let origin = points([&r[0].origin, &r[1].origin, &r[2].origin, &r[3].origin]);
            let mut halves = [[0u16; 8]; 3];
            for a in 0..3 {
                let f32_origin = _mm256_cvtps_pd(_mm_set_ps(
                    l[3].origin[a],
                    l[2].origin[a],
                    l[1].origin[a],
                    l[0].origin[a],
                ));
                // `(ray.origin - scene_origin) - l.origin as f64`.
                let rest = _mm256_sub_pd(_mm256_sub_pd(origin[a], so[a]), f32_origin);
                // SAFETY: `halves[a]` is eight u16s; storeu has no alignment need.
                unsafe { _mm_storeu_si128(halves[a].as_mut_ptr().cast(), half_lanes(rest)) };
            }
            for (i, l) in l.iter_mut().enumerate() {
                if super::super::gets_origin_rest(l) {
                    let (x, y, z) = (halves[0][i], halves[1][i], halves[2][i]);
                    l.origin_lo = [u32::from(x) | u32::from(y) << 16, u32::from(z)];
                }
            }
        }
    }

    /// `rest_bits` on four lanes (`half_bits`, kept when finite and not zero, else 0), in the
    /// low four u16s: the
    /// spacing of half floats at each value, a product by its inverse, the exact rounding to
    /// an integer by adding and taking away 2^52, the product back (all powers of two, made
    /// from exponent bits), then F16C's conversion of what is a half float already.
    #[inline]
    #[target_feature(enable = "avx2,f16c")]
    pub(super) fn half_lanes(x: __m256d) -> __m128i {
        let bias = _mm256_set1_epi64x(1023);
        let exponent = _mm256_sub_epi64(
            _mm256_and_si256(
                _mm256_srli_epi64::<52>(_mm256_castpd_si256(x)),
                _mm256_set1_epi64x(0x7ff),
            ),
            bias,
        );
        // clamp(-14, 15) - 10, in 64-bit lanes (no 64-bit min and max before AVX-512).
        let lo = _mm256_set1_epi64x(-14);
        let hi = _mm256_set1_epi64x(15);
        let e = _mm256_blendv_epi8(exponent, lo, _mm256_cmpgt_epi64(lo, exponent));
        let e = _mm256_blendv_epi8(e, hi, _mm256_cmpgt_epi64(e, hi));
        let e = _mm256_sub_epi64(e, _mm256_set1_epi64x(10));
        let power =
            |e: __m256i| _mm256_castsi256_pd(_mm256_slli_epi64::<52>(_mm256_add_epi64(e, bias)));
        let up = power(e);
        let down = power(_mm256_sub_epi64(_mm256_setzero_si256(), e));
        let sign = _mm256_set1_pd(-0.0);
        let units = _mm256_andnot_pd(sign, _mm256_mul_pd(x, down));
        let two_52 = _mm256_set1_pd(4_503_599_627_370_496.0);
        let integer = _mm256_sub_pd(_mm256_add_pd(units, two_52), two_52);
        // copysign(integer, x): integer is not negative, so its sign bit is clear.
        let signed = _mm256_or_pd(integer, _mm256_and_pd(sign, x));
        let rounded = _mm256_mul_pd(signed, up);
        let h = _mm_cvtps_ph::<_MM_FROUND_TO_NEAREST_INT>(_mm256_cvtpd_ps(rounded));
        // Kept: an exponent field other than 31 (finite) and a magnitude other than 0.
        let field = _mm_and_si128(_mm_srli_epi16::<10>(h), _mm_set1_epi16(31));
        let magnitude = _mm_and_si128(h, _mm_set1_epi16(0x7fff));
        let kept = _mm_andnot_si128(
            _mm_or_si128(
                _mm_cmpeq_epi16(magnitude, _mm_setzero_si128()),
                _mm_cmpeq_epi16(field, _mm_set1_epi16(31)),
            ),
            _mm_set1_epi16(-1),
        );
        _mm_and_si128(h, kept)
    }

    /// The shortest direction the lanes convert: `1 / length` is finite from it up, and so is
    /// `cap / length` for any finite f32 range cap (below 2^128), so neither needs a division.
    const SHORTEST_ON_LANES: f64 = f64::from_bits((1023 - 800) << 52);

    /// What [`four`] hands on of its lanes besides the rays it writes: nothing ([`Skip`], the
    /// plain conversion), or the origins' offsets in f64 and f32 ([`Keep`], for the rests).
    /// Two types, so `four` is two functions, each inlined into its one caller (one function
    /// with two callers was left out of line, and the bunny's camera picks were 5% slower).
    pub(super) trait Lanes {
        fn keep(&mut self, offset: [__m256d; 3], origin: [__m128; 3]);
    }

    /// Keeps nothing.
    pub(super) struct Skip;

    impl Lanes for Skip {
        #[inline(always)]
        fn keep(&mut self, _: [__m256d; 3], _: [__m128; 3]) {}
    }

    /// Keeps `ray.origin - scene_origin` in f64 lanes and rounded to f32 (the rays' scene-frame
    /// origins), x, y and z.
    pub(super) struct Keep {
        offset: [__m256d; 3],
        origin: [__m128; 3],
    }

    impl Lanes for Keep {
        #[inline(always)]
        fn keep(&mut self, offset: [__m256d; 3], origin: [__m128; 3]) {
            (self.offset, self.origin) = (offset, origin);
        }
    }

    /// Converts four rays on the common path of [`super::super::local_ray`]; a ray off it is
    /// marked by a nonzero `origin_lo[0]` (the scalar function then overwrites it).
    #[target_feature(enable = "avx")]
    pub(super) fn four<K: Lanes>(
        scene_origin: DVec3,
        far_squared: f64,
        r: &[Ray],
        flags: u32,
        out: &mut [GpuRay],
        len: &mut [f64],
        keep: &mut K,
    ) {
        let column =
            |f: &dyn Fn(&Ray) -> f64| _mm256_set_pd(f(&r[3]), f(&r[2]), f(&r[1]), f(&r[0]));
        let (ox, oy, oz) = (
            column(&|r| r.origin.x),
            column(&|r| r.origin.y),
            column(&|r| r.origin.z),
        );
        let (dx, dy, dz) = (
            column(&|r| r.dir.x),
            column(&|r| r.dir.y),
            column(&|r| r.dir.z),
        );
        let (tmin, tmax) = (column(&|r| r.tmin), column(&|r| r.tmax));
        let splat = _mm256_set1_pd;
        let abs = |v: __m256d| _mm256_andnot_pd(splat(-0.0), v);
        let finite = |v: __m256d| _mm256_cmp_pd::<_CMP_LT_OQ>(abs(v), splat(f64::INFINITY));
        let and = _mm256_and_pd;
        // `Ray::is_valid`'s first checks: finite origin and direction, tmin <= tmax (no NaN).
        let mut ok = and(
            and(and(finite(ox), finite(oy)), and(finite(oz), finite(dx))),
            and(
                and(finite(dy), finite(dz)),
                _mm256_cmp_pd::<_CMP_LE_OQ>(tmin, tmax),
            ),
        );
        // `direction_scale`: `dir.abs().max_element()` (glam's max is `if a > b { a } else
        // { b }`, as maxpd is) cut to its power of two; a subnormal largest component (or
        // none) is left to the scalar function.
        let max = _mm256_max_pd(abs(dx), _mm256_max_pd(abs(dy), abs(dz)));
        ok = and(
            ok,
            _mm256_cmp_pd::<_CMP_GE_OQ>(max, splat(f64::MIN_POSITIVE)),
        );
        let scale = and(max, splat(f64::from_bits(crate::ray::EXPONENT_BITS)));
        // The inverse of a power of two is exact, so these products are the quotients.
        let inverse_scale = _mm256_div_pd(splat(1.0), scale);
        let (sx, sy, sz) = (
            _mm256_mul_pd(dx, inverse_scale),
            _mm256_mul_pd(dy, inverse_scale),
            _mm256_mul_pd(dz, inverse_scale),
        );
        // `scaled.length()`: sqrt((x * x + y * y) + z * z).
        let squares = _mm256_add_pd(
            _mm256_add_pd(_mm256_mul_pd(sx, sx), _mm256_mul_pd(sy, sy)),
            _mm256_mul_pd(sz, sz),
        );
        let scaled_length = _mm256_sqrt_pd(squares);
        let dir_length = _mm256_mul_pd(scaled_length, scale);
        // A finite length whose inverse is finite too. From 2^-800 up both that and the range
        // cap's check below hold without a division (a finite f32 cap over such a length stays
        // below 2^928); shorter lengths are left to the scalar function.
        ok = and(
            ok,
            and(
                finite(dir_length),
                _mm256_cmp_pd::<_CMP_GE_OQ>(dir_length, splat(SHORTEST_ON_LANES)),
            ),
        );
        let inverse_length = _mm256_div_pd(splat(1.0), scaled_length);
        let unit = [
            _mm256_cvtpd_ps(_mm256_mul_pd(sx, inverse_length)),
            _mm256_cvtpd_ps(_mm256_mul_pd(sy, inverse_length)),
            _mm256_cvtpd_ps(_mm256_mul_pd(sz, inverse_length)),
        ];
        let offset = [
            _mm256_sub_pd(ox, splat(scene_origin.x)),
            _mm256_sub_pd(oy, splat(scene_origin.y)),
            _mm256_sub_pd(oz, splat(scene_origin.z)),
        ];
        let origin = [
            _mm256_cvtpd_ps(offset[0]),
            _mm256_cvtpd_ps(offset[1]),
            _mm256_cvtpd_ps(offset[2]),
        ];
        keep.keep(offset, origin);
        // An origin [`Frame::shift`] may move is left to the scalar function: the offset's
        // `length_squared()`, operation for operation, no farther out than that.
        let length_squared = _mm256_add_pd(
            _mm256_add_pd(
                _mm256_mul_pd(offset[0], offset[0]),
                _mm256_mul_pd(offset[1], offset[1]),
            ),
            _mm256_mul_pd(offset[2], offset[2]),
        );
        ok = and(
            ok,
            _mm256_cmp_pd::<_CMP_LE_OQ>(length_squared, splat(far_squared)),
        );
        // `t.clamp(-f64::MAX, f64::MAX)`, then `(t * dir_length).clamp(f32 range) as f32`:
        // for values that are not NaN (tmin and tmax are not, on the common path, nor their
        // products with a finite length), clamp is max then min.
        let clamp =
            |v: __m256d, lo: f64, hi: f64| _mm256_min_pd(_mm256_max_pd(v, splat(lo)), splat(hi));
        let to_f32 = |t: __m256d| {
            let t = clamp(t, -f64::MAX, f64::MAX);
            _mm256_cvtpd_ps(clamp(
                _mm256_mul_pd(t, dir_length),
                f32::MIN as f64,
                f32::MAX as f64,
            ))
        };
        // A direction shorter than 1 whose range cap would carry a hit's world t past f64::MAX
        // needs the cap stepped down; none on the lanes does (`SHORTEST_ON_LANES`).
        let (tmin32, tmax32) = (to_f32(tmin), to_f32(tmax));
        let finite32 = |v: __m128| {
            _mm_cmplt_ps(
                _mm_andnot_ps(_mm_set1_ps(-0.0), v),
                _mm_set1_ps(f32::INFINITY),
            )
        };
        // The origin fits f32; tmin < tmax in f32 (so `min(tmax)` keeps tmin, whatever the
        // zeros' signs).
        let ok32 = _mm_and_ps(
            _mm_and_ps(finite32(origin[0]), finite32(origin[1])),
            _mm_and_ps(finite32(origin[2]), _mm_cmplt_ps(tmin32, tmax32)),
        );
        let ok = _mm256_movemask_pd(ok) & _mm_movemask_ps(ok32);
        let mut lanes = [[0.0f32; 4]; 8];
        for (k, v) in unit
            .iter()
            .chain(&origin)
            .chain([&tmin32, &tmax32])
            .enumerate()
        {
            // SAFETY: `lanes[k]` is four f32s; storeu has no alignment need.
            unsafe { _mm_storeu_ps(lanes[k].as_mut_ptr(), *v) };
        }
        let mut dl = [0.0f64; 4];
        // SAFETY: `dl` is four f64s.
        unsafe { _mm256_storeu_pd(dl.as_mut_ptr(), dir_length) };
        for i in 0..4 {
            // The unit direction is never zero here: its largest component is at least 1/√3.
            let common = ok & (1 << i) != 0 && r[i].mask != 0;
            out[i] = GpuRay {
                origin: [lanes[3][i], lanes[4][i], lanes[5][i]],
                tmin: lanes[6][i],
                dir: [lanes[0][i], lanes[1][i], lanes[2][i]],
                tmax: lanes[7][i],
                mask: r[i].mask,
                flags,
                origin_lo: [u32::from(!common), 0],
            };
            len[i] = dl[i];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn same(a: &GpuRay, b: &GpuRay) -> bool {
        bytemuck::bytes_of(a) == bytemuck::bytes_of(b)
    }

    /// Special values and ordinary ones, so that every branch of the scalar function is met.
    fn component() -> impl Strategy<Value = f64> {
        prop_oneof![
            Just(0.0),
            Just(-0.0),
            Just(f64::INFINITY),
            Just(f64::NEG_INFINITY),
            Just(f64::NAN),
            Just(f64::MAX),
            Just(f64::MIN_POSITIVE),
            Just(1e-300),
            Just(1e300),
            Just(5e38),
            -1e7..1e7f64,
            -1.0..1.0f64,
            -1e-3..1e-3f64,
        ]
    }

    fn ray() -> impl Strategy<Value = Ray> {
        (
            [component(), component(), component()],
            [component(), component(), component()],
            component(),
            component(),
            prop_oneof![Just(0u32), Just(u32::MAX), any::<u32>()],
        )
            .prop_map(|(o, d, tmin, tmax, mask)| Ray {
                origin: DVec3::from(o),
                dir: DVec3::from(d),
                tmin,
                tmax,
                mask,
            })
    }

    /// A frame's reach: unknown (no origin moved), or one that the rays' origins (within 1e7
    /// of the frame's, or special) are often more than [`FAR_REACHES`] of out.
    fn reach() -> impl Strategy<Value = f64> {
        prop_oneof![Just(f64::INFINITY), 1e-3..1e6f64]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]
        #[test]
        fn four_at_a_time_gives_the_scalar_bits(
            rays in prop::collection::vec(ray(), 0..11),
            origin in [-1e6..1e6f64, -1e6..1e6f64, -1e6..1e6f64],
            reach in reach(),
            cull in 0usize..3,
        ) {
            let query = Query {
                cull: [crate::query::Cull::None, crate::query::Cull::Back, crate::query::Cull::Front][cull],
                ..Query::default()
            };
            let frame = Frame { origin: DVec3::from(origin), reach };
            let mut local = vec![NEVER_TRACED; rays.len()];
            let mut lengths = vec![0.0; rays.len()];
            local_rays_into(frame, &rays, &query, &mut local, &mut lengths);
            for (i, ray) in rays.iter().enumerate() {
                let (want, want_length) =
                    local_ray(frame, ray, &query).unwrap_or((NEVER_TRACED, f64::NAN));
                prop_assert!(same(&local[i], &want), "ray {i} {ray:?}: {:?} vs {want:?}", local[i]);
                prop_assert_eq!(lengths[i].to_bits(), want_length.to_bits(), "ray {}", i);
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]
        /// The origins' rests four at a time give each ray the one-at-a-time bits (rays far
        /// out, near the scene origin, special, never traced, with mask 0).
        #[test]
        fn origin_rests_four_at_a_time_give_the_scalar_bits(
            rays in prop::collection::vec(ray(), 0..11),
            far in prop::collection::vec([-1e7..1e7f64, -1e7..1e7f64, -1e3..1e3f64], 0..11),
            origin in [-1e6..1e6f64, -1e6..1e6f64, -1e6..1e6f64],
            reach in reach(),
        ) {
            let origin = DVec3::from(origin);
            let frame = Frame { origin, reach };
            let mut rays = rays;
            rays.extend(far.iter().map(|&p| Ray::new(DVec3::from(p), DVec3::NEG_Z)));
            // Some aimed at the frame's origin, so that far ones are moved.
            rays.extend(far.iter().map(|&p| Ray::new(DVec3::from(p), origin - DVec3::from(p))));
            let mut local = vec![NEVER_TRACED; rays.len()];
            let mut lengths = vec![0.0; rays.len()];
            local_rays_into(frame, &rays, &Query::default(), &mut local, &mut lengths);
            let mut want = local.clone();
            for (ray, l) in rays.iter().zip(&mut want) {
                super::super::origin_lo_of(frame, ray, l);
            }
            put_origin_lo_into(frame, &rays, &mut local);
            for i in 0..rays.len() {
                prop_assert!(same(&local[i], &want[i]), "ray {i} {:?}: {:?} vs {:?}", rays[i], local[i], want[i]);
            }
            // In one pass with the conversion: the same rays and lengths, bit for bit.
            let mut fused = vec![NEVER_TRACED; rays.len()];
            let mut fused_lengths = vec![0.0; rays.len()];
            local_rays_with_rests_into(frame, &rays, &Query::default(), &mut fused, &mut fused_lengths);
            for i in 0..rays.len() {
                prop_assert!(same(&fused[i], &want[i]), "ray {i} {:?}: {:?} vs {:?}", rays[i], fused[i], want[i]);
                prop_assert_eq!(fused_lengths[i].to_bits(), lengths[i].to_bits(), "ray {}", i);
            }
        }
    }

    /// The lanes' half floats are `rest_bits`' (`half_bits`' where those are finite and not
    /// zero, 0 elsewhere), over values of every magnitude, subnormal midpoints, zeros,
    /// infinities and NaN.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn half_lanes_match_half_bits() {
        if !(std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("f16c"))
        {
            return;
        }
        use std::arch::x86_64::*;
        let mut values = vec![
            0.0,
            -0.0,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            f64::MIN_POSITIVE,
            5e-324,
            65504.0,
            65519.9,
            65520.0,
            1e300,
            2f64.powi(-14),
            2f64.powi(-14) - 2f64.powi(-25),
            2f64.powi(-14) + 2f64.powi(-25) + 2f64.powi(-39),
            2f64.powi(-24),
            -2f64.powi(-24),
            2f64.powi(-25),
            2f64.powi(-25) + 2f64.powi(-60),
            3.0 * 2f64.powi(-25),
            -5.0 * 2f64.powi(-25),
            1023.5 * 2f64.powi(-24),
        ];
        use rand::Rng;
        let mut g = crate::check::synthetic::rng(12);
        for n in 0..100_000 {
            let x = g.random_range(1.0..2.0) * 2f64.powi(g.random_range(-40..24));
            values.push(if n % 2 == 0 { x } else { -x });
        }
        for four in values.chunks(4) {
            let mut v = [0.0; 4];
            v[..four.len()].copy_from_slice(four);
            let mut got = [0u16; 8];
            // SAFETY: the CPU has AVX2 and F16C (checked above); `got` is eight u16s.
            unsafe {
                let h = avx::half_lanes(_mm256_loadu_pd(v.as_ptr()));
                _mm_storeu_si128(got.as_mut_ptr().cast(), h);
            }
            for (x, got) in v.iter().zip(got) {
                assert_eq!(got, super::super::rest_bits(*x), "{x:e}");
            }
        }
    }

    fn point() -> impl Strategy<Value = DVec3> {
        prop_oneof![
            4 => [-10.0..10.0f64, -10.0..10.0f64, -10.0..10.0f64].prop_map(DVec3::from),
            1 => [component(), component(), component()].prop_map(DVec3::from),
            1 => Just(DVec3::ZERO),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]
        #[test]
        fn hits_refined_four_at_a_time_give_the_scalar_bits(
            triangles in prop::array::uniform4([point(), point(), point()]),
            degenerate in prop::array::uniform4(any::<bool>()),
            rays in prop::array::uniform4(ray()),
            traced in prop::array::uniform4([component(), component(), component()]),
        ) {
            // Some triangles with a repeated vertex (zero area, det = 0 for every ray).
            let triangles: [[DVec3; 3]; 4] =
                std::array::from_fn(|i| {
                    let [a, b, c] = triangles[i];
                    if degenerate[i] { [a, b, a] } else { [a, b, c] }
                });
            let corners = [0, 1, 2, 3].map(|i| {
                let [a, b, c] = &triangles[i];
                [a, b, c]
            });
            let refined =
                refine_four(corners, [&rays[0], &rays[1], &rays[2], &rays[3]], |i| traced[i]);
            for i in 0..4 {
                let want = refine(triangles[i], &rays[i], || traced[i]);
                // Every NaN as one (x86 makes a new NaN negative; which NaN a scalar operation
                // passes on depends on the order the compiler chose for its operands).
                let bits = |r: &Refined| {
                    [r.t, r.u, r.v, r.position.x, r.position.y, r.position.z, r.normal.x,
                     r.normal.y, r.normal.z].map(|x| if x.is_nan() { u64::MAX } else { x.to_bits() })
                };
                prop_assert_eq!(bits(&refined[i]), bits(&want), "hit {}", i);
            }
        }
    }

    #[test]
    fn ordinary_rays_stay_on_the_lanes_and_match() {
        let origin = DVec3::new(512_345.25, 4_100_000.5, 310.0);
        let rays: Vec<Ray> = (0..64)
            .map(|i| {
                let f = i as f64;
                Ray {
                    tmin: 0.0,
                    tmax: if i % 3 == 0 { f64::INFINITY } else { 50.0 + f },
                    ..Ray::new(
                        origin + DVec3::new(f * 1.5, -f, 1000.0),
                        if i % 2 == 0 {
                            DVec3::new(0.01 * f - 0.3, 0.2, -1.0 + 0.001 * f)
                        } else {
                            // Unit-length in f64, so often a hair under 1.
                            DVec3::new(0.01 * f - 0.3, 0.2, -1.0 + 0.001 * f).normalize()
                        },
                    )
                }
            })
            .collect();
        let mut local = vec![NEVER_TRACED; rays.len()];
        let mut lengths = vec![0.0; rays.len()];
        let frame = Frame::at(origin);
        local_rays_into(frame, &rays, &Query::default(), &mut local, &mut lengths);
        for (i, ray) in rays.iter().enumerate() {
            let (want, want_length) = local_ray(frame, ray, &Query::default()).unwrap();
            assert!(same(&local[i], &want), "ray {i}");
            assert_eq!(lengths[i].to_bits(), want_length.to_bits());
        }
        // The lanes took every one of them (none was left to the scalar function).
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx") {
            for (r, l) in rays.chunks(4).zip(local.chunks_mut(4)) {
                let mut lengths = [0.0; 4];
                // SAFETY: the CPU has AVX (checked above).
                unsafe {
                    avx::four(
                        origin,
                        f64::INFINITY,
                        r,
                        Query::default().flags(),
                        l,
                        &mut lengths,
                        &mut avx::Skip,
                    )
                };
                assert!(l.iter().all(|l| l.origin_lo[0] == 0), "{r:?}");
            }
        }
    }
}
