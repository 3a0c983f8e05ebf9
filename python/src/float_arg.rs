//! Float arguments (`tmin`, `tmax`, `epsilon`, `target_height`): a Python `float`, `int` or
//! anything else Python turns into a float, never a bool (`tmin=True` is not a `tmin` of 1). A
//! refusal is one sentence naming the argument: a `TypeError` for a bool or what is not a
//! number, a `ValueError` for an int past a float's range (pyo3's own conversion raised
//! `OverflowError` for `tmax=10**400`, and took `True` as 1). What each value may be (finite,
//! ordered) is checked where the query is made, as before.

use crate::errors::value_error;
use pyo3::exceptions::{PyOverflowError, PyTypeError};
use pyo3::prelude::*;
use pyo3::types::PyBool;

/// The float argument `argument`.
pub fn float(value: &Bound<'_, PyAny>, argument: &str) -> PyResult<f64> {
    let py = value.py();
    if value.is_instance_of::<PyBool>()
        || value.is_instance(&py.import("numpy")?.getattr("bool_")?)?
    {
        return Err(PyTypeError::new_err(format!(
            "{argument} must be a number, not {}",
            value.get_type().name()?
        )));
    }
    value.extract::<f64>().map_err(|e| {
        if e.is_instance_of::<PyOverflowError>(py) {
            value_error(format!(
                "{argument} is out of range: an integer too large for a float (at most about \
                 1.8e308)"
            ))
        } else if e.is_instance_of::<PyTypeError>(py) {
            // Python's own words named no argument ("must be real number, not str", or
            // numpy's "only 0-dimensional arrays can be converted to Python scalars").
            match value.get_type().name() {
                Ok(kind) => {
                    PyTypeError::new_err(format!("{argument} must be a number, not {kind}"))
                }
                Err(e) => e,
            }
        } else {
            e
        }
    })
}

/// `tmin=`.
pub fn tmin(value: &Bound<'_, PyAny>) -> PyResult<f64> {
    ray_parameter(value, "tmin")
}

/// `tmax=`.
pub fn tmax(value: &Bound<'_, PyAny>) -> PyResult<f64> {
    ray_parameter(value, "tmax")
}

/// A ray parameter: a number or ±inf, not NaN, which no `t` compares with (every ray came back
/// invalid without a word; the CLI refuses `--tmin NaN`).
fn ray_parameter(value: &Bound<'_, PyAny>, argument: &str) -> PyResult<f64> {
    match float(value, argument)? {
        t if t.is_nan() => Err(value_error(format!(
            "{argument} is NaN; give a ray parameter (a number, or inf)"
        ))),
        t => Ok(t),
    }
}

/// `epsilon=`.
pub fn epsilon(value: &Bound<'_, PyAny>) -> PyResult<f64> {
    float(value, "epsilon")
}

/// `target_height=`.
pub fn target_height(value: &Bound<'_, PyAny>) -> PyResult<f64> {
    float(value, "target_height")
}
