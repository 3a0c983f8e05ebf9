//! Loading triangle meshes from Wavefront OBJ files.
//!
//! This module owns the OBJ reader: it validates the file line by line (so
//! errors can name the line), hands the geometry to the `tobj` crate for fan
//! triangulation, and flattens every `o`/`g` group into one [`Mesh`] whose
//! triangle numbering is the file's face order.
//!
//! Only positions and faces are read. Texture coordinates, normals,
//! materials, vertex colours, `l` (polyline) and `p` (point) elements are
//! ignored. Faces with fewer than 3 vertices give no triangle: they are
//! skipped with one warning on standard error (their count and the first
//! one's line).

use std::path::Path;

use glam::DVec3;

use crate::budget::quote;
use crate::error::Error;
use crate::scene::Mesh;

/// Loads the triangle mesh of the OBJ file at `path`.
///
/// A file with no faces gives an empty mesh. Malformed content (unparseable
/// or non-finite coordinates, face indices that are 0, out of range or not
/// integers) is an [`Error::Parse`] naming the file and the line.
pub fn load_obj(path: &Path) -> Result<Mesh, Error> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| Error::Io {
        path: name.clone(),
        source,
    })?;
    let text = decode_utf8(&name, &bytes)?;
    let (geometry, short) = sanitize(text).map_err(|(line, message)| Error::Parse {
        path: name.clone(),
        line: Some(line),
        message,
    })?;
    if let Some(short) = short {
        eprintln!("warning: {name}: {}", short.describe());
    }

    #[allow(
        clippy::needless_update,
        reason = "tobj's `merging`/`reordering` features add fields"
    )]
    let options = tobj::LoadOptions {
        single_index: false,
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    // Materials are never requested: `sanitize` drops `mtllib` lines.
    let (models, _materials) = tobj::load_obj_buf(&mut geometry.as_bytes(), &options, |_| {
        Err(tobj::LoadError::GenericFailure)
    })
    .map_err(|e| parse_error(&name, format!("the OBJ reader failed: {e}")))?;

    build_mesh(&name, models)
}

fn parse_error(path: &str, message: String) -> Error {
    Error::Parse {
        path: path.to_owned(),
        line: None,
        message,
    }
}

/// Decodes `bytes` as UTF-8, naming the line of the first invalid byte.
fn decode_utf8<'a>(path: &str, bytes: &'a [u8]) -> Result<&'a str, Error> {
    std::str::from_utf8(bytes).map_err(|e| {
        let valid = bytes.get(..e.valid_up_to()).unwrap_or_default();
        Error::Parse {
            path: path.to_owned(),
            line: Some(1 + valid.iter().filter(|&&b| b == b'\n').count()),
            message: "the file is not valid UTF-8 text".to_owned(),
        }
    })
}

/// Faces with fewer than 3 vertices (`f 1 2`): they give no triangle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ShortFaces {
    /// How many.
    pub count: usize,
    /// The 1-based line of the first.
    pub first_line: usize,
}

impl ShortFaces {
    /// The warning, as a sentence.
    pub fn describe(&self) -> String {
        format!(
            "{} face(s) with fewer than 3 vertices give no triangle and were skipped (the first \
             on line {})",
            self.count, self.first_line
        )
    }
}

/// Validates `text` line by line and returns the geometry-only OBJ text that
/// is handed to `tobj`, with the same line count, and the faces with fewer
/// than 3 vertices, if any.
///
/// Comments (from `#` to the end of the line), a byte-order mark, group
/// names, vertex colours and every element other than `v` and `f` are
/// removed; in particular `l` lines, which `tobj` would turn into triangles.
/// Keeping a single group makes `tobj` return one model whose vertices are
/// shared by all faces. On error, returns the 1-based line and a message.
fn sanitize(text: &str) -> Result<(String, Option<ShortFaces>), (usize, String)> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut out = String::with_capacity(text.len());
    let mut vertices = 0usize;
    let mut short: Option<ShortFaces> = None;
    for (i, raw) in text.lines().enumerate() {
        let content = raw.split('#').next().unwrap_or_default();
        let mut words = content.split_whitespace();
        match words.next() {
            Some("v") => {
                let kept = check_vertex(words).map_err(|m| (i + 1, m))?;
                out.push('v');
                for token in kept {
                    out.push(' ');
                    out.push_str(token);
                }
                vertices += 1;
            }
            Some("f") => {
                let corners = check_face(words.clone(), vertices).map_err(|m| (i + 1, m))?;
                if corners < 3 {
                    let s = short.get_or_insert(ShortFaces {
                        count: 0,
                        first_line: i + 1,
                    });
                    s.count += 1;
                }
                out.push('f');
                for token in words {
                    out.push(' ');
                    out.push_str(token);
                }
            }
            _ => {}
        }
        out.push('\n');
    }
    Ok((out, short))
}

