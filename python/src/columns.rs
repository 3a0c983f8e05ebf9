//! Hits out, as numpy columns named like the CLI's CSV columns: `hit`, `t`, `object`,
//! `triangle`, `u`, `v`, `position` (x, y, z), `normal` (nx, ny, nz), `row`, `col` (scenes with
//! a terrain grid), `invalid`; in all-hits mode `overflow`, `offsets`, `ray` and `rank`.
//!
//! A miss has NaN in its float fields and −1 in its integer fields; so has a hit off the grid
//! in `row` and `col`. Columns are filled in parallel straight from the answers into fresh
//! vectors that numpy then owns (no copy); per-ray columns are views of one block per type.

use crate::errors::vec_for;
use numpy::{IntoPyArray, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PySlice};
use raypick::Hit;
use std::mem::MaybeUninit;

/// Which per-ray columns a pick returns.
#[derive(Clone, Copy, Debug)]
pub struct Shape {
    /// `t` … `normal` (closest mode); without them only `hit` and `invalid` (any mode).
    pub fields: bool,
    /// `row` and `col`.
    pub cells: bool,
}

/// The per-ray columns of `n` rays, filled in ray order by [`Columns::fill`], chunk after
/// chunk. The columns of one type share one block (the flags `hit | invalid`; the floats
/// `t | u | v | position | normal`; the integers `object | triangle | row | col`), so that the
/// blocks are large enough for huge pages (a pick of 1M rays writes 130 MB of columns: with
/// 4 KiB pages, their first-touch page faults cost as much as filling them), and each column
/// is a numpy view of its block.
pub struct Columns {
    n: usize,
    shape: Shape,
    written: usize,
    flags: Vec<bool>,
    floats: Vec<f64>,
    ints: Vec<i64>,
}

/// Floats per ray: t, u, v, position (3), normal (3).
const FLOATS: usize = 11;

impl Columns {
    /// Room for `n` rays' columns of `shape` (absent columns take no room).
    pub fn new(n: usize, shape: Shape) -> PyResult<Self> {
        Ok(Self {
            n,
            shape,
            written: 0,
            flags: vec_for(2 * n, "the hit and invalid columns")?,
            floats: vec_for(
                if shape.fields { FLOATS * n } else { 0 },
                "the float columns",
            )?,
            ints: vec_for(Self::int_columns(shape) * n, "the integer columns")?,
        })
    }

    /// Integer columns: object and triangle, then row and col on grids.
    fn int_columns(shape: Shape) -> usize {
        match (shape.fields, shape.cells) {
            (false, _) => 0,
            (true, false) => 2,
            (true, true) => 4,
        }
    }

    /// Writes the columns of the next `hits.len()` rays, in parallel (call it without the
    /// interpreter).
    pub fn fill(&mut self, hits: &[Hit]) {
        let n = self.n;
        let (from, to) = (self.written, self.written + hits.len());
        assert!(to <= n, "more answers than rays");
        let f = self.shape.fields;
        let c = Self::int_columns(self.shape) == 4;
        let flags = &mut self.flags.spare_capacity_mut()[..2 * n];
        let (hit, invalid) = flags.split_at_mut(n);
        let floats = &mut self.floats.spare_capacity_mut()[..if f { FLOATS * n } else { 0 }];
        let (t, floats) = floats.split_at_mut(if f { n } else { 0 });
        let (u, floats) = floats.split_at_mut(if f { n } else { 0 });
        let (v, floats) = floats.split_at_mut(if f { n } else { 0 });
        let (position, normal) = floats.split_at_mut(if f { 3 * n } else { 0 });
        let ints = &mut self.ints.spare_capacity_mut()[..Self::int_columns(self.shape) * n];
        let (object, ints) = ints.split_at_mut(if f { n } else { 0 });
        let (triangle, ints) = ints.split_at_mut(if f { n } else { 0 });
        let (row, col) = ints.split_at_mut(if c { n } else { 0 });
        let slots = Slots {
            hit: part(hit, from, to, 1),
            invalid: part(invalid, from, to, 1),
            t: part(t, from, to, 1),
            object: part(object, from, to, 1),
            triangle: part(triangle, from, to, 1),
            u: part(u, from, to, 1),
            v: part(v, from, to, 1),
            position: part(position, from, to, 3),
            normal: part(normal, from, to, 3),
            row: part(row, from, to, 1),
            col: part(col, from, to, 1),
        };
        crate::threads::on_pool(|| slots.fill(hits, f, c));
        self.written = to;
    }

