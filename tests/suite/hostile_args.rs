//! Hostile arguments and inputs to the `raypick` binary (issue 11, items 2, 5, 6, 9–13): sizes
//! over the memory budget (`--max-memory`), zero and huge counts, directions too short to
//! normalize, ray mask 0, NaN arguments, huge tokens in error messages, extreme numbers in CSV,
//! arguments checked before any output, short OBJ faces, and server answers that must not show
//! the server's paths; and (issue 16) every command's missing required options, and outputs
//! named as a format the command does not write.
//!
//! Every refusal is exit code 2 with one sentence on standard error that names the value, never
//! a panic or an abort. This file owns those checks; `tests/suite/cli.rs` owns ordinary CLI behaviour.

use glam::DVec3;
use raypick::check::oracle::brute_force_query;
use raypick::check::synthetic::example_scene;
use raypick::{
    Backend, BuildOptions, BuiltScene, CpuPicker, Mode, Picker, Query, Ray, ReferencePicker,
};
use std::process::Command;
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::common::raypick;

/// A file in the temporary folder, unique to this test process.
fn temp_file(name: &str, text: &str) -> String {
    crate::unique_temp_file("raypick-hostile", name, text)
        .display()
        .to_string()
}

/// The last part of `path` (a [`temp_file`]'s name, for a description beside it to list).
fn file_name(path: &str) -> String {
    let name = std::path::Path::new(path).file_name().unwrap();
    name.to_str().unwrap().to_owned()
}

/// Asserts a refusal: exit 2, nothing on standard output, one line on standard error that starts
/// with `error:`, contains every one of `named`, and is no panic.
fn assert_refused(args: &[&str], named: &[&str]) -> String {
    let start = Instant::now();
    let (code, out, err) = raypick(args);
    assert_eq!(code, 2, "{args:?}: {err}");
    assert!(
        out.is_empty(),
        "{args:?} wrote output before failing: {out}"
    );
    assert!(!err.contains("panicked"), "{args:?}: {err}");
    assert!(
        err.starts_with("error:") && err.trim_end().lines().count() == 1,
        "{args:?}: one sentence expected, got {err:?}"
    );
    for n in named {
        assert!(err.contains(n), "{args:?}: {n:?} not named in {err:?}");
    }
    assert!(
        start.elapsed() < Duration::from_secs(20),
        "{args:?} took {:?} to refuse",
        start.elapsed()
    );
    err
}

/// A perspective camera file of `width × height` pixels over the example scene.
fn camera_file(name: &str, width: u64, height: u64) -> String {
    temp_file(
        name,
        &format!(
            r#"{{"perspective": {{"eye": [50, -60, 120], "target": [50, 50, 0], "up": [0, 0, 1],
                "fov_y_deg": 45, "width": {width}, "height": {height}}}}}"#
        ),
    )
}

#[test]
fn sizes_over_the_memory_budget_are_refused_by_name() {
    assert_refused(
        &[
            "render",
            "--width",
            "100000",
            "--height",
            "100000",
            "--out",
            "/dev/null",
        ],
        &["100000 x 100000", "memory budget", "--max-memory"],
    );
    let huge = camera_file("huge-camera.json", 1_000_000_000, 1_000_000_000);
    assert_refused(
        &["render", "--camera", &huge, "--out", "/dev/null"],
        &["1000000000 x 1000000000", "memory budget"],
    );
    assert_refused(
        &["idbuffer", "--camera", &huge, "--backend", "cpu"],
        &["1000000000 x 1000000000", "memory budget"],
    );
    let wide = camera_file("wide-camera.json", 100_000, 100_000);
    assert_refused(
        &[
            "select",
            "--camera",
            &wide,
            "--rect",
            "0",
            "0",
            "100000",
            "100000",
            "--backend",
            "cpu",
        ],
        &["100000 x 100000", "memory budget"],
    );
    assert_refused(
        &["probe", "--probes", "4294967295"],
        &["4294967295", "memory budget"],
    );
    assert_refused(
        &["verify", "--random", "18446744073709551615"],
        &["18446744073709551615", "memory budget"],
    );
    assert_refused(
        &["bench", "--rays", "18446744073709551615"],
        &["--rays 18446744073709551615", "memory budget"],
    );
    assert_refused(
        &["bench", "--picks", "18446744073709551615"],
        &["--picks 18446744073709551615", "memory budget"],
    );
}

