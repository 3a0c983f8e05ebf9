//! Large answer buffers on transparent huge pages, where the OS offers them (Linux with
//! `transparent_hugepage` set to `madvise` or `always`; elsewhere this does nothing).
//!
//! A pick of 1M rays writes 104 MB of [`crate::Hit`]s into fresh memory. With 4 KiB pages the
//! kernel takes one page fault per 4 KiB, and on the project's machine those faults were a
//! quarter of the whole pick's time on camera rays (BENCHMARKS.md, "Pipeline cost"). Asking for
//! 2 MiB pages before the buffer is first written cuts the faults 512-fold. Answers are not
//! affected: only how the kernel backs the memory.
//!
//! [`Allocator`] gives the same advice to every large allocation of a program that installs it
//! as its global allocator (the `raypick` binary does): a whole-process pick of an 810k-triangle
//! OBJ touches about 220 MB of fresh memory (the file, the scene, the builder's primitives, the
//! trees), and its page faults were 40% of its CPU time.
//!
//! Huge pages make the faults fewer, not free: the kernel still zeroes every fresh page. So
//! [`Allocator`] also keeps up to [`KEPT_BLOCKS`] freed large blocks ([`KEPT_BYTES`] in all) and
//! hands one back to the next large allocation it fits, as the C allocator already does for
//! blocks below 32 MiB. A program that picks again and again (a server, a batch loop) then
//! writes its answers into memory that is already mapped: on the dragon's 1M camera rays, a
//! pick into a fresh buffer took 57 ms and one into a reused buffer 46 ms (BENCHMARKS.md). A
//! long-running process that must give memory back after a burst turns this off
//! ([`keep_freed_blocks`]; `raypick serve` does).

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

/// Freed large blocks [`Allocator`] keeps for reuse, at most.
pub const KEPT_BLOCKS: usize = 4;
/// Bytes of freed large blocks [`Allocator`] keeps for reuse, at most.
pub const KEPT_BYTES: usize = 1 << 30;

/// The freed large blocks kept: address and usable length (0 for an empty slot).
struct Kept {
    blocks: [(usize, usize); KEPT_BLOCKS],
    bytes: usize,
}

static KEPT: std::sync::Mutex<Kept> = std::sync::Mutex::new(Kept {
    blocks: [(0, 0); KEPT_BLOCKS],
    bytes: 0,
});

/// Whether [`Allocator`] keeps freed large blocks (it does unless told not to).
static KEEPING: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(true);

/// Tells [`Allocator`] whether to keep freed large blocks for reuse (the default) or to give
/// every one back to the system at once; turning it off gives back the blocks kept so far.
pub fn keep_freed_blocks(on: bool) {
    let blocks = {
        let mut kept = kept();
        KEEPING.store(on, std::sync::atomic::Ordering::Relaxed);
        if on {
            return;
        }
        kept.bytes = 0;
        std::mem::take(&mut kept.blocks)
    };
    for (address, len) in blocks.into_iter().filter(|&(_, len)| len > 0) {
        // SAFETY: a kept block came from `System` with alignment 16 or less (see
        // `Allocator`), which frees by pointer alone; it is out of the cache, so no one else
        // holds it.
        unsafe {
            System.dealloc(
                address as *mut u8,
                Layout::from_size_align_unchecked(len, 16),
            )
        };
    }
}

fn kept() -> std::sync::MutexGuard<'static, Kept> {
    // Nothing panics while the lock is held; a poisoned lock still holds consistent slots.
    KEPT.lock().unwrap_or_else(|e| e.into_inner())
}

/// The length [`Allocator`] asks the system for in place of `layout`'s, when the block is large
/// (whole huge pages, so a kept block fits any later request that rounds to its length or
/// less), or `None` for a block it leaves alone: small, over-aligned (the system allocator's
/// aligned blocks are not interchangeable with plain ones), or too large to round.
fn large_length(size: usize, align: usize) -> Option<usize> {
    // 16 is the system allocator's plain alignment on 64-bit targets only.
    (cfg!(target_pointer_width = "64") && size >= MIN_BYTES && align <= 16)
        .then(|| size.checked_next_multiple_of(HUGE_PAGE))
        .flatten()
        .filter(|&bytes| bytes <= isize::MAX as usize - align)
}

/// A kept block of at least `bytes` (and at most half as much again, so a small request does
/// not take a much larger block), taken out of the cache.
fn take_kept(bytes: usize) -> Option<*mut u8> {
    let mut kept = kept();
    let best = (0..KEPT_BLOCKS)
        .filter(|&i| {
            let len = kept.blocks[i].1;
            len >= bytes && len - bytes <= bytes / 2
        })
        .min_by_key(|&i| kept.blocks[i].1)?;
    let (address, len) = std::mem::take(&mut kept.blocks[best]);
    kept.bytes -= len;
    Some(address as *mut u8)
}

/// Keeps the freed block at `block`, at least `bytes` long, when a slot and the byte budget
/// allow; `false` when the caller must free it.
fn keep(block: *mut u8, bytes: usize) -> bool {
    let mut kept = kept();
    // Read under the lock, so no block is kept after `keep_freed_blocks(false)` drained them.
    if !KEEPING.load(std::sync::atomic::Ordering::Relaxed) {
        return false;
    }
    if kept.bytes + bytes > KEPT_BYTES {
        return false;
    }
    let Some(slot) = kept.blocks.iter().position(|&(_, len)| len == 0) else {
        return false;
    };
    kept.blocks[slot] = (block as usize, bytes);
    kept.bytes += bytes;
    true
}

