//! The CPU engine (`--backend cpu`): its wide tree is the binary tree regrouped, and under the
//! tie rule every builder and every backend gives the same answers, bit for bit. (The engine
//! against the twin, the GPU and the oracle on every scene, ray kind and mode runs in
//! `tests/suite/common`'s equivalence check, used by `equivalence.rs` and `modes.rs`.)

use crate::common;

use raypick::check::compare::differences;
use raypick::check::synthetic::{
    RayKind, hills, icosphere, mixed_rays, rays, terrain, triangle_soup,
};
use raypick::engine::wide::{EMPTY, INNER, WIDTH, WideNode};
use raypick::engine::{Simd, WideBvh};
use raypick::instance::Instance;
use raypick::io::scene_files::{SceneFile, load_scene};
use raypick::{
    Answers, BuildOptions, Builder, BuiltScene, CpuPicker, DVec3, GpuPicker, Intersector, Mesh,
    Mode, Picker, Query, Ray, ReferencePicker, Scene,
};
use std::path::Path;
use std::sync::Arc;

fn dem() -> Scene {
    load_scene(&[SceneFile {
        file: Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/jacksboro_fault_dem_utm.asc"),
        mask: None,
        transform: None,
    }])
    .expect("the Jacksboro DEM loads")
}

fn bunny() -> Scene {
    load_scene(&[SceneFile {
        file: Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/bunny.obj"),
        mask: None,
        transform: None,
    }])
    .expect("the bunny loads")
}

fn with(builder: Builder, leaf_size: u32) -> BuildOptions {
    BuildOptions {
        builder,
        leaf_size,
        ..BuildOptions::default()
    }
}

/// Every child of every wide node: its boxes and what it points to.
fn walk(wide: &WideBvh, node: u32, leaves: &mut Vec<(u32, u32)>, depth: usize) -> usize {
    let n: &WideNode = &wide.nodes[node as usize];
    let mut deepest = depth;
    for lane in 0..WIDTH {
        match n.kind[lane] {
            EMPTY => {}
            INNER => deepest = deepest.max(walk(wide, n.child[lane], leaves, depth + 1)),
            count => leaves.push((n.child[lane], u32::from(count))),
        }
    }
    deepest
}

#[test]
fn the_wide_tree_holds_every_leaf_of_the_binary_tree_once() {
    for (name, scene, options) in [
        ("bunny median cut", bunny(), with(Builder::MedianCut, 8)),
        ("bunny sah leaf 1", bunny(), with(Builder::BinnedSah, 1)),
        ("dem grid", dem(), with(Builder::Grid, 8)),
    ] {
        let built = BuiltScene::new(scene, &options).unwrap();
        let wide = WideBvh::collapse(&built.bvh).unwrap();
        let mut leaves = Vec::new();
        let depth = walk(&wide, 0, &mut leaves, 1);
        assert_eq!(depth, wide.depth, "{name}: recorded depth");
        let mut binary: Vec<(u32, u32)> = built
            .bvh
            .nodes
            .iter()
            .filter(|n| n.is_leaf())
            .map(|n| (n.first, n.kind()))
            .collect();
        leaves.sort_unstable();
        binary.sort_unstable();
        assert_eq!(leaves, binary, "{name}: the same leaves");
        // Each wide node stands for a distinct binary inner node (and opens up to seven).
        let inner = built.bvh.nodes.len() - binary.len();
        assert!(
            wide.nodes.len() <= inner,
            "{name}: {} nodes",
            wide.nodes.len()
        );
        // The engine's own memory at the default leaf size (it reads the shared triangles).
        let per_triangle = wide.bytes() as f64 / built.bvh.triangles.len() as f64;
        if options.leaf_size >= 8 {
            assert!(per_triangle <= 40.0, "{name}: {per_triangle} B/triangle");
        }
    }
}

fn answers(picker: &mut dyn Picker, rays: &[Ray], query: &Query) -> Answers {
    picker.query(rays, query).expect("query")
}

