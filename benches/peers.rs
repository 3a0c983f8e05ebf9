//! raypick's CPU traversal against other Rust BVH crates, on the same triangles and rays:
//!
//! - `raypick`: `cpu::trace_all` (median-cut binary BVH, ordered stackless walk, Möller–Trumbore);
//! - `obvhs` 0.4: CWBVH from `fast_build`, `ray_traverse` per ray, as `benches/pick.rs` sets it up;
//! - `bvh` 0.13 (svenstaro): `Bvh::build_par` over one shape per triangle, closest hit by walking
//!   `nearest_traverse_iterator` (leaves in order of their box's entry distance) and testing each
//!   candidate with a two-sided Möller–Trumbore, stopping once a box starts beyond the best hit;
//! - `parry3d` 0.31: `TriMesh::new` and `RayCast::cast_local_ray` with `solid = false`.
//!
//! Every peer runs in parallel over rays with rayon (`with_min_len(256)`), in the same
//! scene-local f32 frame as raypick's tree. Scenes: the Stanford bunny, the Jacksboro fault DEM,
//! a 1001 × 1001-sample terrain (2,000,000 triangles) and a soup of 200,000 random triangles.
//! Rays: 65,536 camera rays and 65,536 random rays per scene (`synthetic::rays`).
//!
//! Before timing, each scene prints every peer's build time and how often each peer agrees with
//! raypick on hit/miss and on t, so a mis-set-up peer cannot pass unnoticed.
//!
//! Run with `cargo bench --bench peers` (one scene: `cargo bench --bench peers -- bunny`).

use bvh::aabb::{Aabb, Bounded};
use bvh::bounding_hierarchy::{BHShape, BoundingHierarchy};
#[path = "common/obvhs_peer.rs"]
mod obvhs_peer;

use criterion::{
    BenchmarkGroup, Criterion, SamplingMode, Throughput, criterion_group, criterion_main,
    measurement::WallTime,
};
use glam::Vec3A;
use nalgebra::{Point3, Vector3};
use obvhs::triangle::Triangle;
use obvhs_peer::{obvhs_build, obvhs_trace};
use parry3d::query::RayCast;
use rayon::prelude::*;
use raypick::frame::local_rays;
use raypick::io::obj::load_obj;
use raypick::io::scene_files::{SceneFile, load_scene};
use raypick::layout::{GpuHit, GpuRay, NO_HIT};
use raypick::synthetic::{RayKind, hills, rays, terrain, triangle_soup};
use raypick::{BuildOptions, BuiltScene, Scene, cpu};
use std::hint::black_box;
use std::path::Path;
use std::time::{Duration, Instant};

/// Rays per batch.
const RAY_COUNT: usize = 65_536;
/// Seed for the ray sets and the soup.
const SEED: u64 = 1;
/// Rays per rayon task, for every peer.
const MIN_LEN: usize = 256;

/// Every group takes 10 flat samples over a short window: the routines run for milliseconds to
/// a few hundred milliseconds, and the whole bench must stay well under 10 minutes on 2 cores.
fn configure(group: &mut BenchmarkGroup<'_, WallTime>) {
    group
        .sample_size(10)
        .sampling_mode(SamplingMode::Flat)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2));
}

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

fn bunny() -> Scene {
    let mesh = load_obj(&data("bunny.obj")).expect("tests/data/bunny.obj loads");
    Scene::from_meshes([("bunny".to_string(), mesh)]).expect("the bunny is well formed")
}

fn dem() -> Scene {
    load_scene(&[SceneFile {
        file: data("jacksboro_fault_dem_utm.asc"),
        mask: None,
    }])
    .expect("the Jacksboro DEM loads")
}

/// 1001 × 1001 samples, 1 m apart: 2,000,000 triangles.
fn terrain_2m() -> Scene {
    let mesh = terrain(1001, 1001, 0.0, 1000.0, 1.0, hills);
    Scene::from_meshes([("terrain".to_string(), mesh)]).expect("the terrain is well formed")
}

/// 200,000 random triangles in a 100-unit cube, edges up to 10 units.
fn soup() -> Scene {
    let mesh = triangle_soup(200_000, 100.0, SEED);
    Scene::from_meshes([("soup".to_string(), mesh)]).expect("the soup is well formed")
}

/// The scene's triangles in the scene-local f32 frame of raypick's tree.
fn local_triangles(built: &BuiltScene) -> Vec<[Vec3A; 3]> {
    let origin = built.bvh.origin;
    (0..built.scene.triangle_count())
        .map(|i| {
            built
                .scene
                .world_triangle(i)
                .map(|p| Vec3A::from((p - origin).as_vec3()))
        })
        .collect()
}

// ---------------------------------------------------------------------------------------------
// bvh (svenstaro)

/// One triangle as a `bvh` shape, with its box precomputed.
struct BvhTriangle {
    corners: [Vec3A; 3],
    aabb: Aabb<f32, 3>,
    node_index: usize,
}

