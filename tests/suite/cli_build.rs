//! `raypick build --out FILE.rpk` and `--scene FILE.rpk`: the saved built scene answers every
//! command's picks byte for byte as the scene it was built from, on every backend, and misuse
//! or a damaged file is exit 2 with one sentence naming the file.

use std::path::Path;

use crate::common::raypick;

fn tmp(name: &str) -> String {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("cli_build");
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name).display().to_string()
}

#[test]
fn a_saved_scene_picks_byte_identically_on_every_backend() {
    let cases: [(&str, Vec<&str>); 3] = [
        ("bunny.rpk", vec!["--scene", "tests/data/bunny.obj"]),
        (
            "dem.rpk",
            vec!["--scene", "tests/data/jacksboro_fault_dem_utm.asc"],
        ),
        ("example.rpk", vec![]),
    ];
    for (name, scene) in cases {
        let rpk = tmp(name);
        let mut build = vec!["build", "-q", "--out", &rpk];
        build.extend(&scene);
        let (code, _, err) = raypick(&build);
        assert_eq!(code, 0, "{err}");
        for backend in ["cpu", "reference", "gpu"] {
            let mut from_files = vec!["pick", "-q", "--backend", backend];
            from_files.extend(&scene);
            let (c1, csv_files, e1) = raypick(&from_files);
            let (c2, csv_rpk, e2) = raypick(&["pick", "-q", "--backend", backend, "--scene", &rpk]);
            assert_eq!((c1, c2), (0, 0), "{e1}{e2}");
            assert!(csv_files.lines().count() > 1);
            assert_eq!(csv_files, csv_rpk, "{name} on {backend}");
        }
    }
}

#[test]
fn misuse_and_damage_are_exit_2_naming_the_file() {
    let rpk = tmp("misuse.rpk");
    assert_eq!(raypick(&["build", "-q", "--out", &rpk]).0, 0);
    let refused = [
        vec!["pick", "--scene", &rpk, "--scene", "tests/data/bunny.obj"],
        vec!["pick", "--scene", &rpk, "--mask", "1"],
        vec!["pick", "--scene", &rpk, "--builder", "sah"],
    ];
    for args in refused {
        let (code, _, err) = raypick(&args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(err.contains("misuse.rpk"), "{err}");
    }
    let bytes = std::fs::read(&rpk).unwrap();
    let truncated = tmp("truncated.rpk");
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
    let mut flipped = bytes.clone();
    let at = bytes.len() * 2 / 3;
    flipped[at] ^= 0x5a;
    let corrupted = tmp("corrupted.rpk");
    std::fs::write(&corrupted, &flipped).unwrap();
    for bad in [&truncated, &corrupted] {
        let (code, _, err) = raypick(&["pick", "-q", "--scene", bad]);
        assert_eq!(code, 2, "{err}");
        let name = Path::new(bad).file_name().unwrap().to_str().unwrap();
        assert!(err.contains(name), "{err}");
        assert!(!err.contains("panicked"), "{err}");
    }
    // A folder as --out is named as one (the save said "Not a directory (os error 20)").
    let folder = std::env::temp_dir().display().to_string();
    let (code, _, err) = raypick(&["build", "-q", "--out", &folder]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains(&format!("--out {folder} is a folder")),
        "{err}"
    );
}

/// The warnings `build` gives about what the scene's frame cannot hold (here a scene 10¹³
/// across, too wide for the f32 tests' products) are given again by every command that picks
/// from the saved scene: loading a `.rpk` said nothing, so its user picked without a word.
#[test]
fn a_saved_scene_repeats_the_warnings_it_was_built_with() {
    let warnings = |err: &str| -> Vec<String> {
        err.lines()
            .filter(|l| l.starts_with("warning:"))
            .map(str::to_owned)
            .collect()
    };
    let wide = tmp("wide.obj");
    std::fs::write(
        &wide,
        "v 0 0 0\nv 1e13 0 0\nv 0 1e13 0\nv 0 0 1e13\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n",
    )
    .unwrap();
    for (obj, rpk, warned) in [
        (wide.as_str(), tmp("wide.rpk"), true),
        ("tests/data/bunny.obj", tmp("quiet.rpk"), false),
    ] {
        let (code, _, err) = raypick(&["build", "-q", "--scene", obj, "--out", &rpk]);
        assert_eq!(code, 0, "{err}");
        let built = warnings(&err);
        assert_eq!(!built.is_empty(), warned, "{obj}: {built:?}");
        if warned {
            assert!(built[0].contains("past 1e12"), "{built:?}");
        }
        for command in [
            vec!["pick", "-q", "--scene", &rpk],
            vec!["pick", "-q", "--backend", "reference", "--scene", &rpk],
            vec![
                "render", "-q", "--scene", &rpk, "--width", "8", "--height", "8", "--out",
            ],
        ] {
            let mut args = command.clone();
            let png = tmp("warned.png");
            if args.last() == Some(&"--out") {
                args.push(&png);
            }
            let (code, _, err) = raypick(&args);
            assert_eq!(code, 0, "{args:?}: {err}");
            assert_eq!(warnings(&err), built, "{args:?}");
        }
    }
}
