//! Instanced scenes: each mesh stored and built once, in its own f32 frame, and placed any
//! number of times by f64 affine transforms. Owns the instance model ([`Instance`],
//! [`Instances`]), the two-level layout the tracers walk (a top tree over the instances' exact
//! world boxes, [`extent`], built by median cut in [`top`], in front of every mesh's bottom
//! tree, in one node buffer), the per-instance records the kernel reads ([`GpuInstance`]), and
//! the way back from a hit to the world ([`Instances::locate`], through [`locate::HitIndex`]).
//!
//! Data flow: meshes ([`Scene`]s of one object, in file coordinates) + instances
//! -> [`Instances::build`] -> (`Instances`, the combined [`Bvh`]) -> the tracers (the kernel, its
//! twin, the engine) -> hits whose `prim` is `prim_base + file-order triangle` -> [`resolve`]
//! (the world triangle in f64, refined as every hit is).

pub mod extent;
pub mod locate;
pub mod resolve;
pub mod top;

use crate::bvh::{BuildOptions, Bvh};
use crate::engine::WideBvh;
use crate::error::{Error, Result};
use crate::layout::{GpuInstance, GpuNode, INSTANCE_MIRRORED, KIND_BITS, MAX_NODES, UNFINISHED};
use crate::scene::{Scene, apply_transform, check_transform};
use glam::{DMat3, DVec3, Vec3};
use std::sync::{Arc, OnceLock};

/// Bytes a world triangle of [`Instances::baked`] takes: its three f64 corners (72) and its
/// indices and share of the scene's other arrays.
pub const BAKED_TRIANGLE_BYTES: u64 = 96;

pub use resolve::{resolve_chunk, resolve_with};

/// The identity transform (3 × 4, row-major).
pub const IDENTITY: [[f64; 4]; 3] = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
];

/// One placed copy of a mesh. Its id (the `object` its hits report) is its position in the
/// scene's instance list.
#[derive(Clone, Debug, PartialEq)]
pub struct Instance {
    /// A name for messages (the file it came from).
    pub name: String,
    /// The mesh it places (an index into the scene's meshes).
    pub mesh: u32,
    /// From the mesh's (file) coordinates to the world: 3 × 4 row-major, world = M·[x, y, z, 1].
    pub transform: [[f64; 4]; 3],
    /// Layer mask: rays hit the instance only when their mask shares a bit with it (0: never).
    pub mask: u32,
}

/// A mesh of an instanced scene: its f64 positions in file coordinates (a scene of one object)
/// and the tree built over it, in the mesh's own f32 frame.
#[derive(Debug)]
pub struct MeshTree {
    /// The mesh, as one object (grid shape and mirroring as loaded).
    pub scene: Scene,
    /// Its own tree (origin: the centre of the mesh's bounds).
    pub bvh: Bvh,
    /// The CPU engine's wide tree, collapsed from `bvh` on first use.
    wide: OnceLock<std::result::Result<WideBvh, String>>,
    /// `bvh`'s leaf-order vertex indices ([`Bvh::leaf_vertices`]), made by the mesh's first
    /// refit and passed on to the refitted tree.
    leaf_vertices: OnceLock<Arc<Vec<[u32; 3]>>>,
    /// The vertices in chunks for its instances' exact world boxes, made on first use.
    extent: OnceLock<extent::Extent>,
}

impl MeshTree {
    /// A mesh with its tree.
    pub fn new(scene: Scene, bvh: Bvh) -> Self {
        Self {
            scene,
            bvh,
            wide: OnceLock::new(),
            leaf_vertices: OnceLock::new(),
            extent: OnceLock::new(),
        }
    }

    /// A mesh with its tree and the CPU engine's tree collapsed from it elsewhere (a saved
    /// scene's, validated).
    pub fn with_wide(scene: Scene, bvh: Bvh, wide: WideBvh) -> Self {
        let tree = Self::new(scene, bvh);
        let _ = tree.wide.set(Ok(wide));
        tree
    }

    /// The box of the mesh's vertices through `transform` ([`extent::Extent`]), exactly the
    /// box of every vertex its triangles use, each through `apply_transform`; `None` for a mesh
    /// with nothing to hit.
    pub fn world_box(&self, transform: &[[f64; 4]; 3]) -> Option<(DVec3, DVec3)> {
        if self.bvh.nodes.is_empty() {
            return None;
        }
        // The mesh box's corners first: where they leave the finite range that box is the
        // answer (and the caller's error). Where they stay in it, so does every vertex's and
        // every chunk bound's row, term by term (each lies between two corners' and the
        // operations are monotone), and the search meets no infinity or NaN.
        let (lo, hi) = self.scene.bounds()?;
        for c in 0..8 {
            let corner = DVec3::new(
                if c & 1 == 0 { lo.x } else { hi.x },
                if c & 2 == 0 { lo.y } else { hi.y },
                if c & 4 == 0 { lo.z } else { hi.z },
            );
            let p = apply_transform(transform, corner);
            if !p.is_finite() {
                return Some((p, p));
            }
        }
        self.extent
            .get_or_init(|| extent::Extent::new(&self.scene, &self.bvh))
            .world_box(self.scene.positions(), transform)
    }

    /// The CPU engine's wide tree (an error for a corrupted tree).
    pub fn wide(&self) -> Result<&WideBvh> {
        self.wide
            .get_or_init(|| WideBvh::collapse(&self.bvh).map_err(|e| e.to_string()))
            .as_ref()
            .map_err(|e| Error::Invalid(e.clone()))
    }
}

