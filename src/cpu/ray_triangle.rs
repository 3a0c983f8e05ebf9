//! Ray/triangle tests. Möller–Trumbore, as in the paper:
//! E1 = V1−V0, E2 = V2−V0, T = O−V0, P = D×E2, Q = T×E1;
//! t = Q·E2 / P·E1, u = P·T / P·E1, v = Q·D / P·E1; hit when u ≥ 0, v ≥ 0, u+v ≤ 1.
//!
//! [`ray_triangle`] is the f32 twin of `ray_triangle` in `wgsl/pick.wgsl`, and
//! [`ray_triangle_watertight`] the twin of the watertight test (Woop, Benthin, Wald 2013). The
//! exact f64 test used to refine hits and by the brute-force oracle is `crate::exact`'s: it is
//! not part of the kernel's twin.
//! In all of them `det > 0` means the triangle is counter-clockwise as seen from the ray.

use crate::layout::GpuTriangle;
use glam::{Vec3, Vec3A};

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
    /// Positive when the triangle is counter-clockwise (front-facing) as seen from the ray.
    pub det: F,
}

impl<F: Default> TriangleHit<F> {
    /// No hit.
    pub fn miss() -> Self {
        Self {
            hit: false,
            t: F::default(),
            u: F::default(),
            v: F::default(),
            det: F::default(),
        }
    }
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
        return TriangleHit::miss();
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
        det,
    }
}

/// Per-ray set-up of the watertight test: the axis the ray runs along most (`kz`), the two
/// others (swapped to keep the winding when the ray runs down `kz`), folded into three rows so
/// that a vertex `v` (relative to the origin) maps to ray space as `(v·x, v·y, v·z)`. Every
/// vertex is mapped the same way whichever triangle it belongs to: the test is watertight.
#[derive(Clone, Copy, Debug)]
pub struct Shear {
    x: Vec3,
    y: Vec3,
    z: Vec3,
}

impl Shear {
    /// The three rows (x, y, z), for the engine's lanes.
    #[inline]
    pub fn rows(&self) -> [Vec3; 3] {
        [self.x, self.y, self.z]
    }
}

fn unit_axis(k: usize) -> Vec3 {
    Vec3::new(
        if k == 0 { 1.0 } else { 0.0 },
        if k == 1 { 1.0 } else { 0.0 },
        if k == 2 { 1.0 } else { 0.0 },
    )
}

/// The twin of `shear_for` in the WGSL.
#[inline]
pub fn shear_for(dir: Vec3) -> Shear {
    let a = dir.abs();
    let mut kz = 2;
    if a.x >= a.y && a.x >= a.z {
        kz = 0;
    } else if a.y >= a.z {
        kz = 1;
    }
    let mut kx = (kz + 1) % 3;
    let mut ky = (kx + 1) % 3;
    if dir[kz] < 0.0 {
        std::mem::swap(&mut kx, &mut ky);
    }
    let ez = unit_axis(kz);
    Shear {
        x: unit_axis(kx) - (dir[kx] / dir[kz]) * ez,
        y: unit_axis(ky) - (dir[ky] / dir[kz]) * ez,
        z: ez / dir[kz],
    }
}

/// [`shear_for`]`(dir).rows()`, bit for bit, for the engine's per-ray set-up: the axes chosen
/// without branches (incoherent rays mispredicted them half the time) and the four quotients
/// (`d_kx/d_kz`, `d_ky/d_kz`, `0/d_kz`, `1/d_kz`) in one four-lane division; each row's
/// components are then the same subtractions and products as `shear_for`'s.
#[inline(always)]
pub fn shear_rows(dir: Vec3) -> [[f32; 3]; 3] {
    let a = dir.abs();
    // `shear_for`'s choice: x when it is at least y and z, else y when at least z, else z.
    let x_first = (a.x >= a.y) & (a.x >= a.z);
    let y_first = !x_first & (a.y >= a.z);
    let kz = 2 - 2 * usize::from(x_first) - usize::from(y_first);
    let d = dir.to_array();
    let dz = d[kz];
    let (mut kx, mut ky) = ([1, 2, 0][kz], [2, 0, 1][kz]);
    if dz < 0.0 {
        std::mem::swap(&mut kx, &mut ky);
    }
    let q = glam::Vec4::new(d[kx], d[ky], 0.0, 1.0) / dz;
    // The unit axes as lane masks, and the rows in four-lane vectors: e_k − s·e_kz per lane.
    let lane = Vec3A::new(0.0, 1.0, 2.0);
    let axis = |k: usize| lane.cmpeq(Vec3A::splat(k as f32));
    let unit = |k: usize| Vec3A::select(axis(k), Vec3A::ONE, Vec3A::ZERO);
    let ez = unit(kz);
    let x = unit(kx) - Vec3A::splat(q.x) * ez;
    let y = unit(ky) - Vec3A::splat(q.y) * ez;
    let z = Vec3A::select(axis(kz), Vec3A::splat(q.w), Vec3A::splat(q.z));
    [x.to_array(), y.to_array(), z.to_array()]
}

