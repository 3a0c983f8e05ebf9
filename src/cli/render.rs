//! `raypick render`: a ray-cast picture of a scene (one closest-hit ray per pixel), written as a
//! PNG, shaded by normal (hillshade), depth or object id.

use super::make_picker;
use super::scene_args::SceneArgs;
use clap::{ArgMatches, Args};
use glam::DVec3;
use raypick::apps::camera::Camera;
use raypick::apps::render::{Shade, check_size, render};
use raypick::{Backend, Error};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

#[derive(Args, Debug)]
pub struct RenderArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Camera file (JSON: perspective, orthographic or matrices); its size is the image's.
    /// Default: a perspective view from the south-south-west, 45° up, framing the whole scene.
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// The PNG file to write.
    #[arg(long)]
    pub out: PathBuf,
    /// How pixels are coloured (misses show the sky).
    #[arg(long, value_parser = crate::cli::choice::choice::<Shade>(), default_value_t = Shade::Normal)]
    pub shade: Shade,
    /// Image width in pixels, without --camera [default: 800].
    #[arg(long, conflicts_with = "camera")]
    pub width: Option<u32>,
    /// Image height in pixels, without --camera [default: 600].
    #[arg(long, conflicts_with = "camera")]
    pub height: Option<u32>,
    /// Which path answers.
    #[arg(long, value_parser = crate::cli::choice::choice::<Backend>(), default_value_t = Backend::Auto)]
    pub backend: Backend,
}

pub fn run(args: RenderArgs, matches: &ArgMatches) -> Result<ExitCode, Error> {
    // The size is checked (against the memory budget too) before the scene is loaded.
    let camera = match &args.camera {
        Some(path) => Some(Camera::from_json_file(path)?),
        None => None,
    };
    let (width, height) = match &camera {
        Some(camera) => (camera.width(), camera.height()),
        None => (args.width.unwrap_or(800), args.height.unwrap_or(600)),
    };
    if width == 0 || height == 0 {
        return Err(Error::Invalid(format!(
            "the image is {width} x {height} pixels; --width and --height must be at least 1"
        )));
    }
    check_size(width, height)?;
    let built = Arc::new(args.scene.build(matches)?);
    let camera = camera.unwrap_or_else(|| {
        let (min, max) = built.scene.bounds().unwrap_or((DVec3::ZERO, DVec3::ZERO));
        Camera::frame_bounds(min, max, width, height)
    });
    let mut picker = make_picker(args.backend, built)?;
    let image = render(picker.as_mut(), &camera, args.shade)?;
    image.save_png(&args.out)?;
    Ok(ExitCode::SUCCESS)
}
