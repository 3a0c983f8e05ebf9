//! The process's memory budget, from Python: what the command line's `--max-memory` sets.
//!
//! Every allocation whose size comes from user input (files' headers, the tree over a file's
//! triangles, ray counts, all-hits lists, a pick's batches) is checked against one budget
//! before it is made (`raypick::budget`). By default it is half of what the process can have;
//! `raypick.set_max_memory` raises or lowers it for the whole process, with the command line's
//! checks and sentences.

use crate::int_arg::Integer;
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyString};

/// `set_max_memory(size)`: the budget from now on, in bytes (an int) or as the command line
/// writes it (a str: "8G", "512M", "1000000"); at least 1 MiB and at most what the process can
/// have. Returns the budget in bytes.
#[pyfunction]
pub fn set_max_memory(size: &Bound<'_, PyAny>) -> PyResult<u64> {
    let refused = |why: String| PyValueError::new_err(format!("max_memory: {why}"));
    let bytes = if let Ok(text) = size.cast::<PyString>() {
        raypick::budget::parse_limit(&text.to_cow()?).map_err(refused)?
    } else if !size.is_instance_of::<PyBool>()
        && let Some(integer) = Integer::of(size, "max_memory")?
    {
        // An int, a numpy integer or another `__index__`: past u64 it is more than any process
        // can have, below 0 below the least budget.
        let bytes = match integer {
            Integer::Fits(v) => u64::try_from(v).unwrap_or(if v < 0 { 0 } else { u64::MAX }),
            Integer::Huge { negative, .. } => {
                if negative {
                    0
                } else {
                    u64::MAX
                }
            }
        };
        raypick::budget::check_limit(bytes, &integer.quoted()).map_err(refused)?
    } else {
        return Err(PyTypeError::new_err(format!(
            "max_memory: a size is an int of bytes or a str such as \"8G\", not {}",
            size.get_type().name()?
        )));
    };
    raypick::budget::set_limit(bytes);
    Ok(bytes)
}

/// `max_memory()`: the budget in bytes (the default until `set_max_memory` sets one).
#[pyfunction]
pub fn max_memory() -> u64 {
    raypick::budget::limit()
}
