//! Fuzzes the ray-file parser, `raypick::io::ray_file::parse_rays`.
//!
//! `parse_rays` takes text; input that is not UTF-8 is passed through
//! `from_utf8_lossy` so every input reaches the parser.
#![no_main]

use libfuzzer_sys::fuzz_target;
use raypick::io::ray_file::parse_rays;

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let result = parse_rays("fuzz.txt", &text);
    raypick_fuzz::debug(&result, |r: &Vec<_>| format!("{} rays", r.len()));
    if let Ok(rays) = result {
        // At most one ray per line.
        assert!(rays.len() <= text.lines().count());
    }
});
