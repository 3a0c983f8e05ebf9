//! Elevation grids end to end, through the public API: the real Jacksboro DEM read from its
//! `.asc` and both GeoTIFFs gives one mesh; downward picks land on exact samples, decode to the
//! right grid cell and agree with the brute-force oracle; NODATA quads are never hit and keep
//! triangle ids stable; the mesh numbering is `synthetic::terrain`'s.

use glam::DVec3;
use rand::Rng;
use raypick::check::compare::Tally;
use raypick::check::oracle::brute_force_all;
use raypick::check::synthetic::{hills, rng, terrain};
use raypick::dem::{ElevationGrid, cell_of_triangle, grid_to_mesh, load_elevation};
use raypick::{BuildOptions, BuiltScene, CpuPicker, Error, Hit, Mesh, Picker, Ray, Scene};
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};
use std::time::Instant;

/// Height rays start from: well above any terrain in these tests.
const TOP: f64 = 10_000.0;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// The Jacksboro grid (from the .asc), its mesh and the built scene, shared by the tests.
fn jacksboro() -> &'static (ElevationGrid, Mesh, Arc<BuiltScene>) {
    static SCENE: OnceLock<(ElevationGrid, Mesh, Arc<BuiltScene>)> = OnceLock::new();
    SCENE.get_or_init(|| {
        let grid = load_elevation(&data("jacksboro_fault_dem_utm.asc")).expect("jacksboro .asc");
        let mesh = grid_to_mesh(&grid);
        let start = Instant::now();
        let built = build("jacksboro", mesh.clone());
        eprintln!("jacksboro: built the tree in {:.2?}", start.elapsed());
        (grid, mesh, built)
    })
}

fn build(name: &str, mesh: Mesh) -> Arc<BuiltScene> {
    let scene = Scene::from_meshes([(name.to_string(), mesh)]).expect("scene");
    Arc::new(BuiltScene::new(scene, &BuildOptions::default()).expect("build"))
}

fn down(x: f64, y: f64) -> Ray {
    Ray::new(DVec3::new(x, y, TOP), DVec3::NEG_Z)
}

fn pick(built: &Arc<BuiltScene>, rays: &[Ray]) -> Vec<Hit> {
    CpuPicker::new(built.clone()).pick(rays).expect("cpu pick")
}

/// World (x, y) of sample (row, col), whether or not it has a height.
fn xy(grid: &ElevationGrid, row: usize, col: usize) -> (f64, f64) {
    (
        grid.x0 + col as f64 * grid.dx,
        grid.y0 - row as f64 * grid.dy,
    )
}

