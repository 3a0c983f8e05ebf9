//! The scene model: objects made of triangles, exact f64 world positions, and the f64 origin
//! that the f32 traversal geometry is measured from.

use crate::error::{Error, Result};
use crate::store::Store;
use glam::DVec3;

/// A triangle mesh as loaded from a file: world positions in f64 and triangles indexing them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions in world coordinates.
    pub positions: Vec<DVec3>,
    /// Triangles as indices into `positions`, in file order.
    pub triangles: Vec<[u32; 3]>,
}

/// One pickable entity: a contiguous run of the scene's triangles.
#[derive(Clone, Debug, PartialEq)]
pub struct Object {
    /// The id reported in hits (the object's position in the scene, e.g. its file's index on the
    /// command line).
    pub id: u32,
    /// A name for messages, such as the file it came from.
    pub name: String,
    /// Index of the object's first triangle in the scene's triangle list.
    pub first_triangle: u32,
    /// Number of triangles; local triangle ids are `0..triangle_count`, in file order.
    pub triangle_count: u32,
    /// Index of the object's first vertex in the scene's vertex list (for a grid: sample (0, 0);
    /// samples follow in row-major order).
    pub first_vertex: u32,
    /// Layer mask: rays hit this object only when their mask shares a bit with it.
    pub mask: u32,
    /// For a height-grid terrain: its shape, so hits can report the cell's row and column.
    pub grid: Option<GridShape>,
    /// The object was mirrored by its transform (a negative determinant,
    /// [`Scene::transform_object`]): its triangles are stored with their second and third
    /// vertices swapped, so the faces that were front faces in the file stay front faces in the
    /// world; hits still report `u` and `v` for the file's vertex order.
    pub mirrored: bool,
}

/// The shape of a height-grid terrain object: quad (r, c) holds triangles 2k and 2k + 1 with
/// k = r·(columns − 1) + c.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GridShape {
    /// Samples per row.
    pub columns: u32,
    /// Rows of samples.
    pub rows: u32,
}

impl GridShape {
    /// Its samples (one vertex each, row by row): what reads a grid by row and column (the grid
    /// builder, `los` and `viewshed`'s targets) indexes its vertices so.
    pub fn samples(&self) -> u64 {
        u64::from(self.columns) * u64::from(self.rows)
    }

    /// The `(row, col)` of the quad holding triangle `triangle`.
    pub fn cell_of(&self, triangle: u32) -> (u32, u32) {
        let k = triangle / 2;
        let quads_per_row = self.columns.saturating_sub(1).max(1);
        (k / quads_per_row, k % quads_per_row)
    }
}

/// `transform` (3 × 4, row-major) applied to `p`: each row by [`transform_row`], in f64.
pub fn apply_transform(transform: &[[f64; 4]; 3], p: DVec3) -> DVec3 {
    DVec3::new(
        transform_row(&transform[0], p),
        transform_row(&transform[1], p),
        transform_row(&transform[2], p),
    )
}

/// One row `r` of a transform applied to `p`: `((a·x + b·y) + c·z) + t`, in f64, the one
/// expression every world coordinate of a transformed point comes from (instances' exact boxes
/// search it too: `instance::extent`).
#[inline(always)]
pub fn transform_row(r: &[f64; 4], p: DVec3) -> f64 {
    r[0] * p.x + r[1] * p.y + r[2] * p.z + r[3]
}

