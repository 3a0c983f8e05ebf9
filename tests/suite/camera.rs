//! Cameras through the public API: the image centre's ray hits the target (also at UTM-sized
//! coordinates), corner rays are symmetric, pixel (0, 0) is top-left, orthographic rays are
//! parallel and evenly spaced, matrix cameras built with glam agree with the equivalent
//! perspective and orthographic cameras, camera files round-trip and fail with clear messages,
//! framing a box shows all of it, and pixel list files give pixel centres.

use glam::dcamera::rh::proj::{directx, opengl};
use glam::dcamera::rh::view::look_at_mat4;
use glam::{DMat4, DVec3};
use proptest::prelude::*;
use raypick::apps::camera::{Camera, CameraSpec};
use raypick::io::pixel_file::{load_pixel_indices_as_centers, parse_pixel_indices_as_centers};
use raypick::{Error, Ray};
use std::path::PathBuf;

const EYE: DVec3 = DVec3::new(3.0, -40.0, 25.0);
const TARGET: DVec3 = DVec3::new(-2.0, 5.0, 1.0);

/// Distance from `p` to the line of `ray`.
fn distance_to_line(ray: &Ray, p: DVec3) -> f64 {
    let d = ray.dir.normalize();
    let v = p - ray.origin;
    (v - d * v.dot(d)).length()
}

fn assert_close(a: DVec3, b: DVec3, tol: f64, what: &str) {
    assert!(
        (a - b).abs().max_element() <= tol,
        "{what}: {a} vs {b} (difference {})",
        (a - b).abs().max_element()
    );
}

fn temp_file(name: &str, text: &str) -> PathBuf {
    crate::unique_temp_file("raypick-camera", name, text)
}

fn invalid_message(result: raypick::Result<Camera>) -> String {
    match result {
        Err(Error::Invalid(message)) => message,
        other => panic!("expected Error::Invalid, got {other:?}"),
    }
}

fn perspective(width: u32, height: u32) -> Camera {
    Camera::perspective(EYE, TARGET, DVec3::Z, 50.0, width, height).expect("camera")
}

#[test]
fn centre_ray_hits_the_target() {
    for (w, h) in [(800, 600), (801, 601), (1, 1), (640, 480)] {
        let camera = perspective(w, h);
        let ray = camera.pixel_ray(f64::from(w) / 2.0, f64::from(h) / 2.0);
        assert_eq!(ray.origin, EYE);
        assert!(ray.is_valid());
        assert!((ray.dir.length() - 1.0).abs() < 1e-15, "unit direction");
        let d = distance_to_line(&ray, TARGET);
        assert!(d < 1e-12, "{w}x{h}: centre ray misses the target by {d}");
        assert_close(
            ray.dir,
            (TARGET - EYE).normalize(),
            1e-15,
            "centre direction",
        );
        // The target lies ahead, and t is a distance.
        let t = (TARGET - EYE).dot(ray.dir);
        assert!((t - EYE.distance(TARGET)).abs() < 1e-12);
    }
    // For odd sizes the centre pixel's centre is the image centre.
    let camera = perspective(801, 601);
    assert_eq!(
        camera.pixel_center_ray(400, 300),
        camera.pixel_ray(400.5, 300.5)
    );
    assert!(distance_to_line(&camera.pixel_center_ray(400, 300), TARGET) < 1e-12);
}

#[test]
fn corner_pixel_directions_are_symmetric() {
    let (w, h) = (800u32, 600u32);
    let camera = perspective(w, h);
    let forward = (TARGET - EYE).normalize();
    let right = forward.cross(DVec3::Z).normalize();
    let up = right.cross(forward);
    let corners = [
        camera.pixel_center_ray(0, 0),
        camera.pixel_center_ray(w - 1, 0),
        camera.pixel_center_ray(0, h - 1),
        camera.pixel_center_ray(w - 1, h - 1),
    ];
    let angle = |r: &Ray| r.dir.angle_between(forward);
    for c in &corners {
        assert!((angle(c) - angle(&corners[0])).abs() < 1e-12);
        assert!((c.dir.dot(forward) - corners[0].dir.dot(forward)).abs() < 1e-12);
        assert!((c.dir.dot(right).abs() - corners[0].dir.dot(right).abs()).abs() < 1e-12);
        assert!((c.dir.dot(up).abs() - corners[0].dir.dot(up).abs()).abs() < 1e-12);
    }
    // Opposite corners average to the view direction.
    for (a, b) in [(0, 3), (1, 2)] {
        let mid = (corners[a].dir + corners[b].dir).normalize();
        assert_close(mid, forward, 1e-12, "opposite corners");
    }
    // Horizontal and vertical tangent extents follow the aspect ratio (square pixels).
    let tan_x = corners[3].dir.dot(right) / corners[3].dir.dot(forward);
    let tan_y = -corners[3].dir.dot(up) / corners[3].dir.dot(forward);
    let tan_half = 25f64.to_radians().tan();
    assert!((tan_y - tan_half * 599.0 / 600.0).abs() < 1e-12);
    assert!((tan_x - tan_half * (4.0 / 3.0) * 799.0 / 800.0).abs() < 1e-12);
    // The image edges are exactly at the field of view.
    let top = camera.pixel_ray(400.0, 0.0);
    assert!((top.dir.angle_between(forward) - 25f64.to_radians()).abs() < 1e-12);
}

