//! Owns the start of the picking threads (rayon's global pool): started before any command
//! runs, and refused with a sentence, before any thread is made, when their stacks could not
//! fit the address space `ulimit -v` leaves.
//!
//! rayon starts its threads at the first parallel call otherwise, and panics there when the
//! system refuses one. Building the pool early turns a refusal into an error; but threads that
//! did start run on, and under a tight limit one of them, or the main thread, could then fail a
//! small allocation and abort the process before the error was said (seen once in CI with
//! `RAYON_NUM_THREADS=5000` under `ulimit -v 1000000`). So the stacks are counted first.

use raypick::budget;

/// The stack a thread rayon starts asks for: `RUST_MIN_STACK` (as the standard library reads
/// it), else the standard library's 2 MiB.
fn stack_bytes() -> u64 {
    std::env::var("RUST_MIN_STACK")
        .ok()
        .and_then(|s| s.trim().parse::<u64>().ok())
        .unwrap_or(2 << 20)
}

/// The threads rayon's global pool will start: `RAYON_NUM_THREADS` when it is a positive count,
/// else one per core.
fn thread_count() -> u64 {
    std::env::var("RAYON_NUM_THREADS")
        .ok()
        .and_then(|s| s.trim().parse::<u64>().ok())
        .filter(|&n| n > 0)
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get() as u64))
}

/// Starts the global pool; the sentence to print when its threads cannot be started.
pub fn start() -> Result<(), String> {
    let advice = "raise `ulimit -v` or set RAYON_NUM_THREADS to fewer threads";
    let threads = thread_count();
    // A stack and its guard page each; at most half of what the limit leaves, as every other
    // size is checked (`raypick::budget`).
    let needed = threads.saturating_mul(stack_bytes().saturating_add(4096));
    if let Some(left) = budget::address_space_left()
        && needed > left / 2
    {
        return Err(format!(
            "cannot start the picking threads ({threads} threads need {} of address space for \
             their stacks, more than half of the {} `ulimit -v` leaves); {advice}",
            budget::human(needed),
            budget::human(left)
        ));
    }
    rayon::ThreadPoolBuilder::new()
        .build_global()
        .map_err(|e| format!("cannot start the picking threads ({e}); {advice}"))
}
