//! `raypick.camera_rays(camera, pixels=None)`: the CLI's camera JSON (as a dict, or its text)
//! and pixels in, rays out, (N, 6) float64 (origin, unit direction).
//!
//! Pixels are as in the CLI's pixel files: (x, y) with a top-left origin, integers naming
//! whole pixels, picked through their centres (x + 0.5, y + 0.5); fractional values are offsets
//! from that centre. Without pixels: every pixel centre, row by row from the top, each row left
//! to right.

use crate::arrays::{self, Dtype};
use crate::errors::{to_py, value_error, vec_for};
use numpy::{IntoPyArray, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{IntoPyDict, PyDict, PyString};
use rayon::prelude::*;
use raypick::Ray;
use raypick::apps::camera::Camera;

/// The camera of a dict or JSON text.
fn camera_of(camera: &Bound<'_, PyAny>) -> PyResult<Camera> {
    let text: String = if camera.is_instance_of::<PyDict>() {
        camera
            .py()
            .import("json")?
            // NaN and infinities refused here, in Python's words ("Out of range float values are
            // not JSON compliant: nan"): written as JSON's non-standard `NaN`, the parse below
            // said "camera:1: expected value (column 26)" of text the user never wrote.
            .call_method(
                "dumps",
                (camera,),
                Some(&[("allow_nan", false)].into_py_dict(camera.py())?),
            )
            .map_err(|e| {
                value_error(format!(
                    "camera cannot be written as JSON ({})",
                    e.value(camera.py())
                ))
            })?
            .extract()?
    } else if let Ok(text) = camera.cast::<PyString>() {
        text.to_str()?.to_owned()
    } else {
        return Err(value_error(format!(
            "camera must be a dict (the CLI's camera JSON) or JSON text; got {}",
            camera.get_type().name()?
        )));
    };
    Camera::from_json_str("camera", &text).map_err(to_py)
}

/// camera_rays(camera, pixels=None): the rays through `pixels` (N, 2) of `camera`, (N, 6)
/// float64.
#[pyfunction]
#[pyo3(signature = (camera, pixels=None))]
pub fn camera_rays<'py>(
    py: Python<'py>,
    camera: &Bound<'py, PyAny>,
    pixels: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    let camera = camera_of(camera)?;
    let rays: Vec<f64> = match pixels.filter(|p| !p.is_none()) {
        Some(pixels) => {
            let pixels = arrays::rows(pixels, "pixels", 2, Dtype::Real, false)?;
            let view = pixels.as_array();
            // Sized first: a view of 10¹² rows of one pixel (zero strides) was read row by row
            // for minutes before its rays were refused.
            let mut out = vec_for::<f64>(view.nrows().saturating_mul(6), "the camera rays")?;
            if let Some(i) =
                (0..view.nrows()).find(|&i| !(view[[i, 0]].is_finite() && view[[i, 1]].is_finite()))
            {
                return Err(value_error(format!(
                    "pixels row {i} is ({}, {}), not a finite pixel",
                    raypick::budget::number(view[[i, 0]]),
                    raypick::budget::number(view[[i, 1]])
                )));
            }
            crate::threads::run(|| {
                out.par_extend((0..view.nrows()).into_par_iter().flat_map_iter(|i| {
                    row(camera.pixel_ray(view[[i, 0]] + 0.5, view[[i, 1]] + 0.5))
                }))
            })?;
            // A pixel so far out that its ray has no direction (a perspective camera's at
            // 1e200: (0, 0, -0)) or no finite origin (an orthographic one's at 1e308) came back
            // as such a ray, documented as a unit direction.
            if let Some(i) = out
                .chunks_exact(6)
                .position(|r| !r.iter().all(|c| c.is_finite()) || r[3..].iter().all(|&c| c == 0.0))
            {
                return Err(value_error(format!(
                    "pixels row {i} is ({}, {}), too far outside the camera's {} x {} image to \
                     make a ray",
                    raypick::budget::number(view[[i, 0]]),
                    raypick::budget::number(view[[i, 1]]),
                    camera.width(),
                    camera.height()
                )));
            }
            warn_outside(py, &camera, view)?;
            out
        }
        None => {
            let (w, h) = (camera.width(), camera.height());
            let count = u64::from(w) * u64::from(h);
            raypick::budget::check("the camera's pixel rays", count, 6 * 8).map_err(to_py)?;
            let mut out = vec_for::<f64>(6 * count as usize, "the camera rays")?;
            crate::threads::run(|| {
                out.par_extend((0..count).into_par_iter().flat_map_iter(|k| {
                    row(camera
                        .pixel_center_ray((k % u64::from(w)) as u32, (k / u64::from(w)) as u32))
                }))
            })?;
            out
        }
    };
    let n = rays.len() / 6;
    Ok(rays.into_pyarray(py).reshape([n, 6])?.into_any())
}

/// Warns once (a `UserWarning`) when pixels lie outside the camera's image, as the CLI does
/// for a pixel file: their rays go through where those pixels would be, but pixels for another
/// image size give picks the user did not mean.
fn warn_outside(
    py: Python<'_>,
    camera: &Camera,
    view: numpy::ndarray::ArrayView2<'_, f64>,
) -> PyResult<()> {
    // Centres, as the CLI checks them.
    let centres = view.rows().into_iter().map(|r| (r[0] + 0.5, r[1] + 0.5));
    if let Some((count, k)) = camera.outside_image(centres) {
        let message = format!(
            "{count} of the {} pixels lie outside the camera's {} x {} image (the first: row \
             {k}, ({}, {})); their rays go through where they would be",
            view.nrows(),
            camera.width(),
            camera.height(),
            raypick::budget::number(view[[k, 0]]),
            raypick::budget::number(view[[k, 1]])
        );
        let category = py.get_type::<pyo3::exceptions::PyUserWarning>();
        PyErr::warn(py, &category, &std::ffi::CString::new(message)?, 1)?;
    }
    Ok(())
}

/// A ray as its row (origin, direction).
fn row(ray: Ray) -> [f64; 6] {
    let (o, d) = (ray.origin, ray.dir);
    [o.x, o.y, o.z, d.x, d.y, d.z]
}
