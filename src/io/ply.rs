//! Loading triangle meshes from PLY (Stanford polygon) files, plain or gzip-compressed.
//!
//! This module owns the PLY reader: the header (`format`, `element`, `property`, `comment`,
//! `obj_info`, `end_header`), the three encodings (`ascii`, `binary_little_endian`,
//! `binary_big_endian`), and the whitespace tokenizer (`Tokens`) its ascii body shares with
//! the ascii STL reader. A file that starts with the gzip magic bytes (a `.ply.gz`) is
//! decompressed as it is read.
//!
//! # What is read
//!
//! - Element `vertex`: the properties `x`, `y` and `z` (`float` or `double`) become the mesh's
//!   positions, in file order (in an ascii body too, a `float` is rounded to f32). Every other
//!   vertex property (any scalar type, and lists) is skipped.
//! - Element `face`: its list property `vertex_indices` (or `vertex_index`), with an integer
//!   count (`uchar`, `ushort`, `uint`, `char`, `short`, `int`) and integer indices. Each
//!   polygon `i0 i1 … in` is fan-triangulated in file order, `(i0,i1,i2), (i0,i2,i3), …`, so
//!   triangle ids follow the faces exactly as in the OBJ reader. Faces with fewer than 3
//!   vertices give no triangle: they are skipped with one warning ([`crate::io::warnings`]: their count
//!   and the first one's index). Other face properties are skipped.
//! - Every other element is skipped, whatever its properties. A file without a `face` element
//!   gives an empty mesh (with a warning, as an OBJ without faces).
//! - In an ascii body each item is a line of its own, as the format says: a line with more or
//!   fewer values than the header's properties, and anything after the last item, are errors
//!   naming the line (blank lines, spaces and CRLF line ends are not values). A binary body
//!   followed by anything but blanks is an error too: the header's counts ask for fewer items
//!   than the file holds.
//!
//! # Sizes
//!
//! Nothing is allocated from a count in the header before it is checked: the header's vertices
//! and faces must fit the memory budget ([`crate::budget`]); the least number of bytes the
//! header's elements need must be in the file; and triangles, whose number the header does not
//! say, are checked against the budget as they grow. The header itself may take at most
//! [`MAX_HEADER_BYTES`]; an ascii token at most [`MAX_TOKEN_BYTES`].
//!
//! A compressed file must be plausible: it may inflate to at most [`MAX_INFLATE_RATIO`] bytes
//! per byte of file, or [`INFLATE_FLOOR`] bytes in all. Its header's elements are refused when
//! the least bytes they need pass that, before anything is inflated past the header; its data,
//! whatever the header says (a list may be longer than its least), as soon as the inflated
//! bytes pass it. So a decompression bomb — a megabyte of zeros that inflates to a gigabyte —
//! stops within [`INFLATE_FLOOR`] or so, as compressed rasters and glTF files do
//! ([`crate::dem::SAMPLES_PER_FILE_BYTE`], [`crate::io::gltf::READ_PER_INPUT_BYTE`]).

use std::collections::HashSet;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;

use flate2::bufread::MultiGzDecoder;
use glam::DVec3;

use crate::budget::quote;
use crate::error::Error;
use crate::scene::Mesh;

/// The longest header read, in bytes (1 MiB); a longer one is an error.
pub const MAX_HEADER_BYTES: u64 = 1 << 20;

/// The longest token of an ascii body, in bytes: longer ones are errors (no number needs more).
pub const MAX_TOKEN_BYTES: usize = 128;

/// The most bytes a deflate stream can inflate to per byte of compressed input (258 bytes from a
/// 2-bit length/distance pair).
pub const MAX_DEFLATE_RATIO: u64 = 1032;

/// The most bytes a compressed PLY file may inflate to per byte of file (beyond
/// [`INFLATE_FLOOR`]). Real meshes compress far less, their coordinates and indices being close
/// to random in their low bits: gzip (level 9) shrinks the Stanford bunny 1.7-fold as binary
/// PLY, 2.4-fold as ascii, and even a flat 500 × 500 grid of integer coordinates only 4.3-fold
/// (binary) and 5.9-fold (ascii). Between this and deflate's own limit ([`MAX_DEFLATE_RATIO`])
/// lies zero-filled or constant data: 1M zero vertices shrink 1017-fold. That is what a
/// decompression bomb is made of, and what this refuses.
pub const MAX_INFLATE_RATIO: u64 = 64;

/// The bytes any compressed PLY file may inflate to, whatever its size (16 MiB): small files of
/// very regular data still load, and a bomb stops within this.
pub const INFLATE_FLOOR: u64 = 16 << 20;

/// Bytes of memory per vertex (its f64 position).
const VERTEX_BYTES: u64 = 24;

/// Bytes of memory per triangle (three u32 indices).
const TRIANGLE_BYTES: u64 = 12;

