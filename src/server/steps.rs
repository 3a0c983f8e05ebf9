//! A pick answered in steps, so that the worker stops working for a client who is gone. The
//! worker has one picker and answers one query call at a time; a client who sends a large or
//! costly pick and then disconnects (or times out) used to keep it busy until the whole query
//! was done — on a scene whose rays cost milliseconds each, minutes of every other client's
//! picks waiting. The rays go through in steps instead, and between steps the worker asks
//! whether anyone still waits for the answer (a reply's receiver is dropped with the request's
//! handler when its connection closes). Steps start at [`FIRST`] rays and are sized by
//! [`crate::steps::StepSizer`] to take about [`STEP_TIME`] (growing at most twofold from one to
//! the next, so a large batch on a fast scene is soon one call of many rays, as before); none has
//! fewer than [`FIRST`] or more than [`MOST`]. Each ray's answer does not depend on the rays
//! beside it, so the answers are those of one call.
//!
//! A pick that is wanted but costs too much (a client's million rays through a scene where each
//! costs milliseconds) would hold the worker for hours; once its steps have taken longer than
//! the server's work limit ([`super::ServerConfig::max_work`]) they stop, and what was answered
//! is handed back with the count, so the requests answered in full are served and the rest are
//! told to send fewer rays.

use crate::picker::Picker;
use crate::query::{Answers, Query};
use crate::ray::Ray;
use crate::steps::StepSizer;
use crate::{Error, Result};
use std::time::{Duration, Instant};

/// The first step's rays, and the fewest in any step.
pub(crate) const FIRST: usize = 256;
/// The most rays in any step: the work limit is checked between steps, so a step that grew on
/// cheap rays (misses) cannot run on for long over costly ones after them unchecked.
pub(crate) const MOST: usize = 1 << 18;
/// What a step is sized to take.
const STEP_TIME: Duration = Duration::from_millis(100);

/// How a stepped query ended.
#[derive(Debug)]
pub(crate) enum Stepped {
    /// Every ray was answered.
    Done(Answers),
    /// No one waited for the answers any longer.
    Unwanted,
    /// The steps took longer than the work limit: the answers of the first `answered` rays.
    OverTime { answered: Answers },
}

/// `picker.query(rays, query)` in steps (see the module docs); [`Stepped::Unwanted`] as soon as
/// `wanted` says, between two steps, that no one waits for the answers; [`Stepped::OverTime`]
/// once the steps have taken longer than `max_work` with rays left.
pub(crate) fn query_in_steps(
    picker: &mut dyn Picker,
    rays: &[Ray],
    query: &Query,
    wanted: impl Fn() -> bool,
    max_work: Duration,
) -> Result<Stepped> {
    let mut out = Answers::default();
    let mut steps = StepSizer::new(FIRST, FIRST, MOST, STEP_TIME);
    let mut done = 0;
    let began = Instant::now();
    while done < rays.len() {
        if !wanted() {
            return Ok(Stepped::Unwanted);
        }
        if done > 0 && began.elapsed() > max_work {
            return Ok(Stepped::OverTime { answered: out });
        }
        let end = (done + steps.next()).min(rays.len());
        let start = Instant::now();
        let answers = picker.query(&rays[done..end], query)?;
        if answers.nearest.len() != end - done {
            return Err(Error::Invalid(format!(
                "the picker answered {} of {} rays",
                answers.nearest.len(),
                end - done
            )));
        }
        steps.took(end - done, start.elapsed());
        append(&mut out, answers);
        done = end;
    }
    Ok(Stepped::Done(out))
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
            let stepped = query_in_steps(&mut picker, &rays, &query, || true, FOREVER).unwrap();
            let Stepped::Done(stepped) = stepped else {
                panic!("{stepped:?}");
            };
            assert_eq!(format!("{whole:?}"), format!("{stepped:?}"), "{mode:?}");
            // Over the work limit after the first step: its answers, the whole call's first.
            let over = query_in_steps(&mut picker, &rays, &query, || true, Duration::ZERO);
            let Ok(Stepped::OverTime { answered }) = over else {
                panic!("{over:?}");
            };
            let n = answered.nearest.len();
            assert_eq!(n, FIRST, "{mode:?}");
            let first = picker.query(&rays[..n], &query).unwrap();
            assert_eq!(format!("{first:?}"), format!("{answered:?}"), "{mode:?}");
        }
        let asked = Cell::new(0);
        let gone = query_in_steps(
            &mut picker,
            &rays,
            &Query::default(),
            || {
                asked.set(asked.get() + 1);
                asked.get() < 2
            },
            FOREVER,
        )
        .unwrap();
        assert!(matches!(gone, Stepped::Unwanted), "{gone:?}");
        assert_eq!(asked.get(), 2, "stopped after the first step");
    }

    /// No work limit to speak of.
    const FOREVER: Duration = Duration::from_secs(3600);
}
