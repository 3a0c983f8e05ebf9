//! Reading scenes and rays from files, and writing hits out.
//!
//! # Which files are read
//!
//! Scene files (`--scene`, the files of a scene description, and the buffers of a glTF file) must
//! be regular files: a FIFO, a device, a socket or a directory is refused by its metadata before
//! it is opened (opening a FIFO for reading blocks until a writer comes, and a device such as
//! `/dev/zero` never ends). Symbolic links are followed to the file they name.
//!
//! A path written *inside* a file — a glTF buffer `uri`, a `file` of a scene description — must
//! stay inside the folder of the file that names it ([`resolve_inside`]): it must be relative,
//! must not contain `..`, and must resolve, symbolic links followed, to a regular file inside
//! that folder. So a scene file can only make raypick read files next to it or below it.

pub mod csv_number;
pub mod gltf;
pub(crate) mod mapped;
pub mod obj;
pub mod output;
pub mod pixel_file;
pub mod ply;
pub mod ray_file;
pub mod scene_files;
pub mod stl;
pub mod warnings;

use std::fs::{File, FileType, Metadata};
use std::io::Read;
use std::path::{Component, Path, PathBuf};

use crate::error::Error;

/// The ASCII bytes `str::split_whitespace` splits text at (an ASCII character is white space
/// exactly when it is one of these six): what the readers of ASCII text split tokens at.
#[inline(always)]
pub(crate) fn is_space(b: u8) -> bool {
    matches!(b, b' ' | b'\n' | b'\t' | b'\r' | 0x0b | 0x0c)
}

/// What kind of file `file_type` is, for "not a regular file" messages.
fn kind_of(file_type: FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if file_type.is_fifo() {
            return "a FIFO (named pipe)";
        }
        if file_type.is_char_device() {
            return "a character device";
        }
        if file_type.is_block_device() {
            return "a block device";
        }
        if file_type.is_socket() {
            return "a socket";
        }
    }
    if file_type.is_dir() {
        "a directory"
    } else {
        "not a regular file"
    }
}

/// The I/O error "is X, not a regular file" for a file of type `file_type`.
fn not_regular(file_type: FileType) -> std::io::Error {
    std::io::Error::new(
        std::io::ErrorKind::InvalidInput,
        format!(
            "is {}, not a regular file; only regular files are read",
            kind_of(file_type)
        ),
    )
}

/// The metadata of `path` (symbolic links followed) when it is a regular file; otherwise an
/// [`Error::Io`] naming `path`. Looks before opening, so a FIFO never blocks.
pub fn regular_file(path: &Path) -> Result<Metadata, Error> {
    let name = || path.display().to_string();
    let metadata = std::fs::metadata(path).map_err(|source| Error::Io {
        path: name(),
        source,
    })?;
    if metadata.is_file() {
        Ok(metadata)
    } else {
        Err(Error::Io {
            path: name(),
            source: not_regular(metadata.file_type()),
        })
    }
}

/// Opens `path` for reading when it is a regular file ([`regular_file`]); returns the file and
/// its length in bytes.
pub fn open_regular(path: &Path) -> Result<(File, u64), Error> {
    regular_file(path)?;
    let io = |source| Error::Io {
        path: path.display().to_string(),
        source,
    };
    let file = File::open(path).map_err(io)?;
    // Checked again on the open handle, in case the path changed in between.
    let metadata = file.metadata().map_err(io)?;
    if !metadata.is_file() {
        return Err(io(not_regular(metadata.file_type())));
    }
    Ok((file, metadata.len()))
}

/// Reads the whole regular file at `path`, after checking that its length fits the memory
/// budget ([`crate::budget`]).
pub fn read_regular(path: &Path) -> Result<Vec<u8>, Error> {
    let (file, length) = open_regular(path)?;
    crate::budget::check(&format!("reading {}", path.display()), length, 1)?;
    read_opened(path, file, length)
}

/// Reads the first `length` bytes of `file` (opened from `path` by [`open_regular`], its
/// length checked by the caller), into a buffer of that size from the start.
pub(crate) fn read_opened(path: &Path, file: File, length: u64) -> Result<Vec<u8>, Error> {
    let io = |source| Error::Io {
        path: path.display().to_string(),
        source,
    };
    let mut bytes = Vec::new();
    bytes
        .try_reserve_exact(usize::try_from(length).unwrap_or(usize::MAX))
        .map_err(|_| io(std::io::Error::from(std::io::ErrorKind::OutOfMemory)))?;
    // The length may change while reading; `take` keeps the read within what was checked.
    file.take(length).read_to_end(&mut bytes).map_err(io)?;
    Ok(bytes)
}

