//! Loading triangle meshes from STL files, binary or ascii.
//!
//! This module owns the STL reader. Each facet is one triangle, in file order, so triangle ids
//! are facet indices; vertices are not welded (each facet adds its own 3 vertices). A binary
//! file's f32 coordinates are widened to f64; an ascii file's numbers are read as written, in
//! f64 (not rounded to f32), like the OBJ reader's. Facet normals and the binary attribute
//! bytes are ignored.
//!
//! # Binary or ascii
//!
//! A binary file is an 80-byte header, a little-endian `u32` facet count `n`, and `n` records of
//! 50 bytes (normal, three vertices, all `f32`, then 2 attribute bytes). As binary headers often
//! begin with `solid` too, the file's length decides: a file of exactly `84 + 50 n` bytes is
//! binary. Any other file must be ascii: `solid name`, then facets (`facet normal nx ny nz`,
//! `outer loop`, three `vertex x y z`, `endloop`, `endfacet`), then `endsolid name`; several
//! solids may follow each other. Keywords are read case-insensitively and tokens may be split
//! over lines in any way; the names run to the end of their lines. Normals are not read, so any
//! three tokens do (exporters write `nan`, `-nan(ind)`, …).
//!
//! # Sizes
//!
//! A binary file's facets are checked against the memory budget ([`crate::budget`]) before they
//! are read (the file length already bounds their count); an ascii file's are checked as the
//! mesh grows. Ascii tokens are read in bounded memory, however long a line is
//! ([`crate::io::ply::MAX_TOKEN_BYTES`]).

use std::io::{BufRead, BufReader, Cursor, Read};
use std::path::Path;

use glam::DVec3;

use crate::budget::quote;
use crate::error::Error;
use crate::io::ply::{TokenError, Tokens};
use crate::scene::Mesh;

/// Bytes of memory per facet: three f64 vertices and a triangle of u32 indices.
const FACET_BYTES: u64 = 3 * 24 + 12;

/// Bytes of a binary STL's header and facet count.
const BINARY_HEADER: u64 = 84;

/// Bytes of a binary STL facet record.
const BINARY_FACET: u64 = 50;

/// Loads the triangle mesh of the STL file at `path`, binary or ascii (see the
/// [module documentation](self)).
///
/// Malformed content (a length that fits neither form, an unexpected keyword, a bad or
/// non-finite number, a truncated file) is an [`Error::Parse`] naming the file, and for ascii
/// files the line; a mesh over the memory budget is an [`Error::OverBudget`] naming the file; a
/// file that cannot be read is an [`Error::Io`].
pub fn load_stl(path: &Path) -> Result<Mesh, Error> {
    let mesh = read_stl_file(path)?;
    if mesh.triangles.is_empty() {
        // As the OBJ and PLY readers say of theirs.
        crate::io::warnings::warn(format!(
            "{}: no facet was read, so its object is empty",
            path.display()
        ));
    }
    Ok(mesh)
}

/// [`load_stl`] without the warning.
fn read_stl_file(path: &Path) -> Result<Mesh, Error> {
    let name = path.display().to_string();
    let (file, length) = crate::io::open_regular(path)?;
    let io = |source| Error::Io {
        path: name.clone(),
        source,
    };
    let mut reader = BufReader::new(file);
    let mut head = Vec::with_capacity(BINARY_HEADER as usize);
    reader
        .by_ref()
        .take(BINARY_HEADER)
        .read_to_end(&mut head)
        .map_err(io)?;
    let count = head
        .get(80..84)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]));
    let binary_length =
        count.map(|n| BINARY_HEADER.saturating_add(u64::from(n).saturating_mul(BINARY_FACET)));
    if let (Some(n), Some(expected)) = (count, binary_length)
        && expected == length
    {
        return read_binary(&name, reader, n);
    }
    let text = head.trim_ascii_start();
    let solid = text.len() >= 5 && text[..5].eq_ignore_ascii_case(b"solid");
    let binary_bytes = head
        .iter()
        .any(|&b| b == 0 || (b < 0x20 && !b.is_ascii_whitespace()));
    let as_binary = match (count, binary_length) {
        (Some(n), Some(expected)) => format!(
            "as a binary STL, its facet count {n} needs 84 + 50 × {n} = {expected} bytes, but \
             the file has {length}"
        ),
        _ => format!("it has {length} bytes, too short for a binary STL (84 at least)"),
    };
    if !solid {
        return Err(parse_error(
            &name,
            None,
            format!(
                "not an STL file: it does not begin with 'solid' as an ascii STL does, and {as_binary}"
            ),
        ));
    }
    if binary_bytes {
        return Err(parse_error(
            &name,
            None,
            format!(
                "the file begins with 'solid' but holds binary bytes, so it is no ascii STL; \
                 {as_binary}"
            ),
        ));
    }
    read_ascii(&name, Tokens::new(Cursor::new(head).chain(reader), 1))
}