fn assert_same(what: &str, mode: Mode, a: &Answers, b: &Answers, rays: &[Ray]) {
    let differ = differences(mode, a, b);
    assert!(
        differ.is_empty(),
        "{what}: {} rays differ, first {:?}:\n  {:?}\n  {:?}",
        differ.len(),
        rays[differ[0]],
        a.hits_of(differ[0]),
        b.hits_of(differ[0])
    );
}

/// `query`'s answers for `rays` on the twin, which the engine (on AVX2 and on its portable
/// lanes) and the GPU must give bit for bit.
fn every_path(what: &str, built: &Arc<BuiltScene>, rays: &[Ray], query: &Query) -> Answers {
    let twin = answers(&mut ReferencePicker::new(built.clone()), rays, query);
    for simd in [Simd::Avx2, Simd::Portable] {
        let mut engine = CpuPicker::new(built.clone());
        engine.set_simd(simd);
        let got = answers(&mut engine, rays, query);
        assert_same(
            &format!("{what} {simd:?}/twin"),
            query.mode,
            &got,
            &twin,
            rays,
        );
    }
    let mut gpu = GpuPicker::new(common::gpu(), built.clone()).unwrap();
    let got = answers(&mut gpu, rays, query);
    assert_same(&format!("{what} gpu/twin"), query.mode, &got, &twin, rays);
    twin
}

/// [`every_path`] on `scene` built by each of `builds`, whose answers must all be the first's.
fn every_builder(name: &str, scene: &Scene, builds: &[BuildOptions], rays: &[Ray], query: &Query) {
    let mut first: Option<Answers> = None;
    for options in builds {
        let built = Arc::new(BuiltScene::new(scene.clone(), options).unwrap());
        let what = format!("{name} {:?} leaf {}", options.builder, options.leaf_size);
        let twin = every_path(&what, &built, rays, query);
        match &first {
            None => first = Some(twin),
            Some(f) => assert_same(
                &format!("{what} against the first builder"),
                query.mode,
                &twin,
                f,
                rays,
            ),
        }
    }
}

/// The tie rule makes the answer independent of the tree: median cut, binned SAH and the grid
/// builder, at several leaf sizes, on the engine, the twin and the GPU, give the same bits in
/// closest and all-hits modes, edge and vertex rays included.
#[test]
fn every_builder_and_backend_gives_the_same_bits() {
    let queries = [
        Query::default(),
        Query {
            mode: Mode::All,
            max_hits: 5,
            ..Query::default()
        },
    ];
    let dem = dem();
    let cases: Vec<(&str, Scene, Vec<BuildOptions>)> = vec![
        (
            "dem",
            dem.clone(),
            vec![
                with(Builder::Grid, 8),
                with(Builder::MedianCut, 8),
                with(Builder::BinnedSah, 8),
                with(Builder::MedianCut, 1),
                with(Builder::Grid, 3),
            ],
        ),
        (
            "bunny",
            bunny(),
            vec![
                with(Builder::MedianCut, 8),
                with(Builder::BinnedSah, 4),
                with(Builder::MedianCut, 15),
            ],
        ),
        (
            "terrain",
            Scene::from_meshes([(
                "terrain".to_string(),
                terrain(24, 24, 0.0, 23.0, 1.0, hills),
            )])
            .unwrap(),
            vec![
                with(Builder::MedianCut, 2),
                with(Builder::BinnedSah, 8),
                with(Builder::MedianCut, 8),
            ],
        ),
    ];
    for (name, scene, builds) in cases {
        let rays: Vec<Ray> = mixed_rays(&scene, 1600, 5)
            .into_iter()
            .map(|(_, r)| r)
            .collect();
        for query in &queries {
            every_builder(name, &scene, &builds, &rays, query);
        }
    }
}

