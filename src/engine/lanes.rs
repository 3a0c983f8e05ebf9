//! Four f32 lanes: the building block of the engine's eight lanes ([`super::lanes8`]), two
//! sets of four where the CPU has no AVX2.
//!
//! [`Lanes`] has two implementations: [`Sse`] (x86-64 SSE2, always present there; its gather
//! also fills the halves of the AVX lanes) and [`Portable`] (plain arrays, every target). Each
//! operation is one IEEE-754 operation per lane, the same as the scalar twin's: no fused
//! multiply-add, no reassociation, so a lane computes the bits the scalar code computes.

/// Four f32 lanes and four lane masks.
pub trait Lanes: Copy {
    /// A lane mask (all ones or all zeros per lane).
    type Mask: Copy;
    /// `x` in every lane.
    fn splat(x: f32) -> Self;
    /// The four values, lane 0 first.
    fn from_array(a: [f32; 4]) -> Self;
    /// The four values, lane 0 first.
    fn to_array(self) -> [f32; 4];
    /// Lane-wise `self + o`.
    fn add(self, o: Self) -> Self;
    /// Lane-wise `self - o`.
    fn sub(self, o: Self) -> Self;
    /// Lane-wise `self * o`.
    fn mul(self, o: Self) -> Self;
    /// Lane-wise `self / o`.
    fn div(self, o: Self) -> Self;
    /// Lane-wise minimum (the operands are never NaN where it is used).
    fn min(self, o: Self) -> Self;
    /// Lane-wise maximum (the operands are never NaN where it is used).
    fn max(self, o: Self) -> Self;
    /// Lane-wise absolute value.
    fn abs(self) -> Self;
    /// Lane-wise `self < o`.
    fn lt(self, o: Self) -> Self::Mask;
    /// Lane-wise `self <= o`.
    fn le(self, o: Self) -> Self::Mask;
    /// Lane-wise `self > o`.
    fn gt(self, o: Self) -> Self::Mask;
    /// Lane-wise `self >= o`.
    fn ge(self, o: Self) -> Self::Mask;
    /// Lane-wise `self == o`.
    fn eq(self, o: Self) -> Self::Mask;
    /// Lane-wise `m ? a : b`.
    fn select(m: Self::Mask, a: Self, b: Self) -> Self;
    /// Lane-wise and.
    fn and(a: Self::Mask, b: Self::Mask) -> Self::Mask;
    /// Lane-wise or.
    fn or(a: Self::Mask, b: Self::Mask) -> Self::Mask;
    /// Lane-wise `a & !b`.
    fn andnot(a: Self::Mask, b: Self::Mask) -> Self::Mask;
    /// Bit `i` set when lane `i` is set.
    fn bits(m: Self::Mask) -> u32;

    /// Four triangles' vertices as `[vertex][axis]` lanes, lane `i` from triangle
    /// `first + min(i, count - 1)` (the last one repeated past `count`, `1 <= count <= 4`).
    /// The values are copies, bit for bit.
    #[inline(always)]
    fn gather(triangles: &[GpuTriangle], first: usize, count: usize) -> [[Self; 3]; 3] {
        let t = four_triangles(triangles, first, count);
        let lane = |v: fn(&GpuTriangle) -> [f32; 3], a: usize| {
            Self::from_array([v(t[0])[a], v(t[1])[a], v(t[2])[a], v(t[3])[a]])
        };
        let vertex = |v: fn(&GpuTriangle) -> [f32; 3]| [lane(v, 0), lane(v, 1), lane(v, 2)];
        [vertex(|t| t.v0), vertex(|t| t.v1), vertex(|t| t.v2)]
    }
}

use crate::layout::GpuTriangle;

/// The four triangles a gather reads: `first + min(i, count - 1)` for lane `i` (written out, not
/// `array::from_fn`, which was left as an out-of-line call in the walk).
#[inline(always)]
fn four_triangles(triangles: &[GpuTriangle], first: usize, count: usize) -> [&GpuTriangle; 4] {
    let last = count - 1;
    [
        &triangles[first],
        &triangles[first + last.min(1)],
        &triangles[first + last.min(2)],
        &triangles[first + last.min(3)],
    ]
}

/// Plain arrays: the fallback for targets without SSE, and the reference the SIMD lanes must
/// match (the equivalence tests run both).
#[derive(Clone, Copy, Debug)]
pub struct Portable([f32; 4]);

#[inline(always)]
fn lanewise(a: [f32; 4], b: [f32; 4], f: impl Fn(f32, f32) -> f32) -> [f32; 4] {
    [f(a[0], b[0]), f(a[1], b[1]), f(a[2], b[2]), f(a[3], b[3])]
}

