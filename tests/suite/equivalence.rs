//! GPU, CPU and brute force agree on every scene and ray kind: zero mismatches.

use crate::common;

use common::check_scene;
use raypick::check::synthetic::{
    hills, single_triangle, terrain, thin_and_degenerate, triangle_soup,
};
use raypick::io::obj::load_obj;
use raypick::{BuildOptions, Builder, Scene, SplitAxis};
use std::path::Path;

fn one(name: &str, mesh: raypick::Mesh) -> Scene {
    Scene::from_meshes([(name.to_string(), mesh)]).expect("scene")
}

fn bunny() -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/bunny.obj");
    one("bunny", load_obj(&path).expect("bunny"))
}

const RAYS: usize = 4000;

#[test]
fn triangle_soup_agrees() {
    let hits = check_scene(
        "soup",
        one("soup", triangle_soup(3000, 10.0, 1)),
        BuildOptions::default(),
        RAYS,
    );
    assert!(hits.iter().filter(|h| h.hit).count() > RAYS / 4);
}

#[test]
fn terrain_agrees() {
    let hits = check_scene(
        "terrain",
        one("terrain", terrain(48, 40, 100.0, 200.0, 2.5, hills)),
        BuildOptions::default(),
        RAYS,
    );
    assert!(hits.iter().filter(|h| h.hit).count() > RAYS / 4);
}

#[test]
fn bunny_agrees() {
    let hits = check_scene("bunny", bunny(), BuildOptions::default(), RAYS);
    assert!(hits.iter().filter(|h| h.hit).count() > RAYS / 4);
}

#[test]
fn thin_and_degenerate_triangles_agree() {
    let scene = one("thin", thin_and_degenerate(3));
    let degenerate = (0..scene.triangle_count())
        .filter(|&i| scene.is_degenerate(i))
        .count();
    assert_eq!(degenerate, 100, "half the triangles have zero area");
    let hits = check_scene("thin", scene, BuildOptions::default(), RAYS);
    for h in hits.iter().filter(|h| h.hit) {
        assert!(
            h.triangle % 4 >= 2,
            "zero-area triangle {} was hit",
            h.triangle
        );
    }
}

#[test]
fn single_triangle_agrees() {
    let hits = check_scene(
        "single",
        one("single", single_triangle()),
        BuildOptions::default(),
        RAYS,
    );
    assert!(hits.iter().any(|h| h.hit));
}

#[test]
fn empty_scene_misses_everything() {
    let hits = check_scene("empty", Scene::new(), BuildOptions::default(), 800);
    assert!(hits.iter().all(|h| !h.hit));
}

#[test]
fn every_split_policy_and_leaf_size_agrees() {
    for split_axis in [SplitAxis::Cycle, SplitAxis::Longest] {
        for leaf_size in [1, 2, 8, 15] {
            let options = BuildOptions {
                builder: Builder::MedianCut,
                split_axis,
                leaf_size,
            };
            let name = format!("{split_axis:?}/{leaf_size}");
            check_scene(&name, bunny(), options, 1600);
            check_scene(
                &name,
                one("terrain", terrain(24, 24, 0.0, 0.0, 1.0, hills)),
                options,
                1600,
            );
        }
    }
}

#[test]
fn real_elevation_grid_agrees() {
    // The Jacksboro fault DEM (403 × 344 samples at UTM-sized coordinates), from a GeoTIFF.
    let dem = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/jacksboro_fault_dem_utm_f32_deflate.tif");
    let scene = raypick::io::scene_files::load_scene(&[raypick::io::scene_files::SceneFile {
        file: dem,
        mask: None,
        transform: None,
    }])
    .unwrap();
    let hits = check_scene("jacksboro", scene, BuildOptions::default(), 800);
    assert!(hits.iter().filter(|h| h.hit).count() > 200);
    assert!(
        hits.iter().filter(|h| h.hit).all(|h| h.cell.is_some()),
        "terrain hits carry row and col"
    );
}
