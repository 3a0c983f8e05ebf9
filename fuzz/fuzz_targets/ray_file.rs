//! Fuzzes the text parsers of `raypick::io::ray_file`: `parse_rays`, and the
//! point / pair parsers of the line-of-sight commands (`parse_points`,
//! `parse_pairs`), which share the line reader. Each input goes to all three.
//!
//! The parsers take text; input that is not UTF-8 is passed through
//! `from_utf8_lossy` so every input reaches them.
#![no_main]

use libfuzzer_sys::fuzz_target;
use raypick::io::ray_file::{parse_pairs, parse_points, parse_rays};

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let lines = text.lines().count();

    let result = parse_rays("fuzz.txt", &text);
    raypick_fuzz::debug(&result, |r: &Vec<_>| format!("{} rays", r.len()));
    if let Ok(rays) = result {
        // At most one ray per line.
        assert!(rays.len() <= lines);
    }

    let result = parse_points("fuzz.txt", &text);
    raypick_fuzz::debug(&result, |p: &Vec<_>| format!("{} points", p.len()));
    if let Ok(points) = result {
        assert!(points.len() <= lines);
    }

    let result = parse_pairs("fuzz.txt", &text);
    raypick_fuzz::debug(&result, |p: &Vec<_>| format!("{} pairs", p.len()));
    if let Ok(pairs) = result {
        assert!(pairs.len() <= lines);
    }
});
