//! Synthetic scenes and ray sets, seeded so every run replays: the built-in example scene (and
//! its files, which `raypick example` writes), the test scenes, and the ray kinds `raypick
//! verify` and the tests check.

use crate::ray::Ray;
use crate::scene::{GridShape, Mesh, Scene};
use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::f64::consts::TAU;

/// A seeded random generator.
pub fn rng(seed: u64) -> Pcg64 {
    Pcg64::seed_from_u64(seed)
}

/// A height-grid terrain of `cols × rows` samples spaced `cell` apart, sample (r, c) at
/// `x = x0 + c·cell`, `y = y0 − r·cell` (row 0 north), `z = height(x, y)`. Quad (r, c) becomes
/// triangles 2k = (NW, SW, SE) and 2k+1 = (NW, SE, NE), k = r·(cols−1) + c.
pub fn terrain(
    cols: usize,
    rows: usize,
    x0: f64,
    y0: f64,
    cell: f64,
    height: impl Fn(f64, f64) -> f64,
) -> Mesh {
    let mut positions = Vec::with_capacity(cols * rows);
    for r in 0..rows {
        for c in 0..cols {
            let (x, y) = (x0 + c as f64 * cell, y0 - r as f64 * cell);
            positions.push(DVec3::new(x, y, height(x, y)));
        }
    }
    let mut triangles = Vec::with_capacity(2 * cols.saturating_sub(1) * rows.saturating_sub(1));
    for r in 0..rows.saturating_sub(1) {
        for c in 0..cols.saturating_sub(1) {
            let nw = (r * cols + c) as u32;
            let (ne, sw, se) = (nw + 1, nw + cols as u32, nw + cols as u32 + 1);
            triangles.push([nw, sw, se]);
            triangles.push([nw, se, ne]);
        }
    }
    Mesh {
        positions,
        triangles,
    }
}

/// Rolling hills, for terrains and the example scene.
pub fn hills(x: f64, y: f64) -> f64 {
    8.0 * (x * 0.05).sin() * (y * 0.07).cos() + 3.0 * (x * 0.21 + y * 0.13).sin()
}

/// `count` random triangles with corners in a `size`-wide cube, edges up to `size / 10`.
pub fn triangle_soup(count: usize, size: f64, seed: u64) -> Mesh {
    let mut rng = rng(seed);
    let mut positions = Vec::with_capacity(3 * count);
    for _ in 0..count {
        let centre = DVec3::new(rng.random(), rng.random(), rng.random()) * size;
        for _ in 0..3 {
            let offset = DVec3::new(rng.random(), rng.random(), rng.random()) - 0.5;
            positions.push(centre + offset * (size / 10.0));
        }
    }
    let triangles = (0..count as u32)
        .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
        .collect();
    Mesh {
        positions,
        triangles,
    }
}

/// Thin slivers, zero-area triangles (repeated and collinear vertices) and ordinary ones mixed.
pub fn thin_and_degenerate(seed: u64) -> Mesh {
    let mut rng = rng(seed);
    let mut mesh = Mesh::default();
    for i in 0..200 {
        // Integer corners keep the collinear case exactly collinear in f64.
        let base = DVec3::new(
            rng.random_range(0..10) as f64,
            rng.random_range(0..10) as f64,
            rng.random_range(0..10) as f64,
        );
        let along = DVec3::new(
            rng.random_range(1..4) as f64,
            rng.random_range(-3..4) as f64,
            rng.random_range(-3..4) as f64,
        );
        let across = DVec3::new(rng.random(), rng.random(), rng.random()) - 0.5;
        let corners = match i % 4 {
            0 => [base, base + along, base + along * 2.0], // collinear: zero area
            1 => [base, base, base + across],              // repeated vertex: zero area
            2 => [base, base + along * 3.0, base + along * 1.5 + across * 1e-4], // sliver
            _ => [base, base + along, base + across],      // ordinary
        };
        let first = mesh.positions.len() as u32;
        mesh.positions.extend(corners);
        mesh.triangles.push([first, first + 1, first + 2]);
    }
    mesh
}

/// One triangle.
pub fn single_triangle() -> Mesh {
    Mesh {
        positions: vec![
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(0.0, 1.0, 0.0),
        ],
        triangles: vec![[0, 1, 2]],
    }
}

