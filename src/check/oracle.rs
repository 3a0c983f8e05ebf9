//! The brute-force oracle: every triangle, in f64, on the exact world vertices. Slow on purpose
//! (every triangle for every ray); it shares nothing with the tree, so tests can check every
//! traversal path against it. The [`sweep`](super::sweep) finds each ray's candidates among all
//! the triangles, a block of rays at a time; the exact test decides on them.

use super::sweep::{Edges, RAYS_PER_SWEEP};
use crate::cpu::ray_triangle::TriangleHit;
use crate::exact::ray_triangle_f64;
use crate::query::{Answers, Cull, Mode, Query};
use crate::ray::{Hit, Ray};
use crate::scene::Scene;
use glam::DVec3;
use rayon::prelude::*;

/// The scene's hittable triangles in world f64, with their scene indices and layer masks, and
/// their edges for the [`sweep`](super::sweep).
pub struct OracleTriangles {
    triangles: Vec<([DVec3; 3], u32, u32)>,
    edges: Edges,
    total: u32,
}

impl OracleTriangles {
    /// Bytes held per triangle: its world corners, scene index and mask, and its edges for the
    /// sweep.
    pub const BYTES_PER_TRIANGLE: u64 =
        (size_of::<([DVec3; 3], u32, u32)>() + 9 * size_of::<f64>()) as u64;

    /// Collects every non-degenerate triangle of `scene`.
    pub fn new(scene: &Scene) -> Self {
        // Room for every triangle at once: collected from a filter, the vector would grow by
        // doubling, to twice what `BYTES_PER_TRIANGLE` counts.
        let mut triangles = Vec::with_capacity(scene.triangle_count());
        triangles.extend(
            (0..scene.triangle_count())
                .filter(|&i| !scene.is_degenerate(i))
                .map(|i| {
                    (
                        scene.world_triangle(i),
                        i as u32,
                        scene.triangle_mask(i as u32),
                    )
                }),
        );
        Self {
            edges: Edges::new(triangles.iter().map(|t| t.0)),
            triangles,
            total: scene.triangle_count() as u32,
        }
    }
}

/// Every hit of `ray` with a finite t in (tmin, tmax], sharing a mask bit and not culled,
/// sorted by t. A ray with mask 0 shares no bit with anything: no hits.
pub fn all_hits(scene: &Scene, all: &OracleTriangles, ray: &Ray, cull: Cull) -> Vec<Hit> {
    all_hits_of_block(scene, all, std::slice::from_ref(ray), cull)
        .pop()
        .expect("one list per ray")
}

/// [`all_hits`] for each of a few rays: the sweep reads each triangle once for all of them,
/// and the exact test runs on its candidates. The same hits as the exact test on every
/// triangle: the candidates hold every triangle it hits, in the same order.
fn all_hits_of_block(
    scene: &Scene,
    all: &OracleTriangles,
    rays: &[Ray],
    cull: Cull,
) -> Vec<Vec<Hit>> {
    let mut candidates = vec![Vec::new(); rays.len()];
    let lines: Vec<(DVec3, DVec3)> = rays.iter().map(|r| (r.origin, r.dir)).collect();
    all.edges.candidates(&lines, &mut candidates);
    rays.iter()
        .zip(candidates)
        .map(|(ray, candidates)| {
            let mut hits: Vec<Hit> = candidates
                .into_iter()
                .map(|k| all.triangles[k as usize])
                .filter(|(_, _, mask)| mask & ray.mask != 0)
                .filter_map(|(vertices, i, _)| exact_hit(scene, all, ray, cull, vertices, i))
                .collect();
            hits.sort_by(|a, b| a.t.total_cmp(&b.t));
            hits
        })
        .collect()
}

