//! The `raypick` command line: `pick` answers rays from a file, `verify` checks the GPU path, the
//! CPU path and the brute-force oracle against each other. Both use a built-in example scene
//! when no `--scene` is given.

use clap::{Args, Parser, Subcommand};
use raypick::compare::Tally;
use raypick::io::output::{Format, write_hits};
use raypick::io::{obj::load_obj, ray_file::load_rays};
use raypick::oracle::brute_force_all;
use raypick::synthetic::{RayKind, example_scene, mixed_rays, rays as synthetic_rays};
use raypick::{
    Backend, BuildOptions, BuiltScene, CpuPicker, Error, GpuContext, GpuPicker, Hit, Picker, Ray,
    Scene, SplitAxis,
};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Instant;

#[derive(Parser)]
#[command(
    name = "raypick",
    version,
    about = "Exact, fast ray picking for 3D scenes on any GPU wgpu reaches, with a CPU path that gives the same answers"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Pick: for each ray, the nearest hit (CSV or JSON).
    Pick(PickArgs),
    /// Run the GPU path, the CPU path and (for small scenes) brute force on the same rays and
    /// report mismatches per ray kind; exits 1 on any mismatch.
    Verify(VerifyArgs),
}

#[derive(Args)]
struct SceneArgs {
    /// Scene files (Wavefront .obj); object ids are their positions here. Default: the built-in
    /// example scene (a terrain with two buildings).
    #[arg(long, num_args = 1..)]
    scene: Vec<PathBuf>,
    /// Split-axis policy of the median-cut builder.
    #[arg(long, value_enum, default_value_t = SplitAxis::Longest)]
    split: SplitAxis,
    /// Most triangles per leaf (1 ..= 15).
    #[arg(long, default_value_t = BuildOptions::default().leaf_size)]
    leaf_size: u32,
}

#[derive(Args)]
struct PickArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Ray file: one ray per line, `ox oy oz dx dy dz [tmax]`, `#` starts a comment. Default: an
    /// 8 × 8 camera grid over the scene.
    #[arg(long)]
    rays: Option<PathBuf>,
    /// Which path answers.
    #[arg(long, value_enum, default_value_t = Backend::Gpu)]
    backend: Backend,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Csv)]
    format: Format,
    /// Output file (default: standard output).
    #[arg(long)]
    out: Option<PathBuf>,
}

#[derive(Args)]
struct VerifyArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Ray file to check (one ray kind, "file").
    #[arg(long, conflicts_with = "random")]
    rays: Option<PathBuf>,
    /// Number of synthetic rays, spread over every ray kind (camera, random, vertex, edge-midpoint,
    /// grazing, axis-parallel, inside-box, tmax-cutoff).
    #[arg(long, default_value_t = 100_000)]
    random: usize,
    /// Seed for the synthetic rays.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Run the brute-force oracle only when triangles × rays is at most this (it is O(N) per ray).
    #[arg(long, default_value_t = 5e9)]
    oracle_budget: f64,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Pick(args) => pick(args),
        Command::Verify(args) => verify(args),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(2)
        }
    }
}

fn load_scene(args: &SceneArgs) -> Result<BuiltScene, Error> {
    let scene = if args.scene.is_empty() {
        example_scene()
    } else {
        let meshes = args
            .scene
            .iter()
            .map(|path| Ok((path.display().to_string(), load_mesh(path)?)))
            .collect::<Result<Vec<_>, Error>>()?;
        Scene::from_meshes(meshes)?
    };
    let options = BuildOptions {
        split_axis: args.split,
        leaf_size: args.leaf_size,
    };
    BuiltScene::new(scene, &options)
}

fn load_mesh(path: &Path) -> Result<raypick::Mesh, Error> {
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("obj") => load_obj(path),
        _ => Err(Error::Invalid(format!(
            "{}: unknown scene format (expected .obj)",
            path.display()
        ))),
    }
}

fn read_rays(path: &Path) -> Result<Vec<Ray>, Error> {
    Ok(load_rays(path)?
        .into_iter()
        .map(|r| Ray::new(r.origin, r.dir).with_range(0.0, r.tmax.unwrap_or(f64::INFINITY)))
        .collect())
}

fn picker(backend: Backend, built: Arc<BuiltScene>) -> Result<Box<dyn Picker>, Error> {
    Ok(match backend {
        Backend::Cpu => Box::new(CpuPicker::new(built)),
        Backend::Gpu => Box::new(GpuPicker::new(&GpuContext::new()?, built)?),
    })
}

fn pick(args: PickArgs) -> Result<ExitCode, Error> {
    let built = Arc::new(load_scene(&args.scene)?);
    let rays = match &args.rays {
        Some(path) => read_rays(path)?,
        None => synthetic_rays(&built.scene, RayKind::Camera, 64, 1),
    };
    let hits = picker(args.backend, built)?.pick(&rays)?;
    let invalid = hits.iter().filter(|h| h.invalid).count();
    if invalid > 0 {
        eprintln!(
            "warning: {invalid} ray(s) were invalid (NaN or infinite values, zero direction, or tmin > tmax) and are reported as misses"
        );
    }
    let write = |out: &mut dyn std::io::Write| {
        write_hits(&mut std::io::BufWriter::new(out), &hits, args.format)
    };
    match &args.out {
        Some(path) => {
            let mut file = std::fs::File::create(path).map_err(io_error(path))?;
            write(&mut file).map_err(io_error(path))?;
        }
        None => write(&mut std::io::stdout().lock()).map_err(io_error(Path::new("<stdout>")))?,
    }
    Ok(ExitCode::SUCCESS)
}

