//! The CPU reference path: the kernel's traversal in Rust over the same flattened buffers,
//! run in parallel over rays with rayon.

pub mod ray_box;
pub mod ray_triangle;
pub mod traverse;

use crate::bvh::Bvh;
use crate::layout::{GpuHit, GpuRay};
use rayon::prelude::*;

/// Traces each ray through `bvh` on the CPU, in parallel; `out[i]` answers `rays[i]`.
pub fn trace_all(bvh: &Bvh, rays: &[GpuRay]) -> Vec<GpuHit> {
    let buffers = traverse::Buffers {
        nodes: &bvh.nodes,
        triangles: &bvh.triangles,
        iteration_cap: bvh.iteration_cap(),
    };
    rays.par_iter()
        .with_min_len(256)
        .map(|ray| traverse::trace(buffers, ray))
        .collect()
}
