//! Fuzzes the STL loader, `raypick::io::stl::load_stl`.
//!
//! `load_stl` only takes a path, so each input is written to a per-process
//! scratch file (on /dev/shm when available) and loaded from there
//! (`raypick_fuzz::load_mesh_file`).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    raypick_fuzz::load_mesh_file("stl", data, raypick::io::stl::load_stl);
});
