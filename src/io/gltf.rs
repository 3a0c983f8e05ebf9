//! Loading triangle meshes from glTF 2.0 files (`.gltf` and `.glb`).
//!
//! [`load_gltf`] turns every triangle primitive placed in the scene into its
//! own named [`Mesh`], with world positions in f64. The JSON is parsed and
//! validated by the `gltf` crate; the GLB container, buffer loading (the
//! GLB `BIN` chunk, external files, `data:` URIs) and every accessor read
//! are done here, with all sizes checked, so malformed files give an
//! [`Error`] instead of a panic.
//!
//! # Which nodes, in which order
//!
//! - The default scene (`"scene"`) is walked. Without one, the roots of
//!   every scene are walked, scene by scene; a file without any scene uses
//!   every node that is nobody's child, in node order.
//! - Each root's subtree is walked depth first: a node's own mesh comes
//!   before its children, children in the order listed. The objects come
//!   out in this order, and within a node in primitive order, so with
//!   [`crate::Scene::from_meshes`] the object ids follow it too.
//! - A node's world transform is `parent world · node local` composed in
//!   f64, where the local transform is its `matrix` or
//!   `translation · rotation · scale` (the quaternion is normalised in f64).
//!   The numbers are read from the JSON's text as f64 (the `gltf` crate reads
//!   them as f32, 6 cm apart at 10⁶ m), so a node placed far from the origin
//!   keeps its millimetres.
//!   A `matrix` whose last row is not `0 0 0 1`, or a node with both a
//!   `matrix` and TRS properties, is an error (glTF asks for one affine
//!   transform); so is a node reached twice within one scene (a cycle, or a
//!   node with two parents). Files whose `asset.version` is not 2.x are
//!   refused, and a `byteStride` less than its elements' size.
//!
//! # Names
//!
//! An object is named `<file>#<mesh>/<primitive>`, where `<file>` is the
//! path as given, `<mesh>` the mesh's name (its index when unnamed or
//! empty) and `<primitive>` the primitive's index within the mesh. When a
//! mesh is placed by several nodes, every instance is its own object and
//! `<mesh>` becomes `<mesh>@node<k>` (`<mesh>@scene<s>.node<k>` when node
//! `k` itself is walked in several scenes).
//!
//! # Triangles
//!
//! Triangle ids are the order the primitive defines them in: `TRIANGLES`
//! takes vertices three at a time; `TRIANGLE_STRIP` triangle `i` is
//! `(v[i], v[i+1], v[i+2])` for even `i` and `(v[i], v[i+2], v[i+1])` for
//! odd `i`; `TRIANGLE_FAN` triangle `i` is `(v[i+1], v[i+2], v[0])` (the
//! glTF 2.0 rules). `v` is the index accessor, or `0, 1, 2, …` for a
//! non-indexed primitive. Degenerate triangles are kept, so ids stay
//! aligned with the file. A strip or fan of fewer than 3 vertices keeps its
//! object with no triangle, said once per file ([`crate::io::warnings`]).
//! Each object holds all of its primitive's `POSITION` vertices, used or not.
//!
//! # Not read
//!
//! `POINTS`, `LINES`, `LINE_LOOP` and `LINE_STRIP` primitives are skipped
//! (they make no object, and the primitive indices in names still count
//! them). Skins, morph targets, animations, cameras, lights, materials and
//! `EXT_mesh_gpu_instancing` are ignored: positions are the rest positions
//! under the node transforms. Files that *require* an extension changing
//! geometry (Draco, meshopt, `KHR_mesh_quantization`, …) are rejected;
//! required material, texture and light extensions are accepted. Buffers
//! are only loaded when a walked primitive reads them. The spec's rule that
//! `POSITION` accessors carry `min`/`max` is not enforced.
//!
//! # Sizes
//!
//! Every size is checked before the memory for it is taken:
//!
//! - Before the file is read, its length plus [`PARSE_PER_JSON_BYTE`] bytes
//!   per byte of its JSON (the whole file for `.gltf`, the JSON chunk its
//!   header declares for `.glb`) must fit the memory budget
//!   ([`crate::budget`]): the file's bytes, and the strings the parse copies
//!   (a `data:` URI's text is copied once and decoded later).
//! - Before the JSON is parsed, its records are counted: the parse holds the
//!   `gltf` crate's records and serde's buffered copies of them, up to about
//!   650 bytes for an empty object (`{}`, a node) and 80 for a number in a
//!   list (measured), in lists that may hold twice their records while they
//!   grow. So each `{` counts [`PARSE_PER_OBJECT`] bytes and each `,`, `:`
//!   and `[` (a further value) [`PARSE_PER_VALUE`], on top of the above, and
//!   the sum must fit the budget: a file of tiny records needs over 200
//!   times its size, a `.gltf` that is mostly a base64 buffer about twice.
//! - The accessors the walked primitives read may claim at most
//!   [`READ_PER_INPUT_BYTE`] bytes per byte of input (the file and the
//!   external buffers loaded), or [`READ_FLOOR`] in all: more can only be
//!   zero-filled (sparse) accessors or accessors sharing their data.
//! - The objects placed may have at most [`OUTPUT_PER_INPUT_BYTE`] vertices,
//!   triangles and objects per byte of input, or [`OUTPUT_FLOOR`] in all,
//!   and their memory ([`OBJECT_BYTES`] an object beside its name, even with
//!   no triangle) must fit the budget.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use ::gltf::accessor::sparse::IndexType;
use ::gltf::accessor::{DataType, Dimensions};
use ::gltf::buffer::{Source, View};
use ::gltf::json;
use ::gltf::mesh::{Mode, Semantic};
use ::gltf::scene::Transform;
use ::gltf::{Accessor, Document, Node, Primitive};
use glam::{DMat4, DQuat, DVec3};

use crate::budget::quote;
use crate::error::Error;
use crate::io::{Refusal, resolve_inside};
use crate::scene::Mesh;

/// Bytes the accessors of a file may claim per byte of input (see
/// [Sizes](self#sizes)).
pub const READ_PER_INPUT_BYTE: u64 = 2;

/// Bytes the accessors of any file may claim, whatever its size (16 MiB).
pub const READ_FLOOR: u64 = 16 << 20;

/// Vertices, triangles and objects a file may produce per byte of input (see
/// [Sizes](self#sizes)).
pub const OUTPUT_PER_INPUT_BYTE: u64 = 8;

/// Vertices, triangles and objects any file may produce, whatever its size.
pub const OUTPUT_FLOOR: u64 = 1 << 23;

/// Bytes a placed object costs beyond its vertices and triangles, and beyond three copies of the
/// file's name (its placement's, its object's and its instance's records and names, and the
/// scene's lists of them; about 680 measured with a short name).
pub const OBJECT_BYTES: u64 = 1024;

/// Bytes of memory per byte of a file's JSON while it is parsed, besides its records (see
/// [Sizes](self#sizes)).
pub const PARSE_PER_JSON_BYTE: u64 = 2;

/// Bytes of memory a JSON object (`{`) may take while the file is parsed (see
/// [Sizes](self#sizes)).
pub const PARSE_PER_OBJECT: u64 = 1024;

/// Bytes of memory a further JSON value (each `,`, `:` and `[`) may take while the file is
/// parsed (see [Sizes](self#sizes)).
pub const PARSE_PER_VALUE: u64 = 128;

