//! The engine's tree: the binary tree any builder made, collapsed into 8-wide nodes whose child
//! boxes are stored structure-of-arrays, so one SIMD box test covers all eight children.
//!
//! Leaves stay what the binary tree made them: a range of the leaf-order triangle array the
//! kernel and the twin read (`Bvh::triangles`), so the engine adds only its nodes to memory and
//! reports the same leaf-order triangle indices as the other paths.

use crate::bvh::Bvh;
use crate::error::{Error, Result};
use crate::layout::{GpuNode, GpuTriangle, KIND_INNER, MAX_LEAF_SIZE};
use crate::store::Store;
use glam::Vec3;
use rayon::prelude::*;

/// Children per node.
pub const WIDTH: usize = 8;
/// `WideNode::kind` of an empty child slot.
pub const EMPTY: u8 = 0;
/// `WideNode::kind` of an inner child (leaves hold their triangle count, 1–15).
pub const INNER: u8 = KIND_INNER as u8;

/// Eight children: their boxes (structure of arrays), what each is, and where it points.
///
/// The layout is plain bytes (no implicit padding), so a saved scene's `WIDE` section is an
/// array of nodes read in place ([`crate::rpk`]).
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct WideNode {
    /// Box minimum x, y, z of each child.
    pub min: [[f32; WIDTH]; 3],
    /// Box maximum x, y, z of each child.
    pub max: [[f32; WIDTH]; 3],
    /// An inner child's node index, or a leaf child's first leaf-order triangle.
    pub child: [u32; WIDTH],
    /// [`EMPTY`], a leaf's triangle count, or [`INNER`].
    pub kind: [u8; WIDTH],
    /// Bit `i` set when child slot `i` holds a child.
    pub occupied: u8,
    /// Zero: the padding to 256 bytes (four cache lines), explicit.
    pub reserved: [u8; RESERVED],
}

/// Sets child slot `lane`'s box.
fn set_box(node: &mut WideNode, lane: usize, min: Vec3, max: Vec3) {
    for a in 0..3 {
        node.min[a][lane] = min[a];
        node.max[a][lane] = max[a];
    }
}

/// Padding bytes at the end of a [`WideNode`].
const RESERVED: usize = 256 - (24 + 4 + 1) * WIDTH - 1;

const _: () = assert!(std::mem::size_of::<WideNode>() == 256);

impl WideNode {
    const EMPTY_NODE: WideNode = WideNode {
        min: [[0.0; WIDTH]; 3],
        max: [[0.0; WIDTH]; 3],
        child: [0; WIDTH],
        kind: [EMPTY; WIDTH],
        occupied: 0,
        reserved: [0; RESERVED],
    };
}

/// The collapsed tree; node 0 is the root. Empty for an empty scene.
#[derive(Clone, Debug, Default)]
pub struct WideBvh {
    /// Nodes, depth-first.
    pub nodes: Store<WideNode>,
    /// Levels of wide nodes on the longest root-to-leaf path.
    pub depth: usize,
    /// For each node, the binary node each child slot was collapsed from (its box is that
    /// node's box), so a refit of the binary tree refits this one by copying
    /// ([`WideBvh::refit`]). Empty for a tree made elsewhere (a saved scene's).
    pub sources: Vec<[u32; WIDTH]>,
}

fn surface_area(n: &GpuNode) -> f32 {
    let d = [0, 1, 2].map(|a| n.max[a] - n.min[a]);
    d[0] * d[1] + d[1] * d[2] + d[2] * d[0]
}

/// The binary node's two children.
fn children(index: u32, node: &GpuNode) -> [u32; 2] {
    [index + 1, node.first]
}