/// Reads an optional `"transform"` (3 rows of 4 numbers), saying what shape it has when it is
/// another: read as `[[f64; 4]; 3]`, a 4 × 4 matrix was refused as "trailing characters". Rows
/// and numbers past the shape are counted, not kept (a request's body of empty rows takes no
/// memory for them). For `#[serde(default, deserialize_with = "crate::scene::transform_rows")]`.
pub(crate) fn transform_rows<'de, D: serde::Deserializer<'de>>(
    deserializer: D,
) -> std::result::Result<Option<[[f64; 4]; 3]>, D::Error> {
    use serde::de::{Deserialize, Deserializer, Error, IgnoredAny, SeqAccess, Visitor};
    use std::fmt;

    /// One row: its first four numbers and how many it has.
    struct Row([f64; 4], usize);

    impl<'de> Deserialize<'de> for Row {
        fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
            struct Numbers;
            impl<'de> Visitor<'de> for Numbers {
                type Value = Row;
                fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                    f.write_str("a row of 4 numbers")
                }
                fn visit_seq<A: SeqAccess<'de>>(
                    self,
                    mut seq: A,
                ) -> std::result::Result<Row, A::Error> {
                    let mut row = Row([0.0; 4], 0);
                    while row.1 < 4 {
                        let Some(x) = seq.next_element::<f64>()? else {
                            return Ok(row);
                        };
                        row.0[row.1] = x;
                        row.1 += 1;
                    }
                    while seq.next_element::<IgnoredAny>()?.is_some() {
                        row.1 += 1;
                    }
                    Ok(row)
                }
            }
            d.deserialize_seq(Numbers)
        }
    }

    /// The whole matrix.
    struct Matrix([[f64; 4]; 3]);

    impl<'de> Deserialize<'de> for Matrix {
        fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
            struct Rows;
            impl<'de> Visitor<'de> for Rows {
                type Value = Matrix;
                fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                    f.write_str("3 rows of 4 numbers")
                }
                fn visit_seq<A: SeqAccess<'de>>(
                    self,
                    mut seq: A,
                ) -> std::result::Result<Matrix, A::Error> {
                    let mut matrix = [[0.0; 4]; 3];
                    let (mut rows, mut shaped) = (0usize, true);
                    let mut lengths = Vec::new();
                    while let Some(Row(values, len)) = seq.next_element::<Row>()? {
                        if let Some(slot) = matrix.get_mut(rows) {
                            *slot = values;
                        }
                        if lengths.len() < 5 {
                            lengths.push(len.to_string());
                        }
                        shaped &= len == 4;
                        rows += 1;
                    }
                    if rows == 3 && shaped {
                        return Ok(Matrix(matrix));
                    }
                    let of = match rows {
                        0 => String::new(),
                        n => {
                            let more = if n > 5 { ", …" } else { "" };
                            format!(" (of {}{more} numbers)", lengths.join(", "))
                        }
                    };
                    Err(A::Error::custom(format!(
                        "the transform must be 3 rows of 4 numbers ([[a, b, c, tx], [d, e, f, \
                         ty], [g, h, i, tz]]), not {rows} rows{of}"
                    )))
                }
            }
            d.deserialize_seq(Rows)
        }
    }

    Ok(Option::<Matrix>::deserialize(deserializer)?.map(|m| m.0))
}

/// The determinant of `transform`'s 3 × 3 part, or why the transform cannot place an object: a
/// number that is not finite, or a singular matrix (which flattens the object) or one so nearly
/// singular that rounding decides its determinant's sign.
pub fn check_transform(transform: &[[f64; 4]; 3]) -> std::result::Result<f64, String> {
    if let Some(x) = transform.iter().flatten().find(|x| !x.is_finite()) {
        return Err(format!("has a number that is not finite ({x})"));
    }
    let m = transform;
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    // Singular, or so nearly that rounding decides the sign: the determinant against the
    // volume its rows could span at most (the product of their lengths).
    let rows: f64 = m
        .iter()
        .map(|r| scaled_length(DVec3::new(r[0], r[1], r[2])))
        .product();
    if !(det.is_finite() && rows.is_finite()) {
        return Err(format!(
            "scales by more than double precision holds (its 3 × 3 part's rows' lengths \
             multiply to {rows:.3e}, its determinant is {det:.3e})"
        ));
    }
    if det.abs() <= 1e-12 * rows {
        return Err(format!(
            "is singular, or too nearly so (its 3 × 3 part's determinant, {det:.3e}, is under \
             10⁻¹² of its rows' lengths multiplied, {rows:.3e})"
        ));
    }
    Ok(det)
}

/// `v`'s length without overflow: scaled by its largest component first (a row or a diagonal
/// of 10²⁰⁰s squared is past f64's range); that component itself when it is 0 or not finite.
pub fn scaled_length(v: DVec3) -> f64 {
    let largest = v.abs().max_element();
    if largest == 0.0 || !largest.is_finite() {
        return largest;
    }
    (v / largest).length() * largest
}

/// The box of `points` (empty: from +∞ to −∞).
pub(crate) fn box_of(points: impl IntoIterator<Item = DVec3>) -> (DVec3, DVec3) {
    points
        .into_iter()
        .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p), hi.max(p))
        })
}

