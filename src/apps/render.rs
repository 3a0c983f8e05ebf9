//! Ray-cast rendering: one closest-hit pick ray per pixel of a [`Camera`] view, shaded into an
//! RGBA8 [`Image`] ([`Shade::Normal`] hillshade, [`Shade::Depth`] or [`Shade::Object`] ids), and
//! PNG encoding of the result.
//!
//! Rendering only sees the [`Hit`]s a [`Picker`] returns, so every shading rule here is a
//! function of the hits of the one image: depth and terrain heights are normalised over the
//! image's own hits, and terrain is recognised by [`Hit::cell`] (set for the objects of height
//! grids, such as DEMs).
//!
//! ```
//! use std::sync::Arc;
//! use raypick::apps::camera::Camera;
//! use raypick::apps::render::{Shade, render};
//! use raypick::{BuildOptions, BuiltScene, CpuPicker, check::synthetic};
//!
//! let built = BuiltScene::new(synthetic::example_scene(), &BuildOptions::default()).unwrap();
//! let (min, max) = built.scene.bounds().unwrap();
//! let camera = Camera::frame_bounds(min, max, 32, 24);
//! let mut picker = CpuPicker::new(Arc::new(built));
//! let image = render(&mut picker, &camera, Shade::Object).unwrap();
//! assert_eq!((image.width, image.height, image.rgba.len()), (32, 24, 32 * 24 * 4));
//! let png = image.to_png().unwrap();
//! assert_eq!(&png[1..4], b"PNG");
//! ```

use std::path::Path;

use glam::DVec3;

use crate::apps::camera::Camera;
use crate::error::{Error, Result};
use crate::picker::Picker;
use crate::query::Query;
use crate::ray::{Hit, Ray};

/// How pixels are coloured.
///
/// [`Shade::Normal`] puts the sun at compass bearing [`SUN_AZIMUTH_DEG`] (north-west) and
/// [`SUN_ELEVATION_DEG`] above the horizon, with `x` east, `y` north and `z` up, as cartographic
/// hillshades have it ([`sun_direction`]); pixels are `tint * (ambient + diffuse)` of the
/// geometric normal turned to face the viewer. [`Shade::Object`] colours are [`object_color`].
/// Misses are [`SKY`] in every mode.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Shade {
    /// Hillshade: Lambert lighting with the sun in the north-west, 45° up; height-grid terrain
    /// (DEMs) tinted by height (green low, brown high, pale summits), other objects pale colours.
    #[default]
    Normal,
    /// Grayscale by hit distance: the nearest hit in the image white, the farthest dark gray.
    Depth,
    /// A flat, distinct colour per object id.
    Object,
}

/// An RGBA8 image, row-major from the top-left.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height` pixels of 4 bytes (red, green, blue, alpha), row after row from the top
    /// row, each row left to right: pixel `(i, j)` starts at byte `4 * (j * width + i)`.
    pub rgba: Vec<u8>,
}

/// The colour of pixels whose ray hits nothing (a pale sky blue, opaque).
pub const SKY: [u8; 4] = [178, 206, 234, 255];

/// The sun's compass direction for [`Shade::Normal`], in degrees clockwise from north (`+y`):
/// 315, the north-west, the cartographic convention for hillshades.
pub const SUN_AZIMUTH_DEG: f64 = 315.0;

/// The sun's angle above the horizon (the `xy` plane) for [`Shade::Normal`], in degrees.
pub const SUN_ELEVATION_DEG: f64 = 45.0;

/// Light that every surface gets in [`Shade::Normal`], whatever way it faces (0 ..= 1).
const AMBIENT: f64 = 0.3;

/// The darkest gray of [`Shade::Depth`], for the farthest hit (0 ..= 1).
const DEPTH_FAR_GRAY: f64 = 0.2;

impl Image {
    /// Checks that the pixel buffer holds exactly `width * height` RGBA pixels and that neither
    /// side is zero.
    fn check(&self) -> Result<()> {
        let expected = 4 * u64::from(self.width) * u64::from(self.height);
        if self.width == 0 || self.height == 0 || self.rgba.len() as u64 != expected {
            return Err(Error::Invalid(format!(
                "an RGBA image of {} x {} pixels needs {expected} bytes (and both sides at least \
                 1), but it has {}",
                self.width,
                self.height,
                self.rgba.len()
            )));
        }
        Ok(())
    }

