//! The brute-force oracle: every triangle, in f64, on the exact world vertices. Slow on purpose;
//! it shares nothing with the tree, so tests can check both traversal paths against it.

use crate::exact::ray_triangle_f64;
use crate::query::{Answers, Cull, Mode, Query};
use crate::ray::{Hit, Ray};
use crate::scene::Scene;
use glam::DVec3;
use rayon::prelude::*;

/// The scene's hittable triangles in world f64, with their scene indices and layer masks.
pub struct OracleTriangles {
    triangles: Vec<([DVec3; 3], u32, u32)>,
    total: u32,
}

impl OracleTriangles {
    /// Collects every non-degenerate triangle of `scene`.
    pub fn new(scene: &Scene) -> Self {
        let triangles = (0..scene.triangle_count())
            .filter(|&i| !scene.is_degenerate(i))
            .map(|i| {
                (
                    scene.world_triangle(i),
                    i as u32,
                    scene.triangle_mask(i as u32),
                )
            })
            .collect();
        Self {
            triangles,
            total: scene.triangle_count() as u32,
        }
    }
}

/// Every hit of `ray` with a finite t in (tmin, tmax], sharing a mask bit and not culled,
/// sorted by t. A ray with mask 0 shares no bit with anything: no hits.
pub fn all_hits(scene: &Scene, all: &OracleTriangles, ray: &Ray, cull: Cull) -> Vec<Hit> {
    let mut hits: Vec<Hit> = all
        .triangles
        .iter()
        .filter(|(_, _, mask)| mask & ray.mask != 0)
        .filter_map(|&(vertices, i, _)| {
            let h = ray_triangle_f64(vertices, ray.origin, ray.dir);
            let facing = match cull {
                Cull::None => true,
                Cull::Back => h.det > 0.0,
                Cull::Front => h.det < 0.0,
            };
            (h.hit && facing && h.t.is_finite() && h.t > ray.tmin && h.t <= ray.tmax).then(|| {
                let [a, b, c] = vertices;
                let (object, triangle) = scene.locate(i);
                let o = &scene.objects()[object as usize];
                let cell = o.grid.map(|g| {
                    let (r, c) = g.cell_of(triangle);
                    [r, c]
                });
                // A mirrored object's triangles are stored with vertices 2 and 3 swapped.
                let (u, v) = if o.mirrored { (h.v, h.u) } else { (h.u, h.v) };
                Hit {
                    hit: true,
                    invalid: false,
                    t: h.t,
                    object,
                    triangle,
                    u,
                    v,
                    position: ray.at(h.t),
                    normal: (b - a).cross(c - a).normalize_or_zero(),
                    cell,
                    box_tests: 0,
                    triangle_tests: all.total,
                }
            })
        })
        .collect();
    hits.sort_by(|a, b| a.t.total_cmp(&b.t));
    hits
}

/// The nearest hit of `ray` over all non-degenerate triangles of `scene`.
pub fn brute_force(scene: &Scene, ray: &Ray) -> Hit {
    let all = OracleTriangles::new(scene);
    nearest(&all, ray, all_hits(scene, &all, ray, Cull::None))
}

fn nearest(all: &OracleTriangles, ray: &Ray, hits: Vec<Hit>) -> Hit {
    if !ray.is_valid() {
        return Hit::INVALID;
    }
    hits.into_iter().next().unwrap_or(Hit {
        triangle_tests: all.total,
        ..Hit::MISS
    })
}

/// [`brute_force`] over a batch, in parallel.
pub fn brute_force_all(scene: &Scene, rays: &[Ray]) -> Vec<Hit> {
    brute_force_query(scene, rays, &Query::default()).nearest
}

/// Answers `query` by brute force. For [`Mode::Any`] the answer is the nearest hit (any hit is a
/// correct answer; compare hit/miss only). In every mode `lists` holds every hit, so callers can
/// check an any-hit miss against all of them.
pub fn brute_force_query(scene: &Scene, rays: &[Ray], query: &Query) -> Answers {
    let all = OracleTriangles::new(scene);
    let per_ray: Vec<(Hit, Vec<Hit>)> = rays
        .par_iter()
        .map(|ray| {
            if !ray.is_valid() {
                return (Hit::INVALID, Vec::new());
            }
            let hits = all_hits(scene, &all, ray, query.cull);
            (nearest(&all, ray, hits.clone()), hits)
        })
        .collect();
    let k = if query.mode == Mode::All {
        query.max_hits as usize
    } else {
        usize::MAX
    };
    let mut answers = Answers {
        list_start: vec![0],
        ..Answers::default()
    };
    for (hit, list) in per_ray {
        answers.nearest.push(hit);
        answers.overflow.push(list.len() > k);
        answers.lists.extend(list.into_iter().take(k));
        answers.list_start.push(answers.lists.len());
    }
    answers
}
