//! The front door: a built scene, the [`Picker`] trait every backend implements, the one pick
//! pipeline they share ([`pick_through`]: validate, world → scene-frame rays, reorder, trace, put
//! back, refine in f64, answers) over a [`Tracer`] of scene-frame ray batches, the CPU pickers,
//! and the backend factory. The GPU tracer lives in [`crate::gpu::picker`].

use crate::bvh::{BuildOptions, Bvh};
use crate::cpu::{TraceSettings, trace_batch};
use crate::engine::{Simd, WideBvh};
use crate::error::Result;
use crate::frame::{
    Frame, NEVER_TRACED, check_found_in, local_rays_into, local_rays_with_rests_into,
    put_origin_lo, resolve_chunk, resolve_with, scene_rays, split_hits,
};
use crate::instance::{Instance, Instances};
use crate::layout::{GpuHit, GpuHitEntry, GpuRay, NO_HIT};
use crate::query::{Answers, Intersector, Mode, Query};
use crate::ray::{Hit, Ray};
use crate::ray_order::{DEFAULT_REORDER_FROM, RayOrder, trace_in_order};
use crate::scene::Scene;
use crate::store::Store;
use glam::DVec3;
use rayon::prelude::*;
use std::sync::{Arc, OnceLock};

/// A scene together with the tree built over it: what both backends pick against.
#[derive(Clone, Debug)]
pub struct BuiltScene {
    /// The scene, with exact f64 positions.
    pub scene: Scene,
    /// The flattened tree over the scene's triangles.
    pub bvh: Bvh,
    /// Layer mask per leaf-order triangle, from the objects' masks; empty when all are all-ones.
    pub triangle_masks: Store<u32>,
    /// The CPU engine's wide tree, collapsed from `bvh` the first time the engine runs (or why
    /// it could not be: a corrupted tree).
    wide: OnceLock<std::result::Result<WideBvh, String>>,
    /// `bvh`'s leaf-order vertex indices ([`Bvh::leaf_vertices`]), made by the first refit and
    /// kept for the next ones (like `wide`, it belongs to the `bvh` it was made from).
    leaf_vertices: OnceLock<Vec<[u32; 3]>>,
    /// How the tree was built, for a rebuild ([`BuiltScene::set_positions`]); the defaults for a
    /// tree made elsewhere.
    options: BuildOptions,
    /// An instanced scene's instances and meshes ([`BuiltScene::instanced`]): `bvh` is then the
    /// two-level tree (top tree first) and `scene` is empty.
    instances: Option<Instances>,
}

/// What moving an object's vertices did to the tree ([`BuiltScene::set_positions`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refit {
    /// The tree kept its shape; its boxes (and the engine's) were recomputed.
    Refitted,
    /// A triangle became degenerate or stopped being so, which changes the set of triangles
    /// the tree holds: it was built again (or, in an instanced scene, the instances were laid
    /// out anew).
    Rebuilt,
    /// An instanced scene's instance moved or changed its mask: only the top tree's boxes and
    /// the instance records changed.
    Moved,
}

impl BuiltScene {
    /// Builds the tree over `scene`.
    pub fn new(scene: Scene, options: &BuildOptions) -> Result<Self> {
        let bvh = Bvh::build(&scene, options)?;
        let triangle_masks = masks_of(&scene, &bvh);
        Ok(Self {
            scene,
            bvh,
            triangle_masks: triangle_masks.into(),
            wide: OnceLock::new(),
            leaf_vertices: OnceLock::new(),
            options: *options,
            instances: None,
        })
    }

    /// An instanced scene: each of `meshes` (scenes of one object, in file coordinates) built
    /// once with `options`, placed by `instances` (the ids hits report are their positions),
    /// under a top tree built by median cut ([`Instances::build`]).
    pub fn instanced(
        meshes: Vec<Scene>,
        instances: Vec<Instance>,
        options: &BuildOptions,
    ) -> Result<Self> {
        let (instances, bvh) = Instances::build(meshes, instances, options)?;
        Ok(Self {
            scene: Scene::new(),
            bvh,
            triangle_masks: Store::default(),
            wide: OnceLock::new(),
            leaf_vertices: OnceLock::new(),
            options: *options,
            instances: Some(instances),
        })
    }

    /// An instanced scene from instances assembled elsewhere (a saved scene, [`crate::rpk`]);
    /// `bvh` is the combined tree [`Instances::assemble`] returned with them.
    pub(crate) fn from_instances(instances: Instances, bvh: Bvh) -> Self {
        Self {
            scene: Scene::new(),
            bvh,
            triangle_masks: Store::default(),
            wide: OnceLock::new(),
            leaf_vertices: OnceLock::new(),
            options: BuildOptions::default(),
            instances: Some(instances),
        }
    }

    /// The scene, its tree and the CPU engine's tree (collapsed now if it was not yet), taken
    /// apart: a saved instanced scene's meshes become [`crate::instance::MeshTree`]s so.
    pub(crate) fn into_tree_parts(self) -> Result<(Scene, Bvh, WideBvh)> {
        let wide = match self.wide.into_inner() {
            Some(Ok(wide)) => wide,
            Some(Err(e)) => return Err(crate::error::Error::Invalid(e)),
            None => WideBvh::collapse(&self.bvh)?,
        };
        Ok((self.scene, self.bvh, wide))
    }

    /// The instances, for an instanced scene.
    pub fn instances(&self) -> Option<&Instances> {
        self.instances.as_ref()
    }

    /// The instances and the combined tree, to change; an error for a scene without instances.
    fn instances_mut(&mut self) -> Result<(&mut Instances, &mut Bvh)> {
        match &mut self.instances {
            Some(i) => Ok((i, &mut self.bvh)),
            None => Err(crate::error::Error::Invalid(
                "the scene has no instances (build it with BuiltScene::instanced)".into(),
            )),
        }
    }

    /// Places instance `instance` by `transform` (3 × 4 row-major, its mesh's coordinates to
    /// the world) and refits the top tree above it ([`Instances::set_transform`]); a move that
    /// takes the scene away from the frame ([`crate::frame::reach::frame_suits`]) lays the top
    /// tree out again about it ([`Refit::Rebuilt`]). Fails,
    /// naming it, on an unknown instance or a transform that cannot place it, with nothing
    /// changed.
    pub fn set_instance_transform(
        &mut self,
        instance: u32,
        transform: [[f64; 4]; 3],
    ) -> Result<Refit> {
        let (i, bvh) = self.instances_mut()?;
        let suited = crate::frame::reach::frame_suits(i.bounds(), i.origin());
        i.set_transform(bvh, instance, transform)?;
        // A move that takes the scene away from the frame's origin (an instance moved far out,
        // the frame re-centred by an addition, then moved back: its rays rounded at the far
        // centre's coarse steps) lays the top tree out again about it; one that leaves a frame
        // already kept away (where re-centring would round others too coarsely) does not.
        if suited && !crate::frame::reach::frame_suits(i.bounds(), i.origin()) {
            i.rebuild_top(bvh)?;
            return Ok(Refit::Rebuilt);
        }
        Ok(Refit::Moved)
    }

