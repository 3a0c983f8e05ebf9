//! `raypick example`: writes the built-in example scene as files (an ESRI ASCII grid, two OBJ
//! files and a scene description with layer masks), so that the README's file examples and a
//! newcomer's first `--scene` have files to load that answer exactly as the built-in scene.

use clap::Args;
use raypick::Error;
use raypick::check::synthetic::example_scene_files;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args, Debug)]
pub struct ExampleArgs {
    /// The folder to write terrain.asc, tower.obj, hall.obj and scene.json into (made if
    /// missing; files of those names are replaced).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

pub fn run(args: ExampleArgs) -> Result<ExitCode, Error> {
    let io_error = |path: &PathBuf| {
        let path = path.display().to_string();
        move |source| Error::Io { path, source }
    };
    std::fs::create_dir_all(&args.out).map_err(io_error(&args.out))?;
    for (name, text) in example_scene_files() {
        let path = args.out.join(name);
        std::fs::write(&path, text).map_err(io_error(&path))?;
        say!("{}", path.display())?;
    }
    Ok(ExitCode::SUCCESS)
}
