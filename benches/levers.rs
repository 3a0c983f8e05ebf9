//! The two performance levers of the "Performance" issue, measured on the ~1M-triangle terrain
//! (708 × 708 samples of `synthetic::hills`, as in `benches/pick.rs`) and the Stanford bunny:
//!
//! - `workgroup_size/{scene}/{rays}/{size}`: the GPU kernel alone (`GpuPicker::trace`) at each
//!   of `SWEPT_WORKGROUP_SIZES`, on 65,536 camera and 65,536 random rays;
//! - `ray_order/{path}/{scene}/{rays}/{batch}/{given|sorted}`: closest-hit traversal (Möller–
//!   Trumbore) of a batch as given, and in `RayOrder` with the sort, the gather and the scatter
//!   back included (`ray_order::trace_in_order`), on the CPU path (`cpu::trace_all` on 2
//!   threads) and the GPU kernel (`GpuPicker::trace_batch`); `ray_order/sort/...` times the
//!   reordering overhead alone. Random rays run at 4,096, 16,384 and 65,536 rays too (CPU only),
//!   for the batch size from which reordering pays; camera rays are the coherent control.
//!
//! The GPU groups are skipped, saying why, without a GPU adapter. The reordering batch has
//! `LEVERS_RAYS` rays (default 262,144, so that the whole bench stays under 5 minutes on 2
//! cores with lavapipe); BENCHMARKS.md's table used `LEVERS_RAYS=1048576`.
//!
//! Run with `cargo bench --bench levers`, one lever with `cargo bench --bench levers --
//! workgroup_size`.

#[path = "common/short_groups.rs"]
mod short_groups;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use raypick::check::synthetic::{RayKind, hills, rays, terrain};
use raypick::frame::local_rays;
use raypick::gpu::picker::SWEPT_WORKGROUP_SIZES;
use raypick::io::obj::load_obj;
use raypick::layout::GpuRay;
use raypick::ray_order::{RayOrder, trace_in_order};
use raypick::{BuildOptions, BuiltScene, GpuContext, GpuPicker, Scene, cpu};
use short_groups::configure;
use std::hint::black_box;
use std::path::Path;
use std::sync::{Arc, LazyLock};

/// Rays per batch in the workgroup-size sweep.
const SWEEP_RAYS: usize = 65_536;
/// Default rays per batch in the reordering comparison (`LEVERS_RAYS` overrides it).
const DEFAULT_ORDER_RAYS: usize = 262_144;
/// Smaller random batches for the size from which reordering pays (CPU path).
const THRESHOLD_SIZES: [usize; 3] = [4096, 16_384, 65_536];
/// Seed for the ray sets.
const SEED: u64 = 1;
/// CPU threads for the CPU path, as on the 2-core machine the figures come from.
const CPU_THREADS: usize = 2;

