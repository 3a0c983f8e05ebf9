//! `raypick bench`: build time, memory, throughput, end-to-end time and single-ray latency of
//! every pick path on one scene, and the CPU/GPU crossover batch size, as plain text tables.

use super::scene_args::SceneArgs;
use clap::{ArgMatches, Args};
use raypick::auto::AutoPicker;
use raypick::check::synthetic::{RayKind, rays};
use raypick::{BuiltScene, CpuPicker, Error, GpuContext, GpuPicker, Picker, Ray};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Instant;

/// Camera rays in the small batch, the end-to-end figure and the crossover's largest-but-one size.
const CAMERA_RAYS: usize = 4096;
/// Batch sizes of the CPU/GPU crossover table.
const CROSSOVER_SIZES: [usize; 5] = [1, 16, 256, 4096, 65_536];
/// Single-ray picks before the latency samples.
const WARM_UP_PICKS: usize = 50;

#[derive(Args, Debug)]
pub struct BenchArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Random rays in the large batch.
    #[arg(long, default_value_t = 1_000_000, value_parser = clap::value_parser!(u64).range(1..))]
    pub rays: u64,
    /// Repetitions per timed figure (builds, batches, end to end); the median is reported.
    /// At most 1000.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub repeat: u32,
    /// Single-ray picks timed per path for the latency percentiles (after a warm-up).
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u64).range(1..))]
    pub picks: u64,
    /// Seed for the synthetic rays.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Time the in-process `pick` (closest hit, f64 refinement included) of your own ray file
    /// (`-`: standard input) instead of the tables: load and build once, then the best of
    /// `--repeat` passes. Ends with one machine-readable line, `pick_rays_per_s=<number>`.
    #[arg(long)]
    pub ray_file: Option<std::path::PathBuf>,
    /// With `--ray-file`: CPU threads (default: all cores).
    #[arg(long, requires = "ray_file", value_parser = clap::value_parser!(u32).range(1..=1024))]
    pub threads: Option<u32>,
    /// With `--ray-file`: the backend to time.
    #[arg(long, requires = "ray_file", value_parser = crate::cli::choice::choice::<raypick::Backend>(), default_value_t = raypick::Backend::Auto)]
    pub backend: raypick::Backend,
}

