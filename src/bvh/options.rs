//! What the caller chooses about a build: which builder, the split-axis policy, the leaf size.

/// Which builder makes the tree. Every builder produces the same flattened layout, so both
/// traversal paths and every query work on any of them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Builder {
    /// The grid builder for a scene that is one height grid, median cut for anything else.
    #[default]
    Auto,
    /// The paper's median cut over individual triangles ([`super::median_cut`]).
    MedianCut,
    /// Binned surface-area heuristic over triangles ([`super::binned_sah`]): slower builds,
    /// fewer box and triangle tests per ray.
    BinnedSah,
    /// Median cut over the cells of a height grid, cut first into rectangular blocks with their
    /// own box and f64 origin ([`super::terrain_blocks`]); for scenes that are one height grid.
    Grid,
}

/// How the builder picks the axis to split a node along.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SplitAxis {
    /// x, then y, then z, by depth, as in the paper.
    Cycle,
    /// The longest axis of the node's box.
    #[default]
    Longest,
}

/// Builder settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BuildOptions {
    /// Which builder runs.
    pub builder: Builder,
    /// Split-axis policy of the median-cut builder. The grid builder always splits the longer
    /// horizontal side of a block (a z split never separates grid cells).
    pub split_axis: SplitAxis,
    /// Most triangles per leaf, 1 ..= 15 (1 is the paper's one object per leaf).
    pub leaf_size: u32,
}

impl Default for BuildOptions {
    /// The defaults chosen by measurement (see BENCHMARKS.md).
    fn default() -> Self {
        Self {
            builder: Builder::Auto,
            split_axis: SplitAxis::Longest,
            leaf_size: 8,
        }
    }
}

crate::names::named!(Builder {
    Auto => ("auto", "The grid builder for a scene that is one height grid, median cut for anything else."),
    MedianCut => ("median-cut", "The paper's median cut over individual triangles."),
    BinnedSah => ("sah", "Binned surface-area heuristic over triangles: slower builds, fewer box and triangle tests per ray."),
    Grid => ("grid", "Median cut over the cells of a height grid, cut first into rectangular blocks; for scenes that are one height grid."),
});

crate::names::named!(SplitAxis {
    Cycle => ("cycle", "x, then y, then z, by depth, as in the paper."),
    Longest => ("longest", "The longest axis of the node's box."),
});
