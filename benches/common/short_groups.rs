//! The sampling the lever benches share: 10 flat samples over a short window, so each bench
//! stays within a few minutes on 2 cores while routines run for milliseconds to a second.

use criterion::{BenchmarkGroup, SamplingMode, measurement::WallTime};
use std::time::Duration;

pub fn configure(group: &mut BenchmarkGroup<'_, WallTime>) {
    group
        .sample_size(10)
        .sampling_mode(SamplingMode::Flat)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2));
}
