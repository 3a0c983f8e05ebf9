//! `raypick serve` end to end: servers started in-process on ephemeral loopback ports, spoken
//! to over real HTTP. Checks the scene facts, that picks (rays or camera pixels, every mode)
//! equal the pickers' own answers bit for bit, the 4xx errors, rendering, and that concurrent
//! requests are batched into shared query calls and still get their own answers.

use glam::DVec3;
use raypick::apps::camera::Camera;
use raypick::check::synthetic::{RayKind, example_scene, mixed_rays, rays as synthetic_rays};
use raypick::server::ServerConfig;
use raypick::{
    Answers, Backend, BuildOptions, BuiltScene, Cull, GpuContext, GpuPicker, Hit, Intersector,
    Mode, Picker, Query, Ray,
};
use serde_json::{Value, json};
use std::io::{Read, Write};
use std::sync::{Arc, Barrier};
use std::time::Duration;

/// The built-in example scene, built.
fn example() -> Arc<BuiltScene> {
    Arc::new(BuiltScene::new(example_scene(), &BuildOptions::default()).expect("example builds"))
}

/// Starts a server over `built` on an ephemeral loopback port; returns its base URL. The server
/// runs on its own runtime thread until the test binary exits.
fn start(built: Arc<BuiltScene>, backend: Backend, config: ServerConfig) -> String {
    format!("http://{}", crate::common::serve(built, backend, config))
}

fn agent() -> ureq::Agent {
    crate::common::http_agent(Duration::from_secs(300))
}

/// GET: status, content type, body bytes.
fn get(url: &str) -> (u16, String, Vec<u8>) {
    let mut response = agent().get(url).call().expect("GET");
    let status = response.status().as_u16();
    let kind = response
        .headers()
        .get("content-type")
        .and_then(|v| v.to_str().ok())
        .unwrap_or_default()
        .to_owned();
    let body = response
        .body_mut()
        .with_config()
        .limit(64 << 20)
        .read_to_vec()
        .expect("body");
    (status, kind, body)
}

fn get_json(url: &str) -> (u16, Value) {
    let (status, kind, body) = get(url);
    assert_eq!(kind, "application/json", "{url}");
    (status, serde_json::from_slice(&body).expect("JSON body"))
}

/// POST a JSON text: status and parsed JSON answer.
fn post(url: &str, body: &str) -> (u16, Value) {
    let mut response = agent()
        .post(url)
        .header("content-type", "application/json")
        .send(body)
        .expect("POST");
    let status = response.status().as_u16();
    let text = response
        .body_mut()
        .with_config()
        .limit(256 << 20)
        .read_to_string()
        .expect("body");
    let value = serde_json::from_str(&text).unwrap_or_else(|e| panic!("{e}: {text}"));
    (status, value)
}

/// A ray as pick-request JSON (tmax left out when unbounded).
fn ray_json(r: &Ray) -> Value {
    let mut v = json!({"origin": r.origin.to_array(), "dir": r.dir.to_array(), "tmin": r.tmin, "mask": r.mask});
    if r.tmax.is_finite() {
        v["tmax"] = json!(r.tmax);
    }
    v
}

/// Rays of every kind that JSON can carry (finite numbers).
fn json_rays(built: &BuiltScene, count: usize, seed: u64) -> Vec<Ray> {
    mixed_rays(&built.scene, count, seed)
        .into_iter()
        .map(|(_, r)| r)
        .filter(|r| r.origin.is_finite() && r.dir.is_finite() && !r.tmin.is_nan())
        .collect()
}

fn vec3(v: &Value) -> DVec3 {
    let a = v.as_array().expect("an array");
    assert_eq!(a.len(), 3);
    DVec3::new(
        a[0].as_f64().unwrap(),
        a[1].as_f64().unwrap(),
        a[2].as_f64().unwrap(),
    )
}

/// Asserts that the JSON record `got` says exactly what `want` says.
fn assert_hit(got: &Value, want: &Hit, names: &[&str], what: &str) {
    assert_eq!(got["hit"], json!(want.hit), "{what}: {got}");
    assert_eq!(
        got.get("invalid").and_then(Value::as_bool).unwrap_or(false),
        want.invalid,
        "{what}: {got}"
    );
    if !want.hit {
        assert!(got.get("position").is_none(), "{what}: {got}");
        return;
    }
    assert_eq!(got["t"].as_f64(), Some(want.t), "{what}: t");
    assert_eq!(
        got["object"].as_u64(),
        Some(u64::from(want.object)),
        "{what}"
    );
    assert_eq!(
        got["object_name"].as_str(),
        Some(names[want.object as usize]),
        "{what}"
    );
    assert_eq!(
        got["triangle"].as_u64(),
        Some(u64::from(want.triangle)),
        "{what}"
    );
    assert_eq!(got["u"].as_f64(), Some(want.u), "{what}: u");
    assert_eq!(got["v"].as_f64(), Some(want.v), "{what}: v");
    // Bit for bit: the positions went through JSON at full precision.
    assert_eq!(vec3(&got["position"]), want.position, "{what}: position");
    assert_eq!(vec3(&got["normal"]), want.normal, "{what}: normal");
    match want.cell {
        Some([row, col]) => {
            assert_eq!(got["row"].as_u64(), Some(u64::from(row)), "{what}");
            assert_eq!(got["col"].as_u64(), Some(u64::from(col)), "{what}");
        }
        None => assert!(
            got.get("row").is_none() && got.get("col").is_none(),
            "{what}"
        ),
    }
}

