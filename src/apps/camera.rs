//! Cameras: turning image pixels into world pick [`Ray`]s, in f64 throughout.
//!
//! This module owns the camera models (perspective, orthographic, and explicit view/projection
//! matrices), their JSON camera files, the default "frame the whole scene" camera, and pixel list
//! files.
//!
//! # Pixel coordinates
//!
//! Every function here uses the same pixel space: `x` grows to the right from the image's left
//! edge and `y` grows *down* from its top edge, in pixels. The image covers
//! `[0, width] x [0, height]`: `(0, 0)` is the top-left corner of the top-left pixel, and the
//! centre of pixel `(i, j)` (column `i`, row `j`) is `(i + 0.5, j + 0.5)`. Coordinates may be
//! fractional, and may lie outside the image (the rays then lie outside the view).
//!
//! # Camera files
//!
//! A camera file is a JSON object with exactly one of these keys (vectors are `[x, y, z]`):
//!
//! ```json
//! {"perspective":  {"eye": [0, -10, 5], "target": [0, 0, 0], "up": [0, 0, 1],
//!                   "fov_y_deg": 45, "width": 800, "height": 600}}
//! {"orthographic": {"eye": [0, -10, 5], "target": [0, 0, 0], "up": [0, 0, 1],
//!                   "view_height": 100.0, "width": 800, "height": 600}}
//! {"matrices":     {"view": [16 numbers], "projection": [16 numbers],
//!                   "width": 800, "height": 600}}
//! ```
//!
//! Matrices are column-major 4x4 (glam / OpenGL order: the first four numbers are the first
//! column), right-handed, with the camera looking down its view space's `-z`.

use std::path::Path;

use glam::{DMat3, DMat4, DVec3, DVec4};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::io::output::csv_number;
use crate::ray::Ray;

/// A camera as written in a camera file or given to [`Camera::from_spec`]: the user's numbers,
/// not yet checked. Serializes as `{"perspective": {...}}`, `{"orthographic": {...}}` or
/// `{"matrices": {...}}`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum CameraSpec {
    /// A pinhole camera: all rays start at `eye`.
    Perspective {
        /// The centre of projection, in world coordinates.
        eye: DVec3,
        /// A world point the camera looks at; the image centre's ray passes through it.
        target: DVec3,
        /// Which way is up; need not be unit length or perpendicular to the view direction, but
        /// must not be parallel to it.
        up: DVec3,
        /// Vertical field of view in degrees, strictly between 0 and 180; the horizontal field
        /// follows from the image's aspect ratio (square pixels).
        fov_y_deg: f64,
        /// Image width in pixels (at least 1).
        width: u32,
        /// Image height in pixels (at least 1).
        height: u32,
    },
    /// A parallel projection: all rays share the view direction and start on the plane through
    /// `eye` perpendicular to it.
    Orthographic {
        /// A point on the plane rays start from: the image centre's ray starts here.
        eye: DVec3,
        /// A world point the camera looks at; the image centre's ray passes through it.
        target: DVec3,
        /// Which way is up; must not be parallel to the view direction.
        up: DVec3,
        /// Height of the view volume in world units (the image's top edge to its bottom edge);
        /// its width is `view_height * width / height` (square pixels).
        view_height: f64,
        /// Image width in pixels (at least 1).
        width: u32,
        /// Image height in pixels (at least 1).
        height: u32,
    },
    /// Explicit view and projection matrices, as a renderer uses them: see
    /// [`Camera::from_matrices`] for what is accepted.
    Matrices {
        /// World to view space, column-major; its last row must be `(0, 0, 0, 1)`.
        view: DMat4,
        /// View space to clip space, column-major.
        projection: DMat4,
        /// Image width in pixels (at least 1).
        width: u32,
        /// Image height in pixels (at least 1).
        height: u32,
    },
}

