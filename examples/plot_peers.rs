//! Plots the peer benchmark summary: throughput (M rays/s) against scene size (triangles), one
//! panel per ray set side by side in one SVG, one line per engine and thread count.
//!
//! Reads the CSV that `cargo bench --bench peers` writes
//! (`scene,triangles,rays,ray_count,engine,threads,median_ms,rays_per_s`):
//!
//! `cargo run --example plot_peers -- [CSV] [SVG] --note "machine, date" [--scenes PREFIX]`
//!
//! CSV defaults to `$CARGO_TARGET_DIR/peers-summary.csv` (else `target/peers-summary.csv`),
//! SVG to `docs/peers_throughput.svg`.

use clap::Parser;
use plotters::coord::combinators::{BindKeyPoints, LogCoord, WithKeyPoints};
use plotters::prelude::*;
use serde::Deserialize;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Parser)]
struct Args {
    /// Summary CSV written by `cargo bench --bench peers`.
    csv: Option<PathBuf>,
    /// SVG to write.
    svg: Option<PathBuf>,
    /// Caption under the plot: the machine, the date, the commit.
    #[arg(long, default_value = "")]
    note: String,
    /// Plot only scenes whose names start with this (e.g. `terrain`, a family that differs in
    /// size alone); default: every scene.
    #[arg(long, default_value = "")]
    scenes: String,
}

/// One row of the summary: one engine timed on one ray set over one scene.
#[derive(Debug, Deserialize)]
struct Row {
    scene: String,
    triangles: u64,
    rays: String,
    ray_count: u64,
    engine: String,
    threads: u32,
    median_ms: f64,
    rays_per_s: f64,
}

const HEADER: &str = "scene,triangles,rays,ray_count,engine,threads,median_ms,rays_per_s";

/// Okabe–Ito colours (distinguishable with colour-blindness); series cycle through them.
const COLOURS: [RGBColor; 8] = [
    RGBColor(0, 114, 178),
    RGBColor(86, 180, 233),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(0, 0, 0),
    RGBColor(170, 170, 0),
];

/// Parses the summary; every error names `source` and the line it is on.
fn parse_rows(text: &str, source: &str) -> Result<Vec<Row>, String> {
    let mut reader = csv::Reader::from_reader(text.as_bytes());
    let header = reader
        .headers()
        .map_err(|e| format!("{source}:1: {e}"))?
        .clone();
    if header.iter().collect::<Vec<_>>().join(",") != HEADER {
        return Err(format!("{source}:1: the header must be `{HEADER}`"));
    }
    let (mut rows, mut first_lines) = (Vec::new(), HashMap::new());
    for record in reader.records() {
        let record = record.map_err(|e| {
            let line = e.position().map_or(0, |p| p.line());
            format!("{source}:{line}: {e}")
        })?;
        let line = record.position().map_or(0, |p| p.line());
        let row: Row = record
            .deserialize(Some(&header))
            .map_err(|e| match e.kind() {
                csv::ErrorKind::Deserialize { err, .. } => {
                    let column = err
                        .field()
                        .and_then(|i| header.get(i as usize))
                        .unwrap_or("?");
                    format!("{source}:{line}: column `{column}`: {}", err.kind())
                }
                _ => format!("{source}:{line}: {e}"),
            })?;
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if row.triangles == 0 || !positive(row.median_ms) || !positive(row.rays_per_s) {
            let what = "triangles, median_ms and rays_per_s must be positive";
            return Err(format!("{source}:{line}: {what}"));
        }
        let key = (
            row.scene.clone(),
            row.rays.clone(),
            row.engine.clone(),
            row.threads,
        );
        if let Some(first) = first_lines.insert(key, line) {
            return Err(format!(
                "{source}:{line}: repeats the measurement on line {first}"
            ));
        }
        rows.push(row);
    }
    if rows.is_empty() {
        return Err(format!("{source}: no rows"));
    }
    Ok(rows)
}

/// Distinct values in order of first appearance.
fn distinct<T: PartialEq>(values: impl Iterator<Item = T>) -> Vec<T> {
    let mut seen = Vec::new();
    for value in values {
        if !seen.contains(&value) {
            seen.push(value);
        }
    }
    seen
}

/// The legend name of a series: the thread count is spelled out only for engines run with several.
fn series_label(rows: &[Row], (engine, threads): (&str, u32)) -> String {
    let counts = distinct(
        rows.iter()
            .filter(|r| r.engine == engine)
            .map(|r| r.threads),
    );
    match (counts.len(), threads) {
        (1, _) => engine.to_string(),
        (_, 1) => format!("{engine}, 1 thread"),
        _ => format!("{engine}, {threads} threads"),
    }
}

