//! raypick against its peers, in one command, on the same scenes and rays in the same run:
//!
//! - `raypick-reference`: `cpu::trace_all`, the kernel's twin (`--backend reference`), at 2
//!   threads; its answers are the reference the others are checked against;
//! - `raypick-cpu`: the CPU engine (`--backend cpu`: the tree collapsed 8-wide, SIMD walk,
//!   packets for coherent groups) at 1 and 2 threads (dedicated rayon pools);
//! - `raypick-pick` (the 1M sets only): the same engine's whole `Picker::pick` of the world
//!   rays (frame conversion, trace, f64 refinement, the 104-byte answers), what issue 13's
//!   targets time, at 1 and 2 threads;
//! - `raypick-gpu`: the WGSL kernel through `GpuPicker::trace` (lavapipe on a machine without a
//!   GPU; skipped, saying why, without an adapter);
//! - `obvhs` 0.4 (CWBVH, `fast_build`), `bvh` 0.13 (svenstaro, `build_par`) and `parry3d` 0.31
//!   (`TriMesh`), at 2 threads;
//! - `embree`: Embree 3's `rtcIntersect1` through our own FFI (`benches/common/embree_peer.rs`)
//!   against the system's `libembree3`, at 1 and 2 threads, with the off-by-default `embree`
//!   feature (`apt-get install libembree-dev`); without it the bench says Embree was skipped.
//!
//! Scenes (`peers/scenes.rs`): bunny, 20k terrain, dragon, Jacksboro DEM, 200k terrain, 200k
//! soup, 2M terrain. Ray sets from `synthetic::rays`: 4,096 camera rays, 1M camera rays and 1M
//! random (incoherent) rays. Every peer works in raypick's scene-local f32 frame.
//!
//! Per scene and engine, in this order: the build and the end-to-end pick (build + the 4,096
//! camera rays), medians of 3 runs (5 below 100k triangles); the agreement of its answers with
//! raypick's reference traversal on each ray set (hit/miss and t within 1e-4), printed before that set
//! counts; throughput on the 4,096 camera rays with criterion (group `peers-<scene>`, bench
//! `camera-4096-<engine>-<threads>t`); single-ray latency (p50/p99 of 1,000 `intersect` calls,
//! scene resident). Then, with every engine of the scene still built, the 1M sets as medians
//! of interleaved rounds of our own (criterion's 10 samples would take too long there): each
//! round times every engine and thread count once, in turn, 7 rounds (the twin and the GPU path
//! 3), so that a slow spell of a shared machine falls on every engine alike. Then the scene's
//! table, and at the end every table again and `peers-summary.csv` in the target directory
//! (`peers/report.rs`).
//!
//! Run everything with `cargo bench --bench peers --features embree` (12–13 minutes on 2
//! cores), or the scenes whose names contain a word with e.g. `cargo bench --bench peers -- bunny`.
//! Every engine runs under the `raypick` binary's allocator (`huge_pages::Allocator`).
//!
//! Without `--bench` (as under `cargo test --benches`) it runs only the bunny, with 16,384 rays
//! in the "1M" sets and one run each, and writes no summary.

#[path = "common/bvh_peer.rs"]
mod bvh_peer;
#[cfg(feature = "embree")]
#[path = "common/embree_peer.rs"]
mod embree_peer;
#[allow(
    dead_code,
    reason = "obvhs_trace is for benches/pick.rs; the engines here go ray by ray through obvhs_intersect"
)]
#[path = "common/obvhs_peer.rs"]
mod obvhs_peer;
#[path = "common/parry_peer.rs"]
mod parry_peer;

#[path = "peers/engines.rs"]
mod engines;
#[path = "peers/measure.rs"]
mod measure;
#[path = "peers/report.rs"]
mod report;
#[path = "peers/scenes.rs"]
mod scenes;

use criterion::{Criterion, SamplingMode, Throughput};
use engines::{Engine, Inputs, Kind};
use glam::Vec3A;
use measure::{latency_us, median, report_agreement, time_in_rounds};
use obvhs::triangle::Triangle;
use raypick::check::synthetic::{RayKind, rays};
use raypick::frame::local_rays;
use raypick::layout::GpuRay;
use raypick::{BuildOptions, BuiltScene, GpuContext, Ray, Scene};
use report::{Cost, RAY_SETS, Rate, SceneReport};
use scenes::SCENES;
use std::collections::HashMap;
use std::hint::black_box;
use std::path::PathBuf;
use std::time::{Duration, Instant, SystemTime};

