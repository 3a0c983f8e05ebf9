//! GeoTIFF loader: single-band elevation rasters (8/16/32-bit integer,
//! 32/64-bit float; uncompressed, LZW, DEFLATE or PackBits; strips or tiles),
//! georeferenced by ModelTiepointTag + ModelPixelScaleTag, with NODATA from
//! the GDAL_NODATA tag and sample placement from GTRasterTypeGeoKey.
//!
//! Placement: with RasterPixelIsArea (GTRasterTypeGeoKey = 1, also the
//! default when the key or the whole GeoKeyDirectoryTag is absent) sample
//! (r, c) sits at the pixel centre, x = tie_x + (c + ½ − tie_i)·sx,
//! y = tie_y − (r + ½ − tie_j)·sy. With RasterPixelIsPoint (2) it sits at
//! x = tie_x + (c − tie_i)·sx, y = tie_y − (r − tie_j)·sy. Only the first
//! tiepoint is used. A ModelTransformationTag without tiepoint/scale is
//! accepted only when it has no rotation or shear. Coordinates stay in the
//! file's own units; nothing is reprojected.
//!
//! NODATA: samples equal to GDAL_NODATA (compared in the raster's own sample
//! type, as GDAL does) become `None`; NaN samples in float rasters are always
//! `None`; infinite samples are an error. Only the first image (IFD) is read,
//! so internal overviews are ignored.
//!
//! Sizes: before anything is allocated for the raster, the header is checked against the file
//! (see the [`dem`](super) module docs): every strip or tile must lie inside the file, the raster
//! must not be larger than the file's bytes can decompress to (×1 uncompressed, ×64 PackBits,
//! ×1032 DEFLATE, ×4096 LZW; strips that share their bytes do not pass), the grid must be
//! plausible for the file's size ([`check_plausible`](super::grid::check_plausible)) and its
//! heights must fit the memory budget. The raster is then decoded one strip or tile at a time,
//! straight into the heights.

use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use tiff::TiffError;
use tiff::decoder::ifd::Value;
use tiff::decoder::{ChunkType, Decoder, DecodingResult, Limits};
use tiff::tags::Tag;

use super::grid::{ElevationGrid, alloc_heights, check_plausible, checked_sample_count};
use super::{io_error, parse_error};
use crate::error::Error;

/// GeoKey id of GTRasterTypeGeoKey inside GeoKeyDirectoryTag.
const GT_RASTER_TYPE_GEO_KEY: u16 = 1025;
/// GTRasterTypeGeoKey value: a pixel covers an area; its value belongs to its centre.
const RASTER_PIXEL_IS_AREA: u16 = 1;
/// GTRasterTypeGeoKey value: a pixel is a point sample at its raster position.
const RASTER_PIXEL_IS_POINT: u16 = 2;

/// Loads a single-band GeoTIFF elevation raster from `path`; see the module docs for the conventions.
///
/// # Errors
/// [`Error::Io`] if the file cannot be read; [`Error::Parse`] for a
/// truncated or malformed TIFF, more than one band, an unsupported sample
/// type or photometric interpretation, missing or rotated georeferencing
/// (naming the tag), a non-numeric GDAL_NODATA, infinite samples, or a
/// raster larger than [`MAX_SAMPLES`](super::MAX_SAMPLES) or implausible for the file's size
/// (see the module docs); [`Error::OverBudget`] when its heights would not fit the memory budget.
pub fn load_geotiff(path: impl AsRef<Path>) -> Result<ElevationGrid, Error> {
    let path = path.as_ref();
    let name = path.display().to_string();
    let (file, _) = crate::io::open_regular(path)?;
    read_geotiff(BufReader::new(file), &name)
}

/// Decodes a single-band GeoTIFF from `reader`; `name` labels errors (usually the file path).
///
/// # Errors
/// As [`load_geotiff`].
pub fn read_geotiff(mut reader: impl Read + Seek, name: &str) -> Result<ElevationGrid, Error> {
    let fail = |message: String| parse_error(name, None, message);
    let tiff_fail = |what: &str, e: TiffError| tiff_error(name, what, e);

    // The file's real size bounds what its header may claim.
    let file_bytes = reader
        .seek(SeekFrom::End(0))
        .and_then(|end| reader.seek(SeekFrom::Start(0)).map(|_| end))
        .map_err(|e| io_error(name, e))?;

    check_text_tags(&mut reader, file_bytes).map_err(fail)?;

    // Tags are read under the decoder's default limits, so a tag claiming a huge value count
    // cannot make it reserve gigabytes before reading anything (found by fuzzing: a 98-byte
    // file asked for 16 GiB). The limits are raised only for the raster itself, below.
    let mut decoder = Decoder::new(reader).map_err(|e| tiff_fail("reading the TIFF header", e))?;

    let (width, height) = decoder
        .dimensions()
        .map_err(|e| tiff_fail("reading the image size", e))?;
    checked_sample_count(name, width.into(), height.into())?;
    let (ncols, nrows) = (width as usize, height as usize);

    let bands: u16 = decoder
        .find_tag_unsigned(Tag::SamplesPerPixel)
        .map_err(|e| tiff_fail("reading SamplesPerPixel (277)", e))?
        .unwrap_or(1);
    if bands != 1 {
        return Err(fail(format!(
            "SamplesPerPixel (277) is {bands}: only single-band rasters are supported"
        )));
    }
    let photometric: Option<u16> = decoder
        .find_tag_unsigned(Tag::PhotometricInterpretation)
        .map_err(|e| tiff_fail("reading PhotometricInterpretation (262)", e))?;
    if let Some(p) = photometric.filter(|&p| p != 1) {
        return Err(fail(format!(
            "PhotometricInterpretation (262) is {p}: an elevation band must be \
             BlackIsZero (1), not a palette, colour or inverted image"
        )));
    }
    let sample_type = sample_type(name, &mut decoder)?;

    let geo = georeferencing(name, &mut decoder)?;
    let nodata = gdal_nodata(name, &mut decoder)?;

    // Sample (0, 0) and the spacing, in the file's units.
    let offset = if geo.pixel_is_point { 0.0 } else { 0.5 };
    let x0 = geo.tie_x + (offset - geo.tie_i) * geo.sx;
    let y0 = geo.tie_y - (offset - geo.tie_j) * geo.sy;
    let x1 = x0 + (ncols - 1) as f64 * geo.sx;
    let y1 = y0 - (nrows - 1) as f64 * geo.sy;
    if ![x0, y0, x1, y1].iter().all(|v| v.is_finite()) {
        return Err(fail(
            "georeferenced extent overflows the range of f64 \
             (ModelTiepointTag 33922 / ModelPixelScaleTag 33550)"
                .into(),
        ));
    }

    let heights = decode_raster(
        name,
        decoder,
        sample_type,
        nodata,
        (ncols, nrows),
        file_bytes,
    )?;

    Ok(ElevationGrid {
        ncols,
        nrows,
        x0,
        y0,
        dx: geo.sx,
        dy: geo.sy,
        heights,
    })
}

