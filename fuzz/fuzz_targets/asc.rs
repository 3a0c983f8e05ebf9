//! Fuzzes the ESRI ASCII grid reader, `raypick::dem::read_asc`.
#![no_main]

use libfuzzer_sys::fuzz_target;
use raypick::dem::read_asc;

fuzz_target!(|data: &[u8]| {
    if let Ok(grid) = read_asc(data, "fuzz.asc") {
        raypick_fuzz::check_grid(&grid);
    }
});