impl WideBvh {
    /// Collapses `bvh`'s binary tree: each wide node takes a binary inner node's subtree into up
    /// to eight slots, opening the inner nodes that the surface-area cost says to open
    /// ([`plan`]: a dynamic program over the binary tree, as Ylitie, Karras and Laine's for
    /// compressed wide trees; the binary leaves stay leaves). O(nodes). A tree whose links do
    /// not all point forward (not made by this crate's builders) keeps opening the inner child
    /// with the largest surface area instead; a corrupted one (a link out of range, or a cycle:
    /// more nodes opened than exist) is an error, never a hang.
    ///
    /// A large tree is collapsed on all cores: its plan in runs of subtrees ([`plan`]), the
    /// root's wide node serially, then the subtrees below it (up to eight) each into a piece of
    /// its own, in parallel; the pieces are copied after it in order (in parallel too), so the
    /// result does not depend on the threads. Wide nodes are made leftmost child first, so the
    /// binary nodes and the plan are read in the order they lie in memory.
    pub fn collapse(bvh: &Bvh) -> Result<WideBvh> {
        let binary = &bvh.nodes;
        if binary.is_empty() {
            return Ok(WideBvh::default());
        }
        if bvh.triangles.len() as u64 >= super::walk::MAX_CHILDREN {
            return Err(crate::error::Error::Invalid(format!(
                "the CPU engine holds fewer than 2^28 triangles per tree, and this one has {} \
                 (`--backend reference` or `gpu` pick it)",
                bvh.triangles.len()
            )));
        }
        if binary[0].is_leaf() {
            // A one-leaf tree: the root holds that leaf alone.
            let mut root = WideNode::EMPTY_NODE;
            set_child(
                &mut root,
                0,
                &binary[0],
                binary[0].first,
                binary[0].kind() as u8,
            );
            return Ok(WideBvh {
                nodes: vec![root].into(),
                depth: 1,
                sources: vec![[0; WIDTH]],
            });
        }
        // Serially: the whole tree, or a large one's top two levels, the subtrees below them
        // left as the pieces' roots (binary node, wide parent, lane).
        let (mut nodes, cut) = if binary.len() >= PARALLEL_FROM {
            (Collapsed::default(), TOP_LEVELS)
        } else {
            (Collapsed::with_capacity(wide_bound(binary, 0)), usize::MAX)
        };
        let plan = plan(binary);
        let plan = plan.as_deref();
        let (mut depth, roots) = collapse_from(binary, plan, 0, &mut nodes, cut)?;
        let pieces = roots
            .par_iter()
            .map(|&(n, _, _)| {
                let mut piece = Collapsed::with_capacity(wide_bound(binary, n));
                collapse_from(binary, plan, n, &mut piece, usize::MAX).map(|(d, _)| (piece, d))
            })
            .collect::<Result<Vec<_>>>()?;
        let Collapsed {
            nodes: mut top,
            sources: mut top_sources,
        } = nodes;
        // The pieces go after the top nodes, in order: each top lane left out is linked to its
        // piece's root, then each piece is copied (its children's indices moved by its offset)
        // by a task of its own into the final arrays.
        let mut offset = top.len();
        for (&(n, slot, lane), (piece, piece_depth)) in roots.iter().zip(&pieces) {
            set_child(
                &mut top[slot],
                lane,
                &binary[n as usize],
                offset as u32,
                INNER,
            );
            top_sources[slot][lane] = n;
            depth = depth.max(TOP_LEVELS + piece_depth);
            offset += piece.nodes.len();
        }
        if pieces.is_empty() {
            return Ok(WideBvh {
                nodes: top.into(),
                depth,
                sources: top_sources,
            });
        }
        let total = offset;
        let mut nodes = Vec::with_capacity(total);
        let mut sources = Vec::with_capacity(total);
        nodes.extend_from_slice(&top);
        sources.extend_from_slice(&top_sources);
        let mut jobs = Vec::with_capacity(pieces.len());
        let (mut node_room, mut source_room) = (
            &mut nodes.spare_capacity_mut()[..total - top.len()],
            &mut sources.spare_capacity_mut()[..total - top.len()],
        );
        let mut offset = top.len();
        for (piece, _) in &pieces {
            let len = piece.nodes.len();
            let (node_part, node_rest) = std::mem::take(&mut node_room).split_at_mut(len);
            let (source_part, source_rest) = std::mem::take(&mut source_room).split_at_mut(len);
            (node_room, source_room) = (node_rest, source_rest);
            jobs.push((piece, offset as u32, node_part, source_part));
            offset += len;
        }
        jobs.into_par_iter()
            .for_each(|(piece, offset, node_part, source_part)| {
                for (to, &from) in node_part.iter_mut().zip(&piece.nodes) {
                    let mut w = from;
                    for lane in 0..WIDTH {
                        if w.kind[lane] == INNER {
                            w.child[lane] += offset;
                        }
                    }
                    to.write(w);
                }
                for (to, &from) in source_part.iter_mut().zip(&piece.sources) {
                    to.write(from);
                }
            });
        // SAFETY: the pieces' parts tile the spare capacity up to `total` (their lengths sum to
        // `total - top.len()`), and each part's slots were all written above.
        unsafe {
            nodes.set_len(total);
            sources.set_len(total);
        }
        Ok(WideBvh {
            nodes: nodes.into(),
            depth,
            sources,
        })
    }

    /// The largest side of the root's box (0 for an empty tree).
    pub fn size(&self) -> f32 {
        let Some(root) = self.nodes.first() else {
            return 0.0;
        };
        let mut side = 0.0f32;
        for a in 0..3 {
            let lanes = (0..WIDTH).filter(|&l| root.kind[l] != EMPTY);
            let lo = lanes
                .clone()
                .map(|l| root.min[a][l])
                .fold(f32::INFINITY, f32::min);
            let hi = lanes
                .map(|l| root.max[a][l])
                .fold(f32::NEG_INFINITY, f32::max);
            side = side.max(hi - lo);
        }
        side
    }

    /// Bytes the engine adds to a built scene (its nodes and their sources; it reads the
    /// shared triangles).
    pub fn bytes(&self) -> u64 {
        (std::mem::size_of_val(self.nodes.as_slice()) + std::mem::size_of_val(&self.sources[..]))
            as u64
    }

