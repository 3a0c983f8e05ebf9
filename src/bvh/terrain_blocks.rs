//! The terrain-aware builder, as the paper organises terrain: the height grid is cut into
//! rectangular blocks of [`BLOCK_CELLS`] × [`BLOCK_CELLS`] cells, each with its own box and f64
//! origin, and the median-cut hierarchy is built over the blocks, then over the cells inside
//! each block.
//!
//! On a regular grid the midplane of a node's box is its middle grid line, so this builder splits
//! ranges of cells by index instead of sorting or partitioning triangles: O(n), no sorting, and
//! every box is the min/max of the triangles under it, so heights are tight. Above the blocks,
//! splits fall on block boundaries; inside a block, on the middle cell line of the longer
//! horizontal side (a z split never separates cells). The output has exactly the layout of
//! [`super::median_cut`]'s, so both traversal paths run on it unchanged.
//!
//! The build is two passes over the same recursion: a plan that counts the nodes of every large
//! subtree (so parallel tasks can write straight into their own part of the node array), then
//! the write. Neither depends on the thread count, so the output is identical on any.

use super::{
    BuildOptions, Bvh, check_leaf_size, check_node_count, inner_node, is_traceable, leaf_node,
    link_parents,
};
use crate::error::{Error, Result};
use crate::layout::{GpuNode, GpuTriangle};
use crate::scene::{Object, Scene};
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use std::ops::Range;

/// Cells along each side of a block (64 × 64 cells: 8,192 triangles).
pub const BLOCK_CELLS: u32 = 64;

/// Subtrees with at least this many triangles are planned and written as two parallel tasks.
const PARALLEL_MIN: u32 = 8 * 1024;

/// One terrain block: a rectangle of grid cells whose triangles form one subtree of the tree.
#[derive(Clone, Debug, PartialEq)]
pub struct Block {
    /// Cell rows `r` (cell r lies between sample rows r and r + 1; row 0 is north for DEMs).
    pub rows: Range<u32>,
    /// Cell columns.
    pub cols: Range<u32>,
    /// World-space minimum corner of the block's triangles (f64).
    pub min: DVec3,
    /// World-space maximum corner of the block's triangles (f64).
    pub max: DVec3,
    /// The block's own f64 origin: the centre of its world box.
    pub origin: DVec3,
    /// The node that roots the block's subtree (its box is the block's box in f32 offsets).
    pub node: u32,
    /// The block's triangles, as a range of [`Bvh::triangles`] (leaf order).
    pub triangles: Range<u32>,
}

/// The scene's one object, when the scene is exactly one height grid (the grid builder's input).
pub fn single_grid(scene: &Scene) -> Option<&Object> {
    match scene.objects() {
        [only] if only.grid.is_some() => Some(only),
        _ => None,
    }
}

/// Builds the tree of a scene that is one height grid (see the module docs).
pub fn build(scene: &Scene, options: &BuildOptions) -> Result<Bvh> {
    check_leaf_size(options)?;
    let object = single_grid(scene).ok_or_else(|| {
        Error::Invalid(format!(
            "the grid builder needs a scene that is one height grid, but this scene has {} object(s){}; use --builder median-cut",
            scene.objects().len(),
            if scene.objects().len() == 1 { " that is not a grid" } else { "" }
        ))
    })?;
    let grid = Grid::new(scene, object, options.leaf_size);
    let whole = grid.whole();
    let triangle_count = grid.count(whole);
    if triangle_count == 0 {
        return Ok(Bvh {
            origin: grid.origin,
            ..Bvh::default()
        });
    }
    let plan = grid.plan(whole);
    check_node_count(plan.nodes as usize)?;
    let mut nodes = vec![GpuNode::default(); plan.nodes as usize];
    let mut triangles = vec![GpuTriangle::default(); triangle_count as usize];
    let mut triangle_ids = vec![0u32; triangle_count as usize];
    let out = Out {
        nodes: &mut nodes,
        node_base: 0,
        triangles: &mut triangles,
        ids: &mut triangle_ids,
        triangle_base: 0,
    };
    let (_, _, mut blocks) = grid.write(whole, &plan, out, false);
    link_parents(&mut nodes);
    blocks.par_iter_mut().for_each(|block| {
        let ids = &triangle_ids[block.triangles.start as usize..block.triangles.end as usize];
        let (min, max) = ids
            .iter()
            .flat_map(|&i| scene.world_triangle(i as usize))
            .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p), hi.max(p))
            });
        block.min = min;
        block.max = max;
        block.origin = min + (max - min) * 0.5;
    });
    Ok(Bvh {
        origin: grid.origin,
        nodes: nodes.into(),
        triangles: triangles.into(),
        triangle_ids: triangle_ids.into(),
        blocks,
    })
}