/// `raypick bench --ray-file`: the in-process pick throughput on a user's own rays.
fn run_ray_file(
    args: &BenchArgs,
    path: &std::path::Path,
    matches: &ArgMatches,
) -> Result<ExitCode, Error> {
    let rays = super::read_rays(path, 0.0, f64::INFINITY, u32::MAX)?;
    let name = super::ray_file_name(path);
    super::check_rays(
        &format!("the {} rays of {name}", rays.len()),
        rays.len() as u64,
        &raypick::Query::default(),
    )?;
    if rays.is_empty() {
        return Err(Error::Invalid(format!(
            "{name}: no rays to time (the file holds no ray lines)"
        )));
    }
    let (built, load_s, build_s) = args.scene.build_timed(matches)?;
    let built = Arc::new(built);
    let threads = args
        .threads
        .map_or(rayon::current_num_threads(), |t| t as usize);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| Error::Invalid(format!("cannot start {threads} CPU threads: {e}")))?;
    let mut picker = raypick::make_picker(args.backend, built.clone())?;
    // Again with what a GPU's driver left (under `ulimit -v` its mappings count).
    super::check_rays(
        &format!("the {} rays of {name}", rays.len()),
        rays.len() as u64,
        &raypick::Query::default(),
    )?;
    super::show_notes(&mut *picker);
    // Described inside the pool: the CPU paths name the threads they will pick on.
    let picking = &mut *picker;
    let described = pool.install(move || picking.describe());
    say!(
        "scene: {} triangles, loaded in {:.0} ms, built in {:.0} ms; {} rays from {}; {described}",
        built.scene.triangle_count(),
        load_s * 1e3,
        build_s * 1e3,
        rays.len(),
        name,
    )?;
    let mut best = f64::INFINITY;
    let mut hits = 0;
    // One untimed pass first (the engine's wide tree, GPU buffers, page faults).
    pool.install(|| picker.pick(&rays))?;
    for pass in 0..args.repeat {
        let start = Instant::now();
        let answers = pool.install(|| picker.pick(&rays))?;
        let s = start.elapsed().as_secs_f64();
        hits = answers.iter().filter(|h| h.hit).count();
        say!(
            "pass {}: {:.1} ms ({:.0} rays/s)",
            pass + 1,
            s * 1e3,
            rays.len() as f64 / s
        )?;
        best = best.min(s);
    }
    super::show_notes(&mut *picker);
    say!(
        "hits: {hits} of {} rays; best of {}, {}",
        rays.len(),
        counted(args.repeat as usize, "pass", "passes"),
        counted(threads, "thread", "threads")
    )?;
    // The tracer alone on the same rays (scene-frame rays made once, in input order, no
    // reordering, no f64 refinement): what the pick pipeline costs around it. For the GPU, the
    // kernel's dispatches with their uploads and readbacks.
    // The picker's resources (a GPU's buffers) go before the tracer makes its own.
    drop(picker);
    let tracer: Option<Box<dyn raypick::picker::Tracer + Send>> = match args.backend {
        raypick::Backend::Cpu => Some(Box::new(raypick::CpuPicker::new(built.clone()))),
        raypick::Backend::Reference => Some(Box::new(raypick::ReferencePicker::new(built.clone()))),
        // Best effort: the pick's figure above stands if a second GPU picker cannot be made.
        raypick::Backend::Gpu => {
            match GpuContext::new().and_then(|context| GpuPicker::new(&context, built.clone())) {
                Ok(gpu) => Some(Box::new(gpu)),
                Err(e) => {
                    eprintln!("note: no trace-alone figure: {e}");
                    None
                }
            }
        }
        raypick::Backend::Auto => None,
    };
    if let Some(mut tracer) = tracer {
        let query = raypick::Query::default();
        let (local, _) = raypick::frame::scene_rays(built.frame(), &rays, &query);
        let settings = built.settings(&query);
        let mut trace_best = f64::INFINITY;
        pool.install(|| tracer.trace(&local, &settings))?;
        for _ in 0..args.repeat {
            let start = Instant::now();
            pool.install(|| tracer.trace(&local, &settings))?;
            trace_best = trace_best.min(start.elapsed().as_secs_f64());
        }
        say!(
            "trace alone: {:.0} rays/s; pick / trace = {:.2}",
            rays.len() as f64 / trace_best,
            trace_best / best
        )?;
    }
    say!("pick_rays_per_s={:.0}", rays.len() as f64 / best)?;
    Ok(ExitCode::SUCCESS)
}

/// One row of the main table; `None` prints as "-".
#[derive(Default)]
struct Row {
    path: String,
    camera_rays_per_s: Option<f64>,
    random_rays_per_s: Option<f64>,
    end_to_end_ms: Option<f64>,
    p50_us: Option<f64>,
    p99_us: Option<f64>,
}