/// Marker shapes as regular polygons: (corners, angle of the first corner in degrees, radius in
/// pixels): a circle, an up triangle, a square, a diamond, a down triangle, a pentagon, a left
/// triangle.
const SHAPES: [(u32, f64, f64); 7] = [
    (16, 0.0, 4.5),
    (3, -90.0, 6.0),
    (4, 45.0, 5.5),
    (4, -90.0, 6.0),
    (3, 90.0, 6.0),
    (5, -90.0, 5.5),
    (3, 180.0, 6.0),
];

/// The marker of series `index`, in pixels around its point (place it with `EmptyElement::at`):
/// shapes and colours cycle at different periods.
fn marker(index: usize) -> Polygon<(i32, i32)> {
    let (corners, first, radius) = SHAPES[index % SHAPES.len()];
    let outline = (0..corners).map(|i| {
        let angle = (first + 360.0 * f64::from(i) / f64::from(corners)).to_radians();
        (
            (radius * angle.cos()).round() as i32,
            (radius * angle.sin()).round() as i32,
        )
    });
    Polygon::new(
        outline.collect::<Vec<_>>(),
        COLOURS[index % COLOURS.len()].filled(),
    )
}

/// A log axis over whole decades around `lo..hi`: bold lines and labels at powers of ten, light
/// lines at 2..9 times them.
fn decade_axis(lo: f64, hi: f64) -> WithKeyPoints<LogCoord<f64>> {
    let first = lo.log10().floor() as i32;
    let last = (hi.log10().ceil() as i32).max(first + 1);
    let decades: Vec<f64> = (first..=last).map(|e| 10f64.powi(e)).collect();
    let light = decades[..decades.len() - 1]
        .iter()
        .flat_map(|d| (2..10).map(move |m| m as f64 * d));
    (decades[0]..decades[decades.len() - 1])
        .log_scale()
        .with_key_points(decades.clone())
        .with_light_points(light)
}

/// `1k`, `10M`, `0.1`: powers of ten in short form.
fn short_number(value: &f64) -> String {
    match *value {
        v if v >= 1e6 => format!("{}M", v / 1e6),
        v if v >= 1e3 => format!("{}k", v / 1e3),
        v => format!("{v}"),
    }
}

/// Layout in pixels: one panel per ray set, then legend rows and the note under them.
const PANEL: (u32, u32) = (560, 440);
const TITLE_HEIGHT: u32 = 40;
const LEGEND_COLUMN: u32 = 230;
const LEGEND_ROW: u32 = 24;
const LEFT: i32 = 40;

type Area<'a> = DrawingArea<SVGBackend<'a>, plotters::coord::Shift>;

/// Writes the figure: the title, one panel per ray set, one legend for all panels, the note.
fn plot(rows: &[Row], svg: &Path, note: &str) -> Result<(), Box<dyn std::error::Error>> {
    let ray_sets = distinct(rows.iter().map(|r| r.rays.as_str()));
    let series = distinct(rows.iter().map(|r| (r.engine.as_str(), r.threads)));
    let width = PANEL.0 * ray_sets.len() as u32;
    let columns = ((width - LEFT as u32) / LEGEND_COLUMN).max(1);
    let legend_rows = (series.len() as u32).div_ceil(columns);
    let height = TITLE_HEIGHT + PANEL.1 + (legend_rows + 2) * LEGEND_ROW;

    let root = SVGBackend::new(svg, (width, height)).into_drawing_area();
    root.fill(&WHITE)?;
    let root = root.titled(
        "Closest-hit throughput against scene size",
        ("sans-serif", 26),
    )?;
    let (panels, footer) = root.split_vertically(PANEL.1);
    for (panel, rays) in panels
        .split_evenly((1, ray_sets.len()))
        .iter()
        .zip(&ray_sets)
    {
        draw_panel(panel, rows, rays, &series)?;
    }
    for (index, &key) in series.iter().enumerate() {
        let x = LEFT + (index as u32 % columns * LEGEND_COLUMN) as i32;
        let y = (LEGEND_ROW * (1 + index as u32 / columns)) as i32 - 4;
        let colour = COLOURS[index % COLOURS.len()];
        footer.draw(&PathElement::new(
            vec![(x, y), (x + 36, y)],
            colour.stroke_width(2),
        ))?;
        footer.draw(&(EmptyElement::at((x + 18, y)) + marker(index)))?;
        let label = series_label(rows, key);
        footer.draw_text(&label, &("sans-serif", 15).into(), (x + 46, y - 8))?;
    }
    let grey = ("sans-serif", 13).into_font().color(&RGBColor(90, 90, 90));
    footer.draw_text(note, &grey, (LEFT, (LEGEND_ROW * (legend_rows + 1)) as i32))?;
    root.present()?;
    Ok(())
}

