//! numpy arrays in: shapes and dtypes checked, each refusal one `ValueError` sentence naming the
//! argument, the shape or dtype wanted and the one given.
//!
//! Float arguments that are numpy arrays must already be float64: converting them here would
//! be a silent copy of what may be a large array, and a loss of precision hidden from the
//! caller for float32. Python lists and tuples are converted (they are copied anyway).

use crate::errors::{collect_for, to_py, value_error, vec_for};
use numpy::ndarray::ArrayView2;
use numpy::{
    PyArray2, PyArrayDescrMethods, PyArrayMethods, PyReadonlyArray2, PyUntypedArray,
    PyUntypedArrayMethods,
};
use pyo3::prelude::*;
use pyo3::types::{PyList, PyTuple};
use rayon::prelude::*;
use raypick::{DVec3, Ray};
use std::ops::Range;

/// What a 2-D array argument must hold.
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum Dtype {
    /// float64 exactly.
    Float64,
    /// Any integer or float dtype, read as float64 (pixel coordinates).
    Real,
}

/// A shape as Python prints it: `(5, 6)`, `(6,)`.
fn shape_text(shape: &[usize]) -> String {
    match shape {
        [one] => format!("({one},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(usize::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// What the argument should be, for messages: "a float64 array of shape (N, 6)".
fn wanted(dtype: Dtype, width: usize, single: bool) -> String {
    let kind = match dtype {
        Dtype::Float64 => "a float64 array",
        Dtype::Real => "a numeric array",
    };
    if single {
        format!("{kind} of shape (N, {width}) or ({width},)")
    } else {
        format!("{kind} of shape (N, {width})")
    }
}

/// `numpy.asarray(obj[, dtype])`, or a `ValueError` naming `name` with numpy's words, cut.
fn asarray<'py>(
    obj: &Bound<'py, PyAny>,
    dtype: Option<&str>,
    name: &str,
    want: &str,
) -> PyResult<Bound<'py, PyUntypedArray>> {
    let py = obj.py();
    let numpy = py.import("numpy")?;
    let read = match dtype {
        Some(dtype) => numpy.call_method1("asarray", (obj, dtype)),
        None => numpy.call_method1("asarray", (obj,)),
    };
    match read {
        Ok(array) => array
            .cast_into::<PyUntypedArray>()
            .map_err(|_| value_error(format!("{name} must be {want}"))),
        Err(e) => Err(value_error(format!(
            "{name} must be {want}; the {} given cannot be read as one ({})",
            obj.get_type().name()?,
            raypick::budget::quote(&e.value(py).to_string())
        ))),
    }
}

/// `obj` as a numpy array: arrays as they are, lists and tuples converted to float64, and what
/// numpy reads as an array through the array protocols (pandas, xarray, torch on the CPU) or
/// as a buffer (memoryview, array.array) as numpy gives it (no dtype forced: its dtype is
/// checked as an array's).
fn as_ndarray<'py>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    want: &str,
) -> PyResult<Bound<'py, PyUntypedArray>> {
    if let Ok(array) = obj.cast::<PyUntypedArray>() {
        return Ok(array.clone());
    }
    if obj.is_instance_of::<PyList>() || obj.is_instance_of::<PyTuple>() {
        return asarray(obj, Some("float64"), name, want);
    }
    let protocol = ["__array__", "__array_interface__", "__array_struct__"]
        .into_iter()
        .any(|attribute| obj.hasattr(attribute).unwrap_or(false));
    // Bytes and str are buffers or sequences of nothing numeric: refused by their type.
    let textual = obj.is_instance_of::<pyo3::types::PyBytes>()
        || obj.is_instance_of::<pyo3::types::PyString>()
        || obj.is_instance_of::<pyo3::types::PyByteArray>();
    let buffer = !textual
        && obj
            .py()
            .import("builtins")?
            .getattr("memoryview")?
            .call1((obj,))
            .is_ok();
    if protocol || buffer {
        return asarray(obj, None, name, want);
    }
    Err(value_error(format!(
        "{name} must be {want}; got {}",
        obj.get_type().name()?
    )))
}

