//! Triangles a tree's single-precision frame loses: they have area in f64, but rounded to f32
//! offsets from the tree's origin they have none, or their offsets are not finite, and they
//! are small for the frame's step where they lie (their box spans fewer than
//! [`crate::frame::reach::RESOLVED_STEPS`] of them). Every builder leaves them out
//! (`is_traceable`), so no ray can hit them, on any backend. A scene loses them when it is wide
//! for the size of its parts: offsets from the centre of a scene 10⁹ units across are rounded
//! to 32 units, so a one-unit triangle at one end of it collapses. Slivers (long, but flatter
//! than f32 resolves wherever they lie) and triangles of objects with layer mask 0 (never hit)
//! are not counted. The command line warns about lost triangles; the server refuses an edit
//! that would lose more. The triangles with no area in f64 that the tree leaves out are
//! counted beside them, for the command line's warning.

use super::Bvh;
use crate::frame::reach::{Unresolved, f32_step};
use crate::scene::{Scene, box_of};
use rayon::prelude::*;

/// What a tree loses of its scene (see the module docs), and the triangles with no area it
/// leaves out besides.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Lost {
    /// Triangles with area in f64 that the frame loses (see the module docs).
    pub triangles: usize,
    /// The first of them, as `(object id, triangle id within the object)`.
    pub first: Option<(u32, u32)>,
    /// Triangles of objects that can be hit with no area in f64 (corners on one line, a corner
    /// repeated: faces a file may hold), which no ray hits either: not the frame's doing, but
    /// the command line says so too.
    pub degenerate: usize,
    /// The first of them, as `first`.
    pub first_degenerate: Option<(u32, u32)>,
}

impl Lost {
    /// A sentence naming how many triangles have no area and the first, each object named as
    /// `object` does; empty when none has.
    pub fn describe_degenerate(&self, object: impl Fn(u32) -> String) -> String {
        match (self.degenerate, self.first_degenerate) {
            (0, _) | (_, None) => String::new(),
            (n, Some((o, triangle))) => format!(
                "{n} triangle(s) have no area (their corners on one line; the first: {}'s \
                 triangle {triangle}), so they can never be hit",
                object(o)
            ),
        }
    }

    /// A sentence naming how many triangles are lost and the first, for a message; empty when
    /// none is.
    pub fn describe(&self) -> String {
        let first = self.first.map_or(String::new(), |(object, triangle)| {
            format!(" (the first: object {object}'s triangle {triangle})")
        });
        match self.triangles {
            0 => String::new(),
            n => format!(
                "{n} triangle(s) with area{first} have none once rounded into the scene's \
                 single-precision frame, so they can never be hit"
            ),
        }
    }
}

