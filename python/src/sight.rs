//! `Scene.los` and `Scene.viewshed`: batched nearest-hit queries, as `raypick los` and
//! `raypick viewshed` make them (`src/cli/los.rs`, `raypick::apps::sight`).
//!
//! A segment from A to B is visible when no triangle is hit with t in (ε, 1 − ε) along
//! A + t·(B − A), so surfaces the end points lie on do not block it. Segments with a NaN or
//! infinite end, or both ends equal, are reported as not visible, with a `RuntimeWarning` that
//! counts them (the CLI's warning).

use crate::arrays::{self, Dtype};
use crate::errors::{collect_for, value_error, vec_for};
use crate::pick::{QueryArgs, answer};
use crate::scene::{Scene, parse_name};
use numpy::{IntoPyArray, PyArrayMethods};
use pyo3::exceptions::{PyRuntimeWarning, PyUserWarning};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use raypick::apps::sight::{self, Sight};
use raypick::{Backend, BuiltScene, DVec3, Ray};
use std::ops::Range;

/// What a segment takes while a query runs: its two ends, and its answer.
const SEGMENT_BYTES: u64 = (size_of::<(DVec3, DVec3)>() + size_of::<bool>()) as u64;

/// What a viewshed target takes while the query runs: the target with its label, its segment
/// and answer, and its answer's position and label columns.
const TARGET_BYTES: u64 = (size_of::<(DVec3, [i64; 3])>()
    + SEGMENT_BYTES as usize
    + size_of::<[f64; 3]>()
    + size_of::<[i64; 3]>()) as u64;

/// The checked settings of a line-of-sight query.
pub struct SightArgs {
    epsilon: f64,
    ray_mask: u32,
    backend: Backend,
}

impl SightArgs {
    pub fn parse(epsilon: f64, ray_mask: u32, backend: &str) -> PyResult<Self> {
        if !(0.0..0.5).contains(&epsilon) {
            return Err(value_error(format!(
                "epsilon {} must be in [0, 0.5)",
                raypick::budget::number(epsilon)
            )));
        }
        Ok(Self {
            epsilon,
            ray_mask,
            backend: parse_name("backend", backend)?,
        })
    }
}

/// Whether each segment is visible; warns about invalid ones, calling them `what`s.
fn visible(
    py: Python<'_>,
    scene: &Scene,
    segments: &[(DVec3, DVec3)],
    args: &SightArgs,
    what: &str,
) -> PyResult<Vec<bool>> {
    let eps = args.epsilon;
    let mask = args.ray_mask;
    let read = |range: Range<usize>, out: &mut Vec<Ray>| {
        out.clear();
        out.extend(
            segments[range]
                .iter()
                .map(|&(a, b)| sight::sight_ray(a, b, eps, mask)),
        );
    };
    let query = QueryArgs {
        query: sight::first_query(),
        backend: args.backend,
        ray_mask: args.ray_mask,
    };
    // As the CLI warns: ends so long (an observer far out) that ε skips the scene.
    if let Some(warning) =
        raypick::apps::sight::long_ends(scene.built().bounds(), segments, eps, what, "epsilon")
    {
        py.import("warnings")?
            .call_method1("warn", (warning, py.get_type::<PyUserWarning>(), 1))?;
    }
    let mut seen = vec_for::<bool>(segments.len(), "the visibility column")?;
    let mut invalid = 0usize;
    // The lines whose nearest hit is the surface the observer stands on, asked again.
    let mut again: Vec<usize> = Vec::new();
    answer(py, scene, segments.len(), &read, &query, |answers| {
        invalid += answers.nearest.iter().filter(|h| h.invalid).count();
        let start = seen.len();
        for (j, h) in answers.nearest.iter().enumerate() {
            let judged = sight::judge_nearest(h, eps);
            seen.push(judged == Sight::Visible);
            if judged == Sight::Again {
                again.push(start + j);
            }
        }
        Ok(())
    })?;
    if !again.is_empty() {
        let read_again = |range: Range<usize>, out: &mut Vec<Ray>| {
            out.clear();
            out.extend(again[range].iter().map(|&k| {
                let (a, b) = segments[k];
                sight::sight_ray(a, b, eps, mask)
            }));
        };
        let query = QueryArgs {
            query: sight::second_query(),
            ..query
        };
        let (mut done, mut undecided) = (0, 0);
        answer(py, scene, again.len(), &read_again, &query, |answers| {
            for j in 0..answers.nearest.len() {
                let overflow = answers.overflow.get(j).copied().unwrap_or(false);
                let judged = sight::judge_all(answers.hits_of(j), overflow, eps);
                seen[again[done + j]] = judged == Some(true);
                undecided += usize::from(judged.is_none());
            }
            done += answers.nearest.len();
            Ok(())
        })?;
        if undecided > 0 {
            py.import("warnings")?.call_method1(
                "warn",
                (
                    sight::undecided_warning(undecided, what),
                    py.get_type::<PyRuntimeWarning>(),
                    1,
                ),
            )?;
        }
    }
    if invalid > 0 {
        let message = sight::invalid_warning(invalid, what);
        py.import("warnings")?
            .call_method1("warn", (message, py.get_type::<PyRuntimeWarning>(), 1))?;
    }
    Ok(seen)
}

