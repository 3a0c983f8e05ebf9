//! Writing a `.rpk` file: a built scene's sections, each checksummed, behind the header, written
//! to a file beside the target and renamed into place.

use super::records::{ObjectRecord, Out, SectionHeader, Summary, encode_block};
use super::{
    ALIGN, HEADER_BYTES, Kind, SECTION_HEADER_BYTES, SECTIONS, VERSION, payload_start, records,
};
use crate::bvh::Bvh;
use crate::engine::WideBvh;
use crate::error::{Error, Result};
use crate::picker::BuiltScene;
use crate::scene::Scene;
use rayon::prelude::*;
use std::borrow::Cow;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Writes `built` to `path` (see [`super::save`]): an instanced scene as
/// [`super::instanced`] lays it out, any other as the eleven sections.
pub fn save(built: &BuiltScene, path: &Path) -> Result<()> {
    refuse_big_endian()?;
    let (kinds, payloads) = match built.instances() {
        Some(instances) => super::instanced::sections(instances)?,
        None => (
            SECTIONS.to_vec(),
            scene_sections(
                &built.scene,
                &built.bvh,
                &built.triangle_masks,
                built.wide()?,
            )?,
        ),
    };
    // The file is renamed into place: over a device, a pipe or a directory that would replace
    // the node itself (`build --out /dev/full` made /dev/full a regular file, run as root).
    if let Ok(meta) = std::fs::metadata(path)
        && !meta.is_file()
    {
        // A file that cannot be written, as the system would say it (Python: OSError, or
        // IsADirectoryError), with what to do instead.
        let kind = if meta.is_dir() {
            std::io::ErrorKind::IsADirectory
        } else {
            std::io::ErrorKind::Other
        };
        return Err(Error::Io {
            path: path.display().to_string(),
            source: std::io::Error::new(
                kind,
                "not a regular file; a built scene is saved to a new file or over a regular one",
            ),
        });
    }
    let temporary = temporary_path(path);
    let result = std::fs::File::create(&temporary)
        .and_then(|file| {
            let mut out = std::io::BufWriter::with_capacity(1 << 20, file);
            write_to(&mut out, &kinds, &payloads)?;
            out.into_inner().map_err(|e| e.into_error())?.sync_all()
        })
        .and_then(|()| std::fs::rename(&temporary, path));
    result.map_err(|source| {
        let _ = std::fs::remove_file(&temporary);
        Error::Io {
            path: path.display().to_string(),
            source,
        }
    })
}

/// A scene with its trees as a whole `.rpk` file's bytes, in memory (an instanced scene's
/// meshes are saved so, each inside a section of the outer file).
pub(crate) fn scene_bytes(
    scene: &Scene,
    bvh: &Bvh,
    triangle_masks: &[u32],
    wide: &WideBvh,
) -> Result<Vec<u8>> {
    let payloads = scene_sections(scene, bvh, triangle_masks, wide)?;
    let mut out = Vec::new();
    write_to(&mut out, &SECTIONS, &payloads).expect("writing to memory");
    Ok(out)
}

/// The eleven sections of a scene with its trees, in the order of `SECTIONS`.
fn scene_sections<'a>(
    scene: &'a Scene,
    bvh: &'a Bvh,
    triangle_masks: &'a [u32],
    wide: &'a WideBvh,
) -> Result<Vec<Cow<'a, [u8]>>> {
    let mut objects = Out::default();
    let mut names = Vec::new();
    for o in scene.objects() {
        let name_length = u32::try_from(o.name.len())
            .map_err(|_| Error::Invalid(format!("object {}'s name is too long to save", o.id)))?;
        ObjectRecord {
            id: o.id,
            first_triangle: o.first_triangle,
            triangle_count: o.triangle_count,
            first_vertex: o.first_vertex,
            mask: o.mask,
            has_grid: u32::from(o.grid.is_some()),
            columns: o.grid.map_or(0, |g| g.columns),
            rows: o.grid.map_or(0, |g| g.rows),
            name_length,
            flags: u32::from(o.mirrored),
        }
        .encode(&mut objects);
        names.extend_from_slice(o.name.as_bytes());
    }
    let mut blocks = Out::default();
    for b in &bvh.blocks {
        encode_block(b, &mut blocks);
    }
    let summary = Summary {
        vertices: scene.vertex_count() as u64,
        triangles: scene.triangle_count() as u64,
        objects: scene.objects().len() as u64,
        name_bytes: names.len() as u64,
        nodes: bvh.nodes.len() as u64,
        leaf_triangles: bvh.triangles.len() as u64,
        blocks: bvh.blocks.len() as u64,
        wide_nodes: wide.nodes.len() as u64,
        wide_depth: wide.depth as u64,
        masks: triangle_masks.len() as u64,
        scene_origin: scene.origin(),
        tree_origin: bvh.origin,
    };
    Ok(vec![
        Cow::Owned(summary.encode()),
        Cow::Borrowed(bytemuck::cast_slice(scene.positions())),
        Cow::Borrowed(bytemuck::cast_slice(scene.triangles())),
        Cow::Owned(objects.0),
        Cow::Owned(names),
        Cow::Borrowed(bytemuck::cast_slice(&bvh.nodes)),
        Cow::Borrowed(bytemuck::cast_slice(&bvh.triangles)),
        Cow::Borrowed(bytemuck::cast_slice(&bvh.triangle_ids)),
        Cow::Borrowed(bytemuck::cast_slice(triangle_masks)),
        Cow::Owned(blocks.0),
        Cow::Borrowed(bytemuck::cast_slice(wide.nodes.as_slice())),
    ])
}

