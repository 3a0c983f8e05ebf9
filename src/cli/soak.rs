//! `raypick soak`: sends many batches of rays through the GPU picker with the scene resident,
//! checks a sample of every batch against the CPU path, and tracks resident memory: after the
//! first batches (warm-up: buffers allocated) it may grow by at most `--max-growth` MiB. Exits 1
//! on a mismatch or on more growth than that.

use super::scene_args::SceneArgs;
use clap::{ArgMatches, Args};
use raypick::check::compare::Tally;
use raypick::check::synthetic::mixed_rays;
use raypick::{CpuPicker, Error, GpuContext, GpuPicker, Picker, Query, Ray};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Instant;

#[derive(Args, Debug)]
pub struct SoakArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Total rays to send.
    #[arg(long, default_value_t = 100_000_000)]
    pub rays: u64,
    /// Rays per batch (at most --rays).
    #[arg(long, default_value_t = 1_000_000)]
    pub batch: usize,
    /// Rays of each batch compared with the CPU path.
    #[arg(long, default_value_t = 1000)]
    pub check: usize,
    /// Seed of the first batch (batch k uses seed + k).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Most growth of resident memory allowed after the warm-up batches, in MiB; more exits 1.
    #[arg(long, value_name = "MIB", default_value_t = DEFAULT_MAX_GROWTH_MIB, allow_hyphen_values = true)]
    pub max_growth: f64,
}

/// The default of `--max-growth`, in MiB.
pub const DEFAULT_MAX_GROWTH_MIB: f64 = 64.0;

/// Batches before resident memory is expected to stay flat (buffers are allocated and grown in
/// the first ones).
const WARM_UP_BATCHES: usize = 3;

/// Resident set size of this process in MiB (Linux), or NaN where unknown.
fn resident_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines().find(|l| l.starts_with("VmRSS:")).and_then(|l| {
                l.split_whitespace()
                    .nth(1)
                    .and_then(|kb| kb.parse::<f64>().ok())
            })
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

pub fn run(args: SoakArgs, matches: &ArgMatches) -> Result<ExitCode, Error> {
    if args.rays == 0 || args.batch == 0 {
        return Err(Error::Invalid(format!(
            "--rays {} --batch {}: both must be at least 1",
            args.rays, args.batch
        )));
    }
    if !(args.max_growth.is_finite() && args.max_growth >= 0.0) {
        return Err(Error::Invalid(format!(
            "--max-growth {} is not a size in MiB; give a number of at least 0",
            args.max_growth
        )));
    }
    // A batch is never larger than the whole run.
    let batch = args
        .batch
        .min(usize::try_from(args.rays).unwrap_or(usize::MAX));
    // One batch of rays is generated, traced and compared at a time.
    super::check_rays(&format!("--batch {batch}"), batch as u64, &Query::default())?;
    let built = Arc::new(args.scene.build_owned(matches)?);
    let context = GpuContext::new()?;
    let mut gpu = GpuPicker::new(&context, built.clone())?;
    // Again with what the GPU's driver left (under `ulimit -v` its mappings count).
    super::check_rays(&format!("--batch {batch}"), batch as u64, &Query::default())?;
    let mut cpu = CpuPicker::new(built.clone());
    let batches = args.rays.div_ceil(batch as u64);
    let checked = args.check.min(batch);
    say!(
        "soak: {} rays in {batches} {} of {batch} on {}; {checked} rays of each batch checked \
         against the CPU path; resident memory may grow by {} MiB after {WARM_UP_BATCHES} \
         warm-up batches",
        args.rays,
        if batches == 1 { "batch" } else { "batches" },
        context.describe(),
        args.max_growth
    )?;
    say!("rays, GPU seconds and mismatches are totals so far; rays/s is their ratio")?;
    say!(
        "{:>8} {:>12} {:>10} {:>12} {:>10} {:>11}",
        "batch",
        "rays",
        "gpu s",
        "gpu rays/s",
        "rss MiB",
        "mismatches"
    )?;
    let (mut gpu_seconds, mut sent, mut mismatches) = (0.0, 0u64, 0usize);
    let mut rss: Vec<f64> = Vec::new();
    let started = Instant::now();
    for b in 0..batches {
        let n = (args.rays - sent).min(batch as u64) as usize;
        let rays: Vec<Ray> = mixed_rays(&built.scene, n, args.seed + b)
            .into_iter()
            .map(|(_, r)| r)
            .collect();
        let start = Instant::now();
        let hits = gpu.pick(&rays)?;
        gpu_seconds += start.elapsed().as_secs_f64();
        let sample = &rays[..args.check.min(n)];
        let reference = cpu.pick(sample)?;
        let (tally, _) = Tally::compare(&built.scene, sample, &hits[..sample.len()], &reference);
        mismatches += tally.mismatches;
        sent += n as u64;
        rss.push(resident_mib());
        if b < 3 || (b + 1) % 10 == 0 || b + 1 == batches {
            say!(
                "{:>8} {:>12} {:>10.1} {:>12.0} {:>10.1} {:>11}",
                b + 1,
                sent,
                gpu_seconds,
                sent as f64 / gpu_seconds,
                rss[rss.len() - 1],
                mismatches
            )?;
        }
    }
    // Memory after the warm-up batches (buffers allocated) must not keep growing.
    let growth = growth_after_warm_up(&rss);
    say!(
        "\n{sent} rays in {:.1} s ({:.1} s on the GPU); resident memory grew by {growth:.1} MiB \
         after warm-up (bound {} MiB); {mismatches} mismatches in {} checked rays",
        started.elapsed().as_secs_f64(),
        gpu_seconds,
        args.max_growth,
        batches as usize * checked
    )?;
    let mut failed = false;
    if mismatches > 0 {
        eprintln!("soak failed: {mismatches} GPU answers differ from the CPU path's");
        failed = true;
    }
    if growth > args.max_growth {
        eprintln!(
            "soak failed: resident memory grew by {growth:.1} MiB after warm-up, more than \
             --max-growth {} MiB",
            args.max_growth
        );
        failed = true;
    }
    Ok(if failed {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    })
}

/// How much resident memory (MiB, one reading per batch) rose above its reading at the end of
/// the warm-up batches (the last reading when there are no more batches than that: 0). Unknown
/// readings (NaN) count as no growth.
fn growth_after_warm_up(rss: &[f64]) -> f64 {
    let Some(&settled) = rss.get(WARM_UP_BATCHES.min(rss.len()).saturating_sub(1)) else {
        return 0.0;
    };
    rss.iter()
        .skip(WARM_UP_BATCHES)
        .map(|&r| r - settled)
        .filter(|g| !g.is_nan())
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::growth_after_warm_up;

    #[test]
    fn growth_is_measured_from_the_end_of_the_warm_up() {
        // Buffers grow in the first batches: that is not growth.
        assert_eq!(
            growth_after_warm_up(&[10.0, 50.0, 80.0, 80.0, 80.5, 80.0]),
            0.5
        );
        // A leak shows as the highest reading over the settled one.
        assert_eq!(growth_after_warm_up(&[10.0, 50.0, 80.0, 90.0, 100.0]), 20.0);
        // Falling memory is no growth; too few batches to tell is none either.
        assert_eq!(growth_after_warm_up(&[80.0, 80.0, 80.0, 70.0]), 0.0);
        assert_eq!(growth_after_warm_up(&[10.0, 500.0]), 0.0);
        assert_eq!(growth_after_warm_up(&[]), 0.0);
        // Unknown readings (no /proc) count as no growth.
        assert_eq!(growth_after_warm_up(&[f64::NAN; 5]), 0.0);
    }
}