/// The memory the parse of `json` may take (see [Sizes](self#sizes)): its objects, its further
/// values and its bytes, each at its rate. Brackets inside strings count too (a bound, not a
/// measure).
fn parse_bytes(json: &[u8]) -> (u64, u64, u64) {
    let (mut objects, mut values) = (0u64, 0u64);
    for &b in json {
        objects += u64::from(b == b'{');
        values += u64::from(matches!(b, b',' | b':' | b'['));
    }
    let bytes = (json.len() as u64)
        .saturating_mul(PARSE_PER_JSON_BYTE)
        .saturating_add(objects.saturating_mul(PARSE_PER_OBJECT))
        .saturating_add(values.saturating_mul(PARSE_PER_VALUE));
    (objects, values, bytes)
}

/// Loads every triangle primitive placed in the scene of the glTF 2.0 file
/// at `path` (`.gltf` with external or `data:` buffers, or binary `.glb`),
/// as `(name, mesh)` pairs with f64 world positions.
///
/// See the [module documentation](self) for the walk order, the names and
/// the triangle numbering. A missing file (the glTF or a buffer it needs)
/// is an [`Error::Io`] naming that file; malformed content (bad JSON or GLB,
/// failed glTF validation, accessors outside their buffers, indices out of
/// range, non-finite positions or transforms, unsupported required
/// extensions) is an [`Error::Parse`] naming the file and the mesh,
/// primitive, accessor or node at fault.
pub fn load_gltf(path: &Path) -> Result<Vec<(String, Mesh)>, Error> {
    Ok(load_gltf_placed(path)?
        .into_iter()
        .map(|(name, mesh, _)| (name, mesh))
        .collect())
}

/// [`load_gltf`], with for each primitive whether its node's world transform mirrors it (a
/// negative determinant). glTF then winds its front faces clockwise; the scene loader swaps
/// such triangles' second and third vertices (`Scene::flip_winding`) so that front faces stay
/// front faces, as the specification asks.
pub fn load_gltf_placed(path: &Path) -> Result<Vec<(String, Mesh, bool)>, Error> {
    load_gltf_shared(path)?.into_placed()
}

/// [`load_gltf_placed`] without copying: each primitive once, in its mesh's own coordinates, and
/// every placement of it with its node's world transform, so that nodes sharing a mesh become
/// instances of it. The placements name the objects as [`load_gltf_placed`] does, in its order.
/// The file is parsed and validated first, with the same errors as [`load_gltf`].
pub fn load_gltf_shared(path: &Path) -> Result<Shared, Error> {
    let name = path.display().to_string();
    let (mut file, length) = crate::io::open_regular(path)?;
    let json_length = glb_json_length(&mut file)
        .map_err(|source| Error::Io {
            path: name.clone(),
            source,
        })?
        .map_or(length, |j| j.min(length));
    crate::budget::check(
        &format!("{name}: reading it and parsing its {json_length} bytes of JSON"),
        length.saturating_add(json_length.saturating_mul(PARSE_PER_JSON_BYTE)),
        1,
    )?;
    let bytes = crate::io::read_opened(path, file, length)?;
    let parse = |line: Option<usize>, message: String| Error::Parse {
        path: name.clone(),
        line,
        message,
    };
    let (json_bytes, blob, is_glb) = if bytes.starts_with(b"glTF") {
        let (json, blob) = split_glb(&bytes).map_err(|m| parse(None, m))?;
        (json, blob, true)
    } else {
        (bytes.as_slice(), None, false)
    };
    let json_bytes = json_bytes
        .strip_prefix(b"\xEF\xBB\xBF".as_slice())
        .unwrap_or(json_bytes);
    let (objects, values, parsing) = parse_bytes(json_bytes);
    crate::budget::check(
        &format!(
            "{name}: parsing its {} bytes of JSON ({objects} objects, {values} further values)",
            json_bytes.len()
        ),
        length.saturating_add(parsing),
        1,
    )?;
    let root: json::Root = json::deserialize::from_slice(json_bytes).map_err(|e| {
        if is_glb {
            parse(
                None,
                format!(
                    "the JSON chunk is not valid glTF JSON (line {}, column {}): {e}",
                    e.line(),
                    e.column()
                ),
            )
        } else {
            parse(
                (e.line() > 0).then_some(e.line()),
                format!("not valid glTF JSON: {e}"),
            )
        }
    })?;
    validate(&root).map_err(|m| parse(None, m))?;
    // The same JSON again, for the nodes' transforms in f64: the parse above succeeded, so
    // this one fails only on a number f64 cannot hold, which f32 cannot either.
    let exact: ExactNodes = serde_json::from_slice(json_bytes)
        .map_err(|e| parse(None, format!("a node's transform cannot be read: {e}")))?;
    if exact.nodes.len() != root.nodes.len() {
        return Err(parse(
            None,
            "the nodes cannot be read twice alike".to_owned(),
        ));
    }
    let document = Document::from_json_without_validation(root);
    let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let mut loader = Loader {
        file: &name,
        dir,
        document: &document,
        exact: &exact.nodes,
        blob,
        buffers: vec![None; document.buffers().len()],
        input_bytes: bytes.len() as u64,
    };
    loader.load_shared()
}

/// A glTF file's triangle primitives, each once in its mesh's coordinates, and their placements
/// in walk order. [`Shared::into_placed`] turns it into [`load_gltf_placed`]'s objects, so a
/// caller that read a file to find out whether its nodes share a mesh need not read it again.
#[derive(Debug)]
pub struct Shared {
    /// The file, as named in messages.
    file: String,
    /// Each triangle primitive once, in walk order of its first placement.
    primitives: Vec<SharedPrimitive>,
    /// Every placement, in walk order: the objects [`load_gltf_placed`] makes, in its order.
    placements: Vec<Placement>,
}

/// A triangle primitive of a [`Shared`] file, in its mesh's coordinates.
#[derive(Clone, Debug)]
pub struct SharedPrimitive {
    /// `<file>#<mesh>/<primitive>`, the mesh's name (or index) unadorned.
    pub name: String,
    /// The primitive's triangles, positions in the mesh's coordinates.
    pub mesh: Mesh,
    /// `mesh <index> ('<name>') primitive <index>`, for messages.
    what: String,
}

/// One placement of a [`Shared`] file's primitive: one object of the placed scene.
#[derive(Debug)]
pub struct Placement {
    /// The object's name (see [Names](self#names)).
    pub name: String,
    /// The primitive placed: an index into [`Shared::into_parts`]'s primitives.
    pub primitive: usize,
    /// The node's world transform.
    pub world: DMat4,
    /// The node, for messages.
    node: usize,
}

impl Shared {
    /// Every placement, in walk order: the objects [`load_gltf_placed`] makes, in its order.
    pub fn placements(&self) -> &[Placement] {
        &self.placements
    }

    /// Each triangle primitive once (in walk order of its first placement), and every placement
    /// (in walk order), whose [`Placement::primitive`] indexes the first list.
    pub fn into_parts(self) -> (Vec<SharedPrimitive>, Vec<Placement>) {
        (self.primitives, self.placements)
    }

