//! Saved built scenes (`.rpk`, issue 14 item 4): build → save → load answers every query bit for
//! bit as the scene it was saved from, on every backend (the CPU engine, the reference twin and
//! the GPU kernel), for the bunny, a real DEM built by the grid builder and a masked scene of
//! several objects. Every byte of a small file flipped, every truncation and another format
//! version give a clean error naming the file (or, where a flip changes nothing that matters,
//! the same answers), never a panic or a hang; a file whose flips are checksummed again is
//! refused by the structural checks or picks without error.

use crate::common;

use raypick::check::synthetic::{
    box_mesh, example_scene, hills, mixed_rays, terrain, thin_and_degenerate, triangle_soup,
};
use raypick::io::obj::load_obj;
use raypick::io::scene_files::{SceneFile, load_scene};
use raypick::rpk;
use raypick::{
    Answers, Backend, BuildOptions, BuiltScene, CpuPicker, Cull, GpuPicker, Hit, Intersector, Mode,
    Picker, Query, Ray, ReferencePicker, Scene, make_picker,
};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// A file of this test binary's own in the target's scratch folder.
fn scratch(name: &str) -> PathBuf {
    Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("rpk-{}-{name}", std::process::id()))
}

fn bunny() -> Scene {
    Scene::from_meshes([(
        "bunny".to_string(),
        load_obj(&data("bunny.obj")).expect("bunny"),
    )])
    .expect("scene")
}

/// The example scene (a terrain grid and two buildings), a triangle soup and thin and
/// degenerate triangles (left out of the tree, so its ids are a subset), each with its own
/// layer mask.
fn masked_scene(soup: usize) -> Scene {
    let mut scene = example_scene();
    scene
        .add_mesh("soup", triangle_soup(soup, 90.0, 3))
        .expect("soup");
    scene
        .add_mesh("thin", thin_and_degenerate(5))
        .expect("thin");
    for (id, mask) in [1, 2, 2, 4, 8].into_iter().enumerate() {
        scene.set_object_mask(id as u32, mask).expect("mask");
    }
    scene
}

/// A few hundred triangles of the same kinds: a small grid, a box, a soup and thin and
/// degenerate triangles, each with its own mask.
fn small_masked_scene() -> Scene {
    let mut scene = Scene::new();
    let (columns, rows) = (9, 8);
    scene
        .add_grid_mesh(
            "grid",
            terrain(columns, rows, 0.0, 10.0, 1.25, hills),
            raypick::GridShape {
                columns: columns as u32,
                rows: rows as u32,
            },
        )
        .expect("grid");
    let lo = glam::DVec3::new(2.0, 3.0, -1.0);
    scene.add_mesh("box", box_mesh(lo, lo + 2.5)).expect("box");
    scene
        .add_mesh("soup", triangle_soup(60, 10.0, 3))
        .expect("soup");
    scene
        .add_mesh("thin", thin_and_degenerate(5))
        .expect("thin");
    for (id, mask) in [1, 2, 4, 8].into_iter().enumerate() {
        scene.set_object_mask(id as u32, mask).expect("mask");
    }
    scene
}

/// A small height grid alone: built by the grid builder, so its file has terrain blocks.
fn small_grid() -> Scene {
    let mut scene = Scene::new();
    let (columns, rows) = (14, 12);
    scene
        .add_grid_mesh(
            "grid",
            terrain(columns, rows, 0.0, 20.0, 1.5, hills),
            raypick::GridShape {
                columns: columns as u32,
                rows: rows as u32,
            },
        )
        .expect("grid");
    scene
}

/// Rays of every kind; some with layer masks when `masks` holds.
fn rays(scene: &Scene, count: usize, masks: bool) -> Vec<Ray> {
    mixed_rays(scene, count, 11)
        .into_iter()
        .enumerate()
        .map(|(i, (_, r))| {
            if masks {
                r.with_mask([u32::MAX, 1, 2, 3, 4, 8, 0, 6][i % 8])
            } else {
                r
            }
        })
        .collect()
}

/// The queries every backend answers: both intersectors, any hit, all hits with culling.
fn queries() -> Vec<Query> {
    vec![
        Query::default(),
        Query {
            intersector: Intersector::MollerTrumbore,
            ..Query::default()
        },
        Query {
            mode: Mode::Any,
            cull: Cull::Front,
            ..Query::default()
        },
        Query {
            mode: Mode::All,
            max_hits: 6,
            cull: Cull::Back,
            ..Query::default()
        },
    ]
}

/// Every field of a hit as bits (t, u, v, object, triangle, cell, position, normal, and the
/// box and triangle test counts, which equal trees also share).
fn bits(h: &Hit) -> [u64; 16] {
    let cell = h
        .cell
        .map_or(u64::MAX, |[r, c]| u64::from(r) << 32 | u64::from(c));
    [
        u64::from(h.hit),
        u64::from(h.invalid),
        h.t.to_bits(),
        h.u.to_bits(),
        h.v.to_bits(),
        u64::from(h.object),
        u64::from(h.triangle),
        cell,
        h.position.x.to_bits(),
        h.position.y.to_bits(),
        h.position.z.to_bits(),
        h.normal.x.to_bits(),
        h.normal.y.to_bits(),
        h.normal.z.to_bits(),
        u64::from(h.box_tests),
        u64::from(h.triangle_tests),
    ]
}

