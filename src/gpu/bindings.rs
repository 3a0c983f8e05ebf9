//! The kernel's binding table, read from `wgsl/pick.wgsl` itself: each `@binding` global's
//! name, number and kind (uniform, read-only or read-write storage). The host builds its bind
//! group layout from this table and names the buffer for each binding by the WGSL variable's
//! name, so the table is written once, in the shader.

use crate::error::{Error, Result};

/// One binding of the kernel: the WGSL variable's name, its binding number and kind.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Binding {
    /// The WGSL variable (`params`, `nodes`, ...).
    pub name: String,
    /// Its `@binding` number in group 0.
    pub binding: u32,
    /// Uniform buffer, or storage buffer read-only / read-write.
    pub kind: wgpu::BufferBindingType,
}

/// Parses `wgsl` and lists its group-0 buffer bindings in binding order.
pub fn bindings(wgsl: &str) -> Result<Vec<Binding>> {
    let module = naga::front::wgsl::parse_str(wgsl)
        .map_err(|e| Error::Gpu(format!("pick.wgsl does not parse: {e}")))?;
    let mut out: Vec<Binding> = module
        .global_variables
        .iter()
        .filter_map(|(_, g)| {
            let binding = g.binding.as_ref()?;
            let kind = match g.space {
                naga::AddressSpace::Uniform => wgpu::BufferBindingType::Uniform,
                naga::AddressSpace::Storage { access } => wgpu::BufferBindingType::Storage {
                    read_only: !access.contains(naga::StorageAccess::STORE),
                },
                _ => return None,
            };
            (binding.group == 0).then(|| Binding {
                name: g.name.clone().unwrap_or_default(),
                binding: binding.binding,
                kind,
            })
        })
        .collect();
    out.sort_by_key(|b| b.binding);
    Ok(out)
}

/// The bind group layout entries of `table`, all visible to the compute stage.
pub fn layout_entries(table: &[Binding]) -> Vec<wgpu::BindGroupLayoutEntry> {
    table
        .iter()
        .map(|b| wgpu::BindGroupLayoutEntry {
            binding: b.binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: b.kind,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        })
        .collect()
}

/// Bind group entries for `table` from `(WGSL name, buffer)` pairs; every binding must be given
/// a buffer, and every buffer must name a binding.
pub fn group_entries<'a>(
    table: &[Binding],
    buffers: &[(&str, &'a wgpu::Buffer)],
) -> Result<Vec<wgpu::BindGroupEntry<'a>>> {
    if let Some((name, _)) = buffers
        .iter()
        .find(|(name, _)| !table.iter().any(|b| b.name == *name))
    {
        return Err(Error::Gpu(format!("pick.wgsl has no binding named {name}")));
    }
    table
        .iter()
        .map(|b| {
            let (_, buffer) = buffers
                .iter()
                .find(|(name, _)| *name == b.name)
                .ok_or_else(|| Error::Gpu(format!("no buffer for pick.wgsl's {}", b.name)))?;
            Ok(wgpu::BindGroupEntry {
                binding: b.binding,
                resource: buffer.as_entire_binding(),
            })
        })
        .collect()
}