/// A checked camera that maps pixels to world rays. Build one with [`Camera::perspective`],
/// [`Camera::orthographic`], [`Camera::from_matrices`], [`Camera::from_spec`],
/// [`Camera::from_json_file`] or [`Camera::frame_bounds`]; every constructor rejects degenerate
/// cameras, so every camera maps every finite pixel coordinate to a valid ray.
///
/// Serializes as its [`CameraSpec`], and deserializing checks it like [`Camera::from_spec`].
/// Numbers read back bit for bit: this crate enables serde_json's `float_roundtrip`
/// (`tests/suite/camera.rs` holds it to that).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(into = "CameraSpec", try_from = "CameraSpec")]
pub struct Camera {
    spec: CameraSpec,
    model: Model,
}

/// Precomputed geometry behind a [`Camera`].
#[derive(Clone, Copy, Debug, PartialEq)]
enum Model {
    /// Pinhole: `dir = forward + right * sx * half_w + up * sy * half_h`, from `eye`.
    Perspective { eye: DVec3, basis: Basis },
    /// Parallel: from `eye + right * sx * half_w + up * sy * half_h`, along `forward`.
    Orthographic { eye: DVec3, basis: Basis },
    /// Unprojection through the inverse matrices.
    Matrices {
        view_inv: DMat4,
        projection_inv: DMat4,
    },
}

/// An orthonormal camera frame and the half extents of the image at unit distance (perspective)
/// or in world units (orthographic).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Basis {
    forward: DVec3,
    right: DVec3,
    up: DVec3,
    half_w: f64,
    half_h: f64,
}

/// Vertical field of view of [`Camera::frame_bounds`] cameras, in degrees.
pub const FRAME_FOV_Y_DEG: f64 = 45.0;

/// The longest camera file read: a camera is a few hundred bytes of JSON.
pub const MAX_CAMERA_FILE_BYTES: u64 = 1 << 20;
/// How far [`Camera::frame_bounds`] cameras look down: the view direction's angle below the
/// horizontal, in degrees.
pub const FRAME_ELEVATION_DEG: f64 = 45.0;
/// Where [`Camera::frame_bounds`] cameras stand: the compass angle of the eye as seen from the
/// box centre, in degrees from south (`-y`) towards west (`-x`); the camera looks the opposite
/// way (north-north-east for 30).
pub const FRAME_AZIMUTH_DEG: f64 = 30.0;

impl Camera {
    /// A checked perspective camera; see [`CameraSpec::Perspective`] for the parameters.
    pub fn perspective(
        eye: DVec3,
        target: DVec3,
        up: DVec3,
        fov_y_deg: f64,
        width: u32,
        height: u32,
    ) -> Result<Camera> {
        Self::from_spec(CameraSpec::Perspective {
            eye,
            target,
            up,
            fov_y_deg,
            width,
            height,
        })
    }

    /// A checked orthographic camera; see [`CameraSpec::Orthographic`] for the parameters.
    pub fn orthographic(
        eye: DVec3,
        target: DVec3,
        up: DVec3,
        view_height: f64,
        width: u32,
        height: u32,
    ) -> Result<Camera> {
        Self::from_spec(CameraSpec::Orthographic {
            eye,
            target,
            up,
            view_height,
            width,
            height,
        })
    }

    /// A camera from a renderer's view and projection matrices: column-major, right-handed, the
    /// camera looking down view-space `-z`, NDC `y` up. glam builds these with
    /// `glam::dcamera::rh::view::look_at_mat4` and `glam::dcamera::rh::proj::{opengl, directx}`
    /// (called `DMat4::look_at_rh`, `DMat4::perspective_rh_gl` and so on before glam 0.34).
    ///
    /// Pixel `(x, y)` is the NDC point `(2x/width - 1, 1 - 2y/height)`, and its ray is the line of
    /// world points that the matrices project there: two of its points are unprojected through
    /// `(projection * view)^-1`, applied as `view^-1 * projection^-1` so the large translations
    /// of world coordinates never mix with the projection's scales. The two points are taken at
    /// NDC depths 0.5 and 1 in homogeneous coordinates, so both clip z conventions are accepted
    /// without being told which: `[-1, 1]` (OpenGL, glam's `opengl`) and `[0, 1]` (wgpu,
    /// Direct3D, glam's `directx`), as are reversed depth and an infinite far plane. A Y-down
    /// projection (glam's `vulkan`) gives an image upside down. Rays point away from the
    /// camera (towards view-space `-z`) and start where the line crosses the view-space plane
    /// `z = 0`: at the eye for a perspective projection, on the plane through the eye facing
    /// the view direction for an orthographic one. Directions are unit length.
    ///
    /// Fails if a number is not finite, the view matrix is singular or its last row is not
    /// `(0, 0, 0, 1)`, the projection is singular, or the projection maps the image's centre or
    /// corners to no usable line of sight.
    pub fn from_matrices(
        view: DMat4,
        projection: DMat4,
        width: u32,
        height: u32,
    ) -> Result<Camera> {
        Self::from_spec(CameraSpec::Matrices {
            view,
            projection,
            width,
            height,
        })
    }

