//! The equivalence check itself can fail: real disagreements are flagged, ties are not.

use glam::DVec3;
use raypick::check::compare::{Verdict, classify};
use raypick::check::oracle::brute_force;
use raypick::check::synthetic::single_triangle;
use raypick::{Hit, Ray, Scene};

fn scene() -> Scene {
    Scene::from_meshes([("t".to_string(), single_triangle())]).unwrap()
}

#[test]
fn a_hit_deep_inside_versus_a_miss_is_a_mismatch() {
    let scene = scene();
    let ray = Ray::new(DVec3::new(0.25, 0.25, 1.0), DVec3::NEG_Z);
    let hit = brute_force(&scene, &ray);
    assert!(hit.hit);
    assert_eq!(classify(&scene, &ray, &hit, &Hit::MISS), Verdict::Mismatch);
    let moved = Hit {
        t: hit.t + 0.5,
        triangle: 7,
        ..hit
    };
    assert_eq!(classify(&scene, &ray, &hit, &moved), Verdict::Mismatch);
}

#[test]
fn a_hit_on_the_edge_versus_a_miss_is_a_boundary_tie() {
    let scene = scene();
    let ray = Ray::new(DVec3::new(0.5, 0.5, 1.0), DVec3::NEG_Z);
    let hit = brute_force(&scene, &ray);
    assert!(hit.hit, "edges are inclusive");
    assert_eq!(classify(&scene, &ray, &hit, &Hit::MISS), Verdict::Boundary);
}

#[test]
fn invalid_rays_are_flagged_misses() {
    let scene = scene();
    for ray in [
        Ray::new(DVec3::new(f64::NAN, 0.0, 1.0), DVec3::NEG_Z),
        Ray::new(DVec3::new(0.2, 0.2, 1.0), DVec3::ZERO),
        Ray::new(
            DVec3::new(0.2, 0.2, 1.0),
            DVec3::new(0.0, 0.0, f64::NEG_INFINITY),
        ),
        Ray::new(DVec3::new(0.2, 0.2, 1.0), DVec3::NEG_Z).with_range(2.0, 1.0),
    ] {
        let hit = brute_force(&scene, &ray);
        assert!(hit.invalid && !hit.hit, "{ray:?}");
    }
}