fn verify(args: VerifyArgs) -> Result<ExitCode, Error> {
    let started = Instant::now();
    let built = Arc::new(load_scene(&args.scene)?);
    let bvh = &built.bvh;
    let triangles = built.scene.triangle_count();
    println!(
        "scene: {} object(s), {triangles} triangles; tree: {} nodes, depth {}, {:.1} GPU bytes/triangle; loaded and built in {:.0} ms",
        built.scene.objects().len(),
        bvh.nodes.len(),
        bvh.depth(),
        bvh.gpu_bytes() as f64 / triangles.max(1) as f64,
        started.elapsed().as_secs_f64() * 1e3
    );
    let labelled: Vec<(&str, Ray)> = match &args.rays {
        Some(path) => read_rays(path)?.into_iter().map(|r| ("file", r)).collect(),
        None => mixed_rays(&built.scene, args.random, args.seed)
            .into_iter()
            .map(|(k, r)| (k.name(), r))
            .collect(),
    };
    let rays: Vec<Ray> = labelled.iter().map(|(_, r)| *r).collect();

    let context = GpuContext::new()?;
    println!("gpu: {}", context.describe());
    let mut gpu = GpuPicker::new(&context, built.clone())?;
    let (gpu_hits, gpu_s) = timed(|| gpu.pick(&rays))?;
    let (cpu_hits, cpu_s) = timed(|| CpuPicker::new(built.clone()).pick(&rays))?;
    println!(
        "gpu path: {} rays in {:.3} s ({:.0} rays/s)",
        rays.len(),
        gpu_s,
        rays.len() as f64 / gpu_s
    );
    println!(
        "cpu path: {} rays in {:.3} s ({:.0} rays/s, {} threads)",
        rays.len(),
        cpu_s,
        rays.len() as f64 / cpu_s,
        rayon::current_num_threads()
    );
    let oracle = if triangles as f64 * rays.len() as f64 <= args.oracle_budget {
        let (hits, s) = timed(|| Ok(brute_force_all(&built.scene, &rays)))?;
        println!("brute force: {} rays in {:.3} s", rays.len(), s);
        Some(hits)
    } else {
        println!(
            "brute force: skipped ({triangles} triangles × {} rays is over --oracle-budget)",
            rays.len()
        );
        None
    };

    let mut kinds: Vec<&str> = Vec::new();
    for (k, _) in &labelled {
        if !kinds.contains(k) {
            kinds.push(k);
        }
    }
    println!("\nmismatches (ties: shared edge + boundary) per ray kind");
    println!(
        "{:<14} {:>9} {:>9} {:>8} {:>20} {:>20} {:>20}",
        "kind", "rays", "hits", "invalid", "gpu/cpu", "gpu/oracle", "cpu/oracle"
    );
    let mut total_mismatches = 0;
    let mut total_rays = 0;
    for kind in kinds {
        let idx: Vec<usize> = (0..labelled.len())
            .filter(|&i| labelled[i].0 == kind)
            .collect();
        let sub = |v: &[Hit]| idx.iter().map(|&i| v[i]).collect::<Vec<_>>();
        let kind_rays: Vec<Ray> = idx.iter().map(|&i| rays[i]).collect();
        let pair =
            |a: &[Hit], b: &[Hit]| Tally::compare(&built.scene, &kind_rays, &sub(a), &sub(b)).0;
        let gc = pair(&gpu_hits, &cpu_hits);
        let go = oracle.as_ref().map(|o| pair(&gpu_hits, o));
        let co = oracle.as_ref().map(|o| pair(&cpu_hits, o));
        let cell = |t: Option<Tally>| {
            t.map_or("-".to_string(), |t| {
                format!("{} ({}+{})", t.mismatches, t.shared_edge, t.boundary)
            })
        };
        println!(
            "{:<14} {:>9} {:>9} {:>8} {:>20} {:>20} {:>20}",
            kind,
            gc.rays,
            gc.hits,
            gc.invalid,
            cell(Some(gc)),
            cell(go),
            cell(co)
        );
        total_mismatches +=
            gc.mismatches + go.map_or(0, |t| t.mismatches) + co.map_or(0, |t| t.mismatches);
        total_rays += gc.rays;
    }
    println!("\n{total_rays} rays, {total_mismatches} mismatches");
    Ok(if total_mismatches == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}

fn io_error(path: &Path) -> impl Fn(std::io::Error) -> Error + '_ {
    move |source| Error::Io {
        path: path.display().to_string(),
        source,
    }
}

fn timed<T>(f: impl FnOnce() -> Result<T, Error>) -> Result<(T, f64), Error> {
    let start = Instant::now();
    let value = f()?;
    Ok((value, start.elapsed().as_secs_f64()))
}
