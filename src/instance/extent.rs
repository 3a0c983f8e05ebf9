//! An instance's exact world box: the box of its mesh's vertices through its transform, found
//! by branch and bound over the vertices in chunks with f64 boxes ([`Extent`]), instead of the
//! mesh box's eight corners through the transform.
//!
//! Why: a turn widens the corners' box by up to √2 per turned axis, and every ray through the
//! slack enters the instance for nothing. In the field of 10,000 turned bunnies
//! (`benches/instances.rs`) half the instance entries met none of the bunny root's boxes; with
//! the exact boxes a quarter do, entries fell from 1.10 to 0.74 a ray, and a pick was 2–6%
//! faster (BENCHMARKS.md).
//!
//! Exact: each side is the largest (or least) of [`transform_row`](crate::scene::transform_row)
//! over the vertices, the expression `apply_transform` evaluates, so the box is the brute
//! force's, bit for bit. A
//! chunk's bound is that expression at the chunk box's corner that each coefficient's sign
//! picks; IEEE products and sums are monotone, so no vertex of the chunk exceeds it and the
//! search may skip a chunk whose bound does not beat the best found.

use crate::bvh::Bvh;
use crate::scene::{Scene, box_of, transform_row as row};
use glam::DVec3;

/// Vertices per chunk.
const CHUNK: usize = 32;
/// Chunks per group (each group has a box too, so a search looks at a few groups, then a few of
/// their chunks, then their vertices).
const GROUP: usize = 32;

/// A mesh's vertices (those its triangles use) in chunks of spatial neighbours, with boxes.
#[derive(Debug)]
pub struct Extent {
    /// Vertex indices, first met in the tree's leaf order (so a chunk's vertices lie close).
    vertices: Vec<u32>,
    /// Each chunk's box, `(lo, hi)`.
    chunks: Vec<(DVec3, DVec3)>,
    /// Each group's box.
    groups: Vec<(DVec3, DVec3)>,
}

/// The most [`row`] can be over the box `(lo, hi)`: at the corner whose every coordinate's
/// product is the larger.
#[inline(always)]
fn upper(r: &[f64; 4], (lo, hi): &(DVec3, DVec3)) -> f64 {
    let pick = |c: f64, lo: f64, hi: f64| if c >= 0.0 { hi } else { lo };
    let corner = DVec3::new(
        pick(r[0], lo.x, hi.x),
        pick(r[1], lo.y, hi.y),
        pick(r[2], lo.z, hi.z),
    );
    row(r, corner)
}

impl Extent {
    /// The vertices `bvh`'s triangles use, in chunks, with their boxes.
    pub fn new(scene: &Scene, bvh: &Bvh) -> Self {
        let (triangles, positions) = (scene.triangles(), scene.positions());
        let mut seen = vec![false; positions.len()];
        let mut vertices = Vec::new();
        for &t in &bvh.triangle_ids {
            for v in triangles[t as usize] {
                if !std::mem::replace(&mut seen[v as usize], true) {
                    vertices.push(v);
                }
            }
        }
        let chunks: Vec<_> = vertices
            .chunks(CHUNK)
            .map(|c| box_of(c.iter().map(|&v| positions[v as usize])))
            .collect();
        let groups = chunks
            .chunks(GROUP)
            .map(|g| box_of(g.iter().flat_map(|&(lo, hi)| [lo, hi])))
            .collect();
        Self {
            vertices,
            chunks,
            groups,
        }
    }

    /// Bytes this takes: about 5.5 a used vertex (an index, and a box per 32).
    pub fn bytes(&self) -> u64 {
        (size_of_val(&self.vertices[..])
            + size_of_val(&self.chunks[..])
            + size_of_val(&self.groups[..])) as u64
    }

    /// The box of `positions` (the mesh's, as [`Extent::new`] saw them) through `transform`:
    /// per axis the least and the most of that row over the vertices. `None` for a mesh whose
    /// triangles use no vertex.
    pub fn world_box(
        &self,
        positions: &[DVec3],
        transform: &[[f64; 4]; 3],
    ) -> Option<(DVec3, DVec3)> {
        if self.vertices.is_empty() {
            return None;
        }
        let mut lo = [0.0; 3];
        let mut hi = [0.0; 3];
        for (a, r) in transform.iter().enumerate() {
            hi[a] = self.most(positions, r);
            // The least of a row is minus the most of its negation, exactly (rounding to
            // nearest is symmetric).
            lo[a] = -self.most(positions, &r.map(|c| -c));
        }
        Some((DVec3::from(lo), DVec3::from(hi)))
    }