pub fn run(args: BenchArgs, matches: &ArgMatches) -> Result<ExitCode, Error> {
    if let Some(path) = &args.ray_file {
        return run_ray_file(&args, path, matches);
    }
    // The random set is answered whole by every path; the single picks are held as rays.
    super::check_rays(
        &format!("--rays {}", args.rays),
        args.rays,
        &raypick::Query::default(),
    )?;
    raypick::budget::check(
        &format!("--picks {}", args.picks),
        args.picks.saturating_add(WARM_UP_PICKS as u64),
        std::mem::size_of::<Ray>() as u64,
    )?;
    let repeat = args.repeat as usize;
    let (built, load_s, _) = args.scene.build_timed(matches)?;
    let options = args.scene.build_options();
    let build_ms = super::progress::phase("timing builds", || {
        median_ms(repeat, || {
            let scene = built.scene.clone();
            let start = Instant::now();
            let rebuilt = BuiltScene::new(scene, &options)?;
            let s = start.elapsed().as_secs_f64();
            drop(rebuilt);
            Ok(s)
        })
    })?;
    let built = Arc::new(built);
    let triangles = built.scene.triangle_count();
    say!(
        "scene: {} object(s), {triangles} triangles (loaded in {:.0} ms); tree: {} nodes, depth {}",
        built.scene.objects().len(),
        load_s * 1e3,
        built.bvh.nodes.len(),
        built.bvh.depth(),
    )?;
    say!(
        "build: {build_ms:.1} ms (median of {repeat}, {} threads); {:.1} GPU bytes/triangle ({:.1} MiB)",
        rayon::current_num_threads(),
        built.bvh.gpu_bytes() as f64 / triangles.max(1) as f64,
        built.bvh.gpu_bytes() as f64 / (1024.0 * 1024.0),
    )?;

    let camera = rays(&built.scene, RayKind::Camera, CAMERA_RAYS, args.seed);
    let random = rays(&built.scene, RayKind::Random, args.rays as usize, args.seed);
    let singles: Vec<Ray> = camera
        .iter()
        .copied()
        .cycle()
        .take(args.picks as usize + WARM_UP_PICKS)
        .collect();
    let sets = Sets {
        camera: &camera,
        random: &random,
        singles: &singles,
        repeat,
    };
    // The paper's cost model T = bB + iI: mean box tests b and triangle tests i per ray.
    for (name, set) in [("camera", &camera), ("random", &random)] {
        let hits = CpuPicker::new(built.clone()).pick(set)?;
        let n = hits.len().max(1) as f64;
        let b: u64 = hits.iter().map(|h| u64::from(h.box_tests)).sum();
        let i: u64 = hits.iter().map(|h| u64::from(h.triangle_tests)).sum();
        say!(
            "{name} rays: mean box tests b = {:.2}, triangle tests i = {:.2} per ray (T = bB + iI)",
            b as f64 / n,
            i as f64 / n
        )?;
    }

    let mut table = Vec::new();
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .map_err(|e| Error::Invalid(format!("cannot start {threads} CPU threads: {e}")))?;
        let mut row = super::progress::phase(&format!("cpu, {threads} thread(s)"), || {
            pool.install(|| sets.measure(&mut CpuPicker::new(built.clone())))
        })?;
        row.path = format!(
            "cpu, {threads} thread{}",
            if threads == 1 { "" } else { "s" }
        );
        row.end_to_end_ms = Some(pool.install(|| {
            median_ms(repeat, || {
                let scene = built.scene.clone();
                let start = Instant::now();
                let fresh = Arc::new(BuiltScene::new(scene, &options)?);
                CpuPicker::new(fresh).pick(&camera)?;
                Ok(start.elapsed().as_secs_f64())
            })
        })?);
        table.push(row);
    }

    let context = GpuContext::new();
    let mut gpu = match &context {
        Ok(context) => {
            say!("gpu: {}", context.describe())?;
            let picker = GpuPicker::new(context, built.clone())?;
            // Again with what the GPU's driver left (under `ulimit -v` its mappings count).
            super::check_rays(
                &format!("--rays {}", args.rays),
                args.rays,
                &raypick::Query::default(),
            )?;
            Some(picker)
        }
        Err(e) => {
            say!("gpu: none ({e}); GPU figures are left out")?;
            None
        }
    };
    if let (Some(picker), Ok(context)) = (&mut gpu, &context) {
        let mut row = super::progress::phase("gpu", || sets.measure(picker))?;
        row.path = "gpu".to_string();
        row.end_to_end_ms = Some(super::progress::phase("gpu, end to end", || {
            median_ms(repeat, || {
                let scene = built.scene.clone();
                let start = Instant::now();
                let fresh = Arc::new(BuiltScene::new(scene, &options)?);
                GpuPicker::new(context, fresh)?.pick(&camera)?;
                Ok(start.elapsed().as_secs_f64())
            })
        })?);
        table.push(row);
    } else {
        table.push(Row {
            path: "gpu".to_string(),
            ..Row::default()
        });
    }

    let mut auto = AutoPicker::new(built.clone());
    super::show_notes(&mut auto);
    let auto_crossover = auto.crossover();
    let mut row = super::progress::phase("auto", || sets.measure(&mut auto))?;
    row.path = "auto".to_string();
    super::show_notes(&mut auto);
    table.push(row);
    say!(
        "{}; GPU used from: {}",
        auto.describe(),
        if auto_crossover == usize::MAX {
            "never".to_string()
        } else {
            format!("{auto_crossover} rays")
        }
    )?;
    drop(auto);

    say!()?;
    print_table(&table, args.rays, repeat, args.picks)?;

    say!()?;
    crossover(&built, gpu.as_mut(), args.seed, repeat)?;
    Ok(ExitCode::SUCCESS)
}