/// The system allocator, with every allocation of at least 4 MiB advised onto huge pages before
/// the caller first writes it (a grown reallocation too), and freed large blocks kept for the
/// next large allocation (see the module's notes). Install it with
/// `#[global_allocator] static ALLOCATOR: raypick::huge_pages::Allocator = raypick::huge_pages::Allocator;`.
#[derive(Clone, Copy, Debug, Default)]
pub struct Allocator;

// SAFETY: every call is forwarded to `System`, with the caller's alignment and at least the
// caller's size (a large block's length rounded up to whole huge pages: `large_length`). A kept
// block came from `System` at a length of at least the one recorded with it (the rounded length
// of the request that freed it, never more than it was allocated with, as each request's length
// rounds the same way), with alignment 16 or less, and is handed out only once, to a request of
// at most that length and alignment 16 or less; it is freed through `System` like any other.
// The advice touches no memory and only hints how the kernel backs the block just returned.
unsafe impl GlobalAlloc for Allocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let Some(bytes) = large_length(layout.size(), layout.align()) else {
            // SAFETY: forwarded with the caller's layout.
            return unsafe { System.alloc(layout) };
        };
        if let Some(block) = take_kept(bytes) {
            return block;
        }
        // SAFETY: the caller's alignment, a length of at least the caller's (`large_length`
        // checked that it fits in usize, and a multiple of a power of two below isize::MAX
        // rounded from a valid layout's size is valid too).
        let block =
            unsafe { System.alloc(Layout::from_size_align_unchecked(bytes, layout.align())) };
        advise_block(block, bytes);
        block
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // Zeroed memory this large comes fresh from the kernel (mmap) and is not touched by the
        // system allocator, so the advice still lands before the first write. Kept blocks are
        // not zero, so they are not used here.
        let Some(bytes) = large_length(layout.size(), layout.align()) else {
            // SAFETY: forwarded with the caller's layout.
            return unsafe { System.alloc_zeroed(layout) };
        };
        // SAFETY: as in `alloc`.
        let block = unsafe {
            System.alloc_zeroed(Layout::from_size_align_unchecked(bytes, layout.align()))
        };
        advise_block(block, bytes);
        block
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        if let Some(bytes) = large_length(layout.size(), layout.align())
            && keep(ptr, bytes)
        {
            return;
        }
        // SAFETY: forwarded with the caller's pointer and layout (for alignment 16 or less the
        // system allocator frees by pointer alone, whatever length the block was given).
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let bytes = large_length(new_size, layout.align()).unwrap_or(new_size);
        // SAFETY: forwarded with the caller's pointer and layout, at a length of at least the
        // caller's new size (as in `alloc`).
        let block = unsafe { System.realloc(ptr, layout, bytes) };
        if new_size > layout.size() {
            advise_block(block, bytes);
        }
        block
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn freed_large_blocks_are_reused_but_never_for_zeroed_memory() {
        let allocator = Allocator;
        let layout = Layout::from_size_align(10 << 20, 8).unwrap();
        // SAFETY: each block is written within its layout and freed once, with its layout.
        unsafe {
            let first = allocator.alloc(layout);
            assert!(!first.is_null());
            first.write_bytes(0xab, layout.size());
            allocator.dealloc(first, layout);
            let again = allocator.alloc(layout);
            assert_eq!(again, first, "the freed block is handed back");
            allocator.dealloc(again, layout);
            let zeroed = allocator.alloc_zeroed(layout);
            let bytes = std::slice::from_raw_parts(zeroed, layout.size());
            assert!(bytes.iter().all(|&b| b == 0), "a zeroed block is zero");
            allocator.dealloc(zeroed, layout);
            // A request much smaller than every kept block gets a fresh one.
            let small = Layout::from_size_align(MIN_BYTES, 8).unwrap();
            let fresh = allocator.alloc(small);
            assert_ne!(fresh, first);
            fresh.write_bytes(1, small.size());
            allocator.dealloc(fresh, small);
            // Over-aligned blocks are left to the system.
            let aligned = Layout::from_size_align(6 << 20, 4096).unwrap();
            let block = allocator.alloc(aligned);
            assert_eq!(block as usize % 4096, 0);
            allocator.dealloc(block, aligned);
        }
        {
            let kept = kept();
            assert!(kept.bytes > 0 && kept.bytes <= KEPT_BYTES);
            assert_eq!(
                kept.bytes,
                kept.blocks.iter().map(|&(_, len)| len).sum::<usize>()
            );
        }
        // Turned off, the kept blocks go back and no freed block is kept.
        keep_freed_blocks(false);
        assert_eq!(kept().bytes, 0);
        // SAFETY: as above.
        unsafe {
            let block = allocator.alloc(layout);
            block.write_bytes(2, layout.size());
            allocator.dealloc(block, layout);
        }
        assert_eq!(kept().bytes, 0);
        keep_freed_blocks(true);
    }
}