    /// Recomputes every child box after `bvh`, the binary tree it was collapsed from, was
    /// refitted (`Bvh::refit`), so the result is the collapse of the refitted binary tree, box
    /// for box, without collapsing again. A collapsed tree copies each slot's box from its
    /// source node, in parallel. A tree made elsewhere (no sources; a validated one: children
    /// after their parents) works them out from the leaf-order triangles: a leaf child's box is
    /// its triangles' min/max, an inner child's the union of its node's children.
    pub fn refit(&mut self, bvh: &Bvh) {
        if self.refit_from_sources(&bvh.nodes) {
            return;
        }
        self.refit_from_triangles(&bvh.triangles);
    }

    /// Copies each slot's box from its source node in `binary` (the refitted nodes this tree
    /// was collapsed from), in parallel; `false`, changing nothing, for a tree without sources.
    pub fn refit_from_sources(&mut self, binary: &[GpuNode]) -> bool {
        if self.sources.len() != self.nodes.len() {
            return false;
        }
        let sources = &self.sources;
        self.nodes
            .to_mut()
            .par_iter_mut()
            .zip(sources.par_iter())
            .with_min_len(256)
            .for_each(|(node, sources)| {
                for lane in 0..WIDTH {
                    if node.kind[lane] != EMPTY {
                        let n = &binary[sources[lane] as usize];
                        set_box(node, lane, n.min.into(), n.max.into());
                    }
                }
            });
        true
    }

    /// [`WideBvh::refit`] for a tree without sources: each leaf child's box from its
    /// leaf-order `triangles`, then each inner child's from its node's, children before parents.
    fn refit_from_triangles(&mut self, triangles: &[GpuTriangle]) {
        let leaf_box = |first: u32, kind: u8| {
            let first = first as usize;
            crate::bvh::bounds(&triangles[first..first + kind as usize])
        };
        let nodes = self.nodes.to_mut();
        // Leaf children first, every node in parallel; then the inner children, each from its
        // node's bounds, children before parents.
        nodes.par_iter_mut().with_min_len(256).for_each(|node| {
            for lane in 0..WIDTH {
                let (kind, first) = (node.kind[lane], node.child[lane]);
                if kind != EMPTY && kind != INNER {
                    let (min, max) = leaf_box(first, kind);
                    set_box(node, lane, min, max);
                }
            }
        });
        let mut node_bounds = vec![(Vec3::INFINITY, Vec3::NEG_INFINITY); nodes.len()];
        for i in (0..nodes.len()).rev() {
            let node = &mut nodes[i];
            let mut all = (Vec3::INFINITY, Vec3::NEG_INFINITY);
            for lane in 0..WIDTH {
                let (min, max) = match node.kind[lane] {
                    EMPTY => continue,
                    INNER => {
                        let (min, max) = node_bounds[node.child[lane] as usize];
                        set_box(node, lane, min, max);
                        (min, max)
                    }
                    _ => (
                        Vec3::new(node.min[0][lane], node.min[1][lane], node.min[2][lane]),
                        Vec3::new(node.max[0][lane], node.max[1][lane], node.max[2][lane]),
                    ),
                };
                all = (all.0.min(min), all.1.max(max));
            }
            node_bounds[i] = all;
        }
    }
}

impl WideBvh {
    /// Checks what the engine's walk relies on and returns the first violation as a sentence:
    /// each child slot is [`EMPTY`], a leaf of 1 to [`MAX_LEAF_SIZE`] triangles within the
    /// `triangle_count` leaf-order triangles, or [`INNER`] pointing to a later node in range;
    /// `occupied` marks exactly the non-empty slots; every node is reached from the root
    /// exactly once; and `depth` is the longest root-to-leaf path, which sizes the walk's stack.
    /// For a tree made elsewhere (a saved scene) before it is walked; [`WideBvh::collapse`]'s
    /// trees pass.
    pub fn validate(&self, triangle_count: usize) -> std::result::Result<(), String> {
        if triangle_count as u64 >= super::walk::MAX_CHILDREN {
            return Err(format!(
                "{triangle_count} triangles: the CPU engine's trees hold fewer than 2^28"
            ));
        }
        let n = self.nodes.len();
        if n == 0 {
            return match self.depth {
                0 => Ok(()),
                d => Err(format!("an empty wide tree has depth {d}, not 0")),
            };
        }
        // Children lie after their parents, so one pass marks each node's one parent and a
        // pass backwards gives every node its height.
        let mut claimed = vec![false; n];
        for (i, node) in self.nodes.iter().enumerate() {
            for lane in 0..WIDTH {
                let (kind, child) = (node.kind[lane], node.child[lane] as usize);
                if (node.occupied >> lane & 1 == 1) != (kind != EMPTY) {
                    return Err(format!(
                        "wide node {i}'s occupied bits disagree with slot {lane}'s kind {kind}"
                    ));
                }
                match kind {
                    EMPTY => {}
                    INNER if child > i && child < n => {
                        if std::mem::replace(&mut claimed[child], true) {
                            return Err(format!("wide node {child} is reached twice"));
                        }
                    }
                    INNER => {
                        return Err(format!(
                            "wide node {i} links to {child}, which is not after it and in range"
                        ));
                    }
                    k if u32::from(k) <= MAX_LEAF_SIZE => {
                        if child + usize::from(k) > triangle_count {
                            return Err(format!(
                                "wide node {i} names triangles {child}..{} past the end ({triangle_count})",
                                child + usize::from(k)
                            ));
                        }
                    }
                    k => return Err(format!("wide node {i} slot {lane} has an unknown kind {k}")),
                }
            }
        }
        if let Some(i) = claimed.iter().skip(1).position(|c| !c) {
            return Err(format!("wide node {} is unreachable", i + 1));
        }
        let mut height = vec![1usize; n];
        for i in (0..n).rev() {
            let node = &self.nodes[i];
            for lane in 0..WIDTH {
                if node.kind[lane] == INNER {
                    height[i] = height[i].max(1 + height[node.child[lane] as usize]);
                }
            }
        }
        if self.depth != height[0] {
            return Err(format!(
                "the wide tree says its depth is {}, but its longest path has {} nodes",
                self.depth, height[0]
            ));
        }
        Ok(())
    }
}