    /// The RGBA of pixel `(i, j)` (column `i` from the left, row `j` from the top), or `None`
    /// outside the image.
    pub fn pixel(&self, i: u32, j: u32) -> Option<[u8; 4]> {
        if i >= self.width || j >= self.height {
            return None;
        }
        let at = 4 * (j as usize * self.width as usize + i as usize);
        let p = self.rgba.get(at..at + 4)?;
        Some([p[0], p[1], p[2], p[3]])
    }

    /// The image as PNG file bytes (8-bit RGBA). Fails with [`Error::Invalid`] when `rgba` does
    /// not hold `width * height` pixels or a side is zero.
    pub fn to_png(&self) -> Result<Vec<u8>> {
        self.check()?;
        let png_error = |e: png::EncodingError| Error::Invalid(format!("PNG encoding failed: {e}"));
        let mut bytes = Vec::new();
        let mut encoder = png::Encoder::new(&mut bytes, self.width, self.height);
        encoder.set_color(png::ColorType::Rgba);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_compression(png::Compression::High);
        encoder
            .write_header()
            .map_err(png_error)?
            .write_image_data(&self.rgba)
            .map_err(png_error)?;
        Ok(bytes)
    }

    /// Writes the image as a PNG file at `path` (see [`Image::to_png`]); a file that cannot be
    /// written is an [`Error::Io`] naming it.
    pub fn save_png(&self, path: &Path) -> Result<()> {
        let bytes = self.to_png()?;
        std::fs::write(path, bytes).map_err(|source| Error::Io {
            path: path.display().to_string(),
            source,
        })
    }
}

/// One ray per pixel through the picker (closest hit), shaded.
///
/// The rays are [`Camera::pixel_center_rays`] (made on all cores:
/// [`Camera::pixel_center_ray_batch`]), traced with the picker's default query (closest hit,
/// no culling, all layers) in one batch; pixel `(i, j)` of the image shows ray
/// `j * width + i`. Misses (and invalid rays) are [`SKY`]. Errors are the picker's.
pub fn render(picker: &mut dyn Picker, camera: &Camera, shade: Shade) -> Result<Image> {
    let image = render_with(camera, shade, |rays| {
        Ok(Ok::<_, std::convert::Infallible>(picker.pick(rays)?))
    })?;
    Ok(image.unwrap_or_else(|never| match never {}))
}

/// [`render`] with the pixel rays' closest hits from `pick`, which may give up (`Err(why)`,
/// handed back): the server picks them in steps and stops for a client who is gone.
pub fn render_with<E>(
    camera: &Camera,
    shade: Shade,
    pick: impl FnOnce(&[Ray]) -> Result<std::result::Result<Vec<Hit>, E>>,
) -> Result<std::result::Result<Image, E>> {
    check_size(camera.width(), camera.height())?;
    let rays: Vec<Ray> = camera.pixel_center_ray_batch(u32::MAX);
    let hits = match pick(&rays)? {
        Ok(hits) => hits,
        Err(why) => return Ok(Err(why)),
    };
    if hits.len() != rays.len() {
        return Err(Error::Invalid(format!(
            "the picker answered {} of {} rays",
            hits.len(),
            rays.len()
        )));
    }
    let rgba = match shade {
        Shade::Normal => shade_normal(&rays, &hits),
        Shade::Depth => shade_depth(&rays, &hits),
        Shade::Object => hits
            .iter()
            .flat_map(|h| if h.hit { object_color(h.object) } else { SKY })
            .collect(),
    };
    Ok(Ok(Image {
        width: camera.width(),
        height: camera.height(),
        rgba,
    }))
}

/// Checks that a render of `width × height` pixels (one ray, one hit and 4 bytes each, in one
/// batch) fits the memory budget ([`crate::budget`]); the error names the size and the limit.
pub fn check_size(width: u32, height: u32) -> Result<()> {
    crate::budget::check(
        &format!("a render of {width} x {height} pixels"),
        u64::from(width) * u64::from(height),
        Query::default().bytes_per_ray() + 4,
    )
}

