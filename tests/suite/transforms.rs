//! Affine transforms in scene descriptions (`"transform"`: 3 × 4, row-major, file → world):
//! a transformed file answers as a file holding the transformed vertices would, on every
//! backend and against the oracle, 10⁶ m from the origin too; a mirror keeps front faces front
//! and reports u and v for the file's vertex order; a file listed twice is two objects; bad
//! matrices are refused with a sentence naming the object; mirrored scenes survive `.rpk`.

use crate::common;

use glam::DVec3;
use raypick::check::synthetic::{box_mesh, icosphere, mixed_rays};
use raypick::io::obj::load_obj;
use raypick::io::scene_files::{load_description, load_scene};
use raypick::scene::apply_transform;
use raypick::{BuildOptions, BuiltScene, CpuPicker, Cull, Mesh, Picker, Query, Ray, Scene};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;

/// A fresh folder under the test target directory.
fn folder(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("transforms-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// `mesh` as OBJ text, with every coordinate written so that it reads back bit for bit.
fn obj(mesh: &Mesh) -> String {
    let mut text = String::new();
    for p in &mesh.positions {
        text += &format!("v {:?} {:?} {:?}\n", p.x, p.y, p.z);
    }
    for t in &mesh.triangles {
        text += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    text
}

fn matrix_json(m: &[[f64; 4]; 3]) -> String {
    let rows: Vec<String> = m
        .iter()
        .map(|r| format!("[{:?}, {:?}, {:?}, {:?}]", r[0], r[1], r[2], r[3]))
        .collect();
    format!("[{}]", rows.join(", "))
}

/// A rotation about z by 30°, a non-uniform scale and a shear, then a translation of ~10⁶ m.
const PLACE: [[f64; 4]; 3] = [
    [0.8660254037844387, -0.5, 0.1, 1_000_000.25],
    [0.5, 0.8660254037844387, 0.0, -2_000_000.5],
    [0.0, 0.2, 1.5, 350.0],
];

/// The same with x mirrored (negative determinant).
const MIRROR: [[f64; 4]; 3] = [
    [-0.8660254037844387, -0.5, 0.1, 1_000_000.25],
    [-0.5, 0.8660254037844387, 0.0, -2_000_000.5],
    [0.0, 0.2, 1.5, 350.0],
];

fn pick_all(built: &Arc<BuiltScene>, rays: &[Ray], query: &Query) -> Vec<raypick::Hit> {
    CpuPicker::new(built.clone())
        .query(rays, query)
        .unwrap()
        .nearest
}

#[test]
fn a_transformed_file_answers_as_its_transformed_copy_and_the_oracle() {
    let dir = folder("placed");
    let bunny = load_obj(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/bunny.obj")
            .as_path(),
    )
    .unwrap();
    std::fs::write(dir.join("bunny.obj"), obj(&bunny)).unwrap();
    let moved = Mesh {
        positions: bunny
            .positions
            .iter()
            .map(|&p| apply_transform(&PLACE, p))
            .collect(),
        triangles: bunny.triangles.clone(),
    };
    std::fs::write(dir.join("moved.obj"), obj(&moved)).unwrap();
    std::fs::write(
        dir.join("scene.json"),
        format!(
            r#"{{"objects": [{{"file": "bunny.obj", "transform": {}}}]}}"#,
            matrix_json(&PLACE)
        ),
    )
    .unwrap();
    std::fs::write(
        dir.join("copy.json"),
        r#"{"objects": [{"file": "moved.obj"}]}"#,
    )
    .unwrap();
    let load = |name: &str| {
        let scene = load_scene(&load_description(&dir.join(name)).unwrap()).unwrap();
        Arc::new(BuiltScene::new(scene, &BuildOptions::default()).unwrap())
    };
    let (placed, copy) = (load("scene.json"), load("copy.json"));
    let rays = mixed_rays(&placed.scene, 3000, 4);
    let plain: Vec<Ray> = rays.iter().map(|(_, r)| *r).collect();
    for cull in [Cull::None, Cull::Back, Cull::Front] {
        let query = Query {
            cull,
            ..Query::default()
        };
        assert_eq!(
            pick_all(&placed, &plain, &query),
            pick_all(&copy, &plain, &query),
            "{cull:?}"
        );
    }
    let hits = common::assert_equivalent("placed bunny", placed.clone(), &rays);
    assert!(hits.iter().filter(|h| h.hit).count() > 500);
    // Positions 10⁶ m out keep their millimetres: each hit lies on its world triangle.
    for h in hits.iter().filter(|h| h.hit) {
        let [a, b, c] = moved.triangles[h.triangle as usize].map(|v| moved.positions[v as usize]);
        let on = a * (1.0 - h.u - h.v) + b * h.u + c * h.v;
        assert!((on - h.position).length() < 1e-3, "{h:?}");
    }
}

#[test]
fn a_mirror_keeps_front_faces_front_and_file_order_barycentrics() {
    let dir = folder("mirror");
    let sphere = icosphere(DVec3::new(1.0, 2.0, 3.0), 2.0, 2);
    std::fs::write(dir.join("sphere.obj"), obj(&sphere)).unwrap();
    std::fs::write(
        dir.join("scene.json"),
        format!(
            r#"{{"objects": [{{"file": "sphere.obj", "transform": {}}}]}}"#,
            matrix_json(&MIRROR)
        ),
    )
    .unwrap();
    let scene = load_scene(&load_description(&dir.join("scene.json")).unwrap()).unwrap();
    assert!(scene.objects()[0].mirrored);
    let built = Arc::new(BuiltScene::new(scene, &BuildOptions::default()).unwrap());
    let world: Vec<DVec3> = sphere
        .positions
        .iter()
        .map(|&p| apply_transform(&MIRROR, p))
        .collect();
    let centre = apply_transform(&MIRROR, DVec3::new(1.0, 2.0, 3.0));
    // Rays from outside at the centre: the near side faces them (a front face), so back-face
    // culling keeps it and front-face culling passes through to the far side.
    let rays: Vec<Ray> = (0..200)
        .map(|i| {
            let a = i as f64 * 0.7;
            let from = centre + DVec3::new(a.cos() * 9.0, a.sin() * 9.0, (a * 0.3).sin() * 4.0);
            Ray::new(from, centre - from + DVec3::new(0.01 * a.sin(), 0.0, 0.02))
        })
        .collect();
    let back = pick_all(
        &built,
        &rays,
        &Query {
            cull: Cull::Back,
            ..Query::default()
        },
    );
    let front = pick_all(
        &built,
        &rays,
        &Query {
            cull: Cull::Front,
            ..Query::default()
        },
    );
    let none = pick_all(&built, &rays, &Query::default());
    for i in 0..rays.len() {
        assert!(back[i].hit && front[i].hit && none[i].hit, "ray {i}");
        assert_eq!(
            back[i].t, none[i].t,
            "ray {i}: the near side is a front face"
        );
        assert!(
            front[i].t > back[i].t,
            "ray {i}: front culling passes through to the far side"
        );
        // The normal faces out of the sphere, back towards the ray.
        assert!(back[i].normal.dot(rays[i].dir) < 0.0, "ray {i}");
        assert!(
            (back[i].position - centre).dot(back[i].normal) > 0.0,
            "ray {i}"
        );
        // u and v weigh the file's second and third vertices.
        let [a, b, c] = sphere.triangles[back[i].triangle as usize].map(|v| world[v as usize]);
        let on = a * (1.0 - back[i].u - back[i].v) + b * back[i].u + c * back[i].v;
        assert!((on - back[i].position).length() < 1e-6, "ray {i}");
    }
    // Every backend and the oracle agree on the mirrored scene.
    let mixed = mixed_rays(&built.scene, 2000, 5);
    common::assert_equivalent("mirrored sphere", built.clone(), &mixed);
    // And a saved scene keeps the mirror.
    let rpk = dir.join("mirrored.rpk");
    raypick::rpk::save(&built, &rpk).unwrap();
    let loaded = Arc::new(raypick::rpk::load(&rpk).unwrap());
    assert!(loaded.scene.objects()[0].mirrored);
    assert_eq!(pick_all(&loaded, &rays, &Query::default()), none);
}

#[test]
fn a_file_listed_twice_is_two_objects_each_with_its_transform() {
    let dir = folder("twice");
    std::fs::write(dir.join("box.obj"), obj(&box_mesh(DVec3::ZERO, DVec3::ONE))).unwrap();
    std::fs::write(
        dir.join("scene.json"),
        r#"{"objects": [
            {"file": "box.obj"},
            {"file": "box.obj", "mask": 2, "transform": [[1, 0, 0, 10], [0, 1, 0, 0], [0, 0, 1, 0]]}
        ]}"#,
    )
    .unwrap();
    let scene: Scene = load_scene(&load_description(&dir.join("scene.json")).unwrap()).unwrap();
    assert_eq!(scene.objects().len(), 2);
    assert_eq!(scene.objects()[1].mask, 2);
    let built = Arc::new(BuiltScene::new(scene, &BuildOptions::default()).unwrap());
    let rays = [
        Ray::new(DVec3::new(0.5, 0.5, 5.0), DVec3::NEG_Z),
        Ray::new(DVec3::new(10.5, 0.5, 5.0), DVec3::NEG_Z),
        Ray::new(DVec3::new(5.5, 0.5, 5.0), DVec3::NEG_Z),
    ];
    let hits = pick_all(&built, &rays, &Query::default());
    assert_eq!((hits[0].hit, hits[0].object), (true, 0));
    assert_eq!((hits[1].hit, hits[1].object), (true, 1));
    assert_eq!(hits[1].position, DVec3::new(10.5, 0.5, 1.0));
    assert!(!hits[2].hit);
}

#[test]
fn bad_transforms_are_refused_with_a_sentence_naming_the_object() {
    let dir = folder("bad");
    std::fs::write(dir.join("box.obj"), obj(&box_mesh(DVec3::ZERO, DVec3::ONE))).unwrap();
    let rays = dir.join("rays.txt");
    std::fs::write(&rays, "0.5 0.5 5 0 0 -1\n").unwrap();
    for (name, transform, says) in [
        (
            "singular",
            "[[1, 0, 0, 0], [2, 0, 0, 0], [0, 0, 1, 0]]",
            "singular",
        ),
        (
            "flat",
            "[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 5]]",
            "singular",
        ),
        (
            "short",
            "[[1, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]]",
            "scene-short.json",
        ),
        (
            "huge",
            "[[1e999, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]]",
            "scene-huge.json",
        ),
        // A 4 × 4 matrix: its shape named (it was "trailing characters").
        (
            "four-rows",
            "[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]",
            "the transform must be 3 rows of 4 numbers ([[a, b, c, tx], [d, e, f, ty], [g, h, \
             i, tz]]), not 4 rows (of 4, 4, 4, 4 numbers)",
        ),
    ] {
        let description = dir.join(format!("scene-{name}.json"));
        std::fs::write(
            &description,
            format!(
                r#"{{"objects": [{{"file": "box.obj"}}, {{"file": "box.obj", "transform": {transform}}}]}}"#
            ),
        )
        .unwrap();
        let out = Command::new(env!("CARGO_BIN_EXE_raypick"))
            .args([
                "pick",
                "--scenes",
                description.to_str().unwrap(),
                "--rays",
                rays.to_str().unwrap(),
            ])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{name}: {stderr}");
        assert!(stderr.contains(says), "{name}: {stderr}");
        assert_eq!(
            stderr.trim().lines().count(),
            1,
            "{name}: one sentence: {stderr}"
        );
        if says == "singular" {
            assert!(stderr.contains("object 1"), "{name}: {stderr}");
        }
    }
}

/// Runs `raypick pick -q --backend cpu` on the description and the ray file (it must succeed);
/// what it wrote on standard error.
fn quiet_pick_stderr(description: &Path, rays: &Path) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_raypick"))
        .args(["pick", "-q", "--backend", "cpu", "--scenes"])
        .arg(description)
        .arg("--rays")
        .arg(rays)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{}: {stderr}", description.display());
    stderr
}

