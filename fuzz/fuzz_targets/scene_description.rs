//! Fuzzes the scene-description reader, `raypick::io::scene_files::load_description`,
//! and loads what it accepts with `load_scene`.
//!
//! Each input is written to `scene.json` in a per-process scratch folder (on
//! /dev/shm when available) that also holds small valid scene files
//! (`tri.obj`, `grid.asc`, `tri.gltf` with `tri.bin`; see
//! `raypick_fuzz::scratch_dir`), so accepted descriptions load real files.
//! Besides "no panic", every file an accepted description lists must lie in
//! the scratch folder (the reader's promise: relative paths without `..`).
#![no_main]

use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use raypick::io::scene_files::{load_description, load_scene};

fuzz_target!(|data: &[u8]| {
    static DIR: OnceLock<std::path::PathBuf> = OnceLock::new();
    let dir = DIR.get_or_init(|| raypick_fuzz::scratch_dir("scenes"));
    let path = dir.join("scene.json");
    std::fs::write(&path, data).expect("write scratch file");
    let result = load_description(&path);
    raypick_fuzz::debug(&result, |files| format!("{} files", files.len()));
    let Ok(files) = result else {
        return;
    };
    let base = std::fs::canonicalize(dir).expect("the scratch folder");
    for file in &files {
        let resolved = std::fs::canonicalize(&file.file).expect("a listed file exists");
        assert!(
            resolved.starts_with(&base),
            "{} leads out of the folder",
            file.file.display()
        );
    }
    let scene = load_scene(&files);
    raypick_fuzz::debug(&scene, |s| format!("{} objects", s.objects().len()));
});