/// A rectangle of cells: rows `r0..r1`, columns `c0..c1`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Cells {
    r0: u32,
    r1: u32,
    c0: u32,
    c1: u32,
}

impl Cells {
    fn is_one_cell(self) -> bool {
        self.r1 - self.r0 == 1 && self.c1 - self.c0 == 1
    }

    /// Blocks spanned along the rows and along the columns.
    fn blocks_spanned(self) -> (u32, u32) {
        (
            (self.r1 - 1) / BLOCK_CELLS - self.r0 / BLOCK_CELLS + 1,
            (self.c1 - 1) / BLOCK_CELLS - self.c0 / BLOCK_CELLS + 1,
        )
    }

    fn within_one_block(self) -> bool {
        self.blocks_spanned() == (1, 1)
    }
}

/// How a node's cells are divided between its two children.
enum Split {
    /// Along grid lines; `axis` is the world axis the cut is perpendicular to.
    Cells {
        axis: usize,
        left: Cells,
        right: Cells,
    },
    /// One cell holding more triangles than a leaf may: its two triangles become two leaves.
    Halves,
}

/// How many nodes a subtree has, and for a large subtree the same for its two children.
struct Plan {
    nodes: u32,
    children: Option<Box<(Plan, Plan)>>,
}

/// The part of the output arrays one subtree writes: its nodes and its triangles, with their
/// indices in the whole arrays.
struct Out<'a> {
    nodes: &'a mut [GpuNode],
    node_base: u32,
    triangles: &'a mut [GpuTriangle],
    ids: &'a mut [u32],
    triangle_base: u32,
}

/// A write cursor into an [`Out`], for subtrees written by one task.
struct Cursor<'a> {
    out: Out<'a>,
    next_node: usize,
    next_triangle: usize,
}

/// The grid as the builder sees it.
struct Grid<'a> {
    scene: &'a Scene,
    origin: DVec3,
    /// Every scene vertex as an f32 offset from `origin`, converted once (each grid vertex is
    /// shared by up to six triangles).
    local_positions: Vec<Vec3>,
    first_triangle: u32,
    cell_rows: u32,
    cell_cols: u32,
    leaf_size: u32,
    /// Per cell: bit 0 set when triangle 2k can be hit, bit 1 when triangle 2k + 1 can.
    traceable: Vec<u8>,
    /// 2D prefix sums of traceable triangles, `(cell_rows + 1) × (cell_cols + 1)`.
    prefix: Vec<u32>,
    /// World axis (0 = x, 1 = y) along which column and row indices advance, whether the
    /// coordinate grows with the index, and the spacing of cells along it.
    column_axis: (usize, bool, f64),
    row_axis: (usize, bool, f64),
}

impl<'a> Grid<'a> {
    fn new(scene: &'a Scene, object: &Object, leaf_size: u32) -> Self {
        let shape = object.grid.expect("single_grid returned a grid object");
        let (cell_rows, cell_cols) = (
            shape.rows.saturating_sub(1),
            shape.columns.saturating_sub(1),
        );
        let origin = scene.origin();
        let local_positions = super::local_positions(scene, origin);
        let holds = super::frame_holds(scene, origin);
        let first_triangle = object.first_triangle;
        let traceable: Vec<u8> = (0..cell_rows as usize * cell_cols as usize)
            .into_par_iter()
            .map(|k| {
                let first = first_triangle as usize + 2 * k;
                (0..2).fold(0u8, |bits, h| {
                    let index = first + h;
                    let local = scene
                        .triangle_vertices(index)
                        .map(|v| local_positions[v as usize]);
                    bits | (u8::from(is_traceable(scene, index, local, holds)) << h)
                })
            })
            .collect();
        let prefix = prefix_sums(&traceable, cell_rows as usize, cell_cols as usize);
        let sample =
            |r: u32, c: u32| scene.position((object.first_vertex + r * shape.columns + c) as usize);
        let direction = |to: DVec3, steps: u32| {
            let d = to - sample(0, 0);
            let axis = usize::from(d.y.abs() > d.x.abs());
            (
                axis,
                d[axis] >= 0.0,
                d[axis].abs() / f64::from(steps.max(1)),
            )
        };
        Self {
            scene,
            origin,
            local_positions,
            first_triangle,
            cell_rows,
            cell_cols,
            leaf_size,
            traceable,
            prefix,
            column_axis: direction(sample(0, cell_cols), cell_cols),
            row_axis: direction(sample(cell_rows, 0), cell_rows),
        }
    }

