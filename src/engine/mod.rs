//! The CPU engine behind `--backend cpu`: the binary tree collapsed 8-wide ([`wide`]), walked
//! nearest child first ([`walk`]) with SIMD tests of eight child boxes or eight triangles at a
//! time in eight f32 lanes ([`lanes8`]: one AVX register, or two sets of four [`lanes`]).
//!
//! It answers exactly what the kernel and its twin (`cpu::traverse`, `--backend reference`)
//! answer, bit for bit, in every mode; `tests/suite/engine.rs` holds it to that on every scene, ray
//! kind and mode, with SIMD and with the portable lanes.

pub mod instanced;
pub mod lanes;
pub mod lanes8;
pub mod walk;
pub mod wide;

use crate::bvh::Bvh;
use crate::cpu::TraceSettings;
use crate::layout::{GpuHit, GpuHitEntry, GpuRay};
use lanes::Portable;
use lanes8::{Lanes8, Pair};
use rayon::prelude::*;
use std::cell::RefCell;
use std::sync::OnceLock;
pub use wide::WideBvh;

/// Which lanes the engine runs on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Simd {
    /// x86-64 SSE lanes compiled with AVX2 enabled (VEX encoding; no FMA is ever emitted, so the
    /// results are the SSE lanes' bits).
    Avx2,
    /// x86-64 SSE2 lanes.
    Sse,
    /// Plain arrays (any target).
    Portable,
}

impl Simd {
    /// The best this CPU runs, unless `RAYPICK_SIMD` (`avx2`, `sse` or `portable`) asks for
    /// less; decided once per process.
    pub fn detect() -> Simd {
        static CHOICE: OnceLock<Simd> = OnceLock::new();
        *CHOICE.get_or_init(|| {
            let best = Simd::best_available();
            match std::env::var("RAYPICK_SIMD").as_deref() {
                Ok("portable") => Simd::Portable,
                Ok("sse") if best != Simd::Portable => Simd::Sse,
                _ => best,
            }
        })
    }

    /// The best lanes this CPU supports.
    pub fn best_available() -> Simd {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                return Simd::Avx2;
            }
            Simd::Sse
        }
        #[cfg(not(target_arch = "x86_64"))]
        Simd::Portable
    }

    /// Whether this CPU can run these lanes.
    pub fn is_available(self) -> bool {
        match self {
            Simd::Portable => true,
            Simd::Sse => cfg!(target_arch = "x86_64"),
            Simd::Avx2 => Simd::best_available() == Simd::Avx2,
        }
    }

    /// The name used in messages and `RAYPICK_SIMD`.
    pub fn name(self) -> &'static str {
        match self {
            Simd::Avx2 => "avx2",
            Simd::Sse => "sse",
            Simd::Portable => "portable",
        }
    }
}

/// Rays handed to one rayon task at a time, at most.
pub const RAYS_PER_TASK: usize = 512;

/// Rays per task for a batch of `n` on `threads` threads: [`RAYS_PER_TASK`], or fewer (whole
/// packets, at least 64) for a batch too small to give each thread eight tasks, so that the
/// last tasks still balance the threads (4,096 of the soup's rays in tasks of 512 left the
/// threads idle 18% of the time; in tasks of 256, 1%: BENCHMARKS.md).
pub fn rays_per_task(n: usize, threads: usize) -> usize {
    n.div_ceil(threads.max(1) * 8)
        .next_multiple_of(walk::PACKET)
        .clamp(64, RAYS_PER_TASK)
}

/// The engine bound to one tree and one batch's settings: traces chunks of rays from any thread
/// ([`Engine::trace_chunk`]); [`trace_batch`] and the pick pipeline's fused loop
/// (`picker::pick_through`) both run on it.
pub struct Engine<'a> {
    scene: walk::Scene<'a>,
    simd: Simd,
    stack: usize,
    /// An instanced scene's top tree and meshes (`scene` is then empty).
    top: Option<instanced::TopScene<'a>>,
}

