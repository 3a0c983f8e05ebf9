//! From an instanced hit back to the world: hit id → instance and file-order triangle
//! ([`Instances::locate`]) → the triangle's world corners in f64 (the instance's transform
//! applied to the mesh's exact positions) → the same f64 refinement every hit gets
//! ([`crate::frame::refine`]). The twin of `frame::resolve_with` / `frame::resolve_chunk`.

use super::Instances;
use crate::frame::{RESOLVE_BLOCK, Refined, refine, refine_four, split_hits, stats_of, traced};
use crate::layout::{GpuHit, NO_HIT};
use crate::ray::{Hit, Ray};
use glam::DVec3;

/// The public hit for a checked traversal result on an instanced scene (see
/// `frame::resolve_with`; `dir_length` NaN: an invalid ray). Always inlined, as that one is.
#[inline(always)]
pub fn resolve_with(instances: &Instances, ray: &Ray, dir_length: f64, found: &GpuHit) -> Hit {
    if dir_length.is_nan() {
        return Hit::INVALID;
    }
    if found.prim == NO_HIT {
        return stats_of(found);
    }
    let (instance, triangle) = instances.locate(found.prim);
    let (corners, swapped) = instances.world_triangle(instance, triangle);
    let refined = refine(corners, ray, || {
        traced(found, dir_length, instances.frame().shift(ray))
    });
    hit_of(instances, instance, triangle, swapped, refined, found)
}

/// [`resolve_with`] for a chunk of results, refined four at a time, bit for bit the same:
/// `emit(k, hit)` for `found[k]`, which answers `rays[input[k]]`. In blocks of
/// [`RESOLVE_BLOCK`] as `frame::resolve_chunk`: the block's hits listed without a branch per
/// result, their instances located and asked for (records scattered over the instances),
/// the rest answered, then the hits refined.
pub fn resolve_chunk(
    instances: &Instances,
    rays: &[Ray],
    input: &[usize],
    lengths: &[f64],
    found: &[GpuHit],
    mut emit: impl FnMut(usize, Hit),
) {
    for start in (0..found.len()).step_by(RESOLVE_BLOCK) {
        let end = (start + RESOLVE_BLOCK).min(found.len());
        let (hits, others) = split_hits(&found[start..end], &lengths[start..end]);
        let mut located = [(0u32, 0u32); RESOLVE_BLOCK];
        for (slot, &j) in located.iter_mut().zip(hits.iter()) {
            let (i, t) = instances.locate(found[start + usize::from(j)].prim);
            crate::prefetch::item(instances.instances(), i as usize);
            crate::prefetch::item(instances.records(), i as usize);
            *slot = (i, t);
        }
        for &j in others.iter() {
            let k = start + usize::from(j);
            emit(
                k,
                resolve_with(instances, &rays[input[k]], lengths[k], &found[k]),
            );
        }
        let whole = hits.len() / 4 * 4;
        for g in (0..whole).step_by(4) {
            let k = |n: usize| start + usize::from(hits[g + n]);
            // Written out (not `array::map`, whose closures were left as calls here).
            let w0 = instances.world_triangle(located[g].0, located[g].1);
            let w1 = instances.world_triangle(located[g + 1].0, located[g + 1].1);
            let w2 = instances.world_triangle(located[g + 2].0, located[g + 2].1);
            let w3 = instances.world_triangle(located[g + 3].0, located[g + 3].1);
            let ray = |n: usize| &rays[input[k(n)]];
            let traced_at = |n: usize| {
                let shift = instances.frame().shift(&rays[input[k(n)]]);
                traced(&found[k(n)], lengths[k(n)], shift)
            };
            let refined = refine_four(
                [
                    corners(&w0.0),
                    corners(&w1.0),
                    corners(&w2.0),
                    corners(&w3.0),
                ],
                [ray(0), ray(1), ray(2), ray(3)],
                traced_at,
            );
            for (n, (w, refined)) in [w0.1, w1.1, w2.1, w3.1]
                .into_iter()
                .zip(refined)
                .enumerate()
            {
                let (i, t) = located[g + n];
                emit(k(n), hit_of(instances, i, t, w, refined, &found[k(n)]));
            }
        }
        for &j in &hits[whole..] {
            let k = start + usize::from(j);
            emit(
                k,
                resolve_with(instances, &rays[input[k]], lengths[k], &found[k]),
            );
        }
    }
}

/// The three corners of a triangle, where they lie.
#[inline(always)]
fn corners(w: &[DVec3; 3]) -> [&DVec3; 3] {
    [&w[0], &w[1], &w[2]]
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