    /// Checks `spec` and precomputes its geometry. Errors are [`Error::Invalid`] sentences saying
    /// what is wrong: a zero width or height, a non-finite number, `eye == target`, `up` zero or
    /// parallel to the view direction, a field of view outside `(0, 180)` degrees, a view height
    /// that is not positive, or singular matrices.
    pub fn from_spec(spec: CameraSpec) -> Result<Camera> {
        let invalid = |message: String| Err(Error::Invalid(format!("invalid camera: {message}")));
        let (width, height) = spec.size();
        if width == 0 || height == 0 {
            return invalid(format!(
                "the image is {width} x {height} pixels; width and height must be at least 1"
            ));
        }
        let aspect = f64::from(width) / f64::from(height);
        let model = match spec {
            CameraSpec::Perspective {
                eye,
                target,
                up,
                fov_y_deg,
                ..
            } => {
                if !(fov_y_deg.is_finite() && fov_y_deg > 0.0 && fov_y_deg < 180.0) {
                    return invalid(format!(
                        "fov_y_deg is {}; the vertical field of view must be strictly \
                         between 0 and 180 degrees",
                        csv_number(fov_y_deg)
                    ));
                }
                let half_h = (fov_y_deg.to_radians() * 0.5).tan();
                let basis = match Basis::new(eye, target, up, half_h, aspect) {
                    Ok(basis) => basis,
                    Err(message) => return invalid(message),
                };
                Model::Perspective { eye, basis }
            }
            CameraSpec::Orthographic {
                eye,
                target,
                up,
                view_height,
                ..
            } => {
                if !(view_height.is_finite() && view_height > 0.0) {
                    return invalid(format!(
                        "view_height is {}; the height of the orthographic view \
                         volume must be a positive, finite number of world units",
                        csv_number(view_height)
                    ));
                }
                let basis = match Basis::new(eye, target, up, view_height * 0.5, aspect) {
                    Ok(basis) => basis,
                    Err(message) => return invalid(message),
                };
                Model::Orthographic { eye, basis }
            }
            CameraSpec::Matrices {
                view, projection, ..
            } => match matrices_model(view, projection) {
                Ok(model) => model,
                Err(message) => return invalid(message),
            },
        };
        let camera = Camera { spec, model };
        // The image centre and corners must give usable rays (this catches overflow in the
        // precomputed numbers, and projections that map pixels to no line of sight).
        let (w, h) = (f64::from(width), f64::from(height));
        for (x, y) in [(0.5 * w, 0.5 * h), (0.0, 0.0), (w, 0.0), (0.0, h), (w, h)] {
            if !camera.pixel_ray(x, y).is_valid() {
                return invalid(format!(
                    "pixel coordinate ({x}, {y}) gets no usable ray (the numbers overflow, or \
                     the projection maps it to no line of sight)"
                ));
            }
        }
        // Neighbouring pixels must look along different lines: a view narrower than double
        // precision resolves (`fov_y_deg` 1e-300, a `view_height` far below the eye's
        // coordinates) gave every pixel the same ray.
        let centre = camera.pixel_ray(0.5 * w, 0.5 * h);
        for (x, y) in [(0.5 * w + 1.0, 0.5 * h), (0.5 * w, 0.5 * h + 1.0)] {
            let next = camera.pixel_ray(x, y);
            if (next.origin, next.dir) == (centre.origin, centre.dir) {
                return invalid(
                    "neighbouring pixels get the same ray: the view is narrower than double \
                     precision resolves here (a smaller field of view or view height than its \
                     eye's coordinates allow)"
                        .to_string(),
                );
            }
        }
        Ok(camera)
    }

