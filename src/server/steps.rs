//! A pick answered in steps, so that the worker stops working for a client who is gone. The
//! worker has one picker and answers one query call at a time; a client who sends a large or
//! costly pick and then disconnects (or times out) used to keep it busy until the whole query
//! was done — on a scene whose rays cost milliseconds each, minutes of every other client's
//! picks waiting. The rays go through in steps instead, and between steps the worker asks
//! whether anyone still waits for the answer (a reply's receiver is dropped with the request's
//! handler when its connection closes). Steps start small and double while each takes under
//! [`FAST`] (so a large batch on a fast scene is soon one call of many rays, as before), and
//! halve, down to [`FIRST`], when one takes over [`SLOW`]. Each ray's answer does not depend on
//! the rays beside it, so the answers are those of one call.

use crate::picker::Picker;
use crate::query::{Answers, Query};
use crate::ray::Ray;
use crate::{Error, Result};
use std::time::{Duration, Instant};

/// The first step's rays, and the fewest in any step.
pub(crate) const FIRST: usize = 256;
/// A step that took less than this doubles the next one.
const FAST: Duration = Duration::from_millis(50);
/// A step that took more than this halves the next one.
const SLOW: Duration = Duration::from_millis(200);

/// `picker.query(rays, query)` in steps (see the module docs); `None` as soon as `wanted` says,
/// between two steps, that no one waits for the answers.
pub(crate) fn query_in_steps(
    picker: &mut dyn Picker,
    rays: &[Ray],
    query: &Query,
    wanted: impl Fn() -> bool,
) -> Result<Option<Answers>> {
    let mut out = Answers::default();
    let (mut done, mut step) = (0, FIRST);
    while done < rays.len() {
        if !wanted() {
            return Ok(None);
        }
        let end = (done + step).min(rays.len());
        let start = Instant::now();
        let answers = picker.query(&rays[done..end], query)?;
        if answers.nearest.len() != end - done {
            return Err(Error::Invalid(format!(
                "the picker answered {} of {} rays",
                answers.nearest.len(),
                end - done
            )));
        }
        let took = start.elapsed();
        append(&mut out, answers);
        done = end;
        step = if took < FAST {
            step.saturating_mul(2)
        } else if took > SLOW {
            (step / 2).max(FIRST)
        } else {
            step
        };
    }
    Ok(Some(out))
}

/// Appends `more` (the answers of the rays after `out`'s, at least one) to `out`.
fn append(out: &mut Answers, more: Answers) {
    if out.nearest.is_empty() {
        *out = more;
        return;
    }
    if !more.list_start.is_empty() {
        let base = out.lists.len();
        out.list_start
            .extend(more.list_start[1..].iter().map(|s| s + base));
        out.lists.extend(more.lists);
        out.overflow.extend(more.overflow);
    }
    out.nearest.extend(more.nearest);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::check::synthetic::{RayKind, example_scene, rays};
    use crate::query::Mode;
    use crate::{BuildOptions, BuiltScene};
    use std::cell::Cell;
    use std::sync::Arc;

    /// In steps, every mode gives the answers of one call, bit for bit (all-hits lists and
    /// their starts included); and the steps stop as soon as no one wants the answers.
    #[test]
    fn steps_answer_as_one_call_and_stop_when_unwanted() {
        let built = Arc::new(BuiltScene::new(example_scene(), &BuildOptions::default()).unwrap());
        let rays = rays(&built.scene, RayKind::Random, 3000, 5);
        let mut picker = crate::picker::CpuPicker::new(built);
        for mode in [Mode::Closest, Mode::Any, Mode::All] {
            let query = Query {
                mode,
                max_hits: 3,
                ..Query::default()
            };
            let whole = picker.query(&rays, &query).unwrap();
            let stepped = query_in_steps(&mut picker, &rays, &query, || true)
                .unwrap()
                .unwrap();
            assert_eq!(format!("{whole:?}"), format!("{stepped:?}"), "{mode:?}");
        }
        let asked = Cell::new(0);
        let gone = query_in_steps(&mut picker, &rays, &Query::default(), || {
            asked.set(asked.get() + 1);
            asked.get() < 2
        })
        .unwrap();
        assert!(gone.is_none());
        assert_eq!(asked.get(), 2, "stopped after the first step");
    }
}