/// Loads the triangle mesh of the PLY file at `path` (ascii or binary, gzip-compressed or not).
///
/// A file without faces gives an empty mesh. A malformed header or body (an unknown keyword or
/// type, missing `x`/`y`/`z`, a bad number, an index out of range, a truncated file) is an
/// [`Error::Parse`] naming the file, and for ascii the line; counts over the memory budget are
/// an [`Error::OverBudget`] naming the file; a file that cannot be read is an [`Error::Io`].
pub fn load_ply(path: &Path) -> Result<Mesh, Error> {
    let name = path.display().to_string();
    let (file, length) = crate::io::open_regular(path)?;
    let mut reader = BufReader::new(file);
    let magic = reader.fill_buf().map_err(|source| Error::Io {
        path: name.clone(),
        source,
    })?;
    if magic.starts_with(&[0x1f, 0x8b]) {
        let input = Input {
            name,
            length,
            compressed: true,
        };
        let inflated = Inflated {
            decoder: MultiGzDecoder::new(reader),
            bytes: 0,
            most: input.most_inflated(),
        };
        let mut reader = BufReader::new(inflated);
        let mesh = read_ply(&input, &mut reader)?;
        // Read to the stream's end, so that its trailer (the CRC-32 and length of what it
        // inflates to) is checked: a file whose data parsed but whose trailer is damaged or
        // missing is refused, not taken on trust. Bytes after the last member are read as
        // another member, as the ascii reader's look past the data reads them (gzip itself
        // warns of them), so a padded file is refused either way.
        std::io::copy(&mut reader, &mut std::io::sink())
            .map_err(|e| input.io(e, "reading the rest of the compressed stream"))?;
        Ok(mesh)
    } else {
        let input = Input {
            name,
            length,
            compressed: false,
        };
        read_ply(&input, reader)
    }
}

/// The file being read, for checks and messages.
struct Input {
    /// The path as given.
    name: String,
    /// The file's length in bytes.
    length: u64,
    /// Whether the bytes are gzip-compressed.
    compressed: bool,
}

/// A gzip stream's inflated bytes, refused once they pass `most` (with an [`InflatedPast`]
/// error).
struct Inflated<R> {
    decoder: R,
    bytes: u64,
    most: u64,
}

impl<R: Read> Read for Inflated<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.decoder.read(buf)?;
        self.bytes = self.bytes.saturating_add(n as u64);
        if self.bytes > self.most {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                InflatedPast(self.most),
            ));
        }
        Ok(n)
    }
}

/// The error of an [`Inflated`] stream that passed its most bytes.
#[derive(Debug)]
struct InflatedPast(u64);

impl std::fmt::Display for InflatedPast {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "the data inflates past {} bytes", self.0)
    }
}

impl std::error::Error for InflatedPast {}

impl Input {
    /// The most bytes a compressed file of this length may inflate to.
    fn most_inflated(&self) -> u64 {
        INFLATE_FLOOR.max(self.length.saturating_mul(MAX_INFLATE_RATIO))
    }

    /// Why a compressed file of this length cannot plausibly hold more.
    fn implausible(&self) -> String {
        format!(
            "which is implausible for a compressed file of {} bytes: a compressed PLY file may \
             inflate to at most {MAX_INFLATE_RATIO} bytes per byte of file (or {INFLATE_FLOOR} \
             bytes in all), so {} here; refusing to decompress it",
            self.length,
            self.most_inflated()
        )
    }

    fn parse(&self, line: Option<usize>, message: String) -> Error {
        Error::Parse {
            path: self.name.clone(),
            line,
            message,
        }
    }

    /// A read error while `context`; a compressed file's data that inflates past its most is a
    /// [`Error::Parse`] saying so.
    fn io(&self, source: std::io::Error, context: &str) -> Error {
        if let Some(past) = source
            .get_ref()
            .and_then(|e| e.downcast_ref::<InflatedPast>())
        {
            return self.parse(None, format!("{past} ({context}), {}", self.implausible()));
        }
        Error::Io {
            path: self.name.clone(),
            source: std::io::Error::new(source.kind(), format!("{source} ({context})")),
        }
    }
}

/// Refuses bytes after a binary body's last item, as the ascii reader refuses values there:
/// they mean the header's counts ask for fewer items than the file holds (a mesh cut short
/// without a word). Blanks alone (a newline some writers add) are no data. Reads to the end,
/// which the file's length (or, compressed, its inflation limit) bounds.
fn check_binary_tail<R: BufRead>(input: &Input, reader: &mut R) -> Result<(), Error> {
    let (mut bytes, mut data) = (0u64, 0u64);
    loop {
        let buf = reader
            .fill_buf()
            .map_err(|e| input.io(e, "reading past the data"))?;
        if buf.is_empty() {
            break;
        }
        let n = buf.len();
        data += buf.iter().filter(|b| !b.is_ascii_whitespace()).count() as u64;
        bytes += n as u64;
        reader.consume(n);
    }
    if data == 0 {
        return Ok(());
    }
    Err(input.parse(
        None,
        format!(
            "{bytes} byte(s) follow the binary body's last item (the header's counts ask for \
             fewer items than the file holds)"
        ),
    ))
}

/// Reads a whole PLY stream (already decompressed).
fn read_ply<R: BufRead>(input: &Input, mut reader: R) -> Result<Mesh, Error> {
    let header = read_header(input, &mut reader)?;
    let plan = Plan::new(input, &header)?;
    check_sizes(input, &header, &plan)?;
    let mut mesh = Mesh::default();
    let mut short = None;
    match header.format {
        Format::Ascii => {
            let mut body = Ascii {
                tokens: Tokens::new(reader, header.lines + 1),
                item_line: None,
            };
            read_body(input, &header, &plan, &mut body, &mut mesh, &mut short)?;
            // Nothing may follow the last element's last item.
            match body.tokens.next_token() {
                Ok(None) => {}
                Ok(Some(token)) => {
                    let text = String::from_utf8_lossy(token).into_owned();
                    return Err(input.parse(
                        Some(body.tokens.line()),
                        format!(
                            "'{}' follows the last element's items (the header's counts ask \
                             for fewer)",
                            quote(&text)
                        ),
                    ));
                }
                Err(TokenError::Io(e)) => return Err(input.io(e, "reading past the data")),
                Err(e @ TokenError::TooLong(_)) => {
                    return Err(input.parse(Some(body.tokens.line()), e.to_string()));
                }
            }
        }
        Format::BinaryLittleEndian | Format::BinaryBigEndian => {
            let mut body = Binary {
                reader,
                big_endian: header.format == Format::BinaryBigEndian,
            };
            read_body(input, &header, &plan, &mut body, &mut mesh, &mut short)?;
            check_binary_tail(input, &mut body.reader)?;
        }
    }
    if let Some((count, first)) = short {
        crate::io::warnings::warn(format!(
            "{}: {count} face(s) with fewer than 3 vertices give no triangle and were \
             skipped (the first is face {first})",
            input.name
        ));
    } else if mesh.triangles.is_empty() {
        // As the OBJ reader says of its files.
        let read = match mesh.positions.len() {
            1 => "1 vertex but no face was read".to_owned(),
            n => format!("{n} vertices but no face were read"),
        };
        crate::io::warnings::warn(format!("{}: {read}, so its object is empty", input.name));
    }
    Ok(mesh)
}

