//! 16-bit grayscale PNG heightmap loader. A PNG carries no georeferencing,
//! so the caller supplies it in [`PngGrid`].
//!
//! Sample (r, c) sits at x = x0 + c·cell_size, y = y0 − r·cell_size (row 0 is
//! the top, i.e. north), height = height_offset + value·height_scale.
//!
//! 16-bit grayscale is the intended input. 8-bit grayscale is also accepted
//! (values 0..=255, same formula), which loses precision: 256 levels only.
//! Other colour types (RGB, palette, alpha) and 1/2/4-bit grayscale are
//! refused. PNG has no NODATA notion: every pixel becomes `Some` height, and
//! a tRNS chunk is ignored.
//!
//! Sizes: the header is checked against the file before anything is allocated (see the
//! [`dem`](super) module docs): the image must not be larger than the file's bytes can inflate
//! to (DEFLATE expands at most 1032×), it must be plausible for the file's size
//! ([`check_plausible`](super::grid::check_plausible)) and its heights must fit the memory
//! budget. A non-interlaced image is then decoded row by row, straight into the heights.

use std::io::{BufRead, BufReader, Seek, SeekFrom};
use std::path::Path;

use png::{BitDepth, ColorType, Decoder, DecodingError};

use super::grid::{ElevationGrid, alloc_heights, check_plausible, checked_sample_count};
use super::{io_error, parse_error};
use crate::error::Error;

/// Georeferencing and height scaling for a PNG heightmap.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PngGrid {
    /// Distance between neighbouring pixels, in world units (both axes).
    pub cell_size: f64,
    /// World x of pixel (0, 0), the top-left (north-west) pixel.
    pub x0: f64,
    /// World y of pixel (0, 0), the top-left (north-west) pixel.
    pub y0: f64,
    /// World height per unit of pixel value.
    pub height_scale: f64,
    /// World height of pixel value 0.
    pub height_offset: f64,
}

/// Loads a grayscale PNG heightmap from `path`, placed and scaled by `grid`.
///
/// # Errors
/// [`Error::Io`] if the file cannot be read; [`Error::Parse`] for a
/// truncated or malformed PNG, a pixel format other than 8/16-bit grayscale,
/// an image larger than [`MAX_SAMPLES`](crate::dem::MAX_SAMPLES), or `grid` values that are
/// non-finite, a non-positive `cell_size`, or overflow.
pub fn load_png16(path: impl AsRef<Path>, grid: PngGrid) -> Result<ElevationGrid, Error> {
    let path = path.as_ref();
    let name = path.display().to_string();
    let (file, _) = crate::io::open_regular(path)?;
    read_png16(BufReader::new(file), &name, grid)
}

