//! The `raypick` binary end to end: outputs, exit codes and error messages.

use std::process::Command;

use crate::common::raypick;

fn temp_file(name: &str, text: &str) -> String {
    crate::unique_temp_file("raypick-cli", name, text)
        .display()
        .to_string()
}

/// The quick start (issue 16): an 8 × 8 grid from straight above, row i = pixel (i mod 8,
/// i div 8) with row 0 north; most rays hit (at least 75%), each building at least once; the
/// terrain is a height grid, so its hits carry row and col; a summary line on standard error.
#[test]
fn pick_on_the_example_scene_prints_one_row_per_ray_on_both_backends() {
    let (auto_code, auto_out, auto_err) = raypick(&["pick"]);
    assert_eq!(auto_code, 0, "{auto_err}");
    let (cpu_code, cpu_out, cpu_err) = raypick(&["pick", "--backend", "cpu"]);
    assert_eq!(cpu_code, 0);
    assert_eq!(auto_out, cpu_out, "the backends agree on the example");
    let lines: Vec<&str> = auto_out.lines().collect();
    assert_eq!(
        lines[0],
        "ray,hit,t,object,triangle,u,v,x,y,z,nx,ny,nz,row,col,invalid,overflow"
    );
    assert_eq!(lines.len(), 65);
    let rows: Vec<Vec<&str>> = lines[1..].iter().map(|l| l.split(',').collect()).collect();
    assert!(rows.iter().all(|r| r.len() == 17), "{auto_out}");
    let hits = rows.iter().filter(|r| r[1] == "1").count();
    assert!(hits * 4 >= 64 * 3, "{hits} of 64 rays hit");
    for (object, name) in [("0", "terrain"), ("1", "tower"), ("2", "hall")] {
        assert!(
            rows.iter().any(|r| r[3] == object),
            "no ray hits the {name}: {auto_out}"
        );
    }
    for r in &rows {
        let (x, y): (f64, f64) = (r[7].parse().unwrap(), r[8].parse().unwrap());
        let i: usize = r[0].parse().unwrap();
        let (column, row) = (i % 8, i / 8);
        // West to east along a row of pixels, north to south down the columns.
        assert!(
            x > 95.0 * column as f64 / 8.0 - 6.0 && x < 95.0 * (column + 1) as f64 / 8.0 + 6.0,
            "ray {i}: x {x}"
        );
        assert!(
            y < 95.0 - 95.0 * row as f64 / 8.0 + 6.0
                && y > 95.0 - 95.0 * (row + 1) as f64 / 8.0 - 6.0,
            "ray {i}: y {y}"
        );
        match r[3] {
            "0" => {
                // Terrain hits carry the quad's row and col (samples 1 apart, row 0 at y = 95).
                let (grid_row, grid_col): (f64, f64) =
                    (r[13].parse().unwrap(), r[14].parse().unwrap());
                assert_eq!(grid_col, x.floor(), "ray {i}");
                assert_eq!(grid_row, (95.0 - y).floor(), "ray {i}");
            }
            _ => assert_eq!((r[13], r[14]), ("", ""), "ray {i}: off the grid"),
        }
        assert_eq!((r[15], r[16]), ("0", "0"), "ray {i}: valid, no overflow");
    }
    let summary = "picked 64 rays: 64 hit, 0 missed; scene: the built-in example (3 objects, 18074 triangles); backend: ";
    for err in [&auto_err, &cpu_err] {
        assert_eq!(err.matches(summary).count(), 1, "{err}");
    }
    assert!(auto_err.contains("backend: auto"), "{auto_err}");
    assert!(cpu_err.contains("backend: cpu"), "{cpu_err}");
    let (_, quiet_out, quiet_err) = raypick(&["pick", "--backend", "cpu", "--quiet"]);
    assert_eq!(quiet_out, cpu_out);
    assert!(!quiet_err.contains("picked"), "{quiet_err}");
}

/// `--backend auto` says once, on standard error, why it uses the CPU path: there is no GPU, or
/// the GPU is a software adapter (issue 16).
#[test]
fn auto_says_why_it_uses_the_cpu_path() {
    let (code, _, err) = raypick(&["pick"]);
    assert_eq!(code, 0, "{err}");
    match raypick::GpuContext::new() {
        Ok(context) if context.is_software() => assert_eq!(
            err.matches("note: software adapter: the CPU path is faster here")
                .count(),
            1,
            "{err}"
        ),
        Ok(_) => assert!(!err.contains("software adapter"), "{err}"),
        Err(_) => assert!(err.contains("note: no GPU"), "{err}"),
    }
    let (_, _, err) = raypick(&["pick", "--backend", "cpu"]);
    assert!(!err.contains("note:"), "{err}");
}

/// The CSV flags (issue 16): `invalid` and `overflow` end every row, after every other column,
/// in every mode; JSON says the same.
#[test]
fn csv_rows_end_with_invalid_and_overflow() {
    // Through the tower (roof, terrain, floor), a zero direction, and a ray over the terrain.
    let rays = temp_file(
        "flags.txt",
        "33.3 45.1 100 0 0 -1\n33.3 45.1 100 0 0 0\n10.5 10.5 100 0 0 -1\n",
    );
    let (code, out, err) = raypick(&["pick", "--rays", &rays, "--backend", "cpu"]);
    assert_eq!(code, 0, "{err}");
    let lines: Vec<&str> = out.lines().collect();
    assert!(lines[0].ends_with(",row,col,invalid,overflow"), "{out}");
    let flags = |line: &str| line.rsplitn(3, ',').take(2).collect::<Vec<_>>().join("");
    assert_eq!(
        lines[1..].iter().map(|l| flags(l)).collect::<Vec<_>>(),
        ["00", "01", "00"],
        "overflow,invalid reversed: {out}"
    );
    assert!(
        lines[2].starts_with("1,0,,,"),
        "an invalid ray is a miss: {out}"
    );
    assert!(err.contains("1 ray(s) were invalid"), "{err}");
    let (code, out, err) = raypick(&[
        "pick",
        "--rays",
        &rays,
        "--backend",
        "cpu",
        "--mode",
        "all",
        "--max-hits",
        "2",
    ]);
    assert_eq!(code, 0, "{err}");
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(
        lines[0],
        "ray,rank,hit,t,object,triangle,u,v,x,y,z,nx,ny,nz,row,col,invalid,overflow"
    );
    let ray0: Vec<&str> = lines
        .iter()
        .filter(|l| l.starts_with("0,"))
        .copied()
        .collect();
    assert_eq!(ray0.len(), 2, "two kept, the floor dropped: {out}");
    assert!(
        ray0.iter().all(|l| l.ends_with(",0,1")),
        "overflow on every row: {out}"
    );
    assert!(
        lines
            .iter()
            .any(|l| l.starts_with("1,,0,") && l.ends_with(",1,0")),
        "{out}"
    );
    assert!(
        lines
            .iter()
            .any(|l| l.starts_with("2,0,1,") && l.ends_with(",0,0")),
        "{out}"
    );
    let (_, json, _) = raypick(&[
        "pick",
        "--rays",
        &rays,
        "--backend",
        "cpu",
        "--mode",
        "all",
        "--max-hits",
        "2",
        "--format",
        "json",
    ]);
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!(
        (v[0]["overflow"].clone(), v[0]["invalid"].clone()),
        (true.into(), false.into())
    );
    assert_eq!(
        (v[1]["overflow"].clone(), v[1]["invalid"].clone()),
        (false.into(), true.into())
    );
}

