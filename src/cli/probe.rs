//! `raypick probe`: watertightness probes (rays aimed exactly at shared edges and interior
//! vertices) through both intersectors on both paths; reports leaks and throughput.

use super::scene_args::SceneArgs;
use clap::{ArgMatches, Args};
use raypick::check::probe::edge_probes;
use raypick::{CpuPicker, Error, GpuContext, GpuPicker, Intersector, Picker, Query};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Instant;

#[derive(Args, Debug)]
pub struct ProbeArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Number of probes.
    #[arg(long, default_value_t = 1_000_000)]
    pub probes: usize,
    /// Seed for the probes.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// Checks `count` probes against the memory budget: each a ray answered in one batch (per path
/// and intersector), with its slack.
fn check_probes(count: usize) -> Result<(), Error> {
    raypick::budget::check(
        &format!("--probes {count}"),
        count as u64,
        Query::default().bytes_per_ray() + size_of::<f64>() as u64,
    )
}

pub fn run(args: ProbeArgs, matches: &ArgMatches) -> Result<ExitCode, Error> {
    if args.probes == 0 {
        return Err(Error::Invalid(
            "--probes 0 asks for no probes; give at least 1".into(),
        ));
    }
    check_probes(args.probes)?;
    let built = Arc::new(args.scene.build(matches)?);
    let probes = edge_probes(&built.scene, args.probes, args.seed);
    if probes.is_empty() {
        return Err(Error::Invalid(
            "the scene has no edge to probe: none shared by two triangles, or none whose triangles \
             are wide enough around it for the f32 ray's rounding (slivers)"
                .into(),
        ));
    }
    let context = GpuContext::new()?;
    say!(
        "{} probes at shared edges and interior vertices; gpu: {}",
        probes.len(),
        context.describe()
    )?;
    let mut gpu = GpuPicker::new(&context, built.clone())?;
    // Again with what the GPU's driver left (under `ulimit -v` its mappings count).
    check_probes(args.probes)?;
    let mut cpu = CpuPicker::new(built);
    let mut watertight_leaks = 0;
    say!(
        "{:<16} {:<5} {:>9} {:>14}",
        "intersector",
        "path",
        "leaks",
        "rays/s"
    )?;
    for intersector in [Intersector::MollerTrumbore, Intersector::Watertight] {
        let query = Query {
            intersector,
            ..Query::default()
        };
        for (name, picker) in [
            ("cpu", &mut cpu as &mut dyn Picker),
            ("gpu", &mut gpu as &mut dyn Picker),
        ] {
            let start = Instant::now();
            let answers = picker.query(&probes.rays, &query)?;
            let seconds = start.elapsed().as_secs_f64();
            let leaked = probes.leaks(&answers.nearest);
            if intersector == Intersector::Watertight {
                watertight_leaks += leaked;
            }
            say!(
                "{:<16} {name:<5} {leaked:>9} {:>14.0}",
                intersector.to_string(),
                probes.len() as f64 / seconds
            )?;
        }
    }
    Ok(if watertight_leaks == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}
