//! Writing answers as CSV or JSON.
//!
//! CSV: one row per ray, `ray,hit,t,object,triangle,u,v,x,y,z,nx,ny,nz`; in all-hits mode one row
//! per hit with `rank` (0-based order along the ray) after `ray`, and a ray with no hit keeps one
//! row with `hit` 0. Scenes with a terrain grid add `row,col` (empty off the grid). Every row
//! ends with `invalid,overflow` (0 or 1): `invalid` marks a ray that could not be traced (a miss),
//! `overflow` a ray that had more hits than `max_hits` in all-hits mode (always 0 in the other
//! modes); both repeat on every row of a ray. A miss keeps its row with the fields between `hit`
//! and `invalid` empty. Numbers are printed in Rust's shortest
//! round-trip form, so an f64 world coordinate keeps every digit (well below a millimetre at map
//! coordinates); beyond 1e-7 ..= 1e21 in magnitude, with an exponent ([`csv_number`]). JSON
//! numbers take the exponent form below 1e-4 and from 1e16 (Rust's `{:?}`).

use crate::query::{Answers, Mode};
use crate::ray::Hit;
use std::io::Write;

/// Output formats.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Format {
    /// Comma-separated values with a header line.
    #[default]
    Csv,
    /// A JSON array with one object per ray.
    Json,
}

/// The CSV header line of closest and any-hit answers on a scene without a terrain grid.
pub const CSV_HEADER: &str = "ray,hit,t,object,triangle,u,v,x,y,z,nx,ny,nz,invalid,overflow";

/// The columns of [`CSV_HEADER`] that follow `ray` and come before the terrain's `row,col`.
const CSV_HIT_COLUMNS: &str = "hit,t,object,triangle,u,v,x,y,z,nx,ny,nz";

/// The flag columns every CSV row ends with.
const CSV_FLAG_COLUMNS: &str = "invalid,overflow";

/// How to write a batch of answers.
#[derive(Clone, Copy, Debug, Default)]
pub struct OutputOptions {
    /// CSV or JSON.
    pub format: Format,
    /// The query mode the answers are for.
    pub mode: Mode,
    /// Add `row,col` (the scene has a terrain grid).
    pub cells: bool,
}

/// Writes closest-hit answers (one hit per ray) as CSV or JSON.
pub fn write_hits(
    out: &mut (impl Write + ?Sized),
    hits: &[Hit],
    format: Format,
) -> std::io::Result<()> {
    let answers = Answers {
        nearest: hits.to_vec(),
        ..Answers::default()
    };
    write_answers(
        out,
        &answers,
        &OutputOptions {
            format,
            ..OutputOptions::default()
        },
    )
}

/// Writes a whole batch of answers.
pub fn write_answers(
    out: &mut (impl Write + ?Sized),
    answers: &Answers,
    options: &OutputOptions,
) -> std::io::Result<()> {
    let mut writer = AnswerWriter::begin(out, *options)?;
    writer.write(out, answers)?;
    writer.finish(out)
}

/// Writes answers chunk after chunk (for batches too large to hold at once): `begin`, then
/// `write` for each chunk in ray order, then `finish`.
#[derive(Debug)]
pub struct AnswerWriter {
    options: OutputOptions,
    rays_written: usize,
    /// The text of each piece of a window, kept for the next.
    texts: Vec<String>,
}

impl AnswerWriter {
    /// Writes the CSV header or opens the JSON array.
    pub fn begin(out: &mut (impl Write + ?Sized), options: OutputOptions) -> std::io::Result<Self> {
        match options.format {
            Format::Csv => {
                let rank = if options.mode == Mode::All {
                    "ray,rank,"
                } else {
                    "ray,"
                };
                let cells = if options.cells { ",row,col" } else { "" };
                writeln!(out, "{rank}{CSV_HIT_COLUMNS}{cells},{CSV_FLAG_COLUMNS}")?;
            }
            Format::Json => write!(out, "[")?,
        }
        Ok(Self {
            options,
            rays_written: 0,
            texts: Vec::new(),
        })
    }

