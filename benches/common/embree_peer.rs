//! The Embree 3 peer: a thin FFI of our own against the system's `libembree3` (Debian:
//! `libembree-dev`, Embree 3.13.5), with only what a closest-hit pick over one triangle mesh
//! needs. One device per bench run; per scene, one triangle geometry (float3 vertices, uint3
//! indices) in a scene with Embree's default build settings; closest hit per ray with
//! `rtcIntersect1` (single-ray traversal, no packets or streams). Compiled only with the
//! off-by-default `embree` cargo feature.
//!
//! The struct layouts are those of `embree3/rtcore_ray.h` and `rtcore_common.h` for
//! `RTC_MAX_INSTANCE_LEVEL_COUNT == 1` and `RTC_MIN_WIDTH == 0` (Debian's `rtcore_config.h`),
//! pinned below by size, alignment and offset asserts. Any error Embree reports while a device
//! or scene is set up becomes a panic with Embree's error name.

use glam::Vec3A;
use raypick::layout::GpuRay;
use std::ffi::{c_uint, c_void};
use std::mem::{align_of, offset_of, size_of};
use std::ptr;

type RTCDevice = *mut c_void;
type RTCScene = *mut c_void;
type RTCGeometry = *mut c_void;

/// `RTC_INVALID_GEOMETRY_ID`: `geomID` of a ray that hit nothing.
const RTC_INVALID_GEOMETRY_ID: c_uint = c_uint::MAX;
/// `RTC_GEOMETRY_TYPE_TRIANGLE`.
const RTC_GEOMETRY_TYPE_TRIANGLE: u32 = 0;
/// `RTC_BUFFER_TYPE_INDEX`.
const RTC_BUFFER_TYPE_INDEX: u32 = 0;
/// `RTC_BUFFER_TYPE_VERTEX`.
const RTC_BUFFER_TYPE_VERTEX: u32 = 1;
/// `RTC_FORMAT_UINT3`.
const RTC_FORMAT_UINT3: u32 = 0x5003;
/// `RTC_FORMAT_FLOAT3`.
const RTC_FORMAT_FLOAT3: u32 = 0x9003;
/// `RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT`.
const RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT: u32 = 0;
/// `RTC_INTERSECT_CONTEXT_FLAG_COHERENT`: what a packet of camera rays is.
const RTC_INTERSECT_CONTEXT_FLAG_COHERENT: u32 = 1;

/// `struct RTCRay` (`RTC_ALIGN(16)`).
#[repr(C, align(16))]
struct RTCRay {
    org: [f32; 3],
    tnear: f32,
    dir: [f32; 3],
    time: f32,
    tfar: f32,
    mask: c_uint,
    id: c_uint,
    flags: c_uint,
}

/// `struct RTCHit` (`RTC_ALIGN(16)`), with one instance level.
#[repr(C, align(16))]
struct RTCHit {
    ng: [f32; 3],
    u: f32,
    v: f32,
    prim_id: c_uint,
    geom_id: c_uint,
    inst_id: [c_uint; 1],
}

/// `struct RTCRayHit`: the ray, then the hit record `rtcIntersect1` fills in.
#[repr(C)]
struct RTCRayHit {
    ray: RTCRay,
    hit: RTCHit,
}

/// `struct RTCRay8` / `RTCRay16`: a packet of N rays, structure of arrays.
#[repr(C, align(64))]
struct RTCRayN<const N: usize> {
    org_x: [f32; N],
    org_y: [f32; N],
    org_z: [f32; N],
    tnear: [f32; N],
    dir_x: [f32; N],
    dir_y: [f32; N],
    dir_z: [f32; N],
    time: [f32; N],
    tfar: [f32; N],
    mask: [c_uint; N],
    id: [c_uint; N],
    flags: [c_uint; N],
}

