//! The elevation grid type every loader produces, its sample-placement
//! convention, and the size guards loaders apply before allocating (see the
//! [`dem`](super) module docs for the rules).

use glam::DVec3;

use super::parse_error;
use crate::error::Error;

/// Largest number of samples (`ncols * nrows`) a loader accepts; bigger
/// headers are refused before anything is allocated.
pub const MAX_SAMPLES: usize = 1 << 31;

/// A regular elevation grid: sample (row, col) sits at world x = x0 + col*dx, y = y0 - row*dy (row 0 is north), height heights[row*ncols+col]; None = NODATA.
///
/// `(x0, y0)` is the position of sample (0, 0), i.e. the north-west sample
/// (not the corner of a cell). Loaders guarantee `dx > 0`, `dy > 0`, finite
/// origin, `heights.len() == ncols * nrows` and finite `Some` heights.
#[derive(Debug, Clone, PartialEq)]
pub struct ElevationGrid {
    /// Number of columns (samples per row, west to east).
    pub ncols: usize,
    /// Number of rows (north to south).
    pub nrows: usize,
    /// World x of sample (0, 0).
    pub x0: f64,
    /// World y of sample (0, 0).
    pub y0: f64,
    /// Spacing between columns, in world units (positive, eastwards).
    pub dx: f64,
    /// Spacing between rows, in world units (positive, southwards).
    pub dy: f64,
    /// Row-major heights, `heights[row * ncols + col]`; `None` = NODATA.
    pub heights: Vec<Option<f64>>,
}

impl ElevationGrid {
    /// Height of sample (row, col); `None` when out of range or NODATA.
    pub fn height(&self, row: usize, col: usize) -> Option<f64> {
        if row >= self.nrows || col >= self.ncols {
            return None;
        }
        let index = row.checked_mul(self.ncols)?.checked_add(col)?;
        self.heights.get(index).copied().flatten()
    }

    /// World position of sample (row, col) with z = height; `None` when out of range or NODATA.
    pub fn sample_position(&self, row: usize, col: usize) -> Option<DVec3> {
        let z = self.height(row, col)?;
        Some(DVec3::new(
            self.x0 + col as f64 * self.dx,
            self.y0 - row as f64 * self.dy,
            z,
        ))
    }
}

/// `ncols * nrows`, or a [`Error::Parse`] naming `path` when it is zero,
/// overflows, or exceeds [`MAX_SAMPLES`].
pub(crate) fn checked_sample_count(path: &str, ncols: u64, nrows: u64) -> Result<usize, Error> {
    if ncols == 0 || nrows == 0 {
        return Err(parse_error(
            path,
            None,
            format!("empty grid ({ncols} columns x {nrows} rows)"),
        ));
    }
    let too_big = || {
        parse_error(
            path,
            None,
            format!(
                "grid of {ncols} columns x {nrows} rows is too large \
                 (more than {MAX_SAMPLES} samples); refusing to allocate it"
            ),
        )
    };
    let n = ncols.checked_mul(nrows).ok_or_else(too_big)?;
    match usize::try_from(n) {
        Ok(n) if n <= MAX_SAMPLES => Ok(n),
        _ => Err(too_big()),
    }
}

/// Samples a compressed raster (GeoTIFF, PNG) may hold per byte of its file, beyond
/// [`COMPRESSED_FLOOR`] samples.
pub const SAMPLES_PER_FILE_BYTE: u64 = 4;

/// Samples any compressed raster may hold, whatever the size of its file (a 2048 × 2048 grid).
pub const COMPRESSED_FLOOR: u64 = 1 << 22;