/// The [`Shade::Object`] colour of object `id`: a strong hue picked by the golden ratio sequence
/// from a hash of the id, so consecutive ids get well separated hues and every id keeps its
/// colour from image to image. Opaque.
pub fn object_color(id: u32) -> [u8; 4] {
    // Consecutive ids step the hue by the golden ratio (the best spread for small ids); the
    // hash of the id's high bits moves the start so large ids do not line up either.
    let mixed = u64::from(id >> 8).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 40;
    let hue =
        (0.08 + f64::from(id & 0xff) * 0.618_033_988_749_895 + mixed as f64 / 16_777_216.0).fract();
    // Alternate the value a little too, so neighbours differ in lightness as well as hue.
    let value = if id & 1 == 0 { 0.92 } else { 0.78 };
    to_rgba(hsv(hue, 0.68, value))
}

/// A unit vector pointing at the sun of [`Shade::Normal`] (`x` east, `y` north, `z` up).
pub fn sun_direction() -> DVec3 {
    let (az, el) = (SUN_AZIMUTH_DEG.to_radians(), SUN_ELEVATION_DEG.to_radians());
    DVec3::new(az.sin() * el.cos(), az.cos() * el.cos(), el.sin())
}

/// [`Shade::Normal`]: Lambert lighting times a per-object or hypsometric tint.
fn shade_normal(rays: &[Ray], hits: &[Hit]) -> Vec<u8> {
    let sun = sun_direction();
    // Terrain heights are normalised over the terrain hits of this image.
    let (z_min, z_max) = hits
        .iter()
        .filter(|h| h.hit && h.cell.is_some())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), h| {
            (lo.min(h.position.z), hi.max(h.position.z))
        });
    rays.iter()
        .zip(hits)
        .flat_map(|(ray, h)| {
            if !h.hit {
                return SKY;
            }
            // The geometric normal, turned towards the viewer (both faces are hit).
            let normal = if h.normal.dot(ray.dir) > 0.0 {
                -h.normal
            } else {
                h.normal
            };
            let lambert = normal.dot(sun).max(0.0);
            let light = AMBIENT + (1.0 - AMBIENT) * lambert;
            let tint = if h.cell.is_some() {
                let f = if z_max > z_min {
                    (h.position.z - z_min) / (z_max - z_min)
                } else {
                    0.5
                };
                hypsometric(f)
            } else {
                object_tint(h.object)
            };
            // Flat ground (lambert = sin 45°) gets light ≈ 0.79; lift it so it shows the tint at
            // about its own brightness (faces turned squarely to the sun saturate a little).
            to_rgba(tint * (light * 1.15))
        })
        .collect()
}

/// [`Shade::Depth`]: grayscale by distance along the ray, near = light, normalised over the
/// image's hits.
fn shade_depth(rays: &[Ray], hits: &[Hit]) -> Vec<u8> {
    let distance = |ray: &Ray, h: &Hit| h.t * ray.dir.length();
    let (near, far) = rays.iter().zip(hits).filter(|(_, h)| h.hit).fold(
        (f64::INFINITY, f64::NEG_INFINITY),
        |(lo, hi), (r, h)| {
            let d = distance(r, h);
            (lo.min(d), hi.max(d))
        },
    );
    rays.iter()
        .zip(hits)
        .flat_map(|(ray, h)| {
            if !h.hit {
                return SKY;
            }
            let f = if far > near {
                (distance(ray, h) - near) / (far - near)
            } else {
                0.0
            };
            let gray = 1.0 - (1.0 - DEPTH_FAR_GRAY) * f;
            to_rgba(DVec3::splat(gray))
        })
        .collect()
}

/// The gentle [`Shade::Normal`] tint of a non-terrain object: a pale colour from the object's
/// [`object_color`] hue family.
fn object_tint(id: u32) -> DVec3 {
    let [r, g, b, _] = object_color(id);
    let strong = DVec3::new(f64::from(r), f64::from(g), f64::from(b)) / 255.0;
    // Mostly light gray, a little of the object's colour.
    DVec3::splat(0.86) * 0.75 + strong * 0.25
}