#[test]
fn pixel_origin_is_top_left() {
    let camera = perspective(800, 600);
    let forward = (TARGET - EYE).normalize();
    let right = forward.cross(DVec3::Z).normalize();
    let up = right.cross(forward);
    let ray = camera.pixel_center_ray(0, 0);
    assert!(
        ray.dir.dot(right) < 0.0,
        "pixel (0, 0) must be left of centre"
    );
    assert!(ray.dir.dot(up) > 0.0, "pixel (0, 0) must be above centre");
    assert!(ray.dir.dot(DVec3::Z) > forward.dot(DVec3::Z));
    // x grows right, y grows down.
    let a = camera.pixel_ray(100.0, 100.0);
    let b = camera.pixel_ray(101.0, 100.0);
    let c = camera.pixel_ray(100.0, 101.0);
    assert!((b.dir - a.dir).dot(right) > 0.0);
    assert!((c.dir - a.dir).dot(up) < 0.0);
    // Fractional coordinates interpolate between pixel centres.
    let mid = camera.pixel_ray(1.0, 0.5);
    let (p0, p1) = (camera.pixel_center_ray(0, 0), camera.pixel_center_ray(1, 0));
    assert!(mid.dir.dot(right) > p0.dir.dot(right) && mid.dir.dot(right) < p1.dir.dot(right));
    // Every pixel, row by row from the top.
    let small = perspective(3, 2);
    let all: Vec<Ray> = small.pixel_center_rays().collect();
    assert_eq!(all.len(), 6);
    assert_eq!(all[0], small.pixel_center_ray(0, 0));
    assert_eq!(all[4], small.pixel_center_ray(1, 1));
}

#[test]
fn orthographic_rays_are_parallel_and_evenly_spaced() {
    let (w, h, view_height) = (400u32, 300u32, 60.0);
    let camera = Camera::orthographic(EYE, TARGET, DVec3::Z, view_height, w, h).expect("camera");
    let forward = (TARGET - EYE).normalize();
    let right = forward.cross(DVec3::Z).normalize();
    let up = right.cross(forward);
    let step = view_height / f64::from(h);
    let centre = camera.pixel_ray(200.0, 150.0);
    assert_close(centre.origin, EYE, 1e-12, "centre origin");
    assert!(distance_to_line(&centre, TARGET) < 1e-12);
    for (i, j) in [(0, 0), (17, 250), (398, 298), (200, 150)] {
        let a = camera.pixel_center_ray(i, j);
        let b = camera.pixel_center_ray(i + 1, j);
        let c = camera.pixel_center_ray(i, j + 1);
        for r in [&a, &b, &c] {
            assert_eq!(r.dir, centre.dir, "all rays share the view direction");
            assert_close(r.dir, forward, 1e-15, "view direction");
            assert!(
                (r.origin - EYE).dot(forward).abs() < 1e-12,
                "origin on the eye plane"
            );
        }
        assert_close(
            b.origin - a.origin,
            right * step,
            1e-12,
            "horizontal spacing",
        );
        assert_close(c.origin - a.origin, -up * step, 1e-12, "vertical spacing");
    }
    // The view volume is view_height tall and view_height * w / h wide.
    let top = camera.pixel_ray(200.0, 0.0).origin;
    let bottom = camera.pixel_ray(200.0, 300.0).origin;
    let left = camera.pixel_ray(0.0, 150.0).origin;
    let right_edge = camera.pixel_ray(400.0, 150.0).origin;
    assert!((top.distance(bottom) - view_height).abs() < 1e-12);
    assert!((left.distance(right_edge) - view_height * 4.0 / 3.0).abs() < 1e-12);
    // Top-left origin here too.
    let tl = camera.pixel_center_ray(0, 0).origin - EYE;
    assert!(tl.dot(right) < 0.0 && tl.dot(up) > 0.0);
}

/// Pixel coordinates to compare cameras at: corners, centre, and fractional points.
fn sample_pixels(w: u32, h: u32) -> Vec<(f64, f64)> {
    let (w, h) = (f64::from(w), f64::from(h));
    vec![
        (0.5, 0.5),
        (w - 0.5, 0.5),
        (0.5, h - 0.5),
        (w - 0.5, h - 0.5),
        (w / 2.0, h / 2.0),
        (0.0, 0.0),
        (w, h),
        (w * 0.123, h * 0.877),
        (17.25, 3.75),
        (-20.0, h + 5.0),
    ]
}

fn assert_same_rays(a: &Camera, b: &Camera, tol: f64, what: &str) {
    for (x, y) in sample_pixels(a.width(), a.height()) {
        let (ra, rb) = (a.pixel_ray(x, y), b.pixel_ray(x, y));
        assert_close(
            ra.origin,
            rb.origin,
            tol,
            &format!("{what}: origin at ({x}, {y})"),
        );
        assert_close(
            ra.dir,
            rb.dir,
            tol,
            &format!("{what}: direction at ({x}, {y})"),
        );
        assert_eq!((ra.tmin, ra.tmax), (rb.tmin, rb.tmax));
    }
}

#[test]
fn matrices_camera_matches_perspective_camera() {
    let (w, h, fov) = (800u32, 600u32, 50.0f64);
    let aspect = f64::from(w) / f64::from(h);
    let expected = perspective(w, h);
    let view = look_at_mat4(EYE, TARGET, DVec3::Z);
    let projections = [
        (
            "opengl::perspective",
            opengl::perspective(fov.to_radians(), aspect, 0.1, 1000.0),
        ),
        (
            "directx::perspective",
            directx::perspective(fov.to_radians(), aspect, 0.5, 50.0),
        ),
        ("opengl::frustum", {
            let (near, top) = (0.2, 0.2 * (fov / 2.0).to_radians().tan());
            opengl::frustum(-top * aspect, top * aspect, -top, top, near, 300.0)
        }),
        (
            "directx::perspective_infinite",
            directx::perspective_infinite(fov.to_radians(), aspect, 0.01),
        ),
        (
            "directx::perspective_infinite_reverse",
            directx::perspective_infinite_reverse(fov.to_radians(), aspect, 0.01),
        ),
    ];
    for (name, projection) in projections {
        let camera = Camera::from_matrices(view, projection, w, h).expect(name);
        assert_same_rays(&camera, &expected, 1e-9, name);
    }
}

