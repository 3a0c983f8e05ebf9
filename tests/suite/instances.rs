//! Instanced scenes (meshes stored once, placed by f64 transforms under a median-cut top
//! tree): random scenes of rotated, non-uniformly scaled, sheared, mirrored and far-translated
//! instances answer every ray kind, in every mode, on the engine, the twin and the GPU as the
//! brute-force oracle answers the instances baked into world triangles, with 0 mismatches; the
//! twin and the GPU agree bit for bit; hits report the instance and the mesh's own triangle.

use crate::common;

use common::assert_query_equivalent;
use glam::{DMat3, DQuat, DVec3};
use rand::Rng;
use raypick::check::synthetic::{
    RayKind, box_mesh, hills, icosphere, mixed_rays, rng, terrain, triangle_soup,
};
use raypick::instance::Instance;
use raypick::{BuildOptions, BuiltScene, Cull, Intersector, Mesh, Mode, Picker, Query, Scene};
use std::sync::Arc;

/// A scene of one object holding `mesh` (a height grid when `grid` says its shape).
fn mesh_scene(name: &str, mesh: Mesh, grid: Option<(u32, u32)>) -> Scene {
    let mut scene = Scene::new();
    match grid {
        Some((columns, rows)) => scene
            .add_grid_mesh(name, mesh, raypick::GridShape { columns, rows })
            .unwrap(),
        None => scene.add_mesh(name, mesh).unwrap(),
    };
    scene
}

fn meshes() -> Vec<Scene> {
    vec![
        mesh_scene(
            "sphere",
            icosphere(DVec3::new(0.5, -0.25, 1.0), 2.0, 2),
            None,
        ),
        mesh_scene(
            "box",
            box_mesh(DVec3::new(-1.0, -2.0, 0.0), DVec3::new(1.5, 1.0, 3.0)),
            None,
        ),
        mesh_scene("soup", triangle_soup(150, 4.0, 11), None),
        mesh_scene(
            "terrain",
            terrain(9, 7, -4.0, 3.0, 1.0, |x, y| hills(x * 5.0, y * 5.0) * 0.1),
            Some((9, 7)),
        ),
    ]
}

/// `m` (3 × 3, applied to column vectors) and translation `t` as a 3 × 4 row-major transform.
fn transform(m: DMat3, t: DVec3) -> [[f64; 4]; 3] {
    let r = |k: usize| {
        let row = m.row(k);
        [row.x, row.y, row.z, t[k]]
    };
    [r(0), r(1), r(2)]
}

/// `count` instances of random meshes: a random rotation, non-uniform scale (a mirror one time
/// in four), a shear one time in three, placed within `spread` of `centre`.
fn random_instances(count: usize, centre: DVec3, spread: f64, seed: u64) -> Vec<Instance> {
    let mut g = rng(seed);
    (0..count)
        .map(|k| {
            let axis = DVec3::new(
                g.random_range(-1.0..1.0),
                g.random_range(-1.0..1.0),
                g.random_range(-1.0..1.0),
            )
            .try_normalize()
            .unwrap_or(DVec3::Z);
            let rotation = DMat3::from_quat(DQuat::from_axis_angle(axis, g.random_range(0.0..6.3)));
            let mut scale = DVec3::new(
                g.random_range(0.4..2.5),
                g.random_range(0.4..2.5),
                g.random_range(0.4..2.5),
            );
            if g.random_range(0..4) == 0 {
                scale.x = -scale.x;
            }
            let mut m = rotation * DMat3::from_diagonal(scale);
            if g.random_range(0..3) == 0 {
                m *= DMat3::from_cols(DVec3::X, DVec3::new(0.3, 1.0, 0.0), DVec3::Z);
            }
            let t = centre
                + DVec3::new(
                    g.random_range(-spread..spread),
                    g.random_range(-spread..spread),
                    g.random_range(-spread * 0.3..spread * 0.3),
                );
            Instance {
                name: format!("instance {k}"),
                mesh: g.random_range(0..4),
                transform: transform(m, t),
                mask: if k % 7 == 3 { 2 } else { 1 },
            }
        })
        .collect()
}

fn queries() -> Vec<Query> {
    let base = Query::default();
    vec![
        base,
        Query {
            intersector: Intersector::MollerTrumbore,
            ..base
        },
        Query {
            mode: Mode::Any,
            ..base
        },
        Query {
            mode: Mode::All,
            max_hits: 4,
            ..base
        },
        Query {
            cull: Cull::Back,
            ..base
        },
        Query {
            cull: Cull::Front,
            mode: Mode::All,
            max_hits: 8,
            ..base
        },
    ]
}

/// Every query over the mixed ray kinds, aimed at the baked world triangles.
fn check(name: &str, instances: Vec<Instance>, rays_per_scene: usize) {
    let built = Arc::new(
        BuiltScene::instanced(meshes(), instances, &BuildOptions::default()).expect("build"),
    );
    let baked = built.instances().unwrap().baked().unwrap();
    let rays = mixed_rays(&baked, rays_per_scene, 5);
    for query in queries() {
        assert_query_equivalent(name, built.clone(), &rays, &query);
    }
}

#[test]
fn random_instances_near_the_origin_match_the_oracle_on_every_path() {
    check("near", random_instances(24, DVec3::ZERO, 12.0, 1), 1200);
}

#[test]
fn instances_a_million_metres_out_match_the_oracle_on_every_path() {
    check(
        "far",
        random_instances(24, DVec3::new(1.0e6, -2.0e6, 300.0), 15.0, 2),
        1200,
    );
}

#[test]
fn instances_spread_over_a_million_metres_match_the_oracle_on_every_path() {
    // One cluster at the origin, one 10⁶ m out: the scene frame's centre is half way, so each
    // instance is entered from a ray origin split in two parts.
    let mut instances = random_instances(12, DVec3::ZERO, 10.0, 3);
    instances.extend(random_instances(12, DVec3::new(1.0e6, 0.0, 0.0), 10.0, 4));
    check("spread", instances, 1200);
}

