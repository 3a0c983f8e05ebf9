//! The OBJ reader (`src/io/obj.rs`, issue 14 item 1) against the `tobj`-based reader it
//! replaced, kept here verbatim as `tobj_reader`: the same meshes, bit for bit, and the same
//! errors and warnings, on every OBJ file under `tests/data` and `../shared/data` and on seeded
//! random files cut into chunks of many sizes; plus the line continuations the old reader did
//! not have.
//!
//! Throughput, old against new (median of 5 reads after one warm-up):
//! `OBJ_BENCH=path/to/big.obj cargo test --release --test suite -- --ignored --nocapture obj_reader::`
//! (default: `../shared/data/dragon_res2.obj`).

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use raypick::io::obj::{ShortFaces, load_obj, parse_obj, parse_obj_in_chunks};
use raypick::{Error, Mesh};

/// The reader as it was before issue 14 (`git show d55c502:src/io/obj.rs`): it validates each
/// line, then hands the geometry to `tobj`.
mod tobj_reader {
    use glam::DVec3;
    use raypick::budget::quote;
    use raypick::io::obj::ShortFaces;
    use raypick::{Error, Mesh};

    /// The old `load_obj`, from the file's bytes, returning the warning instead of printing it.
    pub fn parse(name: &str, bytes: &[u8]) -> Result<(Mesh, Option<ShortFaces>), Error> {
        let text = decode_utf8(name, bytes)?;
        let (geometry, short) = sanitize(text).map_err(|(line, message)| Error::Parse {
            path: name.to_owned(),
            line: Some(line),
            message,
        })?;
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
        let (models, _materials) = tobj::load_obj_buf(&mut geometry.as_bytes(), &options, |_| {
            Err(tobj::LoadError::GenericFailure)
        })
        .map_err(|e| parse_error(name, format!("the OBJ reader failed: {e}")))?;
        Ok((build_mesh(name, models)?, short))
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
    fn check_face<'a>(
        words: impl Iterator<Item = &'a str>,
        vertices: usize,
    ) -> Result<usize, String> {
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
            if !m.face_arities.is_empty() || m.indices.len() % 3 != 0 || m.positions.len() % 3 != 0
            {
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
}

type Parsed = Result<(Mesh, Option<ShortFaces>), Error>;

/// What a reader gave, comparable: vertex bits, triangles and warning, or the error as shown.
#[derive(Debug, PartialEq)]
enum Seen {
    Mesh {
        positions: Vec<[u64; 3]>,
        triangles: Vec<[u32; 3]>,
        short: Option<ShortFaces>,
    },
    Error(String),
}

fn seen(parsed: Parsed) -> Seen {
    match parsed {
        Ok((mesh, short)) => Seen::Mesh {
            positions: mesh
                .positions
                .iter()
                .map(|p| p.to_array().map(f64::to_bits))
                .collect(),
            triangles: mesh.triangles,
            short,
        },
        Err(e) => Seen::Error(e.to_string()),
    }
}

/// The chunk sizes every comparison runs with: one line per chunk and up.
const CHUNKS: [usize; 6] = [1, 7, 64, 1000, 4096, 1 << 20];

/// Checks the new reader against the old on `bytes`, whole and in chunks of every size.
fn assert_same(name: &str, bytes: &[u8]) -> Seen {
    let old = seen(tobj_reader::parse(name, bytes));
    assert_eq!(seen(parse_obj(name, bytes)), old, "{name}");
    for chunk in CHUNKS {
        assert_eq!(
            seen(parse_obj_in_chunks(name, bytes, chunk)),
            old,
            "{name} in chunks of {chunk} bytes"
        );
    }
    old
}

/// Every `.obj` under `dir`, recursively.
fn obj_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            obj_files(&path, out);
        } else if path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("obj"))
        {
            out.push(path);
        }
    }
}

