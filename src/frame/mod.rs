//! Moving between the f64 world and the f32 scene frame: rays go down to f32 offsets from the
//! scene origin (with a unit direction), hits come back up and are refined in f64 against the
//! chosen triangle's exact world vertices.

use crate::bvh::Bvh;
use crate::error::{Error, Result};
use crate::exact::ray_triangle_f64;
use crate::layout::{CAP_REACHED, GpuHit, GpuRay, NO_HIT};
use crate::query::Query;
use crate::ray::{Hit, Ray};
use crate::scene::Scene;
use glam::DVec3;
use rayon::prelude::*;

pub mod faults;
mod four;
pub mod reach;
pub(crate) use four::refine_four;
pub use four::{local_rays_into, local_rays_with_rests_into};

/// The kernel input for an invalid ray: `tmax < tmin`, so traversal returns at once.
pub const NEVER_TRACED: GpuRay = GpuRay {
    origin: [0.0; 3],
    tmin: 1.0,
    dir: [1.0, 0.0, 0.0],
    tmax: -1.0,
    mask: 0,
    flags: 0,
    origin_lo: [0; 2],
};

/// How far out, in the scene's reaches ([`Frame::reach`]), a ray's origin may lie before the
/// conversion moves it along the ray towards the scene ([`Frame::shift`]). Rounding an origin
/// to an f32 offset moves it by up to 2^-24 of its distance: from 16 reaches that is under a
/// millionth of the scene's size, and nearer origins (a camera's, a click's) keep the bits
/// they always had.
pub const FAR_REACHES: f64 = 16.0;

/// The scene frame that world rays are converted into: the f64 point their f32 offsets are
/// taken from, and how far from it the scene's hittable triangles reach.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    /// The scene origin ([`Bvh::origin`]).
    pub origin: DVec3,
    /// No hittable point lies farther than this from `origin`; infinite when unknown (no
    /// origin is then moved).
    pub reach: f64,
}

impl Frame {
    /// A frame about `origin` whose reach is unknown: no ray's origin is moved. For rays
    /// traced without the pipeline's refinement (ordering, the trace alone in benchmarks).
    pub fn at(origin: DVec3) -> Frame {
        Frame {
            origin,
            reach: f64::INFINITY,
        }
    }

    /// The frame about `origin` of a scene whose hittable triangles lie within `bounds`
    /// (`None`: nothing to hit; no ray is moved). The reach is the distance to the farthest
    /// corner of the bounds.
    pub fn around(origin: DVec3, bounds: Option<(DVec3, DVec3)>) -> Frame {
        let reach = bounds.map_or(f64::INFINITY, |(lo, hi)| {
            let corner = (lo - origin).abs().max((hi - origin).abs());
            // Rounded up by a part in 2^40, past the length's own rounding.
            let reach = corner.length() * (1.0 + f64::EPSILON * 4096.0);
            if reach.is_finite() {
                reach
            } else {
                f64::INFINITY
            }
        });
        Frame { origin, reach }
    }

    /// How far along `ray`, in its own units, the conversion moves its origin before rounding
    /// it to f32: 0 unless the origin lies more than [`FAR_REACHES`] reaches out and the ray
    /// heads towards the scene; then to two reaches before the point of the ray nearest the
    /// frame's origin. Every hittable point lies within one reach of that point, so none lies
    /// on the stretch skipped, and the rounded origin keeps the precision of one near the
    /// scene: from 10^9 units out, a 96-unit scene's f32 offsets were 64 units apart, and the
    /// traversal chose the far wall of a building over the near one. The refinement measures t
    /// from the ray's own origin, in f64, as always.
    #[inline]
    pub fn shift(&self, ray: &Ray) -> f64 {
        let offset = ray.origin - self.origin;
        let limit = self.reach * FAR_REACHES;
        // False for NaN, and for an infinite reach.
        let far = offset.length_squared() > limit * limit;
        if !far {
            return 0.0;
        }
        let scale = crate::ray::direction_scale(ray.dir);
        if !(scale > 0.0 && scale.is_finite()) {
            return 0.0;
        }
        let dir = ray.dir / scale;
        let length_squared = dir.length_squared();
        // In the scaled direction's units: the nearest point's parameter, less two reaches.
        let along = -offset.dot(dir) / length_squared - 2.0 * self.reach / length_squared.sqrt();
        let world = along / scale;
        if along > 0.0 && world.is_finite() && world < f64::MAX / 4.0 {
            world
        } else {
            0.0
        }
    }
}