#[test]
fn hits_report_the_instance_and_the_meshs_own_triangle_within_a_millimetre_far_out() {
    // Two copies of the box, one 10⁶ m out and turned, one near the origin; rays aimed at a
    // known point on a known face of each.
    let turn = DMat3::from_rotation_z(0.5);
    let far = DVec3::new(1.0e6 + 0.125, 2.5e5, -40.0);
    let instances = vec![
        Instance {
            name: "near".into(),
            mesh: 1,
            transform: transform(DMat3::IDENTITY, DVec3::ZERO),
            mask: u32::MAX,
        },
        Instance {
            name: "far".into(),
            mesh: 1,
            transform: transform(turn, far),
            mask: u32::MAX,
        },
    ];
    let built = Arc::new(
        BuiltScene::instanced(meshes(), instances, &BuildOptions::default()).expect("build"),
    );
    // The box's top face is z = 3; aim straight down at (0.3, -0.7) in its frame.
    let local = DVec3::new(0.3, -0.7, 3.0);
    for (k, (m, t)) in [(DMat3::IDENTITY, DVec3::ZERO), (turn, far)]
        .into_iter()
        .enumerate()
    {
        let target = m * local + t;
        let ray = raypick::Ray::new(target + DVec3::new(0.0, 0.0, 10.0), DVec3::NEG_Z);
        for mut picker in [
            Box::new(raypick::CpuPicker::new(built.clone())) as Box<dyn Picker>,
            Box::new(raypick::ReferencePicker::new(built.clone())),
        ] {
            let hit = picker.pick(&[ray]).unwrap()[0];
            assert!(hit.hit, "instance {k}: {hit:?}");
            assert_eq!(hit.object, k as u32);
            assert!(
                (hit.position - target).length() < 1e-3,
                "{hit:?} vs {target}"
            );
            assert!((hit.t - 10.0).abs() < 1e-3, "{hit:?}");
            let faces = built.instances().unwrap().meshes()[1]
                .scene
                .triangle_count();
            assert!((hit.triangle as usize) < faces);
            assert!(hit.normal.z > 0.999, "{hit:?}");
        }
    }
}

#[test]
fn a_mesh_placed_many_times_is_stored_once() {
    let instances = random_instances(200, DVec3::ZERO, 100.0, 9);
    let built = BuiltScene::instanced(meshes(), instances, &BuildOptions::default()).unwrap();
    let i = built.instances().unwrap();
    let mesh_triangles: usize = i.meshes().iter().map(|m| m.bvh.triangles.len()).sum();
    assert_eq!(built.bvh.triangles.len(), mesh_triangles);
    assert_eq!(
        built.bvh.nodes.len() as u32,
        i.top_nodes() + {
            i.meshes()
                .iter()
                .map(|m| m.bvh.nodes.len() as u32)
                .sum::<u32>()
        }
    );
    assert_eq!(i.top_nodes(), 2 * 200 - 1);
}

#[test]
fn bad_instances_are_refused_naming_them() {
    let mut instances = random_instances(3, DVec3::ZERO, 5.0, 1);
    instances[1].transform[2] = [0.0, 0.0, 0.0, 1.0];
    let e = BuiltScene::instanced(meshes(), instances.clone(), &BuildOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("instance 1") && e.contains("singular"), "{e}");
    instances[1].transform[2] = [0.0, 0.0, f64::NAN, 1.0];
    let e = BuiltScene::instanced(meshes(), instances.clone(), &BuildOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("instance 1") && e.contains("not finite"), "{e}");
    instances[1].transform = raypick::instance::IDENTITY;
    instances[2].mesh = 9;
    let e = BuiltScene::instanced(meshes(), instances, &BuildOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("instance 2") && e.contains("mesh 9"), "{e}");
    // An instanced scene's objects move as instances, which the sentence names (in one line,
    // its words one space apart).
    let mut built = BuiltScene::instanced(
        meshes(),
        random_instances(3, DVec3::ZERO, 5.0, 1),
        &BuildOptions::default(),
    )
    .unwrap();
    let e = built.set_positions(0, &[]).unwrap_err().to_string();
    assert!(
        e.contains("move one with set_instance_transform") && !e.contains("  "),
        "{e}"
    );
}

#[test]
fn rays_miss_instances_whose_masks_they_do_not_share() {
    let instances = random_instances(20, DVec3::ZERO, 8.0, 12);
    let built = Arc::new(
        BuiltScene::instanced(meshes(), instances.clone(), &BuildOptions::default()).unwrap(),
    );
    let baked = built.instances().unwrap().baked().unwrap();
    let rays: Vec<raypick::Ray> = mixed_rays(&baked, 600, 3)
        .into_iter()
        .filter(|(k, _)| *k == RayKind::Random || *k == RayKind::Camera)
        .map(|(_, mut r)| {
            r.mask = 2;
            r
        })
        .collect();
    let hits = raypick::ReferencePicker::new(built).pick(&rays).unwrap();
    assert!(hits.iter().any(|h| h.hit));
    for h in hits.iter().filter(|h| h.hit) {
        assert_eq!(instances[h.object as usize].mask, 2, "{h:?}");
    }
}

#[test]
fn rays_aimed_a_millimetre_inside_an_edge_pick_that_triangle_in_a_scene_a_million_metres_wide() {
    // Spheres at the origin and 10⁶ m out: the scene frame's centre is 5·10⁵ m from both, where
    // an f32 offset is good to 3 cm. The ray origin is split in two parts, so each instance's
    // frame is entered to within micrometres and the aimed triangle is the one hit.
    let turn = DMat3::from_rotation_z(0.7) * DMat3::from_diagonal(DVec3::new(1.0, 1.5, 0.8));
    let far = DVec3::new(1.0e6 + 0.37, -3.0e5, 12.0);
    let instances = vec![
        Instance {
            name: "near".into(),
            mesh: 0,
            transform: transform(DMat3::IDENTITY, DVec3::ZERO),
            mask: u32::MAX,
        },
        Instance {
            name: "far".into(),
            mesh: 0,
            transform: transform(turn, far),
            mask: u32::MAX,
        },
    ];
    let built = Arc::new(
        BuiltScene::instanced(meshes(), instances, &BuildOptions::default()).expect("build"),
    );
    let baked = built.instances().unwrap().baked().unwrap();
    let sphere_triangles = built.instances().unwrap().meshes()[0]
        .scene
        .triangle_count() as u32;
    let mut g = rng(77);
    let mut rays = Vec::new();
    let mut aimed = Vec::new();
    for _ in 0..300 {
        let (object, triangle) = (1u32, g.random_range(0..sphere_triangles));
        let index = baked.global_index(object, triangle).unwrap();
        let [a, b, c] = baked.world_triangle(index);
        let normal = (b - a).cross(c - a).normalize();
        // 1 mm from edge a–b, inside the triangle.
        let height = (b - a).cross(c - a).length() / (b - a).length();
        let (u, v) = (g.random_range(0.2..0.6), 0.001 / height);
        let target = a + (b - a) * u + (c - a) * v;
        rays.push(raypick::Ray::new(target + normal * 5.0, -normal));
        aimed.push((object, triangle, target));
    }
    for mut picker in [
        Box::new(raypick::CpuPicker::new(built.clone())) as Box<dyn Picker>,
        Box::new(raypick::ReferencePicker::new(built.clone())),
        Box::new(raypick::GpuPicker::new(common::gpu(), built.clone()).unwrap()),
    ] {
        let hits = picker.pick(&rays).unwrap();
        for (hit, &(object, triangle, target)) in hits.iter().zip(&aimed) {
            assert!(hit.hit, "{}: {hit:?}", picker.describe());
            assert_eq!((hit.object, hit.triangle), (object, triangle), "{hit:?}");
            assert!((hit.position - target).length() < 1e-4, "{hit:?} {target}");
        }
    }
}

