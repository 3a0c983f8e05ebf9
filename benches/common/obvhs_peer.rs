//! The obvhs peer, shared by `benches/pick.rs` and `benches/peers.rs`: its recommended set-up
//! for triangle meshes and its closest-hit traversal, parallel over rays like ours.

use obvhs::BvhBuildParams;
use obvhs::cwbvh::CwBvh;
use obvhs::cwbvh::builder::build_cwbvh_from_tris;
use obvhs::ray::RayHit;
use obvhs::triangle::Triangle;
use rayon::prelude::*;
use std::time::Duration;

/// obvhs's recommended set-up for triangle meshes (its `obj_cwbvh` example): a CWBVH from
/// `fast_build`, with the triangles reordered into leaf order so traversal needs no indirection.
pub fn obvhs_build(triangles: &[Triangle]) -> (CwBvh, Vec<Triangle>) {
    let bvh = build_cwbvh_from_tris(
        triangles,
        BvhBuildParams::fast_build(),
        &mut Duration::default(),
    );
    let ordered = bvh
        .primitive_indices
        .iter()
        .map(|&i| triangles[i as usize])
        .collect();
    (bvh, ordered)
}

/// Closest hit of one ray: one `ray_traverse` call over the leaf-ordered triangles.
pub fn obvhs_intersect(bvh: &CwBvh, triangles: &[Triangle], ray: obvhs::ray::Ray) -> RayHit {
    let mut hit = RayHit::none();
    bvh.ray_traverse(ray, &mut hit, |ray, id| triangles[id].intersect(ray));
    hit
}

/// Closest hit per ray, parallel over rays like ours.
pub fn obvhs_trace(bvh: &CwBvh, triangles: &[Triangle], rays: &[obvhs::ray::Ray]) -> Vec<RayHit> {
    rays.par_iter()
        .with_min_len(256)
        .with_max_len(256)
        .map(|ray| obvhs_intersect(bvh, triangles, *ray))
        .collect()
}