#[inline(always)]
fn compare(a: [f32; 4], b: [f32; 4], f: impl Fn(f32, f32) -> bool) -> [bool; 4] {
    [f(a[0], b[0]), f(a[1], b[1]), f(a[2], b[2]), f(a[3], b[3])]
}

impl Lanes for Portable {
    type Mask = [bool; 4];
    #[inline(always)]
    fn splat(x: f32) -> Self {
        Self([x; 4])
    }
    #[inline(always)]
    fn from_array(a: [f32; 4]) -> Self {
        Self(a)
    }
    #[inline(always)]
    fn to_array(self) -> [f32; 4] {
        self.0
    }
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        Self(lanewise(self.0, o.0, |a, b| a + b))
    }
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        Self(lanewise(self.0, o.0, |a, b| a - b))
    }
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        Self(lanewise(self.0, o.0, |a, b| a * b))
    }
    #[inline(always)]
    fn div(self, o: Self) -> Self {
        Self(lanewise(self.0, o.0, |a, b| a / b))
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        Self(lanewise(self.0, o.0, f32::min))
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        Self(lanewise(self.0, o.0, f32::max))
    }
    #[inline(always)]
    fn abs(self) -> Self {
        Self(self.0.map(f32::abs))
    }
    #[inline(always)]
    fn lt(self, o: Self) -> [bool; 4] {
        compare(self.0, o.0, |a, b| a < b)
    }
    #[inline(always)]
    fn le(self, o: Self) -> [bool; 4] {
        compare(self.0, o.0, |a, b| a <= b)
    }
    #[inline(always)]
    fn gt(self, o: Self) -> [bool; 4] {
        compare(self.0, o.0, |a, b| a > b)
    }
    #[inline(always)]
    fn ge(self, o: Self) -> [bool; 4] {
        compare(self.0, o.0, |a, b| a >= b)
    }
    #[inline(always)]
    fn eq(self, o: Self) -> [bool; 4] {
        compare(self.0, o.0, |a, b| a == b)
    }
    #[inline(always)]
    fn select(m: [bool; 4], a: Self, b: Self) -> Self {
        Self(std::array::from_fn(|i| if m[i] { a.0[i] } else { b.0[i] }))
    }
    #[inline(always)]
    fn and(a: [bool; 4], b: [bool; 4]) -> [bool; 4] {
        std::array::from_fn(|i| a[i] & b[i])
    }
    #[inline(always)]
    fn or(a: [bool; 4], b: [bool; 4]) -> [bool; 4] {
        std::array::from_fn(|i| a[i] | b[i])
    }
    #[inline(always)]
    fn andnot(a: [bool; 4], b: [bool; 4]) -> [bool; 4] {
        std::array::from_fn(|i| a[i] & !b[i])
    }
    #[inline(always)]
    fn bits(m: [bool; 4]) -> u32 {
        u32::from(m[0]) | u32::from(m[1]) << 1 | u32::from(m[2]) << 2 | u32::from(m[3]) << 3
    }
}

#[cfg(target_arch = "x86_64")]
pub use sse::Sse;

#[cfg(target_arch = "x86_64")]
mod sse {
    use super::Lanes;
    use crate::layout::GpuTriangle;
    use std::arch::x86_64::*;

    /// x86-64 SSE2 lanes (SSE2 is part of the x86-64 baseline, so no detection is needed).
    #[derive(Clone, Copy, Debug)]
    pub struct Sse(__m128);

    impl Sse {
        /// The register (for joining two into one AVX register, `engine::lanes8`).
        #[inline(always)]
        pub fn register(self) -> __m128 {
            self.0
        }
    }

