//! Fuzzes the GeoTIFF reader, `raypick::dem::read_geotiff`.
#![no_main]

use std::io::Cursor;

use libfuzzer_sys::fuzz_target;
use raypick::dem::read_geotiff;

fuzz_target!(|data: &[u8]| {
    let result = read_geotiff(Cursor::new(data), "fuzz.tif");
    raypick_fuzz::debug(&result, raypick_fuzz::grid_summary);
    if let Ok(grid) = result {
        raypick_fuzz::check_grid(&grid);
    }
});