fn parse_error(path: &str, line: Option<usize>, message: String) -> Error {
    Error::Parse {
        path: path.to_owned(),
        line,
        message,
    }
}

/// Reads the `n` facet records of a binary STL, after its 84-byte header.
fn read_binary(name: &str, mut reader: impl Read, n: u32) -> Result<Mesh, Error> {
    crate::budget::check(
        &format!("{name}: the {n} facets"),
        u64::from(n),
        FACET_BYTES,
    )?;
    let vertices = u64::from(n) * 3;
    if vertices > u64::from(u32::MAX) {
        return Err(parse_error(
            name,
            None,
            format!("its {n} facets have more vertices than a mesh can index (2^32 - 1)"),
        ));
    }
    let mut mesh = Mesh::default();
    let cannot = || parse_error(name, None, format!("cannot allocate memory for {n} facets"));
    mesh.positions
        .try_reserve_exact(vertices as usize)
        .map_err(|_| cannot())?;
    mesh.triangles
        .try_reserve_exact(n as usize)
        .map_err(|_| cannot())?;
    let mut record = [0u8; BINARY_FACET as usize];
    for facet in 0..n {
        reader.read_exact(&mut record).map_err(|e| {
            if e.kind() == std::io::ErrorKind::UnexpectedEof {
                parse_error(
                    name,
                    None,
                    format!("the file ends inside facet {facet} of {n}"),
                )
            } else {
                Error::Io {
                    path: name.to_owned(),
                    source: std::io::Error::new(
                        e.kind(),
                        format!("{e} (reading facet {facet} of {n})"),
                    ),
                }
            }
        })?;
        let base = mesh.positions.len() as u32;
        for corner in 0..3 {
            let mut p = [0.0f64; 3];
            for (axis, value) in p.iter_mut().enumerate() {
                let at = 12 + 12 * corner + 4 * axis;
                let bytes = [record[at], record[at + 1], record[at + 2], record[at + 3]];
                *value = f64::from(f32::from_le_bytes(bytes));
            }
            let p = DVec3::from_array(p);
            if !p.is_finite() {
                return Err(parse_error(
                    name,
                    None,
                    format!(
                        "facet {facet}: vertex {corner} {} is not finite",
                        crate::budget::point(p)
                    ),
                ));
            }
            mesh.positions.push(p);
        }
        mesh.triangles.push([base, base + 1, base + 2]);
    }
    Ok(mesh)
}

/// Reads an ascii STL: one or more solids.
fn read_ascii<R: BufRead>(name: &str, mut tokens: Tokens<R>) -> Result<Mesh, Error> {
    let mut mesh = Mesh::default();
    let mut solids = 0usize;
    loop {
        let word = match next(name, &mut tokens)? {
            None if solids > 0 => return Ok(mesh),
            None => {
                return Err(parse_error(
                    name,
                    Some(tokens.line()),
                    "the file ends before its first solid".to_owned(),
                ));
            }
            Some(word) => word,
        };
        if !word.eq_ignore_ascii_case("solid") {
            return Err(unexpected(name, &tokens, &word, "'solid'"));
        }
        skip_line(name, &mut tokens)?;
        solids += 1;
        loop {
            let Some(word) = next(name, &mut tokens)? else {
                return Err(parse_error(
                    name,
                    Some(tokens.line()),
                    "the file ends before 'endsolid'".to_owned(),
                ));
            };
            if word.eq_ignore_ascii_case("endsolid") {
                skip_line(name, &mut tokens)?;
                break;
            }
            if !word.eq_ignore_ascii_case("facet") {
                return Err(unexpected(name, &tokens, &word, "'facet' or 'endsolid'"));
            }
            read_facet(name, &mut tokens, &mut mesh)?;
        }
    }
}