/// `struct RTCHit8` / `RTCHit16`, with one instance level.
#[repr(C, align(64))]
struct RTCHitN<const N: usize> {
    ng_x: [f32; N],
    ng_y: [f32; N],
    ng_z: [f32; N],
    u: [f32; N],
    v: [f32; N],
    prim_id: [c_uint; N],
    geom_id: [c_uint; N],
    inst_id: [[c_uint; N]; 1],
}

/// `struct RTCRayHit8` / `RTCRayHit16`.
#[repr(C)]
struct RTCRayHitN<const N: usize> {
    ray: RTCRayN<N>,
    hit: RTCHitN<N>,
}

/// `struct RTCIntersectContext` with one instance level and no `minWidthDistanceFactor`.
#[repr(C)]
struct RTCIntersectContext {
    flags: u32,
    filter: Option<unsafe extern "C" fn(args: *const c_void)>,
    inst_id: [c_uint; 1],
}

const _: () = {
    assert!(size_of::<RTCRayHitN<8>>() == 640 && offset_of!(RTCRayHitN<8>, hit) == 384);
    assert!(size_of::<RTCRayHitN<16>>() == 1280 && offset_of!(RTCRayHitN<16>, hit) == 768);
    assert!(size_of::<RTCRay>() == 48 && align_of::<RTCRay>() == 16);
    assert!(size_of::<RTCHit>() == 32 && align_of::<RTCHit>() == 16);
    assert!(offset_of!(RTCHit, prim_id) == 20);
    assert!(offset_of!(RTCHit, geom_id) == 24);
    assert!(offset_of!(RTCHit, inst_id) == 28);
    assert!(size_of::<RTCRayHit>() == 80 && align_of::<RTCRayHit>() == 16);
    assert!(offset_of!(RTCRayHit, hit) == 48);
    assert!(offset_of!(RTCRay, tfar) == 32);
    assert!(size_of::<RTCIntersectContext>() == 24);
    assert!(offset_of!(RTCIntersectContext, filter) == 8);
    assert!(offset_of!(RTCIntersectContext, inst_id) == 16);
};

impl RTCIntersectContext {
    /// What the header's inline `rtcInitIntersectContext` does.
    fn new() -> Self {
        Self {
            flags: RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT,
            filter: None,
            inst_id: [RTC_INVALID_GEOMETRY_ID],
        }
    }
}

#[link(name = "embree3")]
unsafe extern "C" {
    fn rtcNewDevice(config: *const std::ffi::c_char) -> RTCDevice;
    fn rtcRetainDevice(device: RTCDevice);
    fn rtcReleaseDevice(device: RTCDevice);
    fn rtcGetDeviceError(device: RTCDevice) -> u32;
    fn rtcNewScene(device: RTCDevice) -> RTCScene;
    fn rtcReleaseScene(scene: RTCScene);
    fn rtcNewGeometry(device: RTCDevice, kind: u32) -> RTCGeometry;
    fn rtcSetNewGeometryBuffer(
        geometry: RTCGeometry,
        kind: u32,
        slot: c_uint,
        format: u32,
        byte_stride: usize,
        item_count: usize,
    ) -> *mut c_void;
    fn rtcCommitGeometry(geometry: RTCGeometry);
    fn rtcAttachGeometry(scene: RTCScene, geometry: RTCGeometry) -> c_uint;
    fn rtcReleaseGeometry(geometry: RTCGeometry);
    fn rtcCommitScene(scene: RTCScene);
    fn rtcIntersect1(scene: RTCScene, context: *mut RTCIntersectContext, rayhit: *mut RTCRayHit);
    fn rtcIntersect8(
        valid: *const i32,
        scene: RTCScene,
        context: *mut RTCIntersectContext,
        rayhit: *mut RTCRayHitN<8>,
    );
    fn rtcIntersect16(
        valid: *const i32,
        scene: RTCScene,
        context: *mut RTCIntersectContext,
        rayhit: *mut RTCRayHitN<16>,
    );
}