/// The instances of a scene and the meshes they place, with what the tracers read of them.
#[derive(Clone, Debug)]
pub struct Instances {
    meshes: Vec<Arc<MeshTree>>,
    instances: Vec<Instance>,
    /// One record per instance, in instance order.
    records: Vec<GpuInstance>,
    /// From a hit id to its instance ([`Instances::locate`]).
    hits: locate::HitIndex,
    /// Where each mesh's nodes and triangles start in the combined buffers.
    mesh_nodes: Vec<u32>,
    mesh_triangles: Vec<u32>,
    top_nodes: u32,
    /// The top tree collapsed 8-wide, for the CPU engine (leaf children are instances).
    top_wide: WideBvh,
    /// Each instance's leaf in the top tree ([`NO_LEAF`]: a mesh with nothing to hit, or an
    /// instance removed before the tree was last laid out).
    leaf_of: Vec<u32>,
    /// Each instance, whether it was removed ([`Instances::remove`]): never hit, moved or
    /// shown again, and left out of the top tree and the frame from the next layout on.
    removed: Vec<bool>,
    /// Hit ids in all: the triangles of the instances not removed when last laid out.
    prim_total: u64,
    origin: DVec3,
    bounds: Option<(DVec3, DVec3)>,
    iteration_cap: u32,
}

/// The box around `boxes`; `None` when there is none.
fn all_bounds<'a>(
    boxes: impl IntoIterator<Item = &'a Option<(DVec3, DVec3)>>,
) -> Option<(DVec3, DVec3)> {
    let (lo, hi) = boxes
        .into_iter()
        .flatten()
        .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), b| {
            (lo.min(b.0), hi.max(b.1))
        });
    lo.is_finite().then_some((lo, hi))
}

/// `leaf_of` of an instance without a leaf.
const NO_LEAF: u32 = u32::MAX;

impl Instances {
    /// Builds each mesh's tree once with `options`, then the top tree over the instances, and
    /// returns the instances with the combined tree the tracers walk (top nodes first, then
    /// each mesh's nodes; each mesh's triangles in leaf order, one mesh after another). Fails,
    /// naming the instance, on an unknown mesh or a transform that is not finite or is
    /// singular; and when the instanced triangles outnumber the hit ids (2³² − 2).
    pub fn build(
        meshes: Vec<Scene>,
        instances: Vec<Instance>,
        options: &BuildOptions,
    ) -> Result<(Instances, Bvh)> {
        for (k, m) in meshes.iter().enumerate() {
            if m.objects().len() != 1 {
                return Err(Error::Invalid(format!(
                    "mesh {k} has {} objects; a mesh of an instanced scene is one object",
                    m.objects().len()
                )));
            }
        }
        let trees = meshes
            .into_iter()
            .map(|scene| {
                let bvh = Bvh::build(&scene, options)?;
                Ok(Arc::new(MeshTree::new(scene, bvh)))
            })
            .collect::<Result<Vec<_>>>()?;
        Self::assemble(trees, instances)
    }

    /// [`Instances::build`] over meshes whose trees exist; the scene frame is centred on the
    /// instances' bounds.
    pub fn assemble(meshes: Vec<Arc<MeshTree>>, instances: Vec<Instance>) -> Result<(Self, Bvh)> {
        let removed = vec![false; instances.len()];
        Self::assemble_about(meshes, instances, removed, None)
    }

    /// [`Instances::assemble`] with the scene frame's origin at `origin`, or at the centre of
    /// the instances' bounds when `None`; the instances `removed` are left out of the top tree.
    fn assemble_about(
        meshes: Vec<Arc<MeshTree>>,
        instances: Vec<Instance>,
        removed: Vec<bool>,
        origin: Option<DVec3>,
    ) -> Result<(Self, Bvh)> {
        for (k, i) in instances.iter().enumerate() {
            check_instance(&meshes, k, i)?;
        }
        // Hit ids run over the instances not removed (a removed one's range is empty), so
        // instances added and removed over a scene's life do not use the ids up.
        let mut total = 0u64;
        for (i, _) in instances.iter().zip(&removed).filter(|(_, r)| !**r) {
            total += meshes[i.mesh as usize].scene.triangle_count() as u64;
        }
        if total >= u64::from(UNFINISHED) {
            return Err(Error::Invalid(format!(
                "the instances hold {total} triangles in all; hits can name at most {}",
                UNFINISHED - 1
            )));
        }
        let mut mesh_nodes = Vec::with_capacity(meshes.len());
        let mut mesh_triangles = Vec::with_capacity(meshes.len());
        let (mut nodes, mut triangles) = (0u64, 0u64);
        for m in &meshes {
            mesh_nodes.push(nodes);
            mesh_triangles.push(triangles);
            nodes += m.bvh.nodes.len() as u64;
            triangles += m.bvh.triangles.len() as u64;
        }
        let mut this = Instances {
            meshes,
            instances,
            records: Vec::new(),
            hits: locate::HitIndex::default(),
            mesh_nodes: Vec::new(),
            mesh_triangles: mesh_triangles.iter().map(|&t| t as u32).collect(),
            top_nodes: 0,
            top_wide: WideBvh::default(),
            leaf_of: Vec::new(),
            removed,
            prim_total: 0,
            origin: DVec3::ZERO,
            bounds: None,
            iteration_cap: 0,
        };
        let boxes = this.world_boxes();
        if let Some(k) = boxes
            .iter()
            .position(|b| b.is_some_and(|(lo, hi)| !(lo.is_finite() && hi.is_finite())))
        {
            return Err(Error::Invalid(format!(
                "instance {k} (\"{}\"): the transform carries the mesh past the finite range",
                crate::budget::quote(&this.instances[k].name)
            )));
        }
        (this.origin, this.bounds) = match all_bounds(&boxes) {
            Some((lo, hi)) => (origin.unwrap_or((lo + hi) * 0.5), Some((lo, hi))),
            None => (origin.unwrap_or(DVec3::ZERO), None),
        };
        // The frame is centred on every instance (a hidden one may be shown again); the bounds
        // users see are those of the instances that can be hit, where there are any.
        if let Some(live) = this.live_bounds(&boxes) {
            this.bounds = Some(live);
        }
        let top = top::build(&this.scene_boxes(&boxes));
        let top_count = top.len() as u64;
        if top_count + nodes > u64::from(MAX_NODES) || triangles > u64::from(u32::MAX) {
            return Err(Error::Invalid(format!(
                "the instanced scene needs {} nodes, more than the {MAX_NODES} the node format \
                 can address",
                top_count + nodes
            )));
        }
        this.top_nodes = top_count as u32;
        this.mesh_nodes = mesh_nodes.iter().map(|&n| (n + top_count) as u32).collect();
        let mut prim_base = 0u32;
        this.records = Vec::with_capacity(this.instances.len());
        for k in 0..this.instances.len() {
            let record = this.record(k, prim_base);
            this.records.push(record);
            if !this.removed[k] {
                prim_base += this.meshes[this.instances[k].mesh as usize]
                    .scene
                    .triangle_count() as u32;
            }
        }
        this.prim_total = u64::from(prim_base);
        this.hits = locate::HitIndex::new(&this.records, u64::from(prim_base));
        this.leaf_of = vec![NO_LEAF; this.instances.len()];
        for (n, node) in top.iter().enumerate() {
            if node.is_leaf() {
                this.leaf_of[node.first as usize] = n as u32;
            }
        }
        let bvh = this.combined(top);
        if this.records.len() as u64 >= crate::engine::walk::MAX_CHILDREN {
            return Err(crate::error::Error::Invalid(format!(
                "{} instances: the CPU engine's top tree holds fewer than 2^28",
                this.records.len()
            )));
        }
        this.top_wide = WideBvh::collapse(&Bvh {
            nodes: bvh.nodes[..this.top_nodes as usize].to_vec().into(),
            ..Bvh::default()
        })?;
        this.iteration_cap = this.cap(&bvh.nodes[..this.top_nodes as usize]);
        Ok((this, bvh))
    }