    /// The placed objects [`load_gltf_placed`] returns: each placement's primitive moved to the
    /// world by its node's transform (a primitive placed several times is copied for all but its
    /// last placement), with whether that transform mirrors it.
    ///
    /// # Errors
    /// [`Error::Parse`] naming the file, the mesh, the primitive and the node when a vertex is
    /// not finite once placed.
    pub fn into_placed(self) -> Result<Vec<(String, Mesh, bool)>, Error> {
        let mut left = vec![0usize; self.primitives.len()];
        for placement in &self.placements {
            left[placement.primitive] += 1;
        }
        let mut primitives: Vec<Option<SharedPrimitive>> =
            self.primitives.into_iter().map(Some).collect();
        let mut out = Vec::with_capacity(self.placements.len());
        for placement in self.placements {
            let k = placement.primitive;
            left[k] -= 1;
            // The last placement of a primitive takes it; earlier ones copy it.
            let placed = if left[k] == 0 {
                primitives[k].take()
            } else {
                primitives[k].clone()
            };
            let Some(SharedPrimitive {
                what,
                mesh:
                    Mesh {
                        mut positions,
                        triangles,
                    },
                ..
            }) = placed
            else {
                continue; // Each primitive's placements are counted above.
            };
            for (i, p) in positions.iter_mut().enumerate() {
                let w = placement.world.transform_point3(*p);
                if !w.is_finite() {
                    return Err(Error::Parse {
                        path: self.file,
                        line: None,
                        message: format!(
                            "{what}: vertex {i} {} is not finite after node {}'s world transform",
                            crate::budget::point(*p),
                            placement.node
                        ),
                    });
                }
                *p = w;
            }
            out.push((
                placement.name,
                Mesh {
                    positions,
                    triangles,
                },
                placement.world.determinant() < 0.0,
            ));
        }
        Ok(out)
    }
}

/// The files outside `path` that its buffers name (relative URIs inside its folder, as the
/// loader resolves them), for a caller that must not write over an input; empty where the file
/// cannot be read or parsed (loading it then says why). Reads the JSON once more, skipping
/// everything but the buffers' URIs.
pub fn buffer_files(path: &Path) -> Vec<PathBuf> {
    #[derive(serde::Deserialize)]
    struct Buffer {
        uri: Option<String>,
    }
    #[derive(serde::Deserialize)]
    struct Buffers {
        #[serde(default)]
        buffers: Vec<Buffer>,
    }
    let json = (|| -> std::io::Result<Vec<u8>> {
        use std::io::Read;
        let mut file = std::fs::File::open(path)?;
        let mut bytes = Vec::new();
        match glb_json_length(&mut file)? {
            Some(length) => {
                let mut head = [0u8; 20];
                file.read_exact(&mut head)?;
                file.take(length).read_to_end(&mut bytes)?;
            }
            None => {
                file.read_to_end(&mut bytes)?;
            }
        }
        Ok(bytes)
    })();
    let Ok(json) = json else {
        return Vec::new();
    };
    let Ok(parsed) = serde_json::from_slice::<Buffers>(&json) else {
        return Vec::new();
    };
    let dir = path.parent().unwrap_or(Path::new(""));
    parsed
        .buffers
        .into_iter()
        .filter_map(|b| b.uri)
        .filter(|uri| !uri.starts_with("data:") && !has_scheme(uri))
        .filter_map(|uri| percent_decode(&uri).ok())
        .filter_map(|relative| resolve_inside(dir, Path::new(&relative)).ok())
        .collect()
}