    // SAFETY (every block below): SSE2 is enabled on every x86-64 target, and the intrinsics
    // only read and write their register operands.
    impl Lanes for Sse {
        type Mask = __m128;
        #[inline(always)]
        fn splat(x: f32) -> Self {
            unsafe { Self(_mm_set1_ps(x)) }
        }
        #[inline(always)]
        fn from_array(a: [f32; 4]) -> Self {
            unsafe { Self(_mm_loadu_ps(a.as_ptr())) }
        }
        #[inline(always)]
        fn to_array(self) -> [f32; 4] {
            let mut out = [0.0; 4];
            unsafe { _mm_storeu_ps(out.as_mut_ptr(), self.0) };
            out
        }
        #[inline(always)]
        fn add(self, o: Self) -> Self {
            unsafe { Self(_mm_add_ps(self.0, o.0)) }
        }
        #[inline(always)]
        fn sub(self, o: Self) -> Self {
            unsafe { Self(_mm_sub_ps(self.0, o.0)) }
        }
        #[inline(always)]
        fn mul(self, o: Self) -> Self {
            unsafe { Self(_mm_mul_ps(self.0, o.0)) }
        }
        #[inline(always)]
        fn div(self, o: Self) -> Self {
            unsafe { Self(_mm_div_ps(self.0, o.0)) }
        }
        #[inline(always)]
        fn min(self, o: Self) -> Self {
            unsafe { Self(_mm_min_ps(self.0, o.0)) }
        }
        #[inline(always)]
        fn max(self, o: Self) -> Self {
            unsafe { Self(_mm_max_ps(self.0, o.0)) }
        }
        #[inline(always)]
        fn abs(self) -> Self {
            unsafe { Self(_mm_andnot_ps(_mm_set1_ps(-0.0), self.0)) }
        }
        #[inline(always)]
        fn lt(self, o: Self) -> __m128 {
            unsafe { _mm_cmplt_ps(self.0, o.0) }
        }
        #[inline(always)]
        fn le(self, o: Self) -> __m128 {
            unsafe { _mm_cmple_ps(self.0, o.0) }
        }
        #[inline(always)]
        fn gt(self, o: Self) -> __m128 {
            unsafe { _mm_cmpgt_ps(self.0, o.0) }
        }
        #[inline(always)]
        fn ge(self, o: Self) -> __m128 {
            unsafe { _mm_cmpge_ps(self.0, o.0) }
        }
        #[inline(always)]
        fn eq(self, o: Self) -> __m128 {
            unsafe { _mm_cmpeq_ps(self.0, o.0) }
        }
        #[inline(always)]
        fn select(m: __m128, a: Self, b: Self) -> Self {
            unsafe { Self(_mm_or_ps(_mm_and_ps(m, a.0), _mm_andnot_ps(m, b.0))) }
        }
        #[inline(always)]
        fn and(a: __m128, b: __m128) -> __m128 {
            unsafe { _mm_and_ps(a, b) }
        }
        #[inline(always)]
        fn or(a: __m128, b: __m128) -> __m128 {
            unsafe { _mm_or_ps(a, b) }
        }
        #[inline(always)]
        fn andnot(a: __m128, b: __m128) -> __m128 {
            unsafe { _mm_andnot_ps(b, a) }
        }
        #[inline(always)]
        fn bits(m: __m128) -> u32 {
            unsafe { _mm_movemask_ps(m) as u32 }
        }

        /// Two unaligned 4-float loads and one scalar per triangle, then two 4 × 4 transposes:
        /// the first eight floats of the four triangles become eight lanes, the ninth (v2.z) is
        /// set directly.
        #[inline(always)]
        fn gather(triangles: &[GpuTriangle], first: usize, count: usize) -> [[Sse; 3]; 3] {
            let t = super::four_triangles(triangles, first, count);
            // SAFETY: each pointer is a whole `GpuTriangle` (nine f32, 36 bytes); the loads
            // read floats 0..4 and 4..8 of it.
            unsafe {
                let p: [*const f32; 4] = t.map(|t| (t as *const GpuTriangle).cast::<f32>());
                let a = p.map(|p| _mm_loadu_ps(p));
                let b = p.map(|p| _mm_loadu_ps(p.add(4)));
                let [a0, a1, a2, a3] = transpose(a);
                let [b0, b1, b2, b3] = transpose(b);
                let z2 = _mm_setr_ps(t[0].v2[2], t[1].v2[2], t[2].v2[2], t[3].v2[2]);
                [
                    [Sse(a0), Sse(a1), Sse(a2)],
                    [Sse(a3), Sse(b0), Sse(b1)],
                    [Sse(b2), Sse(b3), Sse(z2)],
                ]
            }
        }
    }

    /// Rows to columns: lane `j` of column `i` is lane `i` of row `j`.
    #[inline(always)]
    unsafe fn transpose([r0, r1, r2, r3]: [__m128; 4]) -> [__m128; 4] {
        unsafe {
            let t0 = _mm_unpacklo_ps(r0, r1);
            let t1 = _mm_unpacklo_ps(r2, r3);
            let t2 = _mm_unpackhi_ps(r0, r1);
            let t3 = _mm_unpackhi_ps(r2, r3);
            [
                _mm_movelh_ps(t0, t1),
                _mm_movehl_ps(t1, t0),
                _mm_movelh_ps(t2, t3),
                _mm_movehl_ps(t3, t2),
            ]
        }
    }
}
