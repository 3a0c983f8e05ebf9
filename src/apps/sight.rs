//! Line of sight (`los`, `viewshed`), the same from the command line and from Python: the
//! sight lines' rays and queries, how their answers are judged (on hits refined in f64, so the
//! ends' own surfaces never block a line whatever the frame's rounding), and what a query of
//! segments is warned about.

use crate::query::{Mode, Query};
use crate::ray::{Hit, Ray};
use crate::scene::scaled_length;
use glam::DVec3;

/// The warning when segments ignore ends longer than a thousandth of the scene's size, or
/// `None`: ε is a part of each segment's length, so from an observer 10⁹ units out the default
/// ε skips the last 1,000 units of every segment, more than a 100-unit scene, and everything
/// reads visible. `bounds` are the scene's, `what` names a segment ("pair", "target") and
/// `epsilon` how the caller spells ε (`--epsilon`, `epsilon=`).
pub fn long_ends(
    bounds: Option<(DVec3, DVec3)>,
    segments: &[(DVec3, DVec3)],
    eps: f64,
    what: &str,
    epsilon: &str,
) -> Option<String> {
    let (lo, hi) = bounds?;
    let size = (hi - lo).length();
    // Scaled first, so that no square overflows. Invalid segments (an end not finite, or ends
    // so far apart that their difference is not: reported as not visible, with their own
    // warning) are not counted: no ε would help them.
    let ends = |&(a, b): &(DVec3, DVec3)| match (b - a).is_finite() {
        true => eps * scaled_length(b - a),
        false => 0.0,
    };
    let long = segments.iter().filter(|s| ends(s) > size * 1e-3).count();
    if long == 0 {
        return None;
    }
    let longest = segments.iter().map(ends).fold(0.0, f64::max);
    // A segment longer than f64 holds (ends 10^200 apart: its squared length overflowed, and
    // the warning said "up to 0.000e0 units").
    let longest = if longest.is_finite() {
        format!("{longest:.3e} units")
    } else {
        "more units than f64 holds".to_owned()
    };
    Some(format!(
        "{long} {what}(s) ignore more than a thousandth of the scene's size at each end \
         ({epsilon} {} of their length: up to {longest}, the scene being {size:.3e} across); \
         give a smaller {epsilon} for ends this far apart",
        crate::io::output::csv_number(eps)
    ))
}

/// The sight line of segment `(a, b)`: the ray `a + t·(b − a)` over `[ε, 1 − ε]`, with layer
/// mask `mask`. The traversal tests that range in its single-precision frame, where the ends'
/// own surfaces can fall inside it (a target on the ground 60 m away, in a frame rounding to a
/// millimetre, hit at t = 1 − 10⁻⁵); [`judge_nearest`] decides on the hit refined in f64.
pub fn sight_ray(a: DVec3, b: DVec3, eps: f64, mask: u32) -> Ray {
    Ray::new(a, b - a)
        .with_range(eps, 1.0 - eps)
        .with_mask(mask)
}

/// The first pass's query: each sight line's nearest hit, refined in f64.
pub fn first_query() -> Query {
    Query {
        mode: Mode::Closest,
        ..Query::default()
    }
}

/// The second pass's query, for the sight lines the first leaves open ([`Sight::Again`]):
/// the nearest hits of each, in order ([`judge_all`]).
pub fn second_query() -> Query {
    Query {
        mode: Mode::All,
        max_hits: AGAIN_HITS,
        ..Query::default()
    }
}

/// Hits the second pass keeps per sight line: more than meet at one point of a mesh.
const AGAIN_HITS: u32 = 32;

/// What a sight line's nearest hit says of it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sight {
    /// Nothing within (ε, 1 − ε): no hit, or the nearest lies at the far end (the target's own
    /// surface).
    Visible,
    /// Hit within (ε, 1 − ε) in f64, or invalid (a NaN or infinite end, both ends equal).
    Hidden,
    /// The nearest hit lies within ε of the near end (the surface the observer stands on):
    /// what lies behind it is asked again ([`second_query`]).
    Again,
}

/// [`Sight`] from the first pass's answer `hit` (its t, refined in f64, is the fraction of the
/// segment).
pub fn judge_nearest(hit: &Hit, eps: f64) -> Sight {
    if hit.invalid {
        return Sight::Hidden;
    }
    if !hit.hit || hit.t >= 1.0 - eps {
        return Sight::Visible;
    }
    if hit.t > eps {
        return Sight::Hidden;
    }
    Sight::Again
}

/// Whether a sight line is visible from its hits in order along it (the second pass's list):
/// none with t in (ε, 1 − ε) in f64. `None` where the list leaves it unknown: full
/// (`overflow`), and every hit at the near end (more surfaces meet at the observer than the
/// list holds); such lines are reported not visible, with a warning that counts them
/// ([`undecided_warning`]).
pub fn judge_all(hits: &[Hit], overflow: bool, eps: f64) -> Option<bool> {
    if hits.iter().any(|h| h.t > eps && h.t < 1.0 - eps) {
        return Some(false);
    }
    (!overflow || hits.iter().any(|h| h.t > eps)).then_some(true)
}

/// The warning for `count` sight lines that are no segment (their rays are invalid), calling
/// them `what`s.
pub fn invalid_warning(count: usize, what: &str) -> String {
    format!(
        "{count} {what}(s) were invalid (a NaN or infinite coordinate, both ends at the same \
         point, or ends farther apart than f64 holds) and are reported as not visible"
    )
}

/// The warning for `count` sight lines left unknown ([`judge_all`]), calling them `what`s.
pub fn undecided_warning(count: usize, what: &str) -> String {
    format!(
        "{count} {what}(s) start where more than {AGAIN_HITS} surfaces meet (coincident \
         triangles at the observer), so what lies past them is unknown; they are reported as \
         not visible"
    )
}