    /// Writes the answers of the next rays. Their text is made on all cores, a window of
    /// about 32,768 rows at a time, and written in order.
    pub fn write(
        &mut self,
        out: &mut (impl Write + ?Sized),
        answers: &Answers,
    ) -> std::io::Result<()> {
        use rayon::prelude::*;
        let pieces = pieces(answers);
        let window = WINDOW_ROWS / PIECE_ROWS;
        // Each piece's text is made in a buffer kept from one window to the next (fresh memory
        // for every piece cost more than the text).
        let mut texts = std::mem::take(&mut self.texts);
        texts.resize_with(window.min(pieces.len()), String::new);
        for ranges in pieces.chunks(window) {
            texts
                .par_iter_mut()
                .zip(ranges)
                .for_each(|(text, range)| self.text(text, answers, range.clone()));
            for text in &texts[..ranges.len()] {
                out.write_all(text.as_bytes())?;
            }
        }
        self.texts = texts;
        self.rays_written += answers.nearest.len();
        Ok(())
    }

    /// Replaces `text` with the CSV rows or JSON records of the rays at `range` of `answers`.
    fn text(&self, text: &mut String, answers: &Answers, range: std::ops::Range<usize>) {
        use std::fmt::Write;
        let options = self.options;
        let all = options.mode == Mode::All;
        text.clear();
        for k in range {
            let nearest = &answers.nearest[k];
            let i = self.rays_written + k;
            let hits = answers.hits_of(k);
            let overflow = answers.overflow.get(k).copied().unwrap_or(false);
            match options.format {
                Format::Csv => csv_rows(
                    text,
                    i,
                    hits,
                    all,
                    options.cells,
                    (nearest.invalid, overflow),
                ),
                Format::Json => {
                    let sep = if i == 0 { "\n" } else { ",\n" };
                    let _ = if all {
                        let hits: Vec<String> = hits.iter().map(json_hit).collect();
                        write!(
                            text,
                            "{sep}  {{\"ray\":{i},\"invalid\":{},\"overflow\":{},\"hits\":[{}]}}",
                            nearest.invalid,
                            overflow,
                            hits.join(",")
                        )
                    } else if nearest.hit {
                        write!(text, "{sep}  {{\"ray\":{i},{}", &json_hit(nearest)[1..])
                    } else {
                        write!(
                            text,
                            "{sep}  {{\"ray\":{i},\"hit\":false,\"invalid\":{}}}",
                            nearest.invalid
                        )
                    };
                }
            }
        }
    }

    /// Closes the JSON array.
    pub fn finish(self, out: &mut (impl Write + ?Sized)) -> std::io::Result<()> {
        if self.options.format == Format::Json {
            writeln!(out, "\n]")?;
        }
        Ok(())
    }
}

/// Rows (hits, or a ray's one row without any) that one piece of work writes out as text.
const PIECE_ROWS: usize = 2048;

/// Rows made into text before they are written: their text is what the writer holds (CSV rows
/// take up to about 350 bytes).
const WINDOW_ROWS: usize = 1 << 15;

/// `answers`' rays in ranges of about [`PIECE_ROWS`] rows (at least one ray each).
fn pieces(answers: &Answers) -> Vec<std::ops::Range<usize>> {
    let n = answers.nearest.len();
    if answers.list_start.is_empty() {
        return (0..n)
            .step_by(PIECE_ROWS)
            .map(|s| s..(s + PIECE_ROWS).min(n))
            .collect();
    }
    let mut pieces = Vec::new();
    let (mut start, mut rows) = (0, 0);
    for k in 0..n {
        rows += answers.hits_of(k).len().max(1);
        if rows >= PIECE_ROWS {
            pieces.push(start..k + 1);
            (start, rows) = (k + 1, 0);
        }
    }
    if start < n {
        pieces.push(start..n);
    }
    pieces
}

