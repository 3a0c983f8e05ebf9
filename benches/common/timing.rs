//! The median of repeated wall-clock runs, in milliseconds, that the benches print before
//! criterion runs.

use std::time::Instant;

#[allow(dead_code)]
pub fn median_ms(runs: usize, mut run: impl FnMut()) -> f64 {
    let mut times: Vec<f64> = (0..runs)
        .map(|_| {
            let start = Instant::now();
            run();
            start.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    times.sort_by(f64::total_cmp);
    times[times.len() / 2]
}

/// The medians of `runs` rounds of each of `jobs`, run in turn within each round (so a slow
/// spell on a shared machine falls on all of them alike), in milliseconds.
#[allow(dead_code)]
pub fn interleaved_medians_ms<const N: usize>(
    runs: usize,
    jobs: [&mut dyn FnMut(); N],
) -> [f64; N] {
    let mut jobs = jobs;
    let mut times = vec![Vec::with_capacity(runs); N];
    for _ in 0..runs {
        for (job, times) in jobs.iter_mut().zip(&mut times) {
            let start = Instant::now();
            job();
            times.push(start.elapsed().as_secs_f64() * 1e3);
        }
    }
    std::array::from_fn(|k| {
        times[k].sort_by(f64::total_cmp);
        times[k][runs / 2]
    })
}
