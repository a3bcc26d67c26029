//! A fixed-capacity stack whose storage is left uninitialized, for the traversal walks that
//! make one per ray: zeroing a kilobyte per walk was 3 % of a crowd frame's samples (the
//! instance BVH's walk) and 4 % of a depth-11 frame's (the octree's lone walks).

use std::mem::MaybeUninit;

/// Up to `N` entries of plain `Copy` data; an entry is read only after it was pushed.
pub struct UninitStack<T: Copy, const N: usize> {
    items: [MaybeUninit<T>; N],
    len: usize,
}

impl<T: Copy, const N: usize> UninitStack<T, N> {
    /// An empty stack.
    #[inline(always)]
    pub fn new() -> Self {
        UninitStack { items: [const { MaybeUninit::uninit() }; N], len: 0 }
    }

    /// Pushes an entry. Callers size `N` so that it cannot fill (a tree's depth bounds it);
    /// a push beyond it is a bug, caught in debug builds.
    #[inline(always)]
    pub fn push(&mut self, v: T) {
        debug_assert!(self.len < N, "stack of {N} entries full");
        if self.len < N {
            self.items[self.len] = MaybeUninit::new(v);
            self.len += 1;
        }
    }

    /// Pops the entry pushed last; `None` when empty.
    #[inline(always)]
    pub fn pop(&mut self) -> Option<T> {
        self.len = self.len.checked_sub(1)?;
        // SAFETY: `len` grows only in `push`, after the entry at the old `len` is written, so
        // every entry below it, this one included, holds a value (plain `Copy` data).
        Some(unsafe { self.items[self.len].assume_init() })
    }
}

impl<T: Copy, const N: usize> Default for UninitStack<T, N> {
    fn default() -> Self {
        Self::new()
    }
}
