//! Fuzzes the ESRI ASCII grid reader, `raypick::dem::read_asc`.
#![no_main]

use libfuzzer_sys::fuzz_target;
use raypick::dem::read_asc;

fuzz_target!(|data: &[u8]| {
    let result = read_asc(data, "fuzz.asc");
    raypick_fuzz::debug(&result, raypick_fuzz::grid_summary);
    if let Ok(grid) = result {
        raypick_fuzz::check_grid(&grid);
    }
});