/// `ray` with its origin moved `shift` along it (its own units), the range with it: the
/// stretch skipped holds no hittable point ([`Frame::shift`]).
fn moved(ray: &Ray, shift: f64) -> Ray {
    // `shift * dir` as the scaled parameter times the scaled direction: neither overflows.
    let scale = crate::ray::direction_scale(ray.dir);
    Ray {
        origin: ray.origin + (ray.dir / scale) * (shift * scale),
        tmin: ray.tmin - shift,
        tmax: ray.tmax - shift,
        ..*ray
    }
}

/// A world ray in the scene frame: the kernel input plus the length of the world direction
/// (`t_world = t_local / dir_length`, plus the frame's [`Frame::shift`] of the ray). `None`
/// for an invalid ray ([`Ray::is_valid`]: among others, a direction that cannot be normalized
/// to finite values).
///
/// A ray with layer mask 0 shares no bit with any object, so it is never traced: it comes back
/// as [`NEVER_TRACED`] with its direction length, a plain miss on every backend whatever the
/// objects' masks (the kernels skip the mask test when every object has all bits).
///
/// The local range is capped so that every hit's world `t` stays finite: a hit farther than
/// `f64::MAX` in the ray's own units is no hit.
pub fn local_ray(frame: Frame, ray: &Ray, query: &Query) -> Option<(GpuRay, f64)> {
    let shift = frame.shift(ray);
    if shift == 0.0 {
        local_ray_at(frame.origin, ray, query)
    } else {
        local_ray_at(frame.origin, &moved(ray, shift), query)
    }
}

/// [`local_ray`] for a ray whose origin stays where it is.
fn local_ray_at(scene_origin: DVec3, ray: &Ray, query: &Query) -> Option<(GpuRay, f64)> {
    // `Ray::is_valid`, with `direction_length` taken apart so that the scaled direction and its
    // length are computed once (the same operations in the same order, so the same bits):
    // scaled first so that huge or tiny directions neither overflow nor underflow.
    if !(ray.origin.is_finite()
        && ray.dir.is_finite()
        && !ray.tmin.is_nan()
        && !ray.tmax.is_nan()
        && ray.tmin <= ray.tmax)
    {
        return None;
    }
    let scale = crate::ray::direction_scale(ray.dir);
    if scale == 0.0 {
        return None;
    }
    let scaled = ray.dir / scale;
    let scaled_length = scaled.length();
    let dir_length = scaled_length * scale;
    if !(dir_length.is_finite() && (dir_length >= 1.0 || (1.0 / dir_length).is_finite())) {
        return None;
    }
    // One division for the three components (the lanes do the same: `four::local_rays_into`).
    let unit = (scaled * (1.0 / scaled_length)).as_vec3();
    let origin = (ray.origin - scene_origin).as_vec3();
    let to_f32 = |t: f64| (t * dir_length).clamp(f32::MIN as f64, f32::MAX as f64) as f32;
    let finite = |t: f64| t.clamp(-f64::MAX, f64::MAX);
    let mut tmax = to_f32(finite(ray.tmax));
    // Rounding to f32 may carry the cap just past the largest finite world t (only when the
    // direction is shorter than 1: a finite f32 divided by 1 or more stays finite).
    while dir_length < 1.0 && tmax > 0.0 && !(f64::from(tmax) / dir_length).is_finite() {
        tmax = tmax.next_down();
    }
    // `tmin <= tmax` in the world (checked above); the caps keep it so.
    let tmin = to_f32(finite(ray.tmin)).min(tmax);
    if !origin.is_finite() || unit == glam::Vec3::ZERO {
        return None;
    }
    if ray.mask == 0 {
        return Some((NEVER_TRACED, dir_length));
    }
    Some((
        GpuRay {
            origin: origin.into(),
            tmin,
            dir: unit.into(),
            tmax,
            mask: ray.mask,
            flags: query.flags(),
            origin_lo: [0; 2],
        },
        dir_length,
    ))
}

