//! `raypick pick`: answers rays from a file, or the pixels of a camera view.

use super::query_args::QueryArgs;
use super::scene_args::SceneArgs;
use super::{make_picker, progress, show_notes, stream_chunk_rays, write_output};
use clap::{ArgMatches, Args};
use raypick::apps::camera::Camera;
use raypick::check::synthetic::{RayKind, rays as synthetic_rays};
use raypick::io::output::{AnswerWriter, Format, OutputOptions};
use raypick::io::pixel_file::load_pixel_indices_as_centers;
use raypick::io::ray_file::{RayReader, count_rays};
use raypick::{Answers, Backend, Error, Ray};
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
    #[arg(long, value_parser = crate::cli::choice::choice::<Backend>(), default_value_t = Backend::Auto)]
    pub backend: Backend,
    /// Output format.
    #[arg(long, value_parser = crate::cli::choice::choice::<Format>(), default_value_t = Format::Csv)]
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
    // A ray file is read in chunks while answers are written (memory bounded whatever its
    // length); it is first checked whole, line by line in constant memory, so that a bad line is
    // reported before any output. Camera pixels and the default camera grid are small.
    let rays: Vec<Ray> = match (&args.rays, &args.camera, &args.pixels) {
        (Some(_), _, _) => Vec::new(),
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
    let mut reader = match &args.rays {
        Some(path) => {
            let total = if std::fs::metadata(path).is_ok_and(|m| m.is_file()) {
                Some(count_rays(path)?)
            } else {
                None
            };
            Some((RayReader::open(path)?, total))
        }
        None => None,
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
    let total = match &reader {
        Some((_, total)) => total.unwrap_or(0),
        None => rays.len() as u64,
    };
    let bar = progress::rays_bar(total, "picking");
    write_output(args.out.as_deref(), |out| {
        let mut writer = AnswerWriter::begin(out, options)?;
        let mut sink = |answers: Answers| {
            bar.inc(answers.nearest.len() as u64);
            invalid += answers.nearest.iter().filter(|h| h.invalid).count();
            writer.write(out, &answers).map_err(|source| Error::Io {
                path: "output".into(),
                source,
            })
        };
        let result = match reader.as_mut() {
            Some((reader, _)) => {
                let (mut lines, mut batch) = (Vec::new(), Vec::new());
                // Ray-file chunks stay small enough to keep a pick of millions of rays in
                // a few hundred MB (a chunk's rays, scene-frame rays and answers).
                let chunk = chunk.min(1 << 18);
                (|| {
                    while reader.read_chunk(&mut lines, chunk)? > 0 {
                        batch.clear();
                        batch.extend(lines.iter().map(|r| {
                            Ray::new(r.origin, r.dir)
                                .with_range(q.tmin, r.tmax.unwrap_or(q.tmax))
                                .with_mask(q.ray_mask)
                        }));
                        sink(picker.query(&batch, &query)?)?;
                    }
                    Ok(())
                })()
            }
            None => picker.query_chunked(&rays, &query, chunk, &mut |_, answers| sink(answers)),
        };
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
