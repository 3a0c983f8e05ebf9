//! Moving an object's vertices without rebuilding (`Picker::set_positions`,
//! `BuiltScene::set_positions`): every backend, refitted in place, answers bit for bit as new
//! pickers made over the refitted scene, and the refitted trees pass the equivalence suite
//! (engine, twin, GPU and the f64 oracle: 0 mismatches). A refit keeps the tree's f32 frame, so
//! at a shared edge it may report the other triangle than a build from scratch (a new origin,
//! other f32 roundings): both are hits, which the oracle's tie rules accept. A triangle that
//! becomes degenerate, or stops being so, makes the tree build again; bad positions change
//! nothing.

use crate::common;

use glam::{DMat3, DVec3, Vec3};
use raypick::auto::AutoPicker;
use raypick::check::compare::differences;
use raypick::check::synthetic::{hills, icosphere, mixed_rays, terrain};
use raypick::engine::WideBvh;
use raypick::engine::wide::{EMPTY, INNER, WIDTH};
use raypick::layout::GpuTriangle;
use raypick::picker::Tracer;
use raypick::{
    BuildOptions, Builder, BuiltScene, CpuPicker, GpuPicker, Mode, Picker, Query, Ray,
    ReferencePicker, Refit, Scene,
};
use std::sync::Arc;

/// The positions of object `object` of `scene`, rotated, scaled unevenly, moved and wobbled
/// vertex by vertex (`step` varies the motion).
fn moved(scene: &Scene, object: u32, step: f64) -> Vec<DVec3> {
    let turn = DMat3::from_rotation_z(0.3 * step) * DMat3::from_rotation_x(0.1 * step);
    let stretch = DVec3::new(1.0 + 0.1 * step, 0.9, 1.2);
    scene
        .object_vertices(object)
        .map(|v| {
            let p = scene.position(v);
            let wobble = DVec3::new((v as f64 * 0.7).sin(), (v as f64 * 1.3).cos(), 0.0) * 0.01;
            turn * (p * stretch) + DVec3::new(0.5, -0.25, 0.125) * step + wobble
        })
        .collect()
}

/// A mesh object (a sphere) over a terrain grid object.
fn two_objects() -> Scene {
    let mut scene = Scene::new();
    scene
        .add_mesh("sphere", icosphere(DVec3::new(5.0, -5.0, 4.0), 2.5, 3))
        .unwrap();
    scene
        .add_mesh("terrain", terrain(24, 20, 0.0, 0.0, 0.5, hills))
        .unwrap();
    scene
}

fn plain(rays: &[(raypick::check::synthetic::RayKind, Ray)]) -> Vec<Ray> {
    rays.iter().map(|(_, r)| *r).collect()
}

/// Asserts that `picker` answers `rays` as `want` does, bit for bit, in closest and all-hits
/// modes.
fn assert_same(name: &str, picker: &mut dyn Picker, want: &mut dyn Picker, rays: &[Ray]) {
    for query in [
        Query::default(),
        Query {
            mode: Mode::All,
            max_hits: 8,
            ..Query::default()
        },
    ] {
        let got = picker.query(rays, &query).unwrap();
        let expected = want.query(rays, &query).unwrap();
        let differ = differences(query.mode, &got, &expected);
        assert!(
            differ.is_empty(),
            "{name} {:?}: {} of {} rays differ from a new picker, first {:?}: {:?} vs {:?}",
            query.mode,
            differ.len(),
            rays.len(),
            rays[differ[0]],
            got.hits_of(differ[0]),
            expected.hits_of(differ[0])
        );
    }
}

