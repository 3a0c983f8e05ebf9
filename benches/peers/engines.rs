//! The engines the bench compares, behind one trait. raypick builds from the f64 scene; every
//! peer builds from the scene's triangles in raypick's scene-local f32 frame. All of them
//! answer the same scene-local rays with the closest hit's t, every CPU engine in parallel over
//! rays with rayon in runs of 256 rays, each its own stealable job (`with_min_len(256)
//! .with_max_len(256)`, as `cpu::trace_batch` does; left to rayon's adaptive splitting, the
//! soup's camera rays kept one of two threads idle 13% of the time) on the pool it is run in.

use crate::bvh_peer::BvhPeer;
#[cfg(feature = "embree")]
use crate::embree_peer::{EmbreeDevice, EmbreeScene};
use crate::obvhs_peer::{obvhs_build, obvhs_intersect};
use crate::parry_peer::{parry_build, parry_intersect};
use glam::Vec3A;
use obvhs::cwbvh::CwBvh;
use obvhs::triangle::Triangle;
use rayon::prelude::*;
use raypick::cpu::traverse::{self, Buffers};
use raypick::layout::{GpuRay, NO_HIT};
use raypick::{
    BuildOptions, BuiltScene, CpuPicker, GpuContext, GpuPicker, Picker, Ray, ReferencePicker,
    Scene, cpu,
};
use std::sync::{Arc, Mutex};

/// Rays per rayon task, for every CPU engine.
const MIN_LEN: usize = 256;

/// A built engine, ready to answer scene-local rays.
pub trait Engine: Sync {
    /// The closest hit's t for one ray, on the calling thread.
    fn intersect(&self, ray: &GpuRay) -> Option<f32>;

    /// The closest hit's t for every ray, in parallel over rays on the current rayon pool.
    fn trace(&self, rays: &[GpuRay]) -> Vec<Option<f32>> {
        rays.par_iter()
            .with_min_len(MIN_LEN)
            .with_max_len(MIN_LEN)
            .map(|ray| self.intersect(ray))
            .collect()
    }

    /// raypick's whole `Picker::pick` of the world rays (frame conversion, watertight test,
    /// f64 refinement), for the second end-to-end figure; `false` for the peers, which have no
    /// such path.
    fn api_pick(&self, _world: &[Ray]) -> bool {
        false
    }

    /// raypick's whole `Picker::pick` of `world`, the world rays of a scene-local set (frame
    /// conversion, watertight test, f64 refinement: what issue 13's targets time), each hit's t
    /// in the scene-local ray's units (the world t times the direction's length); `None` for
    /// the engines without such a path.
    fn pick_answers(&self, _world: &[Ray]) -> Option<Vec<Option<f32>>> {
        None
    }
}

/// Which engine: the name is the summary's `engine` column.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Kind {
    RaypickReference,
    RaypickCpu,
    RaypickGpu,
    Obvhs,
    Bvh,
    Parry3d,
    #[cfg(feature = "embree")]
    Embree,
    /// Embree's `rtcIntersect16` packets over consecutive rays.
    #[cfg(feature = "embree")]
    Embree16,
}

