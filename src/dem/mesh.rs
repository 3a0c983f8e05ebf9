//! Turning an [`ElevationGrid`] into a pickable [`Mesh`], and mapping hit triangle ids back to
//! grid cells. The numbering is the one [`crate::check::synthetic::terrain`] uses.
//!
//! Convention:
//! - vertex `r·ncols + c` is sample (r, c), row-major, row 0 north, at the sample's exact world
//!   position ([`ElevationGrid::sample_position`]);
//! - quad (r, c), for `r < nrows − 1`, `c < ncols − 1`, spans samples NW = (r, c),
//!   NE = (r, c+1), SW = (r+1, c), SE = (r+1, c+1) and is split along the NW–SE diagonal into
//!   triangle `2k` = (NW, SW, SE) and triangle `2k+1` = (NW, SE, NE), with
//!   `k = r·(ncols−1) + c`; so the mesh always has `2·(ncols−1)·(nrows−1)` triangles;
//! - NODATA: a quad with any NODATA corner gets two zero-area triangles `[NW, NW, NW]`, which
//!   raypick never hits, so ids of the other quads do not move. A NODATA sample still gets a
//!   vertex (unused by any hittable triangle) at its grid x, y and, as a finite placeholder
//!   height, the grid's lowest valid height (0 when the grid has none), which keeps the scene's
//!   bounds those of the real terrain.

use glam::DVec3;

use super::grid::ElevationGrid;
use crate::scene::Mesh;

/// The pickable mesh of `grid`, numbered as described in the [module docs](self).
///
/// A hand-built grid whose `heights` is shorter than `ncols·nrows` is treated as NODATA where
/// values are missing.
///
/// # Panics
/// If the grid has more than `u32::MAX` samples (loaders refuse grids over
/// [`MAX_SAMPLES`](super::MAX_SAMPLES) = 2³¹ samples, so their grids always fit).
pub fn grid_to_mesh(grid: &ElevationGrid) -> Mesh {
    let (ncols, nrows) = (grid.ncols, grid.nrows);
    let count = ncols
        .checked_mul(nrows)
        .filter(|&n| u32::try_from(n).is_ok())
        .unwrap_or_else(|| {
            panic!("grid_to_mesh: {ncols} x {nrows} samples do not fit u32 vertex indices")
        });

    let placeholder = grid
        .heights
        .iter()
        .take(count)
        .flatten()
        .copied()
        .reduce(f64::min)
        .unwrap_or(0.0);
    let mut positions = Vec::with_capacity(count);
    for r in 0..nrows {
        for c in 0..ncols {
            positions.push(grid.sample_position(r, c).unwrap_or_else(|| {
                DVec3::new(
                    grid.x0 + c as f64 * grid.dx,
                    grid.y0 - r as f64 * grid.dy,
                    placeholder,
                )
            }));
        }
    }

    let (qcols, qrows) = (ncols.saturating_sub(1), nrows.saturating_sub(1));
    let mut triangles = Vec::with_capacity(2 * qcols * qrows);
    for r in 0..qrows {
        for c in 0..qcols {
            let nw = r * ncols + c;
            let (ne, sw, se) = (nw + 1, nw + ncols, nw + ncols + 1);
            let valid = |i: usize| grid.heights.get(i).is_some_and(Option::is_some);
            // Indices fit u32: they are below `count`, checked above.
            let [nw, ne, sw, se] = [nw, ne, sw, se].map(|i| (i as u32, valid(i)));
            if nw.1 && ne.1 && sw.1 && se.1 {
                triangles.push([nw.0, sw.0, se.0]);
                triangles.push([nw.0, se.0, ne.0]);
            } else {
                triangles.push([nw.0; 3]);
                triangles.push([nw.0; 3]);
            }
        }
    }
    Mesh {
        positions,
        triangles,
    }
}

