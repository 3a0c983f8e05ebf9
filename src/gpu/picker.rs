//! The GPU picker: owns the compute pipeline and the resident scene buffers, and runs batches of
//! any size in chunks that respect the adapter's limits, with the kernel's workgroup size set
//! through a pipeline-overridable constant.

use super::bindings::{Binding, bindings, group_entries, layout_entries};
use super::context::GpuContext;
use crate::cpu::TraceSettings;
use crate::error::{Error, Result};
use crate::layout::{
    GpuHit, GpuHitEntry, GpuInstance, GpuNode, GpuParams, GpuRay, GpuTriangle, UNFINISHED,
};
use crate::picker::{BuiltScene, Picker, Refit, Tracer};
use crate::ray_order::DEFAULT_REORDER_FROM;
use rayon::prelude::*;
use std::mem::size_of;
use std::sync::Arc;
use wgpu::util::DeviceExt;

/// The kernel source, compiled into the binary.
pub const PICK_WGSL: &str = include_str!("../../wgsl/pick.wgsl");
/// Default invocations per workgroup (the default of `override WORKGROUP_SIZE` in
/// `wgsl/pick.wgsl`). Chosen by the sweep in BENCHMARKS.md ("Kernel workgroup size").
pub const WORKGROUP_SIZE: u32 = 64;
/// The workgroup sizes measured in BENCHMARKS.md and checked against the CPU path by the tests.
/// Any other size within the adapter's limits works too.
pub const SWEPT_WORKGROUP_SIZES: [u32; 4] = [32, 64, 128, 256];
/// Name of the kernel's pipeline-overridable workgroup size constant.
const WORKGROUP_SIZE_CONSTANT: &str = "WORKGROUP_SIZE";
/// The kernel's override constant that turns its exact division and unfused products on.
const EXACT_ARITHMETIC_CONSTANT: &str = "EXACT_ARITHMETIC";

/// Whether the kernel must round division and products itself on `context`'s adapter: on every
/// adapter but Mesa's llvmpipe (lavapipe), whose division is IEEE and which fuses no product the
/// kernel leaves to it (Möller–Trumbore's `u + v` it did fuse: the kernel keeps those two
/// products apart on every adapter, `mul_unfused`).
pub fn needs_exact_arithmetic(context: &GpuContext) -> bool {
    !(context.is_software() && context.adapter_info.name.starts_with("llvmpipe"))
}

/// The batch size from which this adapter's picks trace rays in
/// [`crate::ray_order::RayOrder`]: [`DEFAULT_REORDER_FROM`] on a software adapter, where the sort
/// won; never on a hardware GPU, where it did not (an NVIDIA H200 traced the dragon's sorted
/// incoherent rays no faster, and the sort cost more than the trace: BENCHMARKS.md, "A real
/// GPU").
pub fn reorder_from_for(context: &GpuContext) -> usize {
    if context.is_software() {
        DEFAULT_REORDER_FROM
    } else {
        usize::MAX
    }
}

/// Bytes from which a dispatch's rays are copied into the GPU's staging memory, and its
/// results out of the mapped readback, on all cores: on an NVIDIA H200's 16-core host the two
/// copies of a 262,144-ray dispatch took 1.1–1.3 and 0.8–1.0 ms on one thread, longer than the
/// GPU's own upload, trace and readback (1.5–1.7 ms). On the rayon pool, though a wait there may
/// run the overlapped pick's host task (`picker::pick_overlapped`) first: four threads of their
/// own measured slower (BENCHMARKS.md, "A real GPU").
const PARALLEL_COPY_BYTES: usize = 1 << 20;

/// Bytes per task of the parallel copies.
const COPY_PIECE_BYTES: usize = 256 << 10;

/// Queues `rays` to be written at the start of `buffer` (which holds at least as many).
fn write_rays(queue: &wgpu::Queue, buffer: &wgpu::Buffer, rays: &[GpuRay]) -> Result<()> {
    let bytes: &[u8] = bytemuck::cast_slice(rays);
    let Some(size) = wgpu::BufferSize::new(bytes.len() as u64) else {
        return Ok(());
    };
    if bytes.len() < PARALLEL_COPY_BYTES {
        queue.write_buffer(buffer, 0, bytes);
        return Ok(());
    }
    let mut view = queue
        .write_buffer_with(buffer, 0, size)
        .ok_or_else(|| Error::Gpu("the rays could not be staged for the GPU".into()))?;
    // Whole pieces (a write-only view of an array may go to another thread; of a slice not).
    let (pieces, mut tail) = view.slice(..).into_chunks::<COPY_PIECE_BYTES>();
    let pieces: Vec<wgpu::WriteOnly<'_, [u8; COPY_PIECE_BYTES]>> = pieces.into_iter().collect();
    let whole = pieces.len() * COPY_PIECE_BYTES;
    pieces
        .into_par_iter()
        .zip(bytes[..whole].par_chunks_exact(COPY_PIECE_BYTES))
        .for_each(|(piece, source)| wgpu::WriteOnly::<[u8]>::from(piece).copy_from_slice(source));
    tail.copy_from_slice(&bytes[whole..]);
    // Dropping the view queues the write.
    Ok(())
}