#[test]
fn every_obj_file_reads_as_tobj_read_it() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    obj_files(&root.join("tests/data"), &mut files);
    obj_files(&root.join("../shared/data"), &mut files);
    files.sort();
    assert!(
        files.iter().any(|f| f.ends_with("tests/data/bunny.obj")),
        "{files:?}"
    );
    for path in &files {
        let bytes = std::fs::read(path).unwrap();
        let name = path.display().to_string();
        let seen = assert_same(&name, &bytes);
        let Seen::Mesh { triangles, .. } = &seen else {
            panic!("{name}: {seen:?}");
        };
        assert!(!triangles.is_empty(), "{name}");
        // And through the file.
        let mesh = load_obj(path).unwrap();
        assert_eq!(&mesh.triangles, triangles, "{name}");
        eprintln!("{name}: {} triangles, the same", triangles.len());
    }
}

/// A number as an OBJ exporter (or a hand) might write it.
fn number(rng: &mut Pcg64) -> String {
    let x: f64 = rng.random_range(-1000.0..1000.0);
    match rng.random_range(0..12) {
        0 => format!("{x}"),
        1 => format!("{x:e}"),
        2 => format!("{x:.3}"),
        3 => format!("{:.0}.", x.abs()),
        4 => format!(".{}", rng.random_range(0..100_000)),
        5 => format!("+{:.2}", x.abs()),
        6 => "-0".to_owned(),
        7 => format!("{:E}", x * 1e-200),
        8 => format!("{}", rng.random_range(-5..5)),
        9 => format!("{x:.17}"),
        10 => format!("{:.25}", x * 1e-10),
        _ => format!("{:.6}", x),
    }
}

/// A blank run between tokens.
fn blank(rng: &mut Pcg64) -> &'static str {
    match rng.random_range(0..20) {
        0 => "\t",
        1 => "  ",
        2 => " \t ",
        3 => "\u{a0}",
        4 => "\u{0b}",
        _ => " ",
    }
}

/// One face corner referring to a vertex among the `vertices` so far.
fn corner(rng: &mut Pcg64, vertices: usize) -> String {
    let i = rng.random_range(1..=vertices);
    let index = if rng.random_bool(0.3) {
        format!("-{}", vertices + 1 - i)
    } else {
        i.to_string()
    };
    match rng.random_range(0..8) {
        0 => format!("{index}/{}", rng.random_range(1..9)),
        1 => format!("{index}//{}", rng.random_range(1..9)),
        2 => format!(
            "{index}/{}/{}",
            rng.random_range(1..9),
            rng.random_range(-9..-1)
        ),
        3 => format!("{index}/"),
        _ => index,
    }
}

/// A mistake, for the error paths.
fn mistake(rng: &mut Pcg64, vertices: usize) -> String {
    match rng.random_range(0..14) {
        0 => format!("f 1 2 {}", vertices + 1 + rng.random_range(0..3)),
        1 => format!("f -{} 1 2", vertices + 1),
        2 => "f 0 1 2".to_owned(),
        3 => "f 1 x 2".to_owned(),
        4 => "f 1 2/a 3".to_owned(),
        5 => "f 1 /1 3".to_owned(),
        6 => "f".to_owned(),
        7 => "v 0 nan 0".to_owned(),
        8 => "v 0 0".to_owned(),
        9 => "v 0 0 0 0".to_owned(),
        10 => "v 1 2 3 4 5 6 7".to_owned(),
        11 => "v 1e999 0 0".to_owned(),
        12 => format!("f 1 2 {}", "9".repeat(30)),
        _ => "f 1 2 3/4/5/6".to_owned(),
    }
}

