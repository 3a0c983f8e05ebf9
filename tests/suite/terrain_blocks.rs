//! The grid builder: terrain cut into blocks with their own box and f64 origin, the tree built
//! over them. Its trees are valid, identical on any thread count, cover every block exactly once,
//! and give the same answers as the median-cut tree, the GPU and the brute-force oracle.

use crate::common;

use common::assert_equivalent;
use raypick::bvh::terrain_blocks::BLOCK_CELLS;
use raypick::check::compare::{Verdict, classify};
use raypick::check::synthetic::{RayKind, hills, mixed_rays, terrain};
use raypick::io::scene_files::{SceneFile, load_scene};
use raypick::layout::KIND_INNER;
use raypick::{BuildOptions, Builder, BuiltScene, Bvh, CpuPicker, GridShape, Picker, Scene};
use std::path::Path;
use std::sync::Arc;

fn grid_scene(cols: u32, rows: u32, cell: f64, holes: bool) -> Scene {
    let mut mesh = terrain(
        cols as usize,
        rows as usize,
        500_000.0,
        4_100_000.0,
        cell,
        hills,
    );
    if holes {
        // NODATA-style dead quads: zero-area triangles in a ring and a scattered pattern.
        for (k, pair) in mesh.triangles.chunks_mut(2).enumerate() {
            let (r, c) = (k as u32 / (cols - 1), k as u32 % (cols - 1));
            let ring = (r as i64 - 40).pow(2) + (c as i64 - 70).pow(2) < 400;
            if ring || (r * 7 + c * 3) % 11 == 0 {
                let nw = pair[0][0];
                pair.copy_from_slice(&[[nw; 3], [nw; 3]]);
            }
        }
    }
    let mut scene = Scene::new();
    scene
        .add_grid_mesh(
            "terrain",
            mesh,
            GridShape {
                columns: cols,
                rows,
            },
        )
        .expect("grid scene");
    scene
}

fn with(builder: Builder, leaf_size: u32) -> BuildOptions {
    BuildOptions {
        builder,
        leaf_size,
        ..BuildOptions::default()
    }
}

fn jacksboro() -> Scene {
    load_scene(&[SceneFile {
        file: Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/jacksboro_fault_dem_utm.asc"),
        mask: None,
        transform: None,
    }])
    .expect("the Jacksboro DEM loads")
}

/// Leaf-order triangles under `node`.
fn triangles_under(bvh: &Bvh, node: usize) -> Vec<u32> {
    let n = &bvh.nodes[node];
    if n.kind() < KIND_INNER {
        (n.first..n.first + n.kind()).collect()
    } else {
        let mut all = triangles_under(bvh, node + 1);
        all.extend(triangles_under(bvh, n.first as usize));
        all
    }
}

#[test]
fn blocks_partition_the_grid_and_own_their_subtrees() {
    let scene = grid_scene(301, 201, 30.0, true);
    let bvh = Bvh::build(&scene, &with(Builder::Grid, 4)).expect("grid build");
    bvh.validate().expect("valid tree");
    assert!(bvh.blocks.len() >= 12, "{} blocks", bvh.blocks.len());
    let mut covered = vec![false; bvh.triangles.len()];
    for block in &bvh.blocks {
        // Inside one 64 × 64 tile.
        assert_eq!(
            block.rows.start / BLOCK_CELLS,
            (block.rows.end - 1) / BLOCK_CELLS
        );
        assert_eq!(
            block.cols.start / BLOCK_CELLS,
            (block.cols.end - 1) / BLOCK_CELLS
        );
        // Its subtree holds exactly its triangles.
        let under = triangles_under(&bvh, block.node as usize);
        assert_eq!(under, block.triangles.clone().collect::<Vec<_>>());
        for t in block.triangles.clone() {
            assert!(!std::mem::replace(&mut covered[t as usize], true));
            let id = bvh.triangle_ids[t as usize];
            let (row, col) = scene.objects()[0].grid.unwrap().cell_of(id);
            assert!(block.rows.contains(&row) && block.cols.contains(&col));
            for p in scene.world_triangle(id as usize) {
                assert!(p.cmpge(block.min).all() && p.cmple(block.max).all());
            }
        }
        // Its own f64 origin is the centre of its box, which its node's f32 box matches.
        assert_eq!(block.origin, block.min + (block.max - block.min) * 0.5);
        let node = &bvh.nodes[block.node as usize];
        let node_min = bvh.origin + glam::Vec3::from(node.min).as_dvec3();
        assert!((node_min - block.min).abs().max_element() < 0.01);
    }
    assert!(covered.iter().all(|&c| c), "every triangle is in a block");
}

#[test]
fn identical_on_one_and_four_threads() {
    let scene = grid_scene(301, 233, 10.0, true);
    let build = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| Bvh::build(&scene, &with(Builder::Grid, 4)).unwrap())
    };
    let (one, four) = (build(1), build(4));
    assert_eq!(one.nodes, four.nodes);
    assert_eq!(one.triangles, four.triangles);
    assert_eq!(one.triangle_ids, four.triangle_ids);
    assert_eq!(one.blocks, four.blocks);
}

