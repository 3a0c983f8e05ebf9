//! The oracle's sweep: which triangles a few rays may hit, found by running the first half of
//! the exact test ([`crate::exact::ray_triangle_f64`]: its products, sums and two divisions,
//! u and v) over every triangle, without branches so that the compiler runs it several
//! triangles at a time. Same f64 operations in the same order, so the same u and v bit for bit:
//! every triangle the exact test hits is a candidate. The oracle then runs the exact test itself
//! on the candidates (a handful per ray), so what it reports does not depend on this file.
//!
//! The triangles are swept in chunks small enough to stay in the L1 cache while a block of
//! rays passes over them: each triangle's 72 bytes are read from memory once per block, not once
//! per ray.

use crate::exact::tested_direction;
use glam::DVec3;

/// Triangles per chunk: 9 × 8 bytes each, 18 KiB a chunk.
const CHUNK: usize = 256;

/// Rays swept over each chunk in turn.
pub const RAYS_PER_SWEEP: usize = 8;

/// Every triangle's first vertex and two edges, in nine arrays (x, y, z of v0, e1 = v1 − v0,
/// e2 = v2 − v0), computed as the exact test computes them.
pub struct Edges {
    lanes: [Vec<f64>; 9],
}

impl Edges {
    /// The edges of `triangles`, in order.
    pub fn new(triangles: impl ExactSizeIterator<Item = [DVec3; 3]>) -> Self {
        let mut lanes: [Vec<f64>; 9] = std::array::from_fn(|_| Vec::with_capacity(triangles.len()));
        for [v0, v1, v2] in triangles {
            let (e1, e2) = (v1 - v0, v2 - v0);
            for (lane, value) in lanes
                .iter_mut()
                .zip([v0.x, v0.y, v0.z, e1.x, e1.y, e1.z, e2.x, e2.y, e2.z])
            {
                lane.push(value);
            }
        }
        Self { lanes }
    }

    /// How many triangles.
    pub fn len(&self) -> usize {
        self.lanes[0].len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// For each ray `(origin, dir)` of `rays`, the indices of the triangles whose u and v the
    /// exact test finds inside (u ≥ 0, v ≥ 0, u + v ≤ 1), in increasing order, appended to the
    /// ray's list in `out`: candidates, not answers (the range, mask and cull are the exact
    /// test's to judge). A triangle whose plane the ray parallels (det = 0, a miss for the exact
    /// test) is never listed: its u or v is infinite or NaN, never inside.
    pub fn candidates(&self, rays: &[(DVec3, DVec3)], out: &mut [Vec<u32>]) {
        let dirs: Vec<DVec3> = rays.iter().map(|&(_, dir)| tested_direction(dir)).collect();
        let mut inside = [false; CHUNK];
        for start in (0..self.len()).step_by(CHUNK) {
            let end = (start + CHUNK).min(self.len());
            let chunk: [&[f64]; 9] = std::array::from_fn(|l| &self.lanes[l][start..end]);
            for ((&(origin, _), &dir), list) in rays.iter().zip(&dirs).zip(out.iter_mut()) {
                inside_of(chunk, origin, dir, &mut inside[..end - start]);
                list.extend(
                    inside[..end - start]
                        .iter()
                        .enumerate()
                        .filter(|&(_, &inside)| inside)
                        .map(|(i, _)| (start + i) as u32),
                );
            }
        }
    }
}

/// [`inside`], four triangles at a time where the CPU has AVX (two elsewhere): the same
/// operations lane by lane, so the same bits.
fn inside_of(chunk: [&[f64]; 9], origin: DVec3, dir: DVec3, inside: &mut [bool]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the CPU has AVX, checked just above.
        return unsafe { inside_avx(chunk, origin, dir, inside) };
    }
    self::inside(chunk, origin, dir, inside)
}

/// [`inside`] compiled for AVX (no FMA: products and sums stay separately rounded).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
fn inside_avx(chunk: [&[f64]; 9], origin: DVec3, dir: DVec3, inside: &mut [bool]) {
    self::inside(chunk, origin, dir, inside)
}

