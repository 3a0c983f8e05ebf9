//! Checking a file's sections against each other and making the built scene of them: the
//! scene's invariants (what [`Scene::add_mesh`] guarantees), the kernel's tree (its links, in
//! one parallel pass: [`tree_links`]; distinct scene triangle ids in range), the masks, the
//! terrain blocks and the CPU engine's tree ([`WideBvh::validate`]). Whatever passes is safe to
//! walk on every backend: no index out of range, no walk that does not end.
//!
//! These are the checks safety needs, made in time linear in the file and mostly in parallel
//! (a few milliseconds for a million triangles). The checksums already make any accidental
//! change an error, so the geometric invariants of [`Bvh::validate`] (boxes nested, leaf
//! triangles inside their boxes) and the leaf triangles' equality with the scene's are not
//! checked again on every load: they cost more than the rest of the load together, and a box
//! that breaks them changes answers, never safety. `tests/suite/rpk.rs` checks them on saved files.

use super::read::{Parts, problem};
use super::records::{ObjectRecord, Summary};
use crate::bvh::Bvh;
use crate::engine::WideBvh;
use crate::error::Result;
use crate::layout::MAX_NODES;
use crate::layout::{KIND_INNER, MAX_LEAF_SIZE};
use crate::picker::BuiltScene;
use crate::scene::{GridShape, Object, Scene};
use crate::store::Store;
use rayon::prelude::*;
use std::path::Path;

/// The built scene of `parts`, after every check (see the module docs). The scene, the
/// kernel's tree and the wide tree are checked side by side.
pub fn assemble(path: &Path, parts: Parts) -> Result<BuiltScene> {
    let corrupted = |why: String| problem(path, format!("the file is corrupted: {why}"));
    let Parts {
        summary,
        positions,
        triangles,
        objects,
        names,
        nodes,
        leaf_triangles,
        triangle_ids,
        masks,
        blocks,
        wide,
    } = parts;
    let scene_triangles = triangles.len();
    let bvh = Bvh {
        origin: summary.tree_origin,
        nodes,
        triangles: leaf_triangles,
        triangle_ids,
        blocks,
    };
    let wide = WideBvh {
        nodes: wide,
        depth: usize::try_from(summary.wide_depth).unwrap_or(usize::MAX),
        sources: Vec::new(),
    };
    let (scene, (tree, wide_tree)) = rayon::join(
        || scene_of(positions, triangles, &objects, &names, &summary),
        || {
            rayon::join(
                || tree_of(&bvh, scene_triangles),
                || {
                    if wide.nodes.is_empty() != bvh.nodes.is_empty() {
                        return Err(format!(
                            "its wide tree has {} nodes for a tree of {}",
                            wide.nodes.len(),
                            bvh.nodes.len()
                        ));
                    }
                    wide.validate(bvh.triangles.len())
                        .map_err(|e| format!("its wide tree is invalid: {e}"))
                },
            )
        },
    );
    let scene = scene.map_err(corrupted)?;
    tree.map_err(corrupted)?;
    wide_tree.map_err(corrupted)?;

    // The masks: the objects' (none when all are all ones), in leaf order.
    let leaf_count = bvh.triangles.len();
    let all_ones = scene.objects().iter().all(|o| o.mask == u32::MAX);
    if masks.is_empty() != all_ones || (!masks.is_empty() && masks.len() != leaf_count) {
        return Err(corrupted(format!(
            "it has {} triangle masks for {leaf_count} triangles whose objects' masks are {}",
            masks.len(),
            if all_ones { "all ones" } else { "not all ones" }
        )));
    }
    let wrong_mask = masks
        .par_iter()
        .zip(bvh.triangle_ids.as_slice())
        .position_any(|(&m, &id)| m != scene.triangle_mask(id));
    if let Some(k) = wrong_mask {
        return Err(corrupted(format!(
            "leaf-order triangle {k}'s mask is not its object's"
        )));
    }
    Ok(BuiltScene::with_wide(scene, bvh, masks, wide))
}

/// The scene, after checking its parts: counts that fit u32 indices, finite vertices, the
/// objects ([`objects_of`]) and the origin the summary gives.
fn scene_of(
    positions: Store<glam::DVec3>,
    triangles: Store<[u32; 3]>,
    objects: &[ObjectRecord],
    names: &[u8],
    summary: &Summary,
) -> std::result::Result<Scene, String> {
    if u32::try_from(positions.len()).is_err() || u32::try_from(triangles.len()).is_err() {
        return Err("it has more than 2^32 vertices or triangles".into());
    }
    if let Some(i) = positions.par_iter().position_any(|p| !p.is_finite()) {
        return Err(format!("vertex {i} is not finite"));
    }
    let objects = objects_of(objects, names, positions.len(), &triangles)?;
    let scene = Scene::from_checked_parts(positions, triangles, objects);
    let bits = |v: glam::DVec3| v.to_array().map(f64::to_bits);
    if bits(scene.origin()) != bits(summary.scene_origin) {
        // In exponent form: a point 10³⁰⁰ out written in full took 300 digits a coordinate.
        let point = |v: glam::DVec3| format!("[{:e}, {:e}, {:e}]", v.x, v.y, v.z);
        return Err(format!(
            "the scene origin {} is not the centre of its vertices' bounds, {}",
            point(summary.scene_origin),
            point(scene.origin())
        ));
    }
    Ok(scene)
}