/// Whether the triangle `[a, b, c]` has exactly zero area in f64 (such triangles are never hit).
#[inline]
pub fn zero_area([a, b, c]: [DVec3; 3]) -> bool {
    cross_is_zero(b - a, c - a)
}

/// Whether `u × v` is the zero vector, each component formed as `DVec3::cross` forms it (so
/// the same answer as `u.cross(v) == DVec3::ZERO`), the z component first and the others only
/// where it is zero: a triangle's normal seldom lies in a coordinate plane, and a terrain's
/// never has z zero, so one component usually decides (the refit checks every moved triangle).
#[inline(always)]
pub(crate) fn cross_is_zero(u: DVec3, v: DVec3) -> bool {
    u.x * v.y - v.x * u.y == 0.0 && u.y * v.z - v.y * u.z == 0.0 && u.z * v.x - v.z * u.x == 0.0
}

/// A set of objects ready to be built into a tree.
///
/// World positions are kept in f64 so hits can be refined exactly; the traversal works on f32
/// offsets from [`Scene::origin`], the centre of the scene's bounds.
#[derive(Clone, Debug, Default)]
pub struct Scene {
    positions: Store<DVec3>,
    triangles: Store<[u32; 3]>,
    objects: Vec<Object>,
    bounds_min: DVec3,
    bounds_max: DVec3,
}

impl Scene {
    /// An empty scene: every ray misses it.
    pub fn new() -> Self {
        Self {
            bounds_min: DVec3::INFINITY,
            bounds_max: DVec3::NEG_INFINITY,
            ..Self::default()
        }
    }

    /// Builds a scene with one object per mesh; object ids are the meshes' positions in `meshes`.
    pub fn from_meshes(meshes: impl IntoIterator<Item = (String, Mesh)>) -> Result<Self> {
        let mut scene = Self::new();
        for (name, mesh) in meshes {
            scene.add_mesh(name, mesh)?;
        }
        Ok(scene)
    }

    /// Appends a mesh as a new object and returns its id. Fails, naming the object, on an index
    /// out of range or a non-finite coordinate.
    pub fn add_mesh(&mut self, name: impl Into<String>, mesh: Mesh) -> Result<u32> {
        let name = name.into();
        let id = u32::try_from(self.objects.len())
            .map_err(|_| Error::Invalid(format!("{name}: too many objects")))?;
        if let Some((i, p)) = mesh
            .positions
            .iter()
            .enumerate()
            .find(|(_, p)| !p.is_finite())
        {
            return Err(Error::Invalid(format!(
                "{name}: vertex {i} has a non-finite coordinate {}",
                crate::budget::point(*p)
            )));
        }
        let vertex_base = self.positions.len();
        let first_triangle = self.triangles.len();
        let total = vertex_base + mesh.positions.len();
        if u32::try_from(total).is_err()
            || u32::try_from(first_triangle + mesh.triangles.len()).is_err()
        {
            return Err(Error::Invalid(format!(
                "{name}: the scene would exceed 2^32 vertices or triangles"
            )));
        }
        for (t, tri) in mesh.triangles.iter().enumerate() {
            if let Some(&bad) = tri.iter().find(|&&i| i as usize >= mesh.positions.len()) {
                return Err(Error::Invalid(format!(
                    "{name}: triangle {t} uses vertex {bad}, but the mesh has {} vertices",
                    mesh.positions.len()
                )));
            }
        }
        for p in &mesh.positions {
            self.bounds_min = self.bounds_min.min(*p);
            self.bounds_max = self.bounds_max.max(*p);
        }
        let base = vertex_base as u32;
        let triangle_count = mesh.triangles.len() as u32;
        if self.positions.is_empty() && self.triangles.is_empty() {
            // The first mesh is moved in, not copied: a loaded scene is never held twice.
            self.positions = mesh.positions.into();
            self.triangles = mesh.triangles.into();
        } else {
            self.positions.to_mut().extend_from_slice(&mesh.positions);
            self.triangles
                .to_mut()
                .extend(mesh.triangles.iter().map(|t| t.map(|i| i + base)));
        }
        self.objects.push(Object {
            id,
            name,
            first_triangle: first_triangle as u32,
            triangle_count,
            first_vertex: base,
            mask: u32::MAX,
            grid: None,
            mirrored: false,
        });
        Ok(id)
    }