#[test]
fn matrices_camera_matches_orthographic_camera() {
    let (w, h, view_height) = (640u32, 480u32, 30.0f64);
    let half_h = view_height / 2.0;
    let half_w = half_h * f64::from(w) / f64::from(h);
    let expected = Camera::orthographic(EYE, TARGET, DVec3::Z, view_height, w, h).expect("camera");
    let view = look_at_mat4(EYE, TARGET, DVec3::Z);
    for (name, projection) in [
        (
            "opengl::orthographic",
            opengl::orthographic(-half_w, half_w, -half_h, half_h, 1.0, 500.0),
        ),
        (
            "directx::orthographic",
            directx::orthographic(-half_w, half_w, -half_h, half_h, -10.0, 100.0),
        ),
    ] {
        let camera = Camera::from_matrices(view, projection, w, h).expect(name);
        assert_same_rays(&camera, &expected, 1e-9, name);
    }
}

#[test]
fn utm_scale_rays_are_exact() {
    let eye = DVec3::new(500_000.0, 4_000_000.0, 1_000.0);
    let target = DVec3::new(500_321.125, 4_000_456.75, 212.5);
    let (w, h) = (1920u32, 1080u32);
    let camera = Camera::perspective(eye, target, DVec3::Z, 45.0, w, h).expect("camera");
    let ray = camera.pixel_ray(960.0, 540.0);
    assert_eq!(ray.origin, eye);
    let d = distance_to_line(&ray, target);
    assert!(
        d < 1e-6,
        "perspective centre ray misses the target by {d} m"
    );
    // The same through matrices.
    let view = look_at_mat4(eye, target, DVec3::Z);
    let projection = opengl::perspective(45f64.to_radians(), f64::from(w) / f64::from(h), 0.5, 1e5);
    let camera = Camera::from_matrices(view, projection, w, h).expect("matrices");
    let ray = camera.pixel_ray(960.0, 540.0);
    assert!(
        ray.origin.distance(eye) < 1e-6,
        "origin {} vs eye {eye}",
        ray.origin
    );
    let d = distance_to_line(&ray, target);
    assert!(d < 1e-6, "matrices centre ray misses the target by {d} m");
    // Orthographic too.
    let camera = Camera::orthographic(eye, target, DVec3::Z, 500.0, w, h).expect("ortho");
    let d = distance_to_line(&camera.pixel_ray(960.0, 540.0), target);
    assert!(
        d < 1e-6,
        "orthographic centre ray misses the target by {d} m"
    );
    // An off-centre pixel: the ray through a world point's projection passes through it.
    let camera = Camera::perspective(eye, target, DVec3::Z, 45.0, w, h).expect("camera");
    let forward = (target - eye).normalize();
    let right = forward.cross(DVec3::Z).normalize();
    let up = right.cross(forward);
    let p = target + right * 40.0 + up * 25.0;
    let v = p - eye;
    let tan_half = 22.5f64.to_radians().tan();
    let sx = v.dot(right) / v.dot(forward) / (tan_half * f64::from(w) / f64::from(h));
    let sy = v.dot(up) / v.dot(forward) / tan_half;
    let x = (sx + 1.0) * f64::from(w) / 2.0;
    let y = (1.0 - sy) * f64::from(h) / 2.0;
    let d = distance_to_line(&camera.pixel_ray(x, y), p);
    assert!(d < 1e-6, "off-centre ray misses its point by {d} m");
}

#[test]
fn json_round_trip() {
    let view = look_at_mat4(EYE, TARGET, DVec3::Y);
    let cameras = [
        Camera::perspective(EYE, TARGET, DVec3::Z, 37.5, 801, 333).unwrap(),
        Camera::orthographic(EYE, TARGET, DVec3::new(0.1, 0.2, 1.0), 0.1 + 0.2, 7, 9).unwrap(),
        Camera::from_matrices(view, opengl::perspective(0.7, 1.5, 0.1, 100.0), 300, 200).unwrap(),
    ];
    for camera in cameras {
        let json = camera.to_json();
        let back = Camera::from_json_str("mem.json", &json).expect("read back");
        assert_eq!(back, camera, "{json}");
        assert_eq!(back.pixel_ray(12.3, 4.5), camera.pixel_ray(12.3, 4.5));
        // Through a file, and through serde directly.
        let path = temp_file("roundtrip.json", &json);
        assert_eq!(Camera::from_json_file(&path).expect("file"), camera);
        std::fs::remove_file(&path).ok();
        // Plain serde_json may read 17-digit numbers an ulp off (no float_roundtrip feature).
        let direct: Camera =
            serde_json::from_str(&serde_json::to_string(&camera).unwrap()).unwrap();
        assert_same_rays(&direct, &camera, 1e-12, "serde_json");
    }
}

