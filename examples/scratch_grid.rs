use raypick::synthetic::{RayKind, hills, rays, terrain};
use raypick::{BuildOptions, Builder, Bvh, GridShape, Scene, cpu, frame::local_rays};
use std::time::Instant;
fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .map(|s| s.parse().unwrap())
        .unwrap_or(1001);
    let mut scene = Scene::new();
    scene
        .add_grid_mesh(
            "t",
            terrain(n, n, 500_000.0, 4_100_000.0, 1.0, hills),
            GridShape {
                columns: n as u32,
                rows: n as u32,
            },
        )
        .unwrap();
    let tri = scene.triangle_count() as f64;
    let configs = [
        (Builder::MedianCut, 4),
        (Builder::Grid, 2),
        (Builder::Grid, 4),
        (Builder::Grid, 8),
        (Builder::MedianCut, 8),
    ];
    let bvhs: Vec<Bvh> = configs
        .iter()
        .map(|&(builder, leaf_size)| {
            Bvh::build(
                &scene,
                &BuildOptions {
                    builder,
                    leaf_size,
                    ..Default::default()
                },
            )
            .unwrap()
        })
        .collect();
    let mut build = vec![vec![]; configs.len()];
    let mut trace = vec![vec![vec![]; 2]; configs.len()];
    let kinds = [RayKind::Camera, RayKind::Random];
    let lrs: Vec<_> = kinds
        .iter()
        .map(|&k| local_rays(bvhs[0].origin, &rays(&scene, k, 65536, 1)))
        .collect();
    for _round in 0..5 {
        for (c, &(builder, leaf_size)) in configs.iter().enumerate() {
            let s = Instant::now();
            let b = Bvh::build(
                &scene,
                &BuildOptions {
                    builder,
                    leaf_size,
                    ..Default::default()
                },
            )
            .unwrap();
            build[c].push(s.elapsed().as_secs_f64() * 1e3);
            drop(b);
            for k in 0..2 {
                let s = Instant::now();
                std::hint::black_box(cpu::trace_all(&bvhs[c], &lrs[k]));
                trace[c][k].push(65536.0 / s.elapsed().as_secs_f64() / 1e6);
            }
        }
    }
    let med = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    for (c, &(builder, leaf)) in configs.iter().enumerate() {
        let bvh = &bvhs[c];
        let mut line = format!(
            "{n}² {builder:?} leaf {leaf}: build {:.1} ms ({:.2} M tri/s), {:.1} B/tri, depth {}",
            med(&mut build[c]),
            tri / med(&mut build[c]) / 1e3,
            bvh.gpu_bytes() as f64 / tri,
            bvh.depth()
        );
        for k in 0..2 {
            let h = cpu::trace_all(bvh, &lrs[k]);
            let b: f64 = h.iter().map(|h| h.box_tests as f64).sum::<f64>() / h.len() as f64;
            let i: f64 = h.iter().map(|h| h.triangle_tests as f64).sum::<f64>() / h.len() as f64;
            line += &format!(
                " | {:?} {:.2} M/s b {b:.1} i {i:.2}",
                kinds[k],
                med(&mut trace[c][k])
            );
        }
        println!("{line}");
    }
}
