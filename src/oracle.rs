//! The brute-force oracle: every triangle, in f64, on the exact world vertices. Slow on purpose;
//! it shares nothing with the tree, so tests can check both traversal paths against it.

use crate::cpu::ray_triangle::ray_triangle_f64;
use crate::ray::{Hit, Ray};
use crate::scene::Scene;
use rayon::prelude::*;

/// The nearest hit of `ray` over all non-degenerate triangles of `scene`.
pub fn brute_force(scene: &Scene, ray: &Ray) -> Hit {
    if !ray.is_valid() {
        return Hit::INVALID;
    }
    let mut best: Option<(f64, usize, f64, f64)> = None;
    for i in 0..scene.triangle_count() {
        if scene.is_degenerate(i) {
            continue;
        }
        let h = ray_triangle_f64(scene.world_triangle(i), ray.origin, ray.dir);
        if h.hit && h.t > ray.tmin && h.t <= ray.tmax && best.is_none_or(|b| h.t < b.0) {
            best = Some((h.t, i, h.u, h.v));
        }
    }
    let Some((t, i, u, v)) = best else {
        return Hit {
            triangle_tests: scene.triangle_count() as u32,
            ..Hit::MISS
        };
    };
    let [a, b, c] = scene.world_triangle(i);
    let (object, triangle) = scene.locate(i as u32);
    Hit {
        hit: true,
        invalid: false,
        t,
        object,
        triangle,
        u,
        v,
        position: ray.at(t),
        normal: (b - a).cross(c - a).normalize_or_zero(),
        box_tests: 0,
        triangle_tests: scene.triangle_count() as u32,
    }
}

/// [`brute_force`] over a batch, in parallel.
pub fn brute_force_all(scene: &Scene, rays: &[Ray]) -> Vec<Hit> {
    rays.par_iter().map(|r| brute_force(scene, r)).collect()
}