impl Kind {
    /// Every engine this build of the bench has, in the order they run; raypick's CPU path
    /// first, since its answers are the reference the others are checked against.
    pub const ALL: &[Kind] = &[
        Kind::RaypickReference,
        Kind::RaypickCpu,
        Kind::RaypickGpu,
        Kind::Obvhs,
        Kind::Bvh,
        Kind::Parry3d,
        #[cfg(feature = "embree")]
        Kind::Embree,
        #[cfg(feature = "embree")]
        Kind::Embree16,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Kind::RaypickReference => "raypick-reference",
            Kind::RaypickCpu => "raypick-cpu",
            Kind::RaypickGpu => "raypick-gpu",
            Kind::Obvhs => "obvhs",
            Kind::Bvh => "bvh",
            Kind::Parry3d => "parry3d",
            #[cfg(feature = "embree")]
            Kind::Embree => "embree",
            #[cfg(feature = "embree")]
            Kind::Embree16 => "embree-packet16",
        }
    }

    /// Whether `build` needs its own copy of the f64 scene.
    pub fn needs_scene(self) -> bool {
        matches!(
            self,
            Kind::RaypickReference | Kind::RaypickCpu | Kind::RaypickGpu
        )
    }

    /// Builds the engine over `inputs` (`scene` is a copy of the scene for raypick, made before
    /// the clock starts). Fails, saying why, when the engine cannot take this scene.
    pub fn build(
        self,
        inputs: &Inputs<'_>,
        scene: Option<Scene>,
    ) -> Result<Box<dyn Engine>, String> {
        let built = || {
            let scene = scene.expect("raypick builds from its own copy of the scene");
            BuiltScene::new(scene, &BuildOptions::default()).map_err(|e| e.to_string())
        };
        Ok(match self {
            Kind::RaypickReference => Box::new(RaypickReference {
                built: Arc::new(built()?),
            }),
            Kind::RaypickCpu => {
                let built = Arc::new(built()?);
                built.wide().map_err(|e| e.to_string())?;
                Box::new(RaypickCpu { built })
            }
            Kind::RaypickGpu => {
                let context = inputs.gpu.ok_or("no GPU adapter")?;
                let picker =
                    GpuPicker::new(context, Arc::new(built()?)).map_err(|e| e.to_string())?;
                Box::new(RaypickGpu {
                    picker: Mutex::new(picker),
                })
            }
            Kind::Obvhs => {
                let (bvh, ordered) = obvhs_build(inputs.obvhs_triangles);
                Box::new(Obvhs { bvh, ordered })
            }
            Kind::Bvh => Box::new(BvhPeer::build(inputs.triangles)),
            Kind::Parry3d => Box::new(Parry3d {
                mesh: parry_build(inputs.triangles),
            }),
            #[cfg(feature = "embree")]
            Kind::Embree => Box::new(EmbreeScene::new(inputs.embree, inputs.triangles)),
            #[cfg(feature = "embree")]
            Kind::Embree16 => Box::new(EmbreePackets(EmbreeScene::new(
                inputs.embree,
                inputs.triangles,
            ))),
        })
    }
}

/// What the engines build from, made once per scene.
pub struct Inputs<'a> {
    /// The scene's triangles in raypick's scene-local f32 frame, in scene order.
    pub triangles: &'a [[Vec3A; 3]],
    /// The same triangles as obvhs triangles.
    pub obvhs_triangles: &'a [Triangle],
    /// The GPU, when there is one.
    pub gpu: Option<&'a GpuContext>,
    #[cfg(feature = "embree")]
    pub embree: &'a EmbreeDevice,
}

/// raypick's reference path (`--backend reference`): `cpu::trace_all`, the kernel's twin
/// (median-cut binary BVH, ordered stackless walk, Möller–Trumbore) over the flattened buffers
/// the GPU kernel reads.
struct RaypickReference {
    built: Arc<BuiltScene>,
}

/// raypick's CPU engine (`--backend cpu`): the 8-wide SIMD walk of `raypick::engine` over the
/// same tree collapsed (built with the tree, so its collapse is in the build figure),
/// Möller–Trumbore, packets for coherent groups.
struct RaypickCpu {
    built: Arc<BuiltScene>,
}

impl RaypickCpu {
    fn trace_hits(&self, rays: &[GpuRay]) -> Vec<raypick::layout::GpuHit> {
        let built = &self.built;
        let settings = raypick::cpu::TraceSettings::default();
        let wide = built.wide().expect("collapsed at build");
        raypick::engine::trace_batch(
            wide,
            &built.bvh,
            rays,
            &settings,
            raypick::engine::Simd::detect(),
            true,
        )
        .0
    }
}

impl Engine for RaypickCpu {
    fn intersect(&self, ray: &GpuRay) -> Option<f32> {
        closest(self.trace_hits(std::slice::from_ref(ray))[0])
    }

    fn trace(&self, rays: &[GpuRay]) -> Vec<Option<f32>> {
        // In parallel, as the peers' adapters collect theirs.
        self.trace_hits(rays).into_par_iter().map(closest).collect()
    }

    fn api_pick(&self, world: &[Ray]) -> bool {
        CpuPicker::new(self.built.clone())
            .pick(world)
            .expect("raypick's CPU pick");
        true
    }

    fn pick_answers(&self, world: &[Ray]) -> Option<Vec<Option<f32>>> {
        let hits = CpuPicker::new(self.built.clone())
            .pick(world)
            .expect("raypick's CPU pick");
        // In parallel, as `trace` collects its answers.
        Some(
            hits.par_iter()
                .zip(world.par_iter())
                .map(|(hit, ray)| hit.hit.then(|| (hit.t * ray.dir.length()) as f32))
                .collect(),
        )
    }
}

