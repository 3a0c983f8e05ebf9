//! The crate's error type: every failure a caller can see, as a sentence.

/// Everything that can go wrong in raypick. Library code returns these; it does not panic on user
/// data.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// What the operating system said.
        #[source]
        source: std::io::Error,
    },
    /// A file's content is malformed; `line` is 1-based when known.
    #[error("{path}{}: {message}", line.map(|l| format!(":{l}")).unwrap_or_default())]
    Parse {
        /// The file.
        path: String,
        /// The 1-based line, for text formats.
        line: Option<usize>,
        /// What is wrong, as a sentence.
        message: String,
    },
    /// A scene or argument is not usable as given.
    #[error("{0}")]
    Invalid(String),
    /// No GPU adapter could be found (on machines without a GPU, install Mesa's lavapipe).
    #[error(
        "no GPU adapter found ({0}); install a Vulkan driver such as Mesa lavapipe (mesa-vulkan-drivers)"
    )]
    NoAdapter(String),
    /// The adapter refused to create a device.
    #[error("the GPU adapter refused to create a device: {0}")]
    RequestDevice(String),
    /// The scene needs more GPU memory in one binding than the adapter allows.
    #[error(
        "{what} needs {needed} bytes in one GPU binding, but this adapter allows at most {limit} (max_storage_buffer_binding_size); use the CPU backend or a smaller scene"
    )]
    TooLargeForGpu {
        /// Which buffer.
        what: &'static str,
        /// Bytes needed.
        needed: u64,
        /// The adapter's limit.
        limit: u64,
    },
    /// The requested kernel workgroup size is zero or beyond what the adapter allows.
    #[error(
        "a workgroup of {requested} invocations is not possible on this adapter: {limit_name} is {limit}"
    )]
    WorkgroupSize {
        /// The size asked for.
        requested: u32,
        /// The adapter limit it breaks (`max_compute_invocations_per_workgroup` or
        /// `max_compute_workgroup_size_x`), or "the smallest workgroup" for zero.
        limit_name: &'static str,
        /// That limit's value.
        limit: u32,
    },
    /// wgpu reported a validation, out-of-memory or internal error.
    #[error("GPU error: {0}")]
    Gpu(String),
    /// The GPU device was lost (driver reset, watchdog, or removal).
    #[error("the GPU device was lost: {0}")]
    DeviceLost(String),
}

/// Shorthand for results in this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;
