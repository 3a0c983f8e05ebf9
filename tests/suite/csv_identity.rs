//! Whole-command identity: `raypick pick` writes the same CSV bytes, closest and all-hits
//! modes, whichever backend (`cpu`, `gpu`, `reference`) and builder (`median-cut`, `sah`, and
//! `grid` for a DEM) answers, on a test mesh and a test DEM, edge and vertex rays included. The
//! tie rule is what makes this hold.

use crate::common;

use raypick::check::synthetic::mixed_rays;
use raypick::io::scene_files::{SceneFile, load_scene};
use std::path::{Path, PathBuf};
use std::process::Command;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// A ray file of `count` mixed rays (camera, random, vertex, edge-midpoint, grazing, …) over
/// the scene in `file`, written with Rust's shortest round-trip formatting.
fn ray_file(file: &Path, count: usize) -> PathBuf {
    let scene = load_scene(&[SceneFile {
        file: file.to_path_buf(),
        mask: None,
        transform: None,
    }])
    .expect("the scene loads");
    let stem = file.file_stem().unwrap().to_string_lossy();
    let path = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("identity-{stem}.rays"));
    write_rays(&scene, count, 17, &path);
    path
}

/// Writes `count` mixed rays over `scene` (seed `seed`) to `path`, one per line.
fn write_rays(scene: &raypick::Scene, count: usize, seed: u64, path: &Path) {
    let mut text = String::new();
    for (_, r) in mixed_rays(scene, count, seed) {
        let (o, d) = (r.origin, r.dir);
        text += &format!(
            "{:?} {:?} {:?} {:?} {:?} {:?}\n",
            o.x, o.y, o.z, d.x, d.y, d.z
        );
    }
    std::fs::write(path, text).expect("write the ray file");
}

/// `raypick pick --scene FILE` (or `--scenes` for a `.json` description) on `rays`.
fn pick(scene: &Path, rays: &Path, extra: &[&str]) -> Vec<u8> {
    let flag = if scene.extension().is_some_and(|e| e == "json") {
        "--scenes"
    } else {
        "--scene"
    };
    let out = Command::new(env!("CARGO_BIN_EXE_raypick"))
        .arg("pick")
        .arg(flag)
        .arg(scene)
        .arg("--rays")
        .arg(rays)
        .args(extra)
        .output()
        .expect("run raypick");
    assert!(
        out.status.success(),
        "raypick pick {extra:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out.stdout
}

#[test]
fn every_backend_and_builder_writes_the_same_csv() {
    common::gpu(); // the GPU runs below: record that the GPU tests ran, and fail without one
    for (name, builders) in [
        ("bunny.obj", vec!["median-cut", "sah"]),
        (
            "jacksboro_fault_dem_utm.asc",
            vec!["grid", "median-cut", "sah"],
        ),
    ] {
        let scene = data(name);
        let rays = ray_file(&scene, 2000);
        for mode in [
            &["--mode", "closest"][..],
            &["--mode", "all", "--max-hits", "4"],
        ] {
            let mut first: Option<(String, Vec<u8>)> = None;
            for builder in &builders {
                for backend in ["cpu", "gpu", "reference"] {
                    let mut args = vec!["--backend", backend, "--builder", builder];
                    args.extend_from_slice(mode);
                    let csv = pick(&scene, &rays, &args);
                    assert!(csv.len() > 2000 * 20, "{name} {args:?}: too little output");
                    match &first {
                        None => first = Some((format!("{args:?}"), csv)),
                        Some((what, want)) => assert!(
                            &csv == want,
                            "{name}: {args:?} writes other CSV than {what}"
                        ),
                    }
                }
            }
        }
    }
}

#[test]
fn a_described_scene_with_transforms_writes_the_same_csv_on_every_backend() {
    common::gpu();
    // The bunny three times: as it is, turned and moved, and mirrored (negative determinant).
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("identity-transforms");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::copy(data("bunny.obj"), dir.join("bunny.obj")).unwrap();
    let description = dir.join("scene.json");
    std::fs::write(
        &description,
        r#"{"objects": [
            {"file": "bunny.obj"},
            {"file": "bunny.obj", "transform": [[0.8, -0.6, 0, 4.5], [0.6, 0.8, 0, -1.25], [0, 0, 1.5, 0.5]]},
            {"file": "bunny.obj", "mask": 2, "transform": [[-1, 0, 0, -4], [0, 1, 0, 0.75], [0, 0, 1, 0]]}
        ]}"#,
    )
    .unwrap();
    let scene = load_scene(&raypick::io::scene_files::load_description(&description).unwrap())
        .expect("the description loads");
    assert!(scene.objects()[2].mirrored);
    let rays = dir.join("rays.txt");
    write_rays(&scene, 2000, 23, &rays);
    for mode in [
        &["--mode", "closest", "--cull", "back"][..],
        &["--mode", "all", "--max-hits", "4"],
    ] {
        let mut first: Option<(String, Vec<u8>)> = None;
        for builder in ["median-cut", "sah"] {
            for backend in ["cpu", "gpu", "reference"] {
                let mut args = vec!["--backend", backend, "--builder", builder];
                args.extend_from_slice(mode);
                let csv = pick(&description, &rays, &args);
                assert!(csv.len() > 2000 * 20, "{args:?}: too little output");
                match &first {
                    None => first = Some((format!("{args:?}"), csv)),
                    Some((what, want)) => {
                        assert!(&csv == want, "{args:?} writes other CSV than {what}")
                    }
                }
            }
        }
    }
}