/// Cost of visiting a wide node (its eight box tests), per unit of surface area. The two costs
/// were measured on this project's machine: a node visit about 80 cycles, a leaf visit (a
/// gather and one test of up to eight triangles) about 100; the collapse barely changes when
/// the leaf's cost is halved or doubled (BENCHMARKS.md).
const C_NODE: f32 = 1.0;
/// Cost of visiting a leaf (one group of up to eight triangle tests), per unit of surface area.
const C_LEAF: f32 = 1.2;

/// The surface-area cost of every binary node's subtree taking up to `i` slots of a wide node
/// (`cost[n][i - 1]`), bottom up; `None` for a tree whose links do not all point forward.
///
/// A leaf takes one slot at its area times [`C_LEAF`]. An inner node either takes one slot as
/// a wide node of its own (its area times [`C_NODE`], plus its two children sharing eight
/// slots) or, given two slots or more, is opened and its children share them, whichever costs
/// less. The collapse then opens what this says ([`Opener::distribute`]). The table (32 bytes
/// per binary node, as much as the binary nodes themselves) lives only while the collapse runs.
fn plan(binary: &[GpuNode]) -> Option<Vec<[f32; WIDTH]>> {
    let len = binary.len();
    let mut cost = vec![[0.0f32; WIDTH]; len];
    if len >= PARALLEL_FROM
        && let Some(ranges) = subtree_ranges(binary, PLAN_LEVELS)
    {
        // The subtrees below the top levels are runs of nodes (depth-first): each planned by a
        // task of its own, then the nodes above them. A run whose links leave it is planned
        // again with the whole tree, serially, so the table is always the serial one.
        let mut runs = Vec::with_capacity(ranges.len());
        let mut rest = cost.as_mut_slice();
        let mut at = 0;
        for range in &ranges {
            let (_, tail) = rest.split_at_mut(range.start - at);
            let (run, tail) = tail.split_at_mut(range.len());
            runs.push((range.start, run));
            (rest, at) = (tail, range.end);
        }
        let whole = runs
            .into_par_iter()
            .all(|(start, run)| plan_run(binary, start, run));
        if whole {
            let mut top = Vec::with_capacity(len);
            let mut at = 0;
            for range in &ranges {
                top.extend(at..range.start);
                at = range.end;
            }
            top.extend(at..len);
            for &n in top.iter().rev() {
                if !links_within(binary, n, len) {
                    return None;
                }
                cost[n] = plan_node(binary, n, |c| cost[c]);
            }
            return Some(cost);
        }
    }
    plan_run(binary, 0, &mut cost).then_some(cost)
}

/// Levels of binary nodes planned serially above the parallel runs of [`plan`] (up to 8 runs).
const PLAN_LEVELS: usize = 3;

/// The runs of nodes (`n .. end`, depth-first) of the subtrees under the inner nodes at binary
/// depth `levels`, in order; `None` for links that do not point forward or runs that do not
/// follow each other (a tree not laid out depth-first).
fn subtree_ranges(binary: &[GpuNode], levels: usize) -> Option<Vec<std::ops::Range<usize>>> {
    let mut roots = vec![0u32];
    for _ in 0..levels {
        let mut next = Vec::with_capacity(2 * roots.len());
        for &n in &roots {
            let node = binary.get(n as usize)?;
            if node.is_leaf() {
                continue;
            }
            next.extend(children(n, node));
        }
        roots = next;
    }
    let mut ranges = Vec::with_capacity(roots.len());
    let mut at = 0;
    for n in roots {
        let n = n as usize;
        if n < at || binary.get(n)?.is_leaf() {
            // A leaf above the cut is a top node; a run out of order is not depth-first.
            if n < at {
                return None;
            }
            continue;
        }
        let end = subtree_end(binary, n);
        ranges.push(n..end);
        at = end;
    }
    Some(ranges)
}

/// One past the last node of binary node `n`'s subtree when it is laid out depth-first: its
/// rightmost leaf, found down the right children (bounded, for corrupted links).
fn subtree_end(binary: &[GpuNode], n: usize) -> usize {
    let mut last = n;
    for _ in 0..binary.len() {
        match binary.get(last) {
            Some(node) if !node.is_leaf() && node.first as usize > last => {
                last = node.first as usize
            }
            _ => break,
        }
    }
    last + 1
}

