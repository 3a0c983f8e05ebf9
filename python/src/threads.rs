//! How many threads this process traces with.
//!
//! By default every pick runs on rayon's global pool, one thread per core. A Dask worker
//! process is one of possibly several on its machine and owns only its Dask threads' share of
//! the cores, so `raypick.dask` sets a pool of that many threads once per worker process
//! (`_set_threads`); every trace of the process then runs inside it.

use crate::int_arg;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use std::sync::{Arc, Mutex, PoisonError};

/// The process's own pool, when one was set.
static POOL: Mutex<Option<Arc<rayon::ThreadPool>>> = Mutex::new(None);

fn pool() -> Option<Arc<rayon::ThreadPool>> {
    POOL.lock().unwrap_or_else(PoisonError::into_inner).clone()
}

/// Runs `work` on the process's pool (or rayon's global one).
pub fn run<R: Send>(work: impl FnOnce() -> R + Send) -> R {
    match pool() {
        Some(pool) => pool.install(work),
        None => work(),
    }
}

/// Starts rayon's global pool (one thread per core, or `RAYON_NUM_THREADS`) as the module is
/// imported. Started lazily, by the first parallel call, it panicked where the system refused a
/// thread (an address-space limit too tight for their stacks): a `PanicException`, which is not
/// an `Exception`, and every later call panicking again. Refused here, the import fails with an
/// `OSError` that says why (once per process: a second import gives the first one's answer).
pub fn start_global_pool() -> PyResult<()> {
    static STARTED: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    STARTED
        .get_or_init(|| {
            rayon::ThreadPoolBuilder::new()
                .build_global()
                .map_err(|e| e.to_string())
        })
        .clone()
        .map_err(|e| {
            pyo3::exceptions::PyOSError::new_err(format!(
                "raypick cannot start its picking threads ({e}); raise the process's \
                 address-space limit or set RAYON_NUM_THREADS to fewer threads"
            ))
        })
}

/// `_set_threads(n)`: trace on `n` threads from now on in this process; 0 goes back to one
/// thread per core.
#[pyfunction]
#[pyo3(name = "_set_threads")]
pub fn set_threads(#[pyo3(from_py_with = thread_count)] threads: usize) -> PyResult<()> {
    let new = match threads {
        0 => None,
        _ => Some(Arc::new(
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .thread_name(|i| format!("raypick-{i}"))
                .build()
                .map_err(|e| {
                    PyValueError::new_err(format!("cannot start {threads} threads: {e}"))
                })?,
        )),
    };
    *POOL.lock().unwrap_or_else(PoisonError::into_inner) = new;
    Ok(())
}

/// `threads` of `_set_threads`: an integer in 0 ..= 4096.
fn thread_count(value: &Bound<'_, PyAny>) -> PyResult<usize> {
    int_arg::integer(value, "threads", 0..=4096, |v| {
        format!("threads {v} is out of range; it must be 0 (one per core) ..= 4096")
    })
}

/// `_threads()`: how many threads a pick runs on in this process.
#[pyfunction]
#[pyo3(name = "_threads")]
pub fn threads() -> usize {
    run(rayon::current_num_threads)
}
