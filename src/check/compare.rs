//! Deciding whether two answers for the same ray agree, to the project's standard:
//! a mismatch is a differing hit/miss, or a differing triangle with |Δt| > 1e-5·max(1, t).
//! A disagreement that only decides which side of an edge, or of the ray's range end, the ray
//! passes (within f32 reach of that boundary) is a tie, counted separately and never hidden.
//! Distances along a ray count at most [`FAR_DISTANCE`] of the scene's reaches: the traversal
//! moves an origin from farther out to there before rounding it (`frame::Frame::shift`), so
//! its f32 error stops growing there (a tolerance of 10⁻⁵ of 10⁹ units called a tower's far
//! wall picked from 10⁹ units out a tie).

use crate::query::{Answers, Mode};
use crate::ray::{Hit, Ray};
use crate::scene::Scene;

/// Relative tolerance on t and on distances to edges.
pub const RELATIVE_TOLERANCE: f64 = 1e-5;

/// The farthest distance along a ray, in the scene's reaches, that the tolerances grow with:
/// past [`crate::frame::FAR_REACHES`] and the two reaches a moved origin keeps before the scene,
/// with room for a frame centred elsewhere (an instanced scene's, against its baked copy).
pub const FAR_DISTANCE: f64 = 2.0 * crate::frame::FAR_REACHES;

/// `|t|` as the tolerances count it: at most [`FAR_DISTANCE`] reaches of `scene` along `ray`.
fn counted_t(scene: &Scene, ray: &Ray, t: f64) -> f64 {
    let reach = crate::frame::Frame::around(scene.origin(), scene.bounds()).reach;
    t.abs().min(FAR_DISTANCE * reach / dir_length(ray))
}

/// The length of `ray`'s direction, without underflow or overflow (`glam`'s `length` is 0 for
/// a direction 10⁻³⁰⁰ long, which the pickers trace).
fn dir_length(ray: &Ray) -> f64 {
    crate::ray::direction_length(ray.dir).unwrap_or_else(|| ray.dir.length())
}

/// The size, in world units, of the coordinates the traversal computes with for `ray`: the
/// scene's reach plus how far from the scene's centre the ray starts (counted as far as
/// [`FAR_DISTANCE`] reaches, as the traversal moves an origin from farther out). No f32
/// rounding of the traversal is larger than a small part of it, so the tolerances' floor (one
/// world unit; one unit of `t`) is never more than this: else a direction 10⁶ long, or a
/// scene 10⁻⁵ across, made every other triangle a tie.
fn coordinate_scale(scene: &Scene, ray: &Ray) -> f64 {
    let frame = crate::frame::Frame::around(scene.origin(), scene.bounds());
    let start = (ray.origin - frame.origin).length();
    start.min(FAR_DISTANCE * frame.reach) + frame.reach
}

/// The tolerance on `t` (in the ray's units) for a hit at `t`. Its floor is one unit of `t`
/// for a direction of length 1 or more (at most [`coordinate_scale`] in world units), and
/// one world unit for a shorter one: a floor of one unit of `t` along a direction 10⁻³⁰⁰
/// long was 10⁻³⁰⁵ world units, and a hit 10⁻³⁰⁰ past the origin, which no f32 traversal
/// can tell from one at the origin, was a mismatch rather than a tie at `tmin`.
fn t_tolerance(scene: &Scene, ray: &Ray, t: f64) -> f64 {
    let length = dir_length(ray);
    let floor = coordinate_scale(scene, ray).min(length.max(1.0)) / length;
    RELATIVE_TOLERANCE * counted_t(scene, ray, t).max(floor)
}

/// How two answers for one ray compare.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Verdict {
    /// Same hit/miss and the same triangle (or both invalid).
    Same,
    /// Both hit different triangles at the same depth: the ray passes a shared edge or vertex.
    SharedEdge,
    /// One path passed an edge or range end the other stopped at, within f32 reach of it.
    Boundary,
    /// A real disagreement.
    Mismatch,
}

