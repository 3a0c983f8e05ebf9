//! The view options of the commands that look through a camera (`render`, `select`,
//! `idbuffer`): `--camera FILE`, or without one the framing camera
//! ([`Camera::frame_bounds`]) at `--width` × `--height` pixels (default 800 × 600).

use clap::Args;
use glam::DVec3;
use raypick::apps::camera::Camera;
use raypick::{BuiltScene, Error, Query};
use std::path::PathBuf;

/// Width of the framing camera without `--camera` or `--width`.
pub const DEFAULT_WIDTH: u32 = 800;
/// Height of the framing camera without `--camera` or `--height`.
pub const DEFAULT_HEIGHT: u32 = 600;

#[derive(Args, Debug)]
pub struct CameraArgs {
    /// Camera file (JSON: perspective, orthographic or matrices); its size is the image's.
    /// Default: a perspective view from the south-south-west, 45° down, framing the whole scene.
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// Image width in pixels, without --camera [default: 800].
    #[arg(long, conflicts_with = "camera")]
    pub width: Option<u32>,
    /// Image height in pixels, without --camera [default: 600].
    #[arg(long, conflicts_with = "camera")]
    pub height: Option<u32>,
}

/// The camera file, read and checked, and the image size; the framing camera is made later,
/// once the scene's bounds are known ([`View::camera`]).
pub struct View {
    file: Option<Camera>,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
}

impl CameraArgs {
    /// Reads the camera file (if any) and checks the size: both at least 1 pixel.
    pub fn view(&self) -> Result<View, Error> {
        let file = match &self.camera {
            Some(path) => Some(Camera::from_json_file(path)?),
            None => None,
        };
        let (width, height) = match &file {
            Some(camera) => (camera.width(), camera.height()),
            None => (
                self.width.unwrap_or(DEFAULT_WIDTH),
                self.height.unwrap_or(DEFAULT_HEIGHT),
            ),
        };
        if width == 0 || height == 0 {
            return Err(Error::Invalid(format!(
                "the image is {width} x {height} pixels; --width and --height must be at least 1"
            )));
        }
        Ok(View {
            file,
            width,
            height,
        })
    }
}

impl View {
    /// The camera file's camera, or the framing camera of `built`'s scene.
    pub fn camera(self, built: &BuiltScene) -> Camera {
        self.file.unwrap_or_else(|| {
            let (min, max) = built.scene.bounds().unwrap_or((DVec3::ZERO, DVec3::ZERO));
            Camera::frame_bounds(min, max, self.width, self.height)
        })
    }
}

/// Warns, as `pick` does, when pixel rays of `camera` are invalid (every pixel of an
/// orthographic view a 10³⁰⁰ units tall, say): they are misses, and the picture or the list
/// would be empty without a word. `lattice` is `(first pixel, columns × rows, step)`, the
/// rays `Camera::pixel_center_ray_lattice` makes; counted a row at a time.
pub fn warn_invalid_rays(
    built: &BuiltScene,
    camera: &Camera,
    lattice: ((u32, u32), (u32, u32), u32),
    mask: u32,
) {
    use rayon::prelude::*;
    let ((x0, y0), (columns, rows), step) = lattice;
    let frame = built.frame();
    let invalid: usize = (0..rows)
        .into_par_iter()
        .map(|b| {
            let row =
                camera.pixel_center_ray_lattice((x0, y0 + b * step), (columns, 1), step, mask);
            row.iter()
                .filter(|r| raypick::frame::local_ray(frame, r, &Query::default()).is_none())
                .count()
        })
        .sum();
    if invalid > 0 {
        eprintln!(
            "warning: {invalid} of the view's {} pixel ray(s) were invalid (NaN or infinite \
             values, a zero direction or one too short or too long to normalize, or an origin \
             too far from the scene for single precision: is the camera's size or place right?) \
             and count as misses",
            u64::from(columns) * u64::from(rows)
        );
    }
}
