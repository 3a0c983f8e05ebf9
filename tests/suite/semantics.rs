//! The documented hit semantics, on both backends: t in (tmin, tmax], inclusive edges, zero-area
//! triangles never hit, invalid rays flagged, huge batches chunked, exact f64 positions.

use crate::common;

use glam::DVec3;
use raypick::check::synthetic::{single_triangle, terrain};
use raypick::{BuildOptions, BuiltScene, CpuPicker, GpuPicker, Hit, Mesh, Picker, Ray, Scene};
use std::sync::Arc;

fn built(meshes: Vec<Mesh>) -> Arc<BuiltScene> {
    let scene = Scene::from_meshes(
        meshes
            .into_iter()
            .enumerate()
            .map(|(i, m)| (format!("m{i}"), m)),
    )
    .unwrap();
    Arc::new(BuiltScene::new(scene, &BuildOptions::default()).unwrap())
}

fn both(built: &Arc<BuiltScene>, rays: &[Ray]) -> [Vec<Hit>; 2] {
    let cpu = CpuPicker::new(built.clone()).pick(rays).unwrap();
    let gpu = GpuPicker::new(common::gpu(), built.clone())
        .unwrap()
        .pick(rays)
        .unwrap();
    [cpu, gpu]
}

#[test]
fn range_is_open_at_tmin_and_closed_at_tmax() {
    let b = built(vec![single_triangle()]);
    let down =
        |tmin, tmax| Ray::new(DVec3::new(0.25, 0.25, 1.0), DVec3::NEG_Z).with_range(tmin, tmax);
    for hits in both(
        &b,
        &[
            down(0.0, 1.0),
            down(0.0, 0.999),
            down(1.0, 2.0),
            down(0.5, 1.5),
        ],
    ) {
        assert!(
            hits[0].hit && (hits[0].t - 1.0).abs() < 1e-12,
            "t == tmax is a hit"
        );
        assert!(!hits[1].hit, "t > tmax is not");
        assert!(!hits[2].hit, "t == tmin is not");
        assert!(hits[3].hit);
    }
}

#[test]
fn invalid_rays_come_back_flagged_and_never_hang() {
    let b = built(vec![single_triangle()]);
    let o = DVec3::new(0.25, 0.25, 1.0);
    let rays = [
        Ray::new(DVec3::new(f64::NAN, 0.0, 0.0), DVec3::NEG_Z),
        Ray::new(o, DVec3::new(0.0, f64::INFINITY, -1.0)),
        Ray::new(o, DVec3::ZERO),
        Ray::new(o, DVec3::NEG_Z).with_range(f64::NAN, 1.0),
        Ray::new(o, DVec3::NEG_Z).with_range(3.0, 1.0),
        Ray::new(o, DVec3::NEG_Z * 1e-300),
        Ray::new(o, DVec3::NEG_Z * 1e300),
    ];
    for hits in both(&b, &rays) {
        for h in &hits[..5] {
            assert!(h.invalid && !h.hit, "{h:?}");
        }
        // Tiny and huge (but finite, non-zero) directions are valid; t scales with them.
        assert!(
            hits[5].hit && (hits[5].t - 1e300).abs() < 1e288,
            "{:?}",
            hits[5]
        );
        assert!(
            hits[6].hit && (hits[6].t - 1e-300).abs() < 1e-312,
            "{:?}",
            hits[6]
        );
    }
}

#[test]
fn hits_report_object_triangle_barycentrics_position_and_normal() {
    let ground = terrain(3, 3, 0.0, 2.0, 1.0, |_, _| 0.0);
    let b = built(vec![single_triangle(), ground]);
    // Straight down onto the terrain's quad (0, 0) NE half: x in (0,1), y in (1,2).
    let ray = Ray::new(DVec3::new(0.75, 1.8, 5.0), DVec3::new(0.0, 0.0, -2.0));
    for hits in both(&b, &[ray]) {
        let h = hits[0];
        assert!(h.hit);
        assert_eq!(
            (h.object, h.triangle),
            (1, 1),
            "object 1, triangle 2k+1 = (NW, SE, NE) of quad 0"
        );
        assert!(
            (h.t - 2.5).abs() < 1e-12,
            "t scales with the direction: {}",
            h.t
        );
        assert!((h.position - DVec3::new(0.75, 1.8, 0.0)).length() < 1e-12);
        assert!((h.normal - DVec3::Z).length() < 1e-12 || (h.normal + DVec3::Z).length() < 1e-12);
        let [a, bb, c] = b.scene.world_triangle(b.scene.global_index(1, 1).unwrap());
        let p = a + (bb - a) * h.u + (c - a) * h.v;
        assert!(
            (p - h.position).length() < 1e-12,
            "u, v reproduce the position"
        );
    }
}