/// Converts a batch of world rays to closest-hit kernel rays; invalid ones become [`NEVER_TRACED`].
pub fn local_rays(frame: Frame, rays: &[Ray]) -> Vec<GpuRay> {
    local_rays_for(frame, rays, &Query::default())
}

/// Converts a batch of world rays to kernel rays for `query`.
pub fn local_rays_for(frame: Frame, rays: &[Ray], query: &Query) -> Vec<GpuRay> {
    let mut out = Vec::new();
    rays.par_iter()
        .with_min_len(4096)
        .map(|r| local_ray(frame, r, query).map_or(NEVER_TRACED, |(g, _)| g))
        .collect_into_vec(&mut out);
    out
}

/// Converts a batch of world rays to kernel rays for `query`, with each ray's world direction
/// length (`t_world = t_local / length`; NaN for an invalid ray), computed once for
/// [`resolve_with`].
pub fn scene_rays(frame: Frame, rays: &[Ray], query: &Query) -> (Vec<GpuRay>, Vec<f64>) {
    // Both vectors are first touched by many threads: `vec![NEVER_TRACED; n]` would write (and
    // fault in) all of a large batch's rays on this thread alone, which on a 16-core host took
    // longer than the GPU's trace of them. `vec![0.0; n]` is zeroed memory, touched below.
    let mut local = Vec::new();
    rays.par_iter()
        .with_min_len(4096)
        .map(|_| NEVER_TRACED)
        .collect_into_vec(&mut local);
    let mut lengths = vec![0.0; rays.len()];
    rays.par_chunks(4096)
        .zip(local.par_chunks_mut(4096))
        .zip(lengths.par_chunks_mut(4096))
        .for_each(|((rays, local), lengths)| local_rays_into(frame, rays, query, local, lengths));
    (local, lengths)
}

/// Fills each traced ray's [`GpuRay::origin_lo`] (an instanced scene's kernels read it): what
/// rounding `rays[i]`'s origin to the f32 offset `local[i].origin` left off, in f64, as three
/// half floats, each rounded once from f64 (to nearest, ties to even), the same bits on every
/// CPU. A rest too small for a normal half float is 0, so every decoder reads the same bits; a
/// ray never traced keeps zeros.
pub fn put_origin_lo(frame: Frame, rays: &[Ray], local: &mut [GpuRay]) {
    if rays.len() <= 4096 {
        four::put_origin_lo_into(frame, rays, local);
    } else {
        rays.par_chunks(4096)
            .zip(local.par_chunks_mut(4096))
            .for_each(|(rays, local)| four::put_origin_lo_into(frame, rays, local));
    }
}

/// Whether scene-frame ray `l` is traced (not [`NEVER_TRACED`], nor of layer mask 0): only
/// those get an origin rest ([`put_origin_lo`]).
#[inline(always)]
fn gets_origin_rest(l: &GpuRay) -> bool {
    // `tmin <= tmax` also rejects NaN.
    l.tmin <= l.tmax && l.mask != 0
}

/// [`put_origin_lo`] for one ray (the rest of its origin as [`local_ray`] moved it).
#[inline]
fn origin_lo_of(frame: Frame, ray: &Ray, l: &mut GpuRay) {
    if !gets_origin_rest(l) {
        return;
    }
    let shift = frame.shift(ray);
    let origin = if shift == 0.0 {
        ray.origin
    } else {
        moved(ray, shift).origin
    };
    let half = |x: f64| -> u32 { u32::from(rest_bits(x)) };
    let rest = (origin - frame.origin) - glam::Vec3::from(l.origin).as_dvec3();
    l.origin_lo = [half(rest.x) | half(rest.y) << 16, half(rest.z)];
}

/// An origin rest's half float ([`half_bits`]): normal or subnormal, and 0 where that is zero
/// (of either sign) or past the largest half float. Subnormals are kept: at 2^-24 apart they
/// place a rest below 2^-14 a thousand times more finely than 0 did (an instanced scene's
/// grazing rays 10⁴ units from its centre picked a triangle beside the one they meet).
#[inline]
fn rest_bits(x: f64) -> u16 {
    let h = half::f16::from_bits(half_bits(x));
    if h.is_finite() && h.to_bits() & 0x7fff != 0 {
        h.to_bits()
    } else {
        0
    }
}