    /// The numbers this camera was built from.
    pub fn spec(&self) -> &CameraSpec {
        &self.spec
    }

    /// Image width in pixels.
    pub fn width(&self) -> u32 {
        self.spec.size().0
    }

    /// Image height in pixels.
    pub fn height(&self) -> u32 {
        self.spec.size().1
    }

    /// Of the pixel `centres` (continuous image coordinates, as [`Camera::pixel_ray`] takes
    /// them), how many lie outside the image, and the first of them (its index); `None` when
    /// all lie inside (edges included). What the command line and Python warn about: a pixel
    /// file made for another image size gives picks the user did not mean.
    pub fn outside_image(
        &self,
        centres: impl IntoIterator<Item = (f64, f64)>,
    ) -> Option<(usize, usize)> {
        let (w, h) = (f64::from(self.width()), f64::from(self.height()));
        let mut found: Option<(usize, usize)> = None;
        for (k, (x, y)) in centres.into_iter().enumerate() {
            if !(0.0..=w).contains(&x) || !(0.0..=h).contains(&y) {
                let (count, first) = found.unwrap_or((0, k));
                found = Some((count + 1, first));
            }
        }
        found
    }

    /// The world ray through pixel-space point `(x, y)`: `x` in pixels right of the image's left
    /// edge, `y` in pixels *down* from its top edge, so the centre of pixel `(i, j)` is
    /// `(i + 0.5, j + 0.5)` and `(width / 2, height / 2)` is the image centre (see
    /// [`Camera::pixel_center_ray`] for whole pixels).
    ///
    /// The direction is unit length, so the hit's `t` is a distance in world units; `t` runs over
    /// `(0, inf]`. Perspective rays start at the eye; orthographic rays start on the plane through
    /// the eye perpendicular to the view direction and are all parallel to it. Points outside the
    /// image give rays outside the view; a NaN or infinite coordinate gives a ray that
    /// [`Ray::is_valid`] rejects (the pickers report it as invalid), never a panic.
    pub fn pixel_ray(&self, x: f64, y: f64) -> Ray {
        let (w, h) = (f64::from(self.width()), f64::from(self.height()));
        // Normalized image coordinates: -1 at the left/bottom edge, +1 at the right/top edge.
        // `2x - w` is exact for pixel centres, so mirrored pixels get exactly mirrored values.
        let sx = (2.0 * x - w) / w;
        let sy = (h - 2.0 * y) / h;
        match &self.model {
            Model::Perspective { eye, basis } => Ray::new(*eye, unit(basis.offset(sx, sy))),
            Model::Orthographic { eye, basis } => {
                Ray::new(*eye + basis.lateral(sx, sy), basis.forward)
            }
            Model::Matrices {
                view_inv,
                projection_inv,
            } => {
                let (origin, dir) = unproject(projection_inv, sx, sy);
                Ray::new(
                    view_inv.transform_point3(origin),
                    unit(view_inv.transform_vector3(dir)),
                )
            }
        }
    }

    /// The world ray through the centre of pixel `(i, j)` (column `i` from the left, row `j` from
    /// the top): `pixel_ray(i + 0.5, j + 0.5)`.
    pub fn pixel_center_ray(&self, i: u32, j: u32) -> Ray {
        self.pixel_ray(f64::from(i) + 0.5, f64::from(j) + 0.5)
    }

