//! The automatic backend: small batches run on the CPU path (no dispatch and readback latency),
//! large ones on the GPU; when no GPU can be opened, or the GPU fails, everything runs on the CPU
//! and the picker says so. A software adapter (lavapipe) is slower than the CPU path at every
//! batch size, so with one everything runs on the CPU, and the picker says that too (once). The GPU picker (scene upload, kernel compilation) is made the first
//! time a batch reaches the crossover, so a software adapter, where the CPU answers every batch,
//! costs only opening the device.

use crate::bvh::Bvh;
use crate::error::{Error, Result};
use crate::gpu::{GpuContext, GpuPicker};
use crate::picker::{BuiltScene, CpuPicker, Picker, Refit, Tracer};
use crate::query::{Answers, Query};
use crate::ray::Ray;
use crate::scene::Scene;
use glam::DVec3;
use std::sync::{Arc, Mutex, PoisonError};

/// Batches below this many rays always run on the CPU path when the GPU is a real one. A
/// software adapter (lavapipe) runs on the same cores as the CPU path and is slower at every
/// batch size (BENCHMARKS.md), so with one every batch runs on the CPU.
pub const DEFAULT_CROSSOVER_RAYS: usize = 4096;

/// Rays per CPU thread below which a batch runs on the CPU engine when the GPU is a real one:
/// the engine's throughput grows with the cores and the GPU's does not. On an NVIDIA H200 with
/// 16 host cores a GPU pick cost about 0.7 ms plus 15 ns a ray, and the engine picked 4,096 and
/// 65,536 camera rays 2–4× faster than the GPU, 1M incoherent rays 2.4× slower (BENCHMARKS.md,
/// "A real GPU"); from 8,192 rays a thread the GPU loses at most about a third on camera rays and
/// wins on incoherent ones.
pub const CROSSOVER_RAYS_PER_THREAD: usize = 8192;

/// The batch size from which [`AutoPicker`] picks on a real GPU, with `threads` CPU threads.
pub fn crossover_for(threads: usize) -> usize {
    CROSSOVER_RAYS_PER_THREAD
        .saturating_mul(threads)
        .max(DEFAULT_CROSSOVER_RAYS)
}

/// Picks on the CPU or the GPU by batch size, falling back to the CPU when the GPU is missing or
/// fails.
pub struct AutoPicker {
    built: Arc<BuiltScene>,
    cpu: CpuPicker,
    /// The device, until the GPU picker is made from it or fails.
    context: Option<GpuContext>,
    /// A software adapter's description: its device is not kept (it is opened again should
    /// [`AutoPicker::set_crossover`] send batches to it), since a software driver's mappings
    /// (about 400 MiB of address space for lavapipe) halved the memory budget under `ulimit -v`
    /// for a device never traced on.
    software: Option<String>,
    gpu: Option<GpuPicker>,
    /// The batch size from which the GPU is used, when fixed (`usize::MAX` on a software
    /// adapter); `None`: [`crossover_for`] the threads at each pick.
    crossover: Option<usize>,
    /// The device found was a hardware GPU (a software adapter left after it was lost turns
    /// the GPU path off: [`AutoPicker::after_reopening`]).
    on_hardware: bool,
    notes: Vec<String>,
}

/// The software adapter an automatic picker of this process found (its description), with the
/// process (a forked child looks for itself).
static SOFTWARE: Mutex<Option<(u32, String)>> = Mutex::new(None);

/// The software adapter found before in this process, if one was.
fn software_found() -> Option<String> {
    let found = SOFTWARE.lock().unwrap_or_else(PoisonError::into_inner);
    found
        .as_ref()
        .filter(|(pid, _)| *pid == std::process::id())
        .map(|(_, adapter)| adapter.clone())
}

/// Notes that this process's adapter is the software one `adapter`.
fn remember_software(adapter: &str) {
    let mut found = SOFTWARE.lock().unwrap_or_else(PoisonError::into_inner);
    *found = Some((std::process::id(), adapter.to_owned()));
}

