//! An instanced scene in a `.rpk` file ([`crate::BuiltScene::instanced`]): the instances, and
//! each mesh once, as a whole saved scene of its own. Loading builds the top tree over the
//! instances again (milliseconds for 10,000; `benches/instances.rs`) and nothing else: each
//! mesh's kernel tree and CPU engine tree are read as saved.
//!
//! The same header (magic, version 3) and section framing as any `.rpk`; the sections, in order:
//!
//! | kind | what | element |
//! |---|---|---|
//! | `INST` | per instance: its mesh, its layer mask, its name's length in bytes, flags (zero) (u32 each), then its transform, 3 × 4 row-major f64 | 112 |
//! | `INAM` | the instances' names, UTF-8, one after another | 1 |
//! | `MESH` | one per mesh, in mesh order: a whole `.rpk` file of one object (the eleven sections), as [`super::save`] writes it | 1 |
//!
//! A file whose first section is `INST` is read as one; everything a plain file's mesh sections
//! are checked for is checked in each `MESH`, and each instance as
//! [`crate::instance::Instances::assemble`] checks it (a known mesh, a finite, invertible
//! transform).

use super::read::{self, problem};
use super::{ALIGN, HEADER_BYTES, Kind, SECTION_HEADER_BYTES, payload_start};
use crate::error::{Error, Result};
use crate::instance::{Instance, Instances, MeshTree};
use crate::picker::BuiltScene;
use std::borrow::Cow;
use std::path::Path;
use std::sync::Arc;

/// The instances.
pub const INST: Kind = Kind {
    tag: *b"INST",
    element: INSTANCE_BYTES,
    what: "instances",
};
/// The instances' names.
pub const INAM: Kind = Kind {
    tag: *b"INAM",
    element: 1,
    what: "instance names",
};
/// One mesh, a saved scene of its own.
pub const MESH: Kind = Kind {
    tag: *b"MESH",
    element: 1,
    what: "a mesh's saved scene",
};

/// Bytes of one `INST` record.
pub const INSTANCE_BYTES: usize = 16 + 96;

/// Whether `bytes` (a whole file, or its start) holds an instanced scene: its first section is
/// `INST`. Says nothing of the rest, which loading checks.
pub fn is_instanced(bytes: &[u8]) -> bool {
    let start = payload_start(HEADER_BYTES);
    bytes
        .get(start - SECTION_HEADER_BYTES..start - SECTION_HEADER_BYTES + 4)
        .is_some_and(|tag| tag == INST.tag)
}