/// An earthy hypsometric tint for relative height `f` (0 = lowest terrain in view, 1 = highest):
/// green lowlands, tan and brown uplands, pale summits.
fn hypsometric(f: f64) -> DVec3 {
    const STOPS: [(f64, [f64; 3]); 5] = [
        (0.0, [0.47, 0.64, 0.40]),
        (0.3, [0.70, 0.75, 0.48]),
        (0.6, [0.80, 0.70, 0.50]),
        (0.85, [0.68, 0.55, 0.42]),
        (1.0, [0.92, 0.90, 0.88]),
    ];
    let f = if f.is_nan() { 0.5 } else { f.clamp(0.0, 1.0) };
    for pair in STOPS.windows(2) {
        let ((f0, c0), (f1, c1)) = (pair[0], pair[1]);
        if f <= f1 {
            let s = (f - f0) / (f1 - f0);
            return DVec3::from(c0).lerp(DVec3::from(c1), s);
        }
    }
    DVec3::from(STOPS[STOPS.len() - 1].1)
}

/// HSV (all 0 ..= 1) to RGB (0 ..= 1).
fn hsv(hue: f64, saturation: f64, value: f64) -> DVec3 {
    let h = hue.fract() * 6.0;
    let c = value * saturation;
    let x = c * (1.0 - (h % 2.0 - 1.0).abs());
    let (r, g, b) = match h as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    DVec3::new(r, g, b) + (value - c)
}

/// An RGB colour (0 ..= 1, clamped) as an opaque RGBA8 pixel.
fn to_rgba(c: DVec3) -> [u8; 4] {
    let byte = |v: f64| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    [byte(c.x), byte(c.y), byte(c.z), 255]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sun_is_north_west_and_45_degrees_up() {
        let s = sun_direction();
        assert!(s.x < 0.0 && s.y > 0.0, "{s}");
        assert!((s.x + s.y).abs() < 1e-12 && (s.z - 0.5f64.sqrt()).abs() < 1e-12);
        assert!((s.length() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn object_colours_differ_for_neighbouring_ids() {
        for id in 0..64u32 {
            assert_ne!(object_color(id), object_color(id + 1));
            assert_ne!(object_color(id), SKY);
        }
    }

    #[test]
    fn hypsometric_tint_is_continuous_at_the_ends() {
        assert_eq!(hypsometric(0.0), DVec3::new(0.47, 0.64, 0.40));
        assert_eq!(hypsometric(1.0), DVec3::new(0.92, 0.90, 0.88));
        assert_eq!(hypsometric(-3.0), hypsometric(0.0));
        assert_eq!(hypsometric(f64::NAN), hypsometric(0.5));
    }

    #[test]
    fn a_wrong_buffer_size_is_an_error() {
        let image = Image {
            width: 2,
            height: 2,
            rgba: vec![0; 15],
        };
        assert!(matches!(image.to_png(), Err(Error::Invalid(_))));
    }

    /// A back face is lit as the front face would be (both faces are hit, and the shading turns
    /// the normal towards the viewer): a ray seeing a face whose stored normal points away from
    /// it gets the very pixel of the same face stored the other way round.
    #[test]
    fn back_faces_are_shaded_as_front_faces() {
        let ray = Ray::new(DVec3::new(0.0, 0.0, 10.0), DVec3::new(0.3, -0.2, -1.0));
        let hit = |normal: DVec3| Hit {
            hit: true,
            t: 10.0,
            position: DVec3::ZERO,
            normal,
            ..Hit::MISS
        };
        let normal = DVec3::new(-0.2, 0.3, 1.0).normalize();
        let front = shade_normal(&[ray], &[hit(normal)]);
        let back = shade_normal(&[ray], &[hit(-normal)]);
        assert_eq!(front, back);
        assert_ne!(front, SKY);
    }
}

crate::names::named!(Shade {
    Normal => ("normal", "Hillshade: Lambert lighting, sun in the north-west 45° up; height grids tinted by height."),
    Depth => ("depth", "Grayscale by hit distance: the nearest hit white, the farthest dark gray."),
    Object => ("object", "A flat, distinct colour per object id."),
});
