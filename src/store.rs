//! The arrays a scene and its trees keep: this module owns [`Store`], an array that is either an
//! owned vector or a view into a mapped `.rpk` file.
//!
//! Built scenes own their arrays. A `.rpk` loaded in place ([`crate::rpk::load_in_place`])
//! leaves its largest sections in the file's mapped pages instead of copying them: the page
//! cache holds them already, so a process that picks from a saved scene touches no fresh memory
//! for them (on a virtual machine, fresh memory is what loading costs most). Reading is the
//! same either way ([`Deref`] to a slice); writing ([`DerefMut`], [`Store::to_mut`]) copies a
//! mapped array into an owned one first.

use bytemuck::Pod;
use std::fmt;
use std::ops::{Deref, DerefMut, Range};
use std::sync::Arc;

/// An array of `T`: owned, or a view of part of a read-only mapped file (see the module docs).
pub struct Store<T: Pod>(Repr<T>);

enum Repr<T> {
    Owned(Vec<T>),
    Mapped {
        /// Keeps the mapping alive while the view exists.
        _map: Arc<memmap2::Mmap>,
        start: *const T,
        len: usize,
    },
}

// SAFETY: a mapped view only reads a read-only mapping, which it keeps alive through an `Arc`;
// sending it is sending a `&[T]`, which needs `T: Sync`, as an owned vector needs `T: Send`.
unsafe impl<T: Pod + Send + Sync> Send for Store<T> {}
// SAFETY: sharing it is sharing a `&[T]`.
unsafe impl<T: Pod + Sync> Sync for Store<T> {}

impl<T: Pod> Store<T> {
    /// The bytes `range` of `map` viewed as an array of `T`, in place; `None` when they are not
    /// a whole number of `T`s or not aligned for `T` (the caller copies them instead).
    ///
    /// # Safety
    /// Nothing may write into the mapped file, or shorten it, while the view or any clone of it
    /// exists: the view's contents are checked once, by the caller, and then trusted.
    pub(crate) unsafe fn mapped(map: &Arc<memmap2::Mmap>, range: Range<usize>) -> Option<Self> {
        let items: &[T] = bytemuck::try_cast_slice(map.get(range)?).ok()?;
        Some(Store(Repr::Mapped {
            _map: Arc::clone(map),
            start: items.as_ptr(),
            len: items.len(),
        }))
    }

    /// The array as a slice.
    pub fn as_slice(&self) -> &[T] {
        self
    }

    /// Whether the array is a view of a mapped file.
    pub fn is_mapped(&self) -> bool {
        matches!(self.0, Repr::Mapped { .. })
    }

    /// The array as an owned vector to change, copied out of the mapped file first if it is a
    /// view.
    pub fn to_mut(&mut self) -> &mut Vec<T> {
        if let Repr::Mapped { .. } = self.0 {
            self.0 = Repr::Owned(self.deref().to_vec());
        }
        match &mut self.0 {
            Repr::Owned(v) => v,
            Repr::Mapped { .. } => unreachable!("made owned above"),
        }
    }
}

impl<T: Pod> Deref for Store<T> {
    type Target = [T];

    fn deref(&self) -> &[T] {
        match &self.0 {
            Repr::Owned(v) => v,
            // SAFETY: `start` and `len` came from a slice of the mapping that `_map` keeps
            // alive and that nothing writes (see `Store::mapped`).
            Repr::Mapped { start, len, .. } => unsafe { std::slice::from_raw_parts(*start, *len) },
        }
    }
}

impl<T: Pod> DerefMut for Store<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        self.to_mut()
    }
}

impl<T: Pod> From<Vec<T>> for Store<T> {
    fn from(v: Vec<T>) -> Self {
        Store(Repr::Owned(v))
    }
}

impl<T: Pod> FromIterator<T> for Store<T> {
    fn from_iter<I: IntoIterator<Item = T>>(items: I) -> Self {
        Store(Repr::Owned(items.into_iter().collect()))
    }
}

impl<T: Pod> Default for Store<T> {
    fn default() -> Self {
        Store(Repr::Owned(Vec::new()))
    }
}

impl<T: Pod> Clone for Store<T> {
    fn clone(&self) -> Self {
        match &self.0 {
            Repr::Owned(v) => Store(Repr::Owned(v.clone())),
            Repr::Mapped { _map, start, len } => Store(Repr::Mapped {
                _map: Arc::clone(_map),
                start: *start,
                len: *len,
            }),
        }
    }
}

impl<T: Pod + fmt::Debug> fmt::Debug for Store<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.deref().fmt(f)
    }
}

impl<T: Pod + PartialEq> PartialEq for Store<T> {
    fn eq(&self, other: &Self) -> bool {
        self.deref() == other.deref()
    }
}

impl<'a, T: Pod> IntoIterator for &'a Store<T> {
    type Item = &'a T;
    type IntoIter = std::slice::Iter<'a, T>;

    fn into_iter(self) -> Self::IntoIter {
        self.iter()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mapped_view_reads_the_file_and_copies_before_a_write() {
        let path = std::env::temp_dir().join(format!("store-{}.bin", std::process::id()));
        let words: Vec<u32> = (0..1024).collect();
        std::fs::write(&path, bytemuck::cast_slice(&words)).unwrap();
        let file = std::fs::File::open(&path).unwrap();
        // SAFETY: the test's own file, written above and not changed while mapped.
        let map = Arc::new(unsafe { memmap2::Mmap::map(&file) }.unwrap());
        // SAFETY: as above.
        let mut view: Store<u32> = unsafe { Store::mapped(&map, 16..4096) }.unwrap();
        assert!(view.is_mapped());
        assert_eq!(&view[..], &words[4..]);
        let twin = view.clone();
        view[0] = 7;
        assert!(!view.is_mapped() && twin.is_mapped());
        assert_eq!((view[0], twin[0]), (7, 4));
        assert_eq!((&view[1..], &twin[1..]), (&words[5..], &words[5..]));
        // Not a whole number of u32s, or not aligned: refused, for the caller to copy.
        // SAFETY: as above.
        assert!(unsafe { Store::<u32>::mapped(&map, 16..4095) }.is_none());
        // SAFETY: as above.
        assert!(unsafe { Store::<u32>::mapped(&map, 2..6) }.is_none());
        // SAFETY: as above.
        assert!(unsafe { Store::<u32>::mapped(&map, 16..5000) }.is_none());
        drop((view, twin, map));
        std::fs::remove_file(&path).unwrap();
    }
}