/// The triangles of `scene` that `bvh`'s frame loses (built over `scene`; see the module). Costs
/// nothing when the tree holds every triangle; otherwise one pass over the scene's triangles.
pub fn lost_triangles(scene: &Scene, bvh: &Bvh) -> Lost {
    let n = scene.triangle_count();
    if bvh.triangle_ids.len() >= n {
        return Lost::default();
    }
    let mut held = vec![false; n];
    for &id in bvh.triangle_ids.iter() {
        if let Some(h) = held.get_mut(id as usize) {
            *h = true;
        }
    }
    // Each triangle left out, of an object that can be hit: lost (true) or with no area (false).
    let left_out = |i: usize| -> Option<bool> {
        let (object, _) = scene.locate(i as u32);
        if held[i] || scene.objects()[object as usize].mask == 0 {
            return None;
        }
        if scene.is_degenerate(i) {
            // A height grid's NODATA cell (its triangles one corner thrice, `dem::mesh`) is no
            // fault of the file's: not counted.
            let [a, b, c] = scene.triangle_vertices(i);
            let grid = scene.objects()[object as usize].grid.is_some();
            return (!(grid && a == b && b == c)).then_some(false);
        }
        // Collapsed by the frame: its box spans few of the frame's steps where it lies (a
        // sliver, long but flat, collapses wherever it lies: not the frame's doing).
        let b = box_of(scene.world_triangle(i));
        Unresolved::of(0, b, bvh.origin, f32_step).map(|_| true)
    };
    let kinds: Vec<(u32, bool)> = (0..n)
        .into_par_iter()
        .filter_map(|i| left_out(i).map(|lost| (i as u32, lost)))
        .collect();
    let first = |lost: bool| {
        kinds
            .iter()
            .find(|k| k.1 == lost)
            .map(|k| scene.locate(k.0))
    };
    let lost = kinds.iter().filter(|k| k.1).count();
    Lost {
        triangles: lost,
        first: first(true),
        degenerate: kinds.len() - lost,
        first_degenerate: first(false),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::BuildOptions;
    use crate::scene::Mesh;
    use glam::DVec3;

    /// A height grid's NODATA cells are not counted as triangles with no area (every DEM with
    /// NODATA was warned about so, as if the file held broken faces).
    #[test]
    fn nodata_cells_are_not_triangles_with_no_area() {
        let grid = crate::dem::ElevationGrid {
            ncols: 3,
            nrows: 3,
            x0: 0.0,
            y0: 2.0,
            dx: 1.0,
            dy: 1.0,
            heights: vec![
                Some(1.0),
                Some(2.0),
                Some(1.0),
                Some(0.5),
                None,
                Some(1.5),
                Some(1.0),
                Some(2.0),
                Some(3.0),
            ],
        };
        let mut scene = Scene::new();
        scene
            .add_grid_mesh(
                "dem",
                crate::dem::grid_to_mesh(&grid),
                crate::scene::GridShape {
                    columns: 3,
                    rows: 3,
                },
            )
            .unwrap();
        let bvh = Bvh::build(&scene, &BuildOptions::default()).unwrap();
        assert!(
            bvh.triangle_ids.len() < scene.triangle_count(),
            "NODATA cells left out"
        );
        assert_eq!(lost_triangles(&scene, &bvh), Lost::default());
    }

    /// A unit triangle at the origin, a degenerate one, and a unit triangle at `far` on x.
    fn scene(far: f64) -> Scene {
        let mut scene = Scene::new();
        let at = |x: f64| {
            vec![
                DVec3::new(x, 0.0, 0.0),
                DVec3::new(x + 1.0, 0.0, 0.0),
                DVec3::new(x, 1.0, 0.0),
            ]
        };
        let mut positions = at(0.0);
        positions.extend(at(far));
        positions.push(DVec3::new(2.0, 0.0, 0.0));
        scene
            .add_mesh(
                "m",
                Mesh {
                    positions,
                    triangles: vec![[0, 1, 2], [0, 1, 6], [3, 4, 5]],
                },
            )
            .unwrap();
        scene
    }

    fn lost(far: f64) -> Lost {
        let scene = scene(far);
        let bvh = Bvh::build(&scene, &BuildOptions::default()).unwrap();
        lost_triangles(&scene, &bvh)
    }

    /// A sliver (area in f64, none in f32 even in a frame of its own) is not lost: it was
    /// never the frame's doing.
    #[test]
    fn slivers_are_not_lost() {
        let mut scene = Scene::new();
        let positions = vec![
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(0.5, 1e-12, 0.0),
            DVec3::new(0.0, 1.0, 0.0),
        ];
        let triangles = vec![[0, 1, 2], [0, 1, 3]];
        scene
            .add_mesh(
                "m",
                Mesh {
                    positions,
                    triangles,
                },
            )
            .unwrap();
        let bvh = Bvh::build(&scene, &BuildOptions::default()).unwrap();
        assert_eq!(bvh.triangle_ids.len(), 1, "the sliver is left out");
        assert_eq!(lost_triangles(&scene, &bvh), Lost::default());
    }

    /// Nearby, only the degenerate triangle is left out, and it is not lost (it has no area in
    /// f64 either). At 10⁹ the triangle at the origin collapses (offsets from the centre are
    /// rounded to 32 units there; the far one, 10⁹ + 1, too); at 10³⁰⁰ the triangle at the
    /// origin's offsets overflow f32 (the far one has no area in f64 there: 10³⁰⁰ + 1 is 10³⁰⁰).
    #[test]
    fn a_scene_too_wide_for_its_frame_loses_its_small_triangles() {
        // Triangle 1 has its corners on one line: no area in f64 either.
        let degenerate = Lost {
            degenerate: 1,
            first_degenerate: Some((0, 1)),
            ..Lost::default()
        };
        assert_eq!(lost(10.0), degenerate);
        assert_eq!(
            lost(1e9),
            Lost {
                triangles: 2,
                first: Some((0, 0)),
                ..degenerate
            }
        );
        // At 10³⁰⁰ the far triangle has no area in f64 either.
        assert_eq!(
            lost(1e300),
            Lost {
                triangles: 1,
                first: Some((0, 0)),
                degenerate: 2,
                ..degenerate
            }
        );
        assert_eq!(
            degenerate.describe_degenerate(|o| format!("object {o}")),
            "1 triangle(s) have no area (their corners on one line; the first: object 0's \
             triangle 1), so they can never be hit"
        );
        assert!(
            lost(1e9)
                .describe()
                .starts_with("2 triangle(s) with area (the first: object 0's triangle 0)")
        );
        assert_eq!(lost(10.0).describe(), "");
    }

    /// An object moved past f32's range from the frame's origin cannot be refitted in place
    /// (its offsets would be infinite): the scene is built again, re-centred, and what the new
    /// frame loses (here both triangles: each lies past f32's range from the new centre) is
    /// counted. Moved back, the scene loses nothing again.
    #[test]
    fn a_move_past_f32s_range_builds_again() {
        use crate::picker::{BuiltScene, Refit};
        let triangle = |x: f64, size: f64| Mesh {
            positions: vec![
                DVec3::new(x, 0.0, 0.0),
                DVec3::new(x + size, 0.0, 0.0),
                DVec3::new(x, size, 0.0),
            ],
            triangles: vec![[0, 1, 2]],
        };
        let mut scene = Scene::new();
        scene.add_mesh("near", triangle(0.0, 1.0)).unwrap();
        scene.add_mesh("moved", triangle(10.0, 1.0)).unwrap();
        let mut built = BuiltScene::new(scene, &BuildOptions::default()).unwrap();
        assert_eq!(built.lost_triangles(), Lost::default());
        let far = triangle(1e39, 1e25).positions;
        assert_eq!(built.set_positions(1, &far).unwrap(), Refit::Rebuilt);
        assert_eq!(built.lost_triangles().triangles, 2);
        let near = triangle(10.0, 1.0).positions;
        assert_eq!(built.set_positions(1, &near).unwrap(), Refit::Rebuilt);
        assert_eq!(built.lost_triangles(), Lost::default());
    }

    /// An object with layer mask 0 is never traced, so none of its triangles is counted lost
    /// or without area (the warnings would speak of triangles no ray is meant to hit), whether
    /// the frame keeps them or not.
    #[test]
    fn a_hidden_object_s_triangles_are_neither_lost_nor_degenerate() {
        for far in [10.0, 1e9] {
            let mut scene = scene(far);
            scene.set_object_mask(0, 0).unwrap();
            let bvh = Bvh::build(&scene, &BuildOptions::default()).unwrap();
            assert_eq!(lost_triangles(&scene, &bvh), Lost::default(), "{far}");
        }
    }
}