    fn whole(&self) -> Cells {
        Cells {
            r0: 0,
            r1: self.cell_rows,
            c0: 0,
            c1: self.cell_cols,
        }
    }

    /// Traceable triangles in `cells`, from the prefix sums.
    fn count(&self, cells: Cells) -> u32 {
        if cells.r0 >= cells.r1 || cells.c0 >= cells.c1 {
            return 0;
        }
        let w = self.cell_cols as usize + 1;
        let at = |r: u32, c: u32| self.prefix[r as usize * w + c as usize];
        at(cells.r1, cells.c1)
            .wrapping_sub(at(cells.r0, cells.c1))
            .wrapping_sub(at(cells.r1, cells.c0))
            .wrapping_add(at(cells.r0, cells.c0))
    }

    /// Where a node over `cells` (more than one leaf's worth) is split.
    fn split(&self, cells: Cells) -> Split {
        if cells.is_one_cell() {
            return Split::Halves;
        }
        let (rows, cols) = (cells.r1 - cells.r0, cells.c1 - cells.c0);
        let by_blocks = !cells.within_one_block();
        let (row_blocks, col_blocks) = cells.blocks_spanned();
        let (can_rows, can_cols) = if by_blocks {
            (row_blocks > 1, col_blocks > 1)
        } else {
            (rows > 1, cols > 1)
        };
        let width = |n: u32, axis: (usize, bool, f64)| f64::from(n) * axis.2;
        let along_columns = match (can_rows, can_cols) {
            (true, true) => width(cols, self.column_axis) >= width(rows, self.row_axis),
            (_, can_cols) => can_cols,
        };
        let middle = |lo: u32, hi: u32| {
            if by_blocks {
                let (b0, b1) = (lo / BLOCK_CELLS, (hi - 1) / BLOCK_CELLS + 1);
                (b0 + b1) / 2 * BLOCK_CELLS
            } else {
                lo + (hi - lo) / 2
            }
        };
        let (axis, ascending, low, high) = if along_columns {
            let m = middle(cells.c0, cells.c1);
            let (axis, ascending, _) = self.column_axis;
            (
                axis,
                ascending,
                Cells { c1: m, ..cells },
                Cells { c0: m, ..cells },
            )
        } else {
            let m = middle(cells.r0, cells.r1);
            let (axis, ascending, _) = self.row_axis;
            (
                axis,
                ascending,
                Cells { r1: m, ..cells },
                Cells { r0: m, ..cells },
            )
        };
        // The left child is the one at lower coordinates along the split axis, as in median cut.
        let (left, right) = if ascending { (low, high) } else { (high, low) };
        Split::Cells { axis, left, right }
    }

    /// Drops empty halves: a node whose cells split into an empty and a non-empty part is the
    /// non-empty part's node.
    fn settle(&self, mut cells: Cells) -> Cells {
        while self.count(cells) > self.leaf_size {
            match self.split(cells) {
                Split::Cells { left, right, .. } if self.count(left) == 0 => cells = right,
                Split::Cells { left, right, .. } if self.count(right) == 0 => cells = left,
                _ => break,
            }
        }
        cells
    }

    /// Nodes of the subtree over `cells`, one task.
    fn node_count(&self, cells: Cells) -> u32 {
        let cells = self.settle(cells);
        match self.count(cells) {
            0 => 0,
            n if n <= self.leaf_size => 1,
            _ => match self.split(cells) {
                Split::Halves => 3,
                Split::Cells { left, right, .. } => {
                    1 + self.node_count(left) + self.node_count(right)
                }
            },
        }
    }

