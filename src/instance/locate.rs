//! From a hit id to its instance without a search over every instance: the ids are cut into
//! blocks of 2^`shift` (about as many ids as an instance holds on average), and each block
//! keeps the instance its first id falls in. An id's instance is then found among the few
//! instances between its block's entry and the next block's (one or two on a field of equal
//! meshes), where a binary search over 10,000 instance records read 14 of them from all over
//! memory for every hit (BENCHMARKS.md, "The field's way back").

use crate::layout::GpuInstance;

/// The block table over the instances' first hit ids (`GpuInstance::prim_base`, ascending).
#[derive(Clone, Debug, Default)]
pub struct HitIndex {
    /// Ids per block: 2^`shift`.
    shift: u32,
    /// For each block and one past the last: the last instance whose first id is at most the
    /// block's first id.
    first: Vec<u32>,
}

impl HitIndex {
    /// The table over `records` (first ids ascending, the first 0), whose ids run to `total`.
    pub fn new(records: &[GpuInstance], total: u64) -> Self {
        if records.is_empty() {
            return Self::default();
        }
        // The smallest blocks that keep the table no longer than the instances.
        let per_instance = total.div_ceil(records.len() as u64).max(1);
        let shift = per_instance.next_power_of_two().trailing_zeros();
        let blocks = (total >> shift) + 1;
        let first = (0..=blocks)
            .map(|b| {
                let id = (b << shift).min(u64::from(u32::MAX)) as u32;
                last_at_or_below(records, id) as u32
            })
            .collect();
        Self { shift, first }
    }

    /// The instance hit id `prim` lands in: the last whose first id is at most `prim` (what
    /// `partition_point` over all of `records` gives). `records` are those the table was made
    /// over; `prim` is below their `total`.
    #[inline]
    pub fn instance(&self, records: &[GpuInstance], prim: u32) -> usize {
        // In u64: one instance of over 2^31 ids makes blocks of 2^32.
        let b = (u64::from(prim) >> self.shift) as usize;
        match (self.first.get(b), self.first.get(b + 1)) {
            (Some(&lo), Some(&hi)) => {
                // records[lo] starts at or below the block's first id, so at or below `prim`;
                // records[hi] is the last that starts at or below the next block's (an index
                // of `records`, and not before `lo`).
                let (lo, hi) = (lo as usize, hi as usize);
                lo + records[lo + 1..=hi].partition_point(|r| r.prim_base <= prim)
            }
            _ => last_at_or_below(records, prim),
        }
    }

    /// The table's bytes.
    pub fn bytes(&self) -> u64 {
        (self.first.len() * size_of::<u32>()) as u64
    }
}

/// The last of `records` whose first id is at most `id` (the first record when none is).
fn last_at_or_below(records: &[GpuInstance], id: u32) -> usize {
    records
        .partition_point(|r| r.prim_base <= id)
        .saturating_sub(1)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn records(sizes: &[u32]) -> (Vec<GpuInstance>, u64) {
        let mut base = 0u32;
        let records = sizes
            .iter()
            .map(|&n| {
                let r = GpuInstance {
                    prim_base: base,
                    ..Default::default()
                };
                base += n;
                r
            })
            .collect();
        (records, u64::from(base))
    }

    /// Every id lands where a search over all the records puts it, whatever the instances'
    /// sizes: equal, mixed, empty ones among them, one huge among many small.
    #[test]
    fn every_id_lands_in_the_searched_instance() {
        let cases: Vec<Vec<u32>> = vec![
            vec![5],
            vec![1; 37],
            vec![3674; 100],
            vec![7, 0, 0, 3, 0, 1000, 1, 1, 1, 0, 64, 63, 65],
            std::iter::once(100_000).chain([1; 300]).collect(),
            [1; 300].into_iter().chain([100_000, 2, 0]).collect(),
            vec![0, 0, 9, 0],
        ];
        // One instance holding nearly every id: blocks of 2^32 (sampled ids only).
        let (huge, total) = records(&[u32::MAX - 2]);
        let index = HitIndex::new(&huge, total);
        for prim in [0, 1, 1 << 31, u32::MAX - 3] {
            assert_eq!(index.instance(&huge, prim), 0);
        }
        for sizes in cases {
            let (records, total) = records(&sizes);
            let index = HitIndex::new(&records, total);
            for prim in 0..total as u32 {
                let k = index.instance(&records, prim);
                assert_eq!(
                    k,
                    last_at_or_below(&records, prim),
                    "sizes {sizes:?}, id {prim}"
                );
                // The instance whose range holds it (empty ones, as removed instances have,
                // hold none).
                let base = records[k].prim_base;
                assert!(
                    base <= prim && prim < base + sizes[k],
                    "sizes {sizes:?}, id {prim}"
                );
            }
            assert!(index.first.len() <= records.len() + 2, "sizes {sizes:?}");
        }
    }
}