    /// Appends a height-grid terrain mesh (triangles numbered by the grid convention) as a new
    /// object whose hits report their cell's row and column.
    pub fn add_grid_mesh(
        &mut self,
        name: impl Into<String>,
        mesh: Mesh,
        grid: GridShape,
    ) -> Result<u32> {
        let expected =
            2 * grid.columns.saturating_sub(1) as usize * grid.rows.saturating_sub(1) as usize;
        let name = name.into();
        if mesh.triangles.len() != expected {
            return Err(Error::Invalid(format!(
                "{name}: a {}×{} grid has {expected} triangles, but the mesh has {}",
                grid.columns,
                grid.rows,
                mesh.triangles.len()
            )));
        }
        let samples = grid.samples();
        if mesh.positions.len() as u64 != samples {
            return Err(Error::Invalid(format!(
                "{name}: a {}×{} grid has {samples} vertices, but the mesh has {}",
                grid.columns,
                grid.rows,
                mesh.positions.len()
            )));
        }
        let id = self.add_mesh(name, mesh)?;
        self.objects[id as usize].grid = Some(grid);
        Ok(id)
    }

    /// Sets an object's layer mask (rays hit it only when their mask shares a bit).
    pub fn set_object_mask(&mut self, object: u32, mask: u32) -> Result<()> {
        let o = self
            .objects
            .get_mut(object as usize)
            .ok_or_else(|| Error::Invalid(format!("there is no object {object}")))?;
        o.mask = mask;
        Ok(())
    }

    /// Maps object `object`'s vertices through the affine `transform` (3 × 4, row-major:
    /// `world = M·[x, y, z, 1]`, each row summed left to right in f64), keeping its triangles.
    /// A transform with a negative determinant (a mirror) also swaps each triangle's second and
    /// third vertices, so that front faces stay front faces as seen in the world (the object is
    /// then [`Object::mirrored`]). Fails, naming the object, on a transform that is not finite
    /// or is singular, or on a vertex that leaves the finite range, with nothing changed.
    pub fn transform_object(&mut self, object: u32, transform: &[[f64; 4]; 3]) -> Result<()> {
        let o = self
            .objects
            .get(object as usize)
            .ok_or_else(|| Error::Invalid(format!("there is no object {object}")))?;
        let det = check_transform(transform)
            .map_err(|why| Error::Invalid(format!("{}: the transform {why}", o.name)))?;
        let moved: Vec<DVec3> = self
            .object_vertices(object)
            .map(|v| apply_transform(transform, self.positions[v]))
            .collect();
        self.set_object_positions(object, &moved)?;
        if det < 0.0 {
            self.flip_winding(object);
        }
        Ok(())
    }

    /// Swaps the second and third vertices of each of object `object`'s triangles (front faces
    /// become back faces) and toggles [`Object::mirrored`], so hits still report `u` and `v` for
    /// the vertex order before the swap. Nothing for an unknown object.
    pub fn flip_winding(&mut self, object: u32) {
        let Some(o) = self.objects.get_mut(object as usize) else {
            return;
        };
        o.mirrored = !o.mirrored;
        let range = o.first_triangle as usize..(o.first_triangle + o.triangle_count) as usize;
        for t in &mut self.triangles.to_mut()[range] {
            t.swap(1, 2);
        }
    }

    /// The scene vertex indices of object `object`'s vertices (empty for an unknown object).
    pub fn object_vertices(&self, object: u32) -> std::ops::Range<usize> {
        let Some(o) = self.objects.get(object as usize) else {
            return 0..0;
        };
        let end = self
            .objects
            .get(object as usize + 1)
            .map_or(self.positions.len(), |next| next.first_vertex as usize);
        o.first_vertex as usize..end
    }

