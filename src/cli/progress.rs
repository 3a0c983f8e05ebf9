//! Progress on standard error for the slow steps (loading, building, large batches), drawn only
//! on a terminal and never with `--quiet` (which also leaves out `pick`'s summary line).

use indicatif::{ProgressBar, ProgressStyle};
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
    spinner.enable_steady_tick(Duration::from_millis(120));
    let value = work();
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
