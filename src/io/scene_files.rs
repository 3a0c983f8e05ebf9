//! Turning files into a scene: each mesh file (OBJ, PLY — `.ply` or gzip-compressed `.ply.gz` —
//! and STL) is one object, each elevation grid (ESRI ASCII
//! `.asc`, GeoTIFF `.tif`/`.tiff`) one terrain object whose hits report row and column, and each
//! glTF (`.gltf`, `.glb`) mesh primitive one object, with node transforms applied. Object ids
//! follow the order of the files, then of the objects inside a file. A scene description file
//! (JSON) lists files with their layer masks and affine transforms; a file listed several times
//! is read once.
//!
//! Two ways to load a description: [`load_scene`] applies each transform to the file's f64
//! positions as it is loaded (`Scene::transform_object`), so each listing of a file is its own
//! copy; [`load_instanced`], when something is placed more than once (a file listed several
//! times, glTF nodes sharing a mesh), stores each mesh once and places it by its transforms, for
//! an instanced scene ([`crate::BuiltScene::instanced`]), and otherwise gives [`load_scene`]'s
//! scene, each file read once either way. Both give the same objects in the same order, under
//! the same names.
//!
//! Every scene file must be a regular file (a FIFO or a device is refused before it is opened),
//! and the files a description lists must stay inside its folder: relative paths without `..`
//! that resolve, symbolic links followed, to regular files in that folder or below it (see
//! [`crate::io::resolve_inside`]).

use crate::dem::{grid_to_mesh, load_elevation};
use crate::error::{Error, Result};
use crate::instance::Instance;
use crate::io::gltf::{Shared, load_gltf_placed, load_gltf_shared};
use crate::io::obj::load_obj;
use crate::io::ply::load_ply;
use crate::io::stl::load_stl;
use crate::io::{Refusal, open_regular, read_opened, regular_file, resolve_inside};
use crate::scene::{GridShape, Mesh, Scene};
use serde::Deserialize;
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

/// One scene file and the layer mask its objects get.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    /// The file; relative paths in a description file are relative to the description.
    pub file: PathBuf,
    /// Layer mask for the file's objects (default: all bits).
    #[serde(default)]
    pub mask: Option<u32>,
    /// Affine transform from the file's coordinates to the world, 3 × 4 row-major
    /// (`[[a, b, c, tx], [d, e, f, ty], [g, h, i, tz]]`: world = M·[x, y, z, 1]); none: the
    /// identity. Finite and not singular; a negative determinant mirrors the file's objects and
    /// keeps their front faces front ([`Scene::transform_object`]).
    #[serde(default, deserialize_with = "crate::scene::transform_rows")]
    pub transform: Option<[[f64; 4]; 3]>,
}

/// A scene description file: `{"objects": [{"file": "terrain.asc", "mask": 1,
/// "transform": [[1, 0, 0, 500], [0, 1, 0, 0], [0, 0, 1, 0]]}, ...]}`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Description {
    objects: Vec<SceneFile>,
}

/// The longest scene description read (64 MiB): one that lists 200,000 objects, each with a
/// file name, a mask and a transform, is about 10 MB.
pub const MAX_DESCRIPTION_BYTES: u64 = 64 << 20;

/// Bytes of memory per byte of a description while it is parsed, at most: its text, and each
/// listing's record (136 bytes, with its path's allocation about 170) for as few as 12 bytes of
/// JSON (`{"file":"a"},`), in a list that may hold twice its records while it grows.
const DESCRIPTION_BYTES_PER_BYTE: u64 = 32;