/// Larger batches than the equivalence suites use (the engine's per-task chunks, the ray
/// reordering from 65,536 rays, camera rays traced as packets of eight), on every lane kind, with
/// and without packets, incoherent rays interleaved and one by one, in every mode.
#[test]
fn large_batches_on_every_lane_kind_and_walk_match_the_twin() {
    let scene = Scene::from_meshes([("soup".to_string(), triangle_soup(20_000, 50.0, 3))]).unwrap();
    let built = Arc::new(BuiltScene::new(scene, &BuildOptions::default()).unwrap());
    let mut batch = rays(&built.scene, RayKind::Camera, 30_000, 9);
    batch.extend(rays(&built.scene, RayKind::Random, 40_000, 9));
    let queries = [
        Query::default(),
        Query {
            mode: Mode::Any,
            ..Query::default()
        },
        Query {
            mode: Mode::All,
            max_hits: 3,
            cull: raypick::Cull::Back,
            ..Query::default()
        },
        Query {
            intersector: raypick::Intersector::MollerTrumbore,
            ..Query::default()
        },
    ];
    for query in queries {
        let twin = answers(&mut ReferencePicker::new(built.clone()), &batch, &query);
        assert!(twin.nearest.iter().filter(|h| h.hit).count() > 10_000);
        for simd in [Simd::Avx2, Simd::Sse, Simd::Portable] {
            if !simd.is_available() {
                continue;
            }
            for (packets, interleave) in [(true, true), (true, false), (false, true)] {
                let mut engine = CpuPicker::new(built.clone());
                engine.set_simd(simd);
                engine.set_packets(packets);
                engine.set_interleave(Some(interleave));
                let got = answers(&mut engine, &batch, &query);
                let what = format!(
                    "{} packets {packets} interleave {interleave} {query:?}",
                    simd.name()
                );
                assert_same(&what, query.mode, &got, &twin, &batch);
            }
        }
    }
}

/// A box `long` units along x, one unit across, its far end one unit higher (the end faces
/// stay square): at 32,768 its long faces are triangles 32,768 times longer than wide (a
/// fuzzed file's shape).
fn long_box(long: f64) -> Scene {
    let p = |x: f64, y: f64, z: f64| DVec3::new(x * long, y, 3.0 + z + x);
    let positions = vec![
        p(0.0, 0.0, 0.0),
        p(1.0, 0.0, 0.0),
        p(0.0, 1.0, 0.0),
        p(1.0, 1.0, 0.0),
        p(0.0, 0.0, 1.0),
        p(1.0, 0.0, 1.0),
        p(0.0, 1.0, 1.0),
        p(1.0, 1.0, 1.0),
    ];
    // The fuzzed file's faces (1-based there): two triangles per side.
    let faces = [
        [1, 2, 4],
        [1, 4, 3],
        [5, 7, 8],
        [5, 8, 6],
        [1, 5, 6],
        [1, 6, 2],
        [3, 4, 8],
        [3, 8, 7],
        [1, 3, 7],
        [1, 7, 5],
        [2, 6, 8],
        [2, 8, 4],
    ];
    let mesh = Mesh {
        positions,
        triangles: faces.iter().map(|f| f.map(|i| i - 1)).collect(),
    };
    Scene::from_meshes([("long box".to_string(), mesh)]).unwrap()
}

/// Rays that start close to a face, or meet long thin triangles end on, found a triangle whose
/// f32 t fell before the padded near end of a box holding it; whether such a triangle was then
/// tested depended on what the walk had met first, so the engine and the twin (and different
/// trees) answered differently (4 of these 32,768 rays on the engine against the twin). Each
/// hit's t is now kept within the ray's interval over its triangle's own box
/// (`ray_box::hit_t`): the same bits everywhere.
#[test]
fn long_thin_triangles_and_near_starts_give_the_same_bits_on_every_walk() {
    let scene = long_box(32768.0);
    let rays: Vec<Ray> = mixed_rays(&scene, 32768, 1)
        .into_iter()
        .map(|(_, r)| r)
        .collect();
    for query in [
        Query::default(),
        Query {
            mode: Mode::All,
            max_hits: 3,
            ..Query::default()
        },
    ] {
        let builds = [
            with(Builder::MedianCut, 8),
            with(Builder::MedianCut, 1),
            with(Builder::BinnedSah, 2),
        ];
        every_builder("long box", &scene, &builds, &rays, &query);
    }
}

