//! GPU limits: a scene larger than the adapter's storage-binding limit is refused with an error
//! that names the limit and the size (never truncated), and ray batches are chunked to fit.

use raypick::synthetic::{RayKind, hills, rays, terrain, triangle_soup};
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
    let (tally, _) = raypick::compare::Tally::compare(&scene.scene, &batch, &gpu, &cpu);
    assert_eq!(tally.mismatches, 0, "{tally:?}");
    assert!(gpu.iter().filter(|h| h.hit).count() > 10_000);
}