/// Compares two answers for `ray` over `scene`.
pub fn classify(scene: &Scene, ray: &Ray, a: &Hit, b: &Hit) -> Verdict {
    if a.invalid || b.invalid {
        return if a.invalid == b.invalid {
            Verdict::Same
        } else {
            Verdict::Mismatch
        };
    }
    match (a.hit, b.hit) {
        (false, false) => return Verdict::Same,
        (true, true) if (a.object, a.triangle) == (b.object, b.triangle) => return Verdict::Same,
        (true, true) if (a.t - b.t).abs() <= t_tolerance(scene, ray, a.t.abs().min(b.t.abs())) => {
            return Verdict::SharedEdge;
        }
        _ => {}
    }
    let nearer = match (a.hit, b.hit) {
        (true, true) if a.t <= b.t => a,
        (true, true) => b,
        (true, false) => a,
        _ => b,
    };
    if near_boundary(scene, ray, nearer) {
        Verdict::Boundary
    } else {
        Verdict::Mismatch
    }
}

/// Compares two any-hit answers: only hit/miss counts. When one side missed, the other side's
/// hit and every hit in `reference` (all hits of the ray, e.g. from the oracle) must lie at a
/// boundary for a tie.
pub fn classify_any(scene: &Scene, ray: &Ray, a: &Hit, b: &Hit, reference: &[Hit]) -> Verdict {
    if a.invalid || b.invalid {
        return if a.invalid == b.invalid {
            Verdict::Same
        } else {
            Verdict::Mismatch
        };
    }
    if a.hit == b.hit {
        return Verdict::Same;
    }
    let found = if a.hit { a } else { b };
    if near_boundary(scene, ray, found) && reference.iter().all(|h| near_boundary(scene, ray, h)) {
        Verdict::Boundary
    } else {
        Verdict::Mismatch
    }
}

/// Compares two all-hits lists (each sorted by t). Hits pair up by triangle, or by equal t
/// (a shared edge); a hit left without a partner is a tie only at a boundary. A list that
/// overflowed holds the hits only as far as its farthest kept one: a hit of the other list
/// beyond that (within the tolerance on t) needs no partner in it.
pub fn classify_lists(scene: &Scene, ray: &Ray, a: (&[Hit], bool), b: (&[Hit], bool)) -> Verdict {
    // How far along the ray each list holds every hit.
    let complete = |(list, overflow): (&[Hit], bool)| match list.last() {
        Some(last) if overflow => last.t - t_tolerance(scene, ray, last.t),
        _ => f64::INFINITY,
    };
    let (a_complete, b_complete) = (complete(a), complete(b));
    let (a, b) = (a.0, b.0);
    let (a_paired, b_paired, by_t) = pair_hits(scene, ray, a, b);
    let mut verdict = if by_t {
        Verdict::SharedEdge
    } else {
        Verdict::Same
    };
    // Each hit left without a partner, with how far the other list holds every hit.
    let unmatched = a
        .iter()
        .zip(&a_paired)
        .map(|(h, &p)| (h, p, b_complete))
        .chain(b.iter().zip(&b_paired).map(|(h, &p)| (h, p, a_complete)))
        .filter(|&(_, paired, _)| !paired);
    for (h, _, other_complete) in unmatched {
        if h.t >= other_complete {
            // Past the other list's last kept hit: it could not hold this one.
            continue;
        }
        if near_boundary(scene, ray, h) {
            verdict = verdict.max(Verdict::Boundary);
        } else {
            return Verdict::Mismatch;
        }
    }
    verdict
}

/// Two lists' hits paired as the comparisons pair them: the same triangles first, then what is
/// left by equal t (within the tolerance on t: a shared edge); pairing by t first let a hit at a
/// vertex take another object's hit at the same t away from its own partner. Returns which hits
/// of `a` and of `b` found a partner, and whether any pair was made by t.
fn pair_hits(scene: &Scene, ray: &Ray, a: &[Hit], b: &[Hit]) -> (Vec<bool>, Vec<bool>, bool) {
    let mut used = vec![false; b.len()];
    let mut paired = vec![false; a.len()];
    for (x, done) in a.iter().zip(&mut paired) {
        let same = (0..b.len())
            .find(|&j| !used[j] && (b[j].object, b[j].triangle) == (x.object, x.triangle));
        if let Some(j) = same {
            (used[j], *done) = (true, true);
        }
    }
    let mut by_t = false;
    for (x, done) in a.iter().zip(&mut paired) {
        if *done {
            continue;
        }
        let edge = (0..b.len())
            .find(|&j| !used[j] && (b[j].t - x.t).abs() <= t_tolerance(scene, ray, x.t));
        if let Some(j) = edge {
            (used[j], *done, by_t) = (true, true, true);
        }
    }
    (paired, used, by_t)
}

