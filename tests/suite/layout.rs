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

/// The value of the WGSL module-scope constant `name`, as f64.
fn wgsl_constant(module: &naga::Module, name: &str) -> f64 {
    let (_, constant) = module
        .constants
        .iter()
        .find(|(_, c)| c.name.as_deref() == Some(name))
        .unwrap_or_else(|| panic!("constant {name} is missing from pick.wgsl"));
    match module.global_expressions[constant.init] {
        naga::Expression::Literal(literal) => match literal {
            naga::Literal::U32(v) => f64::from(v),
            naga::Literal::I32(v) => f64::from(v),
            naga::Literal::F32(v) => f64::from(v),
            naga::Literal::AbstractInt(v) => v as f64,
            naga::Literal::AbstractFloat(v) => v,
            other => panic!("{name}: unexpected literal {other:?}"),
        },
        ref other => panic!("{name}: not a literal: {other:?}"),
    }
}

/// Constants the host and the kernel both use are typed twice; they must agree.
#[test]
fn wgsl_constants_match_rust() {
    use raypick::cpu::ray_box::{BOX_PAD, HUGE, MIN_DIR};
    use raypick::layout::*;
    let module =
        naga::front::wgsl::parse_str(raypick::gpu::picker::PICK_WGSL).expect("pick.wgsl parses");
    let unsigned = [
        ("KIND_INNER", KIND_INNER),
        ("KIND_BITS", KIND_BITS),
        ("KIND_MASK", (1 << KIND_BITS) - 1),
        ("NO_HIT", NO_HIT),
        ("CAP_REACHED", CAP_REACHED),
        ("UNFINISHED", UNFINISHED),
        ("MODE_CLOSEST", MODE_CLOSEST),
        ("MODE_ANY", MODE_ANY),
        ("MODE_ALL", MODE_ALL),
        ("CULL_SHIFT", CULL_SHIFT),
        ("CULL_BACK", CULL_BACK),
        ("CULL_FRONT", CULL_FRONT),
    ];
    for (name, value) in unsigned {
        assert_eq!(wgsl_constant(&module, name), f64::from(value), "{name}");
    }
    use raypick::cpu::traverse::HALF_SUBNORMAL_STEP;
    assert_eq!(HALF_SUBNORMAL_STEP, 2f32.powi(-24));
    for (name, value) in [
        ("BOX_PAD", BOX_PAD),
        ("MIN_DIR", MIN_DIR),
        ("HUGE", HUGE),
        ("HALF_SUBNORMAL_STEP", HALF_SUBNORMAL_STEP),
    ] {
        assert_eq!(wgsl_constant(&module, name) as f32, value, "{name}");
    }
}

/// The host's binding table is the shader's: every binding, in order, with its kind.
#[test]
fn the_binding_table_is_read_from_the_wgsl() {
    use raypick::gpu::bindings::bindings;
    use wgpu::BufferBindingType::{Storage, Uniform};
    let table = bindings(raypick::gpu::picker::PICK_WGSL).expect("bindings");
    let got: Vec<(&str, u32, wgpu::BufferBindingType)> = table
        .iter()
        .map(|b| (b.name.as_str(), b.binding, b.kind))
        .collect();
    let read = Storage { read_only: true };
    let write = Storage { read_only: false };
    assert_eq!(
        got,
        [
            ("params", 0, Uniform),
            ("nodes", 1, read),
            ("triangles", 2, read),
            ("rays", 3, read),
            ("hits", 4, write),
            ("hit_lists", 5, write),
            ("triangle_masks", 6, read),
            ("triangle_ids", 7, read),
            ("instances", 8, read),
        ]
    );
}