/// A random OBJ file: vertices in every notation, faces of 1 to 7 corners with every index
/// form, groups, materials, normals, comments, CRLF and Unicode, and with probability
/// `p_mistake` per line, a mistake.
fn random_obj(rng: &mut Pcg64, lines: usize, p_mistake: f64) -> String {
    let mut out = String::new();
    if rng.random_bool(0.2) {
        out.push('\u{feff}');
    }
    let crlf = rng.random_bool(0.2);
    let mut vertices = 0usize;
    for _ in 0..lines {
        let mut line = String::new();
        if rng.random_bool(0.05) {
            line.push_str(blank(rng));
        }
        let kind = rng.random_range(0..100);
        if rng.random_bool(p_mistake) {
            line.push_str(&mistake(rng, vertices));
        } else if kind < 35 || vertices < 3 {
            line.push('v');
            vertices += 1;
            let count = match rng.random_range(0..10) {
                0 => 4,
                1 => 6,
                _ => 3,
            };
            for k in 0..count {
                line.push_str(blank(rng));
                if count == 4 && k == 3 {
                    line.push_str(&format!("{}", rng.random_range(1..4)));
                } else {
                    line.push_str(&number(rng));
                }
            }
        } else if kind < 75 {
            line.push('f');
            let n = match rng.random_range(0..20) {
                0 => 1,
                1 => 2,
                2..=5 => 4,
                6 => rng.random_range(5..8),
                _ => 3,
            };
            for _ in 0..n {
                line.push_str(blank(rng));
                line.push_str(&corner(rng, vertices));
            }
        } else {
            line.push_str(match kind {
                75..=78 => "vn 0 0 1",
                79..=82 => "vt 0.5 0.5",
                83 => "g group name",
                84 => "o Ünïcödé",
                85 => "usemtl stone",
                86 => "mtllib scene.mtl",
                87 => "s off",
                88 => "l 1 2 3",
                89 => "p 1",
                90 => "# comment \\",
                91 => "#",
                92 => "vp 1 2",
                93 => "g trailing \\",
                94 => "v\u{a0}1 2 3",
                95 => "g é\u{2003}x",
                _ => "",
            });
            if line.starts_with("v\u{a0}") {
                vertices += 1;
            }
        }
        if rng.random_bool(0.1) {
            line.push_str(" # note");
        }
        out.push_str(&line);
        out.push_str(if crlf { "\r\n" } else { "\n" });
    }
    if rng.random_bool(0.3) {
        out.pop();
    }
    out
}

#[test]
fn random_files_read_as_tobj_read_them() {
    let mut rng = Pcg64::seed_from_u64(14);
    let (mut meshes, mut errors) = (0, 0);
    for case in 0..300 {
        let p_mistake = if case % 2 == 0 { 0.0 } else { 0.004 };
        let lines = rng.random_range(1..400);
        let text = random_obj(&mut rng, lines, p_mistake);
        match assert_same(&format!("random case {case}"), text.as_bytes()) {
            Seen::Mesh { .. } => meshes += 1,
            Seen::Error(_) => errors += 1,
        }
    }
    // Both paths were taken.
    assert!(
        meshes > 100 && errors > 50,
        "{meshes} meshes, {errors} errors"
    );
}

/// Random byte edits of random files and of the bunny's head: whatever comes out, error or
/// mesh, must be what the old reader said. (`\\` is left out: the old reader had no
/// continuations.)
#[test]
fn mutated_files_read_as_tobj_read_them() {
    const BYTES: &[u8] = b"0123456789 -+./#\n\r\t\x0bvfeEinx\xc2\xa0";
    let bunny =
        std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/bunny.obj")).unwrap();
    let mut rng = Pcg64::seed_from_u64(141);
    let mut errors = 0;
    for case in 0..1500 {
        let mut bytes = if case % 3 == 0 {
            bunny[..rng.random_range(2000..6000)].to_vec()
        } else {
            let lines = rng.random_range(1..60);
            random_obj(&mut rng, lines, 0.0)
                .replace('\\', "|")
                .into_bytes()
        };
        for _ in 0..rng.random_range(1..5) {
            let at = rng.random_range(0..=bytes.len());
            let byte = BYTES[rng.random_range(0..BYTES.len())];
            match rng.random_range(0..3) {
                0 if at < bytes.len() => bytes[at] = byte,
                1 if at < bytes.len() => {
                    bytes.remove(at);
                }
                _ => bytes.insert(at, byte),
            }
        }
        if matches!(
            assert_same(&format!("mutant {case}"), &bytes),
            Seen::Error(_)
        ) {
            errors += 1;
        }
    }
    assert!((300..1400).contains(&errors), "{errors} errors");
}