/// Plans the nodes `start .. start + run.len()` into `run`, bottom up; `false` when a link
/// leaves the run or does not point forward.
fn plan_run(binary: &[GpuNode], start: usize, run: &mut [[f32; WIDTH]]) -> bool {
    let end = start + run.len();
    for n in (start..end).rev() {
        if !links_within(binary, n, end) {
            return false;
        }
        run[n - start] = plan_node(binary, n, |c| run[c - start]);
    }
    true
}

/// Whether binary node `n` is a leaf, or its children come after it and before `end`.
fn links_within(binary: &[GpuNode], n: usize, end: usize) -> bool {
    let node = &binary[n];
    node.is_leaf()
        || children(n as u32, node)
            .iter()
            .all(|&c| (n + 1..end).contains(&(c as usize)))
}

/// Binary node `n`'s row of [`plan`], from its children's rows (`row(child)`; their links
/// checked by the caller).
fn plan_node(binary: &[GpuNode], n: usize, row: impl Fn(usize) -> [f32; WIDTH]) -> [f32; WIDTH] {
    let node = &binary[n];
    let area = surface_area(node);
    if node.is_leaf() {
        return [area * C_LEAF; WIDTH];
    }
    let [l, r] = children(n as u32, node).map(|c| c as usize);
    let (cl, cr) = (row(l), row(r));
    let (lo, hi) = (binary[l].is_leaf(), binary[r].is_leaf());
    let mut dist = [f32::INFINITY; WIDTH];
    if lo && hi {
        // Two leaves: two slots or more hold both.
        dist[1..].fill(cl[0] + cr[0]);
    } else {
        // dist[i - 1]: the least cost of the two subtrees sharing i slots (one or more each),
        // a (min, +) convolution; `right[WIDTH + k]` is the right one's cost in k slots.
        let mut right = [f32::INFINITY; 2 * WIDTH];
        right[WIDTH + 1..].copy_from_slice(&cr[..WIDTH - 1]);
        for j in 1..WIDTH {
            let a = cl[j - 1];
            let window = &right[WIDTH + 1 - j..2 * WIDTH + 1 - j];
            for m in 0..WIDTH {
                let v = a + window[m];
                if v < dist[m] {
                    dist[m] = v;
                }
            }
        }
    }
    let own = area * C_NODE + dist[WIDTH - 1];
    let mut c = [own; WIDTH];
    for i in 1..WIDTH {
        if dist[i] < own {
            c[i] = dist[i];
        }
    }
    c
}

/// Binary trees of at least this many nodes are collapsed in parallel pieces.
const PARALLEL_FROM: usize = 1 << 14;
/// Levels of wide nodes collapsed serially above the parallel pieces (up to 8 pieces).
const TOP_LEVELS: usize = 1;

/// Opens binary inner nodes for the collapse, checking links and counting: a node opened more
/// often than there are nodes means a cycle.
struct Opener<'a> {
    binary: &'a [GpuNode],
    opened: usize,
    plan: Option<&'a [[f32; WIDTH]]>,
}

impl<'a> Opener<'a> {
    fn new(binary: &'a [GpuNode], plan: Option<&'a [[f32; WIDTH]]>) -> Self {
        Opener {
            binary,
            opened: 0,
            plan,
        }
    }

    /// The split of `i` slots between binary inner node `n`'s children that costs least, and
    /// that cost.
    fn best_split(&self, plan: &[[f32; WIDTH]], n: u32, i: usize) -> (usize, f32) {
        let [l, r] = children(n, &self.binary[n as usize]).map(|c| c as usize);
        (1..i)
            .map(|j| (j, plan[l][j - 1] + plan[r][i - j - 1]))
            .fold((1, f32::INFINITY), |a, b| if b.1 < a.1 { b } else { a })
    }

    /// Puts binary node `n`'s subtree into at most `i` of `slots` (from `len`), as the plan says.
    fn distribute(
        &mut self,
        plan: &[[f32; WIDTH]],
        n: u32,
        i: usize,
        slots: &mut [u32; WIDTH],
        len: &mut usize,
    ) -> Result<()> {
        let node = &self.binary[n as usize];
        if node.is_leaf() || i == 1 {
            slots[*len] = n;
            *len += 1;
            return Ok(());
        }
        let (j, split) = self.best_split(plan, n, i);
        if plan[n as usize][0] <= split {
            slots[*len] = n;
            *len += 1;
            return Ok(());
        }
        let [l, r] = self.open(n)?;
        // The right subtree is read after the left one's: asked for now (a miss each, else).
        crate::prefetch::item(self.binary, r as usize);
        crate::prefetch::item(plan, r as usize);
        self.distribute(plan, l, j, slots, len)?;
        self.distribute(plan, r, i - j, slots, len)
    }

    fn corrupted(&self, why: String) -> Error {
        Error::Invalid(format!(
            "the tree's links are corrupted ({why}): collapsing it for the CPU engine passed \
             its iteration cap of {} nodes",
            self.binary.len()
        ))
    }

