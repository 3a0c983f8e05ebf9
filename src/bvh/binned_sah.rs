//! The binned surface-area-heuristic builder, an option beside median cut. Each node's
//! triangles are binned by centroid into equal-width bins per axis over the centroid bounds
//! (32, or one per triangle in smaller nodes); the split is the cheapest plane between bins on
//! all three axes under the cost model of [`super::sah_cost`]. A node of at most `leaf_size`
//! triangles stays a leaf when no split is cheaper than testing its triangles; a larger one
//! always splits. When all centroids coincide, or from [`SAH_DEPTH_LIMIT`] down, the node
//! splits at the centroid median instead. `split_axis` is not used: every axis is tried.
//!
//! The output contract is median cut's (`median_cut::build_with`: degenerate triangles left
//! out, leaf-size limit, depth-first nodes, parent links, origin), and so is the determinism:
//! bins merge per-chunk minima, maxima and counts, which are exact in any order, and parallel
//! subtrees are stitched in a fixed order, so the tree is identical on any thread count.

use super::sah_cost::{TRAVERSAL_COST, TRIANGLE_COST, half_area};
use super::top_down::{PARALLEL_MIN, PrimRef, Split, build_with, median_split, partition};
use super::{BuildOptions, Bvh};
use crate::error::Result;
use crate::scene::Scene;
use glam::{Vec3, Vec3A};
use rayon::prelude::*;

/// Most equal-width centroid bins per axis (31 candidate planes).
const BINS: usize = 32;
/// Nodes this deep split at the centroid median, which bounds the depth (and the builder's
/// recursion) on adversarial input; real scenes stay well short of it (depth 15–25).
pub const SAH_DEPTH_LIMIT: u32 = 64;
/// Triangles per chunk when a large range is binned in parallel.
const BIN_CHUNK: usize = 4096;

/// Builds a binned-SAH tree over every non-degenerate triangle of `scene`, with the same layout
/// and checks as [`Bvh::build`]; `options.split_axis` is ignored.
pub fn build(scene: &Scene, options: &BuildOptions) -> Result<Bvh> {
    build_with(scene, options, |prims, min, max, depth| {
        split(prims, min, max, depth, options)
    })
}

/// Decides the node over `prims` (box `min ..= max`): `None` keeps it a leaf; otherwise
/// partitions `prims` and returns the split axis and the size of the left part (never 0 or
/// `prims.len()`).
fn split(
    prims: &mut [PrimRef],
    min: Vec3,
    max: Vec3,
    depth: u32,
    options: &BuildOptions,
) -> Option<Split> {
    let count = prims.len();
    let plane = if depth < SAH_DEPTH_LIMIT {
        cheapest_plane(prims, min, max)
    } else {
        None
    };
    if count <= options.leaf_size as usize {
        let leaf_cost = TRIANGLE_COST as f32 * count as f32 * half_area(min, max);
        if plane.is_none_or(|p| p.cost >= leaf_cost) {
            return None;
        }
    }
    Some(match plane {
        Some(p) => {
            let (left, boxes) = partition(prims, |prim| p.binning.bin(prim, p.axis) < p.bin);
            debug_assert_eq!(left, p.left_count);
            Split {
                axis: p.axis,
                left,
                boxes: Some(boxes),
            }
        }
        None => {
            let axis = (max - min).max_position();
            Split {
                axis,
                left: median_split(prims, axis),
                boxes: None,
            }
        }
    })
}

/// The best split plane of a node: left are the bins below `bin` along `axis`.
#[derive(Clone, Copy, Debug)]
struct Plane {
    axis: usize,
    bin: usize,
    binning: Binning,
    left_count: usize,
    /// SAH cost times the node's half area A:
    /// `TRAVERSAL_COST · A + TRIANGLE_COST · (A_left · N_left + A_right · N_right)`.
    cost: f32,
}

/// Triangles binned along one axis: the box around them (SIMD-wide) and their count.
#[derive(Clone, Copy, Debug)]
struct Bin {
    min: Vec3A,
    max: Vec3A,
    count: u32,
}

impl Bin {
    const EMPTY: Bin = Bin {
        min: Vec3A::INFINITY,
        max: Vec3A::NEG_INFINITY,
        count: 0,
    };

    fn add(&mut self, min: Vec3A, max: Vec3A) {
        self.min = self.min.min(min);
        self.max = self.max.max(max);
        self.count += 1;
    }

    fn half_area(&self) -> f32 {
        half_area(self.min.into(), self.max.into())
    }

    fn merge(self, other: Bin) -> Bin {
        Bin {
            min: self.min.min(other.min),
            max: self.max.max(other.max),
            count: self.count + other.count,
        }
    }
}

/// Bins per axis (only the first `Binning::count` are used).
type Bins = [[Bin; BINS]; 3];

