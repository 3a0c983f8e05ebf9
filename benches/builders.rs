//! The builders side by side on the same scenes and rays: median cut, binned SAH
//! (`bvh::binned_sah`) and, on height grids, the grid builder over terrain blocks
//! (`bvh::terrain_blocks`), each at leaf size 4 (the default) and 8:
//!
//! - `build/<scene>`: `Bvh::build` with each builder, the tree alone;
//! - `trace/<scene>`: `cpu::trace_all` of 65,536 camera and 65,536 random rays
//!   (`synthetic::rays`) over each tree;
//! - `gpu/<scene>`: `GpuPicker::trace` of the same rays over each tree, on the bunny and the
//!   terrain only (skipped, saying why, without a GPU adapter).
//!
//! Scenes: the Stanford bunny, the Stanford dragon (`../shared/data/dragon_res2.obj`, skipped
//! with a note when absent), the Jacksboro fault DEM, a 708 × 708-sample terrain (999,698
//! triangles) and a soup of 200,000 random triangles.
//!
//! Before timing, each scene prints per builder: nodes, depth, SAH cost (`bvh::sah_cost`) and the
//! mean box tests b and triangle tests i per ray of each ray kind.
//!
//! Run with `cargo bench --bench builders` (one scene: `cargo bench --bench builders -- bunny`).

#[path = "common/short_groups.rs"]
mod short_groups;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use raypick::bvh::sah_cost::sah_cost;
use raypick::bvh::terrain_blocks::single_grid;
use raypick::check::synthetic::{RayKind, hills, rays, terrain, triangle_soup};
use raypick::frame::local_rays;
use raypick::io::obj::load_obj;
use raypick::io::scene_files::{SceneFile, load_scene};
use raypick::layout::{GpuHit, GpuRay};
use raypick::{
    BuildOptions, Builder, BuiltScene, Bvh, GpuContext, GpuPicker, GridShape, Scene, cpu,
};
use short_groups::configure;
use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Rays per batch.
const RAY_COUNT: usize = 65_536;
/// Seed for the ray sets and the soup.
const SEED: u64 = 1;
/// The dragon, beside the repository in `../shared/data` (it is not in the repository).
const DRAGON: &str = "../shared/data/dragon_res2.obj";

/// The builder settings compared, by the name the bench ids use.
const BUILDERS: [(&str, Builder, u32); 6] = [
    ("median_cut", Builder::MedianCut, 4),
    ("median_cut_leaf8", Builder::MedianCut, 8),
    ("binned_sah", Builder::BinnedSah, 4),
    ("binned_sah_leaf8", Builder::BinnedSah, 8),
    ("grid", Builder::Grid, 4),
    ("grid_leaf8", Builder::Grid, 8),
];

/// The settings of `BUILDERS` that apply to `scene` (the grid builder needs one height grid).
fn builders_for(scene: &Scene) -> Vec<(&'static str, BuildOptions)> {
    BUILDERS
        .iter()
        .filter(|(_, builder, _)| *builder != Builder::Grid || single_grid(scene).is_some())
        .map(|&(name, builder, leaf_size)| {
            let options = BuildOptions {
                builder,
                leaf_size,
                ..BuildOptions::default()
            };
            (name, options)
        })
        .collect()
}

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

fn obj(name: &str, path: &Path) -> Scene {
    let mesh = load_obj(path).unwrap_or_else(|e| panic!("{} loads: {e}", path.display()));
    Scene::from_meshes([(name.to_string(), mesh)]).expect("the mesh is well formed")
}

fn dem() -> Scene {
    load_scene(&[SceneFile {
        file: data("jacksboro_fault_dem_utm.asc"),
        mask: None,
        transform: None,
    }])
    .expect("the Jacksboro DEM loads")
}

/// 708 × 708 samples, 1 m apart: 999,698 triangles (as `benches/pick.rs`), as a height grid.
fn terrain_1m() -> Scene {
    let mesh = terrain(708, 708, 0.0, 707.0, 1.0, hills);
    let shape = GridShape {
        columns: 708,
        rows: 708,
    };
    let mut scene = Scene::new();
    scene
        .add_grid_mesh("terrain", mesh, shape)
        .expect("the terrain is well formed");
    scene
}

/// 200,000 random triangles in a 100-unit cube, edges up to 10 units.
fn soup() -> Scene {
    let mesh = triangle_soup(200_000, 100.0, SEED);
    Scene::from_meshes([("soup".to_string(), mesh)]).expect("the soup is well formed")
}

