//! `raypick render`: a ray-cast picture of a scene (one closest-hit ray per pixel), written as a
//! PNG, shaded by normal (hillshade), depth or object id.

use super::camera_args::{CameraArgs, warn_invalid_rays};
use super::make_picker;
use super::scene_args::SceneArgs;
use clap::{ArgMatches, Args};
use raypick::apps::render::{Shade, check_size, render};
use raypick::{Backend, Error};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

#[derive(Args, Debug)]
pub struct RenderArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    #[command(flatten)]
    pub view: CameraArgs,
    /// The PNG file to write (`-`: standard output).
    #[arg(long)]
    pub out: PathBuf,
    /// How pixels are coloured (misses show the sky).
    #[arg(long, value_parser = crate::cli::choice::choice::<Shade>(), default_value_t = Shade::Normal)]
    pub shade: Shade,
    /// Which path answers.
    #[arg(long, value_parser = crate::cli::choice::choice::<Backend>(), default_value_t = Backend::Auto)]
    pub backend: Backend,
}

pub fn run(args: RenderArgs, matches: &ArgMatches) -> Result<ExitCode, Error> {
    // A name of another picture format got PNG bytes without a word.
    if let Some(extension) = args.out.extension()
        && !extension.eq_ignore_ascii_case("png")
    {
        return Err(Error::Invalid(format!(
            "--out {} names a .{} file, but render writes PNG only; name it .png",
            args.out.display(),
            extension.to_string_lossy()
        )));
    }
    // The size is checked (against the memory budget too) before the scene is loaded.
    let view = args.view.view()?;
    check_size(view.width, view.height)?;
    let built = Arc::new(args.scene.build(matches)?);
    let camera = view.camera(&built);
    let mut picker = make_picker(args.backend, built.clone())?;
    let image = render(picker.as_mut(), &camera, args.shade)?;
    let size = (camera.width(), camera.height());
    warn_invalid_rays(&built, &camera, ((0, 0), size, 1), u32::MAX);
    let png = image.to_png()?;
    super::write_output(Some(&args.out), |out| out.write_all(&png))?;
    Ok(ExitCode::SUCCESS)
}