fn assert_same_answers(what: &str, a: &Answers, b: &Answers) {
    assert_eq!(a.nearest.len(), b.nearest.len(), "{what}: answer count");
    for (i, (x, y)) in a.nearest.iter().zip(&b.nearest).enumerate() {
        assert_eq!(bits(x), bits(y), "{what}: ray {i}: {x:?} vs {y:?}");
    }
    assert_eq!(a.list_start, b.list_start, "{what}: list lengths");
    assert_eq!(a.overflow, b.overflow, "{what}: overflow flags");
    for (i, (x, y)) in a.lists.iter().zip(&b.lists).enumerate() {
        assert_eq!(bits(x), bits(y), "{what}: list entry {i}");
    }
}

/// The loaded scene holds exactly what was saved.
fn assert_same_scene(name: &str, saved: &BuiltScene, loaded: &BuiltScene) {
    let (s, l) = (&saved.scene, &loaded.scene);
    assert_eq!(s.positions(), l.positions(), "{name}: positions");
    assert_eq!(s.triangles(), l.triangles(), "{name}: triangles");
    assert_eq!(s.objects(), l.objects(), "{name}: objects");
    assert_eq!(s.bounds(), l.bounds(), "{name}: bounds");
    assert_eq!(s.origin(), l.origin(), "{name}: origin");
    let (sb, lb) = (&saved.bvh, &loaded.bvh);
    assert_eq!(sb.origin, lb.origin, "{name}: tree origin");
    assert_eq!(sb.nodes, lb.nodes, "{name}: nodes");
    assert_eq!(sb.triangles, lb.triangles, "{name}: leaf triangles");
    assert_eq!(sb.triangle_ids, lb.triangle_ids, "{name}: triangle ids");
    assert_eq!(sb.blocks, lb.blocks, "{name}: blocks");
    assert_eq!(saved.triangle_masks, loaded.triangle_masks, "{name}: masks");
    let (sw, lw) = (saved.wide().expect("wide"), loaded.wide().expect("wide"));
    assert_eq!(sw.nodes, lw.nodes, "{name}: wide nodes");
    assert_eq!(sw.depth, lw.depth, "{name}: wide depth");
    // What loading does not check again (the checksums cover it) holds for a saved file.
    lb.validate().unwrap_or_else(|e| panic!("{name}: {e}"));
    lw.validate(lb.triangles.len()).expect("the wide tree");
    rpk::validate::tree_links(lb).expect("the links");
}

/// Saves `built`, loads it back and checks the scene and every query's answers on every
/// backend against the original. Returns the loaded scene.
fn round_trip(name: &str, built: BuiltScene, rays: &[Ray]) -> Arc<BuiltScene> {
    let path = scratch(&format!("{name}.rpk"));
    rpk::save(&built, &path).expect("save");
    assert!(rpk::is_rpk(&path), "{name}: is_rpk");
    let loaded = rpk::load(&path).expect("load");
    // SAFETY: the test's own file, never written again; removing it (below) leaves the map
    // whole, as replacing a saved scene does.
    let in_place = unsafe { rpk::load_in_place(&path) }.expect("load in place");
    std::fs::remove_file(&path).expect("remove the file");
    assert_same_scene(name, &built, &loaded);
    assert_same_scene(&format!("{name} (in place)"), &built, &in_place);
    // The copy owns its arrays; the in-place load views the file for every array it holds.
    let wide = |b: &BuiltScene| b.wide().expect("wide").nodes.clone();
    let arrays = |b: &BuiltScene| {
        [
            (b.bvh.nodes.is_empty(), b.bvh.nodes.is_mapped()),
            (b.bvh.triangles.is_empty(), b.bvh.triangles.is_mapped()),
            (
                b.bvh.triangle_ids.is_empty(),
                b.bvh.triangle_ids.is_mapped(),
            ),
            (b.triangle_masks.is_empty(), b.triangle_masks.is_mapped()),
            (wide(b).is_empty(), wide(b).is_mapped()),
        ]
    };
    for (k, ((_, copied), (empty, mapped))) in arrays(&loaded)
        .into_iter()
        .zip(arrays(&in_place))
        .enumerate()
    {
        assert!(!copied, "{name}: array {k} of the copied load is a view");
        assert!(
            mapped || empty,
            "{name}: array {k} of the in-place load is a copy"
        );
    }
    let (saved, loaded, in_place) = (Arc::new(built), Arc::new(loaded), Arc::new(in_place));
    type Make = fn(Arc<BuiltScene>) -> Box<dyn Picker>;
    let backends: [(&str, Make); 3] = [
        ("cpu", |b| Box::new(CpuPicker::new(b))),
        ("reference", |b| Box::new(ReferencePicker::new(b))),
        ("gpu", |b| {
            Box::new(GpuPicker::new(common::gpu(), b).expect("gpu picker"))
        }),
    ];
    for (backend, make) in backends {
        let (mut a, mut b) = (make(saved.clone()), make(loaded.clone()));
        let mut c = make(in_place.clone());
        for query in queries() {
            let what = format!("{name}, {backend}, {query:?}");
            let before = a.query(rays, &query).expect("query the saved scene");
            let after = b.query(rays, &query).expect("query the loaded scene");
            assert!(
                before.nearest.iter().any(|h| h.hit),
                "{what}: the rays hit nothing"
            );
            assert_same_answers(&what, &before, &after);
            let viewed = c.query(rays, &query).expect("query the scene in place");
            assert_same_answers(&format!("{what} (in place)"), &before, &viewed);
        }
    }
    loaded
}

