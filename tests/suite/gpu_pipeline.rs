//! Large batches through the GPU picker: rays copied into the GPU's staging memory and results
//! copied out of the mapped readback by several threads (from 1 MiB), and batches of several
//! dispatches with the host's conversion and refinement overlapped, give the twin's answers;
//! the overlapped pipeline refuses a tracer that fails or answers short; a picker remade over
//! another scene on the same device (the server's rebuilding edits) answers as a new one; the
//! process's pickers share one device, and each device compiles the kernel once.

use crate::common;

use common::gpu;
use raypick::auto::AutoPicker;
use raypick::check::compare::differences;
use raypick::check::synthetic::example_scene;
use raypick::check::synthetic::mixed_rays;
use raypick::cpu::TraceSettings;
use raypick::gpu::picker::{WORKGROUP_SIZE, needs_exact_arithmetic};
use raypick::io::obj::load_obj;
use raypick::layout::{GpuHit, GpuHitEntry, GpuRay};
use raypick::picker::Tracer;
use raypick::{
    Answers, Backend, BuildOptions, BuiltScene, CpuPicker, Error, GpuContext, GpuPicker, Mode,
    Picker, Query, Ray, ReferencePicker, Scene, make_picker,
};
use std::path::Path;
use std::sync::Arc;

fn bunny() -> Arc<BuiltScene> {
    let mesh = load_obj(&Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/bunny.obj"))
        .expect("bunny");
    let scene = Scene::from_meshes([("bunny".to_string(), mesh)]).expect("scene");
    Arc::new(BuiltScene::new(scene, &BuildOptions::default()).expect("build"))
}

/// The built-in example scene (terrain and buildings), built.
fn example() -> Arc<BuiltScene> {
    Arc::new(BuiltScene::new(example_scene(), &BuildOptions::default()).expect("build"))
}

fn rays(built: &BuiltScene, count: usize) -> Vec<Ray> {
    mixed_rays(&built.scene, count, 9)
        .into_iter()
        .map(|(_, r)| r)
        .collect()
}

/// Every query mode, all-hits lists of four 16-byte entries per ray.
fn queries() -> [Query; 3] {
    common::every_mode(4)
}

/// `answers` are the twin's: bit for bit, but only hit or miss in any-hit mode.
fn assert_twins(what: &str, query: &Query, rays: &[Ray], answers: &Answers, twin: &Answers) {
    let differ = differences(query.mode, answers, twin);
    assert!(
        differ.is_empty(),
        "{what} {query:?}: {} rays differ from the twin, first {:?}",
        differ.len(),
        differ.first().map(|&i| rays[i])
    );
    if query.mode != Mode::Any {
        assert_eq!(
            format!("{answers:?}"),
            format!("{twin:?}"),
            "{what} {query:?}: not the twin's bits"
        );
    }
}

#[test]
fn batches_past_the_parallel_copies_and_in_overlapped_steps_give_the_twins_answers() {
    let built = bunny();
    // 100,000 rays: 4.8 MB of kernel rays, 3.2 MB of results and, in all-hits mode, 6.4 MB of
    // lists; in steps of 33,000 rays each full step copies 1.58 MB in and 1.06 MB out, past the
    // 1 MiB from which the copies run on several threads.
    let rays = rays(&built, 100_000);
    let mut whole = GpuPicker::new(gpu(), built.clone()).expect("gpu");
    whole.set_reorder_from(usize::MAX);
    let mut stepped = GpuPicker::new(gpu(), built.clone()).expect("gpu");
    stepped.set_reorder_from(usize::MAX);
    stepped.set_chunk_rays(33_000);
    let mut twin = ReferencePicker::new(built);
    for query in queries() {
        let reference = twin.query(&rays, &query).expect("reference");
        let one = whole.query(&rays, &query).expect("gpu, one dispatch");
        assert_twins("one dispatch", &query, &rays, &one, &reference);
        let steps = stepped.query(&rays, &query).expect("gpu, in steps");
        assert_twins("in steps", &query, &rays, &steps, &reference);
        // The same kernel on the same rays: the same bits in every mode, any-hit too.
        assert_eq!(format!("{steps:?}"), format!("{one:?}"), "{query:?}");
        // On a pool of one thread the overlapped host work runs after each step: the same.
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .expect("pool");
        let alone = pool.install(|| stepped.query(&rays, &query).expect("gpu, one thread"));
        assert_eq!(format!("{alone:?}"), format!("{one:?}"), "{query:?}");
    }
}

/// The twin as a tracer that overlaps steps of 1,000 rays, and on its `fail_at`-th step
/// fails (`short`: false) or answers one ray short (`short`: true).
struct Flaky {
    twin: ReferencePicker,
    steps: usize,
    fail_at: usize,
    short: bool,
}

impl Tracer for Flaky {
    fn built(&self) -> &Arc<BuiltScene> {
        Tracer::built(&self.twin)
    }

    fn built_mut(&mut self) -> &mut Arc<BuiltScene> {
        self.twin.built_mut()
    }

    fn trace(
        &mut self,
        rays: &[GpuRay],
        settings: &TraceSettings<'_>,
    ) -> raypick::Result<(Vec<GpuHit>, Vec<GpuHitEntry>)> {
        self.steps += 1;
        let (mut hits, lists) = self.twin.trace(rays, settings)?;
        if self.steps == self.fail_at {
            if !self.short {
                return Err(Error::Gpu("the device was lost".into()));
            }
            hits.pop();
        }
        Ok((hits, lists))
    }

    fn reorder_from(&self) -> usize {
        usize::MAX
    }

    fn overlap_step(&self) -> Option<usize> {
        Some(1000)
    }

    fn path_name(&self) -> String {
        "flaky".into()
    }
}

#[test]
fn an_overlapping_tracer_that_fails_or_answers_short_fails_the_pick() {
    let built = bunny();
    let rays = rays(&built, 4500);
    let twin = || ReferencePicker::new(built.clone());
    let reference = twin().query(&rays, &Query::default()).expect("reference");
    let flaky = |fail_at, short| Flaky {
        twin: twin(),
        steps: 0,
        fail_at,
        short,
    };
    // Healthy: five overlapped steps give the twin's answers.
    let mut healthy = flaky(0, false);
    let answers = healthy.query(&rays, &Query::default()).expect("healthy");
    assert_eq!(healthy.steps, 5);
    assert_twins("healthy", &Query::default(), &rays, &answers, &reference);
    for (fail_at, short) in [(1, false), (3, false), (5, false), (2, true), (5, true)] {
        let mut tracer = flaky(fail_at, short);
        let mut answers = Answers::default();
        let result = tracer.query_into(&rays, &Query::default(), &mut answers);
        assert!(result.is_err(), "step {fail_at}, short {short}: no error");
        assert!(
            answers.nearest.is_empty(),
            "step {fail_at}: answers left behind"
        );
        if short {
            let message = result.unwrap_err().to_string();
            assert!(message.contains("results for a step of"), "{message}");
        }
    }
}

/// Möller–Trumbore on the GPU gives the twin's bits on a ray through the midpoint of a shared
/// terrain edge (found by `raypick verify --random 8000 --mode all --max-hits 3 --cull front
/// --intersector moller-trumbore`, an edge-midpoint ray): on lavapipe the kernel, with the
/// hardware's arithmetic, reported triangle 9682 where the twin and the engine report 9681. On an
/// adapter whose arithmetic the kernel does not trust (every one but llvmpipe) only its own
/// exact arithmetic is checked: the picker never runs the hardware's there.
#[test]
fn moller_trumbore_through_a_shared_terrain_edge_gives_the_twins_triangle() {
    use raypick::glam::DVec3;
    use raypick::{CpuPicker, Intersector};
    let built = Arc::new(
        BuiltScene::new(
            raypick::check::synthetic::example_scene(),
            &BuildOptions::default(),
        )
        .expect("build"),
    );
    let rays = [Ray::new(
        DVec3::new(122.63800912899664, 48.96183905863657, -112.48016798082583),
        DVec3::new(-31.638009128996643, -4.461839058636571, 119.66226225083899),
    )];
    for mode in [Mode::Closest, Mode::All] {
        let query = Query {
            mode,
            intersector: Intersector::MollerTrumbore,
            ..Query::default()
        };
        let twin = ReferencePicker::new(built.clone())
            .query(&rays, &query)
            .unwrap();
        let engine = CpuPicker::new(built.clone()).query(&rays, &query).unwrap();
        assert!(differences(mode, &engine, &twin).is_empty());
        assert_eq!(
            (twin.nearest[0].object, twin.nearest[0].triangle),
            (0, 9681)
        );
        // The hardware's own arithmetic (`exact` false) only where the picker would use it:
        // on an NVIDIA H200 it changed this ray's all-hits list (the nearest stayed 9681), as
        // the picker's documentation says a GPU that fuses or divides to 2.5 ulp may.
        let own_arithmetic = [true, false];
        let checked = if needs_exact_arithmetic(gpu()) {
            &own_arithmetic[..1]
        } else {
            &own_arithmetic[..]
        };
        for &exact in checked {
            let mut kernel = GpuPicker::with_options(gpu(), built.clone(), 64, exact).unwrap();
            let answers = kernel.query(&rays, &query).unwrap();
            assert_eq!(
                (answers.nearest[0].object, answers.nearest[0].triangle),
                (0, 9681),
                "{mode:?}, the kernel's own arithmetic {exact}"
            );
            assert_twins(&format!("exact {exact}"), &query, &rays, &answers, &twin);
        }
    }
}

#[test]
fn a_picker_remade_over_another_scene_keeps_its_device_and_answers_as_a_new_one() {
    let (first, second) = (bunny(), example());
    let (first_rays, second_rays) = (rays(&first, 3000), rays(&second, 3000));
    let mut old = GpuPicker::new(gpu(), first.clone()).expect("gpu picker");
    let before: Vec<Answers> = queries()
        .iter()
        .map(|q| old.query(&first_rays, q).expect("pick"))
        .collect();
    // The device and the kernel are this picker's; only the scene's buffers are new.
    let over = old.over(second.clone()).expect("remade");
    assert!(over.context().device == old.context().device);
    let mut remade = old
        .remake(second.clone())
        .expect("a GPU picker remakes itself")
        .expect("remade");
    let mut fresh = GpuPicker::new(gpu(), second.clone()).expect("gpu picker");
    let mut twin = ReferencePicker::new(second.clone());
    let mut auto = AutoPicker::new(first.clone());
    let mut auto_remade = auto
        .remake(second.clone())
        .expect("an automatic picker with a device remakes itself")
        .expect("remade");
    assert_eq!(
        auto_remade.describe(),
        AutoPicker::new(second.clone()).describe()
    );
    for (q, before) in queries().iter().zip(&before) {
        let want = twin.query(&second_rays, q).expect("twin");
        let fresh = fresh.query(&second_rays, q).expect("fresh");
        assert_twins("a new picker", q, &second_rays, &fresh, &want);
        let got = remade.query(&second_rays, q).expect("remade");
        assert_twins("the remade picker", q, &second_rays, &got, &want);
        // The automatic picker answers these batches on the CPU (the engine's own statistics).
        let got = auto_remade.query(&second_rays, q).expect("auto remade");
        let engine = CpuPicker::new(second.clone())
            .query(&second_rays, q)
            .expect("cpu");
        assert_twins(
            "the remade automatic picker",
            q,
            &second_rays,
            &got,
            &engine,
        );
        // The picker it was made from still answers for its own scene.
        let again = old.query(&first_rays, q).expect("old");
        assert_twins("the old picker", q, &first_rays, &again, before);
        let cpu = CpuPicker::new(first.clone())
            .query(&first_rays, q)
            .expect("cpu");
        assert_twins(
            "the old automatic picker",
            q,
            &first_rays,
            &auto.query(&first_rays, q).expect("auto"),
            &cpu,
        );
    }
    // A CPU picker keeps nothing worth remaking: the factory makes a new one.
    assert!(CpuPicker::new(first).remake(second).is_none());
}

#[test]
fn pickers_share_the_process_device_and_each_device_compiles_the_kernel_once() {
    let shared = GpuContext::shared().expect("device");
    assert!(GpuContext::shared().expect("device").device == shared.device);
    // The factory's GPU pickers are made on it, and answer as pickers on a device of their own.
    let (first, second) = (bunny(), example());
    let own = GpuContext::new().expect("a device of its own");
    for built in [&first, &second] {
        let rays = rays(built, 2000);
        let mut made = make_picker(Backend::Gpu, built.clone()).expect("gpu picker");
        let mut alone = GpuPicker::new(&own, built.clone()).expect("gpu picker");
        for q in &queries() {
            let want = alone.query(&rays, q).expect("alone");
            let got = made.query(&rays, q).expect("shared");
            assert_twins("a picker on the shared device", q, &rays, &got, &want);
        }
    }
    // Two scenes' pickers on one device: one kernel; another workgroup size: a second.
    assert_eq!(own.compiled_kernels(), 1);
    let size = if WORKGROUP_SIZE == 64 { 32 } else { 64 };
    GpuPicker::with_workgroup_size(&own, first.clone(), size).expect("gpu picker");
    GpuPicker::new(&own, second).expect("gpu picker");
    assert_eq!(own.compiled_kernels(), 2);
}

/// A GPU picker on the process's shared device whose device is lost (a driver reset; here
/// `Device::destroy`) makes itself again on the shared device opened anew, and says so: the
/// next pick (in overlapped steps too), an edit, a picker remade over another scene, a second
/// picker on the same device and the automatic picker all answer as before, and each loss's
/// note names the opening. A picker on a device the caller brought says `DeviceLost` with the
/// reason, pick after pick and edit after edit (that device is the caller's to replace). In a
/// process of its own: the shared device is the whole test binary's.
#[test]
fn a_picker_on_the_lost_shared_device_opens_it_again() {
    gpu();
    crate::run_child_test(
        std::process::Command::new(std::env::current_exe().unwrap()),
        module_path!(),
        "child_loses_the_shared_device",
    );
}

#[test]
#[ignore = "run by a_picker_on_the_lost_shared_device_opens_it_again, in a process of its own"]
fn child_loses_the_shared_device() {
    // Not beside other tests: it destroys the device they share.
    if std::env::var_os(crate::CHILD_TEST).is_none() {
        return;
    }
    let (first, second) = (bunny(), example());
    let (first_rays, second_rays) = (rays(&first, 3000), rays(&second, 3000));
    let twin = |built: &Arc<BuiltScene>, rays: &[Ray], q: &Query| {
        ReferencePicker::new(built.clone())
            .query(rays, q)
            .expect("twin")
    };
    let lose = |context: &GpuContext| {
        context.device.destroy();
        // Reported once the work it had ends.
        let _ = context.device.poll(wgpu::PollType::wait_indefinitely());
        assert!(context.is_lost(), "a destroyed device is lost");
    };
    let lost_note = |notes: &[String], opening: u32| {
        let want = format!("opened {opening} times in this process");
        assert!(
            notes.len() == 1
                && notes[0].contains("the GPU device was lost and opened again")
                && notes[0].contains(&want),
            "{notes:?}"
        );
    };
    // Overlapped steps of 512 rays: the pipeline that waits on the device step by step.
    let mut picker =
        GpuPicker::new(&GpuContext::shared().expect("device"), first.clone()).expect("gpu picker");
    picker.set_chunk_rays(512);
    let mut other = make_picker(Backend::Gpu, first.clone()).expect("gpu picker");
    let mut auto = AutoPicker::new(first.clone());
    auto.set_crossover(0);
    let own = GpuContext::new().expect("a device of its own");
    let mut brought = GpuPicker::new(&own, first.clone()).expect("gpu picker");
    for q in &queries() {
        let want = twin(&first, &first_rays, q);
        for (what, p) in [
            ("before", &mut picker as &mut dyn Picker),
            ("another", other.as_mut()),
            ("auto", &mut auto),
            ("brought", &mut brought),
        ] {
            assert_twins(
                what,
                q,
                &first_rays,
                &p.query(&first_rays, q).expect(what),
                &want,
            );
        }
    }
    assert!(Picker::take_notes(&mut picker).is_empty());
    auto.take_notes();

    // The next picks, on the shared device opened again: each picker remakes itself on it.
    lose(&GpuContext::shared().expect("device"));
    for q in &queries() {
        let want = twin(&first, &first_rays, q);
        for (what, p) in [
            ("after the loss", &mut picker as &mut dyn Picker),
            ("another after the loss", other.as_mut()),
            ("auto after the loss", &mut auto),
        ] {
            let got = p.query(&first_rays, q).expect(what);
            assert_twins(what, q, &first_rays, &got, &want);
        }
    }
    lost_note(&Picker::take_notes(&mut picker), 2);
    lost_note(&other.take_notes(), 2);
    lost_note(&auto.take_notes(), 2);
    let reopened = GpuContext::shared().expect("device");
    // (Devices of two wgpu instances cannot be told apart by `==`: each numbers its own.)
    assert!(
        !reopened.is_lost(),
        "the shared device was not opened again"
    );
    assert_eq!(reopened.compiled_kernels(), 1);

    // An edit on the lost device (the masks change: new buffers), after a pick that found the
    // loss: both notes are kept, and the picker answers with the masks.
    lose(&reopened);
    let masked = Query::default();
    picker
        .query(&first_rays, &masked)
        .expect("a pick after the loss");
    picker
        .set_mask(0, 2)
        .expect("an edit (new buffers) after the pick");
    lose(&GpuContext::shared().expect("device"));
    picker.set_mask(0, 2).expect("an edit after the loss");
    let got = picker.query(&first_rays, &masked).expect("gpu");
    let mut edited = ReferencePicker::new(first.clone());
    edited.set_mask(0, 2).expect("twin edit");
    let want = edited.query(&first_rays, &masked).expect("twin");
    assert_twins(
        "after an edit on the lost device",
        &masked,
        &first_rays,
        &got,
        &want,
    );
    let notes = Picker::take_notes(&mut picker);
    assert_eq!(notes.len(), 2, "{notes:?}");
    lost_note(&notes[..1], 3);
    lost_note(&notes[1..], 4);

    // A picker remade over another scene (the server's rebuilding edits).
    lose(&GpuContext::shared().expect("device"));
    let mut remade = picker
        .remake(second.clone())
        .expect("a GPU picker remakes")
        .expect("remade after the loss");
    for q in &queries() {
        let got = remade.query(&second_rays, q).expect("gpu");
        let want = twin(&second, &second_rays, q);
        assert_twins("remade after the loss", q, &second_rays, &got, &want);
    }
    lost_note(&remade.take_notes(), 5);

    // A device the caller brought is not replaced: each use says it was lost, and why.
    lose(&own);
    for _ in 0..2 {
        let e = brought
            .query(&first_rays, &Query::default())
            .expect_err("a pick on a lost device of the caller's");
        assert!(
            matches!(&e, Error::DeviceLost(why) if why == "it was destroyed"),
            "{e}"
        );
        let e = brought.set_mask(0, 2).expect_err("an edit on it");
        assert!(matches!(e, Error::DeviceLost(_)), "{e}");
        let e = brought
            .remake(second.clone())
            .expect("a GPU picker remakes")
            .err()
            .expect("no picker remade on it");
        assert!(matches!(e, Error::DeviceLost(_)), "{e}");
    }
    assert!(Picker::take_notes(&mut brought).is_empty());
}