/// Asserts that a `/pick` answer equals `want`, ray by ray.
fn assert_answers(got: &Value, want: &Answers, mode: Mode, names: &[&str], what: &str) {
    let results = got["results"].as_array().expect("results");
    assert_eq!(results.len(), want.nearest.len(), "{what}: result count");
    for (i, r) in results.iter().enumerate() {
        if mode == Mode::All {
            let hits = r["hits"].as_array().expect("hits");
            let expected = want.hits_of(i);
            assert_eq!(hits.len(), expected.len(), "{what}: ray {i} hit count");
            for (k, (g, w)) in hits.iter().zip(expected).enumerate() {
                assert_hit(g, w, names, &format!("{what}: ray {i} hit {k}"));
            }
            assert_eq!(
                r["overflow"].as_bool(),
                Some(want.overflow[i]),
                "{what}: ray {i}"
            );
            assert_eq!(
                r.get("invalid").and_then(Value::as_bool).unwrap_or(false),
                want.nearest[i].invalid,
                "{what}: ray {i}"
            );
        } else {
            assert_hit(r, &want.nearest[i], names, &format!("{what}: ray {i}"));
        }
    }
}

fn names(built: &BuiltScene) -> Vec<&str> {
    built
        .scene
        .objects()
        .iter()
        .map(|o| o.name.as_str())
        .collect()
}

fn pick_body(rays: &[Ray], query: &Query) -> String {
    let intersector = match query.intersector {
        Intersector::MollerTrumbore => "moller-trumbore",
        Intersector::Watertight => "watertight",
    };
    json!({
        "rays": rays.iter().map(ray_json).collect::<Vec<_>>(),
        "mode": query.mode,
        "cull": query.cull,
        "max_hits": query.max_hits,
        "intersector": intersector,
    })
    .to_string()
}

/// Percent-encodes a query-string value.
fn url_encode(text: &str) -> String {
    text.bytes()
        .map(|b| match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'_' | b'.' | b'~' => {
                (b as char).to_string()
            }
            _ => format!("%{b:02X}"),
        })
        .collect()
}

/// The width and height in a PNG's IHDR.
fn png_size(png: &[u8]) -> (u32, u32) {
    assert!(png.len() > 24, "a PNG is longer than {} bytes", png.len());
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n", "PNG signature");
    assert_eq!(&png[12..16], b"IHDR");
    let be = |at: usize| u32::from_be_bytes([png[at], png[at + 1], png[at + 2], png[at + 3]]);
    (be(16), be(20))
}

#[test]
fn scene_reports_the_scene_and_the_tree() {
    let built = example();
    // Through the convenience entry point, on a listener bound inside the runtime.
    let (tx, rx) = std::sync::mpsc::channel();
    let served = built.clone();
    std::thread::spawn(move || {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .expect("runtime");
        runtime.block_on(async move {
            let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
                .await
                .expect("bind");
            tx.send(listener.local_addr().expect("address")).unwrap();
            raypick::server::serve(listener, served, Backend::Cpu)
                .await
                .expect("serve");
        });
    });
    let base = format!("http://{}", rx.recv().unwrap());
    let (status, scene) = get_json(&format!("{base}/scene"));
    assert_eq!(status, 200);
    assert_eq!(scene["backend"], "cpu");
    assert!(scene["device"].as_str().unwrap().starts_with("cpu"));
    assert_eq!(
        scene["triangles"].as_u64(),
        Some(built.scene.triangle_count() as u64)
    );
    let (lo, hi) = built.scene.bounds().unwrap();
    assert_eq!(vec3(&scene["bounds"]["min"]), lo);
    assert_eq!(vec3(&scene["bounds"]["max"]), hi);
    let objects = scene["objects"].as_array().unwrap();
    assert_eq!(objects.len(), 3);
    for (o, want) in objects.iter().zip(built.scene.objects()) {
        assert_eq!(o["id"].as_u64(), Some(u64::from(want.id)));
        assert_eq!(o["name"].as_str(), Some(want.name.as_str()));
        assert_eq!(
            o["triangles"].as_u64(),
            Some(u64::from(want.triangle_count))
        );
        assert_eq!(o["mask"].as_u64(), Some(u64::from(want.mask)));
        match want.grid {
            // The example's terrain is a height grid; the buildings are meshes.
            Some(grid) => assert_eq!(
                o["grid"],
                json!({"columns": grid.columns, "rows": grid.rows})
            ),
            None => assert_eq!(o["grid"], Value::Null),
        }
    }
    assert_eq!(objects[0]["grid"], json!({"columns": 96, "rows": 96}));
    assert_eq!(objects[1]["name"], "tower");
    let tree = &scene["tree"];
    assert_eq!(tree["nodes"].as_u64(), Some(built.bvh.nodes.len() as u64));
    assert_eq!(tree["depth"].as_u64(), Some(built.bvh.depth() as u64));
    assert_eq!(tree["leaves"].as_u64(), Some(built.bvh.leaf_count() as u64));
    assert_eq!(tree["gpu_bytes"].as_u64(), Some(built.bvh.gpu_bytes()));
    let per_triangle = built.bvh.gpu_bytes() as f64 / built.scene.triangle_count() as f64;
    assert_eq!(tree["gpu_bytes_per_triangle"].as_f64(), Some(per_triangle));
    // The framing camera the viewer starts from reads back as a camera file.
    let camera = Camera::from_json_str("camera", &scene["camera"].to_string()).unwrap();
    assert_eq!(camera, Camera::frame_bounds(lo, hi, 640, 480));
    assert_eq!(
        scene["limits"]["max_rays"].as_u64(),
        Some(ServerConfig::default().max_rays as u64)
    );
    // The viewer page.
    let (status, kind, page) = get(&format!("{base}/"));
    assert_eq!(status, 200);
    assert!(kind.starts_with("text/html"), "{kind}");
    let page = String::from_utf8(page).unwrap();
    assert!(page.contains("raypick viewer") && page.contains("/render"));
    assert!(
        !page.contains("http://") && !page.contains("https://"),
        "no external resources"
    );
}