/// `x` rounded once to the nearest half float (ties to even), as its bits. Not `half`'s
/// `f16::from_f64`: where the CPU has F16C it rounds to f32 first and then to half, and
/// elsewhere it drops the last 32 bits of `x` before rounding, so a value just past the midpoint
/// of two half floats can go either way, depending on the CPU.
fn half_bits(x: f64) -> u16 {
    // The spacing of half floats at x (2^-24 below the normal range): the rounding is then
    // exact in f64 (products by powers of two and an exact rounding to an integer), and the
    // result a half float, or past the largest: `from_f64` then holds it exactly (or makes it
    // infinite) on every CPU, whichever way it converts.
    if x.is_nan() {
        return half::f16::NAN.to_bits();
    }
    let exponent = ((x.to_bits() >> 52) & 0x7ff) as i64 - 1023;
    let power = |e: i64| f64::from_bits(((e + 1023) as u64) << 52);
    let e = exponent.clamp(-14, 15) - 10;
    // |x| in units of the spacing is below 2^11 (or x is past the half floats): adding and
    // taking away 2^52 rounds it to an integer, ties to even, exactly (`round_ties_even`
    // without SSE4.1 is a call).
    let units = (x * power(-e)).abs();
    const TWO_52: f64 = 4_503_599_627_370_496.0;
    let rounded = f64::copysign((units + TWO_52) - TWO_52, x) * power(e);
    half::f16::from_f64(rounded).to_bits()
}

/// Checks that every traversal result names a triangle of the tree (or none): a result past the
/// end or at the iteration cap means the tree's links are corrupted.
pub fn check_found<T: Sync>(
    bvh: &Bvh,
    found: &[T],
    prim: impl Fn(&T) -> u32 + Sync + Send,
) -> Result<()> {
    check_found_in(bvh.triangle_ids.len(), found, prim)
}

/// [`check_found`] against `count` hit ids (an instanced scene's run past its triangles).
pub fn check_found_in<T: Sync>(
    count: usize,
    found: &[T],
    prim: impl Fn(&T) -> u32 + Sync + Send,
) -> Result<()> {
    // Without short-circuits: hits and misses alternate at random on incoherent rays, and a
    // branch per result mispredicted half the time.
    let is_bad = |&p: &u32| (p != NO_HIT) & ((p == CAP_REACHED) | (p as usize >= count));
    // A chunk of the fused pick (a few hundred results) is checked in place, first folded
    // without a branch per result, then searched only when one is bad; a whole batch in
    // parallel.
    let bad = if found.len() <= 4096 {
        let any_bad = found
            .iter()
            .map(&prim)
            .fold(false, |bad, p| bad | is_bad(&p));
        any_bad
            .then(|| found.iter().map(&prim).find(is_bad))
            .flatten()
    } else {
        found
            .par_iter()
            .with_min_len(4096)
            .map(prim)
            .find_any(is_bad)
    };
    match bad {
        None => Ok(()),
        Some(CAP_REACHED) => Err(Error::Invalid(
            "traversal reached its iteration cap: the tree's links are corrupted".into(),
        )),
        Some(p) => Err(Error::Invalid(format!(
            "traversal returned triangle {p} past the end"
        ))),
    }
}

/// Turns a traversal result into the public hit: maps the leaf-order triangle back to its
/// object and file-order id, and recomputes t, u, v, position and normal in f64.
pub fn resolve(scene: &Scene, bvh: &Bvh, ray: &Ray, found: &GpuHit) -> Result<Hit> {
    let frame = Frame::around(bvh.origin, scene.bounds());
    let Some((_, dir_length)) = local_ray(frame, ray, &Query::default()) else {
        return Ok(Hit::INVALID);
    };
    check_found(bvh, std::slice::from_ref(found), |f| f.prim)?;
    Ok(resolve_with(scene, bvh, ray, dir_length, found))
}

/// [`resolve`] for a result already checked by [`check_found`], with the ray's direction length
/// from [`scene_rays`] (NaN: an invalid ray). Always inlined: left as a call (which other code
/// in this module tipped the compiler into), a camera pick of 1M rays on the bunny was 5–7%
/// slower, each miss's 104-byte answer returned through the stack (BENCHMARKS.md).
#[inline(always)]
pub fn resolve_with(scene: &Scene, bvh: &Bvh, ray: &Ray, dir_length: f64, found: &GpuHit) -> Hit {
    if dir_length.is_nan() {
        return Hit::INVALID;
    }
    if found.prim == NO_HIT {
        return stats_of(found);
    }
    let scene_index = bvh.triangle_ids[found.prim as usize];
    let vertices = scene.world_triangle(scene_index as usize);
    let refined = refine(vertices, ray, || {
        let frame = Frame::around(bvh.origin, scene.bounds());
        traced(found, dir_length, frame.shift(ray))
    });
    hit_of(scene, scene_index, refined, found)
}