    /// The rays through every pixel centre, row by row from the top row, each row left to right
    /// (`width * height` rays; pixel `(i, j)` is item `j * width + i`).
    pub fn pixel_center_rays(&self) -> impl Iterator<Item = Ray> + '_ {
        (0..self.height())
            .flat_map(move |j| (0..self.width()).map(move |i| self.pixel_center_ray(i, j)))
    }

    /// [`Camera::pixel_center_rays`] with layer mask `mask`, made on all cores (rayon) into one
    /// vector: what `render` and `idbuffer` trace. A ray costs tens of nanoseconds
    /// to make (two divisions and a normalisation in f64), so for a 1000 × 1000 view one core
    /// took about as long as the engine's pick of the rays on two (BENCHMARKS.md).
    pub fn pixel_center_ray_batch(&self, mask: u32) -> Vec<Ray> {
        self.pixel_center_ray_lattice((0, 0), (self.width(), self.height()), 1, mask)
    }

    /// The rays through the centres of `columns × rows` pixels `step` apart from pixel
    /// `(x0, y0)`, row by row (item `b * columns + a` is pixel `(x0 + a * step, y0 + b *
    /// step)`), with layer mask `mask`, made on all cores: a marquee's rays
    /// ([`super::select::marquee`]), or the whole view's ([`Camera::pixel_center_ray_batch`]).
    /// The pixels' coordinates must fit `u32` (the callers' rectangles lie in the view).
    pub fn pixel_center_ray_lattice(
        &self,
        (x0, y0): (u32, u32),
        (columns, rows): (u32, u32),
        step: u32,
        mask: u32,
    ) -> Vec<Ray> {
        use rayon::prelude::*;
        let columns = columns as usize;
        (0..columns * rows as usize)
            .into_par_iter()
            .with_min_len(4096)
            .map(|k| {
                let (a, b) = ((k % columns) as u32, (k / columns) as u32);
                self.pixel_center_ray(x0 + a * step, y0 + b * step)
                    .with_mask(mask)
            })
            .collect()
    }

    /// A perspective camera that shows the whole axis-aligned box `[min, max]`, looking down at
    /// it from above at an oblique angle with `z` up: the eye stands [`FRAME_AZIMUTH_DEG`] west of
    /// south of the box centre, [`FRAME_ELEVATION_DEG`] above it, and aims at the centre with a
    /// [`FRAME_FOV_Y_DEG`] vertical field of view, just far enough away that the box's bounding
    /// sphere fits in both the vertical and horizontal fields of view. Meant for commands that are
    /// given no camera; `min`/`max` are typically [`crate::Scene::bounds`].
    ///
    /// Never fails: a width or height of 0 is taken as 1; a box with a non-finite corner or
    /// `min > max` on some axis is replaced by the unit cube around the origin; a box of (nearly)
    /// zero size is framed as a sphere of radius `max(1, 1e-6 * |centre|)`.
    pub fn frame_bounds(min: DVec3, max: DVec3, width: u32, height: u32) -> Camera {
        let (width, height) = (width.max(1), height.max(1));
        let usable = min.is_finite() && max.is_finite() && min.cmple(max).all();
        let (min, max) = if usable {
            (min, max)
        } else {
            (DVec3::splat(-0.5), DVec3::splat(0.5))
        };
        // Halves first, so extreme boxes do not overflow.
        let center = min * 0.5 + max * 0.5;
        let scale = center.abs().max_element().max(1.0);
        let mut radius = (max * 0.5 - min * 0.5).length();
        if radius.is_nan() || radius <= 1e-9 * scale {
            radius = (1e-6 * scale).max(1.0);
        }
        let half_y = FRAME_FOV_Y_DEG.to_radians() * 0.5;
        let aspect = f64::from(width) / f64::from(height);
        let half_x = (half_y.tan() * aspect).atan();
        let distance = radius / half_y.min(half_x).sin();
        let (el, az) = (
            FRAME_ELEVATION_DEG.to_radians(),
            FRAME_AZIMUTH_DEG.to_radians(),
        );
        let toward_eye = DVec3::new(-az.sin() * el.cos(), -az.cos() * el.cos(), el.sin());
        let eye = center + toward_eye * distance;
        Self::perspective(eye, center, DVec3::Z, FRAME_FOV_Y_DEG, width, height).unwrap_or_else(
            |_| {
                // Only reachable for boxes so large that the eye overflows: frame the unit cube.
                let spec = CameraSpec::Perspective {
                    eye: toward_eye * 2.0,
                    target: DVec3::ZERO,
                    up: DVec3::Z,
                    fov_y_deg: FRAME_FOV_Y_DEG,
                    width,
                    height,
                };
                let half_h = half_y.tan();
                let forward = -toward_eye;
                let right = unit(forward.cross(DVec3::Z));
                let basis = Basis {
                    forward,
                    right,
                    up: right.cross(forward),
                    half_w: half_h * aspect,
                    half_h,
                };
                Camera {
                    spec,
                    model: Model::Perspective {
                        eye: toward_eye * 2.0,
                        basis,
                    },
                }
            },
        )
    }

    /// A perspective camera looking straight down (`-z`) on the axis-aligned box `[min, max]`,
    /// north (`+y`) at the top of the image and east (`+x`) on the right, with a
    /// [`FRAME_FOV_Y_DEG`] vertical field of view: the eye stands above the centre of the box,
    /// just high enough that the box's bottom face fills the image (its longer side edge to
    /// edge), and always above the box's top. A map view: on a terrain nearly every pixel sees
    /// the ground, and row 0 of the image is the northern edge. `raypick pick` traces its
    /// default 8 × 8 grid through it.
    ///
    /// Never fails: a width or height of 0 is taken as 1, and a box that is not finite, has
    /// `min > max` on some axis, or is (nearly) a point falls back to [`Camera::frame_bounds`].
    pub fn frame_from_above(min: DVec3, max: DVec3, width: u32, height: u32) -> Camera {
        let (width, height) = (width.max(1), height.max(1));
        let usable = min.is_finite() && max.is_finite() && min.cmple(max).all();
        let half = max * 0.5 - min * 0.5;
        let scale = (min * 0.5 + max * 0.5).abs().max_element().max(1.0);
        if !usable || half.x.max(half.y) <= 1e-9 * scale {
            return Self::frame_bounds(min, max, width, height);
        }
        let centre = min * 0.5 + max * 0.5;
        let tan_y = (FRAME_FOV_Y_DEG.to_radians() * 0.5).tan();
        let tan_x = tan_y * f64::from(width) / f64::from(height);
        let distance = (half.x / tan_x).max(half.y / tan_y);
        let eye_z = (min.z + distance).max(max.z + 0.1 * half.x.max(half.y));
        let eye = DVec3::new(centre.x, centre.y, eye_z);
        let target = DVec3::new(centre.x, centre.y, min.z);
        Self::perspective(eye, target, DVec3::Y, FRAME_FOV_Y_DEG, width, height)
            .unwrap_or_else(|_| Self::frame_bounds(min, max, width, height))
    }

    /// Parses and checks the JSON text of a camera file (format in the [module docs](self));
    /// `path` is only used in error messages. Numbers are read correctly rounded, so
    /// [`Camera::to_json`] output reads back bit for bit. Malformed JSON, an unknown key or a wrong type is an
    /// [`Error::Parse`] with `path` and the 1-based line; a degenerate camera is an
    /// [`Error::Invalid`] whose sentence starts with `path`.
    pub fn from_json_str(path: &str, text: &str) -> Result<Camera> {
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let spec: CameraSpec = serde_json::from_str(text).map_err(|e| {
            let full = e.to_string();
            let suffix = format!(" at line {} column {}", e.line(), e.column());
            // serde_json repeats bad keys and strings whole: cut them short.
            let mut message =
                crate::error::shorten_tokens(full.strip_suffix(&suffix).unwrap_or(&full), 300);
            // serde_json says only "expected value" when well-formed JSON has the wrong keys at
            // the top (none, or more than one).
            let well_formed = || serde_json::from_str::<serde_json::Value>(text).is_ok();
            if message == "expected value" && well_formed() {
                message = "a camera file must be an object with exactly one key: \
                           `perspective`, `orthographic` or `matrices`"
                    .to_owned();
            }
            // In well-formed JSON serde_json says "trailing characters" of a list longer than
            // the point or matrix it is read into (an `eye` of four numbers).
            if message == "trailing characters" && well_formed() {
                message = "a list has too many numbers (`eye`, `target` and `up` take 3, `view` \
                           and `projection` 16)"
                    .to_owned();
            }
            // A size of 2^64 or more is read as a float by serde_json, and a fraction is one.
            if message.starts_with("invalid type: floating point")
                && message.ends_with("expected u32")
            {
                message = format!(
                    "{message}: `width` and `height` are whole numbers of pixels, 1 to {}",
                    u32::MAX
                );
            }
            if e.column() > 0 {
                message = format!("{message} (column {})", e.column());
            }
            Error::Parse {
                path: path.to_owned(),
                line: (e.line() > 0).then_some(e.line()),
                message,
            }
        })?;
        Self::from_spec(spec).map_err(|e| Error::Invalid(format!("{path}: {e}")))
    }

    /// Reads, parses and checks the camera file at `path` (at most [`MAX_CAMERA_FILE_BYTES`]) (see [`Camera::from_json_str`]); a
    /// file that cannot be read is an [`Error::Io`] naming it.
    pub fn from_json_file(path: impl AsRef<Path>) -> Result<Camera> {
        let name = path.as_ref().display().to_string();
        let text = crate::io::ray_file::read_text_within(
            path.as_ref(),
            MAX_CAMERA_FILE_BYTES,
            "more than a camera file holds",
            None,
        )?;
        Self::from_json_str(&name, &text)
    }

    /// The camera as camera-file JSON (pretty-printed), which [`Camera::from_json_str`] reads
    /// back to an identical camera.
    pub fn to_json(&self) -> String {
        // Serializing plain numbers into a String cannot fail (checked cameras are finite).
        serde_json::to_string_pretty(&self.spec).unwrap_or_default()
    }
}

