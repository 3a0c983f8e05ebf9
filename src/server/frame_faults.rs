//! What a scene's single-precision frame fails to hold, before and after an edit, so that no
//! edit leaves the scene worse than it found it. One client's object placed far from the rest
//! (a transform in other units, a typo in a coordinate) widens the scene and re-centres its
//! frame, and every other object then lies far from the centre: its triangles rounded out of
//! shape or out of f32's range, every pick on it off or every ray invalid, for every client,
//! and no removal would bring the frame back. The worker refuses such an edit (400) with
//! nothing changed. Plain scenes only: an instanced scene's meshes keep frames of their own,
//! and placing an instance checks itself (`Instances::add`, `Instances::set_transform`). Also
//! a placement so far out for an object's size that f64 itself rounds its triangles flat
//! ([`refuse_collapse`]), which no frame can hold.

use super::batcher::EditError;
use crate::frame::reach::{Unresolved, f32_step, unresolved_objects};
use crate::picker::BuiltScene;
use glam::DVec3;

/// Faults of a plain scene's frame ([`crate::bvh::lost`], [`crate::frame::reach`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct FrameFaults {
    /// Triangles with area that the frame loses.
    pub(crate) lost: usize,
    /// Objects the frame does not resolve.
    pub(crate) unresolved: usize,
}

impl FrameFaults {
    /// `built`'s faults (one pass over its vertices, and over its triangles when the tree
    /// leaves some out).
    pub(crate) fn of(built: &BuiltScene) -> Self {
        FrameFaults {
            lost: built.lost_triangles().triangles,
            unresolved: unresolved_objects(&built.scene, built.bvh.origin).len(),
        }
    }

    /// `built`'s faults, and the refusal of the edit that made it when it has more of either
    /// kind than `self` (the scene's before the edit). The refusal names the edited object
    /// `edited` where it is one the frame does not resolve (a far move re-centres the frame
    /// half-way, so the objects left behind are as far from its centre as the moved one); else
    /// the first that is not, with the edited object beside it.
    pub(crate) fn after(
        &self,
        built: &BuiltScene,
        edited: Option<u32>,
    ) -> (Self, Option<EditError>) {
        let lost = built.lost_triangles();
        let unresolved = unresolved_objects(&built.scene, built.bvh.origin);
        let now = FrameFaults {
            lost: lost.triangles,
            unresolved: unresolved.len(),
        };
        let why = if now.unresolved > self.unresolved {
            match edited.and_then(|e| unresolved.iter().find(|u| u.part == e)) {
                Some(u) => Some(u.describe(&format!("object {}", u.part))),
                None => {
                    let u = &unresolved[0];
                    let by =
                        edited.map_or(String::new(), |e| format!(" (by the edit of object {e})"));
                    Some(u.describe(&format!("object {}{by}", u.part)))
                }
            }
        } else if now.lost > self.lost {
            let span = built
                .bounds()
                .map_or(0.0, |(lo, hi)| (hi - lo).max_element());
            Some(format!(
                "the scene would span {}, and {}",
                crate::frame::reach::units(span),
                lost.describe()
            ))
        } else {
            None
        };
        (now, why.map(refusal))
    }
}

/// The faults after a move of object `object` from the box `here` to the box `there` that
/// `built` (the scene after it) refitted, keeping its frame and every triangle the tree held,
/// from `before`; refused when the object was resolved in that frame and is not now, or when the
/// frame a rebuild would centre on the scene's new bounds (the next edit that builds again)
/// would leave more objects unresolved than `before`.
pub(crate) fn moved(
    object: u32,
    here: (DVec3, DVec3),
    there: (DVec3, DVec3),
    built: &BuiltScene,
    before: FrameFaults,
) -> Result<FrameFaults, EditError> {
    let origin = built.bvh.origin;
    // An object never hit (layer mask 0: removed) is not counted.
    let counted = built.scene.objects()[object as usize].mask != 0;
    let was = counted && Unresolved::of(object, here, origin, f32_step).is_some();
    let is = Unresolved::of(object, there, origin, f32_step).filter(|_| counted);
    if let (false, Some(after)) = (was, is) {
        return Err(refusal(after.describe(&format!("object {object}"))));
    }
    let unresolved =
        (before.unresolved + usize::from(is.is_some())).saturating_sub(usize::from(was));
    if built.scene.origin() != origin {
        let recentred = unresolved_objects(&built.scene, built.scene.origin());
        if recentred.len() > before.unresolved {
            let u = &recentred[0];
            return Err(refusal(u.describe(&format!(
                "once the frame is centred on the scene again, object {}",
                u.part
            ))));
        }
    }
    Ok(FrameFaults {
        unresolved,
        ..before
    })
}

/// Refuses placing object `object` where f64 can no longer tell the corners of triangles apart
/// that had area where it was (`before`; `after` where the edit would put its vertices,
/// `triangles` indexing both): a translation so far for the object's size that its extent is
/// rounded away (a DEM moved 10³⁰⁰ out became a wall no ray crosses). Not the frame's doing, so
/// a lone object, whose frame follows it, was let through; the command line warns of such
/// triangles in a file, and an edit that makes them is refused, with nothing changed.
pub(crate) fn refuse_collapse(
    object: u32,
    triangles: &[[u32; 3]],
    before: &[DVec3],
    after: &[DVec3],
) -> Result<(), EditError> {
    let has_area = |p: &[DVec3], t: &[u32; 3]| !crate::scene::zero_area(t.map(|v| p[v as usize]));
    let mut collapsed = triangles
        .iter()
        .enumerate()
        .filter(|(_, t)| has_area(before, t) && !has_area(after, t));
    let Some((first, _)) = collapsed.next() else {
        return Ok(());
    };
    let n = 1 + collapsed.count();
    Err(refusal(format!(
        "object {object} would leave {n} of its triangles with no area in double precision \
         (the first: its triangle {first}): placed that far for its size, its corners can no \
         longer be told apart"
    )))
}

fn refusal(why: String) -> EditError {
    EditError::Invalid(format!(
        "refused, nothing was changed: after this edit, {why}"
    ))
}