#[test]
fn picks_rays_exactly_as_the_cpu_picker_in_every_mode() {
    let built = example();
    let base = start(built.clone(), Backend::Cpu, ServerConfig::default());
    let rays = json_rays(&built, 1600, 11);
    assert!(rays.len() > 1000);
    let mut cpu = raypick::CpuPicker::new(built.clone());
    let names = names(&built);
    for query in [
        Query::default(),
        Query {
            mode: Mode::Any,
            ..Query::default()
        },
        Query {
            mode: Mode::All,
            max_hits: 3,
            ..Query::default()
        },
        Query {
            cull: Cull::Back,
            intersector: Intersector::MollerTrumbore,
            ..Query::default()
        },
        Query {
            cull: Cull::Front,
            intersector: Intersector::Watertight,
            ..Query::default()
        },
    ] {
        let (status, answer) = post(&format!("{base}/pick"), &pick_body(&rays, &query));
        assert_eq!(status, 200, "{answer}");
        let want = cpu.query(&rays, &query).unwrap();
        assert!(want.nearest.iter().filter(|h| h.hit).count() > 300);
        assert_answers(&answer, &want, query.mode, &names, &format!("{query:?}"));
        if query.mode == Mode::All {
            assert!(
                want.overflow.iter().any(|&o| o),
                "some rays overflow 3 hits"
            );
        }
    }
    // Defaults (closest, unbounded, all layers), an invalid ray, and an empty request.
    let body = r#"{"rays": [{"origin": [34, 44, 100], "dir": [0, 0, -1]},
                            {"origin": [34, 44, 100], "dir": [0, 0, 0]}]}"#;
    let (status, answer) = post(&format!("{base}/pick"), body);
    assert_eq!(status, 200, "{answer}");
    let want = cpu
        .pick(&[
            Ray::new(DVec3::new(34.0, 44.0, 100.0), DVec3::NEG_Z),
            Ray::new(DVec3::new(34.0, 44.0, 100.0), DVec3::ZERO),
        ])
        .unwrap();
    assert_hit(&answer["results"][0], &want[0], &names, "tower");
    assert_eq!(answer["results"][0]["object_name"], "tower");
    assert_eq!(answer["results"][1], json!({"hit": false, "invalid": true}));
    let (status, answer) = post(&format!("{base}/pick"), r#"{"rays": []}"#);
    assert_eq!((status, answer), (200, json!({"results": []})));
}

