//! The bench's scenes, smallest first: the Stanford bunny, a 20k-triangle terrain, the Stanford
//! dragon (when `../shared/data` has it), the Jacksboro fault DEM, a 200k-triangle terrain, a
//! soup of 200,000 random triangles and a 2M-triangle terrain. The three terrains sample the
//! same `synthetic::hills` 1 m apart, so throughput can be plotted against scene size alone.

use raypick::check::synthetic::{hills, terrain, triangle_soup};
use raypick::io::scene_files::{SceneFile, load_scene};
use raypick::{GridShape, Scene};
use std::path::{Path, PathBuf};

/// One scene: its name (in group names and the summary) and how to make it. `make` returns
/// `None`, saying why, when the scene's data file is absent.
pub struct SceneSpec {
    pub name: &'static str,
    pub make: fn() -> Option<Scene>,
}

pub const SCENES: [SceneSpec; 7] = [
    SceneSpec {
        name: "bunny",
        make: bunny,
    },
    SceneSpec {
        name: "terrain_20k",
        make: || Some(terrain_scene(101)),
    },
    SceneSpec {
        name: "dragon",
        make: dragon,
    },
    SceneSpec {
        name: "dem",
        make: dem,
    },
    SceneSpec {
        name: "terrain_200k",
        make: || Some(terrain_scene(317)),
    },
    SceneSpec {
        name: "soup_200k",
        make: soup,
    },
    SceneSpec {
        name: "terrain_2m",
        make: || Some(terrain_scene(1001)),
    },
];

/// Seed of the soup.
const SOUP_SEED: u64 = 1;

fn manifest_path(relative: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(relative)
}

fn load(path: PathBuf, what: &str) -> Scene {
    load_scene(&[SceneFile {
        file: path,
        mask: None,
        transform: None,
    }])
    .unwrap_or_else(|e| panic!("{what} loads: {e}"))
}

/// The Stanford bunny, 3,674 triangles (`tests/data/bunny.obj`).
fn bunny() -> Option<Scene> {
    Some(load(manifest_path("tests/data/bunny.obj"), "the bunny"))
}

/// The Stanford dragon at its second resolution, about 202k triangles
/// (`../shared/data/dragon_res2.obj`, outside the repository: skipped when absent).
fn dragon() -> Option<Scene> {
    let path = manifest_path("../shared/data/dragon_res2.obj");
    if !path.exists() {
        eprintln!("dragon: skipped, {} is absent", path.display());
        return None;
    }
    Some(load(path, "the dragon"))
}

/// The Jacksboro fault DEM, a real elevation grid: 275,772 triangles.
fn dem() -> Option<Scene> {
    Some(load(
        manifest_path("tests/data/jacksboro_fault_dem_utm.asc"),
        "the Jacksboro DEM",
    ))
}

/// `side × side` samples of `hills`, 1 m apart: 2 (side − 1)² triangles (101: 20,000;
/// 317: 199,712; 1001: 2,000,000). A height grid, as a DEM loads, so raypick builds it over
/// blocks.
fn terrain_scene(side: usize) -> Scene {
    let extent = (side - 1) as f64;
    let mesh = terrain(side, side, 0.0, extent, 1.0, hills);
    let shape = GridShape {
        columns: side as u32,
        rows: side as u32,
    };
    let mut scene = Scene::new();
    scene
        .add_grid_mesh("terrain", mesh, shape)
        .expect("the terrain is well formed");
    scene
}

/// 200,000 random triangles in a 100-unit cube, edges up to 10 units.
fn soup() -> Option<Scene> {
    let mesh = triangle_soup(200_000, 100.0, SOUP_SEED);
    Some(Scene::from_meshes([("soup".to_string(), mesh)]).expect("the soup is well formed"))
}
