//! Watertightness probes: rays aimed exactly at points on shared edges and at interior vertices
//! of a mesh, from a direction in front of every triangle meeting there, so the ray truly
//! crosses the surface at its target (rays that only graze a silhouette edge are not probes).
//! Such a ray must hit something no farther than its target (t ≤ 1); a miss, or a first hit
//! beyond the target, means it slipped through a crack: a leak.
//!
//! The pickers trace each ray rounded to f32, which passes a little beside its target. So a
//! target counts only where the triangles meeting there cover a disk around it wider than that
//! rounding can move the crossing (no other edge of theirs comes closer): on a sliver, or where
//! a mesh folds onto itself, the rounded ray may truly pass beyond the triangles meeting at the
//! target, which is no crack. A hit counts as at the target within the same width.

use crate::check::compare::RELATIVE_TOLERANCE;
use crate::check::synthetic::rng;
use crate::frame::Frame;
use crate::ray::{Hit, Ray};
use crate::scene::Scene;
use glam::DVec3;
use rand::Rng;
use std::collections::HashMap;

/// Probes, and for each the most its first hit may lie beyond the target (`t = 1`) before it
/// counts as a leak.
#[derive(Clone, Debug, Default)]
pub struct Probes {
    /// The rays, each reaching its target at `t = 1`.
    pub rays: Vec<Ray>,
    /// Per ray, the slack on `t` past 1.
    pub slack: Vec<f64>,
}

impl Probes {
    /// How many probes there are.
    pub fn len(&self) -> usize {
        self.rays.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.rays.is_empty()
    }

    /// Probes that leaked: missed, or first hit beyond their target by more than their slack.
    /// `hits` are the closest hits of [`Probes::rays`], in order.
    pub fn leaks(&self, hits: &[Hit]) -> usize {
        assert_eq!(hits.len(), self.rays.len(), "one hit per probe");
        hits.iter()
            .zip(&self.slack)
            .filter(|(h, slack)| !h.hit || h.t > 1.0 + **slack)
            .count()
    }
}

/// The distance from `p` to the segment from `a` to `b`.
fn segment_distance(p: DVec3, a: DVec3, b: DVec3) -> f64 {
    let ab = b - a;
    let along = ab.length_squared();
    let s = if along > 0.0 {
        ((p - a).dot(ab) / along).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + ab * s)).length()
}

/// `count` probes for `scene`: each aims at a point exactly on an edge shared by two triangles
/// (its midpoint, a random point, or an end vertex that has no boundary edge), from a random
/// direction in front of every triangle meeting at that point (at least ~3° off each plane), so
/// the target sits at `t = 1`, and only where those triangles cover the f32 rounding's reach
/// around it (the module's text). Returns no probes if no such direction is found.
pub fn edge_probes(scene: &Scene, count: usize, seed: u64) -> Probes {
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
        return Probes::default();
    }
    let (lo, hi) = scene.bounds().unwrap_or((DVec3::ZERO, DVec3::ONE));
    let distance = (hi - lo).length().max(1e-3);
    let mut rng = rng(seed);
    let centre = Frame::around(scene.origin(), scene.bounds()).origin;
    // The vectors grow as probes are found (no up-front allocation sized by `count`).
    let mut probes = Probes {
        rays: Vec::with_capacity(count.min(1 << 16)),
        slack: Vec::with_capacity(count.min(1 << 16)),
    };
    let mut attempts = 0usize;
    while probes.len() < count && attempts < count.saturating_mul(100) {
        attempts += 1;
        let (i, k) = shared[rng.random_range(0..shared.len())];
        let t = triangles[i];
        let (a, b) = (t[k], t[(k + 1) % 3]);
        let (pa, pb) = (scene.position(a as usize), scene.position(b as usize));
        let (target, meeting, through): (_, _, &[u32]) = match rng.random_range(0..4) {
            0 if !on_boundary[&a] => (pa, &around_vertex[&a], &[a]),
            1 => ((pa + pb) * 0.5, &around_edge[&key(a, b)], &[a, b]),
            _ => (
                pa + (pb - pa) * rng.random::<f64>(),
                &around_edge[&key(a, b)],
                &[a, b],
            ),
        };
        let normal = normal_of(i);
        let tilt = DVec3::new(rng.random(), rng.random(), rng.random()) - 0.5;
        let away = (normal + (tilt - normal * tilt.dot(normal)) * 1.5).normalize_or_zero();
        // In front of every triangle meeting at the target, by at least ~3°.
        let sine = meeting
            .iter()
            .map(|&j| away.dot(normal_of(j)))
            .fold(f64::INFINITY, f64::min);
        if sine.is_nan() || sine <= 0.05 {
            continue;
        }
        let origin = target + away * distance;
        // How far the f32 rounding may move the ray's crossing along the triangles' planes,
        // with a wide margin (the rounding is about 10⁻⁷ of the coordinates, in the scene's
        // frame; `verify`'s tolerance is 10⁻⁵): no edge of the meeting triangles but those
        // through the target may come that close to it.
        let reach = RELATIVE_TOLERANCE * ((origin - centre).length() + distance) / sine;
        let covered = meeting.iter().all(|&j| {
            let t = triangles[j];
            (0..3).all(|k| {
                let (u, v) = (t[k], t[(k + 1) % 3]);
                let on_target = match through {
                    [a] => u == *a || v == *a,
                    _ => key(u, v) == key(through[0], through[1]),
                };
                on_target
                    || segment_distance(
                        target,
                        scene.position(u as usize),
                        scene.position(v as usize),
                    ) >= reach
            })
        });
        if !covered {
            continue;
        }
        probes.rays.push(Ray::new(origin, target - origin));
        probes.slack.push(reach / distance);
    }
    probes
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A probe leaks when it misses, or first hits beyond its target by more than its slack.
    #[test]
    fn misses_and_hits_past_the_slack_are_leaks() {
        let ray = Ray::new(DVec3::ZERO, DVec3::X);
        let probes = Probes {
            rays: vec![ray; 4],
            slack: vec![0.0, 0.0, 0.25, 0.25],
        };
        let at = |t: f64| Hit {
            hit: true,
            t,
            ..Hit::MISS
        };
        assert_eq!(probes.leaks(&[at(1.0), at(0.5), at(1.2), at(0.9)]), 0);
        assert_eq!(probes.leaks(&[Hit::MISS, at(1.0), at(1.2), at(0.9)]), 1);
        assert_eq!(probes.leaks(&[at(1.001), at(1.0), at(1.3), Hit::MISS]), 3);
    }
}
