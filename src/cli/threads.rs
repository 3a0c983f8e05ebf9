//! Owns the start of the picking threads (rayon's global pool): started before any command
//! runs, with the count rayon would take from the environment, and refused with a sentence,
//! before any thread is made, when they could not fit the address space `ulimit -v` leaves
//! ([`raypick::budget::prepare_threads`]).
//!
//! rayon starts its threads at the first parallel call otherwise, and panics there when the
//! system refuses one.

use raypick::budget;

/// Starts the global pool; the sentence to print when its threads cannot be started.
pub fn start() -> Result<(), String> {
    let advice = "raise `ulimit -v` or set RAYON_NUM_THREADS to fewer threads";
    let threads = budget::global_thread_count();
    budget::prepare_threads(threads)
        .and_then(|()| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build_global()
                .map_err(|e| e.to_string())
        })
        .map_err(|why| format!("cannot start the picking threads ({why}); {advice}"))
}
