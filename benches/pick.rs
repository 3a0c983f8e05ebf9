//! Benchmarks on a ~1M-triangle terrain (708 × 708 samples of `synthetic::hills`):
//!
//! - `build`: `Bvh::build` (through `BuiltScene::new`) with the default options;
//! - `pick_cpu`: `CpuPicker::pick` end to end, and the bare traversal (`cpu::trace_all`);
//! - `pick_gpu`: `GpuPicker::pick` end to end (skipped, saying why, without a GPU adapter);
//! - `peer_obvhs`: the `obvhs` crate's CWBVH over the same triangles and rays, as a yardstick.
//!
//! Rays: 65,536 camera rays and 65,536 random rays from `synthetic::rays`.
//!
//! `benches/peers.rs` compares the CPU traversal with obvhs, `bvh` and parry3d on four more scenes.
//!
//! Run everything with `cargo bench --bench pick`, or one group with e.g.
//! `cargo bench --bench pick -- pick_cpu`.

#[path = "common/obvhs_peer.rs"]
mod obvhs_peer;

use criterion::{
    BatchSize, BenchmarkGroup, Criterion, SamplingMode, Throughput, criterion_group,
    criterion_main, measurement::WallTime,
};
use glam::Vec3A;
use obvhs::ray::RayHit;
use obvhs::triangle::Triangle;
use obvhs_peer::{obvhs_build, obvhs_trace};
use raypick::check::synthetic::{RayKind, hills, rays, terrain};
use raypick::frame::local_rays;
use raypick::layout::{GpuRay, NO_HIT};
use raypick::{
    BuildOptions, BuiltScene, CpuPicker, GpuContext, GpuPicker, Picker, Ray, Scene, cpu,
};
use std::hint::black_box;
use std::sync::{Arc, LazyLock};
use std::time::Duration;

/// Rays per batch.
const RAY_COUNT: usize = 65_536;
/// Seed for the ray sets.
const SEED: u64 = 1;

/// The terrain, its tree, and the ray sets, built once per bench run.
struct Fixture {
    built: Arc<BuiltScene>,
    /// `(name, world rays, the same rays in the scene frame)`.
    ray_sets: Vec<(&'static str, Vec<Ray>, Vec<GpuRay>)>,
}

static FIXTURE: LazyLock<Fixture> = LazyLock::new(|| {
    let built = BuiltScene::new(terrain_scene(), &BuildOptions::default()).expect("terrain builds");
    let triangles = built.bvh.triangles.len();
    eprintln!(
        "terrain: {} scene triangles, {triangles} in the tree; {} nodes ({} leaves), depth {}; \
         {:.1} GPU bytes per triangle ({:.1} MiB)",
        built.scene.triangle_count(),
        built.bvh.nodes.len(),
        built.bvh.leaf_count(),
        built.bvh.depth(),
        built.bvh.gpu_bytes() as f64 / triangles as f64,
        built.bvh.gpu_bytes() as f64 / (1024.0 * 1024.0),
    );
    let ray_sets = [("camera", RayKind::Camera), ("random", RayKind::Random)]
        .into_iter()
        .map(|(name, kind)| {
            let world = rays(&built.scene, kind, RAY_COUNT, SEED);
            let local = local_rays(raypick::frame::Frame::at(built.bvh.origin), &world);
            (name, world, local)
        })
        .collect();
    Fixture {
        built: Arc::new(built),
        ray_sets,
    }
});

/// 708 × 708 samples, 1 m apart: 999,698 triangles.
fn terrain_scene() -> Scene {
    let mesh = terrain(708, 708, 0.0, 707.0, 1.0, hills);
    Scene::from_meshes([("terrain".to_string(), mesh)]).expect("the terrain is well formed")
}

/// Every group takes 10 flat samples: the routines run for tens to thousands of milliseconds.
fn configure(group: &mut BenchmarkGroup<'_, WallTime>, measurement_secs: u64) {
    group
        .sample_size(10)
        .sampling_mode(SamplingMode::Flat)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(measurement_secs));
}

fn build(c: &mut Criterion) {
    let scene = FIXTURE.built.scene.clone();
    let mut group = c.benchmark_group("build");
    configure(&mut group, 8);
    group.throughput(Throughput::Elements(scene.triangle_count() as u64));
    let options = BuildOptions::default();
    group.bench_function("median_cut_terrain_1m", |b| {
        b.iter_batched(
            || scene.clone(),
            |scene| BuiltScene::new(scene, &options).expect("terrain builds"),
            BatchSize::LargeInput,
        )
    });
    group.finish();
}