/// The quad `(row, col)` that triangle `triangle` of [`grid_to_mesh`]'s mesh belongs to, for a
/// grid `grid_ncols` samples wide: `k = triangle / 2`, `(k / (ncols−1), k % (ncols−1))`.
///
/// The quad's corners are samples (row, col), (row, col+1), (row+1, col) and (row+1, col+1);
/// an even `triangle` is the south-west half (NW, SW, SE), an odd one the north-east half
/// (NW, SE, NE).
///
/// # Panics
/// If `grid_ncols < 2`: such a grid has no quads, hence no triangles.
pub fn cell_of_triangle(grid_ncols: usize, triangle: u32) -> (usize, usize) {
    assert!(
        grid_ncols >= 2,
        "cell_of_triangle: a grid {grid_ncols} sample(s) wide has no triangles"
    );
    let k = triangle as usize / 2;
    (k / (grid_ncols - 1), k % (grid_ncols - 1))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(ncols: usize, nrows: usize, heights: Vec<Option<f64>>) -> ElevationGrid {
        ElevationGrid {
            ncols,
            nrows,
            x0: 1000.0,
            y0: 2000.0,
            dx: 10.0,
            dy: 5.0,
            heights,
        }
    }

    #[test]
    fn two_by_two_quad_is_split_along_nw_se() {
        let g = grid(2, 2, vec![Some(1.0), Some(2.0), Some(3.0), Some(4.0)]);
        let m = grid_to_mesh(&g);
        assert_eq!(
            m.positions,
            vec![
                DVec3::new(1000.0, 2000.0, 1.0),
                DVec3::new(1010.0, 2000.0, 2.0),
                DVec3::new(1000.0, 1995.0, 3.0),
                DVec3::new(1010.0, 1995.0, 4.0),
            ]
        );
        assert_eq!(m.triangles, vec![[0, 2, 3], [0, 3, 1]]);
    }

    #[test]
    fn nodata_quads_are_zero_area_and_ids_stay_put() {
        // 3 x 3 samples, the north-east corner missing: only quad (0, 1) touches it.
        let mut h: Vec<Option<f64>> = (0..9).map(|i| Some(f64::from(i) + 5.0)).collect();
        h[2] = None;
        let m = grid_to_mesh(&grid(3, 3, h));
        assert_eq!(m.triangles.len(), 8);
        assert_eq!(m.triangles[2], [1, 1, 1]);
        assert_eq!(m.triangles[3], [1, 1, 1]);
        assert_eq!(&m.triangles[..2], &[[0, 3, 4], [0, 4, 1]]);
        assert_eq!(
            &m.triangles[4..],
            &[[3, 6, 7], [3, 7, 4], [4, 7, 8], [4, 8, 5]]
        );
        // Placeholder: grid x, y and the lowest valid height.
        assert_eq!(m.positions[2], DVec3::new(1020.0, 2000.0, 5.0));
    }

    #[test]
    fn all_nodata_short_heights_and_thin_grids() {
        let m = grid_to_mesh(&grid(2, 2, vec![None; 4]));
        assert_eq!(m.triangles, vec![[0; 3], [0; 3]]);
        assert!(m.positions.iter().all(|p| p.z == 0.0));
        // A hand-built grid with too few heights: the missing ones are NODATA.
        let m = grid_to_mesh(&grid(2, 2, vec![Some(1.0), Some(1.0)]));
        assert_eq!(m.positions.len(), 4);
        assert_eq!(m.triangles, vec![[0; 3], [0; 3]]);
        let m = grid_to_mesh(&grid(5, 1, vec![Some(1.0); 5]));
        assert_eq!((m.positions.len(), m.triangles.len()), (5, 0));
    }

    #[test]
    fn cell_of_triangle_inverts_the_numbering() {
        let (ncols, nrows) = (7, 4);
        let m = grid_to_mesh(&grid(ncols, nrows, vec![Some(0.0); ncols * nrows]));
        for (t, tri) in m.triangles.iter().enumerate() {
            let (r, c) = cell_of_triangle(ncols, t as u32);
            let nw = (r * ncols + c) as u32;
            assert_eq!(tri[0], nw, "triangle {t}");
            let expected = if t % 2 == 0 {
                [nw, nw + ncols as u32, nw + ncols as u32 + 1]
            } else {
                [nw, nw + ncols as u32 + 1, nw + 1]
            };
            assert_eq!(*tri, expected, "triangle {t}");
        }
        assert_eq!(cell_of_triangle(ncols, 0), (0, 0));
        assert_eq!(cell_of_triangle(ncols, 13), (1, 0));
        assert_eq!(cell_of_triangle(ncols, 35), (2, 5));
    }

    #[test]
    #[should_panic(expected = "has no triangles")]
    fn cell_of_triangle_refuses_a_one_column_grid() {
        cell_of_triangle(1, 0);
    }
}