#[test]
fn pick_scenes_with_a_file_listed_twice_is_instanced_and_writes_the_same_csv_on_every_backend() {
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("instances-cli");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::copy(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/bunny.obj"),
        dir.join("bunny.obj"),
    )
    .unwrap();
    std::fs::write(
        dir.join("scene.json"),
        r#"{"objects": [
            {"file": "bunny.obj", "transform": [[1, 0, 0, 1000000], [0, 1, 0, 2000000], [0, 0, 1, 0]]},
            {"file": "bunny.obj", "transform": [[0, -2, 0, 1000000.5], [2, 0, 0, 2000000], [0, 0, 0.5, 0.1]]},
            {"file": "bunny.obj", "mask": 2, "transform": [[-1, 0, 0, 999999.5], [0, 1, 0, 2000000.25], [0, 0, 1, 0]]}
        ]}"#,
    )
    .unwrap();
    let bin = env!("CARGO_BIN_EXE_raypick");
    let mut first: Option<Vec<u8>> = None;
    for backend in ["cpu", "gpu", "reference"] {
        let out = std::process::Command::new(bin)
            .args(["pick", "--scenes"])
            .arg(dir.join("scene.json"))
            .args(["--backend", backend, "--cull", "back"])
            .env("XDG_RUNTIME_DIR", "/tmp")
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{backend}: {stderr}");
        assert!(
            stderr.contains("3 objects") && stderr.contains("instances of 1 mesh"),
            "{backend}: {stderr}"
        );
        let csv = out.stdout;
        assert!(
            String::from_utf8_lossy(&csv)
                .lines()
                .filter(|l| l.split(',').nth(1) == Some("1"))
                .count()
                > 20,
            "{backend}: no hits"
        );
        match &first {
            None => first = Some(csv),
            Some(want) => assert!(&csv == want, "{backend} writes other CSV than cpu"),
        }
    }
    // Saved by `raypick build` as instances (the bunny once) and picked from the `.rpk`: the
    // same CSV on every backend.
    let rpk = dir.join("scene.rpk");
    let out = std::process::Command::new(bin)
        .args(["build", "--scenes"])
        .arg(dir.join("scene.json"))
        .arg("--out")
        .arg(&rpk)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "build: {stderr}");
    assert!(
        stderr.contains("3 objects (instances of 1 mesh)"),
        "build: {stderr}"
    );
    let one = dir.join("one.rpk");
    let out = std::process::Command::new(bin)
        .args(["build", "--scene"])
        .arg(dir.join("bunny.obj"))
        .arg("--out")
        .arg(&one)
        .output()
        .unwrap();
    assert!(out.status.success());
    let size = |p: &std::path::Path| std::fs::metadata(p).unwrap().len();
    assert!(
        size(&rpk) < size(&one) + 4096,
        "the bunny is saved once: {} bytes against {} for one bunny",
        size(&rpk),
        size(&one)
    );
    for backend in ["cpu", "gpu", "reference"] {
        let out = std::process::Command::new(bin)
            .args(["pick", "--scene"])
            .arg(&rpk)
            .args(["--backend", backend, "--cull", "back"])
            .env("XDG_RUNTIME_DIR", "/tmp")
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{backend} on the .rpk: {stderr}");
        assert!(
            out.stdout == *first.as_ref().unwrap(),
            "{backend} on the .rpk writes other CSV than the description"
        );
    }
}