#[test]
fn json_examples_parse() {
    let p = Camera::from_json_str(
        "p.json",
        r#"{"perspective": {"eye": [500000, 4000000, 1000], "target": [500100, 4000100, 0],
            "up": [0,0,1], "fov_y_deg": 45, "width": 800, "height": 600}}"#,
    )
    .expect("perspective");
    assert_eq!(
        *p.spec(),
        CameraSpec::Perspective {
            eye: DVec3::new(5e5, 4e6, 1e3),
            target: DVec3::new(500_100.0, 4_000_100.0, 0.0),
            up: DVec3::Z,
            fov_y_deg: 45.0,
            width: 800,
            height: 600,
        }
    );
    let o = Camera::from_json_str(
        "o.json",
        r#"{"orthographic": {"eye": [0,0,10], "target": [0,0,0], "up": [0,1,0],
            "view_height": 100.0, "width": 10, "height": 20}}"#,
    )
    .expect("orthographic");
    assert_eq!((o.width(), o.height()), (10, 20));
    assert_eq!(o.pixel_center_ray(0, 0).dir, DVec3::NEG_Z);
    let view = look_at_mat4(EYE, TARGET, DVec3::Z).to_cols_array();
    let projection = opengl::perspective(1.0, 2.0, 0.1, 10.0).to_cols_array();
    let text = format!(
        r#"{{"matrices": {{"view": {view:?}, "projection": {projection:?}, "width": 4, "height": 2}}}}"#
    );
    let m = Camera::from_json_str("m.json", &text).expect("matrices");
    assert_eq!((m.width(), m.height()), (4, 2));
    let centre = m.pixel_ray(2.0, 1.0);
    assert!(distance_to_line(&centre, TARGET) < 1e-12);
}

fn parse_error(result: raypick::Result<Camera>) -> (String, Option<usize>, String) {
    match result {
        Err(Error::Parse {
            path,
            line,
            message,
        }) => (path, line, message),
        other => panic!("expected a parse error, got {other:?}"),
    }
}

#[test]
fn malformed_camera_files_name_file_and_line() {
    let cases = [
        (
            "{\n  \"perspective\": {\n    \"eye\": [0, 0],\n",
            3,
            "invalid length 2",
        ),
        ("{\"persp\": {}}", 1, "unknown variant `persp`"),
        (
            "{}",
            1,
            "exactly one key: `perspective`, `orthographic` or `matrices`",
        ),
        (
            r#"{"perspective": {"eye": [0,1,9], "target": [0,0,0], "up": [0,0,1], "fov_y_deg": 45, "width": 8, "height": 6}, "matrices": {}}"#,
            1,
            "exactly one key",
        ),
        (
            "{\"perspective\": {\"eye\": [0,0,1], \"target\": [0,0,0], \"up\": [0,1,0],\n\"fov\": 45, \"width\": 8, \"height\": 6}}",
            2,
            "unknown field `fov`",
        ),
        (
            "{\"orthographic\": {\"eye\": [0,0,1], \"target\": [0,0,0], \"up\": [0,1,0],\n\"width\": 8, \"height\": 6}}",
            2,
            "missing field `view_height`",
        ),
        (
            "{\"orthographic\": {\"eye\": [0,0,1], \"target\": [0,0,0], \"up\": [0,1,0],\n\"view_height\": 1,\n\"width\": -8, \"height\": 6}}",
            3,
            "-8",
        ),
        (
            "{\"matrices\": {\"view\": [1,2,3], \"projection\": [1], \"width\": 1, \"height\": 1}}",
            1,
            "16",
        ),
        (
            "{\"perspective\": {\"eye\": [0,0,1e999]}}",
            1,
            "number out of range",
        ),
        ("", 1, "EOF"),
        ("not json", 1, "expected"),
        // A list too long said "trailing characters"; a size of 2^64 "invalid type: floating
        // point" alone.
        (
            r#"{"perspective": {"eye": [0, 0, 1, 0], "target": [0,0,0], "up": [0,1,0], "fov_y_deg": 45, "width": 8, "height": 6}}"#,
            1,
            "a list has too many numbers (`eye`, `target` and `up` take 3, `view` and \
             `projection` 16) (column 35)",
        ),
        (
            r#"{"perspective": {"eye": [0, 0, 1], "target": [0,0,0], "up": [0,1,0], "fov_y_deg": 45, "width": 18446744073709551616, "height": 6}}"#,
            1,
            "expected u32: `width` and `height` are whole numbers of pixels, 1 to 4294967295",
        ),
    ];
    for (text, line, needle) in cases {
        let (path, got_line, message) = parse_error(Camera::from_json_str("cam.json", text));
        assert_eq!(path, "cam.json");
        assert_eq!(got_line, Some(line), "{text:?}: {message}");
        assert!(
            message.contains(needle),
            "{text:?}: {message:?} lacks {needle:?}"
        );
        let shown = Error::Parse {
            path,
            line: got_line,
            message,
        }
        .to_string();
        assert!(shown.starts_with(&format!("cam.json:{line}: ")), "{shown}");
    }
    // Through files: missing files are I/O errors naming the file; bad ones name file and line.
    let missing = std::env::temp_dir().join("raypick-camera-does-not-exist.json");
    match Camera::from_json_file(&missing) {
        Err(e @ Error::Io { .. }) => {
            assert!(e.to_string().contains("raypick-camera-does-not-exist.json"))
        }
        other => panic!("expected an I/O error, got {other:?}"),
    }
    let path = temp_file("bad.json", "{\n\"perspective\": 5}");
    let (p, line, _) = parse_error(Camera::from_json_file(&path));
    assert_eq!((p, line), (path.display().to_string(), Some(2)));
    std::fs::write(&path, b"{\"perspective\":\n\xff}").unwrap();
    let (_, line, message) = parse_error(Camera::from_json_file(&path));
    assert_eq!(line, Some(2));
    assert!(message.contains("UTF-8"));
    std::fs::remove_file(&path).ok();
}