/// Why [`resolve_inside`] refused a path.
#[derive(Debug)]
pub enum Refusal {
    /// The path is absolute (or has a drive prefix).
    Absolute,
    /// The path has a `..` component.
    ParentDir,
    /// The path, symbolic links followed, leads to `.0`, outside the folder.
    Outside(PathBuf),
    /// The path names something that is not a regular file (the I/O error says what).
    NotRegular(std::io::Error),
    /// The path (joined to the folder) could not be resolved: usually a missing file.
    Io(std::io::Error),
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Refusal::Absolute => write!(f, "an absolute path is not allowed"),
            Refusal::ParentDir => write!(f, "a path with '..' is not allowed"),
            Refusal::Outside(target) => write!(
                f,
                "it leads (through a symbolic link) to {}, outside the folder",
                target.display()
            ),
            Refusal::NotRegular(e) | Refusal::Io(e) => write!(f, "{e}"),
        }
    }
}

/// Resolves `relative`, a path written inside a file whose folder is `folder`, to the file it
/// names, refusing anything that would read outside `folder`: absolute paths, `..` components,
/// symbolic links leading out of the folder, and anything but a regular file.
///
/// Returns `folder.join(relative)` (not canonicalised, so messages and object names show the
/// path as written).
pub fn resolve_inside(folder: &Path, relative: &Path) -> Result<PathBuf, Refusal> {
    for component in relative.components() {
        match component {
            Component::Normal(_) | Component::CurDir => {}
            Component::ParentDir => return Err(Refusal::ParentDir),
            Component::RootDir | Component::Prefix(_) => return Err(Refusal::Absolute),
        }
    }
    let joined = folder.join(relative);
    let base = if folder.as_os_str().is_empty() {
        Path::new(".")
    } else {
        folder
    };
    let base = std::fs::canonicalize(base).map_err(Refusal::Io)?;
    let target = std::fs::canonicalize(&joined).map_err(Refusal::Io)?;
    if !target.starts_with(&base) {
        return Err(Refusal::Outside(target));
    }
    let metadata = std::fs::metadata(&target).map_err(Refusal::Io)?;
    if !metadata.is_file() {
        return Err(Refusal::NotRegular(not_regular(metadata.file_type())));
    }
    Ok(joined)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("raypick-io-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("sub")).unwrap();
        dir
    }

    #[test]
    fn paths_inside_a_folder_resolve_and_escapes_are_refused() {
        let dir = scratch("resolve");
        std::fs::write(dir.join("a.bin"), b"x").unwrap();
        std::fs::write(dir.join("sub/b.bin"), b"y").unwrap();
        assert_eq!(
            resolve_inside(&dir, Path::new("a.bin")).unwrap(),
            dir.join("a.bin")
        );
        assert!(resolve_inside(&dir, Path::new("./sub/b.bin")).is_ok());
        assert!(matches!(
            resolve_inside(&dir.join("sub"), Path::new("../a.bin")),
            Err(Refusal::ParentDir)
        ));
        assert!(matches!(
            resolve_inside(&dir, Path::new("/etc/passwd")),
            Err(Refusal::Absolute)
        ));
        assert!(matches!(
            resolve_inside(&dir, Path::new("sub")),
            Err(Refusal::NotRegular(_))
        ));
        assert!(matches!(
            resolve_inside(&dir, Path::new("missing.bin")),
            Err(Refusal::Io(_))
        ));
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink("/etc/hostname", dir.join("out.bin")).unwrap();
            assert!(matches!(
                resolve_inside(&dir, Path::new("out.bin")),
                Err(Refusal::Outside(_))
            ));
            std::os::unix::fs::symlink(dir.join("a.bin"), dir.join("sub/in.bin")).unwrap();
            assert!(resolve_inside(&dir, Path::new("sub/in.bin")).is_ok());
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn only_regular_files_are_opened() {
        let dir = scratch("regular");
        let e = open_regular(&dir).unwrap_err().to_string();
        assert!(e.contains("is a directory, not a regular file"), "{e}");
        #[cfg(unix)]
        {
            let e = read_regular(Path::new("/dev/zero"))
                .unwrap_err()
                .to_string();
            assert_eq!(
                e,
                "/dev/zero: is a character device, not a regular file; only regular files are read"
            );
        }
        std::fs::write(dir.join("f.txt"), b"hello").unwrap();
        assert_eq!(read_regular(&dir.join("f.txt")).unwrap(), b"hello");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