    /// Node counts of the subtree over `cells`, large subtrees counted in parallel.
    fn plan(&self, cells: Cells) -> Plan {
        let cells = self.settle(cells);
        if self.count(cells) < PARALLEL_MIN {
            return Plan {
                nodes: self.node_count(cells),
                children: None,
            };
        }
        let Split::Cells { left, right, .. } = self.split(cells) else {
            unreachable!("a node with {PARALLEL_MIN}+ triangles spans more than one cell")
        };
        let (left, right) = rayon::join(|| self.plan(left), || self.plan(right));
        Plan {
            nodes: 1 + left.nodes + right.nodes,
            children: Some(Box::new((left, right))),
        }
    }

    /// Writes the subtree over `cells` (planned by `plan`) into `out`; returns its f32 box and
    /// the blocks in it. `in_block` says whether an ancestor already is a block root.
    fn write(
        &self,
        cells: Cells,
        plan: &Plan,
        out: Out<'_>,
        in_block: bool,
    ) -> (Vec3, Vec3, Vec<Block>) {
        let cells = self.settle(cells);
        let mut blocks = Vec::new();
        let starts_block = !in_block && cells.within_one_block();
        if starts_block {
            blocks.push(self.block(cells, out.node_base, out.triangle_base));
        }
        let in_block = in_block || starts_block;
        let Some((left_plan, right_plan)) = plan.children.as_deref() else {
            let mut cursor = Cursor {
                out,
                next_node: 0,
                next_triangle: 0,
            };
            let (min, max) = self.write_one_task(cells, &mut cursor, in_block, &mut blocks);
            return (min, max, blocks);
        };
        let Split::Cells { axis, left, right } = self.split(cells) else {
            unreachable!("planned as a split along grid lines")
        };
        let left_triangles = self.count(left) as usize;
        let (root, nodes) = out.nodes.split_first_mut().expect("planned nodes");
        let (left_nodes, right_nodes) = nodes.split_at_mut(left_plan.nodes as usize);
        let (left_tris, right_tris) = out.triangles.split_at_mut(left_triangles);
        let (left_ids, right_ids) = out.ids.split_at_mut(left_triangles);
        let right_base = out.node_base + 1 + left_plan.nodes;
        let left_out = Out {
            nodes: left_nodes,
            node_base: out.node_base + 1,
            triangles: left_tris,
            ids: left_ids,
            triangle_base: out.triangle_base,
        };
        let right_out = Out {
            nodes: right_nodes,
            node_base: right_base,
            triangles: right_tris,
            ids: right_ids,
            triangle_base: out.triangle_base + left_triangles as u32,
        };
        let ((lmin, lmax, lblocks), (rmin, rmax, rblocks)) = rayon::join(
            || self.write(left, left_plan, left_out, in_block),
            || self.write(right, right_plan, right_out, in_block),
        );
        let (min, max) = (lmin.min(rmin), lmax.max(rmax));
        *root = inner_node(min, max, axis, right_base);
        blocks.extend(lblocks);
        blocks.extend(rblocks);
        (min, max, blocks)
    }

    /// Depth-first write of the subtree over `cells` at the cursor; returns its f32 box.
    fn write_one_task(
        &self,
        cells: Cells,
        cursor: &mut Cursor<'_>,
        in_block: bool,
        blocks: &mut Vec<Block>,
    ) -> (Vec3, Vec3) {
        let cells = self.settle(cells);
        let starts_block = !in_block && cells.within_one_block();
        if starts_block {
            blocks.push(self.block(cells, cursor.node_index(), cursor.triangle_index()));
        }
        let in_block = in_block || starts_block;
        let here = cursor.next_node;
        if self.count(cells) <= self.leaf_size {
            let first = cursor.triangle_index();
            let mut count = 0;
            let (mut min, mut max) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
            for scene_index in self.traceable_in(cells) {
                let (lo, hi) = cursor.push_triangle(self.local_triangle(scene_index), scene_index);
                (min, max) = (min.min(lo), max.max(hi));
                count += 1;
            }
            cursor.push_node(leaf_node(min, max, count, first));
            return (min, max);
        }
        cursor.push_node(GpuNode::default());
        let (axis, (lmin, lmax), (rmin, rmax)) = match self.split(cells) {
            Split::Halves => {
                let [a, b]: [usize; 2] = self.traceable_in(cells).collect::<Vec<_>>()[..]
                    .try_into()
                    .expect("a cell with more triangles than a leaf holds two");
                let left = cursor.push_single_leaf(self.local_triangle(a), a);
                let right_index = cursor.node_index();
                let right = cursor.push_single_leaf(self.local_triangle(b), b);
                cursor.out.nodes[here].first = right_index;
                (self.column_axis.0, left, right)
            }
            Split::Cells { axis, left, right } => {
                let left = self.write_one_task(left, cursor, in_block, blocks);
                cursor.out.nodes[here].first = cursor.node_index();
                let right = self.write_one_task(right, cursor, in_block, blocks);
                (axis, left, right)
            }
        };
        let (min, max) = (lmin.min(rmin), lmax.max(rmax));
        let right = cursor.out.nodes[here].first;
        cursor.out.nodes[here] = inner_node(min, max, axis, right);
        (min, max)
    }