    /// Places instance `k` by `transform` (from its mesh's coordinates to the world): its
    /// record is worked out again and its leaf's box, and the boxes above it, refitted in the
    /// top tree's nodes at the start of `bvh` (this scene's combined tree); nothing else
    /// changes, the scene frame's origin included. Fails, naming the instance, on an unknown
    /// instance or a transform that cannot place it, with nothing changed.
    pub fn set_transform(&mut self, bvh: &mut Bvh, k: u32, transform: [[f64; 4]; 3]) -> Result<()> {
        let i = self.present(k)?;
        let mut placed = self.instances[i].clone();
        placed.transform = transform;
        check_instance(&self.meshes, i, &placed)?;
        let old = std::mem::replace(&mut self.instances[i], placed);
        let placed_box = self.world_box(i);
        if let Some((lo, hi)) = placed_box
            && !(lo.is_finite() && hi.is_finite())
        {
            self.instances[i] = old;
            return Err(Error::Invalid(format!(
                "instance {k} (\"{}\"): the transform carries the mesh past the finite range",
                crate::budget::quote(&self.instances[i].name)
            )));
        }
        // Placed where its rays would be too coarse to pick it, where they were not (the old
        // place looked at only then: a move's common path costs no second box).
        if let Some(u) = placed_box.and_then(|b| self.unresolved_in(i, b)) {
            let placed = std::mem::replace(&mut self.instances[i], old);
            if self.unresolved_at(i).is_none() {
                return Err(Error::Invalid(u.describe(&format!(
                    "instance {k} (\"{}\")",
                    crate::budget::quote(&self.instances[i].name)
                ))));
            }
            self.instances[i] = placed;
        }
        // Where the instance was, as its leaf box holds it (rounded outward): where that reached
        // the edge of the bounds, they are worked out again after the move (an instance moved
        // far out and back left them reaching its far place, and with them the frame's reach,
        // so rays from far out were no longer moved near the scene before rounding); else the
        // move only grows them.
        let left_the_edge = self.instances[i].mask != 0
            && self
                .leaf_world_box(bvh, i)
                .is_some_and(|b| !self.strictly_within_bounds(b));
        let before = self.bounds;
        self.records[i] = self.record(i, self.records[i].prim_base);
        self.refit_leaf(bvh, i, placed_box);
        if left_the_edge && let Some(before) = before {
            self.bounds = self.bounds_by_leaves(bvh, i, before, placed_box);
        }
        self.refit_top_wide(bvh);
        Ok(())
    }

    /// Instance `k`'s leaf box in the top tree, in the world: its world box rounded outward
    /// (it holds the exact box); `None` for an instance without a leaf.
    fn leaf_world_box(&self, bvh: &Bvh, k: usize) -> Option<(DVec3, DVec3)> {
        let leaf = *self.leaf_of.get(k)?;
        let node = bvh.nodes.get(leaf as usize).filter(|_| leaf != NO_LEAF)?;
        Some((
            self.origin + Vec3::from(node.min).as_dvec3(),
            self.origin + Vec3::from(node.max).as_dvec3(),
        ))
    }

