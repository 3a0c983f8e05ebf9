//! Name arguments (`mode`, `cull`, `intersector`, `backend`, `builder`): a Python `str` naming
//! one of the choices the CLI spells. A refusal is one sentence naming the argument: a
//! `TypeError` listing the choices for what is not a `str` (pyo3's own conversion said "'int'
//! object cannot be converted to 'PyString'"), a `ValueError` for a name that is none of them.
//! The extractor gives the choice's own spelling, which the query and the build read again.

use crate::scene::parse_name;
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::PyString;
use raypick::names::Named;
use raypick::{Backend, Builder, Cull, Intersector, Mode};
use std::str::FromStr;

/// The name argument `argument`: one of `T`'s choices, as the CLI spells it.
pub fn name<T>(value: &Bound<'_, PyAny>, argument: &str) -> PyResult<&'static str>
where
    T: Named + FromStr<Err = String>,
{
    match value.cast::<PyString>() {
        Ok(text) => parse_name::<T>(argument, text.to_str()?).map(T::name),
        Err(_) => Err(PyTypeError::new_err(format!(
            "{argument} must be a str (one of: {}), not {}",
            T::names(),
            value.get_type().name()?
        ))),
    }
}

/// `mode=`.
pub fn mode(value: &Bound<'_, PyAny>) -> PyResult<&'static str> {
    name::<Mode>(value, "mode")
}

/// `cull=`.
pub fn cull(value: &Bound<'_, PyAny>) -> PyResult<&'static str> {
    name::<Cull>(value, "cull")
}

/// `intersector=`.
pub fn intersector(value: &Bound<'_, PyAny>) -> PyResult<&'static str> {
    name::<Intersector>(value, "intersector")
}

/// `backend=`.
pub fn backend(value: &Bound<'_, PyAny>) -> PyResult<&'static str> {
    name::<Backend>(value, "backend")
}

/// `builder=`.
pub fn builder(value: &Bound<'_, PyAny>) -> PyResult<&'static str> {
    name::<Builder>(value, "builder")
}

/// `builder=` where None means the default.
pub fn builder_or_none(value: &Bound<'_, PyAny>) -> PyResult<Option<&'static str>> {
    if value.is_none() {
        Ok(None)
    } else {
        builder(value).map(Some)
    }
}