/// The `raypick` binary's allocator, for every engine in this process alike: large answer
/// buffers on huge pages, and freed ones reused by the next run instead of being faulted in
/// afresh (each engine's run allocates its results, which otherwise pay their page faults at
/// every run).
#[global_allocator]
static ALLOCATOR: raypick::huge_pages::Allocator = raypick::huge_pages::Allocator;

/// Seed of the ray sets.
const SEED: u64 = 1;
/// Rays in the small camera batch (the end-to-end figure's batch).
const CAMERA_BATCH: usize = 4096;
/// Rays in the large sets, and what they shrink to without `--bench`.
const LARGE_SET: usize = 1_000_000;
const LARGE_SET_TEST: usize = 16_384;
/// The CPU thread counts; the first is the one every ratio and the agreement reference use.
const THREADS: [usize; 2] = [2, 1];
/// Single-ray calls timed per engine for the latency percentiles.
const LATENCY_PICKS: usize = 1000;
/// The engine name of raypick's whole `Picker::pick` on the 1M sets.
const PICK_ENGINE: &str = "raypick-pick";
/// Interleaved rounds on the 1M sets with `--bench` (every engine and thread count once per
/// round), and the most the twin and the GPU path take part in.
const ROUNDS: usize = 7;
const SLOW_ROUNDS: usize = 3;
/// Below this many triangles, builds are repeated 5 times instead of 3.
const SMALL_SCENE: usize = 100_000;

/// How much this run measures.
struct Plan {
    /// `--bench` was given: full sizes, several runs, a summary.
    benchmark: bool,
    /// Only scenes whose name contains this.
    filter: Option<String>,
    large_set: usize,
    /// Timed runs of each engine on each 1M set, one per interleaved round.
    runs: usize,
    started: SystemTime,
}

impl Plan {
    /// The rounds `kind` is timed in on a 1M set: every round for the engines the targets
    /// compare, at most [`SLOW_ROUNDS`] for the twin and the GPU path (seconds a run on
    /// lavapipe, and no target of theirs is a ratio here).
    fn rounds(&self, kind: Kind) -> usize {
        match kind {
            Kind::RaypickReference | Kind::RaypickGpu => self.runs.min(SLOW_ROUNDS),
            _ => self.runs,
        }
    }
}

/// One ray set: world rays (for raypick's end-to-end pick) and the same rays scene-local.
struct RaySet {
    name: &'static str,
    world: Vec<Ray>,
    local: Vec<GpuRay>,
}

/// What every scene shares: the thread pools, the GPU and the Embree device.
struct Shared {
    pools: Vec<(usize, rayon::ThreadPool)>,
    gpu: Option<GpuContext>,
    /// `threads` of the GPU rows (see `report.rs`).
    gpu_threads: usize,
    #[cfg(feature = "embree")]
    embree: embree_peer::EmbreeDevice,
}

impl Shared {
    /// The thread counts `kind` is timed at.
    fn threads(&self, kind: Kind) -> Vec<usize> {
        match kind {
            Kind::RaypickCpu => THREADS.to_vec(),
            #[cfg(feature = "embree")]
            Kind::Embree => THREADS.to_vec(),
            Kind::RaypickGpu => vec![self.gpu_threads],
            _ => vec![THREADS[0]],
        }
    }

