//! The `raypick` binary end to end: outputs, exit codes and error messages.

use std::process::Command;

fn raypick(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_raypick"))
        .args(args)
        .output()
        .expect("run raypick");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn temp_file(name: &str, text: &str) -> String {
    let path = std::env::temp_dir().join(format!("raypick-cli-{}-{name}", std::process::id()));
    std::fs::write(&path, text).unwrap();
    path.display().to_string()
}

#[test]
fn pick_on_the_example_scene_prints_one_row_per_ray_on_both_backends() {
    let (gpu_code, gpu_out, gpu_err) = raypick(&["pick"]);
    assert_eq!(gpu_code, 0, "{gpu_err}");
    let (cpu_code, cpu_out, _) = raypick(&["pick", "--backend", "cpu"]);
    assert_eq!(cpu_code, 0);
    assert_eq!(gpu_out, cpu_out, "the backends agree on the example");
    let lines: Vec<&str> = gpu_out.lines().collect();
    assert_eq!(lines[0], "ray,hit,t,object,triangle,u,v,x,y,z,nx,ny,nz");
    assert_eq!(lines.len(), 65);
    assert!(lines.iter().any(|l| l.split(',').nth(1) == Some("1")));
    assert!(lines[1..].iter().all(|l| l.split(',').count() == 13));
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
        "ray,rank,hit,t,object,triangle,u,v,x,y,z,nx,ny,nz"
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
    let (code, out, _) = raypick(&["pick", "--rays", &rays, "--tmin", "60", "--backend", "cpu"]);
    assert_eq!(code, 0);
    let row: Vec<&str> = out.lines().nth(1).unwrap().split(',').collect();
    assert!(row[2].parse::<f64>().unwrap() > 60.0);
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
        "ray,hit,t,object,triangle,u,v,x,y,z,nx,ny,nz,row,col"
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