    /// The bounds of what can be hit after instance `moved` was moved to `placed` (its exact
    /// world box; `None`: nothing to hit) from where it reached the edge of `before` (the
    /// bounds then, exact), worked out again exactly from a few instances' world boxes: on each
    /// side, no other instance passes `before`, so the side is the moved one's where that
    /// reaches `before`, else the farthest of the others' exact sides, looked for only among
    /// those whose leaf box (which holds their exact box) reaches past what was found so far,
    /// and done as soon as one reaches `before` (instances side by side on flat ground share
    /// their lowest z). So a move costs one pass over the leaf boxes and a few meshes'
    /// vertices, not every instance's.
    fn bounds_by_leaves(
        &self,
        bvh: &Bvh,
        moved: usize,
        before: (DVec3, DVec3),
        placed: Option<(DVec3, DVec3)>,
    ) -> Option<(DVec3, DVec3)> {
        let placed = placed.filter(|_| self.instances[moved].mask != 0);
        let others: Vec<(usize, (DVec3, DVec3))> = (0..self.instances.len())
            .filter(|&k| k != moved && self.instances[k].mask != 0 && !self.removed[k])
            .filter_map(|k| Some((k, self.leaf_world_box(bvh, k)?)))
            .collect();
        if others.is_empty() && placed.is_none() {
            let boxes = self.world_boxes();
            return self.live_bounds(&boxes).or_else(|| all_bounds(&boxes));
        }
        let mut exact = std::collections::HashMap::new();
        let mut exact_box = |k: usize| *exact.entry(k).or_insert_with(|| self.world_box(k));
        // One side: `sign` 1 for the highest, -1 for the lowest (values negated).
        let mut side = |axis: usize, sign: f64| -> f64 {
            let limit = sign
                * if sign > 0.0 {
                    before.1[axis]
                } else {
                    before.0[axis]
                };
            let of = |b: (DVec3, DVec3)| sign * if sign > 0.0 { b.1[axis] } else { b.0[axis] };
            let mut far = placed.map_or(f64::NEG_INFINITY, of);
            // The farthest-reaching leaf first: what it holds is likely the side.
            let first = others
                .iter()
                .max_by(|a, b| of(a.1).total_cmp(&of(b.1)))
                .map(|&(k, _)| k);
            if let Some(b) = first.filter(|_| far < limit).and_then(&mut exact_box) {
                far = far.max(of(b));
            }
            for &(k, leaf) in &others {
                if far >= limit {
                    break;
                }
                if of(leaf) > far
                    && let Some(b) = exact_box(k)
                {
                    far = far.max(of(b));
                }
            }
            sign * far
        };
        let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        for axis in 0..3 {
            hi[axis] = side(axis, 1.0);
            lo[axis] = side(axis, -1.0);
        }
        (lo.is_finite() && hi.is_finite()).then_some((lo, hi))
    }

    /// Sets instance `k`'s layer mask (0: never hit, until shown again). Fails on an unknown or
    /// removed instance.
    pub fn set_mask(&mut self, k: u32, mask: u32) -> Result<()> {
        let i = self.present(k)?;
        let shown = |m: u32| m != 0;
        let changed = shown(self.instances[i].mask) != shown(mask);
        self.instances[i].mask = mask;
        self.records[i].mask = mask;
        // The bounds of what can be hit: a shown instance's box joins them; a hidden one that
        // reached their edge makes them worked out again (one box per instance).
        if !changed {
            return Ok(());
        }
        let Some((lo, hi)) = self.world_box(i) else {
            return Ok(());
        };
        if shown(mask) {
            self.bounds = Some(
                self.bounds
                    .map_or((lo, hi), |(blo, bhi)| (blo.min(lo), bhi.max(hi))),
            );
        } else {
            self.bounds_without((lo, hi));
        }
        Ok(())
    }

    /// Whether the box `(lo, hi)` lies within the bounds of what can be hit without touching
    /// their edge on any side: what leaves it leaves the bounds as they are.
    fn strictly_within_bounds(&self, (lo, hi): (DVec3, DVec3)) -> bool {
        self.bounds
            .is_some_and(|(blo, bhi)| lo.cmpgt(blo).all() && hi.cmplt(bhi).all())
    }

    /// After an instance whose world box is `gone` can no longer be hit: where it reached the
    /// edge of the bounds of what can be hit, they are worked out again (one box per instance;
    /// around every instance left when none can be hit, none when none is left).
    fn bounds_without(&mut self, gone: (DVec3, DVec3)) {
        if !self.strictly_within_bounds(gone) {
            let boxes = self.world_boxes();
            self.bounds = self.live_bounds(&boxes).or_else(|| all_bounds(&boxes));
        }
    }

    /// Removes instance `k` without renumbering the others: it is never hit again (its mask
    /// 0), and cannot be moved or shown again; the top tree and the scene frame leave it out
    /// from the next layout on (an addition, [`Instances::rebuild_top`]), so instances added
    /// and removed over a scene's life do not grow the top tree or each layout's time, nor use
    /// up the hit ids (a removed instance's range of them is empty from that layout on). A
    /// saved `.rpk` keeps it as a hidden instance. Fails on an unknown or removed instance.
    pub fn remove(&mut self, k: u32) -> Result<()> {
        let i = self.present(k)?;
        let reached = self.world_box(i);
        self.instances[i].mask = 0;
        self.records[i].mask = 0;
        self.removed[i] = true;
        if let Some(gone) = reached {
            self.bounds_without(gone);
        }
        Ok(())
    }

    /// The box around `boxes` (one per instance) of the instances that can be hit (mask not
    /// 0); `None` when none can.
    fn live_bounds(&self, boxes: &[Option<(DVec3, DVec3)>]) -> Option<(DVec3, DVec3)> {
        all_bounds(
            boxes
                .iter()
                .zip(&self.instances)
                .filter(|(_, i)| i.mask != 0)
                .map(|(b, _)| b),
        )
    }

    /// Adds `instance` (its id is the next one) and builds the top tree again over all
    /// instances, with the combined tree (`bvh`) laid out anew in the frame
    /// [`Instances::reassemble`] chooses (re-centred, or kept). Fails, naming it, on an unknown
    /// mesh or a transform that cannot place it, or when in that frame more instances are too
    /// coarse to pick than before, with nothing changed.
    pub fn add(&mut self, bvh: &mut Bvh, instance: Instance) -> Result<u32> {
        let mut instances = self.instances.clone();
        instances.push(instance);
        let mut removed = self.removed.clone();
        removed.push(false);
        let ((rebuilt, combined), after) = self.reassemble(instances, removed)?;
        // In either frame, instances may be too coarse to pick that were not (one placed far
        // from the rest): refused, nothing changed.
        if after.len() > self.unresolved().len() {
            let u = after[0];
            return Err(Error::Invalid(u.describe(&format!(
                "with it, instance {} (\"{}\")",
                u.part,
                crate::budget::quote(&rebuilt.instances[u.part as usize].name)
            ))));
        }
        *self = rebuilt;
        *bvh = combined;
        Ok(self.instances.len() as u32 - 1)
    }

