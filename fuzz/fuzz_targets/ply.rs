//! Fuzzes the PLY loader, `raypick::io::ply::load_ply`.
//!
//! `load_ply` only takes a path, so each input is written to a per-process
//! scratch file (on /dev/shm when available) and loaded from there.
#![no_main]

use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use raypick::io::ply::load_ply;

fuzz_target!(|data: &[u8]| {
    static PATH: OnceLock<std::path::PathBuf> = OnceLock::new();
    let path = PATH.get_or_init(|| raypick_fuzz::scratch_path("ply"));
    std::fs::write(path, data).expect("write scratch file");
    let result = load_ply(path);
    raypick_fuzz::debug(&result, |m: &raypick::Mesh| {
        format!(
            "{} vertices, {} triangles",
            m.positions.len(),
            m.triangles.len()
        )
    });
    if let Ok(mesh) = result {
        raypick_fuzz::check_mesh(&mesh);
    }
});
