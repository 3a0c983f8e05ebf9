//! raypick for Python: numpy in, numpy out.
//!
//! The extension module `raypick._raypick`, re-exported by the `raypick` package
//! (`python/raypick/__init__.py`). Each file is one concept:
//!
//! - [`scene`]: `raypick.Scene` — loading (files, arrays, `.rpk`), saving, and the pickers;
//! - [`pick`]: `Scene.pick` — the query, the rays in, the answers out;
//! - [`sight`]: `Scene.los` and `Scene.viewshed`, as batched nearest-hit queries (what `raypick los`
//!   and `raypick viewshed` do);
//! - [`camera`]: `raypick.camera_rays` — the CLI's camera JSON, pixels to rays;
//! - [`arrays`]: numpy arrays in, checked: shapes and dtypes, one `ValueError` sentence each;
//! - [`int_arg`]: integer arguments in (`leaf_size`, `max_hits`, masks, …): ints and numpy
//!   integers, not bools, checked against their ranges;
//! - [`columns`]: hits out, as numpy columns named like the CLI's CSV columns;
//! - [`interrupt`]: Ctrl-C during a long pick, checked for between its batches;
//! - [`errors`]: the library's errors as Python exceptions (`OSError` for files, `ValueError`
//!   otherwise, with the library's sentence);
//! - [`threads`]: how many threads a process traces with (the Dask workers' share of a machine);
//! - [`memory`]: the process's memory budget (the command line's `--max-memory`).
//!
//! Tracing runs with the interpreter released (`Python::detach`), so other Python threads run
//! meanwhile; nothing here panics on user input.

mod arrays;
mod camera;
mod columns;
mod errors;
mod float_arg;
mod int_arg;
mod interrupt;
mod memory;
mod name_arg;
mod pick;
mod scene;
mod sight;
mod threads;

use pyo3::prelude::*;

/// The compiled half of the `raypick` package.
#[pymodule]
fn _raypick(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<scene::Scene>()?;
    m.add_function(wrap_pyfunction!(camera::camera_rays, m)?)?;
    m.add_function(wrap_pyfunction!(threads::set_threads, m)?)?;
    m.add_function(wrap_pyfunction!(memory::set_max_memory, m)?)?;
    m.add_function(wrap_pyfunction!(memory::max_memory, m)?)?;
    m.add_function(wrap_pyfunction!(threads::threads, m)?)?;
    Ok(())
}