impl<'a> Engine<'a> {
    /// The engine over `wide` (collapsed from `bvh`) for `settings`, on `simd` lanes (the
    /// portable lanes where the CPU lacks them), with coherent groups of [`walk::PACKET`] rays
    /// as packets when `packets` holds.
    pub fn new(
        wide: &'a WideBvh,
        bvh: &'a Bvh,
        settings: &TraceSettings<'a>,
        simd: Simd,
        packets: bool,
    ) -> Self {
        Self {
            scene: walk::Scene {
                nodes: &wide.nodes,
                triangles: &bvh.triangles,
                triangle_ids: &bvh.triangle_ids,
                triangle_masks: settings.triangle_masks,
                watertight: settings.watertight,
                packets,
                size: wide.size(),
                interleave: true,
            },
            simd: if simd.is_available() {
                simd
            } else {
                Simd::Portable
            },
            stack: walk::stack_size(wide.depth),
            top: None,
        }
    }

    /// The engine over an instanced scene for `settings`: the wide top tree walked nearest
    /// first, each instance's mesh through its own wide tree ([`instanced`]); `nodes` is the
    /// scene's node buffer, whose top tree's leaf boxes bound each instance's hits. Fails on a
    /// corrupted mesh tree.
    pub fn instanced(
        instances: &'a crate::instance::Instances,
        nodes: &'a [crate::layout::GpuNode],
        settings: &TraceSettings<'a>,
        simd: Simd,
    ) -> crate::error::Result<Self> {
        let mut meshes = Vec::with_capacity(instances.meshes().len());
        let mut depth = 0;
        for m in instances.meshes() {
            let wide = m.wide()?;
            depth = depth.max(wide.depth);
            meshes.push(walk::Scene {
                nodes: &wide.nodes,
                triangles: &m.bvh.triangles,
                triangle_ids: &m.bvh.triangle_ids,
                triangle_masks: &[],
                watertight: settings.watertight,
                packets: false,
                size: wide.size(),
                interleave: false,
            });
        }
        let empty = walk::Scene {
            nodes: &[],
            triangles: &[],
            triangle_ids: &[],
            triangle_masks: &[],
            watertight: settings.watertight,
            packets: false,
            size: 0.0,
            interleave: false,
        };
        Ok(Self {
            scene: empty,
            simd: if simd.is_available() {
                simd
            } else {
                Simd::Portable
            },
            stack: walk::stack_size(depth),
            top: Some(instanced::TopScene {
                top: walk::Scene {
                    nodes: &instances.top_wide().nodes,
                    triangles: &[],
                    triangle_ids: &[],
                    triangle_masks: &[],
                    watertight: false,
                    packets: false,
                    size: instances.top_wide().size(),
                    interleave: false,
                },
                instances,
                top_nodes: nodes,
                meshes,
                top_stack: walk::stack_size(instances.top_wide().depth),
            }),
        })
    }

    /// Walks incoherent rays interleaved (`true`, the default) or one by one (`false`).
    /// Answers are the same either way.
    pub fn set_interleave(&mut self, on: bool) {
        self.scene.interleave = on;
    }