/// Reads a scene description (JSON) and returns its files, resolved against its folder.
///
/// # Errors
/// [`Error::Invalid`] naming the description when it is longer than [`MAX_DESCRIPTION_BYTES`],
/// and [`Error::OverBudget`] when its parse would not fit the memory budget, both before it is
/// read; [`Error::Io`] when the description or a file it lists cannot be read (or is not a
/// regular file); [`Error::Parse`] naming the description for malformed JSON, and for a listed path that
/// is absolute, contains `..` or leads out of the description's folder through a symbolic link.
pub fn load_description(path: &Path) -> Result<Vec<SceneFile>> {
    let name = path.display().to_string();
    let (file, length) = open_regular(path)?;
    if length > MAX_DESCRIPTION_BYTES {
        return Err(Error::Invalid(format!(
            "{name} is {} long, more than a scene description may be ({})",
            crate::budget::human(length),
            crate::budget::human(MAX_DESCRIPTION_BYTES)
        )));
    }
    crate::budget::check(
        &format!("reading and parsing the scene description {name}"),
        length,
        DESCRIPTION_BYTES_PER_BYTE,
    )?;
    let bytes = read_opened(path, file, length)?;
    let description: Description = serde_json::from_slice(&bytes).map_err(|e| Error::Parse {
        path: name.clone(),
        line: Some(e.line()),
        message: e.to_string(),
    })?;
    if description.objects.is_empty() {
        return Err(Error::Parse {
            path: name,
            line: None,
            message: "the description lists no objects".to_owned(),
        });
    }
    let folder = path.parent().unwrap_or(Path::new(""));
    description
        .objects
        .into_iter()
        .enumerate()
        .map(|(k, f)| {
            if f.file.as_os_str().is_empty() {
                return Err(Error::Parse {
                    path: name.clone(),
                    line: None,
                    message: format!("object {k}: the file name is empty"),
                });
            }
            let file = match resolve_inside(folder, &f.file) {
                Ok(file) => file,
                Err(Refusal::Io(source)) => {
                    return Err(Error::Io {
                        path: folder.join(&f.file).display().to_string(),
                        source,
                    });
                }
                Err(refusal) => {
                    return Err(Error::Parse {
                        path: name.clone(),
                        line: None,
                        message: format!(
                            "object {k}: file \"{}\" is refused: {refusal}; the files of a \
                             scene description must be relative paths inside its folder",
                            crate::budget::quote(&f.file.display().to_string())
                        ),
                    });
                }
            };
            if let Some(transform) = &f.transform
                && let Err(why) = crate::scene::check_transform(transform)
            {
                return Err(Error::Parse {
                    path: name.clone(),
                    line: None,
                    message: format!(
                        "object {k} (\"{}\"): the transform {why}",
                        crate::budget::quote(&f.file.display().to_string())
                    ),
                });
            }
            Ok(SceneFile {
                file,
                mask: f.mask,
                transform: f.transform,
            })
        })
        .collect()
}

/// What a triangle of a copied listing costs once the scene is built: its indices (12 bytes),
/// its share of the vertices (about 12), and of the tree (the leaf-order triangle, its id, the
/// nodes and the builder's working arrays: about 80). Measured: ten thousand listings of a
/// 32k-triangle grid once took 12 GB, with no budget asked.
const COPIED_TRIANGLE_BYTES: u64 = 104;

/// Loads every file into one scene, in order, each with its mask and transform. A file listed
/// more than once is read once and its objects copied.
pub fn load_scene(files: &[SceneFile]) -> Result<Scene> {
    load_scene_reading(files, HashMap::new())
}

/// [`load_scene`], taking the glTF files in `read` as already read rather than reading them.
///
/// Files are looked up by path in maps: a description of 20,000 files searched lists for each
/// listing, 28 s of the load.
fn load_scene_reading(files: &[SceneFile], mut read: HashMap<&Path, Shared>) -> Result<Scene> {
    let mut scene = Scene::new();
    let mut listings: HashMap<&Path, usize> = HashMap::new();
    for file in files {
        *listings.entry(&file.file).or_default() += 1;
    }
    let mut loaded: HashMap<&Path, Vec<FileObject>> = HashMap::new();
    // The triangles listed so far: a small file listed many times is copied that many times,
    // so the copies are checked against the budget before they are made.
    let mut triangles = 0u64;
    let count_of = |objects: &[FileObject]| {
        objects
            .iter()
            .map(|o| o.1.triangles.len() as u64)
            .sum::<u64>()
    };
    for (at, file) in files.iter().enumerate() {
        let first = scene.objects().len() as u32;
        let objects = match loaded.get(file.file.as_path()) {
            Some(objects) => {
                let copy = count_of(objects);
                let what = format!(
                    "the triangles of the scene's {} listings (a file listed again is copied)",
                    files.len()
                );
                if crate::budget::check(
                    &what,
                    triangles.saturating_add(copy),
                    COPIED_TRIANGLE_BYTES,
                )
                .is_err()
                {
                    // Said with what the whole scene needs as far as it is known (the listings
                    // of the files read so far, to the end), not the sum at the listing where
                    // it crossed the budget: that figure, given as the budget, failed again.
                    let rest: u64 = files[at..]
                        .iter()
                        .filter_map(|f| loaded.get(f.file.as_path()))
                        .map(|objects| count_of(objects))
                        .sum();
                    crate::budget::check(
                        &format!("{what}, counting the files read so far,"),
                        triangles.saturating_add(rest),
                        COPIED_TRIANGLE_BYTES,
                    )?;
                }
                objects.clone()
            }
            None => {
                let objects = match read.remove(file.file.as_path()) {
                    Some(shared) => gltf_objects(shared.into_placed()?),
                    None => read_file(&file.file)?,
                };
                if listings[file.file.as_path()] > 1 {
                    loaded.insert(&file.file, objects.clone());
                }
                objects
            }
        };
        triangles += count_of(&objects);
        for (name, mesh, grid, mirrored) in objects {
            let id = match grid {
                Some(shape) => scene.add_grid_mesh(name, mesh, shape)?,
                None => scene.add_mesh(name, mesh)?,
            };
            if mirrored {
                scene.flip_winding(id);
            }
        }
        for id in first..scene.objects().len() as u32 {
            if let Some(mask) = file.mask {
                scene.set_object_mask(id, mask)?;
            }
            if let Some(transform) = &file.transform {
                scene.transform_object(id, transform)?;
            }
        }
    }
    Ok(scene)
}