impl CameraSpec {
    /// The image size `(width, height)` in pixels.
    pub fn size(&self) -> (u32, u32) {
        match *self {
            CameraSpec::Perspective { width, height, .. }
            | CameraSpec::Orthographic { width, height, .. }
            | CameraSpec::Matrices { width, height, .. } => (width, height),
        }
    }
}

impl From<Camera> for CameraSpec {
    fn from(camera: Camera) -> Self {
        camera.spec
    }
}

impl TryFrom<CameraSpec> for Camera {
    type Error = Error;

    fn try_from(spec: CameraSpec) -> Result<Self> {
        Camera::from_spec(spec)
    }
}

impl Basis {
    /// The camera frame for `eye -> target` with `up`, or a sentence saying why there is none.
    fn new(
        eye: DVec3,
        target: DVec3,
        up: DVec3,
        half_h: f64,
        aspect: f64,
    ) -> std::result::Result<Basis, String> {
        for (name, v) in [("eye", eye), ("target", target), ("up", up)] {
            if !v.is_finite() {
                return Err(format!("{name} {} has a non-finite coordinate", show(v)));
            }
        }
        if eye == target {
            return Err(format!(
                "eye and target are the same point {}, so there is no view direction",
                show(eye)
            ));
        }
        let to_target = target - eye;
        // Scaled first: a distance of 10^160 squared overflowed, and was said not to be
        // representable.
        let length = crate::scene::scaled_length(to_target);
        if !(length.is_finite() && length > 0.0) {
            return Err(format!(
                "the distance from eye {} to target {} cannot be represented",
                show(eye),
                show(target)
            ));
        }
        let forward = to_target / length;
        let up_length = crate::scene::scaled_length(up);
        if !(up_length > 0.0 && up_length.is_finite()) {
            return Err(format!(
                "up {} has no usable length; give a non-zero vector",
                show(up)
            ));
        }
        let side = forward.cross(up / up_length);
        if side.length().is_nan() || side.length() <= 1e-9 {
            return Err(format!(
                "up {} is parallel to the view direction {} (from eye to target), so \
                 the camera's roll is undefined; choose an up vector across the line of sight",
                show(up),
                show(forward)
            ));
        }
        let right = unit(side);
        let basis = Basis {
            forward,
            right,
            up: right.cross(forward),
            half_w: half_h * aspect,
            half_h,
        };
        if !(basis.half_w.is_finite() && basis.half_h.is_finite()) {
            return Err("the image extent overflows".to_owned());
        }
        Ok(basis)
    }

