//! Ray/box slab test in f32: the CPU twin of `ray_box` in `wgsl/pick.wgsl`.

use crate::layout::GpuNode;
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

/// Whether the ray meets the node's box within `[tmin, tmax]` (conservatively).
pub fn ray_box(
    node: &GpuNode,
    origin: Vec3,
    dir: Vec3,
    inv_dir: Vec3,
    tmin: f32,
    tmax: f32,
) -> bool {
    let (min, max) = (Vec3::from(node.min), Vec3::from(node.max));
    let t0 = (min - origin) * inv_dir;
    let t1 = (max - origin) * inv_dir;
    // A ray parallel to a slab and inside it (faces included) is unconstrained by that slab;
    // without this, an origin exactly on a face would give 0 * inverse = 0 and cull the box.
    let free = dir.abs().cmplt(Vec3::splat(MIN_DIR)) & origin.cmpge(min) & origin.cmple(max);
    let near = Vec3::select(free, Vec3::splat(-HUGE), t0.min(t1));
    let far = Vec3::select(free, Vec3::splat(HUGE), t0.max(t1));
    let t_near = near.x.max(near.y).max(near.z);
    let t_far = far.x.min(far.y).min(far.z);
    (t_near - t_near.abs() * BOX_PAD).max(tmin) <= (t_far + t_far.abs() * BOX_PAD).min(tmax)
}