    /// A copy of the scene in which every object that `emptied` picks (by id) has no triangles
    /// and no vertices left, its entry kept (id, name, mask): what a removed object held is
    /// given back, and every other object keeps its triangles, their ids and its vertex order.
    pub fn with_objects_emptied(&self, emptied: impl Fn(u32) -> bool) -> Scene {
        let mut positions: Vec<DVec3> = Vec::new();
        let mut triangles: Vec<[u32; 3]> = Vec::new();
        let mut objects = Vec::with_capacity(self.objects.len());
        let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        for (k, o) in self.objects.iter().enumerate() {
            let first_vertex = positions.len() as u32;
            let first_triangle = triangles.len() as u32;
            if emptied(k as u32) {
                objects.push(Object {
                    first_triangle,
                    triangle_count: 0,
                    first_vertex,
                    grid: None,
                    ..o.clone()
                });
                continue;
            }
            let vertices = self.object_vertices(k as u32);
            for p in &self.positions[vertices.clone()] {
                lo = lo.min(*p);
                hi = hi.max(*p);
            }
            positions.extend_from_slice(&self.positions[vertices.clone()]);
            // Objects before it only lose vertices: its indices move down by what they lost.
            let shift = vertices.start as u32 - first_vertex;
            let own = o.first_triangle as usize..(o.first_triangle + o.triangle_count) as usize;
            triangles.extend(self.triangles[own].iter().map(|t| t.map(|i| i - shift)));
            objects.push(Object {
                first_triangle,
                first_vertex,
                ..o.clone()
            });
        }
        Scene {
            positions: positions.into(),
            triangles: triangles.into(),
            objects,
            bounds_min: lo,
            bounds_max: hi,
        }
    }

    /// Moves object `object`'s vertices to `positions` (as many as it has, in its own vertex
    /// order, finite), keeping its triangles, and updates the scene's bounds. A tree built over
    /// the scene must then be refitted ([`crate::bvh::Bvh::refit`]). Fails, naming the object,
    /// on an unknown object, a wrong count or a non-finite coordinate, with nothing changed.
    pub fn set_object_positions(&mut self, object: u32, positions: &[DVec3]) -> Result<()> {
        self.check_object_positions(object, positions)?;
        self.put_object_positions(object, positions);
        Ok(())
    }

    /// [`Scene::set_object_positions`] for positions already checked
    /// ([`Scene::check_object_positions`]).
    pub(crate) fn put_object_positions(&mut self, object: u32, positions: &[DVec3]) {
        use rayon::prelude::*;
        const CHUNK: usize = 1 << 14;
        let range = self.object_vertices(object);
        let empty = || box_of([]);
        let join = |a: (DVec3, DVec3), b: (DVec3, DVec3)| (a.0.min(b.0), a.1.max(b.1));
        let bounds_of = |points: &[DVec3]| box_of(points.iter().copied());
        let all = self.positions.to_mut();
        let (before, rest) = all.split_at_mut(range.start);
        let (moved, after) = rest.split_at_mut(range.len());
        // One parallel pass: the object's vertices copied in and bounded as they are written
        // (a copy on one thread, then a pass over every position, took a tenth of the dragon's
        // refit), the other objects' bounded where they lie.
        let copied = moved
            .par_chunks_mut(CHUNK)
            .zip(positions.par_chunks(CHUNK))
            .map(|(to, from)| {
                to.copy_from_slice(from);
                bounds_of(from)
            })
            .reduce(empty, join);
        let others = before
            .par_chunks(CHUNK)
            .chain(after.par_chunks(CHUNK))
            .map(bounds_of)
            .reduce(empty, join);
        (self.bounds_min, self.bounds_max) = join(copied, others);
    }

    /// Whether [`Scene::set_object_positions`] would take `positions` for object `object`: the
    /// error it would give, naming the object, if not.
    pub fn check_object_positions(&self, object: u32, positions: &[DVec3]) -> Result<()> {
        let o = self
            .objects
            .get(object as usize)
            .ok_or_else(|| Error::Invalid(format!("there is no object {object}")))?;
        let range = self.object_vertices(object);
        if positions.len() != range.len() {
            return Err(Error::Invalid(format!(
                "{}: {} positions given for its {} vertices",
                o.name,
                positions.len(),
                range.len()
            )));
        }
        use rayon::prelude::*;
        // Whole chunks checked without a branch per vertex; the first bad one is looked for
        // only when there is one.
        let all_finite = positions
            .par_chunks(1 << 14)
            .all(|chunk| chunk.iter().fold(true, |ok, p| ok & p.is_finite()));
        let bad = (!all_finite)
            .then(|| positions.iter().position(|p| !p.is_finite()))
            .flatten();
        if let Some((i, p)) = bad.map(|i| (i, positions[i])) {
            return Err(Error::Invalid(format!(
                "{}: vertex {i} has a non-finite coordinate {}",
                o.name,
                crate::budget::point(p)
            )));
        }
        Ok(())
    }

    /// The layer mask of the object owning scene triangle `index`.
    pub fn triangle_mask(&self, index: u32) -> u32 {
        let (object, _) = self.locate(index);
        self.objects[object as usize].mask
    }