/// The exact test of `ray` on scene triangle `i`, as a hit when it counts.
fn exact_hit(
    scene: &Scene,
    all: &OracleTriangles,
    ray: &Ray,
    cull: Cull,
    vertices: [DVec3; 3],
    i: u32,
) -> Option<Hit> {
    let h = ray_triangle_f64(vertices, ray.origin, ray.dir);
    let facing = match cull {
        Cull::None => true,
        Cull::Back => h.det > 0.0,
        Cull::Front => h.det < 0.0,
    };
    (h.hit && facing && h.t.is_finite() && h.t > ray.tmin && h.t <= ray.tmax).then(|| {
        let [a, b, c] = vertices;
        let (object, triangle, u, v) = located(scene, i, &h);
        let cell = scene.objects()[object as usize].grid.map(|g| {
            let (r, c) = g.cell_of(triangle);
            [r, c]
        });
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
}

/// Scene triangle `i`'s object and own triangle id, and the exact test's u and v as the oracle
/// reports them: a mirrored object's triangles are stored with vertices 2 and 3 swapped, so its
/// u and v are swapped back.
pub(crate) fn located(scene: &Scene, i: u32, h: &TriangleHit<f64>) -> (u32, u32, f64, f64) {
    let (object, triangle) = scene.locate(i);
    let (u, v) = if scene.objects()[object as usize].mirrored {
        (h.v, h.u)
    } else {
        (h.u, h.v)
    };
    (object, triangle, u, v)
}

/// The nearest hit of `ray` over all non-degenerate triangles of `scene`.
pub fn brute_force(scene: &Scene, ray: &Ray) -> Hit {
    let all = OracleTriangles::new(scene);
    nearest(
        &all,
        ray,
        all_hits(scene, &all, ray, Cull::None).first().copied(),
    )
}

fn nearest(all: &OracleTriangles, ray: &Ray, first: Option<Hit>) -> Hit {
    if !ray.is_valid() {
        return Hit::INVALID;
    }
    first.unwrap_or(Hit {
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
    brute_force_every(scene, rays, query).0
}

/// [`brute_force_query`]'s answers, and beside them the same answers with every hit listed
/// (no `max_hits` cut in [`Mode::All`]): what the comparisons judge an any-hit or a cut list
/// against. One brute force for both.
pub fn brute_force_every(scene: &Scene, rays: &[Ray], query: &Query) -> (Answers, Answers) {
    brute_force_reporting(scene, rays, query, |_| ())
}

/// [`brute_force_every`], calling `done(k)` each time another `k` rays are answered (from any
/// thread): for a progress bar over a brute force of minutes.
pub fn brute_force_reporting(
    scene: &Scene,
    rays: &[Ray],
    query: &Query,
    done: impl Fn(usize) + Sync,
) -> (Answers, Answers) {
    let all = OracleTriangles::new(scene);
    let per_ray: Vec<(Hit, Vec<Hit>)> = rays
        .par_chunks(RAYS_PER_SWEEP)
        .flat_map_iter(|block| {
            let valid: Vec<Ray> = block.iter().copied().filter(Ray::is_valid).collect();
            let mut lists = all_hits_of_block(scene, &all, &valid, query.cull).into_iter();
            let answers = block
                .iter()
                .map(|ray| {
                    if !ray.is_valid() {
                        return (Hit::INVALID, Vec::new());
                    }
                    let hits = lists.next().expect("one list per valid ray");
                    (nearest(&all, ray, hits.first().copied()), hits)
                })
                .collect::<Vec<_>>();
            done(block.len());
            answers
        })
        .collect();
    let k = if query.mode == Mode::All {
        query.max_hits as usize
    } else {
        usize::MAX
    };
    let empty = || Answers {
        list_start: vec![0],
        ..Answers::default()
    };
    let (mut answers, mut every) = (empty(), empty());
    for (hit, list) in per_ray {
        for (out, k) in [(&mut answers, k), (&mut every, usize::MAX)] {
            out.nearest.push(hit);
            out.overflow.push(list.len() > k);
            out.lists.extend(list.iter().take(k).copied());
            out.list_start.push(out.lists.len());
        }
    }
    (answers, every)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::check::synthetic::{example_scene, mixed_rays, thin_and_degenerate};

    /// The exact test on every triangle, one ray at a time: the oracle before the sweep.
    fn every_triangle(scene: &Scene, all: &OracleTriangles, ray: &Ray, cull: Cull) -> Vec<Hit> {
        let mut hits: Vec<Hit> = all
            .triangles
            .iter()
            .filter(|(_, _, mask)| mask & ray.mask != 0)
            .filter_map(|&(vertices, i, _)| exact_hit(scene, all, ray, cull, vertices, i))
            .collect();
        hits.sort_by(|a, b| a.t.total_cmp(&b.t));
        hits
    }

    /// The sweep changes how fast the oracle is, not what it says: on the example scene and
    /// on thin and degenerate triangles, every ray kind (vertices, edge midpoints, grazing,
    /// axis-parallel), every cull and a few masks, the same hits bit for bit, in blocks as in
    /// `brute_force_every`.
    #[test]
    fn the_sweep_gives_the_hits_of_the_exact_test_on_every_triangle() {
        let mut thin = Scene::new();
        thin.add_mesh("thin", thin_and_degenerate(3)).unwrap();
        let mut compared = 0;
        for scene in [example_scene(), thin] {
            let all = OracleTriangles::new(&scene);
            let mut rays: Vec<Ray> = mixed_rays(&scene, 800, 11)
                .into_iter()
                .map(|r| r.1)
                .collect();
            for (i, ray) in rays.iter_mut().enumerate() {
                ray.mask = [u32::MAX, 1, 2, 0][i % 4];
            }
            for cull in [Cull::None, Cull::Back, Cull::Front] {
                for block in rays.chunks(RAYS_PER_SWEEP) {
                    let swept = all_hits_of_block(&scene, &all, block, cull);
                    for (ray, swept) in block.iter().zip(swept) {
                        let exact = every_triangle(&scene, &all, ray, cull);
                        assert_eq!(
                            format!("{swept:?}"),
                            format!("{exact:?}"),
                            "{ray:?} {cull:?}"
                        );
                        compared += exact.len();
                    }
                }
            }
        }
        assert!(compared > 1000, "{compared} hits compared");
    }
}