/// Checks the kernel's tree against a scene of `scene_triangles` triangles: its size,
/// distinct scene triangle ids in range, its links ([`tree_links`]) and its blocks' ranges.
/// (Origins and boxes are read as they are: whatever `save` wrote loads; a non-finite one
/// only makes rays miss.)
fn tree_of(bvh: &Bvh, scene_triangles: usize) -> std::result::Result<(), String> {
    if bvh.nodes.len() > MAX_NODES as usize {
        return Err(format!(
            "its tree has {} nodes, more than the node format addresses",
            bvh.nodes.len()
        ));
    }
    distinct_ids(&bvh.triangle_ids, scene_triangles)?;
    tree_links(bvh).map_err(|e| format!("its tree is invalid: {e}"))?;
    let leaf_count = bvh.triangles.len() as u64;
    for (k, b) in bvh.blocks.iter().enumerate() {
        let fine = b.rows.start <= b.rows.end
            && b.cols.start <= b.cols.end
            && (b.node as usize) < bvh.nodes.len()
            && b.triangles.start <= b.triangles.end
            && u64::from(b.triangles.end) <= leaf_count;
        if !fine {
            return Err(format!("terrain block {k} is out of range"));
        }
    }
    Ok(())
}

/// Checks that `ids` are distinct scene triangle ids below `scene_triangles`, with a bit per
/// scene triangle (an eighth of a byte array's memory, so the random marks stay in cache).
fn distinct_ids(ids: &[u32], scene_triangles: usize) -> std::result::Result<(), String> {
    let mut seen = vec![0u64; scene_triangles.div_ceil(64)];
    for (k, &id) in ids.iter().enumerate() {
        if id as usize >= scene_triangles {
            return Err(format!(
                "leaf-order triangle {k} is scene triangle {id}, but the scene has {scene_triangles}"
            ));
        }
        let (word, bit) = (&mut seen[id as usize / 64], 1u64 << (id % 64));
        if *word & bit != 0 {
            return Err(format!("scene triangle {id} is in the tree twice"));
        }
        *word |= bit;
    }
    Ok(())
}

/// The objects of the records and names, after checking what [`Scene::add_mesh`] guarantees:
/// ids in order; triangles covered one object after another; vertices likewise, each object's
/// triangles using only its own vertices; grids with their number of triangles; UTF-8 names.
fn objects_of(
    records: &[ObjectRecord],
    names: &[u8],
    vertex_count: usize,
    triangles: &[[u32; 3]],
) -> std::result::Result<Vec<Object>, String> {
    let mut objects = Vec::with_capacity(records.len());
    let (mut next_triangle, mut next_vertex, mut name_at) = (0u64, 0u64, 0usize);
    for (k, r) in records.iter().enumerate() {
        if r.id as usize != k {
            return Err(format!("object {k} has the id {}", r.id));
        }
        if u64::from(r.first_triangle) != next_triangle {
            return Err(format!(
                "object {k}'s triangles start at {}, not right after the previous object's ({next_triangle})",
                r.first_triangle
            ));
        }
        next_triangle += u64::from(r.triangle_count);
        if next_triangle > triangles.len() as u64 {
            return Err(format!(
                "object {k}'s triangles end at {next_triangle}, past the scene's {}",
                triangles.len()
            ));
        }
        let first_vertex = u64::from(r.first_vertex);
        let vertex_end = records
            .get(k + 1)
            .map_or(vertex_count as u64, |next| u64::from(next.first_vertex));
        if first_vertex != next_vertex
            || vertex_end < first_vertex
            || vertex_end > vertex_count as u64
        {
            return Err(format!(
                "object {k}'s vertices {first_vertex}..{vertex_end} do not follow the previous object's"
            ));
        }
        next_vertex = vertex_end;
        let own = r.first_triangle as usize..next_triangle as usize;
        let outside = triangles[own.clone()].par_iter().position_any(|t| {
            t.iter()
                .any(|&i| u64::from(i) < first_vertex || u64::from(i) >= vertex_end)
        });
        if let Some(t) = outside {
            return Err(format!(
                "triangle {} uses a vertex outside its object's {first_vertex}..{vertex_end}",
                own.start + t
            ));
        }
        let grid = match (r.has_grid, r.columns, r.rows) {
            (0, 0, 0) => None,
            (1, columns, rows) => {
                // At most 2 · (2³² − 2)², which overflows u64: multiplied in u128.
                let cells =
                    2 * u128::from(columns.saturating_sub(1)) * u128::from(rows.saturating_sub(1));
                if cells != u128::from(r.triangle_count) {
                    return Err(format!(
                        "object {k} is a {columns}×{rows} grid with {} triangles instead of {cells}",
                        r.triangle_count
                    ));
                }
                let shape = GridShape { columns, rows };
                let samples = shape.samples();
                if vertex_end - first_vertex != samples {
                    return Err(format!(
                        "object {k} is a {columns}×{rows} grid with {} vertices instead of {samples}",
                        vertex_end - first_vertex
                    ));
                }
                Some(shape)
            }
            _ => return Err(format!("object {k}'s grid fields are malformed")),
        };
        if r.flags > 1 {
            return Err(format!(
                "object {k}'s flags field {} is not 0 or 1",
                r.flags
            ));
        }
        let name = names
            .get(name_at..name_at + r.name_length as usize)
            .ok_or_else(|| format!("object {k}'s name runs past the names"))?;
        name_at += r.name_length as usize;
        let name = std::str::from_utf8(name)
            .map_err(|_| format!("object {k}'s name is not UTF-8"))?
            .to_string();
        objects.push(Object {
            id: r.id,
            name,
            first_triangle: r.first_triangle,
            triangle_count: r.triangle_count,
            first_vertex: r.first_vertex,
            mask: r.mask,
            grid,
            mirrored: r.flags & 1 == 1,
        });
    }
    if next_triangle != triangles.len() as u64 {
        return Err(format!(
            "the objects hold {next_triangle} of the scene's {} triangles",
            triangles.len()
        ));
    }
    if next_vertex != vertex_count as u64 {
        return Err(format!(
            "the objects hold {next_vertex} of the scene's {vertex_count} vertices"
        ));
    }
    if name_at != names.len() {
        return Err(format!(
            "the names hold {} bytes, but the objects' names {name_at}",
            names.len()
        ));
    }
    Ok(objects)
}