#[test]
fn the_bunny_answers_the_same_after_a_round_trip_on_every_backend() {
    let scene = bunny();
    let rays = rays(&scene, 3000, false);
    let built = BuiltScene::new(scene, &BuildOptions::default()).expect("build");
    let loaded = round_trip("bunny", built, &rays);
    // The factory the command line and the server use takes a loaded scene as it is, the GPU
    // included.
    for backend in [Backend::Cpu, Backend::Reference, Backend::Gpu] {
        let hits = make_picker(backend, loaded.clone())
            .expect("picker")
            .pick(&rays)
            .expect("pick");
        assert!(hits.iter().any(|h| h.hit), "{backend:?}");
    }
}

#[test]
fn a_dem_keeps_its_blocks_rows_and_columns_after_a_round_trip() {
    let scene = load_scene(&[SceneFile {
        file: data("jacksboro_fault_dem_utm.asc"),
        mask: None,
        transform: None,
    }])
    .expect("jacksboro");
    let rays = rays(&scene, 2000, false);
    let built = BuiltScene::new(scene, &BuildOptions::default()).expect("build");
    assert!(built.bvh.blocks.len() > 1, "the grid builder made blocks");
    let loaded = round_trip("jacksboro", built, &rays);
    let hits = CpuPicker::new(loaded).pick(&rays).expect("pick");
    assert!(hits.iter().any(|h| h.hit && h.cell.is_some()), "cells");
}

#[test]
fn a_masked_scene_of_several_objects_answers_the_same_after_a_round_trip() {
    let scene = masked_scene(2000);
    let rays = rays(&scene, 3000, true);
    let built = BuiltScene::new(scene, &BuildOptions::default()).expect("build");
    assert!(!built.triangle_masks.is_empty(), "the scene has masks");
    assert!(
        built.bvh.triangle_ids.len() < built.scene.triangle_count(),
        "some triangles are left out of the tree"
    );
    let loaded = round_trip("masked", built, &rays);
    assert_eq!(loaded.scene.objects()[4].name, "thin");
}

#[test]
fn other_builders_and_an_empty_scene_round_trip() {
    let scene = masked_scene(300);
    let rays = rays(&scene, 500, true);
    for builder in [raypick::Builder::BinnedSah, raypick::Builder::MedianCut] {
        let options = BuildOptions {
            builder,
            leaf_size: 3,
            ..BuildOptions::default()
        };
        let built = BuiltScene::new(scene.clone(), &options).expect("build");
        round_trip(&format!("{builder:?}"), built, &rays);
    }
    let empty = BuiltScene::new(Scene::new(), &BuildOptions::default()).expect("build");
    let path = scratch("empty.rpk");
    rpk::save(&empty, &path).expect("save");
    let loaded = Arc::new(rpk::load(&path).expect("load"));
    std::fs::remove_file(&path).expect("remove");
    let hits = CpuPicker::new(loaded).pick(&rays).expect("pick");
    assert!(hits.iter().all(|h| !h.hit));
}

/// A small saved file: its name, the scene saved, the file's bytes and rays to pick it with.
type SmallFile = (String, Arc<BuiltScene>, Vec<u8>, Vec<Ray>);

/// The small files the corruption tests flip and cut: a masked scene of several objects
/// (median cut) and a lone grid (grid builder, with a block), a few hundred triangles each.
fn small_files(test: &str) -> Vec<SmallFile> {
    [
        ("masked", small_masked_scene(), true),
        ("grid", small_grid(), false),
    ]
    .into_iter()
    .map(|(name, scene, masks)| {
        let rays = rays(&scene, 64, masks);
        let built = BuiltScene::new(scene, &BuildOptions::default()).expect("build");
        let path = scratch(&format!("small-{test}-{name}.rpk"));
        rpk::save(&built, &path).expect("save");
        let bytes = std::fs::read(&path).expect("read back");
        std::fs::remove_file(&path).expect("remove");
        (name.to_string(), Arc::new(built), bytes, rays)
    })
    .collect()
}

