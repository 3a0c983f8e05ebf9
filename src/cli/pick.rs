//! `raypick pick`: answers rays from a file, or the pixels of a camera view.

use super::query_args::QueryArgs;
use super::scene_args::SceneArgs;
use super::{make_picker, output_format, progress, show_notes, stream_chunk_rays, write_output};
use clap::{ArgMatches, Args};
use glam::DVec3;
use raypick::apps::camera::Camera;
use raypick::io::output::{AnswerWriter, Format, OutputOptions, csv_number};
use raypick::io::pixel_file::load_pixel_indices_as_centers;
use raypick::io::ray_file::{MIN_RAY_LINE, RayLine, RayReader, count_rays, load_ray_chunks};
use raypick::{Answers, Backend, BuiltScene, Error, Ray};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

#[derive(Args, Debug)]
pub struct PickArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Ray file: one ray per line, `ox oy oz dx dy dz [tmax]`, `#` starts a comment; `-` reads
    /// standard input. Default (without --camera): an 8 × 8 grid of camera rays looking
    /// straight down on the scene, north up; ray i is pixel (i mod 8, i div 8), row 0 north.
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
    /// Output format [default: json when --out ends in .json, else csv].
    #[arg(long, value_parser = crate::cli::choice::choice::<Format>())]
    pub format: Option<Format>,
    /// Output file (default, or `-`: standard output).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

