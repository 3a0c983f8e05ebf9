//! Node and triangle layouts, measured on the CPU walk (issue 5's layout levers):
//!
//! - nodes: the kernel's 32-byte nodes (f32 boxes) against 20-byte nodes whose boxes are 16-bit
//!   fixed point on a grid over the root box, rounded outwards (a decoded box always holds the
//!   exact one, so no hit is lost; boxes grow by up to one grid step);
//! - triangles: 36-byte leaf-order triangles (three f32 vertices) against indexed triangles
//!   (three u32 indices into a shared f32 vertex array, each vertex converted once).
//!
//! Each variant runs the same `cpu::traverse::trace` through its `NodeSource` /
//! `TriangleSource`, so only the memory layout differs. Before timing, every variant's answers are
//! compared with the flat layout's (same triangle, or a different triangle at the same t: a
//! shared edge that a larger quantised box lets the walk reach in another order).
//!
//! Run with `cargo bench --bench layouts`.

#[path = "peers/scenes.rs"]
mod scenes;
#[path = "common/short_groups.rs"]
mod short_groups;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use glam::Vec3;
use rayon::prelude::*;
use raypick::check::synthetic::{RayKind, rays};
use raypick::cpu::traverse::{Buffers, NodeSource, TriangleSource, trace};
use raypick::frame::local_rays;
use raypick::layout::{GpuHit, GpuNode, GpuRay, GpuTriangle};
use raypick::{BuildOptions, Bvh, Scene};
use scenes::SCENES;
use short_groups::configure;
use std::hint::black_box;

const RAY_COUNT: usize = 65_536;
/// Fixed-point steps across the root box on each axis.
const STEPS: f32 = 65_535.0;

/// 20 bytes: the box as 16-bit steps over the root box, then the kernel's link words.
#[derive(Clone, Copy)]
#[repr(C)]
struct QuantisedNode {
    lo: [u16; 3],
    hi: [u16; 3],
    parent_kind: u32,
    first: u32,
}

const _: () = assert!(size_of::<QuantisedNode>() == 20);

struct QuantisedNodes {
    base: Vec3,
    step: Vec3,
    nodes: Vec<QuantisedNode>,
}

impl QuantisedNodes {
    fn new(nodes: &[GpuNode]) -> Self {
        let (base, top) = (Vec3::from(nodes[0].min), Vec3::from(nodes[0].max));
        let step = ((top - base) / STEPS).max(Vec3::splat(f32::MIN_POSITIVE));
        let decode = |q: [u16; 3]| base + Vec3::new(q[0] as f32, q[1] as f32, q[2] as f32) * step;
        let encode = |n: &GpuNode| {
            let (min, max) = (Vec3::from(n.min), Vec3::from(n.max));
            let mut lo = ((min - base) / step)
                .floor()
                .clamp(Vec3::ZERO, Vec3::splat(STEPS));
            let mut hi = ((max - base) / step)
                .ceil()
                .clamp(Vec3::ZERO, Vec3::splat(STEPS));
            // Round outwards for certain: step down or up until the decoded box holds the exact one.
            for a in 0..3 {
                while lo[a] > 0.0 && decode(q16(lo))[a] > min[a] {
                    lo[a] -= 1.0;
                }
                while hi[a] < STEPS && decode(q16(hi))[a] < max[a] {
                    hi[a] += 1.0;
                }
            }
            QuantisedNode {
                lo: q16(lo),
                hi: q16(hi),
                parent_kind: n.parent_kind,
                first: n.first,
            }
        };
        let quantised = Self {
            base,
            step,
            nodes: nodes.iter().map(encode).collect(),
        };
        for (i, n) in nodes.iter().enumerate() {
            let d = quantised.node(i as u32);
            assert!(
                Vec3::from(d.min).cmple(Vec3::from(n.min)).all()
                    && Vec3::from(d.max).cmpge(Vec3::from(n.max)).all(),
                "quantised box {i} does not hold the exact one"
            );
        }
        quantised
    }
}

fn q16(v: Vec3) -> [u16; 3] {
    [v.x as u16, v.y as u16, v.z as u16]
}

impl NodeSource for QuantisedNodes {
    fn node_count(&self) -> usize {
        self.nodes.len()
    }

    #[inline(always)]
    fn node(&self, index: u32) -> GpuNode {
        let q = &self.nodes[index as usize];
        let at = |v: [u16; 3]| {
            (self.base + Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32) * self.step).into()
        };
        GpuNode {
            min: at(q.lo),
            parent_kind: q.parent_kind,
            max: at(q.hi),
            first: q.first,
        }
    }
}

/// Leaf-order triangles as indices into one shared vertex array.
struct IndexedTriangles {
    vertices: Vec<[f32; 3]>,
    indices: Vec<[u32; 3]>,
}

impl IndexedTriangles {
    /// Uses the scene's own vertex sharing; each vertex is converted to f32 exactly as the flat
    /// triangles were, so the decoded triangles are bit-identical to them.
    fn new(scene: &Scene, bvh: &Bvh) -> Self {
        let vertices = (0..scene.vertex_count())
            .map(|i| (scene.position(i) - bvh.origin).as_vec3().into())
            .collect();
        let indices = bvh
            .triangle_ids
            .iter()
            .map(|&id| scene.triangle_vertices(id as usize))
            .collect();
        let indexed = Self { vertices, indices };
        for (i, t) in bvh.triangles.iter().enumerate() {
            assert_eq!(indexed.triangle(i as u32), *t, "indexed triangle {i}");
        }
        indexed
    }
}