    /// Sets instance `instance`'s layer mask (0 hides it from every pick until it is shown
    /// again).
    pub fn set_instance_mask(&mut self, instance: u32, mask: u32) -> Result<Refit> {
        self.instances_mut()?.0.set_mask(instance, mask)?;
        Ok(Refit::Moved)
    }

    /// Removes instance `instance` for good, its id kept ([`Instances::remove`]): never hit
    /// again, and left out of the top tree from its next layout on.
    pub fn remove_instance(&mut self, instance: u32) -> Result<Refit> {
        self.instances_mut()?.0.remove(instance)?;
        Ok(Refit::Moved)
    }

    /// Adds an instance (its id is returned: the next one) and lays the top tree out anew
    /// ([`Instances::add`]).
    pub fn add_instance(&mut self, instance: Instance) -> Result<u32> {
        let (i, bvh) = self.instances_mut()?;
        i.add(bvh, instance)
    }

    /// Adds a mesh (a scene of one object, in its own coordinates) for instances to place,
    /// built with this scene's options; returns its index.
    pub fn add_mesh(&mut self, mesh: Scene) -> Result<u32> {
        let options = self.options;
        self.instances_mut()?.0.add_mesh(mesh, &options)
    }

    /// Moves mesh `mesh`'s vertices (the same triangles) and refits its tree and every instance
    /// of it ([`Instances::set_mesh_positions`]).
    pub fn set_mesh_positions(&mut self, mesh: u32, positions: &[DVec3]) -> Result<Refit> {
        let options = self.options;
        let (i, bvh) = self.instances_mut()?;
        i.set_mesh_positions(bvh, mesh, positions, &options)
    }

    /// Builds the top tree again over the instances where they are now.
    pub fn rebuild_top(&mut self) -> Result<Refit> {
        let (i, bvh) = self.instances_mut()?;
        i.rebuild_top(bvh)?;
        Ok(Refit::Rebuilt)
    }

    /// The world box around the scene (`None`: an empty scene): every object of a plain scene
    /// (but a removed one the server gathered), the instances that can be hit of an instanced
    /// one ([`Instances::bounds`]).
    pub fn bounds(&self) -> Option<(DVec3, DVec3)> {
        match &self.instances {
            Some(i) => i.bounds(),
            None => self.scene.bounds(),
        }
    }

    /// The scene frame the pick pipeline converts world rays into: about the tree's origin,
    /// reaching as far as [`BuiltScene::bounds`] (what the refinement's fallback assumes too:
    /// `frame::resolve_with`, `instance::resolve_with`).
    pub fn frame(&self) -> Frame {
        Frame::around(self.bvh.origin, self.bounds())
    }

    /// Objects that hits can report (an instanced scene's instances).
    pub fn object_count(&self) -> usize {
        match &self.instances {
            Some(i) => i.instances().len(),
            None => self.scene.objects().len(),
        }
    }

    /// Triangles in the world (an instanced scene's counted once per instance).
    pub fn world_triangle_count(&self) -> u64 {
        match &self.instances {
            Some(i) => i.prim_count(),
            None => self.scene.triangle_count() as u64,
        }
    }

    /// The triangles with area that the tree's single-precision frame loses, which no ray can
    /// hit ([`crate::bvh::lost`]); an instanced scene's counted once per mesh (each in its own
    /// frame), the first named by the first instance placing it.
    pub fn lost_triangles(&self) -> crate::bvh::Lost {
        let Some(i) = &self.instances else {
            return crate::bvh::lost_triangles(&self.scene, &self.bvh);
        };
        let mut all = crate::bvh::Lost::default();
        for (m, mesh) in i.meshes().iter().enumerate() {
            let lost = crate::bvh::lost_triangles(&mesh.scene, &mesh.bvh);
            // A mesh's first, as the first instance placing it and the mesh's triangle.
            let placed = |first: Option<(u32, u32)>| {
                let (_, triangle) = first?;
                let k = i.instances().iter().position(|p| p.mesh as usize == m)?;
                Some((k as u32, triangle))
            };
            all.first = all.first.or_else(|| placed(lost.first));
            all.first_degenerate = all
                .first_degenerate
                .or_else(|| placed(lost.first_degenerate));
            all.triangles += lost.triangles;
            all.degenerate += lost.degenerate;
        }
        all
    }

    /// Whether some object is a height grid (hits on it report cells).
    pub fn has_grid(&self) -> bool {
        match &self.instances {
            Some(i) => i
                .meshes()
                .iter()
                .any(|m| m.scene.objects()[0].grid.is_some()),
            None => self.scene.objects().iter().any(|o| o.grid.is_some()),
        }
    }

    /// Hit ids the tracers may report: leaf-order triangles, or an instanced scene's
    /// instance-by-instance triangle ids.
    fn prim_count(&self) -> usize {
        match &self.instances {
            Some(i) => i.prim_count() as usize,
            None => self.bvh.triangle_ids.len(),
        }
    }

