//! CPU-only: parse `wgsl/pick.wgsl` with naga and check every shared struct's size and member
//! offsets against the Rust structs in `src/layout.rs`, that the shader validates, that its
//! workgroup size is the overridable constant the host sets, and the host's check of that size
//! against adapter limits.

use raypick::Error;
use raypick::gpu::picker::{SWEPT_WORKGROUP_SIZES, WORKGROUP_SIZE, check_workgroup_size};
use raypick::layout::SHARED_LAYOUTS;

#[test]
fn wgsl_structs_match_rust_layouts() {
    let module =
        naga::front::wgsl::parse_str(raypick::gpu::picker::PICK_WGSL).expect("pick.wgsl parses");
    let mut layouter = naga::proc::Layouter::default();
    layouter.update(module.to_ctx()).expect("layouts");
    for &(name, size, members) in SHARED_LAYOUTS {
        let (handle, ty) = module
            .types
            .iter()
            .find(|(_, t)| t.name.as_deref() == Some(name))
            .unwrap_or_else(|| panic!("struct {name} is missing from pick.wgsl"));
        let naga::TypeInner::Struct {
            members: wgsl_members,
            span,
        } = &ty.inner
        else {
            panic!("{name} is not a struct in WGSL");
        };
        assert_eq!(
            *span as usize, size,
            "{name}: WGSL size {span} != Rust size {size}"
        );
        assert_eq!(
            layouter[handle].size as usize, size,
            "{name}: layouter size"
        );
        let names: Vec<_> = wgsl_members
            .iter()
            .map(|m| m.name.clone().unwrap_or_default())
            .collect();
        let rust_names: Vec<_> = members.iter().map(|(n, _)| n.to_string()).collect();
        assert_eq!(names, rust_names, "{name}: member names and order");
        for (m, &(member, offset)) in wgsl_members.iter().zip(members) {
            assert_eq!(
                m.offset as usize, offset,
                "{name}.{member}: WGSL offset {} != Rust offset {offset}",
                m.offset
            );
        }
    }
}

#[test]
fn wgsl_validates() {
    let module =
        naga::front::wgsl::parse_str(raypick::gpu::picker::PICK_WGSL).expect("pick.wgsl parses");
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::empty(),
    )
    .validate(&module)
    .expect("pick.wgsl validates");
}

#[test]
fn workgroup_size_is_an_override_defaulting_to_the_host_default() {
    let module =
        naga::front::wgsl::parse_str(raypick::gpu::picker::PICK_WGSL).expect("pick.wgsl parses");
    let entry = module
        .entry_points
        .iter()
        .find(|e| e.name == "pick")
        .expect("entry point pick");
    assert!(
        matches!(entry.workgroup_size_overrides, Some([Some(_), None, None])),
        "@workgroup_size's x must be the pipeline-overridable WORKGROUP_SIZE, y and z literal"
    );
    assert_eq!(
        resolved_workgroup_size(&module, None),
        [WORKGROUP_SIZE, 1, 1],
        "the WGSL default of WORKGROUP_SIZE must be the host's default"
    );
}

#[test]
fn every_swept_workgroup_size_resolves_and_validates() {
    let module =
        naga::front::wgsl::parse_str(raypick::gpu::picker::PICK_WGSL).expect("pick.wgsl parses");
    for size in SWEPT_WORKGROUP_SIZES {
        assert_eq!(resolved_workgroup_size(&module, Some(size)), [size, 1, 1]);
    }
}

/// The entry point's workgroup size once the overrides are applied (as wgpu does when it builds
/// the pipeline), with `WORKGROUP_SIZE` set to `size` or left at its default.
fn resolved_workgroup_size(module: &naga::Module, size: Option<u32>) -> [u32; 3] {
    let info = naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::empty(),
    )
    .validate(module)
    .expect("pick.wgsl validates");
    let mut constants = naga::back::PipelineConstants::default();
    if let Some(size) = size {
        constants.insert("WORKGROUP_SIZE".to_string(), f64::from(size));
    }
    let (resolved, _) = naga::back::pipeline_constants::process_overrides(
        module,
        &info,
        Some((naga::ShaderStage::Compute, "pick")),
        &constants,
    )
    .expect("overrides resolve and the result validates");
    resolved
        .entry_points
        .iter()
        .find(|e| e.name == "pick")
        .expect("entry point pick")
        .workgroup_size
}

#[test]
fn workgroup_sizes_are_checked_against_adapter_limits() {
    let limits = wgpu::Limits {
        max_compute_invocations_per_workgroup: 256,
        max_compute_workgroup_size_x: 128,
        ..wgpu::Limits::default()
    };
    for size in [1, 32, 64, 128] {
        check_workgroup_size(&limits, size).expect("within the limits");
    }
    let refused = |size| match check_workgroup_size(&limits, size) {
        Err(Error::WorkgroupSize {
            requested,
            limit_name,
            limit,
        }) => {
            assert_eq!(requested, size);
            (limit_name, limit)
        }
        other => panic!("size {size}: expected Error::WorkgroupSize, got {other:?}"),
    };
    assert_eq!(refused(0), ("the smallest workgroup", 1));
    assert_eq!(refused(129), ("max_compute_workgroup_size_x", 128));
    let narrow = wgpu::Limits {
        max_compute_invocations_per_workgroup: 64,
        ..limits
    };
    let message = check_workgroup_size(&narrow, 128).unwrap_err().to_string();
    assert!(
        message.contains("128") && message.contains("max_compute_invocations_per_workgroup is 64"),
        "{message}"
    );
}