/// `scene.los(a, b, …)`.
pub fn los<'py>(
    py: Python<'py>,
    scene: &Scene,
    a: &Bound<'py, PyAny>,
    b: &Bound<'py, PyAny>,
    args: &SightArgs,
) -> PyResult<Bound<'py, PyAny>> {
    let a = arrays::rows(a, "a", 3, Dtype::Float64, true)?;
    let b = arrays::rows(b, "b", 3, Dtype::Float64, true)?;
    // Everything the query keeps at once, checked together (each array checked on its own let
    // it take about twice the budget): both ends' points, the segments and the answer.
    // Counted per segment with both its ends (one array of one point costs less: at most this).
    let segments = a.as_array().nrows().max(b.as_array().nrows());
    let per_segment = 2 * size_of::<DVec3>() as u64 + SEGMENT_BYTES;
    raypick::budget::check(
        "the segments with their end points",
        segments as u64,
        per_segment,
    )
    .map_err(crate::errors::to_py)?;
    let (a, b) = (
        arrays::points(a.as_array(), "the points a")?,
        arrays::points(b.as_array(), "the points b")?,
    );
    let what = "the segments";
    let segments: Vec<(DVec3, DVec3)> = match (a.len(), b.len()) {
        (n, m) if n == m => collect_for(n, what, a.into_iter().zip(b))?,
        (1, m) => collect_for(m, what, b.iter().map(|&q| (a[0], q)))?,
        (n, 1) => collect_for(n, what, a.iter().map(|&p| (p, b[0])))?,
        (n, m) => {
            return Err(value_error(format!(
                "a has {n} points but b has {m}; give as many, or one point for every segment"
            )));
        }
    };
    Ok(visible(py, scene, &segments, args, "pair")?
        .into_pyarray(py)
        .into_any())
}

/// `scene.viewshed(observer, targets, target_height, …)`.
pub fn viewshed<'py>(
    py: Python<'py>,
    scene: &Scene,
    observer: &Bound<'py, PyAny>,
    targets: Option<&Bound<'py, PyAny>>,
    target_height: f64,
    args: &SightArgs,
) -> PyResult<Bound<'py, PyDict>> {
    let observer = arrays::rows(observer, "observer", 3, Dtype::Float64, true)?;
    let observer = arrays::points(observer.as_array(), "the observer")?;
    let [observer] = observer.as_slice() else {
        return Err(value_error(format!(
            "observer must be one point (x, y, z); got {} points",
            observer.len()
        )));
    };
    if !observer.is_finite() {
        return Err(value_error(format!(
            "observer ({}, {}, {}) is not finite; give finite numbers",
            raypick::budget::number(observer.x),
            raypick::budget::number(observer.y),
            raypick::budget::number(observer.z)
        )));
    }
    if !target_height.is_finite() {
        return Err(value_error(format!(
            "target_height {} is not finite; give a finite number",
            raypick::budget::number(target_height)
        )));
    }
    let lift = DVec3::Z * target_height;
    // Everything the query keeps per target at once, checked together (each column checked on
    // its own let it take about three times the budget).
    let check_targets = |n: usize| {
        raypick::budget::check(
            "the targets with their segments and columns",
            n as u64,
            TARGET_BYTES,
        )
        .map_err(crate::errors::to_py)
    };
    // (target, [object, row, col]) pairs; −1 for given targets.
    let targets: Vec<(DVec3, [i64; 3])> = match targets.filter(|t| !t.is_none()) {
        Some(given) => {
            let given = arrays::rows(given, "targets", 3, Dtype::Float64, true)?;
            let given = given.as_array();
            check_targets(given.nrows())?;
            let rows = given.rows().into_iter();
            let labelled = rows.map(|r| (DVec3::new(r[0], r[1], r[2]) + lift, [-1; 3]));
            collect_for(given.nrows(), "the targets", labelled)?
        }
        None => grid_targets(scene.built(), lift)?,
    };
    let n = targets.len();
    check_targets(n)?;
    let segments = collect_for(
        n,
        "the segments",
        targets.iter().map(|(t, _)| (*observer, *t)),
    )?;
    let seen = visible(py, scene, &segments, args, "target")?;
    let dict = PyDict::new(py);
    let position = collect_for(
        3 * n,
        "the position column",
        targets.iter().flat_map(|(p, _)| p.to_array()),
    )?;
    dict.set_item("position", position.into_pyarray(py).reshape([n, 3])?)?;
    for (k, key) in ["object", "row", "col"].into_iter().enumerate() {
        let column = collect_for(
            n,
            "a label column",
            targets.iter().map(|(_, label)| label[k]),
        )?;
        dict.set_item(key, column.into_pyarray(py))?;
    }
    dict.set_item("visible", seen.into_pyarray(py))?;
    Ok(dict)
}

/// Every sample of every terrain grid that a hittable triangle uses (NODATA samples are
/// skipped), labelled `[object, row, col]`: the CLI's default viewshed targets.
fn grid_targets(built: &BuiltScene, lift: DVec3) -> PyResult<Vec<(DVec3, [i64; 3])>> {
    let scene = &built.scene;
    let mut targets = Vec::new();
    for object in scene.objects() {
        let Some(grid) = object.grid else { continue };
        let (cols, rows) = (grid.columns as usize, grid.rows as usize);
        let mut used = vec![false; cols * rows];
        for t in 0..object.triangle_count {
            if !scene.is_degenerate((object.first_triangle + t) as usize) {
                let (r, c) = grid.cell_of(t);
                let (r, c) = (r as usize, c as usize);
                for (dr, dc) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                    if let Some(u) = used.get_mut((r + dr) * cols + c + dc) {
                        *u = true;
                    }
                }
            }
        }
        for (sample, _) in used.iter().enumerate().filter(|(_, u)| **u) {
            let p = scene.position(object.first_vertex as usize + sample);
            let (r, c) = (sample / cols, sample % cols);
            targets.push((p + lift, [i64::from(object.id), r as i64, c as i64]));
        }
    }
    if targets.is_empty() {
        return Err(value_error("the scene has no terrain grid: give targets"));
    }
    Ok(targets)
}