/// The exact test's u and v for one ray over a chunk, and whether they are inside. Written out
/// as glam's `cross` and `dot` compute them (`dot`: (x·x') + (y·y') + (z·z'), left to right).
#[inline(always)]
fn inside(chunk: [&[f64]; 9], origin: DVec3, dir: DVec3, inside: &mut [bool]) {
    let n = inside.len();
    let [v0x, v0y, v0z, e1x, e1y, e1z, e2x, e2y, e2z] = chunk.map(|lane| &lane[..n]);
    for i in 0..n {
        // p = dir × e2
        let px = dir.y * e2z[i] - e2y[i] * dir.z;
        let py = dir.z * e2x[i] - e2z[i] * dir.x;
        let pz = dir.x * e2y[i] - e2x[i] * dir.y;
        let det = (px * e1x[i]) + (py * e1y[i]) + (pz * e1z[i]);
        // to = origin − v0
        let (tx, ty, tz) = (origin.x - v0x[i], origin.y - v0y[i], origin.z - v0z[i]);
        let u = ((px * tx) + (py * ty) + (pz * tz)) / det;
        // q = to × e1
        let qx = ty * e1z[i] - e1y[i] * tz;
        let qy = tz * e1x[i] - e1z[i] * tx;
        let qz = tx * e1y[i] - e1x[i] * ty;
        let v = ((qx * dir.x) + (qy * dir.y) + (qz * dir.z)) / det;
        inside[i] = (u >= 0.0) & (v >= 0.0) & (u + v <= 1.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::exact::ray_triangle_f64;

    /// A small deterministic generator (splitmix64), so the test needs no seed crate.
    fn numbers(mut state: u64) -> impl FnMut() -> f64 {
        move || {
            state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// Every triangle the exact test hits is a candidate, on triangles of a small grid (shared
    /// edges and vertices, where u, v or u + v land exactly on their bounds), random ones, and
    /// degenerate ones; rays aimed at vertices and edges, random ones, and directions near
    /// the ends of f64's range.
    #[test]
    fn every_hit_of_the_exact_test_is_a_candidate() {
        let mut r = numbers(7);
        let mut triangles = Vec::new();
        for i in 0..6 {
            for j in 0..6 {
                let (x, y) = (i as f64, j as f64);
                let z = |x: f64, y: f64| (x * 0.37 + y * 0.11).sin();
                let p = |x: f64, y: f64| DVec3::new(x, y, z(x, y));
                triangles.push([p(x, y), p(x + 1.0, y), p(x, y + 1.0)]);
                triangles.push([p(x + 1.0, y), p(x + 1.0, y + 1.0), p(x, y + 1.0)]);
            }
        }
        for _ in 0..300 {
            let mut p = || DVec3::new(r() * 6.0, r() * 6.0, r() * 2.0 - 1.0);
            triangles.push([p(), p(), p()]);
        }
        let a = DVec3::new(1.0, 2.0, 0.5);
        triangles.push([a, a, a]);
        triangles.push([a, a + DVec3::X, a + 2.0 * DVec3::X]);
        let edges = Edges::new(triangles.iter().copied());

        let mut rays = Vec::new();
        for t in &triangles[..72] {
            let origin = DVec3::new(r() * 6.0, r() * 6.0, 5.0);
            for target in [t[0], t[1], t[2], (t[0] + t[1]) * 0.5, (t[1] + t[2]) * 0.5] {
                rays.push((origin, target - origin));
            }
        }
        for _ in 0..400 {
            let origin = DVec3::new(r() * 8.0 - 1.0, r() * 8.0 - 1.0, r() * 10.0 - 5.0);
            let dir = DVec3::new(r() - 0.5, r() - 0.5, r() - 0.5);
            rays.push((origin, dir));
        }
        for length in [2f64.powi(1000), 1e-300, 1e307] {
            rays.push((
                DVec3::new(2.5, 2.5, 4.0),
                DVec3::new(0.01, -0.02, -1.0) * length,
            ));
        }

        let mut hits = 0;
        for block in rays.chunks(RAYS_PER_SWEEP) {
            let mut lists = vec![Vec::new(); block.len()];
            edges.candidates(block, &mut lists);
            for (&(origin, dir), list) in block.iter().zip(&lists) {
                assert!(list.windows(2).all(|w| w[0] < w[1]));
                for (k, &t) in triangles.iter().enumerate() {
                    let exact = ray_triangle_f64(t, origin, dir);
                    if exact.hit {
                        hits += 1;
                        assert!(
                            list.contains(&(k as u32)),
                            "ray {origin} {dir}: triangle {k} is hit but not a candidate"
                        );
                    }
                }
            }
        }
        assert!(hits > 1000, "{hits} hits: the test must exercise the sweep");
    }

    /// The AVX build and the portable one flag the same triangles.
    #[test]
    fn the_avx_build_and_the_portable_one_agree() {
        let mut r = numbers(5);
        let triangles: Vec<[DVec3; 3]> = (0..CHUNK - 3)
            .map(|_| std::array::from_fn(|_| DVec3::new(r(), r(), r() - 0.5)))
            .collect();
        let edges = Edges::new(triangles.iter().copied());
        let chunk: [&[f64]; 9] = std::array::from_fn(|l| &edges.lanes[l][..]);
        let (mut portable, mut best) = ([false; CHUNK - 3], [false; CHUNK - 3]);
        let mut flagged = 0;
        for _ in 0..50 {
            let origin = DVec3::new(r(), r(), 2.0);
            let dir = DVec3::new(r() - 0.5, r() - 0.5, -1.0);
            inside(chunk, origin, dir, &mut portable);
            inside_of(chunk, origin, dir, &mut best);
            assert_eq!(portable, best);
            flagged += portable.iter().filter(|&&b| b).count();
        }
        assert!(flagged > 100, "{flagged}");
    }
}