#[test]
fn degenerate_cameras_are_rejected_with_sentences() {
    let p = |eye: DVec3, target: DVec3, up: DVec3, fov: f64, w: u32, h: u32| {
        invalid_message(Camera::perspective(eye, target, up, fov, w, h))
    };
    let z = DVec3::Z;
    let m = p(EYE, EYE, z, 45.0, 8, 6);
    assert!(m.contains("eye and target are the same point"), "{m}");
    let m = p(DVec3::ZERO, DVec3::new(0.0, 0.0, -5.0), z, 45.0, 8, 6);
    assert!(m.contains("parallel to the view direction"), "{m}");
    let m = p(EYE, TARGET, (TARGET - EYE) * -3.0, 45.0, 8, 6);
    assert!(m.contains("parallel"), "{m}");
    let m = p(EYE, TARGET, DVec3::ZERO, 45.0, 8, 6);
    assert!(m.contains("up"), "{m}");
    for fov in [0.0, 180.0, -10.0, 200.0, f64::NAN, f64::INFINITY] {
        let m = p(EYE, TARGET, z, fov, 8, 6);
        assert!(m.contains("between 0 and 180 degrees"), "{fov}: {m}");
    }
    for (w, h) in [(0, 6), (8, 0), (0, 0)] {
        let m = p(EYE, TARGET, z, 45.0, w, h);
        assert!(m.contains("at least 1"), "{m}");
    }
    let m = p(DVec3::new(f64::NAN, 0.0, 0.0), TARGET, z, 45.0, 8, 6);
    assert!(m.contains("eye") && m.contains("non-finite"), "{m}");
    let m = p(EYE, DVec3::splat(f64::INFINITY), z, 45.0, 8, 6);
    assert!(m.contains("target") && m.contains("non-finite"), "{m}");
    let m = p(DVec3::splat(-1e308), DVec3::splat(1e308), z, 45.0, 8, 6);
    assert!(m.contains("cannot be represented"), "{m}");
    for vh in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let m = invalid_message(Camera::orthographic(EYE, TARGET, z, vh, 8, 6));
        assert!(m.contains("view_height"), "{vh}: {m}");
    }
    // Matrices.
    let view = look_at_mat4(EYE, TARGET, z);
    let projection = opengl::perspective(1.0, 1.0, 0.1, 10.0);
    let m = invalid_message(Camera::from_matrices(view, DMat4::ZERO, 8, 6));
    assert!(m.contains("projection matrix is singular"), "{m}");
    let flat = DMat4::from_scale(DVec3::new(1.0, 1.0, 0.0));
    let m = invalid_message(Camera::from_matrices(flat, projection, 8, 6));
    assert!(m.contains("view matrix is singular"), "{m}");
    let m = invalid_message(Camera::from_matrices(projection, projection, 8, 6));
    assert!(m.contains("last row"), "{m}");
    let mut nan = view.to_cols_array();
    nan[5] = f64::NAN;
    let m = invalid_message(Camera::from_matrices(
        DMat4::from_cols_array(&nan),
        projection,
        8,
        6,
    ));
    assert!(m.contains("non-finite"), "{m}");
    let m = invalid_message(Camera::from_matrices(view, projection, 8, 0));
    assert!(m.contains("at least 1"), "{m}");
    // A projection under which pixels see no line of sight (rays parallel to the image plane).
    let sideways = DMat4::from_cols_array(&[
        1.0, 0.0, 0.0, 0.0, //
        0.0, 0.0, 1.0, 0.0, //
        0.0, 1.0, 0.0, 0.0, //
        0.0, 0.0, 0.0, 1.0,
    ]);
    let m = invalid_message(Camera::from_matrices(view, sideways, 8, 6));
    assert!(m.contains("no usable ray"), "{m}");

    // From files, the sentence names the file.
    let path = temp_file(
        "degenerate.json",
        r#"{"perspective": {"eye": [1,2,3], "target": [1,2,3], "up": [0,0,1], "fov_y_deg": 45, "width": 8, "height": 6}}"#,
    );
    let m = invalid_message(Camera::from_json_file(&path));
    assert!(m.starts_with(&path.display().to_string()), "{m}");
    assert!(m.contains("eye and target are the same point"), "{m}");
    std::fs::remove_file(&path).ok();
    let m = invalid_message(Camera::from_json_str(
        "c.json",
        r#"{"perspective": {"eye": [0,0,9], "target": [0,0,0], "up": [0,0,1], "fov_y_deg": 45, "width": 8, "height": 6}}"#,
    ));
    assert!(m.starts_with("c.json: ") && m.contains("parallel"), "{m}");
    let m = invalid_message(Camera::from_json_str(
        "c.json",
        r#"{"perspective": {"eye": [0,1,9], "target": [0,0,0], "up": [0,0,1], "fov_y_deg": 180, "width": 8, "height": 6}}"#,
    ));
    assert!(m.contains("fov_y_deg is 180"), "{m}");
    // A view narrower than f64 resolves at its eye gave every pixel one ray; a narrow one that
    // it resolves is still a camera.
    for (spec, narrow) in [
        (
            r#""perspective": {"eye": [0,1,9], "target": [0,0,0], "up": [0,0,1], "fov_y_deg": 1e-300"#,
            true,
        ),
        (
            r#""perspective": {"eye": [0,1,9], "target": [0,0,0], "up": [0,0,1], "fov_y_deg": 5e-324"#,
            true,
        ),
        (
            r#""orthographic": {"eye": [1e15,1,9], "target": [1e15,0,0], "up": [0,0,1], "view_height": 1e-6"#,
            true,
        ),
        (
            r#""perspective": {"eye": [0,1,9], "target": [0,0,0], "up": [0,0,1], "fov_y_deg": 1e-6"#,
            false,
        ),
        (
            r#""orthographic": {"eye": [1e15,1,9], "target": [1e15,0,0], "up": [0,0,1], "view_height": 10"#,
            false,
        ),
    ] {
        let made = Camera::from_json_str(
            "c.json",
            &format!(r#"{{{spec}, "width": 64, "height": 48}}}}"#),
        );
        if narrow {
            let m = invalid_message(made);
            assert!(m.contains("neighbouring pixels get the same ray"), "{m}");
        } else {
            let camera = made.unwrap();
            assert_ne!(
                camera.pixel_ray(0.5, 0.5),
                camera.pixel_ray(63.5, 47.5),
                "{spec}"
            );
        }
    }
    let m = invalid_message(Camera::from_json_str(
        "c.json",
        r#"{"matrices": {"view": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1], "projection": [0,0,0,0, 0,0,0,0, 0,0,0,0, 0,0,0,0], "width": 8, "height": 6}}"#,
    ));
    assert!(m.contains("singular"), "{m}");
}