#[test]
fn jacksboro_asc_and_both_geotiffs_give_the_same_mesh() {
    let (asc, mesh, _) = jacksboro();
    assert_eq!((asc.ncols, asc.nrows), (403, 344));
    assert!(asc.heights.iter().all(Option::is_some));
    assert_eq!(mesh.positions.len(), 403 * 344);
    assert_eq!(mesh.triangles.len(), 2 * 402 * 343);
    for name in [
        "jacksboro_fault_dem_utm_int16.tif",
        "jacksboro_fault_dem_utm_f32_deflate.tif",
    ] {
        let grid = load_elevation(&data(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(&grid, asc, "{name}");
        assert_eq!(&grid_to_mesh(&grid), mesh, "{name}");
    }
}

#[test]
fn downward_rays_at_samples_hit_them_exactly_and_decode_to_their_quads() {
    let (grid, mesh, built) = jacksboro();
    let mut samples = vec![
        (1, 1),
        (17, 300),
        (100, 200),
        (172, 201),
        (342, 401),
        // South and west border samples are hit too (north and east: see the border test).
        (343, 0),
        (343, 200),
        (200, 0),
    ];
    let mut random = rng(7);
    for _ in 0..200 {
        samples.push((
            random.random_range(1..grid.nrows - 1),
            random.random_range(1..grid.ncols - 1),
        ));
    }
    let rays: Vec<Ray> = samples
        .iter()
        .map(|&(r, c)| {
            let (x, y) = xy(grid, r, c);
            down(x, y)
        })
        .collect();
    let hits = pick(built, &rays);
    for (&(r, c), hit) in samples.iter().zip(&hits) {
        let p = grid.sample_position(r, c).expect("no NODATA in this grid");
        assert!(hit.hit, "sample ({r}, {c}) at {p}: missed");
        assert_eq!(hit.object, 0);
        let error = (hit.position - p).abs().max_element();
        assert!(
            error <= 1e-3,
            "sample ({r}, {c}): hit {} is {error} m from {p}",
            hit.position
        );
        assert!((hit.t - (TOP - p.z)).abs() <= 1e-3, "sample ({r}, {c})");
        let (qr, qc) = cell_of_triangle(grid.ncols, hit.triangle);
        assert!(
            (r.saturating_sub(1)..=r).contains(&qr) && (c.saturating_sub(1)..=c).contains(&qc),
            "sample ({r}, {c}): triangle {} is in quad ({qr}, {qc}), which does not touch it",
            hit.triangle
        );
        let vertex = (r * grid.ncols + c) as u32;
        assert!(
            mesh.triangles[hit.triangle as usize].contains(&vertex),
            "sample ({r}, {c}): triangle {} does not use vertex {vertex}",
            hit.triangle
        );
    }
}

/// Regression: a ray with a zero direction component lying exactly on a tree box's max face used
/// to be culled by the slab test (0 × inverse = 0), so border picks on the north (max y) and east
/// (max x) edges missed where the oracle hits.
#[test]
fn downward_rays_on_the_north_and_east_border_hit() {
    let (grid, _, built) = jacksboro();
    let samples = [(0, 0), (0, 200), (0, 402), (200, 402), (343, 402)];
    let rays: Vec<Ray> = samples
        .iter()
        .map(|&(r, c)| {
            let (x, y) = xy(grid, r, c);
            down(x, y)
        })
        .collect();
    let oracle = brute_force_all(&built.scene, &rays);
    for ((&(r, c), hit), truth) in samples.iter().zip(pick(built, &rays)).zip(&oracle) {
        assert!(truth.hit, "oracle: sample ({r}, {c}) missed");
        assert!(
            hit.hit,
            "cpu: sample ({r}, {c}) missed; oracle hit {truth:?}"
        );
    }
}

#[test]
fn downward_rays_inside_quads_decode_to_that_quad() {
    let (grid, _, built) = jacksboro();
    let mut random = rng(11);
    let mut cells = Vec::new();
    let mut rays = Vec::new();
    for _ in 0..300 {
        let (r, c) = (
            random.random_range(0..grid.nrows - 1),
            random.random_range(0..grid.ncols - 1),
        );
        // Strictly inside the quad, off its diagonal.
        let (fx, fy): (f64, f64) = (
            random.random_range(0.05..0.95),
            random.random_range(0.05..0.95),
        );
        if (fx - fy).abs() < 0.05 {
            continue;
        }
        let (x, y) = xy(grid, r, c);
        cells.push((r, c, fy > fx));
        rays.push(down(x + fx * grid.dx, y - fy * grid.dy));
    }
    for ((&(r, c, south_west), hit), ray) in cells.iter().zip(pick(built, &rays)).zip(&rays) {
        assert!(hit.hit, "ray {ray:?} missed");
        assert_eq!(
            cell_of_triangle(grid.ncols, hit.triangle),
            (r, c),
            "ray {ray:?}"
        );
        // Below the NW–SE diagonal (further south than east) is the even, south-west half.
        assert_eq!(hit.triangle % 2 == 0, south_west, "ray {ray:?}");
    }
}

#[test]
fn cpu_agrees_with_the_oracle_on_random_downward_rays() {
    let (grid, _, built) = jacksboro();
    let (x_lo, y_hi) = (grid.x0, grid.y0);
    let x_hi = grid.x0 + (grid.ncols - 1) as f64 * grid.dx;
    let y_lo = grid.y0 - (grid.nrows - 1) as f64 * grid.dy;
    // A margin of two cells around the grid, so some rays miss.
    let (mx, my) = (2.0 * grid.dx, 2.0 * grid.dy);
    let mut random = rng(2024);
    let mut rays: Vec<Ray> = (0..500)
        .map(|_| {
            down(
                random.random_range(x_lo - mx..x_hi + mx),
                random.random_range(y_lo - my..y_hi + my),
            )
        })
        .collect();
    // Plus rays through exact samples (vertices, shared edges), borders and corners included.
    let mut snapped = vec![(0, 0), (0, 402), (343, 0), (343, 402)];
    for _ in 0..96 {
        snapped.push((
            random.random_range(0..grid.nrows),
            random.random_range(0..grid.ncols),
        ));
    }
    let random_rays = rays.len();
    rays.extend(snapped.iter().map(|&(r, c)| {
        let (x, y) = xy(grid, r, c);
        down(x, y)
    }));

    let start = Instant::now();
    let cpu = pick(built, &rays);
    let cpu_time = start.elapsed();
    let start = Instant::now();
    let oracle = brute_force_all(&built.scene, &rays);
    let oracle_time = start.elapsed();

    let (tally, bad) = Tally::compare(&built.scene, &rays, &cpu, &oracle);
    eprintln!("jacksboro cpu/oracle: {tally:?}; cpu {cpu_time:.2?}, oracle {oracle_time:.2?}");
    let details: Vec<String> = bad
        .iter()
        .take(3)
        .map(|&i| {
            format!(
                "ray {:?}\n  cpu:    {:?}\n  oracle: {:?}",
                rays[i], cpu[i], oracle[i]
            )
        })
        .collect();
    assert_eq!(tally.mismatches, 0, "{}", details.join("\n"));
    // The random rays hit exactly when they are over the grid (~98% of the sampled area).
    let random_hits = cpu[..random_rays].iter().filter(|h| h.hit).count();
    assert!(random_hits > 450 && random_hits < 500, "{random_hits} hits");
    for (ray, hit) in rays.iter().zip(&cpu).take(random_rays) {
        let inside = (x_lo..=x_hi).contains(&ray.origin.x) && (y_lo..=y_hi).contains(&ray.origin.y);
        assert_eq!(hit.hit, inside, "ray {ray:?}");
    }
}

/// A 5 × 4 grid, cellsize 10, whose sample (1, 2) is NODATA.
const NODATA_ASC: &str = "ncols 5\nnrows 4\nxllcorner 1000\nyllcorner 2000\ncellsize 10\n\
                          NODATA_value -9999\n\
                          10 11 12 13 14\n\
                          15 16 -9999 18 19\n\
                          20 21 22 23 24\n\
                          25 26 27 28 29\n";

#[test]
fn nodata_quads_are_never_hit_and_triangle_ids_stay_stable() {
    let path = std::env::temp_dir().join(format!("raypick_dem_nodata_{}.asc", std::process::id()));
    std::fs::write(&path, NODATA_ASC).expect("write temp .asc");
    let grid = load_elevation(&path);
    std::fs::remove_file(&path).expect("remove temp .asc");
    let grid = grid.expect("nodata .asc");
    assert_eq!((grid.ncols, grid.nrows), (5, 4));
    assert_eq!(grid.height(1, 2), None);

    let mesh = grid_to_mesh(&grid);
    assert_eq!(mesh.triangles.len(), 2 * (5 - 1) * (4 - 1));
    // The same grid with the hole filled numbers every triangle the same way.
    let mut filled = grid.clone();
    filled.heights[7] = Some(17.0);
    let full = grid_to_mesh(&filled);
    let dead = [(0, 1), (0, 2), (1, 1), (1, 2)];
    for (t, (a, b)) in mesh.triangles.iter().zip(&full.triangles).enumerate() {
        if dead.contains(&cell_of_triangle(grid.ncols, t as u32)) {
            assert_eq!(a[0], a[1], "triangle {t} should be zero-area");
            assert_eq!(a[1], a[2], "triangle {t} should be zero-area");
        } else {
            assert_eq!(a, b, "triangle {t}");
        }
    }
    assert!(mesh.positions.iter().all(|p| p.is_finite()));

    let built = build("nodata", mesh);
    // At the NODATA sample, at the centre of each dead quad, and at the centre of every quad.
    let mut rays = Vec::new();
    let (x, y) = xy(&grid, 1, 2);
    rays.push(down(x, y));
    let mut quads = Vec::new();
    for r in 0..grid.nrows - 1 {
        for c in 0..grid.ncols - 1 {
            let (x, y) = xy(&grid, r, c);
            rays.push(down(x + 0.5 * grid.dx, y - 0.3 * grid.dy));
            quads.push((r, c));
        }
    }
    let hits = pick(&built, &rays);
    assert!(!hits[0].hit, "the NODATA sample was hit: {:?}", hits[0]);
    for (&(r, c), hit) in quads.iter().zip(&hits[1..]) {
        if dead.contains(&(r, c)) {
            assert!(!hit.hit, "dead quad ({r}, {c}) was hit: {hit:?}");
        } else {
            assert!(hit.hit, "quad ({r}, {c}) missed");
            assert_eq!(cell_of_triangle(grid.ncols, hit.triangle), (r, c));
        }
    }
    let oracle = brute_force_all(&built.scene, &rays);
    let (tally, bad) = Tally::compare(&built.scene, &rays, &hits, &oracle);
    assert_eq!(tally.mismatches, 0, "{tally:?}, rays {bad:?}");
}

#[test]
fn mesh_numbering_matches_synthetic_terrain() {
    let (cols, rows, x0, y0, cell) = (48, 40, 100.0, 200.0, 2.5);
    let mut heights = Vec::new();
    for r in 0..rows {
        for c in 0..cols {
            heights.push(Some(hills(x0 + c as f64 * cell, y0 - r as f64 * cell)));
        }
    }
    let grid = ElevationGrid {
        ncols: cols,
        nrows: rows,
        x0,
        y0,
        dx: cell,
        dy: cell,
        heights,
    };
    let expected = terrain(cols, rows, x0, y0, cell, hills);
    assert_eq!(grid_to_mesh(&grid), expected);
    for t in 0..expected.triangles.len() as u32 {
        let (r, c) = cell_of_triangle(cols, t);
        assert_eq!(expected.triangles[t as usize][0] as usize, r * cols + c);
    }
}

#[test]
fn load_elevation_refuses_unknown_formats() {
    let e = load_elevation(&data("bunny.obj")).unwrap_err();
    assert!(matches!(e, Error::Invalid(_)), "{e}");
    assert!(e.to_string().contains("bunny.obj"), "{e}");
    let e = load_elevation(&data("missing.tif")).unwrap_err();
    assert!(matches!(e, Error::Io { .. }), "{e}");
}