/// Without `--format`, `--out`'s extension chooses it (issue 16): `.json` is JSON.
#[test]
fn the_output_format_follows_the_out_extension() {
    let rays = temp_file("format.txt", "33.3 45.1 100 0 0 -1\n");
    let dir = std::env::temp_dir();
    let json_out = dir.join(format!("raypick-cli-{}-o.JSON", std::process::id()));
    let csv_out = dir.join(format!("raypick-cli-{}-o.txt", std::process::id()));
    let forced = dir.join(format!("raypick-cli-{}-forced.json", std::process::id()));
    for (out, format) in [(&json_out, None), (&csv_out, None), (&forced, Some("csv"))] {
        let mut args = vec![
            "pick",
            "--rays",
            &rays,
            "--backend",
            "cpu",
            "--out",
            out.to_str().unwrap(),
        ];
        if let Some(format) = format {
            args.extend(["--format", format]);
        }
        let (code, _, err) = raypick(&args);
        assert_eq!(code, 0, "{err}");
    }
    let json = std::fs::read_to_string(&json_out).unwrap();
    let v: serde_json::Value = serde_json::from_str(&json).expect("JSON");
    assert_eq!(v[0]["object"], 1);
    for csv in [&csv_out, &forced] {
        let text = std::fs::read_to_string(csv).unwrap();
        assert!(text.starts_with("ray,hit,"), "{text}");
    }
}

