//! `raypick build`: loads a scene, builds every tree the backends use (the kernel's and the
//! CPU engine's) and saves the whole built scene as a `.rpk` file (`raypick::rpk`), which
//! `--scene FILE.rpk` then loads in any command with no rebuild.

use super::scene_args::SceneArgs;
use clap::{ArgMatches, Args};
use raypick::Error;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args, Debug)]
pub struct BuildArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// The `.rpk` file to write (replaced if it exists; written beside it and renamed into
    /// place, so it is never left half-written).
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
}

pub fn run(args: BuildArgs, matches: &ArgMatches) -> Result<ExitCode, Error> {
    let (built, load_s, build_s) = args.scene.build_timed(matches)?;
    let start = std::time::Instant::now();
    super::progress::phase("saving the built scene", || {
        raypick::rpk::save(&built, &args.out)
    })?;
    if !super::progress::is_quiet() {
        eprintln!(
            "wrote {}: {} triangles, {} objects (loaded in {:.0} ms, built in {:.0} ms, saved in {:.0} ms)",
            args.out.display(),
            built.scene.triangle_count(),
            built.scene.objects().len(),
            load_s * 1e3,
            build_s * 1e3,
            start.elapsed().as_secs_f64() * 1e3
        );
    }
    Ok(ExitCode::SUCCESS)
}