    /// Binary inner node `n`'s two children, after checking the links.
    fn open(&mut self, n: u32) -> Result<[u32; 2]> {
        let cap = self.binary.len();
        self.opened += 1;
        if self.opened > cap {
            return Err(self.corrupted("a cycle".into()));
        }
        let pair = children(n, &self.binary[n as usize]);
        match pair.iter().find(|&&c| c as usize >= cap) {
            Some(&bad) => Err(self.corrupted(format!("a child {bad} past the end"))),
            None => Ok(pair),
        }
    }

    /// The children of the wide node made from binary inner node `source`, in leaf order: its
    /// subtree spread over eight slots as the plan says ([`Opener::distribute`]); without a
    /// plan, its two children, then, while there are fewer than [`WIDTH`], the inner one with
    /// the largest surface area opened in its place. In a fixed array: no allocation per node.
    fn widest_children(&mut self, source: u32) -> Result<([u32; WIDTH], usize)> {
        if let Some(plan) = self.plan {
            let (j, _) = self.best_split(plan, source, WIDTH);
            let [left, right] = self.open(source)?;
            let mut slots = [0; WIDTH];
            let mut len = 0;
            self.distribute(plan, left, j, &mut slots, &mut len)?;
            self.distribute(plan, right, WIDTH - j, &mut slots, &mut len)?;
            return Ok((slots, len));
        }
        let binary = self.binary;
        let [left, right] = self.open(source)?;
        let mut slots = [0; WIDTH];
        (slots[0], slots[1]) = (left, right);
        let mut len = 2;
        while len < WIDTH {
            let widest = slots[..len]
                .iter()
                .enumerate()
                .filter(|&(_, &n)| !binary[n as usize].is_leaf())
                .max_by(|a, b| {
                    surface_area(&binary[*a.1 as usize])
                        .total_cmp(&surface_area(&binary[*b.1 as usize]))
                })
                .map(|(i, _)| i);
            let Some(i) = widest else { break };
            let pair = self.open(slots[i])?;
            slots.copy_within(i + 1..len, i + 2);
            slots[i] = pair[0];
            slots[i + 1] = pair[1];
            len += 1;
        }
        Ok((slots, len))
    }
}

/// At most how many wide nodes the subtree under binary node `n` collapses into: each takes at
/// least one binary inner node, and a subtree of `k` nodes laid out depth-first (`n .. n + k`,
/// its last node found down the right children) has `(k - 1) / 2` inner ones. Only a capacity:
/// a corrupted tree gets a smaller or larger one, never a wrong answer.
fn wide_bound(binary: &[GpuNode], n: u32) -> usize {
    (subtree_end(binary, n as usize) - n as usize) / 2 + 1
}

/// Wide nodes being collapsed, with the binary node each slot comes from
/// ([`WideBvh::sources`]).
#[derive(Default)]
struct Collapsed {
    nodes: Vec<WideNode>,
    sources: Vec<[u32; WIDTH]>,
}

impl Collapsed {
    fn with_capacity(n: usize) -> Self {
        Self {
            nodes: Vec::with_capacity(n),
            sources: Vec::with_capacity(n),
        }
    }
}

/// [`WideBvh::sources`] of an empty slot.
const NO_SOURCE: u32 = u32::MAX;

/// An inner child that [`collapse_from`] leaves unopened: its binary node, the wide node and the
/// lane it belongs in.
type LeftOut = (u32, usize, usize);

/// Collapses the subtree under binary inner node `root` into `nodes` (empty), its wide root
/// first, then depth-first; returns its depth and the inner children of its wide nodes at depth
/// `cut`, which it leaves unopened (binary node, wide node, lane; their lanes stay empty for the
/// caller to fill). Children's indices are within `nodes`.
fn collapse_from(
    binary: &[GpuNode],
    plan: Option<&[[f32; WIDTH]]>,
    root: u32,
    out: &mut Collapsed,
    cut: usize,
) -> Result<(usize, Vec<LeftOut>)> {
    let mut opener = Opener::new(binary, plan);
    // (binary node whose children fill the wide node, wide slot to fill, depth)
    let mut pending: Vec<(u32, u32, usize)> = vec![(root, 0, 1)];
    let mut left_out = Vec::new();
    let Collapsed { nodes, sources } = out;
    nodes.push(WideNode::EMPTY_NODE);
    sources.push([NO_SOURCE; WIDTH]);
    let mut depth = 0;
    while let Some((source, slot, d)) = pending.pop() {
        depth = depth.max(d);
        let (slots, len) = opener.widest_children(source)?;
        let first_pending = pending.len();
        for (lane, &n) in slots[..len].iter().enumerate() {
            let node = &binary[n as usize];
            sources[slot as usize][lane] = n;
            if node.is_leaf() {
                set_child(
                    &mut nodes[slot as usize],
                    lane,
                    node,
                    node.first,
                    node.kind() as u8,
                );
            } else if d == cut {
                left_out.push((n, slot as usize, lane));
            } else {
                let child = nodes.len() as u32;
                nodes.push(WideNode::EMPTY_NODE);
                sources.push([NO_SOURCE; WIDTH]);
                set_child(&mut nodes[slot as usize], lane, node, child, INNER);
                // Its binary node and children are read when it is taken off `pending`.
                for m in [n as usize + 1, node.first as usize] {
                    crate::prefetch::item(binary, m);
                    if let Some(plan) = plan {
                        crate::prefetch::item(plan, m);
                    }
                }
                pending.push((n, child, d + 1));
            }
        }
        // Taken leftmost first: the binary nodes are then read in the order they lie
        // (depth-first), which the hardware's prefetch follows; the right-to-left order took
        // 1.6-1.8 times as long on a 2M-triangle terrain.
        pending[first_pending..].reverse();
    }
    Ok((depth, left_out))
}