/// Appends `source` (mapped GPU results) to `out`, on all cores when it is large.
fn copy_out<T: Copy + Send + Sync>(out: &mut Vec<T>, source: &[T]) {
    if size_of_val(source) < PARALLEL_COPY_BYTES {
        out.extend_from_slice(source);
        return;
    }
    let per_task = (COPY_PIECE_BYTES / size_of::<T>().max(1)).max(1);
    out.par_extend(source.par_iter().copied().with_min_len(per_task));
}

/// Default most rays per dispatch, so that no single dispatch runs long.
pub const DEFAULT_CHUNK_RAYS: u32 = 1 << 18;

/// Picks on a GPU. Scene buffers stay resident; ray, hit and readback buffers are reused across
/// calls and grow only when a larger chunk arrives.
pub struct GpuPicker {
    context: GpuContext,
    built: Arc<BuiltScene>,
    kernel: Kernel,
    params: wgpu::Buffer,
    nodes: wgpu::Buffer,
    triangles: wgpu::Buffer,
    triangle_masks: wgpu::Buffer,
    triangle_ids: wgpu::Buffer,
    instances: wgpu::Buffer,
    batch: Option<BatchBuffers>,
    chunk_rays: u32,
    reorder_from: usize,
    /// What happened that the caller may want to show (the shared device lost and opened
    /// again), since the last [`Picker::take_notes`](crate::Picker::take_notes).
    notes: Vec<String>,
}

/// Gives the picker's buffers back to the device now: destroyed, and the device polled (not
/// waited on). Left to wgpu, a dropped picker's buffers waited for the device's next
/// submission, so a server whose clients only edited grew by a scene's buffers at each edit
/// that rebuilt the tree (its pickers share one device).
impl Drop for GpuPicker {
    fn drop(&mut self) {
        let scene = [
            &self.params,
            &self.nodes,
            &self.triangles,
            &self.triangle_masks,
            &self.triangle_ids,
            &self.instances,
        ];
        let batch = self
            .batch
            .iter()
            .flat_map(|b| [&b.rays, &b.hits, &b.lists, &b.readback]);
        for buffer in scene.into_iter().chain(batch) {
            buffer.destroy();
        }
        let _ = self.context.device.poll(wgpu::PollType::Poll);
    }
}

/// The compiled kernel and what binds to it: what a picker keeps of its device whatever the
/// scene ([`GpuPicker::over`] shares it; the device keeps each one compiled for later pickers,
/// [`Kernel::on`]).
#[derive(Clone, Debug)]
pub(crate) struct Kernel {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    /// The kernel's bindings, read from the WGSL.
    table: Vec<Binding>,
    workgroup_size: u32,
    exact: bool,
}

impl Kernel {
    /// The kernel for `workgroup_size` and `exact` on `context`'s device: compiled once per
    /// device (a compile took about 40 ms on lavapipe; the pickers over many scenes that share
    /// a device, [`GpuContext::shared`], each compiled it), then shared. Checks that there is
    /// room to compile first.
    fn on(context: &GpuContext, workgroup_size: u32, exact: bool) -> Result<Self> {
        let mut kernels = context
            .kernels
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(kernel) = kernels
            .iter()
            .find(|k| k.workgroup_size == workgroup_size && k.exact == exact)
        {
            return Ok(kernel.clone());
        }
        check_room_to_compile()?;
        let kernel = Self::compile(context, workgroup_size, exact)?;
        kernels.push(kernel.clone());
        Ok(kernel)
    }

