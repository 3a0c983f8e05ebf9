//! Turning files into a scene: each OBJ file is one object, each elevation grid (ESRI ASCII
//! `.asc`, GeoTIFF `.tif`/`.tiff`) one terrain object whose hits report row and column, and each
//! glTF (`.gltf`, `.glb`) mesh primitive one object, with node transforms applied. Object ids follow the order of the files, then of the objects
//! inside a file. A scene description file (JSON) lists files with their layer masks.

use crate::dem::{grid_to_mesh, load_elevation};
use crate::error::{Error, Result};
use crate::io::gltf::load_gltf;
use crate::io::obj::load_obj;
use crate::scene::{GridShape, Scene};
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// One scene file and the layer mask its objects get.
#[derive(Clone, Debug, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    /// The file; relative paths in a description file are relative to the description.
    pub file: PathBuf,
    /// Layer mask for the file's objects (default: all bits).
    #[serde(default)]
    pub mask: Option<u32>,
}

/// A scene description file: `{"objects": [{"file": "terrain.asc", "mask": 1}, ...]}`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Description {
    objects: Vec<SceneFile>,
}

/// Reads a scene description (JSON) and returns its files, resolved against its folder.
pub fn load_description(path: &Path) -> Result<Vec<SceneFile>> {
    let name = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
        path: name.clone(),
        source,
    })?;
    let description: Description = serde_json::from_str(&text).map_err(|e| Error::Parse {
        path: name.clone(),
        line: Some(e.line()),
        message: e.to_string(),
    })?;
    let folder = path.parent().unwrap_or(Path::new(""));
    Ok(description
        .objects
        .into_iter()
        .map(|f| SceneFile {
            file: folder.join(f.file),
            mask: f.mask,
        })
        .collect())
}

/// Loads every file into one scene, in order.
pub fn load_scene(files: &[SceneFile]) -> Result<Scene> {
    let mut scene = Scene::new();
    for file in files {
        let first = scene.objects().len() as u32;
        add_file(&mut scene, &file.file)?;
        if let Some(mask) = file.mask {
            for id in first..scene.objects().len() as u32 {
                scene.set_object_mask(id, mask)?;
            }
        }
    }
    Ok(scene)
}

fn add_file(scene: &mut Scene, path: &Path) -> Result<()> {
    let name = path.display().to_string();
    let extension = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match extension.as_deref() {
        Some("obj") => {
            scene.add_mesh(name, load_obj(path)?)?;
        }
        Some("gltf" | "glb") => {
            for (object_name, mesh) in load_gltf(path)? {
                scene.add_mesh(object_name, mesh)?;
            }
        }
        Some("asc" | "tif" | "tiff") => {
            let grid = load_elevation(path)?;
            let shape = GridShape {
                columns: grid.ncols as u32,
                rows: grid.nrows as u32,
            };
            scene.add_grid_mesh(name, grid_to_mesh(&grid), shape)?;
        }
        _ => {
            return Err(Error::Invalid(format!(
                "{name}: unknown scene format (expected .obj, .gltf, .glb, .asc, .tif or .tiff)"
            )));
        }
    }
    Ok(())
}