    /// The pool a row with `threads` runs in (the GPU's rows run in the first pool).
    fn pool(&self, threads: usize) -> &rayon::ThreadPool {
        self.pools
            .iter()
            .find(|(t, _)| *t == threads)
            .map_or(&self.pools[0].1, |(_, pool)| pool)
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let benchmark = args.iter().any(|a| a == "--bench");
    let plan = Plan {
        benchmark,
        filter: args.iter().find(|a| !a.starts_with('-')).cloned(),
        large_set: if benchmark { LARGE_SET } else { LARGE_SET_TEST },
        runs: if benchmark { ROUNDS } else { 1 },
        started: SystemTime::now(),
    };
    let mut criterion = Criterion::default().configure_from_args();
    let shared = open_shared();
    let start = Instant::now();

    let mut reports = Vec::new();
    for spec in &SCENES {
        let selected = match &plan.filter {
            Some(word) => spec.name.contains(word.as_str()),
            None => plan.benchmark || spec.name == "bunny",
        };
        if !selected {
            continue;
        }
        let Some(scene) = (spec.make)() else { continue };
        let report = bench_scene(&mut criterion, &plan, &shared, spec.name, scene);
        report::print_scene(&report);
        reports.push(report);
    }
    criterion.final_summary();

    println!();
    println!(
        "== all scenes ({:.1} min in all)",
        start.elapsed().as_secs_f64() / 60.0
    );
    for report in &reports {
        report::print_scene(report);
    }
    if plan.benchmark {
        let path = report::summary_path();
        match report::write_summary(&path, &reports) {
            Ok(()) => println!("summary: {}", path.display()),
            Err(e) => eprintln!("summary: cannot write {}: {e}", path.display()),
        }
    }
}

fn open_shared() -> Shared {
    let pools = THREADS
        .iter()
        .map(|&threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("rayon starts its threads");
            (threads, pool)
        })
        .collect();
    let gpu = match GpuContext::new() {
        Ok(context) => {
            eprintln!("raypick-gpu: adapter {}", context.describe());
            Some(context)
        }
        Err(e) => {
            eprintln!("raypick-gpu: skipped, no GPU adapter: {e}");
            None
        }
    };
    let gpu_threads = match &gpu {
        Some(context) if context.is_software() => std::env::var("LP_NUM_THREADS")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get())),
        _ => 0,
    };
    #[cfg(not(feature = "embree"))]
    eprintln!(
        "embree: skipped, the `embree` cargo feature is off \
         (cargo bench --bench peers --features embree, with libembree-dev installed)"
    );
    Shared {
        pools,
        gpu,
        gpu_threads,
        #[cfg(feature = "embree")]
        embree: embree_peer::EmbreeDevice::open(),
    }
}

/// The scene's triangles in the scene-local f32 frame of raypick's tree.
fn local_triangles(built: &BuiltScene) -> Vec<[Vec3A; 3]> {
    let origin = built.bvh.origin;
    (0..built.scene.triangle_count())
        .map(|i| {
            built
                .scene
                .world_triangle(i)
                .map(|p| Vec3A::from((p - origin).as_vec3()))
        })
        .collect()
}

fn ray_sets(built: &BuiltScene, large: usize) -> Vec<RaySet> {
    let specs = [
        (RAY_SETS[0], RayKind::Camera, CAMERA_BATCH),
        (RAY_SETS[1], RayKind::Camera, large),
        (RAY_SETS[2], RayKind::Random, large),
    ];
    specs
        .into_iter()
        .map(|(name, kind, count)| {
            let world = rays(&built.scene, kind, count, SEED);
            let local = local_rays(raypick::frame::Frame::at(built.bvh.origin), &world);
            let tmin_max = local.iter().map(|r| r.tmin).fold(0.0f32, f32::max);
            if tmin_max > 0.0 {
                eprintln!("{name} rays have tmin up to {tmin_max} (parry3d ignores tmin)");
            }
            RaySet { name, world, local }
        })
        .collect()
}

