//! From an instanced hit back to the world: hit id → instance and file-order triangle
//! ([`Instances::locate`]) → the triangle's world corners in f64 (the instance's transform
//! applied to the mesh's exact positions) → the same f64 refinement every hit gets
//! ([`crate::frame::refine`]). The twin of `frame::resolve_with` / `frame::resolve_chunk`.

use super::Instances;
use crate::frame::{Refined, refine, refine_four, stats_of, traced};
use crate::layout::{GpuHit, NO_HIT};
use crate::ray::{Hit, Ray};

/// The public hit for a checked traversal result on an instanced scene (see
/// `frame::resolve_with`; `dir_length` NaN: an invalid ray).
pub fn resolve_with(instances: &Instances, ray: &Ray, dir_length: f64, found: &GpuHit) -> Hit {
    if dir_length.is_nan() {
        return Hit::INVALID;
    }
    if found.prim == NO_HIT {
        return stats_of(found);
    }
    let (instance, triangle) = instances.locate(found.prim);
    let (corners, swapped) = instances.world_triangle(instance, triangle);
    let refined = refine(corners, ray, traced(found, dir_length));
    hit_of(instances, instance, triangle, swapped, refined, found)
}

/// [`resolve_with`] for a chunk of results, refined four at a time, bit for bit the same:
/// `emit(k, hit)` for `found[k]`, which answers `rays[input[k]]`.
pub fn resolve_chunk(
    instances: &Instances,
    rays: &[Ray],
    input: &[usize],
    lengths: &[f64],
    found: &[GpuHit],
    mut emit: impl FnMut(usize, Hit),
) {
    let mut pending = [0usize; 4];
    let mut n = 0;
    for k in 0..found.len() {
        if lengths[k].is_nan() || found[k].prim == NO_HIT {
            emit(
                k,
                resolve_with(instances, &rays[input[k]], lengths[k], &found[k]),
            );
            continue;
        }
        pending[n] = k;
        n += 1;
        if n == 4 {
            let located = pending.map(|k| instances.locate(found[k].prim));
            let world = located.map(|(i, t)| instances.world_triangle(i, t));
            let refined = refine_four(
                [0, 1, 2, 3].map(|j| {
                    let [a, b, c] = &world[j].0;
                    [a, b, c]
                }),
                pending.map(|k| &rays[input[k]]),
                pending.map(|k| traced(&found[k], lengths[k])),
            );
            for j in 0..4 {
                let (i, t) = located[j];
                emit(
                    pending[j],
                    hit_of(instances, i, t, world[j].1, refined[j], &found[pending[j]]),
                );
            }
            n = 0;
        }
    }
    for &k in &pending[..n] {
        emit(
            k,
            resolve_with(instances, &rays[input[k]], lengths[k], &found[k]),
        );
    }
}

/// The public hit on `instance`'s file-order `triangle`, refined.
#[inline]
fn hit_of(
    instances: &Instances,
    instance: u32,
    triangle: u32,
    swapped: bool,
    refined: Refined,
    found: &GpuHit,
) -> Hit {
    let mesh = &instances.meshes()[instances.instances()[instance as usize].mesh as usize];
    let grid = mesh.scene.objects()[0].grid;
    let (u, v) = if swapped {
        (refined.v, refined.u)
    } else {
        (refined.u, refined.v)
    };
    Hit {
        hit: true,
        t: refined.t,
        object: instance,
        triangle,
        u,
        v,
        position: refined.position,
        normal: refined.normal,
        cell: grid.map(|g| g.cell_of(triangle)).map(|(r, c)| [r, c]),
        ..stats_of(found)
    }
}
