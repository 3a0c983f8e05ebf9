//! `raypick los` (line of sight between pairs of points) and `raypick viewshed` (which targets an
//! observer can see), both as batched nearest-hit queries ([`raypick::apps::sight`]).
//!
//! A segment from A to B is visible when no triangle is hit with t in (ε, 1 − ε), where the ray
//! is A + t·(B − A) and ε = `--epsilon` (default 1e-6), t refined in f64, so surfaces the end
//! points lie on do not block the view.

use super::scene_args::{SceneArgs, parse_mask};
use super::{csv_only, make_picker, write_output};
use clap::{ArgMatches, Args};
use glam::DVec3;
use raypick::apps::sight::{self, Sight};
use raypick::dem::cell_of_triangle;
use raypick::io::output::{CsvNumber, csv_number};
use raypick::io::ray_file::{load_pairs, load_points};
use raypick::{Backend, BuiltScene, Error, Ray};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

#[derive(Args, Debug)]
pub struct LosArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Pairs file: one pair per line, `x1 y1 z1 x2 y2 z2`, `#` starts a comment.
    #[arg(long)]
    pub pairs: PathBuf,
    #[command(flatten)]
    pub sight: SightArgs,
}

#[derive(Args, Debug)]
pub struct ViewshedArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Observer position `x y z`.
    #[arg(long, required = true, num_args = 3, value_names = ["X", "Y", "Z"], allow_hyphen_values = true)]
    pub observer: Vec<f64>,
    /// Targets file: one `x y z` per line. Default: every sample of every terrain grid in the scene.
    #[arg(long)]
    pub targets: Option<PathBuf>,
    /// Height added to each target's z (e.g. a person's eye height).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub target_height: f64,
    #[command(flatten)]
    pub sight: SightArgs,
}

