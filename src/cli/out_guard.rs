//! An `--out` file that is also one of the command's inputs is refused before anything is
//! read or written: `raypick build --scene a.obj --out a.obj`, a render over its own camera
//! file or a pick over its own ray file replaced the input with the output and exited 0. The
//! inputs are every path-valued argument of the command (`--scene`, `--rays`, `--camera`, …)
//! and every file a scene description lists ([`refuse_listed`]) or a glTF file's buffers name
//! ([`refuse_gltf_buffers`]); the same file is the same
//! file however it is named (a link, `./a.obj`, another folder's `..`).

use clap::ArgMatches;
use raypick::Error;
use std::path::{Path, PathBuf};

/// The command's `--out`, when it names a file that exists (no file, or `-` for standard
/// output, can be no input).
fn existing_out(matches: &ArgMatches) -> Option<(&PathBuf, FileId)> {
    let out = matches.try_get_one::<PathBuf>("out").ok().flatten()?;
    if out.as_os_str() == "-" {
        return None;
    }
    Some((out, FileId::of(out)?))
}

/// The arguments whose `-` is standard input (`pick --rays`, `verify --rays`, `bench
/// --ray-file`).
const STDIN_ARGS: [&str; 2] = ["rays", "ray_file"];

/// Refuses `--out` when it is the same file as any other path-valued argument of `matches`
/// (for a ray file given as `-`, the file standard input reads, if it is one).
pub fn refuse_inputs(matches: &ArgMatches) -> Result<(), Error> {
    let Some((out, id)) = existing_out(matches) else {
        return Ok(());
    };
    for arg in matches.ids().filter(|a| a.as_str() != "out") {
        let Ok(Some(values)) = matches.try_get_many::<PathBuf>(arg.as_str()) else {
            continue;
        };
        for value in values {
            // `-` of a ray file is standard input: the file redirected there, if any.
            let stdin = STDIN_ARGS.contains(&arg.as_str()) && super::is_stdin(value);
            let input = if stdin {
                FileId::of_stdin()
            } else {
                FileId::of(value)
            };
            if input.as_ref() == Some(&id) {
                let flag = format!("--{}", arg.as_str().replace('_', "-"));
                let what = if stdin { ", standard input" } else { "" };
                return Err(refusal(out, &format!("{flag} {}{what}", value.display())));
            }
        }
    }
    Ok(())
}

/// Refuses `--out` when it is the same file as one of `files`, listed by the scene description
/// `description`.
pub fn refuse_listed<'a>(
    matches: &ArgMatches,
    description: &Path,
    files: impl IntoIterator<Item = &'a Path>,
) -> Result<(), Error> {
    let Some((out, id)) = existing_out(matches) else {
        return Ok(());
    };
    for file in files {
        if FileId::of(file).as_ref() == Some(&id) {
            let input = format!("{}, listed by {}", file.display(), description.display());
            return Err(refusal(out, &input));
        }
    }
    Ok(())
}

/// Refuses `--out` when it is the same file as a buffer that one of the glTF files among
/// `files` reads ([`raypick::io::gltf::buffer_files`]): `pick --scene m.gltf --out m.bin`
/// replaced the mesh's data with the answers.
pub fn refuse_gltf_buffers<'a>(
    matches: &ArgMatches,
    files: impl IntoIterator<Item = &'a Path>,
) -> Result<(), Error> {
    let Some((out, id)) = existing_out(matches) else {
        return Ok(());
    };
    for file in files
        .into_iter()
        .filter(|f| raypick::io::scene_files::is_gltf(f))
    {
        for buffer in raypick::io::gltf::buffer_files(file) {
            if FileId::of(&buffer).as_ref() == Some(&id) {
                let input = format!("{}, a buffer of {}", buffer.display(), file.display());
                return Err(refusal(out, &input));
            }
        }
    }
    Ok(())
}

fn refusal(out: &Path, input: &str) -> Error {
    Error::Invalid(format!(
        "--out {} is also an input ({input}); writing it would replace the input: name \
         another file",
        out.display()
    ))
}

/// What makes two names one file: its device and inode on Unix, its canonical path elsewhere.
#[derive(PartialEq)]
struct FileId(#[cfg(unix)] (u64, u64), #[cfg(not(unix))] PathBuf);

impl FileId {
    /// The file on standard input (a pipe or a terminal is no file an `--out` can name).
    fn of_stdin() -> Option<Self> {
        #[cfg(unix)]
        {
            use std::os::fd::AsFd;
            use std::os::unix::fs::MetadataExt;
            let fd = std::io::stdin().as_fd().try_clone_to_owned().ok()?;
            let meta = std::fs::File::from(fd).metadata().ok()?;
            Some(FileId((meta.dev(), meta.ino())))
        }
        #[cfg(not(unix))]
        {
            None
        }
    }

    fn of(path: &Path) -> Option<Self> {
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            let meta = std::fs::metadata(path).ok()?;
            Some(FileId((meta.dev(), meta.ino())))
        }
        #[cfg(not(unix))]
        {
            Some(FileId(std::fs::canonicalize(path).ok()?))
        }
    }
}