#[test]
fn a_saved_instanced_scene_loads_as_instances_and_answers_bit_for_bit() {
    use raypick::{CpuPicker, GpuPicker, ReferencePicker, rpk};
    let built = BuiltScene::instanced(
        meshes(),
        random_instances(40, DVec3::new(1e6, -2e6, 50.0), 30.0, 33),
        &BuildOptions::default(),
    )
    .expect("build");
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("instances-rpk");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("scene.rpk");
    rpk::save(&built, &path).unwrap();
    let rays: Vec<raypick::Ray> = mixed_rays(&built.instances().unwrap().baked().unwrap(), 3000, 4)
        .into_iter()
        .map(|(_, r)| r)
        .collect();
    let want = CpuPicker::new(Arc::new(built.clone())).pick(&rays).unwrap();
    // Loaded copied, in place, and from bytes: instances again, the same answers on every path.
    let bytes = std::fs::read(&path).unwrap();
    let loaded = [
        rpk::load(&path).unwrap(),
        unsafe { rpk::load_in_place(&path) }.unwrap(),
        rpk::from_bytes(&path, &bytes).unwrap(),
    ];
    for l in loaded {
        let i = l.instances().expect("loaded as instances");
        assert_eq!(i.meshes().len(), 4);
        assert_eq!(i.instances(), built.instances().unwrap().instances());
        let l = Arc::new(l);
        let cpu = CpuPicker::new(l.clone()).pick(&rays).unwrap();
        let twin = ReferencePicker::new(l.clone()).pick(&rays).unwrap();
        let gpu = GpuPicker::new(common::gpu(), l.clone())
            .unwrap()
            .pick(&rays)
            .unwrap();
        for (name, got) in [("cpu", &cpu), ("reference", &twin), ("gpu", &gpu)] {
            for (k, (a, b)) in got.iter().zip(&want).enumerate() {
                assert!(
                    a.hit == b.hit
                        && a.object == b.object
                        && a.triangle == b.triangle
                        && a.t.to_bits() == b.t.to_bits(),
                    "{name}, ray {k}: {a:?} vs {b:?}"
                );
            }
        }
    }
    // Changed files are refused with a sentence naming what is wrong (checksums resealed, so
    // the structure is what judges them); none panics.
    let payload = |bytes: &[u8], k: usize| {
        // Section k's payload start: walk the section headers.
        let mut at = 32usize;
        let mut start = 0;
        for _ in 0..=k {
            start = (at + 16).next_multiple_of(64);
            let length = u64::from_le_bytes(bytes[start - 8..start].try_into().unwrap()) as usize;
            at = start + length.next_multiple_of(64);
        }
        start
    };
    let inst = payload(&bytes, 0);
    type Change = Box<dyn Fn(&mut Vec<u8>)>;
    let cases: Vec<(&str, Change, &str)> = vec![
        (
            "unknown mesh",
            Box::new(move |b| b[inst..inst + 4].copy_from_slice(&9u32.to_le_bytes())),
            "places mesh 9, but there are 4 meshes",
        ),
        (
            "flags",
            Box::new(move |b| b[inst + 12] = 1),
            "instance 0's flags are 1",
        ),
        (
            "long name",
            Box::new(move |b| b[inst + 8..inst + 12].copy_from_slice(&u32::MAX.to_le_bytes())),
            "instance 0's name runs past the end",
        ),
        (
            "singular transform",
            Box::new(move |b| b[inst + 16..inst + 16 + 96].fill(0)),
            "singular",
        ),
        (
            "truncated",
            Box::new(|b| b.truncate(b.len() - 64)),
            "truncated",
        ),
        (
            "a mesh that is not a scene",
            Box::new(move |b| {
                let mesh = payload(b, 2);
                b[mesh + 100] ^= 0x55;
            }),
            "mesh 0",
        ),
    ];
    for (what, change, says) in cases {
        let mut changed = bytes.clone();
        change(&mut changed);
        rpk::write::reseal(&mut changed);
        let e = rpk::from_bytes(&path, &changed)
            .expect_err(what)
            .to_string();
        assert!(e.contains(says), "{what}: {e}");
        assert!(e.contains("scene.rpk"), "{what}: {e}");
    }
}

#[test]
fn moved_masked_added_and_reshaped_instances_answer_as_the_oracle_with_incremental_gpu_uploads() {
    use raypick::check::compare::differences;
    use raypick::{CpuPicker, GpuPicker, ReferencePicker, Refit};
    let instances = random_instances(30, DVec3::ZERO, 10.0, 21);
    let built = Arc::new(
        BuiltScene::instanced(meshes(), instances, &BuildOptions::default()).expect("build"),
    );
    let mut gpu = GpuPicker::new(common::gpu(), built.clone()).unwrap();
    let mut cpu = CpuPicker::new(built.clone());
    let mut g = rng(5);
    type Edit = Box<dyn FnMut(&mut BuiltScene) -> raypick::Result<Refit>>;
    let far = transform(
        DMat3::from_rotation_x(0.4) * 1.5,
        DVec3::new(3.0, -4.0, 2.0),
    );
    let mut edits: Vec<(&str, Edit)> = vec![
        ("move", Box::new(move |b| b.set_instance_transform(7, far))),
        (
            "mirror",
            Box::new(|b| {
                let mut m = b.instances().unwrap().instances()[3].transform;
                m[0][0] = -m[0][0];
                m[1][0] = -m[1][0];
                m[2][0] = -m[2][0];
                b.set_instance_transform(3, m)
            }),
        ),
        ("mask", Box::new(|b| b.set_instance_mask(11, 0))),
        ("remove", Box::new(|b| b.remove_instance(5))),
        (
            "add",
            Box::new(|b| {
                b.add_instance(Instance {
                    name: "added".into(),
                    mesh: 0,
                    transform: transform(
                        DMat3::from_diagonal(DVec3::new(1.0, 2.0, 0.5)),
                        DVec3::new(-2.0, 1.0, 0.0),
                    ),
                    mask: u32::MAX,
                })
                .map(|_| Refit::Rebuilt)
            }),
        ),
        (
            "reshape",
            Box::new(move |b| {
                let sphere = &b.instances().unwrap().meshes()[0].scene;
                let moved: Vec<DVec3> = sphere
                    .positions()
                    .iter()
                    .map(|p| *p * DVec3::new(1.3, 0.8, 1.0) + DVec3::new(0.0, 0.0, 0.25))
                    .collect();
                b.set_mesh_positions(0, &moved)
            }),
        ),
    ];
    for (name, edit) in &mut edits {
        let refit_gpu = gpu.edit(&mut **edit).unwrap();
        let refit_cpu = cpu.edit(&mut **edit).unwrap();
        assert_eq!(refit_gpu, refit_cpu, "{name}");
        if ["move", "mask", "mirror", "remove"].contains(name) {
            assert_eq!(refit_gpu, Refit::Moved, "{name}");
        }
        if *name == "reshape" {
            assert_eq!(refit_gpu, Refit::Refitted, "{name}");
        }
        let now = gpu.current_scene().unwrap();
        let baked = now.instances().unwrap().baked().unwrap();
        let rays = mixed_rays(&baked, 800, g.random());
        // Fresh pickers on the edited scene against the oracle of its baked copy ...
        assert_query_equivalent(name, now.clone(), &rays, &Query::default());
        // ... and the pickers that were edited in place give the same answers, bit for bit.
        let plain: Vec<raypick::Ray> = rays.iter().map(|(_, r)| *r).collect();
        let reference = ReferencePicker::new(now.clone())
            .query(&plain, &Query::default())
            .unwrap();
        for (path, answers) in [
            ("gpu", gpu.query(&plain, &Query::default()).unwrap()),
            ("cpu", cpu.query(&plain, &Query::default()).unwrap()),
        ] {
            let differ = differences(Mode::Closest, &answers, &reference);
            assert!(
                differ.is_empty(),
                "{name}: the edited {path} picker differs on {} rays",
                differ.len()
            );
        }
    }
    // The masked instance is never hit; the added one is.
    let now = gpu.current_scene().unwrap();
    let baked = now.instances().unwrap().baked().unwrap();
    let hits = cpu
        .pick(
            &mixed_rays(&baked, 2000, 9)
                .into_iter()
                .map(|(_, r)| r)
                .collect::<Vec<_>>(),
        )
        .unwrap();
    assert!(hits.iter().all(|h| !h.hit || h.object != 11));
    assert!(hits.iter().all(|h| !h.hit || h.object != 5));
    assert!(hits.iter().any(|h| h.hit && h.object == 30));
    // The removed instance left the top tree when the addition laid it out; the hidden one
    // stays in it, to be shown again.
    let instances = now.instances().unwrap();
    assert_eq!(instances.leaf_of(5), u32::MAX);
    assert_ne!(instances.leaf_of(11), u32::MAX);
    assert!(instances.is_removed(5) && !instances.is_removed(11));
    // A removed instance cannot be shown, moved or removed again; a hidden one can be shown.
    let far = transform(DMat3::IDENTITY, DVec3::ONE);
    let mut refusals: Vec<Edit> = vec![
        Box::new(|b| b.set_instance_mask(5, 1)),
        Box::new(move |b| b.set_instance_transform(5, far)),
        Box::new(|b| b.remove_instance(5)),
    ];
    for edit in &mut refusals {
        let e = cpu.edit(&mut **edit).unwrap_err().to_string();
        assert!(e.contains("instance 5 was removed"), "{e}");
    }
    assert_eq!(
        cpu.edit(&mut |b| b.set_instance_mask(11, u32::MAX))
            .unwrap(),
        Refit::Moved
    );
}