    /// Moves object `object`'s vertices to `positions` (as many as it has, in its own vertex
    /// order; the same triangles) and refits the tree and the engine's wide tree to them,
    /// bottom-up, without building again ([`crate::bvh::Bvh::refit`]); the tree's f32 frame
    /// keeps its origin. Only when a triangle of the object becomes degenerate, or stops being
    /// so, or the scene has moved away from the frame
    /// ([`crate::frame::reach::frame_suits`]), is the tree built again, with the options it was
    /// built with. Answers afterwards are
    /// those of a scene built from the new positions, on every backend. Fails, naming the
    /// object, on an unknown object, a wrong count or a non-finite coordinate, with nothing
    /// changed.
    pub fn set_positions(&mut self, object: u32, positions: &[DVec3]) -> Result<Refit> {
        if self.instances.is_some() {
            return Err(crate::error::Error::Invalid(
                "an instanced scene's objects are instances: move one with \
                 set_instance_transform, or its mesh's vertices with set_mesh_positions"
                    .into(),
            ));
        }
        self.scene.check_object_positions(object, positions)?;
        let leaf_vertices = self
            .leaf_vertices
            .get_or_init(|| self.bvh.leaf_vertices(&self.scene));
        if self
            .bvh
            .refit_with(&self.scene, object, positions, leaf_vertices)
        {
            // The positions go in while the engine's wide tree takes the refitted boxes: the
            // two read and write nothing in common.
            let (scene, bvh, wide) = (&mut self.scene, &self.bvh, self.wide.get_mut());
            rayon::join(
                || scene.put_object_positions(object, positions),
                || {
                    if let Some(Ok(wide)) = wide {
                        wide.refit(bvh);
                    }
                },
            );
            if crate::frame::reach::frame_suits(self.scene.bounds(), self.bvh.origin) {
                return Ok(Refit::Refitted);
            }
            // The scene has moved away from the frame's origin (an object moved far out and
            // back): built again, centred on it. Should that fail, the refitted tree stands:
            // the answers of the kept frame, as before the move.
            return Ok(match Bvh::build(&self.scene, &self.options) {
                Ok(bvh) => {
                    self.take_tree(bvh);
                    Refit::Rebuilt
                }
                Err(_) => Refit::Refitted,
            });
        }
        // Built again on a copy of the scene, so a failed build leaves it as it was.
        let mut scene = self.scene.clone();
        scene.put_object_positions(object, positions);
        match Bvh::build(&scene, &self.options) {
            Ok(bvh) => {
                self.scene = scene;
                self.take_tree(bvh);
                Ok(Refit::Rebuilt)
            }
            Err(e) => {
                // The failed refit may have rewritten some triangles: back to the positions the
                // tree was built for (which it fits, so this refit succeeds).
                let old: Vec<DVec3> = self
                    .scene
                    .object_vertices(object)
                    .map(|v| self.scene.position(v))
                    .collect();
                let leaf_vertices = self.leaf_vertices.get().map_or(&[][..], Vec::as_slice);
                self.bvh
                    .refit_with(&self.scene, object, &old, leaf_vertices);
                Err(e)
            }
        }
    }

    /// Takes `bvh`, built anew over this scene, as its tree: the per-triangle masks made for
    /// it, the engine's tree and the refit's vertex list left to be made again.
    fn take_tree(&mut self, bvh: Bvh) {
        self.triangle_masks = masks_of(&self.scene, &bvh).into();
        self.bvh = bvh;
        self.wide = OnceLock::new();
        self.leaf_vertices = OnceLock::new();
    }

    /// Sets object `object`'s layer mask (rays hit it only when their mask shares a bit; 0:
    /// never hit), with the per-triangle masks the tracers read. Fails on an unknown object.
    pub fn set_object_mask(&mut self, object: u32, mask: u32) -> Result<()> {
        if let Some(i) = &mut self.instances {
            return i.set_mask(object, mask);
        }
        self.scene.set_object_mask(object, mask)?;
        self.triangle_masks = masks_of(&self.scene, &self.bvh).into();
        Ok(())
    }

    /// The options the tree was built with (the defaults for a tree made elsewhere).
    pub fn options(&self) -> &BuildOptions {
        &self.options
    }

    /// A built scene from a tree made elsewhere (`bvh` must be built over `scene`).
    pub fn from_parts(scene: Scene, bvh: Bvh, triangle_masks: impl Into<Store<u32>>) -> Self {
        Self {
            scene,
            bvh,
            triangle_masks: triangle_masks.into(),
            wide: OnceLock::new(),
            leaf_vertices: OnceLock::new(),
            options: BuildOptions::default(),
            instances: None,
        }
    }

    /// A built scene whose CPU engine tree was collapsed elsewhere (a saved scene,
    /// [`crate::rpk`]); `wide` must be what `WideBvh::collapse(&bvh)` makes.
    pub fn with_wide(
        scene: Scene,
        bvh: Bvh,
        triangle_masks: impl Into<Store<u32>>,
        wide: WideBvh,
    ) -> Self {
        Self {
            scene,
            bvh,
            triangle_masks: triangle_masks.into(),
            wide: OnceLock::from(Ok(wide)),
            leaf_vertices: OnceLock::new(),
            options: BuildOptions::default(),
            instances: None,
        }
    }

    /// The CPU engine's wide tree (collapsed from `bvh` on first use, then kept); an error for a
    /// corrupted tree.
    pub fn wide(&self) -> Result<&WideBvh> {
        self.wide
            .get_or_init(|| WideBvh::collapse(&self.bvh).map_err(|e| e.to_string()))
            .as_ref()
            .map_err(|e| crate::error::Error::Invalid(e.clone()))
    }

