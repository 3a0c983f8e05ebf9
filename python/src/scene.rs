//! `raypick.Scene`: a built scene (loaded from the files the CLI reads, from numpy arrays, or
//! from a saved `.rpk`), its pickers, and the methods Python calls.

use crate::arrays::{self, Dtype};
use crate::errors::{to_py, value_error};
use crate::float_arg;
use crate::int_arg::{self, Integer};
use crate::name_arg;
use crate::pick::{self, QueryArgs};
use crate::sight::{self, SightArgs};
use crate::threads;
use numpy::ToPyArray;
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyString};
use raypick::auto::AutoPicker;
use raypick::io::scene_files::{Loaded, SceneFile, load_description, load_instanced};
use raypick::{
    Backend, BuildOptions, Builder, BuiltScene, CpuPicker, Mesh, Picker, ReferencePicker, rpk,
};
use std::collections::HashSet;
use std::path::PathBuf;
use std::sync::{Arc, Mutex, OnceLock, PoisonError};

/// A scene and its tree, ready to pick. Load one with `Scene.load(paths)` or make one with
/// `Scene.from_arrays(vertices, triangles)`.
#[pyclass(name = "Scene", module = "raypick", frozen)]
pub struct Scene {
    /// What `pick` answers on: an instanced scene where a file is listed several times or
    /// glTF nodes share a mesh, as the CLI's `pick` builds it.
    built: Arc<BuiltScene>,
    /// How an instanced scene's copies are built for `los` and `viewshed`.
    options: BuildOptions,
    /// An instanced scene's instances baked into objects, for `los` and `viewshed`, which pick
    /// copies as the CLI's `los` and `viewshed` do: made on first use.
    baked: OnceLock<Box<Scene>>,
    /// Held while `baked` is made, so that two threads do not bake at once.
    baking: Mutex<()>,
    /// The GPU picker (`backend="gpu"`), made on first use: it holds the scene's buffers;
    /// with the process that made it (a forked child cannot use its parent's device).
    gpu: Mutex<Option<(u32, Box<dyn Picker + Send>)>>,
    /// What `backend="auto"` resolved to on first use.
    auto: Mutex<Auto>,
}

/// The automatic backend of a scene.
enum Auto {
    /// Not used yet.
    Unopened,
    /// No GPU, or a software one: the CPU engine answers everything (no lock needed).
    Cpu,
    /// A real GPU for large batches: the library's automatic picker, with the process that
    /// made it.
    Picker(u32, Box<dyn Picker + Send>),
}

/// `picker` (made by process `owner`) if this process made it; else it was inherited by a
/// forked child and is let go, never dropped here: closing the parent's device from the child
/// is not the child's to do (the child's first GPU pick on a scene its parent had picked on
/// waited for ever).
fn own<T>(owner: u32, picker: T) -> Option<T> {
    if owner == std::process::id() {
        return Some(picker);
    }
    std::mem::forget(picker);
    None
}

impl Scene {
    fn new(built: BuiltScene, options: BuildOptions) -> Self {
        Self {
            built: Arc::new(built),
            options,
            baked: OnceLock::new(),
            baking: Mutex::new(()),
            gpu: Mutex::new(None),
            auto: Mutex::new(Auto::Unopened),
        }
    }

    /// The built scene.
    pub fn built(&self) -> &Arc<BuiltScene> {
        &self.built
    }

    /// Whether some object is a terrain grid (answers then carry `row` and `col`).
    pub fn has_grid(&self) -> bool {
        self.built.has_grid()
    }