impl Bounded<f32, 3> for BvhTriangle {
    fn aabb(&self) -> Aabb<f32, 3> {
        self.aabb
    }
}

impl BHShape<f32, 3> for BvhTriangle {
    fn set_bh_node_index(&mut self, index: usize) {
        self.node_index = index;
    }
    fn bh_node_index(&self) -> usize {
        self.node_index
    }
}

fn point(p: Vec3A) -> Point3<f32> {
    Point3::new(p.x, p.y, p.z)
}

fn bvh_shapes(triangles: &[[Vec3A; 3]]) -> Vec<BvhTriangle> {
    triangles
        .iter()
        .map(|&corners| {
            let lo = corners[0].min(corners[1]).min(corners[2]);
            let hi = corners[0].max(corners[1]).max(corners[2]);
            BvhTriangle {
                corners,
                aabb: Aabb::with_bounds(point(lo), point(hi)),
                node_index: 0,
            }
        })
        .collect()
}

/// `bvh`'s builder with rayon (its `build_par`, the default features' parallel build).
fn bvh_build(shapes: &mut [BvhTriangle]) -> bvh::bvh::Bvh<f32, 3> {
    bvh::bvh::Bvh::build_par(shapes)
}

/// Two-sided Möller–Trumbore in the ray's own units: t in (tmin, tmax), like raypick's and
/// obvhs's tests. (`bvh::ray::Ray::intersects_triangle` culls back faces, so it cannot answer
/// closest-hit picks over both faces.)
fn moller_trumbore(
    origin: Vec3A,
    dir: Vec3A,
    [v0, v1, v2]: [Vec3A; 3],
    tmin: f32,
    tmax: f32,
) -> Option<f32> {
    let (e1, e2) = (v1 - v0, v2 - v0);
    let p = dir.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 {
        return None;
    }
    let inv = 1.0 / det;
    let s = origin - v0;
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = dir.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > tmin && t < tmax).then_some(t)
}

/// Closest hit per ray: the leaves come nearest box first; each candidate triangle is tested,
/// and the walk stops at the first leaf whose box starts beyond the best hit so far.
fn bvh_trace(
    bvh: &bvh::bvh::Bvh<f32, 3>,
    shapes: &[BvhTriangle],
    rays: &[GpuRay],
) -> Vec<Option<f32>> {
    rays.par_iter()
        .with_min_len(MIN_LEN)
        .map(|r| {
            let (origin, dir) = (Vec3A::from(r.origin), Vec3A::from(r.dir));
            // `bvh::ray::Ray` normalises its direction: its distances are t × |dir|.
            let length = dir.length();
            let ray = bvh::ray::Ray::new(point(origin), Vector3::new(dir.x, dir.y, dir.z));
            let mut best = r.tmax;
            let mut found = None;
            for shape in bvh.nearest_traverse_iterator(&ray, shapes) {
                match ray.intersection_slice_for_aabb(&shape.aabb) {
                    Some((entry, _)) if entry / length > best => break,
                    Some(_) => {}
                    None => continue,
                }
                if let Some(t) = moller_trumbore(origin, dir, shape.corners, r.tmin, best) {
                    best = t;
                    found = Some(t);
                }
            }
            found
        })
        .collect()
}

// ---------------------------------------------------------------------------------------------
// parry3d

fn parry_vector(p: Vec3A) -> parry3d::math::Vector {
    parry3d::math::Vector::new(p.x, p.y, p.z)
}

/// parry3d's triangle mesh (it builds its own BVH), three vertices per triangle as given.
fn parry_build(triangles: &[[Vec3A; 3]]) -> parry3d::shape::TriMesh {
    let vertices = triangles.iter().flat_map(|t| t.map(parry_vector)).collect();
    let indices = (0..triangles.len() as u32)
        .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
        .collect();
    parry3d::shape::TriMesh::new(vertices, indices).expect("parry3d accepts the mesh")
}

/// Closest hit per ray over both faces (`solid = false`). parry3d's rays have no tmin; every
/// benchmark ray starts at tmin = 0.
fn parry_trace(mesh: &parry3d::shape::TriMesh, rays: &[GpuRay]) -> Vec<Option<f32>> {
    rays.par_iter()
        .with_min_len(MIN_LEN)
        .map(|r| {
            let ray = parry3d::query::Ray::new(
                parry_vector(Vec3A::from(r.origin)),
                parry_vector(Vec3A::from(r.dir)),
            );
            mesh.cast_local_ray(&ray, r.tmax.min(f32::MAX), false)
        })
        .collect()
}

// ---------------------------------------------------------------------------------------------

fn ours(hits: &[GpuHit]) -> Vec<Option<f32>> {
    hits.iter()
        .map(|h| (h.prim != NO_HIT).then_some(h.t))
        .collect()
}

