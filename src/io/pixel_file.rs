//! Pixel files: one `x y` pixel index per line (the number-line format of the ray files), read
//! as pixel-centre coordinates for `camera::Camera::pixel_ray`.

use super::ray_file::{parse_number_lines, read_text};
use crate::error::{Error, Result};
use std::path::Path;

/// Parses the text of a pixel list file of pixel *indices*, returning the pixel-space coordinates
/// of their centres, ready for [`crate::apps::camera::Camera::pixel_ray`]; `path` is only used in error messages.
///
/// Each line holds `x y`: column `x` from the left and row `y` from the top. Integers name whole
/// pixels, and each value comes back with 0.5 added: the line `3 4` means pixel (3, 4) and gives
/// `(3.5, 4.5)`, its centre. Fractional values are allowed and are offsets from that centre
/// (`3.25 4` gives `(3.75, 4.5)`, a quarter pixel right of pixel (3, 4)'s centre). Numbers are
/// whitespace separated, `#` starts a comment anywhere on a line, and blank lines are skipped.
///
/// A line with other than 2 numbers, a token that is not a number, or a non-finite value is an
/// [`Error::Parse`] naming `path` and the 1-based line.
pub fn parse_pixel_indices_as_centers(path: &str, text: &str) -> Result<Vec<(f64, f64)>> {
    let lines = parse_number_lines(path, text, &[2], "2 numbers (pixel column x and row y)")?;
    lines
        .into_iter()
        .map(|(line, v)| match v.iter().find(|x| !x.is_finite()) {
            Some(bad) => Err(Error::Parse {
                path: path.to_owned(),
                line: Some(line),
                message: format!(
                    "a pixel coordinate is not a finite number ({bad}: one past f64's range, inf \
                     or NaN)"
                ),
            }),
            None => Ok((v[0] + 0.5, v[1] + 0.5)),
        })
        .collect()
}

/// Reads the pixel list file at `path` and returns its pixels' centres in pixel space (see
/// [`parse_pixel_indices_as_centers`]: the line `i j` gives `(i + 0.5, j + 0.5)`).
pub fn load_pixel_indices_as_centers(path: impl AsRef<Path>) -> Result<Vec<(f64, f64)>> {
    let name = path.as_ref().display().to_string();
    let text = read_text(path.as_ref())?;
    parse_pixel_indices_as_centers(&name, &text)
}