// --- The header ---------------------------------------------------------------------------

/// The body's encoding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Ascii,
    BinaryLittleEndian,
    BinaryBigEndian,
}

/// A PLY scalar type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    /// The type named `word` (`char`/`int8`, `uchar`/`uint8`, …, `double`/`float64`).
    fn named(word: &str) -> Option<Self> {
        Some(match word {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    /// Its size in a binary body.
    fn size(self) -> u64 {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn is_integer(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }

    /// Whether the integer `value` fits this (integer) type.
    fn holds(self, value: i64) -> bool {
        let (low, high) = match self {
            Scalar::I8 => (i64::from(i8::MIN), i64::from(i8::MAX)),
            Scalar::U8 => (0, i64::from(u8::MAX)),
            Scalar::I16 => (i64::from(i16::MIN), i64::from(i16::MAX)),
            Scalar::U16 => (0, i64::from(u16::MAX)),
            Scalar::I32 => (i64::from(i32::MIN), i64::from(i32::MAX)),
            Scalar::U32 => (0, i64::from(u32::MAX)),
            Scalar::F32 | Scalar::F64 => return true,
        };
        (low..=high).contains(&value)
    }

    fn name(self) -> &'static str {
        match self {
            Scalar::I8 => "char",
            Scalar::U8 => "uchar",
            Scalar::I16 => "short",
            Scalar::U16 => "ushort",
            Scalar::I32 => "int",
            Scalar::U32 => "uint",
            Scalar::F32 => "float",
            Scalar::F64 => "double",
        }
    }
}

/// A property's type: a scalar, or a list with its count and item types.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Clone, Debug)]
struct Property {
    name: String,
    kind: Kind,
    /// The header line declaring it.
    line: usize,
}

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: u64,
    properties: Vec<Property>,
    /// The header line declaring it.
    line: usize,
}

impl Element {
    /// The fewest bytes one item can take in the body.
    fn least_item_bytes(&self, format: Format) -> u64 {
        self.properties
            .iter()
            .map(|p| match (format, p.kind) {
                // A token and a separator.
                (Format::Ascii, _) => 2,
                (_, Kind::Scalar(s)) => s.size(),
                (_, Kind::List { count, .. }) => count.size(),
            })
            .sum()
    }
}

#[derive(Clone, Debug)]
struct Header {
    format: Format,
    elements: Vec<Element>,
    /// Its number of lines (the body's first line is the next).
    lines: usize,
    /// Its length in bytes, `end_header` line included.
    bytes: u64,
}

/// Reads and checks the header, leaving `reader` at the first byte of the body.
fn read_header<R: BufRead>(input: &Input, reader: &mut R) -> Result<Header, Error> {
    let mut bytes = 0u64;
    let mut lines = 0usize;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    // The names seen, so that a second one is found in constant time (a 1 MiB header may
    // declare 60,000 elements, or as many properties of one element).
    let mut element_names: HashSet<String> = HashSet::new();
    let mut property_names: HashSet<String> = HashSet::new();
    let mut buf = Vec::new();
    loop {
        lines += 1;
        buf.clear();
        // The first line is "ply": no need to read far to see that it is not.
        let most = if lines == 1 {
            8
        } else {
            MAX_HEADER_BYTES - bytes
        };
        let n = reader
            .by_ref()
            .take(most)
            .read_until(b'\n', &mut buf)
            .map_err(|e| input.io(e, "reading the header"))?;
        bytes += n as u64;
        let at = Some(lines);
        if lines == 1 {
            if buf.last() != Some(&b'\n') || buf.trim_ascii() != b"ply" {
                return Err(input.parse(
                    None,
                    "not a PLY file: it does not begin with a 'ply' line".to_owned(),
                ));
            }
            continue;
        }
        if buf.last() != Some(&b'\n') {
            let message = if bytes >= MAX_HEADER_BYTES {
                format!(
                    "the header is longer than {} bytes without an 'end_header' line",
                    MAX_HEADER_BYTES
                )
            } else {
                "the file ends inside the header (no 'end_header' line)".to_owned()
            };
            return Err(input.parse(at, message));
        }
        let text = std::str::from_utf8(&buf)
            .map_err(|_| input.parse(at, "the header line is not text".to_owned()))?;
        let words: Vec<&str> = text.split_ascii_whitespace().collect();
        match words.as_slice() {
            [] | ["comment" | "obj_info", ..] => {}
            ["end_header"] => break,
            ["format", encoding, version] => {
                if format.is_some() {
                    return Err(input.parse(at, "a second 'format' line".to_owned()));
                }
                format = Some(match *encoding {
                    "ascii" => Format::Ascii,
                    "binary_little_endian" => Format::BinaryLittleEndian,
                    "binary_big_endian" => Format::BinaryBigEndian,
                    other => {
                        return Err(input.parse(
                            at,
                            format!(
                                "unknown format '{}' (expected ascii, binary_little_endian or \
                                 binary_big_endian)",
                                quote(other)
                            ),
                        ));
                    }
                });
                if !version.starts_with("1.") && *version != "1" {
                    return Err(input.parse(
                        at,
                        format!(
                            "unsupported PLY version '{}' (expected 1.0)",
                            quote(version)
                        ),
                    ));
                }
            }
            ["element", name, count] => {
                let count: u64 = count.parse().map_err(|_| {
                    input.parse(
                        at,
                        format!(
                            "the count '{}' of element '{}' is not a whole number",
                            quote(count),
                            quote(name)
                        ),
                    )
                })?;
                if !element_names.insert((*name).to_owned()) {
                    return Err(
                        input.parse(at, format!("a second element named '{}'", quote(name)))
                    );
                }
                property_names.clear();
                elements.push(Element {
                    name: (*name).to_owned(),
                    count,
                    properties: Vec::new(),
                    line: lines,
                });
            }
            ["property", rest @ ..] => {
                let Some(element) = elements.last_mut() else {
                    return Err(input.parse(at, "a property before any element".to_owned()));
                };
                let type_of = |word: &str| {
                    Scalar::named(word).ok_or_else(|| {
                        input.parse(at, format!("unknown property type '{}'", quote(word)))
                    })
                };
                let (kind, name) = match rest {
                    ["list", count, item, name] => (
                        Kind::List {
                            count: type_of(count)?,
                            item: type_of(item)?,
                        },
                        *name,
                    ),
                    [scalar, name] if *scalar != "list" => (Kind::Scalar(type_of(scalar)?), *name),
                    _ => {
                        return Err(input.parse(
                            at,
                            "expected 'property TYPE NAME' or 'property list COUNT_TYPE \
                             ITEM_TYPE NAME'"
                                .to_owned(),
                        ));
                    }
                };
                if let Kind::List { count, .. } = kind
                    && !count.is_integer()
                {
                    return Err(input.parse(
                        at,
                        format!(
                            "the list property '{}' has a count of type {}; a count must be an \
                             integer type",
                            quote(name),
                            count.name()
                        ),
                    ));
                }
                if !property_names.insert(name.to_owned()) {
                    return Err(input.parse(
                        at,
                        format!(
                            "element '{}' has a second property named '{}'",
                            quote(&element.name),
                            quote(name)
                        ),
                    ));
                }
                element.properties.push(Property {
                    name: name.to_owned(),
                    kind,
                    line: lines,
                });
            }
            [word, ..] => {
                return Err(input.parse(
                    at,
                    format!(
                        "unexpected header line starting with '{}' (expected format, element, \
                         property, comment, obj_info or end_header)",
                        quote(word)
                    ),
                ));
            }
        }
    }
    let format = format
        .ok_or_else(|| input.parse(Some(lines), "the header has no 'format' line".to_owned()))?;
    Ok(Header {
        format,
        elements,
        lines,
        bytes,
    })
}

// --- What to read -------------------------------------------------------------------------

/// What is done with one property of an item.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Action {
    /// Vertex coordinate 0, 1 or 2.
    Coordinate(usize),
    /// The face's vertex index list.
    Indices,
    /// Read past.
    Skip,
}