/// Whether an all-hits list, `kept` (and whether it `overflowed`: held more hits than it kept),
/// counts the ray's hits as `every`, all of them (the oracle's, in f64), does. The two are paired
/// as [`classify_lists`] pairs lists: the same triangles, then equal t (a shared edge). A hit left
/// on either side without a partner is a tie only within f32 reach of an edge or a range end
/// ([`near_boundary`]), and a hit of `every` past a list that overflowed needs none. A list that
/// overflowed claims one hit more than it kept: one of `every` past its last kept hit, or else a
/// triangle passed within reach of an edge (or hit within reach of a range end) past it, which the
/// list may count where the oracle does not, or the oracle's hit that a kept hit within reach of
/// an edge took as its partner at equal t. Past those, the count is wrong: a list cut short
/// without its flag, or a flag on a list that held every hit. The check is the lists' against
/// every hit, not the cut one: [`classify_lists`] against the oracle's own cut list cannot see a
/// list one short of its last hit.
pub fn classify_count(
    scene: &Scene,
    ray: &Ray,
    kept: &[Hit],
    overflowed: bool,
    every: &[Hit],
) -> Verdict {
    // How far along the ray the list holds every hit.
    let horizon = match kept.last() {
        Some(last) if overflowed => last.t - t_tolerance(scene, ray, last.t),
        Some(_) => f64::INFINITY,
        None if overflowed => f64::NEG_INFINITY,
        None => f64::INFINITY,
    };
    let (kept_paired, every_paired, by_t) = pair_hits(scene, ray, kept, every);
    let mut verdict = if by_t {
        Verdict::SharedEdge
    } else {
        Verdict::Same
    };
    for (x, _) in kept.iter().zip(&kept_paired).filter(|(_, p)| !**p) {
        if near_boundary(scene, ray, x) {
            verdict = verdict.max(Verdict::Boundary);
        } else {
            return Verdict::Mismatch;
        }
    }
    let mut beyond = false;
    for (h, _) in every.iter().zip(&every_paired).filter(|(_, p)| !**p) {
        if h.t >= horizon {
            beyond = true;
        } else if near_boundary(scene, ray, h) {
            verdict = verdict.max(Verdict::Boundary);
        } else {
            return Verdict::Mismatch;
        }
    }
    if overflowed && !beyond {
        // A kept hit on a triangle the oracle does not count, within reach of an edge, was
        // paired by t with a hit the oracle does count (a ray through a vertex of one of two
        // coplanar triangles, inside the other): the list counted both, so that hit is the
        // one more its flag claims.
        let boundary_pair = by_t
            && kept.iter().any(|x| {
                !every
                    .iter()
                    .any(|e| (e.object, e.triangle) == (x.object, x.triangle))
                    && near_boundary(scene, ray, x)
            });
        let from = kept.last().map_or(f64::NEG_INFINITY, |last| last.t);
        if !boundary_pair && !edge_within_reach_from(scene, ray, from, kept) {
            return Verdict::Mismatch;
        }
        verdict = verdict.max(Verdict::Boundary);
    }
    verdict
}

