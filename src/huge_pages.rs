//! Large answer buffers on transparent huge pages, where the OS offers them (Linux with
//! `transparent_hugepage` set to `madvise` or `always`; elsewhere this does nothing).
//!
//! A pick of 1M rays writes 112 MB of [`crate::Hit`]s into fresh memory. With 4 KiB pages the
//! kernel takes one page fault per 4 KiB, and on the project's machine those faults were a
//! quarter of the whole pick's time on camera rays (BENCHMARKS.md, "Pipeline cost"). Asking for
//! 2 MiB pages before the buffer is first written cuts the faults 512-fold. Answers are not
//! affected: only how the kernel backs the memory.
//!
//! [`Allocator`] gives the same advice to every large allocation of a program that installs it
//! as its global allocator (the `raypick` binary does): a whole-process pick of an 810k-triangle
//! OBJ touches about 220 MB of fresh memory (the file, the scene, the builder's primitives, the
//! trees), and its page faults were 40% of its CPU time.

use std::alloc::{GlobalAlloc, Layout, System};

/// Buffers smaller than this keep ordinary pages (the advice would cover little of them).
const MIN_BYTES: usize = 4 << 20;
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
    advise_range(v.as_mut_ptr().wrapping_add(v.len()) as usize, bytes);
}

/// Advises the whole huge pages inside `[start, start + bytes)` onto huge pages, when the range
/// is at least `MIN_BYTES` long. The range must lie in memory this process owns.
fn advise_range(start: usize, bytes: usize) {
    if bytes < MIN_BYTES {
        return;
    }
    let (first, last) = (
        start.next_multiple_of(HUGE_PAGE),
        (start + bytes) / HUGE_PAGE * HUGE_PAGE,
    );
    if last <= first {
        return;
    }
    #[cfg(target_os = "linux")]
    // SAFETY: [first, last) lies inside an allocation this process owns (a vector's, or one
    // `Allocator` just made); MADV_HUGEPAGE only changes how the kernel backs those pages, never
    // their contents.
    unsafe {
        libc::madvise(
            first as *mut libc::c_void,
            last - first,
            libc::MADV_HUGEPAGE,
        );
    }
}

/// Whether [`Allocator`] advises: yes unless the environment variable `RAYPICK_HUGE_PAGES` is
/// `0` or `off` (read once; with no allocation, as the allocator itself asks).
fn allocator_advises() -> bool {
    use std::sync::atomic::{AtomicU8, Ordering};
    const UNKNOWN: u8 = 0;
    const YES: u8 = 1;
    const NO: u8 = 2;
    static STATE: AtomicU8 = AtomicU8::new(UNKNOWN);
    match STATE.load(Ordering::Relaxed) {
        YES => true,
        NO => false,
        _ => {
            #[cfg(unix)]
            // SAFETY: getenv with a NUL-terminated name; the result is read before any other
            // call could change the environment, and only compared.
            let off = unsafe {
                let value = libc::getenv(c"RAYPICK_HUGE_PAGES".as_ptr());
                !value.is_null() && {
                    let value = std::ffi::CStr::from_ptr(value).to_bytes();
                    value == b"0" || value.eq_ignore_ascii_case(b"off")
                }
            };
            #[cfg(not(unix))]
            let off = false;
            STATE.store(if off { NO } else { YES }, Ordering::Relaxed);
            !off
        }
    }
}

/// [`Allocator`]'s advice for the `bytes`-long block it just got from the system (null when
/// the system had none), when the block is large enough and the advice is on.
fn advise_block(block: *mut u8, bytes: usize) {
    if !block.is_null() && bytes >= MIN_BYTES && allocator_advises() {
        advise_range(block as usize, bytes);
    }
}

/// The system allocator, with every allocation of at least 4 MiB advised onto huge pages before
/// the caller first writes it (a grown reallocation too). Install it with
/// `#[global_allocator] static ALLOCATOR: raypick::huge_pages::Allocator = raypick::huge_pages::Allocator;`.
#[derive(Clone, Copy, Debug, Default)]
pub struct Allocator;

// SAFETY: every call is forwarded to `System` with the same arguments; the advice afterwards
// touches no memory and only hints how the kernel backs the block just returned.
unsafe impl GlobalAlloc for Allocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded with the caller's layout.
        let block = unsafe { System.alloc(layout) };
        advise_block(block, layout.size());
        block
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // Zeroed memory this large comes fresh from the kernel (mmap) and is not touched by the
        // system allocator, so the advice still lands before the first write.
        // SAFETY: forwarded with the caller's layout.
        let block = unsafe { System.alloc_zeroed(layout) };
        advise_block(block, layout.size());
        block
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded with the caller's pointer and layout.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: forwarded with the caller's arguments.
        let block = unsafe { System.realloc(ptr, layout, new_size) };
        if new_size > layout.size() {
            advise_block(block, new_size);
        }
        block
    }
}