/// The header, turned into what to do with each property of each element.
struct Plan {
    /// Per element, per property.
    actions: Vec<Vec<Action>>,
    /// The number of vertices (0 without a vertex element).
    vertices: u64,
    /// The number of faces (0 without a face element).
    faces: u64,
}

impl Plan {
    fn new(input: &Input, header: &Header) -> Result<Self, Error> {
        let mut plan = Plan {
            actions: Vec::with_capacity(header.elements.len()),
            vertices: 0,
            faces: 0,
        };
        for element in &header.elements {
            let mut actions = vec![Action::Skip; element.properties.len()];
            match element.name.as_str() {
                "vertex" => {
                    for (axis, want) in ["x", "y", "z"].into_iter().enumerate() {
                        let Some(k) = element.properties.iter().position(|p| p.name == want) else {
                            return Err(input.parse(
                                Some(element.line),
                                format!("element 'vertex' has no property '{want}'"),
                            ));
                        };
                        let property = &element.properties[k];
                        match property.kind {
                            Kind::Scalar(Scalar::F32 | Scalar::F64) => {}
                            Kind::Scalar(other) => {
                                return Err(input.parse(
                                    Some(property.line),
                                    format!(
                                        "vertex property '{want}' has type {}; coordinates must \
                                         be float or double",
                                        other.name()
                                    ),
                                ));
                            }
                            Kind::List { .. } => {
                                return Err(input.parse(
                                    Some(property.line),
                                    format!(
                                        "vertex property '{want}' is a list; coordinates must be \
                                         float or double"
                                    ),
                                ));
                            }
                        }
                        actions[k] = Action::Coordinate(axis);
                    }
                    plan.vertices = element.count;
                }
                "face" => {
                    let Some(k) = element
                        .properties
                        .iter()
                        .position(|p| p.name == "vertex_indices" || p.name == "vertex_index")
                    else {
                        return Err(input.parse(
                            Some(element.line),
                            "element 'face' has no 'vertex_indices' (or 'vertex_index') list"
                                .to_owned(),
                        ));
                    };
                    let property = &element.properties[k];
                    match property.kind {
                        Kind::List { item, .. } if item.is_integer() => {}
                        Kind::List { item, .. } => {
                            return Err(input.parse(
                                Some(property.line),
                                format!(
                                    "face property '{}' has items of type {}; vertex indices \
                                     must be an integer type",
                                    property.name,
                                    item.name()
                                ),
                            ));
                        }
                        Kind::Scalar(_) => {
                            return Err(input.parse(
                                Some(property.line),
                                format!("face property '{}' is not a list", property.name),
                            ));
                        }
                    }
                    actions[k] = Action::Indices;
                    plan.faces = element.count;
                }
                _ => {}
            }
            plan.actions.push(actions);
        }
        Ok(plan)
    }
}

