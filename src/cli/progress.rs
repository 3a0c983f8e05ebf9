//! Progress on standard error for the slow steps (loading, building, large batches), drawn only
//! on a terminal and never with `--quiet` (which also leaves out `pick`'s summary line).

use indicatif::{ProgressBar, ProgressStyle};
use std::io::IsTerminal;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

static QUIET: AtomicBool = AtomicBool::new(false);

/// Turns all progress display off (`--quiet`).
pub fn set_quiet(quiet: bool) {
    QUIET.store(quiet, Ordering::Relaxed);
}

fn hidden() -> bool {
    QUIET.load(Ordering::Relaxed)
}

/// Whether `--quiet` was given (summary lines are left out too).
pub fn is_quiet() -> bool {
    hidden()
}

/// Runs `work` behind a spinner saying `message` (with the time spent).
pub fn phase<T>(message: &str, work: impl FnOnce() -> T) -> T {
    if hidden() {
        return work();
    }
    let spinner = ProgressBar::new_spinner().with_message(message.to_string());
    if let Ok(style) = ProgressStyle::with_template("{spinner} {msg} ({elapsed})") {
        spinner.set_style(style);
    }
    // Ticked by a thread of its own while `work` runs, only where it is drawn (a terminal).
    // indicatif's own ticker panics when the system refuses the thread (a tight `ulimit -v`);
    // without it the spinner just stands still.
    let stop = Arc::new(AtomicBool::new(false));
    let ticker = std::io::stderr()
        .is_terminal()
        .then(|| {
            let (spinner, stop) = (spinner.clone(), stop.clone());
            std::thread::Builder::new()
                .name("progress".into())
                .spawn(move || {
                    while !stop.load(Ordering::Relaxed) {
                        spinner.tick();
                        std::thread::park_timeout(Duration::from_millis(120));
                    }
                })
                .ok()
        })
        .flatten();
    let value = work();
    stop.store(true, Ordering::Relaxed);
    if let Some(ticker) = ticker {
        ticker.thread().unpark();
        let _ = ticker.join();
    }
    spinner.finish_and_clear();
    value
}

/// A bar over `total` rays for a batch (hidden with `--quiet`).
pub fn rays_bar(total: u64, message: &str) -> ProgressBar {
    if hidden() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(total).with_message(message.to_string());
    if let Ok(style) = ProgressStyle::with_template(
        "{msg} [{bar:30}] {human_pos}/{human_len} rays ({per_sec}, {eta} left)",
    ) {
        bar.set_style(style.progress_chars("=> "));
    }
    bar
}
