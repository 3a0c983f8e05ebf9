//! Ctrl-C during a long pick. Tracing runs without the interpreter, on rayon's threads, so a
//! SIGINT only set Python's flag, and the `KeyboardInterrupt` came once the whole pick was done
//! (minutes, for a large one). A pick runs in batches ([`crate::pick::answer`]), and between
//! two batches, at most every [`EVERY`], it takes the interpreter back for a moment to run
//! Python's signal handlers (`py.check_signals()`): what a handler raises (`KeyboardInterrupt`)
//! stops the pick there and is raised by it.
//!
//! Python runs signal handlers on its main thread only, so a pick on another thread (a Dask
//! worker's) asks once whether it is on the main thread and, being not, never takes the
//! interpreter between its batches.

use pyo3::prelude::*;
use std::time::{Duration, Instant};

/// The least time between two checks: a Ctrl-C stops a pick within about this much more than a
/// batch. Taking the interpreter back waits for it when another Python thread runs (up to its
/// switch interval, 5 ms): at 50 ms between checks a 1M-ray pick beside a busy thread was
/// 10–20% slower (a review's measurement), at 200 ms that share is a quarter as large.
pub const EVERY: Duration = Duration::from_millis(200);

/// The signal checks of one pick, made between its batches without the interpreter.
pub struct Interrupts {
    /// When the pick started, or was last checked.
    last: Instant,
    /// Whether the pick runs on Python's main thread, once asked.
    main: Option<bool>,
}

impl Interrupts {
    /// The checks of a pick starting now.
    pub fn new() -> Self {
        Self {
            last: Instant::now(),
            main: None,
        }
    }

    /// Between two batches, without the interpreter: runs Python's signal handlers when
    /// [`EVERY`] has passed since the last check, and returns what they raised.
    pub fn check(&mut self) -> PyResult<()> {
        if self.main == Some(false) || self.last.elapsed() < EVERY {
            return Ok(());
        }
        let result = Python::attach(|py| {
            let main = match self.main {
                Some(main) => main,
                None => *self.main.insert(on_main_thread(py)?),
            };
            if main { py.check_signals() } else { Ok(()) }
        });
        self.last = Instant::now();
        result
    }
}

/// Whether this is Python's main thread (the one its signal handlers run on). Asking runs
/// Python code, which runs the handlers of signals already come: what they raise is returned
/// (taking it for "not the main thread" lost a Ctrl-C that came during the first batch).
fn on_main_thread(py: Python<'_>) -> PyResult<bool> {
    let threading = py.import("threading")?;
    let main = threading.call_method0("main_thread")?.getattr("ident")?;
    main.eq(threading.call_method0("get_ident")?)
}