#[test]
fn negative_and_out_of_range_indices_across_chunk_seams() {
    let mut text = String::new();
    for i in 0..50 {
        text.push_str(&format!("v {i} {} 0\n", i * i));
    }
    for i in 0..47 {
        text.push_str(&format!(
            "f -3 -2 -1\nf {} -1 {}\nv {i} 1 2\n",
            i + 1,
            i + 2
        ));
    }
    assert_same("relative", text.as_bytes());
    // The first error in the file wins, whichever chunk sees it.
    for bad in ["f 1 2 99\n", "f -99 1 2\n", "f 1 2 q\n", "v 1 2\n"] {
        let mut t = text.clone();
        t.insert_str(t.len() / 2 + t[t.len() / 2..].find('\n').unwrap() + 1, bad);
        t.push_str("f 1 2 999\n");
        let seen = assert_same(bad, t.as_bytes());
        assert!(matches!(seen, Seen::Error(_)), "{bad}");
    }
    // Invalid UTF-8 late in the file is reported before an earlier bad face.
    let mut bytes = b"v 0 0 0\nf 1 2 3\n".to_vec();
    bytes.extend_from_slice(text.as_bytes());
    bytes.extend_from_slice(b"g \xff\n");
    assert_same("utf8", &bytes);
}

/// The triangles' corner positions, for checks that do not depend on vertex numbering.
fn corners(mesh: &Mesh) -> Vec<[DVec3; 3]> {
    mesh.triangles
        .iter()
        .map(|t| t.map(|i| mesh.positions[i as usize]))
        .collect()
}

fn parse_all_chunks(text: &str) -> Parsed {
    let whole = parse_obj("c.obj", text.as_bytes());
    for chunk in CHUNKS {
        assert_eq!(
            seen(parse_obj_in_chunks("c.obj", text.as_bytes(), chunk)),
            seen(parse_obj("c.obj", text.as_bytes())),
            "chunks of {chunk}: {text:?}"
        );
    }
    whole
}

#[test]
fn backslash_continues_v_and_f_lines() {
    let plain = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3 4\n";
    let expected = corners(&parse_all_chunks(plain).unwrap().0);
    for text in [
        "v 0 0 0\nv 1 0 \\\n0\nv 0 1 0\nv 1 1 0\nf 1 2 3 4\n",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 \\\n3 4\n",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1\\\n2\\\r\n3 \\ # a comment\n 4\n",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf \\\n\\\n1 2 3 4 \\",
    ] {
        let (mesh, short) = parse_all_chunks(text).unwrap_or_else(|e| panic!("{text:?}: {e}"));
        assert_eq!(corners(&mesh), expected, "{text:?}");
        assert_eq!(short, None);
    }
    // A comment line is a line: it ends the continuation (here with a face of 2 corners).
    let (mesh, short) = parse_all_chunks("v 0 0 0\nv 1 0 0\nf 1 2 \\\n# between\n3 4\n").unwrap();
    assert_eq!(mesh.triangles.len(), 0);
    assert_eq!(short.map(|s| s.first_line), Some(3));
    // Errors name the first line of the joined ones; later lines keep their numbers.
    let err = parse_all_chunks("v 0 0 0\nf 1 \\\n1 \\\n7\nf 1 1 8\n").unwrap_err();
    assert!(
        err.to_string().starts_with("c.obj:2: face index 7"),
        "{err}"
    );
    let err = parse_all_chunks("v 0 0 0\nf 1 \\\n1 \\\n1\nf 1 1 8\n").unwrap_err();
    assert!(
        err.to_string().starts_with("c.obj:5: face index 8"),
        "{err}"
    );
    // A short face continued: its first line is named.
    let (_, short) = parse_all_chunks("v 0 0 0\nf 1 \\\n1\nf 1 1 1\n").unwrap();
    assert_eq!(
        short,
        Some(ShortFaces {
            count: 1,
            first_line: 2
        })
    );
    // Comments and ignored lines do not continue: the next line stays a line.
    for text in [
        "# C:\\models\\\nv 0 0 0\nf 1 1 1\n",
        "g C:\\models\\\nv 0 0 0\nf 1 1 1\n",
        "v 0 0 0 # \\\nf 1 1 1\n",
        "vt 0 0 \\\nv 0 0 0\nf 1 1 1\n",
    ] {
        let (mesh, _) = parse_all_chunks(text).unwrap_or_else(|e| panic!("{text:?}: {e}"));
        assert_eq!(mesh.triangles.len(), 1, "{text:?}");
        assert_same(text, text.as_bytes());
    }
}