impl TriangleSource for IndexedTriangles {
    #[inline(always)]
    fn triangle(&self, index: u32) -> GpuTriangle {
        let [a, b, c] = self.indices[index as usize].map(|v| self.vertices[v as usize]);
        GpuTriangle {
            v0: a,
            v1: b,
            v2: c,
        }
    }
}

fn trace_with<N: NodeSource + ?Sized, T: TriangleSource + ?Sized>(
    nodes: &N,
    triangles: &T,
    iteration_cap: u32,
    triangle_ids: &[u32],
    rays: &[GpuRay],
) -> Vec<GpuHit> {
    let buffers = Buffers {
        nodes,
        triangles,
        triangle_ids,
        triangle_masks: &[],
        instances: &[],
        top_nodes: 0,
        iteration_cap,
        max_hits: 0,
        watertight: true,
    };
    rays.par_iter()
        .with_min_len(256)
        .map(|ray| trace(buffers, ray, &mut []))
        .collect()
}

/// Rays whose answers differ from the flat layout's other than by a same-t shared edge.
fn disagreements(reference: &[GpuHit], other: &[GpuHit]) -> usize {
    reference
        .iter()
        .zip(other)
        .filter(|(a, b)| a.prim != b.prim && a.t != b.t)
        .count()
}

/// The scenes of `benches/peers.rs` this bench uses.
const SCENE_NAMES: [&str; 4] = ["bunny", "dem", "terrain_2m", "soup_200k"];

fn layouts(c: &mut Criterion) {
    for spec in SCENES.iter().filter(|s| SCENE_NAMES.contains(&s.name)) {
        let (name, scene) = (
            spec.name,
            (spec.make)().expect("the scene's data is in the repository"),
        );
        let bvh = Bvh::build(&scene, &BuildOptions::default()).expect("build");
        let quantised = QuantisedNodes::new(&bvh.nodes);
        let indexed = IndexedTriangles::new(&scene, &bvh);
        let tris = bvh.triangles.len() as f64;
        let node_bytes = bvh.nodes.len() as f64;
        let flat_nodes = node_bytes * 32.0;
        let small_nodes = node_bytes * 20.0;
        let flat_tris = tris * 36.0;
        let indexed_tris = (indexed.indices.len() * 12 + indexed.vertices.len() * 12) as f64;
        println!(
            "{name}: {} triangles; bytes/triangle: flat {:.1}, quantised nodes {:.1}, indexed triangles {:.1}, both {:.1}",
            bvh.triangles.len(),
            (flat_nodes + flat_tris) / tris,
            (small_nodes + flat_tris) / tris,
            (flat_nodes + indexed_tris) / tris,
            (small_nodes + indexed_tris) / tris,
        );
        let cap = bvh.iteration_cap();
        let ids: &[u32] = &bvh.triangle_ids;
        let flat_nodes: &[GpuNode] = &bvh.nodes;
        let flat_tris: &[GpuTriangle] = &bvh.triangles;
        let mut group = c.benchmark_group(format!("layouts/{name}"));
        configure(&mut group);
        group.throughput(Throughput::Elements(RAY_COUNT as u64));
        for kind in [RayKind::Camera, RayKind::Random] {
            let rays = local_rays(
                raypick::frame::Frame::at(bvh.origin),
                &rays(&scene, kind, RAY_COUNT, 1),
            );
            let reference = trace_with(flat_nodes, flat_tris, cap, ids, &rays);
            let box_tests = |hits: &[GpuHit]| {
                hits.iter().map(|h| h.box_tests as f64).sum::<f64>() / hits.len() as f64
            };
            let quantised_hits = trace_with(&quantised, flat_tris, cap, ids, &rays);
            let indexed_hits = trace_with(flat_nodes, &indexed, cap, ids, &rays);
            println!(
                "  {}: box tests/ray flat {:.1}, quantised {:.1}; disagreements: quantised {}, indexed {}",
                kind.name(),
                box_tests(&reference),
                box_tests(&quantised_hits),
                disagreements(&reference, &quantised_hits),
                disagreements(&reference, &indexed_hits),
            );
            let kind = kind.name();
            group.bench_function(format!("flat/{kind}"), |b| {
                b.iter(|| black_box(trace_with(flat_nodes, flat_tris, cap, ids, &rays)))
            });
            group.bench_function(format!("quantised-nodes/{kind}"), |b| {
                b.iter(|| black_box(trace_with(&quantised, flat_tris, cap, ids, &rays)))
            });
            group.bench_function(format!("indexed-triangles/{kind}"), |b| {
                b.iter(|| black_box(trace_with(flat_nodes, &indexed, cap, ids, &rays)))
            });
            group.bench_function(format!("both/{kind}"), |b| {
                b.iter(|| black_box(trace_with(&quantised, &indexed, cap, ids, &rays)))
            });
        }
        group.finish();
    }
}

criterion_group!(benches, layouts);
criterion_main!(benches);