pub fn run(args: PickArgs, matches: &ArgMatches) -> Result<ExitCode, Error> {
    let q = &args.query;
    // Arguments are checked before anything is read or written.
    let query = q.checked()?;
    let built = Arc::new(args.scene.build_instanced(matches, false)?.0);
    // A large ray file is read in chunks while answers are written (memory bounded whatever its
    // length); it is first checked whole, line by line in constant memory, so that a bad line is
    // reported before any output. One whose rays surely fit (a regular file of at most
    // `WHOLE_RAY_FILE` bytes, its most rays within a quarter of the memory budget) is read
    // whole and parsed once, before any output too. Camera pixels and the default camera grid
    // are small.
    let whole_file = args.rays.as_ref().filter(|path| {
        !super::is_stdin(path)
            && std::fs::metadata(path).is_ok_and(|m| {
                let most_rays = m.len() / MIN_RAY_LINE + 1;
                m.is_file()
                    && m.len() <= WHOLE_RAY_FILE
                    && most_rays * size_of::<RayLine>() as u64 <= raypick::budget::limit() / 4
            })
    });
    let rays: Vec<Ray> = match (&args.rays, &args.camera, &args.pixels) {
        (Some(_), _, _) => Vec::new(),
        (None, Some(camera), Some(pixels)) => {
            let camera = Camera::from_json_file(camera)?;
            let pixels_read = load_pixel_indices_as_centers(pixels)?;
            warn_outside(&camera, &pixels_read, &pixels.display().to_string());
            super::check_rays(
                &format!("the {} pixels of {}", pixels_read.len(), pixels.display()),
                pixels_read.len() as u64,
                &query,
            )?;
            pixels_read
                .into_iter()
                .map(|(x, y)| {
                    camera
                        .pixel_ray(x, y)
                        .with_range(q.tmin, q.tmax)
                        .with_mask(q.ray_mask)
                })
                .collect()
        }
        _ => {
            let (min, max) = built.bounds().unwrap_or((DVec3::ZERO, DVec3::ZERO));
            Camera::frame_from_above(min, max, GRID_SIDE, GRID_SIDE)
                .pixel_center_rays()
                .map(|r| r.with_range(q.tmin, q.tmax).with_mask(q.ray_mask))
                .collect()
        }
    };
    // Large batches stream: answers are written chunk by chunk, so memory stays bounded. In
    // all-hits mode the chunk shrinks so that its lists fit the memory budget. Chunks stay
    // small enough to keep a pick of millions of rays in a few hundred MB (a chunk's rays,
    // scene-frame rays and answers).
    let chunk = stream_chunk_rays(&query).min(RAY_CHUNK);
    let mut reader = match &args.rays {
        Some(path) if whole_file.is_some() => {
            let chunks = load_ray_chunks(path, chunk)?;
            let total = chunks.iter().map(|c| c.len() as u64).sum();
            Some((RayChunks::Read(chunks.into_iter()), Some(total)))
        }
        // Standard input is read once, as the answers are written (a bad line ends the
        // output there, with exit code 2).
        Some(path) if super::is_stdin(path) => Some((RayChunks::Stdin(RayReader::stdin()), None)),
        Some(path) => {
            let total = if std::fs::metadata(path).is_ok_and(|m| m.is_file()) {
                Some(count_rays(path)?)
            } else {
                None
            };
            Some((RayChunks::Streamed(RayReader::open(path)?), total))
        }
        None => None,
    };
    let options = OutputOptions {
        format: output_format(args.format, args.out.as_deref()),
        mode: q.mode,
        cells: built.has_grid(),
    };
    let scene_name = scene_summary(&args.scene, &built);
    let mut picker = make_picker(args.backend, built)?;
    let (mut invalid, mut answered, mut hit) = (0, 0u64, 0u64);
    let mut failure = None;
    let total = match &reader {
        Some((_, total)) => total.unwrap_or(0),
        None => rays.len() as u64,
    };
    let bar = progress::rays_bar(total, "picking");
    // The output's name for a failed write, as `write_output` names it.
    let out_name = super::output_name(args.out.as_deref());
    let written = write_output(args.out.as_deref(), |out| {
        let mut writer = AnswerWriter::begin(out, options)?;
        let mut sink = |answers: Answers| {
            bar.inc(answers.nearest.len() as u64);
            invalid += answers.nearest.iter().filter(|h| h.invalid).count();
            answered += answers.nearest.len() as u64;
            hit += answers.nearest.iter().filter(|h| h.hit).count() as u64;
            writer.write(out, &answers).map_err(|source| Error::Io {
                path: out_name.clone(),
                source,
            })
        };
        let result = match reader.as_mut() {
            Some((reader, _)) => {
                let (mut lines, mut batch) = (Vec::new(), Vec::new());
                (|| {
                    while reader.next(&mut lines, chunk)? > 0 {
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
            // What was answered before stays on standard output; an --out file is not written
            // (`write_output` leaves what was there).
            failure = Some(e);
            return Err(std::io::Error::other("the pick failed"));
        }
        writer.finish(out)
    });
    bar.finish_and_clear();
    show_notes(picker.as_mut());
    if let Some(e) = failure {
        return Err(e);
    }
    written?;
    if invalid > 0 {
        eprintln!(
            "warning: {invalid} ray(s) were invalid (NaN or infinite values, a zero direction or one \
             too short or too long to normalize, tmin > tmax, or an origin too far from the scene \
             for single precision) and are reported as misses"
        );
    }
    if !progress::is_quiet() {
        eprintln!(
            "picked {answered} ray{}: {hit} hit, {} missed; scene: {scene_name}; backend: {}",
            if answered == 1 { "" } else { "s" },
            answered - hit,
            picker.describe()
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// The most rays of a chunk of a ray file, read, answered and written at a time.
const RAY_CHUNK: usize = 1 << 18;

/// A ray file's rays, chunk by chunk: read whole before (in chunks of the pick's), or read as
/// they are answered.
enum RayChunks {
    Read(std::vec::IntoIter<Vec<RayLine>>),
    Streamed(RayReader<std::io::BufReader<std::fs::File>>),
    /// Standard input (`--rays -`), read as answered.
    Stdin(RayReader<std::io::StdinLock<'static>>),
}

impl RayChunks {
    /// Replaces `lines` with the next at most `max` rays (at least 1; a file read whole comes in
    /// the chunks it was read in, of the same `max`); how many, 0 at the end.
    fn next(&mut self, lines: &mut Vec<RayLine>, max: usize) -> Result<usize, Error> {
        match self {
            RayChunks::Streamed(reader) => reader.read_chunk(lines, max),
            RayChunks::Stdin(reader) => reader.read_chunk(lines, max),
            RayChunks::Read(chunks) => {
                *lines = chunks.next().unwrap_or_default();
                Ok(lines.len())
            }
        }
    }
}

/// Ray files of at most this many bytes may be read whole (at most 16.8M rays, 1.1 GB of them);
/// larger ones are checked line by line, then streamed in chunks.
const WHOLE_RAY_FILE: u64 = 192 << 20;

/// Rays per side of the default camera grid.
const GRID_SIDE: u32 = 8;

/// The scene for the summary line: the built-in example, or the files (the first three, then a
/// count), with the object and triangle counts.
fn scene_summary(args: &SceneArgs, built: &BuiltScene) -> String {
    let objects = built.object_count();
    let mut counts = format!(
        "{objects} object{}, {} triangles",
        if objects == 1 { "" } else { "s" },
        built.world_triangle_count()
    );
    if let Some(instances) = super::scene_args::instances_of(built) {
        counts += &format!("; {instances}");
    }
    let files: Vec<String> = match &args.scenes {
        Some(description) => vec![description.display().to_string()],
        None => args.scene.iter().map(|p| p.display().to_string()).collect(),
    };
    if files.is_empty() {
        return format!("the built-in example ({counts})");
    }
    let shown = files.len().min(3);
    let more = match files.len() - shown {
        0 => String::new(),
        n => format!(" and {n} more"),
    };
    format!("{}{more} ({counts})", files[..shown].join(", "))
}

/// Warns once when pixels (centres, as read) lie outside the camera's image: their rays are
/// made all the same, through where those pixels would be, but a pixel file for another
/// image size gives picks the user did not mean.
fn warn_outside(camera: &Camera, centres: &[(f64, f64)], file: &str) {
    if let Some((count, k)) = camera.outside_image(centres.iter().copied()) {
        let (x, y) = centres[k];
        eprintln!(
            "warning: {count} of the {} pixels of {file} lie outside the camera's {} x {} image \
             (the first: pixel {} {}, number {} in the file); their rays go through where they \
             would be",
            centres.len(),
            camera.width(),
            camera.height(),
            csv_number(x - 0.5),
            csv_number(y - 0.5),
            k + 1
        );
    }
}
