//! How finely a scene frame resolves what lies far from its origin. Triangles and rays are f32
//! offsets from the frame's origin (the centre of the scene's bounds), so at `reach` units from
//! it positions are rounded to the spacing of f32 values there ([`f32_step`]): 2⁻²⁴ of the
//! reach, 32 units at 5 × 10⁸. An instanced scene's rays carry a half-float rest as well (11
//! more bits: [`ray_step`]); its meshes lie in frames of their own.
//!
//! An object placed far from the rest (in other coordinates, say) widens the scene and
//! re-centres the frame, which leaves the others that far from its centre: their triangles
//! rounded out of shape (or out of f32's range), and every pick on them off. A part counts as
//! resolved where its box spans at least [`RESOLVED_STEPS`] steps of its place in the frame;
//! the command line warns about parts left unresolved, the server refuses edits that leave
//! more unresolved ([`unresolved_objects`]), and an
//! instanced scene refuses to place an instance so (`Instances::add`, `set_transform`).
//!
//! An object can be resolved as a whole while its triangles are not: a height grid with one
//! undeclared NODATA spike of 10¹⁰ is 10¹⁰ units tall, so its frame's centre lies 5 × 10⁹ from
//! the ground, where positions round to 512 units, and its 10-unit cells are rounded out of
//! shape. [`unresolved_triangles`] counts such triangles, for the command line's warning.

use crate::scene::{Scene, box_of, scaled_length, zero_area};
use glam::DVec3;
use rayon::prelude::*;

/// The least number of steps ([`f32_step`], [`ray_step`]) a part's box must span where it lies.
pub const RESOLVED_STEPS: f64 = 16.0;

/// The spacing of f32 values `reach` units from zero: what a frame rounds offsets that far out
/// to. Infinite past f32's range.
pub fn f32_step(reach: f64) -> f64 {
    let x = reach.abs() as f32;
    if x >= f32::MAX {
        return f64::INFINITY;
    }
    f64::from(x.next_up() - x)
}

/// The spacing of f64 values `reach` units from zero: what world positions that far from the
/// world's origin are rounded to, before any frame (2 units at 10¹⁶). Infinite past f64's range.
pub fn f64_step(reach: f64) -> f64 {
    let x = reach.abs();
    if x.is_finite() {
        x.next_up() - x
    } else {
        f64::INFINITY
    }
}

/// A part with the box `b` when positions are rounded, where it lies from `origin`, to steps
/// `step(reach)` of which half is more than picks are held to (`raypick verify`'s tolerance,
/// [`crate::check::compare::RELATIVE_TOLERANCE`] of its size, at least of one unit): with
/// [`f64_step`] about the world's origin, world f64 itself rounds its positions when it is
/// loaded or placed, and no frame gives them back (a bunny listed twice 10¹³ out: 66 mismatches
/// of 3,000 rays); with [`ray_step`] about an instanced scene's frame origin, a ray enters the
/// instance off by up to half a step, which puts hits near an edge on the neighbouring triangle
/// (two bunnies 5 × 10⁷ apart: 3 rays of 2,000; 10⁹: 9; a 1.6 cm bunny 10⁷ from another: 78;
/// 10⁶ apart, and the dragon 10⁶ from another: none).
pub fn coarser_than_picks(
    part: u32,
    b: (DVec3, DVec3),
    origin: DVec3,
    step: fn(f64) -> f64,
) -> Option<Unresolved> {
    let reach = reach_of(b, origin);
    let (step, size) = (step(reach), scaled_length(b.1 - b.0));
    let tolerance = crate::check::compare::RELATIVE_TOLERANCE * size.max(1.0);
    (step / 2.0 > tolerance).then_some(Unresolved {
        part,
        reach,
        step,
        size,
    })
}

/// How finely an instanced scene places rays `reach` units from its frame's origin: f32
/// offsets refined by a half-float rest (`frame::put_origin_lo`: 11 more bits, and no finer
/// than the subnormal half floats' 2^-24).
pub fn ray_step(reach: f64) -> f64 {
    (f32_step(reach) / 2048.0).max(2f64.powi(-24))
}

/// The widest reach from a frame's centre at which the single-precision triangle tests keep
/// their products finite. The watertight test's `t · det` grows as the cube of the distances
/// in the frame (a triangle's size squared, times the distance along the ray, up to 17 reaches
/// before the origin is moved in): a tetrahedron 10¹³ units across (a reach of 5 × 10¹²) gave
/// `raypick verify` 2,709 mismatches of 4,000 rays, every one a miss of a hit; 3 × 10¹² gave
/// none. Frames of wider reach are warned about ([`scale_fault`]).
pub const WIDEST_REACH: f64 = 1e12;