/// Reads the rest of a facet, after its `facet` keyword, into `mesh`.
fn read_facet<R: BufRead>(
    name: &str,
    tokens: &mut Tokens<R>,
    mesh: &mut Mesh,
) -> Result<(), Error> {
    let facet = mesh.triangles.len();
    expect(name, tokens, "normal")?;
    for _ in 0..3 {
        // The normal is not used: any token will do (exporters write "nan", "-nan(ind)", …).
        if next(name, tokens)?.is_none() {
            return Err(parse_error(
                name,
                Some(tokens.line()),
                format!("the file ends inside the normal of facet {facet}"),
            ));
        }
    }
    expect(name, tokens, "outer")?;
    expect(name, tokens, "loop")?;
    if mesh.triangles.len() == mesh.triangles.capacity() {
        grow(name, mesh)?;
    }
    let base = mesh.positions.len() as u32;
    for _ in 0..3 {
        expect(name, tokens, "vertex")?;
        let mut p = [0.0f64; 3];
        for value in &mut p {
            *value = number(name, tokens, facet)?;
        }
        let p = DVec3::from_array(p);
        if !p.is_finite() {
            return Err(parse_error(
                name,
                Some(tokens.line()),
                format!(
                    "facet {facet}: the vertex {} is not finite",
                    crate::budget::point(p)
                ),
            ));
        }
        mesh.positions.push(p);
    }
    expect(name, tokens, "endloop")?;
    expect(name, tokens, "endfacet")?;
    mesh.triangles.push([base, base + 1, base + 2]);
    Ok(())
}

/// Makes room for more facets in `mesh`, within the memory budget and what a mesh can index.
fn grow(name: &str, mesh: &mut Mesh) -> Result<(), Error> {
    let facets = mesh.triangles.len() as u64;
    let grown = facets.saturating_mul(2).max(1024);
    if facets.saturating_add(1).saturating_mul(3) > u64::from(u32::MAX) {
        return Err(parse_error(
            name,
            None,
            "the file has more facets than a mesh can index".to_owned(),
        ));
    }
    crate::budget::check(&format!("{name}: the facets"), grown, FACET_BYTES)?;
    let more = (grown - facets) as usize;
    let cannot = || {
        parse_error(
            name,
            None,
            format!("cannot allocate memory for {grown} facets"),
        )
    };
    mesh.triangles
        .try_reserve_exact(more)
        .map_err(|_| cannot())?;
    mesh.positions
        .try_reserve_exact(3 * more)
        .map_err(|_| cannot())?;
    Ok(())
}

/// The next token as text, or `None` at the end of the file.
fn next<R: BufRead>(name: &str, tokens: &mut Tokens<R>) -> Result<Option<String>, Error> {
    match tokens.next_token() {
        Ok(token) => Ok(token.map(|t| String::from_utf8_lossy(t).into_owned())),
        Err(TokenError::Io(source)) => Err(Error::Io {
            path: name.to_owned(),
            source,
        }),
        Err(e @ TokenError::TooLong(_)) => {
            Err(parse_error(name, Some(tokens.line()), e.to_string()))
        }
    }
}

fn skip_line<R: BufRead>(name: &str, tokens: &mut Tokens<R>) -> Result<(), Error> {
    tokens.skip_line().map_err(|e| match e {
        TokenError::Io(source) => Error::Io {
            path: name.to_owned(),
            source,
        },
        other => parse_error(name, Some(tokens.line()), other.to_string()),
    })
}

/// Reads the keyword `want` (in any case).
fn expect<R: BufRead>(name: &str, tokens: &mut Tokens<R>, want: &str) -> Result<(), Error> {
    match next(name, tokens)? {
        Some(word) if word.eq_ignore_ascii_case(want) => Ok(()),
        Some(word) => Err(unexpected(name, tokens, &word, &format!("'{want}'"))),
        None => Err(parse_error(
            name,
            Some(tokens.line()),
            format!("the file ends where '{want}' was expected"),
        )),
    }
}

/// Reads a number of facet `facet`.
fn number<R: BufRead>(name: &str, tokens: &mut Tokens<R>, facet: usize) -> Result<f64, Error> {
    let Some(word) = next(name, tokens)? else {
        return Err(parse_error(
            name,
            Some(tokens.line()),
            format!("the file ends inside facet {facet}, where a number was expected"),
        ));
    };
    word.parse().map_err(|_| {
        parse_error(
            name,
            Some(tokens.line()),
            format!("facet {facet}: '{}' is not a number", quote(&word)),
        )
    })
}

fn unexpected<R: BufRead>(name: &str, tokens: &Tokens<R>, found: &str, want: &str) -> Error {
    parse_error(
        name,
        Some(tokens.line()),
        format!("expected {want}, found '{}'", quote(found)),
    )
}