#[test]
fn zero_area_triangles_are_never_hit() {
    let flat = Mesh {
        positions: vec![DVec3::ZERO, DVec3::X, DVec3::X * 2.0, DVec3::Y],
        triangles: vec![[0, 1, 2], [0, 0, 3], [0, 1, 3]],
    };
    let b = built(vec![flat]);
    assert_eq!(
        b.bvh.triangles.len(),
        1,
        "only the real triangle is in the tree"
    );
    let rays = [
        Ray::new(DVec3::new(0.5, 0.0, 1.0), DVec3::NEG_Z),
        Ray::new(DVec3::new(0.2, 0.2, 1.0), DVec3::NEG_Z),
    ];
    for hits in both(&b, &rays) {
        assert!(
            hits[1].hit && hits[1].triangle == 2,
            "ids stay stable around skipped triangles"
        );
        assert!(!hits[0].hit || hits[0].triangle == 2);
    }
}

#[test]
fn large_batches_split_into_chunks_give_the_same_answers() {
    let b = built(vec![terrain(
        20,
        20,
        0.0,
        19.0,
        1.0,
        raypick::check::synthetic::hills,
    )]);
    let rays = raypick::check::synthetic::rays(
        &b.scene,
        raypick::check::synthetic::RayKind::Random,
        5000,
        3,
    );
    let mut gpu = GpuPicker::new(common::gpu(), b.clone()).unwrap();
    let whole = gpu.pick(&rays).unwrap();
    gpu.set_chunk_rays(333);
    let chunked = gpu.pick(&rays).unwrap();
    assert_eq!(whole, chunked);
    let single = gpu.pick(&rays[..1]).unwrap();
    assert_eq!(
        single[0], whole[0],
        "a single ray after a large batch reuses the buffers"
    );
    assert!(gpu.pick(&[]).unwrap().is_empty());
}

#[test]
fn a_corrupted_link_hits_the_iteration_cap_instead_of_hanging() {
    let b = built(vec![terrain(
        10,
        10,
        0.0,
        9.0,
        1.0,
        raypick::check::synthetic::hills,
    )]);
    let mut broken = (*b).clone();
    // Point the deepest-right inner node's right child back at the root: a cycle.
    let inner = broken.bvh.nodes.iter().rposition(|n| !n.is_leaf()).unwrap();
    broken.bvh.nodes[inner].first = 0;
    let broken = Arc::new(broken);
    let rays = raypick::check::synthetic::rays(
        &broken.scene,
        raypick::check::synthetic::RayKind::Camera,
        256,
        1,
    );
    let cpu = CpuPicker::new(broken.clone()).pick(&rays);
    let gpu = GpuPicker::new(common::gpu(), broken.clone())
        .unwrap()
        .pick(&rays);
    for result in [cpu, gpu] {
        let error = result.expect_err("a cycle must be reported");
        assert!(error.to_string().contains("iteration cap"), "{error}");
    }
}

#[test]
fn axis_parallel_rays_on_the_scene_border_hit_on_both_backends() {
    // Straight-down rays exactly on every border sample of a terrain: the rays lie in the planes
    // of the boxes' faces (regression: they used to be culled on the max faces).
    let b = built(vec![terrain(
        9,
        7,
        10.0,
        26.0,
        2.0,
        raypick::check::synthetic::hills,
    )]);
    let (lo, hi) = b.scene.bounds().unwrap();
    let mut rays = Vec::new();
    for i in 0..9 {
        for y in [lo.y, hi.y] {
            rays.push(Ray::new(
                DVec3::new(10.0 + 2.0 * i as f64, y, 100.0),
                DVec3::NEG_Z,
            ));
        }
    }
    for j in 0..7 {
        for x in [lo.x, hi.x] {
            rays.push(Ray::new(
                DVec3::new(x, 26.0 - 2.0 * j as f64, 100.0),
                DVec3::NEG_Z,
            ));
        }
    }
    for hits in both(&b, &rays) {
        for (ray, hit) in rays.iter().zip(&hits) {
            assert!(hit.hit, "border ray {:?} missed", ray.origin);
        }
    }
}