/// The narrowest reach at which those products stay clear of f32's subnormals: 10⁻¹⁴ across
/// gave 30 mismatches of 4,000 rays, 10⁻¹³ none.
pub const NARROWEST_REACH: f64 = 1e-12;

/// A sentence when a frame reaching `reach` units from its centre is too wide or too narrow
/// for the single-precision tests ([`WIDEST_REACH`], [`NARROWEST_REACH`]); `None` otherwise
/// (and for a frame of no size).
pub fn scale_fault(reach: f64) -> Option<String> {
    if reach > WIDEST_REACH {
        Some(format!(
            "the scene reaches {} from its centre: past {WIDEST_REACH:.0e}, the single-precision \
             triangle tests overflow and miss hits (measure it in larger units: kilometres, not \
             metres)",
            units(reach)
        ))
    } else if reach > 0.0 && reach < NARROWEST_REACH {
        Some(format!(
            "the scene reaches only {} from its centre: under {NARROWEST_REACH:.0e}, the \
             single-precision triangle tests lose their products to underflow and miss hits \
             (measure it in smaller units)",
            units(reach)
        ))
    } else {
        None
    }
}

/// How far the box `(lo, hi)` reaches from `origin`: its farthest corner's largest offset.
pub fn reach_of((lo, hi): (DVec3, DVec3), origin: DVec3) -> f64 {
    (lo - origin).abs().max((hi - origin).abs()).max_element()
}

/// Whether a frame at `origin` still suits a scene now bounded by `bounds`: it reaches the box
/// at most 16 times as far as a frame at the box's centre would (four bits of the f32 offsets'
/// precision: a scene turned about a far axis, or a lone object moved a few of its own widths,
/// stays within it). A refit keeps its tree's origin; an object moved far out and back left the
/// frame centred between the two, its steps 32 units wide at the scene, and lost every triangle
/// there.
pub fn frame_suits(bounds: Option<(DVec3, DVec3)>, origin: DVec3) -> bool {
    let Some((lo, hi)) = bounds else {
        return true;
    };
    let centred = ((hi - lo) * 0.5).max_element();
    reach_of((lo, hi), origin) <= 16.0 * centred
}

/// A distance for a message: `1.000e12 units`; one past f64's range (the difference of
/// vertices near ±1.8e308) read "inf units".
pub fn units(distance: f64) -> String {
    if distance.is_finite() {
        format!("{distance:.3e} units")
    } else {
        "more than 1.8e308 units (past f64's range)".into()
    }
}

/// A part that its frame does not resolve: where it lies, the step there and its size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Unresolved {
    /// The part (an object id, or an instance).
    pub part: u32,
    /// How far its box reaches from the frame's origin.
    pub reach: f64,
    /// The frame's step there.
    pub step: f64,
    /// Its box's diagonal.
    pub size: f64,
}

impl Unresolved {
    /// `(lo, hi)` measured in a frame centred on `origin` with steps `step(reach)`: `None`
    /// where it spans [`RESOLVED_STEPS`] of them.
    pub fn of(
        part: u32,
        (lo, hi): (DVec3, DVec3),
        origin: DVec3,
        step: fn(f64) -> f64,
    ) -> Option<Self> {
        let reach = reach_of((lo, hi), origin);
        let (size, step) = (scaled_length(hi - lo), step(reach));
        // Past f32's range nothing is resolved, however large (a box 10²⁰⁰ across, whose
        // diagonal is as infinite as the step there, was counted as resolved).
        // A part of no size (every vertex at one point: a glTF node scaled by 0) has nothing to
        // resolve.
        let unresolved = size > 0.0 && (size < RESOLVED_STEPS * step || step.is_infinite());
        unresolved.then_some(Unresolved {
            part,
            reach,
            step,
            size,
        })
    }

    /// The sentence for a message: where the part lies, the step there and its size, and a
    /// question about the likely cause (parts in other coordinates).
    pub fn describe(&self, what: &str) -> String {
        self.describe_asking(what, "are some objects in other coordinates?")
    }

    /// The sentence for a part world f64 rounds too coarsely ([`coarser_than_picks`] with
    /// [`f64_step`]).
    pub fn describe_in_world(&self, what: &str) -> String {
        format!(
            "{what} lies {} from the world's origin, where double precision rounds positions to \
             {:.1e} units: more than a hundred-thousandth of its {:.3e} units, so its triangles \
             are rounded out of shape and picks on it are off (give its coordinates in a frame \
             nearer the origin)",
            units(self.reach),
            self.step,
            self.size
        )
    }