    /// Compiles `pick.wgsl` on `context`'s device with `workgroup_size` invocations per
    /// workgroup (checked against its limits by the caller) and the exact arithmetic on or off.
    fn compile(context: &GpuContext, workgroup_size: u32, exact: bool) -> Result<Self> {
        let table = bindings(PICK_WGSL)?;
        scoped(context, |device| {
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("pick.wgsl"),
                source: wgpu::ShaderSource::Wgsl(PICK_WGSL.into()),
            });
            let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("pick bindings"),
                entries: &layout_entries(&table),
            });
            let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("pick"),
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            });
            let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some("pick"),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some("pick"),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants: &[
                        (WORKGROUP_SIZE_CONSTANT, f64::from(workgroup_size)),
                        (EXACT_ARITHMETIC_CONSTANT, f64::from(u32::from(exact))),
                    ],
                    ..Default::default()
                },
                cache: None,
            });
            (pipeline, layout)
        })
        .map(|(pipeline, layout)| Kernel {
            pipeline,
            layout,
            table,
            workgroup_size,
            exact,
        })
    }
}

/// Runs `make` on `context`'s device within validation and out-of-memory error scopes: what
/// either catches, or a fault recorded meanwhile, fails it.
fn scoped<T>(context: &GpuContext, make: impl FnOnce(&wgpu::Device) -> T) -> Result<T> {
    let device = &context.device;
    let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let oom = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
    let made = make(device);
    let oom_error = pollster::block_on(oom.pop());
    let validation_error = pollster::block_on(scope.pop());
    if let Some(e) = oom_error.or(validation_error) {
        return Err(Error::Gpu(e.to_string()));
    }
    context.take_fault()?;
    Ok(made)
}

/// Per-chunk buffers, sized for `capacity` rays with `list_length` all-hits entries each.
struct BatchBuffers {
    capacity: u32,
    list_length: u32,
    rays: wgpu::Buffer,
    hits: wgpu::Buffer,
    lists: wgpu::Buffer,
    readback: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
}

impl GpuPicker {
    /// Uploads the scene and compiles the kernel with the default [`WORKGROUP_SIZE`]. Fails with
    /// [`Error::TooLargeForGpu`] when the tree does not fit one storage binding, and with
    /// [`Error::Gpu`] if wgpu rejects anything.
    pub fn new(context: &GpuContext, built: Arc<BuiltScene>) -> Result<Self> {
        Self::with_workgroup_size(context, built, WORKGROUP_SIZE)
    }

    /// [`GpuPicker::new`] with `workgroup_size` invocations per workgroup; fails with
    /// [`Error::WorkgroupSize`] when the adapter cannot run workgroups that large.
    pub fn with_workgroup_size(
        context: &GpuContext,
        built: Arc<BuiltScene>,
        workgroup_size: u32,
    ) -> Result<Self> {
        let exact = needs_exact_arithmetic(context);
        Self::with_options(context, built, workgroup_size, exact)
    }

    /// [`GpuPicker::with_workgroup_size`] with the kernel's own exactly rounded division and
    /// unfused products on (`exact`, the default on every adapter but llvmpipe, whose f32
    /// division is exact and which fuses nothing) or off (the hardware's division and products:
    /// 7× faster on llvmpipe; a GPU that divides to 2.5 ulp or fuses multiply-adds then answers
    /// other than the twin on rays through vertices and edges).
    pub fn with_options(
        context: &GpuContext,
        built: Arc<BuiltScene>,
        workgroup_size: u32,
        exact: bool,
    ) -> Result<Self> {
        let limits = context.device.limits();
        check_workgroup_size(&limits, workgroup_size)?;
        check_sizes(&limits, &built)?;
        let kernel = Kernel::on(context, workgroup_size, exact)?;
        Self::with_kernel(context, kernel, built)
    }

    /// A picker over `built` (a scene built anew: another tree, other objects) on this one's
    /// device, with its compiled kernel and settings: the scene's buffers are uploaded, nothing
    /// else is made again (a device opened and a kernel compiled cost a server's rebuilding
    /// edits about a second each on lavapipe). This picker is left as it was, so a failure
    /// changes nothing.
    pub fn over(&self, built: Arc<BuiltScene>) -> Result<Self> {
        if let Some(context) = self.context.reopened() {
            return self.on_device_opened_again(context?, built);
        }
        self.context.take_fault()?;
        check_sizes(&self.context.device.limits(), &built)?;
        let mut picker = Self::with_kernel(&self.context, self.kernel.clone(), built)?;
        picker.chunk_rays = self.chunk_rays;
        picker.reorder_from = self.reorder_from;
        Ok(picker)
    }

