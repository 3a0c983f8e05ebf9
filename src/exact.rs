//! The exact ray/triangle test: f64 Möller–Trumbore on world-space vertices. The f64 refinement
//! of every hit (`frame::resolve`) and the brute-force oracle use it; no traversal path does.

use crate::cpu::ray_triangle::TriangleHit;
use glam::DVec3;

/// Direction components this large or larger (or this small or smaller) are scaled into range
/// by [`ray_triangle_f64`] first: the test's products of a direction with two coordinates would
/// leave f64's range for a direction near its ends.
pub const SCALED_BEYOND: f64 = 1.0 / UNSCALE;

/// The power of two a direction outside the range is multiplied by, once or more.
const UNSCALE: f64 = 3.054936363499605e-151; // 2^-500

/// Whether [`ray_triangle_f64`] scales `dir` before testing (a finite direction whose largest
/// component is not in `(1 / SCALED_BEYOND, SCALED_BEYOND)`, zero aside).
#[inline]
pub fn scales(dir: DVec3) -> bool {
    let most = dir.abs().max_element();
    most.is_finite() && (most >= SCALED_BEYOND || (most > 0.0 && most <= UNSCALE))
}

/// f64 Möller–Trumbore on world-space vertices. `hit` is false when the ray is parallel to the
/// triangle's plane (or the triangle has zero area). A direction near either end of f64's range
/// ([`scales`]) is first multiplied by powers of two (exactly, but for components below the
/// others' rounding), and t multiplied back: u, v and the sign of det are the same test's.
#[inline]
pub fn ray_triangle_f64(v: [DVec3; 3], origin: DVec3, dir: DVec3) -> TriangleHit<f64> {
    if !scales(dir) {
        return test(v, origin, dir);
    }
    let (dir, scale) = rescaled(dir);
    let mut hit = test(v, origin, dir);
    hit.t *= scale;
    hit
}

/// The direction [`ray_triangle_f64`] tests `dir` with: `dir` itself, or `dir` scaled into
/// range when it [`scales`]. The oracle's sweep tests many triangles with it at once.
#[inline]
pub fn tested_direction(dir: DVec3) -> DVec3 {
    if scales(dir) { rescaled(dir).0 } else { dir }
}

/// `dir` multiplied by powers of two until its largest component is in range, and the product
/// of those powers (which t is multiplied back by).
fn rescaled(dir: DVec3) -> (DVec3, f64) {
    let (mut dir, mut scale) = (dir, 1.0);
    while dir.abs().max_element() >= SCALED_BEYOND {
        (dir, scale) = (dir * UNSCALE, scale * UNSCALE);
    }
    while dir.abs().max_element() <= UNSCALE {
        (dir, scale) = (dir * SCALED_BEYOND, scale * SCALED_BEYOND);
    }
    (dir, scale)
}

/// [`ray_triangle_f64`]'s test.
#[inline(always)]
fn test([v0, v1, v2]: [DVec3; 3], origin: DVec3, dir: DVec3) -> TriangleHit<f64> {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_power_of_two_is_two_to_the_minus_500() {
        assert_eq!(UNSCALE, 2f64.powi(-500));
        assert_eq!(SCALED_BEYOND, 2f64.powi(500));
    }

    /// A direction of 1e307 (or 1e-300) hits where a unit one does, with t in its own units:
    /// before the scaling, u overflowed and the f64 test gave up.
    #[test]
    fn directions_near_the_ends_of_f64_hit_as_unit_ones() {
        let triangle = [
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(100.0, 0.0, 0.0),
            DVec3::new(0.0, 100.0, 0.0),
        ];
        let origin = DVec3::new(33.3, 45.1, 100.0);
        let unit = ray_triangle_f64(triangle, origin, DVec3::NEG_Z);
        assert!(unit.hit && unit.t == 100.0);
        // A power of two times the unit direction: the unit test's u and v, bit for bit.
        for length in [2f64.powi(1000), 2f64.powi(-1000)] {
            let h = ray_triangle_f64(triangle, origin, DVec3::NEG_Z * length);
            assert!(h.hit && scales(DVec3::NEG_Z * length), "{length}");
            assert_eq!(
                (h.u, h.v, h.t),
                (unit.u, unit.v, unit.t / length),
                "{length}"
            );
        }
        // Other lengths: the same to rounding.
        for length in [1e307, 1e300, 1e-300] {
            let dir = DVec3::NEG_Z * length;
            assert!(scales(dir));
            let h = ray_triangle_f64(triangle, origin, dir);
            assert!(h.hit, "{length}");
            assert!((h.u - unit.u).abs() < 1e-12 && (h.v - unit.v).abs() < 1e-12);
            let position = origin + dir * h.t;
            assert!((position.z).abs() < 1e-9, "{length}: {position}");
        }
        assert!(!scales(DVec3::NEG_Z * 1e150) && !scales(DVec3::ZERO));
        // Not finite: tested as it is (scaling would never bring it into range); with a NaN
        // beside a large component, scaled and tested, and no hit either way.
        assert!(!scales(DVec3::NEG_Z * f64::INFINITY));
        for dir in [
            DVec3::NEG_Z * f64::INFINITY,
            DVec3::new(f64::NAN, 0.0, -1e300),
        ] {
            assert!(!ray_triangle_f64(triangle, origin, dir).hit);
        }
    }
}
