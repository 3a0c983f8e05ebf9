//! CPU-only: parse `wgsl/pick.wgsl` with naga and check every shared struct's size and member
//! offsets against the Rust structs in `src/layout.rs`, and that the shader validates.

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
fn workgroup_size_matches_host() {
    let module =
        naga::front::wgsl::parse_str(raypick::gpu::picker::PICK_WGSL).expect("pick.wgsl parses");
    let entry = module
        .entry_points
        .iter()
        .find(|e| e.name == "pick")
        .expect("entry point pick");
    assert_eq!(
        entry.workgroup_size,
        [raypick::gpu::picker::WORKGROUP_SIZE, 1, 1]
    );
}