/// Measures every engine on one scene. Each engine is built (its build and end-to-end
/// figures), timed on the camera batch with criterion and for single-ray latency; then the 1M
/// sets are timed in interleaved rounds, every engine and thread count once per round
/// ([`time_in_rounds`]), so that a slow spell of a shared machine falls on all of them alike
/// and the ratios in one round are taken at the same moment. All the scene's engines are kept
/// built until its rounds are done.
fn bench_scene(
    criterion: &mut Criterion,
    plan: &Plan,
    shared: &Shared,
    name: &'static str,
    scene: Scene,
) -> SceneReport {
    let setup = BuiltScene::new(scene.clone(), &BuildOptions::default()).expect("the scene builds");
    let triangles = local_triangles(&setup);
    let obvhs_triangles: Vec<Triangle> = triangles
        .iter()
        .map(|&[v0, v1, v2]| Triangle { v0, v1, v2 })
        .collect();
    let sets = ray_sets(&setup, plan.large_set);
    let mut report = SceneReport {
        name,
        triangles: triangles.len(),
        gpu_bytes_per_triangle: setup.bvh.gpu_bytes() as f64 / triangles.len().max(1) as f64,
        builds: if !plan.benchmark {
            1
        } else if triangles.len() < SMALL_SCENE {
            5
        } else {
            3
        },
        costs: Vec::new(),
        rates: Vec::new(),
    };
    drop(setup);
    eprintln!("{name}: {} triangles", report.triangles);
    let inputs = Inputs {
        triangles: &triangles,
        obvhs_triangles: &obvhs_triangles,
        gpu: shared.gpu.as_ref(),
        #[cfg(feature = "embree")]
        embree: &shared.embree,
    };
    let mut reference: HashMap<&str, Vec<Option<f32>>> = HashMap::new();
    let mut check =
        |engine: &str, set: &RaySet, answers: Vec<Option<f32>>| match reference.get(set.name) {
            Some(expected) => report_agreement(name, engine, set.name, expected, &answers),
            None => {
                reference.insert(set.name, answers);
            }
        };
    let mut engines: Vec<(Kind, Box<dyn Engine>)> = Vec::new();
    let camera = &sets[0];
    for &kind in Kind::ALL {
        let Some((engine, cost)) =
            build_and_pick(&scene, &inputs, camera, kind, report.builds, shared)
        else {
            continue;
        };
        eprintln!(
            "{name}: {} build {:.1} ms, build + {CAMERA_BATCH} camera rays {:.1} ms{} (medians of {})",
            kind.name(),
            cost.build_ms,
            cost.end_to_end_ms,
            cost.end_to_end_api_ms.map_or(String::new(), |ms| format!(
                ", build + Picker::pick {ms:.1} ms"
            )),
            report.builds
        );
        for threads in shared.threads(kind) {
            let pool = shared.pool(threads);
            check(
                kind.name(),
                camera,
                pool.install(|| engine.trace(&camera.local)),
            );
            if let Some(median_ms) =
                criterion_median_ms(criterion, plan, name, camera, kind, threads, &*engine, pool)
            {
                report.rates.push(Rate {
                    rays: camera.name,
                    ray_count: camera.local.len(),
                    engine: kind.name(),
                    threads,
                    median_ms,
                });
            }
        }
        let (p50_us, p99_us) = latency_us(&*engine, &camera.local, LATENCY_PICKS);
        report.costs.push(Cost {
            p50_us,
            p99_us,
            ..cost
        });
        engines.push((kind, engine));
    }
    // The rows of the rounds: (engine, threads, whether it is raypick's whole pick).
    let rows: Vec<(usize, usize, bool)> = engines
        .iter()
        .enumerate()
        .flat_map(|(e, &(kind, _))| {
            let picks: &[bool] = if kind == Kind::RaypickCpu {
                &[false, true]
            } else {
                &[false]
            };
            picks
                .iter()
                .flat_map(move |&pick| shared.threads(kind).into_iter().map(move |t| (e, t, pick)))
        })
        .collect();
    let row_name = |(e, _, pick): (usize, usize, bool)| {
        if pick {
            PICK_ENGINE
        } else {
            engines[e].0.name()
        }
    };
    for set in &sets[1..] {
        let run = |(e, threads, pick): (usize, usize, bool)| {
            let engine = &engines[e].1;
            shared.pool(threads).install(|| {
                if pick {
                    engine
                        .pick_answers(black_box(&set.world))
                        .expect("raypick's engine picks")
                } else {
                    engine.trace(black_box(&set.local))
                }
            })
        };
        let rounds = |(e, _, _): (usize, usize, bool)| plan.rounds(engines[e].0);
        let medians = time_in_rounds(&rows, run, rounds, |row, answers| {
            check(row_name(row), set, answers)
        });
        for (&row, median_ms) in rows.iter().zip(medians) {
            report.rates.push(Rate {
                rays: set.name,
                ray_count: set.local.len(),
                engine: row_name(row),
                threads: row.1,
                median_ms,
            });
        }
    }
    // Each engine's rows together, in the rounds' engine order (a stable sort: sets, then
    // thread counts, in the order measured).
    report
        .rates
        .sort_by_key(|r| rows.iter().position(|&row| row_name(row) == r.engine));
    report
}