/// A transform that places a 1-unit box 10¹⁶ out, where f64 values are 2 units apart: its world
/// positions are rounded out of shape when it is placed, so its picks are off (a bunny there
/// answered another triangle, or a normal across the ray) without a word. Warned about now, as
/// copies (listed once) and as instances (listed twice); the same box 10⁶ out is not.
#[test]
fn a_part_placed_where_f64_cannot_hold_its_shape_is_warned_about() {
    let dir = folder("f64-far");
    std::fs::write(dir.join("box.obj"), obj(&box_mesh(DVec3::ZERO, DVec3::ONE))).unwrap();
    let rays = dir.join("rays.txt");
    std::fs::write(&rays, "0 0 5 0 0 -1\n").unwrap();
    let say = "units from the world's origin, where double precision rounds positions to ";
    for (x, listed, warned) in [
        ("1e16", 1, Some("object 0 ")),
        (
            "1e16",
            2,
            Some("2 instances lie where double precision rounds them too coarsely; the first, "),
        ),
        ("1e6", 1, None),
        ("1e6", 2, None),
        // 10¹³ out f64 values are 2 × 10⁻³ apart: more than the 10⁻⁵ picks are held to (a bunny
        // listed twice there gave 66 mismatches of 3,000 rays); 10¹¹ out, 1.5 × 10⁻⁵: not.
        (
            "1e13",
            2,
            Some("2 instances lie where double precision rounds them too coarsely"),
        ),
        ("1e11", 2, None),
    ] {
        let entry = format!(
            r#"{{"file": "box.obj", "transform": [[1, 0, 0, {x}], [0, 1, 0, 0], [0, 0, 1, 0]]}}"#
        );
        let description = dir.join(format!("far-{x}-{listed}.json"));
        let entries = vec![entry; listed].join(", ");
        std::fs::write(&description, format!(r#"{{"objects": [{entries}]}}"#)).unwrap();
        let stderr = quiet_pick_stderr(&description, &rays);
        match warned {
            Some(what) => {
                assert!(
                    stderr.contains(what) && stderr.contains(say),
                    "{x} ×{listed}: {stderr}"
                );
                assert_eq!(stderr.matches("world's origin").count(), 1, "{stderr}");
            }
            None => assert!(
                !stderr.contains("world's origin"),
                "{x} ×{listed}: {stderr}"
            ),
        }
    }
}

/// A box listed twice, the second listing 10⁸ out: the scene frame's rays reach the first box
/// within 2 × 10⁻³ units, so as instances each is resolved as a whole (16 steps), but a ray
/// can enter it a step off, more than the 10⁻⁵ of its size picks are held to, which put hits
/// near edges on the neighbouring triangle without a word (the bunny: 3 to 9 rays of 2,000
/// from 5 × 10⁷ out). Warned about now; the same listings 10⁶ apart are not.
#[test]
fn instances_whose_rays_the_frame_places_too_coarsely_are_warned_about() {
    let dir = folder("instance-triangles");
    std::fs::write(dir.join("box.obj"), obj(&box_mesh(DVec3::ZERO, DVec3::ONE))).unwrap();
    let rays = dir.join("rays.txt");
    std::fs::write(&rays, "0.5 0.5 5 0 0 -1\n").unwrap();
    for (far, warned) in [("1e8", true), ("1e6", false)] {
        let description = dir.join(format!("two-{far}.json"));
        std::fs::write(
            &description,
            format!(
                r#"{{"objects": [{{"file": "box.obj"}}, {{"file": "box.obj", "transform": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, {far}]]}}]}}"#
            ),
        )
        .unwrap();
        let stderr = quiet_pick_stderr(&description, &rays);
        let says = "instance 0 lies 5.000e7 units from the centre of the scene, where its rays \
                    are placed to 2.0e-3 units: more than a hundred-thousandth of its 1.732e0 \
                    units, so hits near its triangles' edges may name a neighbouring triangle; so \
                    does 1 more instance (are some instances in other coordinates?)";
        assert_eq!(stderr.contains(says), warned, "{far}: {stderr}");
        if warned {
            assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
        }
    }
}
