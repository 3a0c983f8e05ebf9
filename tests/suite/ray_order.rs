//! Ray reordering never changes an answer: the permutation round-trips, and both pickers give
//! the same answers (bit for bit) with and without it, in every query mode.

use crate::common;

use common::gpu;
use proptest::prelude::*;
use raypick::check::synthetic::{RayKind, hills, mixed_rays, rays, terrain};
use raypick::frame::local_rays;
use raypick::io::obj::load_obj;
use raypick::layout::GpuRay;
use raypick::ray_order::{RayOrder, trace_in_order};
use raypick::{
    Answers, BuildOptions, BuiltScene, CpuPicker, GpuPicker, Mode, Picker, Query, Ray, Scene, cpu,
};
use std::path::Path;
use std::sync::Arc;

fn terrain_scene() -> Arc<BuiltScene> {
    let mesh = terrain(64, 48, 100.0, 200.0, 2.5, hills);
    let scene = Scene::from_meshes([("terrain".to_string(), mesh)]).expect("scene");
    Arc::new(BuiltScene::new(scene, &BuildOptions::default()).expect("build"))
}

fn bunny_scene() -> Arc<BuiltScene> {
    let mesh = load_obj(&Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/bunny.obj"))
        .expect("bunny");
    let scene = Scene::from_meshes([("bunny".to_string(), mesh)]).expect("scene");
    Arc::new(BuiltScene::new(scene, &BuildOptions::default()).expect("build"))
}

fn is_permutation(order: &[u32]) -> bool {
    let mut seen = vec![false; order.len()];
    order
        .iter()
        .all(|&i| (i as usize) < seen.len() && !std::mem::replace(&mut seen[i as usize], true))
}

#[test]
fn the_order_is_a_permutation_that_round_trips() {
    let built = terrain_scene();
    for kind in [RayKind::Random, RayKind::AxisParallel, RayKind::InsideBox] {
        let local = local_rays(
            raypick::frame::Frame::at(built.bvh.origin),
            &rays(&built.scene, kind, 5000, 3),
        );
        let order = RayOrder::new(&local).expect("order");
        assert!(is_permutation(order.order()), "{kind:?}");
        let traced = order.gather(&local);
        assert_eq!(order.scatter(&traced), local, "{kind:?}");
        // Groups of three per ray, as all-hits lists are.
        let grouped: Vec<u32> = (0..local.len() as u32 * 3).collect();
        let grouped_traced: Vec<u32> = order
            .order()
            .iter()
            .flat_map(|&i| [3 * i, 3 * i + 1, 3 * i + 2])
            .collect();
        assert_eq!(order.scatter_groups(&grouped_traced, 3), grouped);
        assert_eq!(RayOrder::new(&local), Some(order), "deterministic");
    }
}

#[test]
fn random_rays_are_grouped_by_octant_then_origin() {
    let built = terrain_scene();
    let local = local_rays(
        raypick::frame::Frame::at(built.bvh.origin),
        &rays(&built.scene, RayKind::Random, 4000, 5),
    );
    let order = RayOrder::new(&local).expect("order");
    let traced = order.gather(&local);
    let octant = |r: &GpuRay| r.dir.map(|d| d < 0.0);
    let changes = traced
        .windows(2)
        .filter(|w| octant(&w[0]) != octant(&w[1]))
        .count();
    assert_eq!(changes, 7, "one run per direction octant");
    let step = |w: &[GpuRay]| {
        let (a, b) = (glam::Vec3::from(w[0].origin), glam::Vec3::from(w[1].origin));
        a.distance(b)
    };
    let mean = |rs: &[GpuRay]| rs.windows(2).map(step).sum::<f32>() / (rs.len() - 1) as f32;
    assert!(
        mean(&traced) * 2.0 < mean(&local),
        "neighbours start closer together: {} vs {}",
        mean(&traced),
        mean(&local)
    );
}

#[test]
fn batches_from_one_origin_keep_their_order() {
    let built = terrain_scene();
    let camera = local_rays(
        raypick::frame::Frame::at(built.bvh.origin),
        &rays(&built.scene, RayKind::Camera, 5000, 3),
    );
    assert_eq!(RayOrder::new(&camera), None, "a pinhole camera's rays");
    assert_eq!(RayOrder::new(&[]), None);
    assert_eq!(RayOrder::new(&[GpuRay::default()]), None);
}

#[test]
fn degenerate_batches_round_trip() {
    let nan = GpuRay {
        origin: [f32::NAN, 0.0, f32::INFINITY],
        dir: [0.0, -0.0, 1.0],
        ..GpuRay::default()
    };
    let spread = |i: usize| GpuRay {
        origin: [i as f32, 0.0, -(i as f32)],
        dir: [0.0, -0.0, 1.0],
        ..GpuRay::default()
    };
    let batch: Vec<GpuRay> = (0..9)
        .map(|i| if i % 3 == 0 { nan } else { spread(i) })
        .collect();
    let order = RayOrder::new(&batch).expect("order");
    assert!(is_permutation(order.order()));
    let back = order.scatter(&order.gather(&batch));
    // Bitwise: NaN origins must come back as they went in.
    assert_eq!(bytes(&back), bytes(&batch));
}

fn bytes(rays: &[GpuRay]) -> &[u8] {
    bytemuck::cast_slice(rays)
}

proptest! {
    #[test]
    fn any_batch_round_trips(
        origins in prop::collection::vec(prop::array::uniform3(-1e6f32..1e6), 0..300),
        dirs in prop::collection::vec(prop::array::uniform3(-1f32..1.0), 300),
    ) {
        let batch: Vec<GpuRay> = origins
            .iter()
            .zip(&dirs)
            .map(|(&origin, &dir)| GpuRay { origin, dir, ..GpuRay::default() })
            .collect();
        if let Some(order) = RayOrder::new(&batch) {
            prop_assert!(is_permutation(order.order()));
            prop_assert_eq!(order.scatter(&order.gather(&batch)), batch);
        } else {
            prop_assert!(batch.windows(2).all(|w| w[0].origin == w[1].origin));
        }
    }
}

#[test]
fn cpu_traversal_is_identical_in_either_order() {
    for built in [terrain_scene(), bunny_scene()] {
        for kind in [RayKind::Random, RayKind::Camera] {
            let local = local_rays(
                raypick::frame::Frame::at(built.bvh.origin),
                &rays(&built.scene, kind, 20_000, 9),
            );
            let plain = cpu::trace_all(&built.bvh, &local);
            let (reordered, _) = trace_in_order(&local, 0, true, |r| {
                Ok::<_, ()>((cpu::trace_all(&built.bvh, r), Vec::new()))
            })
            .expect("trace");
            assert_eq!(plain, reordered, "{kind:?}");
        }
    }
}

/// Every query mode, with lists of three so that some overflow.
fn queries() -> [Query; 3] {
    common::every_mode(3)
}

fn assert_same_answers(what: &str, a: &Answers, b: &Answers) {
    assert_eq!(a.nearest.len(), b.nearest.len(), "{what}");
    for (i, (x, y)) in a.nearest.iter().zip(&b.nearest).enumerate() {
        assert_eq!(format!("{x:?}"), format!("{y:?}"), "{what}: ray {i}");
    }
    assert_eq!(a.list_start, b.list_start, "{what}");
    assert_eq!(a.overflow, b.overflow, "{what}");
    assert_eq!(format!("{:?}", a.lists), format!("{:?}", b.lists), "{what}");
}

/// Mixed rays, some of them invalid (a zero or a NaN direction) and some with directions of
/// other lengths: the way back must give each ray its own direction's length (a sorted batch
/// that read another ray's flagged the wrong ray invalid, a mutation test found).
fn world_rays(built: &BuiltScene) -> Vec<Ray> {
    let mut rays: Vec<Ray> = mixed_rays(&built.scene, 6000, 21)
        .into_iter()
        .map(|(_, r)| r)
        .collect();
    for (i, ray) in rays.iter_mut().enumerate() {
        match i % 97 {
            5 => ray.dir = glam::DVec3::ZERO,
            11 => ray.dir = glam::DVec3::new(f64::NAN, 0.0, -1.0),
            k if k % 3 == 0 => ray.dir *= 0.5,
            k if k % 3 == 1 => ray.dir *= 3.0,
            _ => {}
        }
    }
    rays
}

/// The twin: the same answers and the same b and i statistics in either order.
#[test]
fn reference_picker_answers_are_identical_with_and_without_reordering() {
    for built in [terrain_scene(), bunny_scene()] {
        let rays = world_rays(&built);
        for query in queries() {
            let mut given = raypick::ReferencePicker::new(built.clone());
            given.set_reorder_from(usize::MAX);
            let mut sorted = raypick::ReferencePicker::new(built.clone());
            sorted.set_reorder_from(0);
            assert_same_answers(
                &format!("reference {query:?}"),
                &given.query(&rays, &query).expect("reference"),
                &sorted.query(&rays, &query).expect("reference reordered"),
            );
        }
    }
}

/// The engine: the same answers in either order, bit for bit (its b and i count its own walk,
/// and packets form from neighbouring rays, so they follow the order).
#[test]
fn cpu_picker_answers_are_identical_with_and_without_reordering() {
    for built in [terrain_scene(), bunny_scene()] {
        let rays = world_rays(&built);
        for query in queries() {
            let mut given = CpuPicker::new(built.clone());
            given.set_reorder_from(usize::MAX);
            let mut sorted = CpuPicker::new(built.clone());
            sorted.set_reorder_from(0);
            let a = given.query(&rays, &query).expect("cpu");
            let b = sorted.query(&rays, &query).expect("cpu reordered");
            let differ = raypick::check::compare::differences(query.mode, &a, &b);
            assert!(
                differ.is_empty(),
                "cpu {query:?}: {} rays differ",
                differ.len()
            );
            if query.mode == Mode::Any {
                continue;
            }
            assert_eq!(a.list_start, b.list_start);
            assert_eq!(a.overflow, b.overflow);
        }
    }
}

#[test]
fn gpu_picker_answers_are_identical_with_and_without_reordering() {
    for built in [terrain_scene(), bunny_scene()] {
        let rays = world_rays(&built);
        let mut given = GpuPicker::new(gpu(), built.clone()).expect("gpu");
        given.set_reorder_from(usize::MAX);
        let mut sorted = GpuPicker::new(gpu(), built.clone()).expect("gpu");
        sorted.set_reorder_from(0);
        // Chunks smaller than the batch: the order is applied across chunk boundaries.
        sorted.set_chunk_rays(1000);
        for query in queries() {
            assert_same_answers(
                &format!("gpu {query:?}"),
                &given.query(&rays, &query).expect("gpu"),
                &sorted.query(&rays, &query).expect("gpu reordered"),
            );
        }
    }
}