#[test]
fn moved_objects_answer_as_new_pickers_and_the_oracle_on_every_backend() {
    let options = BuildOptions::default();
    let built = Arc::new(BuiltScene::new(two_objects(), &options).unwrap());
    let mut cpu = CpuPicker::new(built.clone());
    let mut reference = ReferencePicker::new(built.clone());
    let mut gpu = GpuPicker::new(common::gpu(), built.clone()).unwrap();
    let mut auto = AutoPicker::new(built.clone());
    let warm = plain(&mixed_rays(&built.scene, 64, 1));
    for picker in [
        &mut cpu as &mut dyn Picker,
        &mut reference,
        &mut gpu,
        &mut auto,
    ] {
        // The engine's wide tree exists before the move, so it is refitted, not collapsed anew.
        picker.pick(&warm).unwrap();
    }
    drop(built);
    // Each object in turn, twice, so refits follow refits.
    for (round, object) in [(1.0, 0u32), (2.0, 1), (3.0, 0)] {
        let positions = moved(&cpu.built().scene, object, round);
        let mut refits = Vec::new();
        for picker in [
            &mut cpu as &mut dyn Picker,
            &mut reference,
            &mut gpu,
            &mut auto,
        ] {
            refits.push(picker.set_positions(object, &positions).unwrap());
        }
        assert_eq!(refits, [Refit::Refitted; 4], "round {round}");
        let refitted = cpu.built().clone();
        let rays = mixed_rays(&refitted.scene, 1500, round as u64);
        let rays_plain = plain(&rays);
        let mut new_reference = ReferencePicker::new(refitted.clone());
        for (name, picker) in [
            ("cpu", &mut cpu as &mut dyn Picker),
            ("reference", &mut reference),
            ("gpu", &mut gpu),
            ("auto", &mut auto),
        ] {
            assert_same(name, picker, &mut new_reference, &rays_plain);
        }
        // The refitted trees themselves: valid, the engine's the collapse of the binary one,
        // and the whole equivalence suite (GPU, twin, engine, oracle) on them.
        refitted.bvh.validate().unwrap();
        let wide = refitted.wide().unwrap();
        wide.validate(refitted.bvh.triangles.len()).unwrap();
        if !wide.nodes.is_empty() {
            wide_bounds(wide, &refitted.bvh.triangles, 0);
        }
        common::assert_equivalent(&format!("refit round {round}"), refitted, &rays);
    }
}

/// Asserts that every child box of wide node `node` (and below) is exactly the min/max of the
/// triangles under it, and returns the node's own bounds.
fn wide_bounds(wide: &WideBvh, triangles: &[GpuTriangle], node: usize) -> (Vec3, Vec3) {
    let n = &wide.nodes[node];
    let mut all = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    for lane in 0..WIDTH {
        let (kind, child) = (n.kind[lane], n.child[lane] as usize);
        let (lo, hi) = match kind {
            EMPTY => continue,
            INNER => wide_bounds(wide, triangles, child),
            count => triangles[child..child + count as usize]
                .iter()
                .flat_map(|t| [t.v0, t.v1, t.v2])
                .map(Vec3::from)
                .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| {
                    (lo.min(p), hi.max(p))
                }),
        };
        let slot = |b: &[[f32; WIDTH]; 3]| Vec3::new(b[0][lane], b[1][lane], b[2][lane]);
        assert_eq!(
            (slot(&n.min), slot(&n.max)),
            (lo, hi),
            "wide node {node} slot {lane}"
        );
        all = (all.0.min(lo), all.1.max(hi));
    }
    all
}

/// The scene `picker` holds, built afresh with `options`.
fn fresh_from(picker: &CpuPicker, options: &BuildOptions) -> BuiltScene {
    BuiltScene::new(picker.built().scene.clone(), options).unwrap()
}