/// Whether `p` lies inside the pyramid spanned by the camera's image corners.
fn in_view(camera: &Camera, p: DVec3) -> bool {
    let (w, h) = (f64::from(camera.width()), f64::from(camera.height()));
    let eye = camera.pixel_ray(0.0, 0.0).origin;
    let corners = [(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)].map(|(x, y)| camera.pixel_ray(x, y).dir);
    (0..4).all(|k| {
        let normal = corners[k].cross(corners[(k + 1) % 4]);
        normal.dot(p - eye) >= -1e-9 * (p - eye).length()
    }) && (p - eye).dot(camera.pixel_ray(w / 2.0, h / 2.0).dir) > 0.0
}

#[test]
fn frame_bounds_shows_the_whole_box_from_above() {
    let boxes = [
        (DVec3::new(-1.0, -2.0, 0.0), DVec3::new(3.0, 1.0, 0.5)),
        (
            DVec3::new(500_000.0, 4_000_000.0, 100.0),
            DVec3::new(510_000.0, 4_012_000.0, 900.0),
        ),
        (DVec3::new(0.0, 0.0, 0.0), DVec3::new(1.0, 1.0, 0.0)), // flat
        (DVec3::new(0.0, 0.0, -50.0), DVec3::new(0.1, 0.1, 50.0)), // tall and thin
    ];
    for (min, max) in boxes {
        for (w, h) in [(800, 600), (300, 1000), (1, 1)] {
            let camera = Camera::frame_bounds(min, max, w, h);
            assert_eq!((camera.width(), camera.height()), (w, h));
            let centre = camera.pixel_ray(f64::from(w) / 2.0, f64::from(h) / 2.0);
            let c = (min + max) * 0.5;
            assert!(distance_to_line(&centre, c) < 1e-6);
            assert!(centre.origin.z > max.z, "the eye is above the box");
            let down = -centre.dir.z;
            assert!(
                down > 0.2 && down < 0.95,
                "oblique, looking down: {}",
                centre.dir
            );
            for k in 0..8 {
                let corner = DVec3::new(
                    if k & 1 == 0 { min.x } else { max.x },
                    if k & 2 == 0 { min.y } else { max.y },
                    if k & 4 == 0 { min.z } else { max.z },
                );
                assert!(
                    in_view(&camera, corner),
                    "{min}..{max} {w}x{h}: corner {corner} outside"
                );
            }
            assert!(matches!(camera.spec(), CameraSpec::Perspective { .. }));
        }
    }
    // Degenerate input never panics and still gives a usable camera.
    let nan = DVec3::splat(f64::NAN);
    for (min, max, w, h) in [
        (nan, nan, 8, 6),
        (DVec3::ONE, DVec3::ZERO, 8, 6),
        (DVec3::splat(5.0), DVec3::splat(5.0), 8, 6),
        (DVec3::splat(4e6), DVec3::splat(4e6), 8, 6),
        (DVec3::splat(-1e308), DVec3::splat(1e308), 8, 6),
        (DVec3::splat(f64::NEG_INFINITY), DVec3::ZERO, 0, 0),
    ] {
        let camera = Camera::frame_bounds(min, max, w, h);
        assert!(camera.width() >= 1 && camera.height() >= 1);
        assert!(
            camera.pixel_center_rays().all(|r| r.is_valid()),
            "{min}..{max}"
        );
    }
}