/// The sample encodings this loader accepts.
#[derive(Clone, Copy, Debug, PartialEq)]
enum SampleType {
    U8,
    I8,
    U16,
    I16,
    U32,
    I32,
    F32,
    F64,
}

/// Reads BitsPerSample / SampleFormat and refuses what the loader cannot turn into heights.
fn sample_type<R: Read + Seek>(name: &str, decoder: &mut Decoder<R>) -> Result<SampleType, Error> {
    let bits: Vec<u16> = decoder
        .find_tag_unsigned_vec(Tag::BitsPerSample)
        .map_err(|e| tiff_error(name, "reading BitsPerSample (258)", e))?
        .unwrap_or_else(|| vec![1]);
    let formats: Vec<u16> = decoder
        .find_tag_unsigned_vec(Tag::SampleFormat)
        .map_err(|e| tiff_error(name, "reading SampleFormat (339)", e))?
        .unwrap_or_else(|| vec![1]);
    let bits = bits.first().copied().unwrap_or(1);
    let format = formats.first().copied().unwrap_or(1);
    Ok(match (format, bits) {
        (1, 8) => SampleType::U8,
        (2, 8) => SampleType::I8,
        (1, 16) => SampleType::U16,
        (2, 16) => SampleType::I16,
        (1, 32) => SampleType::U32,
        (2, 32) => SampleType::I32,
        (3, 32) => SampleType::F32,
        (3, 64) => SampleType::F64,
        _ => {
            let kind = match format {
                1 => "unsigned integer",
                2 => "signed integer",
                3 => "floating point",
                4 => "untyped",
                5 => "complex integer",
                6 => "complex floating point",
                _ => "unknown-format",
            };
            return Err(parse_error(
                name,
                None,
                format!(
                    "unsupported sample type: {bits}-bit {kind} (BitsPerSample 258 = {bits}, \
                     SampleFormat 339 = {format}); expected 8/16/32-bit integer or \
                     32/64-bit float"
                ),
            ));
        }
    })
}

/// The georeferencing of pixel space, reduced to one tiepoint and a scale.
struct Georef {
    tie_i: f64,
    tie_j: f64,
    tie_x: f64,
    tie_y: f64,
    sx: f64,
    sy: f64,
    pixel_is_point: bool,
}

/// Refuses a tag that holds more than `most` values before it is read: a georeferencing tag is
/// a few numbers or a short string, and the decoder reads what a tag claims (and prints a
/// debugging line of its own for a string over its limit).
fn check_count<R: Read + Seek>(
    name: &str,
    decoder: &mut Decoder<R>,
    tag: Tag,
    label: &str,
    most: u64,
) -> Result<(), Error> {
    match decoder.image_ifd().find_entry(tag) {
        Some(entry) if entry.count() > most => Err(parse_error(
            name,
            None,
            format!(
                "{label} holds {} values; at most {most} are read",
                entry.count()
            ),
        )),
        _ => Ok(()),
    }
}

/// Reads a tag as a list of numbers, whatever numeric TIFF type it was stored with.
fn find_numbers<R: Read + Seek>(
    name: &str,
    decoder: &mut Decoder<R>,
    tag: Tag,
    label: &str,
) -> Result<Option<Vec<f64>>, Error> {
    // Tie points come six numbers each; a model transformation is sixteen.
    check_count(name, decoder, tag, label, 6 * 4096)?;
    let Some(value) = decoder
        .find_tag(tag)
        .map_err(|e| tiff_error(name, &format!("reading {label}"), e))?
    else {
        return Ok(None);
    };
    let numbers = match value {
        Value::List(items) => items.into_iter().map(number).collect(),
        other => number(other).map(|x| vec![x]),
    };
    match numbers {
        Some(v) if v.iter().all(|x| x.is_finite()) => Ok(Some(v)),
        Some(_) => Err(parse_error(
            name,
            None,
            format!("{label} holds NaN or infinite values"),
        )),
        None => Err(parse_error(
            name,
            None,
            format!("{label} does not hold numbers"),
        )),
    }
}

/// One numeric tag value as f64.
fn number(value: Value) -> Option<f64> {
    Some(match value {
        Value::Double(x) => x,
        Value::Float(x) => x.into(),
        Value::Byte(x) => x.into(),
        Value::SignedByte(x) => x.into(),
        Value::Short(x) => x.into(),
        Value::SignedShort(x) => x.into(),
        Value::Unsigned(x) => x.into(),
        Value::Signed(x) => x.into(),
        Value::UnsignedBig(x) => x as f64,
        Value::SignedBig(x) => x as f64,
        _ => return None,
    })
}

fn georeferencing<R: Read + Seek>(name: &str, decoder: &mut Decoder<R>) -> Result<Georef, Error> {
    let fail = |message: &str| parse_error(name, None, message);
    let scale = find_numbers(
        name,
        decoder,
        Tag::ModelPixelScaleTag,
        "ModelPixelScaleTag (33550)",
    )?;
    let tie = find_numbers(
        name,
        decoder,
        Tag::ModelTiepointTag,
        "ModelTiepointTag (33922)",
    )?;
    let matrix = find_numbers(
        name,
        decoder,
        Tag::ModelTransformationTag,
        "ModelTransformationTag (34264)",
    )?;

    let (tie_i, tie_j, tie_x, tie_y, sx, sy) = match (scale, tie, matrix) {
        (Some(scale), Some(tie), _) => {
            if tie.len() < 6 || tie.len() % 6 != 0 {
                return Err(fail(&format!(
                    "ModelTiepointTag (33922) holds {} values; expected a multiple of 6",
                    tie.len()
                )));
            }
            let &[sx, sy, ..] = scale.as_slice() else {
                return Err(fail(&format!(
                    "ModelPixelScaleTag (33550) holds {} values; expected 3",
                    scale.len()
                )));
            };
            (tie[0], tie[1], tie[3], tie[4], sx, sy)
        }
        (None, Some(_), _) => {
            return Err(fail(
                "missing ModelPixelScaleTag (33550): cannot georeference the grid",
            ));
        }
        (Some(_), None, _) => {
            return Err(fail(
                "missing ModelTiepointTag (33922): cannot georeference the grid",
            ));
        }
        (None, None, Some(m)) => {
            if m.len() < 16 {
                return Err(fail(&format!(
                    "ModelTransformationTag (34264) holds {} values; expected 16",
                    m.len()
                )));
            }
            // x = m0·i + m1·j + m3, y = m4·i + m5·j + m7.
            if m[1] != 0.0 || m[4] != 0.0 {
                return Err(fail(
                    "rotated or sheared georeferencing (ModelTransformationTag 34264) \
                     is not supported; the grid must be north-up",
                ));
            }
            (0.0, 0.0, m[3], m[7], m[0], -m[5])
        }
        (None, None, None) => {
            return Err(fail(
                "no georeferencing: missing ModelTiepointTag (33922) and \
                 ModelPixelScaleTag (33550)",
            ));
        }
    };
    if sx <= 0.0 || sy <= 0.0 {
        return Err(fail(&format!(
            "pixel scale ({}, {}) from ModelPixelScaleTag (33550) / \
             ModelTransformationTag (34264) must be positive (north-up, east-right)",
            crate::budget::number(sx),
            crate::budget::number(sy)
        )));
    }

    let pixel_is_point = match raster_type(name, decoder)? {
        None | Some(RASTER_PIXEL_IS_AREA) => false,
        Some(RASTER_PIXEL_IS_POINT) => true,
        Some(other) => {
            return Err(fail(&format!(
                "GTRasterTypeGeoKey (1025) in GeoKeyDirectoryTag (34735) is {other}; \
                 expected 1 (PixelIsArea) or 2 (PixelIsPoint)"
            )));
        }
    };
    Ok(Georef {
        tie_i,
        tie_j,
        tie_x,
        tie_y,
        sx,
        sy,
        pixel_is_point,
    })
}