/// The built-in example scene: a 96 × 96 height-grid terrain (object 0; samples 1 apart at
/// integer x, y from 0 to 95, row 0 north at y = 95, heights [`hills`]; hits report row and
/// column) with two box "buildings" on it, the "tower" (object 1) and the "hall" (object 2).
pub fn example_scene() -> Scene {
    let mut scene = Scene::new();
    for (name, mesh, grid) in example_objects() {
        let added = match grid {
            Some(grid) => scene.add_grid_mesh(name, mesh, grid),
            None => scene.add_mesh(name, mesh),
        };
        added.expect("the example scene is well formed");
    }
    scene
}

/// The objects of [`example_scene`] in id order: name, mesh and, for the terrain, its grid
/// shape.
pub fn example_objects() -> Vec<(String, Mesh, Option<GridShape>)> {
    let (columns, rows) = (96, 96);
    let ground = terrain(columns, rows, 0.0, 95.0, 1.0, hills);
    let building = |x: f64, y: f64, w: f64, h: f64| {
        let z0 = hills(x, y) - 2.0;
        let lo = DVec3::new(x, y, z0);
        let hi = DVec3::new(x + w, y + w, z0 + h);
        box_mesh(lo, hi)
    };
    let grid = GridShape {
        columns: columns as u32,
        rows: rows as u32,
    };
    vec![
        ("terrain".to_string(), ground, Some(grid)),
        ("tower".to_string(), building(30.0, 40.0, 8.0, 30.0), None),
        ("hall".to_string(), building(60.0, 55.0, 14.0, 12.0), None),
    ]
}

/// The layer masks of [`example_scene_files`]' scene description: the terrain is layer 1, the
/// buildings layer 2.
pub const EXAMPLE_MASKS: [u32; 3] = [1, 2, 2];

/// [`example_scene`] as files, `(file name, text)`: `terrain.asc` (an ESRI ASCII grid whose
/// samples sit where the terrain's vertices do), `tower.obj` and `hall.obj`, and `scene.json`, a
/// scene description listing the three in object order with the layer masks
/// [`EXAMPLE_MASKS`]. Numbers are written in shortest round-trip form, so the files load into
/// the very same triangles, ids and answers as the built-in scene (`raypick example`).
pub fn example_scene_files() -> Vec<(String, String)> {
    use std::fmt::Write;
    let number = crate::io::output::csv_number;
    let mut files = Vec::new();
    for (name, mesh, grid) in example_objects() {
        let mut text = String::new();
        let file = match grid {
            Some(grid) => {
                let (columns, rows) = (grid.columns as usize, grid.rows as usize);
                let (first, cell) = (mesh.positions[0], mesh.positions[1].x - mesh.positions[0].x);
                // Sample (r, c) at x = xllcenter + c·cell, y = yllcenter + (rows − 1 − r)·cell:
                // the south-west sample is the last row's first.
                let _ = writeln!(text, "ncols {columns}\nnrows {rows}");
                let _ = writeln!(text, "xllcenter {}", number(first.x));
                let _ = writeln!(
                    text,
                    "yllcenter {}",
                    number(first.y - (rows - 1) as f64 * cell)
                );
                let _ = writeln!(text, "cellsize {}", number(cell));
                for row in mesh.positions.chunks(columns) {
                    let heights: Vec<String> = row.iter().map(|p| number(p.z)).collect();
                    let _ = writeln!(text, "{}", heights.join(" "));
                }
                format!("{name}.asc")
            }
            None => {
                let _ = writeln!(text, "# raypick's built-in example scene: the {name}");
                for p in &mesh.positions {
                    let _ = writeln!(text, "v {} {} {}", number(p.x), number(p.y), number(p.z));
                }
                for [a, b, c] in &mesh.triangles {
                    let _ = writeln!(text, "f {} {} {}", a + 1, b + 1, c + 1);
                }
                format!("{name}.obj")
            }
        };
        files.push((file, text));
    }
    let objects: Vec<String> = files
        .iter()
        .zip(EXAMPLE_MASKS)
        .map(|((file, _), mask)| format!("    {{\"file\": \"{file}\", \"mask\": {mask}}}"))
        .collect();
    files.push((
        "scene.json".to_string(),
        format!("{{\"objects\": [\n{}\n]}}\n", objects.join(",\n")),
    ));
    files
}

