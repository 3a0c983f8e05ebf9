//! Eight f32 lanes: the SIMD vocabulary the engine's walk is written in. One lane per child box
//! of an 8-wide node, and one per triangle of a leaf (up to eight at a time).
//!
//! [`Lanes8`] has two implementations: [`Avx`] (one 256-bit AVX register, used where the CPU
//! has AVX2, see `engine::Engine`) and [`Pair`] (two sets of four [`Lanes`]: SSE2 on x86-64,
//! plain arrays everywhere). Each operation is one IEEE-754 operation per lane, the same as the
//! scalar twin's: no fused multiply-add, no reassociation, so every path computes the bits the
//! scalar code computes.

use super::lanes::Lanes;
use crate::layout::GpuTriangle;

/// Lanes per [`Lanes8`] value.
pub const LANES: usize = 8;

/// Eight f32 lanes and their masks.
pub trait Lanes8: Copy {
    /// A lane mask (all ones or all zeros per lane).
    type Mask: Copy;
    /// `x` in every lane.
    fn splat(x: f32) -> Self;
    /// The eight values, lane 0 first.
    fn load(a: &[f32; 8]) -> Self;
    /// The eight values, lane 0 first.
    fn to_array(self) -> [f32; 8];
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
    /// Up to eight triangles' vertices as `[vertex][axis]` lanes, lane `i < count` from triangle
    /// `first + i` (`1 <= count <= 8`); the lanes past `count` hold copies of triangles of the
    /// range, for the caller to mask. The values are copies, bit for bit.
    fn gather(triangles: &[GpuTriangle], first: usize, count: usize) -> [[Self; 3]; 3];
}

/// The two sets of four lanes a gather of up to eight triangles joins (lanes 0–3, 4–7). With
/// four triangles or fewer the second is the first again: its lanes are all past `count`, so
/// no triangle is read twice.
#[inline(always)]
fn halves<L: Lanes>(
    triangles: &[GpuTriangle],
    first: usize,
    count: usize,
) -> ([[L; 3]; 3], [[L; 3]; 3]) {
    let lo = L::gather(triangles, first, count.min(4));
    let hi = if count > 4 {
        L::gather(triangles, first + 4, count - 4)
    } else {
        lo
    };
    (lo, hi)
}

/// Eight lanes as two sets of four: lanes 0–3 in the first, 4–7 in the second.
#[derive(Clone, Copy, Debug)]
pub struct Pair<L>(L, L);

impl<L: Lanes> Lanes8 for Pair<L> {
    type Mask = (L::Mask, L::Mask);
    #[inline(always)]
    fn splat(x: f32) -> Self {
        Pair(L::splat(x), L::splat(x))
    }
    #[inline(always)]
    fn load(a: &[f32; 8]) -> Self {
        Pair(
            L::from_array([a[0], a[1], a[2], a[3]]),
            L::from_array([a[4], a[5], a[6], a[7]]),
        )
    }
    #[inline(always)]
    fn to_array(self) -> [f32; 8] {
        let (a, b) = (self.0.to_array(), self.1.to_array());
        [a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3]]
    }
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        Pair(self.0.add(o.0), self.1.add(o.1))
    }
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        Pair(self.0.sub(o.0), self.1.sub(o.1))
    }
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        Pair(self.0.mul(o.0), self.1.mul(o.1))
    }
    #[inline(always)]
    fn div(self, o: Self) -> Self {
        Pair(self.0.div(o.0), self.1.div(o.1))
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        Pair(self.0.min(o.0), self.1.min(o.1))
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        Pair(self.0.max(o.0), self.1.max(o.1))
    }
    #[inline(always)]
    fn abs(self) -> Self {
        Pair(self.0.abs(), self.1.abs())
    }
    #[inline(always)]
    fn lt(self, o: Self) -> Self::Mask {
        (self.0.lt(o.0), self.1.lt(o.1))
    }
    #[inline(always)]
    fn le(self, o: Self) -> Self::Mask {
        (self.0.le(o.0), self.1.le(o.1))
    }
    #[inline(always)]
    fn gt(self, o: Self) -> Self::Mask {
        (self.0.gt(o.0), self.1.gt(o.1))
    }
    #[inline(always)]
    fn ge(self, o: Self) -> Self::Mask {
        (self.0.ge(o.0), self.1.ge(o.1))
    }
    #[inline(always)]
    fn eq(self, o: Self) -> Self::Mask {
        (self.0.eq(o.0), self.1.eq(o.1))
    }
    #[inline(always)]
    fn select(m: Self::Mask, a: Self, b: Self) -> Self {
        Pair(L::select(m.0, a.0, b.0), L::select(m.1, a.1, b.1))
    }
    #[inline(always)]
    fn and(a: Self::Mask, b: Self::Mask) -> Self::Mask {
        (L::and(a.0, b.0), L::and(a.1, b.1))
    }
    #[inline(always)]
    fn or(a: Self::Mask, b: Self::Mask) -> Self::Mask {
        (L::or(a.0, b.0), L::or(a.1, b.1))
    }
    #[inline(always)]
    fn andnot(a: Self::Mask, b: Self::Mask) -> Self::Mask {
        (L::andnot(a.0, b.0), L::andnot(a.1, b.1))
    }
    #[inline(always)]
    fn bits(m: Self::Mask) -> u32 {
        L::bits(m.0) | L::bits(m.1) << 4
    }
    #[inline(always)]
    fn gather(triangles: &[GpuTriangle], first: usize, count: usize) -> [[Self; 3]; 3] {
        let (lo, hi) = halves::<L>(triangles, first, count);
        let pair = |v: usize, a: usize| Pair(lo[v][a], hi[v][a]);
        [
            [pair(0, 0), pair(0, 1), pair(0, 2)],
            [pair(1, 0), pair(1, 1), pair(1, 2)],
            [pair(2, 0), pair(2, 1), pair(2, 2)],
        ]
    }
}