/// Decodes a grayscale PNG heightmap from `reader`; `name` labels errors (usually the file path).
///
/// # Errors
/// As [`load_png16`].
pub fn read_png16(
    mut reader: impl BufRead + Seek,
    name: &str,
    grid: PngGrid,
) -> Result<ElevationGrid, Error> {
    let fail = |message: String| parse_error(name, None, message);
    check_params(name, &grid)?;
    // The file's real size bounds what its header may claim.
    let file_bytes = reader
        .seek(SeekFrom::End(0))
        .and_then(|end| reader.seek(SeekFrom::Start(0)).map(|_| end))
        .map_err(|e| io_error(name, e))?;

    let mut decoder = Decoder::new(reader);
    let info = decoder
        .read_header_info()
        .map_err(|e| png_error(name, "reading the PNG header", e))?;
    let (width, height, color, depth) = (info.width, info.height, info.color_type, info.bit_depth);
    let bytes_per_sample = match (color, depth) {
        (ColorType::Grayscale, BitDepth::Sixteen) => 2,
        (ColorType::Grayscale, BitDepth::Eight) => 1,
        _ => {
            return Err(fail(format!(
                "unsupported PNG pixel format {color:?} {}-bit; expected 16-bit \
                 (or 8-bit) grayscale",
                depth as u8
            )));
        }
    };
    let count = checked_sample_count(name, width.into(), height.into())?;
    // Each row inflates to a filter byte and its samples.
    let inflated = u64::from(height) * (1 + u64::from(width) * bytes_per_sample as u64);
    let most = file_bytes.saturating_mul(1032);
    if inflated > most {
        return Err(fail(format!(
            "file is truncated, or its image data is missing: the header claims {width} x \
             {height} pixels ({inflated} bytes inflated), but DEFLATE in a file of {file_bytes} \
             bytes gives at most {most} bytes"
        )));
    }
    check_plausible(name, width.into(), height.into(), file_bytes)?;
    let (ncols, nrows) = (width as usize, height as usize);

    let x1 = grid.x0 + (ncols - 1) as f64 * grid.cell_size;
    let y1 = grid.y0 - (nrows - 1) as f64 * grid.cell_size;
    if !x1.is_finite() || !y1.is_finite() {
        return Err(fail(
            "grid extent (PngGrid x0/y0 + image size x cell_size) overflows the range of f64"
                .into(),
        ));
    }

    let mut heights = alloc_heights(name, count)?;
    let mut reader = decoder
        .read_info()
        .map_err(|e| png_error(name, "reading the PNG metadata", e))?;
    let to_height = |value: f64| {
        let h = grid.height_offset + value * grid.height_scale;
        if h.is_finite() {
            Ok(Some(h))
        } else {
            Err(fail(format!(
                "height for pixel value {value} overflows (PngGrid height_scale/offset)"
            )))
        }
    };
    let row_bytes = ncols * bytes_per_sample;
    let mut push_row = |row: &[u8]| -> Result<(), Error> {
        let row = row
            .get(..row_bytes)
            .ok_or_else(|| fail("decoded image is smaller than its header declares".into()))?;
        if bytes_per_sample == 2 {
            for pair in row.chunks_exact(2) {
                let value = u16::from_be_bytes([pair[0], pair[1]]);
                heights.push(to_height(value.into())?);
            }
        } else {
            for &value in row {
                heights.push(to_height(value.into())?);
            }
        }
        Ok(())
    };
    if reader.info().interlaced {
        // Adam7 passes come out of order: decode the frame (its size was checked above).
        let size = reader
            .output_buffer_size()
            .ok_or_else(|| fail("image too large to decode".into()))?;
        let mut buf = vec![0u8; size];
        let frame = reader
            .next_frame(&mut buf)
            .map_err(|e| png_error(name, "decoding the image data", e))?;
        let line = frame.line_size;
        if line < row_bytes || buf.len() / line < nrows {
            return Err(fail(
                "decoded image is smaller than its header declares".into(),
            ));
        }
        for row in buf.chunks_exact(line).take(nrows) {
            push_row(row)?;
        }
    } else {
        for _ in 0..nrows {
            let row = reader
                .next_row()
                .map_err(|e| png_error(name, "decoding the image data", e))?
                .ok_or_else(|| fail("decoded image is smaller than its header declares".into()))?;
            push_row(row.data())?;
        }
        // Past the last row: the decoder checks the end of the image data, as next_frame does.
        reader
            .next_row()
            .map_err(|e| png_error(name, "decoding the image data", e))?;
    }
    Ok(ElevationGrid {
        ncols,
        nrows,
        x0: grid.x0,
        y0: grid.y0,
        dx: grid.cell_size,
        dy: grid.cell_size,
        heights,
    })
}

/// Refuses placements that would give non-finite or degenerate positions.
fn check_params(name: &str, grid: &PngGrid) -> Result<(), Error> {
    let bad = |what: &str, v: f64| {
        Err(parse_error(
            name,
            None,
            format!(
                "invalid PngGrid: {what} must be finite{}, got {v}",
                if what == "cell_size" {
                    " and positive"
                } else {
                    ""
                }
            ),
        ))
    };
    if !(grid.cell_size.is_finite() && grid.cell_size > 0.0) {
        return bad("cell_size", grid.cell_size);
    }
    for (what, v) in [
        ("x0", grid.x0),
        ("y0", grid.y0),
        ("height_scale", grid.height_scale),
        ("height_offset", grid.height_offset),
    ] {
        if !v.is_finite() {
            return bad(what, v);
        }
    }
    Ok(())
}