/// `raypick example` writes the built-in scene as files that answer exactly as it does, with
/// the layer masks of its scene description (issue 16).
#[test]
fn the_example_scene_written_out_answers_as_the_built_in_one() {
    let dir = std::env::temp_dir().join(format!("raypick-cli-{}-example", std::process::id()));
    let dir_arg = dir.to_str().unwrap();
    let (code, out, err) = raypick(&["example", "--out", dir_arg]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out.lines().count(), 4, "{out}");
    let file = |name: &str| dir.join(name).display().to_string();
    let (_, built_in, _) = raypick(&["pick", "--backend", "cpu"]);
    let (code, from_files, err) = raypick(&[
        "pick",
        "--backend",
        "cpu",
        "--scene",
        &file("terrain.asc"),
        "--scene",
        &file("tower.obj"),
        "--scene",
        &file("hall.obj"),
    ]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(from_files, built_in, "the same triangles, ids and answers");
    let rays = temp_file("example-masks.txt", "33.3 45.1 100 0 0 -1\n");
    let object = |mask: &str| {
        let (code, out, err) = raypick(&[
            "pick",
            "--backend",
            "cpu",
            "--scenes",
            &file("scene.json"),
            "--rays",
            &rays,
            "--ray-mask",
            mask,
        ]);
        assert_eq!(code, 0, "{err}");
        out.lines()
            .nth(1)
            .unwrap()
            .split(',')
            .nth(3)
            .unwrap()
            .to_string()
    };
    assert_eq!(object("1"), "0", "layer 1: the terrain, through the tower");
    assert_eq!(object("2"), "1", "layer 2: the tower's roof");
    assert_eq!(object("0"), "", "mask 0: a miss");
    // The very same triangles, vertex for vertex, and the terrain a grid again.
    let files: Vec<_> =
        raypick::io::scene_files::load_description(&dir.join("scene.json")).unwrap();
    let loaded = raypick::io::scene_files::load_scene(&files).unwrap();
    let built_in = raypick::check::synthetic::example_scene();
    assert_eq!(loaded.triangle_count(), built_in.triangle_count());
    for t in 0..built_in.triangle_count() {
        assert_eq!(
            loaded.world_triangle(t),
            built_in.world_triangle(t),
            "triangle {t}"
        );
    }
    for (a, b) in loaded.objects().iter().zip(built_in.objects()) {
        assert_eq!((a.grid, a.triangle_count), (b.grid, b.triangle_count));
    }
    let masks: Vec<u32> = loaded.objects().iter().map(|o| o.mask).collect();
    assert_eq!(masks, raypick::check::synthetic::EXAMPLE_MASKS);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn ray_files_take_tmax_comments_and_obj_scenes() {
    let obj = temp_file(
        "quad.obj",
        "# a quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf -4 -3 -2 -1\n",
    );
    let rays = temp_file(
        "rays.txt",
        "# ox oy oz dx dy dz [tmax]\n0.75 0.25 1 0 0 -1\n0.25 0.75 1 0 0 -1 # second triangle\n0.25 0.75 1 0 0 -1 0.5\n5 5 1 0 0 -1\n",
    );
    let (code, out, err) = raypick(&["pick", "--scene", &obj, "--rays", &rays, "--format", "csv"]);
    assert_eq!(code, 0, "{err}");
    let rows: Vec<Vec<&str>> = out
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    assert_eq!((rows[0][1], rows[0][3], rows[0][4]), ("1", "0", "0"));
    assert_eq!(
        (rows[1][1], rows[1][4]),
        ("1", "1"),
        "fan triangle (i0, i2, i3)"
    );
    assert_eq!(rows[1][9], "0", "z of the hit");
    assert_eq!(rows[2][1], "0", "tmax 0.5 stops short of t = 1");
    assert_eq!(rows[3][1], "0");
    let (code, json, _) = raypick(&["pick", "--scene", &obj, "--rays", &rays, "--format", "json"]);
    assert_eq!(code, 0);
    let parsed: serde_json::Value = serde_json::from_str(&json).expect("valid JSON");
    assert_eq!(parsed.as_array().unwrap().len(), 4);
    assert_eq!(parsed[1]["triangle"], 1);
}

/// `bench --ray-file` (issue 13): a user's own rays timed in-process on the chosen backend and
/// thread count, ending with the machine-readable `pick_rays_per_s=<number>`; a file with no
/// rays is refused (exit 2, naming it) rather than timed as zero.
#[test]
fn bench_on_a_ray_file_ends_with_its_rate() {
    let obj = temp_file(
        "bench-quad.obj",
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n",
    );
    let rays = temp_file(
        "bench-rays.txt",
        "0.75 0.25 1 0 0 -1\n0.25 0.75 1 0 0 -1\n5 5 1 0 0 -1\n",
    );
    for backend in ["cpu", "reference"] {
        let args = [
            "bench",
            "--scene",
            &obj,
            "--ray-file",
            &rays,
            "--backend",
            backend,
            "--threads",
            "1",
            "--repeat",
            "2",
        ];
        let (code, out, err) = raypick(&args);
        assert_eq!(code, 0, "{backend}: {err}");
        assert!(out.contains("hits: 2 of 3 rays"), "{backend}: {out}");
        // The picker's description names the threads it picks on, as `--threads` asked.
        let scene = out.lines().find(|l| l.starts_with("scene:")).unwrap();
        assert!(scene.ends_with(", 1 thread)"), "{backend}: {scene}");
        assert!(
            out.contains("best of 2 passes, 1 thread\n"),
            "{backend}: {out}"
        );
        let last = out.trim_end().lines().last().unwrap();
        let rate: f64 = last
            .strip_prefix("pick_rays_per_s=")
            .unwrap_or_else(|| panic!("{backend}: last line {last:?}"))
            .parse()
            .unwrap();
        assert!(rate.is_finite() && rate > 0.0, "{backend}: {last}");
    }
    let empty = temp_file("bench-no-rays.txt", "# no rays here\n");
    let (code, out, err) = raypick(&["bench", "--scene", &obj, "--ray-file", &empty]);
    assert_eq!(code, 2, "{out}");
    assert!(
        err.contains("bench-no-rays.txt") && err.contains("no rays"),
        "{err}"
    );
}

#[test]
fn bad_input_names_the_file_and_line_and_exits_2() {
    let rays = temp_file("bad.txt", "0 0 1 0 0 -1\n0 0 1 0 zero -1\n");
    let (code, _, err) = raypick(&["pick", "--backend", "cpu", "--rays", &rays]);
    assert_eq!(code, 2);
    assert!(
        err.contains(&format!("{rays}:2")) && err.contains("zero"),
        "{err}"
    );
    let obj = temp_file("bad.obj", "v 0 0 0\nv 1 0 0\nf 1 2 9\n");
    let (code, _, err) = raypick(&["pick", "--backend", "cpu", "--scene", &obj]);
    assert_eq!(code, 2);
    assert!(err.contains(&format!("{obj}:3")), "{err}");
    let (code, _, err) = raypick(&["pick", "--scene", "missing.obj"]);
    assert_eq!(code, 2);
    assert!(err.contains("missing.obj"), "{err}");
    assert!(!err.contains("panicked"));
}

#[test]
fn verify_reports_zero_mismatches_on_the_example() {
    let (code, out, err) = raypick(&["verify", "--random", "4000"]);
    assert_eq!(code, 0, "{out}\n{err}");
    assert!(
        out.contains("4000 rays, 0 differences, 0 mismatches"),
        "{out}"
    );
    for kind in [
        "camera",
        "random",
        "vertex",
        "edge-midpoint",
        "grazing",
        "axis-parallel",
        "inside-box",
        "tmax-cutoff",
    ] {
        assert!(out.contains(kind), "{kind} missing from\n{out}");
    }
}

/// A ray valid in f64 whose origin no f32 frame holds (1e308 out, too far even to be moved
/// towards the scene) is invalid on every path, as documented; `verify` counts it in the
/// invalid column and says why, not as a mismatch against the oracle (which had hit).
#[test]
fn verify_does_not_count_rays_the_frame_cannot_hold_as_mismatches() {
    let cube = temp_file(
        "cube.obj",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4\nf 1 4 3\n",
    );
    let rays = temp_file(
        "far.txt",
        "0.25 0.5 5 0 0 -1\n0.5 0.25 1e308 0 0 -1\n0.75 0.5 -5 0 0 1\n",
    );
    let (code, out, err) = raypick(&["verify", "--scene", &cube, "--rays", &rays, "-q"]);
    assert_eq!(code, 0, "{out}\n{err}");
    assert!(out.contains("3 rays, 0 differences, 0 mismatches"), "{out}");
    assert!(
        out.contains("1 rays valid in f64 lie beyond what the scene's f32 frame holds"),
        "{out}"
    );
    let file_row = out.lines().find(|l| l.starts_with("file")).unwrap_or("");
    let columns: Vec<&str> = file_row.split_whitespace().collect();
    assert_eq!(columns.get(1..4), Some(&["3", "2", "1"][..]), "{out}");
}

/// The oracle's own copy of the triangles is sized against `--max-memory` before it is made:
/// over the budget, `verify` says so and compares the paths without it; within it, the oracle
/// runs (its line and the brute force's time).
#[test]
fn verify_skips_the_oracle_whose_triangles_are_over_the_memory_budget() {
    // 2.6 MiB: the example scene's tree fits (18,074 triangles × 144 bytes), the oracle's
    // copy (× 152) does not.
    let (code, out, err) = raypick(&["verify", "--random", "100", "--max-memory", "2.6M"]);
    assert_eq!(code, 0, "{out}\n{err}");
    assert!(
        out.contains("brute force: skipped (the oracle's copy of the triangles would need"),
        "{out}"
    );
    assert!(
        out.contains("100 rays, 0 differences, 0 mismatches"),
        "{out}"
    );
    let (code, out, err) = raypick(&["verify", "--random", "100", "--max-memory", "64M"]);
    assert_eq!(code, 0, "{out}\n{err}");
    assert!(out.contains("brute force: 100 rays in"), "{out}");
}

#[test]
fn modes_culling_masks_and_ranges_on_the_command_line() {
    // Through the tower's roof away from every edge, then its floor and the terrain.
    let rays = temp_file(
        "modes.txt",
        "33.3 45.1 100 0 0 -1\n33.3 45.1 100 0 0 -1 50\n",
    );
    let (code, out, err) = raypick(&["pick", "--rays", &rays, "--mode", "all", "--max-hits", "8"]);
    assert_eq!(code, 0, "{err}");
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(
        lines[0],
        "ray,rank,hit,t,object,triangle,u,v,x,y,z,nx,ny,nz,row,col,invalid,overflow"
    );
    let ray0: Vec<&str> = lines
        .iter()
        .filter(|l| l.starts_with("0,"))
        .copied()
        .collect();
    assert_eq!(ray0.len(), 3, "tower roof, terrain, tower floor: {ray0:?}");
    assert_eq!(
        ray0.iter()
            .map(|l| l.split(',').nth(1).unwrap())
            .collect::<Vec<_>>(),
        ["0", "1", "2"]
    );
    let ray1: Vec<&str> = lines
        .iter()
        .filter(|l| l.starts_with("1,"))
        .copied()
        .collect();
    assert_eq!(ray1.len(), 1, "tmax 50 stops at the roof: {ray1:?}");
    // The roof faces up (outward, counter-clockwise from above): culling front faces skips it,
    // and the ray meets the tower's floor from inside (a back face) next.
    let (code, out, _) = raypick(&[
        "pick",
        "--rays",
        &rays,
        "--backend",
        "cpu",
        "--cull",
        "front",
    ]);
    assert_eq!(code, 0);
    let row: Vec<&str> = out.lines().nth(1).unwrap().split(',').collect();
    assert_eq!(row[3], "1", "{out}");
    let (_, closest, _) = raypick(&["pick", "--rays", &rays, "--backend", "cpu"]);
    let closest_t: f64 = closest
        .lines()
        .nth(1)
        .unwrap()
        .split(',')
        .nth(2)
        .unwrap()
        .parse()
        .unwrap();
    assert!(
        row[2].parse::<f64>().unwrap() > closest_t,
        "the floor lies below the roof"
    );
    assert!(
        (82.0..82.2).contains(&closest_t),
        "the roof, as the README says"
    );
    // The README's --tmin example: past the roof (t ≈ 82.1) only beyond it; at 90, the terrain
    // inside the tower (t ≈ 107.1).
    let (code, out, _) = raypick(&["pick", "--rays", &rays, "--tmin", "60", "--backend", "cpu"]);
    assert_eq!(code, 0);
    let row: Vec<&str> = out.lines().nth(1).unwrap().split(',').collect();
    assert_eq!((row[2].parse::<f64>().unwrap(), row[3]), (closest_t, "1"));
    let (code, out, _) = raypick(&["pick", "--rays", &rays, "--tmin", "90", "--backend", "cpu"]);
    assert_eq!(code, 0);
    let row: Vec<&str> = out.lines().nth(1).unwrap().split(',').collect();
    assert_eq!(row[3], "0", "the terrain: {out}");
    assert!(
        (107.0..107.2).contains(&row[2].parse::<f64>().unwrap()),
        "{out}"
    );
}

#[test]
fn scene_masks_pair_with_the_scene_before_them() {
    let quad = |z: f64| format!("v 0 0 {z}\nv 1 0 {z}\nv 1 1 {z}\nv 0 1 {z}\nf 1 2 3 4\n");
    let low = temp_file("low.obj", &quad(0.0));
    let high = temp_file("high.obj", &quad(1.0));
    let rays = temp_file("down.txt", "0.5 0.25 5 0 0 -1\n");
    let pick = |extra: &[&str]| {
        let mut args = vec![
            "pick",
            "--backend",
            "cpu",
            "--rays",
            &rays,
            "--scene",
            &low,
            "--mask",
            "1",
            "--scene",
            &high,
            "--mask",
            "2",
        ];
        args.extend_from_slice(extra);
        let (code, out, err) = raypick(&args);
        assert_eq!(code, 0, "{err}");
        out.lines()
            .nth(1)
            .unwrap()
            .split(',')
            .nth(3)
            .unwrap()
            .to_string()
    };
    assert_eq!(pick(&[]), "1", "the high quad is nearer");
    assert_eq!(
        pick(&["--ray-mask", "1"]),
        "0",
        "mask 1 sees only the low quad"
    );
    assert_eq!(pick(&["--ray-mask", "0b10"]), "1");
    // Paths in a description are relative to its folder (absolute ones are refused).
    let name = |p: &str| {
        std::path::Path::new(p)
            .file_name()
            .unwrap()
            .to_str()
            .unwrap()
            .to_string()
    };
    let (low_name, high_name) = (name(&low), name(&high));
    let description = temp_file(
        "scene.json",
        &format!(
            "{{\"objects\": [{{\"file\": \"{low_name}\", \"mask\": 1}}, {{\"file\": \"{high_name}\", \"mask\": 2}}]}}"
        ),
    );
    let (code, out, err) = raypick(&[
        "pick",
        "--backend",
        "cpu",
        "--rays",
        &rays,
        "--scenes",
        &description,
        "--ray-mask",
        "1",
    ]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out.lines().nth(1).unwrap().split(',').nth(3), Some("0"));
}

#[test]
fn line_of_sight_viewshed_select_and_idbuffer() {
    let pairs = temp_file("pairs.txt", "10 10 60 60 60 60\n31 41 5 90 90 5\n");
    let (code, out, err) = raypick(&["los", "--pairs", &pairs]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out, "pair,visible\n0,1\n1,0\n");
    let targets = temp_file("targets.txt", "34 44 200\n20 20 -50\n");
    let (code, out, err) = raypick(&[
        "viewshed",
        "--observer",
        "50",
        "50",
        "150",
        "--targets",
        &targets,
        "--backend",
        "cpu",
    ]);
    assert_eq!(code, 0, "{err}");
    let visible: Vec<&str> = out
        .lines()
        .skip(1)
        .map(|l| l.rsplit(',').next().unwrap())
        .collect();
    assert_eq!(visible, ["1", "0"], "{out}");
    let camera = temp_file(
        "camera.json",
        "{\"perspective\": {\"eye\": [34, 44, 300], \"target\": [34, 44, 0], \"up\": [0, 1, 0], \"fov_y_deg\": 10, \"width\": 40, \"height\": 30}}",
    );
    let (code, out, err) = raypick(&[
        "select", "--camera", &camera, "--rect", "15", "10", "25", "20",
    ]);
    assert_eq!(code, 0, "{err}");
    let objects: Vec<&str> = out
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap())
        .collect();
    assert_eq!(
        objects,
        ["0", "1"],
        "terrain around the tower, no hall: {out}"
    );
    assert!(out.contains("\n1,tower,"), "{out}");
    let (code, out, err) = raypick(&["idbuffer", "--camera", &camera, "--backend", "cpu"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out.lines().count(), 30);
    assert!(out.lines().all(|l| l.split(',').count() == 40));
    assert_eq!(out.lines().nth(15).unwrap().split(',').nth(20), Some("1"));
}

/// The surfaces a sight line's ends lie on never block it, whatever the scene frame's
/// rounding: the traversal's single-precision t of a target on the ground 30–60 m away, in a
/// frame rounding to a fraction of a millimetre, fell inside (ε, 1 − ε), and the target's own
/// triangle hid it (a 3 × 3 grid below a 500 m spike: 7 of 9 cells hidden, 1 truly; on the
/// Jacksboro DEM a nearby target 1.7 m below the observer). Judged now on hits refined in f64.
/// Observers standing on a surface (t ≈ 0) are asked again past it.
#[test]
fn the_ends_own_surfaces_never_block_a_sight_line() {
    let grid = temp_file(
        "spike.asc",
        "ncols 3\nnrows 3\nxllcorner 0\nyllcorner 0\ncellsize 30\n500 0 0\n0 2 3\n0 4 0\n",
    );
    for backend in ["cpu", "reference", "gpu"] {
        let (code, out, err) = raypick(&[
            "viewshed",
            "--scene",
            &grid,
            "--observer",
            "45",
            "45",
            "3.7",
            "--backend",
            backend,
        ]);
        assert_eq!(code, 0, "{err}");
        let visible: String = out
            .lines()
            .skip(1)
            .map(|l| l.rsplit(',').next().unwrap())
            .collect();
        // Only the cell behind the spike's slope, (2, 0), is hidden.
        assert_eq!(visible, "111111011", "{backend}: {out}");
    }
    let dem = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/jacksboro_fault_dem_utm.asc"
    );
    // There and back, and an observer on the ground (its own surface at t = 0) looking at a
    // target in the open, and one behind a wall of terrain.
    let pairs = temp_file(
        "dem-pairs.txt",
        "518925 4037595 430.7 518955 4037655 443\n518955 4037655 443 518925 4037595 430.7\n",
    );
    let (code, out, err) = raypick(&["los", "--scene", dem, "--pairs", &pairs]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out, "pair,visible\n0,1\n1,1\n");
    let flat = temp_file(
        "flat.asc",
        "ncols 4\nnrows 3\nxllcorner 0\nyllcorner 0\ncellsize 10\n0 0 0 0\n0 0 9 0\n0 0 0 0\n",
    );
    let pairs = temp_file("ground.txt", "5 15 0 15 15 0.5\n5 15 0 35 15 0\n");
    let (code, out, err) = raypick(&["los", "--scene", &flat, "--pairs", &pairs]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out, "pair,visible\n0,1\n1,0\n", "{err}");
}

/// A sight line starting where more surfaces meet than the second pass lists (40 coincident
/// triangles at the observer, in a frame 35 km wide) cannot be decided: it is reported not
/// visible, as before, and now with a warning that counts it (it was silent).
#[test]
fn sight_lines_from_too_many_coincident_surfaces_are_warned_about() {
    let mut obj = String::new();
    for _ in 0..40 {
        obj +=
            "v 517995.1 4034995.3 399.95\nv 518005.1 4034996.3 401.0\nv 518000.1 4035006.3 401.0\n";
    }
    obj += "v 538000.1 4055000.3 20400.7\nv 538001.1 4055000.3 20400.7\nv 538000.1 4055001.3 20400.7\n";
    for k in 0..41 {
        obj += &format!("f {} {} {}\n", 3 * k + 1, 3 * k + 2, 3 * k + 3);
    }
    let scene = temp_file("coincident.obj", &obj);
    let pairs = temp_file(
        "coincident-pairs.txt",
        "518000.39999999997 4035001.0 400.765 517997.39999999997 4035003.0 396.765\n",
    );
    let (code, out, err) = raypick(&["los", "--scene", &scene, "--pairs", &pairs]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out, "pair,visible\n0,0\n");
    assert!(
        err.contains("1 pair(s) start where more than 32 surfaces meet"),
        "{err}"
    );
}

#[test]
fn camera_pixels_on_a_real_dem_report_row_and_col() {
    let dem = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/jacksboro_fault_dem_utm.asc"
    );
    let camera = temp_file(
        "dem-camera.json",
        "{\"perspective\": {\"eye\": [518775, 4030000, 4000], \"target\": [518775, 4037310, 300], \"up\": [0, 0, 1], \"fov_y_deg\": 40, \"width\": 64, \"height\": 48}}",
    );
    let pixels = temp_file("pixels.txt", "# x y\n32 24\n0 47\n63 40\n");
    let (code, out, err) = raypick(&[
        "pick", "--scene", dem, "--camera", &camera, "--pixels", &pixels,
    ]);
    assert_eq!(code, 0, "{err}");
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(
        lines[0],
        "ray,hit,t,object,triangle,u,v,x,y,z,nx,ny,nz,row,col,invalid,overflow"
    );
    for line in &lines[1..] {
        let f: Vec<&str> = line.split(',').collect();
        assert_eq!(f[1], "1", "{line}");
        let (triangle, row, col): (u32, u32, u32) = (
            f[4].parse().unwrap(),
            f[13].parse().unwrap(),
            f[14].parse().unwrap(),
        );
        assert_eq!(
            triangle / 2,
            row * 402 + col,
            "row/col follow the grid convention"
        );
        let x: f64 = f[7].parse().unwrap();
        assert!((512730.0..512730.0 + 403.0 * 30.0).contains(&x));
    }
}