#[test]
fn a_refitted_grid_tree_is_the_tree_a_fresh_grid_build_makes() {
    // The grid builder's shape depends on the grid alone: refitted, the tree (nodes,
    // triangles, ids, blocks) is the one a fresh build makes, as long as the origin stays.
    let mut scene = Scene::new();
    let grid = terrain(33, 29, 0.0, 0.0, 1.0, hills);
    let shape = raypick::scene::GridShape {
        columns: 33,
        rows: 29,
    };
    scene.add_grid_mesh("dem", grid, shape).unwrap();
    let options = BuildOptions {
        builder: Builder::Grid,
        ..BuildOptions::default()
    };
    let mut built = BuiltScene::new(scene, &options).unwrap();
    // New heights inside the old height range, so the bounds and the origin stay.
    let (lo, hi) = built.scene.bounds().unwrap();
    let positions: Vec<DVec3> = built
        .scene
        .object_vertices(0)
        .map(|v| {
            let p = built.scene.position(v);
            let z = lo.z + (hi.z - lo.z) * (0.5 + 0.45 * (p.x * 0.37 + p.y * 0.11).sin());
            DVec3::new(p.x, p.y, z)
        })
        .collect();
    let mut positions = positions;
    // Keep the extremes where they were so the bounds (and the origin) do not move.
    let (first, last) = (0, positions.len() - 1);
    positions[first].z = lo.z;
    positions[last].z = hi.z;
    assert_eq!(built.set_positions(0, &positions).unwrap(), Refit::Refitted);
    let want = BuiltScene::new(built.scene.clone(), &options).unwrap();
    assert_eq!(
        built.bvh.origin, want.bvh.origin,
        "the test keeps the origin"
    );
    assert!(built.bvh.nodes.as_slice() == want.bvh.nodes.as_slice());
    assert!(built.bvh.triangles.as_slice() == want.bvh.triangles.as_slice());
    assert!(built.bvh.triangle_ids.as_slice() == want.bvh.triangle_ids.as_slice());
    assert_eq!(built.bvh.blocks, want.bvh.blocks);
}

#[test]
fn a_triangle_becoming_degenerate_or_not_rebuilds_the_tree() {
    let options = BuildOptions::default();
    let built = Arc::new(BuiltScene::new(two_objects(), &options).unwrap());
    let mut cpu = CpuPicker::new(built.clone());
    let mut gpu = GpuPicker::new(common::gpu(), built).unwrap();
    // Triangle 0 of the sphere flattened to a point: it leaves the tree.
    let mut positions = moved(&cpu.built().scene, 0, 0.0);
    let [a, b, c] = cpu.built().scene.triangle_vertices(0);
    let first = cpu.built().scene.objects()[0].first_vertex;
    for v in [b, c] {
        positions[(v - first) as usize] = positions[(a - first) as usize];
    }
    let flattened = positions.clone();
    for picker in [&mut cpu as &mut dyn Picker, &mut gpu] {
        assert_eq!(picker.set_positions(0, &flattened).unwrap(), Refit::Rebuilt);
    }
    check_rebuilt(&mut cpu, &mut gpu, &options, 9);
    // Moved while it stays a point: the tree, which holds every triangle but that one, is
    // refitted (the refit counts the traceable ones in scene order first), and answers as a
    // new picker over it and the oracle do.
    let held = cpu.built().bvh.triangles.len();
    let shifted: Vec<DVec3> = flattened
        .iter()
        .map(|&p| p + DVec3::new(0.0, 0.0, 0.125))
        .collect();
    for picker in [&mut cpu as &mut dyn Picker, &mut gpu] {
        assert_eq!(picker.set_positions(0, &shifted).unwrap(), Refit::Refitted);
    }
    let refitted = cpu.built().clone();
    assert_eq!(refitted.bvh.triangles.len(), held);
    refitted.bvh.validate().unwrap();
    let rays = mixed_rays(&refitted.scene, 1000, 11);
    let plain_rays = plain(&rays);
    let mut new_reference = ReferencePicker::new(refitted.clone());
    assert_same("cpu", &mut cpu, &mut new_reference, &plain_rays);
    assert_same("gpu", &mut gpu, &mut new_reference, &plain_rays);
    common::assert_equivalent("refitted around a flat triangle", refitted, &rays);
    // And back: the triangle is traceable again, so the tree is built again.
    let original = two_objects();
    let restored: Vec<DVec3> = original
        .object_vertices(0)
        .map(|v| original.position(v) + DVec3::new(0.0, 0.0, 0.25))
        .collect();
    for picker in [&mut cpu as &mut dyn Picker, &mut gpu] {
        assert_eq!(picker.set_positions(0, &restored).unwrap(), Refit::Rebuilt);
    }
    check_rebuilt(&mut cpu, &mut gpu, &options, 10);
}

