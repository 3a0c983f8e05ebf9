//! Fuzzes the saved-scene reader, `raypick::rpk::from_bytes` (what `raypick::rpk::load` runs
//! on the mapped file: header, sections, checksums, then the structural checks).
//!
//! Each input is read twice: as it is, so the header, length and checksum checks are fuzzed;
//! and with its checksums recomputed (`raypick::rpk::write::reseal`), so that mutations reach
//! the structural checks instead of stopping at a checksum (as the `png16` target fixes PNG
//! CRCs). An error must be one line naming the file. A scene that loads is picked by the CPU
//! engine (its walk for the tree's size, and the interleaved walk) and the reference twin in
//! every query mode, and all must answer without error: the
//! checks promise trees the walks can take (no read out of range, no hang, no iteration cap).
//! Instanced scenes (`raypick::rpk::instanced`) go the same way: their instances, names and
//! each mesh's nested saved scene.
#![no_main]

use std::path::Path;
use std::sync::Arc;

use libfuzzer_sys::fuzz_target;
use raypick::{BuiltScene, CpuPicker, Cull, DVec3, Mode, Picker, Query, Ray, ReferencePicker, rpk};

fuzz_target!(|data: &[u8]| {
    check(data);
    let mut sealed = data.to_vec();
    rpk::write::reseal(&mut sealed);
    if sealed != data {
        check(&sealed);
    }
});

fn check(bytes: &[u8]) {
    let path = Path::new("fuzz.rpk");
    let result = rpk::from_bytes(path, bytes);
    raypick_fuzz::debug(&result, |b: &BuiltScene| {
        format!(
            "{} objects, {} triangles, {} nodes, {} wide nodes",
            b.object_count(),
            b.world_triangle_count(),
            b.bvh.nodes.len(),
            b.wide().map_or(0, |w| w.nodes.len())
        )
    });
    match result {
        Err(e) => {
            let text = e.to_string();
            assert!(
                text.starts_with("fuzz.rpk: ") && !text.contains('\n'),
                "an error that does not name the file in one line: {text}"
            );
        }
        Ok(built) => pick(Arc::new(built)),
    }
}

/// Rays at the scene from its bounds' corners, faces and centre, in every mode.
fn pick(built: Arc<BuiltScene>) {
    let (lo, hi) = built
        .bounds()
        .unwrap_or((DVec3::splat(-1.0), DVec3::splat(1.0)));
    let centre = lo + (hi - lo) * 0.5;
    let mut rays = Vec::new();
    for k in 0..8 {
        let corner = DVec3::new(
            if k & 1 == 0 { lo.x } else { hi.x },
            if k & 2 == 0 { lo.y } else { hi.y },
            if k & 4 == 0 { lo.z } else { hi.z },
        );
        let from = centre + (corner - centre) * 2.0 + DVec3::splat(1e-3);
        rays.push(Ray::new(from, centre - from).with_mask(if k == 3 { 1 } else { u32::MAX }));
    }
    for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
        let reach = (hi - lo).max_element().max(1.0) * 2.0;
        rays.push(Ray::new(centre - axis * reach, axis));
        rays.push(Ray::new(centre + axis * reach, -axis));
    }
    rays.push(Ray::new(centre, DVec3::new(0.3, -0.5, 0.8)));
    let queries = [
        Query::default(),
        Query {
            mode: Mode::Any,
            cull: Cull::Back,
            ..Query::default()
        },
        Query {
            mode: Mode::All,
            max_hits: 4,
            ..Query::default()
        },
    ];
    for query in &queries {
        for interleave in [None, Some(true)] {
            let mut engine = CpuPicker::new(built.clone());
            engine.set_interleave(interleave);
            engine
                .query(&rays, query)
                .expect("the CPU engine picks a scene that loaded");
        }
        ReferencePicker::new(built.clone())
            .query(&rays, query)
            .expect("the reference twin picks a scene that loaded");
    }
}