/// The length of a GLB file's JSON chunk, from its header (the file left at its start); `None`
/// for a file that does not start as a GLB file with a JSON chunk (a `.gltf`, all JSON).
fn glb_json_length(file: &mut std::fs::File) -> std::io::Result<Option<u64>> {
    use std::io::{Read, Seek};
    let mut head = [0u8; 20];
    let mut got = 0;
    while got < head.len() {
        match file.read(&mut head[got..]) {
            Ok(0) => break,
            Ok(n) => got += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    file.rewind()?;
    Ok(
        (got == head.len() && head.starts_with(b"glTF") && &head[16..20] == b"JSON")
            .then(|| u64::from(u32::from_le_bytes([head[12], head[13], head[14], head[15]]))),
    )
}

/// Splits a GLB container into its JSON chunk and optional `BIN` chunk.
fn split_glb(bytes: &[u8]) -> Result<(&[u8], Option<&[u8]>), String> {
    let word = |at: usize| -> Option<u32> {
        let b = bytes.get(at..at.checked_add(4)?)?;
        Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let truncated = || "the GLB file is truncated".to_owned();
    let version = word(4).ok_or_else(truncated)?;
    if version != 2 {
        return Err(format!(
            "GLB version {version} is not supported (expected 2)"
        ));
    }
    let length = word(8).ok_or_else(truncated)? as usize;
    if length < 12 || length > bytes.len() {
        return Err(format!(
            "the GLB header gives a length of {length} bytes, but the file has {}",
            bytes.len()
        ));
    }
    let mut at = 12;
    let mut json = None;
    let mut bin = None;
    while at < length {
        let chunk_length = word(at).ok_or_else(truncated)? as usize;
        let kind = bytes.get(at + 4..at + 8).ok_or_else(truncated)?;
        let start = at + 8;
        let end = start
            .checked_add(chunk_length)
            .filter(|&end| end <= length)
            .ok_or_else(|| {
                format!(
                    "a GLB chunk at byte {at} runs past the end of the file ({chunk_length} bytes)"
                )
            })?;
        let data = &bytes[start..end];
        match kind {
            b"JSON" if json.is_none() && at == 12 => json = Some(data),
            b"BIN\0" if json.is_some() && bin.is_none() => bin = Some(data),
            b"JSON" | b"BIN\0" => {
                return Err(format!("unexpected GLB chunk at byte {at}"));
            }
            _ => {} // Unknown chunk types are skipped, as the spec asks.
        }
        // Chunks start on 4-byte boundaries.
        at = end.div_ceil(4) * 4;
    }
    let json = json.ok_or_else(|| "the GLB file has no JSON chunk".to_owned())?;
    Ok((json, bin))
}

/// Required extensions that do not change triangles or positions.
fn is_harmless_extension(name: &str) -> bool {
    [
        "KHR_materials_",
        "KHR_texture_",
        "EXT_texture_",
        "MSFT_texture_",
    ]
    .iter()
    .any(|prefix| name.starts_with(prefix))
        || name == "KHR_lights_punctual"
}

/// The validation errors an invalid file's message names; the rest are counted.
const SHOWN_ERRORS: usize = 3;

/// Runs the `gltf` crate's validation (after the checks it needs to not
/// panic itself), dropping what this loader handles on its own.
fn validate(root: &json::Root) -> Result<(), String> {
    use json::validation::Validate;
    // glTF 1.0 is another format; 2.x files read alike.
    if root.asset.version.split('.').next() != Some("2") {
        return Err(format!(
            "asset.version is '{}': only glTF 2.x files are read",
            crate::budget::quote(&root.asset.version)
        ));
    }
    // A node's transform is a matrix or translation, rotation and scale, never both; and a
    // matrix must be affine (its last row 0 0 0 1): the spec's MUSTs, which the crate does not
    // check, and which left a node's placement to whichever was read.
    for (k, node) in root.nodes.iter().enumerate() {
        let Some(matrix) = node.matrix else {
            continue;
        };
        // TRS properties that place the node elsewhere than where they default to (an
        // exporter may write identity ones beside the matrix).
        let moved = node.translation.is_some_and(|t| t != [0.0; 3])
            || node.rotation.is_some_and(|r| r.0 != [0.0, 0.0, 0.0, 1.0])
            || node.scale.is_some_and(|s| s != [1.0; 3]);
        if moved {
            return Err(format!(
                "node {k} has both a matrix and a translation, rotation or scale (glTF allows \
                 one or the other)"
            ));
        }
        // Within a millionth: a matrix made by a general inversion may keep rounding noise
        // there.
        let last_row = [matrix[3], matrix[7], matrix[11], matrix[15]];
        let affine = last_row
            .iter()
            .zip([0.0, 0.0, 0.0, 1.0])
            .all(|(&got, want)| (got - want).abs() <= 1e-6);
        if !affine {
            let [a, b, c, d] = last_row;
            return Err(format!(
                "node {k}: the matrix's last row is {a} {b} {c} {d}, not 0 0 0 1 (glTF asks for \
                 an affine matrix)"
            ));
        }
    }
    // The crate's primitive check indexes `accessors` with the POSITION
    // index before bounds are checked.
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, primitive) in mesh.primitives.iter().enumerate() {
            for (semantic, index) in &primitive.attributes {
                if index.value() >= root.accessors.len() {
                    return Err(format!(
                        "invalid glTF: mesh {m} primitive {p}: attribute {} uses accessor {}, but the file has {} accessors",
                        semantic.to_string(),
                        index.value(),
                        root.accessors.len()
                    ));
                }
            }
        }
    }
    if let Some(name) = root
        .extensions_required
        .iter()
        .find(|name| !is_harmless_extension(name))
    {
        return Err(format!(
            "the file requires the extension {name}, which this loader does not support"
        ));
    }
    // The first few errors in words, the rest counted.
    let mut errors = Vec::new();
    let mut count = 0usize;
    root.validate(root, json::Path::new, &mut |path, error| {
        let path = path().to_string();
        let ignored = path.starts_with("extensionsRequired")
            || (error == json::validation::Error::Missing
                && (path.ends_with("[\"POSITION\"].min") || path.ends_with("[\"POSITION\"].max")));
        if !ignored {
            count += 1;
            if errors.len() < SHOWN_ERRORS {
                errors.push(format!("{path}: {error}"));
            }
        }
    });
    match count {
        0 => Ok(()),
        n if n <= SHOWN_ERRORS => Err(format!("invalid glTF: {}", errors.join("; "))),
        n => Err(format!(
            "invalid glTF: {}; and {} more",
            errors[..SHOWN_ERRORS].join("; "),
            n - SHOWN_ERRORS
        )),
    }
}

/// The JSON's `nodes` as far as their transforms go, read as f64.
#[derive(serde::Deserialize)]
struct ExactNodes {
    #[serde(default)]
    nodes: Vec<ExactNode>,
}

/// A node's `matrix` (column-major) or translation, rotation (x, y, z, w) and scale, as the
/// JSON's text writes them; glTF's defaults where absent.
#[derive(serde::Deserialize)]
struct ExactNode {
    matrix: Option<[f64; 16]>,
    translation: Option<[f64; 3]>,
    rotation: Option<[f64; 4]>,
    scale: Option<[f64; 3]>,
}

/// Says once for the file ([`crate::io::warnings`]) when triangle primitives give no triangle (a
/// strip or fan of fewer than 3 vertices, an empty list): their objects are kept, so ids stay
/// aligned with the file, but nothing can hit them (an OBJ file's short faces say the same).
fn warn_of_empty_primitives(file: &str, primitives: &[SharedPrimitive]) {
    let mut empty = primitives.iter().filter(|p| p.mesh.triangles.is_empty());
    if let Some(first) = empty.next() {
        crate::io::warnings::warn(format!(
            "{file}: {} triangle primitive(s) give no triangle (too few vertices; the \
             first: {}), so their objects cannot be hit",
            1 + empty.count(),
            first.what
        ));
    }
}

/// A primitive in its own frame: local positions and triangles.
struct LocalPrimitive {
    positions: Vec<DVec3>,
    triangles: Vec<[u32; 3]>,
}

/// One placement of a mesh by a node.
struct Instance {
    scene: usize,
    node: usize,
    mesh: usize,
    world: DMat4,
}

/// State of one load: the document and its buffers (loaded on first use).
struct Loader<'a> {
    file: &'a str,
    dir: PathBuf,
    document: &'a Document,
    /// The nodes' transforms in f64, by node index.
    exact: &'a [ExactNode],
    blob: Option<&'a [u8]>,
    buffers: Vec<Option<Vec<u8>>>,
    /// The glTF file's size plus the sizes of the external buffers loaded.
    input_bytes: u64,
}

