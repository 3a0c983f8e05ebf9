//! The GPU path: device setup ([`context`]) and the picker that owns the kernel and the resident
//! scene buffers ([`picker`]).

pub mod context;
pub mod picker;

pub use context::GpuContext;
pub use picker::GpuPicker;