    /// Traces `rays` in parallel: the per-ray records and the all-hits lists (`max_hits`
    /// entries per ray; `max_hits` is 0 outside all-hits mode).
    /// Each task sets its own slots to their defaults just before it traces into them (a
    /// `vec![default; n]` had first written them all on one thread: the bunny's 1M camera rays
    /// traced 3–4% faster without it, BENCHMARKS.md).
    pub fn trace_batch(&self, rays: &[GpuRay], max_hits: usize) -> (Vec<GpuHit>, Vec<GpuHitEntry>) {
        let (n, k) = (rays.len(), max_hits);
        let mut hits: Vec<GpuHit> = crate::huge_pages::vec_with_capacity(n);
        let mut lists: Vec<GpuHitEntry> = crate::huge_pages::vec_with_capacity(n * k);
        let hit_slots = &mut hits.spare_capacity_mut()[..n];
        let per_task = rays_per_task(n, rayon::current_num_threads());
        // Every task its own stealable job (`with_max_len(1)`), as in the pick pipeline's loop:
        // see `picker::pick_fused`.
        if k == 0 {
            rays.par_chunks(per_task)
                .zip(hit_slots.par_chunks_mut(per_task))
                .with_max_len(1)
                .for_each(|(r, h)| self.trace_chunk(r, filled(h), &mut []));
        } else {
            let list_slots = &mut lists.spare_capacity_mut()[..n * k];
            rays.par_chunks(per_task)
                .zip(hit_slots.par_chunks_mut(per_task))
                .zip(list_slots.par_chunks_mut(per_task * k))
                .with_max_len(1)
                .for_each(|((r, h), l)| self.trace_chunk(r, filled(h), filled(l)));
        }
        // SAFETY: the tasks' runs cover the first `n` (and `n * k`) slots, and each task set all
        // of its own (a task's panic comes out of `for_each` before this).
        unsafe {
            hits.set_len(n);
            lists.set_len(n * k);
        }
        (hits, lists)
    }

    /// Traces `rays` into `hits` (one per ray) and `lists` (`lists.len() / rays.len()` entries
    /// per ray; empty outside all-hits mode), on the calling thread.
    pub fn trace_chunk(&self, rays: &[GpuRay], hits: &mut [GpuHit], lists: &mut [GpuHitEntry]) {
        thread_local! {
            /// This thread's stacks, kept between chunks (the interleaved walks' are a few
            /// tens of KiB).
            static STACKS: RefCell<Stacks> = const {
                RefCell::new(Stacks {
                    single: Vec::new(),
                    packet: Vec::new(),
                    frustum: Vec::new(),
                    top: Vec::new(),
                    scratch: Vec::new(),
                })
            };
        }
        STACKS.with_borrow_mut(|stacks| {
            if stacks.packet.len() < self.stack {
                stacks.single = vec![walk::Pushed::default(); self.stack * walk::INTERLEAVED];
                stacks.packet = vec![walk::PacketEntry::default(); self.stack];
                stacks.frustum = vec![walk::Entry::default(); self.stack];
            }
            if let Some(top) = &self.top {
                if stacks.top.len() < top.top_stack * walk::INTERLEAVED {
                    stacks.top = vec![walk::Pushed::default(); top.top_stack * walk::INTERLEAVED];
                }
                match self.simd {
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: `Engine::instanced` checked that this CPU has AVX2.
                    Simd::Avx2 => unsafe { trace_instanced_avx2(top, rays, hits, lists, stacks) },
                    #[cfg(target_arch = "x86_64")]
                    Simd::Sse => {
                        trace_instanced::<Pair<lanes::Sse>>(top, rays, hits, lists, stacks)
                    }
                    _ => trace_instanced::<Pair<Portable>>(top, rays, hits, lists, stacks),
                }
                return;
            }
            let scene = &self.scene;
            match self.simd {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `Engine::new` checked that this CPU has AVX2.
                Simd::Avx2 => unsafe { trace_chunk_avx2(scene, rays, hits, lists, stacks) },
                #[cfg(target_arch = "x86_64")]
                Simd::Sse => trace_chunk::<Pair<lanes::Sse>>(scene, rays, hits, lists, stacks),
                _ => trace_chunk::<Pair<Portable>>(scene, rays, hits, lists, stacks),
            }
        })
    }
}

/// Traces each ray as its flags say, in parallel, on `simd` lanes (falling back to the portable
/// lanes where the CPU lacks them), with coherent groups of [`walk::PACKET`] rays as packets
/// when `packets` holds. Returns the per-ray records and the all-hits lists (`max_hits` entries
/// per ray), as `cpu::trace_batch` does.
pub fn trace_batch(
    wide: &WideBvh,
    bvh: &Bvh,
    rays: &[GpuRay],
    settings: &TraceSettings<'_>,
    simd: Simd,
    packets: bool,
) -> (Vec<GpuHit>, Vec<GpuHitEntry>) {
    Engine::new(wide, bvh, settings, simd, packets).trace_batch(rays, settings.max_hits as usize)
}