/// Checks the numbers of a `v` line and returns the tokens to keep: `x y z`,
/// or `x y z w` (`tobj` divides by `w`); colours are dropped.
fn check_vertex<'a>(words: impl Iterator<Item = &'a str>) -> Result<Vec<&'a str>, String> {
    let tokens: Vec<&str> = words.collect();
    let n = tokens.len();
    if !matches!(n, 3 | 4 | 6) {
        return Err(format!(
            "expected 3, 4 or 6 numbers after 'v' (x y z [w] or x y z r g b), found {n}"
        ));
    }
    let mut values = [0.0f64; 6];
    for (value, token) in values.iter_mut().zip(&tokens) {
        *value = token
            .parse::<f64>()
            .map_err(|_| format!("vertex value '{}' is not a number", quote(token)))?;
        if !value.is_finite() {
            return Err(format!("vertex value '{}' is not finite", quote(token)));
        }
    }
    if n == 4 {
        let w = values[3];
        if w == 0.0 {
            return Err("vertex weight w is zero".to_owned());
        }
        if values[..3].iter().any(|c| !(c / w).is_finite()) {
            return Err(format!(
                "vertex coordinates are not finite after dividing by w = {w}"
            ));
        }
        return Ok(tokens);
    }
    Ok(tokens.into_iter().take(3).collect())
}

/// Checks the vertex references of an `f` line, given the number of
/// vertices defined before it; returns how many it has.
fn check_face<'a>(words: impl Iterator<Item = &'a str>, vertices: usize) -> Result<usize, String> {
    let mut count = 0usize;
    for token in words {
        count += 1;
        let mut parts = token.split('/');
        let position = parts.next().unwrap_or_default();
        let rest: Vec<&str> = parts.collect();
        if rest.len() > 2
            || rest
                .iter()
                .any(|p| !p.is_empty() && p.parse::<isize>().is_err())
        {
            return Err(format!(
                "face vertex '{}' is malformed (expected v, v/vt, v//vn or v/vt/vn)",
                quote(token)
            ));
        }
        if position.is_empty() {
            return Err(format!(
                "face vertex '{}' has no position index",
                quote(token)
            ));
        }
        let index: isize = position
            .parse()
            .map_err(|_| format!("face index '{}' is not an integer", quote(position)))?;
        if index == 0 {
            return Err("face index 0 is invalid (OBJ indices start at 1)".to_owned());
        }
        if index.unsigned_abs() > vertices {
            return Err(format!(
                "face index {index} is out of range (the file has {vertices} vertices so far)"
            ));
        }
    }
    if count == 0 {
        return Err("face has no vertex indices".to_owned());
    }
    Ok(count)
}