    /// The sentence for an instance whose rays are placed more coarsely than picks are held to
    /// ([`coarser_than_picks`] with [`ray_step`]), `others` more after it.
    pub fn describe_coarse(&self, others: usize) -> String {
        let more = match others {
            0 => String::new(),
            1 => "; so does 1 more instance".to_owned(),
            n => format!("; so do {n} more instances"),
        };
        format!(
            "instance {} lies {} from the centre of the scene, where its rays are placed to \
             {:.1e} units: more than a hundred-thousandth of its {:.3e} units, so hits near its \
             triangles' edges may name a neighbouring triangle{more} (are some instances in \
             other coordinates?)",
            self.part,
            units(self.reach),
            self.step,
            self.size
        )
    }

    /// [`Unresolved::describe`] with the question `question` at its end.
    pub fn describe_asking(&self, what: &str, question: &str) -> String {
        let rounds = if self.step.is_finite() {
            format!("rounds positions to {:.1e} units", self.step)
        } else {
            "cannot hold positions at all".into()
        };
        let reach = units(self.reach);
        let size = if self.size.is_finite() {
            format!("its {:.3e} units", self.size)
        } else {
            "a size past f64's range".into()
        };
        format!(
            "{what} lies {reach} from the centre of the scene, where its \
             single-precision frame {rounds}: too coarse for {size} ({question})"
        )
    }
}

/// The objects of `scene` with triangles that its f32 frame, centred on `origin`, does not
/// resolve ([`Unresolved::of`] with [`f32_step`]), in id order; objects with layer mask 0 (never
/// hit: removed) are not counted. One pass over the vertices.
pub fn unresolved_objects(scene: &Scene, origin: DVec3) -> Vec<Unresolved> {
    unresolved_among(&object_boxes(scene), origin, f32_step)
}

/// The boxes of the objects of `scene` that [`unresolved_objects`] looks at (with triangles,
/// layer mask not 0), with their ids, in id order. One pass over the vertices.
pub fn object_boxes(scene: &Scene) -> Vec<(u32, (DVec3, DVec3))> {
    scene
        .objects()
        .par_iter()
        .filter_map(|o| Some((o.id, object_box(scene, o.id)?)))
        .collect()
}

/// Object `id`'s box, as [`object_boxes`] lists it: `None` for an unknown id or an object with
/// nothing to hit (no triangles, layer mask 0). One pass over its vertices.
pub fn object_box(scene: &Scene, id: u32) -> Option<(DVec3, DVec3)> {
    let o = scene.objects().get(id as usize)?;
    (o.triangle_count > 0 && o.mask != 0)
        .then(|| box_of(scene.object_vertices(o.id).map(|v| scene.position(v))))
}

/// Of `boxes` ([`object_boxes`], `Instances::hittable_boxes`), those not resolved in a frame
/// centred on `origin` with steps `step(reach)` ([`f32_step`], or [`ray_step`] for instances).
pub fn unresolved_among(
    boxes: &[(u32, (DVec3, DVec3))],
    origin: DVec3,
    step: fn(f64) -> f64,
) -> Vec<Unresolved> {
    boxes
        .iter()
        .filter_map(|&(id, b)| Unresolved::of(id, b, origin, step))
        .collect()
}

/// The triangles of a scene that its frame does not resolve ([`unresolved_triangles`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct UnresolvedTriangles {
    /// How many: triangles with area in f64, of objects that can be hit, whose box spans fewer
    /// than [`RESOLVED_STEPS`] steps where it lies.
    pub count: usize,
    /// The first in scene order: its object, its triangle within the object, and where it lies
    /// ([`Unresolved::part`] is the object).
    pub first: Option<(u32, u32, Unresolved)>,
}

impl UnresolvedTriangles {
    /// The sentence for a warning, naming the first triangle's object as `object` does (an
    /// instanced scene's mesh is object 0 of a scene of its own); empty when every triangle is
    /// resolved.
    pub fn describe(&self, object: impl Fn(u32) -> String) -> String {
        let Some((id, triangle, first)) = self.first else {
            return String::new();
        };
        // A grid's stray value is the other common cause.
        let lies = first.describe_asking(
            &format!("{}'s triangle {triangle}", object(id)),
            "are some objects in other coordinates, or does a grid hold a NODATA value it does \
             not declare?",
        );
        format!(
            "{} triangle(s) are too small for where they lie, so picks on them may miss or name a \
             neighbour; the first, {lies}",
            self.count
        )
    }
}

