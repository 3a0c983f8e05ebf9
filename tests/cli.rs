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
    assert!(out.contains("4000 rays, 0 mismatches"), "{out}");
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