/// `pick`'s default view (issue 16): straight down, north up, east right, the box's bottom face
/// in view and filling it along one side, the eye above the box.
#[test]
fn frame_from_above_looks_straight_down_with_north_up() {
    let boxes = [
        (DVec3::new(0.0, 0.0, -11.0), DVec3::new(95.0, 95.0, 28.0)), // the example scene
        (DVec3::new(-1.0, -2.0, 0.0), DVec3::new(3.0, 1.0, 0.5)),
        (
            DVec3::new(500_000.0, 4_000_000.0, 100.0),
            DVec3::new(510_000.0, 4_012_000.0, 900.0),
        ),
        (DVec3::new(0.0, 0.0, 0.0), DVec3::new(1.0, 1.0, 0.0)), // flat
        (DVec3::new(0.0, 0.0, -50.0), DVec3::new(0.1, 0.1, 50.0)), // tall and thin
    ];
    for (min, max) in boxes {
        for (w, h) in [(8, 8), (800, 600), (300, 1000), (1, 1)] {
            let camera = Camera::frame_from_above(min, max, w, h);
            assert_eq!((camera.width(), camera.height()), (w, h));
            let (fw, fh) = (f64::from(w), f64::from(h));
            let centre = camera.pixel_ray(fw / 2.0, fh / 2.0);
            assert!(centre.origin.z > max.z, "the eye is above the box");
            assert!(
                (centre.dir - DVec3::NEG_Z).length() < 1e-12,
                "{}",
                centre.dir
            );
            let c = (min + max) * 0.5;
            assert!(
                (centre.origin.truncate() - c.truncate()).length() < 1e-6 * c.length().max(1.0)
            );
            // North is up, east is right.
            assert!(camera.pixel_ray(fw / 2.0, 0.0).dir.y > 0.0);
            assert!(camera.pixel_ray(fw, fh / 2.0).dir.x > 0.0);
            for k in 0..4 {
                let corner = DVec3::new(
                    if k & 1 == 0 { min.x } else { max.x },
                    if k & 2 == 0 { min.y } else { max.y },
                    min.z,
                );
                assert!(
                    in_view(&camera, corner),
                    "{min}..{max} {w}x{h}: corner {corner} outside"
                );
            }
        }
    }
    // Degenerate boxes fall back to the oblique framing camera, never panic.
    let nan = DVec3::splat(f64::NAN);
    for (min, max) in [
        (nan, nan),
        (DVec3::ONE, DVec3::ZERO),
        (DVec3::splat(5.0), DVec3::splat(5.0)),
        (DVec3::splat(-1e308), DVec3::splat(1e308)),
    ] {
        let camera = Camera::frame_from_above(min, max, 8, 0);
        assert_eq!((camera.width(), camera.height()), (8, 1));
        assert!(
            camera.pixel_center_rays().all(|r| r.is_valid()),
            "{min}..{max}"
        );
    }
}

#[test]
fn pixel_list_files_give_pixel_centres() {
    let text = "# pixels\n3 4\n\n  0\t0   # top-left\n1.25 2\n-1 7\n";
    let pixels = parse_pixel_indices_as_centers("px.txt", text).expect("parse");
    assert_eq!(
        pixels,
        vec![(3.5, 4.5), (0.5, 0.5), (1.75, 2.5), (-0.5, 7.5)]
    );
    // Integers are whole pixels: their centres give pixel_center_ray.
    let camera = perspective(8, 6);
    assert_eq!(
        camera.pixel_ray(pixels[0].0, pixels[0].1),
        camera.pixel_center_ray(3, 4)
    );
    assert_eq!(parse_pixel_indices_as_centers("e.txt", "").unwrap(), vec![]);

    for (text, line, needle) in [
        ("1 2\n3\n", 2, "expected 2 numbers"),
        ("1 2 3\n", 1, "found 3"),
        ("# c\n\nx 2\n", 3, "'x' is not a number"),
        ("1 nan\n", 1, "not a finite"),
        ("1 inf\n", 1, "not a finite"),
    ] {
        match parse_pixel_indices_as_centers("px.txt", text) {
            Err(e @ Error::Parse { .. }) => {
                let shown = e.to_string();
                assert!(shown.starts_with(&format!("px.txt:{line}: ")), "{shown}");
                assert!(shown.contains(needle), "{shown}");
            }
            other => panic!("{text:?}: expected a parse error, got {other:?}"),
        }
    }
    let path = temp_file("pixels.txt", "10 20\n5 5 5\n");
    match load_pixel_indices_as_centers(&path) {
        Err(e) => assert_eq!(
            e.to_string(),
            format!(
                "{}:2: expected 2 numbers (pixel column x and row y), found 3",
                path.display()
            )
        ),
        Ok(p) => panic!("expected an error, got {p:?}"),
    }
    std::fs::write(&path, "10 20\n").unwrap();
    assert_eq!(
        load_pixel_indices_as_centers(&path).unwrap(),
        vec![(10.5, 20.5)]
    );
    std::fs::remove_file(&path).ok();
    let missing = std::env::temp_dir().join("raypick-pixels-does-not-exist.txt");
    assert!(matches!(
        load_pixel_indices_as_centers(&missing),
        Err(Error::Io { .. })
    ));
}

proptest! {
    /// Arbitrary numbers never panic: constructors either fail or give a camera whose in-image
    /// rays are valid.
    #[test]
    fn arbitrary_cameras_never_panic(
        eye in prop::array::uniform3(prop::num::f64::ANY),
        target in prop::array::uniform3(-1e6f64..1e6),
        up in prop::array::uniform3(-2f64..2.0),
        fov in prop::num::f64::ANY,
        view_height in prop::num::f64::ANY,
        w in 0u32..5000,
        h in 0u32..5000,
        x in 0f64..1.0,
        y in 0f64..1.0,
        matrix in prop::array::uniform16(-3f64..3.0),
    ) {
        let (eye, target, up) = (DVec3::from(eye), DVec3::from(target), DVec3::from(up));
        let cameras = [
            Camera::perspective(eye, target, up, fov, w, h),
            Camera::perspective(eye.clamp(DVec3::splat(-1e7), DVec3::splat(1e7)), target, up, fov.rem_euclid(180.0), w, h),
            Camera::orthographic(eye, target, up, view_height, w, h),
            Camera::from_matrices(look_at_mat4(target, target + DVec3::X, DVec3::Z), DMat4::from_cols_array(&matrix), w, h),
        ];
        for camera in cameras.into_iter().flatten() {
            let ray = camera.pixel_ray(x * f64::from(w), y * f64::from(h));
            prop_assert!(ray.is_valid(), "{:?} at ({x}, {y}): {ray:?}", camera.spec());
            prop_assert!(!camera.pixel_ray(f64::NAN, 0.0).is_valid());
        }
    }
}