    /// Uploads `built`'s buffers for `kernel` (compiled on `context`'s device; `built`'s sizes
    /// checked against its limits).
    fn with_kernel(context: &GpuContext, kernel: Kernel, built: Arc<BuiltScene>) -> Result<Self> {
        let max_binding = context.device.limits().max_storage_buffer_binding_size;
        // Empty scenes still bind one (unused) element: bindings may not be empty.
        let [
            nodes,
            triangles,
            triangle_masks,
            triangle_ids,
            instances,
            params,
        ] = scoped(context, |device| {
            [
                storage_init(device, "nodes", &built.bvh.nodes, GpuNode::default()),
                storage_init(
                    device,
                    "triangles",
                    &built.bvh.triangles,
                    GpuTriangle::default(),
                ),
                storage_init(device, "triangle masks", &built.triangle_masks, 0u32),
                storage_init(device, "triangle ids", &built.bvh.triangle_ids, 0u32),
                storage_init(
                    device,
                    "instances",
                    instance_records(&built),
                    GpuInstance::default(),
                ),
                device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("params"),
                    size: size_of::<GpuParams>() as u64,
                    usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                }),
            ]
        })?;
        let by_binding = (max_binding / size_of::<GpuRay>() as u64).min(u32::MAX as u64) as u32;
        Ok(Self {
            context: context.clone(),
            built,
            kernel,
            params,
            nodes,
            triangles,
            triangle_masks,
            triangle_ids,
            instances,
            batch: None,
            chunk_rays: DEFAULT_CHUNK_RAYS.min(by_binding),
            reorder_from: reorder_from_for(context),
            notes: Vec::new(),
        })
    }

    /// When this picker's device is the process's shared one ([`GpuContext::shared`]) and was
    /// lost (a driver reset, a GPU taken away, `Device::destroy`), makes it again on the shared
    /// device opened anew: the same scene, kernel settings, chunking and ray order, and says so
    /// in a note. `Ok(false)` when the device is not lost; [`Error::DeviceLost`] when no device
    /// opens, or for a lost device the caller brought ([`GpuPicker::new`]), which is not
    /// replaced.
    fn reopen_if_lost(&mut self) -> Result<bool> {
        let Some(context) = self.context.reopened() else {
            return Ok(false);
        };
        let picker = self.on_device_opened_again(context?, self.built.clone())?;
        self.replace_with(picker);
        Ok(true)
    }

    /// `picker` in this one's place, with the notes this one had not handed out yet.
    fn replace_with(&mut self, picker: Self) {
        let notes = std::mem::take(&mut self.notes);
        *self = picker;
        self.notes.splice(0..0, notes);
    }

    /// After work on the device failed: [`GpuPicker::reopen_if_lost`] once wgpu has said
    /// whether the device was lost ([`GpuContext::settle`]).
    fn settled_and_reopened(&mut self) -> Result<bool> {
        self.context.settle();
        self.reopen_if_lost()
    }

    /// A picker like this one over `built` on `context`, the shared device opened again after
    /// this one's was lost; its note says so. On the same adapter it keeps this one's kernel
    /// settings, chunking and ray order; another adapter (the GPU gone, a software one left)
    /// gets that adapter's own (its exact arithmetic, whether it sorts rays).
    fn on_device_opened_again(&self, context: GpuContext, built: Arc<BuiltScene>) -> Result<Self> {
        let same = context.adapter_info == self.context.adapter_info;
        let mut picker = if same {
            let mut picker = Self::with_options(
                &context,
                built,
                self.kernel.workgroup_size,
                self.kernel.exact,
            )?;
            picker.set_chunk_rays(self.chunk_rays);
            picker.reorder_from = self.reorder_from;
            picker
        } else {
            Self::new(&context, built)?
        };
        picker.notes.push(format!(
            "the GPU device was lost and opened again: {} (opened {} times in this process)",
            context.describe(),
            context.opening()
        ));
        Ok(picker)
    }

    /// Invocations per workgroup of this picker's kernel.
    pub fn workgroup_size(&self) -> u32 {
        self.kernel.workgroup_size
    }

    /// Sets the batch size from which [`Picker::query`] traces rays in
    /// [`crate::ray_order::RayOrder`] (`usize::MAX`: never). Answers are the same either way.
    pub fn set_reorder_from(&mut self, rays: usize) {
        self.reorder_from = rays;
    }

    /// Sets the most rays per dispatch (at least 1; capped by the storage binding limit).
    pub fn set_chunk_rays(&mut self, rays: u32) {
        let max_binding = self.context.device.limits().max_storage_buffer_binding_size;
        let by_binding = (max_binding / size_of::<GpuRay>() as u64).min(u32::MAX as u64) as u32;
        self.chunk_rays = rays.clamp(1, by_binding);
    }

    /// The scene this picker holds.
    pub fn built(&self) -> &Arc<BuiltScene> {
        &self.built
    }

    /// The device this picker runs on.
    pub fn context(&self) -> &GpuContext {
        &self.context
    }

    /// Runs the closest-hit kernel (Möller–Trumbore) over kernel-frame rays; raw results.
    pub fn trace(&mut self, rays: &[GpuRay]) -> Result<Vec<GpuHit>> {
        Ok(self.trace_batch(rays, 0, false)?.0)
    }

    /// Runs the kernel over kernel-frame rays (each with its own flags), with all-hits lists of
    /// `max_hits` entries per ray. Returns the per-ray records and the lists.
    pub fn trace_batch(
        &mut self,
        rays: &[GpuRay],
        max_hits: u32,
        watertight: bool,
    ) -> Result<(Vec<GpuHit>, Vec<GpuHitEntry>)> {
        let mut hits = Vec::with_capacity(rays.len());
        let mut lists = Vec::with_capacity(rays.len() * max_hits as usize);
        let chunk = self.chunk_for(max_hits) as usize;
        for part in rays.chunks(chunk) {
            let traced = self.trace_chunk(part, max_hits, watertight, &mut hits, &mut lists);
            if traced.is_err() {
                // Never keep buffers or a bind group that took part in a failed dispatch: the
                // next request starts from fresh ones.
                self.batch = None;
            }
            traced?;
        }
        self.finish_cut_walks(rays, max_hits, watertight, &mut hits, &mut lists);
        Ok((hits, lists))
    }

    /// Traces again, on the twin (`cpu::traverse`, the kernel line for line, so the same bits),
    /// each ray whose walk the driver cut short ([`UNFINISHED`]: llvmpipe's iteration limit,
    /// shared by a group of lanes, which long walks side by side used up). Other adapters
    /// never cut a walk.
    fn finish_cut_walks(
        &self,
        rays: &[GpuRay],
        max_hits: u32,
        watertight: bool,
        hits: &mut [GpuHit],
        lists: &mut [GpuHitEntry],
    ) {
        if !hits.iter().any(|h| h.prim == UNFINISHED) {
            return;
        }
        let settings = TraceSettings {
            triangle_masks: &self.built.triangle_masks,
            max_hits,
            watertight,
            instances: self.built.instances(),
        };
        let buffers = crate::cpu::buffers(&self.built.bvh, &settings);
        let again = |(ray, hit, list): (&GpuRay, &mut GpuHit, &mut [GpuHitEntry])| {
            if hit.prim == UNFINISHED {
                list.fill(GpuHitEntry::default());
                *hit = crate::cpu::traverse::trace(buffers, ray, list);
            }
        };
        let k = max_hits as usize;
        if k == 0 {
            rays.par_iter()
                .zip(hits.par_iter_mut())
                .for_each(|(ray, hit)| again((ray, hit, &mut [])));
        } else {
            rays.par_iter()
                .zip(hits.par_iter_mut())
                .zip(lists.par_chunks_mut(k))
                .for_each(|((ray, hit), list)| again((ray, hit, list)));
        }
    }

    /// The most rays one dispatch may carry with `max_hits` list entries per ray: every per-chunk
    /// buffer (rays, hits, lists, and the readback holding hits and lists) must fit the adapter's
    /// storage binding and buffer size limits.
    pub fn chunk_for(&self, max_hits: u32) -> u32 {
        let limits = self.context.device.limits();
        let per_ray_readback =
            size_of::<GpuHit>() as u64 + size_of::<GpuHitEntry>() as u64 * u64::from(max_hits);
        let per_ray_list = size_of::<GpuHitEntry>() as u64 * u64::from(max_hits.max(1));
        let per_ray_binding = per_ray_list
            .max(size_of::<GpuRay>() as u64)
            .max(size_of::<GpuHit>() as u64);
        let by_binding = limits.max_storage_buffer_binding_size / per_ray_binding;
        let by_buffer = limits.max_buffer_size / per_ray_readback.max(per_ray_binding);
        let most = by_binding.min(by_buffer).clamp(1, u64::from(u32::MAX)) as u32;
        self.chunk_rays.min(most)
    }

    fn trace_chunk(
        &mut self,
        rays: &[GpuRay],
        max_hits: u32,
        watertight: bool,
        hits_out: &mut Vec<GpuHit>,
        lists_out: &mut Vec<GpuHitEntry>,
    ) -> Result<()> {
        let count = rays.len() as u32;
        self.ensure_capacity(count, max_hits)?;
        let device = &self.context.device;
        let queue = &self.context.queue;
        let batch = self
            .batch
            .as_ref()
            .expect("ensure_capacity allocates the batch buffers");
        let groups = count.div_ceil(self.kernel.workgroup_size);
        let max_groups = device.limits().max_compute_workgroups_per_dimension.max(1);
        let groups_x = groups.min(max_groups);
        let groups_y = groups.div_ceil(groups_x);
        let params = GpuParams {
            ray_count: count,
            node_count: self.built.bvh.nodes.len() as u32,
            iteration_cap: self
                .built
                .instances()
                .map_or(self.built.bvh.iteration_cap(), |i| i.iteration_cap()),
            row_pitch: groups_x * self.kernel.workgroup_size,
            max_hits,
            use_masks: u32::from(!self.built.triangle_masks.is_empty()),
            watertight: u32::from(watertight),
            top_nodes: self.built.instances().map_or(0, |i| i.top_nodes()),
            opaque: [0; 3],
            pad: 0,
        };
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        queue.write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        write_rays(queue, &batch.rays, rays)?;
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("pick"),
        });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("pick"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.kernel.pipeline);
            pass.set_bind_group(0, &batch.bind_group, &[]);
            pass.dispatch_workgroups(groups_x, groups_y, 1);
        }
        let hit_bytes = (rays.len() * size_of::<GpuHit>()) as u64;
        let list_bytes = (rays.len() * max_hits as usize * size_of::<GpuHitEntry>()) as u64;
        let list_offset = batch.capacity as u64 * size_of::<GpuHit>() as u64;
        encoder.copy_buffer_to_buffer(&batch.hits, 0, &batch.readback, 0, hit_bytes);
        if list_bytes > 0 {
            encoder.copy_buffer_to_buffer(
                &batch.lists,
                0,
                &batch.readback,
                list_offset,
                list_bytes,
            );
        }
        let submission = queue.submit([encoder.finish()]);
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(Error::Gpu(e.to_string()));
        }
        let mapped_end = if list_bytes > 0 {
            list_offset + list_bytes
        } else {
            hit_bytes
        };
        let slice = batch.readback.slice(..mapped_end);
        let (sender, receiver) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = sender.send(r);
        });
        device
            .poll(wgpu::PollType::Wait {
                submission_index: Some(submission),
                timeout: None,
            })
            .map_err(|e| Error::Gpu(e.to_string()))?;
        self.context.take_fault()?;
        match receiver.recv() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(Error::Gpu(format!("reading results back failed: {e}"))),
            Err(_) => return Err(Error::Gpu("reading results back was abandoned".into())),
        }
        {
            let read_error = |e| Error::Gpu(format!("reading results back failed: {e}"));
            let view = batch
                .readback
                .slice(..hit_bytes)
                .get_mapped_range()
                .map_err(read_error)?;
            copy_out(hits_out, bytemuck::cast_slice(&view));
            if list_bytes > 0 {
                let view = batch
                    .readback
                    .slice(list_offset..list_offset + list_bytes)
                    .get_mapped_range()
                    .map_err(read_error)?;
                copy_out(lists_out, bytemuck::cast_slice(&view));
            }
        }
        batch.readback.unmap();
        Ok(())
    }

    /// Makes sure the per-chunk buffers hold `rays` rays with `list_length` list entries each,
    /// replacing them when they are too small. Buffers or a bind group that wgpu rejects are
    /// dropped, never kept for the next request.
    fn ensure_capacity(&mut self, rays: u32, list_length: u32) -> Result<()> {
        if self
            .batch
            .as_ref()
            .is_some_and(|b| b.capacity >= rays && b.list_length >= list_length)
        {
            return Ok(());
        }
        self.batch = None;
        // Sized for this request alone (a long list asked for once is not carried into later
        // requests), and never past what one dispatch may carry (`chunk_for`).
        let capacity = rays
            .next_power_of_two()
            .min(self.chunk_for(list_length))
            .max(rays);
        let device = &self.context.device;
        let validation = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let oom = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let buffer = |label, size: usize, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: (size * capacity as usize) as u64,
                usage,
                mapped_at_creation: false,
            })
        };
        use wgpu::BufferUsages as U;
        let rays_buffer = buffer("rays", size_of::<GpuRay>(), U::STORAGE | U::COPY_DST);
        let hits = buffer("hits", size_of::<GpuHit>(), U::STORAGE | U::COPY_SRC);
        let entry = size_of::<GpuHitEntry>() * list_length.max(1) as usize;
        let lists = buffer("hit lists", entry, U::STORAGE | U::COPY_SRC);
        let readback = buffer(
            "readback",
            size_of::<GpuHit>() + size_of::<GpuHitEntry>() * list_length as usize,
            U::MAP_READ | U::COPY_DST,
        );
        let entries = group_entries(
            &self.kernel.table,
            &[
                ("params", &self.params),
                ("nodes", &self.nodes),
                ("triangles", &self.triangles),
                ("rays", &rays_buffer),
                ("hits", &hits),
                ("hit_lists", &lists),
                ("triangle_masks", &self.triangle_masks),
                ("triangle_ids", &self.triangle_ids),
                ("instances", &self.instances),
            ],
        );
        // On an error the scope guards pop themselves as they drop.
        let entries = entries?;
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("pick"),
            layout: &self.kernel.layout,
            entries: &entries,
        });
        let oom_error = pollster::block_on(oom.pop());
        let validation_error = pollster::block_on(validation.pop());
        if let Some(e) = oom_error.or(validation_error) {
            return Err(Error::Gpu(format!(
                "could not allocate buffers for {capacity} rays with {list_length} hits each: {e}"
            )));
        }
        self.batch = Some(BatchBuffers {
            capacity,
            list_length,
            rays: rays_buffer,
            hits,
            lists,
            readback,
            bind_group,
        });
        Ok(())
    }
}

