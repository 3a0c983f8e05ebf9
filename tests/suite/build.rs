//! The median-cut builder: deterministic whatever the thread count, and its trees keep their
//! invariants (checked by `Bvh::validate`) on arbitrary triangle sets.

use glam::DVec3;
use proptest::prelude::*;
use raypick::check::synthetic::{hills, terrain, triangle_soup};
use raypick::{BuildOptions, Builder, Bvh, Mesh, Scene, SplitAxis};

fn scene(mesh: Mesh) -> Scene {
    Scene::from_meshes([("m".to_string(), mesh)]).unwrap()
}

#[test]
fn output_is_identical_on_one_and_many_threads() {
    // Large enough to take the parallel path.
    let s = scene(terrain(130, 130, 0.0, 0.0, 1.0, hills));
    let build_on = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| Bvh::build(&s, &BuildOptions::default()).unwrap())
    };
    let (one, four) = (build_on(1), build_on(4));
    assert_eq!(one.nodes, four.nodes);
    assert_eq!(one.triangle_ids, four.triangle_ids);
    one.validate().unwrap();
}

#[test]
fn paper_defaults_work_leaf_size_one_and_cycling_axes() {
    let s = scene(triangle_soup(5000, 10.0, 5));
    let bvh = Bvh::build(
        &s,
        &BuildOptions {
            split_axis: SplitAxis::Cycle,
            leaf_size: 1,
            ..Default::default()
        },
    )
    .unwrap();
    bvh.validate().unwrap();
    assert_eq!(bvh.leaf_count(), 5000);
    assert_eq!(bvh.nodes.len(), 2 * 5000 - 1);
}

#[test]
fn leaf_size_out_of_range_is_an_error() {
    let s = scene(triangle_soup(10, 1.0, 1));
    for leaf_size in [0, 16] {
        let e = Bvh::build(
            &s,
            &BuildOptions {
                leaf_size,
                ..Default::default()
            },
        )
        .unwrap_err();
        assert!(e.to_string().contains("leaf size"), "{e}");
    }
}

#[test]
fn identical_centroids_fall_back_to_the_median() {
    // 100 copies of one triangle: the midplane puts all on one side every time, and no SAH
    // plane separates them either.
    let mut mesh = Mesh::default();
    for i in 0..100u32 {
        mesh.positions.extend([DVec3::ZERO, DVec3::X, DVec3::Y]);
        mesh.triangles.push([3 * i, 3 * i + 1, 3 * i + 2]);
    }
    let scene = scene(mesh);
    for builder in [Builder::MedianCut, Builder::BinnedSah] {
        let options = BuildOptions {
            builder,
            ..BuildOptions::default()
        };
        let bvh = Bvh::build(&scene, &options).unwrap();
        bvh.validate().unwrap();
        assert!(
            bvh.depth() <= 8,
            "{builder:?}: median fallback keeps the tree balanced: depth {}",
            bvh.depth()
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    #[test]
    fn trees_keep_their_invariants(
        points in prop::collection::vec((-1e3f64..1e3, -1e3f64..1e3, -1e3f64..1e3), 3..600),
        leaf_size in 1u32..=15,
        cycle in any::<bool>(),
    ) {
        let positions: Vec<DVec3> = points.iter().map(|&(x, y, z)| DVec3::new(x, y, z)).collect();
        let triangles = (0..positions.len() as u32 / 3).map(|i| [3 * i, 3 * i + 1, 3 * i + 2]).collect();
        let s = scene(Mesh { positions, triangles });
        let options = BuildOptions { split_axis: if cycle { SplitAxis::Cycle } else { SplitAxis::Longest }, leaf_size, ..Default::default() };
        let bvh = Bvh::build(&s, &options).unwrap();
        prop_assert_eq!(bvh.validate(), Ok(()));
        let hittable = (0..s.triangle_count()).filter(|&i| !s.is_degenerate(i)).count();
        prop_assert!(bvh.triangles.len() <= hittable);
        // Traversal terminates within its bound for every ray.
        let rays = raypick::check::synthetic::rays(&s, raypick::check::synthetic::RayKind::Random, 64, 1);
        let local = raypick::frame::local_rays(raypick::frame::Frame::at(bvh.origin), &rays);
        for hit in raypick::cpu::trace_all(&bvh, &local) {
            prop_assert!(hit.prim != raypick::layout::CAP_REACHED);
            prop_assert!(hit.box_tests <= bvh.nodes.len() as u32);
        }
    }
}

/// With cycling axes every inner node splits on its depth's axis (x, y, z, x, …), in the
/// parallel builder's top levels (a scene past its 8,192-triangle threshold) as in the
/// sequential levels below them, on both sides of each split.
#[test]
fn cycling_axes_follow_the_depth_on_the_parallel_path_too() {
    let s = scene(terrain(130, 130, 0.0, 0.0, 1.0, hills));
    let bvh = Bvh::build(
        &s,
        &BuildOptions {
            split_axis: SplitAxis::Cycle,
            ..Default::default()
        },
    )
    .unwrap();
    let mut pending = vec![(0usize, 0u32)];
    let mut inner = 0;
    while let Some((i, depth)) = pending.pop() {
        let node = &bvh.nodes[i];
        if node.is_leaf() {
            continue;
        }
        inner += 1;
        assert_eq!(
            node.kind() - raypick::layout::KIND_INNER,
            depth % 3,
            "node {i} at depth {depth}"
        );
        pending.extend([(i + 1, depth + 1), (node.first as usize, depth + 1)]);
    }
    assert!(inner > 8192 / 8, "{inner} inner nodes");
}

/// `Bvh::validate` refuses a tree that breaks one of its invariants, saying which: a triangle
/// that pokes out of its leaf's box past the box's high corner or its low one, and a triangle
/// that no leaf holds.
#[test]
fn validate_names_a_triangle_outside_its_leaf_box_or_in_no_leaf() {
    let bvh = Bvh::build(
        &scene(triangle_soup(200, 10.0, 3)),
        &BuildOptions::default(),
    )
    .unwrap();
    bvh.validate().unwrap();
    let leaf = bvh.nodes.iter().position(|n| n.is_leaf()).unwrap();
    let (node, t) = (bvh.nodes[leaf], bvh.nodes[leaf].first as usize);
    for (corner, x) in [("high", node.max[0] + 1.0), ("low", node.min[0] - 1.0)] {
        let mut broken = bvh.clone();
        broken.triangles.to_mut()[t].v0[0] = x;
        assert_eq!(
            broken.validate(),
            Err(format!("triangle {t} pokes out of leaf {leaf}'s box")),
            "past the {corner} corner"
        );
    }
    let mut broken = bvh.clone();
    let extra = broken.triangles[t];
    broken.triangles.to_mut().push(extra);
    broken.triangle_ids.to_mut().push(0);
    let last = broken.triangles.len() - 1;
    assert_eq!(
        broken.validate(),
        Err(format!("triangle {last} is in no leaf"))
    );
}