/// Panics with Embree's error name if `device` (or, for a null device, the calling thread)
/// has an error pending after `what`.
fn check(device: RTCDevice, what: &str) {
    // SAFETY: rtcGetDeviceError accepts any device handle Embree returned, and null.
    let code = unsafe { rtcGetDeviceError(device) };
    let name = match code {
        0 => return,
        1 => "RTC_ERROR_UNKNOWN",
        2 => "RTC_ERROR_INVALID_ARGUMENT",
        3 => "RTC_ERROR_INVALID_OPERATION",
        4 => "RTC_ERROR_OUT_OF_MEMORY",
        5 => "RTC_ERROR_UNSUPPORTED_CPU",
        6 => "RTC_ERROR_CANCELLED",
        _ => "an unknown RTCError",
    };
    panic!("Embree: {what} failed with {name} ({code})");
}

/// An Embree device, with its default configuration (all hardware threads for builds).
pub struct EmbreeDevice {
    raw: RTCDevice,
}

impl EmbreeDevice {
    /// Opens a device with the default configuration.
    pub fn open() -> Self {
        // SAFETY: a null config string asks for the defaults.
        let raw = unsafe { rtcNewDevice(ptr::null()) };
        check(raw, "rtcNewDevice");
        assert!(!raw.is_null(), "Embree: rtcNewDevice returned no device");
        Self { raw }
    }
}

impl Drop for EmbreeDevice {
    fn drop(&mut self) {
        // SAFETY: `raw` came from rtcNewDevice and is released once.
        unsafe { rtcReleaseDevice(self.raw) };
    }
}

/// A committed Embree scene holding one triangle geometry.
pub struct EmbreeScene {
    device: RTCDevice,
    scene: RTCScene,
}

// SAFETY: a committed Embree scene may be traced from any number of threads at once
// (rtcIntersect1 only reads it); the handles are released once, in Drop.
unsafe impl Send for EmbreeScene {}
// SAFETY: as above.
unsafe impl Sync for EmbreeScene {}

impl EmbreeScene {
    /// Builds the scene: the triangles' corners become the vertex buffer (three per
    /// triangle, as the other peers get them) and `[3i, 3i + 1, 3i + 2]` the index buffer.
    pub fn new(device: &EmbreeDevice, triangles: &[[Vec3A; 3]]) -> Self {
        let device = device.raw;
        // SAFETY: every handle passed below was returned by Embree for this device, and each
        // buffer is written within the item count and stride it was allocated with.
        unsafe {
            rtcRetainDevice(device);
            let scene = rtcNewScene(device);
            check(device, "rtcNewScene");
            let geometry = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
            check(device, "rtcNewGeometry");
            let vertices = rtcSetNewGeometryBuffer(
                geometry,
                RTC_BUFFER_TYPE_VERTEX,
                0,
                RTC_FORMAT_FLOAT3,
                3 * size_of::<f32>(),
                3 * triangles.len(),
            ) as *mut [f32; 3];
            check(device, "rtcSetNewGeometryBuffer (vertices)");
            let indices = rtcSetNewGeometryBuffer(
                geometry,
                RTC_BUFFER_TYPE_INDEX,
                0,
                RTC_FORMAT_UINT3,
                3 * size_of::<u32>(),
                triangles.len(),
            ) as *mut [u32; 3];
            check(device, "rtcSetNewGeometryBuffer (indices)");
            for (i, corners) in triangles.iter().enumerate() {
                for (k, corner) in corners.iter().enumerate() {
                    vertices.add(3 * i + k).write(corner.to_array());
                }
                let first = 3 * i as u32;
                indices.add(i).write([first, first + 1, first + 2]);
            }
            rtcCommitGeometry(geometry);
            check(device, "rtcCommitGeometry");
            rtcAttachGeometry(scene, geometry);
            check(device, "rtcAttachGeometry");
            rtcReleaseGeometry(geometry);
            rtcCommitScene(scene);
            check(device, "rtcCommitScene");
            Self { device, scene }
        }
    }

