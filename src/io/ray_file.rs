//! Reading ray files (one ray per line, `ox oy oz dx dy dz [tmax]`), and the point (`x y z`)
//! and pair (`x1 y1 z1 x2 y2 z2`) files of the line-of-sight commands.
//!
//! Numbers are whitespace separated, `#` starts a comment anywhere on a line
//! and blank lines are skipped. The parser accepts any value Rust parses as
//! an `f64`, including `nan` and `inf`: deciding what such rays mean (they
//! come back flagged invalid) is the picker's job, not the reader's.

use std::path::Path;

use glam::DVec3;

use crate::error::Error;

/// One ray read from a ray file.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayLine {
    /// The ray's origin `(ox, oy, oz)`.
    pub origin: DVec3,
    /// The ray's direction `(dx, dy, dz)`, as written (not normalized).
    pub dir: DVec3,
    /// The optional seventh number: the largest ray parameter to accept
    /// (`inf` is allowed and means unbounded).
    pub tmax: Option<f64>,
}

/// Parses the text of a ray file; `path` is only used in error messages.
///
/// A line with fewer than 6 or more than 7 numbers, or with a token that is
/// not a number, is an [`Error::Parse`] naming `path` and the 1-based line.
pub fn parse_rays(path: &str, text: &str) -> Result<Vec<RayLine>, Error> {
    let lines = parse_number_lines(
        path,
        text,
        &[6, 7],
        "6 or 7 numbers (ox oy oz dx dy dz [tmax])",
    )?;
    Ok(lines
        .iter()
        .map(|(_, v)| RayLine {
            origin: DVec3::new(v[0], v[1], v[2]),
            dir: DVec3::new(v[3], v[4], v[5]),
            tmax: v.get(6).copied(),
        })
        .collect())
}

/// Parses a point file: one `x y z` per line, same comment rules as ray files.
pub fn parse_points(path: &str, text: &str) -> Result<Vec<DVec3>, Error> {
    let lines = parse_number_lines(path, text, &[3], "3 numbers (x y z)")?;
    Ok(lines
        .iter()
        .map(|(_, v)| DVec3::new(v[0], v[1], v[2]))
        .collect())
}

/// Parses a pair file: one `x1 y1 z1 x2 y2 z2` per line, same comment rules as ray files.
pub fn parse_pairs(path: &str, text: &str) -> Result<Vec<(DVec3, DVec3)>, Error> {
    let lines = parse_number_lines(path, text, &[6], "6 numbers (x1 y1 z1 x2 y2 z2)")?;
    Ok(lines
        .iter()
        .map(|(_, v)| (DVec3::new(v[0], v[1], v[2]), DVec3::new(v[3], v[4], v[5])))
        .collect())
}

/// The numbers of each non-blank line with its 1-based line number; each line must hold one of
/// `counts` numbers. `#` starts a comment; a leading byte-order mark is skipped.
pub(crate) fn parse_number_lines(
    path: &str,
    text: &str,
    counts: &[usize],
    expected: &str,
) -> Result<Vec<(usize, Vec<f64>)>, Error> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut lines = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let error = |message: String| Error::Parse {
            path: path.to_owned(),
            line: Some(i + 1),
            message,
        };
        let content = raw.split('#').next().unwrap_or_default();
        let values = content
            .split_whitespace()
            .map(|token| {
                token
                    .parse::<f64>()
                    .map_err(|_| error(format!("'{token}' is not a number")))
            })
            .collect::<Result<Vec<f64>, Error>>()?;
        if values.is_empty() {
            continue;
        }
        if !counts.contains(&values.len()) {
            return Err(error(format!(
                "expected {expected}, found {}",
                values.len()
            )));
        }
        lines.push((i + 1, values));
    }
    Ok(lines)
}

/// Reads and parses the ray file at `path` (see [`parse_rays`]).
pub fn load_rays(path: &Path) -> Result<Vec<RayLine>, Error> {
    let name = path.display().to_string();
    parse_rays(&name, &read_text(path)?)
}

/// Reads and parses the point file at `path` (see [`parse_points`]).
pub fn load_points(path: &Path) -> Result<Vec<DVec3>, Error> {
    let name = path.display().to_string();
    parse_points(&name, &read_text(path)?)
}

/// Reads and parses the pair file at `path` (see [`parse_pairs`]).
pub fn load_pairs(path: &Path) -> Result<Vec<(DVec3, DVec3)>, Error> {
    let name = path.display().to_string();
    parse_pairs(&name, &read_text(path)?)
}