/// One task's stacks, for the interleaved single-ray walks and the packet walk.
struct Stacks {
    /// [`walk::INTERLEAVED`] stacks, one after another.
    single: Vec<walk::Pushed>,
    packet: Vec<walk::PacketEntry>,
    /// The frustum walk's stack.
    frustum: Vec<walk::Entry>,
    /// The instanced walk's top-tree stacks ([`walk::INTERLEAVED`]) and one instance's all-hits
    /// list.
    top: Vec<walk::Pushed>,
    scratch: Vec<GpuHitEntry>,
}

/// `slots` set to their default values, as initialised items.
#[inline]
fn filled<T: Default + Copy>(slots: &mut [std::mem::MaybeUninit<T>]) -> &mut [T] {
    let value = T::default();
    for slot in slots.iter_mut() {
        slot.write(value);
    }
    // SAFETY: every slot was just written, and `MaybeUninit<T>` has `T`'s layout.
    unsafe { &mut *(slots as *mut [std::mem::MaybeUninit<T>] as *mut [T]) }
}

/// Entries of each ray's all-hits list in `lists` (0 outside all-hits mode).
#[inline(always)]
fn list_length(rays: &[GpuRay], lists: &[GpuHitEntry]) -> usize {
    if rays.is_empty() {
        0
    } else {
        lists.len() / rays.len()
    }
}

/// Traces a task's rays through an instanced scene, [`walk::INTERLEAVED`] at a time
/// ([`instanced::trace_interleaved`]).
#[inline(always)]
fn trace_instanced<L: Lanes8>(
    top: &instanced::TopScene<'_>,
    rays: &[GpuRay],
    hits: &mut [GpuHit],
    lists: &mut [GpuHitEntry],
    stacks: &mut Stacks,
) {
    let k = list_length(rays, lists);
    if stacks.scratch.len() < k {
        stacks.scratch = vec![GpuHitEntry::default(); k];
    }
    for (j, run) in rays.chunks(walk::INTERLEAVED).enumerate() {
        let i = j * walk::INTERLEAVED;
        instanced::trace_interleaved::<L>(
            top,
            run,
            &mut lists[i * k..(i + run.len()) * k],
            &mut stacks.scratch[..k],
            &mut stacks.top,
            &mut stacks.single,
            &mut hits[i..i + run.len()],
        );
    }
}

/// [`trace_instanced`] on AVX lanes, compiled with AVX2 enabled.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn trace_instanced_avx2(
    top: &instanced::TopScene<'_>,
    rays: &[GpuRay],
    hits: &mut [GpuHit],
    lists: &mut [GpuHitEntry],
    stacks: &mut Stacks,
) {
    trace_instanced::<lanes8::Avx>(top, rays, hits, lists, stacks);
}

