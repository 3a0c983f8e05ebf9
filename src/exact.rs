//! The exact ray/triangle test: f64 Möller–Trumbore on world-space vertices. The f64 refinement
//! of every hit (`frame::resolve`) and the brute-force oracle use it; no traversal path does.

use crate::cpu::ray_triangle::TriangleHit;
use glam::DVec3;

/// f64 Möller–Trumbore on world-space vertices. `hit` is false when the ray is parallel to the
/// triangle's plane (or the triangle has zero area).
#[inline]
pub fn ray_triangle_f64([v0, v1, v2]: [DVec3; 3], origin: DVec3, dir: DVec3) -> TriangleHit<f64> {
    let e1 = v1 - v0;
    let e2 = v2 - v0;
    let p = dir.cross(e2);
    let det = p.dot(e1);
    if det == 0.0 {
        return TriangleHit::miss();
    }
    let to_origin = origin - v0;
    let u = p.dot(to_origin) / det;
    let q = to_origin.cross(e1);
    let v = q.dot(dir) / det;
    let t = q.dot(e2) / det;
    TriangleHit {
        hit: u >= 0.0 && v >= 0.0 && u + v <= 1.0,
        t,
        u,
        v,
        det,
    }
}