/// A closed axis-aligned box as 12 outward-facing triangles.
pub fn box_mesh(lo: DVec3, hi: DVec3) -> Mesh {
    let positions = (0..8)
        .map(|i| {
            DVec3::new(
                [lo.x, hi.x][i & 1],
                [lo.y, hi.y][(i >> 1) & 1],
                [lo.z, hi.z][(i >> 2) & 1],
            )
        })
        .collect();
    let quads = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let triangles = quads
        .iter()
        .flat_map(|&[a, b, c, d]| [[a, b, c], [a, c, d]])
        .collect();
    Mesh {
        positions,
        triangles,
    }
}

/// A closed sphere: an icosahedron subdivided `levels` times (20·4^levels triangles, all
/// outward-facing), every edge shared by exactly two triangles.
pub fn icosphere(centre: DVec3, radius: f64, levels: u32) -> Mesh {
    let p = (1.0 + 5f64.sqrt()) / 2.0;
    let mut positions: Vec<DVec3> = [
        (-1.0, p, 0.0),
        (1.0, p, 0.0),
        (-1.0, -p, 0.0),
        (1.0, -p, 0.0),
        (0.0, -1.0, p),
        (0.0, 1.0, p),
        (0.0, -1.0, -p),
        (0.0, 1.0, -p),
        (p, 0.0, -1.0),
        (p, 0.0, 1.0),
        (-p, 0.0, -1.0),
        (-p, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| DVec3::new(x, y, z).normalize())
    .collect();
    let mut triangles: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..levels {
        let mut midpoints = std::collections::HashMap::new();
        let mut midpoint = |a: u32, b: u32, positions: &mut Vec<DVec3>| {
            *midpoints.entry((a.min(b), a.max(b))).or_insert_with(|| {
                positions.push(((positions[a as usize] + positions[b as usize]) * 0.5).normalize());
                positions.len() as u32 - 1
            })
        };
        triangles = triangles
            .iter()
            .flat_map(|&[a, b, c]| {
                let ab = midpoint(a, b, &mut positions);
                let bc = midpoint(b, c, &mut positions);
                let ca = midpoint(c, a, &mut positions);
                [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
            })
            .collect();
    }
    Mesh {
        positions: positions.into_iter().map(|p| centre + p * radius).collect(),
        triangles,
    }
}

/// The kinds of ray the equivalence checks cover.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum RayKind {
    /// A pinhole camera's pixel grid looking at the scene.
    Camera,
    /// Random origins around the scene, random directions.
    Random,
    /// Aimed exactly at triangle vertices.
    Vertex,
    /// Aimed exactly at edge midpoints.
    EdgeMidpoint,
    /// Nearly parallel to the triangle they are aimed at (0.2° to 3°).
    Grazing,
    /// Along ±x, ±y or ±z, so two direction components are zero.
    AxisParallel,
    /// Starting inside the scene's bounds.
    InsideBox,
    /// Aimed at a triangle with `tmax` cutting off before or after it.
    TmaxCutoff,
}

impl RayKind {
    /// Every kind, in report order.
    pub const ALL: [RayKind; 8] = [
        RayKind::Camera,
        RayKind::Random,
        RayKind::Vertex,
        RayKind::EdgeMidpoint,
        RayKind::Grazing,
        RayKind::AxisParallel,
        RayKind::InsideBox,
        RayKind::TmaxCutoff,
    ];

    /// A short lowercase name for reports.
    pub fn name(self) -> &'static str {
        match self {
            RayKind::Camera => "camera",
            RayKind::Random => "random",
            RayKind::Vertex => "vertex",
            RayKind::EdgeMidpoint => "edge-midpoint",
            RayKind::Grazing => "grazing",
            RayKind::AxisParallel => "axis-parallel",
            RayKind::InsideBox => "inside-box",
            RayKind::TmaxCutoff => "tmax-cutoff",
        }
    }
}