/// Instances added and removed over a scene's life: each removed one is left out of the next
/// layout's top tree (it stayed in it, hidden, so the top tree and each addition's time grew
/// with every instance ever added; found by a soak of the server's edits). With every instance
/// removed the top tree is empty and every path misses; an instance added then is hit, as the
/// oracle says.
#[test]
fn removed_instances_leave_the_top_tree_and_every_path_still_answers_as_the_oracle() {
    use raypick::{CpuPicker, GpuPicker, Refit};
    let instances = random_instances(12, DVec3::ZERO, 10.0, 33);
    let built = Arc::new(
        BuiltScene::instanced(meshes(), instances, &BuildOptions::default()).expect("build"),
    );
    let leaves = |b: &BuiltScene| {
        let i = b.instances().unwrap();
        (0..i.instances().len())
            .filter(|&k| i.leaf_of(k) != u32::MAX)
            .count()
    };
    let full = leaves(&built);
    let mut gpu = GpuPicker::new(common::gpu(), built.clone()).unwrap();
    let mut cpu = CpuPicker::new(built);
    let mut g = rng(8);
    for k in 0..12 {
        for picker in [&mut gpu as &mut dyn raypick::Picker, &mut cpu] {
            assert_eq!(
                picker.edit(&mut |b| b.remove_instance(k)).unwrap(),
                Refit::Moved
            );
        }
        if k == 5 {
            // Half removed, then the top tree laid out again: only the rest are in it, and the
            // hit ids run over their triangles only.
            let before = gpu.current_scene().unwrap().world_triangle_count();
            for picker in [&mut gpu as &mut dyn raypick::Picker, &mut cpu] {
                picker
                    .edit(&mut |b| b.rebuild_top().map(|_| Refit::Rebuilt))
                    .unwrap();
            }
            let now = gpu.current_scene().unwrap();
            assert_eq!(leaves(&now), full - 6);
            let i = now.instances().unwrap();
            let left: u64 = (6..12)
                .map(|k| {
                    i.meshes()[i.instances()[k].mesh as usize]
                        .scene
                        .triangle_count() as u64
                })
                .sum();
            assert!(left < before);
            assert_eq!(now.world_triangle_count(), left);
        }
        let now = gpu.current_scene().unwrap();
        let baked = now.instances().unwrap().baked().unwrap();
        let rays = mixed_rays(&baked, 400, g.random());
        assert_query_equivalent("removed", now, &rays, &Query::default());
    }
    // Nothing left to hit: no bounds, and after the next layout no top tree and no hit ids.
    assert_eq!(
        gpu.current_scene().unwrap().instances().unwrap().bounds(),
        None
    );
    for picker in [&mut gpu as &mut dyn raypick::Picker, &mut cpu] {
        picker
            .edit(&mut |b| b.rebuild_top().map(|_| Refit::Rebuilt))
            .unwrap();
    }
    let now = gpu.current_scene().unwrap();
    assert_eq!(leaves(&now), 0);
    assert_eq!(now.world_triangle_count(), 0);
    // A mesh reshaped then (the combined tree holds none to write in place: it panicked).
    let reshaped: Vec<DVec3> = now.instances().unwrap().meshes()[0]
        .scene
        .positions()
        .iter()
        .map(|p| *p * 1.1)
        .collect();
    for picker in [&mut gpu as &mut dyn raypick::Picker, &mut cpu] {
        let reshaped = reshaped.clone();
        picker
            .edit(&mut move |b| b.set_mesh_positions(0, &reshaped))
            .unwrap();
    }
    let rays: Vec<raypick::Ray> = (0..200)
        .map(|k| raypick::Ray::new(DVec3::new(-30.0, f64::from(k) * 0.1 - 10.0, 0.5), DVec3::X))
        .collect();
    for (path, hits) in [("gpu", gpu.pick(&rays)), ("cpu", cpu.pick(&rays))] {
        assert!(hits.unwrap().iter().all(|h| !h.hit), "{path}");
    }
    let added = Instance {
        name: "after".into(),
        mesh: 0,
        transform: transform(DMat3::IDENTITY, DVec3::ZERO),
        mask: u32::MAX,
    };
    for picker in [&mut gpu as &mut dyn raypick::Picker, &mut cpu] {
        let added = added.clone();
        picker
            .edit(&mut move |b| b.add_instance(added.clone()).map(|_| Refit::Rebuilt))
            .unwrap();
    }
    let now = gpu.current_scene().unwrap();
    assert_eq!(leaves(&now), 1);
    let baked = now.instances().unwrap().baked().unwrap();
    let rays = mixed_rays(&baked, 400, 77);
    assert_query_equivalent("added after", now, &rays, &Query::default());
    let through: Vec<raypick::Ray> = vec![raypick::Ray::new(DVec3::new(-30.0, 0.0, 0.0), DVec3::X)];
    for (path, hits) in [("gpu", gpu.pick(&through)), ("cpu", cpu.pick(&through))] {
        let hits = hits.unwrap();
        assert!(hits[0].hit && hits[0].object == 12, "{path}: {:?}", hits[0]);
    }
}