/// Runs `work`, failing the test if it takes longer than `limit` (a hang).
fn within(limit: Duration, work: impl FnOnce() + Send + 'static) {
    let (done, finished) = std::sync::mpsc::channel();
    let worker = std::thread::spawn(move || {
        work();
        let _ = done.send(());
    });
    match finished.recv_timeout(limit) {
        Ok(()) => worker.join().expect("the work panicked"),
        // The sender is gone without a message: the work panicked; show its panic.
        Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => {
            worker.join().expect("the work panicked")
        }
        Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
            panic!("still running after {limit:?}: a hang")
        }
    }
}

/// An error from loading `name` is one sentence that names it.
fn assert_clean_error(name: &Path, e: &raypick::Error, what: &str) {
    let text = e.to_string();
    assert!(
        text.starts_with(&format!("{}: ", name.display())) && !text.contains('\n'),
        "{what}: {text}"
    );
}

#[test]
fn every_byte_flipped_gives_a_clean_error_or_the_same_answers() {
    within(Duration::from_secs(600), || {
        for (name, built, bytes, rays) in small_files("flips") {
            let path = PathBuf::from(format!("{name}.rpk"));
            let expected = CpuPicker::new(built.clone()).pick(&rays).expect("pick");
            let (mut refused, mut same) = (0, 0);
            for i in 0..bytes.len() {
                for flip in [0xFF, 1 << (i % 8)] {
                    let mut changed = bytes.clone();
                    changed[i] ^= flip;
                    match rpk::from_bytes(&path, &changed) {
                        Err(e) => {
                            assert_clean_error(&path, &e, &format!("{name}: byte {i} ^ {flip:#x}"));
                            refused += 1;
                        }
                        Ok(loaded) => {
                            let hits = CpuPicker::new(Arc::new(loaded)).pick(&rays).expect("pick");
                            let (a, b): (Vec<_>, Vec<_>) = (
                                expected.iter().map(bits).collect(),
                                hits.iter().map(bits).collect(),
                            );
                            assert_eq!(a, b, "{name}: byte {i} ^ {flip:#x} was accepted");
                            same += 1;
                        }
                    }
                }
            }
            eprintln!(
                "{name}: {} bytes, {refused} flips refused, {same} accepted with the same answers",
                bytes.len()
            );
        }
    });
}

#[test]
fn flipped_files_on_disk_are_refused_by_load() {
    for (name, _, bytes, _) in small_files("disk") {
        let path = scratch(&format!("flipped-{name}.rpk"));
        for i in (0..bytes.len()).step_by(97) {
            let mut changed = bytes.clone();
            changed[i] ^= 0x20;
            std::fs::write(&path, &changed).expect("write");
            let e = rpk::load(&path).expect_err("a flipped byte is refused");
            assert_clean_error(&path, &e, &format!("{name}: byte {i}"));
            // SAFETY: the test's own file, not written while loaded.
            let e = unsafe { rpk::load_in_place(&path) }.expect_err("refused in place too");
            assert_clean_error(&path, &e, &format!("{name}: byte {i}, in place"));
        }
        std::fs::remove_file(&path).expect("remove");
    }
}

#[test]
fn every_truncation_is_a_clean_error() {
    within(Duration::from_secs(600), || {
        for (name, _, bytes, _) in small_files("cuts") {
            let path = PathBuf::from(format!("{name}.rpk"));
            for length in 0..bytes.len() {
                let e = rpk::from_bytes(&path, &bytes[..length]).expect_err("a cut file");
                assert_clean_error(&path, &e, &format!("{name} cut to {length} bytes"));
                assert!(
                    e.to_string().contains("truncated"),
                    "{name} cut to {length}: {e}"
                );
            }
            // Through the file system too, at a sample of lengths (the header's first).
            let file = scratch(&format!("cut-{name}.rpk"));
            for length in (0..64).chain((64..bytes.len()).step_by(211)) {
                std::fs::write(&file, &bytes[..length]).expect("write");
                let e = rpk::load(&file).expect_err("a cut file");
                assert!(
                    e.to_string().contains("truncated"),
                    "{name} cut to {length}: {e}"
                );
                assert_clean_error(&file, &e, &format!("{name} cut to {length} bytes"));
                // SAFETY: the test's own file, not written while loaded.
                let e = unsafe { rpk::load_in_place(&file) }.expect_err("a cut file in place");
                assert!(e.to_string().contains("truncated"), "{name} in place: {e}");
            }
            // Bytes past the end are refused as well.
            let mut longer = bytes.clone();
            longer.extend_from_slice(&[0; 16]);
            let e = rpk::from_bytes(&path, &longer).expect_err("a longer file");
            assert!(e.to_string().contains("more than"), "{e}");
            std::fs::remove_file(&file).expect("remove");
        }
    });
}

