//! How many threads this process traces with.
//!
//! By default every pick runs on rayon's global pool, one thread per core. A Dask worker
//! process is one of possibly several on its machine and owns only its Dask threads' share of
//! the cores, so `raypick.dask` sets a pool of that many threads once per worker process
//! (`_set_threads`); every trace of the process then runs inside it.

use crate::int_arg;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

/// The process's own pool, when one was set (or made for a forked process), with the id of
/// the process it was made in.
static POOL: Mutex<Option<(u32, Arc<rayon::ThreadPool>)>> = Mutex::new(None);

/// The id of the process that started rayon's global pool (0: not started).
static GLOBAL_IN: AtomicU32 = AtomicU32::new(0);

fn pool() -> Option<Arc<rayon::ThreadPool>> {
    let slot = POOL.lock().unwrap_or_else(PoisonError::into_inner);
    slot.as_ref()
        .filter(|(made_in, _)| *made_in == std::process::id())
        .map(|(_, pool)| pool.clone())
}

/// Runs `work` on the process's pool (or rayon's global one), once [`ready`] says picking
/// threads run in this process: every call that picks, loads or builds goes through here.
pub fn run<R: Send>(work: impl FnOnce() -> R + Send) -> PyResult<R> {
    ready()?;
    Ok(on_pool(work))
}

/// [`run`] inside work that [`run`] already runs (no [`ready`] to ask again).
pub fn on_pool<R: Send>(work: impl FnOnce() -> R + Send) -> R {
    match pool() {
        Some(pool) => pool.install(work),
        None => work(),
    }
}

/// Makes sure picking threads run in this process ([`run`] asks first).
///
/// - rayon's global pool (one thread per core, or `RAYON_NUM_THREADS`) is started here, not at
///   rayon's first parallel call: there a thread the system refused (an address-space limit too
///   tight for their stacks) was a panic, a `PanicException` (not an `Exception`) with every
///   later call panicking again. Here it is an `OSError` that says why, each time.
/// - Threads do not survive `fork`: a process forked from one that had picked
///   (`multiprocessing`'s default start on Linux, a scene loaded before the workers) hung on its
///   first pick, waiting on threads left in the parent. A forked process gets a pool of its own,
///   of as many threads.
///
/// A process with a pool of its own (`_set_threads`) needs nothing else. The threads are counted
/// against the address-space limit before any is started
/// ([`raypick::budget::prepare_threads`]); a refusal there is not kept, so a later call
/// tries again (the address space the process uses changes), while the global pool's start,
/// once tried, is.
fn ready() -> PyResult<()> {
    static STARTED: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    let pid = std::process::id();
    let refused = |e: String| {
        pyo3::exceptions::PyOSError::new_err(format!(
            "raypick cannot start its picking threads ({e}); raise the process's address-space \
             limit or set RAYON_NUM_THREADS to fewer threads"
        ))
    };
    let mut slot = POOL.lock().unwrap_or_else(PoisonError::into_inner);
    match &*slot {
        Some((made_in, _)) if *made_in == pid => return Ok(()),
        // Forked from a process with a pool of its own: one of as many threads here.
        Some((_, pool)) => {
            let pool = new_pool(pool.current_num_threads()).map_err(refused)?;
            *slot = Some((pid, Arc::new(pool)));
            return Ok(());
        }
        None => {}
    }
    let started = match STARTED.get() {
        Some(started) => started,
        None => {
            let threads = raypick::budget::global_thread_count();
            raypick::budget::prepare_threads(threads).map_err(refused)?;
            STARTED.get_or_init(|| {
                match rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build_global()
                {
                    Ok(()) => {}
                    // Started by a parallel call that came first: running, in this process.
                    Err(e) if e.to_string().contains("already") => {}
                    Err(e) => return Err(e.to_string()),
                }
                GLOBAL_IN.store(pid, Ordering::Relaxed);
                Ok(())
            })
        }
    };
    started.clone().map_err(refused)?;
    // Forked from a process that had started the global pool: a pool of as many threads here.
    if GLOBAL_IN.load(Ordering::Relaxed) != pid {
        let pool = new_pool(rayon::current_num_threads()).map_err(refused)?;
        *slot = Some((pid, Arc::new(pool)));
    }
    Ok(())
}

/// A pool of `threads` threads (their stacks counted first, as the global pool's).
fn new_pool(threads: usize) -> Result<rayon::ThreadPool, String> {
    raypick::budget::prepare_threads(threads)?;
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(|i| format!("raypick-{i}"))
        .build()
        .map_err(|e| e.to_string())
}

/// `_set_threads(n)`: trace on `n` threads from now on in this process; 0 goes back to one
/// thread per core.
#[pyfunction]
#[pyo3(name = "_set_threads")]
pub fn set_threads(#[pyo3(from_py_with = thread_count)] threads: usize) -> PyResult<()> {
    let new = match threads {
        0 => None,
        _ => Some((
            std::process::id(),
            Arc::new(new_pool(threads).map_err(|e| {
                PyValueError::new_err(format!("cannot start {threads} threads: {e}"))
            })?),
        )),
    };
    *POOL.lock().unwrap_or_else(PoisonError::into_inner) = new;
    // Back to the global pool: started here, or a forked process's own made again.
    ready()
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
    on_pool(rayon::current_num_threads)
}