/// A large instance moved far out, where the frame it keeps resolves it, then a small one added
/// beside the first: a frame centred on bounds that now reach 10¹² would round the small ones'
/// rays to 16 units, so the scene keeps its frame (the addition was once refused for it, naming
/// an instance it had not touched), and every path answers as the oracle on the small ones; a
/// rebuilt top tree keeps the frame too.
#[test]
fn after_a_far_move_additions_and_rebuilds_keep_a_frame_that_resolves_every_instance() {
    let placed = |scale: f64, x: f64| {
        transform(
            DMat3::from_diagonal(DVec3::splat(scale)),
            DVec3::new(x, 0.0, 0.0),
        )
    };
    let instance = |name: &str, transform| Instance {
        name: name.into(),
        mesh: 1,
        transform,
        mask: u32::MAX,
    };
    let mut built = BuiltScene::instanced(
        meshes(),
        vec![
            instance("small", placed(1.0, 0.0)),
            instance("large", placed(1000.0, 5000.0)),
        ],
        &BuildOptions::default(),
    )
    .expect("build");
    let origin = built.instances().unwrap().origin();
    built
        .set_instance_transform(1, placed(1000.0, 1e12))
        .expect("the large box is resolved where it goes");
    let added = built
        .add_instance(instance("added", placed(1.0, 10.0)))
        .expect("the small box is added beside the first");
    assert_eq!(added, 2);
    assert_eq!(built.instances().unwrap().origin(), origin);
    assert!(built.instances().unwrap().unresolved().is_empty());
    built.rebuild_top().unwrap();
    assert_eq!(built.instances().unwrap().origin(), origin);
    assert!(built.instances().unwrap().unresolved().is_empty());
    // Rays of every kind aimed at the two small boxes (made over a scene of them alone).
    let near = BuiltScene::instanced(
        meshes(),
        vec![
            instance("small", placed(1.0, 0.0)),
            instance("added", placed(1.0, 10.0)),
        ],
        &BuildOptions::default(),
    )
    .unwrap();
    let rays = mixed_rays(&near.instances().unwrap().baked().unwrap(), 800, 17);
    let built = Arc::new(built);
    for query in queries() {
        let answers = assert_query_equivalent("kept frame", built.clone(), &rays, &query);
        for object in [0, 2] {
            assert!(
                answers.nearest.iter().any(|h| h.hit && h.object == object),
                "instance {object} is hit"
            );
        }
    }
}

#[test]
fn camera_rays_on_instances_give_the_twins_answers_with_packets_asked_for_or_not() {
    // The instanced walk goes ray by ray (an 8-ray packet walk of both levels measured no faster
    // on the 10,000-bunny field: 7.9–8.2 M rays/s either way, and was taken out).
    use raypick::apps::camera::Camera;
    use raypick::check::compare::differences;
    use raypick::engine::Simd;
    use raypick::{CpuPicker, ReferencePicker};
    let built = Arc::new(
        BuiltScene::instanced(
            meshes(),
            random_instances(40, DVec3::ZERO, 12.0, 31),
            &BuildOptions::default(),
        )
        .unwrap(),
    );
    let (lo, hi) = built.bounds().unwrap();
    let rays: Vec<raypick::Ray> = Camera::frame_from_above(lo, hi, 96, 96)
        .pixel_center_rays()
        .collect();
    for query in queries() {
        let reference = ReferencePicker::new(built.clone())
            .query(&rays, &query)
            .unwrap();
        assert!(reference.nearest.iter().filter(|h| h.hit).count() > 1000);
        for (simd, packets) in [
            (Simd::best_available(), true),
            (Simd::best_available(), false),
            (Simd::Portable, true),
        ] {
            let mut engine = CpuPicker::new(built.clone());
            engine.set_simd(simd);
            engine.set_packets(packets);
            let answers = engine.query(&rays, &query).unwrap();
            let differ = differences(query.mode, &answers, &reference);
            assert!(
                differ.is_empty(),
                "{query:?} {simd:?} packets {packets}: {} rays differ",
                differ.len()
            );
        }
    }
}

#[test]
fn the_kernels_own_exact_arithmetic_gives_the_twins_bits_on_lavapipe_too() {
    // On llvmpipe the kernel uses the hardware's division and products (already rounded as the
    // CPU rounds them); every other adapter runs the kernel's own exactly rounded division and
    // unfused products, which made an NVIDIA H200 give the twin's bits. Here that path runs on
    // lavapipe, against the twin, on a plain scene and an instanced one.
    use raypick::check::compare::differences;
    use raypick::{GpuPicker, ReferencePicker};
    let bunny = raypick::io::obj::load_obj(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/bunny.obj")
            .as_path(),
    )
    .unwrap();
    let plain = Arc::new(
        BuiltScene::new(
            Scene::from_meshes([("bunny".to_string(), bunny)]).unwrap(),
            &BuildOptions::default(),
        )
        .unwrap(),
    );
    let instanced = Arc::new(
        BuiltScene::instanced(
            meshes(),
            random_instances(20, DVec3::new(1.0e6, 0.0, 5.0), 10.0, 8),
            &BuildOptions::default(),
        )
        .unwrap(),
    );
    for (name, built) in [("bunny", plain), ("instances", instanced)] {
        let world = match built.instances() {
            Some(i) => i.baked().unwrap(),
            None => built.scene.clone(),
        };
        let rays: Vec<raypick::Ray> = mixed_rays(&world, 1600, 13)
            .into_iter()
            .map(|(_, r)| r)
            .collect();
        let mut exact = GpuPicker::with_options(common::gpu(), built.clone(), 64, true).unwrap();
        for query in queries() {
            let reference = ReferencePicker::new(built.clone())
                .query(&rays, &query)
                .unwrap();
            let answers = exact.query(&rays, &query).unwrap();
            let differ = differences(query.mode, &answers, &reference);
            assert!(
                differ.is_empty(),
                "{name} {query:?}: the exact kernel differs from the twin on {} rays",
                differ.len()
            );
        }
    }
}