/// What [`load_instanced`] made of a scene's files.
#[derive(Debug)]
pub enum Loaded {
    /// Something is placed more than once (a file listed several times, or glTF nodes sharing a
    /// mesh): each mesh stored once in its file's coordinates, and one instance per object
    /// [`load_scene`] would make, in the same order and with the same names, its transform the
    /// listing's composed with the glTF node's.
    Instanced(Vec<Scene>, Vec<Instance>),
    /// Nothing repeats: the scene [`load_scene`] makes (a scene of copies is then the same
    /// scene, and simpler).
    Copies(Scene),
}

/// Loads `files` for a scene that may be instanced ([`Loaded`]), reading each file once.
/// Listed once each, only a glTF file's nodes can repeat a mesh: those files are read first,
/// and when none repeats one the scene is loaded as [`load_scene`] loads it, from those reads.
pub fn load_instanced(files: &[SceneFile]) -> Result<Loaded> {
    // Per distinct file: its placements (name, mesh index, file-to-listing transform).
    type Placements = Vec<(String, u32, glam::DMat4)>;
    // Files are looked up by path in maps (a description of 20,000 files searched lists for
    // each listing: 28 s).
    let mut seen = HashSet::new();
    let listed_twice = !files.iter().all(|f| seen.insert(f.file.as_path()));
    let mut early: HashMap<&Path, Shared> = HashMap::new();
    if !listed_twice {
        for file in files.iter().filter(|f| is_gltf(&f.file)) {
            early.insert(&file.file, read_gltf(&file.file)?);
        }
        if !early.values().any(repeats) {
            return load_scene_reading(files, early).map(Loaded::Copies);
        }
    }
    let mut meshes: Vec<Scene> = Vec::new();
    let mut loaded: Vec<Placements> = Vec::new();
    let mut loaded_at: HashMap<&Path, usize> = HashMap::new();
    let mut instances = Vec::new();
    for file in files {
        let k = match loaded_at.get(file.file.as_path()) {
            Some(&k) => k,
            None => {
                // A glTF read above: its meshes go after those before it, as if read here.
                let placements = match early.remove(file.file.as_path()) {
                    Some(shared) => share(shared, &mut meshes)?,
                    None => read_file_shared(&file.file, &mut meshes)?,
                };
                loaded.push(placements);
                loaded_at.insert(&file.file, loaded.len() - 1);
                loaded.len() - 1
            }
        };
        let listing = file.transform.map_or(glam::DMat4::IDENTITY, |m| {
            glam::DMat4::from_cols_array_2d(&[
                [m[0][0], m[1][0], m[2][0], 0.0],
                [m[0][1], m[1][1], m[2][1], 0.0],
                [m[0][2], m[1][2], m[2][2], 0.0],
                [m[0][3], m[1][3], m[2][3], 1.0],
            ])
        });
        for (name, mesh, placed) in &loaded[k] {
            let world = listing * *placed;
            let row = |r: usize| {
                let v = world.row(r);
                [v.x, v.y, v.z, v.w]
            };
            instances.push(Instance {
                name: name.clone(),
                mesh: *mesh,
                transform: [row(0), row(1), row(2)],
                mask: file.mask.unwrap_or(u32::MAX),
            });
        }
    }
    Ok(Loaded::Instanced(meshes, instances))
}

/// Whether a placement's transform can place an instance: finite, not singular and affine. A
/// node that flattens its mesh (a zero scale) places a copy instead (see [`share`]).
fn instanceable(world: &glam::DMat4) -> bool {
    let affine = [0, 1, 2].map(|r| world.row(r).to_array());
    crate::scene::check_transform(&affine).is_ok() && world.row(3) == glam::DVec4::W
}

/// Whether two of a glTF file's instanceable placements place the same primitive.
fn repeats(shared: &Shared) -> bool {
    let mut used: Vec<usize> = shared
        .placements()
        .iter()
        .filter(|p| instanceable(&p.world))
        .map(|p| p.primitive)
        .collect();
    used.sort_unstable();
    used.windows(2).any(|w| w[0] == w[1])
}

/// Whether `path` names a glTF file (`.gltf` or `.glb`, any case).
pub fn is_gltf(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("gltf") || e.eq_ignore_ascii_case("glb"))
}