/// The kernel's tree is a tree whose every index is in range, checked node by node in
/// parallel: kinds are leaves (1 to [`MAX_LEAF_SIZE`] triangles, within the triangle array)
/// or inner nodes (`KIND_INNER` + axis); an inner node's children (the next node and `first`)
/// lie after it, in range, distinct, and name it in their parent links; and there are exactly
/// `nodes − 1` such links. Then every node but the root has exactly one parent, earlier in the
/// array, so every node is reached from the root once and both walks end. Every leaf-order
/// triangle lies in exactly one leaf.
pub fn tree_links(bvh: &Bvh) -> std::result::Result<(), String> {
    use std::sync::atomic::{AtomicU64, Ordering};
    let (nodes, triangles) = (&bvh.nodes, bvh.triangles.len());
    if bvh.triangle_ids.len() != triangles {
        return Err("triangle_ids and triangles differ in length".into());
    }
    if nodes.is_empty() {
        return match triangles {
            0 => Ok(()),
            _ => Err("triangles without nodes".into()),
        };
    }
    let n = nodes.len();
    // One bit per triangle, set by the leaf holding it.
    let covered: Vec<AtomicU64> = (0..triangles.div_ceil(64))
        .map(|_| AtomicU64::new(0))
        .collect();
    let inner = nodes
        .par_iter()
        .enumerate()
        .with_min_len(4096)
        .map(|(i, node)| -> std::result::Result<usize, String> {
            let kind = node.kind();
            if (1..=MAX_LEAF_SIZE).contains(&kind) {
                let (first, end) = (node.first as usize, node.first as usize + kind as usize);
                if end > triangles {
                    return Err(format!(
                        "leaf {i} names triangles {first}..{end} past the end"
                    ));
                }
                // The leaf's bits, one word at a time (a leaf spans at most two words).
                let mut t = first;
                while t < end {
                    let (word, low) = (t / 64, t % 64);
                    let high = (end - word * 64).min(64);
                    let bits = (u64::MAX >> (64 - (high - low))) << low;
                    let before = covered[word].fetch_or(bits, Ordering::Relaxed);
                    if before & bits != 0 {
                        let t = word * 64 + (before & bits).trailing_zeros() as usize;
                        return Err(format!("triangle {t} is in two leaves"));
                    }
                    t = word * 64 + high;
                }
                Ok(0)
            } else if (KIND_INNER..KIND_INNER + 3).contains(&kind) {
                let right = node.first as usize;
                if right <= i + 1 || right >= n {
                    return Err(format!(
                        "node {i}'s right child {right} is not after its left child and in range"
                    ));
                }
                for child in [i + 1, right] {
                    if nodes[child].parent() as usize != i {
                        return Err(format!(
                            "node {child}'s parent link is {}, not {i}",
                            nodes[child].parent()
                        ));
                    }
                }
                Ok(1)
            } else {
                Err(format!("node {i} has an unknown kind {kind}"))
            }
        })
        .try_reduce(|| 0, |a, b| Ok(a + b))?;
    if 2 * inner != n - 1 {
        return Err(format!(
            "its {inner} inner nodes link {} children, but the tree has {} nodes besides the root",
            2 * inner,
            n - 1
        ));
    }
    let held: u64 = covered
        .iter()
        .map(|w| u64::from(w.load(Ordering::Relaxed).count_ones()))
        .sum();
    if held != triangles as u64 {
        return Err(format!(
            "{} of its {triangles} triangles are in no leaf",
            triangles as u64 - held
        ));
    }
    Ok(())
}