/// GTRasterTypeGeoKey from GeoKeyDirectoryTag, if present.
fn raster_type<R: Read + Seek>(name: &str, decoder: &mut Decoder<R>) -> Result<Option<u16>, Error> {
    const LABEL: &str = "GeoKeyDirectoryTag (34735)";
    let fail = |message: String| parse_error(name, None, format!("{LABEL} {message}"));
    check_count(name, decoder, Tag::GeoKeyDirectoryTag, LABEL, 4 * 4096)?;
    let Some(value) = decoder
        .find_tag(Tag::GeoKeyDirectoryTag)
        .map_err(|e| tiff_error(name, &format!("reading {LABEL}"), e))?
    else {
        return Ok(None);
    };
    let keys = value
        .into_u16_vec()
        .map_err(|_| fail("does not hold SHORT values".into()))?;
    let Some(&[_, _, _, declared]) = keys.get(..4) else {
        return Err(fail(format!(
            "holds {} values, fewer than its 4-value header",
            keys.len()
        )));
    };
    let declared = usize::from(declared);
    let Some(entries) = keys.get(4..4 + 4 * declared) else {
        return Err(fail(format!(
            "declares {declared} keys but holds only {}",
            (keys.len() - 4) / 4
        )));
    };
    for entry in entries.chunks_exact(4) {
        if entry[0] == GT_RASTER_TYPE_GEO_KEY {
            if entry[1] != 0 || entry[2] != 1 {
                return Err(fail(format!(
                    "stores GTRasterTypeGeoKey (1025) out of line (location {}, count {}); \
                     expected one inline SHORT",
                    entry[1], entry[2]
                )));
            }
            return Ok(Some(entry[3]));
        }
    }
    Ok(None)
}

/// The GDAL_NODATA value, if the tag is present.
fn gdal_nodata<R: Read + Seek>(name: &str, decoder: &mut Decoder<R>) -> Result<Option<f64>, Error> {
    const LABEL: &str = "GDAL_NODATA (42113)";
    check_count(name, decoder, Tag::GdalNodata, LABEL, 256)?;
    let Some(value) = decoder
        .find_tag(Tag::GdalNodata)
        .map_err(|e| tiff_error(name, &format!("reading {LABEL}"), e))?
    else {
        return Ok(None);
    };
    let Value::Ascii(text) = value else {
        return Err(parse_error(
            name,
            None,
            format!("{LABEL} is not an ASCII string"),
        ));
    };
    let trimmed = text.trim_matches(|c: char| c.is_whitespace() || c == '\0');
    trimmed.parse::<f64>().map(Some).map_err(|_| {
        let quoted = crate::budget::quote(trimmed);
        parse_error(name, None, format!("{LABEL} is not a number: '{quoted}'"))
    })
}

impl SampleType {
    fn bytes(self) -> u64 {
        match self {
            SampleType::U8 | SampleType::I8 => 1,
            SampleType::U16 | SampleType::I16 => 2,
            SampleType::U32 | SampleType::I32 | SampleType::F32 => 4,
            SampleType::F64 => 8,
        }
    }
}

/// The most a TIFF compression can expand its input (output bytes per input byte), and its name.
/// Unknown codes get the largest factor; the decoder refuses what it does not support.
fn expansion(compression: u16) -> (u64, &'static str) {
    match compression {
        1 => (1, "uncompressed data"),
        32773 => (64, "PackBits"),
        8 | 32946 => (1032, "DEFLATE"),
        5 => (4096, "LZW"),
        _ => (4096, "this compression"),
    }
}

