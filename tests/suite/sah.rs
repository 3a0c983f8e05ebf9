//! The binned-SAH builder keeps median cut's output contract (valid tree, the same hittable
//! triangles, leaf-size limit, origin, errors), is identical on any thread count, and its trees
//! answer exactly like the median-cut tree and the f64 oracle on the CPU path, and on the GPU.
//! `sah_cost` scores trees by hand-checkable numbers.

use crate::common;

use glam::DVec3;
use proptest::prelude::*;
use raypick::bvh::binned_sah;
use raypick::bvh::sah_cost::{TRAVERSAL_COST, TRIANGLE_COST, sah_cost};
use raypick::check::compare::compare_answers;
use raypick::check::oracle::brute_force_every;
use raypick::check::synthetic::{
    RayKind, hills, mixed_rays, terrain, thin_and_degenerate, triangle_soup,
};
use raypick::io::obj::load_obj;
use raypick::layout::{GpuNode, KIND_INNER};
use raypick::{
    Answers, BuildOptions, BuiltScene, Bvh, CpuPicker, Intersector, Mesh, Picker, Query, Ray, Scene,
};
use std::path::Path;
use std::sync::Arc;

fn one(name: &str, mesh: Mesh) -> Scene {
    Scene::from_meshes([(name.to_string(), mesh)]).expect("scene")
}

fn bunny() -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/bunny.obj");
    one("bunny", load_obj(&path).expect("bunny"))
}

fn leaf_size(leaf_size: u32) -> BuildOptions {
    BuildOptions {
        leaf_size,
        ..BuildOptions::default()
    }
}

/// `scene` with a binned-SAH tree (the test scenes carry no layer masks).
fn sah_built(scene: Scene, options: &BuildOptions) -> BuiltScene {
    assert!(
        scene.objects().iter().all(|o| o.mask == u32::MAX),
        "test scenes carry no layer masks"
    );
    let bvh = binned_sah::build(&scene, options).expect("binned SAH builds");
    BuiltScene::from_parts(scene, bvh, Vec::new())
}

/// The contract shared with median cut: a valid tree over the same triangles, no leaf above the
/// leaf size, the same origin.
fn assert_same_contract(name: &str, sah: &Bvh, median: &Bvh, options: &BuildOptions) {
    sah.validate()
        .unwrap_or_else(|e| panic!("{name}: invalid SAH tree: {e}"));
    assert_eq!(sah.origin, median.origin, "{name}: origin");
    let sorted = |ids: &[u32]| {
        let mut ids = ids.to_vec();
        ids.sort_unstable();
        ids
    };
    assert_eq!(
        sorted(&sah.triangle_ids),
        sorted(&median.triangle_ids),
        "{name}: the trees hold different triangles"
    );
    for node in sah.nodes.iter().filter(|n| n.is_leaf()) {
        assert!(
            (1..=options.leaf_size).contains(&node.kind()),
            "{name}: a leaf holds {} triangles, leaf size {}",
            node.kind(),
            options.leaf_size
        );
    }
}

