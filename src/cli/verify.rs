//! `raypick verify`: the GPU path, the CPU engine, the reference twin and (for small scenes)
//! brute force on the same rays, compared per ray kind: bit differences among the backends,
//! mismatches against the oracle; also the traversal statistics b and i of the paper's cost
//! model.

use super::query_args::QueryArgs;
use super::read_rays;
use super::scene_args::SceneArgs;
use clap::{ArgMatches, Args};
use raypick::check::compare::{Tally, compare_answers, differences};
use raypick::check::oracle::{OracleTriangles, brute_force_reporting};
use raypick::check::synthetic::mixed_rays;
use raypick::{
    Answers, CpuPicker, Error, GpuContext, GpuPicker, Picker, Query, Ray, ReferencePicker,
};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Instant;

#[derive(Args, Debug)]
pub struct VerifyArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Ray file to check (reported as one ray kind, "file"; `-`: standard input).
    #[arg(long, conflicts_with = "random")]
    pub rays: Option<PathBuf>,
    /// Number of synthetic rays, spread over every ray kind (camera, random, vertex,
    /// edge-midpoint, grazing, axis-parallel, inside-box, tmax-cutoff).
    /// At least 1 (verifying no rays reported `b = NaN` and passed).
    #[arg(long, default_value_t = 100_000,
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..))]
    pub random: usize,
    /// Seed for the synthetic rays.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Run the brute-force oracle only when triangles × rays is at most this (it is O(N) per ray;
    /// the default takes a million rays through 300,000 triangles, about 6 minutes on 2 cores).
    #[arg(long, default_value_t = 3e11, value_parser = parse_oracle_budget)]
    pub oracle_budget: f64,
    #[command(flatten)]
    pub query: QueryArgs,
}

/// The answers verify holds per ray: three paths and two oracle runs.
const ANSWER_SETS: u64 = 5;

/// Checks that verify's `count` rays fit the memory budget.
fn check_count(count: u64, query: &Query) -> Result<(), Error> {
    raypick::budget::check(
        &format!("verifying {count} rays"),
        count,
        query.bytes_per_ray().saturating_mul(ANSWER_SETS),
    )
}

