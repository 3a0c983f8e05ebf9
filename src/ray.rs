//! Pick rays in, hits out: the public records, in f64 world coordinates.

use glam::DVec3;
use serde::Serialize;

/// A pick ray in world coordinates. Points on it are `origin + t * dir`; `dir` need not be unit
/// length, and `t` scales with it (as in parry and Embree).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Start point.
    pub origin: DVec3,
    /// Direction; a zero or non-finite direction, or one too short or too long to normalize
    /// ([`direction_length`]), makes the ray invalid.
    pub dir: DVec3,
    /// Hits need `t > tmin`.
    pub tmin: f64,
    /// Hits need `t <= tmax`; `f64::INFINITY` for an unbounded ray.
    pub tmax: f64,
    /// Layer mask: the ray only hits objects whose mask shares a bit with it (default: all bits).
    pub mask: u32,
}

impl Ray {
    /// An unbounded ray from `origin` along `dir`: `t` in `(0, inf]`.
    pub fn new(origin: DVec3, dir: DVec3) -> Self {
        Self {
            origin,
            dir,
            tmin: 0.0,
            tmax: f64::INFINITY,
            mask: u32::MAX,
        }
    }

    /// The same ray with a layer mask.
    pub fn with_mask(self, mask: u32) -> Self {
        Self { mask, ..self }
    }

    /// The same ray with `t` limited to `(tmin, tmax]`.
    pub fn with_range(self, tmin: f64, tmax: f64) -> Self {
        Self { tmin, tmax, ..self }
    }

    /// The point at parameter `t`.
    pub fn at(&self, t: f64) -> DVec3 {
        self.origin + self.dir * t
    }

    /// Whether the ray can be traced: finite origin, a direction that can be normalized to
    /// finite values (see [`direction_length`]), a non-NaN range with `tmin <= tmax`. Invalid
    /// rays come back as misses flagged `invalid`.
    pub fn is_valid(&self) -> bool {
        self.origin.is_finite()
            && direction_length(self.dir).is_some()
            && !self.tmin.is_nan()
            && !self.tmax.is_nan()
            && self.tmin <= self.tmax
    }
}

/// The length of `dir`, computed without overflow or underflow, when `dir` can be normalized to
/// finite values: finite, non-zero, with a finite length whose reciprocal is finite too (a
/// length below `1 / f64::MAX`, about 5.6e-309, has none: `t` would come back infinite).
/// `None` otherwise.
pub fn direction_length(dir: DVec3) -> Option<f64> {
    if !dir.is_finite() {
        return None;
    }
    let scale = direction_scale(dir);
    if scale == 0.0 {
        return None;
    }
    let length = (dir / scale).length() * scale;
    (length.is_finite() && (1.0 / length).is_finite()).then_some(length)
}

/// What [`direction_length`] divides a finite `dir` by before squaring it: the power of two at
/// or below its largest component's magnitude, or that magnitude itself when it is below
/// `f64::MIN_POSITIVE` (zero for a zero direction). Dividing by a power of two is exact (bar
/// underflow, which division and multiplication round alike), so the scaled direction is also
/// `dir * (1 / scale)`, which is how the frame's lanes compute it (`frame::four`).
pub(crate) fn direction_scale(dir: DVec3) -> f64 {
    let max = dir.abs().max_element();
    if max >= f64::MIN_POSITIVE {
        f64::from_bits(max.to_bits() & EXPONENT_BITS)
    } else {
        max
    }
}

/// The exponent field of an f64: masking a normal number with it gives the power of two at or
/// below its magnitude.
pub(crate) const EXPONENT_BITS: u64 = 0x7ff0_0000_0000_0000;

/// The answer for one ray.
///
/// Semantics, the same on every backend:
/// - the nearest intersection with `t` in `(tmin, tmax]` wins; triangle edges and vertices are
///   inclusive, so a ray through an edge hits one of the triangles sharing it;
/// - zero-area triangles are never hit; both faces of a triangle are hit;
/// - a ray with NaN or infinite values, a zero direction (or one too short or too long to
///   normalize, [`direction_length`]) or `tmin > tmax` is a miss with `invalid` set, and never
///   hangs;
/// - a ray with layer mask 0 shares no bit with any object: it is a plain miss (not invalid);
/// - `t` is always finite: a hit whose `t` would overflow f64 is not a hit;
/// - `t`, `u`, `v`, `position` and `normal` are recomputed in f64 against the chosen triangle's
///   exact world vertices, so the position is the exact f64 intersection with that triangle.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Hit {
    /// Whether the ray hit anything.
    pub hit: bool,
    /// Whether the ray was rejected as invalid (always a miss).
    pub invalid: bool,
    /// Ray parameter of the hit (`origin + t * dir`), in the ray's own units.
    pub t: f64,
    /// Id of the object hit.
    pub object: u32,
    /// Triangle id within the object (file order).
    pub triangle: u32,
    /// Barycentric weight of the triangle's second vertex.
    pub u: f64,
    /// Barycentric weight of the triangle's third vertex.
    pub v: f64,
    /// World position of the hit.
    pub position: DVec3,
    /// Unit geometric normal, `normalize((v1 - v0) x (v2 - v0))` in world space.
    pub normal: DVec3,
    /// For a terrain grid hit: the `[row, col]` of the cell (quad) hit.
    pub cell: Option<[u32; 2]>,
    /// Ray/box tests made (the paper's b).
    pub box_tests: u32,
    /// Ray/triangle tests made (the paper's i).
    pub triangle_tests: u32,
}

impl Hit {
    /// A miss.
    pub const MISS: Hit = Hit {
        hit: false,
        invalid: false,
        t: f64::INFINITY,
        object: 0,
        triangle: 0,
        u: 0.0,
        v: 0.0,
        position: DVec3::ZERO,
        normal: DVec3::ZERO,
        cell: None,
        box_tests: 0,
        triangle_tests: 0,
    };

    /// The answer for an invalid ray.
    pub const INVALID: Hit = Hit {
        invalid: true,
        ..Hit::MISS
    };
}