    /// The columns as numpy arrays in `dict`, in the CSV's order (every ray must have been
    /// written).
    pub fn into_dict(mut self, dict: &Bound<'_, PyDict>) -> PyResult<()> {
        assert_eq!(self.written, self.n, "a ray without an answer");
        let n = self.n;
        let f = self.shape.fields;
        let ints = Self::int_columns(self.shape);
        // SAFETY: `fill` wrote rays 0..n (`written == n`) of every present column, and the
        // present columns tile each block's first `len` slots exactly (see `fill`'s split);
        // every element type is plain data.
        unsafe {
            self.flags.set_len(2 * n);
            self.floats.set_len(if f { FLOATS * n } else { 0 });
            self.ints.set_len(ints * n);
        }
        let py = dict.py();
        let flags = self.flags.into_pyarray(py).into_any();
        let floats = self.floats.into_pyarray(py).into_any();
        let ints_block = self.ints.into_pyarray(py).into_any();
        dict.set_item("hit", view(&flags, 0, n, 1)?)?;
        if f {
            dict.set_item("t", view(&floats, 0, n, 1)?)?;
            dict.set_item("object", view(&ints_block, 0, n, 1)?)?;
            dict.set_item("triangle", view(&ints_block, n, n, 1)?)?;
            dict.set_item("u", view(&floats, n, n, 1)?)?;
            dict.set_item("v", view(&floats, 2 * n, n, 1)?)?;
            dict.set_item("position", view(&floats, 3 * n, n, 3)?)?;
            dict.set_item("normal", view(&floats, 6 * n, n, 3)?)?;
        }
        if ints == 4 {
            dict.set_item("row", view(&ints_block, 2 * n, n, 1)?)?;
            dict.set_item("col", view(&ints_block, 3 * n, n, 1)?)?;
        }
        dict.set_item("invalid", view(&flags, n, n, 1)?)?;
        Ok(())
    }
}

/// Rays `from..to` of a column's slots (`width` values a ray); an absent column stays empty.
fn part<T>(column: &mut [T], from: usize, to: usize, width: usize) -> &mut [T] {
    if column.is_empty() {
        return column;
    }
    &mut column[from * width..to * width]
}

/// The numpy view of `n` rays of `width` values from element `start` of a 1-D `block`: shape
/// (n,) or (n, width).
fn view<'py>(
    block: &Bound<'py, PyAny>,
    start: usize,
    n: usize,
    width: usize,
) -> PyResult<Bound<'py, PyAny>> {
    let py = block.py();
    let (a, b) = (start as isize, (start + n * width) as isize);
    let part = block.get_item(PySlice::new(py, a, b, 1))?;
    if width == 1 {
        Ok(part)
    } else {
        part.call_method1("reshape", ((n, width),))
    }
}

/// The unwritten slots of a run of rays, one slice a column (empty for an absent column).
struct Slots<'a> {
    hit: &'a mut [MaybeUninit<bool>],
    invalid: &'a mut [MaybeUninit<bool>],
    t: &'a mut [MaybeUninit<f64>],
    object: &'a mut [MaybeUninit<i64>],
    triangle: &'a mut [MaybeUninit<i64>],
    u: &'a mut [MaybeUninit<f64>],
    v: &'a mut [MaybeUninit<f64>],
    position: &'a mut [MaybeUninit<f64>],
    normal: &'a mut [MaybeUninit<f64>],
    row: &'a mut [MaybeUninit<i64>],
    col: &'a mut [MaybeUninit<i64>],
}

/// Splits an optional column's slots after `k` rays of `width` values.
fn cut<T>(s: &mut [T], k: usize, width: usize) -> (&mut [T], &mut [T]) {
    if s.is_empty() {
        (&mut [], &mut [])
    } else {
        s.split_at_mut(k * width)
    }
}

/// Rays per sequential piece of a parallel fill.
const PIECE: usize = 4096;