impl Tracer for GpuPicker {
    fn built(&self) -> &Arc<BuiltScene> {
        &self.built
    }

    fn built_mut(&mut self) -> &mut Arc<BuiltScene> {
        &mut self.built
    }

    /// A refit keeps every buffer's size and the triangles' ids and masks: only the nodes and
    /// the triangles are written again, into the resident buffers. A rebuilt tree gets buffers
    /// of its own (the kernel stays compiled).
    fn scene_changed(&mut self, refit: Refit) -> Result<()> {
        // A picker made again holds the changed scene already.
        if self.reopen_if_lost()? {
            return Ok(());
        }
        let built = self.built.clone();
        match refit {
            Refit::Refitted => {
                if !built.bvh.nodes.is_empty() {
                    let queue = &self.context.queue;
                    queue.write_buffer(&self.nodes, 0, bytemuck::cast_slice(&built.bvh.nodes));
                    queue.write_buffer(
                        &self.triangles,
                        0,
                        bytemuck::cast_slice(&built.bvh.triangles),
                    );
                    let records = instance_records(&built);
                    if !records.is_empty() {
                        queue.write_buffer(&self.instances, 0, bytemuck::cast_slice(records));
                    }
                }
            }
            Refit::Moved => {
                // The top tree's nodes (first in the node buffer) and the instance records.
                let queue = &self.context.queue;
                let top = built.instances().map_or(0, |i| i.top_nodes() as usize);
                if top > 0 {
                    queue.write_buffer(
                        &self.nodes,
                        0,
                        bytemuck::cast_slice(&built.bvh.nodes[..top]),
                    );
                }
                let records = instance_records(&built);
                if !records.is_empty() {
                    queue.write_buffer(&self.instances, 0, bytemuck::cast_slice(records));
                }
            }
            // New buffers, each bound anew (the batch's bind group names the old ones).
            Refit::Rebuilt => {
                let picker = self.over(built)?;
                self.replace_with(picker);
            }
        }
        // The writes' staging memory is the device's until a submission carries them and
        // completes: sent now, and what earlier edits staged released, so a client that only
        // edits does not grow the process (300 moves had grown a server by 259 MB).
        self.context.queue.submit([]);
        let _ = self.context.device.poll(wgpu::PollType::Poll);
        match self.context.take_fault() {
            Err(e) if !self.settled_and_reopened()? => Err(e),
            _ => Ok(()),
        }
    }

