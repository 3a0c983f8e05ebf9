//! Moving an object's vertices without rebuilding (`BuiltScene::set_positions`) against
//! building again, on the same scene:
//!
//! - `refit/<scene>/build`: `BuiltScene::new` (median cut, the default) and the engine's
//!   collapse (`BuiltScene::wide`): what a picker over new positions needs from scratch;
//! - `refit/<scene>/build_binary`: `Bvh::build` alone;
//! - `refit/<scene>/refit`: `BuiltScene::set_positions` with the whole object moved (rotated,
//!   scaled, shifted), alternating between two poses: the positions copied in, the bounds, the
//!   object's leaf-order triangles rewritten, the binary tree's and the wide tree's boxes
//!   recomputed.
//!
//! Before criterion runs, each scene prints the medians of 15 rounds (each runs all three in
//! turn, so a slow spell on a shared machine falls on all alike) and the ratios
//! refit ÷ build and refit ÷ binary build (issue 15's target: ≤ 10% on the 202k-triangle
//! dragon).
//!
//! Scenes: the Stanford dragon (`../shared/data/dragon_res2.obj`, skipped with a note when
//! absent) and the bunny (`tests/data/bunny.obj`). Run with `cargo bench --bench refit`.

#[path = "common/short_groups.rs"]
mod short_groups;
#[path = "common/timing.rs"]
mod timing;

use criterion::{Criterion, criterion_group, criterion_main};
use glam::{DMat3, DVec3};
use raypick::io::obj::load_obj;
use raypick::{BuildOptions, BuiltScene, Bvh, Refit, Scene};
use short_groups::configure;
use std::hint::black_box;
use std::path::Path;
use timing::interleaved_medians_ms;

/// The scenes: name and OBJ path.
const SCENES: [(&str, &str); 2] = [
    ("dragon", "../shared/data/dragon_res2.obj"),
    ("bunny", "tests/data/bunny.obj"),
];

/// Object 0's positions turned by `angle` about z, stretched and shifted.
fn pose(scene: &Scene, angle: f64) -> Vec<DVec3> {
    let turn = DMat3::from_rotation_z(angle);
    scene
        .object_vertices(0)
        .map(|v| turn * (scene.position(v) * DVec3::new(1.0, 1.1, 0.9)) + DVec3::splat(angle))
        .collect()
}

fn refit(c: &mut Criterion) {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    for (name, path) in SCENES {
        let path = manifest.join(path);
        if !path.exists() {
            eprintln!("refit/{name}: skipped, {} is absent", path.display());
            continue;
        }
        let mesh = load_obj(&path).expect("load");
        let scene = Scene::from_meshes([(name.to_string(), mesh)]).expect("scene");
        let options = BuildOptions::default();
        let build = || {
            let built = BuiltScene::new(scene.clone(), &options).expect("build");
            built.wide().expect("collapse");
            built
        };
        let mut built = build();
        let poses = [pose(&scene, 0.25), pose(&scene, 0.5)];
        let mut k = 0;
        let mut refit = |built: &mut BuiltScene| {
            k ^= 1;
            let outcome = built.set_positions(0, &poses[k]).expect("refit");
            assert_eq!(outcome, Refit::Refitted);
        };
        // Built, built binary and refitted in turn, fifteen rounds.
        let [build_ms, binary_ms, refit_ms] = interleaved_medians_ms(
            15,
            [
                &mut || {
                    black_box(build());
                },
                &mut || {
                    black_box(Bvh::build(&scene, &options).expect("build"));
                },
                &mut || refit(&mut built),
            ],
        );
        println!(
            "refit/{name}: {} triangles; build + collapse {build_ms:.2} ms, binary build \
             {binary_ms:.2} ms, refit {refit_ms:.2} ms: refit / build = {:.3}, refit / binary \
             build = {:.3} (medians of 15)",
            scene.triangle_count(),
            refit_ms / build_ms,
            refit_ms / binary_ms
        );
        let mut group = c.benchmark_group(format!("refit/{name}"));
        configure(&mut group);
        group.bench_function("build", |b| b.iter(|| black_box(build())));
        group.bench_function("build_binary", |b| {
            b.iter(|| black_box(Bvh::build(&scene, &options).expect("build")))
        });
        group.bench_function("refit", |b| b.iter(|| refit(&mut built)));
        group.finish();
    }
}

criterion_group!(benches, refit);
criterion_main!(benches);
