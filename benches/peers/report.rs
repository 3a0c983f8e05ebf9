//! What the bench measured, as tables on stdout and as the machine-readable summary
//! `peers-summary.csv` in the target directory, one row per (scene, ray set, engine, threads)
//! throughput measurement:
//!
//! `scene,triangles,rays,ray_count,engine,threads,median_ms,rays_per_s`
//!
//! `threads` is the CPU threads the engine traced on; for `raypick-gpu` it is the threads
//! lavapipe runs on when the adapter is a software one, and 0 on a hardware GPU.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The ray sets, in the order they are measured.
pub const RAY_SETS: [&str; 3] = ["camera-4096", "camera-1m", "random-1m"];

/// One throughput measurement.
pub struct Rate {
    pub rays: &'static str,
    pub ray_count: usize,
    pub engine: &'static str,
    pub threads: usize,
    pub median_ms: f64,
}

impl Rate {
    pub fn rays_per_s(&self) -> f64 {
        self.ray_count as f64 / (self.median_ms / 1e3)
    }
}

/// Per engine and scene: build, end to end and single-ray latency.
pub struct Cost {
    pub engine: &'static str,
    /// Median build, milliseconds.
    pub build_ms: f64,
    /// Median of build + the engine's trace of the 4096 camera rays, milliseconds.
    pub end_to_end_ms: f64,
    /// raypick only: median of build + `Picker::pick` of the same rays (world frame, watertight,
    /// f64 refinement), milliseconds.
    pub end_to_end_api_ms: Option<f64>,
    pub p50_us: f64,
    pub p99_us: f64,
}

/// Everything measured on one scene.
pub struct SceneReport {
    pub name: &'static str,
    pub triangles: usize,
    pub gpu_bytes_per_triangle: f64,
    pub builds: usize,
    pub costs: Vec<Cost>,
    pub rates: Vec<Rate>,
}

impl SceneReport {
    fn rate(&self, rays: &str, engine: &str, threads: usize) -> Option<&Rate> {
        self.rates
            .iter()
            .find(|r| r.rays == rays && r.engine == engine && r.threads == threads)
    }

    /// raypick's CPU path at 2 threads on `rays`: what every ratio divides.
    fn ours(&self, rays: &str) -> Option<f64> {
        self.rate(rays, "raypick-cpu", 2).map(Rate::rays_per_s)
    }
}

/// Prints the scene's table: M rays/s per ray set with raypick-cpu (2 threads) ÷ the row in
/// brackets, then build, end-to-end and latency figures per engine.
pub fn print_scene(report: &SceneReport) {
    println!();
    println!(
        "== {}: {} triangles; raypick {:.1} GPU bytes/triangle",
        report.name, report.triangles, report.gpu_bytes_per_triangle
    );
    let mut rows = vec![{
        let mut header = vec!["engine".to_string(), "thr".to_string()];
        header.extend(RAY_SETS.iter().map(|s| format!("{s} Mray/s (ours÷)")));
        header.extend(
            [
                "build ms",
                "build+4096 ms",
                "build+pick ms",
                "1-ray p50 us",
                "1-ray p99 us",
            ]
            .map(String::from),
        );
        header
    }];
    let mut runs: Vec<(&str, usize)> = Vec::new();
    for rate in &report.rates {
        if !runs.contains(&(rate.engine, rate.threads)) {
            runs.push((rate.engine, rate.threads));
        }
    }
    for (i, &(engine, threads)) in runs.iter().enumerate() {
        let mut row = vec![engine.to_string(), threads.to_string()];
        for set in RAY_SETS {
            row.push(match report.rate(set, engine, threads) {
                Some(r) => {
                    let ratio = report.ours(set).map_or(String::new(), |ours| {
                        format!(" ({:.2}x)", ours / r.rays_per_s())
                    });
                    format!("{:.3}{ratio}", r.rays_per_s() / 1e6)
                }
                None => "-".to_string(),
            });
        }
        let first_of_engine = runs[..i].iter().all(|(e, _)| *e != engine);
        match report.costs.iter().find(|c| c.engine == engine) {
            Some(c) if first_of_engine => row.extend([
                format!("{:.1}", c.build_ms),
                format!("{:.1}", c.end_to_end_ms),
                c.end_to_end_api_ms
                    .map_or("-".to_string(), |ms| format!("{ms:.1}")),
                format!("{:.2}", c.p50_us),
                format!("{:.2}", c.p99_us),
            ]),
            _ => row.extend(["", "", "", "", ""].map(String::from)),
        }
        rows.push(row);
    }
    print_rows(&rows);
    println!(
        "(throughput: camera-4096 criterion medians, 1M sets medians of rounds that time every engine in turn; ours÷ = \
         raypick-cpu at 2 threads ÷ the row. build, build+4096 (build, then the engine's trace of \
         the scene-local rays at 2 threads) and build+pick (raypick: build, then Picker::pick of \
         the world rays: frame conversion, watertight test, f64 refinement): medians of {} runs)",
        report.builds
    );
}

fn print_rows(rows: &[Vec<String>]) {
    let columns = rows.iter().map(Vec::len).max().unwrap_or(0);
    let widths: Vec<usize> = (0..columns)
        .map(|c| {
            rows.iter()
                .map(|r| r.get(c).map_or(0, String::len))
                .max()
                .unwrap_or(0)
        })
        .collect();
    for row in rows {
        let mut line = format!("{:<w$}", row[0], w = widths[0]);
        for (c, cell) in row.iter().enumerate().skip(1) {
            let _ = write!(line, "  {cell:>w$}", w = widths[c]);
        }
        println!("{}", line.trim_end());
    }
}

/// Where the summary goes: `$CARGO_TARGET_DIR/peers-summary.csv`, else `target/` in the package.
pub fn summary_path() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("target"))
        .join("peers-summary.csv")
}

/// Writes the summary CSV (see the module comment) for every scene measured.
pub fn write_summary(path: &Path, reports: &[SceneReport]) -> std::io::Result<()> {
    let mut text =
        String::from("scene,triangles,rays,ray_count,engine,threads,median_ms,rays_per_s\n");
    for report in reports {
        for r in &report.rates {
            let _ = writeln!(
                text,
                "{},{},{},{},{},{},{:.4},{:.0}",
                report.name,
                report.triangles,
                r.rays,
                r.ray_count,
                r.engine,
                r.threads,
                r.median_ms,
                r.rays_per_s()
            );
        }
    }
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(path, text)
}