impl Loader<'_> {
    fn parse(&self, message: String) -> Error {
        Error::Parse {
            path: self.file.to_owned(),
            line: None,
            message,
        }
    }

    /// Each triangle primitive once, in its mesh's coordinates, and its placements in walk order.
    fn load_shared(&mut self) -> Result<Shared, Error> {
        let instances = self.instances()?;
        self.check_sizes(&instances)?;
        let labels = self.labels(&instances);
        let document = self.document;
        let mut primitives: Vec<SharedPrimitive> = Vec::new();
        let mut index: HashMap<(usize, usize), Option<usize>> = HashMap::new();
        let mut placements = Vec::new();
        for (instance, label) in instances.iter().zip(labels) {
            let Some(mesh) = document.meshes().nth(instance.mesh) else {
                continue; // Validation guarantees the index.
            };
            for primitive in mesh.primitives() {
                let key = (instance.mesh, primitive.index());
                let at = match index.get(&key) {
                    Some(&at) => at,
                    None => {
                        let read = self.read_primitive(&primitive, instance.mesh)?;
                        let at = read.map(
                            |LocalPrimitive {
                                 positions,
                                 triangles,
                             }| {
                                primitives.push(SharedPrimitive {
                                    name: format!(
                                        "{}#{}/{}",
                                        self.file,
                                        mesh_label(&mesh),
                                        primitive.index()
                                    ),
                                    mesh: Mesh {
                                        positions,
                                        triangles,
                                    },
                                    what: format!(
                                        "mesh {} primitive {}",
                                        describe_mesh(&mesh),
                                        primitive.index()
                                    ),
                                });
                                primitives.len() - 1
                            },
                        );
                        index.insert(key, at);
                        at
                    }
                };
                if let Some(at) = at {
                    placements.push(Placement {
                        name: format!("{}#{label}/{}", self.file, primitive.index()),
                        primitive: at,
                        world: instance.world,
                        node: instance.node,
                    });
                }
            }
        }
        self.warn_if_empty(placements.len(), &instances);
        warn_of_empty_primitives(self.file, &primitives);
        Ok(Shared {
            file: self.file.to_owned(),
            primitives,
            placements,
        })
    }

    /// Says ([`crate::io::warnings`]) when the file places no triangle primitive: it then adds no
    /// object to the scene, which is otherwise silent (an OBJ file says the same).
    fn warn_if_empty(&self, placed: usize, instances: &[Instance]) {
        if placed > 0 {
            return;
        }
        let document = self.document;
        let why = if document.meshes().len() == 0 {
            "it has no mesh".to_owned()
        } else if instances.is_empty() {
            format!(
                "none of its {} mesh(es) is placed by a node of its scene",
                document.meshes().len()
            )
        } else {
            "its placed meshes hold only point and line primitives".to_owned()
        };
        crate::io::warnings::warn(format!(
            "{}: no triangle is placed ({why}), so it adds no object",
            self.file
        ));
    }

    /// Each placement's label: the mesh's name (or index), with the node (and the scene, when
    /// the node is walked from several) for a mesh placed more than once.
    fn labels(&self, instances: &[Instance]) -> Vec<String> {
        let mut per_mesh: HashMap<usize, usize> = HashMap::new();
        let mut node_scenes: HashMap<usize, Vec<usize>> = HashMap::new();
        for instance in instances {
            *per_mesh.entry(instance.mesh).or_default() += 1;
            let scenes = node_scenes.entry(instance.node).or_default();
            if !scenes.contains(&instance.scene) {
                scenes.push(instance.scene);
            }
        }
        instances
            .iter()
            .map(|instance| {
                let mut label = match self.document.meshes().nth(instance.mesh) {
                    Some(mesh) => mesh_label(&mesh),
                    None => instance.mesh.to_string(),
                };
                if per_mesh[&instance.mesh] > 1 {
                    if node_scenes[&instance.node].len() > 1 {
                        label.push_str(&format!("@scene{}.node{}", instance.scene, instance.node));
                    } else {
                        label.push_str(&format!("@node{}", instance.node));
                    }
                }
                label
            })
            .collect()
    }

    /// Loads every buffer the walked triangle primitives read, then checks
    /// the whole file's sizes (see [Sizes](self#sizes)) before any accessor
    /// is read.
    fn check_sizes(&mut self, instances: &[Instance]) -> Result<(), Error> {
        let document = self.document;
        let triangles_of = |mode: Mode, n: u64| match mode {
            Mode::Triangles => n / 3,
            _ => n.saturating_sub(2),
        };
        // Per walked (mesh, primitive): vertices, index count and triangles.
        let mut shapes: HashMap<(usize, usize), (u64, u64, u64)> = HashMap::new();
        let mut claimed_by: HashMap<usize, u64> = HashMap::new();
        for instance in instances {
            let Some(mesh) = document.meshes().nth(instance.mesh) else {
                continue;
            };
            for primitive in mesh.primitives() {
                let key = (instance.mesh, primitive.index());
                let mode = primitive.mode();
                if shapes.contains_key(&key)
                    || !matches!(
                        mode,
                        Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
                    )
                {
                    continue;
                }
                let at = format!(
                    "mesh {} primitive {}",
                    describe_mesh(&mesh),
                    primitive.index()
                );
                let positions = primitive.get(&Semantic::Positions);
                let indices = primitive.indices();
                for (accessor, size, kind) in [
                    positions.as_ref().map(|a| (a, 12, "POSITION")),
                    indices.as_ref().map(|a| (a, a.size() as u64, "index")),
                ]
                .into_iter()
                .flatten()
                {
                    let what = format!("{kind} accessor {}", accessor.index());
                    let mut views = Vec::new();
                    views.extend(accessor.view());
                    if let Some(sparse) = accessor.sparse() {
                        views.push(sparse.indices().view());
                        views.push(sparse.values().view());
                    }
                    for view in &views {
                        self.ensure_buffer(view, &at, &what)?;
                    }
                    claimed_by.insert(
                        accessor.index(),
                        (accessor.count() as u64).saturating_mul(size),
                    );
                }
                let vertices = positions.map_or(0, |a| a.count() as u64);
                let n = indices.map_or(vertices, |a| a.count() as u64);
                shapes.insert(key, (vertices, n, triangles_of(mode, n)));
            }
        }

        let input = self.input_bytes;
        let claimed: u64 = claimed_by.values().fold(0, |a, &b| a.saturating_add(b));
        let most = READ_FLOOR.max(input.saturating_mul(READ_PER_INPUT_BYTE));
        if claimed > most {
            return Err(self.parse(format!(
                "the accessors read claim {claimed} bytes, but a file with {input} bytes of \
                 input may claim at most {most} ({READ_PER_INPUT_BYTE} per byte of input, or \
                 {READ_FLOOR} in all): zero-filled (sparse) accessors or accessors sharing \
                 their data ask for more than the file holds"
            )));
        }

        let (mut vertices, mut triangles, mut objects) = (0u64, 0u64, 0u64);
        for instance in instances {
            for primitive in self
                .document
                .meshes()
                .nth(instance.mesh)
                .into_iter()
                .flat_map(|m| m.primitives())
            {
                if let Some(&(v, _, t)) = shapes.get(&(instance.mesh, primitive.index())) {
                    vertices = vertices.saturating_add(v);
                    triangles = triangles.saturating_add(t);
                    objects += 1;
                }
            }
        }
        // Objects count too: a primitive of no vertices placed by every node costs its records
        // and names each time (3,000 nodes × 3,000 such primitives, a 137 KB file, asked for
        // gigabytes).
        let output = vertices.saturating_add(triangles).saturating_add(objects);
        let most = OUTPUT_FLOOR.max(input.saturating_mul(OUTPUT_PER_INPUT_BYTE));
        if output > most {
            return Err(self.parse(format!(
                "the scene places {objects} objects with {vertices} vertices and {triangles} \
                 triangles, but a file with {input} bytes of input may give at most {most} \
                 vertices, triangles and objects ({OUTPUT_PER_INPUT_BYTE} per byte of input, or \
                 {OUTPUT_FLOOR} in all)"
            )));
        }
        // The objects (their records and names), plus the accessors' decoded data and indices
        // while they are read.
        let reading: u64 = shapes.values().fold(0, |a, &(v, n, _)| {
            a.saturating_add(v.saturating_mul(12))
                .saturating_add(n.saturating_mul(4))
        });
        let per_object = OBJECT_BYTES.saturating_add(3 * self.file.len() as u64);
        let bytes = vertices
            .saturating_mul(24)
            .saturating_add(triangles.saturating_mul(12))
            .saturating_add(objects.saturating_mul(per_object))
            .saturating_add(reading);
        crate::budget::check(
            &format!(
                "{}: {objects} objects with {vertices} vertices and {triangles} triangles",
                self.file
            ),
            bytes,
            1,
        )
    }

    /// The mesh placements in walk order (see the module documentation).
    fn instances(&self) -> Result<Vec<Instance>, Error> {
        let document = self.document;
        let walks: Vec<(usize, Vec<Node<'_>>)> = if let Some(scene) = document.default_scene() {
            vec![(scene.index(), scene.nodes().collect())]
        } else if document.scenes().len() > 0 {
            document
                .scenes()
                .map(|s| (s.index(), s.nodes().collect()))
                .collect()
        } else {
            let mut is_child = vec![false; document.nodes().len()];
            for node in document.nodes() {
                for child in node.children() {
                    is_child[child.index()] = true;
                }
            }
            let roots = document.nodes().filter(|n| !is_child[n.index()]).collect();
            vec![(0, roots)]
        };
        let mut instances = Vec::new();
        for (scene, roots) in walks {
            // Nodes are marked when they are pushed, so the stack holds each node at most once
            // (a node listing one child a million times is refused at the second, not after a
            // million pushes).
            let mut reached = vec![false; document.nodes().len()];
            let mut reach = |k: usize| {
                if std::mem::replace(&mut reached[k], true) {
                    Err(self.parse(format!(
                        "node {k} is reached twice from scene {scene} (a cycle, a node with two parents, or a root listed twice)"
                    )))
                } else {
                    Ok(())
                }
            };
            let mut stack: Vec<(Node<'_>, DMat4)> = Vec::with_capacity(roots.len());
            for n in roots.into_iter().rev() {
                reach(n.index())?;
                stack.push((n, DMat4::IDENTITY));
            }
            while let Some((node, parent)) = stack.pop() {
                let k = node.index();
                let world = parent * self.local_transform(&node)?;
                if !world.is_finite() {
                    return Err(self.parse(format!(
                        "node {k}: the world transform (parent · node) is not finite"
                    )));
                }
                if let Some(mesh) = node.mesh() {
                    instances.push(Instance {
                        scene,
                        node: k,
                        mesh: mesh.index(),
                        world,
                    });
                }
                let at = stack.len();
                for c in node.children() {
                    reach(c.index())?;
                    stack.push((c, world));
                }
                stack[at..].reverse();
            }
        }
        Ok(instances)
    }

    /// The node's own transform, in f64.
    fn local_transform(&self, node: &Node<'_>) -> Result<DMat4, Error> {
        let bad = |what: &str| {
            self.parse(format!(
                "node {}{}: {what}",
                node.index(),
                node.name()
                    .map(|n| format!(" ('{}')", quote(n)))
                    .unwrap_or_default()
            ))
        };
        // The crate's reading decides which form the node has (validation refused both); the
        // numbers are the f64 ones.
        let exact = &self.exact[node.index()];
        let m = match node.transform() {
            Transform::Matrix { .. } => {
                let mut cols = exact.matrix.unwrap_or([
                    1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
                ]);
                if cols.iter().any(|v| !v.is_finite()) {
                    return Err(bad("the matrix has a non-finite value"));
                }
                // The last row is 0 0 0 1 within the rounding noise validation lets through:
                // made exactly that, as glTF means it (kept, a child's w of 1.0000009 scaled its
                // parent's translation of 10⁶ into a shift of 0.9).
                [cols[3], cols[7], cols[11], cols[15]] = [0.0, 0.0, 0.0, 1.0];
                DMat4::from_cols_array(&cols)
            }
            Transform::Decomposed { .. } => {
                let t = DVec3::from_array(exact.translation.unwrap_or([0.0; 3]));
                let s = DVec3::from_array(exact.scale.unwrap_or([1.0; 3]));
                let q = DQuat::from_array(exact.rotation.unwrap_or([0.0, 0.0, 0.0, 1.0]));
                if !t.is_finite() || !s.is_finite() || !q.is_finite() {
                    return Err(bad("the translation, rotation or scale is not finite"));
                }
                // Scaled by a power of two first (exactly), so that a quaternion of tiny or huge
                // components normalises instead of its length underflowing or overflowing.
                let largest = glam::DVec4::from(q).abs().max_element();
                if largest == 0.0 {
                    return Err(bad("the rotation quaternion is 0 0 0 0"));
                }
                let q = q * 2f64.powi(-largest.log2().floor() as i32).min(f64::MAX);
                let length = q.length();
                if length == 0.0 || !length.is_finite() {
                    return Err(bad("the rotation quaternion cannot be normalised"));
                }
                DMat4::from_scale_rotation_translation(s, q / length, t)
            }
        };
        Ok(m)
    }

    /// Reads a primitive's local positions and triangles; `None` for point
    /// and line primitives.
    fn read_primitive(
        &mut self,
        primitive: &Primitive<'_>,
        mesh_index: usize,
    ) -> Result<Option<LocalPrimitive>, Error> {
        let mode = primitive.mode();
        if !matches!(
            mode,
            Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
        ) {
            return Ok(None);
        }
        let mesh = self.document.meshes().nth(mesh_index);
        let at = format!(
            "mesh {} primitive {}",
            mesh.as_ref().map(describe_mesh).unwrap_or_default(),
            primitive.index()
        );
        let fail = |this: &Self, message: String| this.parse(format!("{at}: {message}"));

        let Some(accessor) = primitive.get(&Semantic::Positions) else {
            return Err(fail(self, "has no POSITION attribute".to_owned()));
        };
        let what = format!("POSITION accessor {}", accessor.index());
        if accessor.data_type() != DataType::F32 || accessor.dimensions() != Dimensions::Vec3 {
            return Err(fail(
                self,
                format!(
                    "{what} holds {} {}; only FLOAT VEC3 positions are supported",
                    type_name(accessor.dimensions()),
                    component_name(accessor.data_type())
                ),
            ));
        }
        let raw = self.read_accessor(
            &accessor,
            12,
            |b| [0, 4, 8].map(|o| f32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]])),
            &at,
            &what,
        )?;
        let mut positions = Vec::with_capacity(raw.len());
        for (i, p) in raw.iter().enumerate() {
            let p = DVec3::from_array(p.map(f64::from));
            if !p.is_finite() {
                return Err(fail(
                    self,
                    format!(
                        "{what}: vertex {i} {} is not finite",
                        crate::budget::point(p)
                    ),
                ));
            }
            positions.push(p);
        }
        let vertex_count = u32::try_from(positions.len())
            .map_err(|_| fail(self, format!("{what} has more than {} vertices", u32::MAX)))?;

        let indices: Vec<u32> = match primitive.indices() {
            None => (0..vertex_count).collect(),
            Some(accessor) => {
                let what = format!("index accessor {}", accessor.index());
                if accessor.dimensions() != Dimensions::Scalar {
                    return Err(fail(
                        self,
                        format!(
                            "{what} is {}; indices must be SCALAR",
                            type_name(accessor.dimensions())
                        ),
                    ));
                }
                let indices = match accessor.data_type() {
                    DataType::U8 => {
                        self.read_accessor(&accessor, 1, |b| u32::from(b[0]), &at, &what)?
                    }
                    DataType::U16 => self.read_accessor(
                        &accessor,
                        2,
                        |b| u32::from(u16::from_le_bytes([b[0], b[1]])),
                        &at,
                        &what,
                    )?,
                    DataType::U32 => self.read_accessor(
                        &accessor,
                        4,
                        |b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
                        &at,
                        &what,
                    )?,
                    other => {
                        return Err(fail(
                            self,
                            format!(
                                "{what} has component type {}; indices must be UNSIGNED_BYTE, UNSIGNED_SHORT or UNSIGNED_INT",
                                component_name(other)
                            ),
                        ));
                    }
                };
                if let Some((i, v)) = indices
                    .iter()
                    .enumerate()
                    .find(|(_, v)| **v >= vertex_count)
                {
                    return Err(fail(
                        self,
                        format!(
                            "{what}: index {i} is {v}, out of range (POSITION has {vertex_count} vertices)"
                        ),
                    ));
                }
                indices
            }
        };

        let triangles = match mode {
            Mode::Triangles => {
                if !indices.len().is_multiple_of(3) {
                    return Err(fail(
                        self,
                        format!(
                            "TRIANGLES needs a multiple of 3 vertices, but it has {}",
                            indices.len()
                        ),
                    ));
                }
                indices
                    .chunks_exact(3)
                    .map(|t| [t[0], t[1], t[2]])
                    .collect()
            }
            Mode::TriangleStrip => indices
                .windows(3)
                .enumerate()
                .map(|(i, w)| {
                    if i % 2 == 0 {
                        [w[0], w[1], w[2]]
                    } else {
                        [w[0], w[2], w[1]]
                    }
                })
                .collect(),
            _ => match indices.split_first() {
                Some((&first, rest)) => rest.windows(2).map(|w| [w[0], w[1], first]).collect(),
                None => Vec::new(),
            },
        };
        Ok(Some(LocalPrimitive {
            positions,
            triangles,
        }))
    }

    /// Reads every element of `accessor` (`size` bytes each, decoded by
    /// `decode`), applying sparse substitution, with every range checked.
    fn read_accessor<T: Copy + Default>(
        &mut self,
        accessor: &Accessor<'_>,
        size: usize,
        decode: impl Fn(&[u8]) -> T,
        at: &str,
        what: &str,
    ) -> Result<Vec<T>, Error> {
        let count = accessor.count();
        let fail = |this: &Self, message: String| this.parse(format!("{at}: {what}: {message}"));
        let sparse = accessor.sparse();
        // Load every buffer this accessor touches first.
        let mut views = Vec::new();
        views.extend(accessor.view());
        if let Some(s) = &sparse {
            views.push(s.indices().view());
            views.push(s.values().view());
        }
        for view in &views {
            self.ensure_buffer(view, at, what)?;
        }

        let mut out = match accessor.view() {
            Some(view) => {
                let s = self
                    .strided(&view, accessor.offset(), count, size)
                    .map_err(|m| fail(self, m))?;
                let mut out = Vec::new();
                out.try_reserve_exact(count)
                    .map_err(|_| fail(self, format!("{count} elements do not fit in memory")))?;
                out.extend((0..count).map(|i| decode(s.get(i))));
                out
            }
            None => {
                // Zero-filled: the size was checked with the file's (see `check_sizes`).
                let mut out = Vec::new();
                out.try_reserve_exact(count)
                    .map_err(|_| fail(self, format!("{count} elements do not fit in memory")))?;
                out.resize(count, T::default());
                out
            }
        };
        if let Some(sparse) = sparse {
            let n = sparse.count();
            if n > count {
                return Err(fail(
                    self,
                    format!("sparse.count is {n}, more than the accessor's count {count}"),
                ));
            }
            let indices = sparse.indices();
            let index_size = match indices.index_type() {
                IndexType::U8 => 1,
                IndexType::U16 => 2,
                IndexType::U32 => 4,
            };
            let index_view = indices.view();
            let index_data = self
                .strided(&index_view, indices.offset(), n, index_size)
                .map_err(|m| fail(self, format!("sparse indices: {m}")))?;
            let values = sparse.values();
            let value_view = values.view();
            let value_data = self
                .strided(&value_view, values.offset(), n, size)
                .map_err(|m| fail(self, format!("sparse values: {m}")))?;
            for k in 0..n {
                let b = index_data.get(k);
                let target = match index_size {
                    1 => usize::from(b[0]),
                    2 => usize::from(u16::from_le_bytes([b[0], b[1]])),
                    _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize,
                };
                let Some(slot) = out.get_mut(target) else {
                    return Err(fail(
                        self,
                        format!(
                            "sparse index {k} is {target}, but the accessor has {count} elements"
                        ),
                    ));
                };
                *slot = decode(value_data.get(k));
            }
        }
        Ok(out)
    }

    /// Checks that `count` elements of `size` bytes, `offset` bytes into
    /// `view`, lie inside the view and its buffer.
    fn strided(
        &self,
        view: &View<'_>,
        offset: usize,
        count: usize,
        size: usize,
    ) -> Result<Strided<'_>, String> {
        let buffer = view.buffer().index();
        let data = self.buffer_data(buffer);
        let view_end = view
            .offset()
            .checked_add(view.length())
            .filter(|&end| end <= data.len())
            .ok_or_else(|| {
                format!(
                    "bufferView {} (bytes {}..+{}) runs past the end of buffer {buffer} ({} bytes)",
                    view.index(),
                    view.offset(),
                    view.length(),
                    data.len()
                )
            })?;
        let view_data = &data[view.offset()..view_end];
        // Elements closer than their size overlap: the spec asks for a stride of at least the
        // element's size.
        if let Some(stride) = view.stride().filter(|&stride| stride < size) {
            return Err(format!(
                "bufferView {} has a byteStride of {stride}, less than its elements' {size} bytes",
                view.index()
            ));
        }
        let stride = view.stride().unwrap_or(size);
        let needed = if count == 0 {
            Some(offset)
        } else {
            (count - 1)
                .checked_mul(stride)
                .and_then(|n| n.checked_add(size))
                .and_then(|n| n.checked_add(offset))
        };
        match needed {
            Some(end) if end <= view_data.len() => Ok(Strided {
                data: &view_data[offset..end],
                stride,
                size,
            }),
            _ => Err(format!(
                "{count} elements of {size} bytes (stride {stride}) from byte {offset} do not fit in bufferView {} ({} bytes)",
                view.index(),
                view_data.len()
            )),
        }
    }

    fn buffer_data(&self, index: usize) -> &[u8] {
        match self.buffers.get(index) {
            Some(Some(data)) => data,
            _ if index == 0 => self.blob.unwrap_or_default(),
            _ => &[],
        }
    }

    /// The first `length` bytes of the buffer file `file` (a regular file),
    /// after checking `length` against the memory budget.
    fn read_buffer_file(
        &self,
        file: &Path,
        length: usize,
        context: &dyn Fn() -> String,
    ) -> Result<Vec<u8>, Error> {
        use std::io::Read;
        crate::budget::check(&format!("{}: {}", self.file, context()), length as u64, 1)?;
        let io = |e: std::io::Error| Error::Io {
            path: file.display().to_string(),
            source: std::io::Error::new(e.kind(), format!("{e} ({})", context())),
        };
        let (handle, size) = crate::io::open_regular(file).map_err(|e| match e {
            Error::Io { source, .. } => io(source),
            other => other,
        })?;
        let mut data = Vec::new();
        data.try_reserve_exact(length.min(size as usize))
            .map_err(|_| {
                self.parse(format!(
                    "{}: {length} bytes do not fit in memory",
                    context()
                ))
            })?;
        handle
            .take(length as u64)
            .read_to_end(&mut data)
            .map_err(io)?;
        Ok(data)
    }

    /// Loads the buffer under `view` if it is not loaded yet.
    fn ensure_buffer(&mut self, view: &View<'_>, at: &str, what: &str) -> Result<(), Error> {
        let buffer = view.buffer();
        let index = buffer.index();
        if matches!(self.buffers.get(index), Some(Some(_))) {
            return Ok(());
        }
        let context = || format!("buffer {index} of {}, read by {at}, {what}", self.file);
        let data = match buffer.source() {
            Source::Bin => {
                let blob = self.blob.filter(|_| index == 0).ok_or_else(|| {
                    self.parse(format!(
                        "{}: the buffer has no uri and the file has no GLB BIN chunk for it",
                        context()
                    ))
                })?;
                if blob.len() < buffer.length() {
                    return Err(self.parse(format!(
                        "{}: the BIN chunk has {} bytes, but the buffer's byteLength is {}",
                        context(),
                        blob.len(),
                        buffer.length()
                    )));
                }
                // The blob is read in place (see `buffer_data`).
                return Ok(());
            }
            Source::Uri(uri) => {
                if let Some(rest) = uri.strip_prefix("data:") {
                    decode_data_uri(rest)
                        .map_err(|m| self.parse(format!("{}: bad data URI: {m}", context())))?
                } else if has_scheme(uri) {
                    return Err(self.parse(format!(
                        "{}: the URI '{}' is neither relative nor a data URI",
                        context(),
                        quote(uri)
                    )));
                } else {
                    let relative = percent_decode(uri).map_err(|m| {
                        self.parse(format!("{}: bad URI '{}': {m}", context(), quote(uri)))
                    })?;
                    let file = match resolve_inside(&self.dir, Path::new(&relative)) {
                        Ok(file) => file,
                        Err(Refusal::Io(e)) => {
                            return Err(Error::Io {
                                path: self.dir.join(&relative).display().to_string(),
                                source: std::io::Error::new(
                                    e.kind(),
                                    format!("{e} ({})", context()),
                                ),
                            });
                        }
                        Err(refusal) => {
                            return Err(self.parse(format!(
                                "{}: the URI '{}' is refused: {refusal}; a buffer must be a \
                                 data URI or a relative path inside the glTF file's folder",
                                context(),
                                quote(uri)
                            )));
                        }
                    };
                    let data = self.read_buffer_file(&file, buffer.length(), &context)?;
                    self.input_bytes = self.input_bytes.saturating_add(data.len() as u64);
                    data
                }
            }
        };
        if data.len() < buffer.length() {
            return Err(self.parse(format!(
                "{}: it has {} bytes, but its byteLength is {}",
                context(),
                data.len(),
                buffer.length()
            )));
        }
        if let Some(slot) = self.buffers.get_mut(index) {
            *slot = Some(data);
        }
        Ok(())
    }
}