pub fn run(args: VerifyArgs, matches: &ArgMatches) -> Result<ExitCode, Error> {
    args.query.checked()?;
    if args.rays.is_none() {
        check_count(args.random as u64, &args.query.query())?;
    }
    let (built, load_s, build_s) = args.scene.build_instanced(matches, false)?;
    let built = Arc::new(built);
    // The scene in world triangles: an instanced scene's instances are baked into copies for
    // the rays aimed at triangles, the oracle and the tie checks (which share nothing with the
    // trees).
    let baked;
    let world = match built.instances() {
        Some(instances) => {
            instances.check_bake("baking the instances into world triangles for the oracle")?;
            baked = instances.baked()?;
            say!(
                "instances: {} of {} meshes, top tree {} nodes",
                instances.instances().len(),
                instances.meshes().len(),
                instances.top_nodes()
            )?;
            &baked
        }
        None => &built.scene,
    };
    let bvh = &built.bvh;
    let triangles = world.triangle_count();
    say!(
        "scene: {} object(s), {triangles} triangles, loaded in {:.0} ms; tree: {} nodes, depth {}, {:.1} GPU bytes/triangle, built in {:.0} ms",
        world.objects().len(),
        load_s * 1e3,
        bvh.nodes.len(),
        bvh.depth(),
        bvh.gpu_bytes() as f64 / triangles.max(1) as f64,
        build_s * 1e3
    )?;
    let q = &args.query;
    let query = q.query();
    // The command line's names (`closest`, `watertight`), not the library's type names.
    let max_hits = match query.mode {
        raypick::Mode::All => format!(", max hits {}", query.max_hits),
        _ => String::new(),
    };
    say!(
        "query: mode {}, cull {}{max_hits}, intersector {}, ray mask {:#x}",
        query.mode,
        query.cull,
        query.intersector,
        q.ray_mask
    )?;
    let labelled: Vec<(&str, Ray)> = match &args.rays {
        Some(path) => {
            let rays = read_rays(path, q.tmin, q.tmax, q.ray_mask)?;
            super::check_rays(
                &format!("the {} rays of {}", rays.len(), super::ray_file_name(path)),
                rays.len() as u64,
                &query,
            )?;
            rays.into_iter().map(|r| ("file", r)).collect()
        }
        // --tmin and --tmax as a ray file's rays take them: every ray's tmin, and the tmax of
        // those that set none (a tmax-cutoff ray keeps its own). They were ignored here.
        None => mixed_rays(world, args.random, args.seed)
            .into_iter()
            .map(|(k, r)| {
                let tmax = if r.tmax == f64::INFINITY {
                    q.tmax
                } else {
                    r.tmax
                };
                (k.name(), r.with_mask(q.ray_mask).with_range(q.tmin, tmax))
            })
            .collect(),
    };
    check_count(labelled.len() as u64, &query)?;
    let rays: Vec<Ray> = labelled.iter().map(|(_, r)| *r).collect();

    let mut gpu = match GpuContext::new().and_then(|c| GpuPicker::new(&c, built.clone())) {
        Ok(gpu) => {
            say!("gpu: {}", gpu.context().describe())?;
            Some(gpu)
        }
        Err(e) => {
            say!("gpu: none ({e}); comparing the CPU paths and the oracle only")?;
            None
        }
    };
    // Again with what the GPU's driver left (under `ulimit -v` its mappings count).
    check_count(labelled.len() as u64, &query)?;
    let collapse_start = Instant::now();
    let wide = built.wide()?;
    let collapse_s = collapse_start.elapsed().as_secs_f64();
    say!(
        "engine: {} wide nodes, depth {}, {:.1} bytes/triangle of its own, collapsed in {:.1} ms ({:.0}% of the build)",
        wide.nodes.len(),
        wide.depth,
        wide.bytes() as f64 / triangles.max(1) as f64,
        collapse_s * 1e3,
        100.0 * collapse_s / build_s.max(1e-9)
    )?;
    let mut engine = CpuPicker::new(built.clone());
    let engine_name = engine.describe();
    let mut reference = ReferencePicker::new(built.clone());
    let mut pickers: Vec<(&str, &mut dyn Picker)> = Vec::new();
    if let Some(gpu) = gpu.as_mut() {
        pickers.push(("gpu", gpu));
    }
    pickers.push(("engine", &mut engine));
    pickers.push(("reference", &mut reference));
    let mut paths: Vec<(&str, Answers, f64)> = Vec::new();
    for (name, picker) in pickers {
        let (answers, s) = super::progress::phase(name, || timed(|| picker.query(&rays, &query)))?;
        paths.push((name, answers, s));
    }
    let n = rays.len() as f64;
    for (name, a, s) in &paths {
        let b: u64 = a.nearest.iter().map(|h| h.box_tests as u64).sum();
        let i: u64 = a.nearest.iter().map(|h| h.triangle_tests as u64).sum();
        say!(
            "{name:>9}: {} rays in {s:.3} s ({:.0} rays/s); b = {:.2}, i = {:.2} per ray (T = bB + iI)",
            rays.len(),
            n / s,
            b as f64 / n,
            i as f64 / n
        )?;
    }
    say!("engine: {engine_name}")?;
    // Within the budget of triangle tests, the oracle's own copy of the triangles must fit the
    // memory budget too: a baked field of instances can be tens of millions of triangles.
    let tests_fit = triangles as f64 * n <= args.oracle_budget;
    let room = tests_fit.then(|| {
        raypick::budget::check(
            "the oracle's copy of the triangles",
            triangles as u64,
            OracleTriangles::BYTES_PER_TRIANGLE,
        )
    });
    let oracle = if let Some(Err(e)) = room {
        say!("brute force: skipped ({e})")?;
        None
    } else if tests_fit {
        // Rays valid in f64 whose origin the scene's f32 frame cannot hold (beyond f32's range
        // even after the far-origin shift): every path reports them invalid, as documented, and
        // the oracle is given them as invalid too, so they are counted in the invalid column,
        // not as mismatches.
        let frame = built.frame();
        let oracle_rays: Vec<Ray> = rays
            .iter()
            .map(|r| {
                if r.is_valid() && raypick::frame::local_ray(frame, r, &query).is_none() {
                    Ray {
                        origin: raypick::DVec3::NAN,
                        ..*r
                    }
                } else {
                    *r
                }
            })
            .collect();
        let unframed = rays
            .iter()
            .zip(&oracle_rays)
            .filter(|(a, b)| a.is_valid() != b.is_valid())
            .count();
        if unframed > 0 {
            say!(
                "{unframed} rays valid in f64 lie beyond what the scene's f32 frame holds: every path reports them invalid, and they are not compared with the oracle"
            )?;
        }
        let bar = super::progress::rays_bar(rays.len() as u64, "brute force");
        let ((answers, every), s) = timed(|| {
            Ok(brute_force_reporting(world, &oracle_rays, &query, |k| {
                bar.inc(k as u64)
            }))
        })?;
        bar.finish_and_clear();
        say!("brute force: {} rays in {s:.3} s", rays.len())?;
        Some((answers, every))
    } else {
        say!(
            "brute force: skipped ({triangles} triangles × {} rays is over --oracle-budget)",
            rays.len()
        )?;
        None
    };

    let mut kinds: Vec<&str> = Vec::new();
    for (k, _) in &labelled {
        if !kinds.contains(k) {
            kinds.push(k);
        }
    }
    say!(
        "\ndifferences (rays whose answers differ in any bit) and mismatches against the oracle \
         (ties: shared edge + boundary) per ray kind"
    )?;
    say!(
        "{:<14} {:>9} {:>9} {:>8} {:>12} {:>12} {:>17} {:>17} {:>17}",
        "kind",
        "rays",
        "hits",
        "invalid",
        "engine≠ref",
        "gpu≠ref",
        "engine/oracle",
        "gpu/oracle",
        "ref/oracle"
    )?;
    let answers = |name: &str| paths.iter().find(|p| p.0 == name).map(|p| &p.1);
    let (gpu_answers, engine_answers, reference_answers) = (
        answers("gpu"),
        answers("engine").expect("the engine ran"),
        answers("reference").expect("the reference ran"),
    );
    let mut total_mismatches = 0;
    let mut total_differences = 0;
    for kind in kinds {
        let idx: Vec<usize> = (0..labelled.len())
            .filter(|&i| labelled[i].0 == kind)
            .collect();
        let kind_rays: Vec<Ray> = idx.iter().map(|&i| rays[i]).collect();
        let reference = oracle.as_ref().map(|(_, every)| every.subset(&idx));
        let pair = |a: &Answers, b: &Answers| {
            compare_answers(
                world,
                &kind_rays,
                query.mode,
                &a.subset(&idx),
                &b.subset(&idx),
                reference.as_ref(),
            )
            .0
        };
        let differ = |a: &Answers| {
            differences(query.mode, &a.subset(&idx), &reference_answers.subset(&idx)).len()
        };
        let engine_diff = differ(engine_answers);
        let gpu_diff = gpu_answers.map(differ);
        // The kind's rays, hits and invalid rays (the twin against itself: no oracle needed).
        let base = compare_answers(
            world,
            &kind_rays,
            query.mode,
            &reference_answers.subset(&idx),
            &reference_answers.subset(&idx),
            None,
        )
        .0;
        let against = |a: &Answers| oracle.as_ref().map(|(o, _)| pair(a, o));
        let (eo, go, ro) = (
            against(engine_answers),
            gpu_answers.and_then(against),
            against(reference_answers),
        );
        let cell = |t: Option<Tally>| {
            t.map_or("-".to_string(), |t| {
                format!("{} ({}+{})", t.mismatches, t.shared_edge, t.boundary)
            })
        };
        say!(
            "{:<14} {:>9} {:>9} {:>8} {:>12} {:>12} {:>17} {:>17} {:>17}",
            kind,
            base.rays,
            base.hits,
            base.invalid,
            engine_diff,
            gpu_diff.map_or("-".to_string(), |d| d.to_string()),
            cell(eo),
            cell(go),
            cell(ro)
        )?;
        total_differences += engine_diff + gpu_diff.unwrap_or(0);
        total_mismatches += [eo, go, ro]
            .iter()
            .map(|t| t.map_or(0, |t| t.mismatches))
            .sum::<usize>();
    }
    say!(
        "\n{} rays, {total_differences} differences, {total_mismatches} mismatches",
        rays.len()
    )?;
    Ok(if total_mismatches == 0 && total_differences == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}
fn timed<T>(f: impl FnOnce() -> Result<T, Error>) -> Result<(T, f64), Error> {
    let start = Instant::now();
    let value = f()?;
    Ok((value, start.elapsed().as_secs_f64()))
}

/// An `--oracle-budget` value: a number of exact triangle tests, 0 or more (`inf`: always).
fn parse_oracle_budget(text: &str) -> Result<f64, String> {
    super::query_args::parse_number_where(
        text,
        |n| n >= 0.0,
        "a number of triangle tests (0 or more, or inf)",
    )
}