    /// Closest hit of one ray with `rtcIntersect1`: t in [tmin, tmax], both faces.
    pub fn intersect(&self, ray: &GpuRay) -> Option<f32> {
        let mut context = RTCIntersectContext::new();
        let mut rayhit = RTCRayHit {
            ray: RTCRay {
                org: ray.origin,
                tnear: ray.tmin,
                dir: ray.dir,
                time: 0.0,
                tfar: ray.tmax,
                mask: c_uint::MAX,
                id: 0,
                flags: 0,
            },
            hit: RTCHit {
                ng: [0.0; 3],
                u: 0.0,
                v: 0.0,
                prim_id: RTC_INVALID_GEOMETRY_ID,
                geom_id: RTC_INVALID_GEOMETRY_ID,
                inst_id: [RTC_INVALID_GEOMETRY_ID],
            },
        };
        // SAFETY: the scene is committed; context and rayhit are valid, aligned and initialised.
        unsafe { rtcIntersect1(self.scene, &mut context, &mut rayhit) };
        (rayhit.hit.geom_id != RTC_INVALID_GEOMETRY_ID).then_some(rayhit.ray.tfar)
    }
}

impl EmbreeScene {
    /// Closest hits of up to `N` rays (N = 8 or 16) with one `rtcIntersect8` / `rtcIntersect16`
    /// packet call, as a coherent packet.
    pub fn intersect_packet<const N: usize>(&self, rays: &[GpuRay]) -> Vec<Option<f32>> {
        assert!(rays.len() <= N && (N == 8 || N == 16));
        let mut valid = [0i32; N];
        let mut packet = RTCRayHitN::<N> {
            ray: RTCRayN {
                org_x: [0.0; N],
                org_y: [0.0; N],
                org_z: [0.0; N],
                tnear: [0.0; N],
                dir_x: [0.0; N],
                dir_y: [0.0; N],
                dir_z: [1.0; N],
                time: [0.0; N],
                tfar: [0.0; N],
                mask: [c_uint::MAX; N],
                id: [0; N],
                flags: [0; N],
            },
            hit: RTCHitN {
                ng_x: [0.0; N],
                ng_y: [0.0; N],
                ng_z: [0.0; N],
                u: [0.0; N],
                v: [0.0; N],
                prim_id: [RTC_INVALID_GEOMETRY_ID; N],
                geom_id: [RTC_INVALID_GEOMETRY_ID; N],
                inst_id: [[RTC_INVALID_GEOMETRY_ID; N]],
            },
        };
        for (i, r) in rays.iter().enumerate() {
            valid[i] = -1;
            let p = &mut packet.ray;
            [p.org_x[i], p.org_y[i], p.org_z[i]] = r.origin;
            [p.dir_x[i], p.dir_y[i], p.dir_z[i]] = r.dir;
            p.tnear[i] = r.tmin;
            p.tfar[i] = r.tmax;
            p.id[i] = i as c_uint;
        }
        let mut context = RTCIntersectContext {
            flags: RTC_INTERSECT_CONTEXT_FLAG_COHERENT,
            ..RTCIntersectContext::new()
        };
        // SAFETY: the scene is committed; valid, context and the packet are valid, initialised
        // and aligned (64 bytes, at least the header's 32 or 64).
        unsafe {
            if N == 16 {
                rtcIntersect16(
                    valid.as_ptr(),
                    self.scene,
                    &mut context,
                    (&mut packet as *mut RTCRayHitN<N>).cast(),
                );
            } else {
                rtcIntersect8(
                    valid.as_ptr(),
                    self.scene,
                    &mut context,
                    (&mut packet as *mut RTCRayHitN<N>).cast(),
                );
            }
        }
        (0..rays.len())
            .map(|i| {
                (packet.hit.geom_id[i] != RTC_INVALID_GEOMETRY_ID).then_some(packet.ray.tfar[i])
            })
            .collect()
    }
}

impl Drop for EmbreeScene {
    fn drop(&mut self) {
        // SAFETY: both handles are held once by this value (the device was retained in `new`).
        unsafe {
            rtcReleaseScene(self.scene);
            rtcReleaseDevice(self.device);
        }
    }
}