/// Whether `ray`, at t from `from` (less the tolerance on t), passes a triangle not among
/// `kept`'s that shares a bit of its mask where a path in f32 may count a hit the oracle does
/// not: within reach of one of its edges ([`near_boundary`]) with t in the ray's range (within
/// the tolerance), or through it within reach of a range end. Every triangle is tested, on all
/// cores: this runs only for a list whose last counted hit nothing else explains. (Culling is
/// not applied: a tie it would have culled is let pass.)
fn edge_within_reach_from(scene: &Scene, ray: &Ray, from: f64, kept: &[Hit]) -> bool {
    use rayon::prelude::*;
    let unbounded = Ray {
        tmin: f64::NEG_INFINITY,
        tmax: f64::INFINITY,
        ..*ray
    };
    (0..scene.triangle_count())
        .into_par_iter()
        .with_min_len(4096)
        .filter(|&i| !scene.is_degenerate(i) && scene.triangle_mask(i as u32) & ray.mask != 0)
        .any(|i| {
            let h = crate::exact::ray_triangle_f64(scene.world_triangle(i), ray.origin, ray.dir);
            let tolerance = t_tolerance(scene, ray, h.t);
            if !(h.t.is_finite()
                && h.t >= from - tolerance
                && h.t > ray.tmin - tolerance
                && h.t <= ray.tmax + tolerance)
            {
                return false;
            }
            let (object, triangle, u, v) = crate::check::oracle::located(scene, i as u32, &h);
            if kept
                .iter()
                .any(|k| (k.object, k.triangle) == (object, triangle))
            {
                return false;
            }
            let near = Hit {
                hit: true,
                t: h.t,
                object,
                triangle,
                u,
                v,
                ..Hit::MISS
            };
            // Through the triangle: a tie at a range end too; beside it, only at an edge.
            near_boundary(scene, if h.hit { ray } else { &unbounded }, &near)
        })
}

/// Compares two batches of answers to the same query, ray by ray. `reference_lists` (all hits
/// per ray, e.g. the oracle's) backs any-hit ties and checks all-hits counts
/// ([`classify_count`]). Returns the tally and the mismatching rays.
pub fn compare_answers(
    scene: &Scene,
    rays: &[Ray],
    mode: Mode,
    a: &Answers,
    b: &Answers,
    reference_lists: Option<&Answers>,
) -> (Tally, Vec<usize>) {
    let mut tally = Tally::default();
    let mut bad = Vec::new();
    for (i, ray) in rays.iter().enumerate() {
        let (x, y) = (&a.nearest[i], &b.nearest[i]);
        tally.rays += 1;
        tally.hits += x.hit as usize;
        tally.invalid += x.invalid as usize;
        let verdict = match mode {
            Mode::Closest => classify(scene, ray, x, y),
            Mode::Any => classify_any(
                scene,
                ray,
                x,
                y,
                reference_lists.map_or(&[], |r| r.hits_of(i)),
            ),
            Mode::All => {
                if x.invalid != y.invalid {
                    Verdict::Mismatch
                } else {
                    let lists = classify_lists(
                        scene,
                        ray,
                        (a.hits_of(i), a.overflow[i]),
                        (b.hits_of(i), b.overflow[i]),
                    );
                    // With every hit at hand, each side's count (its overflow flag) is checked
                    // too: the lists alone cannot tell a list cut one short of its last hit.
                    let count = |side: &Answers| {
                        reference_lists.map_or(Verdict::Same, |r| {
                            classify_count(
                                scene,
                                ray,
                                side.hits_of(i),
                                side.overflow[i],
                                r.hits_of(i),
                            )
                        })
                    };
                    lists.max(count(a)).max(count(b))
                }
            }
        };
        match verdict {
            Verdict::Same => {}
            Verdict::SharedEdge => tally.shared_edge += 1,
            Verdict::Boundary => tally.boundary += 1,
            Verdict::Mismatch => {
                tally.mismatches += 1;
                bad.push(i);
            }
        }
    }
    (tally, bad)
}