    /// Adds `mesh` (a scene of one object, in its own coordinates) with its tree built by
    /// `options`, for instances to place; returns its index. The combined tree holds it once an
    /// instance places it ([`Instances::add`]). Fails on a mesh too wide for its own
    /// single-precision frame to hold (no instance of it could be hit).
    pub fn add_mesh(&mut self, mesh: Scene, options: &BuildOptions) -> Result<u32> {
        if mesh.objects().len() != 1 {
            return Err(Error::Invalid(format!(
                "a mesh of an instanced scene is one object, not {}",
                mesh.objects().len()
            )));
        }
        if !crate::bvh::frame_holds(&mesh, mesh.origin()) {
            let span = mesh
                .bounds()
                .map_or(0.0, |(lo, hi)| (hi - lo).max_element());
            return Err(Error::Invalid(format!(
                "the mesh spans {}, more than its single-precision frame holds",
                crate::frame::reach::units(span)
            )));
        }
        let bvh = Bvh::build(&mesh, options)?;
        self.meshes.push(Arc::new(MeshTree::new(mesh, bvh)));
        Ok(self.meshes.len() as u32 - 1)
    }

    /// Builds the top tree again over the instances where they are now (a refitted top tree's
    /// boxes may have grown loose after many moves), the combined tree laid out anew, in the
    /// frame [`Instances::reassemble`] chooses.
    pub fn rebuild_top(&mut self, bvh: &mut Bvh) -> Result<()> {
        let ((rebuilt, combined), _) =
            self.reassemble(self.instances.clone(), self.removed.clone())?;
        *self = rebuilt;
        *bvh = combined;
        Ok(())
    }

    /// `instances` over this scene's meshes, assembled in a frame centred on their bounds,
    /// unless that frame leaves more of them unresolved than this scene's frame would (checked
    /// only then): the frame then keeps its origin. A move places an instance where the frame it
    /// keeps resolves it (a large one can lie far out), and the centre of the bounds that now
    /// reach it may lie so far from the rest that re-centring there would round their rays too
    /// coarsely to pick them. Returns the chosen assembly with its unresolved instances.
    #[allow(clippy::type_complexity)]
    fn reassemble(
        &self,
        instances: Vec<Instance>,
        removed: Vec<bool>,
    ) -> Result<((Self, Bvh), Vec<crate::frame::reach::Unresolved>)> {
        let centred = Self::assemble_about(
            self.meshes.clone(),
            instances.clone(),
            removed.clone(),
            None,
        )?;
        let unresolved = centred.0.unresolved();
        if unresolved.is_empty() || centred.0.origin == self.origin {
            return Ok((centred, unresolved));
        }
        let kept =
            Self::assemble_about(self.meshes.clone(), instances, removed, Some(self.origin))?;
        let kept_unresolved = kept.0.unresolved();
        Ok(if kept_unresolved.len() < unresolved.len() {
            (kept, kept_unresolved)
        } else {
            (centred, unresolved)
        })
    }

    /// Moves mesh `mesh`'s vertices to `positions` (its vertex order, the same triangles) and
    /// refits its bottom tree bottom-up without building it again, then every instance of it in
    /// the top tree; the mesh's part of `bvh` is rewritten in place. Only when one of its
    /// triangles becomes degenerate or stops being so, or the mesh moves away from its frame
    /// ([`crate::frame::reach::frame_suits`]), is its tree built again with `options`
    /// (and the combined tree laid out anew). Fails on an unknown mesh, a wrong count or a
    /// non-finite coordinate, with nothing changed.
    pub fn set_mesh_positions(
        &mut self,
        bvh: &mut Bvh,
        mesh: u32,
        positions: &[DVec3],
        options: &BuildOptions,
    ) -> Result<crate::picker::Refit> {
        let m = mesh as usize;
        let Some(tree) = self.meshes.get(m) else {
            return Err(Error::Invalid(format!(
                "there is no mesh {mesh} (the scene has {})",
                self.meshes.len()
            )));
        };
        tree.scene.check_object_positions(0, positions)?;
        let mut scene = tree.scene.clone();
        let mut tree_bvh = tree.bvh.clone();
        let leaf_vertices = tree
            .leaf_vertices
            .get_or_init(|| Arc::new(tree.bvh.leaf_vertices(&tree.scene)))
            .clone();
        let mut refitted = tree_bvh.refit_with(&scene, 0, positions, &leaf_vertices);
        scene.put_object_positions(0, positions);
        // A mesh moved away from its frame's origin (10⁹ out: its triangles rounded at that
        // far frame's steps) is built again about where it now lies, as a plain scene's is.
        refitted &= crate::frame::reach::frame_suits(scene.bounds(), tree_bvh.origin);
        if !refitted {
            tree_bvh = Bvh::build(&scene, options)?;
        }
        let fresh = MeshTree::new(scene, tree_bvh);
        if refitted {
            let _ = fresh.leaf_vertices.set(leaf_vertices);
        }
        if refitted && let Some(Ok(wide)) = self.meshes[m].wide.get() {
            // The engine's wide tree refitted too, not collapsed again.
            let mut wide = wide.clone();
            wide.refit(&fresh.bvh);
            let _ = fresh.wide.set(Ok(wide));
        }
        let old = std::mem::replace(&mut self.meshes[m], Arc::new(fresh));
        // A mesh added since the combined tree was laid out is not in it (no instance placed it
        // then): nothing there to write.
        if m >= self.mesh_nodes.len() && refitted {
            return Ok(crate::picker::Refit::Refitted);
        }
        // Laid out anew too where the top tree is empty (every instance removed or with
        // nothing to hit): the combined tree then holds no mesh to write in place.
        if !refitted
            || m >= self.mesh_nodes.len()
            || self.meshes[m].bvh.nodes.is_empty()
            || bvh.nodes.is_empty()
        {
            if let Err(e) = self.rebuild_top(bvh) {
                // Nothing changed: the mesh as it was.
                self.meshes[m] = old;
                return Err(e);
            }
            return Ok(crate::picker::Refit::Rebuilt);
        }
        // The mesh's nodes and triangles where the combined tree holds them.
        let (node_base, tri_base) = (self.mesh_nodes[m], self.mesh_triangles[m]);
        let own = &self.meshes[m].bvh;
        let nodes = bvh.nodes.to_mut();
        for (j, n) in own.nodes.iter().enumerate() {
            let at = &mut nodes[node_base as usize + j];
            at.min = n.min;
            at.max = n.max;
        }
        let triangles = bvh.triangles.to_mut();
        triangles[tri_base as usize..tri_base as usize + own.triangles.len()]
            .copy_from_slice(&own.triangles);
        for i in 0..self.instances.len() {
            if self.instances[i].mesh == mesh {
                self.records[i] = self.record(i, self.records[i].prim_base);
                self.refit_leaf(bvh, i, self.world_box(i));
            }
        }
        self.refit_top_wide(bvh);
        Ok(crate::picker::Refit::Refitted)
    }

