//! Getting a GPU: instance, adapter, device and queue, kept apart from the picking work so that
//! callers can bring their own device ([`GpuContext::from_device`]).

use crate::error::{Error, Result};
use std::sync::{Arc, Mutex};

/// A wgpu device and queue, with the errors and device loss wgpu reports asynchronously.
#[derive(Clone, Debug)]
pub struct GpuContext {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// What the adapter says about itself (name, backend, driver).
    pub adapter_info: wgpu::AdapterInfo,
    /// The first uncaptured error or device loss, as a sentence.
    fault: Arc<Mutex<Option<Error>>>,
}

impl GpuContext {
    /// Opens the best adapter the primary backends (Vulkan, Metal, DX12) offer, with the
    /// adapter's full limits. `WGPU_BACKEND` and `WGPU_ADAPTER_NAME` are honoured.
    pub fn new() -> Result<Self> {
        pollster::block_on(Self::new_async())
    }

    /// Async form of [`GpuContext::new`].
    pub async fn new_async() -> Result<Self> {
        let mut descriptor = wgpu::InstanceDescriptor::new_without_display_handle();
        descriptor.backends = wgpu::Backends::PRIMARY;
        let descriptor = descriptor.with_env();
        let instance = wgpu::Instance::new(descriptor);
        let adapter = instance
            .request_adapter(&wgpu::RequestAdapterOptions {
                power_preference: wgpu::PowerPreference::HighPerformance,
                ..Default::default()
            })
            .await
            .map_err(|e| match crate::budget::address_space_left() {
                // Drivers map hundreds of MiB as they load: under a tight limit none loads.
                Some(left) if left < 1 << 30 => Error::Gpu(format!(
                    "no GPU adapter could be opened ({e}) with the {} of address space that \
                     `ulimit -v` leaves this process (a GPU driver maps hundreds of MiB); raise \
                     the limit or use the CPU backend",
                    crate::budget::human(left)
                )),
                _ => Error::NoAdapter(e.to_string()),
            })?;
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("raypick"),
                required_limits: adapter.limits(),
                ..Default::default()
            })
            .await
            .map_err(|e| Error::RequestDevice(e.to_string()))?;
        Ok(Self::from_device(device, queue, adapter.get_info()))
    }

    /// Wraps a device and queue the caller created. Installs handlers that turn uncaptured errors
    /// and device loss into [`Error`]s returned by the next pick instead of panics.
    pub fn from_device(
        device: wgpu::Device,
        queue: wgpu::Queue,
        adapter_info: wgpu::AdapterInfo,
    ) -> Self {
        let fault: Arc<Mutex<Option<Error>>> = Arc::default();
        let on_error = fault.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            record(&on_error, Error::Gpu(e.to_string()));
        }));
        let on_lost = fault.clone();
        device.set_device_lost_callback(move |reason, message| {
            record(
                &on_lost,
                Error::DeviceLost(format!("{reason:?}: {message}")),
            );
        });
        Self {
            device,
            queue,
            adapter_info,
            fault,
        }
    }

    /// A one-line description of the adapter, e.g. `llvmpipe (LLVM 15.0.6, 256 bits) (Vulkan, Cpu)`.
    pub fn describe(&self) -> String {
        let i = &self.adapter_info;
        format!("{} ({:?}, {:?})", i.name, i.backend, i.device_type)
    }

    /// Whether the adapter is a software rasteriser such as lavapipe.
    pub fn is_software(&self) -> bool {
        self.adapter_info.device_type == wgpu::DeviceType::Cpu
    }

    /// Returns (and clears) the first asynchronous fault recorded since the last call.
    pub(crate) fn take_fault(&self) -> Result<()> {
        match self.fault.lock().map(|mut f| f.take()) {
            Ok(Some(e)) => Err(e),
            _ => Ok(()),
        }
    }
}

fn record(slot: &Mutex<Option<Error>>, error: Error) {
    if let Ok(mut slot) = slot.lock() {
        slot.get_or_insert(error);
    }
}
