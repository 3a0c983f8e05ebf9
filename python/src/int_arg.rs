//! Integer arguments: a Python `int`, a numpy integer or anything else with `__index__`, never
//! a bool (`True` is not a leaf size of 1), checked against the argument's range. A refusal is
//! one sentence naming the argument: a `TypeError` for what is not an integer, a `ValueError`
//! for an integer out of range however large (pyo3's own conversion to `i64` raised
//! `OverflowError` from 2**63 on, and took `True` as 1).
//!
//! Each integer argument has an extractor calling [`integer`] (`scene::leaf_size`,
//! `pick::max_hits`, …), named by `#[pyo3(from_py_with = …)]` where the argument is declared.

use crate::errors::value_error;
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyInt};
use std::ops::RangeInclusive;

/// The integer argument `argument` in `range`: a `TypeError` naming it when `value` is not an
/// integer (or is a bool), else a `ValueError` of `refusal(value as quoted)` when it is out of
/// range. The value is quoted whole up to 128 bits (39 digits), by its size beyond.
pub fn integer<T>(
    value: &Bound<'_, PyAny>,
    argument: &str,
    range: RangeInclusive<T>,
    refusal: impl FnOnce(&str) -> String,
) -> PyResult<T>
where
    T: Copy + PartialOrd + TryFrom<i128>,
{
    match Integer::of(value, argument)? {
        Some(integer) => integer.within(range, refusal),
        None => Err(not_an_integer(value, argument)),
    }
}

/// An integer argument's value: exact up to 128 bits, its sign and size beyond.
pub enum Integer {
    /// Within i128.
    Fits(i128),
    /// Past i128: out of every argument's range.
    Huge { negative: bool, bits: u64 },
}

impl Integer {
    /// `value` as an integer, `None` when it is not one (for the caller to refuse in its own
    /// words); a bool is a `TypeError` naming `argument`.
    pub fn of(value: &Bound<'_, PyAny>, argument: &str) -> PyResult<Option<Self>> {
        let Some(int) = as_int(value, argument)? else {
            return Ok(None);
        };
        if let Ok(fits) = int.extract::<i128>() {
            return Ok(Some(Self::Fits(fits)));
        }
        Ok(Some(Self::Huge {
            negative: int.lt(0)?,
            bits: int.call_method0("bit_length")?.extract()?,
        }))
    }

    /// The value in `range`, or a `ValueError` of `refusal(value as quoted)`.
    pub fn within<T>(
        &self,
        range: RangeInclusive<T>,
        refusal: impl FnOnce(&str) -> String,
    ) -> PyResult<T>
    where
        T: Copy + PartialOrd + TryFrom<i128>,
    {
        let inside = match *self {
            Self::Fits(v) => T::try_from(v).ok().filter(|t| range.contains(t)),
            Self::Huge { .. } => None,
        };
        inside.ok_or_else(|| value_error(refusal(&self.quoted())))
    }

    /// The value for a message: whole when it fits 128 bits, else its size (a 400-digit
    /// integer is not quoted whole; Python would not even print one of 4,300 digits).
    pub fn quoted(&self) -> String {
        match *self {
            Self::Fits(v) => v.to_string(),
            Self::Huge { negative, bits } => format!(
                "(a{} integer of {bits} bits)",
                if negative { " negative" } else { "n" }
            ),
        }
    }
}

/// `value` as a Python int: an int as it is, another integer through `__index__`; `None` when
/// it is not an integer; a `TypeError` naming `argument` for a bool (Python's, or numpy's,
/// which older numpy let `__index__` read as 0 or 1).
fn as_int<'py>(value: &Bound<'py, PyAny>, argument: &str) -> PyResult<Option<Bound<'py, PyInt>>> {
    if value.is_instance_of::<PyBool>() {
        return Err(not_an_integer(value, argument));
    }
    if let Ok(int) = value.cast::<PyInt>() {
        return Ok(Some(int.clone()));
    }
    let py = value.py();
    if value.is_instance(&py.import("numpy")?.getattr("bool_")?)? {
        return Err(not_an_integer(value, argument));
    }
    if !value.hasattr("__index__")? {
        return Ok(None);
    }
    match py.import("operator")?.call_method1("index", (value,)) {
        Ok(int) => Ok(Some(int.cast_into::<PyInt>()?)),
        Err(e) if e.is_instance_of::<PyTypeError>(py) => Ok(None),
        Err(e) => Err(e),
    }
}

/// The `TypeError` for an integer argument given something else.
pub fn not_an_integer(value: &Bound<'_, PyAny>, argument: &str) -> PyErr {
    let kind = value
        .get_type()
        .name()
        .map(|n| n.to_string())
        .unwrap_or_else(|_| "something else".to_string());
    PyTypeError::new_err(format!("{argument} must be an integer, not {kind}"))
}