/// Concatenates `tobj`'s models (in file order) into one mesh.
fn build_mesh(path: &str, models: Vec<tobj::Model>) -> Result<Mesh, Error> {
    let mut mesh = Mesh::default();
    for model in models {
        let m = model.mesh;
        if !m.face_arities.is_empty() || m.indices.len() % 3 != 0 || m.positions.len() % 3 != 0 {
            return Err(parse_error(
                path,
                "the OBJ reader returned faces that are not triangles".to_owned(),
            ));
        }
        let base = mesh.positions.len();
        let count = m.positions.len() / 3;
        let end = base
            .checked_add(count)
            .filter(|&end| u32::try_from(end).is_ok())
            .ok_or_else(|| parse_error(path, "the mesh has too many vertices".to_owned()))?;
        mesh.positions.extend(
            m.positions
                .chunks_exact(3)
                .map(|p| DVec3::new(p[0], p[1], p[2])),
        );
        for t in m.indices.chunks_exact(3) {
            let mut triangle = [0u32; 3];
            for (slot, &local) in triangle.iter_mut().zip(t) {
                let global = usize::try_from(local)
                    .ok()
                    .filter(|&l| l < count)
                    .map(|l| base + l)
                    .filter(|&g| g < end)
                    .and_then(|g| u32::try_from(g).ok())
                    .ok_or_else(|| {
                        parse_error(
                            path,
                            "the OBJ reader returned an out-of-range index".to_owned(),
                        )
                    })?;
                *slot = global;
            }
            mesh.triangles.push(triangle);
        }
    }
    if mesh.positions.iter().any(|p| !p.is_finite()) {
        return Err(parse_error(
            path,
            "a vertex coordinate is not finite".to_owned(),
        ));
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// A temporary file removed on drop.
    struct TempFile(PathBuf);

    impl TempFile {
        fn new(text: &str) -> Self {
            static COUNTER: AtomicUsize = AtomicUsize::new(0);
            let n = COUNTER.fetch_add(1, Ordering::Relaxed);
            let path = std::env::temp_dir()
                .join(format!("raypick-obj-test-{}-{n}.obj", std::process::id()));
            std::fs::write(&path, text).expect("write temp file");
            Self(path)
        }
    }

    impl Drop for TempFile {
        fn drop(&mut self) {
            let _ = std::fs::remove_file(&self.0);
        }
    }

    fn load(text: &str) -> Result<Mesh, Error> {
        load_obj(&TempFile::new(text).0)
    }

    /// The corner positions of every triangle, for order checks that do not
    /// depend on the vertex numbering.
    fn corners(mesh: &Mesh) -> Vec<[DVec3; 3]> {
        mesh.triangles
            .iter()
            .map(|t| t.map(|i| mesh.positions[i as usize]))
            .collect()
    }

    /// Vertex `i` (1-based) of the test files: distinct, easy to name.
    fn v(i: u32) -> DVec3 {
        DVec3::new(f64::from(i), f64::from(i * i), 0.5)
    }

    fn vertex_lines(n: u32) -> String {
        (1..=n)
            .map(|i| {
                let p = v(i);
                format!("v {} {} {}\n", p.x, p.y, p.z)
            })
            .collect()
    }

    fn tris(list: &[[u32; 3]]) -> Vec<[DVec3; 3]> {
        list.iter().map(|t| t.map(v)).collect()
    }

    fn parse_err(result: Result<Mesh, Error>) -> (Option<usize>, String) {
        match result {
            Err(Error::Parse { line, message, .. }) => (line, message),
            other => panic!("expected a parse error, got {other:?}"),
        }
    }

    #[test]
    fn quad_and_pentagon_are_fan_triangulated_in_order() {
        let text = format!("{}f 1 2 3 4\nf 5 3 1 2 4\nf 2 4 5\n", vertex_lines(5));
        let mesh = load(&text).unwrap();
        assert_eq!(mesh.triangles.len(), 6);
        assert_eq!(
            corners(&mesh),
            tris(&[
                [1, 2, 3],
                [1, 3, 4],
                [5, 3, 1],
                [5, 1, 2],
                [5, 2, 4],
                [2, 4, 5],
            ])
        );
    }

    #[test]
    fn negative_indices_are_relative() {
        let text = format!(
            "{}f -3 -2 -1\n{}f -4 -3 -2 -1\nf 1 -1 2\n",
            vertex_lines(3),
            "v 4 16 0.5\nv 5 25 0.5\nv 6 36 0.5\nv 7 49 0.5\n"
        );
        let mesh = load(&text).unwrap();
        assert_eq!(
            corners(&mesh),
            tris(&[[1, 2, 3], [4, 5, 6], [4, 6, 7], [1, 7, 2]])
        );
    }

    #[test]
    fn comments_and_blank_lines_are_ignored() {
        let text = "# header\n\n  # indented\n#nospace\n\
                    v 1 1 0.5 # trailing\nv 2 4 0.5#glued\nv 3 9 0.5\n\
                    f 1 2 3 # a triangle\n# f 3 2 1\n";
        let mesh = load(text).unwrap();
        assert_eq!(corners(&mesh), tris(&[[1, 2, 3]]));
    }

    #[test]
    fn groups_keep_file_order() {
        let text = format!(
            "{}o a\nf 1 2 3\nf 2 3 4\no b\nf 4 1 2\ng c\nf 3 4 1\n",
            vertex_lines(4)
        );
        let mesh = load(&text).unwrap();
        assert_eq!(
            corners(&mesh),
            tris(&[[1, 2, 3], [2, 3, 4], [4, 1, 2], [3, 4, 1]])
        );
        // One model for the whole file: shared vertices are not duplicated.
        assert_eq!(mesh.positions.len(), 4);
    }

    #[test]
    fn degenerate_faces_are_kept() {
        let text = "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\n\
                    f 1 1 2\nf 1 2 3\nf 3 3 3\nf 1 2 4\n";
        let mesh = load(text).unwrap();
        assert_eq!(mesh.triangles.len(), 4);
        let c = corners(&mesh);
        assert_eq!(c[0][0], c[0][1]);
        assert_eq!(c[3], [DVec3::ZERO, DVec3::X, DVec3::Y]);
    }

    #[test]
    fn points_lines_and_polylines_give_no_triangles() {
        let text = format!("{}f 1\nf 1 2\nl 1 2 3\np 1\nf 1 2 3\n", vertex_lines(3));
        let mesh = load(&text).unwrap();
        assert_eq!(corners(&mesh), tris(&[[1, 2, 3]]));
    }

    #[test]
    fn texture_normal_and_weight_data_are_accepted() {
        let text = "v 2 2 2 2\nv 2 0 0 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n\
                    usemtl missing\nmtllib missing.mtl\n\
                    s 1\nf 1/1/1 2//1 3/1\n";
        let mesh = load(text).unwrap();
        assert_eq!(
            corners(&mesh),
            vec![[DVec3::ONE, DVec3::new(2.0, 0.0, 0.0), DVec3::Y]]
        );
    }

    #[test]
    fn crlf_and_byte_order_mark() {
        let text = "\u{feff}v 1 1 0.5\r\nv 2 4 0.5\r\nv 3 9 0.5\r\nf 1 2 3\r\nf 1 2 9\r\n";
        assert_eq!(parse_err(load(text)).0, Some(5));
        let mesh = load(&text.replace("f 1 2 9\r\n", "")).unwrap();
        assert_eq!(corners(&mesh), tris(&[[1, 2, 3]]));
    }

    #[test]
    fn file_without_faces_is_an_empty_mesh() {
        assert_eq!(load("").unwrap(), Mesh::default());
        let mesh = load("# nothing\nv 1 2 3\no empty\n").unwrap();
        assert!(mesh.triangles.is_empty());
    }

    #[test]
    fn out_of_range_index_names_the_line() {
        let text = format!("{}f 1 2 3\n# c\nf 1 2 17\n", vertex_lines(12));
        let (line, message) = parse_err(load(&text));
        assert_eq!(line, Some(15));
        assert_eq!(
            message,
            "face index 17 is out of range (the file has 12 vertices so far)"
        );
        let (line, message) = parse_err(load("v 0 0 0\nf 1 -2 1\n"));
        assert_eq!(line, Some(2));
        assert!(message.contains("-2 is out of range"), "{message}");
        // Forward references are rejected too.
        let (line, _) = parse_err(load("v 0 0 0\nf 1 2 3\nv 1 0 0\nv 0 1 0\n"));
        assert_eq!(line, Some(2));
    }

    #[test]
    fn bad_face_tokens_name_the_line() {
        let base = vertex_lines(3);
        for (face, expected) in [
            ("f 0 1 2", "face index 0 is invalid"),
            ("f 1 x 2", "face index 'x' is not an integer"),
            ("f 1 2/a 3", "is malformed"),
            ("f 1 2/1/1/1 3", "is malformed"),
            ("f 1 /1 3", "has no position index"),
            ("f", "face has no vertex indices"),
        ] {
            let (line, message) = parse_err(load(&format!("{base}{face}\n")));
            assert_eq!(line, Some(4), "{face}");
            assert!(message.contains(expected), "{face}: {message}");
        }
    }

    #[test]
    fn non_finite_or_bad_coordinates_name_the_line() {
        for (vertex, expected) in [
            ("v 0 nan 0", "'nan' is not finite"),
            ("v 0 0 -inf", "'-inf' is not finite"),
            ("v 1e999 0 0", "'1e999' is not finite"),
            ("v 0 zero 0", "'zero' is not a number"),
            ("v 0 0", "found 2"),
            ("v 0 0 0 1 1", "found 5"),
            ("v 0 0 0 0", "w is zero"),
            ("v 1e300 0 0 1e-300", "after dividing by w"),
        ] {
            // The vertex is unused: it is still checked.
            let text = format!("v 0 0 0\nv 1 0 0\n{vertex}\nv 0 1 0\nf 1 2 4\n");
            let (line, message) = parse_err(load(&text));
            assert_eq!(line, Some(3), "{vertex}");
            assert!(message.contains(expected), "{vertex}: {message}");
        }
    }

    #[test]
    fn error_display_names_file_and_line() {
        let file = TempFile::new("v 0 0 0\nf 1 1 2\n");
        let err = load_obj(&file.0).unwrap_err();
        let shown = err.to_string();
        assert!(
            shown.starts_with(&format!("{}:2: face index 2", file.0.display())),
            "{shown}"
        );
    }

    #[test]
    fn invalid_utf8_names_the_line() {
        let file = TempFile::new("");
        std::fs::write(&file.0, b"v 0 0 0\nv 1 \xff 0\n").unwrap();
        let (line, _) = parse_err(load_obj(&file.0));
        assert_eq!(line, Some(2));
    }

    #[test]
    fn missing_file_names_the_path() {
        let path = std::env::temp_dir().join("raypick-obj-test-does-not-exist.obj");
        let err = load_obj(&path).unwrap_err();
        assert!(matches!(err, Error::Io { .. }));
        assert!(err.to_string().contains(&path.display().to_string()));
    }

    #[test]
    fn bunny_loads() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/bunny.obj");
        let mesh = load_obj(&path).unwrap();
        assert_eq!(mesh.positions.len(), 1839);
        assert_eq!(mesh.triangles.len(), 3674);
        assert!(mesh.positions.iter().all(|p| p.is_finite()));
    }
}
