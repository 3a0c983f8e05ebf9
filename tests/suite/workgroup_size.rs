//! Every swept kernel workgroup size answers exactly as the CPU path does (zero mismatches, and
//! the same raw records bit for bit on a software adapter such as lavapipe, which rounds like
//! the CPU), and sizes the adapter cannot run are refused with `Error::WorkgroupSize`.

use crate::common;

use common::gpu;
use raypick::check::compare::compare_answers;
use raypick::check::synthetic::{hills, mixed_rays, terrain};
use raypick::gpu::picker::{SWEPT_WORKGROUP_SIZES, WORKGROUP_SIZE};
use raypick::io::obj::load_obj;
use raypick::{BuildOptions, BuiltScene, CpuPicker, Error, GpuPicker, Picker, Query, Scene};
use std::path::Path;
use std::sync::Arc;

/// Not a multiple of any swept size, so the last workgroup of every dispatch is partial.
const RAYS: usize = 3001;

fn scenes() -> Vec<(&'static str, Arc<BuiltScene>)> {
    let bunny = load_obj(&Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/bunny.obj"))
        .expect("bunny");
    [
        ("terrain", terrain(48, 40, 100.0, 200.0, 2.5, hills)),
        ("bunny", bunny),
    ]
    .into_iter()
    .map(|(name, mesh)| {
        let scene = Scene::from_meshes([(name.to_string(), mesh)]).expect("scene");
        let built = BuiltScene::new(scene, &BuildOptions::default()).expect("build");
        (name, Arc::new(built))
    })
    .collect()
}

#[test]
fn every_swept_workgroup_size_answers_as_the_cpu_path() {
    for (name, built) in scenes() {
        let rays: Vec<_> = mixed_rays(&built.scene, RAYS, 11)
            .into_iter()
            .map(|(_, r)| r)
            .collect();
        let query = Query::default();
        let cpu = CpuPicker::new(built.clone())
            .query(&rays, &query)
            .expect("cpu query");
        let mut first_size_hits = None;
        for size in SWEPT_WORKGROUP_SIZES {
            let mut picker =
                GpuPicker::with_workgroup_size(gpu(), built.clone(), size).expect("gpu picker");
            assert_eq!(picker.workgroup_size(), size);
            let answers = picker.query(&rays, &query).expect("gpu query");
            let (tally, bad) =
                compare_answers(&built.scene, &rays, query.mode, &answers, &cpu, None);
            eprintln!("{name}, workgroup {size}: {tally:?}");
            assert!(
                bad.is_empty(),
                "{name}, workgroup {size}: {} rays differ from the CPU path, first {:?}",
                bad.len(),
                bad.first()
                    .map(|&i| (&rays[i], &answers.nearest[i], &cpu.nearest[i]))
            );
            // Raw kernel records against the CPU twin's, bit for bit.
            let local =
                raypick::frame::local_rays(raypick::frame::Frame::at(built.bvh.origin), &rays);
            let settings = built.settings(&query);
            let (cpu_raw, _) = raypick::cpu::trace_batch(&built.bvh, &local, &settings);
            let (gpu_raw, _) = picker
                .trace_batch(&local, 0, settings.watertight)
                .expect("gpu trace");
            let differ = cpu_raw
                .iter()
                .zip(&gpu_raw)
                .filter(|(a, b)| bytemuck::bytes_of(*a) != bytemuck::bytes_of(*b))
                .count();
            eprintln!("{name}, workgroup {size}: {differ} raw records differ from the CPU's");
            // lavapipe rounds like the CPU path (0 of 3,001 differ at every size); a real GPU
            // may contract to FMA, so there only the answers above must agree.
            if gpu().is_software() {
                assert_eq!(differ, 0, "{name}, workgroup {size}: raw records differ");
            }
            // The size changes only how rays are grouped, never a ray's answer.
            let hits: Vec<_> = answers
                .nearest
                .iter()
                .map(|h| (h.hit, h.object, h.triangle, h.t.to_bits(), h.box_tests))
                .collect();
            match &first_size_hits {
                None => first_size_hits = Some(hits),
                Some(first) => assert!(
                    first == &hits,
                    "{name}: workgroup {size} answers differ from workgroup {}",
                    SWEPT_WORKGROUP_SIZES[0]
                ),
            }
        }
    }
}

#[test]
fn the_default_workgroup_size_is_the_plain_constructors() {
    let (_, built) = scenes().remove(0);
    let picker = GpuPicker::new(gpu(), built).expect("gpu picker");
    assert_eq!(picker.workgroup_size(), WORKGROUP_SIZE);
}

#[test]
fn workgroups_beyond_the_adapter_limits_are_refused() {
    let (_, built) = scenes().remove(0);
    let limits = gpu().device.limits();
    let too_many = limits
        .max_compute_invocations_per_workgroup
        .max(limits.max_compute_workgroup_size_x)
        + 1;
    for size in [0, too_many] {
        match GpuPicker::with_workgroup_size(gpu(), built.clone(), size) {
            Err(Error::WorkgroupSize { requested, .. }) => assert_eq!(requested, size),
            Err(other) => panic!("workgroup {size}: expected Error::WorkgroupSize, got {other}"),
            Ok(_) => panic!("workgroup {size}: accepted"),
        }
    }
}
