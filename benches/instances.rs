//! Issue 15's instancing targets, on 10,000 instances of the bunny (`tests/data/bunny.obj`, 3,674
//! triangles: 36.7M instanced triangles) on a 100 × 100 grid 1.25 bunny widths apart, each
//! stood up, turned about the vertical and scaled 0.8–1.2:
//!
//! - `instances/top_build`: the top tree over the 10,000 instances once the bunny's tree exists
//!   (`Instances::assemble`: world boxes, median cut, records, the combined node buffer);
//!   target ≤ 50 ms;
//! - bytes per instance beyond one bunny (`Instances::instance_bytes` ÷ instances: the f64
//!   instance with its name, its kernel record, its share of the top tree, binary and wide,
//!   its top leaf's index and its share of the hit ids' block table); target ≤ 100;
//! - `instances/pick_field` and `instances/pick_one`: CPU engine picks of 512 × 512 camera rays
//!   looking down on the field, and on one bunny alone (a scene of one bunny, no instances);
//!   target: the field ≥ 0.5× one bunny's rays per second;
//! - `instances/move_pick_cpu`: one instance moved (`Picker::edit` →
//!   `BuiltScene::set_instance_transform`) and one click picked again on the CPU engine; target
//!   ≤ 1 ms;
//! - `instances/move_pick_gpu`: the same on the GPU picker (lavapipe here), the round trip with
//!   the upload; target ≤ 5 ms;
//! - the corner instance moved out past the field's edge and back, a click picked after each
//!   move: each move leaves the edge of the bounds, which are worked out again from the top
//!   tree's leaf boxes and a few instances' exact boxes; and the same on a field on flat ground
//!   (every bunny at scale 1: they share their lowest z) (printed only).
//!
//! Before criterion runs it prints the medians of repeated runs and the ratios. Run with
//! `cargo bench --bench instances`.

#[path = "common/short_groups.rs"]
mod short_groups;
#[path = "common/timing.rs"]
mod timing;

use criterion::{Criterion, criterion_group, criterion_main};
use glam::{DMat3, DVec3};
use rand::Rng;
use raypick::apps::camera::Camera;
use raypick::check::synthetic::rng;
use raypick::instance::{Instance, Instances, MeshTree};
use raypick::io::obj::load_obj;
use raypick::{
    BuildOptions, BuiltScene, Bvh, CpuPicker, GpuContext, GpuPicker, Picker, Ray, Scene,
};
use short_groups::configure;
use std::hint::black_box;
use std::path::Path;
use std::sync::Arc;
use timing::median_ms;

const SIDE: usize = 100;
/// Grid step, in bunny widths: neighbours' boxes do not overlap.
const SPACING: f64 = 1.25;
const RAYS_SIDE: u32 = 512;

/// The bunny stood up (its y axis to z), turned by `angle` about z, scaled by `scale`, at
/// `at`.
fn placement(angle: f64, scale: f64, at: DVec3) -> [[f64; 4]; 3] {
    let stand = DMat3::from_cols(DVec3::X, DVec3::Z, DVec3::Y);
    let m = DMat3::from_rotation_z(angle) * stand * scale;
    let r = |k: usize| {
        let row = m.row(k);
        [row.x, row.y, row.z, at[k]]
    };
    [r(0), r(1), r(2)]
}

/// The field, `step` apart.
fn field(step: f64) -> Vec<Instance> {
    let mut g = rng(15);
    (0..SIDE * SIDE)
        .map(|k| {
            let at = DVec3::new((k % SIDE) as f64 * step, (k / SIDE) as f64 * step, 0.0);
            Instance {
                name: format!("bunny {k}"),
                mesh: 0,
                transform: placement(g.random_range(0.0..6.3), g.random_range(0.8..1.2), at),
                mask: u32::MAX,
            }
        })
        .collect()
}

/// Camera rays looking down on `bounds`.
fn camera_rays((min, max): (DVec3, DVec3)) -> Vec<Ray> {
    Camera::frame_from_above(min, max, RAYS_SIDE, RAYS_SIDE)
        .pixel_center_rays()
        .collect()
}