/// Refuses a compressed raster whose header claims more samples than its file plausibly holds:
/// more than `max(COMPRESSED_FLOOR, SAMPLES_PER_FILE_BYTE × file_bytes)`. Decompression bombs (a
/// few kilobytes of zeros that inflate to gigabytes) stop here, before anything is allocated.
pub(crate) fn check_plausible(
    path: &str,
    ncols: u64,
    nrows: u64,
    file_bytes: u64,
) -> Result<(), Error> {
    let count = ncols.saturating_mul(nrows);
    let most = COMPRESSED_FLOOR.max(SAMPLES_PER_FILE_BYTE.saturating_mul(file_bytes));
    if count <= most {
        return Ok(());
    }
    Err(parse_error(
        path,
        None,
        format!(
            "a grid of {ncols} columns x {nrows} rows ({count} samples) from a file of \
             {file_bytes} bytes is implausible: a compressed raster may hold at most \
             {SAMPLES_PER_FILE_BYTE} samples per byte of file (or {COMPRESSED_FLOOR} samples \
             in all), so {most} here; refusing to decompress it"
        ),
    ))
}

/// An empty height vector with room for `capacity` samples, checked against the memory budget
/// ([`crate::budget`], 16 bytes a sample); a [`Error::Parse`] naming `path` if the memory cannot
/// be reserved.
pub(crate) fn alloc_heights(path: &str, capacity: usize) -> Result<Vec<Option<f64>>, Error> {
    crate::budget::check(
        &format!("{path}: the grid's heights"),
        capacity as u64,
        std::mem::size_of::<Option<f64>>() as u64,
    )?;
    let mut heights = Vec::new();
    heights.try_reserve_exact(capacity).map_err(|_| {
        parse_error(
            path,
            None,
            format!("cannot allocate memory for {capacity} samples"),
        )
    })?;
    Ok(heights)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid_2x3() -> ElevationGrid {
        ElevationGrid {
            ncols: 3,
            nrows: 2,
            x0: 100.0,
            y0: 200.0,
            dx: 10.0,
            dy: 5.0,
            heights: vec![Some(1.0), Some(2.0), None, Some(4.0), Some(5.0), Some(6.0)],
        }
    }

    #[test]
    fn sample_position_follows_row_north_convention() {
        let g = grid_2x3();
        assert_eq!(g.sample_position(0, 0), Some(DVec3::new(100.0, 200.0, 1.0)));
        assert_eq!(g.sample_position(1, 2), Some(DVec3::new(120.0, 195.0, 6.0)));
    }

    #[test]
    fn nodata_and_out_of_range_give_none() {
        let g = grid_2x3();
        assert_eq!(g.sample_position(0, 2), None);
        assert_eq!(g.sample_position(2, 0), None);
        assert_eq!(g.sample_position(0, 3), None);
        assert_eq!(g.sample_position(usize::MAX, usize::MAX), None);
    }

    #[test]
    fn inconsistent_hand_built_grid_does_not_panic() {
        let mut g = grid_2x3();
        g.heights.truncate(2);
        assert_eq!(g.height(1, 1), None);
        g.ncols = usize::MAX;
        assert_eq!(g.height(1, 1), None);
    }

    #[test]
    fn sample_count_guards() {
        assert_eq!(checked_sample_count("f", 403, 344).unwrap(), 403 * 344);
        assert!(checked_sample_count("f", 0, 5).is_err());
        let e = checked_sample_count("f", 1_000_000_000_000, 1_000_000_000_000).unwrap_err();
        assert!(e.to_string().contains("too large"), "{e}");
        assert!(checked_sample_count("f", 1 << 16, (1 << 15) + 1).is_err());
        assert!(checked_sample_count("f", 1 << 16, 1 << 15).is_ok());
    }

    #[test]
    fn compressed_rasters_must_be_plausible_for_their_file_size() {
        assert!(check_plausible("f", 2048, 2048, 10).is_ok());
        assert!(check_plausible("f", 2049, 2048, 10).is_err());
        assert!(check_plausible("f", 4096, 4096, 4 << 20).is_ok());
        let e = check_plausible("f.tif", 46340, 46340, 254).unwrap_err();
        assert!(
            e.to_string().starts_with("f.tif: a grid of 46340 columns"),
            "{e}"
        );
    }

    #[test]
    fn heights_over_the_budget_are_refused_by_name() {
        let e = alloc_heights("g.asc", usize::MAX / 32).unwrap_err();
        assert!(
            e.to_string().starts_with("g.asc: the grid's heights"),
            "{e}"
        );
    }
}