/// Reads the glTF file at `path`, each primitive once.
fn read_gltf(path: &Path) -> Result<Shared> {
    regular_file(path)?;
    load_gltf_shared(path)
}

/// Puts a glTF file's primitives into `meshes` (each a scene of one object, in the mesh's
/// coordinates) and returns its placements: name, mesh index and the transform that places it.
fn share(shared: Shared, meshes: &mut Vec<Scene>) -> Result<Vec<(String, u32, glam::DMat4)>> {
    let base = meshes.len() as u32;
    let (primitives, placements) = shared.into_parts();
    for primitive in primitives {
        let mut scene = Scene::new();
        scene.add_mesh(primitive.name, primitive.mesh)?;
        meshes.push(scene);
    }
    let mut out = Vec::with_capacity(placements.len());
    for placement in placements {
        let mesh = base + placement.primitive as u32;
        if instanceable(&placement.world) {
            out.push((placement.name, mesh, placement.world));
        } else {
            // A node that flattens its mesh (a zero scale) places a copy, as loaded.
            let source = &meshes[mesh as usize];
            let copy = Mesh {
                positions: source
                    .positions()
                    .iter()
                    .map(|p| placement.world.transform_point3(*p))
                    .collect(),
                triangles: source.triangles().to_vec(),
            };
            let mut scene = Scene::new();
            scene.add_mesh(placement.name.clone(), copy)?;
            meshes.push(scene);
            out.push((
                placement.name,
                meshes.len() as u32 - 1,
                glam::DMat4::IDENTITY,
            ));
        }
    }
    Ok(out)
}

/// Reads `path`'s meshes into `meshes` (each a scene of one object, in the file's coordinates)
/// and returns its objects' placements: name, mesh index and the transform that places it.
fn read_file_shared(
    path: &Path,
    meshes: &mut Vec<Scene>,
) -> Result<Vec<(String, u32, glam::DMat4)>> {
    if is_gltf(path) {
        return share(read_gltf(path)?, meshes);
    }
    let mut out = Vec::new();
    for (name, mesh, grid, mirrored) in read_file(path)? {
        let mut scene = Scene::new();
        let id = match grid {
            Some(shape) => scene.add_grid_mesh(name.clone(), mesh, shape)?,
            None => scene.add_mesh(name.clone(), mesh)?,
        };
        if mirrored {
            scene.flip_winding(id);
        }
        meshes.push(scene);
        out.push((name, meshes.len() as u32 - 1, glam::DMat4::IDENTITY));
    }
    Ok(out)
}

/// One object a file holds: its name, mesh, grid shape (for an elevation grid), and whether
/// the file's own placement mirrors it (a glTF node with a negative determinant).
type FileObject = (String, Mesh, Option<GridShape>, bool);

/// A glTF file's placed objects ([`load_gltf_placed`]) as a file's objects.
fn gltf_objects(placed: Vec<(String, Mesh, bool)>) -> Vec<FileObject> {
    placed
        .into_iter()
        .map(|(name, mesh, mirrored)| (name, mesh, None, mirrored))
        .collect()
}

/// Reads `path`'s objects.
fn read_file(path: &Path) -> Result<Vec<FileObject>> {
    let name = path.display().to_string();
    // Before any loader opens it: a FIFO would block the open, a device never ends.
    regular_file(path)?;
    let extension = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let inner_extension = path
        .file_stem()
        .map(Path::new)
        .and_then(Path::extension)
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let one = |mesh: Mesh| vec![(name.clone(), mesh, None, false)];
    Ok(match extension.as_deref() {
        Some("obj") => one(load_obj(path)?),
        Some("ply") => one(load_ply(path)?),
        Some("gz") if inner_extension.as_deref() == Some("ply") => one(load_ply(path)?),
        Some("stl") => one(load_stl(path)?),
        Some("gltf" | "glb") => gltf_objects(load_gltf_placed(path)?),
        Some("asc" | "tif" | "tiff") => {
            let grid = load_elevation(path)?;
            // The mesh: a vertex (24 bytes) and two triangles (2 × 12 bytes) per sample.
            crate::budget::check(
                &format!(
                    "{name}: the mesh of the {} × {} grid",
                    grid.ncols, grid.nrows
                ),
                (grid.ncols as u64).saturating_mul(grid.nrows as u64),
                48,
            )?;
            let shape = GridShape {
                columns: grid.ncols as u32,
                rows: grid.nrows as u32,
            };
            vec![(name.clone(), grid_to_mesh(&grid), Some(shape), false)]
        }
        _ => {
            return Err(Error::Invalid(format!(
                "{name}: unknown scene format (expected .obj, .ply, .ply.gz, .stl, .gltf, .glb, .asc, \
                 .tif or .tiff)"
            )));
        }
    })
}