#[cfg(target_arch = "x86_64")]
pub use avx::Avx;

#[cfg(target_arch = "x86_64")]
mod avx {
    use super::Lanes8;
    use crate::layout::GpuTriangle;
    use std::arch::x86_64::*;

    /// One 256-bit AVX register. Only for code compiled with AVX enabled and run where the CPU
    /// has it (the engine's AVX2 path, `engine::trace_chunk_avx2`): the methods are inlined
    /// into that code.
    #[derive(Clone, Copy, Debug)]
    pub struct Avx(__m256);

    // SAFETY (every block below): these lanes are only used inside functions compiled with AVX2
    // enabled, which run only after `Simd::Avx2` was detected (AVX2 implies AVX); the
    // intrinsics read and write their register operands, and `load` / `to_array` whole arrays.
    impl Lanes8 for Avx {
        type Mask = __m256;
        #[inline(always)]
        fn splat(x: f32) -> Self {
            unsafe { Self(_mm256_set1_ps(x)) }
        }
        #[inline(always)]
        fn load(a: &[f32; 8]) -> Self {
            unsafe { Self(_mm256_loadu_ps(a.as_ptr())) }
        }
        #[inline(always)]
        fn to_array(self) -> [f32; 8] {
            let mut out = [0.0; 8];
            unsafe { _mm256_storeu_ps(out.as_mut_ptr(), self.0) };
            out
        }
        #[inline(always)]
        fn add(self, o: Self) -> Self {
            unsafe { Self(_mm256_add_ps(self.0, o.0)) }
        }
        #[inline(always)]
        fn sub(self, o: Self) -> Self {
            unsafe { Self(_mm256_sub_ps(self.0, o.0)) }
        }
        #[inline(always)]
        fn mul(self, o: Self) -> Self {
            unsafe { Self(_mm256_mul_ps(self.0, o.0)) }
        }
        #[inline(always)]
        fn div(self, o: Self) -> Self {
            unsafe { Self(_mm256_div_ps(self.0, o.0)) }
        }
        #[inline(always)]
        fn min(self, o: Self) -> Self {
            unsafe { Self(_mm256_min_ps(self.0, o.0)) }
        }
        #[inline(always)]
        fn max(self, o: Self) -> Self {
            unsafe { Self(_mm256_max_ps(self.0, o.0)) }
        }
        #[inline(always)]
        fn abs(self) -> Self {
            unsafe { Self(_mm256_andnot_ps(_mm256_set1_ps(-0.0), self.0)) }
        }
        #[inline(always)]
        fn lt(self, o: Self) -> __m256 {
            unsafe { _mm256_cmp_ps::<_CMP_LT_OQ>(self.0, o.0) }
        }
        #[inline(always)]
        fn le(self, o: Self) -> __m256 {
            unsafe { _mm256_cmp_ps::<_CMP_LE_OQ>(self.0, o.0) }
        }
        #[inline(always)]
        fn gt(self, o: Self) -> __m256 {
            unsafe { _mm256_cmp_ps::<_CMP_GT_OQ>(self.0, o.0) }
        }
        #[inline(always)]
        fn ge(self, o: Self) -> __m256 {
            unsafe { _mm256_cmp_ps::<_CMP_GE_OQ>(self.0, o.0) }
        }
        #[inline(always)]
        fn eq(self, o: Self) -> __m256 {
            unsafe { _mm256_cmp_ps::<_CMP_EQ_OQ>(self.0, o.0) }
        }
        #[inline(always)]
        fn select(m: __m256, a: Self, b: Self) -> Self {
            unsafe { Self(_mm256_blendv_ps(b.0, a.0, m)) }
        }
        #[inline(always)]
        fn and(a: __m256, b: __m256) -> __m256 {
            unsafe { _mm256_and_ps(a, b) }
        }
        #[inline(always)]
        fn or(a: __m256, b: __m256) -> __m256 {
            unsafe { _mm256_or_ps(a, b) }
        }
        #[inline(always)]
        fn andnot(a: __m256, b: __m256) -> __m256 {
            unsafe { _mm256_andnot_ps(b, a) }
        }
        #[inline(always)]
        fn bits(m: __m256) -> u32 {
            unsafe { _mm256_movemask_ps(m) as u32 }
        }
        /// Each triangle's first eight floats loaded whole, triangles `i` and `i + 4` in one
        /// register's two halves, transposed four by four within the halves; the ninth float
        /// (the third vertex's z) lane by lane. With four triangles or fewer each half holds the
        /// same four.
        #[inline(always)]
        fn gather(triangles: &[GpuTriangle], first: usize, count: usize) -> [[Self; 3]; 3] {
            let range = &triangles[first..first + count];
            let last = count - 1;
            // SAFETY: every pointer is a whole `GpuTriangle` of `range` (nine f32, 36 bytes);
            // the loads read its floats 0..4, 4..8 and 8.
            unsafe {
                let p = |i: usize| range.as_ptr().add(last.min(i)).cast::<f32>();
                // Written out (not `array::from_fn`, which is not always inlined here).
                let row = |i: usize, offset: usize| {
                    let low = _mm_loadu_ps(p(i).add(offset));
                    let high = if count > 4 {
                        _mm_loadu_ps(p(i + 4).add(offset))
                    } else {
                        low
                    };
                    _mm256_set_m128(high, low)
                };
                let rows = |offset: usize| {
                    [
                        row(0, offset),
                        row(1, offset),
                        row(2, offset),
                        row(3, offset),
                    ]
                };
                let [a0, a1, a2, a3] = transpose_halves(rows(0));
                let [b0, b1, b2, b3] = transpose_halves(rows(4));
                let z = |i: usize| *p(i).add(8);
                let z2 = _mm256_setr_ps(z(0), z(1), z(2), z(3), z(4), z(5), z(6), z(7));
                [
                    [Avx(a0), Avx(a1), Avx(a2)],
                    [Avx(a3), Avx(b0), Avx(b1)],
                    [Avx(b2), Avx(b3), Avx(z2)],
                ]
            }
        }
    }

