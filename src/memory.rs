//! The memory budget: one limit that the large allocations are checked against before they
//! are made (voxelization, solid fill, textures, frames and their AOVs, the path-traced
//! reference, animated GIF frames, GI volumes), so that an input asking for too much gets an
//! error that says what to change instead of an out-of-memory abort.
//!
//! The budget is process-wide (the CLI sets it from `--memory-budget`); by default it is
//! three quarters of the smaller of the machine's memory and the process's address-space
//! limit (`ulimit -v`). Estimates are of what the data structures really hold, peak
//! included, not of what the input file weighs.

use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};

/// 0: not set, use [`default_budget`].
static BUDGET: AtomicU64 = AtomicU64::new(0);

thread_local! {
    /// This thread's own budget ([`with_budget`]); 0: the process's.
    static THREAD_BUDGET: Cell<u64> = const { Cell::new(0) };
}

/// A large allocation the budget refused.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("{what} needs about {}, more than the memory budget of {}; {advice}", size(*need), size(*budget))]
pub struct MemoryError {
    /// What was to be allocated.
    pub what: String,
    /// Bytes it needs (estimated before allocating).
    pub need: u64,
    /// The budget in bytes.
    pub budget: u64,
    /// What to change.
    pub advice: String,
}

/// Bytes as KiB/MiB/GiB with one decimal.
pub fn size(bytes: u64) -> String {
    let b = bytes as f64;
    match bytes {
        0..=1023 => format!("{bytes} B"),
        1024..=1_048_575 => format!("{:.1} KiB", b / 1024.0),
        1_048_576..=1_073_741_823 => format!("{:.1} MiB", b / 1_048_576.0),
        _ => format!("{:.1} GiB", b / 1_073_741_824.0),
    }
}

/// Parses a size such as `512M`, `4G`, `1.5GiB` or `1000000` (bytes); K, M, G and T are
/// powers of 1024.
pub fn parse_size(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let digits = t.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(t.len());
    let (num, unit) = t.split_at(digits);
    let v: f64 = num.parse().map_err(|_| format!("'{s}' is not a size (e.g. 512M, 4G)"))?;
    let mult: f64 = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1.0,
        "k" | "kb" | "kib" => 1024.0,
        "m" | "mb" | "mib" => 1024.0 * 1024.0,
        "g" | "gb" | "gib" => 1024.0 * 1024.0 * 1024.0,
        "t" | "tb" | "tib" => 1024.0f64.powi(4),
        u => return Err(format!("'{s}': unknown unit '{u}' (use K, M, G or T)")),
    };
    let bytes = v * mult;
    if !(1.0..1.8e19).contains(&bytes) {
        return Err(format!("'{s}' is not a usable memory size"));
    }
    Ok(bytes as u64)
}

/// Sets the budget (bytes; 0 goes back to the default).
pub fn set_budget(bytes: u64) {
    BUDGET.store(bytes, Ordering::Relaxed);
}

/// The budget in bytes: the calling thread's own ([`with_budget`]) or the process's.
pub fn budget() -> u64 {
    match (THREAD_BUDGET.with(Cell::get), BUDGET.load(Ordering::Relaxed)) {
        (0, 0) => default_budget(),
        (0, b) | (b, _) => b,
    }
}

/// The calling thread's own budget as [`with_budget`] set it (0: the process's).
#[cfg(feature = "parallel")]
pub(crate) fn thread_budget() -> u64 {
    THREAD_BUDGET.with(Cell::get)
}

/// Runs `work` with the calling thread's budget set to `bytes`, other threads keeping the
/// process's: jobs side by side in one process, each under its own limit. The checks run on
/// the thread that asks for the memory, before worker threads start, so they see it.
pub fn with_budget<T>(bytes: u64, work: impl FnOnce() -> T) -> T {
    /// Puts the previous budget back, also when `work` panics.
    struct Restore(u64);
    impl Drop for Restore {
        fn drop(&mut self) {
            THREAD_BUDGET.with(|b| b.set(self.0));
        }
    }
    let _restore = Restore(THREAD_BUDGET.with(|b| b.replace(bytes)));
    work()
}

