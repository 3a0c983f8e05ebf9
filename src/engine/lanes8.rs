//! Eight f32 lanes: the SIMD vocabulary the engine's walk is written in. One lane per child box
//! of an 8-wide node, and one per triangle of a leaf (up to eight at a time).
//!
//! [`Lanes8`] has two implementations: [`Avx`] (one 256-bit AVX register, used where the CPU
//! has AVX2, see `engine::Engine`) and [`Pair`] (two sets of four [`Lanes`]: SSE2 on x86-64,
//! plain arrays everywhere). Each operation is one IEEE-754 operation per lane, the same as the
//! scalar twin's: no fused multiply-add, no reassociation, so every path computes the bits the
//! scalar code computes.

use super::lanes::Lanes;
use super::wide::WideNode;
use crate::layout::{GpuRay, GpuTriangle};

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
    /// The first eight floats of each of eight rays, one ray a lane: `[origin x, y, z, tmin,
    /// dir x, y, z, tmax]` (`GpuRay`'s first 32 bytes), copies bit for bit. `rays` holds at
    /// least eight.
    #[inline(always)]
    fn rays(rays: &[GpuRay]) -> [Self; 8] {
        let mut columns = [[0.0f32; 8]; 8];
        for (i, r) in rays[..8].iter().enumerate() {
            let row = [
                r.origin[0],
                r.origin[1],
                r.origin[2],
                r.tmin,
                r.dir[0],
                r.dir[1],
                r.dir[2],
                r.tmax,
            ];
            for (column, value) in columns.iter_mut().zip(row) {
                column[i] = value;
            }
        }
        [
            Self::load(&columns[0]),
            Self::load(&columns[1]),
            Self::load(&columns[2]),
            Self::load(&columns[3]),
            Self::load(&columns[4]),
            Self::load(&columns[5]),
            Self::load(&columns[6]),
            Self::load(&columns[7]),
        ]
    }
    /// Bit `i` set when lane `i` of `self` and of `o` have the same bits (not `==`: 0.0 and
    /// -0.0 differ, a NaN equals its own bits).
    #[inline(always)]
    fn same_bits(self, o: Self) -> u32 {
        let (a, b) = (self.to_array(), o.to_array());
        let mut bits = 0;
        for i in 0..8 {
            bits |= u32::from(a[i].to_bits() == b[i].to_bits()) << i;
        }
        bits
    }
    /// Up to eight triangles' vertices as `[vertex][axis]` lanes, lane `i < count` from triangle
    /// `first + i` (`1 <= count <= 8`); the lanes past `count` hold copies of triangles of the
    /// range, for the caller to mask. The values are copies, bit for bit.
    fn gather(triangles: &[GpuTriangle], first: usize, count: usize) -> [[Self; 3]; 3];
    /// Writes a node's eight children in the order a walk's stack wants them, where a sorting
    /// network does it without branches, and gives the nearest child met: `out[s]` is
    /// `[child, kind | lane << 8, near's bits, at]` of the `s`-th lane (`walk::Entry`'s
    /// words; `at` is the node's index), the lanes of `met` first, farthest first; the slots
    /// after them hold copies of some lane's words, for the walk to overwrite. `None` where
    /// there is no network (the walk then sorts the lanes itself). Distances within eight
    /// representable floats of each other may come in either order: the order decides which
    /// child is visited first, never an answer.
    #[inline(always)]
    fn far_first(
        near: Self,
        met: u32,
        node: &WideNode,
        at: u32,
        out: &mut [[u32; 4]; 8],
    ) -> Option<usize> {
        let _ = (near, met, node, at, out);
        None
    }
    /// [`Lanes8::far_first`] for the single-ray walks' eight-byte entries: `out[s]` is
    /// `[child << 4 | kind & 15, near's bits]` of the `s`-th lane (`walk::Pushed`'s words), in
    /// the same order. `None` where there is no network.
    #[inline(always)]
    fn far_first_packed(
        near: Self,
        met: u32,
        node: &WideNode,
        out: &mut [[u32; 2]; 8],
    ) -> Option<usize> {
        let _ = (near, met, node, out);
        None
    }
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
    use crate::engine::wide::WideNode;
    use crate::layout::{GpuRay, GpuTriangle};
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
        /// Each ray's first 32 bytes loaded whole and the eight rows transposed: four by four
        /// within the halves, then the halves exchanged.
        #[inline(always)]
        fn rays(rays: &[GpuRay]) -> [Self; 8] {
            let rays = &rays[..8];
            // SAFETY: each load reads the first 32 bytes of a whole `GpuRay` of `rays` (48
            // bytes each).
            unsafe {
                let row = |i: usize| _mm256_loadu_ps(rays.as_ptr().add(i).cast::<f32>());
                let [a0, a1, a2, a3] = transpose_halves([row(0), row(1), row(2), row(3)]);
                let [b0, b1, b2, b3] = transpose_halves([row(4), row(5), row(6), row(7)]);
                let low = |a, b| Avx(_mm256_permute2f128_ps::<0x20>(a, b));
                let high = |a, b| Avx(_mm256_permute2f128_ps::<0x31>(a, b));
                [
                    low(a0, b0),
                    low(a1, b1),
                    low(a2, b2),
                    low(a3, b3),
                    high(a0, b0),
                    high(a1, b1),
                    high(a2, b2),
                    high(a3, b3),
                ]
            }
        }
        #[inline(always)]
        fn same_bits(self, o: Self) -> u32 {
            // SAFETY: as above.
            unsafe {
                let same =
                    _mm256_cmpeq_epi32(_mm256_castps_si256(self.0), _mm256_castps_si256(o.0));
                _mm256_movemask_ps(_mm256_castsi256_ps(same)) as u32
            }
        }
        /// Each triangle's first eight floats loaded whole, triangles `i` and `i + 4` in one
        /// register's two halves, transposed four by four within the halves; the ninth float
        /// (the third vertex's z) as the last column of floats 5..9 loaded the same way. With
        /// four triangles or fewer each half holds the same four.
        #[inline(always)]
        fn gather(triangles: &[GpuTriangle], first: usize, count: usize) -> [[Self; 3]; 3] {
            let range = &triangles[first..first + count];
            let last = count - 1;
            // SAFETY: every pointer is a whole `GpuTriangle` of `range` (nine f32, 36 bytes);
            // the loads read its floats 0..4, 4..8 and 5..9.
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
                // The ninth float: the last column of floats 5..9 (loads within the same
                // lines), three shuffles instead of eight single loads and inserts.
                let [c0, c1, c2, c3] = rows(5);
                let z2 = _mm256_shuffle_ps::<0xEE>(
                    _mm256_unpackhi_ps(c0, c1),
                    _mm256_unpackhi_ps(c2, c3),
                );
                [
                    [Avx(a0), Avx(a1), Avx(a2)],
                    [Avx(a3), Avx(b0), Avx(b1)],
                    [Avx(b2), Avx(b3), Avx(z2)],
                ]
            }
        }
        /// Each lane's key is its distance's bits mapped to an unsigned order (negative floats
        /// flipped), the low three bits replaced by the lane; lanes not met get 0 and sort
        /// last. The nearest is found apart from the sort (the smallest key met), so the next
        /// node's load need not wait for it.
        #[inline(always)]
        fn far_first(
            near: Self,
            met: u32,
            node: &WideNode,
            at: u32,
            out: &mut [[u32; 4]; 8],
        ) -> Option<usize> {
            // SAFETY: as above; the loads read `node.child` and `node.kind` whole, the stores
            // write `out` whole.
            unsafe {
                let (next, order) = far_order(near.0, met);
                let lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
                let children = _mm256_loadu_si256(node.child.as_ptr().cast());
                let kinds = _mm256_or_si256(
                    _mm256_cvtepu8_epi32(_mm_loadl_epi64(node.kind.as_ptr().cast())),
                    _mm256_slli_epi32::<8>(lanes),
                );
                let [r0, r1, r2, r3] = transpose_halves([
                    _mm256_castsi256_ps(_mm256_permutevar8x32_epi32(children, order)),
                    _mm256_castsi256_ps(_mm256_permutevar8x32_epi32(kinds, order)),
                    _mm256_permutevar8x32_ps(near.0, order),
                    _mm256_castsi256_ps(_mm256_set1_epi32(at as i32)),
                ]);
                let p = out.as_mut_ptr().cast::<f32>();
                _mm_storeu_ps(p, _mm256_castps256_ps128(r0));
                _mm_storeu_ps(p.add(4), _mm256_castps256_ps128(r1));
                _mm_storeu_ps(p.add(8), _mm256_castps256_ps128(r2));
                _mm_storeu_ps(p.add(12), _mm256_castps256_ps128(r3));
                _mm_storeu_ps(p.add(16), _mm256_extractf128_ps::<1>(r0));
                _mm_storeu_ps(p.add(20), _mm256_extractf128_ps::<1>(r1));
                _mm_storeu_ps(p.add(24), _mm256_extractf128_ps::<1>(r2));
                _mm_storeu_ps(p.add(28), _mm256_extractf128_ps::<1>(r3));
                Some(next)
            }
        }
        /// The entries as `[child << 4 | kind & 15, near]` pairs: one shift and one mask
        /// where the sixteen-byte entries take four-by-four transposes, and two stores of
        /// 32 bytes where they take eight of 16.
        #[inline(always)]
        fn far_first_packed(
            near: Self,
            met: u32,
            node: &WideNode,
            out: &mut [[u32; 2]; 8],
        ) -> Option<usize> {
            // SAFETY: as above; the loads read `node.child` and `node.kind` whole, the stores
            // write `out` whole (64 bytes).
            unsafe {
                let (next, order) = far_order(near.0, met);
                let children = _mm256_loadu_si256(node.child.as_ptr().cast());
                let kinds = _mm256_cvtepu8_epi32(_mm_loadl_epi64(node.kind.as_ptr().cast()));
                let words = _mm256_or_si256(
                    _mm256_slli_epi32::<4>(children),
                    _mm256_and_si256(kinds, _mm256_set1_epi32(15)),
                );
                let w = _mm256_permutevar8x32_epi32(words, order);
                let n = _mm256_castps_si256(_mm256_permutevar8x32_ps(near.0, order));
                // [w0 n0 w1 n1 | w4 n4 w5 n5] and [w2 n2 w3 n3 | w6 n6 w7 n7].
                let (lo, hi) = (_mm256_unpacklo_epi32(w, n), _mm256_unpackhi_epi32(w, n));
                let p = out.as_mut_ptr().cast::<__m256i>();
                _mm256_storeu_si256(p, _mm256_permute2x128_si256::<0x20>(lo, hi));
                _mm256_storeu_si256(p.add(1), _mm256_permute2x128_si256::<0x31>(lo, hi));
                Some(next)
            }
        }
    }

    /// The nearest lane met and the lanes in the order the walk's stack wants them (met lanes
    /// first, farthest first): each lane's key is its distance's bits mapped to an unsigned
    /// order (negative floats flipped), the low three bits replaced by the lane; lanes not met
    /// get 0 and sort last. The nearest is found apart from the sort (the smallest key met),
    /// so the next node's load need not wait for it.
    #[inline(always)]
    unsafe fn far_order(near: __m256, met_bits: u32) -> (usize, __m256i) {
        unsafe {
            let bits = _mm256_castps_si256(near);
            let flip = _mm256_or_si256(_mm256_srai_epi32::<31>(bits), _mm256_set1_epi32(i32::MIN));
            let lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
            let keys = _mm256_or_si256(
                _mm256_and_si256(_mm256_xor_si256(bits, flip), _mm256_set1_epi32(!7)),
                lanes,
            );
            let lane_bits = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
            let met = _mm256_cmpeq_epi32(
                _mm256_and_si256(_mm256_set1_epi32(met_bits as i32), lane_bits),
                lane_bits,
            );
            let m = _mm256_or_si256(keys, _mm256_andnot_si256(met, _mm256_set1_epi32(-1)));
            let m = _mm256_min_epu32(m, _mm256_shuffle_epi32::<0xB1>(m));
            let m = _mm256_min_epu32(m, _mm256_shuffle_epi32::<0x4E>(m));
            let m = _mm256_min_epu32(m, _mm256_permute2x128_si256::<0x01>(m, m));
            let next = (_mm256_cvtsi256_si32(m) & 7) as usize;
            let masked = _mm256_and_si256(keys, met);
            let few = FEW_MET[(met_bits & 255) as usize];
            let order = if few >> 63 == 0 {
                // Four met or fewer (nine nodes in ten on incoherent rays): the met lanes moved
                // to the first four, a lane not met after them (key 0, sorting last), and
                // those four sorted, in half the layers.
                let idx = _mm256_cvtepu8_epi32(_mm_cvtsi64_si128(few as i64));
                let k = _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(masked, idx));
                _mm256_zextsi128_si256(_mm_and_si128(sort4_descending(k), _mm_set1_epi32(7)))
            } else {
                _mm256_and_si256(sort_descending(masked), _mm256_set1_epi32(7))
            };
            (next, order)
        }
    }

    /// Per set of lanes met (a byte of lane bits) with at most four lanes: the lanes met in
    /// order, a byte each, then the first lane not met in the bytes left. Sets of more than
    /// four have the top bit set.
    static FEW_MET: [u64; 256] = {
        let mut table = [0u64; 256];
        let mut m = 0;
        while m < 256 {
            let (mut entry, mut slot, mut lane, mut unmet) = (0u64, 0, 0, 8);
            while lane < 8 {
                if m >> lane & 1 == 1 {
                    entry |= (lane as u64) << (8 * slot);
                    slot += 1;
                } else if unmet == 8 {
                    unmet = lane;
                }
                lane += 1;
            }
            if slot > 4 {
                entry = 1 << 63;
            } else {
                while slot < 8 {
                    entry |= (unmet as u64) << (8 * slot);
                    slot += 1;
                }
            }
            table[m] = entry;
            m += 1;
        }
        table
    };

    /// Sorts four u32 keys, largest first: the five-comparator network (0,1)(2,3), (0,2)(1,3),
    /// (1,2), a layer per shuffle.
    #[inline(always)]
    unsafe fn sort4_descending(mut k: __m128i) -> __m128i {
        unsafe {
            macro_rules! layer {
                ($partner:expr, $take_max:literal) => {{
                    let p = $partner;
                    k = _mm_blend_epi32::<$take_max>(_mm_min_epu32(k, p), _mm_max_epu32(k, p));
                }};
            }
            layer!(_mm_shuffle_epi32::<0xB1>(k), 0b0101);
            layer!(_mm_shuffle_epi32::<0x4E>(k), 0b0011);
            layer!(_mm_shuffle_epi32::<0xD8>(k), 0b0011);
            k
        }
    }

    /// Bitonic sort of eight u32 keys, largest first: per layer each lane meets its partner
    /// (`i ^ j`), and keeps the larger or the smaller as its block's direction says.
    #[inline(always)]
    unsafe fn sort_descending(mut k: __m256i) -> __m256i {
        unsafe {
            macro_rules! layer {
                ($partner:expr, $take_max:literal) => {{
                    let p = $partner;
                    k = _mm256_blend_epi32::<$take_max>(
                        _mm256_min_epu32(k, p),
                        _mm256_max_epu32(k, p),
                    );
                }};
            }
            layer!(_mm256_shuffle_epi32::<0xB1>(k), 0x99);
            layer!(_mm256_shuffle_epi32::<0x4E>(k), 0xC3);
            layer!(_mm256_shuffle_epi32::<0xB1>(k), 0xA5);
            layer!(_mm256_permute2x128_si256::<0x01>(k, k), 0x0F);
            layer!(_mm256_shuffle_epi32::<0x4E>(k), 0x33);
            layer!(_mm256_shuffle_epi32::<0xB1>(k), 0x55);
            k
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

    /// The AVX rays' columns and bit comparison, in a function compiled with AVX2.
    #[target_feature(enable = "avx2")]
    fn avx_rays(rays: &[GpuRay]) -> ([[f32; 8]; 8], u32, u32) {
        let c = Avx::rays(rays);
        (
            c.map(|l| l.to_array()),
            c[0].same_bits(Avx::splat(rays[0].origin[0])),
            c[3].same_bits(c[7]),
        )
    }

    #[test]
    fn avx_rays_are_the_portable_columns_bit_for_bit() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        // Distinct bits in every float, and zeros of both signs and NaNs among them.
        let rays: Vec<GpuRay> = (0..11)
            .map(|r| {
                let f = |k: usize| (r * 12 + k) as f32 * 1.5 - 40.0;
                GpuRay {
                    origin: [if r % 3 == 0 { -0.0 } else { 0.0 }, f(1), f(2)],
                    tmin: if r == 4 { f32::NAN } else { f(3) },
                    dir: [f(4), f(5), f(6)],
                    tmax: if r % 2 == 0 { f(3) } else { -0.0 },
                    mask: r as u32,
                    flags: 7,
                    origin_lo: [9, 9],
                }
            })
            .collect();
        for first in [0, 1, 3] {
            let rays = &rays[first..];
            // SAFETY: AVX2 was detected above.
            let (avx, same_origin, same_range) = unsafe { avx_rays(rays) };
            let portable = Pair::<Portable>::rays(rays);
            for (column, (a, p)) in avx.iter().zip(&portable).enumerate() {
                let p = p.to_array();
                for lane in 0..8 {
                    assert_eq!(
                        a[lane].to_bits(),
                        p[lane].to_bits(),
                        "{first} {column} {lane}"
                    );
                }
            }
            let p_origin = portable[0].same_bits(Pair::<Portable>::splat(rays[0].origin[0]));
            assert_eq!(same_origin, p_origin);
            assert_eq!(same_range, portable[3].same_bits(portable[7]));
            for (lane, r) in rays[..8].iter().enumerate() {
                let same = r.origin[0].to_bits() == rays[0].origin[0].to_bits();
                assert_eq!(same_origin >> lane & 1 == 1, same, "{first} {lane}");
                assert_eq!(
                    same_range >> lane & 1 == 1,
                    r.tmin.to_bits() == r.tmax.to_bits()
                );
            }
        }
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

    /// The AVX ordering, in a function compiled with AVX2 as the engine's walk is.
    #[target_feature(enable = "avx2")]
    fn avx_far_first(
        near: &[f32; 8],
        met: u32,
        node: &WideNode,
        at: u32,
    ) -> (Option<usize>, [[u32; 4]; 8]) {
        let mut out = [[0u32; 4]; 8];
        let next = Avx::far_first(Avx::load(near), met, node, at, &mut out);
        (next, out)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn avx_far_first_packed(
        near: &[f32; 8],
        met: u32,
        node: &WideNode,
    ) -> (Option<usize>, [[u32; 2]; 8]) {
        let mut out = [[0u32; 2]; 8];
        let next = Avx::far_first_packed(Avx::load(near), met, node, &mut out);
        (next, out)
    }

    /// A distance's sort key without its lane: the order-preserving unsigned bits, the low three
    /// cleared.
    fn bucket(x: f32) -> u32 {
        let b = x.to_bits();
        (if b >> 31 == 1 { !b } else { b | 1 << 31 }) & !7
    }

    #[test]
    fn avx_far_first_writes_the_met_children_farthest_first_and_finds_the_nearest() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg32::seed_from_u64(13);
        let mut node: WideNode = bytemuck::Zeroable::zeroed();
        for case in 0..20_000 {
            for lane in 0..8 {
                node.child[lane] = rng.random();
                node.kind[lane] = rng.random_range(0..=16);
            }
            // Distances of every kind: equal ones, neighbours, negative ones, and spread ones.
            let base: f32 = rng.random_range(-10.0..1000.0);
            let near: [f32; 8] = std::array::from_fn(|_| match rng.random_range(0..4) {
                0 => base,
                1 => f32::from_bits(base.to_bits() + rng.random_range(0..20)),
                2 => -rng.random_range(0.0..5.0f32),
                _ => rng.random_range(0.0..1e6f32),
            });
            let met: u32 = rng.random_range(1..256);
            let at: u32 = rng.random();
            // SAFETY: AVX2 was detected above.
            let (next, out) = unsafe { avx_far_first(&near, met, &node, at) };
            let n = met.count_ones() as usize;
            let lanes: Vec<usize> = out.iter().map(|row| (row[1] >> 8) as usize).collect();
            for (s, row) in out.iter().enumerate() {
                let lane = lanes[s];
                assert!(lane < 8, "case {case}");
                let want = [
                    node.child[lane],
                    u32::from(node.kind[lane]) | (lane as u32) << 8,
                    near[lane].to_bits(),
                    at,
                ];
                assert_eq!(*row, want, "case {case} slot {s}");
            }
            let mut seen = lanes[..n].to_vec();
            seen.sort_unstable();
            let want: Vec<usize> = (0..8).filter(|l| met >> l & 1 == 1).collect();
            assert_eq!(seen, want, "case {case}: the met lanes first, each once");
            for s in 1..n {
                let (a, b) = (bucket(near[lanes[s - 1]]), bucket(near[lanes[s]]));
                assert!(a >= b, "case {case}: farthest first ({near:?}, {lanes:?})");
            }
            // The nearest: the last met one written.
            assert_eq!(next, Some(lanes[n - 1]), "case {case}");
            // The packed entries: the same children in the same order, kind in four bits.
            // SAFETY: AVX2 was detected above.
            let (packed_next, packed) = unsafe { avx_far_first_packed(&near, met, &node) };
            assert_eq!(packed_next, next, "case {case}");
            for (s, (p, row)) in packed.iter().zip(&out).enumerate() {
                assert_eq!(
                    *p,
                    [row[0] << 4 | (row[1] & 15), row[2]],
                    "case {case} slot {s}"
                );
            }
        }
    }
}