    /// `right * sx * half_w + up * sy * half_h`: the image-plane offset of `(sx, sy)`.
    fn lateral(&self, sx: f64, sy: f64) -> DVec3 {
        self.right * (sx * self.half_w) + self.up * (sy * self.half_h)
    }

    /// `forward + lateral(sx, sy)`: the (unnormalized) perspective direction of `(sx, sy)`.
    fn offset(&self, sx: f64, sy: f64) -> DVec3 {
        self.forward + self.lateral(sx, sy)
    }
}

/// Checks a view/projection pair and inverts it, or says why it cannot be used.
fn matrices_model(view: DMat4, projection: DMat4) -> std::result::Result<Model, String> {
    for (name, m) in [("view", view), ("projection", projection)] {
        if !m.is_finite() {
            return Err(format!("the {name} matrix has a non-finite entry"));
        }
    }
    let last_row = view.row(3);
    if (last_row - DVec4::W).abs().max_element() > 1e-12 {
        return Err(format!(
            "the view matrix's last row is ({:?}, {:?}, {:?}, {:?}), not (0, 0, 0, 1): a view \
             matrix must be an affine transform (rotation, translation, scale)",
            last_row.x, last_row.y, last_row.z, last_row.w
        ));
    }
    let linear = DMat3::from_mat4(view);
    let bound = linear.x_axis.length() * linear.y_axis.length() * linear.z_axis.length();
    if degenerate(linear.determinant(), bound) {
        return Err(format!(
            "the view matrix is singular or too large to invert (its 3x3 part has determinant {}); it must be invertible",
            linear.determinant()
        ));
    }
    let bound = projection.x_axis.length()
        * projection.y_axis.length()
        * projection.z_axis.length()
        * projection.w_axis.length();
    if degenerate(projection.determinant(), bound) {
        return Err(format!(
            "the projection matrix is singular or too large to invert (determinant {}); it must be invertible",
            projection.determinant()
        ));
    }
    let (view_inv, projection_inv) = (view.inverse(), projection.inverse());
    if !(view_inv.is_finite() && projection_inv.is_finite()) {
        return Err("the matrices cannot be inverted in f64".to_owned());
    }
    Ok(Model::Matrices {
        view_inv,
        projection_inv,
    })
}