    /// The wide top tree's boxes copied from the binary top tree's in `bvh` (after
    /// [`Instances::refit_leaf`]): the top tree's nodes lead the combined ones, as when
    /// [`Instances::assemble`] collapsed it (so it has its sources).
    fn refit_top_wide(&mut self, bvh: &Bvh) {
        let copied = self
            .top_wide
            .refit_from_sources(&bvh.nodes[..self.top_nodes as usize]);
        debug_assert!(
            copied,
            "the top tree is always collapsed here, with its sources"
        );
    }

    /// Instance `k`'s index, or an error naming it.
    fn known(&self, k: u32) -> Result<usize> {
        if (k as usize) < self.instances.len() {
            Ok(k as usize)
        } else {
            Err(Error::Invalid(format!(
                "there is no instance {k} (the scene has {})",
                self.instances.len()
            )))
        }
    }

    /// Instance `k`'s index when it was not removed, else an error naming it.
    fn present(&self, k: u32) -> Result<usize> {
        let i = self.known(k)?;
        if self.removed[i] {
            return Err(Error::Invalid(format!("instance {k} was removed")));
        }
        Ok(i)
    }

    /// Whether instance `k` was removed ([`Instances::remove`]).
    pub fn is_removed(&self, k: usize) -> bool {
        self.removed[k]
    }

    /// Instance `i`'s leaf box from `world`, its world box where it is now, and every box
    /// above it, in `bvh`'s top nodes.
    fn refit_leaf(&mut self, bvh: &mut Bvh, i: usize, world: Option<(DVec3, DVec3)>) {
        let leaf = self.leaf_of[i];
        if leaf == NO_LEAF {
            return;
        }
        let Some((lo, hi)) = self.scene_boxes(&[world])[0] else {
            return;
        };
        let nodes = bvh.nodes.to_mut();
        nodes[leaf as usize].min = lo.into();
        nodes[leaf as usize].max = hi.into();
        let mut at = leaf as usize;
        while at != 0 {
            at = nodes[at].parent() as usize;
            let (l, r) = (nodes[at + 1], nodes[nodes[at].first as usize]);
            nodes[at].min = Vec3::from(l.min).min(Vec3::from(r.min)).into();
            nodes[at].max = Vec3::from(l.max).max(Vec3::from(r.max)).into();
        }
        if let Some((blo, bhi)) = world
            && self.instances[i].mask != 0
        {
            self.bounds = Some(match self.bounds {
                Some((a, b)) => (a.min(blo), b.max(bhi)),
                None => (blo, bhi),
            });
        }
    }

    /// The meshes, in order.
    pub fn meshes(&self) -> &[Arc<MeshTree>] {
        &self.meshes
    }

    /// The instances, in id order.
    pub fn instances(&self) -> &[Instance] {
        &self.instances
    }

    /// Instance `k`'s leaf in the top tree (an index into the scene's node buffer), or
    /// `u32::MAX` for an instance with nothing to hit (no ray enters it).
    pub fn leaf_of(&self, k: usize) -> u32 {
        self.leaf_of[k]
    }

    /// The kernel's record of each instance, in id order.
    pub fn records(&self) -> &[GpuInstance] {
        &self.records
    }

    /// Nodes of the top tree, at the start of the combined node buffer.
    pub fn top_nodes(&self) -> u32 {
        self.top_nodes
    }

    /// The top tree collapsed 8-wide (the CPU engine's; leaf children are instances).
    pub fn top_wide(&self) -> &WideBvh {
        &self.top_wide
    }

    /// The scene frame's origin: the centre of the instances' world boxes when they were last
    /// assembled, or the origin kept then ([`Instances::reassemble`]).
    pub fn origin(&self) -> DVec3 {
        self.origin
    }

    /// The scene frame rays are converted into: about [`Instances::origin`], reaching as far as
    /// [`Instances::bounds`] (the instances that can be hit).
    pub fn frame(&self) -> crate::frame::Frame {
        crate::frame::Frame::around(self.origin, self.bounds)
    }

    /// The world box around the instances that can be hit (mask not 0; around all of them
    /// when none can, `None` when none has a box): worked out when instances are placed, added,
    /// hidden or shown; a move grows it to the moved instance's new box (it may then hold the
    /// old place too).
    pub fn bounds(&self) -> Option<(DVec3, DVec3)> {
        self.bounds
    }

    /// Loop iterations the two-level walk may take: each top node entered at most once going
    /// down and once coming up, and each entered instance's bottom tree likewise, plus the step
    /// back to its leaf.
    pub fn iteration_cap(&self) -> u32 {
        self.iteration_cap
    }

    /// Triangles of all instances together, but those removed before the last layout (the hit
    /// ids run `0..` this).
    pub fn prim_count(&self) -> u64 {
        self.prim_total
    }