#[derive(Args, Debug)]
pub struct SightArgs {
    /// End-point margin ε, as a fraction of the segment: hits with t in (ε, 1 − ε) block it.
    #[arg(long, default_value_t = 1e-6, allow_hyphen_values = true)]
    pub epsilon: f64,
    /// Layer mask of the sight lines: only objects sharing a bit can block them.
    #[arg(long, value_parser = parse_mask, default_value = "0xffffffff")]
    pub ray_mask: u32,
    /// Which path answers.
    #[arg(long, value_parser = crate::cli::choice::choice::<Backend>(), default_value_t = Backend::Auto)]
    pub backend: Backend,
    /// Output file for the CSV rows (default, or `-`: standard output).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Sight lines asked again (their hits listed) at a time: about 80 MB of lists.
const AGAIN_BATCH: usize = 16_384;

/// Visibility of each segment `(from, to)` ([`raypick::apps::sight`]).
/// Invalid segments (NaN or infinite ends, or both ends equal) are not visible, with a warning
/// that counts them as `what`s.
fn visible(
    built: Arc<BuiltScene>,
    segments: &[(DVec3, DVec3)],
    sight: &SightArgs,
    what: &str,
) -> Result<Vec<bool>, Error> {
    let eps = sight.epsilon;
    if !(0.0..0.5).contains(&eps) {
        return Err(Error::Invalid(format!(
            "--epsilon {} must be in [0, 0.5)",
            csv_number(eps)
        )));
    }
    let query = sight::first_query();
    super::check_rays(
        &format!("the {} {what}s", segments.len()),
        segments.len() as u64,
        &query,
    )?;
    let rays: Vec<Ray> = segments
        .iter()
        .map(|&(a, b)| sight::sight_ray(a, b, eps, sight.ray_mask))
        .collect();
    if let Some(warning) =
        raypick::apps::sight::long_ends(built.bounds(), segments, eps, what, "--epsilon")
    {
        eprintln!("warning: {warning}");
    }
    let mut picker = make_picker(sight.backend, built)?;
    // Again with what a GPU's driver left (under `ulimit -v` its mappings count).
    super::check_rays(
        &format!("the {} {what}s", segments.len()),
        segments.len() as u64,
        &query,
    )?;
    let answers = picker.query(&rays, &query)?;
    let invalid = answers.nearest.iter().filter(|h| h.invalid).count();
    if invalid > 0 {
        eprintln!("warning: {}", sight::invalid_warning(invalid, what));
    }
    let judged: Vec<Sight> = answers
        .nearest
        .iter()
        .map(|h| sight::judge_nearest(h, eps))
        .collect();
    drop(answers);
    let mut seen: Vec<bool> = judged.iter().map(|&j| j == Sight::Visible).collect();
    // The lines whose nearest hit is the surface the observer stands on: what lies behind it.
    let again: Vec<usize> = (0..judged.len())
        .filter(|&k| judged[k] == Sight::Again)
        .collect();
    // In batches: every line of a viewshed from an observer on the ground may be asked again,
    // and each keeps a list of hits.
    let query = sight::second_query();
    let mut undecided = 0;
    for batch in again.chunks(AGAIN_BATCH) {
        super::check_rays(
            &format!("{} {what}s", batch.len()),
            batch.len() as u64,
            &query,
        )?;
        let rays: Vec<Ray> = batch.iter().map(|&k| rays[k]).collect();
        let answers = picker.query(&rays, &query)?;
        for (j, &k) in batch.iter().enumerate() {
            let overflow = answers.overflow.get(j).copied().unwrap_or(false);
            let judged = sight::judge_all(answers.hits_of(j), overflow, eps);
            seen[k] = judged == Some(true);
            undecided += usize::from(judged.is_none());
        }
    }
    if undecided > 0 {
        eprintln!("warning: {}", sight::undecided_warning(undecided, what));
    }
    Ok(seen)
}

/// A finite number of an argument, or an error naming it.
fn finite_argument(name: &str, values: &[f64]) -> Result<(), Error> {
    if values.iter().all(|v| v.is_finite()) {
        return Ok(());
    }
    let shown: Vec<String> = values.iter().map(|&v| csv_number(v)).collect();
    Err(Error::Invalid(format!(
        "{name} {} is not finite; give finite numbers",
        shown.join(" ")
    )))
}

pub fn run_los(args: LosArgs, matches: &ArgMatches) -> Result<ExitCode, Error> {
    csv_only("los", args.sight.out.as_deref())?;
    let built = Arc::new(args.scene.build(matches)?);
    let segments = load_pairs(&args.pairs)?;
    let seen = visible(built, &segments, &args.sight, "pair")?;
    write_output(args.sight.out.as_deref(), |out| {
        writeln!(out, "pair,visible")?;
        for (i, v) in seen.iter().enumerate() {
            writeln!(out, "{i},{}", u8::from(*v))?;
        }
        Ok(())
    })?;
    Ok(ExitCode::SUCCESS)
}

pub fn run_viewshed(args: ViewshedArgs, matches: &ArgMatches) -> Result<ExitCode, Error> {
    csv_only("viewshed", args.sight.out.as_deref())?;
    finite_argument("--observer", &args.observer)?;
    finite_argument("--target-height", &[args.target_height])?;
    let built = Arc::new(args.scene.build(matches)?);
    let observer = DVec3::new(args.observer[0], args.observer[1], args.observer[2]);
    let lift = DVec3::Z * args.target_height;
    // (target, terrain cell label) pairs.
    let targets: Vec<(DVec3, String)> = match &args.targets {
        Some(path) => load_points(path)?
            .into_iter()
            .map(|p| (p + lift, String::new()))
            .collect(),
        None => grid_targets(&built, lift)?,
    };
    let segments: Vec<(DVec3, DVec3)> = targets.iter().map(|(t, _)| (observer, *t)).collect();
    let seen = visible(built, &segments, &args.sight, "target")?;
    write_output(args.sight.out.as_deref(), |out| {
        writeln!(out, "target,x,y,z,object,row,col,visible")?;
        for (i, ((p, label), v)) in targets.iter().zip(&seen).enumerate() {
            let label = if label.is_empty() {
                ",,"
            } else {
                label.as_str()
            };
            let f = CsvNumber;
            writeln!(
                out,
                "{i},{},{},{},{label},{}",
                f(p.x),
                f(p.y),
                f(p.z),
                u8::from(*v)
            )?;
        }
        Ok(())
    })?;
    Ok(ExitCode::SUCCESS)
}

/// Every sample of every terrain grid that a hittable triangle uses (NODATA samples are
/// skipped), labelled `object,row,col`.
fn grid_targets(built: &BuiltScene, lift: DVec3) -> Result<Vec<(DVec3, String)>, Error> {
    let scene = &built.scene;
    let mut targets = Vec::new();
    for object in scene.objects() {
        let Some(grid) = object.grid else { continue };
        let (cols, rows) = (grid.columns as usize, grid.rows as usize);
        let mut used = vec![false; cols * rows];
        for t in 0..object.triangle_count {
            if !scene.is_degenerate((object.first_triangle + t) as usize) {
                let (r, c) = cell_of_triangle(cols, t);
                for (dr, dc) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                    used[(r + dr) * cols + c + dc] = true;
                }
            }
        }
        for (sample, _) in used.iter().enumerate().filter(|(_, u)| **u) {
            let p = scene.position(object.first_vertex as usize + sample);
            let (r, c) = (sample / cols, sample % cols);
            targets.push((p + lift, format!("{},{r},{c}", object.id)));
        }
    }
    if targets.is_empty() {
        let grids: Vec<_> = scene.objects().iter().filter_map(|o| o.grid).collect();
        let why = if grids.is_empty() {
            "the scene has no terrain grid".to_string()
        } else if grids.iter().all(|g| g.columns < 2 || g.rows < 2) {
            // One row or one column of samples: no cell between them.
            let g = grids[0];
            format!(
                "the scene's terrain grids have no cells (the first is {} x {} samples; a cell \
                 needs two rows and two columns)",
                g.columns, g.rows
            )
        } else {
            "the scene's terrain grids have no cells with data (NODATA everywhere)".to_string()
        };
        return Err(Error::Invalid(format!("{why}: give --targets FILE")));
    }
    Ok(targets)
}