#[test]
fn auto_uses_the_grid_builder_for_one_grid_only() {
    let grid = Bvh::build(&grid_scene(70, 70, 5.0, false), &BuildOptions::default()).unwrap();
    assert_eq!(grid.blocks.len(), 4);
    let example = Bvh::build(
        &raypick::check::synthetic::example_scene(),
        &BuildOptions::default(),
    );
    assert!(example.unwrap().blocks.is_empty());
    let e = Bvh::build(
        &raypick::check::synthetic::example_scene(),
        &with(Builder::Grid, 4),
    )
    .unwrap_err();
    assert!(e.to_string().contains("one height grid"), "{e}");
}

#[test]
fn same_answers_as_median_cut_every_leaf_size() {
    let scene = grid_scene(131, 97, 30.0, true);
    let rays: Vec<_> = mixed_rays(&scene, 3000, 11)
        .into_iter()
        .map(|(_, r)| r)
        .collect();
    for leaf_size in [1, 2, 3, 4, 8, 15] {
        let pick = |builder| {
            let built = BuiltScene::new(scene.clone(), &with(builder, leaf_size)).unwrap();
            built.bvh.validate().unwrap();
            CpuPicker::new(Arc::new(built)).pick(&rays).unwrap()
        };
        let (grid, median) = (pick(Builder::Grid), pick(Builder::MedianCut));
        let mut same = 0;
        for (i, (g, m)) in grid.iter().zip(&median).enumerate() {
            // Two trees may pick different triangles only where the ray meets a shared edge.
            match classify(&scene, &rays[i], g, m) {
                Verdict::Same => same += 1,
                Verdict::SharedEdge => {}
                other => panic!("leaf size {leaf_size}, ray {i}: {other:?}: {g:?} vs {m:?}"),
            }
        }
        assert!(
            same > rays.len() * 9 / 10,
            "leaf size {leaf_size}: {same} same"
        );
    }
}

#[test]
fn gpu_cpu_and_oracle_agree_on_grid_trees() {
    let scene = grid_scene(121, 90, 20.0, true);
    for leaf_size in [1, 4] {
        let built =
            Arc::new(BuiltScene::new(scene.clone(), &with(Builder::Grid, leaf_size)).unwrap());
        let rays = mixed_rays(&built.scene, 3000, 5);
        assert_equivalent(&format!("holey grid, leaf {leaf_size}"), built, &rays);
    }
    let dem = Arc::new(BuiltScene::new(jacksboro(), &BuildOptions::default()).unwrap());
    assert!(!dem.bvh.blocks.is_empty(), "the DEM is built over blocks");
    let rays = mixed_rays(&dem.scene, 1000, 9);
    let hits = assert_equivalent("Jacksboro DEM, blocks", dem, &rays);
    let camera_hits = rays
        .iter()
        .zip(&hits)
        .filter(|((kind, _), h)| *kind == RayKind::Camera && h.hit)
        .count();
    assert!(camera_hits > 30, "{camera_hits} camera rays hit the DEM");
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(48))]

    /// Any grid shape, any pattern of dead (NODATA) cells, any leaf size: the grid builder's
    /// tree is valid, its blocks cover every triangle once, and its answers match median cut's.
    #[test]
    fn any_grid_builds_a_valid_tree_with_median_cut_answers(
        cols in 2u32..150,
        rows in 2u32..150,
        dead_one_in in 1u32..12,
        seed in 0u32..1000,
        leaf_size in 1u32..=15,
    ) {
        let mut mesh = terrain(cols as usize, rows as usize, 1000.0, 2000.0, 3.0, hills);
        for (k, pair) in mesh.triangles.chunks_mut(2).enumerate() {
            if (k as u32).wrapping_mul(2654435761).wrapping_add(seed) % dead_one_in == 0
                && dead_one_in > 1
            {
                let nw = pair[0][0];
                pair.copy_from_slice(&[[nw; 3], [nw; 3]]);
            }
        }
        let mut scene = Scene::new();
        scene.add_grid_mesh("g", mesh, GridShape { columns: cols, rows }).unwrap();
        let grid = Bvh::build(&scene, &with(Builder::Grid, leaf_size)).unwrap();
        grid.validate().map_err(proptest::test_runner::TestCaseError::fail)?;
        let in_blocks: u32 = grid.blocks.iter().map(|b| b.triangles.len() as u32).sum();
        proptest::prop_assert_eq!(in_blocks as usize, grid.triangles.len());
        let rays: Vec<_> = mixed_rays(&scene, 200, u64::from(seed))
            .into_iter()
            .map(|(_, r)| r)
            .collect();
        let pick = |bvh: Bvh| {
            let built = BuiltScene::from_parts(scene.clone(), bvh, Vec::new());
            CpuPicker::new(Arc::new(built)).pick(&rays).unwrap()
        };
        let median = Bvh::build(&scene, &with(Builder::MedianCut, leaf_size)).unwrap();
        let (g, m) = (pick(grid), pick(median));
        for (i, (a, b)) in g.iter().zip(&m).enumerate() {
            let verdict = classify(&scene, &rays[i], a, b);
            proptest::prop_assert!(
                matches!(verdict, Verdict::Same | Verdict::SharedEdge),
                "ray {}: {:?}: {:?} vs {:?}", i, verdict, a, b
            );
        }
    }
}