/// A 2-D float64 array argument of `width` columns (or, with `single`, one row of `width`
/// numbers), checked, borrowed read-only.
pub fn rows<'py>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    width: usize,
    dtype: Dtype,
    single: bool,
) -> PyResult<PyReadonlyArray2<'py, f64>> {
    let want = wanted(dtype, width, single);
    let mut array = as_ndarray(obj, name, &want)?;
    let shape = array.shape().to_vec();
    let shape_ok = match shape.as_slice() {
        [_, w] => *w == width,
        [w] => single && *w == width,
        _ => false,
    };
    if !shape_ok {
        return Err(value_error(format!(
            "{name} must be {want}; got shape {}",
            shape_text(&shape)
        )));
    }
    let py = obj.py();
    // A copy numpy makes (to float64, or aligned) is made before anything else is checked: its
    // size first (a zero-stride view may claim any number of rows).
    let count = shape.iter().product::<usize>() as u64;
    let copy_fits =
        |what: &str| raypick::budget::check(&format!("{name} {what}"), count, 8).map_err(to_py);
    let descr = array.dtype();
    if !descr.is_equiv_to(&numpy::dtype::<f64>(py)) {
        let kind = descr.kind();
        let convertible = dtype == Dtype::Real && matches!(kind, b'i' | b'u' | b'f');
        if !convertible {
            return Err(value_error(format!(
                "{name} must be {want}; got dtype {descr}{}",
                if dtype == Dtype::Float64 && matches!(kind, b'i' | b'u' | b'f') {
                    " (convert it with .astype(numpy.float64))"
                } else {
                    ""
                }
            )));
        }
        copy_fits("as float64")?;
        array = array
            .call_method1("astype", ("float64",))?
            .cast_into::<PyUntypedArray>()?;
    }
    if shape.len() == 1 {
        array = array
            .call_method1("reshape", ((1usize, width),))?
            .cast_into::<PyUntypedArray>()?;
    }
    if !array.is_aligned() {
        // Numbers off their natural alignment (a view into a packed buffer) cannot be read in
        // place: an aligned copy.
        copy_fits("aligned")?;
        array = py
            .import("numpy")?
            .call_method1("require", (array, "float64", "A"))?
            .cast_into::<PyUntypedArray>()?;
    }
    let typed = array
        .cast_into::<PyArray2<f64>>()
        .map_err(|_| value_error(format!("{name} must be {want}")))?;
    typed.try_readonly().map_err(|_| {
        value_error(format!(
            "{name} is being written elsewhere and cannot be read"
        ))
    })
}

/// A triangle array: integers of any width, shape (T, 3), each a vertex index in 0 ..= 2^32 − 1
/// (the scene checks them against the vertex count).
pub fn triangles(obj: &Bound<'_, PyAny>) -> PyResult<Vec<[u32; 3]>> {
    let want = "an integer array of shape (T, 3)";
    let py = obj.py();
    let array = match obj.cast::<PyUntypedArray>() {
        Ok(array) => array.clone(),
        Err(_) if obj.is_instance_of::<PyList>() || obj.is_instance_of::<PyTuple>() => py
            .import("numpy")?
            .call_method1("asarray", (obj,))
            .map_err(|e| value_error(format!("triangles must be {want}; ({})", e.value(py))))?
            .cast_into::<PyUntypedArray>()?,
        Err(_) => {
            return Err(value_error(format!(
                "triangles must be {want}; got {}",
                obj.get_type().name()?
            )));
        }
    };
    let shape = array.shape().to_vec();
    if !matches!(shape.as_slice(), [_, 3]) {
        return Err(value_error(format!(
            "triangles must be {want}; got shape {}",
            shape_text(&shape)
        )));
    }
    let descr = array.dtype();
    let count = shape[0];
    let mut out = vec_for::<[u32; 3]>(count, "the triangles")?;
    // numpy's widened copy below, before it is made.
    raypick::budget::check("the triangles as 64-bit integers", count as u64, 24).map_err(to_py)?;
    let bad = |t: usize, value: String| {
        value_error(format!(
            "triangles must hold vertex indices in 0 ..= 4294967295; triangle {t} has {value}"
        ))
    };
    match descr.kind() {
        b'u' => {
            let wide = array
                .call_method1("astype", ("uint64",))?
                .cast_into::<PyArray2<u64>>()?;
            let wide = wide.try_readonly()?;
            for (t, row) in wide.as_array().rows().into_iter().enumerate() {
                let mut tri = [0u32; 3];
                for (k, &i) in row.iter().enumerate() {
                    tri[k] = u32::try_from(i).map_err(|_| bad(t, i.to_string()))?;
                }
                out.push(tri);
            }
        }
        b'i' => {
            let wide = array
                .call_method1("astype", ("int64",))?
                .cast_into::<PyArray2<i64>>()?;
            let wide = wide.try_readonly()?;
            for (t, row) in wide.as_array().rows().into_iter().enumerate() {
                let mut tri = [0u32; 3];
                for (k, &i) in row.iter().enumerate() {
                    tri[k] = u32::try_from(i).map_err(|_| bad(t, i.to_string()))?;
                }
                out.push(tri);
            }
        }
        _ => {
            return Err(value_error(format!(
                "triangles must be {want}; got dtype {descr}"
            )));
        }
    }
    Ok(out)
}

