//! Files being written: each output is written to a temporary sibling and renamed into place
//! once complete, and the temporaries in flight are listed here so that an interrupted run
//! (the CLI's Ctrl-C handler) can remove them before it exits. Finished files are kept; none
//! is left half-written, under its own name or a temporary one.

use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// Temporaries being written now.
static IN_FLIGHT: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// A temporary file in flight; it leaves the list when dropped (renamed or removed by then).
pub(crate) struct Partial {
    path: PathBuf,
}

impl Partial {
    /// Lists `path` as being written.
    pub(crate) fn new(path: PathBuf) -> Partial {
        IN_FLIGHT.lock().unwrap_or_else(|p| p.into_inner()).push(path.clone());
        Partial { path }
    }

    /// Its path.
    pub(crate) fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for Partial {
    fn drop(&mut self) {
        let mut list = IN_FLIGHT.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(i) = list.iter().position(|p| *p == self.path) {
            list.swap_remove(i);
        }
    }
}

/// Removes every temporary file being written now and returns how many there were: for a
/// process about to exit mid-write (Ctrl-C). Writers still running may fail afterwards; the
/// caller exits.
pub fn remove_in_flight() -> usize {
    let list = std::mem::take(&mut *IN_FLIGHT.lock().unwrap_or_else(|p| p.into_inner()));
    for p in &list {
        let _ = std::fs::remove_file(p);
    }
    list.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn in_flight_files_are_listed_until_dropped_and_removed_on_request() {
        let dir = std::env::temp_dir().join(format!("voxray-partial-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (a, b) = (dir.join("a.tmp"), dir.join("b.tmp"));
        std::fs::write(&a, b"a").unwrap();
        std::fs::write(&b, b"b").unwrap();
        let done = Partial::new(a.clone());
        let writing = Partial::new(b.clone());
        drop(done); // renamed into place by its writer: no longer ours to remove
        assert!(IN_FLIGHT.lock().unwrap().contains(&b));
        remove_in_flight();
        assert!(a.exists() && !b.exists());
        drop(writing);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
