//! `Scene.pick`: the query's settings, the rays in, the answers out.
//!
//! Rays are answered in batches: on the CPU of [`CPU_BATCH`] rays (converted, traced and
//! written out one batch after the other, so a batch stays in the processor's cache), on a GPU
//! of as many as fit half the library's memory budget. Every batch fits that budget, as the
//! CLI's `--mode all` does; the answer columns are checked against it before they are made, and
//! the all-hits lists, which grow with the hits found, each time they grow (a `ValueError`
//! naming the budget once they would pass it).

use crate::arrays;
use crate::columns::{Columns, Lists, Shape};
use crate::errors::{to_py, value_error, vec_for};
use crate::scene::{Scene, log_notes, mask, parse_name};
use crate::threads;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use raypick::query::MAX_HITS_LIMIT;
use raypick::{Backend, Mode, Query, Ray};
use std::ops::Range;

/// The checked settings of one pick.
pub struct QueryArgs {
    /// Mode, culling, list length, intersector.
    pub query: Query,
    /// Which picker answers.
    pub backend: Backend,
    /// Every ray's layer mask.
    pub ray_mask: u32,
}

impl QueryArgs {
    /// Parses the names (as the CLI spells them) and checks the numbers.
    pub fn parse(
        mode: &str,
        max_hits: i64,
        cull: &str,
        ray_mask: i64,
        intersector: &str,
        backend: &str,
    ) -> PyResult<Self> {
        let max_hits = u32::try_from(max_hits)
            .ok()
            .filter(|k| (1..=MAX_HITS_LIMIT).contains(k))
            .ok_or_else(|| {
                value_error(format!(
                    "max hits {max_hits} is out of range; it must be 1 ..= {MAX_HITS_LIMIT}"
                ))
            })?;
        let query = Query {
            mode: parse_name("mode", mode)?,
            cull: parse_name("cull", cull)?,
            max_hits,
            intersector: parse_name("intersector", intersector)?,
        };
        query.validate().map_err(to_py)?;
        Ok(Self {
            query,
            backend: parse_name("backend", backend)?,
            ray_mask: mask("ray_mask", ray_mask)?,
        })
    }
}

/// Rays per batch: as many as fit half the memory budget.
pub fn batch_rays(query: &Query) -> usize {
    let per_ray = query.bytes_per_ray().max(1);
    usize::try_from(raypick::budget::limit() / 2 / per_ray)
        .unwrap_or(usize::MAX)
        .max(1)
}

/// `scene.pick(rays, …)`.
pub fn pick<'py>(
    py: Python<'py>,
    scene: &Scene,
    rays: &Bound<'py, PyAny>,
    args: &QueryArgs,
    tmin: f64,
    tmax: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let arrays = arrays::RayArrays::new(rays)?;
    let reader = arrays.reader(tmin, tmax, args.ray_mask);
    let n = reader.len();
    let read = |range: Range<usize>, out: &mut Vec<Ray>| reader.read(range, out);
    let dict = PyDict::new(py);
    match args.query.mode {
        Mode::Closest | Mode::Any => {
            let shape = Shape {
                fields: args.query.mode == Mode::Closest,
                cells: scene.has_grid(),
            };
            let mut columns = Columns::new(n, shape)?;
            answer(py, scene, n, &read, args, |answers| {
                columns.fill(&answers.nearest);
                Ok(())
            })?;
            columns.into_dict(&dict)?;
        }
        Mode::All => {
            let mut lists = Lists::new(n, scene.has_grid())?;
            answer(py, scene, n, &read, args, |answers| lists.add(answers))?;
            lists.into_dict(&dict)?;
        }
    }
    Ok(dict)
}

/// Rays per batch of a pick on the CPU: small enough that a batch's rays and answers stay in
/// the processor's cache between the steps (conversion, trace, columns). Measured on the 1M
/// camera and incoherent sets of the bunny, the dragon and the DEM (BENCHMARKS.md): 32,768 rays
/// a batch picked 1.1–1.3× as fast as one 1M batch, and as fast as 16,384 or 65,535; it is
/// below the batch size from which the pipeline reorders rays, which on these sets cost more
/// than it gained. A GPU gets the largest batch that fits the memory budget.
pub const CPU_BATCH: usize = 1 << 15;

/// Answers rays `0..n`, made by `read` a batch at a time, without the interpreter, handing
/// each batch's answers to `sink` in ray order (the same buffers, batch after batch).
pub fn answer(
    py: Python<'_>,
    scene: &Scene,
    n: usize,
    read: &(dyn Fn(Range<usize>, &mut Vec<Ray>) + Sync),
    args: &QueryArgs,
    mut sink: impl FnMut(&raypick::Answers) -> PyResult<()> + Send,
) -> PyResult<()> {
    let query = args.query;
    let (result, notes) = py.detach(|| {
        threads::run(|| {
            scene.trace(args.backend, |picker, gpu| {
                let most = batch_rays(&query);
                let batch = if gpu { most } else { most.min(CPU_BATCH) };
                let mut rays = vec_for::<Ray>(batch.min(n), "the rays")?;
                // One answer buffer for every batch: a fresh one per batch faulted its pages in
                // anew wherever the allocator returns such blocks to the OS on free, as in a
                // Dask worker (`MALLOC_TRIM_THRESHOLD_`): 23% of a 1M-ray pick.
                let mut answers = raypick::Answers::default();
                for start in (0..n).step_by(batch) {
                    read(start..(start + batch).min(n), &mut rays);
                    picker
                        .query_into(&rays, &query, &mut answers)
                        .map_err(to_py)?;
                    sink(&answers)?;
                }
                Ok(())
            })
        })
    });
    log_notes(py, notes)?;
    result
}