/// After a rebuild both pickers hold a tree a fresh build makes, and answer as a new picker
/// over a fresh build does, bit for bit.
fn check_rebuilt(cpu: &mut CpuPicker, gpu: &mut GpuPicker, options: &BuildOptions, seed: u64) {
    let want = Arc::new(fresh_from(cpu, options));
    assert!(cpu.built().bvh.nodes.as_slice() == want.bvh.nodes.as_slice());
    assert!(gpu.built().bvh.nodes.as_slice() == want.bvh.nodes.as_slice());
    let rays = mixed_rays(&want.scene, 1000, seed);
    let plain = plain(&rays);
    assert_same("cpu", cpu, &mut ReferencePicker::new(want.clone()), &plain);
    assert_same("gpu", gpu, &mut ReferencePicker::new(want.clone()), &plain);
    common::assert_equivalent("rebuilt", want, &rays);
}

#[test]
fn bad_positions_are_refused_and_change_nothing() {
    let built = Arc::new(BuiltScene::new(two_objects(), &BuildOptions::default()).unwrap());
    let rays = plain(&mixed_rays(&built.scene, 500, 3));
    let mut cpu = CpuPicker::new(built.clone());
    let before = cpu.pick(&rays).unwrap();
    let count = built.scene.object_vertices(0).len();
    let mut with_nan = moved(&built.scene, 0, 1.0);
    with_nan[7].y = f64::NAN;
    with_nan[count - 1].z = f64::INFINITY;
    for (positions, object, says) in [
        (vec![DVec3::ZERO; count - 1], 0, "positions given for its"),
        (with_nan, 0, "vertex 7 has a non-finite"),
        (vec![DVec3::ZERO; count], 9, "there is no object 9"),
    ] {
        let error = cpu
            .set_positions(object, &positions)
            .unwrap_err()
            .to_string();
        assert!(error.contains(says), "{error}");
    }
    assert_eq!(cpu.pick(&rays).unwrap(), before);
    assert!(
        Arc::ptr_eq(cpu.built(), &built),
        "a refused move copies nothing"
    );
}

/// Asserts that binary node `node`'s box (and every box below it) is exactly the min/max of
/// the triangles under it, and returns it.
fn binary_bounds(built: &BuiltScene, node: usize) -> (Vec3, Vec3) {
    let n = &built.bvh.nodes[node];
    let (lo, hi) = if n.is_leaf() {
        let first = n.first as usize;
        built.bvh.triangles[first..first + n.kind() as usize]
            .iter()
            .flat_map(|t| [t.v0, t.v1, t.v2])
            .map(Vec3::from)
            .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p), hi.max(p))
            })
    } else {
        let (l, r) = (
            binary_bounds(built, node + 1),
            binary_bounds(built, n.first as usize),
        );
        (l.0.min(r.0), l.1.max(r.1))
    };
    assert_eq!(
        (Vec3::from(n.min), Vec3::from(n.max)),
        (lo, hi),
        "binary node {node}"
    );
    (lo, hi)
}