/// Checks the header's counts before anything is allocated from them: the memory for its
/// vertices and faces against the budget, the vertex count against what a mesh can index, and
/// the least bytes its elements need against what the file can hold.
fn check_sizes(input: &Input, header: &Header, plan: &Plan) -> Result<(), Error> {
    let name = &input.name;
    crate::budget::check(
        &format!("{name}: the header's vertices ({})", plan.vertices),
        plan.vertices,
        VERTEX_BYTES,
    )?;
    crate::budget::check(
        &format!(
            "{name}: the header's vertices ({}) and faces ({})",
            plan.vertices, plan.faces
        ),
        plan.vertices
            .saturating_mul(VERTEX_BYTES)
            .saturating_add(plan.faces.saturating_mul(TRIANGLE_BYTES)),
        1,
    )?;
    if plan.vertices > u64::from(u32::MAX) {
        return Err(input.parse(
            None,
            format!(
                "the header's {} vertices are more than a mesh can index (2^32 - 1)",
                plan.vertices
            ),
        ));
    }
    let need = header.elements.iter().fold(0u64, |sum, e| {
        sum.saturating_add(e.count.saturating_mul(e.least_item_bytes(header.format)))
    });
    // The last ascii token needs no separator after it.
    let need = if header.format == Format::Ascii {
        need.saturating_sub(1)
    } else {
        need
    };
    let have = if input.compressed {
        input.most_inflated().saturating_sub(header.bytes)
    } else {
        input.length.saturating_sub(header.bytes)
    };
    if need > have {
        // The first few elements, and how many more: a header may declare 60,000.
        const NAMED: usize = 4;
        let mut counts: Vec<String> = header
            .elements
            .iter()
            .take(NAMED)
            .map(|e| format!("{} {}", e.count, quote(&e.name)))
            .collect();
        if header.elements.len() > NAMED {
            counts.push(format!("and {} more", header.elements.len() - NAMED));
        }
        let why = if input.compressed {
            input.implausible()
        } else {
            format!(
                "but the file has {have} bytes after its header: the file is truncated or its \
                 counts are wrong"
            )
        };
        return Err(input.parse(
            None,
            format!(
                "the header's elements ({}) need at least {need} bytes of data, {why}",
                counts.join(", ")
            ),
        ));
    }
    Ok(())
}

// --- The body -----------------------------------------------------------------------------

/// Why reading a value failed.
enum Problem {
    /// The data ended.
    End,
    /// A bad value, as a sentence.
    Bad(String),
    /// A read failed.
    Io(std::io::Error),
    /// A complete error (the memory budget).
    Fatal(Error),
}

/// A token that could not be read, as a body's problem.
impl From<TokenError> for Problem {
    fn from(e: TokenError) -> Self {
        match e {
            TokenError::Io(e) => e.into(),
            e @ TokenError::TooLong(_) => Problem::Bad(e.to_string()),
        }
    }
}

impl From<std::io::Error> for Problem {
    fn from(e: std::io::Error) -> Self {
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            Problem::End
        } else {
            Problem::Io(e)
        }
    }
}

/// A PLY body in one of the encodings.
trait Body {
    /// Reads one value of type `s` (integers are exact in an f64).
    fn scalar(&mut self, s: Scalar) -> Result<f64, Problem>;
    /// Reads past `count` values of type `s`.
    fn skip(&mut self, s: Scalar, count: u64) -> Result<(), Problem>;
    /// Reads past `count` items of `bytes` each, when every item has that size; `false` when
    /// the encoding has no fixed item size (then nothing is read).
    fn skip_fixed(&mut self, count: u64, bytes: u64) -> Result<bool, Problem>;
    /// The 1-based line of the current item (text; the last value's before any item).
    fn line(&self) -> Option<usize>;
    /// An element's next item starts here (text: on a line of its own).
    fn start_item(&mut self) {}
    /// The item's values have been read (text: nothing else is on its line).
    fn end_item(&mut self) -> Result<(), Problem> {
        Ok(())
    }
}

/// A binary body.
struct Binary<R> {
    reader: R,
    big_endian: bool,
}

impl<R: BufRead> Binary<R> {
    fn skip_bytes(&mut self, bytes: u64) -> Result<(), Problem> {
        let skipped = std::io::copy(&mut self.reader.by_ref().take(bytes), &mut std::io::sink())?;
        if skipped < bytes {
            return Err(Problem::End);
        }
        Ok(())
    }
}