/// Sections' kinds and payloads, in file order.
pub(crate) type Sections = (Vec<Kind>, Vec<Cow<'static, [u8]>>);

/// The sections of `instances`, in file order.
pub(crate) fn sections(instances: &Instances) -> Result<Sections> {
    let mut records = Vec::with_capacity(instances.instances().len() * INSTANCE_BYTES);
    let mut names = Vec::new();
    for (k, i) in instances.instances().iter().enumerate() {
        let name_length = u32::try_from(i.name.len())
            .map_err(|_| Error::Invalid(format!("instance {k}'s name is too long to save")))?;
        for word in [i.mesh, i.mask, name_length, 0] {
            records.extend_from_slice(&word.to_le_bytes());
        }
        for x in i.transform.iter().flatten() {
            records.extend_from_slice(&x.to_le_bytes());
        }
        names.extend_from_slice(i.name.as_bytes());
    }
    let mut kinds = vec![INST, INAM];
    let mut payloads = vec![Cow::Owned(records), Cow::Owned(names)];
    for mesh in instances.meshes() {
        let masks = crate::picker::masks_of(&mesh.scene, &mesh.bvh);
        payloads.push(Cow::Owned(super::write::scene_bytes(
            &mesh.scene,
            &mesh.bvh,
            &masks,
            mesh.wide()?,
        )?));
        kinds.push(MESH);
    }
    Ok((kinds, payloads))
}

/// Reads the instanced scene in `bytes` (the whole file at `path`, which names it in
/// messages).
pub(crate) fn decode(path: &Path, bytes: &[u8]) -> Result<BuiltScene> {
    let corrupted = |why: String| problem(path, format!("the file is corrupted: {why}"));
    let header = read::header(path, bytes)?;
    let sections = header.sections as usize;
    // Each section takes at least one 64-byte line, which bounds the table by the file.
    if sections < 3 || sections > bytes.len() / ALIGN {
        return Err(corrupted(format!(
            "its header lists {} sections, but an instanced scene has the instances, their \
             names and one to {} meshes",
            header.sections,
            (bytes.len() / ALIGN).saturating_sub(2)
        )));
    }
    let mut kinds = vec![INST, INAM];
    kinds.resize(sections, MESH);
    let table = read::section_table(path, bytes, &kinds)?;
    let payload = |k: usize| {
        read::checked(
            path,
            kinds[k],
            &bytes[table[k].clone()],
            read::table_crc(bytes, &table, k),
        )
    };
    let (records, names) = (payload(0)?, payload(1)?);
    if records.len() % INSTANCE_BYTES != 0 {
        return Err(corrupted(format!(
            "section {} holds {} bytes, not a whole number of {INSTANCE_BYTES}-byte records",
            read::name(INST),
            records.len()
        )));
    }
    let mut instances = Vec::with_capacity(records.len() / INSTANCE_BYTES);
    let mut at = 0usize;
    for (k, r) in records.chunks_exact(INSTANCE_BYTES).enumerate() {
        let word = |i: usize| u32::from_le_bytes(r[4 * i..4 * i + 4].try_into().expect("4"));
        let (mesh, mask, length, flags) = (word(0), word(1), word(2) as usize, word(3));
        if flags != 0 {
            return Err(corrupted(format!(
                "instance {k}'s flags are {flags}, not 0"
            )));
        }
        let Some(name) = at.checked_add(length).and_then(|end| names.get(at..end)) else {
            return Err(corrupted(format!(
                "instance {k}'s name runs past the end of section {}",
                read::name(INAM)
            )));
        };
        let Ok(name) = std::str::from_utf8(name) else {
            return Err(corrupted(format!("instance {k}'s name is not UTF-8")));
        };
        at += length;
        let x = |i: usize| f64::from_le_bytes(r[16 + 8 * i..24 + 8 * i].try_into().expect("8"));
        let transform = std::array::from_fn(|row| std::array::from_fn(|c| x(4 * row + c)));
        instances.push(Instance {
            name: name.to_string(),
            mesh,
            transform,
            mask,
        });
    }
    if at != names.len() {
        return Err(corrupted(format!(
            "section {} holds {} bytes, but the names take {at}",
            read::name(INAM),
            names.len()
        )));
    }
    let meshes = (2..sections)
        .map(|k| {
            let m = k - 2;
            // A plain saved scene (an `INST` section here is refused as out of place).
            let built = read::parse(path, payload(k)?)
                .and_then(|parts| super::validate::assemble(path, parts))
                .map_err(|e| match e {
                    Error::Parse {
                        path,
                        line,
                        message,
                    } => Error::Parse {
                        path,
                        line,
                        message: format!("mesh {m}: {message}"),
                    },
                    other => other,
                })?;
            if built.scene.objects().len() != 1 {
                return Err(corrupted(format!(
                    "mesh {m} holds {} objects, not one",
                    built.scene.objects().len()
                )));
            }
            // The wide tree the file held, moved (not copied) into the mesh.
            let (scene, bvh, wide) = built.into_tree_parts()?;
            Ok(Arc::new(MeshTree::with_wide(scene, bvh, wide)))
        })
        .collect::<Result<Vec<_>>>()?;
    let (instances, bvh) = Instances::assemble(meshes, instances).map_err(|e| match e {
        Error::Invalid(why) => corrupted(why),
        other => other,
    })?;
    Ok(BuiltScene::from_instances(instances, bvh))
}
