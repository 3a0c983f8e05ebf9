//! Elevation grids (DEMs) as pickable terrain: loaders for ESRI ASCII grids, GeoTIFF and 16-bit
//! PNG heightmaps, all producing an [`ElevationGrid`], and [`grid_to_mesh`], which turns a grid
//! into a [`Mesh`](crate::Mesh) with stable, documented triangle ids.
//!
//! ```no_run
//! use std::path::Path;
//! use raypick::dem::{cell_of_triangle, grid_to_mesh, load_elevation};
//!
//! let grid = load_elevation(Path::new("tests/data/jacksboro_fault_dem_utm.asc"))?;
//! let mesh = grid_to_mesh(&grid);
//! // A hit on triangle t of this mesh lies in quad (row, col):
//! let (row, col) = cell_of_triangle(grid.ncols, 1234);
//! # let _ = (mesh, row, col);
//! # Ok::<(), raypick::Error>(())
//! ```
//!
//! Errors are [`crate::error::Error`]: [`Error::Io`] when a file cannot be read (or is not a
//! regular file) and [`Error::Parse`] (with the line for text formats) when its content is
//! malformed.
//!
//! # Sizes
//!
//! A header decides how much a loader allocates, so every size it implies is checked before
//! anything is allocated for the grid:
//!
//! - at most [`MAX_SAMPLES`] samples in all;
//! - against the file's real size: an ESRI ASCII grid reserves no more than its file can hold;
//!   a GeoTIFF's strips or tiles must lie inside the file, and a raster (GeoTIFF, PNG) must not
//!   be larger than its compression can expand the file's bytes to (×1 uncompressed, ×64
//!   PackBits, ×1032 DEFLATE, ×4096 LZW);
//! - plausibility, for compressed rasters: at most [`SAMPLES_PER_FILE_BYTE`] samples per byte of
//!   file, or [`COMPRESSED_FLOOR`] samples whatever the file's size (any grid up to 2048 × 2048).
//!   Real elevation rasters compress far less than this (the Jacksboro GeoTIFFs hold 0.5 to 0.6
//!   samples per byte), while a few kilobytes of DEFLATE zeros that claim a huge grid (a
//!   decompression bomb) are refused;
//! - the memory budget ([`crate::budget`]): 16 bytes a sample for the heights, and when a scene
//!   is loaded 48 more for the mesh.
//!
//! The compressed formats are then decoded a strip, tile or row at a time into the heights.

pub mod asc;
pub mod geotiff;
pub mod grid;
pub mod mesh;
pub mod png16;

use std::path::Path;

use crate::error::Error;

pub use asc::{load_asc, read_asc};
pub use geotiff::{load_geotiff, read_geotiff};
pub use grid::{COMPRESSED_FLOOR, ElevationGrid, MAX_SAMPLES, SAMPLES_PER_FILE_BYTE};
pub use mesh::{cell_of_triangle, grid_to_mesh};
pub use png16::{PngGrid, load_png16, read_png16};

/// Loads an elevation grid, choosing the format by the file's extension (case-insensitive):
/// `.asc` is an ESRI ASCII grid ([`load_asc`]), `.tif` / `.tiff` a GeoTIFF ([`load_geotiff`]).
///
/// PNG heightmaps carry no georeferencing, so they are not handled here: call [`load_png16`]
/// with a [`PngGrid`].
///
/// # Errors
/// [`Error::Invalid`] for any other extension (naming the file); otherwise as the loader chosen.
pub fn load_elevation(path: &Path) -> Result<ElevationGrid, Error> {
    let extension = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match extension.as_deref() {
        Some("asc") => {
            // Before opening it: a FIFO would block the open, a device never ends.
            crate::io::regular_file(path)?;
            load_asc(path)
        }
        Some("tif" | "tiff") => load_geotiff(path),
        Some("png") => Err(Error::Invalid(format!(
            "{}: a PNG heightmap has no georeferencing; load it with \
             raypick::dem::load_png16 and a PngGrid",
            path.display()
        ))),
        _ => Err(Error::Invalid(format!(
            "{}: unknown elevation grid format; expected an .asc, .tif or .tiff file",
            path.display()
        ))),
    }
}

/// An [`Error::Io`] for the file `path`.
fn io_error(path: &str, source: std::io::Error) -> Error {
    Error::Io {
        path: path.to_owned(),
        source,
    }
}

/// An [`Error::Parse`] for the file `path`, with an optional 1-based line number.
fn parse_error(path: &str, line: Option<usize>, message: impl Into<String>) -> Error {
    Error::Parse {
        path: path.to_owned(),
        line,
        message: message.into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parse_error_with_line_shows_path_line_and_message() {
        let e = parse_error("a.asc", Some(7), "bad number 'x'");
        assert_eq!(e.to_string(), "a.asc:7: bad number 'x'");
    }

    #[test]
    fn parse_error_without_line_omits_the_colon() {
        let e = parse_error("a.tif", None, "missing ModelTiepointTag (33922)");
        assert_eq!(e.to_string(), "a.tif: missing ModelTiepointTag (33922)");
    }

    #[test]
    fn io_error_shows_path_and_keeps_source() {
        let e = io_error(
            "missing.asc",
            std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
        );
        assert_eq!(e.to_string(), "missing.asc: no such file");
        assert!(std::error::Error::source(&e).is_some());
    }

    #[test]
    fn load_elevation_dispatches_on_the_extension() {
        let e = load_elevation(Path::new("/nonexistent/x.ASC")).unwrap_err();
        assert!(matches!(e, Error::Io { .. }), "{e}");
        let e = load_elevation(Path::new("/nonexistent/x.Tiff")).unwrap_err();
        assert!(matches!(e, Error::Io { .. }), "{e}");
        let e = load_elevation(Path::new("/nonexistent/x.png")).unwrap_err();
        assert!(e.to_string().contains("load_png16"), "{e}");
        for name in ["/nonexistent/x.obj", "/nonexistent/asc", "/nonexistent/x."] {
            let e = load_elevation(Path::new(name)).unwrap_err();
            assert!(matches!(e, Error::Invalid(_)), "{e}");
            assert!(e.to_string().starts_with(name), "{e}");
        }
    }
}