/// serde_json with `float_roundtrip` (Cargo.toml) reads every f64 of a camera file back bit for
/// bit, in the shortest form and in 17 significant digits, so the camera needs no number walker
/// of its own.
#[test]
fn camera_file_numbers_round_trip_bit_for_bit() {
    use rand::Rng;
    let mut rng = raypick::check::synthetic::rng(77);
    for i in 0..5000 {
        let eye: [f64; 3] = std::array::from_fn(|_| {
            let magnitude = 10f64.powf(rng.random_range(-3.0..7.0));
            let sign = if rng.random_bool(0.5) { -1.0 } else { 1.0 };
            sign * magnitude * rng.random_range(1.0..10.0)
        });
        let fov: f64 = rng.random_range(1.0..170.0);
        for (form, text) in [
            (
                "shortest",
                format!(
                    r#"{{"perspective": {{"eye": [{:?}, {:?}, {:?}], "target": [0, 0, 0], "up": [0, 0, 1], "fov_y_deg": {fov:?}, "width": 8, "height": 6}}}}"#,
                    eye[0], eye[1], eye[2]
                ),
            ),
            (
                "17 digits",
                format!(
                    r#"{{"perspective": {{"eye": [{:.16e}, {:.16e}, {:.16e}], "target": [0, 0, 0], "up": [0, 0, 1], "fov_y_deg": {fov:.16e}, "width": 8, "height": 6}}}}"#,
                    eye[0], eye[1], eye[2]
                ),
            ),
        ] {
            // Eyes straight above the target are degenerate with up = z: skip those draws.
            let Ok(camera) = raypick::apps::camera::Camera::from_json_str("roundtrip.json", &text)
            else {
                continue;
            };
            let raypick::apps::camera::CameraSpec::Perspective {
                eye: got,
                fov_y_deg,
                ..
            } = camera.spec()
            else {
                panic!("a perspective camera");
            };
            for a in 0..3 {
                assert_eq!(got[a].to_bits(), eye[a].to_bits(), "{form} #{i}: {text}");
            }
            assert_eq!(fov_y_deg.to_bits(), fov.to_bits(), "{form} #{i}");
        }
    }
}

/// The batch made on all cores is `pixel_center_rays` with the mask, ray for ray.
#[test]
fn pixel_center_ray_batch_is_pixel_center_rays() {
    let camera = Camera::frame_bounds(
        DVec3::new(-3.0, -2.0, 0.0),
        DVec3::new(5.0, 4.0, 2.0),
        131,
        67,
    );
    let batch = camera.pixel_center_ray_batch(0b101);
    let rows: Vec<_> = camera
        .pixel_center_rays()
        .map(|r| r.with_mask(0b101))
        .collect();
    assert_eq!(batch.len(), 131 * 67);
    assert_eq!(batch, rows);
}

/// A lattice of every `step`-th pixel is the rays of those pixels, row by row; one of step 1
/// over the view is the whole batch.
#[test]
fn pixel_center_ray_lattice_is_the_pixels_rays() {
    let camera = Camera::frame_bounds(DVec3::ZERO, DVec3::new(4.0, 3.0, 1.0), 40, 30);
    let lattice = camera.pixel_center_ray_lattice((5, 7), (4, 3), 3, 9);
    let expected: Vec<_> = (0..3)
        .flat_map(|b| (0..4).map(move |a| (5 + 3 * a, 7 + 3 * b)))
        .map(|(i, j)| camera.pixel_center_ray(i, j).with_mask(9))
        .collect();
    assert_eq!(lattice, expected);
    assert_eq!(
        camera.pixel_center_ray_lattice((0, 0), (40, 30), 1, 9),
        camera.pixel_center_ray_batch(9)
    );
}

/// An eye 10¹⁶⁰ from its target is a camera (its distance's square overflowed, and the
/// camera was refused as "the distance … cannot be represented"); one whose distance does not
/// fit f64 is refused so.
#[test]
fn eyes_far_beyond_the_square_roots_reach_are_cameras() {
    let camera = |eye: DVec3| Camera::perspective(eye, DVec3::ZERO, DVec3::Y, 30.0, 4, 3);
    let far = camera(DVec3::new(0.0, 0.0, 1e160)).expect("a camera");
    let centre = far.pixel_center_ray(2, 1);
    assert!(centre.dir.z < 0.0, "{centre:?}");
    let e = invalid_message(Camera::perspective(
        DVec3::new(1e308, 0.0, 0.0),
        DVec3::new(-1e308, 0.0, 0.0),
        DVec3::Y,
        30.0,
        4,
        3,
    ));
    assert!(e.contains("cannot be represented"), "{e}");
}

/// Of a list of pixel centres, `outside_image` counts those outside the image and names the
/// first of them by its index (what the warning about a pixel file made for another image size
/// says); points on the image's edges, its right and bottom ones included, are inside.
#[test]
fn pixel_centres_outside_the_image_are_counted_and_the_first_named() {
    let camera = Camera::perspective(EYE, TARGET, DVec3::Z, 50.0, 4, 3).unwrap();
    let edges = [(0.0, 0.0), (4.0, 3.0), (4.0, 0.0), (0.0, 3.0), (2.0, 1.5)];
    assert_eq!(camera.outside_image(edges), None);
    let centres = [
        (2.0, 1.5),
        (4.5, 1.0),
        (0.5, 0.5),
        (1.0, -0.5),
        (1.0, 3.5),
        (f64::NAN, 1.0),
    ];
    assert_eq!(camera.outside_image(centres), Some((4, 1)));
}