fn closest(hit: raypick::layout::GpuHit) -> Option<f32> {
    (hit.prim != NO_HIT).then_some(hit.t)
}

impl Engine for RaypickReference {
    fn intersect(&self, ray: &GpuRay) -> Option<f32> {
        let bvh = &self.built.bvh;
        let buffers = Buffers {
            nodes: bvh.nodes.as_slice(),
            triangles: bvh.triangles.as_slice(),
            triangle_ids: bvh.triangle_ids.as_slice(),
            triangle_masks: &[],
            instances: &[],
            top_nodes: 0,
            iteration_cap: bvh.iteration_cap(),
            max_hits: 0,
            watertight: false,
        };
        closest(traverse::trace(buffers, ray, &mut []))
    }

    fn trace(&self, rays: &[GpuRay]) -> Vec<Option<f32>> {
        cpu::trace_all(&self.built.bvh, rays)
            .into_par_iter()
            .map(closest)
            .collect()
    }

    fn api_pick(&self, world: &[Ray]) -> bool {
        ReferencePicker::new(self.built.clone())
            .pick(world)
            .expect("raypick's reference pick");
        true
    }
}

/// raypick's GPU path: the WGSL kernel (Möller–Trumbore) through `GpuPicker::trace`, the scene
/// resident.
struct RaypickGpu {
    picker: Mutex<GpuPicker>,
}

impl RaypickGpu {
    fn picker(&self) -> std::sync::MutexGuard<'_, GpuPicker> {
        self.picker.lock().expect("no GPU call panicked")
    }
}

impl Engine for RaypickGpu {
    fn intersect(&self, ray: &GpuRay) -> Option<f32> {
        closest(self.trace_hits(std::slice::from_ref(ray))[0])
    }

    fn trace(&self, rays: &[GpuRay]) -> Vec<Option<f32>> {
        self.trace_hits(rays).into_par_iter().map(closest).collect()
    }

    fn api_pick(&self, world: &[Ray]) -> bool {
        self.picker().pick(world).expect("raypick's GPU pick");
        true
    }
}

impl RaypickGpu {
    fn trace_hits(&self, rays: &[GpuRay]) -> Vec<raypick::layout::GpuHit> {
        self.picker().trace(rays).expect("raypick's GPU trace")
    }
}

/// obvhs 0.4: its recommended CWBVH set-up (`benches/common/obvhs_peer.rs`).
struct Obvhs {
    bvh: CwBvh,
    ordered: Vec<Triangle>,
}

impl Engine for Obvhs {
    fn intersect(&self, r: &GpuRay) -> Option<f32> {
        let ray = obvhs::ray::Ray::new(r.origin.into(), r.dir.into(), r.tmin, r.tmax.min(f32::MAX));
        let hit = obvhs_intersect(&self.bvh, &self.ordered, ray);
        hit.t.is_finite().then_some(hit.t)
    }
}

impl Engine for BvhPeer {
    fn intersect(&self, ray: &GpuRay) -> Option<f32> {
        BvhPeer::intersect(self, ray)
    }
}

/// parry3d 0.31's `TriMesh`.
struct Parry3d {
    mesh: parry3d::shape::TriMesh,
}

impl Engine for Parry3d {
    fn intersect(&self, ray: &GpuRay) -> Option<f32> {
        parry_intersect(&self.mesh, ray)
    }
}

#[cfg(feature = "embree")]
impl Engine for EmbreeScene {
    fn intersect(&self, ray: &GpuRay) -> Option<f32> {
        EmbreeScene::intersect(self, ray)
    }
}

/// Embree 3's `rtcIntersect16`: consecutive rays (pixel order for camera rays) in packets of 16,
/// the packets in parallel.
#[cfg(feature = "embree")]
struct EmbreePackets(EmbreeScene);

#[cfg(feature = "embree")]
impl Engine for EmbreePackets {
    fn intersect(&self, ray: &GpuRay) -> Option<f32> {
        self.0.intersect_packet::<16>(std::slice::from_ref(ray))[0]
    }

    fn trace(&self, rays: &[GpuRay]) -> Vec<Option<f32>> {
        rays.par_chunks(16)
            .with_min_len(MIN_LEN / 16)
            .with_max_len(MIN_LEN / 16)
            .flat_map_iter(|packet| self.0.intersect_packet::<16>(packet))
            .collect()
    }
}