/// Appends ray `i`'s CSV rows to `text`: one per hit of `hits` (with its rank when `all`), or a
/// row with `hit` 0 and empty fields when there is none; `row,col` when `cells`; the `invalid`
/// and `overflow` flags last.
fn csv_rows(
    text: &mut String,
    i: usize,
    hits: &[Hit],
    all: bool,
    cells: bool,
    (invalid, overflow): (bool, bool),
) {
    let mut int = itoa::Buffer::new();
    let flags = match (invalid, overflow) {
        (false, false) => "0,0",
        (false, true) => "0,1",
        (true, false) => "1,0",
        (true, true) => "1,1",
    };
    if hits.is_empty() {
        text.push_str(int.format(i));
        text.push_str(if all {
            ",,0,,,,,,,,,,,"
        } else {
            ",0,,,,,,,,,,,"
        });
        if cells {
            text.push_str(",,");
        }
        text.push(',');
        text.push_str(flags);
        text.push('\n');
        return;
    }
    for (r, h) in hits.iter().enumerate() {
        text.push_str(int.format(i));
        text.push(',');
        if all {
            text.push_str(int.format(r));
            text.push(',');
        }
        text.push_str("1,");
        push_csv_number(text, h.t);
        text.push(',');
        text.push_str(int.format(h.object));
        text.push(',');
        text.push_str(int.format(h.triangle));
        let (p, n) = (h.position, h.normal);
        for x in [h.u, h.v, p.x, p.y, p.z, n.x, n.y, n.z] {
            text.push(',');
            push_csv_number(text, x);
        }
        if cells {
            match h.cell {
                Some([row, col]) => {
                    text.push(',');
                    text.push_str(int.format(row));
                    text.push(',');
                    text.push_str(int.format(col));
                }
                None => text.push_str(",,"),
            }
        }
        text.push(',');
        text.push_str(flags);
        text.push('\n');
    }
}

fn json_hit(h: &Hit) -> String {
    let (p, n) = (h.position, h.normal);
    let cell = h
        .cell
        .map_or(String::new(), |[r, c]| format!(",\"row\":{r},\"col\":{c}"));
    format!(
        "{{\"hit\":true,\"t\":{},\"object\":{},\"triangle\":{},\"u\":{},\"v\":{},\"position\":[{},{},{}],\"normal\":[{},{},{}]{cell}}}",
        json_number(h.t),
        h.object,
        h.triangle,
        json_number(h.u),
        json_number(h.v),
        json_number(p.x),
        json_number(p.y),
        json_number(p.z),
        json_number(n.x),
        json_number(n.y),
        json_number(n.z)
    )
}

/// A JSON number in shortest round-trip form (`null` for non-finite values).
fn json_number(x: f64) -> String {
    if x.is_finite() {
        format!("{x:?}")
    } else {
        "null".into()
    }
}

use super::csv_number::push_csv_number;
pub use super::csv_number::{CsvNumber, csv_number};