/// One ray set: M rays/s against triangles, both on log axes shared by all panels.
fn draw_panel(
    panel: &Area,
    rows: &[Row],
    rays: &str,
    series: &[(&str, u32)],
) -> Result<(), Box<dyn std::error::Error>> {
    let (tri_lo, tri_hi) = rows.iter().fold((f64::MAX, 0f64), |(lo, hi), r| {
        (lo.min(r.triangles as f64), hi.max(r.triangles as f64))
    });
    let (mrays_lo, mrays_hi) = rows.iter().fold((f64::MAX, 0f64), |(lo, hi), r| {
        (lo.min(r.rays_per_s / 1e6), hi.max(r.rays_per_s / 1e6))
    });
    let ray_count = rows
        .iter()
        .find(|r| r.rays == rays)
        .map_or(0, |r| r.ray_count);
    let mut chart = ChartBuilder::on(panel)
        .caption(
            format!("{rays}: {ray_count} rays per batch"),
            ("sans-serif", 18),
        )
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(decade_axis(tri_lo, tri_hi), decade_axis(mrays_lo, mrays_hi))?;
    chart
        .configure_mesh()
        .x_desc("scene size (triangles)")
        .y_desc("throughput (M rays/s)")
        .x_label_formatter(&short_number)
        .y_label_formatter(&short_number)
        .label_style(("sans-serif", 14))
        .draw()?;
    for (index, &(engine, threads)) in series.iter().enumerate() {
        let mut points: Vec<(f64, f64)> = rows
            .iter()
            .filter(|r| r.rays == rays && r.engine == engine && r.threads == threads)
            .map(|r| (r.triangles as f64, r.rays_per_s / 1e6))
            .collect();
        points.sort_by(|a, b| a.0.total_cmp(&b.0));
        let style = COLOURS[index % COLOURS.len()].stroke_width(2);
        chart.draw_series(LineSeries::new(points.iter().copied(), style))?;
        chart.draw_series(points.iter().map(|&p| EmptyElement::at(p) + marker(index)))?;
    }
    Ok(())
}

fn main() -> ExitCode {
    let args = Args::parse();
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    let target =
        std::env::var_os("CARGO_TARGET_DIR").map_or(manifest.join("target"), PathBuf::from);
    let csv = args.csv.unwrap_or_else(|| target.join("peers-summary.csv"));
    let svg = args
        .svg
        .unwrap_or_else(|| manifest.join("docs/peers_throughput.svg"));
    let outcome = std::fs::read_to_string(&csv)
        .map_err(|e| format!("{}: {e}", csv.display()))
        .and_then(|text| parse_rows(&text, &csv.display().to_string()))
        .map(|rows| {
            let kept: Vec<Row> = rows
                .into_iter()
                .filter(|row| row.scene.starts_with(&args.scenes))
                .collect();
            kept
        })
        .and_then(|rows| {
            if rows.is_empty() {
                return Err(format!("no scene name starts with {:?}", args.scenes));
            }
            plot(&rows, &svg, &args.note).map_err(|e| format!("{}: {e}", svg.display()))
        });
    match outcome {
        Ok(()) => {
            println!("wrote {}", svg.display());
            ExitCode::SUCCESS
        }
        Err(message) => {
            eprintln!("plot_peers: {message}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = "scene,triangles,rays,ray_count,engine,threads,median_ms,rays_per_s\n\
                        bunny,69451,camera-4096,4096,raypick-cpu,2,0.5,8192000\n";

    #[test]
    fn a_well_formed_summary_parses() {
        let rows = parse_rows(GOOD, "summary.csv").unwrap();
        assert_eq!(
            (rows.len(), rows[0].triangles, rows[0].threads),
            (1, 69451, 2)
        );
    }

    #[test]
    fn a_malformed_row_is_rejected_with_its_line() {
        let bad = format!("{GOOD}dragon,lots,camera-4096,4096,obvhs,1,0.7,5851428\n");
        let error = parse_rows(&bad, "summary.csv").unwrap_err();
        assert!(error.starts_with("summary.csv:3: "), "{error}");
    }

    #[test]
    fn a_short_row_a_repeat_and_a_wrong_header_are_rejected() {
        let short = format!("{GOOD}dragon,871306,camera-4096\n");
        assert!(parse_rows(&short, "s").unwrap_err().starts_with("s:3: "));
        let repeat = format!("{GOOD}bunny,69451,camera-4096,4096,raypick-cpu,2,0.6,6826666\n");
        assert!(parse_rows(&repeat, "s").unwrap_err().contains("line 2"));
        let renamed = GOOD.replace("rays_per_s", "rays_per_second");
        assert!(parse_rows(&renamed, "s").unwrap_err().starts_with("s:1: "));
    }
}
