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
pub mod swallowed;
pub mod threads;
pub mod verify;

use raypick::io::output::Format;
use raypick::io::ray_file::{RayLine, RayReader, STDIN_NAME, load_rays_as, read_rays_as};
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

/// Whether a ray file argument is `-`: standard input.
pub fn is_stdin(path: &Path) -> bool {
    path.as_os_str() == "-"
}

/// What messages call the ray file `path`: its path, or [`STDIN_NAME`] for `-`.
pub fn ray_file_name(path: &Path) -> String {
    if is_stdin(path) {
        STDIN_NAME.to_owned()
    } else {
        path.display().to_string()
    }
}

/// Reads a ray file (`-`: standard input); rays get `tmin`, `mask`, and `tmax` unless the line
/// gives one.
pub fn read_rays(path: &Path, tmin: f64, tmax: f64, mask: u32) -> Result<Vec<Ray>, Error> {
    let make = |r: &RayLine| {
        Ray::new(r.origin, r.dir)
            .with_range(tmin, r.tmax.unwrap_or(tmax))
            .with_mask(mask)
    };
    if is_stdin(path) {
        read_rays_as(RayReader::stdin(), make)
    } else {
        load_rays_as(path, make)
    }
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

/// How errors name `out`: its path, or `<stdout>` (no `out`, or `-`).
pub fn output_name(out: Option<&Path>) -> String {
    match out {
        Some(path) if path.as_os_str() != "-" => path.display().to_string(),
        _ => "<stdout>".to_string(),
    }
}

/// Runs `write` against `out` (a file) or standard output (no `out`, or `-`), turning I/O
/// failures into errors that name the destination. A new or regular file is written as a new
/// file beside it first, so a command that fails part way (a pick whose streamed ray file turns
/// out bad at line 270,001) leaves no partial output and the file that was there as it was;
/// once `write` succeeds the new file is renamed over the old one, or, where a rename would
/// change more than its contents (another owner's file, one with other hard links, a folder
/// that refuses the rename), copied into it. An existing file must be one the command may write
/// (a read-only one is refused, as a write in place refuses it). Other files (`/dev/null`, a
/// FIFO, a link) are written where they are.
pub fn write_output(
    out: Option<&Path>,
    write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> Result<(), Error> {
    let name = output_name(out);
    let out = out.filter(|p| p.as_os_str() != "-");
    let io_error = |source| Error::Io {
        path: name.clone(),
        source,
    };
    let Some(path) = out else {
        let mut stdout = std::io::BufWriter::new(std::io::stdout().lock());
        return write(&mut stdout)
            .and_then(|()| stdout.flush())
            .map_err(io_error);
    };
    let existing = std::fs::symlink_metadata(path);
    let absent = matches!(&existing, Err(e) if e.kind() == std::io::ErrorKind::NotFound);
    let regular = matches!(&existing, Ok(meta) if meta.file_type().is_file());
    // An existing file opened for writing, not cut: refused where a write in place would be.
    let old = if regular {
        Some(
            std::fs::OpenOptions::new()
                .write(true)
                .open(path)
                .map_err(io_error)?,
        )
    } else {
        None
    };
    let file_name = path.file_name().unwrap_or_default().to_string_lossy();
    let temporary = path.with_file_name(format!(
        ".{file_name}.raypick-{}.partial",
        std::process::id()
    ));
    // Written where it is: not a regular file, or a folder that takes no new file.
    let created = (absent || regular)
        .then(|| std::fs::File::create(&temporary).ok())
        .flatten();
    let Some(created) = created else {
        let file = match old {
            Some(file) => file.set_len(0).map(|()| file),
            None => std::fs::File::create(path),
        }
        .map_err(io_error)?;
        let mut file = std::io::BufWriter::new(file);
        return write(&mut file)
            .and_then(|()| file.flush())
            .map_err(io_error);
    };
    let written = (|| {
        let mut file = std::io::BufWriter::new(created);
        write(&mut file)?;
        file.flush()?;
        drop(file);
        let Some(mut old) = old else {
            return std::fs::rename(&temporary, path);
        };
        // Renamed over the old file where only its contents change: the writer's own file, of
        // one link, its permissions kept.
        #[cfg(unix)]
        let renamable = {
            use std::os::unix::fs::MetadataExt;
            // SAFETY: geteuid has no preconditions and cannot fail.
            let me = unsafe { libc::geteuid() };
            existing
                .as_ref()
                .is_ok_and(|m| m.nlink() == 1 && m.uid() == me)
        };
        #[cfg(not(unix))]
        let renamable = true;
        if renamable {
            if let Ok(meta) = &existing {
                let _ = std::fs::set_permissions(&temporary, meta.permissions());
            }
            if std::fs::rename(&temporary, path).is_ok() {
                return Ok(());
            }
        }
        // Else copied into it.
        old.set_len(0)?;
        std::io::copy(&mut std::fs::File::open(&temporary)?, &mut old)?;
        std::fs::remove_file(&temporary)
    })();
    if written.is_err() {
        let _ = std::fs::remove_file(&temporary);
    }
    written.map_err(io_error)
}
