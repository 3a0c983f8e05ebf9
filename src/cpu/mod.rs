//! The CPU reference path: the kernel's traversal in Rust over the same flattened buffers,
//! run in parallel over rays with rayon.

pub mod ray_box;
pub mod ray_triangle;
pub mod traverse;

use crate::bvh::Bvh;
use crate::layout::{GpuHit, GpuHitEntry, GpuRay};
use rayon::prelude::*;

/// Settings shared by a batch: the kernel's `GpuParams` minus the dispatch geometry.
#[derive(Clone, Copy, Debug, Default)]
pub struct TraceSettings<'a> {
    /// Layer mask per leaf-order triangle; empty when every object has the all-ones mask.
    pub triangle_masks: &'a [u32],
    /// All-hits list length per ray (0 outside all-hits mode).
    pub max_hits: u32,
    /// Watertight triangle test instead of Möller–Trumbore.
    pub watertight: bool,
    /// The instances of an instanced scene (whose tree then starts with the top tree).
    pub instances: Option<&'a crate::instance::Instances>,
}

/// Closest-hit traversal of each ray with Möller–Trumbore, in parallel; `out[i]` answers `rays[i]`.
pub fn trace_all(bvh: &Bvh, rays: &[GpuRay]) -> Vec<GpuHit> {
    trace_batch(bvh, rays, &TraceSettings::default()).0
}

/// The kernel's buffers for `bvh` and one batch's `settings`.
pub fn buffers<'a>(bvh: &'a Bvh, settings: &TraceSettings<'a>) -> traverse::Buffers<'a> {
    traverse::Buffers {
        nodes: bvh.nodes.as_slice(),
        triangles: bvh.triangles.as_slice(),
        triangle_ids: bvh.triangle_ids.as_slice(),
        triangle_masks: settings.triangle_masks,
        instances: settings.instances.map_or(&[], |i| i.records()),
        top_nodes: settings.instances.map_or(0, |i| i.top_nodes()),
        iteration_cap: settings
            .instances
            .map_or(bvh.iteration_cap(), |i| i.iteration_cap()),
        max_hits: settings.max_hits,
        watertight: settings.watertight,
    }
}

/// Traces each ray as its flags say, in parallel. Returns the per-ray records and the all-hits
/// lists (`max_hits` entries per ray).
pub fn trace_batch(
    bvh: &Bvh,
    rays: &[GpuRay],
    settings: &TraceSettings<'_>,
) -> (Vec<GpuHit>, Vec<GpuHitEntry>) {
    let buffers = buffers(bvh, settings);
    let k = settings.max_hits as usize;
    let mut lists = vec![GpuHitEntry::default(); rays.len() * k];
    let hits = if k == 0 {
        // Runs of 256 rays, each its own stealable job (as the engine's: `picker::pick_fused`).
        rays.par_iter()
            .with_min_len(256)
            .with_max_len(256)
            .map(|ray| traverse::trace(buffers, ray, &mut []))
            .collect()
    } else {
        rays.par_iter()
            .zip(lists.par_chunks_mut(k))
            .with_min_len(256)
            .with_max_len(256)
            .map(|(ray, list)| traverse::trace(buffers, ray, list))
            .collect()
    };
    (hits, lists)
}
