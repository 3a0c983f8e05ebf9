//! The command-line front end: one file per command, shared scene and query options.

/// `println!` that hands a failed write back as an error naming standard output (a closed pipe:
/// `raypick verify | head -1`), for `?`, instead of panicking as `println!` does.
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        writeln!(std::io::stdout().lock(), $($arg)*).map_err(|source| raypick::Error::Io {
            path: "<stdout>".to_string(),
            source,
        })
    }};
}

pub mod bench;
pub mod build;
pub mod camera_args;
pub mod choice;
pub mod example;
pub mod los;
pub mod mapped_file_guard;
pub mod out_guard;
pub mod pick;
pub mod probe;
pub mod progress;
pub mod query_args;
pub mod render;
pub mod scene_args;
pub mod select;
pub mod serve;
pub mod soak;
pub mod threads;
pub mod verify;

use raypick::io::output::Format;
use raypick::io::ray_file::load_rays;
use raypick::{Backend, BuiltScene, Error, Picker, Query, Ray};
use std::io::Write;
use std::path::Path;
use std::sync::Arc;

/// The most rays answered per chunk by commands that stream their output.
pub const STREAM_CHUNK_RAYS: usize = 1 << 20;

/// Rays per chunk for `query` in commands that stream: at most [`STREAM_CHUNK_RAYS`], and few
/// enough that one chunk's answers (in all-hits mode, `max_hits` list slots per ray) take at
/// most half the memory budget (the rest is for the scene and the rays).
pub fn stream_chunk_rays(query: &Query) -> usize {
    let fit = raypick::budget::limit() / 2 / query.bytes_per_ray().max(1);
    usize::try_from(fit)
        .unwrap_or(usize::MAX)
        .clamp(1, STREAM_CHUNK_RAYS)
}

/// Checks that `count` rays of `query` (answered in one batch) fit the memory budget; `what`
/// names them, e.g. "the render's 10000000000 pixels".
pub fn check_rays(what: &str, count: u64, query: &Query) -> Result<(), Error> {
    raypick::budget::check(what, count, query.bytes_per_ray())
}

/// Prints a command-line parsing error (or help) and exits, with every long value in it cut
/// short: a bad argument is quoted with at most 60 characters.
pub fn exit_with_clap_error(error: clap::Error) -> ! {
    use clap::error::ContextValue;
    if !error.use_stderr() {
        error.exit();
    }
    let mut text = error.render().to_string();
    for (_, value) in error.context() {
        let values = match value {
            ContextValue::String(v) => vec![v.clone()],
            ContextValue::Strings(v) => v.clone(),
            _ => Vec::new(),
        };
        for v in values {
            if v.chars().nth(60).is_some() {
                text = text.replace(&v, &raypick::budget::quote(&v));
            }
        }
    }
    eprint!("{}", raypick::error::shorten_tokens(&text, 4000));
    std::process::exit(error.exit_code());
}

/// A picker for `backend`. The automatic backend prints on standard error when it falls back to
/// the CPU path.
pub fn make_picker(backend: Backend, built: Arc<BuiltScene>) -> Result<Box<dyn Picker>, Error> {
    let mut picker = raypick::make_picker(backend, built)?;
    show_notes(picker.as_mut());
    Ok(picker)
}

/// Prints the picker's fallback notes on standard error.
pub fn show_notes(picker: &mut dyn Picker) {
    for note in picker.take_notes() {
        eprintln!("note: {note}");
    }
}

/// Reads a ray file; rays get `tmin`, `mask`, and `tmax` unless the line gives one.
pub fn read_rays(path: &Path, tmin: f64, tmax: f64, mask: u32) -> Result<Vec<Ray>, Error> {
    Ok(load_rays(path)?
        .into_iter()
        .map(|r| {
            Ray::new(r.origin, r.dir)
                .with_range(tmin, r.tmax.unwrap_or(tmax))
                .with_mask(mask)
        })
        .collect())
}

/// Whether `path`'s extension is `extension` (ASCII case ignored).
fn has_extension(path: &Path, extension: &str) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case(extension))
}

/// The output format: `--format` when given, else the one `--out`'s extension names (`.json`:
/// JSON), else CSV.
pub fn output_format(format: Option<Format>, out: Option<&Path>) -> Format {
    format.unwrap_or(match out {
        Some(path) if has_extension(path, "json") => Format::Json,
        _ => Format::Csv,
    })
}

/// Refuses an `--out` file named `.json` for `command`, which writes CSV only (rather than
/// writing CSV into a file named as JSON).
pub fn csv_only(command: &str, out: Option<&Path>) -> Result<(), Error> {
    no_json_out(command, "CSV only", ".csv", out)
}

/// Refuses an `--out` file named `.json` for `command`, which writes `writes` ("CSV or PNG");
/// the sentence asks for a name ending in `name_it`.
pub fn no_json_out(
    command: &str,
    writes: &str,
    name_it: &str,
    out: Option<&Path>,
) -> Result<(), Error> {
    match out {
        Some(path) if has_extension(path, "json") => Err(Error::Invalid(format!(
            "--out {} names a JSON file, but {command} writes {writes}; name it {name_it}",
            path.display()
        ))),
        _ => Ok(()),
    }
}

/// Runs `write` against `out` (a file) or standard output (no `out`, or `-`), turning I/O
/// failures into errors that name the destination. A new or regular file is written as a new
/// file beside it and renamed over it once `write` succeeds, so a command that fails part way
/// (a pick whose streamed ray file turns out bad at line 270,001) leaves no partial output and
/// the file that was there as it was; other files (`/dev/null`, a FIFO, a link) are written
/// where they are.
pub fn write_output(
    out: Option<&Path>,
    write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> Result<(), Error> {
    let out = out.filter(|p| p.as_os_str() != "-");
    let name = out.map_or("<stdout>".to_string(), |p| p.display().to_string());
    let io_error = |source| Error::Io {
        path: name.clone(),
        source,
    };
    match out {
        Some(path) => {
            let file_name = path.file_name().unwrap_or_default().to_string_lossy();
            let temporary = path.with_file_name(format!(
                ".{file_name}.raypick-{}.partial",
                std::process::id()
            ));
            let replaced = match std::fs::symlink_metadata(path) {
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => true,
                Ok(meta) => meta.file_type().is_file(),
                Err(_) => false,
            };
            // A folder that takes no new file (a writable file in a read-only folder): written
            // where it is.
            let created = replaced
                .then(|| std::fs::File::create(&temporary).ok())
                .flatten();
            let Some(created) = created else {
                let mut file =
                    std::io::BufWriter::new(std::fs::File::create(path).map_err(io_error)?);
                return write(&mut file)
                    .and_then(|()| file.flush())
                    .map_err(io_error);
            };
            // The new file's errors name `--out`: it is where the output goes.
            let written = (|| {
                if let Ok(meta) = std::fs::metadata(path) {
                    // The replaced file's permissions kept.
                    let _ = created.set_permissions(meta.permissions());
                }
                let mut file = std::io::BufWriter::new(created);
                write(&mut file)?;
                file.flush()?;
                drop(file);
                std::fs::rename(&temporary, path)
            })();
            if written.is_err() {
                let _ = std::fs::remove_file(&temporary);
            }
            written.map_err(io_error)
        }
        None => {
            let mut stdout = std::io::BufWriter::new(std::io::stdout().lock());
            write(&mut stdout)
                .and_then(|()| stdout.flush())
                .map_err(io_error)
        }
    }
}
