//! `raypick build`: loads a scene, builds every tree the backends use (the kernel's and the
//! CPU engine's) and saves the whole built scene as a `.rpk` file (`raypick::rpk`), which
//! `--scene FILE.rpk` then loads in any command with no rebuild. A scene of instances (a file
//! listed several times, glTF nodes sharing a mesh) is saved as instances, each mesh once;
//! `pick`, `verify` and `serve` pick it so, the other commands bake it into copies.

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
    // Before the scene is built: a folder made the save fail with "Not a directory", and `-`
    // wrote a file of that name (a .rpk is read mapped from a file, not from a stream).
    if args.out.as_os_str() == "-" {
        return Err(Error::Invalid(
            "--out - (standard output) cannot hold a built scene: a .rpk is loaded mapped from \
             a file; name the .rpk file to write"
                .into(),
        ));
    }
    if args.out.is_dir() {
        return Err(Error::Invalid(format!(
            "--out {} is a folder; name the .rpk file to write",
            args.out.display()
        )));
    }
    // A description placing a file several times, or glTF nodes sharing a mesh, is saved as
    // instances (each mesh once).
    let (built, load_s, build_s) = args.scene.build_instanced(matches, false)?;
    let start = std::time::Instant::now();
    super::progress::phase("saving the built scene", || {
        raypick::rpk::save(&built, &args.out)
    })?;
    if !super::progress::is_quiet() {
        eprintln!(
            "wrote {}: {} triangles, {} objects{} (loaded in {:.0} ms, built in {:.0} ms, saved in {:.0} ms)",
            args.out.display(),
            built.world_triangle_count(),
            built.object_count(),
            super::scene_args::instances_of(&built).map_or(String::new(), |i| format!(" ({i})")),
            load_s * 1e3,
            build_s * 1e3,
            start.elapsed().as_secs_f64() * 1e3
        );
    }
    Ok(ExitCode::SUCCESS)
}
