//! GPU limits: a scene larger than the adapter's storage-binding limit is refused with an error
//! that names the limit and the size (never truncated), and ray batches are chunked to fit.

use raypick::check::synthetic::{RayKind, hills, rays, terrain, triangle_soup};
use raypick::{BuildOptions, BuiltScene, CpuPicker, Error, GpuContext, GpuPicker, Picker, Scene};
use std::sync::Arc;

/// A device whose storage bindings may hold at most `bytes`.
fn small_device(bytes: u64) -> GpuContext {
    let mut descriptor = wgpu::InstanceDescriptor::new_without_display_handle();
    descriptor.backends = wgpu::Backends::PRIMARY;
    let instance = wgpu::Instance::new(descriptor);
    let adapter =
        pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions::default()))
            .expect("GPU tests need a GPU adapter (install Mesa lavapipe)");
    let mut limits = adapter.limits();
    limits.max_storage_buffer_binding_size = bytes;
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("small"),
        required_limits: limits,
        ..Default::default()
    }))
    .expect("device with lowered limits");
    GpuContext::from_device(device, queue, adapter.get_info())
}

fn built(mesh: raypick::Mesh) -> Arc<BuiltScene> {
    let scene = Scene::from_meshes([("m".to_string(), mesh)]).unwrap();
    Arc::new(BuiltScene::new(scene, &BuildOptions::default()).unwrap())
}

#[test]
fn a_scene_over_the_binding_limit_is_refused_by_name() {
    let context = small_device(1 << 20);
    let big = built(triangle_soup(60_000, 100.0, 1)); // 60k × 36 B = 2.1 MB of triangles
    let error = GpuPicker::new(&context, big).err().expect("refused");
    assert!(
        matches!(
            error,
            Error::TooLargeForGpu {
                limit: 1_048_576,
                ..
            }
        ),
        "{error:?}"
    );
    let message = error.to_string();
    assert!(
        message.contains("max_storage_buffer_binding_size") && message.contains("1048576"),
        "{message}"
    );
}

#[test]
fn ray_batches_are_chunked_to_the_binding_limit() {
    let context = small_device(1 << 20); // at most 21,845 rays of 48 B per chunk
    let scene = built(terrain(40, 40, 0.0, 39.0, 1.0, hills));
    let batch = rays(&scene.scene, RayKind::Random, 100_000, 4);
    let gpu = GpuPicker::new(&context, scene.clone())
        .unwrap()
        .pick(&batch)
        .unwrap();
    let cpu = CpuPicker::new(scene.clone()).pick(&batch).unwrap();
    assert_eq!(gpu.len(), cpu.len());
    let (tally, _) = raypick::check::compare::Tally::compare(&scene.scene, &batch, &gpu, &cpu);
    assert_eq!(tally.mismatches, 0, "{tally:?}");
    assert!(gpu.iter().filter(|h| h.hit).count() > 10_000);
}

/// Issue 11: one all-hits request with a long list used to leave the picker with buffers sized
/// for that list, so every later larger batch built a bind group over the binding limit and
/// failed ("BindGroup with 'pick' label is invalid") until restart.
#[test]
fn a_long_all_hits_list_never_breaks_later_requests() {
    use raypick::{Mode, Query};
    let context = small_device(1 << 20); // 1 MiB: 64 rays of 1,024 hits, 21,845 rays of 48 B
    let scene = built(terrain(40, 40, 0.0, 39.0, 1.0, hills));
    let batch = rays(&scene.scene, RayKind::Random, 30_000, 5);
    let mut gpu = GpuPicker::new(&context, scene.clone()).unwrap();
    // The twin: the same answers and the same b and i statistics as the kernel.
    let mut cpu = raypick::ReferencePicker::new(scene.clone());
    for max_hits in [64, 1024] {
        let all = Query {
            mode: Mode::All,
            max_hits,
            ..Query::default()
        };
        // One ray, then a batch that needs several chunks at this list length.
        for part in [&batch[..1], &batch[..300]] {
            let g = gpu.query(part, &all).expect("all-hits query");
            let c = cpu.query(part, &all).unwrap();
            assert_eq!(g.lists, c.lists, "max_hits {max_hits}");
            assert_eq!(g.overflow, c.overflow);
        }
        // Then larger closest-hit batches than the long list allows in one chunk.
        let g = gpu
            .pick(&batch)
            .expect("closest batch after an all-hits request");
        let c = cpu.pick(&batch).unwrap();
        assert_eq!(g, c, "closest after max_hits {max_hits}");
    }
}

/// Long walks side by side: 20,000 large triangles that overlap across the whole box, so every
/// ray's walk visits nearly every node and tests nearly every triangle (about 30,000 loop
/// iterations each, well under the tree's own cap). On llvmpipe a group of lanes shares one
/// limit of 65,535 loop iterations, after which the driver ends every loop: rays traced
/// together there stopped part way and missed or hit another triangle, while each traced
/// alone was right (found by a helper's fuzzing, on far rays through an instanced scene). The
/// picker traces such rays again on the twin, so the GPU answers as the twin, bit for bit,
/// in every mode, on any adapter.
#[test]
fn walks_cut_short_by_the_driver_are_finished_on_the_twin() {
    use rand::Rng;
    use raypick::check::synthetic::rng;
    use raypick::{Mode, Query, Ray, ReferencePicker};
    let mut g = rng(8);
    let mut point = |range: std::ops::Range<f64>| {
        glam::DVec3::new(
            g.random_range(range.clone()),
            g.random_range(range.clone()),
            g.random_range(range),
        )
    };
    let positions: Vec<_> = (0..60_000).map(|_| point(0.0..100.0)).collect();
    let triangles = (0..20_000u32)
        .map(|k| [3 * k, 3 * k + 1, 3 * k + 2])
        .collect();
    let big = built(raypick::Mesh {
        positions,
        triangles,
    });
    let rays: Vec<Ray> = (0..96)
        .map(|_| Ray::new(point(0.0..100.0), point(-1.0..1.0)))
        .collect();
    let mut gpu = GpuPicker::new(crate::common::gpu(), big.clone()).unwrap();
    let mut twin = ReferencePicker::new(big);
    for query in [
        Query::default(),
        Query {
            mode: Mode::All,
            max_hits: 8,
            ..Query::default()
        },
    ] {
        let want = twin.query(&rays, &query).unwrap();
        let heavy = want
            .nearest
            .iter()
            .filter(|h| h.box_tests + h.triangle_tests > 10_000)
            .count();
        assert!(
            heavy > 48,
            "{query:?}: the walks are long ({heavy} of 96 over 10,000 tests)"
        );
        let got = gpu.query(&rays, &query).unwrap();
        assert_eq!(
            format!("{got:?}"),
            format!("{want:?}"),
            "{query:?}: the GPU's answers differ from the twin's"
        );
    }
}