    /// The most of [`row`] `r` over the vertices: the group and chunk with the highest bounds
    /// first, then every other one whose bound beats the best found.
    fn most(&self, positions: &[DVec3], r: &[f64; 4]) -> f64 {
        let mut best = f64::NEG_INFINITY;
        let chunk = |c: usize, best: &mut f64| {
            let end = ((c + 1) * CHUNK).min(self.vertices.len());
            for &v in &self.vertices[c * CHUNK..end] {
                *best = best.max(row(r, positions[v as usize]));
            }
        };
        let group = |g: usize, best: &mut f64| {
            let span = g * GROUP..((g + 1) * GROUP).min(self.chunks.len());
            let first = span
                .clone()
                .max_by(|&a, &b| upper(r, &self.chunks[a]).total_cmp(&upper(r, &self.chunks[b])))
                .expect("a group has a chunk");
            chunk(first, best);
            for c in span {
                if c != first && upper(r, &self.chunks[c]) > *best {
                    chunk(c, best);
                }
            }
        };
        let first = (0..self.groups.len())
            .max_by(|&a, &b| upper(r, &self.groups[a]).total_cmp(&upper(r, &self.groups[b])))
            .expect("a mesh with vertices has a group");
        group(first, &mut best);
        for g in 0..self.groups.len() {
            if g != first && upper(r, &self.groups[g]) > best {
                group(g, &mut best);
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::BuildOptions;
    use crate::scene::apply_transform;
    use glam::DMat3;
    use rand::Rng;

    /// The extent's box is the brute force's (every used vertex through the transform), bit
    /// for bit, for meshes of every size (one chunk, several chunks, several groups, unused
    /// vertices) under rotations, scales, shears, mirrors and far translations.
    #[test]
    fn world_box_is_the_brute_force_box() {
        let mut g = crate::check::synthetic::rng(21);
        let mut checked = 0;
        for case in 0..60 {
            let count = [1, 5, 40, 700, 3000][case % 5];
            let mut positions: Vec<DVec3> = (0..count * 3 + 7)
                .map(|_| {
                    DVec3::new(
                        g.random_range(-3.0..3.0),
                        g.random_range(-1.0..2.0),
                        g.random_range(-0.5..0.5),
                    )
                })
                .collect();
            // A few vertices no triangle uses, far out: they must not widen the box.
            positions.extend([DVec3::splat(1e3), DVec3::splat(-1e3)]);
            let used = positions.len() - 2;
            let triangles: Vec<[u32; 3]> = (0..count)
                .map(|_| std::array::from_fn(|_| g.random_range(0..used as u32)))
                .collect();
            let mut scene = Scene::new();
            scene
                .add_mesh(
                    "m",
                    crate::scene::Mesh {
                        positions: positions.clone(),
                        triangles: triangles.clone(),
                    },
                )
                .unwrap();
            let bvh = Bvh::build(&scene, &BuildOptions::default()).unwrap();
            let extent = Extent::new(&scene, &bvh);
            for _ in 0..20 {
                let m = DMat3::from_euler(
                    glam::EulerRot::ZXY,
                    g.random_range(-3.2..3.2),
                    g.random_range(-3.2..3.2),
                    g.random_range(-3.2..3.2),
                ) * DMat3::from_diagonal(DVec3::new(
                    g.random_range(0.1..5.0) * if g.random::<bool>() { -1.0 } else { 1.0 },
                    g.random_range(0.1..5.0),
                    g.random_range(0.1..5.0),
                ));
                let shear = DMat3::from_cols(
                    DVec3::X,
                    DVec3::new(g.random_range(-1.0..1.0), 1.0, 0.0),
                    DVec3::Z,
                );
                let m = m * shear;
                let t = DVec3::new(
                    g.random_range(-1e6..1e6),
                    g.random_range(-1e6..1e6),
                    g.random_range(-1e3..1e3),
                );
                let transform: [[f64; 4]; 3] = std::array::from_fn(|k| {
                    let r = m.row(k);
                    [r.x, r.y, r.z, t[k]]
                });
                // The triangles the tree holds (the scene drops degenerate ones).
                let used: Vec<u32> = bvh
                    .triangle_ids
                    .iter()
                    .flat_map(|&t| scene.triangles()[t as usize])
                    .collect();
                let want = (!used.is_empty()).then(|| {
                    box_of(
                        used.iter()
                            .map(|&v| apply_transform(&transform, positions[v as usize])),
                    )
                });
                let got = extent.world_box(&positions, &transform);
                assert_eq!(got, want, "case {case}, {count} triangles, {transform:?}");
                checked += usize::from(got.is_some());
            }
        }
        assert!(checked > 1000, "only {checked} boxes compared");
    }

    /// A transform that carries the mesh past f64's range gives a box that is not finite (the
    /// caller's error), from the mesh box's corners before any search: here one vertex's row is
    /// NaN (inf − inf), which a search's `max` would pass over, leaving a finite box. One that
    /// keeps the mesh in range gives the exact box.
    #[test]
    fn a_mesh_carried_past_the_range_gets_a_box_that_is_not_finite() {
        let mut scene = Scene::new();
        let positions = vec![
            DVec3::new(2.0, 2.0, 0.0),
            DVec3::new(1.0, 1.0, 0.0),
            DVec3::new(1.0, 1.5, 1.0),
        ];
        scene
            .add_mesh(
                "m",
                crate::scene::Mesh {
                    positions: positions.clone(),
                    triangles: vec![[0, 1, 2]],
                },
            )
            .unwrap();
        let bvh = Bvh::build(&scene, &BuildOptions::default()).unwrap();
        let tree = crate::instance::MeshTree::new(scene, bvh);
        let mut transform = crate::instance::IDENTITY;
        transform[0] = [1e308, -1e308, 0.0, 0.0];
        assert!(apply_transform(&transform, positions[0]).x.is_nan());
        let (lo, hi) = tree.world_box(&transform).expect("a mesh with a triangle");
        assert!(!(lo.is_finite() && hi.is_finite()), "{lo} {hi}");
        transform[0] = [1e307, -1e307, 0.0, 0.0];
        let want = box_of(positions.iter().map(|&p| apply_transform(&transform, p)));
        assert_eq!(tree.world_box(&transform), Some(want));
    }
}