#[test]
fn another_format_version_is_named_in_the_error() {
    let (_, _, bytes, _) = small_files("version").swap_remove(1);
    let path = scratch("other-version.rpk");
    for version in [1, rpk::VERSION + 1] {
        let mut other = bytes.clone();
        other[8..12].copy_from_slice(&version.to_le_bytes());
        rpk::write::reseal(&mut other);
        std::fs::write(&path, &other).expect("write");
        let e = rpk::load(&path).expect_err("another version");
        assert_clean_error(&path, &e, "another version");
        let text = e.to_string();
        assert!(
            text.contains(&format!("format version {version}"))
                && text.contains(&format!("reads version {}", rpk::VERSION)),
            "{text}"
        );
    }
    // A version changed by corruption (its header checksum not matching) is corruption.
    let mut flipped = bytes.clone();
    flipped[8] ^= 2;
    let e = rpk::from_bytes(&path, &flipped).expect_err("a flipped version");
    assert!(e.to_string().contains("header fails its checksum"), "{e}");
    // Not a saved scene at all.
    let e = rpk::load(&data("bunny.obj")).expect_err("an OBJ");
    assert!(e.to_string().contains("not a raypick saved scene"), "{e}");
    assert!(!rpk::is_rpk(&data("bunny.obj")));
    assert!(!rpk::is_rpk(&scratch("does-not-exist.rpk")));
    let e = rpk::load(&scratch("does-not-exist.rpk")).expect_err("a missing file");
    assert!(e.to_string().contains("does-not-exist.rpk"), "{e}");
    std::fs::remove_file(&path).expect("remove");
}

/// The payload range of section `tag` in a saved file's bytes.
fn section(bytes: &[u8], tag: &[u8; 4]) -> std::ops::Range<usize> {
    let mut at = 32;
    loop {
        let start = rpk::payload_start(at);
        let header = start - 16;
        let length = u64::from_le_bytes(bytes[header + 8..start].try_into().unwrap()) as usize;
        if &bytes[header..header + 4] == tag {
            return start..start + length;
        }
        at = start + length.next_multiple_of(rpk::ALIGN);
    }
}

/// Found by `cargo fuzz run rpk` (fuzz/artifacts/rpk/crash-8297eaa3…): a grid object of
/// 2³² − 1 × 2³² − 1 samples overflowed the check of its triangle count.
#[test]
fn a_grid_too_large_for_any_triangle_count_is_refused() {
    let (_, _, bytes, _) = small_files("huge-grid").swap_remove(1);
    let objects = section(&bytes, b"OBJS");
    for (columns, rows) in [(u32::MAX, u32::MAX), (u32::MAX, 2), (0, u32::MAX)] {
        let mut changed = bytes.clone();
        changed[objects.start + 24..objects.start + 28].copy_from_slice(&columns.to_le_bytes());
        changed[objects.start + 28..objects.start + 32].copy_from_slice(&rows.to_le_bytes());
        rpk::write::reseal(&mut changed);
        let path = Path::new("grid.rpk");
        let e = rpk::from_bytes(path, &changed).expect_err("a grid of the wrong size");
        assert_clean_error(path, &e, "a huge grid");
        assert!(e.to_string().contains("grid with"), "{e}");
    }
}

/// Found by a review: a grid object's shape was checked against its triangles only, so a file
/// whose 14 × 12 grid claimed 2 × 144 samples (the same 286 triangles) loaded, and `viewshed`,
/// `los` and `render` read its samples by row and column past its vertices (a panic); a grid
/// of 2³² − 1 × 1 samples and no triangles made `viewshed` ask for 4 GiB. Every grid's vertices
/// are now its samples.
#[test]
fn a_grid_whose_shape_disagrees_with_its_vertices_is_refused() {
    let (_, _, bytes, _) = small_files("grid-vertices").swap_remove(1);
    let objects = section(&bytes, b"OBJS");
    let field =
        |b: &[u8], at: usize| u32::from_le_bytes(b[objects.start + at..][..4].try_into().unwrap());
    assert_eq!(
        (field(&bytes, 24), field(&bytes, 28)),
        (14, 12),
        "the small grid"
    );
    for (columns, rows, triangles) in [
        (2u32, 144u32, None),
        (144, 2, None),
        (u32::MAX, 1, Some(0u32)),
    ] {
        let mut changed = bytes.clone();
        changed[objects.start + 24..objects.start + 28].copy_from_slice(&columns.to_le_bytes());
        changed[objects.start + 28..objects.start + 32].copy_from_slice(&rows.to_le_bytes());
        if let Some(count) = triangles {
            changed[objects.start + 8..objects.start + 12]
                .copy_from_slice(&u32::to_le_bytes(count));
        }
        rpk::write::reseal(&mut changed);
        let path = Path::new("grid.rpk");
        let e = rpk::from_bytes(path, &changed).expect_err("a grid of other samples");
        assert_clean_error(path, &e, "a grid of other samples");
        let said = e.to_string();
        assert!(
            said.contains("grid with") && (said.contains("vertices") || triangles.is_some()),
            "{said}"
        );
    }
    // The same shape swapped (12 × 14: as many samples and triangles) stays in bounds: it loads.
    let mut swapped = bytes.clone();
    swapped[objects.start + 24..objects.start + 28].copy_from_slice(&12u32.to_le_bytes());
    swapped[objects.start + 28..objects.start + 32].copy_from_slice(&14u32.to_le_bytes());
    rpk::write::reseal(&mut swapped);
    rpk::from_bytes(Path::new("swapped.rpk"), &swapped).expect("as many samples");
    // And a scene is never given such a grid.
    let mut scene = Scene::new();
    let mesh = terrain(14, 12, 0.0, 20.0, 1.5, hills);
    let e = scene
        .add_grid_mesh(
            "grid",
            mesh,
            raypick::GridShape {
                columns: 2,
                rows: 144,
            },
        )
        .expect_err("a grid of other samples");
    assert!(
        e.to_string()
            .contains("a 2×144 grid has 288 vertices, but the mesh has 168"),
        "{e}"
    );
}

