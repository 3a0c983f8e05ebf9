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
use pyo3::types::{PyDict, PyString};
use rayon::prelude::*;
use raypick::Ray;
use raypick::apps::camera::Camera;

/// The camera of a dict or JSON text.
fn camera_of(camera: &Bound<'_, PyAny>) -> PyResult<Camera> {
    let text: String = if camera.is_instance_of::<PyDict>() {
        camera
            .py()
            .import("json")?
            .call_method1("dumps", (camera,))
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
            if let Some(i) =
                (0..view.nrows()).find(|&i| !(view[[i, 0]].is_finite() && view[[i, 1]].is_finite()))
            {
                return Err(value_error(format!(
                    "pixels row {i} is ({}, {}), not a finite pixel",
                    view[[i, 0]],
                    view[[i, 1]]
                )));
            }
            let mut out = vec_for::<f64>(6 * view.nrows(), "the camera rays")?;
            crate::threads::run(|| {
                out.par_extend((0..view.nrows()).into_par_iter().flat_map_iter(|i| {
                    row(camera.pixel_ray(view[[i, 0]] + 0.5, view[[i, 1]] + 0.5))
                }))
            });
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
            });
            out
        }
    };
    let n = rays.len() / 6;
    Ok(rays.into_pyarray(py).reshape([n, 6])?.into_any())
}

/// A ray as its row (origin, direction).
fn row(ray: Ray) -> [f64; 6] {
    let (o, d) = (ray.origin, ray.dir);
    [o.x, o.y, o.z, d.x, d.y, d.z]
}
