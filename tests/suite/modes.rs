//! Every query mode and option agrees on GPU, CPU and brute force: closest, any and all hits;
//! back- and front-face culling; layer masks; the watertight intersector.

use crate::common;

use common::assert_query_equivalent;
use raypick::check::synthetic::{example_scene, hills, mixed_rays, terrain, triangle_soup};
use raypick::io::obj::load_obj;
use raypick::{BuildOptions, BuiltScene, Cull, Intersector, Mode, Query, Scene};
use std::path::Path;
use std::sync::Arc;

fn scenes() -> Vec<(&'static str, Scene)> {
    let one = |name: &str, mesh| Scene::from_meshes([(name.to_string(), mesh)]).unwrap();
    let bunny =
        load_obj(&Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/bunny.obj")).unwrap();
    vec![
        ("soup", one("soup", triangle_soup(1500, 10.0, 2))),
        (
            "terrain",
            one("terrain", terrain(30, 30, 0.0, 29.0, 1.0, hills)),
        ),
        ("bunny", one("bunny", bunny)),
        ("example", example_scene()),
    ]
}

fn check_all_scenes(query: Query) {
    for (name, scene) in scenes() {
        let built = Arc::new(BuiltScene::new(scene, &BuildOptions::default()).unwrap());
        let rays = mixed_rays(&built.scene, 1600, 11);
        assert_query_equivalent(name, built, &rays, &query);
    }
}

#[test]
fn closest_with_back_face_culling() {
    check_all_scenes(Query {
        cull: Cull::Back,
        ..Query::default()
    });
}

#[test]
fn closest_with_front_face_culling() {
    check_all_scenes(Query {
        cull: Cull::Front,
        ..Query::default()
    });
}

#[test]
fn any_hit() {
    check_all_scenes(Query {
        mode: Mode::Any,
        ..Query::default()
    });
}

#[test]
fn all_hits_with_room_to_spare() {
    check_all_scenes(Query {
        mode: Mode::All,
        max_hits: 64,
        ..Query::default()
    });
}

#[test]
fn all_hits_overflowing() {
    let answers = {
        let built =
            Arc::new(BuiltScene::new(scenes().remove(0).1, &BuildOptions::default()).unwrap());
        let rays = mixed_rays(&built.scene, 1600, 11);
        assert_query_equivalent(
            "soup",
            built,
            &rays,
            &Query {
                mode: Mode::All,
                max_hits: 2,
                ..Query::default()
            },
        )
    };
    assert!(
        answers.overflow.iter().any(|&o| o),
        "some rays have more than 2 hits"
    );
    check_all_scenes(Query {
        mode: Mode::All,
        max_hits: 3,
        cull: Cull::Back,
        ..Query::default()
    });
}

#[test]
fn watertight_intersector() {
    check_all_scenes(Query {
        intersector: Intersector::Watertight,
        ..Query::default()
    });
    check_all_scenes(Query {
        intersector: Intersector::Watertight,
        mode: Mode::All,
        max_hits: 8,
        cull: Cull::Front,
    });
}

#[test]
fn layer_masks_select_objects() {
    let mut scene = example_scene();
    scene.set_object_mask(0, 0b001).unwrap(); // terrain
    scene.set_object_mask(1, 0b010).unwrap(); // tower
    scene.set_object_mask(2, 0b110).unwrap(); // hall
    let built = Arc::new(BuiltScene::new(scene, &BuildOptions::default()).unwrap());
    for (mask, allowed) in [
        (0b010u32, vec![1, 2]),
        (0b100, vec![2]),
        (0b001, vec![0]),
        (0, vec![]),
    ] {
        let rays: Vec<_> = mixed_rays(&built.scene, 1600, 5)
            .into_iter()
            .map(|(k, r)| (k, r.with_mask(mask)))
            .collect();
        for query in [
            Query::default(),
            Query {
                mode: Mode::All,
                max_hits: 16,
                ..Query::default()
            },
            // Any-hit walks test the masks where they end early.
            Query {
                mode: Mode::Any,
                ..Query::default()
            },
        ] {
            let answers = assert_query_equivalent("masked", built.clone(), &rays, &query);
            let hits: Vec<_> = (0..rays.len())
                .flat_map(|i| answers.hits_of(i).to_vec())
                .collect();
            assert!(
                hits.iter().all(|h| allowed.contains(&h.object)),
                "mask {mask:#b} hit a filtered object"
            );
            assert_eq!(hits.is_empty(), allowed.is_empty(), "mask {mask:#b}");
        }
    }
}

/// `query_into` reusing one `Answers` batch after batch (larger and smaller batches, every
/// mode in turn) answers exactly what a fresh `query` does, on every CPU picker.
#[test]
fn query_into_reuses_answers_across_batches_and_modes() {
    use raypick::Backend;
    let scene = scenes().swap_remove(2).1;
    let built = Arc::new(BuiltScene::new(scene, &BuildOptions::default()).unwrap());
    let rays: Vec<_> = mixed_rays(&built.scene, 3000, 5)
        .into_iter()
        .map(|(_, ray)| ray)
        .collect();
    let queries = [
        Query::default(),
        Query {
            mode: Mode::All,
            max_hits: 3,
            ..Query::default()
        },
        Query {
            mode: Mode::Any,
            ..Query::default()
        },
        Query {
            cull: Cull::Back,
            intersector: Intersector::MollerTrumbore,
            ..Query::default()
        },
    ];
    let batches = [0..3000, 10..700, 700..701, 1000..2900, 5..5];
    for backend in [Backend::Cpu, Backend::Reference] {
        let mut picker = raypick::make_picker(backend, built.clone()).unwrap();
        let mut fresh = raypick::make_picker(backend, built.clone()).unwrap();
        let mut reused = raypick::Answers::default();
        for (k, batch) in batches.iter().cycle().take(12).enumerate() {
            let query = &queries[k % queries.len()];
            let rays = &rays[batch.clone()];
            picker.query_into(rays, query, &mut reused).unwrap();
            let expected = fresh.query(rays, query).unwrap();
            assert_eq!(
                format!("{reused:?}"),
                format!("{expected:?}"),
                "{backend:?}, batch {batch:?}, {query:?}"
            );
        }
    }
}

/// Coplanar duplicates (two squares and a triangle, one copy wound the other way) seen from far
/// off: their hits' refined f64 `t` are equal while the walk's f32 `t` differ by a rounding, so
/// the lists sorted again by the f64 `t` put another triangle first than the closest-mode
/// answer and the list's own `nearest` (found by a helper's fuzzing). An all-hits list is in the
/// walk's order, the same on every backend: its first hit is the closest-mode answer.
#[test]
fn an_all_hits_lists_first_hit_is_the_closest_mode_answer() {
    use rand::Rng;
    use raypick::{CpuPicker, GpuPicker, Picker, Ray, ReferencePicker};
    let corners = [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]];
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    for copy in 0..3u32 {
        positions.extend(corners.map(|[x, y]| glam::DVec3::new(x, y, 0.0)));
        let b = 4 * copy;
        triangles.extend([[b, b + 1, b + 2], [b, b + 2, b + 3]]);
    }
    // The second triangle of the square again, wound the other way.
    triangles.push([0, 3, 2]);
    let scene = Scene::from_meshes([(
        "coplanar".to_string(),
        raypick::Mesh {
            positions,
            triangles,
        },
    )])
    .unwrap();
    let built = Arc::new(BuiltScene::new(scene, &BuildOptions::default()).unwrap());
    let mut g = raypick::check::synthetic::rng(108);
    let rays: Vec<Ray> = (0..2000)
        .map(|_| {
            let at = glam::DVec3::new(g.random_range(0.5..9.5), g.random_range(0.5..9.5), 0.0);
            let from = glam::DVec3::new(
                g.random_range(-1.0..1.0),
                g.random_range(-1.0..1.0),
                g.random_range(0.2..1.0),
            )
            .normalize()
                * g.random_range(1.0..1e7);
            Ray::new(at + from, -from)
        })
        .collect();
    let closest = Query::default();
    let all = Query {
        mode: Mode::All,
        max_hits: 8,
        ..Query::default()
    };
    let mut pickers: Vec<Box<dyn Picker>> = vec![
        Box::new(CpuPicker::new(built.clone())),
        Box::new(ReferencePicker::new(built.clone())),
        Box::new(GpuPicker::new(common::gpu(), built.clone()).unwrap()),
    ];
    let mut swapped = 0;
    for picker in &mut pickers {
        let near = picker.query(&rays, &closest).unwrap();
        let lists = picker.query(&rays, &all).unwrap();
        for (i, h) in near.nearest.iter().enumerate() {
            let list = lists.hits_of(i);
            assert!(h.hit && !list.is_empty(), "ray {i}");
            let key = |h: &raypick::Hit| (h.object, h.triangle, h.t.to_bits());
            assert_eq!(
                key(&list[0]),
                key(h),
                "ray {i}: the list's first against closest"
            );
            assert_eq!(
                key(&lists.nearest[i]),
                key(h),
                "ray {i}: the list's nearest"
            );
            swapped +=
                usize::from(list.windows(2).any(|w| {
                    w[1].t < w[0].t || (w[1].t == w[0].t && w[1].triangle < w[0].triangle)
                }));
        }
    }
    assert!(
        swapped > 0,
        "no ray's f32 order differs from its f64 order: the test tests nothing"
    );
}