/// The ray sets every path runs, and how often.
struct Sets<'a> {
    camera: &'a [Ray],
    random: &'a [Ray],
    singles: &'a [Ray],
    repeat: usize,
}

impl Sets<'_> {
    /// Throughput on both batches (one warm-up call, then the median of `repeat`) and single-ray
    /// latency (after a warm-up).
    fn measure(&self, picker: &mut dyn Picker) -> Result<Row, Error> {
        let mut rays_per_s = |rays: &[Ray]| -> Result<f64, Error> {
            picker.pick(rays)?;
            let s = median_ms(self.repeat, || {
                let start = Instant::now();
                picker.pick(rays)?;
                Ok(start.elapsed().as_secs_f64())
            })? / 1e3;
            Ok(rays.len() as f64 / s)
        };
        let camera_rays_per_s = Some(rays_per_s(self.camera)?);
        let random_rays_per_s = Some(rays_per_s(self.random)?);
        let mut samples = Vec::with_capacity(self.singles.len());
        for (i, ray) in self.singles.iter().enumerate() {
            let start = Instant::now();
            picker.pick(std::slice::from_ref(ray))?;
            if i >= WARM_UP_PICKS {
                samples.push(start.elapsed().as_secs_f64() * 1e6);
            }
        }
        samples.sort_by(f64::total_cmp);
        Ok(Row {
            camera_rays_per_s,
            random_rays_per_s,
            p50_us: Some(percentile(&samples, 50.0)),
            p99_us: Some(percentile(&samples, 99.0)),
            ..Row::default()
        })
    }
}

fn print_table(table: &[Row], random_rays: u64, repeat: usize, picks: u64) -> Result<(), Error> {
    let headers = [
        "path".to_string(),
        format!("{CAMERA_RAYS} camera rays/s"),
        format!("{random_rays} random rays/s"),
        format!("build+{CAMERA_RAYS} camera ms"),
        "1-ray p50 us".to_string(),
        "1-ray p99 us".to_string(),
    ];
    let cells: Vec<[String; 6]> = table
        .iter()
        .map(|r| {
            [
                r.path.clone(),
                cell(r.camera_rays_per_s, |v| format!("{:.3}M", v / 1e6)),
                cell(r.random_rays_per_s, |v| format!("{:.3}M", v / 1e6)),
                cell(r.end_to_end_ms, |v| format!("{v:.1}")),
                cell(r.p50_us, |v| format!("{v:.1}")),
                cell(r.p99_us, |v| format!("{v:.1}")),
            ]
        })
        .collect();
    let widths: Vec<usize> = (0..headers.len())
        .map(|c| {
            cells
                .iter()
                .map(|row| row[c].len())
                .chain([headers[c].len()])
                .max()
                .unwrap_or(0)
        })
        .collect();
    let line = |row: &[String]| {
        let mut text = format!("{:<w$}", row[0], w = widths[0]);
        for (c, value) in row.iter().enumerate().skip(1) {
            text.push_str(&format!("  {value:>w$}", w = widths[c]));
        }
        say!("{}", text.trim_end())
    };
    line(&headers)?;
    for row in &cells {
        line(row)?;
    }
    say!(
        "(throughput and end to end: median of {repeat}; end to end = build + upload (GPU) + \
         pick, GPU context already open; latency: {picks} single-ray picks, scene resident)"
    )
}

