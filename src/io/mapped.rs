//! Memory-mapped input files read a piece at a time.
//!
//! This module owns [`Pages`]: the hints that bring a mapped file's pages in just before a piece
//! is read and let them go once it is, so a loaded file is never resident whole beside what is
//! built from it (the `.rpk` reader copies a section at a time; the OBJ reader lets go of what
//! it touched to cut the file into chunks). A later read of a piece let go faults the same bytes
//! back in from the file.

/// Where a file's bytes lie: in a map (`Some`), whose pages follow the hints, or already in
/// memory (`None`), where the hints do nothing.
pub(crate) struct Pages<'a>(pub(crate) Option<&'a memmap2::Mmap>);

impl Pages<'_> {
    /// The offset range of `piece` in the map, when `piece` is a non-empty slice of it.
    fn range(&self, piece: &[u8]) -> Option<(&memmap2::Mmap, usize, usize)> {
        let map = self.0?;
        let start = (piece.as_ptr() as usize).checked_sub(map.as_ptr() as usize)?;
        (!piece.is_empty() && start + piece.len() <= map.len()).then_some((map, start, piece.len()))
    }

    /// `piece` is about to be read: fault its pages in at once (Linux).
    pub(crate) fn need(&self, piece: &[u8]) {
        #[cfg(target_os = "linux")]
        if let Some((map, start, len)) = self.range(piece) {
            // Only a hint: on an older kernel the reads fault the pages in themselves.
            let _ = map.advise_range(memmap2::Advice::PopulateRead, start, len);
        }
        let _ = piece;
    }

    /// `piece` is read: let its pages go.
    pub(crate) fn done(&self, piece: &[u8]) {
        #[cfg(unix)]
        if let Some((map, start, len)) = self.range(piece) {
            // SAFETY: the map is a read-only shared map of a file; MADV_DONTNEED only drops
            // the pages from this process, and a later read faults the same bytes back in
            // from the file. Only a hint: errors are ignored.
            let _ = unsafe {
                map.unchecked_advise_range(memmap2::UncheckedAdvice::DontNeed, start, len)
            };
        }
        let _ = piece;
    }
}