impl AutoPicker {
    /// Takes the process's shared GPU device ([`GpuContext::shared`]) if it can; otherwise
    /// records why and uses the CPU alone. A software adapter is never traced on (unless
    /// [`AutoPicker::set_crossover`] says so), with a note saying so; a software device opened
    /// for this look alone is closed again, and later automatic pickers of the process do not
    /// open it to learn what it is.
    pub fn new(built: Arc<BuiltScene>) -> Self {
        let mut notes = Vec::new();
        // A software adapter found before in this process is not opened again to learn so
        // (Python's scenes each made an automatic picker: about 60 ms a scene on lavapipe).
        let known = software_found();
        let (mut context, opened) = match &known {
            Some(_) => (None, false),
            None => match GpuContext::shared_or_opened() {
                Ok((context, opened)) => (Some(context), opened),
                Err(e) => {
                    notes.push(format!("no GPU ({e}); using the CPU path"));
                    (None, false)
                }
            },
        };
        let (mut crossover, mut software) = (None, None);
        let found = context.take_if(|c| c.is_software()).map(|c| {
            // Opened for this look alone: closed again, not held for later pickers. One that
            // GPU pickers share stays theirs.
            if opened {
                c.unshare();
            }
            c.describe()
        });
        if let Some(adapter) = found.or(known) {
            remember_software(&adapter);
            notes.push(format!(
                "software adapter: the CPU path is faster here, so it answers every batch \
                 (adapter: {adapter})"
            ));
            crossover = Some(usize::MAX);
            software = Some(adapter);
        }
        Self {
            cpu: CpuPicker::new(built.clone()),
            built,
            on_hardware: context.is_some(),
            context,
            software,
            gpu: None,
            crossover,
            notes,
        }
    }

    /// After a batch on the GPU: a hardware GPU that was lost and opened again as a software
    /// adapter (the GPU gone, lavapipe left) is let go, and the CPU path answers every batch
    /// from then on, as it does for an automatic picker made with a software adapter; a note
    /// says so.
    fn after_reopening(&mut self) {
        if !self.on_hardware {
            return;
        }
        let Some(mut gpu) = self.gpu.take_if(|gpu| gpu.context().is_software()) else {
            return;
        };
        self.notes.extend(Picker::take_notes(&mut gpu));
        let adapter = gpu.context().describe();
        self.notes.push(format!(
            "only a software adapter was left when the GPU device was opened again; the CPU \
             path answers every batch (adapter: {adapter})"
        ));
        self.software = Some(adapter);
        self.crossover = Some(usize::MAX);
        self.on_hardware = false;
    }

    /// The GPU picker, made from the device on first use; `None` (saying why, once) when there
    /// is no device or the scene cannot go on it.
    fn gpu(&mut self) -> Option<&mut GpuPicker> {
        if self.gpu.is_none() {
            let context = match self.context.take() {
                Some(context) => context,
                // The software adapter, closed when it was found, opened again (as the
                // process's shared device, which the GPU pickers share).
                None if self.software.take().is_some() => match GpuContext::shared() {
                    Ok(context) => context,
                    Err(e) => {
                        self.notes.push(format!("no GPU ({e}); using the CPU path"));
                        return None;
                    }
                },
                None => return None,
            };
            match GpuPicker::new(&context, self.built.clone()) {
                Ok(gpu) => self.gpu = Some(gpu),
                Err(e) => self.notes.push(format!("no GPU ({e}); using the CPU path")),
            }
        }
        self.gpu.as_mut()
    }

    /// Sets the batch size from which the GPU is used.
    pub fn set_crossover(&mut self, rays: usize) {
        self.crossover = Some(rays);
    }

    /// The batch size from which the GPU is used (`usize::MAX`: never): unless set, on a real
    /// GPU [`crossover_for`] the threads of the rayon pool the call runs in (a pick's own).
    pub fn crossover(&self) -> usize {
        self.crossover
            .unwrap_or_else(|| crossover_for(rayon::current_num_threads()))
    }
}

impl Picker for AutoPicker {
    fn query(&mut self, rays: &[Ray], query: &Query) -> Result<Answers> {
        let mut answers = Answers::default();
        self.query_into(rays, query, &mut answers)?;
        Ok(answers)
    }

    fn query_into(&mut self, rays: &[Ray], query: &Query, answers: &mut Answers) -> Result<()> {
        if rays.len() >= self.crossover() {
            if let Some(gpu) = self.gpu() {
                match gpu.query_into(rays, query, answers) {
                    Ok(()) => {
                        self.after_reopening();
                        return Ok(());
                    }
                    Err(e) => {
                        self.notes.push(format!(
                            "the GPU failed ({e}); falling back to the CPU path"
                        ));
                        self.gpu = None;
                    }
                }
            }
        }
        self.cpu.query_into(rays, query, answers)
    }

