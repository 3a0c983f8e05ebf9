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

/// The kernel input for an invalid ray: `tmax < tmin`, so traversal returns at once.
pub const NEVER_TRACED: GpuRay = GpuRay {
    origin: [0.0; 3],
    tmin: 1.0,
    dir: [1.0, 0.0, 0.0],
    tmax: -1.0,
    mask: 0,
    flags: 0,
    pad: [0; 2],
};

/// A world ray in the scene frame: the kernel input plus the length of the world direction
/// (`t_world = t_local / dir_length`). `None` for an invalid ray ([`Ray::is_valid`]: among
/// others, a direction that cannot be normalized to finite values).
///
/// A ray with layer mask 0 shares no bit with any object, so it is never traced: it comes back
/// as [`NEVER_TRACED`] with its direction length, a plain miss on every backend whatever the
/// objects' masks (the kernels skip the mask test when every object has all bits).
///
/// The local range is capped so that every hit's world `t` stays finite: a hit farther than
/// `f64::MAX` in the ray's own units is no hit.
pub fn local_ray(scene_origin: DVec3, ray: &Ray, query: &Query) -> Option<(GpuRay, f64)> {
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
    let scale = ray.dir.abs().max_element();
    if scale == 0.0 {
        return None;
    }
    let scaled = ray.dir / scale;
    let scaled_length = scaled.length();
    let dir_length = scaled_length * scale;
    if !(dir_length.is_finite() && (dir_length >= 1.0 || (1.0 / dir_length).is_finite())) {
        return None;
    }
    let unit = (scaled / scaled_length).as_vec3();
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
            pad: [0; 2],
        },
        dir_length,
    ))
}

/// Converts a batch of world rays to closest-hit kernel rays; invalid ones become [`NEVER_TRACED`].
pub fn local_rays(scene_origin: DVec3, rays: &[Ray]) -> Vec<GpuRay> {
    local_rays_for(scene_origin, rays, &Query::default())
}

/// Converts a batch of world rays to kernel rays for `query`.
pub fn local_rays_for(scene_origin: DVec3, rays: &[Ray], query: &Query) -> Vec<GpuRay> {
    let mut out = Vec::new();
    rays.par_iter()
        .with_min_len(4096)
        .map(|r| local_ray(scene_origin, r, query).map_or(NEVER_TRACED, |(g, _)| g))
        .collect_into_vec(&mut out);
    out
}

/// Converts a batch of world rays to kernel rays for `query`, with each ray's world direction
/// length (`t_world = t_local / length`; NaN for an invalid ray), computed once for
/// [`resolve_with`].
pub fn scene_rays(scene_origin: DVec3, rays: &[Ray], query: &Query) -> (Vec<GpuRay>, Vec<f64>) {
    let (mut local, mut lengths) = (Vec::new(), Vec::new());
    rays.par_iter()
        .with_min_len(4096)
        .map(|r| local_ray(scene_origin, r, query).unwrap_or((NEVER_TRACED, f64::NAN)))
        .unzip_into_vecs(&mut local, &mut lengths);
    (local, lengths)
}

/// Checks that every traversal result names a triangle of the tree (or none): a result past the
/// end or at the iteration cap means the tree's links are corrupted.
pub fn check_found<T: Sync>(
    bvh: &Bvh,
    found: &[T],
    prim: impl Fn(&T) -> u32 + Sync + Send,
) -> Result<()> {
    let count = bvh.triangle_ids.len();
    let is_bad = |&p: &u32| p != NO_HIT && (p == CAP_REACHED || p as usize >= count);
    // A chunk of the fused pick (a few hundred results) is checked in place; a whole batch in
    // parallel.
    let bad = if found.len() <= 4096 {
        found.iter().map(&prim).find(is_bad)
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
    let Some((_, dir_length)) = local_ray(bvh.origin, ray, &Query::default()) else {
        return Ok(Hit::INVALID);
    };
    check_found(bvh, std::slice::from_ref(found), |f| f.prim)?;
    Ok(resolve_with(scene, bvh, ray, dir_length, found))
}

/// [`resolve`] for a result already checked by [`check_found`], with the ray's direction length
/// from [`scene_rays`] (NaN: an invalid ray).
pub fn resolve_with(scene: &Scene, bvh: &Bvh, ray: &Ray, dir_length: f64, found: &GpuHit) -> Hit {
    if dir_length.is_nan() {
        return Hit::INVALID;
    }
    let stats = Hit {
        box_tests: found.box_tests,
        triangle_tests: found.triangle_tests,
        ..Hit::MISS
    };
    if found.prim == NO_HIT {
        return stats;
    }
    let scene_index = bvh.triangle_ids[found.prim as usize];
    let vertices = scene.world_triangle(scene_index as usize);
    let exact = ray_triangle_f64(vertices, ray.origin, ray.dir);
    let (t, u, v) =
        if exact.t.is_finite() && exact.u.is_finite() && exact.v.is_finite() && exact.t != 0.0 {
            (exact.t, exact.u, exact.v)
        } else {
            (found.t as f64 / dir_length, found.u as f64, found.v as f64)
        };
    let [a, b, c] = vertices;
    let (object, triangle) = scene.locate(scene_index);
    let cell = scene.objects()[object as usize]
        .grid
        .map(|g| g.cell_of(triangle))
        .map(|(r, c)| [r, c]);
    Hit {
        hit: true,
        t,
        object,
        triangle,
        u,
        v,
        position: ray.at(t),
        normal: (b - a).cross(c - a).normalize_or_zero(),
        cell,
        ..stats
    }
}