/// Found by `cargo fuzz run rpk` (fuzz/artifacts/rpk/crash-27ba6e8a…): a summary section
/// shorter than its record was read past its end. Here it is cut to nothing, the file's
/// length and checksums made right.
#[test]
fn a_summary_of_the_wrong_length_is_refused() {
    let (_, _, bytes, _) = small_files("short-summary").swap_remove(1);
    let summary = section(&bytes, b"SUMM");
    assert_eq!(
        summary.len() % rpk::ALIGN,
        0,
        "the summary needs no padding"
    );
    for keep in [0, 16, 112] {
        let mut changed = bytes[..summary.start].to_vec();
        changed[summary.start - 8..summary.start].copy_from_slice(&(keep as u64).to_le_bytes());
        changed.extend_from_slice(&bytes[summary.start..summary.start + keep]);
        changed.resize(summary.start + keep.next_multiple_of(rpk::ALIGN), 0);
        changed.extend_from_slice(&bytes[summary.end..]);
        let length = changed.len() as u64;
        changed[16..24].copy_from_slice(&length.to_le_bytes());
        rpk::write::reseal(&mut changed);
        let path = Path::new("short.rpk");
        let e = rpk::from_bytes(path, &changed).expect_err("a short summary");
        assert_clean_error(path, &e, "a short summary");
        assert!(e.to_string().contains("SUMM (summary) holds"), "{e}");
    }
}

/// A mutation round found four checks no test needed: a resealed file whose one field breaks
/// exactly one invariant must be refused by the check that owns it, in its own words. The
/// masked file (objects grid, box, soup, thin; layer masks) and the lone grid (no masks).
#[test]
fn resealed_files_that_break_one_invariant_are_refused_by_its_check() {
    let mut files = small_files("one-invariant");
    let (_, grid, grid_bytes, _) = files.swap_remove(1);
    let (_, masked, masked_bytes, _) = files.swap_remove(0);
    let word = |b: &[u8], at: usize| u32::from_le_bytes(b[at..at + 4].try_into().unwrap());
    let refused = |bytes: &[u8], at: usize, value: u32, says: &str| {
        let mut changed = bytes.to_vec();
        changed[at..at + 4].copy_from_slice(&value.to_le_bytes());
        rpk::write::reseal(&mut changed);
        let path = Path::new("one.rpk");
        let e = rpk::from_bytes(path, &changed).expect_err(says);
        assert_clean_error(path, &e, says);
        assert!(e.to_string().contains(says), "expected “{says}”: {e}");
    };

    // A leaf-order triangle's mask that is not its object's.
    let masks = section(&masked_bytes, b"MASK");
    let ids = &masked.bvh.triangle_ids;
    assert_eq!(masks.len(), 4 * ids.len(), "one mask per leaf triangle");
    let first = word(&masked_bytes, masks.start);
    refused(
        &masked_bytes,
        masks.start,
        first ^ 16,
        "leaf-order triangle 0's mask is not its object's",
    );

    // A triangle of the box (object 1) using a vertex of the grid (object 0).
    let triangles = section(&masked_bytes, b"TRIS");
    let box_first = masked.scene.objects()[1].first_triangle as usize;
    assert!(word(&masked_bytes, triangles.start + 12 * box_first) >= 72);
    refused(
        &masked_bytes,
        triangles.start + 12 * box_first,
        0,
        &format!("triangle {box_first} uses a vertex outside its object's"),
    );

    // A scene triangle in two leaves (the grid has no masks to disagree first).
    let grid_ids = section(&grid_bytes, b"TIDS");
    let id0 = word(&grid_bytes, grid_ids.start);
    assert_eq!(id0, grid.bvh.triangle_ids[0]);
    refused(
        &grid_bytes,
        grid_ids.start + 4,
        id0,
        &format!("scene triangle {id0} is in the tree twice"),
    );

    // A child whose parent link points elsewhere: node 1 (the root's left child) said to be
    // node 2's, its kind kept.
    let nodes = section(&grid_bytes, b"NODE");
    let parent_kind = word(&grid_bytes, nodes.start + 32 + 12);
    assert_eq!(parent_kind >> 5, 0, "node 1's parent is the root");
    refused(
        &grid_bytes,
        nodes.start + 32 + 12,
        (2 << 5) | (parent_kind & 31),
        "node 1's parent link is 2, not 0",
    );
}