crate::names::named!(Format {
    Csv => ("csv", "Comma-separated values with a header line."),
    Json => ("json", "A JSON array with one object per ray."),
});

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    /// Four rays' answers: a hit, a miss, an invalid ray and a hit with a terrain cell; in
    /// all-hits mode the first has two hits and the last overflowed.
    fn answers(mode: Mode) -> Answers {
        let hit = |t: f64, object: u32| Hit {
            hit: true,
            t,
            object,
            triangle: 3,
            u: 0.25,
            v: 0.5,
            position: DVec3::new(1.0, 2.0, t),
            normal: DVec3::Z,
            ..Hit::MISS
        };
        let nearest = vec![
            hit(1.5, 0),
            Hit::MISS,
            Hit::INVALID,
            Hit {
                cell: Some([4, 7]),
                ..hit(2.5, 1)
            },
        ];
        if mode != Mode::All {
            return Answers {
                nearest,
                ..Answers::default()
            };
        }
        Answers {
            lists: vec![hit(1.5, 0), hit(3.0, 2), nearest[3]],
            list_start: vec![0, 2, 2, 2, 3],
            overflow: vec![false, false, false, true],
            nearest,
        }
    }

    /// A batch of many pieces and windows (rays with 0 to 3 hits each in all-hits mode) is
    /// written as the rays' rows made one after another on one thread, in every format and
    /// mode, whole or in two chunks.
    #[test]
    fn pieces_made_in_parallel_are_the_rows_made_in_order() {
        let n = 3 * WINDOW_ROWS + 123;
        let hit = |k: usize, r: usize| Hit {
            hit: true,
            t: k as f64 + r as f64 / 8.0,
            object: (k % 5) as u32,
            triangle: k as u32,
            position: DVec3::new(k as f64 * 0.1, 1e-9 * r as f64, 3e20),
            normal: DVec3::Z,
            ..Hit::MISS
        };
        let mut all = Answers {
            list_start: vec![0],
            ..Answers::default()
        };
        for k in 0..n {
            let count = k % 4;
            all.lists.extend((0..count).map(|r| hit(k, r)));
            all.list_start.push(all.lists.len());
            all.overflow.push(k % 7 == 0);
            all.nearest
                .push(if count > 0 { hit(k, 0) } else { Hit::MISS });
        }
        let nearest = Answers {
            nearest: all.nearest.clone(),
            ..Answers::default()
        };
        for format in [Format::Csv, Format::Json] {
            for (mode, answers) in [(Mode::Closest, &nearest), (Mode::All, &all)] {
                let options = OutputOptions {
                    format,
                    mode,
                    cells: false,
                };
                let mut expected = Vec::new();
                let writer = AnswerWriter::begin(&mut expected, options).unwrap();
                let mut text = String::new();
                writer.text(&mut text, answers, 0..n);
                expected.extend_from_slice(text.as_bytes());
                writer.finish(&mut expected).unwrap();
                let mut whole = Vec::new();
                write_answers(&mut whole, answers, &options).unwrap();
                assert!(whole == expected, "{format:?} {mode:?}");
                let mut chunked = Vec::new();
                let mut writer = AnswerWriter::begin(&mut chunked, options).unwrap();
                for range in [0..n / 3, n / 3..n] {
                    let idx: Vec<usize> = range.collect();
                    writer.write(&mut chunked, &answers.subset(&idx)).unwrap();
                }
                writer.finish(&mut chunked).unwrap();
                assert!(chunked == expected, "{format:?} {mode:?} in chunks");
            }
        }
    }

    /// Answers written chunk after chunk ([`AnswerWriter`], as `raypick pick` streams a large
    /// ray file) are the very bytes written at once, in every format and mode: the rows and
    /// records go on numbering the rays from the chunks before, and the JSON array has one comma
    /// between records, so it still parses, one record per ray.
    #[test]
    fn answers_written_in_chunks_are_the_bytes_written_at_once() {
        for format in [Format::Csv, Format::Json] {
            for mode in [Mode::Closest, Mode::All] {
                let options = OutputOptions {
                    format,
                    mode,
                    cells: true,
                };
                let all = answers(mode);
                let mut whole = Vec::new();
                write_answers(&mut whole, &all, &options).unwrap();
                for chunks in [[0..1, 1..4], [0..3, 3..4]] {
                    let mut out = Vec::new();
                    let mut writer = AnswerWriter::begin(&mut out, options).unwrap();
                    for range in chunks {
                        let idx: Vec<usize> = range.collect();
                        writer.write(&mut out, &all.subset(&idx)).unwrap();
                    }
                    writer.finish(&mut out).unwrap();
                    assert_eq!(
                        String::from_utf8(out).unwrap(),
                        String::from_utf8(whole.clone()).unwrap(),
                        "{format:?} {mode:?}"
                    );
                }
                if format == Format::Json {
                    let parsed: Vec<serde_json::Value> = serde_json::from_slice(&whole).unwrap();
                    let rays: Vec<u64> =
                        parsed.iter().map(|r| r["ray"].as_u64().unwrap()).collect();
                    assert_eq!(rays, [0, 1, 2, 3], "{mode:?}");
                }
            }
        }
    }
}
