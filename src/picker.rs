//! The front door: a built scene, the [`Picker`] trait both backends implement, and the CPU
//! picker. The GPU picker lives in [`crate::gpu::picker`].

use crate::bvh::{BuildOptions, Bvh};
use crate::cpu::trace_all;
use crate::error::Result;
use crate::frame::{local_rays, resolve};
use crate::layout::GpuHit;
use crate::ray::{Hit, Ray};
use crate::scene::Scene;
use rayon::prelude::*;

/// A scene together with the tree built over it: what both backends pick against.
#[derive(Clone, Debug)]
pub struct BuiltScene {
    /// The scene, with exact f64 positions.
    pub scene: Scene,
    /// The flattened tree over the scene's triangles.
    pub bvh: Bvh,
}

impl BuiltScene {
    /// Builds the tree over `scene`.
    pub fn new(scene: Scene, options: &BuildOptions) -> Result<Self> {
        let bvh = Bvh::build(&scene, options)?;
        Ok(Self { scene, bvh })
    }

    /// Turns raw traversal results into public hits, in parallel.
    pub fn resolve_all(&self, rays: &[Ray], found: &[GpuHit]) -> Result<Vec<Hit>> {
        rays.par_iter()
            .zip(found)
            .map(|(ray, f)| resolve(&self.scene, &self.bvh, ray, f))
            .collect()
    }
}

/// Something that answers pick rays: the CPU or the GPU path.
pub trait Picker {
    /// The nearest hit for each ray; `out[i]` answers `rays[i]`.
    fn pick(&mut self, rays: &[Ray]) -> Result<Vec<Hit>>;
}

/// The CPU reference path: the kernel's traversal, run on all cores.
#[derive(Clone, Debug)]
pub struct CpuPicker {
    built: std::sync::Arc<BuiltScene>,
}

impl CpuPicker {
    /// A CPU picker over `built`.
    pub fn new(built: std::sync::Arc<BuiltScene>) -> Self {
        Self { built }
    }
}

impl Picker for CpuPicker {
    fn pick(&mut self, rays: &[Ray]) -> Result<Vec<Hit>> {
        let local = local_rays(self.built.bvh.origin, rays);
        let found = trace_all(&self.built.bvh, &local);
        self.built.resolve_all(rays, &found)
    }
}

/// Which path answers picks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Backend {
    /// The WGSL kernel on a GPU (lavapipe on machines without one).
    #[default]
    Gpu,
    /// The CPU reference path.
    Cpu,
}
