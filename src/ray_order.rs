//! Ray reordering for incoherent batches: a permutation of a batch of kernel rays that puts rays
//! heading the same way from nearby origins next to each other, so that consecutive rays walk
//! the same part of the tree (warm caches on the CPU, agreeing lanes on a GPU). Rays are traced
//! in that order and the results are put back in input order, so answers are identical with and
//! without it.
//!
//! The sort key of a ray is its direction octant (3 bits, most significant) followed by the
//! 27-bit Morton code of its origin, quantised to 512 steps per axis inside the batch's origin
//! bounds. Ties keep input order, so the permutation is deterministic. A batch whose rays all
//! start at one point (a pinhole camera) is left as it is: the key would only split it by
//! octant, and its own order (pixel order) is already coherent.

use crate::layout::{GpuHit, GpuHitEntry, GpuRay};
use glam::Vec3;
use rayon::prelude::*;

/// Batches from this many rays are reordered by default on the twin and a software GPU
/// (lavapipe); smaller ones are traced as given (`usize::MAX` turns reordering off). From here
/// on it won on both scenes and both paths, sort included; below it the gain is within noise
/// (BENCHMARKS.md, "Ray reordering"). The CPU engine (`picker::ENGINE_REORDER_FROM`) and a
/// hardware GPU (`gpu::picker::reorder_from_for`) do not sort: neither gained from it.
pub const DEFAULT_REORDER_FROM: usize = 65_536;

/// Bits per axis of the origin's Morton code.
const MORTON_BITS: u32 = 9;
/// Quantisation steps per axis.
const STEPS: f32 = (1u32 << MORTON_BITS) as f32;

/// A permutation of a batch: `order()[i]` is the input index of the `i`-th ray to trace.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RayOrder {
    order: Vec<u32>,
    /// The inverse: `position[j]` is where input ray `j` is traced.
    position: Vec<u32>,
}

impl RayOrder {
    /// Sorts `rays` by [`sort_key`] within the bounds of their origins. `None` when there is
    /// nothing to gain: all rays start at one point, or there are more than `u32::MAX` of them
    /// (their indices do not fit the packed sort entries).
    pub fn new(rays: &[GpuRay]) -> Option<Self> {
        if rays.len() > u32::MAX as usize {
            return None;
        }
        let (lo, hi) = origin_bounds(rays);
        if lo == hi {
            return None;
        }
        let scale = Vec3::splat(STEPS) / (hi - lo).max(Vec3::splat(f32::MIN_POSITIVE));
        // Key in the high half, input index in the low half: one u64 sort, ties in input order.
        let mut entries: Vec<u64> = rays
            .par_iter()
            .enumerate()
            .with_min_len(4096)
            .map(|(i, ray)| (u64::from(sort_key(ray, lo, scale)) << 32) | i as u64)
            .collect();
        entries.par_sort_unstable();
        let order: Vec<u32> = entries.into_par_iter().map(|e| e as u32).collect();
        let mut position = vec![0u32; order.len()];
        for (traced_at, &input) in order.iter().enumerate() {
            position[input as usize] = traced_at as u32;
        }
        Some(Self { order, position })
    }

    /// The permutation: the input index of each traced position.
    pub fn order(&self) -> &[u32] {
        &self.order
    }

    /// The batch's items in trace order (`items` is in input order).
    pub fn gather<T: Copy + Send + Sync>(&self, items: &[T]) -> Vec<T> {
        self.order
            .par_iter()
            .with_min_len(4096)
            .map(|&i| items[i as usize])
            .collect()
    }

    /// Puts per-ray results traced in this order back in input order.
    pub fn scatter<T: Copy + Send + Sync>(&self, traced: &[T]) -> Vec<T> {
        self.position
            .par_iter()
            .with_min_len(4096)
            .map(|&at| traced[at as usize])
            .collect()
    }

    /// Puts groups of `per_ray` results per ray (all-hits lists), traced in this order, back in
    /// input order.
    pub fn scatter_groups<T: Copy + Send + Sync>(&self, traced: &[T], per_ray: usize) -> Vec<T> {
        self.position
            .par_iter()
            .with_min_len(4096)
            .flat_map_iter(|&at| {
                let start = at as usize * per_ray;
                traced[start..start + per_ray].iter().copied()
            })
            .collect()
    }
}

/// The smallest box holding every finite origin of the batch (a point when there is none).
fn origin_bounds(rays: &[GpuRay]) -> (Vec3, Vec3) {
    let (lo, hi) = rays
        .par_iter()
        .with_min_len(4096)
        .map(|r| Vec3::from(r.origin))
        .filter(|o| o.is_finite())
        .fold(
            || (Vec3::INFINITY, Vec3::NEG_INFINITY),
            |(lo, hi), o| (lo.min(o), hi.max(o)),
        )
        .reduce(
            || (Vec3::INFINITY, Vec3::NEG_INFINITY),
            |(a, b), (c, d)| (a.min(c), b.max(d)),
        );
    if lo.cmple(hi).all() {
        (lo, hi)
    } else {
        (Vec3::ZERO, Vec3::ZERO)
    }
}

/// The 30-bit sort key of `ray`: direction octant, then the Morton code of its origin
/// quantised as `(origin - lo) * scale`, clamped to the grid (NaN counts as 0).
pub fn sort_key(ray: &GpuRay, lo: Vec3, scale: Vec3) -> u32 {
    let [dx, dy, dz] = ray.dir;
    let octant = u32::from(dx < 0.0) | u32::from(dy < 0.0) << 1 | u32::from(dz < 0.0) << 2;
    let cell = ((Vec3::from(ray.origin) - lo) * scale).clamp(Vec3::ZERO, Vec3::splat(STEPS - 1.0));
    let morton = spread_bits(cell.x as u32)
        | spread_bits(cell.y as u32) << 1
        | spread_bits(cell.z as u32) << 2;
    octant << (3 * MORTON_BITS) | morton
}

/// Spreads the low 9 bits of `v` to every third bit (bit k goes to bit 3k).
fn spread_bits(v: u32) -> u32 {
    let mut x = v & 0x1ff;
    x = (x | x << 16) & 0x0300_00ff;
    x = (x | x << 8) & 0x0300_f00f;
    x = (x | x << 4) & 0x030c_30c3;
    x = (x | x << 2) & 0x0924_9249;
    x
}

/// Traces `rays` through `trace` (which returns per-ray records and `max_hits`-entry lists), in
/// [`RayOrder`] when `reorder` holds and the batch allows it, and returns the results in input
/// order either way.
pub fn trace_in_order<E>(
    rays: &[GpuRay],
    max_hits: u32,
    reorder: bool,
    trace: impl FnOnce(&[GpuRay]) -> Result<(Vec<GpuHit>, Vec<GpuHitEntry>), E>,
) -> Result<(Vec<GpuHit>, Vec<GpuHitEntry>), E> {
    let Some(order) = reorder.then(|| RayOrder::new(rays)).flatten() else {
        return trace(rays);
    };
    let (hits, lists) = trace(&order.gather(rays))?;
    Ok((
        order.scatter(&hits),
        order.scatter_groups(&lists, max_hits as usize),
    ))
}

#[cfg(test)]
mod tests {
    use super::spread_bits;

    #[test]
    fn spread_bits_puts_bit_k_at_3k() {
        for k in 0..9 {
            assert_eq!(spread_bits(1 << k), 1 << (3 * k));
        }
        assert_eq!(spread_bits(0x1ff), 0x0924_9249 & ((1 << 27) - 1));
    }
}
