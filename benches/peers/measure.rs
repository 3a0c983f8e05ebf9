//! Timing and checking outside criterion: medians of repeated runs, single-ray latency
//! percentiles, and the agreement check every engine's answers go through before they count.

use crate::engines::Engine;
use raypick::layout::GpuRay;
use std::time::Instant;

/// Single-ray calls before the latency samples.
const WARM_UP_PICKS: usize = 50;

/// The median of `samples` (the mean of the middle two for an even count).
pub fn median(mut samples: Vec<f64>) -> f64 {
    assert!(!samples.is_empty(), "a median needs samples");
    samples.sort_by(f64::total_cmp);
    let n = samples.len();
    if n % 2 == 1 {
        samples[n / 2]
    } else {
        (samples[n / 2 - 1] + samples[n / 2]) / 2.0
    }
}

/// Runs `f` and returns its value and the milliseconds it took.
pub fn timed_ms<T>(f: impl FnOnce() -> T) -> (T, f64) {
    let start = Instant::now();
    let value = f();
    (value, start.elapsed().as_secs_f64() * 1e3)
}

/// Times each of `rows` in interleaved rounds and returns each row's median in milliseconds:
/// round `k` runs, in turn, every row that takes part in at least `k + 1` rounds (`rounds`), so
/// that the rows' samples are taken at the same moments of a noisy machine. Each row's first
/// run's output goes to `check` before the next row runs (the agreement check; that run is
/// timed too).
pub fn time_in_rounds<R: Copy, T>(
    rows: &[R],
    mut run: impl FnMut(R) -> T,
    rounds: impl Fn(R) -> usize,
    mut check: impl FnMut(R, T),
) -> Vec<f64> {
    let mut samples: Vec<Vec<f64>> = vec![Vec::new(); rows.len()];
    let most = rows.iter().map(|&r| rounds(r).max(1)).max().unwrap_or(0);
    for round in 0..most {
        for (&row, samples) in rows.iter().zip(&mut samples) {
            if round >= rounds(row).max(1) {
                continue;
            }
            let (out, ms) = timed_ms(|| run(row));
            samples.push(ms);
            if round == 0 {
                check(row, out);
            }
        }
    }
    samples.into_iter().map(median).collect()
}

/// Single-ray latency with the scene resident: p50 and p99 in microseconds over `picks` calls
/// of `Engine::intersect` (after a warm-up), on rays taken evenly across `rays` (a camera
/// batch's first rows may all look at the sky).
pub fn latency_us(engine: &dyn Engine, rays: &[GpuRay], picks: usize) -> (f64, f64) {
    let stride = (rays.len() / picks.max(1)).max(1);
    let spread = rays.iter().step_by(stride).cycle();
    let mut samples = Vec::with_capacity(picks);
    for (i, ray) in spread.take(WARM_UP_PICKS + picks).enumerate() {
        let start = Instant::now();
        std::hint::black_box(engine.intersect(std::hint::black_box(ray)));
        if i >= WARM_UP_PICKS {
            samples.push(start.elapsed().as_secs_f64() * 1e6);
        }
    }
    samples.sort_by(f64::total_cmp);
    (percentile(&samples, 50.0), percentile(&samples, 99.0))
}

/// Nearest-rank percentile of sorted `samples`.
fn percentile(samples: &[f64], p: f64) -> f64 {
    let rank = ((p / 100.0) * samples.len() as f64).ceil() as usize;
    samples[rank.clamp(1, samples.len()) - 1]
}

/// Prints how often `theirs` agrees with the reference (raypick's CPU traversal) on hit/miss
/// and on t (relative 1e-4), so a mis-set-up engine cannot pass unnoticed.
pub fn report_agreement(
    scene: &str,
    engine: &str,
    set: &str,
    reference: &[Option<f32>],
    theirs: &[Option<f32>],
) {
    assert_eq!(reference.len(), theirs.len(), "one answer per ray");
    let (mut hits, mut same_outcome, mut same_t) = (0, 0, 0);
    for (a, b) in reference.iter().zip(theirs) {
        hits += usize::from(a.is_some());
        match (a, b) {
            (None, None) => {
                same_outcome += 1;
                same_t += 1;
            }
            (Some(a), Some(b)) => {
                same_outcome += 1;
                if (a - b).abs() <= 1e-4 * a.abs().max(1.0) {
                    same_t += 1;
                }
            }
            _ => {}
        }
    }
    let n = reference.len();
    eprintln!(
        "{scene}: {engine} vs raypick-reference, {set}: raypick hits {hits}/{n}; same hit/miss {same_outcome}, \
         same t {same_t}{}",
        if same_t == n { "" } else { " (differs)" }
    );
}