/// Checks the strip or tile table against the file, then decodes the raster one chunk at a
/// time into heights (row-major), applying NODATA.
fn decode_raster<R: Read + Seek>(
    name: &str,
    mut decoder: Decoder<R>,
    sample_type: SampleType,
    nodata: Option<f64>,
    (ncols, nrows): (usize, usize),
    file_bytes: u64,
) -> Result<Vec<Option<f64>>, Error> {
    let fail = |message: String| parse_error(name, None, message);
    let tiff_fail = |what: &str, e: TiffError| tiff_error(name, what, e);
    let count = ncols * nrows;
    let sample_bytes = sample_type.bytes();

    let compression: u16 = decoder
        .find_tag_unsigned(Tag::Compression)
        .map_err(|e| tiff_fail("reading Compression (259)", e))?
        .unwrap_or(1);
    let (factor, codec) = expansion(compression);
    let raster_bytes = count as u64 * sample_bytes;
    let most = file_bytes.saturating_mul(factor);
    if raster_bytes > most {
        return Err(fail(format!(
            "file is truncated, or its raster data is missing or repeated: the header claims \
             {ncols} columns x {nrows} rows ({raster_bytes} bytes of samples), but {codec} in a \
             file of {file_bytes} bytes gives at most {most} bytes"
        )));
    }

    let (kind, offsets_tag, counts_tag) = match decoder.get_chunk_type() {
        ChunkType::Strip => ("strip", Tag::StripOffsets, Tag::StripByteCounts),
        ChunkType::Tile => ("tile", Tag::TileOffsets, Tag::TileByteCounts),
    };
    let (chunk_w, chunk_h) = decoder.chunk_dimensions();
    let (chunk_w, chunk_h) = (chunk_w as usize, chunk_h as usize);
    if chunk_w == 0 || chunk_h == 0 {
        return Err(fail(format!(
            "the {kind} size is {chunk_w} x {chunk_h} pixels; it must not be empty"
        )));
    }
    let across = ncols.div_ceil(chunk_w);
    let down = nrows.div_ceil(chunk_h);
    let chunks = across * down;
    let offsets = decoder
        .get_tag_u64_vec(offsets_tag)
        .map_err(|e| tiff_fail(&format!("reading the {kind} offsets"), e))?;
    let byte_counts = decoder
        .get_tag_u64_vec(counts_tag)
        .map_err(|e| tiff_fail(&format!("reading the {kind} byte counts"), e))?;
    if offsets.len() < chunks || byte_counts.len() < chunks {
        return Err(fail(format!(
            "the raster needs {chunks} {kind}s, but the file lists {} offsets and {} byte \
             counts",
            offsets.len(),
            byte_counts.len()
        )));
    }
    // Where chunk k goes: its first column and row, and its size without padding.
    let place = |k: usize| {
        let (col, row) = ((k % across) * chunk_w, (k / across) * chunk_h);
        (col, row, chunk_w.min(ncols - col), chunk_h.min(nrows - row))
    };
    let mut largest = 0u64;
    for k in 0..chunks {
        let (offset, length) = (offsets[k], byte_counts[k]);
        let end = offset.checked_add(length).filter(|&end| end <= file_bytes);
        if end.is_none() {
            return Err(fail(format!(
                "file is truncated, or its raster data is missing: {kind} {k} claims bytes \
                 {offset}..+{length}, past the end of the file ({file_bytes} bytes)"
            )));
        }
        let (_, _, w, h) = place(k);
        let decoded = (w * h) as u64 * sample_bytes;
        if decoded > length.saturating_mul(factor) {
            return Err(fail(format!(
                "file is truncated, or its raster data is missing: {kind} {k} holds {length} \
                 bytes, but its {w} x {h} samples need {decoded} bytes, more than {codec} can \
                 give"
            )));
        }
        largest = largest.max(decoded);
    }

    check_plausible(name, ncols as u64, nrows as u64, file_bytes)?;
    let mut heights = alloc_heights(name, count)?;
    heights.resize(count, None);
    // One chunk's samples at a time, and only as many compressed bytes as the file holds.
    let mut limits = Limits::default();
    limits.decoding_buffer_size = usize::try_from(largest).unwrap_or(usize::MAX);
    limits.intermediate_buffer_size = usize::try_from(file_bytes).unwrap_or(usize::MAX);
    let mut decoder = decoder.with_limits(limits);
    // NODATA is compared in the raster's own sample type, like GDAL does, so
    // e.g. "-3.4028234663852886e+38" matches f32::MIN.
    let nodata = match sample_type {
        SampleType::F32 => nodata.map(|v| f64::from(v as f32)),
        _ => nodata,
    };
    for k in 0..chunks {
        let decoded = decoder
            .read_chunk(k as u32)
            .map_err(|e| tiff_fail(&format!("decoding {kind} {k} of the raster data"), e))?;
        let at = Placement {
            name,
            kind,
            index: k,
            ncols,
            nodata,
            place: place(k),
        };
        at.put(decoded, sample_type, &mut heights)?;
    }
    Ok(heights)
}

/// Where one decoded strip or tile goes in the grid.
struct Placement<'a> {
    name: &'a str,
    kind: &'a str,
    index: usize,
    ncols: usize,
    nodata: Option<f64>,
    /// First column, first row, width and height of the chunk's data.
    place: (usize, usize, usize, usize),
}

impl Placement<'_> {
    /// Converts the chunk's samples into heights at their place, applying NODATA.
    fn put(
        &self,
        decoded: DecodingResult,
        expected: SampleType,
        heights: &mut [Option<f64>],
    ) -> Result<(), Error> {
        match (decoded, expected) {
            (DecodingResult::U8(v), SampleType::U8) => self.convert(&v, f64::from, heights),
            (DecodingResult::I8(v), SampleType::I8) => self.convert(&v, f64::from, heights),
            (DecodingResult::U16(v), SampleType::U16) => self.convert(&v, f64::from, heights),
            (DecodingResult::I16(v), SampleType::I16) => self.convert(&v, f64::from, heights),
            (DecodingResult::U32(v), SampleType::U32) => self.convert(&v, f64::from, heights),
            (DecodingResult::I32(v), SampleType::I32) => self.convert(&v, f64::from, heights),
            (DecodingResult::F32(v), SampleType::F32) => self.convert(&v, f64::from, heights),
            (DecodingResult::F64(v), SampleType::F64) => self.convert(&v, |x| x, heights),
            (_, expected) => Err(parse_error(
                self.name,
                None,
                format!(
                    "decoder returned samples of another type than the tags declare \
                     ({expected:?})"
                ),
            )),
        }
    }

    fn convert<T: Copy>(
        &self,
        samples: &[T],
        to_f64: impl Fn(T) -> f64,
        heights: &mut [Option<f64>],
    ) -> Result<(), Error> {
        let (col0, row0, w, h) = self.place;
        if samples.len() < w * h {
            return Err(parse_error(
                self.name,
                None,
                format!(
                    "decoded {} samples for {} {}, expected {}",
                    samples.len(),
                    self.kind,
                    self.index,
                    w * h
                ),
            ));
        }
        for (r, line) in samples.chunks_exact(w).take(h).enumerate() {
            let start = (row0 + r) * self.ncols + col0;
            for (c, (&s, slot)) in line.iter().zip(&mut heights[start..start + w]).enumerate() {
                let v = to_f64(s);
                *slot = if self.nodata == Some(v) || v.is_nan() {
                    None
                } else if v.is_finite() {
                    Some(v)
                } else {
                    return Err(parse_error(
                        self.name,
                        None,
                        format!(
                            "infinite sample {v} at row {}, column {} (not the GDAL_NODATA value)",
                            row0 + r,
                            col0 + c
                        ),
                    ));
                };
            }
        }
        Ok(())
    }
}

/// The tags the decoder or this reader reads from the first image: the image's own (size,
/// samples, compression, strips, tiles, predictor, sample format, JPEG tables) and the
/// georeferencing ones (pixel scale, tie points, transformation, GeoKey directory and its
/// double and text parameters, GDAL_NODATA). Others (DateTime, Software, GDAL_METADATA, …)
/// are never read, so nothing amiss in them stops a file from loading.
const READ_TAGS: [u16; 25] = [
    256, 257, 258, 259, 262, 273, 277, 278, 279, 284, 317, 322, 323, 324, 325, 338, 339, 347,
    33550, 33922, 34264, 34735, 34736, 34737, 42113,
];