/// Prints how often `theirs` agrees with raypick on hit/miss and on t (relative 1e-4).
fn report_agreement(
    scene: &str,
    peer: &str,
    kind: &str,
    ours: &[Option<f32>],
    theirs: &[Option<f32>],
) {
    let (mut hits, mut same_outcome, mut same_t) = (0, 0, 0);
    for (a, b) in ours.iter().zip(theirs) {
        hits += usize::from(a.is_some());
        match (a, b) {
            (None, None) => {
                same_outcome += 1;
                same_t += 1;
            }
            (Some(a), Some(b)) => {
                same_outcome += 1;
                if (a - b).abs() <= 1e-4 * a.abs().max(1.0) {
                    same_t += 1;
                }
            }
            _ => {}
        }
    }
    eprintln!(
        "{scene}: {peer} vs raypick, {kind} rays: raypick hits {hits}/{}; same hit/miss {same_outcome}, same t {same_t}",
        ours.len()
    );
}

fn timed<T>(f: impl FnOnce() -> T) -> (T, f64) {
    let start = Instant::now();
    let value = f();
    (value, start.elapsed().as_secs_f64() * 1e3)
}

/// Builds every peer over `scene`, checks agreement, and times closest-hit traversal of the
/// camera and random rays. The scene and the trees are dropped before the next scene.
fn bench_scene(c: &mut Criterion, name: &str, scene: Scene) {
    let (built, ours_ms) =
        timed(|| BuiltScene::new(scene, &BuildOptions::default()).expect("the scene builds"));
    let triangles = local_triangles(&built);
    let obvhs_input: Vec<Triangle> = triangles
        .iter()
        .map(|&[v0, v1, v2]| Triangle { v0, v1, v2 })
        .collect();
    let ((obvhs_bvh, obvhs_ordered), obvhs_ms) = timed(|| obvhs_build(&obvhs_input));
    let mut shapes = bvh_shapes(&triangles);
    let (bvh_tree, bvh_ms) = timed(|| bvh_build(&mut shapes));
    let (parry_mesh, parry_ms) = timed(|| parry_build(&triangles));
    eprintln!(
        "{name}: {} triangles; build ms (one run): raypick {ours_ms:.1}, obvhs fast_build {obvhs_ms:.1}, \
         bvh build_par {bvh_ms:.1}, parry3d TriMesh::new {parry_ms:.1}",
        triangles.len()
    );

    let mut group = c.benchmark_group(format!("peers/{name}"));
    configure(&mut group);
    for (kind_name, kind) in [("camera", RayKind::Camera), ("random", RayKind::Random)] {
        let world = rays(&built.scene, kind, RAY_COUNT, SEED);
        let local = local_rays(built.bvh.origin, &world);
        let obvhs_rays: Vec<obvhs::ray::Ray> = local
            .iter()
            .map(|r| {
                obvhs::ray::Ray::new(r.origin.into(), r.dir.into(), r.tmin, r.tmax.min(f32::MAX))
            })
            .collect();
        let reference = ours(&cpu::trace_all(&built.bvh, &local));
        let tmin_max = local.iter().map(|r| r.tmin).fold(0.0f32, f32::max);
        if tmin_max > 0.0 {
            eprintln!("{name}: {kind_name} rays have tmin up to {tmin_max} (parry3d ignores tmin)");
        }
        report_agreement(
            name,
            "obvhs",
            kind_name,
            &reference,
            &obvhs_trace(&obvhs_bvh, &obvhs_ordered, &obvhs_rays)
                .iter()
                .map(|h| h.t.is_finite().then_some(h.t))
                .collect::<Vec<_>>(),
        );
        report_agreement(
            name,
            "bvh",
            kind_name,
            &reference,
            &bvh_trace(&bvh_tree, &shapes, &local),
        );
        report_agreement(
            name,
            "parry3d",
            kind_name,
            &reference,
            &parry_trace(&parry_mesh, &local),
        );

        group.throughput(Throughput::Elements(local.len() as u64));
        group.bench_function(format!("raypick/{kind_name}"), |b| {
            b.iter(|| cpu::trace_all(&built.bvh, black_box(&local)))
        });
        group.bench_function(format!("obvhs/{kind_name}"), |b| {
            b.iter(|| obvhs_trace(&obvhs_bvh, &obvhs_ordered, black_box(&obvhs_rays)))
        });
        group.bench_function(format!("bvh/{kind_name}"), |b| {
            b.iter(|| bvh_trace(&bvh_tree, &shapes, black_box(&local)))
        });
        group.bench_function(format!("parry3d/{kind_name}"), |b| {
            b.iter(|| parry_trace(&parry_mesh, black_box(&local)))
        });
    }
    group.finish();
}

/// Makes one benchmark scene.
type SceneMaker = fn() -> Scene;

fn peers(c: &mut Criterion) {
    let scenes: [(&str, SceneMaker); 4] = [
        ("bunny", bunny),
        ("dem", dem),
        ("terrain_2m", terrain_2m),
        ("soup_200k", soup),
    ];
    for (name, make) in scenes {
        bench_scene(c, name, make());
    }
}

criterion_group!(benches, peers);
criterion_main!(benches);
