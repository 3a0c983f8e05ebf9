//! Fuzzes the PNG heightmap reader, `raypick::dem::read_png16`.
//!
//! Chunk CRCs are recomputed before decoding (`fix_png_crcs`): otherwise
//! nearly every mutation is rejected by the CRC check and the decoder is
//! barely exercised. The grid parameters are fixed and valid.
#![no_main]

use std::io::Cursor;

use libfuzzer_sys::fuzz_target;
use raypick::dem::{PngGrid, read_png16};

const GRID: PngGrid = PngGrid {
    cell_size: 30.0,
    x0: 500_000.0,
    y0: 4_000_000.0,
    height_scale: 0.1,
    height_offset: -500.0,
};

fuzz_target!(|data: &[u8]| {
    let mut bytes = data.to_vec();
    raypick_fuzz::fix_png_crcs(&mut bytes);
    let result = read_png16(Cursor::new(bytes), "fuzz.png", GRID);
    raypick_fuzz::debug(&result, raypick_fuzz::grid_summary);
    if let Ok(grid) = result {
        raypick_fuzz::check_grid(&grid);
    }
});
