//! Watertightness probes: rays aimed exactly at points on shared edges and at interior vertices
//! of a mesh, from a direction in front of every triangle meeting there, so the ray truly
//! crosses the surface at its target (rays that only graze a silhouette edge are not probes).
//! Such a ray must hit something no farther than its target (t ≤ 1); a miss, or a first hit
//! beyond the target, means it slipped through a crack: a leak.

use crate::check::synthetic::rng;
use crate::ray::{Hit, Ray};
use crate::scene::Scene;
use glam::DVec3;
use rand::Rng;
use std::collections::HashMap;

/// Relative slack on t before a hit beyond the target counts as a leak.
pub const LEAK_SLACK: f64 = 1e-6;

/// `count` probes for `scene`: each aims at a point exactly on an edge shared by two triangles
/// (its midpoint, a random point, or an end vertex that has no boundary edge), from a random
/// direction in front of every triangle meeting at that point (at least ~3° off each plane), so
/// the target sits at `t = 1`. Returns no probes if no such direction is found.
pub fn edge_probes(scene: &Scene, count: usize, seed: u64) -> Vec<Ray> {
    let mut edge_uses: HashMap<(u32, u32), u32> = HashMap::new();
    let triangles: Vec<[u32; 3]> = (0..scene.triangle_count())
        .filter(|&i| !scene.is_degenerate(i))
        .map(|i| scene.triangle_vertices(i))
        .collect();
    let key = |a: u32, b: u32| (a.min(b), a.max(b));
    for t in &triangles {
        for k in 0..3 {
            *edge_uses.entry(key(t[k], t[(k + 1) % 3])).or_default() += 1;
        }
    }
    let mut around_vertex: HashMap<u32, Vec<usize>> = HashMap::new();
    let mut around_edge: HashMap<(u32, u32), Vec<usize>> = HashMap::new();
    for (i, t) in triangles.iter().enumerate() {
        for k in 0..3 {
            around_vertex.entry(t[k]).or_default().push(i);
            around_edge
                .entry(key(t[k], t[(k + 1) % 3]))
                .or_default()
                .push(i);
        }
    }
    let normal_of = |i: usize| {
        let [v0, v1, v2] = triangles[i].map(|v| scene.position(v as usize));
        (v1 - v0).cross(v2 - v0).normalize_or_zero()
    };
    let mut on_boundary: HashMap<u32, bool> = HashMap::new();
    for (&(a, b), &uses) in &edge_uses {
        for v in [a, b] {
            *on_boundary.entry(v).or_default() |= uses != 2;
        }
    }
    let uses = &edge_uses;
    let shared: Vec<(usize, usize)> = triangles
        .iter()
        .enumerate()
        .flat_map(|(i, t)| {
            (0..3)
                .filter(move |&k| uses[&key(t[k], t[(k + 1) % 3])] == 2)
                .map(move |k| (i, k))
        })
        .collect();
    if shared.is_empty() {
        return Vec::new();
    }
    let (lo, hi) = scene.bounds().unwrap_or((DVec3::ZERO, DVec3::ONE));
    let distance = (hi - lo).length().max(1e-3);
    let mut rng = rng(seed);
    // The vector grows as probes are found (no up-front allocation sized by `count`).
    let mut probes = Vec::with_capacity(count.min(1 << 16));
    let mut attempts = 0usize;
    while probes.len() < count && attempts < count.saturating_mul(100) {
        attempts += 1;
        let (i, k) = shared[rng.random_range(0..shared.len())];
        let t = triangles[i];
        let (a, b) = (t[k], t[(k + 1) % 3]);
        let (pa, pb) = (scene.position(a as usize), scene.position(b as usize));
        let (target, meeting) = match rng.random_range(0..4) {
            0 if !on_boundary[&a] => (pa, &around_vertex[&a]),
            1 => ((pa + pb) * 0.5, &around_edge[&key(a, b)]),
            _ => (
                pa + (pb - pa) * rng.random::<f64>(),
                &around_edge[&key(a, b)],
            ),
        };
        let normal = normal_of(i);
        let tilt = DVec3::new(rng.random(), rng.random(), rng.random()) - 0.5;
        let away = (normal + (tilt - normal * tilt.dot(normal)) * 1.5).normalize_or_zero();
        // In front of every triangle meeting at the target, by at least ~3°.
        if meeting.iter().any(|&j| away.dot(normal_of(j)) <= 0.05) {
            continue;
        }
        let origin = target + away * distance;
        probes.push(Ray::new(origin, target - origin));
    }
    probes
}

/// Probes that leaked: missed, or first hit beyond their target.
pub fn leaks(hits: &[Hit]) -> usize {
    hits.iter()
        .filter(|h| !h.hit || h.t > 1.0 + LEAK_SLACK)
        .count()
}