    /// The block over `cells` whose subtree starts at node `node` and triangle `first` (its
    /// world bounds are filled in after the build).
    fn block(&self, cells: Cells, node: u32, first: u32) -> Block {
        Block {
            rows: cells.r0..cells.r1,
            cols: cells.c0..cells.c1,
            min: DVec3::ZERO,
            max: DVec3::ZERO,
            origin: DVec3::ZERO,
            node,
            triangles: first..first + self.count(cells),
        }
    }

    /// Scene triangle `index` as the kernel stores it (as [`super::local_triangle`] makes it).
    fn local_triangle(&self, index: usize) -> GpuTriangle {
        let [v0, v1, v2] = self
            .scene
            .triangle_vertices(index)
            .map(|v| self.local_positions[v as usize].into());
        GpuTriangle { v0, v1, v2 }
    }

    /// Scene indices of the traceable triangles in `cells`, row by row.
    fn traceable_in(&self, cells: Cells) -> impl Iterator<Item = usize> + '_ {
        (cells.r0..cells.r1).flat_map(move |r| {
            (cells.c0..cells.c1).flat_map(move |c| {
                let k = r as usize * self.cell_cols as usize + c as usize;
                let bits = self.traceable[k];
                let first = self.first_triangle as usize + 2 * k;
                (0..2)
                    .filter(move |h| bits & (1 << h) != 0)
                    .map(move |h| first + h)
            })
        })
    }
}

impl Cursor<'_> {
    fn node_index(&self) -> u32 {
        self.out.node_base + self.next_node as u32
    }

    fn triangle_index(&self) -> u32 {
        self.out.triangle_base + self.next_triangle as u32
    }

    fn push_node(&mut self, node: GpuNode) {
        self.out.nodes[self.next_node] = node;
        self.next_node += 1;
    }

    /// Writes `triangle` (scene triangle `index`) at the cursor; returns its f32 box.
    fn push_triangle(&mut self, triangle: GpuTriangle, index: usize) -> (Vec3, Vec3) {
        self.out.triangles[self.next_triangle] = triangle;
        self.out.ids[self.next_triangle] = index as u32;
        self.next_triangle += 1;
        let [a, b, c] = [triangle.v0, triangle.v1, triangle.v2].map(Vec3::from);
        (a.min(b).min(c), a.max(b).max(c))
    }

    /// Writes a leaf holding only `triangle` (scene triangle `index`); returns its box.
    fn push_single_leaf(&mut self, triangle: GpuTriangle, index: usize) -> (Vec3, Vec3) {
        let first = self.triangle_index();
        let (min, max) = self.push_triangle(triangle, index);
        self.push_node(leaf_node(min, max, 1, first));
        (min, max)
    }
}

/// Inclusive 2D prefix sums of the traceable-triangle counts of a `rows × cols` cell grid, as a
/// `(rows + 1) × (cols + 1)` table with a zero first row and column.
fn prefix_sums(traceable: &[u8], rows: usize, cols: usize) -> Vec<u32> {
    let w = cols + 1;
    let mut prefix = vec![0u32; (rows + 1) * w];
    prefix[w..]
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(r, row)| {
            let mut running = 0u32;
            for c in 0..cols {
                running += traceable[r * cols + c].count_ones();
                row[c + 1] = running;
            }
        });
    for r in 1..=rows {
        let (above, here) = prefix.split_at_mut(r * w);
        let above = &above[(r - 1) * w..];
        for (cell, up) in here[..w].iter_mut().zip(above) {
            *cell += *up;
        }
    }
    prefix
}