fn instances(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/bunny.obj");
    let bunny = load_obj(&path).expect("load the bunny");
    let mut mesh = Scene::new();
    mesh.add_mesh("bunny", bunny.clone()).unwrap();
    let options = BuildOptions::default();
    let tree = Arc::new(MeshTree::new(
        mesh.clone(),
        Bvh::build(&mesh, &options).unwrap(),
    ));
    let (lo, hi) = mesh.bounds().unwrap();
    let step = SPACING * (hi - lo).max_element();
    let placed = field(step);

    // The top tree once the bunny's tree exists.
    let top_ms = median_ms(15, || {
        black_box(Instances::assemble(vec![tree.clone()], placed.clone()).unwrap());
    });
    let built =
        Arc::new(BuiltScene::instanced(vec![mesh.clone()], placed.clone(), &options).unwrap());
    let i = built.instances().unwrap();
    let per_instance = i.instance_bytes() as f64 / placed.len() as f64;

    // One bunny alone, stood up as in the field.
    let mut one = Scene::new();
    one.add_mesh("bunny", bunny).unwrap();
    one.transform_object(0, &placement(0.3, 1.0, DVec3::ZERO))
        .unwrap();
    let one = Arc::new(BuiltScene::new(one, &options).unwrap());

    // Framed on the bunny's box corners through each placement (not on the scene's bounds,
    // which depend on how tightly the top tree boxes the instances).
    let corners = |m: [[f64; 4]; 3]| {
        (0..8).map(move |c| {
            let p = DVec3::new(
                if c & 1 == 0 { lo.x } else { hi.x },
                if c & 2 == 0 { lo.y } else { hi.y },
                if c & 4 == 0 { lo.z } else { hi.z },
            );
            DVec3::from_array(m.map(|r| r[0] * p.x + r[1] * p.y + r[2] * p.z + r[3]))
        })
    };
    let framed = placed
        .iter()
        .flat_map(|i| corners(i.transform))
        .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(a, b), p| {
            (a.min(p), b.max(p))
        });
    let field_rays = camera_rays(framed);
    let one_rays = camera_rays(one.bounds().unwrap());
    let mut field_picker = CpuPicker::new(built.clone());
    let mut one_picker = CpuPicker::new(one.clone());
    let field_answers = field_picker.pick(&field_rays).unwrap();
    let field_hits = field_answers.iter().filter(|h| h.hit).count();
    let stats = |hits: &[raypick::Hit]| {
        let n = hits.len().max(1) as f64;
        (
            hits.iter().map(|h| h.box_tests as f64).sum::<f64>() / n,
            hits.iter().map(|h| h.triangle_tests as f64).sum::<f64>() / n,
        )
    };
    eprintln!(
        "field: box tests, triangle tests per ray {:?}",
        stats(&field_answers)
    );
    let twin = raypick::ReferencePicker::new(built.clone())
        .pick(&field_rays[..4096])
        .unwrap();
    eprintln!("field, twin: {:?}", stats(&twin));
    let one_hits = one_picker
        .pick(&one_rays)
        .unwrap()
        .iter()
        .filter(|h| h.hit)
        .count();
    let field_ms = median_ms(7, || {
        black_box(field_picker.pick(&field_rays).unwrap());
    });
    let one_ms = median_ms(7, || {
        black_box(one_picker.pick(&one_rays).unwrap());
    });
    let n = field_rays.len() as f64;

    // One of the 10,000 moved, one click picked again.
    let mut k = 0u32;
    let mut g = rng(3);
    let moves: Vec<[[f64; 4]; 3]> = (0..64)
        .map(|j| {
            let side = step * SIDE as f64;
            let at = DVec3::new(g.random_range(0.0..side), g.random_range(0.0..side), 0.0);
            placement(j as f64 * 0.1, 1.0, at)
        })
        .collect();
    let click = |m: &[[f64; 4]; 3]| {
        let at = DVec3::new(m[0][3], m[1][3], 100.0);
        Ray::new(at, DVec3::NEG_Z)
    };
    let mut move_pick = |picker: &mut dyn Picker| {
        k = (k + 1) % moves.len() as u32;
        let m = moves[k as usize];
        let which = (k * 157) % (SIDE * SIDE) as u32;
        picker
            .edit(&mut |b| b.set_instance_transform(which, m))
            .unwrap();
        black_box(picker.pick(&[click(&m)]).unwrap());
    };
    let mut cpu = CpuPicker::new(built.clone());
    move_pick(&mut cpu);
    let move_cpu_ms = median_ms(101, || move_pick(&mut cpu));
    // The corner instance moved out past the field's edge and back: each move leaves the edge
    // of the bounds, which are worked out again (`Instances::set_transform`).
    let corner = placed[0].transform;
    let mut outside = corner;
    outside[0][3] -= step;
    outside[1][3] -= step;
    let mut out = false;
    let move_edge_ms = median_ms(101, || {
        out = !out;
        let m = if out { outside } else { corner };
        cpu.edit(&mut |b| b.set_instance_transform(0, m)).unwrap();
        black_box(cpu.pick(&[click(&m)]).unwrap());
    });
    // The same on flat ground: every bunny at scale 1, so all share their lowest z (and the
    // side they hold), which each move of the corner one leaves and finds again.
    let flat: Vec<Instance> = placed
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let at = DVec3::new(p.transform[0][3], p.transform[1][3], 0.0);
            Instance {
                transform: placement(k as f64 * 0.37, 1.0, at),
                ..p.clone()
            }
        })
        .collect();
    let flat_corner = flat[0].transform;
    let mut flat_outside = flat_corner;
    flat_outside[0][3] -= step;
    flat_outside[1][3] -= step;
    let mut flat_cpu = CpuPicker::new(Arc::new(
        BuiltScene::instanced(vec![mesh.clone()], flat, &options).unwrap(),
    ));
    let move_flat_ms = median_ms(101, || {
        out = !out;
        let m = if out { flat_outside } else { flat_corner };
        flat_cpu
            .edit(&mut |b| b.set_instance_transform(0, m))
            .unwrap();
        black_box(flat_cpu.pick(&[click(&m)]).unwrap());
    });
    let gpu = GpuContext::new()
        .and_then(|context| GpuPicker::new(&context, built.clone()))
        .ok();
    let mut gpu_line = String::from("no GPU adapter");
    let mut gpu = gpu;
    if let Some(gpu) = &mut gpu {
        move_pick(gpu);
        let ms = median_ms(31, || move_pick(gpu));
        gpu_line = format!("{ms:.3} ms on {} (target ≤ 5 ms)", gpu.context().describe());
    }

    println!(
        "instances: {} bunnies ({} instanced triangles), top tree {} nodes\n\
         top tree build {top_ms:.2} ms (target ≤ 50 ms, medians of 15)\n\
         bytes per instance beyond one bunny {per_instance:.0} (target ≤ 100)\n\
         pick, {} camera rays, {} threads: field {:.2} M rays/s ({field_hits} hits), one bunny \
         {:.2} M rays/s ({one_hits} hits): field ÷ one = {:.3} (target ≥ 0.5, medians of 7)\n\
         move one of 10,000 and pick a click again: cpu {move_cpu_ms:.3} ms (target ≤ 1 ms, \
         median of 101); gpu {gpu_line}\n\
         the corner one out past the edge and back, each move followed by a click: cpu \
         {move_edge_ms:.3} ms (median of 101); on flat ground (every lowest z shared): \
         {move_flat_ms:.3} ms",
        placed.len(),
        i.prim_count(),
        i.top_nodes(),
        field_rays.len(),
        rayon::current_num_threads(),
        n / field_ms / 1e3,
        n / one_ms / 1e3,
        one_ms / field_ms,
    );

    let mut group = c.benchmark_group("instances");
    configure(&mut group);
    group.bench_function("top_build", |b| {
        b.iter(|| black_box(Instances::assemble(vec![tree.clone()], placed.clone()).unwrap()))
    });
    group.bench_function("pick_field", |b| {
        b.iter(|| black_box(field_picker.pick(&field_rays).unwrap()))
    });
    group.bench_function("pick_one", |b| {
        b.iter(|| black_box(one_picker.pick(&one_rays).unwrap()))
    });
    group.bench_function("move_pick_cpu", |b| b.iter(|| move_pick(&mut cpu)));
    if let Some(gpu) = &mut gpu {
        group.bench_function("move_pick_gpu", |b| b.iter(|| move_pick(gpu)));
    }
    group.finish();
}

criterion_group!(benches, instances);
criterion_main!(benches);