/// The rows of `view` as points (`what`, for the memory budget's message).
pub fn points(view: ArrayView2<'_, f64>, what: &str) -> PyResult<Vec<DVec3>> {
    let rows = view.rows().into_iter();
    collect_for(
        view.nrows(),
        what,
        rows.map(|r| DVec3::new(r[0], r[1], r[2])),
    )
}

/// The ray argument of `pick`: `(N, 6)` float64 rows (origin, direction), or a tuple
/// `(origins, directions)` of two `(N, 3)` float64 arrays; checked, borrowed read-only.
pub enum RayArrays<'py> {
    /// `(N, 6)` rows.
    Rows(PyReadonlyArray2<'py, f64>),
    /// `(origins, directions)`.
    Pair(PyReadonlyArray2<'py, f64>, PyReadonlyArray2<'py, f64>),
}

impl<'py> RayArrays<'py> {
    /// Checks the argument's shapes and dtypes.
    pub fn new(obj: &Bound<'py, PyAny>) -> PyResult<Self> {
        if let Ok(pair) = obj.cast::<PyTuple>()
            && pair.len() == 2
        {
            let origins = rows(&pair.get_item(0)?, "origins", 3, Dtype::Float64, false)?;
            let dirs = rows(&pair.get_item(1)?, "directions", 3, Dtype::Float64, false)?;
            let (o, d) = (origins.as_array().nrows(), dirs.as_array().nrows());
            if o != d {
                return Err(value_error(format!(
                    "origins has {o} rows but directions has {d}; give one direction per origin"
                )));
            }
            return Ok(Self::Pair(origins, dirs));
        }
        Ok(Self::Rows(rows(obj, "rays", 6, Dtype::Float64, false)?))
    }

    /// A reader of the rays, each with `tmin`, `tmax` and `mask`.
    pub fn reader(&self, tmin: f64, tmax: f64, mask: u32) -> RayReader<'_> {
        let layout = match self {
            Self::Rows(array) => match array.as_slice() {
                Ok(flat) if array.is_c_contiguous() => Layout::Flat(flat),
                _ => Layout::Rows(array.as_array()),
            },
            Self::Pair(o, d) => Layout::Pair(o.as_array(), d.as_array()),
        };
        RayReader {
            layout,
            tmin,
            tmax,
            mask,
        }
    }
}

/// How the numbers of the rays lie in memory.
enum Layout<'a> {
    /// C-contiguous `(N, 6)` rows.
    Flat(&'a [f64]),
    /// `(N, 6)` rows with any strides.
    Rows(ArrayView2<'a, f64>),
    /// Origins and directions, any strides.
    Pair(ArrayView2<'a, f64>, ArrayView2<'a, f64>),
}

/// Turns the numbers of a ray argument into [`Ray`]s, a batch at a time: the one conversion of
/// the ray array, made in parallel into a buffer the batches reuse (so no batch-sized vector
/// is made twice, and a batch's rays are still in the cache when the picker reads them). It
/// reads the array without the interpreter, as numpy's own functions do.
pub struct RayReader<'a> {
    layout: Layout<'a>,
    tmin: f64,
    tmax: f64,
    mask: u32,
}

impl RayReader<'_> {
    /// The number of rays.
    pub fn len(&self) -> usize {
        match &self.layout {
            Layout::Flat(flat) => flat.len() / 6,
            Layout::Rows(view) => view.nrows(),
            Layout::Pair(o, _) => o.nrows(),
        }
    }

    /// Ray `i`.
    fn ray(&self, i: usize) -> Ray {
        let (o, d) = match &self.layout {
            Layout::Flat(flat) => {
                let r = &flat[6 * i..6 * i + 6];
                ([r[0], r[1], r[2]], [r[3], r[4], r[5]])
            }
            Layout::Rows(v) => (
                [v[[i, 0]], v[[i, 1]], v[[i, 2]]],
                [v[[i, 3]], v[[i, 4]], v[[i, 5]]],
            ),
            Layout::Pair(o, d) => (
                [o[[i, 0]], o[[i, 1]], o[[i, 2]]],
                [d[[i, 0]], d[[i, 1]], d[[i, 2]]],
            ),
        };
        Ray::new(DVec3::from_array(o), DVec3::from_array(d))
            .with_range(self.tmin, self.tmax)
            .with_mask(self.mask)
    }

    /// Replaces `out` with rays `range`, made in parallel.
    pub fn read(&self, range: Range<usize>, out: &mut Vec<Ray>) {
        out.clear();
        out.par_extend(range.into_par_iter().map(|i| self.ray(i)));
    }
}
