//! Large answer buffers on transparent huge pages, where the OS offers them (Linux with
//! `transparent_hugepage` set to `madvise` or `always`; elsewhere this does nothing).
//!
//! A pick of 1M rays writes 112 MB of [`crate::Hit`]s into fresh memory. With 4 KiB pages the
//! kernel takes one page fault per 4 KiB, and on the project's machine those faults were a
//! quarter of the whole pick's time on camera rays (BENCHMARKS.md, "Pipeline cost"). Asking for
//! 2 MiB pages before the buffer is first written cuts the faults 512-fold. Answers are not
//! affected: only how the kernel backs the memory.

/// Buffers smaller than this keep ordinary pages (the advice would cover little of them).
const MIN_BYTES: usize = 8 << 20;
/// The huge page size the advice is aligned to.
const HUGE_PAGE: usize = 2 << 20;

/// A vector with room for `n` items whose untouched capacity is advised onto huge pages.
pub fn vec_with_capacity<T>(n: usize) -> Vec<T> {
    let mut v = Vec::with_capacity(n);
    advise(&mut v);
    v
}

/// Advises the spare capacity of `v`, from the first whole huge page to the last, onto huge
/// pages. Errors are ignored: the advice is only a hint.
pub fn advise<T>(v: &mut Vec<T>) {
    let bytes = (v.capacity() - v.len()) * size_of::<T>();
    if bytes < MIN_BYTES {
        return;
    }
    let start = v.as_mut_ptr().wrapping_add(v.len()) as usize;
    let (first, last) = (
        start.next_multiple_of(HUGE_PAGE),
        (start + bytes) / HUGE_PAGE * HUGE_PAGE,
    );
    if last <= first {
        return;
    }
    #[cfg(target_os = "linux")]
    // SAFETY: [first, last) lies inside `v`'s allocation, which this process owns; MADV_HUGEPAGE
    // only changes how the kernel backs those pages, never their contents.
    unsafe {
        libc::madvise(
            first as *mut libc::c_void,
            last - first,
            libc::MADV_HUGEPAGE,
        );
    }
}