impl<'a> Slots<'a> {
    fn split(self, k: usize) -> (Slots<'a>, Slots<'a>) {
        let (hit, hit2) = cut(self.hit, k, 1);
        let (invalid, invalid2) = cut(self.invalid, k, 1);
        let (t, t2) = cut(self.t, k, 1);
        let (object, object2) = cut(self.object, k, 1);
        let (triangle, triangle2) = cut(self.triangle, k, 1);
        let (u, u2) = cut(self.u, k, 1);
        let (v, v2) = cut(self.v, k, 1);
        let (position, position2) = cut(self.position, k, 3);
        let (normal, normal2) = cut(self.normal, k, 3);
        let (row, row2) = cut(self.row, k, 1);
        let (col, col2) = cut(self.col, k, 1);
        (
            Slots {
                hit,
                invalid,
                t,
                object,
                triangle,
                u,
                v,
                position,
                normal,
                row,
                col,
            },
            Slots {
                hit: hit2,
                invalid: invalid2,
                t: t2,
                object: object2,
                triangle: triangle2,
                u: u2,
                v: v2,
                position: position2,
                normal: normal2,
                row: row2,
                col: col2,
            },
        )
    }

    /// Writes one slot per ray (three for points) of every present column: `fields` (`t` …
    /// `normal`) and `cells` (`row`, `col`) say which are.
    fn fill(self, hits: &[Hit], fields: bool, cells: bool) {
        if hits.len() > PIECE {
            let mid = hits.len() / 2;
            let (a, b) = self.split(mid);
            let (ha, hb) = hits.split_at(mid);
            rayon::join(|| a.fill(ha, fields, cells), || b.fill(hb, fields, cells));
            return;
        }
        for (i, h) in hits.iter().enumerate() {
            self.hit[i].write(h.hit);
            self.invalid[i].write(h.invalid);
            if fields {
                let f = HitFields::of(h);
                self.t[i].write(f.t);
                self.object[i].write(f.object);
                self.triangle[i].write(f.triangle);
                self.u[i].write(f.u);
                self.v[i].write(f.v);
                for k in 0..3 {
                    self.position[3 * i + k].write(f.position[k]);
                    self.normal[3 * i + k].write(f.normal[k]);
                }
            }
            if cells {
                let [r, c] = HitFields::cell(h);
                self.row[i].write(r);
                self.col[i].write(c);
            }
        }
    }
}

/// One hit's field values, NaN and −1 for a miss.
pub struct HitFields {
    pub t: f64,
    pub object: i64,
    pub triangle: i64,
    pub u: f64,
    pub v: f64,
    pub position: [f64; 3],
    pub normal: [f64; 3],
}

impl HitFields {
    pub fn of(h: &Hit) -> Self {
        if h.hit {
            Self {
                t: h.t,
                object: i64::from(h.object),
                triangle: i64::from(h.triangle),
                u: h.u,
                v: h.v,
                position: h.position.to_array(),
                normal: h.normal.to_array(),
            }
        } else {
            Self {
                t: f64::NAN,
                object: -1,
                triangle: -1,
                u: f64::NAN,
                v: f64::NAN,
                position: [f64::NAN; 3],
                normal: [f64::NAN; 3],
            }
        }
    }

    /// `[row, col]` of a grid hit, `[-1, -1]` otherwise.
    pub fn cell(h: &Hit) -> [i64; 2] {
        match (h.hit, h.cell) {
            (true, Some([r, c])) => [i64::from(r), i64::from(c)],
            _ => [-1, -1],
        }
    }
}

/// All-hits answers: per ray `hit`, `invalid`, `overflow` and `offsets` (N + 1: ray i's hits
/// are `offsets[i]..offsets[i + 1]`), and per hit `ray`, `rank` and the hit columns, as
/// Open3D's `list_intersections` lays them out.
pub struct Lists {
    cells: bool,
    hit: Vec<bool>,
    invalid: Vec<bool>,
    overflow: Vec<bool>,
    offsets: Vec<i64>,
    ray: Vec<i64>,
    rank: Vec<i64>,
    t: Vec<f64>,
    object: Vec<i64>,
    triangle: Vec<i64>,
    u: Vec<f64>,
    v: Vec<f64>,
    position: Vec<f64>,
    normal: Vec<f64>,
    row: Vec<i64>,
    col: Vec<i64>,
}

/// Makes room for `more` items in `v` (the budget was checked for every column at once:
/// [`Lists::add`]), or says that the memory is not there.
fn grow<T>(v: &mut Vec<T>, more: usize) -> PyResult<()> {
    v.try_reserve(more).map_err(|_| {
        pyo3::exceptions::PyMemoryError::new_err(format!(
            "the hit lists would need {more} more entries of {} bytes, more than this process \
             can allocate",
            size_of::<T>()
        ))
    })
}