#[test]
fn a_large_tree_refits_in_parallel_to_boxes_exact_for_its_new_triangles() {
    // Large enough that the binary refit splits into tasks over disjoint node and triangle
    // runs, and that the engine's tree was collapsed in pieces (its slots' sources too).
    let mut scene = Scene::new();
    scene
        .add_mesh("sphere", icosphere(DVec3::new(5.0, -5.0, 4.0), 2.5, 3))
        .unwrap();
    scene
        .add_mesh("terrain", terrain(180, 170, 0.0, 0.0, 0.25, hills))
        .unwrap();
    let mut built = BuiltScene::new(scene, &BuildOptions::default()).unwrap();
    assert!(
        built.bvh.nodes.len() >= 1 << 14,
        "{}",
        built.bvh.nodes.len()
    );
    let collapsed = built.wide().unwrap().clone();
    assert_eq!(collapsed.sources.len(), collapsed.nodes.len());
    for (round, object) in [(1.0, 1u32), (2.0, 0), (3.0, 1)] {
        let positions = moved(&built.scene, object, round);
        assert_eq!(
            built.set_positions(object, &positions).unwrap(),
            Refit::Refitted
        );
        // Every leaf-order triangle is its scene triangle rounded into the tree's frame.
        let origin = built.bvh.origin;
        for (t, &id) in built
            .bvh
            .triangles
            .iter()
            .zip(built.bvh.triangle_ids.iter())
        {
            let [v0, v1, v2] = built
                .scene
                .world_triangle(id as usize)
                .map(|p| <[f32; 3]>::from((p - origin).as_vec3()));
            assert_eq!(
                *t,
                GpuTriangle { v0, v1, v2 },
                "triangle {id}, round {round}"
            );
        }
        binary_bounds(&built, 0);
        let wide = built.wide().unwrap();
        wide_bounds(wide, &built.bvh.triangles, 0);
        // A wide tree without its sources (a saved scene's) refits to the same boxes.
        let mut unsourced = WideBvh {
            sources: Vec::new(),
            ..collapsed.clone()
        };
        unsourced.refit(&built.bvh);
        assert!(
            unsourced.nodes.as_slice() == wide.nodes.as_slice(),
            "round {round}"
        );
    }
}

/// Found by a fuzz of edit sequences: an object moved 10⁹ out was built again in a frame
/// centred between it and the rest, and moved back it was refitted in that frame (its
/// triangles stayed as flat as they were there), whose steps are 32 units wide where the scene
/// now is: 180 of 400 rays missed or hit wrongly on every backend, for good. A refit now keeps
/// its frame only while it reaches the scene at most 16 times as far as a frame at the scene's
/// centre; else the tree is built again, and answers as a fresh build does.
#[test]
fn an_object_moved_far_out_and_back_answers_as_a_fresh_build() {
    let options = BuildOptions::default();
    let built = Arc::new(BuiltScene::new(two_objects(), &options).unwrap());
    let mut cpu = CpuPicker::new(built.clone());
    let mut gpu = GpuPicker::new(common::gpu(), built.clone()).unwrap();
    let original: Vec<DVec3> = built
        .scene
        .object_vertices(0)
        .map(|v| built.scene.position(v))
        .collect();
    let rays = mixed_rays(&built.scene, 1000, 21);
    drop(built);
    for far in [1e8, 1e9, 1e10] {
        let out: Vec<DVec3> = original.iter().map(|&p| p + DVec3::X * far).collect();
        for picker in [&mut cpu as &mut dyn Picker, &mut gpu] {
            picker.set_positions(0, &out).unwrap();
            assert_eq!(
                picker.set_positions(0, &original).unwrap(),
                Refit::Rebuilt,
                "back from {far:e}"
            );
        }
        check_rebuilt(&mut cpu, &mut gpu, &options, 12);
        common::assert_equivalent(&format!("back from {far:e}"), cpu.built().clone(), &rays);
    }
    // A move that keeps the scene where it was is still a refit.
    let nudged: Vec<DVec3> = original.iter().map(|&p| p + DVec3::X * 0.5).collect();
    for picker in [&mut cpu as &mut dyn Picker, &mut gpu] {
        assert_eq!(picker.set_positions(0, &nudged).unwrap(), Refit::Refitted);
    }
}