/// Whether `hit` lies within f32 reach of its triangle's edges or of the ray's range ends.
/// The reach is `1e-5·max(1, distance along the ray)` (the distance counted as far as
/// [`FAR_DISTANCE`] reaches of the scene), divided by the sine of the angle between ray and
/// plane (floored at 1e-3) because a grazing ray moves that much further per error.
pub fn near_boundary(scene: &Scene, ray: &Ray, hit: &Hit) -> bool {
    let t_tolerance = t_tolerance(scene, ray, hit.t);
    if (hit.t - ray.tmax).abs() <= t_tolerance || (hit.t - ray.tmin).abs() <= t_tolerance {
        return true;
    }
    let Some(index) = scene.global_index(hit.object, hit.triangle) else {
        return false;
    };
    let [a, b, c] = scene.world_triangle(index);
    let normal = (b - a).cross(c - a);
    let twice_area = normal.length();
    if twice_area == 0.0 {
        return true;
    }
    // Signed distance from the hit to each edge line: barycentric weight times the height.
    let weights = [1.0 - hit.u - hit.v, hit.u, hit.v];
    let opposite = [c - b, c - a, b - a];
    let edge_distance = (0..3)
        .map(|k| weights[k] * twice_area / opposite[k].length())
        .fold(f64::INFINITY, f64::min);
    let dir_length = dir_length(ray);
    let sine = (normal.dot(ray.dir / dir_length) / twice_area)
        .abs()
        .max(1e-3);
    let floor = coordinate_scale(scene, ray).min(1.0);
    let reach = RELATIVE_TOLERANCE * (counted_t(scene, ray, hit.t) * dir_length).max(floor) / sine;
    edge_distance.abs() <= reach
}

/// Counts of verdicts over a batch.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Tally {
    /// Rays compared.
    pub rays: usize,
    /// Rays the first answer says hit.
    pub hits: usize,
    /// Rays flagged invalid.
    pub invalid: usize,
    /// Shared-edge ties.
    pub shared_edge: usize,
    /// Boundary ties.
    pub boundary: usize,
    /// Real disagreements.
    pub mismatches: usize,
}

impl Tally {
    /// Compares two batches of closest hits; also returns the indices of the mismatching rays.
    pub fn compare(scene: &Scene, rays: &[Ray], a: &[Hit], b: &[Hit]) -> (Tally, Vec<usize>) {
        let answers = |hits: &[Hit]| Answers {
            nearest: hits.to_vec(),
            ..Answers::default()
        };
        compare_answers(scene, rays, Mode::Closest, &answers(a), &answers(b), None)
    }
}

/// Whether two hits are the same answer, bit for bit (every field but the b and i statistics).
pub fn same_answer(a: &Hit, b: &Hit) -> bool {
    let bits = |h: &Hit| {
        (
            h.hit,
            h.invalid,
            h.t.to_bits(),
            h.object,
            h.triangle,
            h.u.to_bits(),
            h.v.to_bits(),
            h.position.to_array().map(f64::to_bits),
            h.normal.to_array().map(f64::to_bits),
            h.cell,
        )
    };
    bits(a) == bits(b)
}