    /// The CPU/GPU trace settings for `query`.
    pub fn settings(&self, query: &Query) -> TraceSettings<'_> {
        TraceSettings {
            triangle_masks: &self.triangle_masks,
            max_hits: query.list_length(),
            watertight: query.intersector == Intersector::Watertight,
            instances: self.instances.as_ref(),
        }
    }

    /// Turns raw traversal results into public answers, refining every hit in f64, in parallel.
    /// `found[i]` answers `rays[i]`; `dir_lengths` come from [`crate::frame::scene_rays`].
    pub fn answers(
        &self,
        rays: &[Ray],
        dir_lengths: &[f64],
        query: &Query,
        found: &[GpuHit],
        lists: &[GpuHitEntry],
    ) -> Result<Answers> {
        self.answers_in(None, rays, dir_lengths, query, found, lists)
    }

    /// [`BuiltScene::answers`] for results traced in `order` (`found[j]` answers
    /// `rays[order.order()[j]]`; all-hits lists in input order): hits are refined in traced
    /// order, so neighbouring refinements read neighbouring triangles, and written straight to
    /// their input slots.
    fn answers_in(
        &self,
        order: Option<&RayOrder>,
        rays: &[Ray],
        dir_lengths: &[f64],
        query: &Query,
        found: &[GpuHit],
        lists: &[GpuHitEntry],
    ) -> Result<Answers> {
        let prims = self.prim_count();
        check_found_in(prims, found, |f| f.prim)?;
        if query.mode == Mode::All {
            let k = query.max_hits as usize;
            let counted = |i: usize| (i % k) < found[i / k].count as usize;
            let live: Vec<u32> = lists
                .par_iter()
                .enumerate()
                .map(|(i, e)| if counted(i) { e.prim } else { NO_HIT })
                .collect();
            check_found_in(prims, &live, |&p| p)?;
        }
        let resolved = |i: usize, f: &GpuHit| match &self.instances {
            Some(instances) => {
                crate::instance::resolve_with(instances, &rays[i], dir_lengths[i], f)
            }
            None => resolve_with(&self.scene, &self.bvh, &rays[i], dir_lengths[i], f),
        };
        let mut nearest = Vec::new();
        match order {
            None => found
                .par_iter()
                .enumerate()
                .with_min_len(1024)
                .map(|(i, f)| resolved(i, f))
                .collect_into_vec(&mut nearest),
            Some(order) => {
                let slots = order.order();
                assert_eq!(slots.len(), found.len(), "one result per ray");
                nearest.reserve_exact(found.len());
                let out = SlotWriter(nearest.as_mut_ptr());
                found
                    .par_iter()
                    .zip(slots)
                    .with_min_len(1024)
                    .for_each(|(f, &i)| {
                        let hit = resolved(i as usize, f);
                        // SAFETY: `slots` is a permutation of 0..len (`RayOrder`), so each
                        // slot of the reserved capacity is written exactly once, by one task.
                        unsafe { out.write(i as usize, hit) };
                    });
                // SAFETY: every slot below len was written above (Hit is Copy: a panic above
                // leaves the vector empty, never half-initialised).
                unsafe { nearest.set_len(found.len()) };
            }
        }
        if query.mode != Mode::All {
            return Ok(Answers {
                nearest,
                ..Answers::default()
            });
        }
        let k = query.max_hits as usize;
        let per_ray = found
            .par_iter()
            .enumerate()
            .map(|(i, f)| {
                // In the walk's order: by f32 t, equal t by the lower scene triangle id (object,
                // then triangle), so the first is the closest-mode answer. (Sorted again by the
                // refined f64 t, two hits within f32's resolution of each other could swap, and
                // the first was then not the closest-mode answer, nor this ray's `nearest`.)
                let hits = lists[i * k..i * k + f.count as usize]
                    .iter()
                    .map(|e| {
                        let entry = GpuHit {
                            t: e.t,
                            prim: e.prim,
                            u: e.u,
                            v: e.v,
                            ..GpuHit::default()
                        };
                        resolved(i, &entry)
                    })
                    .collect::<Vec<Hit>>();
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

/// The layer mask of each leaf-order triangle of `bvh`, or none when every object has all bits.
pub(crate) fn masks_of(scene: &Scene, bvh: &Bvh) -> Vec<u32> {
    if scene.objects().iter().all(|o| o.mask == u32::MAX) {
        Vec::new()
    } else {
        bvh.triangle_ids
            .iter()
            .map(|&i| scene.triangle_mask(i))
            .collect()
    }
}

/// Something that answers pick rays: the CPU or the GPU path.
pub trait Picker {
    /// Answers `rays` as `query` asks; `nearest[i]` answers `rays[i]`.
    fn query(&mut self, rays: &[Ray], query: &Query) -> Result<Answers>;

    /// [`Picker::query`] into `answers`, reusing its buffers' memory where the backend can (the
    /// CPU pickers' closest and any modes do, and the GPU's batches of several dispatches): for
    /// a caller that picks batch after batch. Each new buffer of a batch of 32k answers is
    /// 3.6 MB of fresh memory, and where the C
    /// allocator hands such blocks back to the OS on every free (a Dask worker's
    /// `MALLOC_TRIM_THRESHOLD_`), writing them faulted in every page anew: 23% of a 1M-ray
    /// pick's time in one thread (BENCHMARKS.md, Dask).
    fn query_into(&mut self, rays: &[Ray], query: &Query, answers: &mut Answers) -> Result<()> {
        *answers = self.query(rays, query)?;
        Ok(())
    }

    /// The nearest hit for each ray; `out[i]` answers `rays[i]`. In new memory, which the OS
    /// zeroes as it is first written: batch after batch, [`Picker::query_into`] (or
    /// [`crate::huge_pages::Allocator`]) reuses it (a 1M-ray camera pick 1.2–1.4 times faster,
    /// BENCHMARKS.md).
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

    /// Moves object `object`'s vertices and refits the picker's tree to them
    /// ([`BuiltScene::set_positions`]); later picks see the new positions. A picker whose scene
    /// is shared (another picker, or the caller, holds its `Arc`) takes its own copy first; the
    /// GPU picker uploads the new boxes and triangles only. Pickers that cannot move vertices
    /// say so.
    fn set_positions(&mut self, object: u32, positions: &[DVec3]) -> Result<Refit> {
        let _ = (object, positions);
        Err(crate::error::Error::Invalid(format!(
            "the {} picker cannot move vertices",
            self.describe()
        )))
    }

    /// Sets object `object`'s layer mask ([`BuiltScene::set_object_mask`]); later picks see it.
    /// As with [`Picker::set_positions`], a shared scene is copied first.
    fn set_mask(&mut self, object: u32, mask: u32) -> Result<()> {
        let _ = (object, mask);
        Err(crate::error::Error::Invalid(format!(
            "the {} picker cannot change masks",
            self.describe()
        )))
    }

    /// Applies `change` to the picker's scene (a shared scene is copied first) and brings the
    /// picker up to date as the returned [`Refit`] says (the GPU uploads only what changed):
    /// how an instanced scene's instances are moved, masked or added, e.g.
    /// `picker.edit(&mut |scene| scene.set_instance_transform(3, m))`. Pickers that cannot
    /// change their scene say so.
    fn edit(&mut self, change: &mut dyn FnMut(&mut BuiltScene) -> Result<Refit>) -> Result<Refit> {
        let _ = change;
        Err(crate::error::Error::Invalid(format!(
            "the {} picker cannot change its scene",
            self.describe()
        )))
    }

    /// The scene this picker answers for now (after any edits), when it has one to show.
    fn current_scene(&self) -> Option<Arc<BuiltScene>> {
        None
    }

    /// A picker of this kind over `built` (a scene built anew), made from what this one keeps
    /// that does not depend on the scene: a GPU's device and compiled kernel (opening a device
    /// and compiling the kernel again cost about a second on lavapipe). This picker is left as
    /// it was. `None` when it keeps nothing worth reusing: make one with [`make_picker`].
    fn remake(&self, built: Arc<BuiltScene>) -> Option<Result<Box<dyn Picker + Send>>> {
        let _ = built;
        None
    }

    /// Messages about fallbacks since the last call (the automatic backend's), for the caller
    /// to show.
    fn take_notes(&mut self) -> Vec<String> {
        Vec::new()
    }
}

/// Writes hits into distinct slots of a vector's reserved capacity from parallel tasks.
struct SlotWriter(*mut Hit);

// SAFETY: tasks write disjoint slots, each once (its uses: `answers_in`, `pick_fused` and
// `pick_overlapped`, whose spawned task and the calling thread refine different steps).
unsafe impl Send for SlotWriter {}
unsafe impl Sync for SlotWriter {}

impl SlotWriter {
    /// # Safety
    /// `slot` is within the reserved capacity and written by no one else.
    unsafe fn write(&self, slot: usize, hit: Hit) {
        unsafe { self.0.add(slot).write(hit) };
    }
}

/// A backend's core: traces batches of scene-frame rays (each with its own mode and culling
/// flags) and returns the raw per-ray records and all-hits lists. [`pick_through`] does
/// everything else.
pub trait Tracer {
    /// The scene this tracer answers for.
    fn built(&self) -> &Arc<BuiltScene>;
    /// The same, to change (set it, then call [`Tracer::scene_changed`]).
    fn built_mut(&mut self) -> &mut Arc<BuiltScene>;
    /// Brings whatever the tracer keeps of the scene (the GPU's buffers) up to date after its
    /// `BuiltScene` changed as `refit` says.
    fn scene_changed(&mut self, refit: Refit) -> Result<()> {
        let _ = refit;
        Ok(())
    }
    /// Traces `rays`; `out.0[i]` answers `rays[i]`, and `out.1` holds `settings.max_hits`
    /// entries per ray.
    fn trace(
        &mut self,
        rays: &[GpuRay],
        settings: &TraceSettings<'_>,
    ) -> Result<(Vec<GpuHit>, Vec<GpuHitEntry>)>;
    /// The batch size from which [`pick_through`] traces rays in [`RayOrder`].
    fn reorder_from(&self) -> usize;
    /// This tracer as a [`ChunkTrace`] for `settings`, or `None` when it traces whole batches
    /// only (the GPU). With one, [`pick_through`] takes each chunk of closest- or any-hit rays
    /// into the scene frame, traces it and refines its hits in one pass on one thread, with no
    /// batch-sized buffers between the steps.
    fn chunk_trace<'a>(&'a self, settings: &TraceSettings<'a>) -> Result<Option<ChunkTrace<'a>>> {
        let _ = settings;
        Ok(None)
    }
    /// Rays per step when [`pick_through`] overlaps this tracer's work with the pipeline's
    /// own (`None` or 0: it does not). For a tracer of whole batches that waits on a device (the
    /// GPU): while it traces one step, the cores refine the step before and convert the step
    /// after. [`Tracer::trace`] must then return one record per ray of each step (a pick fails
    /// otherwise).
    fn overlap_step(&self) -> Option<usize> {
        None
    }
    /// Which path this is, for messages ([`Picker::describe`]).
    fn path_name(&self) -> String;
    /// [`Picker::take_notes`] for this tracer.
    fn tracer_notes(&mut self) -> Vec<String> {
        Vec::new()
    }
    /// [`Picker::remake`] for this tracer.
    fn picker_over(&self, built: Arc<BuiltScene>) -> Option<Result<Box<dyn Picker + Send>>> {
        let _ = built;
        None
    }
}

/// Traces one chunk of closest- or any-hit scene-frame rays into `hits` (one per ray), on the
/// calling thread: how a CPU tracer runs inside [`pick_through`]'s own parallel loop.
pub type ChunkTrace<'a> = Box<dyn Fn(&[GpuRay], &mut [GpuHit]) + Sync + 'a>;

/// Every tracer is a picker through the one pipeline.
impl<T: Tracer> Picker for T {
    fn query(&mut self, rays: &[Ray], query: &Query) -> Result<Answers> {
        let mut answers = Answers::default();
        self.query_into(rays, query, &mut answers)?;
        Ok(answers)
    }

    fn query_into(&mut self, rays: &[Ray], query: &Query, answers: &mut Answers) -> Result<()> {
        let from = self.reorder_from();
        pick_through(self, from, rays, query, answers)
    }

    fn describe(&self) -> String {
        self.path_name()
    }

    fn edit(&mut self, change: &mut dyn FnMut(&mut BuiltScene) -> Result<Refit>) -> Result<Refit> {
        let refit = change(Arc::make_mut(self.built_mut()))?;
        self.scene_changed(refit)?;
        Ok(refit)
    }

    fn set_mask(&mut self, object: u32, mask: u32) -> Result<()> {
        if object as usize >= Tracer::built(self).object_count() {
            return Err(crate::error::Error::Invalid(format!(
                "there is no object {object}"
            )));
        }
        Arc::make_mut(self.built_mut()).set_object_mask(object, mask)?;
        // The per-triangle masks may have appeared or gone: new buffers where there are any.
        self.scene_changed(Refit::Rebuilt)
    }

    fn current_scene(&self) -> Option<Arc<BuiltScene>> {
        Some(Tracer::built(self).clone())
    }

    fn remake(&self, built: Arc<BuiltScene>) -> Option<Result<Box<dyn Picker + Send>>> {
        self.picker_over(built)
    }

    fn take_notes(&mut self) -> Vec<String> {
        self.tracer_notes()
    }

    fn set_positions(&mut self, object: u32, positions: &[DVec3]) -> Result<Refit> {
        // Refused positions copy nothing, even from a shared scene.
        self.built()
            .scene
            .check_object_positions(object, positions)?;
        let refit = Arc::make_mut(self.built_mut()).set_positions(object, positions)?;
        self.scene_changed(refit)?;
        Ok(refit)
    }
}

/// The one pick pipeline: validates `query`, takes `rays` into the scene frame, traces them
/// through `tracer` (in ray order from `reorder_from` rays), and refines every hit in f64,
/// into `answers` (whose old contents are replaced; the fused and overlapped paths reuse its
/// memory).
pub fn pick_through<T: Tracer + ?Sized>(
    tracer: &mut T,
    reorder_from: usize,
    rays: &[Ray],
    query: &Query,
    answers: &mut Answers,
) -> Result<()> {
    query.validate()?;
    let built = tracer.built().clone();
    let settings = built.settings(query);
    if query.mode != Mode::All {
        if let Some(chunk) = tracer.chunk_trace(&settings)? {
            return pick_fused(&built, &chunk, reorder_from, rays, query, answers);
        }
        if let Some(step) = tracer.overlap_step()
            && step > 0
            && rays.len() > step
            && rays.len() < reorder_from
        {
            return pick_overlapped(tracer, &built, &settings, step, rays, query, answers);
        }
    }
    *answers = trace_whole(tracer, &built, &settings, reorder_from, rays, query)?;
    Ok(())
}

/// `rays` in the scene frame for `query`, with their direction lengths
/// ([`crate::frame::scene_rays`]), and an instanced scene's origin low parts
/// ([`put_origin_lo`]).
fn kernel_rays(built: &BuiltScene, rays: &[Ray], query: &Query) -> (Vec<GpuRay>, Vec<f64>) {
    let frame = built.frame();
    let (mut local, lengths) = scene_rays(frame, rays, query);
    if built.instances.is_some() {
        put_origin_lo(frame, rays, &mut local);
    }
    (local, lengths)
}

/// `answers` emptied for a batch of `n` closest or any answers, and its answer vector, empty
/// with room for `n` (its memory kept when it has room; else fresh, advised onto huge pages).
fn answer_buffer(answers: &mut Answers, n: usize) -> Vec<Hit> {
    let mut nearest = std::mem::take(&mut answers.nearest);
    *answers = Answers::default();
    nearest.clear();
    if nearest.capacity() < n {
        nearest = crate::huge_pages::vec_with_capacity(n);
    }
    nearest
}

/// [`pick_through`] for whole batches: all-hits mode, and tracers that neither trace in chunks
/// ([`ChunkTrace`]) nor overlap steps ([`Tracer::overlap_step`]), or batches they do not
/// overlap.
fn trace_whole<T: Tracer + ?Sized>(
    tracer: &mut T,
    built: &BuiltScene,
    settings: &TraceSettings<'_>,
    reorder_from: usize,
    rays: &[Ray],
    query: &Query,
) -> Result<Answers> {
    let (local, dir_lengths) = kernel_rays(built, rays, query);
    let reorder = local.len() >= reorder_from;
    if query.mode == Mode::All {
        let (found, lists) = trace_in_order(&local, settings.max_hits, reorder, |rays| {
            tracer.trace(rays, settings)
        })?;
        return built.answers(rays, &dir_lengths, query, &found, &lists);
    }
    match reorder.then(|| RayOrder::new(&local)).flatten() {
        None => {
            let (found, lists) = tracer.trace(&local, settings)?;
            built.answers(rays, &dir_lengths, query, &found, &lists)
        }
        Some(order) => {
            let (found, lists) = tracer.trace(&order.gather(&local), settings)?;
            built.answers_in(Some(&order), rays, &dir_lengths, query, &found, &lists)
        }
    }
}

/// Rays per step of [`pick_fused`]: small enough that a step's scene-frame rays and raw
/// results stay in the core's cache (and on its stack), large enough to amortise a task.
const FUSED_CHUNK: usize = 256;

/// [`pick_through`] for a [`ChunkTrace`] in closest or any mode: each parallel step takes
/// [`FUSED_CHUNK`] rays into the scene frame, traces them and refines their hits straight into
/// their answer slots. The answers are those of the batch path, bit for bit: the same
/// conversion, trace, check and refinement per ray, only without the batch-sized buffers
/// between them. Batches from `reorder_from` rays are traced in [`RayOrder`] (the sort needs
/// their scene-frame rays, so those are made first). The hits go into `answers.nearest`, whose
/// memory is reused when it has room.
fn pick_fused(
    built: &BuiltScene,
    chunk: &ChunkTrace<'_>,
    reorder_from: usize,
    rays: &[Ray],
    query: &Query,
    answers: &mut Answers,
) -> Result<()> {
    let n = rays.len();
    let frame = built.frame();
    let ordered = (n >= reorder_from)
        .then(|| {
            let (local, lengths) = kernel_rays(built, rays, query);
            RayOrder::new(&local).map(|order| (local, lengths, order))
        })
        .flatten();
    let mut nearest = answer_buffer(answers, n);
    let out = SlotWriter(nearest.as_mut_ptr());
    // Each step its own stealable job. Left to rayon's adaptive splitting, a thread ran one
    // sequential run of steps to its end while the other, done with its own, had nothing left
    // to steal: where steps cost unevenly (the soup's camera rays: one half of the picture
    // costs 1.4 times the other) the two threads were idle 13% of a trace (BENCHMARKS.md).
    (0..n.div_ceil(FUSED_CHUNK))
        .into_par_iter()
        .with_max_len(1)
        .try_for_each(|c| -> Result<()> {
            let span = c * FUSED_CHUNK..((c + 1) * FUSED_CHUNK).min(n);
            let m = span.len();
            let mut local = [NEVER_TRACED; FUSED_CHUNK];
            let mut lengths = [0.0f64; FUSED_CHUNK];
            let mut input = [0usize; FUSED_CHUNK];
            match &ordered {
                Some((all, all_lengths, order)) => {
                    for (k, j) in span.enumerate() {
                        let i = order.order()[j] as usize;
                        (local[k], lengths[k]) = (all[i], all_lengths[i]);
                        input[k] = i;
                    }
                }
                None => {
                    let start = span.start;
                    // The next step's rays asked for now: read at the start of each step, they
                    // came from memory one miss after another.
                    let next = (span.end..(span.end + FUSED_CHUNK).min(n)).len();
                    if next > 0 {
                        crate::prefetch::bytes(
                            rays[span.end..].as_ptr().cast(),
                            next * std::mem::size_of::<Ray>(),
                        );
                    }
                    // An instanced scene's rays carry their origins' rests too, made in the
                    // same pass.
                    let (rays, local, lengths) = (&rays[span], &mut local[..m], &mut lengths[..m]);
                    if built.instances.is_some() {
                        local_rays_with_rests_into(frame, rays, query, local, lengths);
                    } else {
                        local_rays_into(frame, rays, query, local, lengths);
                    }
                    for (k, slot) in input[..m].iter_mut().enumerate() {
                        *slot = start + k;
                    }
                }
            }
            let mut found = [GpuHit::default(); FUSED_CHUNK];
            chunk(&local[..m], &mut found[..m]);
            // SAFETY: `input` holds each step's slots of a permutation of 0..n (the identity, or
            // `RayOrder`), and steps cover disjoint spans of it, so each slot of the reserved
            // capacity is written exactly once, by one task.
            unsafe { refine_into(built, rays, &input[..m], &lengths[..m], &found[..m], &out) }
        })?;
    // SAFETY: every slot below n was written above (on an error we return before this, and Hit
    // is Copy, so the vector is dropped empty).
    unsafe { nearest.set_len(n) };
    answers.nearest = nearest;
    Ok(())
}

/// Checks one chunk's raw results and refines its hits in f64: `found[k]` and `lengths[k]`
/// belong to `rays[input[k]]`, whose answer is written to slot `input[k]` of `out`.
///
/// # Safety
/// Each slot `input[k]` is within `out`'s reserved capacity and written by no other task.
unsafe fn refine_into(
    built: &BuiltScene,
    rays: &[Ray],
    input: &[usize],
    lengths: &[f64],
    found: &[GpuHit],
    out: &SlotWriter,
) -> Result<()> {
    check_found_in(built.prim_count(), found, |f| f.prim)?;
    // SAFETY (both writes): the caller's promise.
    if let Some(instances) = &built.instances {
        crate::instance::resolve_chunk(instances, rays, input, lengths, found, |k, hit| unsafe {
            out.write(input[k], hit)
        });
        return Ok(());
    }
    prefetch_hit_triangles(&built.scene, &built.bvh, found, lengths);
    resolve_chunk(
        &built.scene,
        &built.bvh,
        rays,
        input,
        lengths,
        found,
        |k, hit| unsafe { out.write(input[k], hit) },
    );
    Ok(())
}

/// [`pick_through`] for a tracer of whole batches with an [`Tracer::overlap_step`] (the GPU), in
/// closest or any mode, for a batch traced in input order that is longer than one step: the
/// batch goes through in steps, and while this thread waits on the tracer for one step, the
/// other cores refine the step before it ([`refine_into`], as the fused path does) and take the
/// step after it into the scene frame. Every ray is converted, traced, checked and refined as in
/// [`trace_whole`], so the answers are the same bits; only the host's work and the device's
/// overlap (on an NVIDIA H200 a 1M-ray pick ran 1.3–1.9× faster: BENCHMARKS.md, "A real GPU").
fn pick_overlapped<T: Tracer + ?Sized>(
    tracer: &mut T,
    built: &BuiltScene,
    settings: &TraceSettings<'_>,
    step: usize,
    rays: &[Ray],
    query: &Query,
    answers: &mut Answers,
) -> Result<()> {
    let n = rays.len();
    let convert = |span: std::ops::Range<usize>| kernel_rays(built, &rays[span], query);
    let mut nearest = answer_buffer(answers, n);
    let out = SlotWriter(nearest.as_mut_ptr());
    // Refines a traced step (its first ray, direction lengths and raw results) into `out`.
    let refine = |(start, lengths, found): (usize, Vec<f64>, Vec<GpuHit>)| -> Result<()> {
        found
            .par_chunks(FUSED_CHUNK)
            .zip(lengths.par_chunks(FUSED_CHUNK))
            .enumerate()
            .try_for_each(|(c, (found, lengths))| {
                let first = start + c * FUSED_CHUNK;
                let mut input = [0usize; FUSED_CHUNK];
                for (k, slot) in input[..found.len()].iter_mut().enumerate() {
                    *slot = first + k;
                }
                // SAFETY: steps and their chunks cover disjoint spans of 0..n, each slot once
                // (each step's results were checked to be one per ray).
                unsafe { refine_into(built, rays, &input[..found.len()], lengths, found, &out) }
            })
    };
    let spans: Vec<_> = (0..n).step_by(step).map(|s| s..(s + step).min(n)).collect();
    let mut next = Some(convert(spans[0].clone()));
    let mut traced: Option<(usize, Vec<f64>, Vec<GpuHit>)> = None;
    for (i, span) in spans.iter().enumerate() {
        let (local, lengths) = next
            .take()
            .expect("each step is converted before it is traced");
        let (previous, later) = (traced.take(), spans.get(i + 1).cloned());
        let mut host = None;
        let found = rayon::in_place_scope(|scope| {
            scope.spawn(|_| {
                let refined = previous.map_or(Ok(()), refine);
                host = Some(refined.map(|()| later.map(convert)));
            });
            tracer.trace(&local, settings)
        });
        next = host.expect("the scope ends after its task")?;
        let found = found?.0;
        if found.len() != span.len() {
            return Err(crate::error::Error::Invalid(format!(
                "the tracer returned {} results for a step of {} rays",
                found.len(),
                span.len()
            )));
        }
        traced = Some((span.start, lengths, found));
    }
    if let Some(last) = traced {
        refine(last)?;
    }
    // SAFETY: every slot below n was written above: the steps cover 0..n, each step's results
    // were one per ray, and each was refined whole (on an error we return before this, and Hit
    // is Copy, so the vector is dropped empty).
    unsafe { nearest.set_len(n) };
    answers.nearest = nearest;
    Ok(())
}

/// Asks the cache for the world triangles `resolve_with` is about to refine, in two sweeps over
/// a chunk's hits (their scene triangles, then those triangles' vertices), so the chunk's cache
/// misses overlap instead of coming three in a row per hit. `found` was checked
/// ([`check_found`]).
fn prefetch_hit_triangles(scene: &Scene, bvh: &Bvh, found: &[GpuHit], lengths: &[f64]) {
    let (triangles, positions) = (scene.triangles(), scene.positions());
    let block = crate::frame::RESOLVE_BLOCK;
    for (found, lengths) in found.chunks(block).zip(lengths.chunks(block)) {
        // The hits listed once, without a branch per result (hits and misses alternate at
        // random on incoherent rays: three filtering passes mispredicted half the time).
        let (hits, _) = split_hits(found, lengths);
        let prims = || hits.iter().map(|&j| found[usize::from(j)].prim as usize);
        for p in prims() {
            crate::prefetch::item(&bvh.triangle_ids, p);
        }
        for p in prims() {
            crate::prefetch::item(triangles, bvh.triangle_ids[p] as usize);
        }
        for p in prims() {
            for v in triangles[bvh.triangle_ids[p] as usize] {
                crate::prefetch::item(positions, v as usize);
            }
        }
    }
}

/// The CPU engine (`--backend cpu`): the wide SIMD walk of [`crate::engine`], on all cores.
#[derive(Clone, Debug)]
pub struct CpuPicker {
    built: Arc<BuiltScene>,
    reorder_from: usize,
    simd: Simd,
    packets: bool,
    interleave: Option<bool>,
}

/// The engine traces batches in the order given, however large ([`CpuPicker::set_reorder_from`]
/// turns [`RayOrder`] on): on the 1M incoherent sets of the bunny, the dragon and the DEM its
/// pick ran 1.1–1.45× faster unsorted (BENCHMARKS.md, "What changed, each step measured A/B");
/// the 8-wide walk gains less from sorted rays than the sort costs. The twin and a software GPU
/// keep sorting from [`DEFAULT_REORDER_FROM`] (a hardware GPU does not:
/// [`crate::gpu::picker::reorder_from_for`]).
pub const ENGINE_REORDER_FROM: usize = usize::MAX;

impl CpuPicker {
    /// A CPU engine picker over `built`, on the best lanes this CPU has (see [`Simd::detect`]).
    pub fn new(built: Arc<BuiltScene>) -> Self {
        Self {
            built,
            reorder_from: ENGINE_REORDER_FROM,
            simd: Simd::detect(),
            packets: true,
            interleave: None,
        }
    }

    /// Sets the batch size from which rays are traced in [`crate::ray_order::RayOrder`]
    /// (`usize::MAX`: never). Answers are the same either way.
    pub fn set_reorder_from(&mut self, rays: usize) {
        self.reorder_from = rays;
    }

    /// Runs on `simd` lanes (the portable lanes where this CPU lacks them). Answers are the
    /// same on every choice.
    pub fn set_simd(&mut self, simd: Simd) {
        self.simd = simd;
    }

    /// Traces coherent groups of eight rays as packets (the default) or every ray alone. Answers
    /// are the same either way.
    pub fn set_packets(&mut self, on: bool) {
        self.packets = on;
    }

    /// Walks incoherent rays interleaved (`Some(true)`), one by one (`Some(false)`), or as the
    /// engine chooses (`None`, the default: interleaved).
    /// Answers are the same either way.
    pub fn set_interleave(&mut self, on: Option<bool>) {
        self.interleave = on;
    }

    /// The engine over this picker's scene for `settings`, as this picker is set.
    fn engine<'a>(&'a self, settings: &TraceSettings<'a>) -> Result<crate::engine::Engine<'a>> {
        let built = &self.built;
        if let Some(instances) = built.instances() {
            return crate::engine::Engine::instanced(
                instances,
                &built.bvh.nodes,
                settings,
                self.simd,
            );
        }
        let mut engine = crate::engine::Engine::new(
            built.wide()?,
            &built.bvh,
            settings,
            self.simd,
            self.packets,
        );
        if let Some(on) = self.interleave {
            engine.set_interleave(on);
        }
        Ok(engine)
    }
}

impl Tracer for CpuPicker {
    fn built(&self) -> &Arc<BuiltScene> {
        &self.built
    }

    fn built_mut(&mut self) -> &mut Arc<BuiltScene> {
        &mut self.built
    }

    fn trace(
        &mut self,
        rays: &[GpuRay],
        settings: &TraceSettings<'_>,
    ) -> Result<(Vec<GpuHit>, Vec<GpuHitEntry>)> {
        Ok(self
            .engine(settings)?
            .trace_batch(rays, settings.max_hits as usize))
    }

    fn chunk_trace<'a>(&'a self, settings: &TraceSettings<'a>) -> Result<Option<ChunkTrace<'a>>> {
        let engine = self.engine(settings)?;
        Ok(Some(Box::new(move |rays, hits| {
            engine.trace_chunk(rays, hits, &mut [])
        })))
    }

    fn reorder_from(&self) -> usize {
        self.reorder_from
    }

    fn path_name(&self) -> String {
        let simd = if self.simd.is_available() {
            self.simd
        } else {
            Simd::Portable
        };
        format!(
            "cpu engine ({}, {})",
            simd.name(),
            threads_phrase(rayon::current_num_threads())
        )
    }
}

/// The reference path (`--backend reference`): the kernel's twin, its traversal line for line in
/// Rust (`cpu::traverse`), on all cores.
#[derive(Clone, Debug)]
pub struct ReferencePicker {
    built: Arc<BuiltScene>,
    reorder_from: usize,
}

impl ReferencePicker {
    /// A reference picker over `built`.
    pub fn new(built: Arc<BuiltScene>) -> Self {
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

impl Tracer for ReferencePicker {
    fn built(&self) -> &Arc<BuiltScene> {
        &self.built
    }

    fn built_mut(&mut self) -> &mut Arc<BuiltScene> {
        &mut self.built
    }

    fn trace(
        &mut self,
        rays: &[GpuRay],
        settings: &TraceSettings<'_>,
    ) -> Result<(Vec<GpuHit>, Vec<GpuHitEntry>)> {
        Ok(trace_batch(&self.built.bvh, rays, settings))
    }

    fn chunk_trace<'a>(&'a self, settings: &TraceSettings<'a>) -> Result<Option<ChunkTrace<'a>>> {
        let buffers = crate::cpu::buffers(&self.built.bvh, settings);
        Ok(Some(Box::new(move |rays, hits| {
            for (ray, hit) in rays.iter().zip(hits) {
                *hit = crate::cpu::traverse::trace(buffers, ray, &mut []);
            }
        })))
    }

    fn reorder_from(&self) -> usize {
        self.reorder_from
    }

    fn path_name(&self) -> String {
        format!(
            "reference (the kernel's twin, {})",
            threads_phrase(rayon::current_num_threads())
        )
    }
}

/// Which path answers picks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Backend {
    /// The CPU engine on a CPU-only or software-GPU machine and for small batches; the GPU for
    /// large batches on a real GPU (see [`crate::auto::AutoPicker`]). Says so when it falls back.
    #[default]
    Auto,
    /// The WGSL kernel on a GPU (lavapipe on machines without one); fails when there is none.
    Gpu,
    /// The CPU engine: wide SIMD traversal on all cores.
    Cpu,
    /// The kernel's twin on the CPU: the reference the other paths are checked against.
    Reference,
}

crate::names::named!(Backend {
    Auto => ("auto", "The CPU engine on a CPU-only or software-GPU machine and for small batches; the GPU for large batches on a real GPU."),
    Gpu => ("gpu", "The WGSL kernel on a GPU (lavapipe on machines without one); fails when there is none."),
    Cpu => ("cpu", "The CPU engine: wide SIMD traversal on all cores."),
    Reference => ("reference", "The kernel's twin on the CPU: the reference the other paths are checked against."),
});

/// The picker for `backend`: the one factory the command line and the server share. GPU and
/// automatic pickers use the process's shared device ([`crate::GpuContext::shared`]).
pub fn make_picker(backend: Backend, built: Arc<BuiltScene>) -> Result<Box<dyn Picker + Send>> {
    Ok(match backend {
        Backend::Cpu => Box::new(CpuPicker::new(built)),
        Backend::Reference => Box::new(ReferencePicker::new(built)),
        Backend::Gpu => Box::new(crate::gpu::GpuPicker::new(
            &crate::gpu::GpuContext::shared()?,
            built,
        )?),
        Backend::Auto => Box::new(crate::auto::AutoPicker::new(built)),
    })
}

/// "1 thread", "2 threads": how a picker's description names its CPU threads.
fn threads_phrase(n: usize) -> String {
    format!("{n} thread{}", if n == 1 { "" } else { "s" })
}
