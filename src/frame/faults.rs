//! What a built scene's single-precision frames cannot hold, as the sentences its user is
//! warned with (the command line on standard error, Python as `UserWarning`s): frames too wide
//! or too narrow for the f32 tests' products ([`reach::scale_fault`]), triangles with no area
//! and triangles the frame loses ([`crate::bvh::lost`]), objects or instances it rounds too
//! coarsely, and triangles of a resolved object rounded out of shape
//! ([`reach::unresolved_triangles`]); and before them, parts placed so far from the world's
//! origin that f64 itself rounds them out of shape, and instances whose rays the frame places
//! more coarsely than picks are held to ([`reach::coarser_than_picks`]). Without them, picks
//! on those parts would be missed or off without a word.

use super::reach::{self, f32_step, unresolved_triangles};
use crate::picker::BuiltScene;
use crate::scene::Scene;
use glam::DVec3;

/// The warnings for `built`, each one sentence, most basic first; empty for a sound scene.
pub fn frame_warnings(built: &BuiltScene) -> Vec<String> {
    let mut said = Vec::new();
    // Each part's box once, for every check: the objects', or the instances' in the world; and
    // the frame the parts are measured in (an instanced scene's rays carry half-float rests).
    let (parts, origin, step, kind) = match built.instances() {
        None => (
            reach::object_boxes(&built.scene),
            built.bvh.origin,
            f32_step as fn(f64) -> f64,
            "object",
        ),
        Some(i) => (
            i.hittable_boxes(),
            i.origin(),
            reach::ray_step as _,
            "instance",
        ),
    };
    let coarser = |origin: DVec3, step: fn(f64) -> f64| -> Vec<reach::Unresolved> {
        parts
            .iter()
            .filter_map(|&(id, b)| reach::coarser_than_picks(id, b, origin, step))
            .collect()
    };
    // Parts placed so far from the world's origin for their size that f64 itself rounds them
    // out of shape (a small mesh 10¹⁶ out): no frame gives those positions back.
    let in_world = coarser(DVec3::ZERO, reach::f64_step);
    if let Some(first) = in_world.first() {
        let others = match in_world.len() {
            1 => String::new(),
            n => format!(
                "{n} {kind}s lie where double precision rounds them too coarsely; the first, "
            ),
        };
        said.push(format!(
            "{others}{}",
            first.describe_in_world(&format!("{kind} {}", first.part))
        ));
    }
    // The frames: the scene's, or each of an instanced scene's meshes' (a mesh lies in a frame
    // of its own), with whether it is a mesh's.
    let frames: Vec<(&Scene, DVec3, bool)> = match built.instances() {
        None => vec![(&built.scene, built.bvh.origin, false)],
        Some(i) => i
            .meshes()
            .iter()
            .map(|m| (&m.scene, m.bvh.origin, true))
            .collect(),
    };
    // Frames too wide or too narrow for the f32 tests' products.
    said.extend(frames.iter().find_map(|(scene, origin, _)| {
        reach::scale_fault(scene.bounds().map_or(0.0, |b| reach::reach_of(b, *origin)))
    }));
    let lost = built.lost_triangles();
    if lost.degenerate > 0 {
        // An instanced scene's first is an instance placing the mesh.
        let object = |id: u32| match built.instances() {
            None => format!("object {id} ({})", built.scene.objects()[id as usize].name),
            Some(i) => format!("instance {id} ({})", i.instances()[id as usize].name),
        };
        said.push(lost.describe_degenerate(object));
    }
    if lost.triangles > 0 {
        let (lo, hi) = built.bounds().unwrap_or_default();
        let span = (hi - lo).max_element();
        let step = f32_step(span * 0.5);
        let frame = if step.is_finite() {
            format!("in a frame that wide offsets are rounded to about {step:.1e} units")
        } else {
            "more than single precision holds".into()
        };
        said.push(format!(
            "{}; the scene spans {}, {frame} (are some objects in other coordinates?)",
            lost.describe(),
            reach::units(span),
        ));
    }
    let unresolved = reach::unresolved_among(&parts, origin, step);
    if let Some(first) = unresolved.first() {
        let what = format!("{kind} {}", first.part);
        let others = match unresolved.len() {
            1 => String::new(),
            n => format!("{n} {kind}s are too small for where they lie; the first, "),
        };
        // Asked of the parts the sentence names.
        let question = format!("are some {kind}s in other coordinates?");
        said.push(format!(
            "{others}{}",
            first.describe_asking(&what, &question)
        ));
        return said;
    }
    if lost.triangles > 0 {
        return said;
    }
    // Each object resolved as a whole, and nothing lost: its triangles may still be rounded
    // out of shape (a grid's stray spike makes the frame tall).
    for (scene, origin, mesh) in frames {
        let small = unresolved_triangles(scene, origin);
        let object = |id: u32| match mesh {
            false => format!("object {id}"),
            true => format!("the mesh of {}", scene.objects()[id as usize].name),
        };
        if small.count > 0 {
            said.push(small.describe(object));
            return said;
        }
    }
    // An instanced scene's meshes resolved in their own frames: its rays enter them from the
    // scene frame, whose step where an instance lies may be coarser than picks are held to.
    if built.instances().is_some() {
        let coarse = coarser(origin, reach::ray_step);
        if let Some(first) = coarse.first() {
            said.push(first.describe_coarse(coarse.len() - 1));
        }
    }
    said
}

/// The warnings about part `part` (an object, or an instance) alone where an edit has just
/// placed it, as [`frame_warnings`] gives them for a loaded scene: f64 rounding it out of
/// shape in the world, and an instance's rays placed more coarsely than picks are held to.
/// What an edit makes worse for the whole scene is refused, not warned about; these are the
/// placements that are allowed and still picked less exactly. Empty for a part that cannot
/// be hit (removed, mask 0, no triangles). One pass over the part's vertices.
pub fn placement_warnings(built: &BuiltScene, part: u32) -> Vec<String> {
    let (b, kind) = match built.instances() {
        Some(i) => (i.hittable_box(part), "instance"),
        None => (reach::object_box(&built.scene, part), "object"),
    };
    let Some(b) = b else {
        return Vec::new();
    };
    let mut said = Vec::new();
    if let Some(u) = reach::coarser_than_picks(part, b, DVec3::ZERO, reach::f64_step) {
        said.push(u.describe_in_world(&format!("{kind} {part}")));
    }
    if let Some(i) = built.instances()
        && let Some(u) = reach::coarser_than_picks(part, b, i.origin(), reach::ray_step)
    {
        said.push(u.describe_coarse(0));
    }
    said
}
