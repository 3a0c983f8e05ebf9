//! Möller–Trumbore ray/triangle intersection, as in the paper:
//! E1 = V1−V0, E2 = V2−V0, T = O−V0, P = D×E2, Q = T×E1;
//! t = Q·E2 / P·E1, u = P·T / P·E1, v = Q·D / P·E1; hit when u ≥ 0, v ≥ 0, u+v ≤ 1.
//!
//! [`ray_triangle`] is the f32 twin of `ray_triangle` in `wgsl/pick.wgsl`;
//! [`ray_triangle_f64`] is the exact version used to refine hits and by the brute-force oracle.

use crate::layout::GpuTriangle;
use glam::{DVec3, Vec3};

/// What one ray/triangle test found: `hit` says whether the ray's line crosses the triangle
/// (edges inclusive); `t`, `u`, `v` are only meaningful when it does.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleHit<F> {
    /// The line crosses the triangle.
    pub hit: bool,
    /// Ray parameter.
    pub t: F,
    /// Barycentric weight of v1.
    pub u: F,
    /// Barycentric weight of v2.
    pub v: F,
}

/// f32 Möller–Trumbore, the twin of the WGSL function.
pub fn ray_triangle(tri: &GpuTriangle, origin: Vec3, dir: Vec3) -> TriangleHit<f32> {
    let v0 = Vec3::from(tri.v0);
    let v1 = Vec3::from(tri.v1);
    let v2 = Vec3::from(tri.v2);
    let e1 = v1 - v0;
    let e2 = v2 - v0;
    let p = dir.cross(e2);
    let det = p.dot(e1);
    if det == 0.0 {
        return TriangleHit {
            hit: false,
            t: 0.0,
            u: 0.0,
            v: 0.0,
        };
    }
    let inv_det = 1.0 / det;
    let to_origin = origin - v0;
    let u = p.dot(to_origin) * inv_det;
    let q = to_origin.cross(e1);
    let v = q.dot(dir) * inv_det;
    let t = q.dot(e2) * inv_det;
    TriangleHit {
        hit: u >= 0.0 && v >= 0.0 && u + v <= 1.0,
        t,
        u,
        v,
    }
}

/// f64 Möller–Trumbore on world-space vertices. `hit` is false when the ray is parallel to the
/// triangle's plane (or the triangle has zero area).
pub fn ray_triangle_f64([v0, v1, v2]: [DVec3; 3], origin: DVec3, dir: DVec3) -> TriangleHit<f64> {
    let e1 = v1 - v0;
    let e2 = v2 - v0;
    let p = dir.cross(e2);
    let det = p.dot(e1);
    if det == 0.0 {
        return TriangleHit {
            hit: false,
            t: 0.0,
            u: 0.0,
            v: 0.0,
        };
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
    }
}