impl Lists {
    /// Room for the per-ray columns of `n` rays; hit columns grow as answers come.
    pub fn new(n: usize, cells: bool) -> PyResult<Self> {
        let mut offsets = vec_for(n + 1, "the offsets column")?;
        offsets.push(0);
        Ok(Self {
            cells,
            hit: vec_for(n, "the hit column")?,
            invalid: vec_for(n, "the invalid column")?,
            overflow: vec_for(n, "the overflow column")?,
            offsets,
            ray: Vec::new(),
            rank: Vec::new(),
            t: Vec::new(),
            object: Vec::new(),
            triangle: Vec::new(),
            u: Vec::new(),
            v: Vec::new(),
            position: Vec::new(),
            normal: Vec::new(),
            row: Vec::new(),
            col: Vec::new(),
        })
    }

    /// Appends the answers of the next rays.
    pub fn add(&mut self, answers: &raypick::Answers) -> PyResult<()> {
        let m = answers.lists.len();
        // Every hit column at once, at the capacity they grow to (a vector's room doubles):
        // each column checked on its own let the lists take several times the budget.
        let needed = self.ray.len().saturating_add(m);
        let capacity = if needed > self.ray.capacity() {
            needed.max(self.ray.capacity().saturating_mul(2))
        } else {
            self.ray.capacity()
        };
        // ray, rank, object, triangle; t, u, v and the position's and normal's three each.
        let per_hit = 4 * size_of::<i64>() + 9 * size_of::<f64>();
        let per_hit = per_hit + if self.cells { 2 * size_of::<i64>() } else { 0 };
        raypick::budget::check("the hit lists", capacity as u64, per_hit as u64)
            .map_err(crate::errors::to_py)?;
        grow(&mut self.ray, m)?;
        grow(&mut self.rank, m)?;
        grow(&mut self.t, m)?;
        grow(&mut self.object, m)?;
        grow(&mut self.triangle, m)?;
        grow(&mut self.u, m)?;
        grow(&mut self.v, m)?;
        grow(&mut self.position, 3 * m)?;
        grow(&mut self.normal, 3 * m)?;
        if self.cells {
            grow(&mut self.row, m)?;
            grow(&mut self.col, m)?;
        }
        for (k, nearest) in answers.nearest.iter().enumerate() {
            let ray = self.hit.len() as i64;
            let hits = answers.hits_of(k);
            self.hit.push(!hits.is_empty());
            self.invalid.push(nearest.invalid);
            self.overflow
                .push(answers.overflow.get(k).copied().unwrap_or(false));
            for (rank, h) in hits.iter().enumerate() {
                let f = HitFields::of(h);
                self.ray.push(ray);
                self.rank.push(rank as i64);
                self.t.push(f.t);
                self.object.push(f.object);
                self.triangle.push(f.triangle);
                self.u.push(f.u);
                self.v.push(f.v);
                self.position.extend_from_slice(&f.position);
                self.normal.extend_from_slice(&f.normal);
                if self.cells {
                    let [r, c] = HitFields::cell(h);
                    self.row.push(r);
                    self.col.push(c);
                }
            }
            self.offsets.push(self.ray.len() as i64);
        }
        Ok(())
    }

    /// The columns as numpy arrays in `dict`.
    pub fn into_dict(self, dict: &Bound<'_, PyDict>) -> PyResult<()> {
        let py = dict.py();
        let m = self.ray.len();
        dict.set_item("hit", self.hit.into_pyarray(py))?;
        dict.set_item("invalid", self.invalid.into_pyarray(py))?;
        dict.set_item("overflow", self.overflow.into_pyarray(py))?;
        dict.set_item("offsets", self.offsets.into_pyarray(py))?;
        dict.set_item("ray", self.ray.into_pyarray(py))?;
        dict.set_item("rank", self.rank.into_pyarray(py))?;
        dict.set_item("t", self.t.into_pyarray(py))?;
        dict.set_item("object", self.object.into_pyarray(py))?;
        dict.set_item("triangle", self.triangle.into_pyarray(py))?;
        dict.set_item("u", self.u.into_pyarray(py))?;
        dict.set_item("v", self.v.into_pyarray(py))?;
        dict.set_item("position", self.position.into_pyarray(py).reshape([m, 3])?)?;
        dict.set_item("normal", self.normal.into_pyarray(py).reshape([m, 3])?)?;
        if self.cells {
            dict.set_item("row", self.row.into_pyarray(py))?;
            dict.set_item("col", self.col.into_pyarray(py))?;
        }
        Ok(())
    }
}