    /// Its own notes, then its GPU picker's (the device lost and opened again).
    fn take_notes(&mut self) -> Vec<String> {
        let mut notes = std::mem::take(&mut self.notes);
        if let Some(gpu) = &mut self.gpu {
            notes.extend(Picker::take_notes(gpu));
        }
        notes
    }

    fn set_mask(&mut self, object: u32, mask: u32) -> Result<()> {
        self.edit(|built| built.set_object_mask(object, mask).map(|()| Refit::Rebuilt))
            .map(|_| ())
    }

    fn current_scene(&self) -> Option<Arc<BuiltScene>> {
        Some(self.built.clone())
    }

    /// Over `built`, on the device this one has (its GPU picker's compiled kernel too) and
    /// with its crossover; a software adapter stays closed. `None` when it has no device left
    /// (none was found, or the GPU failed): [`crate::picker::make_picker`] looks again.
    fn remake(&self, built: Arc<BuiltScene>) -> Option<Result<Box<dyn Picker + Send>>> {
        let (gpu, context) = match &self.gpu {
            Some(gpu) => match gpu.over(built.clone()) {
                Ok(gpu) => (Some(gpu), None),
                // A scene the GPU cannot hold is answered on the CPU, as a new automatic
                // picker's would be (its first large batch says why, once).
                Err(Error::TooLargeForGpu { .. }) => (None, Some(gpu.context().clone())),
                Err(e) => return Some(Err(e)),
            },
            None if self.context.is_none() && self.software.is_none() => return None,
            None => (None, self.context.clone()),
        };
        Some(Ok(Box::new(Self {
            cpu: CpuPicker::new(built.clone()),
            built,
            context,
            software: self.software.clone(),
            gpu,
            crossover: self.crossover,
            on_hardware: self.on_hardware,
            notes: Vec::new(),
        })))
    }

    fn edit(&mut self, change: &mut dyn FnMut(&mut BuiltScene) -> Result<Refit>) -> Result<Refit> {
        AutoPicker::edit(self, change)
    }

    /// Moves the vertices once for both paths: the scene is taken from the pickers while it is
    /// refitted (so it is not copied unless the caller holds it too), then handed back to both
    /// (the GPU's buffers brought up to date).
    fn set_positions(&mut self, object: u32, positions: &[DVec3]) -> Result<Refit> {
        self.edit(|built| built.set_positions(object, positions))
    }

    fn describe(&self) -> String {
        let device = match (&self.gpu, &self.context) {
            (Some(gpu), _) => Some(gpu.context().describe()),
            (None, Some(context)) => Some(context.describe()),
            (None, None) => self.software.clone(),
        };
        match device {
            Some(device) if self.crossover() != usize::MAX => format!(
                "auto: cpu below {} rays, gpu {device} above",
                self.crossover(),
            ),
            _ => format!("auto: {}", self.cpu.describe()),
        }
    }
}

impl AutoPicker {
    /// Applies `change` to the scene once for both paths: the scene is taken from the pickers
    /// while it changes (so it is not copied unless the caller holds it too), then handed back
    /// to both, the GPU's buffers brought up to date as the change's [`Refit`] says.
    fn edit(&mut self, change: impl FnOnce(&mut BuiltScene) -> Result<Refit>) -> Result<Refit> {
        let placeholder = Arc::new(BuiltScene::from_parts(
            Scene::new(),
            Bvh::default(),
            Vec::new(),
        ));
        let mut built = std::mem::replace(&mut self.built, placeholder.clone());
        *self.cpu.built_mut() = placeholder.clone();
        if let Some(gpu) = &mut self.gpu {
            *gpu.built_mut() = placeholder;
        }
        let refit = change(Arc::make_mut(&mut built));
        self.built = built.clone();
        *self.cpu.built_mut() = built.clone();
        if let Some(gpu) = &mut self.gpu {
            *gpu.built_mut() = built;
        }
        let refit = refit?;
        if let Some(gpu) = &mut self.gpu
            && let Err(e) = gpu.scene_changed(refit)
        {
            self.notes.push(format!(
                "the GPU failed ({e}); falling back to the CPU path"
            ));
            self.gpu = None;
        }
        Ok(refit)
    }
}