/// The file as UTF-8 text; errors name the file (and the line of the first invalid byte).
fn read_text(path: &Path) -> Result<String, Error> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| Error::Io {
        path: name.clone(),
        source,
    })?;
    String::from_utf8(bytes).map_err(|e| {
        let bytes = e.as_bytes();
        let valid = bytes
            .get(..e.utf8_error().valid_up_to())
            .unwrap_or_default();
        Error::Parse {
            path: name,
            line: Some(1 + valid.iter().filter(|&&b| b == b'\n').count()),
            message: "the file is not valid UTF-8 text".to_owned(),
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse_err(result: Result<Vec<RayLine>, Error>) -> (String, Option<usize>, String) {
        match result {
            Err(Error::Parse {
                path,
                line,
                message,
            }) => (path, line, message),
            other => panic!("expected a parse error, got {other:?}"),
        }
    }

    #[test]
    fn six_and_seven_numbers() {
        let rays = parse_rays("r.txt", "0 0 -5 0 0 1\n1 2 3\t4 5 6 7.5\n").unwrap();
        assert_eq!(
            rays,
            vec![
                RayLine {
                    origin: DVec3::new(0.0, 0.0, -5.0),
                    dir: DVec3::Z,
                    tmax: None,
                },
                RayLine {
                    origin: DVec3::new(1.0, 2.0, 3.0),
                    dir: DVec3::new(4.0, 5.0, 6.0),
                    tmax: Some(7.5),
                },
            ]
        );
    }

    #[test]
    fn comments_and_blank_lines_are_skipped() {
        let text = "# header\n\n   \n0 0 0 1 0 0 # trailing\n0 0 0 0 1 0 2#glued\n  # indented\n";
        let rays = parse_rays("r.txt", text).unwrap();
        assert_eq!(rays.len(), 2);
        assert_eq!(rays[0].dir, DVec3::X);
        assert_eq!(rays[1].tmax, Some(2.0));
    }

    #[test]
    fn crlf_and_empty_input() {
        assert!(parse_rays("r.txt", "").unwrap().is_empty());
        let rays = parse_rays("r.txt", "0 0 0 1 0 0\r\n0 0 0 0 0 1 3\r\n").unwrap();
        assert_eq!(rays.len(), 2);
        assert_eq!(rays[1].tmax, Some(3.0));
    }

    #[test]
    fn too_few_numbers() {
        let text = "0 0 0 1 0 0\n# c\n1 2 3 4 5\n";
        let (path, line, message) = parse_err(parse_rays("rays.txt", text));
        assert_eq!((path.as_str(), line), ("rays.txt", Some(3)));
        assert_eq!(
            message,
            "expected 6 or 7 numbers (ox oy oz dx dy dz [tmax]), found 5"
        );
        let err = parse_rays("rays.txt", text).unwrap_err();
        assert_eq!(
            err.to_string(),
            "rays.txt:3: expected 6 or 7 numbers (ox oy oz dx dy dz [tmax]), found 5"
        );
    }

    #[test]
    fn too_many_numbers() {
        let (_, line, message) = parse_err(parse_rays("r.txt", "1 2 3 4 5 6 7 8\n"));
        assert_eq!(line, Some(1));
        assert!(message.ends_with("found 8"), "{message}");
    }

    #[test]
    fn bad_token_is_named() {
        let (_, line, message) = parse_err(parse_rays("r.txt", "\n0 0 0 1 0 0\n0 0 x 1 0 0\n"));
        assert_eq!(line, Some(3));
        assert_eq!(message, "'x' is not a number");
        let (_, _, message) = parse_err(parse_rays("r.txt", "0 0 0 1 0 0 1,5\n"));
        assert_eq!(message, "'1,5' is not a number");
    }

    #[test]
    fn nan_and_inf_are_accepted() {
        let rays = parse_rays(
            "r.txt",
            "nan 0 0 inf -inf 0\n0 0 0 1 0 0 inf\n0 0 0 1 0 0 NaN\n",
        )
        .unwrap();
        assert!(rays[0].origin.x.is_nan());
        assert_eq!(rays[0].dir.x, f64::INFINITY);
        assert_eq!(rays[0].dir.y, f64::NEG_INFINITY);
        assert_eq!(rays[1].tmax, Some(f64::INFINITY));
        assert!(rays[2].tmax.is_some_and(f64::is_nan));
    }

    #[test]
    fn load_rays_reads_a_file() {
        let path =
            std::env::temp_dir().join(format!("raypick-rays-test-{}.txt", std::process::id()));
        std::fs::write(&path, "0 0 0 1 0 0 # r\n0 0\n").unwrap();
        let result = load_rays(&path);
        let _ = std::fs::remove_file(&path);
        let (name, line, _) = parse_err(result);
        assert_eq!(name, path.display().to_string());
        assert_eq!(line, Some(2));
    }

    #[test]
    fn missing_file_names_the_path() {
        let path = std::env::temp_dir().join("raypick-rays-test-does-not-exist.txt");
        let err = load_rays(&path).unwrap_err();
        assert!(matches!(err, Error::Io { .. }));
        assert!(err.to_string().contains(&path.display().to_string()));
    }
}