/// The files are little-endian and their arrays are copied as they lie in memory.
pub(crate) fn refuse_big_endian() -> Result<()> {
    if cfg!(target_endian = "big") {
        return Err(Error::Invalid(
            ".rpk files are little-endian, and this build of raypick runs on a big-endian machine"
                .into(),
        ));
    }
    Ok(())
}

/// `.<name>.<pid>-<k>.tmp` beside `path`, `k` counting this process's saves (so saves from
/// several threads never share one).
fn temporary_path(path: &Path) -> PathBuf {
    static SAVES: AtomicU64 = AtomicU64::new(0);
    let name = path
        .file_name()
        .map_or_else(|| "scene.rpk".into(), |n| n.to_string_lossy());
    let k = SAVES.fetch_add(1, Ordering::Relaxed);
    path.with_file_name(format!(".{name}.{}-{k}.tmp", std::process::id()))
}

/// Writes the header and the sections `kinds` with their `payloads`, each checksummed, to
/// `out`.
fn write_to(
    out: &mut impl Write,
    kinds: &[Kind],
    payloads: &[Cow<'_, [u8]>],
) -> std::io::Result<()> {
    let crcs: Vec<u32> = payloads.par_iter().map(|p| crc32fast::hash(p)).collect();
    let file_length = payloads.iter().fold(HEADER_BYTES, |at, p| {
        payload_start(at) + p.len().next_multiple_of(ALIGN)
    }) as u64;
    let header = records::Header {
        version: VERSION,
        sections: kinds.len() as u32,
        file_length,
    };
    out.write_all(&header.encode())?;
    let mut at = HEADER_BYTES;
    for ((kind, payload), &crc) in kinds.iter().zip(payloads).zip(&crcs) {
        let section = SectionHeader {
            tag: kind.tag,
            crc,
            length: payload.len() as u64,
        };
        let start = payload_start(at);
        out.write_all(&[0; ALIGN][..start - SECTION_HEADER_BYTES - at])?;
        out.write_all(&section.encode())?;
        out.write_all(payload)?;
        let padding = payload.len().next_multiple_of(ALIGN) - payload.len();
        out.write_all(&[0; ALIGN][..padding])?;
        at = start + payload.len() + padding;
    }
    Ok(())
}

/// Recomputes the header's and every section's checksum over `bytes` as they lie, as far as the
/// section headers can be followed: for tests and fuzzing, which change files on purpose and
/// want the structural checks, not the checksums, to judge them.
pub fn reseal(bytes: &mut [u8]) {
    if bytes.len() >= HEADER_BYTES {
        let crc = crc32fast::hash(&bytes[..HEADER_BYTES - 4]);
        bytes[HEADER_BYTES - 4..HEADER_BYTES].copy_from_slice(&crc.to_le_bytes());
    }
    let mut at = HEADER_BYTES;
    loop {
        let start = payload_start(at);
        let header_at = start - SECTION_HEADER_BYTES;
        let Some(header) = bytes.get(header_at..start) else {
            return;
        };
        let header = SectionHeader::decode(header.try_into().expect("16 bytes"));
        let Some(end) = usize::try_from(header.length)
            .ok()
            .and_then(|n| start.checked_add(n))
            .filter(|&end| end <= bytes.len())
        else {
            return;
        };
        let crc = crc32fast::hash(&bytes[start..end]);
        bytes[header_at + 4..header_at + 8].copy_from_slice(&crc.to_le_bytes());
        let Some(next) = end.checked_next_multiple_of(ALIGN) else {
            return;
        };
        at = next;
    }
}