    /// On the shared device, a loss found before the batch, or one that failed it, is met by
    /// making the picker again on the device opened anew, and the batch traced there once more.
    fn trace(
        &mut self,
        rays: &[GpuRay],
        settings: &TraceSettings<'_>,
    ) -> Result<(Vec<GpuHit>, Vec<GpuHitEntry>)> {
        self.reopen_if_lost()?;
        match self.trace_batch(rays, settings.max_hits, settings.watertight) {
            // (A device the caller brought and lost: its loss, said as such.)
            Err(e) if !self.settled_and_reopened()? => Err(e),
            Err(_) => self.trace_batch(rays, settings.max_hits, settings.watertight),
            traced => traced,
        }
    }

    fn tracer_notes(&mut self) -> Vec<String> {
        std::mem::take(&mut self.notes)
    }

    fn reorder_from(&self) -> usize {
        self.reorder_from
    }

    fn picker_over(&self, built: Arc<BuiltScene>) -> Option<Result<Box<dyn Picker + Send>>> {
        Some(
            self.over(built)
                .map(|picker| Box::new(picker) as Box<dyn Picker + Send>),
        )
    }

    /// One dispatch's rays: a batch of several dispatches overlaps the host's conversion and
    /// refinement with the GPU's work.
    fn overlap_step(&self) -> Option<usize> {
        Some(self.chunk_for(0) as usize)
    }

