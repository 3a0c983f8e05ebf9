//! `Scene.pick`: the query's settings, the rays in, the answers out.
//!
//! Rays are answered in batches: on the CPU of up to [`CPU_BATCH`] rays (converted, traced and
//! written out one batch after the other, so a batch stays in the processor's cache), on a GPU
//! of up to [`GPU_BATCH`]. Every batch fits half the library's memory budget, as the CLI's
//! `--mode all` does; the answer columns are checked against it before they are made, and the
//! all-hits lists, which grow with the hits found, each time they grow (a `ValueError` naming
//! the budget once they would pass it).
//!
//! Between batches a pick runs Python's signal handlers ([`crate::interrupt`]), so Ctrl-C stops
//! it soon: a pick starts with a batch of [`FIRST`] rays, and each batch after is sized from
//! the one before to take about [`BATCH_TIME`] (by the library's [`raypick::steps::StepSizer`],
//! as the server sizes its steps: at most twice the batch before, so a batch of cheap rays
//! followed by costly ones does not make one long batch), within [`FEWEST`] and the sizes
//! above. Batches of those sizes
//! took seconds on costly rays: in a stack of 20,000 triangles that a ray passes beside, each
//! ray cost 80 µs on two cores (2.6 s a 32,768-ray batch); on a software GPU (lavapipe), a
//! batch of 3M bunny rays took over 45 s. Each ray's answer does not depend on the rays beside
//! it (the automatic backend answers batches below its crossover on the CPU, with the GPU's
//! bits), so the answers are those of one call.

use crate::arrays;
use crate::columns::{Columns, Lists, Shape};
use crate::errors::{to_py, vec_for};
use crate::int_arg;
use crate::interrupt::Interrupts;
use crate::scene::{Scene, log_notes, parse_name};
use crate::threads;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use raypick::query::MAX_HITS_LIMIT;
use raypick::steps::StepSizer;
use raypick::{Backend, Mode, Query, Ray};
use std::ops::Range;
use std::time::{Duration, Instant};

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
    /// Parses the names (as the CLI spells them) and checks the query.
    pub fn parse(
        mode: &str,
        max_hits: u32,
        cull: &str,
        ray_mask: u32,
        intersector: &str,
        backend: &str,
    ) -> PyResult<Self> {
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
            ray_mask,
        })
    }
}

/// `max_hits=`: an integer in 1 ..= 1024.
pub fn max_hits(value: &Bound<'_, PyAny>) -> PyResult<u32> {
    int_arg::integer(value, "max_hits", 1..=MAX_HITS_LIMIT, |v| {
        format!("max_hits {v} is out of range; it must be 1 ..= {MAX_HITS_LIMIT}")
    })
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
/// than it gained.
pub const CPU_BATCH: usize = 1 << 15;

/// Rays per batch of a pick on a GPU, at most (fewer when half the memory budget holds fewer):
/// about 60 ms of an NVIDIA H200's picking at 15 ns a ray (BENCHMARKS.md, "A real GPU"), next to
/// which a batch's dispatch and readback (0.7 ms) are small.
pub const GPU_BATCH: usize = 1 << 22;

/// The first batch's rays: a pick of up to 4,096 rays (an interactive one) is one batch, and a
/// first batch of costly rays still ends soon (0.3 s at 80 µs a ray).
pub const FIRST: usize = 1 << 12;

/// The fewest rays in a batch after the first: a batch of rays that cost a millisecond each (a
/// scene the tree cannot cut up, many hits wanted, a software GPU) still ends soon.
pub const FEWEST: usize = 256;

/// What a batch after the first is sized to take, from the time per ray of the one before
/// (within [`FEWEST`] ..= [`CPU_BATCH`] or [`GPU_BATCH`]).
pub const BATCH_TIME: Duration = Duration::from_millis(100);

/// The batches of a pick of `query` on the CPU, or on a GPU when `gpu`.
fn batches(query: &Query, gpu: bool) -> StepSizer {
    let most = if gpu { GPU_BATCH } else { CPU_BATCH }.min(batch_rays(query));
    StepSizer::new(FIRST, FEWEST, most, BATCH_TIME)
}

/// Answers rays `0..n`, made by `read` a batch at a time, without the interpreter, handing
/// each batch's answers to `sink` in ray order (the same buffers, batch after batch); between
/// batches, runs Python's signal handlers and stops with what they raise (Ctrl-C).
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
        scene.trace(args.backend, |picker, gpu| {
            let mut batches = batches(&query, gpu);
            let mut rays = vec_for::<Ray>(batches.most().min(n), "the rays")?;
            // One answer buffer for every batch: a fresh one per batch faulted its pages in
            // anew wherever the allocator returns such blocks to the OS on free, as in a
            // Dask worker (`MALLOC_TRIM_THRESHOLD_`): 23% of a 1M-ray pick.
            let mut answers = raypick::Answers::default();
            let mut interrupts = Interrupts::new();
            let mut start = 0;
            while start < n {
                let end = start + batches.next().min(n - start);
                let began = Instant::now();
                // On the process's pool; the signal checks stay on this thread, which may be
                // Python's main thread.
                threads::run(|| -> PyResult<()> {
                    read(start..end, &mut rays);
                    picker
                        .query_into(&rays, &query, &mut answers)
                        .map_err(to_py)?;
                    sink(&answers)
                })??;
                batches.took(end - start, began.elapsed());
                start = end;
                if start < n {
                    interrupts.check()?;
                }
            }
            Ok(())
        })
    });
    log_notes(py, notes)?;
    result
}
