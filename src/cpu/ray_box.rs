//! Ray/box slab test in f32, and the intervals that keep hits within their boxes: the CPU twin
//! of `box_interval`, `meets`, `clip` and `clamp_to` in `wgsl/pick.wgsl`.

use crate::layout::GpuTriangle;
use glam::Vec3;

/// Relative widening of each box's `[t_near, t_far]` so rounding never culls a box the ray touches.
pub const BOX_PAD: f32 = 1e-6;
/// Direction components smaller than this are treated as this (WGSL has no infinities).
pub const MIN_DIR: f32 = 1e-30;
/// Stands in for infinity in slab intervals.
pub const HUGE: f32 = 3.0e38;

/// `1 / dir` with tiny components clamped, keeping the sign (a zero counts as positive).
pub fn safe_inverse(dir: Vec3) -> Vec3 {
    let magnitude = dir.abs().max(Vec3::splat(MIN_DIR));
    let sign = Vec3::select(dir.cmpge(Vec3::ZERO), Vec3::ONE, Vec3::NEG_ONE);
    sign / magnitude
}

/// Whether the ray's interval over a box ([`box_interval`]) meets `[tmin, tmax]`: the box test
/// (conservative: the interval is padded).
#[inline]
pub fn meets((lo, hi): (f32, f32), tmin: f32, tmax: f32) -> bool {
    lo.max(tmin) <= hi.min(tmax)
}

/// The ray's slab interval over the box `[min, max]`, each end widened by [`BOX_PAD`] relative:
/// `(t_near - |t_near| * BOX_PAD, t_far + |t_far| * BOX_PAD)`, before `tmin` and `tmax` cut it
/// ([`meets`]). For a larger box every end moves outward (a lower
/// first and a higher second end: the computed operations are monotonic), which [`hit_t`]
/// relies on.
#[inline]
pub fn box_interval(min: Vec3, max: Vec3, origin: Vec3, dir: Vec3, inv_dir: Vec3) -> (f32, f32) {
    let t0 = (min - origin) * inv_dir;
    let t1 = (max - origin) * inv_dir;
    // A ray parallel to a slab and inside it (faces included) is unconstrained by that slab;
    // without this, an origin exactly on a face would give 0 * inverse = 0 and cull the box.
    let free = dir.abs().cmplt(Vec3::splat(MIN_DIR)) & origin.cmpge(min) & origin.cmple(max);
    let near = Vec3::select(free, Vec3::splat(-HUGE), t0.min(t1));
    let far = Vec3::select(free, Vec3::splat(HUGE), t0.max(t1));
    let t_near = near.x.max(near.y).max(near.z);
    let t_far = far.x.min(far.y).min(far.z);
    (
        t_near - t_near.abs() * BOX_PAD,
        t_far + t_far.abs() * BOX_PAD,
    )
}

/// [`box_interval`] over the triangle's own box (the min and max of its vertices).
#[inline]
pub fn triangle_interval(tri: &GpuTriangle, origin: Vec3, dir: Vec3, inv_dir: Vec3) -> (f32, f32) {
    let (a, b, c) = (Vec3::from(tri.v0), Vec3::from(tri.v1), Vec3::from(tri.v2));
    box_interval(a.min(b).min(c), a.max(b).max(c), origin, dir, inv_dir)
}

/// The interval `a` (a triangle's own, in its mesh's frame) cut by `b` (the world ray's over
/// the instance's leaf box in the top tree), by comparisons alone, as the kernel and the engine
/// cut it. Where the two do not meet (the frames' roundings apart by more than the boxes'
/// padding), `b` alone: the hit is kept, within the top tree's box, not dropped; an empty `a`
/// stays empty.
#[inline]
pub fn clip(a: (f32, f32), b: (f32, f32)) -> (f32, f32) {
    let both = (
        if b.0 > a.0 { b.0 } else { a.0 },
        if b.1 < a.1 { b.1 } else { a.1 },
    );
    if both.0 <= both.1 {
        both
    } else if a.0 <= a.1 {
        b
    } else {
        a
    }
}

/// A triangle hit at `t` as every walk counts it: `None` when the ray's interval over the
/// triangle's own box, `(lo, hi)` ([`triangle_interval`], cut by an instance's leaf box),
/// is empty; else `t` moved into it.
///
/// Why: a walk prunes a box by the nearest hit so far, comparing its padded near end with it.
/// The triangle test's `t` is rounded otherwise, so for a ray starting close to the surface, or
/// a long thin triangle, it can fall before the padded near end of a box that holds its
/// triangle; whether that triangle was then tested depended on what the walk had found first,
/// and so on the tree and the walk (a tie could go to the higher id). A `t` within the
/// triangle's own interval is within every enclosing box's, so no box holding a hit at or
/// before the nearest is ever pruned, and the answer is the least hit under the tie rule
/// whatever the walk.
#[inline]
pub fn hit_t(t: f32, (lo, hi): (f32, f32)) -> Option<f32> {
    // Not `lo > hi`: a NaN end (a box the ray never enters) is no interval either.
    if lo.partial_cmp(&hi).is_none_or(|o| o.is_gt()) {
        return None;
    }
    Some(if t < lo {
        // +0 for a zero end, whose sign the paths' max and min leave to the hardware.
        if lo == 0.0 { 0.0 } else { lo }
    } else if t > hi {
        hi
    } else {
        t
    })
}
