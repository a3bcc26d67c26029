//! Cache hints: asking for memory a walk will read soon, so that the load overlaps other
//! work instead of stalling it (a crowd's prepared instances and an octree hit's attributes
//! are scattered over megabytes).

/// Asks the cache for the line at `p` without waiting for it (no-op off x86-64).
#[inline(always)]
pub fn prefetch<T>(p: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: SSE is part of x86-64's baseline, and a prefetch reads nothing and cannot fault,
    // whatever the address.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(p.cast())
    };
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

/// Asks for every cache line of the first `bytes` bytes at `p` (no-op off x86-64).
#[inline(always)]
pub fn prefetch_bytes<T>(p: *const T, bytes: usize) {
    let start = p.cast::<u8>();
    // The first line, each line start after it, and the line of the last byte.
    let mut at = 0;
    while at < bytes {
        prefetch(start.wrapping_add(at));
        at += 64;
    }
    prefetch(start.wrapping_add(bytes.saturating_sub(1)));
}