/// [`resolve_with`] for a chunk of results: `emit(k, hit)` for each `k`, with the hit
/// `resolve_with(scene, bvh, &rays[input[k]], lengths[k], &found[k])`, bit for bit; in blocks
/// of [`RESOLVE_BLOCK`], the misses first, then the hits, refined four at a time
/// (`four::refine_four`). `found` was checked ([`check_found`]).
pub fn resolve_chunk(
    scene: &Scene,
    bvh: &Bvh,
    rays: &[Ray],
    input: &[usize],
    lengths: &[f64],
    found: &[GpuHit],
    mut emit: impl FnMut(usize, Hit),
) {
    let positions = scene.positions();
    for start in (0..found.len()).step_by(RESOLVE_BLOCK) {
        let end = (start + RESOLVE_BLOCK).min(found.len());
        // The block's hits and the rest, listed without a branch per result (on incoherent
        // rays hit and miss alternate at random, and a branch on it mispredicted half the time).
        let (hits, others) = split_hits(&found[start..end], &lengths[start..end]);
        for &j in others.iter() {
            let k = start + usize::from(j);
            emit(
                k,
                resolve_with(scene, bvh, &rays[input[k]], lengths[k], &found[k]),
            );
        }
        let mut groups = hits.chunks_exact(4);
        for group in groups.by_ref() {
            let pending: [usize; 4] = std::array::from_fn(|i| start + usize::from(group[i]));
            let index = pending.map(|k| bvh.triangle_ids[found[k].prim as usize]);
            // Written out (not `array::map`, which was left as a call here, and the loads of
            // what it returned through the stack stalled).
            let corners = |j: usize| {
                let [a, b, c] = scene.triangle_vertices(index[j] as usize);
                [
                    &positions[a as usize],
                    &positions[b as usize],
                    &positions[c as usize],
                ]
            };
            let ray = |j: usize| &rays[input[pending[j]]];
            let traced_at = |j: usize| {
                let frame = Frame::around(bvh.origin, scene.bounds());
                traced(&found[pending[j]], lengths[pending[j]], frame.shift(ray(j)))
            };
            let refined = four::refine_four(
                [corners(0), corners(1), corners(2), corners(3)],
                [ray(0), ray(1), ray(2), ray(3)],
                traced_at,
            );
            for ((k, i), refined) in pending.into_iter().zip(index).zip(refined) {
                emit(k, hit_of(scene, i, refined, &found[k]));
            }
        }
        for &j in groups.remainder() {
            let k = start + usize::from(j);
            emit(
                k,
                resolve_with(scene, bvh, &rays[input[k]], lengths[k], &found[k]),
            );
        }
    }
}

/// Results per block of [`resolve_chunk`] (its lists of hits and misses are on the stack).
pub(crate) const RESOLVE_BLOCK: usize = 256;

/// The indices of `found`'s hits (a valid ray, a triangle found) and of the rest, in order,
/// listed without branches; at most [`RESOLVE_BLOCK`] results.
#[inline]
pub(crate) fn split_hits(found: &[GpuHit], lengths: &[f64]) -> (HitList, HitList) {
    debug_assert!(found.len() <= RESOLVE_BLOCK && lengths.len() == found.len());
    let (mut hits, mut others) = (HitList::default(), HitList::default());
    for (j, (f, length)) in found.iter().zip(lengths).take(RESOLVE_BLOCK).enumerate() {
        let hit = !length.is_nan() && f.prim != NO_HIT;
        hits.push_if(j as u16, hit);
        others.push_if(j as u16, !hit);
    }
    (hits, others)
}

/// Up to [`RESOLVE_BLOCK`] indices of a block's results, filled without branches.
pub(crate) struct HitList {
    items: [u16; RESOLVE_BLOCK],
    len: usize,
}

