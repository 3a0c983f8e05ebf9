//! Cache hints: asking for memory a few steps before it is read, so that several cache misses
//! are in flight at once instead of one after another. Only hints: they never fault, whatever
//! the address, and change no result. Elsewhere than x86-64 they do nothing.

/// Asks for the cache lines of the `bytes` bytes from `start` (at least one line).
#[inline(always)]
pub fn bytes(start: *const u8, bytes: usize) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        let start = start as *const i8;
        let mut offset = 0;
        while offset < bytes {
            // SAFETY: a prefetch reads nothing and never faults; SSE is part of x86-64.
            unsafe { _mm_prefetch(start.wrapping_add(offset), _MM_HINT_T0) };
            offset += 64;
        }
        // SAFETY: as above (the last line, when the range does not start on a line).
        unsafe { _mm_prefetch(start.wrapping_add(bytes.max(1) - 1), _MM_HINT_T0) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (start, bytes);
}

/// Asks for `items[index]`, if it exists.
#[inline(always)]
pub fn item<T>(items: &[T], index: usize) {
    if index < items.len() {
        bytes(
            items.as_ptr().wrapping_add(index) as *const u8,
            size_of::<T>(),
        );
    }
}