/// Grazing rays over a finely gridded terrain near the origin, with another instance 10⁴ units
/// out (the scene frame's centre half way, so each ray enters the terrain from an origin split in
/// an f32 part and a half-float rest): every path answers as the oracle. The rests were kept
/// only when normal, so a quarter of them (those under 2^-14, about 6·10⁻⁵) were dropped, and
/// such rays met a triangle beside the one they cross (found by a helper's fuzzing: `raypick
/// verify --scenes` on a grid turned and placed near the origin beside a copy 10⁴ out).
#[test]
fn grazing_rays_enter_an_instance_half_a_frame_from_its_centre_with_their_whole_origin() {
    let fine = mesh_scene(
        "fine terrain",
        terrain(41, 41, 0.0, 1.0, 0.025, |x, y| {
            0.2 * (3.0 * x).sin() * (2.0 * y).cos() + 0.9 * x
        }),
        Some((41, 41)),
    );
    let turn = DMat3::from_rotation_z(0.7);
    let far_turn = DMat3::from_rotation_z(2.0) * DMat3::from_rotation_x(0.3);
    let instances = vec![
        Instance {
            name: "near".to_string(),
            mesh: 0,
            transform: transform(turn, DVec3::new(1.5, 0.0, 0.0)),
            mask: 1,
        },
        Instance {
            name: "far".to_string(),
            mesh: 0,
            transform: transform(far_turn, DVec3::new(1.0e4, 1.0e4, -1.0e4)),
            mask: 1,
        },
    ];
    let built = Arc::new(
        BuiltScene::instanced(vec![fine], instances, &BuildOptions::default()).expect("build"),
    );
    let baked = built.instances().unwrap().baked().unwrap();
    // Rays skimming the near terrain: from just above a point of its surface, nearly level,
    // across the slope.
    let mut g = rng(21);
    let near: Vec<raypick::Ray> = {
        let tri = baked.triangles();
        let pos = baked.positions();
        let near_triangles = tri.len() / 2;
        (0..6000)
            .map(|_| {
                let t = tri[g.random_range(0..near_triangles)];
                let (a, b, c) = (pos[t[0] as usize], pos[t[1] as usize], pos[t[2] as usize]);
                let (u, v) = (g.random_range(0.0..0.5), g.random_range(0.0..0.5));
                let on = a + (b - a) * u + (c - a) * v;
                let up = g.random_range(1e-4..2e-2);
                let heading = g.random_range(0.0..std::f64::consts::TAU);
                let dir = DVec3::new(heading.cos(), heading.sin(), g.random_range(-0.05..0.0));
                raypick::Ray::new(on + DVec3::new(0.0, 0.0, up) - dir * 0.3, dir)
            })
            .collect()
    };
    let rays: Vec<_> = near.into_iter().map(|r| (RayKind::Grazing, r)).collect();
    assert_query_equivalent("grazing", built, &rays, &Query::default());
}

/// The bounds of what can be hit, after any sequence of moves, hides and shows (far out and
/// back, rotated, tied on a side with others), are those of the same instances assembled
/// afresh: a move that leaves the bounds' edge works them out again from the top tree's leaf
/// boxes and a few exact boxes (`Instances::set_transform`), and a hidden instance's leaf
/// follows its moves.
#[test]
fn bounds_after_moves_and_masks_are_those_of_a_fresh_assembly() {
    let meshes = meshes();
    let mut g = rng(31);
    let mut placed: Vec<Instance> = (0..8)
        .map(|k| Instance {
            name: format!("i{k}"),
            mesh: (k % meshes.len()) as u32,
            transform: transform(DMat3::IDENTITY, DVec3::new(k as f64 * 6.0, 0.0, 0.0)),
            mask: u32::MAX,
        })
        .collect();
    let options = BuildOptions::default();
    let mut built = BuiltScene::instanced(meshes.clone(), placed.clone(), &options).unwrap();
    for step in 0..300 {
        let k = g.random_range(0..placed.len());
        match g.random_range(0..4) {
            0 => {
                let mask = if placed[k].mask == 0 { u32::MAX } else { 0 };
                if mask == 0 && placed.iter().filter(|p| p.mask != 0).count() == 1 {
                    continue;
                }
                placed[k].mask = mask;
                built.set_instance_mask(k as u32, mask).unwrap();
            }
            kind => {
                let at = match kind {
                    // Far out along x, either way.
                    1 => DVec3::new(g.random_range(-1.0..1.0) * 1e5, 0.0, 0.0),
                    // Back on the row, on the ground (a side tied with others).
                    2 => DVec3::new(g.random_range(0..8) as f64 * 6.0, 0.0, 0.0),
                    _ => DVec3::new(
                        g.random_range(-30.0..60.0),
                        g.random_range(-20.0..20.0),
                        g.random_range(-5.0..5.0),
                    ),
                };
                let turn = DMat3::from_rotation_z(g.random_range(0.0..6.3));
                placed[k].transform = transform(turn, at);
                built
                    .set_instance_transform(k as u32, placed[k].transform)
                    .unwrap();
            }
        }
        let fresh = BuiltScene::instanced(meshes.clone(), placed.clone(), &options).unwrap();
        assert_eq!(built.bounds(), fresh.bounds(), "step {step}");
    }
}

/// Found by a fuzz of edit sequences: reshaping a mesh added after the scene was laid out, and
/// not yet placed by any instance, indexed the combined tree's record of its nodes, which it is
/// not in: a panic, with the mesh already reshaped. It is now reshaped alone (nothing else
/// holds it), and an instance placing it afterwards picks it reshaped, on every path.
#[test]
fn a_mesh_no_instance_places_yet_is_reshaped_and_placed_as_reshaped() {
    use raypick::{CpuPicker, GpuPicker, ReferencePicker, Refit};
    let built = BuiltScene::instanced(
        meshes(),
        random_instances(6, DVec3::ZERO, 8.0, 3),
        &BuildOptions::default(),
    )
    .expect("build");
    let mut gpu = GpuPicker::new(common::gpu(), Arc::new(built)).unwrap();
    let mut cpu = CpuPicker::new(gpu.current_scene().unwrap());
    let sphere = icosphere(DVec3::ZERO, 1.0, 1);
    let doubled: Vec<DVec3> = sphere.positions.iter().map(|p| *p * 2.0).collect();
    let mut added = None;
    for picker in [&mut gpu as &mut dyn Picker, &mut cpu] {
        let sphere = mesh_scene("added", sphere.clone(), None);
        let mut mesh = 0;
        picker
            .edit(&mut |b: &mut BuiltScene| {
                mesh = b.add_mesh(sphere.clone())?;
                Ok(Refit::Moved)
            })
            .unwrap();
        let refit = picker
            .edit(&mut |b: &mut BuiltScene| b.set_mesh_positions(mesh, &doubled))
            .unwrap();
        assert_eq!(refit, Refit::Refitted);
        let place = Instance {
            name: "placed".into(),
            mesh,
            transform: transform(DMat3::IDENTITY, DVec3::new(0.0, 0.0, 20.0)),
            mask: u32::MAX,
        };
        picker
            .edit(&mut |b: &mut BuiltScene| b.add_instance(place.clone()).map(|_| Refit::Rebuilt))
            .unwrap();
        added = Some(mesh);
    }
    let now = gpu.current_scene().unwrap();
    let placed = &now.instances().unwrap().meshes()[added.unwrap() as usize].scene;
    assert_eq!(
        placed.positions(),
        &doubled[..],
        "the reshaped mesh is placed"
    );
    // A ray down onto the placed sphere meets it 2 units above its centre, not 1.
    let down = [raypick::Ray::new(DVec3::new(0.0, 0.0, 40.0), DVec3::NEG_Z)];
    for (path, hits) in [
        ("gpu", gpu.pick(&down).unwrap()),
        ("cpu", cpu.pick(&down).unwrap()),
        (
            "reference",
            ReferencePicker::new(now.clone()).pick(&down).unwrap(),
        ),
    ] {
        assert!(hits[0].hit, "{path}");
        assert!(
            (hits[0].position.z - 22.0).abs() < 0.2,
            "{path}: {:?}",
            hits[0].position
        );
    }
    let baked = now.instances().unwrap().baked().unwrap();
    assert_query_equivalent(
        "reshaped, then placed",
        now,
        &mixed_rays(&baked, 600, 4),
        &Query::default(),
    );
}