/// Five instances of one cube in one place: every hit is a tie between five instances, which
/// the lowest id must win whatever the walk. A grazing ray's hit in the first instance walked
/// fell before the padded near end of the others' boxes, and the twin and the kernel answered
/// with another instance (2 of these 20,000 rays on the engine against the twin). Each
/// instance's hits are now kept within the ray's interval over its leaf box in the top tree as
/// well.
#[test]
fn coincident_instances_give_the_lowest_id_on_every_walk() {
    // The fuzzed file's unit cube, its faces as it lists them.
    let corners = (0..8)
        .map(|k| DVec3::new((k >> 2) as f64, ((k >> 1) & 1) as f64, (k & 1) as f64))
        .collect();
    let cube = Scene::from_meshes([(
        "cube".to_string(),
        Mesh {
            positions: corners,
            triangles: common::CUBE_FACES.to_vec(),
        },
    )])
    .unwrap();
    let instances: Vec<Instance> = (0..5)
        .map(|k| Instance {
            name: format!("cube {k}"),
            mesh: 0,
            transform: [
                [1.0, 0.0, 0.0, 0.0],
                [0.0, 1.0, 0.0, 0.0],
                [0.0, 0.0, 1.0, 0.0],
            ],
            mask: u32::MAX,
        })
        .collect();
    let built =
        Arc::new(BuiltScene::instanced(vec![cube], instances, &BuildOptions::default()).unwrap());
    let world = built.instances().unwrap().baked().unwrap();
    let rays: Vec<Ray> = mixed_rays(&world, 20000, 1)
        .into_iter()
        .map(|(_, r)| r)
        .collect();
    let twin = every_path("five cubes", &built, &rays, &Query::default());
    let hits = twin.nearest.iter().filter(|h| h.hit).count();
    assert!(hits > 10000, "{hits} hits");
    assert!(
        twin.nearest.iter().all(|h| !h.hit || h.object == 0),
        "a tie went to an instance other than the first"
    );
}

/// In a coarse frame (a sphere 10⁶ units from the scene's centre, not instanced, whose f32
/// offsets round to 1/16 unit) Möller–Trumbore can take a hit a rounding step outside its
/// triangle; its t is kept within the triangle's own box like any other, so every builder and
/// path still gives the same bits, under either test.
#[test]
fn a_coarse_frame_gives_the_same_bits_on_every_builder_under_both_tests() {
    let near = icosphere(DVec3::ZERO, 1.0, 3);
    let far = icosphere(DVec3::new(1e6, 0.5, -0.25), 1.0, 3);
    let alone = Scene::from_meshes([("far".to_string(), far.clone())]).unwrap();
    let scene = Scene::from_meshes([("near".to_string(), near), ("far".to_string(), far)]).unwrap();
    // Edge, vertex and grazing rays made on the far sphere alone, traced in the whole scene.
    let rays: Vec<Ray> = mixed_rays(&alone, 8192, 4)
        .into_iter()
        .map(|(_, r)| r)
        .collect();
    for intersector in [Intersector::MollerTrumbore, Intersector::Watertight] {
        let query = Query {
            intersector,
            ..Query::default()
        };
        let builds = [
            with(Builder::MedianCut, 8),
            with(Builder::BinnedSah, 4),
            with(Builder::MedianCut, 1),
        ];
        every_builder(
            &format!("coarse {intersector:?}"),
            &scene,
            &builds,
            &rays,
            &query,
        );
    }
}
