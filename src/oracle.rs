//! The brute-force oracle: every triangle, in f64, on the exact world vertices. Slow on purpose;
//! it shares nothing with the tree, so tests can check both traversal paths against it.

use crate::cpu::ray_triangle::ray_triangle_f64;
use crate::ray::{Hit, Ray};
use crate::scene::Scene;
use glam::DVec3;
use rayon::prelude::*;

/// The scene's hittable triangles in world f64, with their scene indices: what the oracle tests.
pub struct OracleTriangles {
    triangles: Vec<([DVec3; 3], u32)>,
    total: u32,
}

impl OracleTriangles {
    /// Collects every non-degenerate triangle of `scene`.
    pub fn new(scene: &Scene) -> Self {
        let triangles = (0..scene.triangle_count())
            .filter(|&i| !scene.is_degenerate(i))
            .map(|i| (scene.world_triangle(i), i as u32))
            .collect();
        Self {
            triangles,
            total: scene.triangle_count() as u32,
        }
    }
}

/// The nearest hit of `ray` over all non-degenerate triangles of `scene`.
pub fn brute_force(scene: &Scene, ray: &Ray) -> Hit {
    brute_force_with(scene, &OracleTriangles::new(scene), ray)
}

fn brute_force_with(scene: &Scene, all: &OracleTriangles, ray: &Ray) -> Hit {
    if !ray.is_valid() {
        return Hit::INVALID;
    }
    let mut best: Option<(f64, u32, f64, f64)> = None;
    for &(vertices, i) in &all.triangles {
        let h = ray_triangle_f64(vertices, ray.origin, ray.dir);
        if h.hit && h.t > ray.tmin && h.t <= ray.tmax && best.is_none_or(|b| h.t < b.0) {
            best = Some((h.t, i, h.u, h.v));
        }
    }
    let Some((t, i, u, v)) = best else {
        return Hit {
            triangle_tests: all.total,
            ..Hit::MISS
        };
    };
    let [a, b, c] = scene.world_triangle(i as usize);
    let (object, triangle) = scene.locate(i);
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
        triangle_tests: all.total,
    }
}

/// [`brute_force`] over a batch, in parallel.
pub fn brute_force_all(scene: &Scene, rays: &[Ray]) -> Vec<Hit> {
    let all = OracleTriangles::new(scene);
    rays.par_iter()
        .map(|r| brute_force_with(scene, &all, r))
        .collect()
}
