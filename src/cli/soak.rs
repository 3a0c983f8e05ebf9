//! `raypick soak`: sends many batches of rays through the GPU picker with the scene resident,
//! checks a sample of every batch against the CPU path, and tracks resident memory, which must
//! stay flat.

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
    /// Rays per batch.
    #[arg(long, default_value_t = 1_000_000)]
    pub batch: usize,
    /// Rays of each batch compared with the CPU path.
    #[arg(long, default_value_t = 1000)]
    pub check: usize,
    /// Seed of the first batch (batch k uses seed + k).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

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
    // One batch of rays is generated, traced and compared at a time.
    super::check_rays(
        &format!("--batch {}", args.batch),
        args.batch as u64,
        &Query::default(),
    )?;
    let built = Arc::new(args.scene.build(matches)?);
    let context = GpuContext::new()?;
    let mut gpu = GpuPicker::new(&context, built.clone())?;
    let mut cpu = CpuPicker::new(built.clone());
    let batches = args.rays.div_ceil(args.batch as u64);
    println!(
        "soak: {} rays in {batches} batches of {} on {}; {} rays of each batch checked against the CPU path",
        args.rays,
        args.batch,
        context.describe(),
        args.check
    );
    println!(
        "{:>8} {:>12} {:>10} {:>12} {:>10} {:>11}",
        "batch", "rays", "gpu s", "gpu rays/s", "rss MiB", "mismatches"
    );
    let (mut gpu_seconds, mut sent, mut mismatches) = (0.0, 0u64, 0usize);
    let mut rss: Vec<f64> = Vec::new();
    let started = Instant::now();
    for b in 0..batches {
        let n = (args.rays - sent).min(args.batch as u64) as usize;
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
            println!(
                "{:>8} {:>12} {:>10.1} {:>12.0} {:>10.1} {:>11}",
                b + 1,
                sent,
                gpu_seconds,
                sent as f64 / gpu_seconds,
                rss[rss.len() - 1],
                mismatches
            );
        }
    }
    // Memory after the first few batches (buffers allocated) must not keep growing.
    let settled = &rss[rss.len().min(3) - 1..];
    let (low, high) = settled
        .iter()
        .fold((f64::INFINITY, 0f64), |(l, h), &r| (l.min(r), h.max(r)));
    println!(
        "\n{sent} rays in {:.1} s ({:.1} s on the GPU); resident memory after warm-up {low:.1}..{high:.1} MiB; {mismatches} mismatches in {} checked rays",
        started.elapsed().as_secs_f64(),
        gpu_seconds,
        batches as usize * args.check.min(args.batch)
    );
    Ok(if mismatches == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}