/// Flips with the checksums made right again: only the structural checks stand between the
/// bytes and the walks. Each is refused cleanly, or loads and picks without a panic, a hang or
/// a traversal error on the CPU engine and the reference twin.
#[test]
fn resealed_flips_are_refused_by_the_checks_or_pick_safely() {
    within(Duration::from_secs(600), || {
        for (name, _, bytes, rays) in small_files("resealed") {
            let path = PathBuf::from(format!("{name}.rpk"));
            let (mut refused, mut accepted) = (0, 0);
            for i in 0..bytes.len() {
                for flip in [0xFF, 1 << (i % 8)] {
                    let mut changed = bytes.clone();
                    changed[i] ^= flip;
                    rpk::write::reseal(&mut changed);
                    match rpk::from_bytes(&path, &changed) {
                        Err(e) => {
                            assert_clean_error(&path, &e, &format!("{name}: byte {i} ^ {flip:#x}"));
                            refused += 1;
                        }
                        Ok(loaded) => {
                            let loaded = Arc::new(loaded);
                            for query in [Query::default(), queries()[3]] {
                                CpuPicker::new(loaded.clone())
                                    .query(&rays, &query)
                                    .expect("the engine picks");
                                ReferencePicker::new(loaded.clone())
                                    .query(&rays, &query)
                                    .expect("the twin picks");
                            }
                            accepted += 1;
                        }
                    }
                }
            }
            eprintln!("{name}: resealed flips: {refused} refused, {accepted} accepted");
            assert!(refused > 0 && accepted > 0);
        }
    });
}

/// What a saved scene holds, and how fast it loads: the dragon (`RPK_BENCH` names another OBJ)
/// and four copies of it side by side (about the 871k-triangle dragon's size).
#[test]
#[ignore = "a measurement: cargo test --release --test suite -- --ignored --nocapture rpk::"]
fn loading_a_saved_dragon_is_fast() {
    let obj = std::env::var_os("RPK_BENCH").map_or_else(
        || Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/dragon_res2.obj"),
        PathBuf::from,
    );
    let mesh = load_obj(&obj).expect("the dragon");
    let size = {
        let (lo, hi) = mesh.positions.iter().fold(
            (glam::DVec3::INFINITY, glam::DVec3::NEG_INFINITY),
            |(lo, hi), p| (lo.min(*p), hi.max(*p)),
        );
        hi - lo
    };
    for copies in [1usize, 4] {
        let mut scene = Scene::new();
        for k in 0..copies {
            let mut m = mesh.clone();
            for p in &mut m.positions {
                p.x += k as f64 * size.x * 1.1;
            }
            scene.add_mesh(format!("dragon {k}"), m).expect("scene");
        }
        let triangles = scene.triangle_count();
        let start = Instant::now();
        let built = BuiltScene::new(scene, &BuildOptions::default()).expect("build");
        built.wide().expect("wide");
        let build = start.elapsed();
        let path = scratch(&format!("dragon-{copies}.rpk"));
        let start = Instant::now();
        rpk::save(&built, &path).expect("save");
        let save = start.elapsed();
        let bytes = std::fs::metadata(&path).expect("size").len();
        let mut times = Vec::new();
        for _ in 0..7 {
            let start = Instant::now();
            let loaded = rpk::load(&path).expect("load");
            times.push(start.elapsed());
            drop(loaded);
        }
        times.sort();
        let rays = rays(&built.scene, 4096, false);
        let loaded = Arc::new(rpk::load(&path).expect("load"));
        let a = CpuPicker::new(Arc::new(built)).pick(&rays).expect("pick");
        let b = CpuPicker::new(loaded).pick(&rays).expect("pick");
        assert_eq!(
            a.iter().map(bits).collect::<Vec<_>>(),
            b.iter().map(bits).collect::<Vec<_>>()
        );
        if std::env::var_os("RPK_KEEP").is_none() {
            std::fs::remove_file(&path).expect("remove");
        } else {
            eprintln!("kept {}", path.display());
        }
        eprintln!(
            "{copies} × {}: {triangles} triangles, build {build:.1?}, save {save:.1?}, file {:.1} MB, \
             load min {:.2?} median {:.2?} max {:.2?} ({:.0} MB/s at the median)",
            obj.display(),
            bytes as f64 / 1e6,
            times[0],
            times[times.len() / 2],
            times[times.len() - 1],
            bytes as f64 / 1e6 / times[times.len() / 2].as_secs_f64()
        );
    }
}

/// One load of the file `RPK_FILE` in a process that does nothing else (the first load of a
/// process pays for fresh memory): `RPK_KEEP=1` keeps the files of the measurement above.
#[test]
#[ignore = "a measurement: RPK_FILE=x.rpk cargo test --release --test suite -- --ignored --nocapture rpk::one_load"]
fn one_load_in_a_fresh_process() {
    let path = PathBuf::from(std::env::var_os("RPK_FILE").expect("RPK_FILE names a .rpk file"));
    let start = Instant::now();
    let loaded = rpk::load(&path).expect("load");
    let load = start.elapsed();
    eprintln!(
        "{}: {} triangles, loaded in {load:.2?}",
        path.display(),
        loaded.scene.triangle_count()
    );
}

