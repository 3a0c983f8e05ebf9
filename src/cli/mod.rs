//! The command-line front end: one file per command, shared scene and query options.

pub mod bench;
pub mod los;
pub mod pick;
pub mod probe;
pub mod progress;
pub mod query_args;
pub mod render;
pub mod scene_args;
pub mod select;
pub mod serve;
pub mod soak;
pub mod verify;

use raypick::io::ray_file::load_rays;
use raypick::{Backend, BuiltScene, Error, Picker, Ray};

/// Rays answered per chunk by commands that stream their output.
pub const STREAM_CHUNK_RAYS: usize = 1 << 20;
use std::io::Write;
use std::path::Path;
use std::sync::Arc;

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

/// Runs `write` against `out` (a file) or standard output, turning I/O failures into errors
/// that name the destination.
pub fn write_output(
    out: Option<&Path>,
    write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> Result<(), Error> {
    let name = out.map_or("<stdout>".to_string(), |p| p.display().to_string());
    let io_error = |source| Error::Io {
        path: name.clone(),
        source,
    };
    match out {
        Some(path) => {
            let mut file = std::io::BufWriter::new(std::fs::File::create(path).map_err(io_error)?);
            write(&mut file)
                .and_then(|()| file.flush())
                .map_err(io_error)
        }
        None => {
            let mut stdout = std::io::BufWriter::new(std::io::stdout().lock());
            write(&mut stdout)
                .and_then(|()| stdout.flush())
                .map_err(io_error)
        }
    }
}