    /// Bytes the instancing adds beyond the meshes: the instances (f64, with their names' text)
    /// and kernel records, the top tree (binary, and the engine's wide collapse of it), each
    /// instance's top leaf and removal flag, the hit ids' block table, and each mesh's vertex chunks for the
    /// exact boxes ([`extent::Extent`]).
    pub fn instance_bytes(&self) -> u64 {
        let names: usize = self.instances.iter().map(|i| i.name.capacity()).sum();
        let extents: u64 = self
            .meshes
            .iter()
            .filter_map(|m| m.extent.get())
            .map(extent::Extent::bytes)
            .sum();
        (self.instances.len() * (size_of::<Instance>() + size_of::<GpuInstance>())
            + names
            + self.top_nodes as usize * size_of::<GpuNode>()
            + size_of_val(&self.leaf_of[..])
            + size_of_val(&self.removed[..])) as u64
            + self.top_wide.bytes()
            + self.hits.bytes()
            + extents
    }

    /// Where hit id `prim` lands: the instance, and the mesh's file-order triangle.
    pub fn locate(&self, prim: u32) -> (u32, u32) {
        let k = self.hits.instance(&self.records, prim);
        (k as u32, prim - self.records[k].prim_base)
    }

    /// The world corners of instance `instance`'s triangle `triangle` (file order), in the
    /// winding the world sees (swapped once more for a mirroring transform), and whether u and v
    /// come out swapped against the file's vertex order.
    #[inline(always)]
    pub fn world_triangle(&self, instance: u32, triangle: u32) -> ([DVec3; 3], bool) {
        let i = &self.instances[instance as usize];
        let mesh = &self.meshes[i.mesh as usize].scene;
        // Written out (not `array::map`, whose closure was left as a call in the refinement),
        // each corner read where it lies: the mesh's `world_triangle`, left as a call, returned
        // its corners through the stack, and reading them back across the stores stalled (half
        // of this function's samples on the field of bunnies).
        let [a, b, c] = mesh.triangle_vertices(triangle as usize);
        let corner = |v: u32| apply_transform(&i.transform, mesh.position(v as usize));
        let (a, b, c) = (corner(a), corner(b), corner(c));
        let mirrored = self.records[instance as usize].flags & INSTANCE_MIRRORED != 0;
        let swapped = mesh.objects()[0].mirrored != mirrored;
        if mirrored {
            ([a, c, b], swapped)
        } else {
            ([a, b, c], swapped)
        }
    }

    /// Checks that [`Instances::baked`]'s copies fit the memory budget, before they are made:
    /// [`BAKED_TRIANGLE_BYTES`] a world triangle; `what` names the bake in the refusal.
    pub fn check_bake(&self, what: &str) -> Result<()> {
        crate::budget::check(what, self.prim_count(), BAKED_TRIANGLE_BYTES)
    }

    /// The same scene with every instance's mesh copied and transformed into world f64
    /// positions: one object per instance, ids in order (what the brute-force oracle and a
    /// scene without instances see). Callers check its size first ([`Instances::check_bake`]).
    pub fn baked(&self) -> Result<Scene> {
        let mut scene = Scene::new();
        for (k, i) in self.instances.iter().enumerate() {
            let mesh = &self.meshes[i.mesh as usize].scene;
            let o = &mesh.objects()[0];
            // A mirrored mesh is stored swapped: copied in file order, then swapped as loaded.
            let unswap = |t: &[u32; 3]| if o.mirrored { [t[0], t[2], t[1]] } else { *t };
            let m = crate::scene::Mesh {
                positions: mesh.positions().to_vec(),
                triangles: mesh.triangles().iter().map(unswap).collect(),
            };
            let id = match o.grid {
                Some(shape) => scene.add_grid_mesh(i.name.clone(), m, shape)?,
                None => scene.add_mesh(i.name.clone(), m)?,
            };
            debug_assert_eq!(id as usize, k);
            if o.mirrored {
                scene.flip_winding(id);
            }
            scene.set_object_mask(id, i.mask)?;
            scene.transform_object(id, &i.transform)?;
        }
        Ok(scene)
    }

    /// Each instance's world box in f64 (`None` for a mesh with nothing to hit), on all cores.
    fn world_boxes(&self) -> Vec<Option<(DVec3, DVec3)>> {
        use rayon::prelude::*;
        (0..self.instances.len())
            .into_par_iter()
            .with_min_len(256)
            .map(|k| self.world_box(k))
            .collect()
    }

    /// The instances that can be hit (mask not 0) whose rays the scene frame places too
    /// coarsely to pick them ([`crate::frame::reach`]: an instance far from the others, in
    /// other coordinates say, widens the frame and leaves them far from its centre), in id
    /// order. One box per instance.
    pub fn unresolved(&self) -> Vec<crate::frame::reach::Unresolved> {
        (0..self.instances.len())
            .filter_map(|k| self.unresolved_at(k))
            .collect()
    }

    /// The instances that can be hit (mask not 0, not removed), with their world boxes, in id
    /// order: what the frame warnings measure ([`crate::frame::faults`]), as
    /// [`crate::frame::reach::object_boxes`] lists a plain scene's objects.
    pub fn hittable_boxes(&self) -> Vec<(u32, (DVec3, DVec3))> {
        self.world_boxes()
            .into_iter()
            .enumerate()
            .filter(|&(k, _)| self.instances[k].mask != 0)
            .filter_map(|(k, b)| Some((k as u32, b?)))
            .collect()
    }

    /// Instance `k`'s world box when it can be hit (placed, mask not 0), as
    /// [`Instances::hittable_boxes`] lists it; `None` for an unknown id.
    pub fn hittable_box(&self, k: u32) -> Option<(DVec3, DVec3)> {
        let k = k as usize;
        (self.instances.get(k)?.mask != 0)
            .then(|| self.world_box(k))
            .flatten()
    }

    /// Instance `k`, where it is placed now, when it can be hit and the frame does not resolve it.
    fn unresolved_at(&self, k: usize) -> Option<crate::frame::reach::Unresolved> {
        self.unresolved_in(k, self.world_box(k)?)
    }