/// The fuzz seeds `fuzz/make_seeds.py` writes from the format's description alone (an
/// independent writer) load and pick: `python3 fuzz/make_seeds.py` first.
#[test]
#[ignore = "needs the seeds: python3 fuzz/make_seeds.py, then --ignored"]
fn the_python_seed_writer_agrees_with_the_reader() {
    let folder = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus/rpk");
    for name in ["empty", "one_triangle", "masks", "grid"] {
        let path = folder.join(format!("{name}.rpk"));
        let built = Arc::new(rpk::load(&path).unwrap_or_else(|e| panic!("{e}")));
        let rays = rays(&built.scene, 200, true);
        let hits = CpuPicker::new(built.clone()).pick(&rays).expect("pick");
        let reference = ReferencePicker::new(built.clone())
            .pick(&rays)
            .expect("pick");
        // The same answers; the walks' box and triangle test counts differ.
        let answer = |h: &Hit| bits(h)[..14].to_vec();
        assert_eq!(
            hits.iter().map(answer).collect::<Vec<_>>(),
            reference.iter().map(answer).collect::<Vec<_>>()
        );
        // The Python writer's tree is the one raypick builds and collapses for that scene
        // wherever the builder would split the same way; its collapse at least must match.
        let collapsed = raypick::engine::WideBvh::collapse(&built.bvh).expect("collapse");
        assert_eq!(collapsed.nodes, built.wide().expect("wide").nodes, "{name}");
        eprintln!(
            "{name}: {} objects, {} triangles, {} nodes, {} hits",
            built.scene.objects().len(),
            built.scene.triangle_count(),
            built.bvh.nodes.len(),
            hits.iter().filter(|h| h.hit).count()
        );
    }
}

/// A description (and its copy of the bunny, beside it) listing the bunny `count` times, 20
/// units apart along x.
fn bunny_listings(stem: &str, count: usize) -> (PathBuf, PathBuf) {
    let description = scratch(&format!("{stem}.json"));
    let mesh = scratch(&format!("{stem}.obj"));
    std::fs::copy(data("bunny.obj"), &mesh).unwrap();
    let name = mesh.file_name().unwrap().to_str().unwrap();
    let listings: Vec<String> = (0..count)
        .map(|k| {
            format!(
                r#"{{"file": {name:?}, "transform": [[1, 0, 0, {}], [0, 1, 0, 0], [0, 0, 1, 0]]}}"#,
                20 * k
            )
        })
        .collect();
    std::fs::write(
        &description,
        format!(r#"{{"objects": [{}]}}"#, listings.join(", ")),
    )
    .unwrap();
    (description, mesh)
}

/// `raypick render` of an 8 × 8 view of the scene `path` (given after `flag`) under the memory
/// budget `budget`: its exit code and standard error.
fn tiny_render(flag: &str, path: &str, budget: &str) -> (i32, String) {
    let (code, _, err) = common::raypick(&[
        "render",
        flag,
        path,
        "--max-memory",
        budget,
        "--width",
        "8",
        "--height",
        "8",
        "--out",
        "-",
    ]);
    (code, err)
}

/// A saved scene of 2,000 bunny instances (7.3M triangles as copies) rendered under a 256 MiB
/// budget: the command bakes the instances into copies, which is refused before the copies are
/// made (they were allocated first, and the budget only checked at the tree's build).
#[test]
fn baking_a_saved_instanced_scene_is_checked_against_the_budget() {
    let (description, mesh) = bunny_listings("many-bunnies", 2000);
    let saved = scratch("many-bunnies.rpk");
    let (description, saved) = (description.to_str().unwrap(), saved.to_str().unwrap());
    let (code, _, err) = common::raypick(&["build", "-q", "--scenes", description, "--out", saved]);
    assert_eq!(code, 0, "{err}");
    let (code, err) = tiny_render("--scene", saved, "256M");
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("baking the saved instances into copies would need"),
        "{err}"
    );
    let _ = std::fs::remove_file(saved);
    let _ = std::fs::remove_file(&mesh);
}

/// The same refusal for a description read as copies (`render --scenes`): it named the sum at
/// the listing where the budget was crossed ("would need 8.0 MiB …, over the memory budget of
/// 8.0 MiB"), which, given as the budget, failed again; it names the whole scene's need now.
#[test]
fn copying_a_listed_file_names_what_the_whole_scene_needs() {
    let (description, mesh) = bunny_listings("copied-bunnies", 200);
    for budget in ["8M", "40M"] {
        let (code, err) = tiny_render("--scenes", description.to_str().unwrap(), budget);
        assert_eq!(code, 2, "{err}");
        assert!(
            err.contains(
                "the triangles of the scene's 200 listings (a file listed again is copied), \
                 counting the files read so far, would need 72.9 MiB (734800 × 104 bytes)"
            ),
            "{err}"
        );
    }
    let _ = std::fs::remove_file(&mesh);
}