/// One scene with its tree and its kernel-frame ray sets: `(kind name, sweep rays, large rays)`.
struct Fixture {
    name: &'static str,
    built: Arc<BuiltScene>,
    ray_sets: Vec<(&'static str, Vec<GpuRay>, Vec<GpuRay>)>,
}

static FIXTURES: LazyLock<Vec<Fixture>> = LazyLock::new(|| {
    let order_rays = std::env::var("LEVERS_RAYS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(DEFAULT_ORDER_RAYS);
    [("terrain_1m", terrain_scene()), ("bunny", bunny_scene())]
        .into_iter()
        .map(|(name, scene)| {
            let built = BuiltScene::new(scene, &BuildOptions::default()).expect("scene builds");
            eprintln!(
                "{name}: {} triangles; reordering batches of {order_rays} rays",
                built.scene.triangle_count()
            );
            let ray_sets = [("camera", RayKind::Camera), ("random", RayKind::Random)]
                .into_iter()
                .map(|(kind_name, kind)| {
                    let local = |count| {
                        local_rays(
                            raypick::frame::Frame::at(built.bvh.origin),
                            &rays(&built.scene, kind, count, SEED),
                        )
                    };
                    (kind_name, local(SWEEP_RAYS), local(order_rays))
                })
                .collect();
            Fixture {
                name,
                built: Arc::new(built),
                ray_sets,
            }
        })
        .collect()
});

/// 708 × 708 samples, 1 m apart: 999,698 triangles.
fn terrain_scene() -> Scene {
    let mesh = terrain(708, 708, 0.0, 707.0, 1.0, hills);
    Scene::from_meshes([("terrain".to_string(), mesh)]).expect("the terrain is well formed")
}

fn bunny_scene() -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/bunny.obj");
    let mesh = load_obj(&path).expect("tests/data/bunny.obj loads");
    Scene::from_meshes([("bunny".to_string(), mesh)]).expect("the bunny is well formed")
}

fn gpu_context(group: &str) -> Option<GpuContext> {
    match GpuContext::new() {
        Ok(context) => {
            eprintln!("{group}: adapter {}", context.describe());
            Some(context)
        }
        Err(e) => {
            eprintln!("{group}: GPU figures skipped, no GPU adapter: {e}");
            None
        }
    }
}

fn workgroup_size(c: &mut Criterion) {
    let Some(context) = gpu_context("workgroup_size") else {
        return;
    };
    let mut group = c.benchmark_group("workgroup_size");
    configure(&mut group);
    for fixture in FIXTURES.iter() {
        for size in SWEPT_WORKGROUP_SIZES {
            let mut picker =
                match GpuPicker::with_workgroup_size(&context, fixture.built.clone(), size) {
                    Ok(picker) => picker,
                    Err(e) => {
                        eprintln!("workgroup_size/{}/{size}: skipped: {e}", fixture.name);
                        continue;
                    }
                };
            for (kind, sweep, _) in &fixture.ray_sets {
                group.throughput(Throughput::Elements(sweep.len() as u64));
                group.bench_function(format!("{}/{kind}/{size}", fixture.name), |b| {
                    b.iter(|| picker.trace(black_box(sweep)).expect("gpu trace"))
                });
            }
        }
    }
    group.finish();
}

fn ray_order(c: &mut Criterion) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(CPU_THREADS)
        .build()
        .expect("a 2-thread pool");
    let context = gpu_context("ray_order");
    let mut group = c.benchmark_group("ray_order");
    configure(&mut group);
    for fixture in FIXTURES.iter() {
        let bvh = &fixture.built.bvh;
        let mut gpu = context.as_ref().and_then(|context| {
            GpuPicker::new(context, fixture.built.clone())
                .map_err(|e| eprintln!("ray_order/gpu/{}: skipped: {e}", fixture.name))
                .ok()
        });
        for (kind, _, large) in &fixture.ray_sets {
            // Random rays also at smaller batch sizes (prefixes of the large batch), for the
            // size from which reordering pays; camera rays only as the control.
            let sizes: Vec<usize> = match *kind {
                "random" => THRESHOLD_SIZES
                    .into_iter()
                    .filter(|&n| n < large.len())
                    .chain([large.len()])
                    .collect(),
                _ => vec![large.len()],
            };
            for n in sizes {
                let batch = &large[..n];
                let id = |path: &str| format!("{path}/{}/{kind}/{n}", fixture.name);
                group.throughput(Throughput::Elements(n as u64));
                group.bench_function(id("sort"), |b| {
                    b.iter(|| {
                        pool.install(|| {
                            RayOrder::new(black_box(batch)).map(|o| o.scatter(&o.gather(batch)))
                        })
                    })
                });
                for (order_name, reorder) in [("given", false), ("sorted", true)] {
                    group.bench_function(format!("{}/{order_name}", id("cpu")), |b| {
                        b.iter(|| {
                            pool.install(|| {
                                trace_in_order(black_box(batch), 0, reorder, |r| {
                                    Ok::<_, ()>((cpu::trace_all(bvh, r), Vec::new()))
                                })
                            })
                        })
                    });
                }
                // The GPU only at the large batch: lavapipe is slow enough to dominate the bench.
                let Some(gpu) = gpu.as_mut().filter(|_| n == large.len()) else {
                    continue;
                };
                for (order_name, reorder) in [("given", false), ("sorted", true)] {
                    group.bench_function(format!("{}/{order_name}", id("gpu")), |b| {
                        b.iter(|| {
                            pool.install(|| {
                                trace_in_order(black_box(batch), 0, reorder, |r| {
                                    gpu.trace_batch(r, 0, false)
                                })
                                .expect("gpu trace")
                            })
                        })
                    });
                }
            }
        }
    }
    group.finish();
}

criterion_group!(benches, workgroup_size, ray_order);
criterion_main!(benches);