    /// The objects, in id order.
    pub fn objects(&self) -> &[Object] {
        &self.objects
    }

    /// Number of triangles over all objects.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// World-space bounds `(min, max)`, or `None` for a scene without vertices.
    pub fn bounds(&self) -> Option<(DVec3, DVec3)> {
        (self.bounds_min.x <= self.bounds_max.x).then_some((self.bounds_min, self.bounds_max))
    }

    /// The f64 point that f32 traversal coordinates are offsets from: the centre of the bounds.
    pub fn origin(&self) -> DVec3 {
        self.bounds()
            .map_or(DVec3::ZERO, |(lo, hi)| lo + (hi - lo) * 0.5)
    }

    /// Number of vertices over all objects.
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    /// The world position of scene vertex `index`.
    pub fn position(&self, index: usize) -> DVec3 {
        self.positions[index]
    }

    /// The scene vertex indices of triangle `index`.
    pub fn triangle_vertices(&self, index: usize) -> [u32; 3] {
        self.triangles[index]
    }

    /// The three world-space vertices of scene triangle `index`.
    #[inline]
    pub fn world_triangle(&self, index: usize) -> [DVec3; 3] {
        // Written out (not `array::map`, which was left as a call in the pick's refinement).
        let [a, b, c] = self.triangles[index];
        [
            self.positions[a as usize],
            self.positions[b as usize],
            self.positions[c as usize],
        ]
    }

    /// Maps a scene triangle index to `(object id, triangle id within the object)`.
    pub fn locate(&self, index: u32) -> (u32, u32) {
        let k = self
            .objects
            .partition_point(|o| o.first_triangle <= index)
            .saturating_sub(1);
        let object = &self.objects[k];
        (object.id, index - object.first_triangle)
    }

    /// Whether scene triangle `index` has exactly zero area in f64 (such triangles are never hit).
    pub fn is_degenerate(&self, index: usize) -> bool {
        zero_area(self.world_triangle(index))
    }
}

impl Scene {
    /// Every vertex's world position, in scene order (objects' vertices one after another).
    pub fn positions(&self) -> &[DVec3] {
        &self.positions
    }

    /// Every triangle's scene vertex indices, in scene order.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// A scene from its parts, as [`Scene::add_mesh`] would have made them; the bounds are
    /// computed here, in the same order as `add_mesh` computes them. The caller has checked
    /// what `add_mesh` guarantees (finite positions; objects numbered in order, covering the
    /// triangles contiguously; vertex indices in range): [`crate::rpk::validate`] does.
    pub(crate) fn from_checked_parts(
        positions: Store<DVec3>,
        triangles: Store<[u32; 3]>,
        objects: Vec<Object>,
    ) -> Self {
        let mut scene = Self::new();
        for p in positions.iter() {
            scene.bounds_min = scene.bounds_min.min(*p);
            scene.bounds_max = scene.bounds_max.max(*p);
        }
        Self {
            positions,
            triangles,
            objects,
            ..scene
        }
    }