    /// The scene `los` and `viewshed` answer on: this one, or an instanced scene's copies
    /// (the same objects, ids and names), built on first use as the CLI's `los` builds them.
    pub fn for_sight(&self, py: Python<'_>) -> PyResult<&Scene> {
        let Some(instances) = self.built.instances() else {
            return Ok(self);
        };
        if let Some(baked) = self.baked.get() {
            return Ok(baked);
        }
        // The grid builder needs one grid, which copies of a grid listed twice are not: "auto"
        // takes the grid builder where it can (every builder gives the same answers).
        let mut options = self.options;
        if options.builder == Builder::Grid {
            options.builder = Builder::Auto;
        }
        // One thread bakes; another asking meanwhile waits for it (taken without the
        // interpreter, which the baking thread does not hold either).
        let made = py.detach(|| {
            let _baking = self.baking.lock().unwrap_or_else(PoisonError::into_inner);
            if self.baked.get().is_some() {
                return Ok(None);
            }
            threads::run(|| {
                // Every instance's world triangles are copied: checked before they are made, as
                // a description's copies are.
                instances.check_bake("baking the instances into copies for los and viewshed")?;
                BuiltScene::new(instances.baked()?, &options)
            })?
            .map_err(to_py)
            .map(|built| {
                let _ = self.baked.set(Box::new(Scene::new(built, options)));
                Some(())
            })
        })?;
        let baked = self
            .baked
            .get()
            .expect("made above or by the thread that held the lock");
        // The copies' own frame warnings, as the CLI's `los` gives them (once, by the thread
        // that made them).
        if made.is_some() {
            warn_frame(py, baked.built())?;
        }
        Ok(baked)
    }

    /// Runs `work` on `backend`'s picker, telling it whether the picker may run on a GPU (call
    /// it without the interpreter). Also returns the automatic backend's notes for the caller
    /// to log: what it chose when it opened (no GPU, a software GPU: informational) and what
    /// happened while it traced (a GPU failure and the CPU fallback: a warning).
    pub fn trace<R>(
        &self,
        backend: Backend,
        work: impl FnOnce(&mut (dyn Picker + Send), bool) -> PyResult<R>,
    ) -> (PyResult<R>, Vec<Note>) {
        let mut notes = Vec::new();
        let built = &self.built;
        // A pick from a signal handler that runs between this thread's batches of another
        // pick ([`crate::interrupt`]) would wait for the picker that pick holds, for ever: it is
        // answered on the CPU engine instead (the same answers, bit for bit).
        let backend = match HOLDS_PICKER.get() {
            true => Backend::Cpu,
            false => backend,
        };
        let _holds = HoldsPicker::new();
        let result = match backend {
            Backend::Cpu => work(&mut CpuPicker::new(built.clone()), false),
            Backend::Reference => work(&mut ReferencePicker::new(built.clone()), false),
            Backend::Gpu => {
                let mut slot = self.gpu.lock().unwrap_or_else(PoisonError::into_inner);
                *slot = slot
                    .take()
                    .and_then(|(owner, picker)| own(owner, picker).map(|p| (owner, p)));
                if slot.is_none() {
                    match raypick::make_picker(Backend::Gpu, built.clone()) {
                        Ok(picker) => *slot = Some((std::process::id(), picker)),
                        Err(e) => return (Err(to_py(e)), notes),
                    }
                }
                match slot.as_mut() {
                    // Its notes: the shared device lost and opened again.
                    Some((_, picker)) => {
                        let result = work(picker.as_mut(), true);
                        notes.extend(picker.take_notes().into_iter().map(Note::Fell));
                        result
                    }
                    None => Err(value_error("the GPU picker could not be made")),
                }
            }
            Backend::Auto => {
                let mut state = self.auto.lock().unwrap_or_else(PoisonError::into_inner);
                *state = match std::mem::replace(&mut *state, Auto::Unopened) {
                    Auto::Picker(owner, picker) => own(owner, picker)
                        .map_or(Auto::Unopened, |picker| Auto::Picker(owner, picker)),
                    other => other,
                };
                if let Auto::Unopened = *state {
                    let mut picker = AutoPicker::new(built.clone());
                    notes.extend(picker.take_notes().into_iter().map(Note::Chose));
                    *state = if picker.crossover() == usize::MAX {
                        Auto::Cpu
                    } else {
                        Auto::Picker(std::process::id(), Box::new(picker))
                    };
                }
                match &mut *state {
                    Auto::Picker(_, picker) => {
                        let result = work(picker.as_mut(), true);
                        notes.extend(picker.take_notes().into_iter().map(Note::Fell));
                        result
                    }
                    _ => {
                        drop(state);
                        work(&mut CpuPicker::new(built.clone()), false)
                    }
                }
            }
        };
        (result, notes)
    }
}