/// Traces a task's rays: each group of [`walk::PACKET`] coherent rays (camera rays, pixel
/// picks) as one packet (from one origin, as one frustum: [`walk::trace_frustum`]), runs of
/// other rays [`walk::INTERLEAVED`] at a time, interleaved (`Scene::interleave`, the default)
/// or one by one. Either way each ray gets its single-ray
/// answer.
#[inline(always)]
fn trace_chunk<L: Lanes8>(
    scene: &walk::Scene<'_>,
    rays: &[GpuRay],
    hits: &mut [GpuHit],
    lists: &mut [GpuHitEntry],
    stacks: &mut Stacks,
) {
    let k = list_length(rays, lists);
    let p = walk::PACKET;
    // The group at `i`, when the run before it already looked.
    let mut known = None;
    let mut i = 0;
    while i < rays.len() {
        // The rays two packets ahead, so that reading a batch streams instead of stalling on
        // each packet's first loads.
        if i + 3 * p <= rays.len() {
            crate::prefetch::bytes(
                rays[i + 2 * p..].as_ptr() as *const u8,
                p * size_of::<GpuRay>(),
            );
        }
        let grouped = match known.take() {
            Some(grouped) => Some(grouped),
            None => group_at::<L>(scene, rays, i),
        };
        if let Some((group, columns)) = grouped
            && group != walk::Group::Single
        {
            if group == walk::Group::Frustum {
                walk::trace_frustum::<L>(
                    scene,
                    &rays[i..i + p],
                    &columns,
                    &mut lists[i * k..(i + p) * k],
                    &mut stacks.frustum,
                    &mut hits[i..i + p],
                );
            } else {
                walk::trace_packet::<L>(
                    scene,
                    &rays[i..i + p],
                    &columns,
                    &mut lists[i * k..(i + p) * k],
                    &mut stacks.packet,
                    &mut hits[i..i + p],
                );
            }
            i += p;
            continue;
        }
        if !scene.interleave {
            let end = (i + p).min(rays.len());
            for j in i..end {
                let list = &mut lists[j * k..(j + 1) * k];
                hits[j] = walk::trace::<L>(scene, &rays[j], list, &mut stacks.single);
            }
            i = end;
            continue;
        }
        // A run of groups that are not packets, up to `INTERLEAVED` rays.
        let mut end = (i + p).min(rays.len());
        while end < rays.len() && end - i < walk::INTERLEAVED {
            let next = group_at::<L>(scene, rays, end);
            if let Some((group, _)) = next
                && group != walk::Group::Single
            {
                known = next;
                break;
            }
            end = (end + p).min(rays.len()).min(i + walk::INTERLEAVED);
        }
        walk::trace_interleaved::<L>(
            scene,
            &rays[i..end],
            &mut lists[i * k..end * k],
            &mut stacks.single,
            &mut hits[i..end],
        );
        i = end;
    }
}

/// How the [`walk::PACKET`] rays from `i` are traced, with the rays in lanes
/// ([`walk::group_of`]); `None` where they are not grouped (fewer left, packets off). A
/// function, not a closure: a closure is not compiled with its caller's AVX2, and its lanes
/// were calls.
#[inline(always)]
fn group_at<L: Lanes8>(
    scene: &walk::Scene<'_>,
    rays: &[GpuRay],
    i: usize,
) -> Option<(walk::Group, [L; 8])> {
    if scene.packets && i + walk::PACKET <= rays.len() {
        Some(walk::group_of::<L>(&rays[i..i + walk::PACKET], scene.size))
    } else {
        None
    }
}

/// [`trace_chunk`] on AVX lanes, compiled with AVX2 enabled.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn trace_chunk_avx2(
    scene: &walk::Scene<'_>,
    rays: &[GpuRay],
    hits: &mut [GpuHit],
    lists: &mut [GpuHitEntry],
    stacks: &mut Stacks,
) {
    trace_chunk::<lanes8::Avx>(scene, rays, hits, lists, stacks);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Tasks are whole packets from 64 rays up to `RAYS_PER_TASK`, and a batch too small for
    /// eight full tasks a thread is cut finer.
    #[test]
    fn task_sizes_are_whole_packets_and_balance_small_batches() {
        for threads in [1, 2, 3, 16] {
            for n in [0, 1, 100, 4096, 10_000, 1 << 20] {
                let k = rays_per_task(n, threads);
                assert!(k.is_multiple_of(walk::PACKET) && (64..=RAYS_PER_TASK).contains(&k));
                if k > 64 && k < RAYS_PER_TASK {
                    assert!(
                        n.div_ceil(k) >= threads * 8 - threads,
                        "{n} rays, {threads}: {k}"
                    );
                }
            }
        }
        assert_eq!(rays_per_task(4096, 2), 256);
        assert_eq!(rays_per_task(1 << 20, 2), RAYS_PER_TASK);
    }
}