/// `count` rays of `kind` for `scene`, from `seed`.
pub fn rays(scene: &Scene, kind: RayKind, count: usize, seed: u64) -> Vec<Ray> {
    let mut rng = rng(seed ^ (kind as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let (lo, hi) = scene.bounds().unwrap_or((DVec3::ZERO, DVec3::ONE));
    let centre = (lo + hi) * 0.5;
    let radius = ((hi - lo).length() * 0.5).max(1e-3);
    let in_box = |rng: &mut Pcg64, grow: f64| {
        let f = DVec3::new(rng.random(), rng.random(), rng.random());
        centre + (lo - centre + (hi - lo) * f) * grow
    };
    let triangles = scene.triangle_count();
    let random_triangle = |rng: &mut Pcg64| {
        scene.world_triangle(rng.random_range(0..triangles.max(1)).min(triangles - 1))
    };
    let around = |rng: &mut Pcg64| centre + unit_vector(rng) * radius * 2.0;
    if triangles == 0
        && matches!(
            kind,
            RayKind::Vertex | RayKind::EdgeMidpoint | RayKind::Grazing | RayKind::TmaxCutoff
        )
    {
        return rays(scene, RayKind::Random, count, seed);
    }
    match kind {
        RayKind::Camera => {
            let side = (count as f64).sqrt().ceil().max(1.0) as usize;
            let eye = centre + DVec3::new(0.4, -1.0, 1.6).normalize() * radius * 2.5;
            let forward = (centre - eye).normalize();
            let right = forward.cross(DVec3::Z).normalize();
            let up = right.cross(forward);
            let half = (20f64.to_radians()).tan();
            (0..count)
                .map(|i| {
                    let (px, py) = ((i % side) as f64 + 0.5, (i / side) as f64 + 0.5);
                    let sx = (2.0 * px / side as f64 - 1.0) * half;
                    let sy = (1.0 - 2.0 * py / side as f64) * half;
                    Ray::new(eye, forward + right * sx + up * sy)
                })
                .collect()
        }
        RayKind::Random => (0..count)
            .map(|_| Ray::new(in_box(&mut rng, 1.5), unit_vector(&mut rng)))
            .collect(),
        RayKind::Vertex => (0..count)
            .map(|_| {
                let target = random_triangle(&mut rng)[rng.random_range(0..3)];
                let origin = around(&mut rng);
                Ray::new(origin, target - origin)
            })
            .collect(),
        RayKind::EdgeMidpoint => (0..count)
            .map(|_| {
                let t = random_triangle(&mut rng);
                let k = rng.random_range(0..3);
                let target = (t[k] + t[(k + 1) % 3]) * 0.5;
                let origin = around(&mut rng);
                Ray::new(origin, target - origin)
            })
            .collect(),
        RayKind::Grazing => (0..count)
            .map(|_| {
                let [a, b, c] = random_triangle(&mut rng);
                let (s, w) = (rng.random::<f64>(), rng.random::<f64>());
                let (s, w) = if s + w > 1.0 {
                    (1.0 - s, 1.0 - w)
                } else {
                    (s, w)
                };
                let target = a + (b - a) * s + (c - a) * w;
                let normal = (b - a).cross(c - a).normalize_or_zero();
                let tangent = (b - a).normalize_or_zero();
                let angle = rng.random_range(0.2f64..3.0).to_radians();
                let dir = tangent * angle.cos() + normal * angle.sin();
                let dir = if dir == DVec3::ZERO {
                    unit_vector(&mut rng)
                } else {
                    dir
                };
                Ray::new(target - dir * radius, dir * radius)
            })
            .collect(),
        RayKind::AxisParallel => (0..count)
            .map(|_| {
                let mut dir = DVec3::ZERO;
                dir[rng.random_range(0..3)] = if rng.random() { 1.0 } else { -1.0 };
                Ray::new(in_box(&mut rng, 1.2), dir)
            })
            .collect(),
        RayKind::InsideBox => (0..count)
            .map(|_| Ray::new(in_box(&mut rng, 1.0), unit_vector(&mut rng)))
            .collect(),
        RayKind::TmaxCutoff => (0..count)
            .map(|_| {
                let [a, b, c] = random_triangle(&mut rng);
                let target = (a + b + c) / 3.0;
                let origin = around(&mut rng);
                Ray::new(origin, target - origin).with_range(0.0, rng.random_range(0.5..1.5))
            })
            .collect(),
    }
}

/// `count` rays spread evenly over every kind, with each ray's kind.
pub fn mixed_rays(scene: &Scene, count: usize, seed: u64) -> Vec<(RayKind, Ray)> {
    let per_kind = count / RayKind::ALL.len();
    let extra = count % RayKind::ALL.len();
    RayKind::ALL
        .iter()
        .enumerate()
        .flat_map(|(k, &kind)| {
            let n = per_kind + usize::from(k < extra);
            rays(scene, kind, n, seed)
                .into_iter()
                .map(move |r| (kind, r))
        })
        .collect()
}

fn unit_vector(rng: &mut Pcg64) -> DVec3 {
    let z: f64 = rng.random_range(-1.0..1.0);
    let phi = rng.random::<f64>() * TAU;
    let s = (1.0 - z * z).sqrt();
    DVec3::new(s * phi.cos(), s * phi.sin(), z)
}