/// Refuses a tag that the decoder or this reader reads ([`READ_TAGS`]) given as text (ASCII)
/// whose bytes lie past the end of the file, or are more than the decoder's limit for one
/// value, before the decoder reads the header: the `tiff` crate reads a tag of that type (the
/// sample format given as text, say) into memory it sizes by the claimed count, and one over
/// its limit printed a `dbg!` line on standard error before its error ("image too large for the
/// decoder"). Anything else amiss in the header is left to the decoder; the reader is put back
/// at the start.
fn check_text_tags(reader: &mut (impl Read + Seek), file_bytes: u64) -> Result<(), String> {
    const ASCII: u16 = 2;
    let mut head = [0u8; 16];
    let got = read_up_to(reader, &mut head)?;
    let little = match &head[..2] {
        b"II" => true,
        b"MM" => false,
        _ => return rewind(reader),
    };
    let u16_at = |b: &[u8]| {
        let b = [b[0], b[1]];
        if little {
            u16::from_le_bytes(b)
        } else {
            u16::from_be_bytes(b)
        }
    };
    let u32_at = |b: &[u8]| {
        let b = [b[0], b[1], b[2], b[3]];
        if little {
            u32::from_le_bytes(b)
        } else {
            u32::from_be_bytes(b)
        }
    };
    let u64_at = |b: &[u8]| {
        let b: [u8; 8] = b[..8].try_into().expect("eight bytes");
        if little {
            u64::from_le_bytes(b)
        } else {
            u64::from_be_bytes(b)
        }
    };
    // Classic TIFF: 12-byte entries, 4-byte counts and values; BigTIFF: 20, 8 and 8.
    let big = match (got >= 8, u16_at(&head[2..4])) {
        (true, 42) => false,
        (true, 43) if got >= 16 => true,
        _ => return rewind(reader),
    };
    let first = if big {
        u64_at(&head[8..16])
    } else {
        u64::from(u32_at(&head[4..8]))
    };
    let (count_bytes, entry_bytes, inline) = if big { (8, 20, 8) } else { (2, 12, 4) };
    let mut count = [0u8; 8];
    // A directory that cannot be reached is the decoder's to report.
    if reader.seek(SeekFrom::Start(first)).is_err()
        || read_up_to(reader, &mut count[..count_bytes])? < count_bytes
    {
        return rewind(reader);
    }
    let entries = if big {
        u64_at(&count)
    } else {
        u64::from(u16_at(&count))
    };
    // No more entries than the file holds after the count.
    let room = file_bytes.saturating_sub(first + count_bytes as u64) / entry_bytes as u64;
    let mut entry = [0u8; 20];
    for _ in 0..entries.min(room) {
        if read_up_to(reader, &mut entry[..entry_bytes])? < entry_bytes {
            break;
        }
        let (tag, kind) = (u16_at(&entry[0..2]), u16_at(&entry[2..4]));
        if kind != ASCII || !READ_TAGS.contains(&tag) {
            continue;
        }
        let (bytes, offset) = if big {
            (u64_at(&entry[4..12]), u64_at(&entry[12..20]))
        } else {
            (
                u64::from(u32_at(&entry[4..8])),
                u64::from(u32_at(&entry[8..12])),
            )
        };
        if bytes > inline && offset.checked_add(bytes).is_none_or(|end| end > file_bytes) {
            return Err(format!(
                "the text of tag {tag} claims {bytes} bytes at offset {offset}, past the end of \
                 the file ({file_bytes} bytes): the file is truncated or corrupt"
            ));
        }
        let most = Limits::default().decoding_buffer_size as u64;
        if bytes > most {
            return Err(format!(
                "the text of tag {tag} claims {bytes} bytes, more than the {most} the decoder \
                 reads"
            ));
        }
    }
    rewind(reader)
}

/// Reads into `buf` until it is full or the reader ends; how many bytes were read.
fn read_up_to(reader: &mut impl Read, buf: &mut [u8]) -> Result<usize, String> {
    let mut got = 0;
    while got < buf.len() {
        match reader.read(&mut buf[got..]) {
            Ok(0) => break,
            Ok(n) => got += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(format!("reading the TIFF header failed: {e}")),
        }
    }
    Ok(got)
}

/// Puts the reader back at the start of the file.
fn rewind(reader: &mut impl Seek) -> Result<(), String> {
    reader
        .seek(SeekFrom::Start(0))
        .map(|_| ())
        .map_err(|e| format!("reading the TIFF header failed: {e}"))
}

