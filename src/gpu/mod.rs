//! The GPU path: device setup ([`context`]), the kernel's binding table read from the WGSL
//! ([`bindings`]), and the picker that owns the kernel and the resident scene buffers
//! ([`picker`]).

pub mod bindings;
pub mod context;
pub mod picker;

pub use context::GpuContext;
pub use picker::GpuPicker;
