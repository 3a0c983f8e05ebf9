//! Line of sight (`los`, `viewshed`): what a query of segments is warned about, the same words
//! from the command line and from Python.

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
    // Scaled first, so that no square overflows.
    let ends = |&(a, b): &(DVec3, DVec3)| eps * scaled_length(b - a);
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
