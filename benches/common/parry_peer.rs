//! The parry3d 0.31 peer: `TriMesh::new` (parry builds its own BVH) over three vertices per
//! triangle, and `RayCast::cast_local_ray` with `solid = false` for the closest hit.

use glam::Vec3A;
use parry3d::query::RayCast;
use parry3d::shape::TriMesh;
use raypick::layout::GpuRay;

fn vector(p: Vec3A) -> parry3d::math::Vector {
    parry3d::math::Vector::new(p.x, p.y, p.z)
}

/// parry3d's triangle mesh, three vertices per triangle as given.
pub fn parry_build(triangles: &[[Vec3A; 3]]) -> TriMesh {
    let vertices = triangles.iter().flat_map(|t| t.map(vector)).collect();
    let indices = (0..triangles.len() as u32)
        .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
        .collect();
    TriMesh::new(vertices, indices).expect("parry3d accepts the mesh")
}

/// Closest hit of one ray over both faces (`solid = false`). parry3d's rays have no tmin; every
/// benchmark ray starts at tmin = 0.
pub fn parry_intersect(mesh: &TriMesh, r: &GpuRay) -> Option<f32> {
    let ray = parry3d::query::Ray::new(vector(Vec3A::from(r.origin)), vector(Vec3A::from(r.dir)));
    mesh.cast_local_ray(&ray, r.tmax.min(f32::MAX), false)
}