impl Default for HitList {
    fn default() -> Self {
        Self {
            items: [0; RESOLVE_BLOCK],
            len: 0,
        }
    }
}

impl HitList {
    /// Writes `j` in the next place and keeps it when `keep`.
    #[inline(always)]
    fn push_if(&mut self, j: u16, keep: bool) {
        self.items[self.len.min(RESOLVE_BLOCK - 1)] = j;
        self.len += usize::from(keep);
    }
}

impl std::ops::Deref for HitList {
    type Target = [u16];
    fn deref(&self) -> &[u16] {
        &self.items[..self.len]
    }
}

/// A miss carrying the traversal's b and i.
pub(crate) fn stats_of(found: &GpuHit) -> Hit {
    Hit {
        box_tests: found.box_tests,
        triangle_tests: found.triangle_tests,
        ..Hit::MISS
    }
}

/// The traversal's own t (in the world ray's units, from its own origin: `shift` is the
/// conversion's [`Frame::shift`] of the ray), u and v: what the refinement falls back on.
pub(crate) fn traced(found: &GpuHit, dir_length: f64, shift: f64) -> [f64; 3] {
    [
        found.t as f64 / dir_length + shift,
        found.u as f64,
        found.v as f64,
    ]
}

/// What the f64 refinement makes of a hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Refined {
    /// Ray parameter, in the world ray's units.
    pub t: f64,
    /// Barycentric weight of the second vertex.
    pub u: f64,
    /// Barycentric weight of the third vertex.
    pub v: f64,
    /// World position (`origin + dir * t`).
    pub position: DVec3,
    /// Unit geometric normal (zero for a triangle too small to normalize it).
    pub normal: DVec3,
}

/// The f64 refinement of a hit on the world triangle `[a, b, c]`: the exact test's t, u and v
/// where they are finite and plausible ([`plausible`]), else `traced()` (the traversal's, asked
/// for only then).
#[inline]
pub fn refine([a, b, c]: [DVec3; 3], ray: &Ray, traced: impl FnOnce() -> [f64; 3]) -> Refined {
    let exact = ray_triangle_f64([a, b, c], ray.origin, ray.dir);
    let [t, u, v] = if plausible(exact.t, exact.u, exact.v) {
        [exact.t, exact.u, exact.v]
    } else {
        traced()
    };
    Refined {
        t,
        u,
        v,
        position: ray.at(t),
        normal: (b - a).cross(c - a).normalize_or_zero(),
    }
}

/// Whether the exact test's t, u and v can stand for a hit the traversal found: finite, t not
/// 0, and u and v within a triangle's width of the triangle (u, v ≥ −1, u + v ≤ 2). A ray
/// within 10⁻⁵ rad of a triangle's plane, which the f32 test met near a vertex, had its plane
/// crossing refined 130 units away, behind the ray's origin (t = −8.1, u = −125); the
/// traversal's own values (inside the triangle, within the ray's range) stand there instead.
/// A t a little outside the ray's range with u and v in the triangle stays (faces closer than
/// f32 resolves; the sight lines judge an observer on a surface by it).
/// [`four::refine_four`] applies the same test in lanes.
#[inline]
pub fn plausible(t: f64, u: f64, v: f64) -> bool {
    t.is_finite()
        && u.is_finite()
        && v.is_finite()
        && t != 0.0
        && u >= -1.0
        && v >= -1.0
        && u + v <= 2.0
}