    /// The scene triangle index of `(object id, triangle id within the object)`.
    pub fn global_index(&self, object: u32, triangle: u32) -> Option<usize> {
        let o = self.objects.get(object as usize)?;
        (triangle < o.triangle_count).then_some((o.first_triangle + triangle) as usize)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Emptying objects keeps every object's id, name and mask, and every other object's
    /// triangles at the same world corners under the same ids, those after an emptied one
    /// included; the bounds are those of what is left.
    #[test]
    fn emptied_objects_leave_the_others_as_they_were() {
        let quad = |x: f64| Mesh {
            positions: vec![
                DVec3::new(x, 0.0, 0.0),
                DVec3::new(x + 1.0, 0.0, 0.0),
                DVec3::new(x + 1.0, 1.0, 0.0),
                DVec3::new(x, 1.0, 0.5),
            ],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        };
        let mut scene = Scene::new();
        for (k, x) in [0.0, 10.0, 20.0, 30.0].into_iter().enumerate() {
            scene.add_mesh(format!("quad {k}"), quad(x)).unwrap();
        }
        scene.set_object_mask(2, 4).unwrap();
        let emptied = scene.with_objects_emptied(|k| k == 1 || k == 3);
        assert_eq!(emptied.objects().len(), 4);
        assert_eq!(emptied.triangle_count(), 4);
        assert_eq!(emptied.positions().len(), 8);
        for (k, (a, b)) in scene.objects().iter().zip(emptied.objects()).enumerate() {
            assert_eq!(
                (a.id, &a.name, a.mask),
                (b.id, &b.name, b.mask),
                "object {k}"
            );
            if k == 1 || k == 3 {
                assert_eq!(b.triangle_count, 0);
                assert_eq!(emptied.object_vertices(k as u32).len(), 0);
                continue;
            }
            assert_eq!(a.triangle_count, b.triangle_count);
            for t in 0..a.triangle_count {
                let old = scene.world_triangle((a.first_triangle + t) as usize);
                let new = emptied.world_triangle((b.first_triangle + t) as usize);
                assert_eq!(old, new, "object {k} triangle {t}");
            }
        }
        assert_eq!(
            emptied.bounds(),
            Some((DVec3::new(0.0, 0.0, 0.0), DVec3::new(21.0, 1.0, 0.5)))
        );
        let none = scene.with_objects_emptied(|_| true);
        assert_eq!((none.triangle_count(), none.bounds()), (0, None));
    }

    /// `cross_is_zero` answers as `cross() == ZERO` on every pair of vectors whose coordinates
    /// come from values that make products and differences zero, tiny, huge, infinite or NaN,
    /// and on collinear edges (which a component-wise slip would call zero or not wrongly).
    #[test]
    fn cross_is_zero_is_the_cross_product_compared_with_zero() {
        let values = [
            0.0,
            -0.0,
            1.0,
            -2.5,
            3.0,
            1e-300,
            1e300,
            f64::INFINITY,
            f64::NAN,
        ];
        let mut checked = 0;
        let mut zeros = 0;
        for i in 0..values.len().pow(3) {
            let u = DVec3::new(values[i % 9], values[i / 9 % 9], values[i / 81]);
            for (k, v) in [
                u * 2.0,
                u * -0.5,
                DVec3::new(u.y, u.z, u.x),
                DVec3::new(1.0, -2.5, 3.0),
                DVec3::new(0.0, 0.0, 1e-300),
            ]
            .into_iter()
            .enumerate()
            {
                let expected = u.cross(v) == DVec3::ZERO;
                assert_eq!(cross_is_zero(u, v), expected, "{u} × {v} ({k})");
                checked += 1;
                zeros += usize::from(expected);
            }
        }
        assert_eq!(checked, 729 * 5);
        // Both answers occur often.
        assert!(zeros > 300 && zeros < checked - 300, "{zeros} of {checked}");
    }

    /// A transform whose rows are all but parallel is refused as singular though its
    /// determinant is not exactly 0 (rounding would decide whether it mirrors the object),
    /// while one that only scales everything by 10⁻¹³ (rows at right angles) is taken.
    #[test]
    fn nearly_singular_transforms_are_refused_and_small_scales_are_not() {
        let sheared = [
            [1.0, 0.0, 0.0, 0.0],
            [1.0, 1e-13, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ];
        let e = check_transform(&sheared).unwrap_err();
        assert!(e.contains("singular"), "{e}");
        let small = [
            [1e-13, 0.0, 0.0, 5.0],
            [0.0, 1e-13, 0.0, 0.0],
            [0.0, 0.0, 1e-13, 0.0],
        ];
        assert!(check_transform(&small).is_ok_and(|det| det > 0.0));
    }

    /// Mirrored twice, an object is not mirrored: its triangles are back in their first
    /// winding and [`Object::mirrored`] is false again, so its hits' u and v are reported for
    /// that winding as they were before either mirror.
    #[test]
    fn an_object_mirrored_twice_is_not_mirrored() {
        let mut scene = Scene::new();
        let mesh = Mesh {
            positions: vec![DVec3::ZERO, DVec3::X, DVec3::Y],
            triangles: vec![[0, 1, 2]],
        };
        scene.add_mesh("t", mesh).unwrap();
        let mirror = [
            [-1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ];
        scene.transform_object(0, &mirror).unwrap();
        assert!(scene.objects()[0].mirrored);
        assert_eq!(scene.triangles(), [[0, 2, 1]]);
        scene.transform_object(0, &mirror).unwrap();
        assert!(!scene.objects()[0].mirrored);
        assert_eq!(scene.triangles(), [[0, 1, 2]]);
        assert_eq!(scene.positions(), [DVec3::ZERO, DVec3::X, DVec3::Y]);
    }
}