/// Elements at a fixed stride in a byte slice whose bounds were checked.
struct Strided<'d> {
    data: &'d [u8],
    stride: usize,
    size: usize,
}

impl Strided<'_> {
    /// Element `i`; `i` must be below the count the slice was checked for.
    fn get(&self, i: usize) -> &[u8] {
        let start = i * self.stride;
        &self.data[start..start + self.size]
    }
}

/// The glTF spelling of an accessor's component type.
fn component_name(t: DataType) -> &'static str {
    match t {
        DataType::I8 => "BYTE",
        DataType::U8 => "UNSIGNED_BYTE",
        DataType::I16 => "SHORT",
        DataType::U16 => "UNSIGNED_SHORT",
        DataType::U32 => "UNSIGNED_INT",
        DataType::F32 => "FLOAT",
    }
}

/// The glTF spelling of an accessor's type.
fn type_name(t: Dimensions) -> &'static str {
    match t {
        Dimensions::Scalar => "SCALAR",
        Dimensions::Vec2 => "VEC2",
        Dimensions::Vec3 => "VEC3",
        Dimensions::Vec4 => "VEC4",
        Dimensions::Mat2 => "MAT2",
        Dimensions::Mat3 => "MAT3",
        Dimensions::Mat4 => "MAT4",
    }
}