/// Builds `scene` both ways and asserts, per ray kind and for both intersectors, zero
/// mismatches between the SAH tree's CPU answers and the oracle's and the median-cut tree's.
/// Returns the SAH tree's closest hits (watertight).
fn assert_sah_agrees_on_cpu(
    name: &str,
    scene: Scene,
    options: BuildOptions,
    rays: usize,
) -> Answers {
    let median = Arc::new(BuiltScene::new(scene.clone(), &options).expect("median cut builds"));
    let sah = Arc::new(sah_built(scene, &options));
    assert_same_contract(name, &sah.bvh, &median.bvh, &options);
    let rays = mixed_rays(&sah.scene, rays, 7);
    let plain: Vec<Ray> = rays.iter().map(|(_, r)| *r).collect();
    let mt = Query {
        intersector: Intersector::MollerTrumbore,
        ..Query::default()
    };
    let mut failures = Vec::new();
    let mut watertight = None;
    for query in [mt, Query::default()] {
        let answer = |built: &Arc<BuiltScene>| {
            CpuPicker::new(built.clone())
                .query(&plain, &query)
                .expect("cpu query")
        };
        let (sah_answers, median_answers) = (answer(&sah), answer(&median));
        let (oracle, every_hit) = brute_force_every(&sah.scene, &plain, &query);
        for kind in RayKind::ALL {
            let idx: Vec<usize> = (0..rays.len()).filter(|&i| rays[i].0 == kind).collect();
            if idx.is_empty() {
                continue;
            }
            let kind_rays: Vec<Ray> = idx.iter().map(|&i| plain[i]).collect();
            for (pair, other) in [("sah/oracle", &oracle), ("sah/median", &median_answers)] {
                let (tally, bad) = compare_answers(
                    &sah.scene,
                    &kind_rays,
                    query.mode,
                    &sah_answers.subset(&idx),
                    &other.subset(&idx),
                    Some(&every_hit.subset(&idx)),
                );
                eprintln!("{name:>8} {:>13} {pair:>10}: {tally:?}", kind.name());
                failures.extend(bad.iter().take(3).map(|&j| {
                    format!(
                        "{name} {:?} {} {pair}: ray {:?}",
                        query.intersector,
                        kind.name(),
                        kind_rays[j]
                    )
                }));
            }
        }
        if query.intersector == Intersector::Watertight {
            watertight = Some(sah_answers);
        }
    }
    assert!(
        failures.is_empty(),
        "{} mismatches:\n{}",
        failures.len(),
        failures.join("\n")
    );
    watertight.expect("the watertight query ran")
}

fn hit_count(answers: &Answers) -> usize {
    answers.nearest.iter().filter(|h| h.hit).count()
}

const RAYS: usize = 4000;

#[test]
fn bunny_agrees_with_median_cut_and_the_oracle() {
    let answers = assert_sah_agrees_on_cpu("bunny", bunny(), BuildOptions::default(), RAYS);
    assert!(hit_count(&answers) > RAYS / 4);
}

#[test]
fn terrain_agrees_with_median_cut_and_the_oracle() {
    let scene = one("terrain", terrain(48, 40, 100.0, 200.0, 2.5, hills));
    let answers = assert_sah_agrees_on_cpu("terrain", scene, BuildOptions::default(), RAYS);
    assert!(hit_count(&answers) > RAYS / 4);
}

#[test]
fn triangle_soup_agrees_with_median_cut_and_the_oracle() {
    let scene = one("soup", triangle_soup(3000, 10.0, 1));
    let answers = assert_sah_agrees_on_cpu("soup", scene, BuildOptions::default(), RAYS);
    assert!(hit_count(&answers) > RAYS / 4);
}

#[test]
fn degenerate_triangles_are_left_out_and_the_rest_agree() {
    let scene = one("thin", thin_and_degenerate(3));
    let answers = assert_sah_agrees_on_cpu("thin", scene, BuildOptions::default(), RAYS);
    assert!(hit_count(&answers) > 0);
    for h in answers.nearest.iter().filter(|h| h.hit) {
        assert!(
            h.triangle % 4 >= 2,
            "zero-area triangle {} was hit",
            h.triangle
        );
    }
}

#[test]
fn every_leaf_size_agrees() {
    for size in [1, 2, 8, 15] {
        let name = format!("leaf {size}");
        assert_sah_agrees_on_cpu(&name, bunny(), leaf_size(size), 1600);
        let scene = one("terrain", terrain(24, 24, 0.0, 0.0, 1.0, hills));
        assert_sah_agrees_on_cpu(&name, scene, leaf_size(size), 1600);
    }
}

#[test]
fn gpu_agrees_with_the_cpu_and_the_oracle() {
    let built = Arc::new(sah_built(bunny(), &BuildOptions::default()));
    let rays = mixed_rays(&built.scene, RAYS, 7);
    let hits = common::assert_equivalent("sah bunny", built, &rays);
    assert!(hits.iter().filter(|h| h.hit).count() > RAYS / 4);
}