#[test]
fn max_memory_sets_the_budget_and_is_documented() {
    let err = assert_refused(
        &[
            "render",
            "--max-memory",
            "4M",
            "--width",
            "1000",
            "--height",
            "1000",
            "--out",
            "/dev/null",
        ],
        &["1000 x 1000", "4.0 MiB"],
    );
    assert!(err.contains("memory budget"), "{err}");
    // The option is global: before the command too.
    assert_refused(
        &["--max-memory", "4M", "probe", "--probes", "100000"],
        &["100000", "4.0 MiB"],
    );
    let (code, _, err) = raypick(&["pick", "--max-memory", "lots"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("lots") && !err.contains("panicked"), "{err}");
    // Below the least budget: refused, not taken as 1 MiB without a word.
    for small in ["1", "1000", "1023K"] {
        let (code, _, err) = raypick(&["pick", "--max-memory", small]);
        assert_eq!(code, 2, "{small}: {err}");
        assert!(err.contains("least memory budget"), "{small}: {err}");
    }
    let (code, help, _) = raypick(&["pick", "--help"]);
    assert_eq!(code, 0);
    assert!(help.contains("--max-memory <SIZE>"), "{help}");
}

#[test]
fn all_hits_mode_shrinks_its_chunks_to_the_budget_instead_of_refusing() {
    // 3000 rays through the tower: 1024 list slots each would need about 450 MB in one chunk;
    // under a 16 MiB budget they are answered a few dozen rays at a time, with the same output.
    let rays: String = (0..3000)
        .map(|i| format!("{} 45.1 100 0 0 -1\n", 30.0 + (i % 100) as f64 * 0.07))
        .collect();
    let rays = temp_file("all-hits-rays.txt", &rays);
    let args = [
        "pick",
        "--rays",
        &rays,
        "--mode",
        "all",
        "--max-hits",
        "1024",
        "--backend",
        "cpu",
    ];
    let (code, small, err) = raypick(&[&args[..], &["--max-memory", "16M"]].concat());
    assert_eq!(code, 0, "{err}");
    let (code, whole, err) = raypick(&args);
    assert_eq!(code, 0, "{err}");
    assert_eq!(small, whole, "chunking changes nothing in the answers");
    assert!(small.lines().count() > 3000, "every hit has its row");
}

/// Under a 400 MB address-space limit, 20000 all-hits rays with 1024 list slots each (over
/// 600 MB of lists in one chunk) are answered within a 64 MiB budget instead of aborting.
#[cfg(target_os = "linux")]
#[test]
fn all_hits_mode_stays_within_the_budget_under_an_address_space_limit() {
    let rays: String = (0..20_000)
        .map(|i| format!("{} 45.1 100 0 0 -1\n", 30.0 + (i % 100) as f64 * 0.07))
        .collect();
    let rays = temp_file("all-hits-20k.txt", &rays);
    let script = format!(
        "ulimit -v 400000 && exec '{}' pick --rays '{rays}' --mode all --max-hits 1024 \
         --backend cpu --max-memory 64M",
        env!("CARGO_BIN_EXE_raypick")
    );
    let out = Command::new("sh")
        .args(["-c", &script])
        .env("MALLOC_ARENA_MAX", "2")
        .env("RAYON_NUM_THREADS", "2")
        .output()
        .expect("run sh");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{}", &err[..err.len().min(300)]);
    let rows = out.stdout.iter().filter(|&&b| b == b'\n').count();
    assert!(rows > 20_000, "{rows} rows");
}

/// The default budget is half of what the process can have: under a 1 GB address-space limit
/// (`ulimit -v`) a 3000 × 3000 render (3.3 GB of answers) is refused by name. With half the
/// machine's memory as the budget it passed the check and the process aborted when the
/// allocation failed. And `--max-memory` over what the process can have is refused.
#[cfg(target_os = "linux")]
#[test]
fn the_default_budget_keeps_within_an_address_space_limit() {
    let (code, err) = under_limit(
        "ulimit -v 1000000",
        "render --width 3000 --height 3000 --backend cpu --out /dev/null",
    );
    let start: String = err.chars().take(300).collect();
    assert_eq!(code, Some(2), "{start}");
    assert!(
        err.starts_with("error:")
            && err.contains("3000 x 3000")
            && err.contains("memory budget")
            && !err.contains("panicked"),
        "{err}"
    );
    let (code, _, err) = raypick(&["--max-memory", "1000000T", "pick"]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("1000000T") && err.contains("more memory than this process can have"),
        "{err}"
    );
}

/// Under `ulimit -v` the GPU's driver maps hundreds of MiB when it opens (lavapipe), which the
/// budget, checked before, did not see: a 1100 x 1100 render on `--backend gpu` or `auto`,
/// `verify --random 200000` and `soak --batch 1000000` aborted (exit 134, "memory allocation
/// of … failed"). The budget is now at most half of what the limit leaves the process at each
/// check, and the commands check again once the GPU is open.
#[test]
fn a_gpu_driver_s_mappings_count_against_an_address_space_limit() {
    if !backends().contains(&"gpu") {
        eprintln!("no GPU here: nothing maps the driver's memory");
        return;
    }
    let mut refused_after_opening = 0;
    for command in [
        "render --width 1100 --height 1100 --backend gpu --out /dev/null",
        "render --width 1100 --height 1100 --backend auto --out /dev/null",
        "verify --random 200000",
        "soak --rays 1000000 --batch 1000000",
    ] {
        let (code, err) = under_limit("ulimit -v 1000000", command);
        let start: String = err.chars().take(400).collect();
        assert!(
            code == Some(0) || code == Some(2),
            "{command}: {code:?} {start}"
        );
        assert!(
            !err.contains("panicked") && !err.contains("memory allocation of"),
            "{command}: {start}"
        );
        if code == Some(2) {
            assert!(err.contains("memory"), "{command}: {start}");
            refused_after_opening += usize::from(err.contains("`ulimit -v`, leaves it"));
        }
    }
    // Each needs over 300 MiB; with the driver mapped, less than that is left under 977 MiB.
    assert!(refused_after_opening >= 3, "{refused_after_opening}");
}

/// Limits of the process's own: a file-size limit (`ulimit -f`) killed the process with
/// SIGXFSZ and no word (exit 153), leaving a cut file, and `idbuffer --raw-ids` ignored a
/// failed write (exit 0, a cut PNG); threads the system refuses made rayon panic (exit 101).
/// Each is exit 2 with a sentence now.
#[test]
fn a_file_size_limit_and_refused_threads_are_errors_with_a_sentence() {
    let dir = std::env::temp_dir().join(format!("raypick-limits-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let rays = dir.join("rays.txt");
    let many: String = (0..2000)
        .map(|i| format!("{} 45.1 100 0 0 -1\n", 10.0 + f64::from(i) * 0.01))
        .collect();
    std::fs::write(&rays, many).unwrap();
    for (what, args) in [
        (
            "pick.csv",
            format!("pick --rays '{}' --backend cpu", rays.display()),
        ),
        ("ids.png", "idbuffer --backend cpu --raw-ids".to_owned()),
        ("view.png", "render --backend cpu".to_owned()),
    ] {
        let out = dir.join(what);
        let (code, err) = under_limit(
            "ulimit -f 1",
            &format!("{args} --out '{}' -q", out.display()),
        );
        assert_eq!(code, Some(2), "{what}: {err}");
        assert!(
            err.starts_with("error:") && err.contains(what) && err.contains("too large"),
            "{what}: {err}"
        );
    }
    // Counted as rayon counts them (the deprecated variable too), and refused before any is
    // started: those that did start could abort the process on a failed allocation before the
    // error was said.
    for (variable, threads) in [("RAYON_NUM_THREADS", 5000), ("RAYON_RS_NUM_CPUS", 5000)] {
        let (code, err) = under_limit(
            // `under_limit` sets RAYON_NUM_THREADS=2, which rayon reads first.
            &format!("ulimit -v 1000000 && unset RAYON_NUM_THREADS && export {variable}={threads}"),
            "pick --backend cpu",
        );
        assert_eq!(code, Some(2), "{variable}={threads}: {err}");
        assert!(
            err.starts_with(&format!(
                "error: cannot start the picking threads ({threads} threads need"
            )) && err.contains("for their stacks")
                && !err.contains("panicked"),
            "{variable}={threads}: {err}"
        );
    }
    // 100 threads' stacks fit under 1 GB; their allocator arenas, capped to the rest, do too
    // (they failed part-way before: the first threads' arenas took the later ones' stacks).
    let (code, err) = under_limit(
        "ulimit -v 1000000 && export RAYON_NUM_THREADS=100",
        "pick --backend cpu",
    );
    assert_eq!(code, Some(0), "{err}");
    assert!(err.contains("100 threads"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn zero_counts_and_counts_that_overflow_are_refused() {
    assert_refused(&["soak", "--rays", "0"], &["--rays 0"]);
    assert_refused(&["soak", "--batch", "0"], &["--batch 0"]);
    assert_refused(&["probe", "--probes", "0"], &["--probes 0"]);
    // verify of no rays said `b = NaN` and passed; a repeat count of billions never ended.
    for (args, named) in [
        (&["verify", "--random", "0"][..], "'0'"),
        (&["bench", "--repeat", "4294967295"][..], "'4294967295'"),
    ] {
        let (code, out, err) = raypick(args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(out.is_empty() && err.contains(named), "{args:?}: {err}");
    }
    // Argument errors come before any output.
    assert_refused(
        &["pick", "--mode", "all", "--max-hits", "0"],
        &["max hits 0"],
    );
}

/// `raypick ARGS` (as the shell splits them) run by `sh` after `limits` (e.g. `ulimit -v
/// 1000000`), on two threads: its exit code and standard error.
fn under_limit(limits: &str, args: &str) -> (Option<i32>, String) {
    let script = format!(
        "{limits} && exec '{}' {args}",
        env!("CARGO_BIN_EXE_raypick")
    );
    let out = Command::new("sh")
        .args(["-c", &script])
        .env("RAYON_NUM_THREADS", "2")
        .output()
        .expect("run sh");
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The backends to try on the command line: the GPU only where one opens.
fn backends() -> Vec<&'static str> {
    let (code, _, err) = raypick(&["pick", "--backend", "gpu"]);
    if code == 0 {
        vec!["cpu", "reference", "gpu"]
    } else {
        eprintln!("no GPU here ({err}); checking the CPU backends only");
        vec!["cpu", "reference"]
    }
}

#[test]
fn a_direction_too_short_to_normalize_is_invalid_and_warned() {
    let rays = temp_file(
        "tiny-dirs.txt",
        "33.3 45.1 100 0 0 -1e-320\n33.3 45.1 100 0 0 -1e-300\n",
    );
    for backend in backends() {
        let (code, out, err) = raypick(&["pick", "--rays", &rays, "--backend", backend]);
        assert_eq!(code, 0, "{err}");
        let rows: Vec<Vec<&str>> = out
            .lines()
            .skip(1)
            .map(|l| l.split(',').collect())
            .collect();
        assert_eq!(
            rows[0][1], "0",
            "{backend}: 1e-320 cannot be normalized: {out}"
        );
        assert!(!out.contains("inf") && !out.contains("NaN"), "{out}");
        assert!(
            err.contains("1 ray(s) were invalid") && err.contains("too short"),
            "{err}"
        );
        // 1e-300 can: a hit, t about 1e301, finite.
        assert_eq!(rows[1][1], "1", "{backend}: {out}");
        let t: f64 = rows[1][2].parse().unwrap();
        assert!(t.is_finite() && t > 1e300, "{t}");
        let (_, json, _) = raypick(&[
            "pick",
            "--rays",
            &rays,
            "--backend",
            backend,
            "--format",
            "json",
        ]);
        let v: serde_json::Value = serde_json::from_str(&json).unwrap();
        assert_eq!(v[0]["invalid"], true, "{json}");
    }
    // The library agrees: the ray is invalid, and the oracle says so too.
    let ray = Ray::new(DVec3::new(33.3, 45.1, 100.0), DVec3::new(0.0, 0.0, -1e-320));
    assert!(!ray.is_valid());
    let oracle = brute_force_query(&example_scene(), &[ray], &Query::default());
    assert!(oracle.nearest[0].invalid);
}

#[test]
fn a_hit_too_far_for_f64_is_no_hit_on_every_path() {
    // t of the tower's roof is about 1e308 / 6e-309: beyond f64. The ray is valid, but misses.
    let ray = Ray::new(DVec3::new(33.3, 45.1, 100.0), DVec3::new(0.0, 0.0, -6e-309));
    assert!(ray.is_valid());
    let built = Arc::new(BuiltScene::new(example_scene(), &BuildOptions::default()).unwrap());
    let query = Query::default();
    let oracle = brute_force_query(&built.scene, &[ray], &query);
    let mut pickers: Vec<Box<dyn Picker>> = vec![
        Box::new(CpuPicker::new(built.clone())),
        Box::new(ReferencePicker::new(built.clone())),
    ];
    assert!(!oracle.nearest[0].hit && !oracle.nearest[0].invalid);
    for picker in &mut pickers {
        let h = picker.query(&[ray], &query).unwrap().nearest[0];
        assert!(!h.hit && !h.invalid, "{h:?}");
    }
}

#[test]
fn ray_mask_zero_hits_nothing_on_every_backend() {
    let rays = temp_file("mask-rays.txt", "33.3 45.1 100 0 0 -1\n10 10 50 0 0 -1\n");
    for backend in backends() {
        for mode in ["closest", "any", "all"] {
            let (code, out, err) = raypick(&[
                "pick",
                "--rays",
                &rays,
                "--backend",
                backend,
                "--mode",
                mode,
                "--ray-mask",
                "0",
                "--format",
                "json",
            ]);
            assert_eq!(code, 0, "{err}");
            let v: serde_json::Value = serde_json::from_str(&out).unwrap();
            for r in v.as_array().unwrap() {
                let hit = r["hit"].as_bool().unwrap_or(false)
                    || r["hits"].as_array().is_some_and(|h| !h.is_empty());
                assert!(!hit, "{backend} {mode}: mask 0 hit something: {out}");
                assert_eq!(r["invalid"], false, "a plain miss, not invalid: {out}");
            }
            assert!(!err.contains("invalid"), "{err}");
        }
    }
    // With object masks set or not, the library and the oracle agree: nothing.
    let mut masked = example_scene();
    masked.set_object_mask(0, 1).unwrap();
    for scene in [example_scene(), masked] {
        let built = Arc::new(BuiltScene::new(scene, &BuildOptions::default()).unwrap());
        let ray = Ray::new(DVec3::new(33.3, 45.1, 100.0), DVec3::NEG_Z).with_mask(0);
        let query = Query {
            mode: Mode::All,
            ..Query::default()
        };
        let oracle = brute_force_query(&built.scene, &[ray], &query);
        assert!(oracle.hits_of(0).is_empty());
        let answers = CpuPicker::new(built.clone()).query(&[ray], &query).unwrap();
        assert!(answers.hits_of(0).is_empty() && !answers.nearest[0].invalid);
    }
}

#[test]
fn nan_arguments_and_points_are_refused_or_flagged() {
    assert_refused(
        &[
            "viewshed",
            "--observer",
            "nan",
            "0",
            "0",
            "--backend",
            "cpu",
        ],
        &["--observer NaN 0 0"],
    );
    assert_refused(
        &[
            "viewshed",
            "--observer",
            "50",
            "50",
            "200",
            "--target-height",
            "nan",
            "--backend",
            "cpu",
        ],
        &["--target-height NaN"],
    );
    let pairs = temp_file("nan-pairs.txt", "nan 0 0 1 1 1\n10 10 200 90 90 200\n");
    let (code, out, err) = raypick(&["los", "--pairs", &pairs, "--backend", "cpu"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("0,0") && out.contains("1,1"), "{out}");
    assert!(
        err.contains("warning: 1 pair(s) were invalid"),
        "the NaN pair is flagged: {err}"
    );
    // Finite ends whose difference overflows are no segment either, and the warning says so.
    let pairs = temp_file(
        "far-pairs.txt",
        "-1e308 0 0 1e308 0 0\n10 10 200 90 90 200\n",
    );
    let (code, out, err) = raypick(&["los", "--pairs", &pairs, "--backend", "cpu"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("0,0") && out.contains("1,1"), "{out}");
    assert!(
        err.contains("warning: 1 pair(s) were invalid")
            && err.contains("ends farther apart than f64 holds"),
        "the overflowing pair is flagged as such: {err}"
    );
}

#[test]
fn error_messages_quote_at_most_a_few_dozen_characters_of_a_bad_token() {
    let long = "9".repeat(2_000_000);
    let junk = "z".repeat(2_000_000);
    let check = |args: &[&str], named: &str| {
        let err = assert_refused(args, &[named, "…"]);
        assert!(err.len() < 400, "{} bytes: {}", err.len(), &err[..400]);
    };
    let obj = temp_file("long.obj", &format!("v 0 0 {junk}\n"));
    check(
        &["pick", "--backend", "cpu", "--scene", &obj],
        "is not a number",
    );
    let obj = temp_file("long-face.obj", &format!("v 0 0 0\nf 1 1 {junk}\n"));
    check(
        &["pick", "--backend", "cpu", "--scene", &obj],
        "not an integer",
    );
    let asc = temp_file(
        "long.asc",
        &format!("ncols 2\nnrows 1\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 {long}\n"),
    );
    check(
        &["pick", "--backend", "cpu", "--scene", &asc],
        "non-finite value",
    );
    let asc = temp_file("long-key.asc", &format!("{junk} 2\n"));
    check(
        &["pick", "--backend", "cpu", "--scene", &asc],
        "unknown header key",
    );
    // Ray files are read a line at a time: a token under the 1 MiB line limit is quoted short,
    // a longer line is refused as such, both naming the file and line.
    let rays = temp_file(
        "long-rays.txt",
        &format!("0 0 0 0 0 {}\n", &junk[..100_000]),
    );
    check(
        &["pick", "--backend", "cpu", "--rays", &rays],
        "is not a number",
    );
    let rays = temp_file("longer-rays.txt", &format!("0 0 0 0 0 {junk}\n"));
    let err = assert_refused(
        &["pick", "--backend", "cpu", "--rays", &rays],
        &["longer-rays.txt:1", "longer than"],
    );
    assert!(err.len() < 400, "{} bytes", err.len());
    // So are pixel files, read whole: a longer line is refused as such.
    let pixels = temp_file("long-pixels.txt", &format!("1 {}\n", &junk[..100_000]));
    let camera = camera_file("small-camera.json", 8, 6);
    check(
        &[
            "pick",
            "--backend",
            "cpu",
            "--camera",
            &camera,
            "--pixels",
            &pixels,
        ],
        "is not a number",
    );
    // Camera files are at most 1 MiB.
    let bad_camera = temp_file(
        "long-camera.json",
        &format!(r#"{{"perspective": {{"{}": 1}}}}"#, &junk[..500_000]),
    );
    check(
        &["render", "--camera", &bad_camera, "--out", "/dev/null"],
        "unknown field",
    );
    let string_camera = temp_file(
        "string-camera.json",
        &format!(r#"{{"perspective": {{"eye": "{}"}}}}"#, &junk[..500_000]),
    );
    check(
        &["render", "--camera", &string_camera, "--out", "/dev/null"],
        "invalid type",
    );
    // Arguments (the OS allows about 128 KB per argument): the parser's errors have a usage
    // line after the sentence, and quote the bad value short.
    let arg = "7".repeat(100_000);
    let unknown = format!("--{}", &junk[..100_000]);
    for (args, named) in [
        (
            vec!["render", "--width", &arg, "--out", "/dev/null"],
            "--width",
        ),
        (vec!["pick", "--ray-mask", &arg], "32-bit mask"),
        (vec!["pick", &unknown], "unexpected argument"),
    ] {
        let (code, out, err) = raypick(&args);
        assert_eq!(code, 2, "{err}");
        assert!(out.is_empty() && !err.contains("panicked"));
        assert!(
            err.starts_with("error:") && err.contains(named) && err.contains('…'),
            "{}",
            &err[..err.len().min(400)]
        );
        assert!(err.len() < 1000, "{} bytes", err.len());
    }
}

#[test]
fn csv_writes_extreme_numbers_with_an_exponent_and_ordinary_ones_as_before() {
    let rays = temp_file(
        "far-rays.txt",
        "33.3 45.1 100 0 0 -1e-300\n33.3 45.1 100 0 0 -1\n",
    );
    let (code, csv, err) = raypick(&["pick", "--backend", "cpu", "--rays", &rays]);
    assert_eq!(code, 0, "{err}");
    let (_, json, _) = raypick(&[
        "pick",
        "--backend",
        "cpu",
        "--rays",
        &rays,
        "--format",
        "json",
    ]);
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    let rows: Vec<Vec<&str>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    let far = rows[0][2];
    assert!(far.len() <= 24 && far.contains('e'), "t = {far}");
    assert_eq!(far.parse::<f64>().unwrap(), v[0]["t"].as_f64().unwrap());
    assert!(json.len() < 1000, "JSON stays short too: {json}");
    // The roof of the tower: printed as ever (Rust's `{}`).
    let roof = v[1]["t"].as_f64().unwrap();
    assert_eq!(rows[1][2], roof.to_string());
    assert_eq!(rows[1][7], "33.3");
}

#[test]
fn obj_faces_with_fewer_than_three_vertices_are_warned_about_once() {
    let obj = temp_file(
        "short-faces.obj",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\nf 1 2 3\nf 3\nf 2 3\n",
    );
    let (code, _, err) = raypick(&["pick", "--backend", "cpu", "--scene", &obj]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(err.matches("fewer than 3 vertices").count(), 1, "{err}");
    assert!(
        err.contains("3 face(s)") && err.contains("line 4") && err.contains(&obj),
        "{err}"
    );
}

#[test]
fn server_answers_name_objects_by_file_name_only() {
    use raypick::io::scene_files::{SceneFile, load_scene};
    use raypick::server::{Server, ServerConfig};
    use std::io::{Read, Write};

    let dir = std::env::temp_dir().join(format!("raypick-hostile-secret-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let obj = dir.join("ground.obj");
    std::fs::write(&obj, "v 0 0 0\nv 10 0 0\nv 0 10 0\nf 1 2 3\n").unwrap();
    let scene = load_scene(&[SceneFile {
        file: obj.clone(),
        mask: None,
        transform: None,
    }])
    .unwrap();
    let built = Arc::new(BuiltScene::new(scene, &BuildOptions::default()).unwrap());
    let server = Server::new(built, Backend::Cpu, ServerConfig::default()).unwrap();
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    listener.set_nonblocking(true).unwrap();
    let addr = listener.local_addr().unwrap();
    std::thread::spawn(move || {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .unwrap();
        runtime.block_on(async move {
            let listener = tokio::net::TcpListener::from_std(listener).unwrap();
            server.serve(listener).await.unwrap();
        });
    });
    let request = |head: &str, body: &str| {
        let mut stream = std::net::TcpStream::connect(addr).unwrap();
        write!(
            stream,
            "{head} HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
            body.len()
        )
        .unwrap();
        let mut answer = String::new();
        stream.read_to_string(&mut answer).unwrap();
        answer
    };
    let scene = request("GET /scene", "");
    let pick = request(
        "POST /pick",
        r#"{"rays":[{"origin":[1,1,5],"dir":[0,0,-1]}]}"#,
    );
    let folder = dir.display().to_string();
    for answer in [&scene, &pick] {
        assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
        assert!(answer.contains("\"ground.obj\""), "{answer}");
        assert!(
            !answer.contains(&folder),
            "the server's path shows: {answer}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A scene description whose bad value is a 2 MB string: the error quotes a short piece of it.
#[test]
fn scene_description_errors_quote_a_short_piece_of_a_bad_token() {
    let junk = "z".repeat(2_000_000);
    let description = temp_file(
        "long-scene.json",
        &format!(r#"{{"objects": [{{"file": "{junk}", "mask": "{junk}"}}]}}"#),
    );
    let err = assert_refused(
        &["pick", "--backend", "cpu", "--scenes", &description],
        &["long-scene.json"],
    );
    assert!(err.len() < 2100, "{} bytes", err.len());
}

/// The options each command cannot run without, as `--help`'s usage line must show them (issue
/// 16). A command missing here fails the test below, so every new command is looked at.
const REQUIRED: &[(&str, &[&str])] = &[
    ("pick", &[]),
    ("verify", &[]),
    ("los", &["--pairs"]),
    ("viewshed", &["--observer"]),
    ("select", &["--rect"]),
    ("idbuffer", &[]),
    ("probe", &[]),
    ("soak", &[]),
    ("render", &["--out"]),
    ("build", &["--out"]),
    ("serve", &[]),
    ("example", &["--out"]),
    ("bench", &[]),
];

/// Asserts a parser refusal: exit 2, nothing on standard output, a first line that is one
/// sentence starting with `error:` and naming every one of `named`, and no panic.
fn assert_parser_refused(args: &[&str], named: &[&str]) {
    let (code, out, err) = raypick(args);
    assert_eq!(code, 2, "{args:?}: {err}");
    assert!(out.is_empty(), "{args:?} wrote {out}");
    assert!(!err.contains("panicked"), "{args:?}: {err}");
    let first = err.lines().next().unwrap_or_default();
    assert!(first.starts_with("error:"), "{args:?}: {err}");
    for n in named {
        assert!(err.contains(n), "{args:?}: {n} not named in {err}");
    }
}

/// Every command, without its required options, is exit 2 and a sentence naming them, never a
/// panic (issue 16: `viewshed` without `--observer` and `select` without `--rect` used to
/// panic). The required options are the parser's (its usage line), and match [`REQUIRED`];
/// options that need each other, and options given too few values, are refused the same way.
#[test]
fn missing_required_options_are_named_not_panics() {
    let (code, help, _) = raypick(&["--help"]);
    assert_eq!(code, 0);
    let commands: Vec<&str> = help
        .lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .skip(1)
        .take_while(|l| !l.trim().is_empty())
        .filter_map(|l| l.split_whitespace().next())
        .filter(|&c| c != "help")
        .collect();
    let listed: Vec<&str> = REQUIRED.iter().map(|(c, _)| *c).collect();
    assert_eq!(commands, listed, "every command has its row in REQUIRED");
    for (command, required) in REQUIRED {
        let (code, help, _) = raypick(&[command, "--help"]);
        assert_eq!(code, 0, "{command} --help");
        let usage = help
            .lines()
            .find(|l| l.starts_with("Usage:"))
            .unwrap_or_else(|| panic!("{command}: no usage line in {help}"));
        let in_usage: Vec<&str> = usage
            .split_whitespace()
            .filter(|w| w.starts_with("--"))
            .collect();
        assert_eq!(&in_usage, required, "{command}: {usage}");
        if !required.is_empty() {
            let mut named = vec!["required arguments were not provided"];
            named.extend(required.iter());
            assert_parser_refused(&[command], &named);
            assert_parser_refused(&[command, "--backend", "cpu"], required);
        }
    }
    let dem = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/jacksboro_fault_dem_utm.asc"
    );
    assert_parser_refused(&["viewshed", "--scene", dem], &["--observer"]);
    let camera = camera_file("required-camera.json", 8, 6);
    assert_parser_refused(&["select", "--camera", &camera], &["--rect"]);
    // Too few values.
    assert_parser_refused(
        &["viewshed", "--observer", "1", "2"],
        &["--observer", "3 values"],
    );
    assert_parser_refused(
        &["select", "--rect", "1", "2", "3"],
        &["--rect", "4 values"],
    );
    // Options that need another.
    assert_parser_refused(&["pick", "--camera", &camera], &["--pixels"]);
    let pixels = temp_file("required-pixels.txt", "1 1\n");
    assert_parser_refused(&["pick", "--pixels", &pixels], &["--camera"]);
    assert_parser_refused(&["bench", "--threads", "2"], &["--ray-file"]);
    assert_parser_refused(&["bench", "--backend", "cpu"], &["--ray-file"]);
    // Too few values before the next option: options whose values may start with a hyphen
    // (negative numbers) would take that option as a value; the sentence names both, not the
    // word after them.
    let targets = temp_file("swallowed-targets.txt", "1 1 1\n");
    for (args, named) in [
        (
            vec![
                "viewshed",
                "--scene",
                dem,
                "--observer",
                "1",
                "2",
                "--targets",
                &targets,
            ],
            vec!["--observer takes 3 values (X Y Z) but only 2 come before --targets"],
        ),
        (
            vec!["los", "--pairs", &targets, "--epsilon", "--out", "o.csv"],
            vec!["--epsilon takes a value (EPSILON) but none comes before --out"],
        ),
        (
            vec!["pick", "--rays", &targets, "--tmin", "--tmax", "5"],
            vec!["--tmin takes a value", "before --tmax"],
        ),
        (
            vec!["--quiet", "soak", "--max-growth", "--rays", "5"],
            vec!["--max-growth takes a value (MIB)", "--rays"],
        ),
    ] {
        let err = assert_refused(&args, &named);
        assert!(!err.contains(&targets) && !err.contains("o.csv"), "{err}");
    }
    // Negative values are still values.
    let (code, _, err) = raypick(&[
        "viewshed",
        "--scene",
        dem,
        "--observer",
        "-1",
        "-2e-3",
        "-inf",
        "--targets",
        &targets,
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("--observer") && err.contains("finite"),
        "{err}"
    );
    // Options that exclude each other.
    assert_parser_refused(
        &[
            "render",
            "--camera",
            &camera,
            "--width",
            "8",
            "--out",
            "/dev/null",
        ],
        &["--width", "--camera"],
    );
    assert_parser_refused(
        &["idbuffer", "--camera", &camera, "--height", "8"],
        &["--height", "--camera"],
    );
}

/// Commands that write CSV only refuse an `--out` file named `.json` (issue 16: `pick --out
/// o.json` used to write CSV); `--raw-ids` needs a PNG; `soak --max-growth` is a size.
#[test]
fn outputs_that_cannot_be_what_their_name_says_are_refused() {
    let pairs = temp_file("json-pairs.txt", "10 10 60 60 60 60\n");
    assert_refused(
        &["los", "--pairs", &pairs, "--out", "seen.json"],
        &["--out seen.json", "CSV"],
    );
    assert_refused(
        &[
            "viewshed",
            "--observer",
            "50",
            "50",
            "150",
            "--out",
            "seen.JSON",
        ],
        &["--out seen.JSON", "CSV"],
    );
    assert_refused(
        &[
            "select",
            "--rect",
            "0",
            "0",
            "8",
            "8",
            "--out",
            "objects.json",
        ],
        &["--out objects.json", "CSV"],
    );
    assert_refused(
        &["idbuffer", "--out", "ids.json"],
        &["--out ids.json", "CSV"],
    );
    assert_refused(
        &["idbuffer", "--raw-ids", "--out", "ids.csv"],
        &["--raw-ids", ".png"],
    );
    assert_refused(&["idbuffer", "--raw-ids"], &["--raw-ids", ".png"]);
    // A server limit of 0 would refuse every request: refused, not raised to 1 in silence.
    for flag in ["--max-rays", "--max-body-bytes", "--max-connections"] {
        assert_refused(&["serve", flag, "0"], &[flag, "at least 1"]);
    }
    // The server's timeouts and work limit are finite seconds, at least a millisecond (1e-10,
    // which a Duration rounds to nothing, dropped every connection unanswered).
    for flag in ["--idle-timeout", "--body-timeout", "--max-work-seconds"] {
        for bad in ["0", "nan", "inf", "1e10", "1e-10", "1e-320", "0.0009"] {
            assert_refused(&["serve", flag, bad], &[flag, "from 0.001 to 1e9"]);
        }
    }
    // `--allow-host` takes a bare host name (no scheme, no port), or `*`.
    for bad in [
        "http://picks.example",
        "picks.example:8080",
        "*.example",
        "",
    ] {
        assert_refused(
            &["serve", "--allow-host", bad],
            &["--allow-host", "not a host name"],
        );
    }
    // `--max-hits` outside `--mode all` would be ignored: refused.
    for args in [
        &["pick", "--max-hits", "5"][..],
        &["verify", "--mode", "any", "--max-hits", "5"],
    ] {
        assert_refused(args, &["--max-hits 5", "--mode all"]);
    }
    for bad in ["-1", "nan", "inf"] {
        assert_refused(&["soak", "--max-growth", bad], &["--max-growth"]);
    }
}

/// `idbuffer --raw-ids` writes ids + 1 in 16 bits: a scene of 65,536 objects (one small file
/// listed that many times) is refused, by its count, once loaded and before its tree is built.
#[test]
fn raw_ids_refuse_a_scene_with_more_objects_than_sixteen_bits_hold() {
    let obj = temp_file("one-triangle.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let entry = format!("{{\"file\": \"{}\"}}", file_name(&obj));
    let listed = vec![entry; usize::from(u16::MAX) + 1].join(",");
    let description = temp_file("many-objects.json", &format!("{{\"objects\": [{listed}]}}"));
    let png = std::env::temp_dir().join(format!("raypick-hostile-{}-ids.png", std::process::id()));
    let png = png.display().to_string();
    assert_refused(
        &[
            "idbuffer",
            "--scenes",
            &description,
            "--raw-ids",
            "--out",
            &png,
        ],
        &["65536 objects", "--raw-ids"],
    );
    assert!(!std::path::Path::new(&png).exists(), "{png} written");
}

/// Heights past f32's range (±10¹⁶⁰ in a 2 × 2 grid, a triangle 10²⁰⁰ across in an OBJ) lose
/// their triangles, and every command that builds says so: before, a box that large counted as
/// resolved (its diagonal's square overflowed), and the picks missed without a word.
#[test]
fn triangles_past_f32s_range_are_warned_about() {
    let rays = temp_file("one-ray.txt", "1.0 -100 0 0 1 0\n");
    let grid = temp_file(
        "h160.asc",
        "ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1e160 2\n3 -1e160\n",
    );
    let obj = temp_file("huge.obj", "v 0 0 0\nv 1e200 0 0\nv 0 1e200 0\nf 1 2 3\n");
    for scene in [&grid, &obj] {
        let (code, _, err) = raypick(&["pick", "--scene", scene, "--rays", &rays, "-q"]);
        assert_eq!(code, 0, "{scene}: {err}");
        assert!(err.contains("can never be hit"), "{scene}: {err}");
    }
}

/// A view whose every pixel ray is invalid (an orthographic view 10³⁰⁰ units tall: origins
/// past single precision) is warned about by `render`, `select` and `idbuffer`, as `pick`
/// warns about invalid rays: before, they drew the sky and listed nothing without a word.
#[test]
fn views_of_invalid_pixel_rays_are_warned_about() {
    let camera = temp_file(
        "tall-view.json",
        r#"{"orthographic":{"eye":[50,-60,80],"target":[48,48,0],"up":[0,0,1],"view_height":1e300,"width":16,"height":12}}"#,
    );
    let png = std::env::temp_dir().join(format!("raypick-hostile-{}-tall.png", std::process::id()));
    let png = png.display().to_string();
    for (args, count) in [
        (
            &["render", "--camera", &camera, "--out", &png][..],
            "192 of the view's 192",
        ),
        (
            &[
                "select", "--camera", &camera, "--rect", "0", "0", "16", "12", "--step", "4",
            ],
            "12 of the view's 12",
        ),
        (&["idbuffer", "--camera", &camera], "192 of the view's 192"),
    ] {
        let (code, _, err) = raypick(args);
        assert_eq!(code, 0, "{args:?}: {err}");
        assert!(
            err.contains(&format!("warning: {count} pixel ray(s) were invalid")),
            "{args:?}: {err}"
        );
    }
    let (_, _, err) = raypick(&["render", "--width", "16", "--height", "12", "--out", &png]);
    assert!(!err.contains("invalid"), "an ordinary view: {err}");
}

/// An observer so far out that `--epsilon` of each segment's length is more than a thousandth
/// of the scene (10⁹ units from the 100-unit example: 1,000 units skipped at each end) is
/// warned about; a near one is not. Before, every sample read visible without a word.
#[test]
fn segments_whose_ignored_ends_outgrow_the_scene_are_warned_about() {
    for (x, warned) in [("1e9", true), ("50", false)] {
        let args = ["viewshed", "--observer", x, "50", "150", "--backend", "cpu"];
        let (code, _, err) = raypick(&args);
        assert_eq!(code, 0, "{err}");
        assert_eq!(
            err.contains("give a smaller --epsilon"),
            warned,
            "{x}: {err}"
        );
    }
    // Ends 10^200 apart: the squared length overflowed and the warning said "up to 0.000e0
    // units"; now the length is taken without squares that overflow.
    let args = [
        "viewshed",
        "--observer",
        "1e200",
        "50",
        "150",
        "--backend",
        "cpu",
    ];
    let (code, _, err) = raypick(&args);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains("give a smaller --epsilon")
            && err.contains("up to 1.000e194 units")
            && !err.contains("0.000e0"),
        "{err}"
    );
}

/// Pixels outside the camera's image (a pixel file made for another size) are picked through
/// where they would be, with one warning naming how many and the first; inside, no word.
#[test]
fn pixels_outside_the_image_are_warned_about() {
    let camera = camera_file("outside-camera.json", 8, 6);
    for (text, warned) in [
        ("3 4\n-1 -1\n100000 100000\n", Some("2 of the 3 pixels")),
        ("0 0\n7 5\n7.49 5.49\n", None),
    ] {
        let pixels = temp_file("outside-pixels.txt", text);
        let args = [
            "pick",
            "--backend",
            "cpu",
            "--camera",
            &camera,
            "--pixels",
            &pixels,
        ];
        let (code, out, err) = raypick(&args);
        assert_eq!(code, 0, "{err}");
        assert_eq!(out.lines().count(), 4, "{out}");
        match warned {
            Some(count) => assert!(
                err.contains(&format!("warning: {count} of"))
                    && err.contains(
                        "lie outside the camera's 8 x 6 image (the first: pixel -1 -1, number 2"
                    ),
                "{err}"
            ),
            None => assert!(!err.contains("outside"), "{err}"),
        }
    }
}

/// Inputs whose size no header gives (a device, a pipe, a file of endless short lines, a small
/// file listed thousands of times) are refused as soon as the reading shows them too long or
/// over the budget: before, `/dev/zero` as a pair, pixel, target, camera or verify ray file
/// grew to gigabytes, `--max-memory` or not.
#[test]
fn inputs_of_unknown_length_are_refused_when_too_long_or_over_the_budget() {
    let pixels = temp_file("one-pixel.txt", "3 4\n");
    let camera = camera_file("small-camera.json", 64, 48);
    for args in [
        &["los", "--pairs", "/dev/zero", "--backend", "cpu"][..],
        &[
            "viewshed",
            "--observer",
            "1",
            "1",
            "100",
            "--targets",
            "/dev/zero",
            "--backend",
            "cpu",
        ],
        &[
            "pick",
            "--camera",
            &camera,
            "--pixels",
            "/dev/zero",
            "--backend",
            "cpu",
        ],
        &["bench", "--ray-file", "/dev/zero"],
    ] {
        assert_refused(args, &["/dev/zero:1:", "longer than 1048576 bytes"]);
    }
    // A folder opens like a file and fails at the first read: refused before any output.
    let folder = std::env::temp_dir().display().to_string();
    assert_refused(
        &["pick", "--rays", &folder, "--backend", "cpu"],
        &["is a folder, not a ray file"],
    );
    // `verify` describes the scene before it reads its rays.
    let (code, _, err) = raypick(&["verify", "--rays", "/dev/zero"]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.starts_with("error: /dev/zero:1: the line is longer than 1048576 bytes"),
        "{err}"
    );
    assert_refused(
        &[
            "pick",
            "--camera",
            "/dev/zero",
            "--pixels",
            &pixels,
            "--backend",
            "cpu",
        ],
        &["/dev/zero is longer than 1.0 MiB", "camera file"],
    );
    // Many short lines: each parsed line costs ten times its bytes (a budget that holds the
    // example scene's tree, 2.5 MiB, but not the 40,000 parsed lines, 4.8 MB).
    let pairs = temp_file("many-pairs.txt", &"0 0 0 1 1 1\n".repeat(40_000));
    assert_refused(
        &[
            "los",
            "--pairs",
            &pairs,
            "--max-memory",
            "3M",
            "--backend",
            "cpu",
        ],
        &["40000 lines of", "many-pairs.txt", "memory budget"],
    );
    // A file longer than the budget is refused before it is read.
    let longer = temp_file("more-pairs.txt", &"0 0 0 1 1 1\n".repeat(300_000));
    assert_refused(
        &[
            "los",
            "--pairs",
            &longer,
            "--max-memory",
            "3M",
            "--backend",
            "cpu",
        ],
        &["more-pairs.txt is longer than 3.0 MiB, the memory budget"],
    );
    // A line over 1 MiB is refused wherever it ends (here its line break falls in the block
    // where it crosses the limit), naming its line.
    let long_line = temp_file(
        "long-line-pairs.txt",
        &format!(
            "0 0 0 1 1 1\n{}\n0 0 0 1 1 1\n",
            " ".repeat((1 << 20) + 1000)
        ),
    );
    assert_refused(
        &["los", "--pairs", &long_line, "--backend", "cpu"],
        &["long-line-pairs.txt:2:", "longer than 1048576 bytes"],
    );
    // A small mesh listed 200 times: the copies are counted before they are made.
    let soup: String = (0..100)
        .map(|k| {
            format!(
                "v {k} 0 0\nv {k} 1 0\nv {k} 0 1\nf {} {} {}\n",
                3 * k + 1,
                3 * k + 2,
                3 * k + 3
            )
        })
        .collect();
    let obj = temp_file("listed-soup.obj", &soup);
    let name = file_name(&obj);
    let listings = vec![format!(r#"{{"file": "{name}"}}"#); 200].join(", ");
    let description = temp_file(
        "listed-many.json",
        &format!(r#"{{"objects": [{listings}]}}"#),
    );
    assert_refused(
        &[
            "render",
            "--scenes",
            &description,
            "--max-memory",
            "1M",
            "--width",
            "8",
            "--height",
            "8",
            "--out",
            "/dev/null",
        ],
        &["200 listings", "× 104 bytes", "memory budget"],
    );
}

/// A description that lists nothing, or an empty file name, is refused naming the description
/// (an empty list once loaded the built-in example scene without a word); a NaN `--tmin`,
/// `--tmax` or `--oracle-budget` is refused; control bytes in a bad token or a file's name are
/// escaped; a transform too large for f64 says so in a short sentence, not as "singular" with
/// 309 digits.
#[test]
fn empty_descriptions_nan_bounds_control_bytes_and_huge_transforms_are_refused_plainly() {
    let empty = temp_file("empty-scene.json", r#"{"objects": []}"#);
    assert_refused(
        &["pick", "--scenes", &empty, "--backend", "cpu"],
        &["empty-scene.json", "lists no objects"],
    );
    let unnamed = temp_file("unnamed-scene.json", r#"{"objects": [{"file": ""}]}"#);
    assert_refused(
        &["pick", "--scenes", &unnamed, "--backend", "cpu"],
        &["unnamed-scene.json", "object 0: the file name is empty"],
    );
    for flag in ["--tmin", "--tmax"] {
        assert_parser_refused(&["pick", flag, "NaN"], &[flag, "not a ray parameter"]);
    }
    assert_parser_refused(
        &["verify", "--oracle-budget", "NaN"],
        &["--oracle-budget", "not a number of triangle tests"],
    );
    let nul = temp_file("nul-pairs.txt", &"\0".repeat(2000));
    let err = assert_refused(&["los", "--pairs", &nul, "--backend", "cpu"], &["\\u{0}"]);
    assert!(!err.contains('\0') && err.len() < 500, "{err:?}");
    // A line break in a file's name is written as `\n`: the sentence stays one line.
    let broken = std::env::temp_dir().join("raypick-no-such\nfile.obj");
    let err = assert_refused(
        &[
            "pick",
            "--scene",
            broken.to_str().unwrap(),
            "--backend",
            "cpu",
        ],
        &["raypick-no-such\\nfile.obj"],
    );
    assert!(!err.trim_end().contains('\n'), "{err:?}");
    let obj = temp_file("scaled-box.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let name = file_name(&obj);
    let huge = temp_file(
        "huge-transform.json",
        &format!(
            r#"{{"objects": [{{"file": "{name}", "transform": [[1e308, 0, 0, 0], [0, 1e308, 0, 0], [0, 0, 1, 0]]}}]}}"#
        ),
    );
    let err = assert_refused(
        &["pick", "--scenes", &huge, "--backend", "cpu"],
        &["more than double precision holds"],
    );
    assert!(err.len() < 300 && !err.contains("singular"), "{err}");
}

/// A direction near the top (or the bottom) of f64's range is refined in f64 like a unit one:
/// the same triangle, u, v and position on every path and for the oracle, with t in its own
/// units (the exact test overflowed and the f32 traversal's values were reported).
#[test]
fn directions_near_the_ends_of_f64_are_refined_in_f64_on_every_path() {
    let built = Arc::new(BuiltScene::new(example_scene(), &BuildOptions::default()).unwrap());
    let query = Query::default();
    let origin = DVec3::new(33.3, 45.1, 100.0);
    let unit = Ray::new(origin, DVec3::NEG_Z);
    let expected = brute_force_query(&built.scene, &[unit], &query).nearest[0];
    assert!(expected.hit);
    for length in [1e307, 1e-300] {
        let ray = Ray::new(origin, DVec3::NEG_Z * length);
        let oracle = brute_force_query(&built.scene, &[ray], &query).nearest[0];
        // The unit ray's answer, to rounding (the direction is not a power of two times it).
        assert!(
            oracle.hit && (oracle.object, oracle.triangle) == (expected.object, expected.triangle)
        );
        assert!((oracle.u - expected.u).abs() < 1e-12 && (oracle.v - expected.v).abs() < 1e-12);
        assert!(
            (oracle.position - expected.position).length() < 1e-9,
            "{oracle:?}"
        );
        assert!(
            (oracle.t * length / expected.t - 1.0).abs() < 1e-12,
            "{oracle:?}"
        );
        let mut pickers: Vec<Box<dyn Picker>> = vec![
            Box::new(CpuPicker::new(built.clone())),
            Box::new(ReferencePicker::new(built.clone())),
        ];
        for h in std::iter::once(oracle).chain(
            pickers
                .iter_mut()
                .map(|p| p.query(&[ray; 5], &query).unwrap().nearest[4]),
        ) {
            // Every path gives the oracle's bits.
            assert!(h.hit, "{length}: {h:?}");
            let bits =
                |h: raypick::Hit| (h.object, h.triangle, h.t, h.u, h.v, h.position, h.normal);
            assert_eq!(bits(h), bits(oracle), "{length}");
        }
    }
}

/// `viewshed` without `--targets` on a grid with no data anywhere says so, rather than that the
/// scene has no grid.
#[test]
fn a_viewshed_over_a_grid_with_no_data_says_so() {
    let asc = temp_file(
        "no-data.asc",
        "ncols 3\nnrows 3\nxllcorner 0\nyllcorner 0\ncellsize 1\nNODATA_value -9999\n\
         -9999 -9999 -9999\n-9999 -9999 -9999\n-9999 -9999 -9999\n",
    );
    let (code, out, err) = raypick(&[
        "viewshed",
        "--scene",
        &asc,
        "--observer",
        "1",
        "1",
        "100",
        "--backend",
        "cpu",
    ]);
    assert_eq!(code, 2, "{out}{err}");
    assert!(
        err.contains("no cells with data") && !err.contains("has no terrain grid"),
        "{err}"
    );
    // A grid of one row holds data but no cell: said so, not "NODATA everywhere".
    let row = temp_file(
        "one-row.asc",
        "ncols 3\nnrows 1\nxllcorner 0\nyllcorner 0\ncellsize 1\n5 6 7\n",
    );
    assert_refused(
        &["viewshed", "--scene", &row, "--observer", "0", "0", "10"],
        &["3 x 1 samples", "--targets"],
    );
}

/// Commands that report on standard output, read by a reader that goes away (`raypick verify |
/// head -1`): a failed write is an error naming standard output, exit 2, not a panic (their
/// lines were `println!`, which panicked with exit 101: found by a helper's fuzzing).
#[test]
fn a_closed_standard_output_is_an_error_not_a_panic() {
    let runs: [&[&str]; 4] = [
        &["verify", "--random", "2000"],
        &["probe", "--probes", "2000"],
        &["bench", "--rays", "2000", "--repeat", "1", "--picks", "10"],
        &[
            "soak", "--rays", "4000", "--batch", "1000", "--check", "100",
        ],
    ];
    for args in runs {
        let mut child = Command::new(env!("CARGO_BIN_EXE_raypick"))
            .args(args)
            .env("XDG_RUNTIME_DIR", std::env::temp_dir())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("run raypick");
        // The reading end closed before the command has written a line.
        drop(child.stdout.take());
        let out = child.wait_with_output().expect("wait for raypick");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!err.contains("panicked"), "{args:?}: {err}");
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(
            err.contains("<stdout>") && err.contains("Broken pipe"),
            "{args:?}: {err}"
        );
    }
}

/// Negative numbers in every form a number takes are values, not flags: clap's own test for a
/// negative number left out `-1e+3`, `-.5`, `-0` and `-inf`, so `--observer -1e+30 3 5` was
/// "unexpected argument '-1'" (found by a helper's fuzzing); a value that is not a number is
/// still refused by name.
#[test]
fn negative_numbers_in_any_form_are_values_not_flags() {
    for observer in ["-1e+3", "-1.5e-3", "-.5", "-0"] {
        let (code, _, err) = raypick(&[
            "viewshed",
            "--observer",
            observer,
            "3",
            "5",
            "--target-height",
            "-1e+0",
            "--epsilon",
            "-0",
            "--backend",
            "cpu",
            "-q",
        ]);
        assert_eq!(code, 0, "--observer {observer}: {err}");
    }
    for tmin in ["-1e+3", "-.5", "-0"] {
        let (code, _, err) = raypick(&["pick", "--tmin", tmin, "--backend", "cpu", "-q"]);
        assert_eq!(code, 0, "--tmin {tmin}: {err}");
    }
    assert_refused(
        &["viewshed", "--observer", "-inf", "3", "5"],
        &["--observer", "not finite"],
    );
}

/// A 16-bit id image holds ids 0 ..= 65,534 (written as id + 1, 0 for nothing): a scene of
/// 65,535 objects fits (it was refused: found by a helper's fuzzing; 65,536 are refused, above).
#[test]
fn a_16_bit_id_image_holds_65535_objects() {
    let obj = temp_file("one-triangle.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let listing = format!(r#"{{"file": "{}"}}"#, file_name(&obj));
    let description = temp_file(
        "objects-65535.json",
        &format!(r#"{{"objects": [{}]}}"#, vec![listing; 65_535].join(",")),
    );
    let png = temp_file("ids-65535.png", "");
    let (code, _, err) = raypick(&[
        "idbuffer",
        "--scenes",
        &description,
        "--width",
        "4",
        "--height",
        "3",
        "--raw-ids",
        "--out",
        &png,
        "-q",
    ]);
    assert_eq!(code, 0, "{err}");
}