fn set_child(wide: &mut WideNode, lane: usize, node: &GpuNode, child: u32, kind: u8) {
    for a in 0..3 {
        wide.min[a][lane] = node.min[a];
        wide.max[a][lane] = node.max[a];
    }
    wide.child[lane] = child;
    wide.kind[lane] = kind;
    if kind != EMPTY {
        wide.occupied |= 1 << lane;
    } else {
        wide.occupied &= !(1 << lane);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::BuildOptions;

    /// The tree below wide node `i`, lane by lane, with inner children's indices replaced by
    /// their own subtrees: equal for two collapses that differ only in node order.
    fn canonical(nodes: &[WideNode], i: usize, out: &mut Vec<(usize, u8, u32, [u32; 6])>) {
        let node = &nodes[i];
        for lane in 0..WIDTH {
            let bounds = [0, 1, 2]
                .map(|a| node.min[a][lane].to_bits())
                .into_iter()
                .chain([0, 1, 2].map(|a| node.max[a][lane].to_bits()))
                .collect::<Vec<_>>();
            let leaf_first = if node.kind[lane] == INNER {
                0
            } else {
                node.child[lane]
            };
            out.push((
                lane,
                node.kind[lane],
                leaf_first,
                bounds.try_into().unwrap(),
            ));
            if node.kind[lane] == INNER {
                canonical(nodes, node.child[lane] as usize, out);
            }
        }
    }

    /// The model cost of a collapsed tree: each wide node below the root at its source's area
    /// times [`C_NODE`], each leaf slot at its area times [`C_LEAF`], the root at its own.
    fn model_cost(binary: &[GpuNode], wide: &WideBvh) -> f64 {
        let mut cost = f64::from(surface_area(&binary[0]) * C_NODE);
        for (node, sources) in wide.nodes.iter().zip(&wide.sources) {
            for lane in 0..WIDTH {
                let area = || f64::from(surface_area(&binary[sources[lane] as usize]));
                match node.kind[lane] {
                    EMPTY => {}
                    INNER => cost += area() * f64::from(C_NODE),
                    _ => cost += area() * f64::from(C_LEAF),
                }
            }
        }
        cost
    }

    /// The collapse builds the tree its plan costs, and no greedy collapse costs less.
    #[test]
    fn the_collapse_follows_its_plan_and_beats_the_greedy_one() {
        use crate::check::synthetic::{hills, terrain};
        let mesh = terrain(60, 45, 0.0, 0.0, 1.0, hills);
        let scene = crate::Scene::from_meshes([("hills".to_string(), mesh)]).unwrap();
        for leaf_size in [1, 4, 8] {
            let options = BuildOptions {
                leaf_size,
                ..BuildOptions::default()
            };
            let bvh = Bvh::build(&scene, &options).unwrap();
            let planned = plan(&bvh.nodes).unwrap();
            let wide = WideBvh::collapse(&bvh).unwrap();
            wide.validate(bvh.triangles.len()).unwrap();
            let got = model_cost(&bvh.nodes, &wide);
            let want = f64::from(planned[0][0]);
            assert!(
                (got - want).abs() <= 1e-4 * want,
                "{got} against the plan's {want}"
            );
            let mut greedy = Collapsed::default();
            collapse_from(&bvh.nodes, None, 0, &mut greedy, usize::MAX).unwrap();
            let greedy = WideBvh {
                nodes: greedy.nodes.into(),
                depth: 0,
                sources: greedy.sources,
            };
            let greedy_cost = model_cost(&bvh.nodes, &greedy);
            assert!(
                got <= greedy_cost * (1.0 + 1e-5),
                "{got} against greedy {greedy_cost}"
            );
            assert!(wide.nodes.len() <= greedy.nodes.len());
        }
    }

    /// What a saved tree must not carry past `validate`: a depth other than its longest path
    /// (which sizes the walk's stack) and a node that links to itself (a walk that never ends),
    /// even where that node is reached from nowhere else.
    #[test]
    fn validate_refuses_a_wrong_depth_and_a_node_linked_to_itself() {
        use crate::check::synthetic::{hills, terrain};
        let mesh = terrain(40, 40, 0.0, 0.0, 1.0, hills);
        let scene = crate::Scene::from_meshes([("hills".to_string(), mesh)]).unwrap();
        let bvh = Bvh::build(&scene, &BuildOptions::default()).unwrap();
        let count = bvh.triangles.len();
        let wide = WideBvh::collapse(&bvh).unwrap();
        wide.validate(count).unwrap();
        assert!(wide.depth >= 2, "depth {}", wide.depth);
        for depth in [wide.depth - 1, wide.depth + 1] {
            let mut wrong = wide.clone();
            wrong.depth = depth;
            let error = wrong.validate(count).unwrap_err();
            assert!(error.contains("depth"), "{error}");
        }
        // A parent's link to a node of leaves taken away, and that node's first slot made a
        // link to itself: it is then reached exactly once, by itself.
        let (parent, lane) = (0..wide.nodes.len())
            .flat_map(|p| (0..WIDTH).map(move |lane| (p, lane)))
            .find(|&(p, lane)| {
                let node = &wide.nodes[p];
                node.kind[lane] == INNER && {
                    let child = &wide.nodes[node.child[lane] as usize];
                    (0..WIDTH).all(|l| child.kind[l] != INNER)
                }
            })
            .expect("a node of leaves under another");
        let mut looped = wide.clone();
        let nodes = looped.nodes.to_mut();
        let child = nodes[parent].child[lane] as usize;
        nodes[parent].kind[lane] = EMPTY;
        nodes[parent].occupied &= !(1 << lane);
        nodes[child].kind[0] = INNER;
        nodes[child].occupied |= 1;
        nodes[child].child[0] = child as u32;
        let error = looped.validate(count).unwrap_err();
        assert!(error.contains("not after it"), "{error}");
    }

    #[test]
    fn the_parallel_collapse_is_the_serial_one_in_another_order() {
        use crate::check::synthetic::{hills, terrain};
        let mesh = terrain(200, 200, 0.0, 0.0, 1.0, hills);
        let scene = crate::Scene::from_meshes([("hills".to_string(), mesh)]).unwrap();
        let bvh = Bvh::build(&scene, &BuildOptions::default()).unwrap();
        assert!(
            bvh.nodes.len() >= PARALLEL_FROM,
            "{} nodes",
            bvh.nodes.len()
        );
        let parallel = WideBvh::collapse(&bvh).unwrap();
        let mut serial = Collapsed::default();
        let (depth, left_out) = collapse_from(
            &bvh.nodes,
            plan(&bvh.nodes).as_deref(),
            0,
            &mut serial,
            usize::MAX,
        )
        .unwrap();
        let serial = serial.nodes;
        assert!(left_out.is_empty());
        assert_eq!(
            (parallel.nodes.len(), parallel.depth),
            (serial.len(), depth)
        );
        assert_ne!(
            &parallel.nodes[..],
            &serial[..],
            "the pieces change the order"
        );
        let (mut a, mut b) = (Vec::new(), Vec::new());
        canonical(&parallel.nodes, 0, &mut a);
        canonical(&serial, 0, &mut b);
        assert_eq!(a, b);
        parallel.validate(bvh.triangles.len()).unwrap();
        // Each slot's source is the binary node whose box it holds (what a refit copies).
        for (node, sources) in parallel.nodes.iter().zip(&parallel.sources) {
            for lane in (0..WIDTH).filter(|&lane| node.kind[lane] != EMPTY) {
                let source = &bvh.nodes[sources[lane] as usize];
                for a in 0..3 {
                    assert_eq!(node.min[a][lane], source.min[a]);
                    assert_eq!(node.max[a][lane], source.max[a]);
                }
            }
        }
        // And it does not depend on the threads.
        assert_eq!(WideBvh::collapse(&bvh).unwrap().nodes, parallel.nodes);
    }

    /// The plan made in parallel runs is the serial one, row for row, and a tree whose links
    /// leave their runs (not laid out depth-first) is planned serially.
    #[test]
    fn the_parallel_plan_is_the_serial_one() {
        use crate::check::synthetic::{hills, terrain};
        let mesh = terrain(200, 200, 0.0, 0.0, 1.0, hills);
        let scene = crate::Scene::from_meshes([("hills".to_string(), mesh)]).unwrap();
        let bvh = Bvh::build(&scene, &BuildOptions::default()).unwrap();
        let binary = &bvh.nodes[..];
        assert!(binary.len() >= PARALLEL_FROM, "{} nodes", binary.len());
        let ranges = subtree_ranges(binary, PLAN_LEVELS).unwrap();
        assert_eq!(ranges.len(), 1 << PLAN_LEVELS);
        let mut serial = vec![[0.0f32; WIDTH]; binary.len()];
        assert!(plan_run(binary, 0, &mut serial));
        let parallel = plan(binary).unwrap();
        assert!(parallel == serial, "the parallel plan differs");
        // A link from one run into another: the runs refuse it, the serial plan takes it.
        let mut moved = binary.to_vec();
        let (a, b) = (&ranges[0], &ranges[1]);
        let inner = (a.start..a.end)
            .find(|&n| !moved[n].is_leaf() && moved[n].first as usize > n + 1)
            .unwrap();
        moved[inner].first = b.start as u32;
        let mut run = vec![[0.0f32; WIDTH]; a.len()];
        assert!(!plan_run(&moved, a.start, &mut run));
        let mut serial = vec![[0.0f32; WIDTH]; moved.len()];
        assert!(plan_run(&moved, 0, &mut serial));
        assert!(plan(&moved).unwrap() == serial);
        // A link backwards: no plan at all.
        moved[inner].first = inner as u32;
        assert!(plan(&moved).is_none());
    }
}
