//! The library's errors as Python exceptions, with the library's sentence: a file that cannot
//! be read or written is an `OSError` (`FileNotFoundError`, `PermissionError`,
//! `IsADirectoryError` where the system says so), everything else a `ValueError`.

use pyo3::PyErr;
use pyo3::exceptions::{
    PyFileNotFoundError, PyIsADirectoryError, PyMemoryError, PyOSError, PyPermissionError,
    PyValueError,
};
use raypick::Error;
use std::io::ErrorKind;

/// The Python exception for a library error.
pub fn to_py(error: Error) -> PyErr {
    let sentence = error.to_string();
    match &error {
        Error::Io { source, .. } => match source.kind() {
            ErrorKind::NotFound => PyFileNotFoundError::new_err(sentence),
            ErrorKind::PermissionDenied => PyPermissionError::new_err(sentence),
            ErrorKind::IsADirectory => PyIsADirectoryError::new_err(sentence),
            _ => PyOSError::new_err(sentence),
        },
        // Python sets the budget with `raypick.set_max_memory`, not --max-memory.
        Error::OverBudget(_) => PyValueError::new_err(sentence.replace(
            "(set it with --max-memory)",
            "(set it with raypick.set_max_memory)",
        )),
        // And the builder with `builder=`.
        _ => PyValueError::new_err(
            sentence.replace("use --builder median-cut", "use builder=\"median-cut\""),
        ),
    }
}

/// `items` (at most `n` of them) in a vector made by [`vec_for`]: checked against the memory
/// budget before anything is allocated (a zero-copy view, `numpy.broadcast_to`, may claim
/// billions of rows).
pub fn collect_for<T>(
    n: usize,
    what: &str,
    items: impl IntoIterator<Item = T>,
) -> Result<Vec<T>, PyErr> {
    let mut v = vec_for(n, what)?;
    v.extend(items.into_iter().take(n));
    Ok(v)
}

/// A `ValueError` with one sentence.
pub fn value_error(sentence: impl Into<String>) -> PyErr {
    PyValueError::new_err(sentence.into())
}

/// A vector with room for `n` items, advised onto huge pages when large: a `ValueError` when
/// they are over the memory budget (`raypick.set_max_memory`), a `MemoryError` instead of an
/// abort when the memory is not there.
pub fn vec_for<T>(n: usize, what: &str) -> Result<Vec<T>, PyErr> {
    raypick::budget::check(what, n as u64, size_of::<T>() as u64).map_err(to_py)?;
    let mut v = Vec::new();
    v.try_reserve_exact(n).map_err(|_| {
        PyMemoryError::new_err(format!(
            "{what} would need {n} × {} bytes, more than this process can allocate",
            size_of::<T>()
        ))
    })?;
    raypick::huge_pages::advise(&mut v);
    Ok(v)
}