/// The PNG at `path`: (colour type, bit depth, width, height, pixel bytes).
fn read_png(path: &std::path::Path) -> (png::ColorType, png::BitDepth, u32, u32, Vec<u8>) {
    let file = std::fs::File::open(path).unwrap();
    let mut reader = png::Decoder::new(std::io::BufReader::new(file))
        .read_info()
        .unwrap();
    let mut buffer = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buffer).unwrap();
    buffer.truncate(info.buffer_size());
    (
        info.color_type,
        info.bit_depth,
        info.width,
        info.height,
        buffer,
    )
}

/// `select` quotes an object's name that holds a comma, a quote or a line break, a carriage
/// return too (left bare, it split the row for CSV readers).
#[test]
fn select_quotes_names_that_would_split_a_row() {
    for odd in ["sel\rname.obj", "sel,\"odd\"\nname.obj"] {
        let obj = temp_file(odd, "v -1 -1 0\nv 1 -1 0\nv 0 1 0\nf 1 2 3\n");
        let (code, out, err) = raypick(&[
            "select",
            "--scene",
            &obj,
            "--width",
            "16",
            "--height",
            "12",
            "--rect",
            "0",
            "0",
            "16",
            "12",
            "--backend",
            "cpu",
        ]);
        assert_eq!(code, 0, "{err}");
        // Named as given.
        let quoted = format!("\"{}\"", obj.replace('"', "\"\""));
        let (header, row) = out.split_once('\n').unwrap();
        assert_eq!(header, "object,name,pixels", "{out:?}");
        assert!(row.starts_with(&format!("0,{quoted},")), "{out:?}");
    }
}