/// Rays whose answers differ in any bit between two backends: the nearest hit (hit or miss only
/// in [`Mode::Any`], where any hit is an answer), and in [`Mode::All`] the whole list and the
/// overflow flag. Returns the indices of the differing rays.
pub fn differences(mode: Mode, a: &Answers, b: &Answers) -> Vec<usize> {
    (0..a.nearest.len())
        .filter(|&i| {
            let (x, y) = (&a.nearest[i], &b.nearest[i]);
            if mode == Mode::Any {
                return x.hit != y.hit || x.invalid != y.invalid;
            }
            if !same_answer(x, y) {
                return true;
            }
            mode == Mode::All
                && (a.overflow[i] != b.overflow[i]
                    || a.hits_of(i).len() != b.hits_of(i).len()
                    || a.hits_of(i)
                        .iter()
                        .zip(b.hits_of(i))
                        .any(|(p, q)| !same_answer(p, q)))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::check::synthetic::box_mesh;
    use glam::DVec3;

    /// Two faces 10 units wide stacked 0.005 apart under a ray straight down: their hits (at
    /// t = 1 and 1.005, far from every edge) and the scene.
    fn stacked_faces() -> (Scene, Ray, Hit, Hit) {
        let mut scene = Scene::new();
        let mesh = crate::scene::Mesh {
            positions: [0.0, -0.005]
                .into_iter()
                .flat_map(|z| {
                    [(0.0, 0.0), (10.0, 0.0), (0.0, 10.0)].map(|(x, y)| DVec3::new(x, y, z))
                })
                .collect(),
            triangles: vec![[0, 1, 2], [3, 4, 5]],
        };
        scene.add_mesh("stack", mesh).unwrap();
        let ray = Ray::new(DVec3::new(0.25, 0.25, 1.0), DVec3::NEG_Z);
        let hits = crate::check::oracle::all_hits(
            &scene,
            &crate::check::oracle::OracleTriangles::new(&scene),
            &ray,
            crate::query::Cull::None,
        );
        assert_eq!(hits.len(), 2, "{hits:?}");
        (scene, ray, hits[0], hits[1])
    }

    /// One batch of all-hits answers, one ray's list, with its overflow flag.
    fn one_list(list: &[Hit], overflow: bool) -> Answers {
        Answers {
            nearest: vec![list.first().copied().unwrap_or(Hit::MISS)],
            lists: list.to_vec(),
            list_start: vec![0, list.len()],
            overflow: vec![overflow],
        }
    }

    /// Faces 0.005 apart at t = 1 are two answers, not one answer on a shared edge: the
    /// tolerance on t is 10⁻⁵ of t (a tolerance a thousand times looser called them a tie).
    #[test]
    fn stacked_faces_a_little_apart_are_a_mismatch() {
        let (scene, ray, near, far) = stacked_faces();
        assert!((far.t - near.t - 0.005).abs() < 1e-9);
        assert_eq!(classify(&scene, &ray, &near, &near), Verdict::Same);
        assert_eq!(classify(&scene, &ray, &near, &far), Verdict::Mismatch);
        assert_eq!(classify(&scene, &ray, &far, &near), Verdict::Mismatch);
    }

    /// A ray one side calls invalid and the other answers is a mismatch in every mode.
    #[test]
    fn invalid_against_answered_is_a_mismatch() {
        let (scene, ray, near, far) = stacked_faces();
        let invalid = Hit::INVALID;
        assert_eq!(classify(&scene, &ray, &invalid, &near), Verdict::Mismatch);
        assert_eq!(classify(&scene, &ray, &near, &invalid), Verdict::Mismatch);
        assert_eq!(
            classify(&scene, &ray, &invalid, &Hit::MISS),
            Verdict::Mismatch
        );
        assert_eq!(classify(&scene, &ray, &invalid, &invalid), Verdict::Same);
        let every = [near, far];
        assert_eq!(
            classify_any(&scene, &ray, &invalid, &near, &every),
            Verdict::Mismatch
        );
        assert_eq!(
            classify_any(&scene, &ray, &Hit::MISS, &invalid, &every),
            Verdict::Mismatch
        );
    }

    /// A grazing ray's reach around the edges grows as the sine of its angle with the plane
    /// shrinks, floored at 10⁻³: a ray 10⁻⁵ off a face's plane, meeting it at t = 1 half a unit
    /// inside an edge, is not near it (reach 10⁻²; a floor of 10⁻⁶ made it 1 and every hit of
    /// such a ray a tie), while 0.005 inside is.
    #[test]
    fn a_grazing_ray_s_reach_is_floored_at_a_sine_of_a_thousandth() {
        let mut scene = Scene::new();
        let mesh = crate::scene::Mesh {
            positions: vec![
                DVec3::ZERO,
                DVec3::new(10.0, 0.0, 0.0),
                DVec3::new(0.0, 10.0, 0.0),
            ],
            triangles: vec![[0, 1, 2]],
        };
        scene.add_mesh("face", mesh).unwrap();
        let oracle = crate::check::oracle::OracleTriangles::new(&scene);
        let dir = DVec3::new(1.0, 0.0, -1e-5);
        for (inside, near) in [(0.5, false), (0.1, false), (0.005, true)] {
            let at = DVec3::new(inside, 3.0, 0.0);
            let ray = Ray::new(at - dir, dir);
            let hits =
                crate::check::oracle::all_hits(&scene, &oracle, &ray, crate::query::Cull::None);
            assert_eq!(hits.len(), 1, "{hits:?}");
            assert!((hits[0].t - 1.0).abs() < 1e-9 && (hits[0].u - inside / 10.0).abs() < 1e-9);
            assert_eq!(
                near_boundary(&scene, &ray, &hits[0]),
                near,
                "{inside} inside"
            );
        }
    }

    /// An any-hit miss against a hit on an edge is a tie only when every hit of the ray lies at
    /// a boundary: here the face below is met well inside, so the miss is a mismatch.
    #[test]
    fn an_any_hit_miss_is_a_tie_only_where_every_hit_is_at_a_boundary() {
        let (scene, ray, near, far) = stacked_faces();
        let on_edge = Hit { u: 0.0, ..near };
        assert!(near_boundary(&scene, &ray, &on_edge));
        assert!(!near_boundary(&scene, &ray, &far));
        assert_eq!(
            classify_any(&scene, &ray, &on_edge, &Hit::MISS, &[on_edge]),
            Verdict::Boundary
        );
        assert_eq!(
            classify_any(&scene, &ray, &on_edge, &Hit::MISS, &[on_edge, far]),
            Verdict::Mismatch
        );
        assert_eq!(
            classify_any(&scene, &ray, &Hit::MISS, &on_edge, &[on_edge, far]),
            Verdict::Mismatch
        );
    }

    /// An all-hits list cut short of the ray's second hit without its overflow flag is a
    /// mismatch against every hit, whichever side holds it (each side's count is checked).
    #[test]
    fn a_list_cut_short_without_its_flag_is_a_mismatch_on_either_side() {
        let (scene, ray, near, far) = stacked_faces();
        let every = one_list(&[near, far], false);
        let (flagged, unflagged) = (one_list(&[near], true), one_list(&[near], false));
        let rays = [ray];
        let verdict = |a: &Answers, b: &Answers| {
            compare_answers(&scene, &rays, Mode::All, a, b, Some(&every)).0
        };
        assert_eq!(verdict(&flagged, &flagged).mismatches, 0);
        assert_eq!(verdict(&every, &flagged).mismatches, 0);
        assert_eq!(verdict(&unflagged, &flagged).mismatches, 1);
        assert_eq!(verdict(&flagged, &unflagged).mismatches, 1);
    }

    /// Two all-hits answers that differ only in the overflow flag are a difference.
    #[test]
    fn differences_see_the_overflow_flag() {
        let (_, _, near, far) = stacked_faces();
        let (a, b) = (one_list(&[near, far], false), one_list(&[near, far], true));
        assert!(differences(Mode::All, &a, &a).is_empty());
        assert_eq!(differences(Mode::All, &a, &b), vec![0]);
        assert_eq!(
            differences(Mode::All, &a, &one_list(&[near], false)),
            vec![0]
        );
    }

    /// Two walls of a box 8 units apart, picked from 10³ and from 10⁹ units out: the far wall
    /// is a tie of neither. Before distances were counted only as far as the scene's reaches,
    /// from 10⁹ out the far wall was within 10⁻⁵·t of the near one, a "shared edge".
    #[test]
    fn a_far_wall_is_a_mismatch_however_far_out_the_ray_starts() {
        let mut scene = Scene::new();
        let mesh = box_mesh(DVec3::new(30.0, 40.0, 0.0), DVec3::new(38.0, 48.0, 30.0));
        scene.add_mesh("tower", mesh).unwrap();
        for x in [1e3, 1e9] {
            let ray = Ray::new(DVec3::new(x, 44.0, 10.0), DVec3::NEG_X);
            let hit = |t: f64| {
                let hits = crate::check::oracle::all_hits(
                    &scene,
                    &crate::check::oracle::OracleTriangles::new(&scene),
                    &ray,
                    crate::query::Cull::None,
                );
                *hits
                    .iter()
                    .find(|h| (h.t - t).abs() < 1e-6)
                    .expect("a wall there")
            };
            let (near, far) = (hit(x - 38.0), hit(x - 30.0));
            assert_eq!(classify(&scene, &ray, &near, &near), Verdict::Same);
            assert_eq!(
                classify(&scene, &ray, &near, &far),
                Verdict::Mismatch,
                "from {x}"
            );
        }
    }
}
