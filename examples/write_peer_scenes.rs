//! Writes the peers bench's two synthetic scenes as files, so that programs outside Rust (Open3D
//! in `benches/engine_vs_open3d.sh`) can load the very same triangles: the 2M-triangle terrain
//! as an ESRI ASCII grid (`terrain_2m.asc`: `synthetic::hills` sampled 1 m apart, 1001 × 1001
//! samples, which raypick loads as a height grid, like the bench) and the 200k-triangle soup as
//! OBJ (`soup_200k.obj`).
//!
//! `cargo run --release --example write_peer_scenes -- OUT_DIR`

use raypick::check::synthetic::{hills, terrain, triangle_soup};
use std::fmt::Write as _;
use std::path::PathBuf;

/// Samples per side of the 2M terrain (as `benches/peers/scenes.rs`).
const SIDE: usize = 1001;
/// Triangles and seed of the soup (as `benches/peers/scenes.rs`).
const SOUP: (usize, u64) = (200_000, 1);

fn main() -> std::io::Result<()> {
    let out = PathBuf::from(
        std::env::args()
            .nth(1)
            .unwrap_or_else(|| "target/peer-scenes".into()),
    );
    std::fs::create_dir_all(&out)?;

    // Row r of `terrain` lies at y = extent - r (north first), as an ASCII grid lists its rows;
    // the lower-left sample is at (0, 0).
    let extent = (SIDE - 1) as f64;
    let mesh = terrain(SIDE, SIDE, 0.0, extent, 1.0, hills);
    let mut asc = format!(
        "ncols {SIDE}\nnrows {SIDE}\nxllcenter 0\nyllcenter 0\ncellsize 1\nNODATA_value -9999\n"
    );
    for row in mesh.positions.chunks(SIDE) {
        let line: Vec<String> = row.iter().map(|p| format!("{}", p.z)).collect();
        asc.push_str(&line.join(" "));
        asc.push('\n');
    }
    std::fs::write(out.join("terrain_2m.asc"), asc)?;

    let soup = triangle_soup(SOUP.0, 100.0, SOUP.1);
    let mut obj = String::new();
    for p in &soup.positions {
        writeln!(obj, "v {} {} {}", p.x, p.y, p.z).expect("writing to a String");
    }
    for t in &soup.triangles {
        writeln!(obj, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1).expect("writing to a String");
    }
    std::fs::write(out.join("soup_200k.obj"), obj)?;
    println!("wrote {}/terrain_2m.asc and soup_200k.obj", out.display());
    Ok(())
}
