//! The front door: a built scene, the [`Picker`] trait both backends implement, and the CPU
//! picker. The GPU picker lives in [`crate::gpu::picker`].

use crate::bvh::{BuildOptions, Bvh};
use crate::cpu::{TraceSettings, trace_batch};
use crate::error::Result;
use crate::frame::{local_rays_for, resolve};
use crate::layout::{GpuHit, GpuHitEntry};
use crate::query::{Answers, Intersector, Mode, Query};
use crate::ray::{Hit, Ray};
use crate::ray_order::{DEFAULT_REORDER_FROM, trace_in_order};
use crate::scene::Scene;
use rayon::prelude::*;

/// A scene together with the tree built over it: what both backends pick against.
#[derive(Clone, Debug)]
pub struct BuiltScene {
    /// The scene, with exact f64 positions.
    pub scene: Scene,
    /// The flattened tree over the scene's triangles.
    pub bvh: Bvh,
    /// Layer mask per leaf-order triangle, from the objects' masks; empty when all are all-ones.
    pub triangle_masks: Vec<u32>,
}

impl BuiltScene {
    /// Builds the tree over `scene`.
    pub fn new(scene: Scene, options: &BuildOptions) -> Result<Self> {
        let bvh = Bvh::build(&scene, options)?;
        let triangle_masks = if scene.objects().iter().all(|o| o.mask == u32::MAX) {
            Vec::new()
        } else {
            bvh.triangle_ids
                .iter()
                .map(|&i| scene.triangle_mask(i))
                .collect()
        };
        Ok(Self {
            scene,
            bvh,
            triangle_masks,
        })
    }

    /// The CPU/GPU trace settings for `query`.
    pub fn settings(&self, query: &Query) -> TraceSettings<'_> {
        TraceSettings {
            triangle_masks: &self.triangle_masks,
            max_hits: query.list_length(),
            watertight: query.intersector == Intersector::Watertight,
        }
    }

    /// Turns raw traversal results into public answers, refining every hit in f64, in parallel.
    pub fn answers(
        &self,
        rays: &[Ray],
        query: &Query,
        found: &[GpuHit],
        lists: &[GpuHitEntry],
    ) -> Result<Answers> {
        let nearest = rays
            .par_iter()
            .zip(found)
            .map(|(ray, f)| resolve(&self.scene, &self.bvh, ray, f))
            .collect::<Result<Vec<Hit>>>()?;
        if query.mode != Mode::All {
            return Ok(Answers {
                nearest,
                ..Answers::default()
            });
        }
        let k = query.max_hits as usize;
        let per_ray = rays
            .par_iter()
            .zip(found)
            .enumerate()
            .map(|(i, (ray, f))| {
                let mut hits = lists[i * k..i * k + f.count as usize]
                    .iter()
                    .map(|e| {
                        let entry = GpuHit {
                            t: e.t,
                            prim: e.prim,
                            u: e.u,
                            v: e.v,
                            ..GpuHit::default()
                        };
                        resolve(&self.scene, &self.bvh, ray, &entry)
                    })
                    .collect::<Result<Vec<Hit>>>()?;
                hits.sort_by(|a, b| a.t.total_cmp(&b.t));
                Ok((hits, f.overflow != 0))
            })
            .collect::<Result<Vec<_>>>()?;
        let mut answers = Answers {
            nearest,
            list_start: vec![0],
            ..Answers::default()
        };
        for (hits, overflow) in per_ray {
            answers.lists.extend(hits);
            answers.list_start.push(answers.lists.len());
            answers.overflow.push(overflow);
        }
        Ok(answers)
    }
}

/// Something that answers pick rays: the CPU or the GPU path.
pub trait Picker {
    /// Answers `rays` as `query` asks; `nearest[i]` answers `rays[i]`.
    fn query(&mut self, rays: &[Ray], query: &Query) -> Result<Answers>;

    /// The nearest hit for each ray; `out[i]` answers `rays[i]`.
    fn pick(&mut self, rays: &[Ray]) -> Result<Vec<Hit>> {
        Ok(self.query(rays, &Query::default())?.nearest)
    }

    /// Answers `rays` `chunk` rays at a time, handing each chunk's answers to `sink` with the
    /// index of its first ray, so memory stays bounded however many rays there are.
    fn query_chunked(
        &mut self,
        rays: &[Ray],
        query: &Query,
        chunk: usize,
        sink: &mut dyn FnMut(usize, Answers) -> Result<()>,
    ) -> Result<()> {
        for (k, part) in rays.chunks(chunk.max(1)).enumerate() {
            sink(k * chunk.max(1), self.query(part, query)?)?;
        }
        Ok(())
    }

    /// Which path this picker runs on, for messages.
    fn describe(&self) -> String;

    /// Messages about fallbacks since the last call (the automatic backend's), for the caller
    /// to show.
    fn take_notes(&mut self) -> Vec<String> {
        Vec::new()
    }
}

/// The CPU reference path: the kernel's traversal, run on all cores.
#[derive(Clone, Debug)]
pub struct CpuPicker {
    built: std::sync::Arc<BuiltScene>,
    reorder_from: usize,
}

impl CpuPicker {
    /// A CPU picker over `built`.
    pub fn new(built: std::sync::Arc<BuiltScene>) -> Self {
        Self {
            built,
            reorder_from: DEFAULT_REORDER_FROM,
        }
    }

    /// Sets the batch size from which rays are traced in [`crate::ray_order::RayOrder`]
    /// (`usize::MAX`: never). Answers are the same either way.
    pub fn set_reorder_from(&mut self, rays: usize) {
        self.reorder_from = rays;
    }
}

impl Picker for CpuPicker {
    fn query(&mut self, rays: &[Ray], query: &Query) -> Result<Answers> {
        query.validate()?;
        let local = local_rays_for(self.built.bvh.origin, rays, query);
        let settings = self.built.settings(query);
        let reorder = local.len() >= self.reorder_from;
        let (found, lists) = trace_in_order(&local, settings.max_hits, reorder, |rays| {
            Ok::<_, crate::error::Error>(trace_batch(&self.built.bvh, rays, &settings))
        })?;
        self.built.answers(rays, query, &found, &lists)
    }

    fn describe(&self) -> String {
        format!("cpu ({} threads)", rayon::current_num_threads())
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
    /// Small batches on the CPU, large ones on the GPU (see [`crate::auto::AutoPicker`]); the CPU
    /// alone, saying so, when no GPU can be opened.
    Auto,
}
