//! The automatic backend: small batches run on the CPU path (no dispatch and readback latency),
//! large ones on the GPU; when no GPU can be opened, or the GPU fails, everything runs on the CPU
//! and the picker says so.

use crate::error::Result;
use crate::gpu::{GpuContext, GpuPicker};
use crate::picker::{BuiltScene, CpuPicker, Picker};
use crate::query::{Answers, Query};
use crate::ray::Ray;
use std::sync::Arc;

/// Batches below this many rays run on the CPU path when the GPU is a real one. A software
/// adapter (lavapipe) runs on the same cores as the CPU path and is slower at every batch size
/// (BENCHMARKS.md), so with one every batch runs on the CPU.
pub const DEFAULT_CROSSOVER_RAYS: usize = 4096;

/// Picks on the CPU or the GPU by batch size, falling back to the CPU when the GPU is missing or
/// fails.
pub struct AutoPicker {
    cpu: CpuPicker,
    gpu: Option<GpuPicker>,
    crossover: usize,
    notes: Vec<String>,
}

impl AutoPicker {
    /// Opens the GPU if it can; otherwise records why and uses the CPU alone.
    pub fn new(built: Arc<BuiltScene>) -> Self {
        let mut notes = Vec::new();
        let gpu = GpuContext::new()
            .and_then(|context| GpuPicker::new(&context, built.clone()))
            .map_err(|e| notes.push(format!("no GPU ({e}); using the CPU path")))
            .ok();
        let crossover = match &gpu {
            Some(g) if g.context().is_software() => usize::MAX,
            _ => DEFAULT_CROSSOVER_RAYS,
        };
        Self {
            cpu: CpuPicker::new(built),
            gpu,
            crossover,
            notes,
        }
    }

    /// Sets the batch size from which the GPU is used.
    pub fn set_crossover(&mut self, rays: usize) {
        self.crossover = rays;
    }

    /// The batch size from which the GPU is used (`usize::MAX`: never).
    pub fn crossover(&self) -> usize {
        self.crossover
    }
}

impl Picker for AutoPicker {
    fn query(&mut self, rays: &[Ray], query: &Query) -> Result<Answers> {
        if rays.len() >= self.crossover {
            if let Some(gpu) = &mut self.gpu {
                match gpu.query(rays, query) {
                    Ok(answers) => return Ok(answers),
                    Err(e) => {
                        self.notes.push(format!(
                            "the GPU failed ({e}); falling back to the CPU path"
                        ));
                        self.gpu = None;
                    }
                }
            }
        }
        self.cpu.query(rays, query)
    }

    fn take_notes(&mut self) -> Vec<String> {
        std::mem::take(&mut self.notes)
    }

    fn describe(&self) -> String {
        match &self.gpu {
            Some(gpu) if self.crossover != usize::MAX => {
                format!(
                    "auto: cpu below {} rays, {} above",
                    self.crossover,
                    gpu.describe()
                )
            }
            _ => format!("auto: {}", self.cpu.describe()),
        }
    }
}