#[test]
fn seams_never_cut_a_continuation() {
    let mut text = String::new();
    for i in 0..200 {
        text.push_str(&format!("v {i} \\\n  {} \\\n\\\n 0\n", i % 7));
    }
    for i in 1..198 {
        text.push_str(&format!("f {i} \\\n{} \\\n {}\n", i + 1, i + 2));
    }
    let (mesh, short) = parse_all_chunks(&text).unwrap();
    assert_eq!(
        (mesh.positions.len(), mesh.triangles.len(), short),
        (199, 197, None)
    );
    assert_eq!(mesh.positions[5], DVec3::new(5.0, 5.0, 0.0));
}

#[test]
fn long_continuation_chains_and_lines_take_linear_time() {
    const N: usize = 200_000;
    let start = Instant::now();
    // One face continued over N lines: N + 1 corners.
    let text = format!("v 0 0 0\nf \\\n{}1\n", "1 \\\n".repeat(N));
    let (mesh, _) = parse_obj("chain.obj", text.as_bytes()).unwrap();
    assert_eq!(mesh.triangles.len(), N - 1);
    // One line of N corners, and a file that is one unknown keyword.
    let text = format!("v 0 0 0\nf{}\n", " -1".repeat(N));
    let (mesh, _) = parse_obj("line.obj", text.as_bytes()).unwrap();
    assert_eq!(mesh.triangles.len(), N - 2);
    let text = "\\".repeat(4 * N);
    assert_eq!(
        parse_obj("x.obj", text.as_bytes()).unwrap().0,
        Mesh::default()
    );
    let elapsed = start.elapsed();
    assert!(elapsed.as_secs() < 10, "{elapsed:?}");
}

/// Median seconds of 5 runs of `f` after one warm-up.
fn median_seconds(mut f: impl FnMut()) -> f64 {
    f();
    let mut times: Vec<f64> = (0..5)
        .map(|_| {
            let start = Instant::now();
            f();
            start.elapsed().as_secs_f64()
        })
        .collect();
    times.sort_by(f64::total_cmp);
    times[2]
}

#[test]
#[ignore = "a measurement: run with --release --ignored --nocapture (OBJ_BENCH=path)"]
fn throughput_old_against_new() {
    let path = std::env::var_os("OBJ_BENCH").map_or_else(
        || Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/dragon_res2.obj"),
        PathBuf::from,
    );
    let name = path.display().to_string();
    let megabytes = std::fs::metadata(&path).unwrap().len() as f64 / 1e6;
    let old = median_seconds(|| {
        let bytes = std::fs::read(&path).unwrap();
        tobj_reader::parse(&name, &bytes).unwrap();
    });
    let new = median_seconds(|| {
        load_obj(&path).unwrap();
    });
    let same = seen(tobj_reader::parse(&name, &std::fs::read(&path).unwrap()))
        == seen(parse_obj(&name, &std::fs::read(&path).unwrap()));
    println!(
        "{name}: {megabytes:.1} MB, {} threads; tobj reader {:.1} MB/s ({:.1} ms), new reader \
         {:.1} MB/s ({:.1} ms), {:.1}× faster; same mesh: {same}",
        rayon::current_num_threads(),
        megabytes / old,
        old * 1e3,
        megabytes / new,
        new * 1e3,
        old / new
    );
    assert!(same);
}