impl<R: BufRead> Body for Binary<R> {
    fn scalar(&mut self, s: Scalar) -> Result<f64, Problem> {
        let mut buf = [0u8; 8];
        let bytes = &mut buf[..s.size() as usize];
        self.reader.read_exact(bytes)?;
        if self.big_endian {
            bytes.reverse();
        }
        let [b0, b1, b2, b3, ..] = buf;
        Ok(match s {
            Scalar::I8 => f64::from(b0 as i8),
            Scalar::U8 => f64::from(b0),
            Scalar::I16 => f64::from(i16::from_le_bytes([b0, b1])),
            Scalar::U16 => f64::from(u16::from_le_bytes([b0, b1])),
            Scalar::I32 => f64::from(i32::from_le_bytes([b0, b1, b2, b3])),
            Scalar::U32 => f64::from(u32::from_le_bytes([b0, b1, b2, b3])),
            Scalar::F32 => f64::from(f32::from_le_bytes([b0, b1, b2, b3])),
            Scalar::F64 => f64::from_le_bytes(buf),
        })
    }

    fn skip(&mut self, s: Scalar, count: u64) -> Result<(), Problem> {
        self.skip_bytes(count.saturating_mul(s.size()))
    }

    fn skip_fixed(&mut self, count: u64, bytes: u64) -> Result<bool, Problem> {
        self.skip_bytes(count.saturating_mul(bytes))?;
        Ok(true)
    }

    fn line(&self) -> Option<usize> {
        None
    }
}

/// An ascii body: its tokens, each element item on a line of its own (the format's rule). Read
/// as one stream of tokens, a line with a value too many followed by one with a value too few
/// loaded as different triangles without a word.
struct Ascii<R> {
    tokens: Tokens<R>,
    /// The line the current item's first value is on (`None` before it).
    item_line: Option<usize>,
}

impl<R: BufRead> Ascii<R> {
    /// The next token of the current item, on the item's line.
    fn token(&mut self) -> Result<&[u8], Problem> {
        if self.tokens.next_token()?.is_none() {
            return Err(Problem::End);
        }
        let line = self.tokens.line();
        match self.item_line {
            None => self.item_line = Some(line),
            Some(first) if first != line => {
                return Err(Problem::Bad(
                    "its line ends before its last value (the header's properties ask for more)"
                        .to_owned(),
                ));
            }
            Some(_) => {}
        }
        Ok(self.tokens.last())
    }
}

impl<R: BufRead> Body for Ascii<R> {
    fn scalar(&mut self, s: Scalar) -> Result<f64, Problem> {
        let token = self.token()?;
        let text = String::from_utf8_lossy(token);
        if s.is_integer() {
            let value: i64 = text.parse().map_err(|_| {
                Problem::Bad(format!(
                    "'{}' is not an integer ({} expected)",
                    quote(&text),
                    s.name()
                ))
            })?;
            if !s.holds(value) {
                return Err(Problem::Bad(format!(
                    "{value} is out of range for type {}",
                    s.name()
                )));
            }
            Ok(value as f64)
        } else {
            let bad = |_| {
                Problem::Bad(format!(
                    "'{}' is not a number ({} expected)",
                    quote(&text),
                    s.name()
                ))
            };
            // The declared type holds, as in a binary body (rounded once, to f32 directly).
            if s == Scalar::F32 {
                text.parse::<f32>().map(f64::from).map_err(bad)
            } else {
                text.parse::<f64>().map_err(bad)
            }
        }
    }

    fn skip(&mut self, _s: Scalar, count: u64) -> Result<(), Problem> {
        // Every value is a token on the item's line, so this ends with the line.
        for _ in 0..count {
            self.token()?;
        }
        Ok(())
    }

    fn skip_fixed(&mut self, _count: u64, bytes: u64) -> Result<bool, Problem> {
        // Only an item without properties takes no token.
        Ok(bytes == 0)
    }

    fn line(&self) -> Option<usize> {
        // The item's own line: where a value is missing or wrong.
        Some(self.item_line.unwrap_or(self.tokens.line()))
    }

    fn start_item(&mut self) {
        self.item_line = None;
    }

    fn end_item(&mut self) -> Result<(), Problem> {
        if self.tokens.rest_of_line_is_blank()? {
            return Ok(());
        }
        Err(Problem::Bad(
            "its line holds more values than the header's properties".to_owned(),
        ))
    }
}