    fn path_name(&self) -> String {
        format!("gpu {}", self.context.describe())
    }
}

/// The instance records an instanced scene's kernel reads (none for other scenes).
fn instance_records(built: &BuiltScene) -> &[GpuInstance] {
    built.instances().map_or(&[], |i| i.records())
}

/// Checks that the adapter can run workgroups of `size` invocations (the kernel's workgroups are
/// `size` × 1 × 1). wgpu checks the shader's declared size, not the value an override gives it,
/// so this is the only check the chosen size gets before the driver sees it.
pub fn check_workgroup_size(limits: &wgpu::Limits, size: u32) -> Result<()> {
    let broken = [
        ("the smallest workgroup", 1, size >= 1),
        (
            "max_compute_invocations_per_workgroup",
            limits.max_compute_invocations_per_workgroup,
            size <= limits.max_compute_invocations_per_workgroup,
        ),
        (
            "max_compute_workgroup_size_x",
            limits.max_compute_workgroup_size_x,
            size <= limits.max_compute_workgroup_size_x,
        ),
    ]
    .into_iter()
    .find(|&(_, _, ok)| !ok);
    match broken {
        Some((limit_name, limit, _)) => Err(Error::WorkgroupSize {
            requested: size,
            limit_name,
            limit,
        }),
        None => Ok(()),
    }
}