/// `select` and `idbuffer` frame the scene as `render` does when given no camera, and
/// `idbuffer`'s PNG is a colour picture unless `--raw-ids` asks for the 16-bit ids (issue 16).
#[test]
fn select_and_idbuffer_frame_the_scene_without_a_camera() {
    let (code, out, err) = raypick(&[
        "select", "--rect", "320", "260", "400", "400", "--step", "4",
    ]);
    assert_eq!(code, 0, "{err}");
    let objects: Vec<&str> = out
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(1).unwrap())
        .collect();
    assert_eq!(objects, ["terrain", "tower"], "{out}");
    let (code, out, err) = raypick(&["select", "--rect", "0", "0", "800", "600", "--step", "8"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out.lines().count(), 4, "every object is in view: {out}");
    // Each refusal says which it is (all three said "is empty or outside the view").
    for (rect, step, says) in [
        (
            ["0", "0", "801", "600"],
            "1",
            "marquee 0..801 × 0..600 reaches past the 800×600 view (columns 0..800, rows 0..600)",
        ),
        (
            ["10", "0", "10", "600"],
            "1",
            "marquee 10..10 × 0..600 is empty: each range's end must be past its start",
        ),
        (
            ["0", "0", "800", "600"],
            "0",
            "the marquee 0..800 × 0..600's step is 0; give a step of at least 1",
        ),
    ] {
        let mut args = vec!["select", "--rect"];
        args.extend(rect);
        args.extend(["--step", step]);
        let (code, _, err) = raypick(&args);
        assert_eq!(code, 2, "{err}");
        assert!(err.contains(says), "{err}");
    }
    let (code, out, err) = raypick(&[
        "select", "--width", "80", "--height", "60", "--rect", "0", "0", "80", "60",
    ]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out.lines().count(), 4, "{out}");

    let dir = std::env::temp_dir();
    let colour = dir.join(format!("raypick-cli-{}-ids.png", std::process::id()));
    let raw = dir.join(format!("raypick-cli-{}-ids16.PNG", std::process::id()));
    let (code, _, err) = raypick(&["idbuffer", "--out", colour.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = raypick(&["idbuffer", "--out", raw.to_str().unwrap(), "--raw-ids"]);
    assert_eq!(code, 0, "{err}");
    let (code, csv, err) = raypick(&["idbuffer"]);
    assert_eq!(code, 0, "{err}");
    let ids: Vec<Vec<&str>> = csv.lines().map(|l| l.split(',').collect()).collect();
    assert_eq!((ids.len(), ids[0].len()), (600, 800));
    let (kind, depth, w, h, rgba) = read_png(&colour);
    assert_eq!(
        (kind, depth, w, h),
        (png::ColorType::Rgba, png::BitDepth::Eight, 800, 600)
    );
    let (kind, depth, w, h, grey) = read_png(&raw);
    assert_eq!(
        (kind, depth, w, h),
        (png::ColorType::Grayscale, png::BitDepth::Sixteen, 800, 600)
    );
    for (i, id) in ids.iter().flatten().enumerate() {
        let raw_id = u16::from_be_bytes([grey[2 * i], grey[2 * i + 1]]);
        let pixel: [u8; 4] = rgba[4 * i..4 * i + 4].try_into().unwrap();
        match id.parse::<u32>() {
            Ok(id) => {
                assert_eq!(u32::from(raw_id), id + 1, "pixel {i}");
                assert_eq!(pixel, raypick::apps::render::object_color(id), "pixel {i}");
            }
            Err(_) => {
                assert_eq!(raw_id, 0, "pixel {i}");
                assert_eq!(pixel, raypick::apps::render::SKY, "pixel {i}");
            }
        }
    }
    let _ = std::fs::remove_file(&colour);
    let _ = std::fs::remove_file(&raw);
}

/// `soak` counts its batches right when --rays is smaller than --batch, says its columns are
/// totals, and states the memory bound it checks (issue 16).
#[test]
fn soak_reports_batches_totals_and_its_memory_bound() {
    let (code, out, err) = raypick(&["soak", "--rays", "2000", "--check", "100"]);
    assert_eq!(code, 0, "{out}\n{err}");
    assert!(
        out.starts_with("soak: 2000 rays in 1 batch of 2000 on "),
        "{out}"
    );
    assert!(
        out.contains("may grow by 64 MiB after 3 warm-up batches"),
        "{out}"
    );
    assert!(out.contains("totals so far"), "{out}");
    assert!(
        out.contains("(bound 64 MiB); 0 mismatches in 100 checked rays"),
        "{out}"
    );
    let (code, out, err) = raypick(&["soak", "--rays", "5000", "--batch", "1000", "--check", "10"]);
    assert_eq!(code, 0, "{out}\n{err}");
    assert!(
        out.starts_with("soak: 5000 rays in 5 batches of 1000 on "),
        "{out}"
    );
    assert!(out.contains("0 mismatches in 50 checked rays"), "{out}");
}

/// `RAYPICK_HUGE_PAGES=off` (the binary's allocator then gives no huge-page advice) changes no
/// answer, on a mesh large enough to be mapped and to fill buffers of several MiB.
#[test]
fn huge_pages_off_changes_no_answer() {
    let side = 400;
    let mut text = String::new();
    for k in 0..side * side {
        let (x, y) = (k % side, k / side);
        text += &format!("v {x} {y} {}\n", ((x * 7 + y * 3) % 11) as f64 * 0.1);
    }
    for y in 0..side - 1 {
        for x in 0..side - 1 {
            let k = y * side + x + 1;
            text += &format!(
                "f {k} {} {}\nf {} {} {}\n",
                k + 1,
                k + side,
                k + 1,
                k + side + 1,
                k + side
            );
        }
    }
    assert!(text.len() > 4 << 20);
    let obj = temp_file("huge-pages.obj", &text);
    let run = |setting: Option<&str>| {
        let mut command = Command::new(env!("CARGO_BIN_EXE_raypick"));
        command.args(["pick", "--scene", &obj, "--backend", "cpu"]);
        if let Some(value) = setting {
            command.env("RAYPICK_HUGE_PAGES", value);
        }
        let out = command.output().expect("run raypick");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        out.stdout
    };
    let default = run(None);
    assert!(default.len() > 1000);
    assert_eq!(run(Some("off")), default);
    assert_eq!(run(Some("0")), default);
    std::fs::remove_file(&obj).ok();
}

/// Runs the binary with `args` in the folder `dir`.
fn run_in(dir: &std::path::Path, args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_raypick"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("run raypick")
}

/// [`run_in`], which must succeed: its standard output.
fn stdout_in(dir: &std::path::Path, args: &[&str]) -> Vec<u8> {
    let out = run_in(dir, args);
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out.stdout
}

/// `--out -` is standard output, as the help says, and never a file named `-`.
#[test]
fn out_dash_is_standard_output() {
    let dir = std::env::temp_dir().join(format!("raypick-cli-dash-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let run = |args: &[&str]| stdout_in(&dir, args);
    let plain = run(&["pick"]);
    assert!(
        plain.starts_with(b"ray,hit,"),
        "{}",
        String::from_utf8_lossy(&plain)
    );
    assert_eq!(run(&["pick", "--out", "-"]), plain);
    // `render --out -` wrote a file named `-`: the PNG goes to standard output now, the same
    // bytes as the file.
    let size = ["--width", "16", "--height", "12"];
    let png = run(&[&["render", "--out", "-"][..], &size].concat());
    assert!(png.starts_with(b"\x89PNG\r\n\x1a\n"), "not a PNG on stdout");
    run(&[&["render", "--out", "file.png"][..], &size].concat());
    assert_eq!(std::fs::read(dir.join("file.png")).unwrap(), png);
    assert!(!dir.join("-").exists(), "a file named - was written");
    // `build --out -` wrote a file named `-` too: a .rpk is read mapped from a file, so it is
    // refused; and a render named as another picture format got PNG bytes.
    for (args, words) in [
        (
            &["build", "--out", "-"][..],
            "--out - (standard output) cannot hold a built scene",
        ),
        (
            &["render", "--out", "view.jpg"][..],
            "--out view.jpg names a .jpg file, but render writes PNG only",
        ),
    ] {
        let out = run_in(&dir, args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.starts_with(&format!("error: {words}")), "{err}");
        assert_eq!(err.lines().count(), 1, "{err}");
    }
    assert!(!dir.join("-").exists() && !dir.join("view.jpg").exists());
    std::fs::remove_dir_all(&dir).ok();
}

/// An `--out` naming one of the command's inputs replaced the input with the output and exited
/// 0 (an OBJ overwritten by a .rpk or a PNG, a ray file by its answers, a description's file by
/// the built scene). It is refused before anything is read or written, however the file is
/// named (another spelling, a symbolic link, a file a description lists), and the input is
/// left as it was.
/// `build` saves by writing a file beside the target and renaming it into place: over a FIFO
/// or a device that replaced the node itself (run as root, `build --out /dev/full` made
/// /dev/full a regular file, exit 0). A target that is not a regular file is refused.
#[test]
fn build_does_not_replace_a_target_that_is_not_a_regular_file() {
    use std::os::unix::fs::FileTypeExt;
    let dir = std::env::temp_dir().join(format!("raypick-fifo-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let fifo = dir.join("scene.rpk");
    let made = Command::new("mkfifo").arg(&fifo).status().expect("mkfifo");
    assert!(made.success());
    let (code, _, err) = raypick(&["build", "--out", fifo.to_str().unwrap()]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("not a regular file"), "{err}");
    let kind = std::fs::symlink_metadata(&fifo).unwrap().file_type();
    assert!(kind.is_fifo(), "the FIFO was replaced: {kind:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_out_file_that_is_one_of_the_inputs_is_refused_and_left_as_it_was() {
    let dir = std::env::temp_dir().join(format!("raypick-cli-out-in-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (code, _, err) = raypick(&["example", "--out", &dir.join("ex").display().to_string()]);
    assert_eq!(code, 0, "{err}");
    std::fs::write(dir.join("rays.txt"), "10 10 500 0 0 -1\n").unwrap();
    #[cfg(unix)]
    std::os::unix::fs::symlink("rays.txt", dir.join("link.txt")).unwrap();
    let cases: &[(&[&str], &str)] = &[
        (
            &["build", "--scene", "ex/tower.obj", "--out", "ex/tower.obj"],
            "(--scene ex/tower.obj)",
        ),
        // Any of a repeated option's values, not only its first.
        (
            &[
                "build",
                "--scene",
                "ex/tower.obj",
                "--scene",
                "ex/hall.obj",
                "--out",
                "ex/hall.obj",
            ],
            "(--scene ex/hall.obj)",
        ),
        (
            &[
                "build",
                "--scenes",
                "ex/scene.json",
                "--out",
                "ex/scene.json",
            ],
            "(--scenes ex/scene.json)",
        ),
        (
            &["build", "--scenes", "ex/scene.json", "--out", "ex/hall.obj"],
            "(ex/hall.obj, listed by ex/scene.json)",
        ),
        (
            &[
                "render",
                "--scene",
                "ex/tower.obj",
                "--out",
                "./ex/../ex/tower.obj",
            ],
            "(--scene ex/tower.obj)",
        ),
        (
            &["pick", "--rays", "rays.txt", "--out", "rays.txt"],
            "(--rays rays.txt)",
        ),
        #[cfg(unix)]
        (
            &["pick", "--rays", "link.txt", "--out", "rays.txt"],
            "(--rays link.txt)",
        ),
    ];
    let before: Vec<Vec<u8>> = ["ex/tower.obj", "ex/hall.obj", "ex/scene.json", "rays.txt"]
        .iter()
        .map(|f| std::fs::read(dir.join(f)).unwrap())
        .collect();
    for (args, input) in cases {
        let out = run_in(&dir, args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        let out_name = args[args.len() - 1];
        assert!(
            err.starts_with(&format!("error: --out {out_name} is also an input {input}")),
            "{args:?}: {err}"
        );
        assert_eq!(err.lines().count(), 1, "{err}");
    }
    let after: Vec<Vec<u8>> = ["ex/tower.obj", "ex/hall.obj", "ex/scene.json", "rays.txt"]
        .iter()
        .map(|f| std::fs::read(dir.join(f)).unwrap())
        .collect();
    assert!(before == after, "an input was changed");
    // Another file is written as before.
    stdout_in(&dir, &["pick", "--rays", "rays.txt", "--out", "hits.csv"]);
    assert!(
        std::fs::read_to_string(dir.join("hits.csv"))
            .unwrap()
            .starts_with("ray,hit,")
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// `raypick` run in `dir` with `input` on its standard input.
fn run_with_input(dir: &std::path::Path, args: &[&str], input: &str) -> std::process::Output {
    use std::io::Write as _;
    let mut child = Command::new(env!("CARGO_BIN_EXE_raypick"))
        .args(args)
        .current_dir(dir)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run raypick");
    let mut stdin = child.stdin.take().unwrap();
    let input = input.to_owned();
    let feeding = std::thread::spawn(move || {
        let _ = stdin.write_all(input.as_bytes());
    });
    let out = child.wait_with_output().unwrap();
    feeding.join().unwrap();
    out
}

/// `--rays -` (and `bench --ray-file -`) reads standard input, as `--out -` writes standard
/// output: the answers of the same rays in a file, a bad line named "standard input", and a
/// file named `-` never read in its place.
#[test]
fn rays_dash_is_standard_input() {
    let dir = std::env::temp_dir().join(format!("raypick-cli-stdin-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // Rays over the built-in scene's 1 km square, hits and misses, past one 262,144-ray chunk.
    let rays: String = (0..300_000)
        .map(|k| {
            let (x, y) = ((k % 613) as f64 * 1.7, (k / 613) as f64 * 2.1);
            format!("{x} {y} 600 0.{} 0 -1\n", k % 7)
        })
        .collect();
    std::fs::write(dir.join("rays.txt"), &rays).unwrap();
    std::fs::write(dir.join("-"), "not a ray file\n").unwrap();
    let few: String = rays.lines().take(100).map(|l| format!("{l}\n")).collect();
    let pick = ["pick", "-q", "--backend", "cpu", "--rays"];
    let from_file = stdout_in(&dir, &[&pick[..], &["rays.txt"]].concat());
    let out = run_with_input(&dir, &[&pick[..], &["-"]].concat(), &rays);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(from_file.len() > 300_000 * 20);
    assert!(out.stdout == from_file, "the answers differ");
    let out = run_with_input(&dir, &["verify", "--rays", "-"], &few);
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(said.contains(" 0 mismatches"), "{said}");
    let out = run_with_input(
        &dir,
        &[
            "bench",
            "--ray-file",
            "-",
            "--repeat",
            "1",
            "--backend",
            "cpu",
        ],
        &few,
    );
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(said.contains("pick_rays_per_s="), "{said}");
    // `--out` naming the file redirected to standard input is refused, the file kept; a file
    // named `-` is no input then.
    let out = Command::new(env!("CARGO_BIN_EXE_raypick"))
        .args([&pick[..], &["-", "--out", "rays.txt"]].concat())
        .current_dir(&dir)
        .stdin(std::fs::File::open(dir.join("rays.txt")).unwrap())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("is also an input (--rays -, standard input)"),
        "{err}"
    );
    assert!(std::fs::read_to_string(dir.join("rays.txt")).unwrap() == rays);
    let out = run_with_input(&dir, &[&pick[..], &["-", "--out", "./-"]].concat(), &few);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        std::fs::read_to_string(dir.join("-"))
            .unwrap()
            .starts_with("ray,hit,")
    );
    for args in [&pick[..], &["verify", "--rays"], &["bench", "--ray-file"]] {
        let out = run_with_input(&dir, &[args, &["-"]].concat(), "0 0 600 0 0 -1\nbad\n");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(
            err.contains("standard input:2: 'bad' is not a number"),
            "{args:?}: {err}"
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// Found by a sweep of hostile arguments: a ray file read from a pipe is checked as it streams,
/// so a bad line after the first chunk ended the pick with exit 2 and the answers so far in
/// `--out`, the file that was there replaced. The output is now written beside it and renamed
/// over it only when the pick succeeds.
#[test]
fn a_pick_that_fails_part_way_leaves_the_out_file_as_it_was() {
    let dir = std::env::temp_dir().join(format!("raypick-cli-partial-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("hits.csv"), "precious\n").unwrap();
    let mut rays = "10 10 500 0 0 -1\n".repeat(270_000);
    rays.push_str("bad\n");
    let out = run_with_input(
        &dir,
        &[
            "pick",
            "-q",
            "--backend",
            "cpu",
            "--rays",
            "/dev/stdin",
            "--out",
            "hits.csv",
        ],
        &rays,
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("/dev/stdin:270001: 'bad' is not a number"),
        "{err}"
    );
    let kept = std::fs::read_to_string(dir.join("hits.csv")).unwrap();
    assert!(kept == "precious\n", "--out replaced: {} bytes", kept.len());
    let left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left.len(), 1, "{left:?}");
    // A pick that succeeds replaces it; a file with another hard link is written into, so
    // both names give the new contents (a rename would have left the other with the old).
    std::fs::write(dir.join("rays.txt"), "10 10 500 0 0 -1\n").unwrap();
    std::fs::hard_link(dir.join("hits.csv"), dir.join("linked.csv")).unwrap();
    stdout_in(
        &dir,
        &["pick", "-q", "--rays", "rays.txt", "--out", "hits.csv"],
    );
    for name in ["hits.csv", "linked.csv"] {
        let text = std::fs::read_to_string(dir.join(name)).unwrap();
        assert!(text.starts_with("ray,hit,"), "{name}: {text}");
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// Found by a sweep of hostile arguments: with standard error closed (`raypick … 2>&1 | head
/// -1` once `head` has gone), every note, warning and error sentence panicked (exit 101, even
/// a bad flag's). The lines are now lost and the exit codes are the usual ones.
#[test]
fn a_closed_standard_error_loses_lines_without_a_panic() {
    let dir =
        std::env::temp_dir().join(format!("raypick-cli-closed-stderr-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("rays.txt"), "10 10 500 0 0 -1\n").unwrap();
    // A face with no area: a warning on standard error.
    std::fs::write(
        dir.join("flat.obj"),
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 1 2\n",
    )
    .unwrap();
    for (args, code) in [
        (&["pick", "--rays", "rays.txt"][..], 0),
        (
            &["pick", "-q", "--scene", "flat.obj", "--rays", "rays.txt"],
            0,
        ),
        (&["pick", "--rays", "missing.txt"], 2),
        (&["--no-such-flag"], 2),
        (&["verify", "--random", "50"], 0),
    ] {
        let (reader, writer) = std::io::pipe().unwrap();
        drop(reader);
        let status = Command::new(env!("CARGO_BIN_EXE_raypick"))
            .args(args)
            .current_dir(&dir)
            .env("XDG_RUNTIME_DIR", std::env::temp_dir())
            .stdout(std::process::Stdio::null())
            .stderr(writer)
            .status()
            .unwrap();
        assert_eq!(status.code(), Some(code), "{args:?}");
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// Found by a sweep of hostile arguments: `verify --random` ignored `--tmin` and `--tmax`
/// (`--tmax 0` gave the same table); they now apply as to a ray file's rays, a tmax-cutoff ray
/// keeping its own tmax.
#[test]
fn verify_random_rays_take_tmin_and_tmax() {
    let hits = |extra: &[&str]| -> Vec<(String, u64)> {
        let mut args = vec!["verify", "-q", "--random", "400"];
        args.extend_from_slice(extra);
        let (code, out, err) = raypick(&args);
        assert_eq!(code, 0, "{err}");
        out.lines()
            .skip_while(|l| !l.starts_with("kind"))
            .skip(1)
            .take(8)
            .map(|l| {
                let cols: Vec<&str> = l.split_whitespace().collect();
                (cols[0].to_string(), cols[2].parse().unwrap())
            })
            .collect()
    };
    let all = hits(&[]);
    assert!(all.iter().filter(|(_, h)| *h > 0).count() >= 6, "{all:?}");
    for (kind, h) in hits(&["--tmax", "0"]) {
        let own_tmax = kind == "tmax-cutoff";
        assert!(own_tmax || h == 0, "{kind}: {h} hits with --tmax 0");
    }
    for (kind, h) in hits(&["--tmin", "1e300"]) {
        assert_eq!(h, 0, "{kind}: {h} hits with --tmin 1e300");
    }
}

/// Found by a sweep of hostile arguments: a glTF's external buffer is an input too, which the
/// guard did not know: `pick --scene m.gltf --out m.bin` replaced the mesh's data with the
/// answers, exit 0 (so did `build`, and `los` over a description listing the glTF). And
/// `--mask` with `--scenes` was ignored without a word (a description gives its files' masks).
#[test]
fn a_gltf_buffer_as_out_and_a_mask_with_scenes_are_refused() {
    let dir = std::env::temp_dir().join(format!("raypick-cli-out-buffer-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let corners: Vec<u8> = [0f32, 0., 0., 10., 0., 0., 0., 10., 0.]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    std::fs::write(dir.join("m.bin"), &corners).unwrap();
    let gltf = r#"{"asset":{"version":"2.0"},"buffers":[{"uri":"m%2Ebin","byteLength":36}],
        "bufferViews":[{"buffer":0,"byteLength":36}],
        "accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3",
                      "min":[0,0,0],"max":[10,10,0]}],
        "meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],
        "nodes":[{"mesh":0}],"scenes":[{"nodes":[0]}],"scene":0}"#;
    std::fs::write(dir.join("m.gltf"), gltf).unwrap();
    std::fs::write(dir.join("d.json"), r#"{"objects": [{"file": "m.gltf"}]}"#).unwrap();
    std::fs::write(dir.join("pairs.txt"), "1 1 5 1 1 -5\n").unwrap();
    for args in [
        &["pick", "--scene", "m.gltf", "--out", "m.bin"][..],
        &["build", "--scene", "m.gltf", "--out", "m.bin"],
        &[
            "los",
            "--scenes",
            "d.json",
            "--pairs",
            "pairs.txt",
            "--out",
            "m.bin",
        ],
    ] {
        let out = run_in(&dir, args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(
            err.starts_with("error: --out m.bin is also an input (m.bin, a buffer of m.gltf)"),
            "{args:?}: {err}"
        );
        assert_eq!(
            std::fs::read(dir.join("m.bin")).unwrap(),
            corners,
            "{args:?}"
        );
    }
    let out = run_in(&dir, &["pick", "--scene", "m.gltf", "--out", "hits.csv"]);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = run_in(&dir, &["pick", "--scenes", "d.json", "--mask", "0"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--mask does not apply to --scenes d.json"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// A saved scene is picked from in place (`rpk::load_in_place`); a file shortened underneath a
/// running command raises SIGBUS, which the tool turns into exit code 2 and one sentence. The
/// signal is sent by hand here, once the command is surely running: it has opened the FIFO its
/// rays come from (the writer's open returns only then) and waits for rays.
#[cfg(unix)]
#[test]
fn sigbus_from_a_shortened_mapped_file_is_exit_2_and_a_sentence() {
    use std::ffi::CString;
    let rpk = std::env::temp_dir().join(format!("raypick-cli-{}-bus.rpk", std::process::id()));
    let (code, _, err) = raypick(&["build", "--out", &rpk.display().to_string()]);
    assert_eq!(code, 0, "{err}");
    let fifo = std::env::temp_dir().join(format!("raypick-cli-{}-rays.fifo", std::process::id()));
    let name = CString::new(fifo.display().to_string()).unwrap();
    // SAFETY: a valid C string; mkfifo only creates the FIFO.
    assert_eq!(unsafe { libc::mkfifo(name.as_ptr(), 0o600) }, 0, "mkfifo");
    let child = Command::new(env!("CARGO_BIN_EXE_raypick"))
        .args([
            "pick",
            "--scene",
            &rpk.display().to_string(),
            "--backend",
            "cpu",
        ])
        .args(["--rays", &fifo.display().to_string(), "--out", "-"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run raypick");
    // Blocks until the command opens the FIFO to read: the scene is loaded by then.
    let writer = std::fs::OpenOptions::new()
        .write(true)
        .open(&fifo)
        .expect("open the FIFO");
    // SAFETY: signalling our own child, which is alive (it holds the FIFO open).
    assert_eq!(
        unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGBUS) },
        0
    );
    let out = child.wait_with_output().expect("wait");
    drop(writer);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("was shortened by another program"), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    std::fs::remove_file(&fifo).ok();
    std::fs::remove_file(&rpk).ok();
}

/// A scene too wide for its single-precision frame (parts 10⁹ units apart, in other coordinates
/// say) is picked with a warning naming what the frame loses: triangles no ray can hit, objects
/// or instances it rounds too coarsely. Nearby, no warning.
#[test]
fn scenes_too_wide_for_their_frame_are_warned_about() {
    let near = temp_file("near.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let far = temp_file("far.obj", "v 1e9 0 0\nv 1e9 1 0\nv 1e9 0 1\nf 1 2 3\n");
    let both = temp_file(
        "both.obj",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1e9 0 0\nv 1e9 1 0\nv 1e9 0 1\nf 1 2 3\nf 4 5 6\n",
    );
    let rays = temp_file("down.txt", "0.2 0.2 5 0 0 -1\n");
    let pick = |scenes: &[&str]| {
        let mut args = vec!["pick", "--rays", &rays, "-q"];
        for s in scenes {
            args.extend(["--scene", s]);
        }
        raypick(&args)
    };
    let (code, out, err) = pick(&[&near, &near]);
    assert_eq!(code, 0, "{err}");
    assert!(!err.contains("warning"), "{err}");
    assert!(out.lines().nth(1).unwrap().starts_with("0,1,"), "{out}");
    let (code, out, err) = pick(&[&both]);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains(
            "warning: 1 triangle(s) with area (the first: object 0's triangle 0) have none once \
             rounded into the scene's single-precision frame, so they can never be hit; the \
             scene spans 1.000e9 units"
        ),
        "{err}"
    );
    assert!(out.lines().nth(1).unwrap().starts_with("0,0,"), "{out}");
    let (code, _, err) = pick(&[&near, &far]);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains(
            "warning: 2 objects are too small for where they lie; the first, object 0 lies \
             5.000e8 units from the centre of the scene"
        ),
        "{err}"
    );
    // Listed twice, the file is one mesh placed twice (the description beside it).
    let name = std::path::Path::new(&near)
        .file_name()
        .unwrap()
        .to_str()
        .unwrap();
    let description = temp_file(
        "far.json",
        &format!(
            r#"{{"objects": [{{"file": "{name}"}}, {{"file": "{name}", "transform": [[1, 0, 0, 1e12], [0, 1, 0, 0], [0, 0, 1, 0]]}}]}}"#
        ),
    );
    let (code, _, err) = raypick(&["pick", "--scenes", &description, "--rays", &rays, "-q"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains(
            "warning: 2 instances are too small for where they lie; the first, instance 0 lies \
             5.000e11 units from the centre of the scene"
        ),
        "{err}"
    );
}