/// Whether a matrix with determinant `det` and column-length product `bound` (Hadamard's bound on
/// `|det|`) is too close to singular, or too large, to invert reliably. The ratio is
/// scale-free per column, so projections with tiny near planes and views at large world
/// coordinates pass.
fn degenerate(det: f64, bound: f64) -> bool {
    !(det.is_finite() && bound.is_finite()) || det.abs() <= 1e-12 * bound
}

/// The view-space line of NDC point `(sx, sy)`: its point on the plane `z = 0` and its direction
/// towards `-z` (not normalized).
fn unproject(projection_inv: &DMat4, sx: f64, sy: f64) -> (DVec3, DVec3) {
    let a = *projection_inv * DVec4::new(sx, sy, 0.5, 1.0);
    let b = *projection_inv * DVec4::new(sx, sy, 1.0, 1.0);
    // Homogeneous difference: the direction from a to b, valid even when b is at infinity.
    let mut dir = b.truncate() * a.w - a.truncate() * b.w;
    if dir.z > 0.0 {
        dir = -dir;
    }
    let point = a.truncate() / a.w;
    (point - dir * (point.z / dir.z), dir)
}

fn show(v: DVec3) -> String {
    format!("({:?}, {:?}, {:?})", v.x, v.y, v.z)
}

/// `v / |v|`, without glam's debug assertions (NaN in, NaN out).
fn unit(v: DVec3) -> DVec3 {
    v / v.length()
}