/// Mean box tests b and triangle tests i per ray.
fn mean_tests(hits: &[GpuHit]) -> (f64, f64) {
    let n = hits.len().max(1) as f64;
    let b: u64 = hits.iter().map(|h| u64::from(h.box_tests)).sum();
    let i: u64 = hits.iter().map(|h| u64::from(h.triangle_tests)).sum();
    (b as f64 / n, i as f64 / n)
}

/// Builds both trees over `scene`, prints their statistics, and times the builds and the CPU
/// (and, with `gpu`, GPU) traversal of camera and random rays over each.
fn bench_scene(c: &mut Criterion, name: &str, scene: Scene, gpu: Option<&GpuContext>) {
    let builders = builders_for(&scene);
    let ray_sets: Vec<(&str, Vec<GpuRay>)> =
        [("camera", RayKind::Camera), ("random", RayKind::Random)]
            .into_iter()
            .map(|(kind_name, kind)| {
                let world = rays(&scene, kind, RAY_COUNT, SEED);
                (
                    kind_name,
                    local_rays(raypick::frame::Frame::at(scene.origin()), &world),
                )
            })
            .collect();
    let trees: Vec<(&str, Bvh)> = builders
        .iter()
        .map(|(name, options)| {
            (
                *name,
                Bvh::build(&scene, options).expect("the scene builds"),
            )
        })
        .collect();
    eprintln!(
        "{name}: {} triangles, {} in the trees",
        scene.triangle_count(),
        trees[0].1.triangles.len()
    );
    for (builder, bvh) in &trees {
        let tests: Vec<String> = ray_sets
            .iter()
            .map(|(kind_name, local)| {
                let (b, i) = mean_tests(&cpu::trace_all(bvh, local));
                format!("{kind_name} b {b:.2} i {i:.2}")
            })
            .collect();
        eprintln!(
            "{name} {builder:>16}: {} nodes, depth {}, {:.1} GPU bytes/triangle, SAH cost {:.2}; {}",
            bvh.nodes.len(),
            bvh.depth(),
            bvh.gpu_bytes() as f64 / bvh.triangles.len().max(1) as f64,
            sah_cost(bvh),
            tests.join(", ")
        );
    }

    let mut group = c.benchmark_group(format!("build/{name}"));
    configure(&mut group);
    group.throughput(Throughput::Elements(scene.triangle_count() as u64));
    for (builder, options) in &builders {
        group.bench_function(*builder, |b| {
            b.iter(|| Bvh::build(black_box(&scene), options).expect("the scene builds"))
        });
    }
    group.finish();

    let mut group = c.benchmark_group(format!("trace/{name}"));
    configure(&mut group);
    for (builder, bvh) in &trees {
        for (kind_name, local) in &ray_sets {
            group.throughput(Throughput::Elements(local.len() as u64));
            group.bench_function(format!("{builder}/{kind_name}"), |b| {
                b.iter(|| cpu::trace_all(bvh, black_box(local)))
            });
        }
    }
    group.finish();

    let Some(context) = gpu else {
        return;
    };
    let mut group = c.benchmark_group(format!("gpu/{name}"));
    configure(&mut group);
    for (builder, bvh) in trees {
        let built = Arc::new(BuiltScene::from_parts(scene.clone(), bvh, Vec::new()));
        let mut picker = GpuPicker::new(context, built).expect("the scene uploads");
        for (kind_name, local) in &ray_sets {
            group.throughput(Throughput::Elements(local.len() as u64));
            group.bench_function(format!("{builder}/{kind_name}"), |b| {
                b.iter(|| picker.trace(black_box(local)).expect("gpu trace"))
            });
        }
    }
    group.finish();
}

fn builders(c: &mut Criterion) {
    let context = GpuContext::new()
        .inspect(|context| eprintln!("gpu: adapter {}", context.describe()))
        .inspect_err(|e| eprintln!("gpu: skipped, no GPU adapter: {e}"))
        .ok();
    bench_scene(
        c,
        "bunny",
        obj("bunny", &data("bunny.obj")),
        context.as_ref(),
    );
    let dragon = Path::new(env!("CARGO_MANIFEST_DIR")).join(DRAGON);
    if dragon.exists() {
        bench_scene(c, "dragon", obj("dragon", &dragon), None);
    } else {
        eprintln!("dragon: skipped, {DRAGON} is absent");
    }
    bench_scene(c, "jacksboro", dem(), None);
    bench_scene(c, "terrain_1m", terrain_1m(), context.as_ref());
    bench_scene(c, "soup_200k", soup(), None);
}

criterion_group!(benches, builders);
criterion_main!(benches);
