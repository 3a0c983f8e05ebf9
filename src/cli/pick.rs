//! `raypick pick`: answers rays from a file, or the pixels of a camera view.

use super::query_args::QueryArgs;
use super::scene_args::SceneArgs;
use super::{make_picker, progress, read_rays, show_notes, stream_chunk_rays, write_output};
use clap::{ArgMatches, Args};
use raypick::camera::{Camera, load_pixel_indices_as_centers};
use raypick::io::output::{AnswerWriter, Format, OutputOptions};
use raypick::synthetic::{RayKind, rays as synthetic_rays};
use raypick::{Backend, Error, Ray};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

#[derive(Args, Debug)]
pub struct PickArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Ray file: one ray per line, `ox oy oz dx dy dz [tmax]`, `#` starts a comment. Default
    /// (without --camera): an 8 × 8 camera grid over the scene.
    #[arg(long, conflicts_with = "camera")]
    pub rays: Option<PathBuf>,
    /// Camera file (JSON: perspective, orthographic or matrices); pick its pixels.
    #[arg(long, requires = "pixels")]
    pub camera: Option<PathBuf>,
    /// Pixel file for --camera: one `x y` per line, top-left origin; integers name whole pixels
    /// and are picked through their centres (x + 0.5, y + 0.5).
    #[arg(long, requires = "camera")]
    pub pixels: Option<PathBuf>,
    #[command(flatten)]
    pub query: QueryArgs,
    /// Which path answers.
    #[arg(long, value_enum, default_value_t = Backend::Auto)]
    pub backend: Backend,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Csv)]
    pub format: Format,
    /// Output file (default: standard output).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

pub fn run(args: PickArgs, matches: &ArgMatches) -> Result<ExitCode, Error> {
    let q = &args.query;
    // Arguments are checked before anything is read or written.
    let query = q.query();
    query.validate()?;
    let built = Arc::new(args.scene.build(matches)?);
    let rays: Vec<Ray> = match (&args.rays, &args.camera, &args.pixels) {
        (Some(path), _, _) => read_rays(path, q.tmin, q.tmax, q.ray_mask)?,
        (None, Some(camera), Some(pixels)) => {
            let camera = Camera::from_json_file(camera)?;
            load_pixel_indices_as_centers(pixels)?
                .into_iter()
                .map(|(x, y)| {
                    camera
                        .pixel_ray(x, y)
                        .with_range(q.tmin, q.tmax)
                        .with_mask(q.ray_mask)
                })
                .collect()
        }
        _ => synthetic_rays(&built.scene, RayKind::Camera, 64, 1)
            .into_iter()
            .map(|r| r.with_range(q.tmin, q.tmax).with_mask(q.ray_mask))
            .collect(),
    };
    let options = OutputOptions {
        format: args.format,
        mode: q.mode,
        cells: built.scene.objects().iter().any(|o| o.grid.is_some()),
    };
    let mut picker = make_picker(args.backend, built)?;
    let mut invalid = 0;
    let mut failure = None;
    // Large batches stream: answers are written chunk by chunk, so memory stays bounded. In
    // all-hits mode the chunk shrinks so that its lists fit the memory budget.
    let chunk = stream_chunk_rays(&query);
    let bar = progress::rays_bar(rays.len() as u64, "picking");
    write_output(args.out.as_deref(), |out| {
        let mut writer = AnswerWriter::begin(out, options)?;
        let result = picker.query_chunked(&rays, &query, chunk, &mut |_, answers| {
            bar.inc(answers.nearest.len() as u64);
            invalid += answers.nearest.iter().filter(|h| h.invalid).count();
            writer.write(out, &answers).map_err(|source| Error::Io {
                path: "output".into(),
                source,
            })
        });
        if let Err(e) = result {
            failure = Some(e);
            return Ok(());
        }
        writer.finish(out)
    })?;
    bar.finish_and_clear();
    show_notes(picker.as_mut());
    if let Some(e) = failure {
        return Err(e);
    }
    if invalid > 0 {
        eprintln!(
            "warning: {invalid} ray(s) were invalid (NaN or infinite values, a zero direction or one \
             too short or too long to normalize, or tmin > tmax) and are reported as misses"
        );
    }
    Ok(ExitCode::SUCCESS)
}