/// The address space a driver may need to compile the kernel: under `ulimit -v`, lavapipe
/// compiling it with about 18 MiB left crashed the process (a segmentation fault inside the
/// driver, not an error it returns); it needed about 28 MiB. Twice that is asked for.
const ROOM_TO_COMPILE: u64 = 64 << 20;

/// Refuses to compile the kernel where an address-space limit leaves less than
/// [`ROOM_TO_COMPILE`].
fn check_room_to_compile() -> Result<()> {
    match crate::budget::address_space_left() {
        Some(left) if left < ROOM_TO_COMPILE => Err(Error::Gpu(format!(
            "`ulimit -v` leaves this process {} of address space, too little for the GPU's \
             driver to compile the kernel (it needs about {}); raise the limit or use the CPU \
             backend",
            crate::budget::human(left),
            crate::budget::human(ROOM_TO_COMPILE)
        ))),
        _ => Ok(()),
    }
}

/// Refuses a tree whose nodes or triangles do not fit one storage binding.
fn check_sizes(limits: &wgpu::Limits, built: &BuiltScene) -> Result<()> {
    let max_binding = limits.max_storage_buffer_binding_size;
    for (what, bytes) in [
        (
            "the tree's node buffer",
            size_of::<GpuNode>() * built.bvh.nodes.len(),
        ),
        (
            "the triangle buffer",
            size_of::<GpuTriangle>() * built.bvh.triangles.len(),
        ),
    ] {
        if bytes as u64 > max_binding {
            return Err(Error::TooLargeForGpu {
                what,
                needed: bytes as u64,
                limit: max_binding,
            });
        }
    }
    Ok(())
}

/// A storage buffer holding `data` (or one `filler` when it is empty: bindings may not be
/// empty), which later writes may replace ([`Tracer::scene_changed`]).
fn storage_init<T: bytemuck::Pod>(
    device: &wgpu::Device,
    label: &str,
    data: &[T],
    filler: T,
) -> wgpu::Buffer {
    let filler = [filler];
    let contents: &[T] = if data.is_empty() { &filler } else { data };
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents: bytemuck::cast_slice(contents),
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
    })
}