/// Reads the elements in header order into `mesh`; `short` gets the count of faces with fewer
/// than 3 vertices and the first one's index.
fn read_body<B: Body>(
    input: &Input,
    header: &Header,
    plan: &Plan,
    body: &mut B,
    mesh: &mut Mesh,
    short: &mut Option<(u64, u64)>,
) -> Result<(), Error> {
    for (element, actions) in header.elements.iter().zip(&plan.actions) {
        let fail = |body: &B, problem: Problem, item: Option<u64>| -> Error {
            let name = quote(&element.name);
            let at = match item {
                Some(item) => format!("{name} {item} of {}", element.count),
                None => format!("the {} items of element '{name}'", element.count),
            };
            match problem {
                Problem::End => input.parse(
                    body.line(),
                    format!(
                        "the data ends inside {at}: the file is truncated or its header counts \
                         are wrong"
                    ),
                ),
                Problem::Bad(message) => input.parse(body.line(), format!("{at}: {message}")),
                Problem::Io(e) => input.io(e, &format!("reading {at}")),
                Problem::Fatal(e) => e,
            }
        };
        let vertex = actions.iter().any(|a| matches!(a, Action::Coordinate(_)));
        let face = actions.contains(&Action::Indices);
        if !vertex && !face {
            // Only properties to skip.
            let all_scalars = element
                .properties
                .iter()
                .all(|p| matches!(p.kind, Kind::Scalar(_)));
            if all_scalars {
                match body.skip_fixed(element.count, element.least_item_bytes(header.format)) {
                    Ok(true) => continue,
                    Ok(false) => {}
                    Err(problem) => return Err(fail(body, problem, None)),
                }
            }
        }
        // The counts were checked against the budget and the input's size; for compressed input
        // the memory follows the data actually read.
        let first = if input.compressed {
            element.count.min(1 << 16)
        } else {
            element.count
        };
        let cannot =
            |what: &str| input.parse(None, format!("cannot allocate memory for the {what}"));
        if vertex {
            mesh.positions
                .try_reserve_exact(first as usize)
                .map_err(|_| cannot("vertices"))?;
        }
        if face {
            mesh.triangles
                .try_reserve_exact(first as usize)
                .map_err(|_| cannot("triangles"))?;
        }
        let vertices = plan.vertices;
        for item in 0..element.count {
            body.start_item();
            let mut position = [0.0f64; 3];
            for (property, action) in element.properties.iter().zip(actions) {
                let result = match (*action, property.kind) {
                    (Action::Coordinate(axis), Kind::Scalar(s)) => {
                        body.scalar(s).map(|v| position[axis] = v)
                    }
                    (Action::Indices, Kind::List { count, item: index }) => read_polygon(
                        body,
                        count,
                        index,
                        vertices,
                        &mut mesh.triangles,
                        &|triangles| {
                            crate::budget::check(
                                &format!("{}: the faces' triangles", input.name),
                                triangles,
                                TRIANGLE_BYTES,
                            )
                        },
                    )
                    .map(|corners| {
                        if corners < 3 {
                            short.get_or_insert((0, item)).0 += 1;
                        }
                    }),
                    (_, Kind::Scalar(s)) => body.skip(s, 1),
                    (_, Kind::List { count, item }) => body
                        .scalar(count)
                        .and_then(|n| list_length(n, count))
                        .and_then(|n| body.skip(item, n)),
                };
                result.map_err(|problem| fail(body, problem, Some(item)))?;
            }
            body.end_item()
                .map_err(|problem| fail(body, problem, Some(item)))?;
            if vertex {
                let p = DVec3::from_array(position);
                if !p.is_finite() {
                    return Err(fail(
                        body,
                        Problem::Bad(format!(
                            "the position {} is not finite",
                            crate::budget::point(p)
                        )),
                        Some(item),
                    ));
                }
                if mesh.positions.len() == mesh.positions.capacity() {
                    let more = (element.count - item).min(mesh.positions.len().max(1) as u64);
                    mesh.positions
                        .try_reserve_exact(more as usize)
                        .map_err(|_| cannot("vertices"))?;
                }
                mesh.positions.push(p);
            }
        }
    }
    Ok(())
}

/// A list's length from its count value `n` of type `count`.
fn list_length(n: f64, count: Scalar) -> Result<u64, Problem> {
    if n < 0.0 {
        return Err(Problem::Bad(format!(
            "the list count {n} ({}) is negative",
            count.name()
        )));
    }
    Ok(n as u64)
}

/// Reads one face's index list and appends its fan triangles to `triangles`, calling
/// `budget(n)` before the list grows to room for `n` triangles. Returns the face's number of
/// corners.
fn read_polygon<B: Body>(
    body: &mut B,
    count: Scalar,
    index: Scalar,
    vertices: u64,
    triangles: &mut Vec<[u32; 3]>,
    budget: &dyn Fn(u64) -> Result<(), Error>,
) -> Result<u64, Problem> {
    let corners = list_length(body.scalar(count)?, count)?;
    let mut first = 0u32;
    let mut previous = 0u32;
    for k in 0..corners {
        let value = body.scalar(index)?;
        if !(0.0..vertices as f64).contains(&value) {
            return Err(Problem::Bad(format!(
                "vertex index {value} (corner {k}) is out of range: the file has {vertices} \
                 vertices"
            )));
        }
        let i = value as u32;
        match k {
            0 => first = i,
            1 => previous = i,
            _ => {
                if triangles.len() >= u32::MAX as usize {
                    return Err(Problem::Bad(
                        "the faces give more than 2^32 - 1 triangles".to_owned(),
                    ));
                }
                if triangles.len() == triangles.capacity() {
                    let grown = (triangles.len() as u64).saturating_mul(2).max(1024);
                    budget(grown).map_err(Problem::Fatal)?;
                    triangles
                        .try_reserve_exact(grown as usize - triangles.len())
                        .map_err(|_| Problem::Bad("cannot allocate the triangles".to_owned()))?;
                }
                triangles.push([first, previous, i]);
                previous = i;
            }
        }
    }
    Ok(corners)
}

// --- Text tokens --------------------------------------------------------------------------

/// Why [`Tokens::next_token`] failed.
#[derive(Debug)]
pub(crate) enum TokenError {
    /// A read failed.
    Io(std::io::Error),
    /// A token longer than [`MAX_TOKEN_BYTES`]; its beginning, quoted.
    TooLong(String),
}

impl std::fmt::Display for TokenError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TokenError::Io(e) => write!(f, "{e}"),
            TokenError::TooLong(start) => write!(
                f,
                "the token '{start}' is longer than {MAX_TOKEN_BYTES} characters"
            ),
        }
    }
}

/// `reader`'s buffer, filled (empty at the end), a read interrupted by a signal tried again.
fn filled<R: BufRead>(reader: &mut R) -> Result<&[u8], TokenError> {
    loop {
        match reader.fill_buf() {
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(TokenError::Io(e)),
            Ok(_) => break,
        }
    }
    // Asked again for the borrow returned (the compiler does not let the loop return it): a
    // filled buffer is handed back without reading.
    reader.fill_buf().map_err(TokenError::Io)
}