/// Found by a fuzz of edit sequences: one of two spheres moved 10⁹ out, an instance added (the
/// frame re-centred half way, 5 × 10⁸ out), then the sphere moved back: every move was a refit
/// of the top tree, so the rays of the spheres, now both near the origin, were rounded at the
/// far centre's steps (23 of 4,000 rays against the oracle; a fresh build 0). A move that takes
/// the scene away from the frame now lays the top tree out again about it.
#[test]
fn a_move_back_from_far_out_lays_the_top_tree_out_about_the_scene() {
    use raypick::{CpuPicker, GpuPicker, Refit};
    let sphere = || mesh_scene("sphere", icosphere(DVec3::ZERO, 1.0, 3), None);
    let at = |x: f64| transform(DMat3::IDENTITY, DVec3::new(x, 0.0, 0.0));
    let placed = |name: &str, x: f64| Instance {
        name: name.into(),
        mesh: 0,
        transform: at(x),
        mask: u32::MAX,
    };
    for far in [1e8, 1e9] {
        let built = BuiltScene::instanced(
            vec![sphere()],
            vec![placed("a", 0.0), placed("b", 3.0)],
            &BuildOptions::default(),
        )
        .expect("build");
        let mut gpu = GpuPicker::new(common::gpu(), Arc::new(built)).unwrap();
        let mut cpu = CpuPicker::new(gpu.current_scene().unwrap());
        for picker in [&mut gpu as &mut dyn Picker, &mut cpu] {
            let moved = picker.edit(&mut |b: &mut BuiltScene| b.set_instance_transform(1, at(far)));
            assert_eq!(moved.unwrap(), Refit::Moved, "out to {far:e}");
            picker
                .edit(&mut |b: &mut BuiltScene| {
                    b.add_instance(placed("c", far + 3.0))
                        .map(|_| Refit::Rebuilt)
                })
                .unwrap();
            // Back, and the far one moved next to the others too.
            let back = picker.edit(&mut |b: &mut BuiltScene| b.set_instance_transform(1, at(3.0)));
            assert_eq!(
                back.unwrap(),
                Refit::Moved,
                "back from {far:e}: the far one still there"
            );
            let home = picker.edit(&mut |b: &mut BuiltScene| b.set_instance_transform(2, at(6.0)));
            assert_eq!(home.unwrap(), Refit::Rebuilt, "all home from {far:e}");
        }
        let now = gpu.current_scene().unwrap();
        let origin = now.instances().unwrap().origin();
        assert!(
            origin.length() < 10.0,
            "{far:e}: the frame stayed at {origin}"
        );
        let baked = now.instances().unwrap().baked().unwrap();
        let rays = mixed_rays(&baked, 2000, 7);
        assert_query_equivalent(&format!("home from {far:e}"), now, &rays, &Query::default());
        let plain: Vec<raypick::Ray> = rays.iter().map(|(_, r)| *r).collect();
        let (on_gpu, on_cpu) = (
            gpu.query(&plain, &Query::default()).unwrap(),
            cpu.query(&plain, &Query::default()).unwrap(),
        );
        let differ = raypick::check::compare::differences(Mode::Closest, &on_gpu, &on_cpu);
        assert!(differ.is_empty(), "{far:e}: {} rays differ", differ.len());
    }
}

/// Found by a review: a mesh's vertices moved 10⁹ out were refitted in the mesh's own frame,
/// centred where they had been, so its triangles were rounded at that far frame's steps (220
/// of 400 rays differed from a fresh build). The mesh's tree is now built again about where it
/// lies, as a plain scene's is.
#[test]
fn a_mesh_moved_far_from_its_frame_is_built_again_about_it() {
    use raypick::Refit;
    // A grid of 100-unit cells: at 10⁹ out its f32 steps (64 units) leave every triangle some
    // area, so the refit alone would not see a change.
    let grid = terrain(11, 11, 0.0, 0.0, 100.0, |x, y| hills(x, y) * 50.0);
    let placed = Instance {
        name: "a".into(),
        mesh: 0,
        transform: transform(DMat3::IDENTITY, DVec3::ZERO),
        mask: u32::MAX,
    };
    for (far, expected) in [(1e9, Refit::Rebuilt), (50.0, Refit::Refitted)] {
        let mut built = BuiltScene::instanced(
            vec![mesh_scene("grid", grid.clone(), None)],
            vec![placed.clone()],
            &BuildOptions::default(),
        )
        .expect("build");
        let moved: Vec<DVec3> = grid.positions.iter().map(|p| *p + DVec3::X * far).collect();
        assert_eq!(
            built.set_mesh_positions(0, &moved).unwrap(),
            expected,
            "{far:e}"
        );
        let baked = built.instances().unwrap().baked().unwrap();
        let rays = mixed_rays(&baked, 800, 5);
        assert_query_equivalent(
            &format!("moved {far:e}"),
            Arc::new(built),
            &rays,
            &Query::default(),
        );
    }
}