/// The public hit on scene triangle `scene_index`, refined.
#[inline]
fn hit_of(scene: &Scene, scene_index: u32, refined: Refined, found: &GpuHit) -> Hit {
    let (object, triangle) = scene.locate(scene_index);
    let o = &scene.objects()[object as usize];
    let cell = o.grid.map(|g| g.cell_of(triangle)).map(|(r, c)| [r, c]);
    // A mirrored object's triangles are stored with vertices 2 and 3 swapped.
    let (u, v) = if o.mirrored {
        (refined.v, refined.u)
    } else {
        (refined.u, refined.v)
    };
    Hit {
        hit: true,
        t: refined.t,
        object,
        triangle,
        u,
        v,
        position: refined.position,
        normal: refined.normal,
        cell,
        ..stats_of(found)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An origin's rest is rounded to a half float once, from f64: a rest just past the
    /// midpoint between two half floats, which rounds to that midpoint in f32 (and from there
    /// to the even neighbour below), goes up to the neighbour above.
    #[test]
    fn origin_rest_is_rounded_once() {
        // Half floats from 2^-14 are 2^-24 apart: the midpoint is 2^-14 + 2^-25, and 2^-39 past
        // it is below f32's resolution there (2^-37). At 2048 the f32 origin keeps none of it.
        let rest = 2f64.powi(-14) + 2f64.powi(-25) + 2f64.powi(-39);
        let origin = DVec3::new(2048.0 + rest, 1.0, 1.0);
        assert_eq!(origin.x - 2048.0, rest, "the rest is exact in f64");
        let ray = Ray::new(origin, DVec3::X);
        let (mut local, _) = scene_rays(Frame::at(DVec3::ZERO), &[ray], &Query::default());
        assert_eq!(local[0].origin[0], 2048.0);
        put_origin_lo(Frame::at(DVec3::ZERO), &[ray], &mut local);
        let (below, above) = (0x0400, 0x0401);
        assert_eq!(half::f16::from_bits(below).to_f64(), 2f64.powi(-14));
        assert_eq!(
            half::f16::from_bits(above).to_f64(),
            2f64.powi(-14) + 2f64.powi(-24)
        );
        assert_eq!(local[0].origin_lo[0] & 0xffff, u32::from(above));
        assert_eq!(local[0].origin_lo[0] >> 16, 0, "y's rest is 0");
    }

    /// `half_bits` gives the nearest half float (ties to even) for values all over the range,
    /// checked against both neighbours in exact f64 arithmetic.
    #[test]
    fn half_bits_rounds_to_the_nearest_half() {
        use rand::Rng;
        let mut g = crate::check::synthetic::rng(11);
        for n in 0..200_000 {
            // Exponents from 2^-30 to 2^17, any mantissa, either sign; every 7th just past or
            // on a midpoint.
            let exponent = g.random_range(-30..18);
            let mut x = g.random_range(1.0..2.0) * 2f64.powi(exponent);
            if n % 7 == 0 {
                let spacing = 2f64.powi(exponent.clamp(-14, 15) - 10);
                x = ((x / spacing).floor() + 0.5) * spacing
                    + [0.0, spacing * 2f64.powi(-30)][n % 2];
            }
            if g.random::<bool>() {
                x = -x;
            }
            let h = half::f16::from_bits(half_bits(x));
            let value = h.to_f64();
            if value.is_infinite() {
                assert!(x.abs() >= 65520.0, "{x:e}");
                continue;
            }
            for step in [-1i32, 1] {
                let next = half::f16::from_bits(h.to_bits().wrapping_add_signed(step as i16));
                let other = next.to_f64();
                if !other.is_finite() || other.signum() != value.signum() && value != 0.0 {
                    continue;
                }
                let (mine, theirs) = ((x - value).abs(), (x - other).abs());
                assert!(
                    mine < theirs || mine == theirs && h.to_bits() & 1 == 0,
                    "{x:e} -> {value:e}, but {other:e} is nearer or an even tie"
                );
            }
        }
    }

    /// `split_hits` lists a block's hits (a valid ray and a triangle) and the rest, each in
    /// order, every result once, whatever the pattern.
    #[test]
    fn split_hits_lists_hits_and_the_rest_in_order() {
        let mut seed = 12345u32;
        for len in [0, 1, 3, 4, 255, RESOLVE_BLOCK] {
            let mut found = vec![GpuHit::default(); len];
            let mut lengths = vec![1.0; len];
            for (f, l) in found.iter_mut().zip(&mut lengths) {
                seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                f.prim = if seed >> 31 == 1 { NO_HIT } else { seed >> 20 };
                if seed >> 28 & 7 == 0 {
                    *l = f64::NAN;
                }
            }
            let (hits, others) = split_hits(&found, &lengths);
            let want: Vec<u16> = (0..len as u16)
                .filter(|&j| {
                    let j = usize::from(j);
                    !lengths[j].is_nan() && found[j].prim != NO_HIT
                })
                .collect();
            let rest: Vec<u16> = (0..len as u16).filter(|j| !want.contains(j)).collect();
            assert_eq!(&hits[..], &want[..], "{len} results");
            assert_eq!(&others[..], &rest[..], "{len} results");
        }
    }
}