#[test]
fn output_is_identical_on_one_and_four_threads() {
    // Large enough to take the parallel path (and parallel binning) several levels down.
    let s = one("terrain", terrain(130, 130, 0.0, 0.0, 1.0, hills));
    let build_on = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| binned_sah::build(&s, &BuildOptions::default()).unwrap())
    };
    let (one_thread, four) = (build_on(1), build_on(4));
    let bits = |nodes: &[GpuNode]| bytemuck::cast_slice::<GpuNode, u32>(nodes).to_vec();
    assert_eq!(bits(&one_thread.nodes), bits(&four.nodes));
    assert_eq!(one_thread.triangle_ids, four.triangle_ids);
    assert_eq!(one_thread.triangles, four.triangles);
    one_thread.validate().unwrap();
}

#[test]
fn leaf_size_out_of_range_is_the_median_cut_error() {
    let s = one("soup", triangle_soup(10, 1.0, 1));
    for size in [0, 16] {
        let sah = binned_sah::build(&s, &leaf_size(size)).unwrap_err();
        let median = Bvh::build(&s, &leaf_size(size)).unwrap_err();
        assert_eq!(sah.to_string(), median.to_string());
    }
}

#[test]
fn empty_and_all_degenerate_scenes_give_empty_trees() {
    let mut flat = Mesh::default();
    flat.positions
        .extend([DVec3::ZERO, DVec3::X, DVec3::X * 2.0]);
    flat.triangles.push([0, 1, 2]);
    for scene in [Scene::new(), one("flat", flat)] {
        let bvh = binned_sah::build(&scene, &BuildOptions::default()).unwrap();
        assert!(bvh.nodes.is_empty() && bvh.triangles.is_empty());
        assert_eq!(bvh.origin, scene.origin());
        assert_eq!(sah_cost(&bvh), 0.0);
    }
}

#[test]
fn sah_trees_cost_less_than_median_cut_trees() {
    for (name, scene) in [
        ("bunny", bunny()),
        ("soup", one("soup", triangle_soup(3000, 10.0, 1))),
    ] {
        let options = BuildOptions::default();
        let median = sah_cost(&Bvh::build(&scene, &options).unwrap());
        let sah = sah_cost(&binned_sah::build(&scene, &options).unwrap());
        eprintln!("{name}: SAH cost median cut {median:.2}, binned SAH {sah:.2}");
        assert!(
            sah < median,
            "{name}: binned SAH {sah} vs median cut {median}"
        );
    }
}

#[test]
fn sah_cost_of_hand_made_trees() {
    let node = |min: [f32; 3], max: [f32; 3], kind: u32, first: u32| GpuNode {
        min,
        parent_kind: kind,
        max,
        first,
    };
    // One leaf of 3 triangles: reached by every ray.
    let single = Bvh {
        nodes: vec![node([0.0; 3], [1.0; 3], 3, 0)].into(),
        ..Bvh::default()
    };
    assert_eq!(sah_cost(&single), 3.0 * TRIANGLE_COST);
    // A 2×1×1 root over two unit-cube leaves of 1 and 2 triangles:
    // half areas 5 (root) and 3 (each leaf).
    let split = Bvh {
        nodes: vec![
            node([0.0; 3], [2.0, 1.0, 1.0], KIND_INNER, 2),
            node([0.0; 3], [1.0; 3], 1, 0),
            node([1.0, 0.0, 0.0], [2.0, 1.0, 1.0], 2, 1),
        ]
        .into(),
        ..Bvh::default()
    };
    let expected = TRAVERSAL_COST + (3.0 / 5.0) * (1.0 + 2.0) * TRIANGLE_COST;
    assert!((sah_cost(&split) - expected).abs() < 1e-12);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    #[test]
    fn trees_keep_the_median_cut_contract(
        points in prop::collection::vec((-1e3f64..1e3, -1e3f64..1e3, -1e3f64..1e3), 3..600),
        size in 1u32..=15,
    ) {
        let positions: Vec<DVec3> = points.iter().map(|&(x, y, z)| DVec3::new(x, y, z)).collect();
        let triangles = (0..positions.len() as u32 / 3)
            .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
            .collect();
        let s = one("points", Mesh { positions, triangles });
        let options = leaf_size(size);
        let sah = binned_sah::build(&s, &options).unwrap();
        let median = Bvh::build(&s, &options).unwrap();
        if median.nodes.is_empty() {
            prop_assert!(sah.nodes.is_empty());
        } else {
            assert_same_contract("points", &sah, &median, &options);
        }
    }
}