/// Maps a `png` crate error to ours; a short read means the file is truncated.
fn png_error(name: &str, what: &str, e: DecodingError) -> Error {
    let message = match e {
        DecodingError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            format!("file is truncated (unexpected end of file while {what})")
        }
        DecodingError::IoError(io) => return io_error(name, io),
        DecodingError::Format(f) => format!("not a valid PNG ({what}): {f}"),
        DecodingError::LimitsExceeded => format!("image too large for the decoder ({what})"),
        other => format!("PNG decoding failed ({what}): {other}"),
    };
    parse_error(name, None, message)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use std::io::Cursor;

    const GRID: PngGrid = PngGrid {
        cell_size: 2.0,
        x0: 500.0,
        y0: 900.0,
        height_scale: 0.5,
        height_offset: -10.0,
    };

    fn encode(w: u32, h: u32, color: ColorType, depth: BitDepth, data: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(color);
        enc.set_depth(depth);
        let mut writer = enc.write_header().unwrap();
        writer.write_image_data(data).unwrap();
        writer.finish().unwrap();
        out
    }

    fn gray16(w: u32, h: u32, values: &[u16]) -> Vec<u8> {
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
        encode(w, h, ColorType::Grayscale, BitDepth::Sixteen, &bytes)
    }

    fn read(bytes: &[u8], grid: PngGrid) -> Result<ElevationGrid, Error> {
        read_png16(Cursor::new(bytes), "t.png", grid)
    }

    fn err(bytes: &[u8], grid: PngGrid) -> String {
        match read(bytes, grid) {
            Ok(g) => panic!("expected an error, got a {}x{} grid", g.ncols, g.nrows),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn sixteen_bit_heights_and_positions() {
        let values = [0u16, 1, 2, 300, 65535, 40000];
        let g = read(&gray16(3, 2, &values), GRID).unwrap();
        assert_eq!((g.ncols, g.nrows, g.dx, g.dy), (3, 2, 2.0, 2.0));
        let expected: Vec<Option<f64>> = values
            .iter()
            .map(|&v| Some(-10.0 + f64::from(v) * 0.5))
            .collect();
        assert_eq!(g.heights, expected);
        assert_eq!(
            g.sample_position(0, 0),
            Some(DVec3::new(500.0, 900.0, -10.0))
        );
        assert_eq!(
            g.sample_position(1, 1),
            Some(DVec3::new(502.0, 898.0, -10.0 + 65535.0 * 0.5))
        );
    }

    #[test]
    fn file_on_disk_round_trip() {
        let path = std::env::temp_dir().join(format!("dem_png16_{}.png", std::process::id()));
        std::fs::write(&path, gray16(2, 2, &[10, 20, 30, 40])).unwrap();
        let g = load_png16(&path, GRID);
        std::fs::remove_file(&path).unwrap();
        assert_eq!(g.unwrap().height(1, 1), Some(10.0));
        let e = load_png16("/nonexistent/x.png", GRID).unwrap_err();
        assert!(matches!(e, Error::Io { .. }), "{e}");
    }

    #[test]
    fn eight_bit_gray_is_accepted() {
        let png = encode(2, 1, ColorType::Grayscale, BitDepth::Eight, &[0, 255]);
        let g = read(&png, GRID).unwrap();
        assert_eq!(g.heights, vec![Some(-10.0), Some(117.5)]);
    }

    #[test]
    fn other_pixel_formats_are_refused() {
        let rgb = encode(1, 1, ColorType::Rgb, BitDepth::Eight, &[1, 2, 3]);
        assert_eq!(
            err(&rgb, GRID),
            "t.png: unsupported PNG pixel format Rgb 8-bit; expected 16-bit (or 8-bit) grayscale"
        );
        let ga = encode(
            1,
            1,
            ColorType::GrayscaleAlpha,
            BitDepth::Sixteen,
            &[0, 1, 0, 2],
        );
        assert!(err(&ga, GRID).contains("GrayscaleAlpha 16-bit"));
        let g4 = encode(2, 1, ColorType::Grayscale, BitDepth::Four, &[0x12]);
        assert!(err(&g4, GRID).contains("Grayscale 4-bit"));
    }

    #[test]
    fn invalid_parameters() {
        let png = gray16(1, 1, &[1]);
        let e = err(
            &png,
            PngGrid {
                cell_size: 0.0,
                ..GRID
            },
        );
        assert_eq!(
            e,
            "t.png: invalid PngGrid: cell_size must be finite and positive, got 0"
        );
        let e = err(
            &png,
            PngGrid {
                x0: f64::NAN,
                ..GRID
            },
        );
        assert_eq!(e, "t.png: invalid PngGrid: x0 must be finite, got NaN");
        let e = err(
            &png,
            PngGrid {
                height_scale: f64::INFINITY,
                ..GRID
            },
        );
        assert!(e.contains("height_scale must be finite"), "{e}");
        let e = err(
            &png,
            PngGrid {
                height_scale: 1e308,
                height_offset: 1e308,
                ..GRID
            },
        );
        assert!(e.contains("overflows"), "{e}");
        let wide = gray16(2, 1, &[1, 1]);
        let e = err(
            &wide,
            PngGrid {
                x0: f64::MAX,
                cell_size: f64::MAX,
                ..GRID
            },
        );
        assert!(e.contains("extent"), "{e}");
    }

    #[test]
    fn garbage_truncated_and_corrupted_files() {
        assert!(err(b"", GRID).starts_with("t.png: "));
        let e = err(b"definitely not a png file", GRID);
        assert!(e.starts_with("t.png: not a valid PNG"), "{e}");

        let values: Vec<u16> = (0..64 * 48).map(|i| (i * 37 % 65536) as u16).collect();
        let png = gray16(64, 48, &values);
        // Every cut up to the start of the final IEND chunk is an error (the
        // decoder stops once it has seen IEND's type, so a lost IEND CRC is
        // harmless).
        for cut in [8, 20, 33, 40, png.len() / 2, png.len() - 17, png.len() - 12] {
            let e = read(&png[..cut], GRID).map(|_| ()).unwrap_err().to_string();
            assert!(e.starts_with("t.png: "), "cut at {cut}: {e}");
        }
        let e = err(&png[..png.len() / 2], GRID);
        assert!(e.contains("truncated"), "{e}");

        // Absurd IHDR size (CRC ignored by patching bytes after it is checked
        // would fail, so fix the CRC up).
        let mut huge = png.clone();
        huge[16..20].copy_from_slice(&100_000u32.to_be_bytes());
        huge[20..24].copy_from_slice(&100_000u32.to_be_bytes());
        let crc = crc32(&huge[12..29]);
        huge[29..33].copy_from_slice(&crc.to_be_bytes());
        let e = err(&huge, GRID);
        assert!(e.contains("too large"), "{e}");

        let mut state = 0x1234_5678_9abc_def1u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for _ in 0..500 {
            let mut f = png.clone();
            let at = (next() % f.len() as u64) as usize;
            f[at] = next() as u8;
            let _ = read(&f, GRID); // Ok or Err, but no panic.
        }
    }

    /// CRC-32 as used by PNG chunks.
    fn crc32(bytes: &[u8]) -> u32 {
        let mut crc = !0u32;
        for &b in bytes {
            crc ^= u32::from(b);
            for _ in 0..8 {
                crc = if crc & 1 == 1 {
                    (crc >> 1) ^ 0xEDB8_8320
                } else {
                    crc >> 1
                };
            }
        }
        !crc
    }
}