/// The request's layer mask is `mask`, or `ray_mask` as the command line's `--ray-mask` names
/// it (issue 16), in the request and in a ray; both at once is a 400.
#[test]
fn the_mask_field_is_also_read_as_ray_mask() {
    let base = start(example(), Backend::Cpu, ServerConfig::default());
    let down = r#"{"origin": [33.3, 45.1, 100], "dir": [0, 0, -1]"#;
    let object_of = |body: String| {
        let (status, answer) = post(&format!("{base}/pick"), &body);
        assert_eq!(status, 200, "{body}: {answer}");
        answer["results"][0]["object"].clone()
    };
    // Every object of the example keeps all bits: any mask but 0 meets the tower's roof.
    assert_eq!(object_of(format!(r#"{{"rays": [{down}}}]}}"#)), json!(1));
    for field in ["mask", "ray_mask"] {
        assert_eq!(
            object_of(format!(r#"{{"rays": [{down}}}], "{field}": 0}}"#)),
            Value::Null,
            "{field} 0 matches no layer"
        );
        assert_eq!(
            object_of(format!(r#"{{"rays": [{down}, "{field}": 0}}]}}"#)),
            Value::Null,
            "a ray's own {field} 0"
        );
        assert_eq!(
            object_of(format!(
                r#"{{"rays": [{down}, "{field}": 2}}], "mask": 0}}"#
            )),
            json!(1),
            "the ray's {field} wins over the request's"
        );
    }
    let (status, answer) = post(
        &format!("{base}/pick"),
        &format!(r#"{{"rays": [{down}}}], "mask": 1, "ray_mask": 1}}"#),
    );
    assert_eq!(status, 400, "{answer}");
    assert!(
        answer["error"]
            .as_str()
            .unwrap()
            .contains("duplicate field"),
        "{answer}"
    );
}

#[test]
fn picks_camera_pixels_through_their_centres() {
    let built = example();
    let base = start(built.clone(), Backend::Cpu, ServerConfig::default());
    let (lo, hi) = built.scene.bounds().unwrap();
    let camera = Camera::frame_bounds(lo, hi, 64, 48);
    let mut pixels: Vec<[f64; 2]> = (0..48)
        .step_by(3)
        .flat_map(|y| {
            (0..64)
                .step_by(3)
                .map(move |x| [f64::from(x), f64::from(y)])
        })
        .collect();
    pixels.extend([[10.25, 7.5], [-3.0, 2.0], [63.0, 47.0]]);
    let names = names(&built);
    let mut cpu = raypick::CpuPicker::new(built.clone());
    for mode in [Mode::Closest, Mode::All] {
        let body = json!({"camera": camera.spec(), "pixels": pixels, "mode": mode}).to_string();
        let (status, answer) = post(&format!("{base}/pick"), &body);
        assert_eq!(status, 200, "{answer}");
        let rays: Vec<Ray> = pixels
            .iter()
            .map(|&[x, y]| camera.pixel_ray(x + 0.5, y + 0.5))
            .collect();
        let query = Query {
            mode,
            ..Query::default()
        };
        let want = cpu.query(&rays, &query).unwrap();
        let hits = want.nearest.iter().filter(|h| h.hit).count();
        assert!(hits > 50, "{hits} of {} pixels hit", pixels.len());
        assert_answers(&answer, &want, mode, &names, &format!("camera {mode:?}"));
    }
    // A camera with large coordinates and 17-digit numbers is read exactly.
    let camera = Camera::perspective(
        DVec3::new(31.123456789012345, -40.98765432109876, 80.00000000000001),
        DVec3::new(47.5, 47.5, 1.0000000000000002),
        DVec3::Z,
        33.333333333333336,
        7,
        5,
    )
    .unwrap();
    let pixels = [[3.0, 2.0], [0.0, 0.0], [6.0, 4.0]];
    let body = json!({"camera": camera.spec(), "pixels": pixels}).to_string();
    let (status, answer) = post(&format!("{base}/pick"), &body);
    assert_eq!(status, 200, "{answer}");
    let rays: Vec<Ray> = pixels
        .iter()
        .map(|&[x, y]| camera.pixel_ray(x + 0.5, y + 0.5))
        .collect();
    let want = cpu.query(&rays, &Query::default()).unwrap();
    assert_answers(&answer, &want, Mode::Closest, &names, "exact camera");
}

#[test]
fn bad_requests_get_clear_4xx_json_errors() {
    let built = example();
    let config = ServerConfig {
        max_rays: 100,
        max_body_bytes: 16 << 10,
        ..ServerConfig::default()
    };
    let base = start(built.clone(), Backend::Cpu, config);
    let pick = format!("{base}/pick");
    let ray = r#"{"origin": [0, 0, 50], "dir": [0, 0, -1]}"#;
    let camera = Camera::frame_bounds(DVec3::ZERO, DVec3::ONE, 8, 8);
    let camera_json = serde_json::to_string(camera.spec()).unwrap();
    let cases: Vec<(String, u16, &str)> = vec![
        ("{\"rays\": [".into(), 400, "not a valid pick request"),
        ("not json".into(), 400, "not a valid pick request"),
        (
            format!("{{\"rays\": [{ray}], \"colour\": 1}}"),
            400,
            "unknown field",
        ),
        (
            format!("{{\"rays\": [{ray}], \"mode\": \"nearest\"}}"),
            400,
            "unknown variant",
        ),
        // The field's path is named (serde's own sentence named none).
        (
            format!("{{\"rays\": [{ray}, {{\"origin\": [0, 0, \"x\"], \"dir\": [0, 0, 1]}}]}}"),
            400,
            "`rays[1].origin[2]`: invalid type: string",
        ),
        // serde_json said "expected value" for a name given as something else, and
        // "trailing characters" for an array too long.
        (
            format!("{{\"rays\": [{ray}], \"mode\": 1}}"),
            400,
            "pick request: `mode`: expected one of \"closest\", \"any\", \"all\" at line 1",
        ),
        (
            format!("{{\"rays\": [{ray}], \"cull\": null}}"),
            400,
            "`cull`: expected one of \"none\", \"back\", \"front\"",
        ),
        (
            r#"{"camera": {"perspective": {"eye": [0, 0, 9], "target": [0, 0, 0], "up": [0, 1, 0],
                "fov_y_deg": 60, "width": 8, "height": 8}, "orthographic": {}}, "pixels": [[1, 1]]}"#
                .into(),
            400,
            "`camera`: expected an object with exactly one of perspective, orthographic or matrices",
        ),
        (
            r#"{"rays": [{"origin": [NaN, 0, 1], "dir": [0, 0, 1]}]}"#.into(),
            400,
            "`rays[0].origin[0]`: expected a JSON value (NaN and Infinity are not JSON) at line 1",
        ),
        (
            r#"{"rays": [{"origin": [0, 0, 1, 2], "dir": [0, 0, 1]}]}"#.into(),
            400,
            "`rays[0].origin`: more values than it takes at line 1 column",
        ),
        (
            format!("{{\"rays\": [{ray}], \"mask\": -1}}"),
            400,
            "`mask`: invalid value",
        ),
        (
            format!(
                "{{\"rays\": [{ray}], \"camera\": {{\"perspective\": {{\"{}\": 1}}}}}}",
                "xx ".repeat(200)
            ),
            400,
            "`camera.perspective`: unknown field `xx xx",
        ),
        (
            format!("{{\"rays\": [{ray}]}} x"),
            400,
            "trailing characters",
        ),
        (
            format!("[[{ray}]]"),
            400,
            "pick request: it must be a JSON object",
        ),
        ("  [1".into(), 400, "it must be a JSON object"),
        // serde_path_to_error's `?` (a place it cannot name) was shown as the path: "`?`: EOF
        // while parsing", "`rays[0].?`".
        (
            "{".into(),
            400,
            "not a valid pick request: EOF while parsing an object at line 1 column 1",
        ),
        (
            "{\"rays\": [{".into(),
            400,
            "not a valid pick request: `rays[0]`: EOF while parsing an object",
        ),
        (
            r#"{"rays": [[[0, 0, 50], [0, 0, -1], 0, null, 1]]}"#.into(),
            400,
            "`rays[0]`: invalid type: sequence, expected a JSON object",
        ),
        (
            format!("{{\"rays\": [{ray}], \"mode\": \"all\", \"max_hits\": 0}}"),
            400,
            "max_hits 0 is out of range; it must be 1 ..= 1024",
        ),
        // Checked in every mode, as the command line and Python check it (closest and any
        // took any value, unread).
        (
            format!("{{\"rays\": [{ray}], \"mode\": \"closest\", \"max_hits\": 0}}"),
            400,
            "max_hits 0 is out of range; it must be 1 ..= 1024",
        ),
        (
            format!("{{\"rays\": [{ray}], \"mode\": \"any\", \"max_hits\": 5000}}"),
            400,
            "max_hits 5000 is out of range; it must be 1 ..= 1024",
        ),
        (
            format!("{{\"rays\": [{ray}], \"intersector\": \"fast\"}}"),
            400,
            "intersector",
        ),
        (
            r#"{"rays": [{"origin": [0, 0], "dir": [0, 0, 1]}]}"#.into(),
            400,
            "expected an array of length 3",
        ),
        ("{}".into(), 400, "no rays"),
        (format!("{{\"camera\": {camera_json}}}"), 400, "no `pixels`"),
        ("{\"pixels\": [[1, 2]]}".into(), 400, "no `camera`"),
        (
            format!("{{\"rays\": [{ray}], \"camera\": {camera_json}, \"pixels\": [[1, 2]]}}"),
            400,
            "both",
        ),
        (
            r#"{"camera": {"perspective": {"eye": [1, 2, 3], "target": [1, 2, 3], "up": [0, 0, 1],
                "fov_y_deg": 45, "width": 8, "height": 8}}, "pixels": [[1, 1]]}"#
                .into(),
            400,
            "invalid camera",
        ),
        (
            format!("{{\"rays\": [{}]}}", vec![ray; 101].join(",")),
            413,
            "more than this server's limit of 100",
        ),
        (
            format!(
                "{{\"camera\": {camera_json}, \"pixels\": [{}]}}",
                vec!["[1, 1]"; 101].join(",")
            ),
            413,
            "more than this server's limit of 100",
        ),
        (
            format!("{{\"rays\": [{ray}, {ray}], \"mode\": \"all\", \"max_hits\": 1024}}"),
            413,
            "lower max_hits",
        ),
        (
            format!("{{\"rays\": [{}]}}", vec![ray; 400].join(",")),
            413,
            "larger than this server's limit of 16384 bytes; send fewer rays",
        ),
    ];
    for (body, status, says) in &cases {
        let (got, answer) = post(&pick, body);
        let error = answer["error"].as_str().unwrap_or_default();
        assert_eq!(got, *status, "{body:.80}: {answer}");
        assert!(error.contains(says), "{body:.80}: {error}");
        assert_eq!(answer.as_object().map(|o| o.len()), Some(1), "{answer}");
    }
    // An inline mesh over the body limit: the advice is the mesh's, not the rays'.
    let vertex = "[1.0, 2.0, 3.0]";
    let (got, answer) = post(
        &format!("{base}/objects"),
        &format!(
            "{{\"vertices\": [{}], \"triangles\": [[0, 1, 2]]}}",
            vec![vertex; 1200].join(",")
        ),
    );
    let error = answer["error"].as_str().unwrap_or_default();
    assert_eq!(got, 413, "{answer}");
    assert!(
        error.contains("larger than this server's limit of 16384 bytes; send a smaller mesh"),
        "{error}"
    );
    // The limit is exactly at max_rays.
    let (status, answer) = post(
        &pick,
        &format!("{{\"rays\": [{}]}}", vec![ray; 100].join(",")),
    );
    assert_eq!(status, 200, "{answer}");

    // A chunked body (no Content-Length) over the limit is cut off while it is read.
    let chunk = "x".repeat(4096);
    let answer = raw_request(
        &base,
        "POST /pick HTTP/1.1\r\nHost: localhost\r\nTransfer-Encoding: chunked\r\nConnection: close\r\n\r\n",
        &(0..6)
            .map(|_| format!("{:x}\r\n{chunk}\r\n", chunk.len()))
            .chain(["0\r\n\r\n".to_owned()])
            .collect::<String>(),
    );
    assert!(answer.starts_with("HTTP/1.1 413"), "{answer}");
    assert!(
        answer.contains("larger than this server's limit"),
        "{answer}"
    );
    // A declared length over the limit is refused before the body is sent.
    let answer = raw_request(
        &base,
        "POST /pick HTTP/1.1\r\nHost: localhost\r\nContent-Length: 9000000\r\nConnection: close\r\n\r\n",
        "",
    );
    assert!(answer.starts_with("HTTP/1.1 413"), "{answer}");

    // Other routes and methods.
    let (status, answer) = get_json(&format!("{base}/nothing-here"));
    assert_eq!(status, 404);
    assert!(answer["error"].as_str().unwrap().contains("POST /pick"));
    let (status, answer) = get_json(&pick);
    assert_eq!(status, 405);
    assert!(answer["error"].as_str().unwrap().contains("POST"));
    for (query, status, says) in [
        ("shade=shiny", 400, "unknown shade 'shiny'"),
        ("camera=%7B", 400, "camera"),
        ("camera=%7B%7D", 400, "exactly one key"),
        ("width=0&height=3", 400, "at least 1"),
        ("width=100&height=100", 413, "10000 pixels"),
        ("colour=red", 400, "not valid"),
        (
            "width=ten",
            400,
            "width 'ten' is not a whole number of pixels",
        ),
        (
            "width=20&height=-1",
            400,
            "height '-1' is not a whole number of pixels",
        ),
        (
            "width=4294967296",
            400,
            "width '4294967296' is more pixels than 4294967295",
        ),
    ] {
        let (got, answer) = get_json(&format!("{base}/render?{query}"));
        assert_eq!(got, status, "{query}: {answer}");
        let error = answer["error"].as_str().unwrap_or_default();
        assert!(error.contains(says), "{query}: {error}");
    }
    let bad_camera = r#"{"perspective": {"eye": [0, 0, 0], "target": [0, 0, 0], "up": [0, 0, 1], "fov_y_deg": 45, "width": 4, "height": 4}}"#;
    let (status, answer) = get_json(&format!("{base}/render?camera={}", url_encode(bad_camera)));
    assert_eq!(status, 400);
    assert!(answer["error"].as_str().unwrap().contains("invalid camera"));
}

/// Sends `head` and `body` on a fresh connection and reads the whole answer as text.
fn raw_request(base: &str, head: &str, body: &str) -> String {
    let address = base.trim_start_matches("http://");
    let mut stream = std::net::TcpStream::connect(address).expect("connect");
    stream
        .set_read_timeout(Some(Duration::from_secs(60)))
        .unwrap();
    stream.write_all(head.as_bytes()).expect("write head");
    // The server may answer and close before reading all of the body.
    let _ = stream.write_all(body.as_bytes());
    let mut answer = Vec::new();
    let _ = stream.read_to_end(&mut answer);
    String::from_utf8_lossy(&answer).into_owned()
}

#[test]
fn renders_pngs() {
    let built = example();
    let base = start(built.clone(), Backend::Cpu, ServerConfig::default());
    let (status, kind, png) = get(&format!("{base}/render"));
    assert_eq!((status, kind.as_str()), (200, "image/png"));
    assert_eq!(png_size(&png), (640, 480));
    let (status, _, png) = get(&format!("{base}/render?width=40&height=30&shade=depth"));
    assert_eq!(status, 200);
    assert_eq!(png_size(&png), (40, 30));
    // The viewer's edit count is accepted and ignored, however large (a u64 refused 10^30).
    let (status, _, png) = get(&format!(
        "{base}/render?width=40&height=30&version=999999999999999999999999999999"
    ));
    assert_eq!(status, 200);
    assert_eq!(png_size(&png), (40, 30));
    let (lo, hi) = built.scene.bounds().unwrap();
    let camera = Camera::frame_bounds(lo, hi, 32, 24);
    for shade in ["normal", "depth", "object"] {
        let url = format!(
            "{base}/render?shade={shade}&camera={}",
            url_encode(&camera.to_json())
        );
        let (status, kind, png) = get(&url);
        assert_eq!((status, kind.as_str()), (200, "image/png"), "{shade}");
        assert_eq!(png_size(&png), (32, 24));
    }
}

/// Sends `clients` pick requests at once (24 rays each, closest/all/any in turn) to `base`,
/// checks every answer against the CPU picker, and returns the server's `/stats`.
fn concurrent_round(built: &Arc<BuiltScene>, base: &str, clients: usize, seed: u64) -> Value {
    let rays = synthetic_rays(&built.scene, RayKind::Camera, clients * 24, seed);
    let names = names(built);
    let barrier = Arc::new(Barrier::new(clients));
    let answers: Vec<(Query, Vec<Ray>, Value)> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..clients)
            .map(|c| {
                let barrier = barrier.clone();
                let mine = rays[c * 24..(c + 1) * 24].to_vec();
                let query = match c % 3 {
                    0 => Query::default(),
                    1 => Query {
                        mode: Mode::All,
                        max_hits: 4,
                        ..Query::default()
                    },
                    _ => Query {
                        mode: Mode::Any,
                        ..Query::default()
                    },
                };
                scope.spawn(move || {
                    let body = pick_body(&mine, &query);
                    barrier.wait();
                    let (status, answer) = post(&format!("{base}/pick"), &body);
                    assert_eq!(status, 200, "{answer}");
                    (query, mine, answer)
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    let mut cpu = raypick::CpuPicker::new(built.clone());
    for (c, (query, mine, answer)) in answers.iter().enumerate() {
        let want = cpu.query(mine, query).unwrap();
        assert_answers(answer, &want, query.mode, &names, &format!("client {c}"));
    }
    let (status, stats) = get_json(&format!("{base}/stats"));
    assert_eq!(status, 200);
    let count = |k: &str| stats[k].as_u64().unwrap();
    assert_eq!(count("pick_requests"), clients as u64, "{stats}");
    assert_eq!(count("rays"), rays.len() as u64, "{stats}");
    assert!(count("batches") <= clients as u64, "{stats}");
    stats
}

#[test]
fn concurrent_requests_are_batched_and_answered_separately() {
    let built = example();
    let clients = 50;
    // A wide window, so that requests released together surely meet.
    let wide = ServerConfig {
        batch_window: Duration::from_millis(40),
        ..ServerConfig::default()
    };
    let base = start(built.clone(), Backend::Cpu, wide);
    let stats = concurrent_round(&built, &base, clients, 5);
    eprintln!("{clients} concurrent requests, 40 ms window: {stats}");
    let count = |k: &str| stats[k].as_u64().unwrap();
    assert!(count("batches") < clients as u64, "{stats}");
    assert!(count("batched_requests") >= 2, "{stats}");
    assert!(count("largest_batch") >= 2, "{stats}");
    // The default 1 ms window: batching depends on timing here, the answers may not.
    let base = start(built.clone(), Backend::Cpu, ServerConfig::default());
    let stats = concurrent_round(&built, &base, clients, 6);
    eprintln!("{clients} concurrent requests, default window: {stats}");
}

#[test]
fn gpu_backend_answers_as_the_gpu_picker() {
    let built = example();
    let base = start(built.clone(), Backend::Gpu, ServerConfig::default());
    let (status, scene) = get_json(&format!("{base}/scene"));
    assert_eq!(status, 200);
    assert_eq!(scene["backend"], "gpu");
    let device = scene["device"].as_str().unwrap();
    assert!(device.starts_with("gpu "), "{device}");
    eprintln!("server device: {device}");
    let context = GpuContext::new().expect("a GPU adapter (install Mesa lavapipe without a GPU)");
    let mut gpu = GpuPicker::new(&context, built.clone()).unwrap();
    let rays = json_rays(&built, 1200, 23);
    let names = names(&built);
    for query in [
        Query::default(),
        Query {
            mode: Mode::All,
            max_hits: 5,
            ..Query::default()
        },
    ] {
        let (status, answer) = post(&format!("{base}/pick"), &pick_body(&rays, &query));
        assert_eq!(status, 200, "{answer}");
        let want = gpu.query(&rays, &query).unwrap();
        assert_answers(
            &answer,
            &want,
            query.mode,
            &names,
            &format!("gpu {query:?}"),
        );
    }
    let (status, kind, png) = get(&format!("{base}/render?width=64&height=48"));
    assert_eq!((status, kind.as_str()), (200, "image/png"));
    assert_eq!(png_size(&png), (64, 48));
}

/// Issue 11: one valid all-hits request with a long list broke a GPU-backed server for good
/// (every later larger `/pick` and every `/render` answered 500 "BindGroup with 'pick' label is
/// invalid"). Each request must stand alone.
#[test]
fn a_long_all_hits_request_never_breaks_a_gpu_server() {
    let built = example();
    let base = start(built.clone(), Backend::Gpu, ServerConfig::default());
    for max_hits in [64, 1024] {
        let body = format!(
            r#"{{"rays":[{{"origin":[33.3,45.1,100],"dir":[0,0,-1]}}],"mode":"all","max_hits":{max_hits}}}"#
        );
        let (status, answer) = post(&format!("{base}/pick"), &body);
        assert_eq!(status, 200, "max_hits {max_hits}: {answer}");
        let rays = json_rays(&built, 3000, 29);
        let (status, answer) = post(
            &format!("{base}/pick"),
            &pick_body(&rays, &Query::default()),
        );
        assert_eq!(
            status, 200,
            "a larger pick after max_hits {max_hits}: {answer}"
        );
        let (status, kind, _) = get(&format!("{base}/render?width=320&height=240"));
        assert_eq!(
            (status, kind.as_str()),
            (200, "image/png"),
            "a render after max_hits {max_hits}"
        );
    }
}

/// A web page can point a name of its own at a server on the user's machine (DNS rebinding):
/// the browser then sends the page's requests with that name as `Host`, and with the page's
/// own origin, which the `Origin` check takes for the server's. Before the `Host` check such a
/// page read the scene and its picks and edited it. Now a request whose `Host` is not an IP
/// address, `localhost` (or under `.localhost`) or a name given with `--allow-host` gets 403
/// with a sentence naming it and the flag; every path and method is refused, the allowed names
/// are served, and a request without a `Host` (HTTP/1.0) is not a browser's and is served
/// (HTTP/1.1 without one gets 400).
#[test]
fn requests_through_a_name_the_server_was_not_given_are_refused() {
    let built = example();
    let base = start(built.clone(), Backend::Cpu, ServerConfig::default());
    let port = base.rsplit(':').next().unwrap();
    let pick = r#"{"rays": [{"origin": [0, 0, 50], "dir": [0, 0, -1]}]}"#;
    let ask = |base: &str, host: Option<&str>, method: &str, path: &str, body: &str| {
        let host = host.map_or(String::new(), |h| format!("Host: {h}\r\n"));
        let origin = if host.is_empty() {
            String::new()
        } else {
            format!("Origin: http://{}\r\n", &host[6..host.len() - 2])
        };
        let version = if host.is_empty() { "1.0" } else { "1.1" };
        raw_request(
            base,
            &format!(
                "{method} {path} HTTP/{version}\r\n{host}{origin}Content-Type: text/plain\r\n\
                 Content-Length: {}\r\nConnection: close\r\n\r\n",
                body.len()
            ),
            body,
        )
    };
    let evil = format!("rebound.evil.example:{port}");
    for (method, path, body) in [
        ("GET", "/scene", ""),
        ("GET", "/", ""),
        ("GET", "/render", ""),
        ("POST", "/pick", pick),
        ("DELETE", "/objects/0", ""),
    ] {
        let answer = ask(&base, Some(&evil), method, path, body);
        assert!(
            answer.starts_with("HTTP/1.1 403"),
            "{method} {path}: {answer}"
        );
        assert!(
            answer.contains(&format!("does not answer to the name \\\"{evil}\\\""))
                && answer.contains("--allow-host rebound.evil.example"),
            "{answer}"
        );
    }
    for host in [
        format!("127.0.0.1:{port}"),
        format!("localhost:{port}"),
        format!("[::1]:{port}"),
        format!("viewer.localhost:{port}"),
    ] {
        let answer = ask(&base, Some(&host), "POST", "/pick", pick);
        assert!(answer.starts_with("HTTP/1.1 200"), "{host}: {answer}");
    }
    let answer = ask(&base, None, "GET", "/scene", "");
    assert!(answer.starts_with("HTTP/1.0 200"), "{answer}");
    // HTTP/1.1 without a Host: a malformed request (RFC 9112, 3.2), not served.
    let answer = raw_request(
        &base,
        "GET /scene HTTP/1.1\r\nConnection: close\r\n\r\n",
        "",
    );
    assert!(
        answer.starts_with("HTTP/1.1 400") && answer.contains("must name the server in a Host"),
        "{answer}"
    );
    // Two Host headers: which one a proxy in front read is unknown, so neither is trusted.
    let answer = raw_request(
        &base,
        &format!(
            "GET /scene HTTP/1.1\r\nHost: localhost:{port}\r\nHost: {evil}\r\n\
             Connection: close\r\n\r\n"
        ),
        "",
    );
    assert!(
        answer.starts_with("HTTP/1.1 400") && answer.contains("more than one Host header"),
        "{answer}"
    );
    // A request target's own name counts over the `Host` header's (RFC 9112, 3.2.2).
    let answer = ask(
        &base,
        Some(&format!("127.0.0.1:{port}")),
        "GET",
        &format!("http://rebound.evil.example:{port}/scene"),
        "",
    );
    assert!(answer.starts_with("HTTP/1.1 403"), "{answer}");
    // A name given to the server (as `--allow-host` gives it) is served.
    let named = start(
        built,
        Backend::Cpu,
        ServerConfig {
            allowed_hosts: vec!["rebound.evil.example".to_owned()],
            ..ServerConfig::default()
        },
    );
    let port = named.rsplit(':').next().unwrap();
    let answer = ask(
        &named,
        Some(&format!("Rebound.Evil.Example:{port}")),
        "POST",
        "/pick",
        pick,
    );
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
}
