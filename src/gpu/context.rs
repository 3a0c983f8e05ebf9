//! Getting a GPU: instance, adapter, device and queue, kept apart from the picking work so that
//! callers can bring their own device ([`GpuContext::from_device`]); the process's one shared
//! device ([`GpuContext::shared`]); the kernels compiled on a device, kept with it.

use crate::error::{Error, Result};
use std::sync::{Arc, Mutex, OnceLock, PoisonError};

/// The device [`GpuContext::shared`] hands out, with the process that opened it (a forked
/// child cannot use its parent's device).
static SHARED: Mutex<Option<(u32, GpuContext)>> = Mutex::new(None);

/// How many shared devices a process has opened and kept ([`GpuContext::shared`]: the first,
/// then each one opened again after a loss), with that process (a forked child counts its
/// own). Counted under [`SHARED`]'s lock, as each is stored.
static OPENINGS: Mutex<(u32, u32)> = Mutex::new((0, 0));

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
    /// Why the device was lost, once it is (it stays so, whoever took the fault).
    lost: Arc<OnceLock<String>>,
    /// Which of the process's shared devices this is (1 for the first: [`OPENINGS`]), or 0
    /// for a device opened or brought otherwise. Once lost, a picker on a shared device may
    /// open it again; a device the caller brought is the caller's to replace.
    opening: u32,
    /// The kernels compiled on this device, for every picker made on it
    /// (`crate::gpu::picker::Kernel`, by workgroup size and exact arithmetic).
    pub(crate) kernels: Arc<Mutex<Vec<crate::gpu::picker::Kernel>>>,
}

impl GpuContext {
    /// Opens the best adapter the primary backends (Vulkan, Metal, DX12) offer, with the
    /// adapter's full limits. `WGPU_BACKEND` and `WGPU_ADAPTER_NAME` are honoured.
    pub fn new() -> Result<Self> {
        pollster::block_on(Self::new_async())
    }

    /// One device for the whole process: opened by the first call ([`GpuContext::new`]),
    /// handed out again to later ones, so pickers over many scenes (Python's `Scene`s, each
    /// GPU or automatic picker [`crate::make_picker`] makes) share one device and its compiled
    /// kernel instead of each opening its own. Opened again once it is lost, and in a forked
    /// child (whose parent's device is left alone, never closed from the child).
    pub fn shared() -> Result<Self> {
        Self::shared_or_opened().map(|(context, _)| context)
    }

    /// [`GpuContext::shared`], and whether this call opened it. The device is opened without
    /// holding the lock (a process forked while another thread held it through an open, a
    /// second or so, had its child wait on it for ever); two threads opening at once keep the
    /// first one stored.
    pub(crate) fn shared_or_opened() -> Result<(Self, bool)> {
        let pid = std::process::id();
        let lock = || SHARED.lock().unwrap_or_else(PoisonError::into_inner);
        let current = |slot: &mut Option<(u32, GpuContext)>| match slot.take() {
            Some((owner, context)) if owner == pid && !context.is_lost() => {
                *slot = Some((owner, context.clone()));
                Some(context)
            }
            // The parent's: its driver state is not this process's to release.
            Some((owner, context)) if owner != pid => {
                std::mem::forget(context);
                None
            }
            _ => None,
        };
        if let Some(context) = current(&mut lock()) {
            return Ok((context, false));
        }
        let opened = Self::new()?;
        let mut slot = lock();
        match current(&mut slot) {
            Some(context) => Ok((context, false)),
            None => {
                let mut openings = OPENINGS.lock().unwrap_or_else(PoisonError::into_inner);
                *openings = match *openings {
                    (owner, count) if owner == pid => (pid, count + 1),
                    _ => (pid, 1),
                };
                let opened = Self {
                    opening: openings.1,
                    ..opened
                };
                *slot = Some((pid, opened.clone()));
                Ok((opened, true))
            }
        }
    }

    /// Stops handing out `self`'s device as the shared one, if it is (those who hold it keep
    /// it); the next [`GpuContext::shared`] opens another. The automatic picker lets a software
    /// adapter go so ([`crate::auto::AutoPicker::new`]).
    pub(crate) fn unshare(&self) {
        let mut slot = SHARED.lock().unwrap_or_else(PoisonError::into_inner);
        // The same device: `==` on devices cannot tell two wgpu instances' devices apart
        // (each numbers its own), so the loss flag they share is compared.
        if slot.as_ref().is_some_and(|(owner, shared)| {
            *owner == std::process::id() && Arc::ptr_eq(&shared.lost, &self.lost)
        }) {
            *slot = None;
        }
    }

    /// How many kernels have been compiled on this device (one per workgroup size and
    /// arithmetic, whatever the number of pickers made on it).
    pub fn compiled_kernels(&self) -> usize {
        self.kernels
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .len()
    }

    /// Whether the device was lost (every later use of it fails).
    pub fn is_lost(&self) -> bool {
        self.lost.get().is_some()
    }

    /// Which of the process's shared devices this is, counting from 1 (0: not a shared one).
    pub(crate) fn opening(&self) -> u32 {
        self.opening
    }

    /// `None` while the device is not lost (as far as wgpu has said: [`GpuContext::settle`]).
    /// Once it is: the shared device opened again, for a lost shared one
    /// ([`GpuContext::shared`]); [`Error::DeviceLost`] with the reason for a device the caller
    /// brought (every later use of it would fail with wgpu's words about invalid buffers and
    /// submissions), or when no device opens again.
    pub(crate) fn reopened(&self) -> Option<Result<Self>> {
        let why = self.lost.get()?;
        Some(if self.opening == 0 {
            Err(Error::DeviceLost(why.clone()))
        } else {
            Self::shared().map_err(|e| Error::DeviceLost(format!("opening it again failed: {e}")))
        })
    }

    /// Lets wgpu report a loss that failed the last work: it does so as the device is polled,
    /// once the work it was given has ended, which this waits for (at most a second).
    pub(crate) fn settle(&self) {
        let _ = self.device.poll(wgpu::PollType::Wait {
            submission_index: None,
            timeout: Some(std::time::Duration::from_secs(1)),
        });
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
        let lost: Arc<OnceLock<String>> = Arc::default();
        let was_lost = lost.clone();
        device.set_device_lost_callback(move |reason, message| {
            let why = match reason {
                wgpu::DeviceLostReason::Destroyed => "it was destroyed",
                wgpu::DeviceLostReason::Unknown => "the driver lost it",
            };
            let why = match message.trim() {
                "" => why.to_owned(),
                message => format!("{why} ({message})"),
            };
            let _ = was_lost.set(why.clone());
            record(&on_lost, Error::DeviceLost(why));
        });
        Self {
            device,
            queue,
            adapter_info,
            fault,
            lost,
            opening: 0,
            kernels: Arc::default(),
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