/// The whitespace-separated tokens of a text stream, with line numbers, in bounded memory
/// (however long a line is): for the ascii bodies of PLY and STL files.
pub(crate) struct Tokens<R> {
    reader: R,
    /// The line the reader is on.
    current: usize,
    /// The line of the last token.
    line: usize,
    token: Vec<u8>,
}

impl<R: BufRead> Tokens<R> {
    /// Tokens of `reader`, whose first byte is on line `first_line`.
    pub(crate) fn new(reader: R, first_line: usize) -> Self {
        Self {
            reader,
            current: first_line,
            line: first_line,
            token: Vec::new(),
        }
    }

    /// The 1-based line of the last token read (the first line before any).
    pub(crate) fn line(&self) -> usize {
        self.line
    }

    /// The next token, or `None` at the end of the stream.
    pub(crate) fn next_token(&mut self) -> Result<Option<&[u8]>, TokenError> {
        self.token.clear();
        let mut inside = false;
        loop {
            let buf = filled(&mut self.reader)?;
            if buf.is_empty() {
                // At the end, `line` stays the last token's.
                return Ok(inside.then_some(self.token.as_slice()));
            }
            let mut i = 0;
            if !inside {
                while i < buf.len() && buf[i].is_ascii_whitespace() {
                    if buf[i] == b'\n' {
                        self.current += 1;
                    }
                    i += 1;
                }
                if i < buf.len() {
                    inside = true;
                    self.line = self.current;
                }
            }
            let start = i;
            while i < buf.len() && !buf[i].is_ascii_whitespace() {
                i += 1;
            }
            let piece = &buf[start..i];
            if self.token.len() + piece.len() > MAX_TOKEN_BYTES {
                self.token.extend_from_slice(piece);
                let text = String::from_utf8_lossy(&self.token).into_owned();
                return Err(TokenError::TooLong(quote(&text)));
            }
            self.token.extend_from_slice(piece);
            let ended = inside && i < buf.len();
            self.reader.consume(i);
            if ended {
                return Ok(Some(self.token.as_slice()));
            }
        }
    }

    /// The last token read.
    fn last(&self) -> &[u8] {
        &self.token
    }

    /// Whether the rest of the last token's line is blank: read past it (its newline included)
    /// when it is; when it is not, nothing past the blanks is read.
    fn rest_of_line_is_blank(&mut self) -> Result<bool, TokenError> {
        loop {
            let buf = filled(&mut self.reader)?;
            if buf.is_empty() {
                return Ok(true);
            }
            let blanks = buf
                .iter()
                .position(|&b| b == b'\n' || !b.is_ascii_whitespace());
            match blanks.map(|k| (k, buf[k])) {
                Some((k, b'\n')) => {
                    self.reader.consume(k + 1);
                    self.current += 1;
                    return Ok(true);
                }
                Some((k, _)) => {
                    self.reader.consume(k);
                    return Ok(false);
                }
                None => {
                    let n = buf.len();
                    self.reader.consume(n);
                }
            }
        }
    }

    /// Reads past the rest of the current line (its newline included).
    pub(crate) fn skip_line(&mut self) -> Result<(), TokenError> {
        loop {
            let buf = filled(&mut self.reader)?;
            if buf.is_empty() {
                return Ok(());
            }
            match buf.iter().position(|&b| b == b'\n') {
                Some(k) => {
                    self.reader.consume(k + 1);
                    self.current += 1;
                    return Ok(());
                }
                None => {
                    let n = buf.len();
                    self.reader.consume(n);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn all_tokens(text: &[u8], chunk: usize) -> Vec<(String, usize)> {
        let reader = BufReader::with_capacity(chunk, text);
        let mut tokens = Tokens::new(reader, 1);
        let mut out = Vec::new();
        while let Some(t) = tokens.next_token().unwrap() {
            let t = String::from_utf8(t.to_vec()).unwrap();
            out.push((t, tokens.line()));
        }
        out
    }

    #[test]
    fn tokens_keep_their_lines_across_buffer_boundaries() {
        let text = b"  ab\tcd\r\n\n  efgh  \n\nij";
        let want: Vec<(String, usize)> = [("ab", 1), ("cd", 1), ("efgh", 3), ("ij", 5)]
            .iter()
            .map(|&(t, l)| (t.to_owned(), l))
            .collect();
        for chunk in [1, 2, 3, 5, 64] {
            assert_eq!(all_tokens(text, chunk), want, "chunk {chunk}");
        }
    }

    #[test]
    fn long_tokens_are_refused_and_quoted_short() {
        let text = "1".repeat(10_000);
        let mut tokens = Tokens::new(BufReader::with_capacity(7, text.as_bytes()), 1);
        let e = tokens.next_token().unwrap_err().to_string();
        assert!(e.contains("longer than 128"), "{e}");
        assert!(e.chars().count() < 120, "{e}");
    }

    #[test]
    fn skip_line_moves_to_the_next_line() {
        let mut tokens = Tokens::new(BufReader::with_capacity(2, &b"solid a b c\nfacet"[..]), 1);
        assert_eq!(tokens.next_token().unwrap(), Some(&b"solid"[..]));
        tokens.skip_line().unwrap();
        assert_eq!(tokens.next_token().unwrap(), Some(&b"facet"[..]));
        assert_eq!(tokens.line(), 2);
        assert_eq!(tokens.next_token().unwrap(), None);
    }
}
