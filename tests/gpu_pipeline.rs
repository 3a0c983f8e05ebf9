//! Large batches through the GPU picker: rays copied into the GPU's staging memory and results
//! copied out of the mapped readback on all cores (batches from 1 MiB), and batches of several
//! dispatches with the host's conversion and refinement overlapped, give the twin's answers.

mod common;

use common::gpu;
use raypick::check::compare::differences;
use raypick::check::synthetic::mixed_rays;
use raypick::io::obj::load_obj;
use raypick::{
    BuildOptions, BuiltScene, GpuPicker, Mode, Picker, Query, Ray, ReferencePicker, Scene,
};
use std::path::Path;
use std::sync::Arc;

fn bunny() -> Arc<BuiltScene> {
    let mesh = load_obj(&Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/bunny.obj"))
        .expect("bunny");
    let scene = Scene::from_meshes([("bunny".to_string(), mesh)]).expect("scene");
    Arc::new(BuiltScene::new(scene, &BuildOptions::default()).expect("build"))
}

#[test]
fn batches_past_the_parallel_copies_and_in_overlapped_steps_give_the_twins_answers() {
    let built = bunny();
    // 40,000 rays: 1.9 MB of kernel rays, past the 1 MiB from which the copies run in parallel.
    let rays: Vec<Ray> = mixed_rays(&built.scene, 40_000, 9)
        .into_iter()
        .map(|(_, r)| r)
        .collect();
    let queries = [
        Query::default(),
        Query {
            mode: Mode::Any,
            ..Query::default()
        },
        // Lists of four 16-byte entries per ray: 2.5 MB copied out.
        Query {
            mode: Mode::All,
            max_hits: 4,
            ..Query::default()
        },
    ];
    let mut whole = GpuPicker::new(gpu(), built.clone()).expect("gpu");
    whole.set_reorder_from(usize::MAX);
    // Two steps of 25,000 and 15,000 rays: the first past 1 MiB, the second not.
    let mut stepped = GpuPicker::new(gpu(), built.clone()).expect("gpu");
    stepped.set_reorder_from(usize::MAX);
    stepped.set_chunk_rays(25_000);
    let mut twin = ReferencePicker::new(built);
    for query in queries {
        let reference = twin.query(&rays, &query).expect("reference");
        for (name, picker) in [("one dispatch", &mut whole), ("two steps", &mut stepped)] {
            let answers = picker.query(&rays, &query).expect("gpu");
            let differ = differences(query.mode, &answers, &reference);
            assert!(
                differ.is_empty(),
                "{name} {query:?}: {} rays differ from the twin, first {:?}",
                differ.len(),
                differ.first().map(|&i| rays[i])
            );
            if query.mode != Mode::Any {
                assert_eq!(
                    format!("{answers:?}"),
                    format!("{reference:?}"),
                    "{name} {query:?}: not the twin's bits"
                );
            }
        }
    }
}