/// Watertight ray/triangle test (Woop, Benthin, Wald, JCGT 2013): edge functions in a sheared
/// ray space are computed identically for the two triangles sharing an edge, so a ray can never
/// slip between them. Edges are inclusive.
pub fn ray_triangle_watertight(tri: &GpuTriangle, origin: Vec3, sh: &Shear) -> TriangleHit<f32> {
    let a = Vec3::from(tri.v0) - origin;
    let b = Vec3::from(tri.v1) - origin;
    let c = Vec3::from(tri.v2) - origin;
    let ax = a.dot(sh.x);
    let ay = a.dot(sh.y);
    let bx = b.dot(sh.x);
    let by = b.dot(sh.y);
    let cx = c.dot(sh.x);
    let cy = c.dot(sh.y);
    let u_edge = cx * by - cy * bx;
    let v_edge = ax * cy - ay * cx;
    let w_edge = bx * ay - by * ax;
    let outside = (u_edge < 0.0 || v_edge < 0.0 || w_edge < 0.0)
        && (u_edge > 0.0 || v_edge > 0.0 || w_edge > 0.0);
    let det = u_edge + v_edge + w_edge;
    if outside || det == 0.0 {
        return TriangleHit::miss();
    }
    let t_scaled = u_edge * a.dot(sh.z) + v_edge * b.dot(sh.z) + w_edge * c.dot(sh.z);
    let inv_det = 1.0 / det;
    TriangleHit {
        hit: true,
        t: t_scaled * inv_det,
        u: v_edge * inv_det,
        v: w_edge * inv_det,
        det,
    }
}

/// Direction components that test a set-up's edge cases: signed zeros, a subnormal, tiny and
/// huge magnitudes, infinities, NaN, and ties between axes.
#[cfg(test)]
pub(crate) const SPECIAL_COMPONENTS: [f32; 17] = [
    0.0,
    -0.0,
    1.0,
    -1.0,
    0.5,
    -0.5,
    1e-30,
    -1e-30,
    1e-40,
    -1e-40,
    3e38,
    -3e38,
    f32::INFINITY,
    f32::NEG_INFINITY,
    f32::NAN,
    0.577_350_26,
    -0.577_350_26,
];

/// `n` directions with components uniform in [−1, 1] (xorshift, fixed seed): the same ones on
/// every run.
#[cfg(test)]
pub(crate) fn random_directions(n: usize) -> Vec<[f32; 3]> {
    let mut seed = 0x2545_f491_u32;
    let mut next = || {
        seed ^= seed << 13;
        seed ^= seed >> 17;
        seed ^= seed << 5;
        (seed as f32 / u32::MAX as f32) * 2.0 - 1.0
    };
    (0..n).map(|_| [next(), next(), next()]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bits(rows: [[f32; 3]; 3]) -> [[u32; 3]; 3] {
        rows.map(|r| r.map(f32::to_bits))
    }

    /// `shear_rows` is `shear_for(dir).rows()` bit for bit: ties between the axes' magnitudes,
    /// signed zeros, tiny and huge components, infinities and NaN included.
    #[test]
    fn the_engines_shear_rows_are_shear_fors() {
        let special = SPECIAL_COMPONENTS;
        let mut checked = 0;
        for &x in &special {
            for &y in &special {
                for &z in &special {
                    let dir = Vec3::new(x, y, z);
                    let [a, b, c] = shear_for(dir).rows();
                    let want = [a.to_array(), b.to_array(), c.to_array()];
                    assert_eq!(bits(shear_rows(dir)), bits(want), "{dir:?}");
                    checked += 1;
                }
            }
        }
        for dir in random_directions(100_000) {
            let dir = Vec3::from(dir);
            let [a, b, c] = shear_for(dir).rows();
            let want = [a.to_array(), b.to_array(), c.to_array()];
            assert_eq!(bits(shear_rows(dir)), bits(want), "{dir:?}");
            checked += 1;
        }
        assert_eq!(checked, 17 * 17 * 17 + 100_000);
    }
}
