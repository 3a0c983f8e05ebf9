//! Screen-space selection: the objects visible inside a marquee rectangle, and an object-id
//! buffer for a whole view, both by casting one ray per pixel (or per `step` pixels).

use crate::apps::camera::Camera;
use crate::error::{Error, Result};
use crate::picker::Picker;
use crate::query::Query;
use crate::ray::Ray;
use std::collections::BTreeMap;

/// The id-buffer value of a pixel where nothing is hit.
pub const NO_OBJECT: u32 = u32::MAX;

/// A screen rectangle in pixels, top-left origin: columns `x0..x1`, rows `y0..y1`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rect {
    /// First column.
    pub x0: u32,
    /// First row.
    pub y0: u32,
    /// One past the last column.
    pub x1: u32,
    /// One past the last row.
    pub y1: u32,
}

/// One object seen inside a marquee: its id and how many sampled pixels show it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Selected {
    /// Object id.
    pub object: u32,
    /// Sampled pixels whose nearest hit is this object.
    pub pixels: u32,
}

/// The objects visible inside `rect`: a ray through the centre of every `step`-th pixel
/// (step 1 = every pixel), nearest hits only, deduplicated and sorted by object id. Rays carry
/// `mask`.
pub fn marquee(
    picker: &mut dyn Picker,
    camera: &Camera,
    rect: Rect,
    step: u32,
    mask: u32,
) -> Result<Vec<Selected>> {
    let (w, h) = (camera.width(), camera.height());
    let marquee = format!(
        "marquee {}..{} × {}..{}",
        rect.x0, rect.x1, rect.y0, rect.y1
    );
    // Each refusal says which: a step of 0, an empty marquee, or one reaching past the view.
    if step == 0 {
        return Err(Error::Invalid(format!(
            "the {marquee}'s step is 0; give a step of at least 1 (1 samples every pixel)"
        )));
    }
    if rect.x0 >= rect.x1 || rect.y0 >= rect.y1 {
        return Err(Error::Invalid(format!(
            "{marquee} is empty: each range's end must be past its start"
        )));
    }
    if rect.x1 > w || rect.y1 > h {
        return Err(Error::Invalid(format!(
            "{marquee} reaches past the {w}×{h} view (columns 0..{w}, rows 0..{h})"
        )));
    }
    let (columns, rows) = (
        u64::from(rect.x1 - rect.x0).div_ceil(u64::from(step)),
        u64::from(rect.y1 - rect.y0).div_ceil(u64::from(step)),
    );
    crate::budget::check(
        &format!(
            "a marquee of {columns} x {rows} rays ({}..{} × {}..{}, step {step})",
            rect.x0, rect.x1, rect.y0, rect.y1
        ),
        columns * rows,
        Query::default().bytes_per_ray(),
    )?;
    // `columns` and `rows` are at most the view's sides (u32), checked above.
    let rays: Vec<Ray> = camera.pixel_center_ray_lattice(
        (rect.x0, rect.y0),
        (columns as u32, rows as u32),
        step,
        mask,
    );
    let mut counts: BTreeMap<u32, u32> = BTreeMap::new();
    for hit in picker.pick(&rays)? {
        if hit.hit {
            *counts.entry(hit.object).or_default() += 1;
        }
    }
    Ok(counts
        .into_iter()
        .map(|(object, pixels)| Selected { object, pixels })
        .collect())
}

/// Checks that an id buffer of `width × height` pixels (one ray, one hit and one id each, in
/// one batch) fits the memory budget ([`crate::budget`]); the error names the size and the
/// limit.
pub fn check_id_buffer_size(width: u32, height: u32) -> Result<()> {
    crate::budget::check(
        &format!("an id buffer of {width} x {height} pixels"),
        u64::from(width) * u64::from(height),
        Query::default().bytes_per_ray() + 4,
    )
}

/// The object under every pixel of the view, row-major from the top-left; [`NO_OBJECT`] where
/// nothing is hit.
pub fn object_id_buffer(picker: &mut dyn Picker, camera: &Camera, mask: u32) -> Result<Vec<u32>> {
    check_id_buffer_size(camera.width(), camera.height())?;
    let rays: Vec<Ray> = camera.pixel_center_ray_batch(mask);
    Ok(picker
        .pick(&rays)?
        .iter()
        .map(|h| if h.hit { h.object } else { NO_OBJECT })
        .collect())
}