/// How centroids map to bins: `count` equal-width bins per axis over the centroid bounds.
#[derive(Clone, Copy, Debug)]
struct Binning {
    centroid_min: Vec3,
    /// Bins per unit of length on each axis (0 on an axis where all centroids coincide).
    scale: Vec3,
    count: usize,
}

impl Binning {
    /// `count` bins (at least 2) over the centroid bounds `min ..= max`.
    fn new(min: Vec3, max: Vec3, count: usize) -> Binning {
        let extent = max - min;
        let scale = Vec3::select(
            extent.cmpgt(Vec3::ZERO),
            Vec3::splat(count as f32) / extent,
            Vec3::ZERO,
        );
        Binning {
            centroid_min: min,
            scale,
            count,
        }
    }

    /// The bin of `prim`'s centroid along `axis`. Any value (even a scale of infinity over a
    /// vanishing extent) maps to a valid bin, and binning and partitioning call this same code,
    /// so their counts agree.
    fn bin(&self, prim: &PrimRef, axis: usize) -> usize {
        let offset = (prim.centroid[axis] - self.centroid_min[axis]) * self.scale[axis];
        (offset as usize).min(self.count - 1)
    }
}

/// The cheapest plane between bins over all axes, ties going to the lower axis and plane;
/// `None` when all centroids coincide.
fn cheapest_plane(prims: &[PrimRef], min: Vec3, max: Vec3) -> Option<Plane> {
    let parallel = prims.len() >= PARALLEL_MIN;
    let (centroid_min, centroid_max) = centroid_bounds(prims, parallel);
    let extent = centroid_max - centroid_min;
    if extent.max_element() <= 0.0 {
        return None;
    }
    // Nodes under 32 triangles get one bin per triangle: as good there, and cheaper.
    let binning = Binning::new(centroid_min, centroid_max, prims.len().min(BINS));
    let bins = if parallel {
        prims
            .par_chunks(BIN_CHUNK)
            .map(|chunk| bin_all(chunk, &binning))
            .reduce(|| [[Bin::EMPTY; BINS]; 3], merge_bins)
    } else {
        bin_all(prims, &binning)
    };
    let planes = binning.count;
    let traversal = TRAVERSAL_COST as f32 * half_area(min, max);
    let mut best: Option<Plane> = None;
    for axis in (0..3).filter(|&a| extent[a] > 0.0) {
        let axis_bins = &bins[axis];
        // Right-side area · count for the plane before each bin, swept from the right.
        let mut right_cost = [0.0f32; BINS];
        let mut right = Bin::EMPTY;
        for b in (1..planes).rev() {
            right = right.merge(axis_bins[b]);
            right_cost[b] = right.half_area() * right.count as f32;
        }
        let mut left = Bin::EMPTY;
        for b in 1..planes {
            left = left.merge(axis_bins[b - 1]);
            let right_count = prims.len() - left.count as usize;
            if left.count == 0 || right_count == 0 {
                continue;
            }
            let cost = traversal
                + TRIANGLE_COST as f32 * (left.half_area() * left.count as f32 + right_cost[b]);
            if best.is_none_or(|p| cost < p.cost) {
                best = Some(Plane {
                    axis,
                    bin: b,
                    binning,
                    left_count: left.count as usize,
                    cost,
                });
            }
        }
    }
    best
}

/// The box around the centroids of `prims`.
fn centroid_bounds(prims: &[PrimRef], parallel: bool) -> (Vec3, Vec3) {
    let grow = |(lo, hi): (Vec3, Vec3), p: &PrimRef| (lo.min(p.centroid), hi.max(p.centroid));
    let empty = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    if parallel {
        prims
            .par_chunks(BIN_CHUNK)
            .map(|chunk| chunk.iter().fold(empty, grow))
            .reduce(|| empty, |a, b| (a.0.min(b.0), a.1.max(b.1)))
    } else {
        prims.iter().fold(empty, grow)
    }
}

/// Bins `prims` along all three axes at once.
fn bin_all(prims: &[PrimRef], binning: &Binning) -> Bins {
    let mut bins = [[Bin::EMPTY; BINS]; 3];
    for prim in prims {
        let (min, max) = (Vec3A::from(prim.min), Vec3A::from(prim.max));
        for (axis, axis_bins) in bins.iter_mut().enumerate() {
            axis_bins[binning.bin(prim, axis)].add(min, max);
        }
    }
    bins
}

fn merge_bins(mut a: Bins, b: Bins) -> Bins {
    for (axis_a, axis_b) in a.iter_mut().zip(&b) {
        for (bin_a, bin_b) in axis_a.iter_mut().zip(axis_b) {
            *bin_a = bin_a.merge(*bin_b);
        }
    }
    a
}
