//! Fuzzes the glTF 2.0 / GLB loader, `raypick::io::gltf::load_gltf`.
//!
//! `load_gltf` only takes a path, so each input is written to `in.gltf` in a
//! per-process scratch folder (on /dev/shm when available) that also holds a
//! few valid files (`tri.bin`, `sub/tri.bin`, ...; see
//! `raypick_fuzz::scratch_dir`) for buffer URIs to name. GLB inputs are
//! recognised by their magic, whatever the extension. Every mesh of a
//! successful load is checked (indices in range, finite positions).
#![no_main]

use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use raypick::io::gltf::load_gltf;

fuzz_target!(|data: &[u8]| {
    static PATH: OnceLock<std::path::PathBuf> = OnceLock::new();
    let path = PATH.get_or_init(|| raypick_fuzz::scratch_dir("gltf").join("in.gltf"));
    std::fs::write(path, data).expect("write scratch file");
    let result = load_gltf(path);
    raypick_fuzz::debug(&result, |objects: &Vec<(String, raypick::Mesh)>| {
        let vertices: usize = objects.iter().map(|(_, m)| m.positions.len()).sum();
        let triangles: usize = objects.iter().map(|(_, m)| m.triangles.len()).sum();
        format!(
            "{} objects, {vertices} vertices, {triangles} triangles",
            objects.len()
        )
    });
    if let Ok(objects) = result {
        for (_, mesh) in &objects {
            raypick_fuzz::check_mesh(mesh);
        }
    }
});
