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

use crate::scene::{Scene, box_of, scaled_length};
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

/// How finely an instanced scene places rays `reach` units from its frame's origin: f32
/// offsets refined by a half-float rest (`frame::put_origin_lo`: 11 more bits).
pub fn ray_step(reach: f64) -> f64 {
    f32_step(reach) / 2048.0
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
        let reach = (lo - origin).abs().max((hi - origin).abs()).max_element();
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

    /// The sentence for a message: where the part lies, the step there and its size.
    pub fn describe(&self, what: &str) -> String {
        let rounds = if self.step.is_finite() {
            format!("rounds positions to {:.1e} units", self.step)
        } else {
            "cannot hold positions at all".into()
        };
        format!(
            "{what} lies {:.3e} units from the centre of the scene, where its \
             single-precision frame {rounds}: too coarse for its {:.3e} units (are some objects \
             in other coordinates?)",
            self.reach, self.size
        )
    }
}

/// The objects of `scene` with triangles that its f32 frame, centred on `origin`, does not
/// resolve ([`Unresolved::of`] with [`f32_step`]), in id order; objects with layer mask 0 (never
/// hit: removed) are not counted. One pass over the vertices.
pub fn unresolved_objects(scene: &Scene, origin: DVec3) -> Vec<Unresolved> {
    scene
        .objects()
        .par_iter()
        .filter(|o| o.triangle_count > 0 && o.mask != 0)
        .filter_map(|o| {
            let b = box_of(scene.object_vertices(o.id).map(|v| scene.position(v)));
            Unresolved::of(o.id, b, origin, f32_step)
        })
        .collect()
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
}
