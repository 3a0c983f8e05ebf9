//! The `bvh` 0.13 peer (svenstaro): `Bvh::build_par` over one shape per triangle, and a
//! closest hit per ray by walking `nearest_traverse_iterator` (leaves in order of their box's
//! entry distance), testing each candidate with a two-sided Möller–Trumbore and stopping once a
//! box starts beyond the best hit.

use bvh::aabb::{Aabb, Bounded};
use bvh::bounding_hierarchy::{BHShape, BoundingHierarchy};
use glam::Vec3A;
use nalgebra::{Point3, Vector3};
use raypick::layout::GpuRay;

/// One triangle as a `bvh` shape, with its box precomputed.
pub struct BvhTriangle {
    corners: [Vec3A; 3],
    aabb: Aabb<f32, 3>,
    node_index: usize,
}

impl Bounded<f32, 3> for BvhTriangle {
    fn aabb(&self) -> Aabb<f32, 3> {
        self.aabb
    }
}

impl BHShape<f32, 3> for BvhTriangle {
    fn set_bh_node_index(&mut self, index: usize) {
        self.node_index = index;
    }
    fn bh_node_index(&self) -> usize {
        self.node_index
    }
}

/// The tree and the shapes it indexes.
pub struct BvhPeer {
    bvh: bvh::bvh::Bvh<f32, 3>,
    shapes: Vec<BvhTriangle>,
}

fn point(p: Vec3A) -> Point3<f32> {
    Point3::new(p.x, p.y, p.z)
}

impl BvhPeer {
    /// One shape per triangle, then `bvh`'s builder with rayon (its `build_par`, the default
    /// features' parallel build).
    pub fn build(triangles: &[[Vec3A; 3]]) -> Self {
        let mut shapes: Vec<BvhTriangle> = triangles
            .iter()
            .map(|&corners| {
                let lo = corners[0].min(corners[1]).min(corners[2]);
                let hi = corners[0].max(corners[1]).max(corners[2]);
                BvhTriangle {
                    corners,
                    aabb: Aabb::with_bounds(point(lo), point(hi)),
                    node_index: 0,
                }
            })
            .collect();
        let bvh = bvh::bvh::Bvh::build_par(&mut shapes);
        Self { bvh, shapes }
    }

    /// Closest hit of one ray: the leaves come nearest box first; each candidate triangle is
    /// tested, and the walk stops at the first leaf whose box starts beyond the best hit so far.
    pub fn intersect(&self, r: &GpuRay) -> Option<f32> {
        let (origin, dir) = (Vec3A::from(r.origin), Vec3A::from(r.dir));
        // `bvh::ray::Ray` normalises its direction: its distances are t × |dir|.
        let length = dir.length();
        let ray = bvh::ray::Ray::new(point(origin), Vector3::new(dir.x, dir.y, dir.z));
        let mut best = r.tmax;
        let mut found = None;
        for shape in self.bvh.nearest_traverse_iterator(&ray, &self.shapes) {
            match ray.intersection_slice_for_aabb(&shape.aabb) {
                Some((entry, _)) if entry / length > best => break,
                Some(_) => {}
                None => continue,
            }
            if let Some(t) = moller_trumbore(origin, dir, shape.corners, r.tmin, best) {
                best = t;
                found = Some(t);
            }
        }
        found
    }
}

/// Two-sided Möller–Trumbore in the ray's own units: t in (tmin, tmax), like raypick's and
/// obvhs's tests. (`bvh::ray::Ray::intersects_triangle` culls back faces, so it cannot answer
/// closest-hit picks over both faces.)
fn moller_trumbore(
    origin: Vec3A,
    dir: Vec3A,
    [v0, v1, v2]: [Vec3A; 3],
    tmin: f32,
    tmax: f32,
) -> Option<f32> {
    let (e1, e2) = (v1 - v0, v2 - v0);
    let p = dir.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 {
        return None;
    }
    let inv = 1.0 / det;
    let s = origin - v0;
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = dir.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > tmin && t < tmax).then_some(t)
}