fn cell(value: Option<f64>, format: impl Fn(f64) -> String) -> String {
    value.map_or("-".to_string(), format)
}

/// Time per batch on the CPU (all threads) and the GPU for each crossover size, and the first
/// size from which the GPU is faster.
fn crossover(
    built: &Arc<BuiltScene>,
    mut gpu: Option<&mut GpuPicker>,
    seed: u64,
    repeat: usize,
) -> Result<(), Error> {
    let mut cpu = CpuPicker::new(built.clone());
    say!(
        "cpu/gpu crossover (camera rays; ms per batch, median of {repeat}; cpu on {} threads)",
        rayon::current_num_threads()
    )?;
    say!(
        "{:>8}  {:>10}  {:>10}  {:>8}",
        "rays",
        "cpu ms",
        "gpu ms",
        "gpu/cpu"
    )?;
    let mut first_faster = None;
    for size in CROSSOVER_SIZES {
        let batch = rays(&built.scene, RayKind::Camera, size, seed);
        let time = |picker: &mut dyn Picker| -> Result<f64, Error> {
            picker.pick(&batch)?;
            median_ms(repeat, || {
                let start = Instant::now();
                picker.pick(&batch)?;
                Ok(start.elapsed().as_secs_f64())
            })
        };
        let cpu_ms =
            super::progress::phase(&format!("crossover, cpu, {size} rays"), || time(&mut cpu))?;
        let gpu_ms = match gpu.as_deref_mut() {
            Some(g) => Some(super::progress::phase(
                &format!("crossover, gpu, {size} rays"),
                || time(g),
            )?),
            None => None,
        };
        if first_faster.is_none() && gpu_ms.is_some_and(|g| g < cpu_ms) {
            first_faster = Some(size);
        }
        say!(
            "{size:>8}  {cpu_ms:>10.3}  {:>10}  {:>8}",
            cell(gpu_ms, |g| format!("{g:.3}")),
            cell(gpu_ms, |g| format!("{:.2}", g / cpu_ms)),
        )?;
    }
    match (first_faster, gpu.is_some()) {
        (Some(size), _) => say!("the GPU is faster from {size} rays per batch")?,
        (None, true) => say!(
            "the GPU is faster from: never (up to {} rays)",
            CROSSOVER_SIZES[4]
        )?,
        (None, false) => say!("the GPU is faster from: - (no GPU)")?,
    }
    Ok(())
}

/// The median, in milliseconds, of `repeat` runs of `run` (each returning seconds).
fn median_ms(repeat: usize, mut run: impl FnMut() -> Result<f64, Error>) -> Result<f64, Error> {
    let mut samples = (0..repeat.max(1))
        .map(|_| run())
        .collect::<Result<Vec<f64>, Error>>()?;
    samples.sort_by(f64::total_cmp);
    let n = samples.len();
    let median = if n % 2 == 1 {
        samples[n / 2]
    } else {
        (samples[n / 2 - 1] + samples[n / 2]) / 2.0
    };
    Ok(median * 1e3)
}

/// Nearest-rank percentile of sorted `samples`.
fn percentile(samples: &[f64], p: f64) -> f64 {
    if samples.is_empty() {
        return f64::NAN;
    }
    let rank = ((p / 100.0) * samples.len() as f64).ceil() as usize;
    samples[rank.clamp(1, samples.len()) - 1]
}

/// `n` with its noun: "1 pass", "5 passes".
fn counted(n: usize, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}