/// `index` or `index ('name')`.
fn describe_mesh(mesh: &::gltf::Mesh<'_>) -> String {
    match mesh.name() {
        Some(name) => format!("{} ('{}')", mesh.index(), quote(name)),
        None => mesh.index().to_string(),
    }
}

/// A mesh's part of an object's name: its name, or its index when unnamed or empty.
fn mesh_label(mesh: &::gltf::Mesh<'_>) -> String {
    match mesh.name().filter(|n| !n.is_empty()) {
        Some(name) => name.to_owned(),
        None => mesh.index().to_string(),
    }
}

/// Whether `uri` starts with a URI scheme (`letter *(letter / digit / + - .) :`).
fn has_scheme(uri: &str) -> bool {
    match uri.split_once(':') {
        Some((scheme, _)) => {
            let mut chars = scheme.chars();
            chars.next().is_some_and(|c| c.is_ascii_alphabetic())
                && chars.all(|c| c.is_ascii_alphanumeric() || matches!(c, '+' | '-' | '.'))
        }
        None => false,
    }
}

/// Decodes `%XX` escapes in a relative URI into a path string.
fn percent_decode(uri: &str) -> Result<String, String> {
    let bytes = percent_decode_bytes(uri)?;
    String::from_utf8(bytes).map_err(|_| "the decoded path is not UTF-8".to_owned())
}