    /// [`Instances::unresolved_at`] with instance `k`'s world box `b`.
    fn unresolved_in(
        &self,
        k: usize,
        b: (DVec3, DVec3),
    ) -> Option<crate::frame::reach::Unresolved> {
        use crate::frame::reach::{Unresolved, ray_step};
        if self.instances[k].mask == 0 {
            return None;
        }
        Unresolved::of(k as u32, b, self.origin, ray_step)
    }

    /// Instance `k`'s world box: the exact box of its mesh's vertices through its transform
    /// ([`MeshTree::world_box`]); `None` for a removed instance (nothing to hit).
    fn world_box(&self, k: usize) -> Option<(DVec3, DVec3)> {
        if self.removed[k] {
            return None;
        }
        let i = &self.instances[k];
        self.meshes[i.mesh as usize].world_box(&i.transform)
    }

    /// The boxes in the scene frame, rounded outward to f32 and widened by a few units in the
    /// last place of their largest coordinate: the top tree is tested with the ray's f32 origin
    /// alone, so a box must hold whatever the instance's frame can hit.
    fn scene_boxes(&self, boxes: &[Option<(DVec3, DVec3)>]) -> Vec<Option<(Vec3, Vec3)>> {
        boxes
            .iter()
            .map(|b| {
                let (lo, hi) = (*b)?;
                let (lo, hi) = (lo - self.origin, hi - self.origin);
                let size = lo.abs().max(hi.abs()).max_element() + (hi - lo).max_element();
                let pad = size * f64::from(f32::EPSILON) * 8.0;
                let down = |x: f64| {
                    let f = (x - pad) as f32;
                    if f64::from(f) > x - pad {
                        f.next_down()
                    } else {
                        f
                    }
                };
                let up = |x: f64| {
                    let f = (x + pad) as f32;
                    if f64::from(f) < x + pad {
                        f.next_up()
                    } else {
                        f
                    }
                };
                Some((
                    Vec3::new(down(lo.x), down(lo.y), down(lo.z)),
                    Vec3::new(up(hi.x), up(hi.y), up(hi.z)),
                ))
            })
            .collect()
    }

    /// Instance `k`'s kernel record, its hits numbered from `prim_base`: the inverse linear map
    /// and the mesh origin's place in the scene frame, worked out in f64 and rounded once.
    fn record(&self, k: usize, prim_base: u32) -> GpuInstance {
        let i = &self.instances[k];
        let m = &i.transform;
        let mesh = &self.meshes[i.mesh as usize];
        let linear = DMat3::from_cols(
            DVec3::new(m[0][0], m[1][0], m[2][0]),
            DVec3::new(m[0][1], m[1][1], m[2][1]),
            DVec3::new(m[0][2], m[1][2], m[2][2]),
        );
        let inverse = linear.inverse();
        let c = apply_transform(m, mesh.bvh.origin) - self.origin;
        let c_hi = c.as_vec3();
        let c_lo = (c - c_hi.as_dvec3()).as_vec3();
        let row = |r: usize| inverse.row(r).as_vec3().to_array();
        GpuInstance {
            l0: row(0),
            cx: c_hi.x,
            l1: row(1),
            cy: c_hi.y,
            l2: row(2),
            cz: c_hi.z,
            c_lo: c_lo.to_array(),
            root: if mesh.bvh.nodes.is_empty() {
                u32::MAX
            } else {
                self.mesh_nodes[i.mesh as usize]
            },
            prim_base,
            mask: i.mask,
            flags: if linear.determinant() < 0.0 {
                INSTANCE_MIRRORED
            } else {
                0
            },
            mesh: i.mesh,
        }
    }

    /// The combined tree: `top` (parents linked), then each mesh's nodes with their links and
    /// triangle ranges moved to where the mesh sits in the shared buffers.
    fn combined(&self, mut top: Vec<GpuNode>) -> Bvh {
        if top.is_empty() {
            // Nothing to hit: no tree at all, so no walk starts in a bottom tree.
            return Bvh {
                origin: self.origin,
                ..Bvh::default()
            };
        }
        crate::bvh::link_parents(&mut top);
        let mut nodes = top;
        let mut triangles = Vec::new();
        let mut triangle_ids = Vec::new();
        for (k, m) in self.meshes.iter().enumerate() {
            let (node_base, tri_base) = (self.mesh_nodes[k], self.mesh_triangles[k]);
            nodes.extend(m.bvh.nodes.iter().map(|n| {
                let mut n = *n;
                let parent = n.parent() + node_base;
                n.parent_kind = parent << KIND_BITS | n.kind();
                n.first += if n.is_leaf() { tri_base } else { node_base };
                n
            }));
            triangles.extend_from_slice(&m.bvh.triangles);
            triangle_ids.extend_from_slice(&m.bvh.triangle_ids);
        }
        Bvh {
            origin: self.origin,
            nodes: nodes.into(),
            triangles: triangles.into(),
            triangle_ids: triangle_ids.into(),
            blocks: Vec::new(),
        }
    }

    /// [`Instances::iteration_cap`] for the top tree `top`.
    fn cap(&self, top: &[GpuNode]) -> u32 {
        let mut cap = 2 * top.len() as u64 + 2;
        for n in top.iter().filter(|n| n.is_leaf()) {
            let mesh = self.instances[n.first as usize].mesh as usize;
            cap += 2 * self.meshes[mesh].bvh.nodes.len() as u64 + 2;
        }
        cap.min(u64::from(u32::MAX)) as u32
    }
}

/// Refuses an instance with an unknown mesh or a transform that cannot place it.
fn check_instance(meshes: &[Arc<MeshTree>], k: usize, i: &Instance) -> Result<()> {
    if i.mesh as usize >= meshes.len() {
        return Err(Error::Invalid(format!(
            "instance {k} (\"{}\") places mesh {}, but there are {} meshes",
            crate::budget::quote(&i.name),
            i.mesh,
            meshes.len()
        )));
    }
    check_transform(&i.transform).map_err(|why| {
        Error::Invalid(format!(
            "instance {k} (\"{}\"): the transform {why}",
            crate::budget::quote(&i.name)
        ))
    })?;
    Ok(())
}