/// Builds `kind` `builds` times, each followed at once by its trace of the camera batch at the
/// first thread count (and, for raypick, by `Picker::pick` of the same rays); returns the last
/// engine built and the medians. `None` (saying why) when the engine cannot take the scene.
fn build_and_pick(
    scene: &Scene,
    inputs: &Inputs<'_>,
    camera: &RaySet,
    kind: Kind,
    builds: usize,
    shared: &Shared,
) -> Option<(Box<dyn Engine>, Cost)> {
    let pool = shared.pool(THREADS[0]);
    let (mut build_ms, mut end_to_end_ms, mut api_ms, mut last) =
        (Vec::new(), Vec::new(), Vec::new(), None);
    for _ in 0..builds {
        drop(last.take());
        let copy = kind.needs_scene().then(|| scene.clone());
        let start = Instant::now();
        let engine = match kind.build(inputs, copy) {
            Ok(engine) => engine,
            Err(why) => {
                eprintln!("{}: skipped on this scene: {why}", kind.name());
                return None;
            }
        };
        let built = start.elapsed().as_secs_f64() * 1e3;
        pool.install(|| engine.trace(&camera.local));
        let traced = start.elapsed().as_secs_f64() * 1e3;
        let before_pick = Instant::now();
        if pool.install(|| engine.api_pick(&camera.world)) {
            api_ms.push(built + before_pick.elapsed().as_secs_f64() * 1e3);
        }
        build_ms.push(built);
        end_to_end_ms.push(traced);
        last = Some(engine);
    }
    let cost = Cost {
        engine: kind.name(),
        build_ms: median(build_ms),
        end_to_end_ms: median(end_to_end_ms),
        end_to_end_api_ms: (!api_ms.is_empty()).then(|| median(api_ms)),
        p50_us: f64::NAN,
        p99_us: f64::NAN,
    };
    Some((last.expect("at least one build"), cost))
}

/// Times the camera batch with criterion (10 flat samples over a short window) and reads the
/// median back from criterion's `estimates.json`; `None` when criterion did not measure it
/// (filtered out, or not in `--bench` mode).
#[allow(
    clippy::too_many_arguments,
    reason = "one call site; the pieces are unrelated"
)]
fn criterion_median_ms(
    criterion: &mut Criterion,
    plan: &Plan,
    scene: &str,
    set: &RaySet,
    kind: Kind,
    threads: usize,
    engine: &dyn Engine,
    pool: &rayon::ThreadPool,
) -> Option<f64> {
    let group_name = format!("peers-{scene}");
    let bench_name = format!("{}-{}-{threads}t", set.name, kind.name());
    let mut group = criterion.benchmark_group(&group_name);
    group
        .sample_size(10)
        .sampling_mode(SamplingMode::Flat)
        .warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_millis(1500))
        .throughput(Throughput::Elements(set.local.len() as u64));
    group.bench_function(&bench_name, |b| {
        b.iter(|| pool.install(|| engine.trace(black_box(&set.local))))
    });
    group.finish();
    let path = criterion_dir()
        .join(&group_name)
        .join(&bench_name)
        .join("new/estimates.json");
    let fresh = std::fs::metadata(&path)
        .and_then(|m| m.modified())
        .is_ok_and(|modified| modified >= plan.started);
    if !fresh {
        return None;
    }
    let text = std::fs::read_to_string(&path).ok()?;
    let estimates: serde_json::Value = serde_json::from_str(&text).ok()?;
    let median_ns = estimates["median"]["point_estimate"].as_f64()?;
    Some(median_ns / 1e6)
}

/// Where criterion writes: `$CRITERION_HOME`, else `$CARGO_TARGET_DIR/criterion`, else
/// `target/criterion` in the package.
fn criterion_dir() -> PathBuf {
    if let Some(home) = std::env::var_os("CRITERION_HOME") {
        return PathBuf::from(home);
    }
    std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target"))
        .join("criterion")
}