    /// Rows to columns within each 128-bit half: lane `j` of column `i`'s half is lane `i` of
    /// row `j`'s same half.
    #[inline(always)]
    unsafe fn transpose_halves([r0, r1, r2, r3]: [__m256; 4]) -> [__m256; 4] {
        unsafe {
            let t0 = _mm256_unpacklo_ps(r0, r1);
            let t1 = _mm256_unpacklo_ps(r2, r3);
            let t2 = _mm256_unpackhi_ps(r0, r1);
            let t3 = _mm256_unpackhi_ps(r2, r3);
            [
                _mm256_shuffle_ps::<0x44>(t0, t1),
                _mm256_shuffle_ps::<0xEE>(t0, t1),
                _mm256_shuffle_ps::<0x44>(t2, t3),
                _mm256_shuffle_ps::<0xEE>(t2, t3),
            ]
        }
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;
    use crate::engine::lanes::Portable;

    /// The AVX gather, in a function compiled with AVX2 as the engine's walk is.
    #[target_feature(enable = "avx2")]
    fn avx_gather(triangles: &[GpuTriangle], first: usize, count: usize) -> [[[f32; 8]; 3]; 3] {
        let g = Avx::gather(triangles, first, count);
        [0, 1, 2].map(|v| [0, 1, 2].map(|a| g[v][a].to_array()))
    }

    #[test]
    fn avx_gather_copies_each_lane_as_the_portable_gather_does() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        // Distinct bits in every float, so a lane or a float out of place shows.
        let triangles: Vec<GpuTriangle> = (0..20)
            .map(|t| {
                let f = |k: usize| (t * 9 + k) as f32 * 1.25 - 7.0;
                GpuTriangle {
                    v0: [f(0), f(1), f(2)],
                    v1: [f(3), f(4), f(5)],
                    v2: [f(6), f(7), f(8)],
                }
            })
            .collect();
        for first in [0, 3, 12] {
            for count in 1..=8 {
                // SAFETY: AVX2 was detected above.
                let avx = unsafe { avx_gather(&triangles, first, count) };
                let portable = Pair::<Portable>::gather(&triangles, first, count);
                for v in 0..3 {
                    for a in 0..3 {
                        let p = portable[v][a].to_array();
                        for lane in 0..8 {
                            let got = avx[v][a][lane];
                            if lane < count {
                                assert_eq!(got.to_bits(), p[lane].to_bits(), "{first} {count}");
                            } else {
                                // Past `count`: a copy of some triangle of the range.
                                let of = |t: &GpuTriangle| [t.v0, t.v1, t.v2][v][a].to_bits();
                                assert!(
                                    triangles[first..first + count]
                                        .iter()
                                        .any(|t| of(t) == got.to_bits()),
                                    "{first} {count} lane {lane}"
                                );
                            }
                        }
                    }
                }
            }
        }
    }
}