/// The triangles of `scene` that its f32 frame, centred on `origin`, does not resolve
/// ([`Unresolved::of`] with [`f32_step`], on each triangle's box): degenerate triangles (no area
/// in f64) and those of objects with layer mask 0 are not counted. One pass over each object's
/// vertices (its box) and one over its triangles (a second to find the first, only in the first
/// object with one).
pub fn unresolved_triangles(scene: &Scene, origin: DVec3) -> UnresolvedTriangles {
    let mut count = 0;
    let mut first = None;
    for o in scene.objects().iter().filter(|o| o.mask != 0) {
        let range = o.first_triangle as usize..(o.first_triangle + o.triangle_count) as usize;
        if range.is_empty() {
            continue;
        }
        // No triangle of the object lies farther out than its box, so none sees a coarser step
        // than its box's: a triangle whose longest side of box spans RESOLVED_STEPS of those is
        // resolved without the exact test (a cheap pass for every sound scene; the exact test,
        // a diagonal and the step where the triangle lies, took 13% of a DEM's whole `pick`).
        let object_box = box_of(scene.object_vertices(o.id).map(|v| scene.position(v)));
        let enough = RESOLVED_STEPS * f32_step(reach_of(object_box, origin));
        let unresolved = |i: usize| -> Option<Unresolved> {
            let corners = scene.world_triangle(i);
            let (a, b) = box_of(corners);
            if (b - a).max_element() >= enough || zero_area(corners) {
                return None;
            }
            Unresolved::of(o.id, (a, b), origin, f32_step)
        };
        let here = range
            .clone()
            .into_par_iter()
            .filter(|&i| unresolved(i).is_some())
            .count();
        if here > 0 && first.is_none() {
            first = range
                .into_par_iter()
                .find_first(|&i| unresolved(i).is_some())
                .and_then(|i| Some((o.id, i as u32 - o.first_triangle, unresolved(i)?)));
        }
        count += here;
    }
    UnresolvedTriangles { count, first }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::check::synthetic::box_mesh;

    #[test]
    fn steps_are_the_spacing_of_f32_values() {
        assert_eq!(f32_step(1.0), f64::from(f32::EPSILON));
        assert_eq!(f32_step(5e8), 32.0);
        assert_eq!(f32_step(-5e8), 32.0);
        assert_eq!(f32_step(1e39), f64::INFINITY);
        assert_eq!(ray_step(5e8), 32.0 / 2048.0);
        assert_eq!(f64_step(1e16), 2.0);
        assert_eq!(f64_step(-1.0), f64::EPSILON);
        assert_eq!(f64_step(f64::INFINITY), f64::INFINITY);
    }

    /// Two one-unit boxes: nearby both are resolved; 10⁸ apart, the frame's centre lies 5 × 10⁷
    /// from each, where f32 values are 4 apart (a box spans under one step); at 10³⁰⁰ apart the
    /// offsets leave f32's range.
    #[test]
    fn parts_far_from_the_frames_centre_are_unresolved() {
        let scene = |gap: f64| {
            let mut scene = Scene::new();
            for (name, x) in [("near", 0.0), ("far", gap)] {
                let at = DVec3::new(x, 0.0, 0.0);
                scene.add_mesh(name, box_mesh(at, at + DVec3::ONE)).unwrap();
            }
            unresolved_objects(&scene, scene.origin())
        };
        assert_eq!(scene(100.0), vec![]);
        let far = scene(1e8);
        assert_eq!(far.iter().map(|u| u.part).collect::<Vec<_>>(), vec![0, 1]);
        assert_eq!(far[0].step, 4.0);
        assert!(
            far[0]
                .describe("object 0")
                .starts_with("object 0 lies 5.000e7 units")
        );
        assert!(scene(1e300).iter().all(|u| u.step.is_infinite()));
    }

    /// A part past f32's range is unresolved however large it is: one 10²⁰⁰ across (its
    /// diagonal's square past f64's range) was counted as resolved, and its triangles, which no
    /// tree holds, went without a warning.
    #[test]
    fn parts_past_f32s_range_are_unresolved_however_large() {
        for size in [1e150, 1e200, 1e300] {
            let b = (DVec3::ZERO, DVec3::new(size, size, 0.0));
            let u = Unresolved::of(0, b, DVec3::ZERO, f32_step).expect("unresolved");
            assert_eq!(u.size, size * 2f64.sqrt());
            assert!(u.step.is_infinite());
        }
        assert!((scaled_length(DVec3::new(3e200, 4e200, 0.0)) / 5e200 - 1.0).abs() < 1e-15);
        // A part of no size has nothing to resolve (its warning read "too coarse for its 0
        // units").
        let point = (DVec3::splat(1e8), DVec3::splat(1e8));
        assert_eq!(Unresolved::of(0, point, DVec3::ZERO, f32_step), None);
    }

    /// A 10 × 10 grid of unit cells in one object, its middle vertex raised to `spike`.
    fn spiked_grid(spike: f64) -> Scene {
        let positions = (0..121)
            .map(|k| {
                let z = if k == 60 { spike } else { 0.0 };
                DVec3::new(f64::from(k % 11), f64::from(k / 11), z)
            })
            .collect();
        let triangles = (0..100u32)
            .flat_map(|c| {
                let k = c / 10 * 11 + c % 10;
                [[k, k + 1, k + 12], [k, k + 12, k + 11]]
            })
            .collect();
        let mut scene = Scene::new();
        let mesh = crate::scene::Mesh {
            positions,
            triangles,
        };
        scene.add_mesh("grid", mesh).unwrap();
        scene
    }

    /// A 10 × 10 grid of unit cells, resolved as an object with or without a spike of 10¹⁰ at
    /// one vertex; with it, the frame's centre lies 5 × 10⁹ above the ground (512-unit steps)
    /// and every cell not touching the spike is too small there. Objects with mask 0 are not
    /// counted.
    #[test]
    fn cells_of_a_grid_with_a_spike_are_unresolved_though_the_grid_is_not() {
        let plain = spiked_grid(0.0);
        assert_eq!(unresolved_objects(&plain, plain.origin()), vec![]);
        assert_eq!(
            unresolved_triangles(&plain, plain.origin()),
            UnresolvedTriangles::default()
        );
        let mut spiked = spiked_grid(1e10);
        assert_eq!(unresolved_objects(&spiked, spiked.origin()), vec![]);
        let small = unresolved_triangles(&spiked, spiked.origin());
        // The six triangles around the spike's vertex are 10¹⁰ tall.
        assert_eq!(small.count, 200 - 6);
        let (object, triangle, first) = small.first.unwrap();
        assert_eq!((object, triangle, first.step), (0, 0, 512.0));
        let text = small.describe(|o| format!("object {o}"));
        assert!(text.starts_with("194 triangle(s) are too small"), "{text}");
        assert!(
            text.contains("object 0's triangle 0 lies 5.000e9"),
            "{text}"
        );
        spiked.set_object_mask(0, 0).unwrap();
        assert_eq!(unresolved_triangles(&spiked, spiked.origin()).count, 0);
    }

    /// The line itself: a box spanning fewer than [`RESOLVED_STEPS`] steps where it lies is
    /// unresolved, one spanning more is not (the far-out cases above are hundreds of steps
    /// under it, so a mutation round's threshold of one step passed them).
    #[test]
    fn a_part_is_resolved_from_sixteen_steps_on() {
        // 1,024 to 2,048 units out, f32 values are 2⁻¹³ apart.
        let step = f32_step(1024.0);
        assert_eq!(step, 2f64.powi(-13));
        let part = |steps: f64| {
            let lo = DVec3::new(1024.0, 0.0, 0.0);
            Unresolved::of(7, (lo, lo + DVec3::X * steps * step), DVec3::ZERO, f32_step)
        };
        for steps in [1.5, 2.0, 8.0, 15.0, 15.9] {
            let u = part(steps).expect("under sixteen steps");
            assert_eq!((u.part, u.step), (7, step));
            assert!(
                (u.size - steps * step).abs() < 1e-12,
                "{steps} steps: {}",
                u.size
            );
        }
        for steps in [16.0, 16.1, 17.0, 1000.0] {
            assert_eq!(part(steps), None, "{steps} steps");
        }
    }

    /// A grid's cells against the same line, where the object's box is resolved: raised
    /// 3 × 2²⁰ at its middle, the frame's centre lies 1.5 × 2²⁰ above the ground, where steps
    /// are 1/8 and a unit cell spans 8 of them (unresolved); raised 3 × 2¹⁸, steps are 1/32 and a
    /// cell spans 32 (resolved). The cheap pass that skips the exact test must not skip the
    /// first.
    #[test]
    fn cells_a_few_steps_wide_are_unresolved_and_wider_ones_are_not() {
        let coarse = spiked_grid(3.0 * 2f64.powi(20));
        assert_eq!(unresolved_objects(&coarse, coarse.origin()), vec![]);
        let small = unresolved_triangles(&coarse, coarse.origin());
        assert_eq!(small.count, 200 - 6);
        assert_eq!(small.first.unwrap().2.step, 0.125);
        let fine = spiked_grid(3.0 * 2f64.powi(18));
        assert_eq!(unresolved_triangles(&fine, fine.origin()).count, 0);
    }
}