fn percent_decode_bytes(text: &str) -> Result<Vec<u8>, String> {
    let bytes = text.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%' {
            let hex = bytes
                .get(i + 1..i + 3)
                .and_then(|h| std::str::from_utf8(h).ok())
                .and_then(|h| u8::from_str_radix(h, 16).ok())
                .ok_or_else(|| format!("bad percent escape at byte {i}"))?;
            out.push(hex);
            i += 3;
        } else {
            out.push(bytes[i]);
            i += 1;
        }
    }
    Ok(out)
}

/// Decodes the part of a `data:` URI after `data:`.
fn decode_data_uri(rest: &str) -> Result<Vec<u8>, String> {
    let (header, payload) = rest
        .split_once(',')
        .ok_or_else(|| "no ',' before the data".to_owned())?;
    if header
        .rsplit(';')
        .next()
        .is_some_and(|p| p.eq_ignore_ascii_case("base64"))
    {
        decode_base64(payload)
    } else {
        percent_decode_bytes(payload)
    }
}

/// Standard base64 (RFC 4648 alphabet, `=` padding optional).
fn decode_base64(text: &str) -> Result<Vec<u8>, String> {
    let text = text.trim_end_matches('=');
    let mut out = Vec::with_capacity(text.len() / 4 * 3 + 2);
    let mut acc = 0u32;
    let mut bits = 0;
    for (i, c) in text.bytes().enumerate() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' => 62,
            b'/' => 63,
            _ => return Err(format!("invalid base64 character at position {i}")),
        };
        acc = (acc << 6) | u32::from(v);
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    if bits >= 6 {
        return Err("the base64 data has a stray final character".to_owned());
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_round_trips_known_vectors() {
        for (plain, coded) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg"),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(decode_base64(coded).unwrap(), plain.as_bytes(), "{coded}");
        }
        assert!(decode_base64("Zm9v!").is_err());
        assert!(decode_base64("Z").is_err());
    }

    #[test]
    fn uri_helpers() {
        assert!(has_scheme("http://x/y.bin"));
        assert!(!has_scheme("y.bin"));
        assert!(!has_scheme("dir/a:b.bin"));
        assert_eq!(percent_decode("a%20b.bin").unwrap(), "a b.bin");
        assert!(percent_decode("a%2").is_err());
        assert_eq!(decode_data_uri(",a%41").unwrap(), b"aA");
        assert_eq!(
            decode_data_uri("application/octet-stream;base64,AAEC").unwrap(),
            [0, 1, 2]
        );
    }

    #[test]
    fn glb_headers_are_checked() {
        assert!(split_glb(b"glTF").is_err());
        let mut short = b"glTF".to_vec();
        short.extend(2u32.to_le_bytes());
        short.extend(4u32.to_le_bytes());
        assert!(split_glb(&short).is_err());
    }
}