/// Maps a `tiff` crate error to ours; a short read means the file is truncated.
fn tiff_error(name: &str, what: &str, e: TiffError) -> Error {
    let message = match e {
        TiffError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            format!("file is truncated (unexpected end of file while {what})")
        }
        // The file was opened and sized: a read failing now follows an offset in it (a
        // BigTIFF's 64-bit first IFD offset gave only "Invalid argument").
        TiffError::IoError(io) if io.kind() == std::io::ErrorKind::InvalidInput => {
            format!("{what} failed: {io} (an offset in the file may point outside it)")
        }
        TiffError::IoError(io) => return io_error(name, io),
        TiffError::FormatError(f) => format!("not a valid TIFF ({what}): {f}"),
        TiffError::UnsupportedError(u) => format!("unsupported TIFF feature ({what}): {u}"),
        TiffError::LimitsExceeded => format!("image too large for the decoder ({what})"),
        other => format!("TIFF decoding failed ({what}): {other}"),
    };
    // The decoder's own texts list a tag's values (a sample format's, one per sample): a few.
    parse_error(name, None, crate::error::shorten_tokens(&message, 240))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dem::asc::load_asc;
    use glam::DVec3;
    use std::io::Cursor;
    use tiff::encoder::colortype::{self, ColorType};
    use tiff::encoder::{Compression, DeflateLevel, TiffEncoder, TiffValue};

    const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data");

    /// GeoTIFF tags to attach to a synthetic image.
    #[derive(Default)]
    struct Geo<'a> {
        tie: Option<&'a [f64]>,
        scale: Option<&'a [f64]>,
        matrix: Option<&'a [f64]>,
        keys: Option<&'a [u16]>,
        nodata: Option<&'a str>,
        photometric: Option<u16>,
    }

    /// Standard georeferencing: tie (0,0) -> (1000, 2000), 10 x 5 units.
    fn std_geo<'a>() -> Geo<'a> {
        Geo {
            tie: Some(&[0.0, 0.0, 0.0, 1000.0, 2000.0, 0.0]),
            scale: Some(&[10.0, 5.0, 0.0]),
            ..Geo::default()
        }
    }

    fn write_geo<W: std::io::Write + Seek, K: tiff::encoder::TiffKind>(
        dir: &mut tiff::encoder::DirectoryEncoder<'_, W, K>,
        geo: &Geo,
    ) {
        if let Some(t) = geo.tie {
            dir.write_tag(Tag::ModelTiepointTag, t).unwrap();
        }
        if let Some(s) = geo.scale {
            dir.write_tag(Tag::ModelPixelScaleTag, s).unwrap();
        }
        if let Some(m) = geo.matrix {
            dir.write_tag(Tag::ModelTransformationTag, m).unwrap();
        }
        if let Some(k) = geo.keys {
            dir.write_tag(Tag::GeoKeyDirectoryTag, k).unwrap();
        }
        if let Some(n) = geo.nodata {
            dir.write_tag(Tag::GdalNodata, n).unwrap();
        }
        if let Some(p) = geo.photometric {
            dir.write_tag(Tag::PhotometricInterpretation, p).unwrap();
        }
    }

    /// A striped TIFF written by the `tiff` crate's encoder.
    fn striped<C: ColorType>(
        w: u32,
        h: u32,
        data: &[C::Inner],
        compression: Compression,
        rows_per_strip: Option<u32>,
        geo: &Geo,
    ) -> Vec<u8>
    where
        [C::Inner]: TiffValue,
    {
        let mut out = Cursor::new(Vec::new());
        let mut enc = TiffEncoder::new(&mut out)
            .unwrap()
            .with_compression(compression);
        let mut image = enc.new_image::<C>(w, h).unwrap();
        if let Some(r) = rows_per_strip {
            image.rows_per_strip(r).unwrap();
        }
        write_geo(image.encoder(), geo);
        image.write_data(data).unwrap();
        out.into_inner()
    }

    /// An uncompressed tiled int16 TIFF (16 x 16 tiles), assembled tag by tag.
    fn tiled_i16(w: u32, h: u32, data: &[i16], geo: &Geo) -> Vec<u8> {
        const T: u32 = 16;
        let mut out = Cursor::new(Vec::new());
        let mut enc = TiffEncoder::new(&mut out).unwrap();
        let mut dir = enc.image_directory().unwrap();
        let (mut offsets, mut counts) = (Vec::new(), Vec::new());
        for ty in 0..h.div_ceil(T) {
            for tx in 0..w.div_ceil(T) {
                let mut tile = vec![0i16; (T * T) as usize];
                for r in 0..T {
                    for c in 0..T {
                        let (row, col) = (ty * T + r, tx * T + c);
                        if row < h && col < w {
                            tile[(r * T + c) as usize] = data[(row * w + col) as usize];
                        }
                    }
                }
                offsets.push(dir.write_data(&tile[..]).unwrap() as u32);
                counts.push(T * T * 2);
            }
        }
        dir.write_tag(Tag::ImageWidth, w).unwrap();
        dir.write_tag(Tag::ImageLength, h).unwrap();
        dir.write_tag(Tag::BitsPerSample, 16u16).unwrap();
        dir.write_tag(Tag::Compression, 1u16).unwrap();
        dir.write_tag(Tag::PhotometricInterpretation, 1u16).unwrap();
        dir.write_tag(Tag::SamplesPerPixel, 1u16).unwrap();
        dir.write_tag(Tag::SampleFormat, 2u16).unwrap();
        dir.write_tag(Tag::TileWidth, T).unwrap();
        dir.write_tag(Tag::TileLength, T).unwrap();
        dir.write_tag(Tag::TileOffsets, &offsets[..]).unwrap();
        dir.write_tag(Tag::TileByteCounts, &counts[..]).unwrap();
        write_geo(&mut dir, geo);
        dir.finish().unwrap();
        out.into_inner()
    }

    fn read(bytes: &[u8]) -> Result<ElevationGrid, Error> {
        read_geotiff(Cursor::new(bytes), "t.tif")
    }

    fn err(bytes: &[u8]) -> String {
        match read(bytes) {
            Ok(g) => panic!("expected an error, got a {}x{} grid", g.ncols, g.nrows),
            Err(e) => e.to_string(),
        }
    }

    fn ramp(n: usize) -> Vec<u16> {
        (0..n as u16).map(|v| v * 7 + 3).collect()
    }

    #[test]
    fn real_int16_and_f32_deflate_match_the_asc_grid() {
        let asc = load_asc(format!("{DATA}/jacksboro_fault_dem_utm.asc")).unwrap();
        let int16 = load_geotiff(format!("{DATA}/jacksboro_fault_dem_utm_int16.tif")).unwrap();
        let f32d = load_geotiff(format!("{DATA}/jacksboro_fault_dem_utm_f32_deflate.tif")).unwrap();
        assert_eq!(int16, asc);
        assert_eq!(f32d, asc);
        assert_eq!(
            int16.sample_position(0, 0).map(|p| (p.x, p.y)),
            Some((512745.0, 4032150.0 + 344.0 * 30.0 - 15.0))
        );
        for (r, c) in [(0, 0), (17, 300), (343, 402)] {
            assert_eq!(int16.sample_position(r, c), asc.sample_position(r, c));
            assert_eq!(f32d.sample_position(r, c), asc.sample_position(r, c));
        }
    }

    #[test]
    fn pixel_is_area_is_the_default_and_centres_samples() {
        let data = ramp(12);
        let expected_x0y0 = (1005.0, 1997.5);
        for keys in [None, Some(&[1u16, 1, 0, 1, 1025, 0, 1, 1][..])] {
            let geo = Geo { keys, ..std_geo() };
            let g = read(&striped::<colortype::Gray16>(
                4,
                3,
                &data,
                Compression::Uncompressed,
                None,
                &geo,
            ))
            .unwrap();
            assert_eq!((g.ncols, g.nrows, g.dx, g.dy), (4, 3, 10.0, 5.0));
            assert_eq!((g.x0, g.y0), expected_x0y0);
            assert_eq!(
                g.sample_position(2, 3),
                Some(DVec3::new(1035.0, 1987.5, 80.0))
            );
        }
    }

    #[test]
    fn pixel_is_point_and_offset_tiepoint() {
        let data = ramp(12);
        let tie = [2.0, 3.0, 0.0, 1000.0, 2000.0, 0.0];
        let point = Geo {
            tie: Some(&tie),
            keys: Some(&[1, 1, 0, 2, 1024, 0, 1, 1, 1025, 0, 1, 2]),
            ..std_geo()
        };
        let g = read(&striped::<colortype::Gray16>(
            4,
            3,
            &data,
            Compression::Lzw,
            None,
            &point,
        ))
        .unwrap();
        assert_eq!((g.x0, g.y0), (980.0, 2015.0));
        // Sample (3, 2) is the tiepoint pixel itself.
        assert_eq!(g.sample_position(3, 2), None); // row 3 is out of range
        assert_eq!(
            g.sample_position(2, 2).map(|p| (p.x, p.y)),
            Some((1000.0, 2005.0))
        );

        let area = Geo {
            tie: Some(&tie),
            ..std_geo()
        };
        let g = read(&striped::<colortype::Gray16>(
            4,
            3,
            &data,
            Compression::Lzw,
            None,
            &area,
        ))
        .unwrap();
        assert_eq!((g.x0, g.y0), (985.0, 2012.5));
    }

    #[test]
    fn compressions_strips_and_sample_types_agree() {
        let (w, h) = (7u32, 5u32);
        let n = (w * h) as usize;
        let geo = std_geo();
        let reference: Vec<Option<f64>> = (0..n).map(|i| Some((i as f64) * 3.0 - 40.0)).collect();
        let i16s: Vec<i16> = (0..n as i16).map(|i| i * 3 - 40).collect();
        let i32s: Vec<i32> = i16s.iter().map(|&v| v.into()).collect();
        let f32s: Vec<f32> = i16s.iter().map(|&v| v.into()).collect();
        let f64s: Vec<f64> = i16s.iter().map(|&v| v.into()).collect();
        let compressions = [
            Compression::Uncompressed,
            Compression::Lzw,
            Compression::Deflate(DeflateLevel::Balanced),
            Compression::Packbits,
        ];
        for c in compressions {
            for rps in [None, Some(1), Some(2)] {
                let files = [
                    striped::<colortype::GrayI16>(w, h, &i16s, c, rps, &geo),
                    striped::<colortype::GrayI32>(w, h, &i32s, c, rps, &geo),
                    striped::<colortype::Gray32Float>(w, h, &f32s, c, rps, &geo),
                    striped::<colortype::Gray64Float>(w, h, &f64s, c, rps, &geo),
                ];
                for f in files {
                    let g = read(&f).unwrap();
                    assert_eq!(g.heights, reference);
                    assert_eq!((g.x0, g.y0), (1005.0, 1997.5));
                }
            }
        }
        let u8s: Vec<u8> = (0..n as u8).collect();
        let g = read(&striped::<colortype::Gray8>(
            w,
            h,
            &u8s,
            Compression::Lzw,
            None,
            &geo,
        ))
        .unwrap();
        assert_eq!(g.height(4, 6), Some(34.0));
    }

    #[test]
    fn tiled_raster_with_partial_edge_tiles() {
        let (w, h) = (20u32, 19u32);
        let data: Vec<i16> = (0..(w * h) as i16).map(|i| i - 100).collect();
        let g = read(&tiled_i16(w, h, &data, &std_geo())).unwrap();
        assert_eq!((g.ncols, g.nrows), (20, 19));
        let expected: Vec<Option<f64>> = data.iter().map(|&v| Some(v.into())).collect();
        assert_eq!(g.heights, expected);
    }

    #[test]
    fn a_georeferencing_tag_with_too_many_values_is_refused_before_it_is_read() {
        let long = "1".repeat(1000);
        let geo = Geo {
            nodata: Some(&long),
            ..std_geo()
        };
        let data: Vec<u16> = vec![1, 2, 3, 4];
        let e = read(&striped::<colortype::Gray16>(
            2,
            2,
            &data,
            Compression::Uncompressed,
            None,
            &geo,
        ))
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("GDAL_NODATA (42113) holds 1001 values; at most 256 are read"),
            "{e}"
        );
    }

    #[test]
    fn gdal_nodata_and_nan() {
        let data: Vec<u16> = vec![1, 7, 3, 7];
        let geo = Geo {
            nodata: Some("7"),
            ..std_geo()
        };
        let g = read(&striped::<colortype::Gray16>(
            2,
            2,
            &data,
            Compression::Uncompressed,
            None,
            &geo,
        ))
        .unwrap();
        assert_eq!(g.heights, vec![Some(1.0), None, Some(3.0), None]);

        // NaN is NODATA; f32 NODATA is matched in f32 precision.
        let data = [f32::NAN, f32::MIN, 0.1, 2.5];
        let geo = Geo {
            nodata: Some(" -3.4028234663852886e+38 "),
            ..std_geo()
        };
        let g = read(&striped::<colortype::Gray32Float>(
            2,
            2,
            &data,
            Compression::Lzw,
            None,
            &geo,
        ))
        .unwrap();
        assert_eq!(
            g.heights,
            vec![None, None, Some(f64::from(0.1f32)), Some(2.5)]
        );

        let data = [1.0f32, f32::INFINITY];
        let e = err(&striped::<colortype::Gray32Float>(
            2,
            1,
            &data,
            Compression::Uncompressed,
            None,
            &std_geo(),
        ));
        assert_eq!(
            e,
            "t.tif: infinite sample inf at row 0, column 1 (not the GDAL_NODATA value)"
        );

        let nodata_error = |text: &str| {
            let geo = Geo {
                nodata: Some(text),
                ..std_geo()
            };
            err(&striped::<colortype::Gray16>(
                1,
                1,
                &[1],
                Compression::Uncompressed,
                None,
                &geo,
            ))
        };
        assert_eq!(
            nodata_error("none"),
            "t.tif: GDAL_NODATA (42113) is not a number: 'none'"
        );
        // Quoted as every bad token is: a control character escaped (the sentence on one
        // line), at most 60 characters shown.
        let e = nodata_error(&format!("no\ndata{}", "x".repeat(150)));
        assert!(!e.contains('\n') && e.len() < 200 && e.contains('…'), "{e}");
    }

    #[test]
    fn missing_or_unsupported_georeferencing_names_the_tag() {
        let d = [1u16, 2, 3, 4];
        let file = |geo: &Geo| {
            striped::<colortype::Gray16>(2, 2, &d, Compression::Uncompressed, None, geo)
        };

        let e = err(&file(&Geo::default()));
        assert!(
            e.starts_with("t.tif: no georeferencing: missing ModelTiepointTag (33922)"),
            "{e}"
        );
        let e = err(&file(&Geo {
            scale: None,
            ..std_geo()
        }));
        assert!(
            e.starts_with("t.tif: missing ModelPixelScaleTag (33550)"),
            "{e}"
        );
        let e = err(&file(&Geo {
            tie: None,
            ..std_geo()
        }));
        assert!(
            e.starts_with("t.tif: missing ModelTiepointTag (33922)"),
            "{e}"
        );

        let rotated = [
            8.66, -5.0, 0.0, 1000.0, 5.0, -8.66, 0.0, 2000.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
            1.0,
        ];
        let e = err(&file(&Geo {
            matrix: Some(&rotated),
            ..Geo::default()
        }));
        assert!(
            e.contains("rotated or sheared") && e.contains("ModelTransformationTag 34264"),
            "{e}"
        );

        let north_up = [
            10.0, 0.0, 0.0, 1000.0, 0.0, -5.0, 0.0, 2000.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0,
        ];
        let g = read(&file(&Geo {
            matrix: Some(&north_up),
            ..Geo::default()
        }))
        .unwrap();
        assert_eq!((g.x0, g.y0, g.dx, g.dy), (1005.0, 1997.5, 10.0, 5.0));

        let e = err(&file(&Geo {
            scale: Some(&[10.0, -5.0, 0.0]),
            ..std_geo()
        }));
        assert!(e.contains("must be positive"), "{e}");
        let e = err(&file(&Geo {
            scale: Some(&[f64::NAN, 5.0, 0.0]),
            ..std_geo()
        }));
        assert_eq!(
            e,
            "t.tif: ModelPixelScaleTag (33550) holds NaN or infinite values"
        );
        let e = err(&file(&Geo {
            tie: Some(&[0.0, 0.0, 0.0, 1.0]),
            ..std_geo()
        }));
        assert_eq!(
            e,
            "t.tif: ModelTiepointTag (33922) holds 4 values; expected a multiple of 6"
        );
        let e = err(&file(&Geo {
            keys: Some(&[1, 1, 0, 3, 1025, 0, 1, 1]),
            ..std_geo()
        }));
        assert_eq!(
            e,
            "t.tif: GeoKeyDirectoryTag (34735) declares 3 keys but holds only 1"
        );
        let e = err(&file(&Geo {
            keys: Some(&[1, 1]),
            ..std_geo()
        }));
        assert!(
            e.starts_with("t.tif: GeoKeyDirectoryTag (34735) holds 2 values"),
            "{e}"
        );
        let e = err(&file(&Geo {
            keys: Some(&[1, 1, 0, 1, 1025, 0, 1, 9]),
            ..std_geo()
        }));
        assert!(
            e.contains("GTRasterTypeGeoKey (1025) in GeoKeyDirectoryTag (34735) is 9"),
            "{e}"
        );
    }

    #[test]
    fn multi_band_unsupported_types_and_photometric() {
        let rgb = striped::<colortype::RGB8>(
            2,
            1,
            &[1, 2, 3, 4, 5, 6],
            Compression::Uncompressed,
            None,
            &std_geo(),
        );
        assert_eq!(
            err(&rgb),
            "t.tif: SamplesPerPixel (277) is 3: only single-band rasters are supported"
        );
        let u64s =
            striped::<colortype::Gray64>(1, 1, &[5], Compression::Uncompressed, None, &std_geo());
        let e = err(&u64s);
        assert!(
            e.starts_with("t.tif: unsupported sample type: 64-bit unsigned integer"),
            "{e}"
        );
        let white = Geo {
            photometric: Some(0),
            ..std_geo()
        };
        let inverted =
            striped::<colortype::Gray16>(1, 1, &[5], Compression::Uncompressed, None, &white);
        assert!(err(&inverted).starts_with("t.tif: PhotometricInterpretation (262) is 0"));
    }

    #[test]
    fn absurd_dimensions_are_refused_before_decoding() {
        let mut file =
            striped::<colortype::Gray16>(1, 1, &[5], Compression::Uncompressed, None, &std_geo());
        // Patch ImageWidth / ImageLength (SHORT or LONG) in the first IFD.
        let ifd = u32::from_le_bytes(file[4..8].try_into().unwrap()) as usize;
        let entries = u16::from_le_bytes(file[ifd..ifd + 2].try_into().unwrap()) as usize;
        for k in 0..entries {
            let at = ifd + 2 + 12 * k;
            let tag = u16::from_le_bytes(file[at..at + 2].try_into().unwrap());
            if tag == 256 || tag == 257 {
                file[at + 2..at + 4].copy_from_slice(&4u16.to_le_bytes()); // LONG
                file[at + 8..at + 12].copy_from_slice(&100_000u32.to_le_bytes());
            }
        }
        let e = err(&file);
        assert!(
            e.contains("100000 columns x 100000 rows is too large"),
            "{e}"
        );
    }

    #[test]
    fn garbage_truncated_and_missing_files() {
        assert!(err(b"").starts_with("t.tif: "));
        let e = err(b"hello, this is not a tiff");
        assert!(e.starts_with("t.tif: not a valid TIFF"), "{e}");
        let e = load_geotiff("/nonexistent/x.tif").unwrap_err();
        assert!(matches!(e, Error::Io { .. }), "{e}");

        let real = std::fs::read(format!("{DATA}/jacksboro_fault_dem_utm_int16.tif")).unwrap();
        let e = err(&real[..real.len() / 2]);
        assert!(e.starts_with("t.tif: file is truncated"), "{e}");
        for cut in [4, 8, 16, 100, 300, 587, 600, real.len() - 1] {
            let e = read(&real[..cut]).unwrap_err().to_string();
            assert!(e.starts_with("t.tif: "), "{e}");
        }
        let deflate =
            std::fs::read(format!("{DATA}/jacksboro_fault_dem_utm_f32_deflate.tif")).unwrap();
        for cut in [10, 500, 1000, deflate.len() / 3, deflate.len() - 10] {
            assert!(read(&deflate[..cut]).is_err(), "cut at {cut}");
        }
    }

    #[test]
    fn corrupted_bytes_never_panic() {
        let data = ramp(40 * 30);
        let clean =
            striped::<colortype::Gray16>(40, 30, &data, Compression::Lzw, Some(4), &std_geo());
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for _ in 0..2000 {
            let mut f = clean.clone();
            for _ in 0..1 + next() % 4 {
                let at = (next() % f.len() as u64) as usize;
                f[at] = next() as u8;
            }
            let _ = read(&f); // Ok or Err, but no panic.
        }
    }

    /// Regression (fuzzing): a ModelPixelScaleTag claiming 2^29 values must be refused without
    /// the decoder reserving 16 GiB for it first.
    #[test]
    fn a_tag_with_a_huge_count_is_refused_cheaply() {
        let hex = "49492a0008000000070000010300010000000100000001010300010000000100000002010300010000001000000006010300010000000100000011010400010000000000000017010400010000000200000000e830c00000000200000000000000000";
        let bytes: Vec<u8> = (0..hex.len() / 2)
            .map(|i| u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).unwrap())
            .collect();
        let result = read_geotiff(std::io::Cursor::new(bytes), "huge-tag.tif");
        assert!(result.is_err());
    }

    /// A grid stored south-up (a ModelTransformationTag whose row step is positive) is refused
    /// as a negative pixel scale is, not read upside down; a ModelTiepointTag of more than one
    /// tiepoint's values but not whole tiepoints is refused, not read as its first six.
    #[test]
    fn south_up_matrices_and_ragged_tiepoints_are_refused() {
        let d = [1u16, 2, 3, 4];
        let file = |geo: &Geo| {
            striped::<colortype::Gray16>(2, 2, &d, Compression::Uncompressed, None, geo)
        };
        let south_up = [
            10.0, 0.0, 0.0, 1000.0, 0.0, 5.0, 0.0, 2000.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0,
        ];
        let e = err(&file(&Geo {
            matrix: Some(&south_up),
            ..Geo::default()
        }));
        assert!(
            e.contains("must be positive") && e.contains("ModelTransformationTag (34264)"),
            "{e}"
        );
        let e = err(&file(&Geo {
            tie: Some(&[0.0, 0.0, 0.0, 1000.0, 2000.0, 0.0, 1.0]),
            ..std_geo()
        }));
        assert_eq!(
            e,
            "t.tif: ModelTiepointTag (33922) holds 7 values; expected a multiple of 6"
        );
    }
}