/// Three quarters of the smaller of physical memory and the address-space limit (8 GiB
/// where neither can be read).
pub fn default_budget() -> u64 {
    let total = machine_memory();
    let limit = address_space_limit();
    let base = match (total, limit) {
        (Some(t), Some(l)) => t.min(l),
        (Some(t), None) => t,
        (None, Some(l)) => l,
        (None, None) => 8 << 30,
    };
    base / 4 * 3
}

/// Physical memory (Linux: `/proc/meminfo`'s MemTotal).
pub fn machine_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// The soft address-space limit (`ulimit -v`; Linux: `/proc/self/limits`), if any.
pub fn address_space_limit() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/self/limits").ok()?;
    let line = text.lines().find(|l| l.starts_with("Max address space"))?;
    line.split_whitespace().nth(3)?.parse().ok()
}

/// Checks that `need` bytes for `what` fit the budget.
pub fn check(what: &str, need: u64, advice: &str) -> Result<(), MemoryError> {
    check_against(budget(), what, need, advice)
}

/// [`check`] against a given budget.
pub fn check_against(budget: u64, what: &str, need: u64, advice: &str) -> Result<(), MemoryError> {
    if need > budget {
        return Err(MemoryError { what: what.into(), need, budget, advice: advice.into() });
    }
    Ok(())
}

/// Peak bytes per voxel while a part is voxelized and built: the per-triangle entries and
/// their sort, the merged voxels, then the levels of the octree and its attributes. Measured:
/// `voxray voxelize --obj models/test/cube.obj --depth 10` peaks at 963 MB of resident
/// memory for 6.28 million voxels (157 bytes each); 14 400 needles at depth 12 (a tree with
/// almost a node per voxel) at 12.5 GB for 59.0 million (212 bytes each).
pub const VOXELIZE_BYTES_PER_VOXEL: u64 = 220;

/// Bytes per pixel of a rendered frame with its AOVs, the hit records, the hit buffer kept
/// for the next frame and the 8-bit image written out. Measured: a 2048×2048 render of the
/// test cube with `--aov-dir` peaks at 553 MB resident (132 bytes a pixel), one frame or three.
pub const FRAME_BYTES_PER_PIXEL: u64 = 160;

/// Bytes per pixel the path-traced reference adds to a frame's (its radiance sums and
/// sample state; a 1024×1024 `--reference` peaks at 221 MB resident, 211 bytes a pixel in all).
pub const REFERENCE_BYTES_PER_PIXEL: u64 = 96;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_and_print() {
        assert_eq!(parse_size("512M"), Ok(512 << 20));
        assert_eq!(parse_size("4G"), Ok(4 << 30));
        assert_eq!(parse_size("1.5GiB"), Ok(3 << 29));
        assert_eq!(parse_size("1000"), Ok(1000));
        assert!(parse_size("4X").is_err() && parse_size("").is_err() && parse_size("0").is_err());
        assert!(parse_size("1e30").is_err() && parse_size("-1G").is_err());
        assert_eq!(size(3 << 29), "1.5 GiB");
        assert_eq!(size(2048), "2.0 KiB");
    }

    #[test]
    fn the_budget_refuses_what_exceeds_it() {
        // (The process-wide budget is left alone: other tests run beside this one.)
        assert!(check_against(1 << 20, "a", 1 << 20, "").is_ok());
        let e = check_against(1 << 20, "a frame", 3 << 20, "lower the resolution").unwrap_err();
        assert_eq!(
            e.to_string(),
            "a frame needs about 3.0 MiB, more than the memory budget of 1.0 MiB; lower the resolution"
        );
        assert!(default_budget() >= 1 << 20);
    }

    #[test]
    fn a_thread_budget_applies_to_its_thread_only() {
        let outer = budget();
        let (inner, other) = with_budget(4096, || {
            let other = std::thread::spawn(budget).join().unwrap_or(0);
            (budget(), other)
        });
        assert_eq!((inner, other, budget()), (4096, outer, outer));
        assert!(with_budget(4096, || check("x", 5000, "")).is_err());
        assert!(check("x", 5000, "").is_ok());
    }
}