thread_local! {
    /// Whether this thread is inside [`Scene::trace`] (and may hold a shared picker's lock).
    static HOLDS_PICKER: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Marks this thread as inside [`Scene::trace`] until dropped (restoring what it was).
struct HoldsPicker(bool);

impl HoldsPicker {
    fn new() -> Self {
        Self(HOLDS_PICKER.replace(true))
    }
}

impl Drop for HoldsPicker {
    fn drop(&mut self) {
        HOLDS_PICKER.set(self.0);
    }
}

/// A note of the automatic backend.
pub enum Note {
    /// What it chose when it opened (no GPU, or a software one: the CPU answers).
    Chose(String),
    /// What happened while it traced (the GPU failed and the CPU answered instead, or the
    /// device was lost and opened again).
    Fell(String),
}

/// Warns (a `UserWarning` each) about what the scene's single-precision frames cannot hold, as
/// the CLI warns on standard error ([`raypick::frame::faults`]): picks on those parts would be
/// missed or off without a word (a scene 10¹⁴ units across missed most of its hits).
fn warn_frame(py: Python<'_>, built: &BuiltScene) -> PyResult<()> {
    let warnings = py.detach(|| threads::run(|| raypick::frame::faults::frame_warnings(built)))?;
    warn_all(py, warnings)
}

/// Raises each of `warnings` as a `UserWarning`, in order.
fn warn_all(py: Python<'_>, warnings: Vec<String>) -> PyResult<()> {
    let category = py.get_type::<pyo3::exceptions::PyUserWarning>();
    for warning in warnings {
        let text = std::ffi::CString::new(warning.replace('\0', "\\0"))?;
        PyErr::warn(py, &category, &text, 1)?;
    }
    Ok(())
}

/// Logs each note of the automatic backend once per process through
/// `logging.getLogger("raypick")`, where the CLI says them on standard error: its choices at
/// INFO (silent unless logging is configured), its fallbacks at WARNING.
pub fn log_notes(py: Python<'_>, notes: Vec<Note>) -> PyResult<()> {
    static SAID: Mutex<Option<HashSet<String>>> = Mutex::new(None);
    for note in notes {
        let (level, text) = match note {
            Note::Chose(text) => ("info", text),
            Note::Fell(text) => ("warning", text),
        };
        let new = SAID
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .get_or_insert_with(HashSet::new)
            .insert(text.clone());
        if new {
            py.import("logging")?
                .call_method1("getLogger", ("raypick",))?
                .call_method1(level, (text,))?;
        }
    }
    Ok(())
}

/// A name the library parses (mode, cull, builder, …), or a `ValueError` naming the argument.
pub fn parse_name<T: std::str::FromStr<Err = String>>(argument: &str, value: &str) -> PyResult<T> {
    value
        .parse()
        .map_err(|e: String| value_error(format!("{argument}: {e}")))
}

/// The builder settings of `builder=` and `leaf_size=`, the defaults for those not given.
fn build_options(builder: Option<&str>, leaf_size: Option<u32>) -> PyResult<BuildOptions> {
    let default = BuildOptions::default();
    Ok(BuildOptions {
        builder: match builder {
            Some(name) => parse_name::<Builder>("builder", name)?,
            None => default.builder,
        },
        leaf_size: leaf_size.unwrap_or(default.leaf_size),
        ..default
    })
}

/// `leaf_size=`: an integer in 1 ..= 15.
fn leaf_size(value: &Bound<'_, PyAny>) -> PyResult<u32> {
    let most = raypick::layout::MAX_LEAF_SIZE;
    int_arg::integer(value, "leaf_size", 1..=most, |v| {
        format!("leaf_size {v} is out of range; it must be 1 ..= {most}")
    })
}

/// `leaf_size=` of `Scene.load`: as [`leaf_size`], or None (not given).
fn leaf_size_or_none(value: &Bound<'_, PyAny>) -> PyResult<Option<u32>> {
    if value.is_none() {
        return Ok(None);
    }
    leaf_size(value).map(Some)
}

/// A layer mask argument: an integer in 0 ..= 0xFFFFFFFF.
pub fn mask(argument: &str, value: &Bound<'_, PyAny>) -> PyResult<u32> {
    int_arg::integer(value, argument, 0..=u32::MAX, |v| {
        format!("{argument} {v} is out of range; it must be 0 ..= 0xFFFFFFFF")
    })
}

/// `ray_mask=`: every ray's layer mask.
pub fn ray_mask(value: &Bound<'_, PyAny>) -> PyResult<u32> {
    mask("ray_mask", value)
}

/// `paths`: one path (str or os.PathLike) or a sequence of them.
fn path_list(paths: &Bound<'_, PyAny>) -> PyResult<Vec<PathBuf>> {
    if let Ok(one) = paths.extract::<PathBuf>() {
        return Ok(vec![one]);
    }
    let wrong = || {
        value_error(format!(
            "paths must be a path or a list of paths; got {}",
            paths
                .get_type()
                .name()
                .map(|n| n.to_string())
                .unwrap_or_default()
        ))
    };
    let items = paths.try_iter().map_err(|_| wrong())?;
    // An item that is not a path is named by its place ("got list" named the list).
    items
        .enumerate()
        .map(|(k, item)| {
            let item = item?;
            item.extract::<PathBuf>().map_err(|_| {
                value_error(format!(
                    "paths[{k}] must be a path (str or os.PathLike); got {}",
                    item.get_type()
                        .name()
                        .map(|n| n.to_string())
                        .unwrap_or_default()
                ))
            })
        })
        .collect()
}

/// `masks`: None, one mask for a single path, or one mask (or None) per path. A list of the
/// wrong length is a `ValueError`; what is neither an integer nor a list (a float, a string),
/// or an item that is neither an integer nor None, is a `TypeError`.
fn mask_list(masks: Option<&Bound<'_, PyAny>>, count: usize) -> PyResult<Vec<Option<u32>>> {
    let Some(masks) = masks.filter(|m| !m.is_none()) else {
        return Ok(vec![None; count]);
    };
    let plural = if count == 1 { "" } else { "s" };
    let expected =
        format!("a list of {count} mask{plural} (an integer or None each), one per path");
    let wrong_count = || value_error(format!("masks must be {expected}"));
    let within = |one: Integer| {
        one.within(0..=u32::MAX, |v| {
            format!("mask {v} is out of range; it must be 0 ..= 0xFFFFFFFF")
        })
    };
    if let Some(one) = Integer::of(masks, "mask")? {
        if count != 1 {
            return Err(wrong_count());
        }
        return Ok(vec![Some(within(one)?)]);
    }
    let wrong_type = || {
        let kind = masks
            .get_type()
            .name()
            .map(|n| n.to_string())
            .unwrap_or_default();
        let one = if count == 1 { "an integer or " } else { "" };
        PyTypeError::new_err(format!("masks must be {one}{expected}, not {kind}"))
    };
    if masks.is_instance_of::<PyString>() {
        return Err(wrong_type());
    }
    let items: Vec<Bound<'_, PyAny>> = masks
        .try_iter()
        .map_err(|_| wrong_type())?
        .collect::<PyResult<_>>()?;
    if items.len() != count {
        return Err(wrong_count());
    }
    items
        .iter()
        .map(|m| {
            if m.is_none() {
                return Ok(None);
            }
            match Integer::of(m, "mask")? {
                Some(one) => within(one).map(Some),
                None => Err(crate::int_arg::not_an_integer(m, "mask")),
            }
        })
        .collect()
}

fn is_description(path: &std::path::Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
}

#[pymethods]
impl Scene {
    /// Scene.load(paths, masks=None, builder=None, leaf_size=None)
    ///
    /// Loads the files the CLI reads (OBJ, PLY, STL, glTF, ESRI ASCII grids, GeoTIFF; a `.json`
    /// scene description; a saved `.rpk`, alone) and builds the tree. `masks` gives each path's
    /// layer mask (an integer or None). Object ids follow the order of the files. `builder`
    /// and `leaf_size` (by default "auto" and 8) choose how the tree is built; a saved `.rpk`
    /// is already built, with its trees, and refuses them.
    #[staticmethod]
    #[pyo3(signature = (paths, masks=None, builder=None, leaf_size=None))]
    fn load(
        py: Python<'_>,
        paths: &Bound<'_, PyAny>,
        masks: Option<&Bound<'_, PyAny>>,
        #[pyo3(from_py_with = name_arg::builder_or_none)] builder: Option<&str>,
        #[pyo3(from_py_with = leaf_size_or_none)] leaf_size: Option<u32>,
    ) -> PyResult<Scene> {
        let paths = path_list(paths)?;
        if paths.is_empty() {
            return Err(value_error("paths is empty; give at least one scene file"));
        }
        let masks = mask_list(masks, paths.len())?;
        if paths.iter().any(|p| rpk::has_rpk_extension(p)) {
            if paths.len() > 1 {
                return Err(value_error(
                    "an .rpk file holds a whole built scene; load it alone, not with other files",
                ));
            }
            if masks[0].is_some() {
                return Err(value_error(
                    "an .rpk file keeps the masks it was saved with; load it without masks",
                ));
            }
            let given: Vec<&str> = [
                ("builder", builder.is_some()),
                ("leaf_size", leaf_size.is_some()),
            ]
            .into_iter()
            .filter_map(|(name, given)| given.then_some(name))
            .collect();
            if !given.is_empty() {
                // As the CLI refuses --builder and --leaf-size with a `.rpk`.
                return Err(value_error(format!(
                    "{} is a built scene (.rpk) with its trees: {} {} when building from a \
                     scene's files, not to a saved scene; load it without {}",
                    paths[0].display(),
                    given.join(" and "),
                    if given.len() == 1 { "applies" } else { "apply" },
                    given.join(" or ")
                )));
            }
            let path = paths[0].clone();
            let built = py
                .detach(|| threads::run(|| rpk::load(&path)))?
                .map_err(to_py)?;
            // The warnings the scene gave when it was built, given again (as the CLI does).
            warn_frame(py, &built)?;
            // A saved instanced scene is picked as its instances, as the CLI's `pick` picks
            // it; `los` and `viewshed` bake its copies as by default (as the CLI's do).
            return Ok(Scene::new(built, BuildOptions::default()));
        }
        let options = build_options(builder, leaf_size)?;
        // The readers' warnings (a file that gave no triangle, …) are collected on the thread
        // that reads and raised below as `UserWarning`s, not written on standard error.
        let (built, said) = py.detach(|| {
            threads::run(|| {
                raypick::io::warnings::collect(|| -> PyResult<BuiltScene> {
                    let mut files = Vec::new();
                    for (path, mask) in paths.iter().zip(&masks) {
                        if is_description(path) {
                            if mask.is_some() {
                                return Err(value_error(format!(
                                    "{}: a scene description gives its files' masks itself; \
                                     give None as its mask",
                                    path.display()
                                )));
                            }
                            files.extend(load_description(path).map_err(to_py)?);
                        } else {
                            files.push(SceneFile {
                                file: path.clone(),
                                mask: *mask,
                                transform: None,
                            });
                        }
                    }
                    // As the CLI's `pick` loads it: a file listed several times, or glTF nodes
                    // sharing a mesh, built once per mesh and placed by its transforms.
                    match load_instanced(&files).map_err(to_py)? {
                        Loaded::Copies(scene) => BuiltScene::new(scene, &options),
                        Loaded::Instanced(meshes, instances) => {
                            BuiltScene::instanced(meshes, instances, &options)
                        }
                    }
                    .map_err(to_py)
                })
            })
        })?;
        warn_all(py, said)?;
        let built = built?;
        warn_frame(py, &built)?;
        Ok(Scene::new(built, options))
    }

    /// Scene.from_arrays(vertices, triangles, builder="auto", leaf_size=8)
    ///
    /// One object (id 0) from float64 vertices (V, 3) and integer triangles (T, 3).
    #[staticmethod]
    #[pyo3(signature = (vertices, triangles, builder="auto", leaf_size=8))]
    fn from_arrays(
        py: Python<'_>,
        vertices: &Bound<'_, PyAny>,
        triangles: &Bound<'_, PyAny>,
        #[pyo3(from_py_with = name_arg::builder)] builder: &str,
        #[pyo3(from_py_with = leaf_size)] leaf_size: u32,
    ) -> PyResult<Scene> {
        let options = build_options(Some(builder), Some(leaf_size))?;
        let vertices = arrays::rows(vertices, "vertices", 3, Dtype::Float64, false)?;
        let positions = arrays::points(vertices.as_array(), "the vertices")?;
        let triangles = arrays::triangles(triangles)?;
        let mesh = Mesh {
            positions,
            triangles,
        };
        let built = py
            .detach(|| {
                threads::run(|| {
                    let scene = raypick::Scene::from_meshes([("arrays".to_string(), mesh)])?;
                    BuiltScene::new(scene, &options)
                })
            })?
            .map_err(to_py)?;
        warn_frame(py, &built)?;
        Ok(Scene::new(built, options))
    }

    /// scene.save(path): writes the scene and its trees as an `.rpk` file, which
    /// `Scene.load(path)` reads back with no rebuild.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        if !rpk::has_rpk_extension(&path) {
            return Err(value_error(format!(
                "{}: a saved scene's file name must end in .rpk",
                path.display()
            )));
        }
        let built = &self.built;
        py.detach(|| threads::run(|| rpk::save(built, &path)))?
            .map_err(to_py)
    }

    /// scene.pick(rays, mode="closest", max_hits=16, cull="none", tmin=0.0, tmax=inf,
    /// ray_mask=0xFFFFFFFF, intersector="watertight", backend="auto")
    ///
    /// Answers `rays` — (N, 6) float64 (origin, direction), or a tuple (origins, directions) —
    /// and returns a dict of numpy arrays named like the CLI's CSV columns.
    #[pyo3(signature = (rays, mode="closest", max_hits=16, cull="none", tmin=0.0, tmax=f64::INFINITY, ray_mask=0xFFFF_FFFF, intersector="watertight", backend="auto"))]
    #[allow(clippy::too_many_arguments)]
    fn pick<'py>(
        &self,
        py: Python<'py>,
        rays: &Bound<'py, PyAny>,
        #[pyo3(from_py_with = name_arg::mode)] mode: &str,
        #[pyo3(from_py_with = pick::max_hits)] max_hits: u32,
        #[pyo3(from_py_with = name_arg::cull)] cull: &str,
        #[pyo3(from_py_with = float_arg::tmin)] tmin: f64,
        #[pyo3(from_py_with = float_arg::tmax)] tmax: f64,
        #[pyo3(from_py_with = ray_mask)] ray_mask: u32,
        #[pyo3(from_py_with = name_arg::intersector)] intersector: &str,
        #[pyo3(from_py_with = name_arg::backend)] backend: &str,
    ) -> PyResult<Bound<'py, PyDict>> {
        let args = QueryArgs::parse(mode, max_hits, cull, ray_mask, intersector, backend)?;
        pick::pick(py, self, rays, &args, tmin, tmax)
    }

    /// scene.los(a, b, epsilon=1e-6, ray_mask=0xFFFFFFFF, backend="auto")
    ///
    /// Whether each segment a → b is unblocked: no triangle hit with t in (ε, 1 − ε) along
    /// a + t·(b − a). `a` and `b` are (N, 3) float64, or one point (3,) for every segment.
    #[pyo3(signature = (a, b, epsilon=1e-6, ray_mask=0xFFFF_FFFF, backend="auto"))]
    fn los<'py>(
        &self,
        py: Python<'py>,
        a: &Bound<'py, PyAny>,
        b: &Bound<'py, PyAny>,
        #[pyo3(from_py_with = float_arg::epsilon)] epsilon: f64,
        #[pyo3(from_py_with = ray_mask)] ray_mask: u32,
        #[pyo3(from_py_with = name_arg::backend)] backend: &str,
    ) -> PyResult<Bound<'py, PyAny>> {
        let args = SightArgs::parse(epsilon, ray_mask, backend)?;
        sight::los(py, self.for_sight(py)?, a, b, &args)
    }

    /// scene.viewshed(observer, targets=None, target_height=0.0, epsilon=1e-6,
    /// ray_mask=0xFFFFFFFF, backend="auto")
    ///
    /// Which targets the observer sees. Without `targets`, every sample of every terrain grid.
    /// Returns a dict: `position` (M, 3), `object`, `row`, `col` (−1 for given targets) and
    /// `visible` (bool).
    #[pyo3(signature = (observer, targets=None, target_height=0.0, epsilon=1e-6, ray_mask=0xFFFF_FFFF, backend="auto"))]
    #[allow(clippy::too_many_arguments)]
    fn viewshed<'py>(
        &self,
        py: Python<'py>,
        observer: &Bound<'py, PyAny>,
        targets: Option<&Bound<'py, PyAny>>,
        #[pyo3(from_py_with = float_arg::target_height)] target_height: f64,
        #[pyo3(from_py_with = float_arg::epsilon)] epsilon: f64,
        #[pyo3(from_py_with = ray_mask)] ray_mask: u32,
        #[pyo3(from_py_with = name_arg::backend)] backend: &str,
    ) -> PyResult<Bound<'py, PyDict>> {
        let args = SightArgs::parse(epsilon, ray_mask, backend)?;
        sight::viewshed(
            py,
            self.for_sight(py)?,
            observer,
            targets,
            target_height,
            &args,
        )
    }

    /// The number of triangles (an instanced scene's counted once per instance).
    #[getter]
    fn triangle_count(&self) -> u64 {
        self.built.world_triangle_count()
    }

    /// The objects, in id order: dicts with `id`, `name`, `triangles`, `mask` and `grid`
    /// ((rows, columns) of samples for a terrain grid, else None).
    #[getter]
    fn objects<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let list = PyList::empty(py);
        let add = |id: u32, name: &str, o: &raypick::scene::Object, mask: u32| -> PyResult<()> {
            let d = PyDict::new(py);
            d.set_item("id", id)?;
            d.set_item("name", name)?;
            d.set_item("triangles", o.triangle_count)?;
            d.set_item("mask", mask)?;
            d.set_item("grid", o.grid.map(|g| (g.rows, g.columns)))?;
            list.append(d)
        };
        match self.built.instances() {
            // An instance is its mesh's object, under the instance's name and mask.
            Some(instances) => {
                for (k, i) in instances.instances().iter().enumerate() {
                    let mesh = &instances.meshes()[i.mesh as usize].scene;
                    add(k as u32, &i.name, &mesh.objects()[0], i.mask)?;
                }
            }
            None => {
                for o in self.built.scene.objects() {
                    add(o.id, &o.name, o, o.mask)?;
                }
            }
        }
        Ok(list)
    }

    /// The world bounds as two float64 arrays (min, max), or None for an empty scene.
    #[getter]
    fn bounds<'py>(&self, py: Python<'py>) -> Option<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        self.built.bounds().map(|(lo, hi)| {
            (
                lo.to_array().to_pyarray(py).into_any(),
                hi.to_array().to_pyarray(py).into_any(),
            )
        })
    }

    fn __repr__(&self) -> String {
        let objects = self.built.object_count();
        format!(
            "raypick.Scene({objects} object{}, {} triangles)",
            if objects == 1 { "" } else { "s" },
            self.built.world_triangle_count()
        )
    }
}