fn pick_cpu(c: &mut Criterion) {
    let fixture = &*FIXTURE;
    let mut group = c.benchmark_group("pick_cpu");
    configure(&mut group, 5);
    for (name, world, local) in &fixture.ray_sets {
        group.throughput(Throughput::Elements(world.len() as u64));
        let mut picker = CpuPicker::new(fixture.built.clone());
        group.bench_function(format!("pick/{name}"), |b| {
            b.iter(|| picker.pick(black_box(world)).expect("cpu pick"))
        });
        // The traversal alone, without the frame conversion and f64 refinement: the part that
        // compares like for like with the peer below.
        group.bench_function(format!("trace/{name}"), |b| {
            b.iter(|| cpu::trace_all(&fixture.built.bvh, black_box(local)))
        });
    }
    group.finish();
}

fn pick_gpu(c: &mut Criterion) {
    let context = match GpuContext::new() {
        Ok(context) => context,
        Err(e) => {
            eprintln!("pick_gpu: skipped, no GPU adapter: {e}");
            return;
        }
    };
    eprintln!("pick_gpu: adapter {}", context.describe());
    let fixture = &*FIXTURE;
    let mut picker = match GpuPicker::new(&context, fixture.built.clone()) {
        Ok(picker) => picker,
        Err(e) => {
            eprintln!("pick_gpu: skipped, the scene cannot be uploaded: {e}");
            return;
        }
    };
    let mut group = c.benchmark_group("pick_gpu");
    configure(&mut group, 10);
    for (name, world, _) in &fixture.ray_sets {
        group.throughput(Throughput::Elements(world.len() as u64));
        group.bench_function(format!("pick/{name}"), |b| {
            b.iter(|| picker.pick(black_box(world)).expect("gpu pick"))
        });
    }
    group.finish();
}

/// The scene's triangles as obvhs triangles, in the same scene-local f32 frame as our tree.
fn obvhs_triangles(built: &BuiltScene) -> Vec<Triangle> {
    let origin = built.bvh.origin;
    (0..built.scene.triangle_count())
        .map(|i| {
            let [v0, v1, v2] = built
                .scene
                .world_triangle(i)
                .map(|p| Vec3A::from((p - origin).as_vec3()));
            Triangle { v0, v1, v2 }
        })
        .collect()
}

fn peer_obvhs(c: &mut Criterion) {
    let fixture = &*FIXTURE;
    let triangles = obvhs_triangles(&fixture.built);
    let (bvh, ordered) = obvhs_build(&triangles);
    let bytes = std::mem::size_of_val(bvh.nodes.as_slice())
        + std::mem::size_of_val(bvh.primitive_indices.as_slice())
        + std::mem::size_of_val(ordered.as_slice());
    eprintln!(
        "obvhs: {} CWBVH nodes; {:.1} bytes per triangle (nodes, indices, leaf-ordered triangles)",
        bvh.nodes.len(),
        bytes as f64 / triangles.len() as f64,
    );

    let mut group = c.benchmark_group("peer_obvhs");
    configure(&mut group, 10);
    group.throughput(Throughput::Elements(triangles.len() as u64));
    group.bench_function("build_cwbvh_fast_terrain_1m", |b| {
        b.iter(|| obvhs_build(black_box(&triangles)))
    });

    let cpu_trace = |local: &[GpuRay]| cpu::trace_all(&fixture.built.bvh, local);
    for (name, _, local) in &fixture.ray_sets {
        let peer_rays: Vec<obvhs::ray::Ray> = local
            .iter()
            .map(|r| {
                obvhs::ray::Ray::new(r.origin.into(), r.dir.into(), r.tmin, r.tmax.min(f32::MAX))
            })
            .collect();
        report_agreement(
            name,
            &cpu_trace(local),
            &obvhs_trace(&bvh, &ordered, &peer_rays),
        );
        group.throughput(Throughput::Elements(peer_rays.len() as u64));
        group.bench_function(format!("trace/{name}"), |b| {
            b.iter(|| obvhs_trace(&bvh, &ordered, black_box(&peer_rays)))
        });
    }
    group.finish();
}

/// Prints how often obvhs and our traversal agree on hit/miss and on the hit distance, so a
/// mis-set-up peer cannot pass unnoticed.
fn report_agreement(name: &str, ours: &[raypick::layout::GpuHit], theirs: &[RayHit]) {
    let mut same_outcome = 0;
    let mut same_t = 0;
    let mut hits = 0;
    for (a, b) in ours.iter().zip(theirs) {
        let (ours_hit, theirs_hit) = (a.prim != NO_HIT, b.t.is_finite());
        hits += usize::from(ours_hit);
        if ours_hit == theirs_hit {
            same_outcome += 1;
            if !ours_hit || (a.t - b.t).abs() <= 1e-4 * a.t.abs().max(1.0) {
                same_t += 1;
            }
        }
    }
    eprintln!(
        "obvhs vs raypick, {name} rays: {hits}/{} hit; same hit/miss {same_outcome}, same t {same_t}",
        ours.len()
    );
}

criterion_group!(benches, build, pick_cpu, pick_gpu, peer_obvhs);
criterion_main!(benches);
