//! Files being written: each output is written to a temporary sibling and renamed into place
//! once complete, and the temporaries in flight are listed here so that an interrupted run
//! (the CLI's Ctrl-C handler) can remove them before it exits. Finished files are kept; none
//! is left half-written, under its own name or a temporary one.
//!
//! A temporary is created only here, under the list's lock, and written through the handle
//! returned with it (never reopened by name): so once [`stop_writes`] has removed the list's
//! files and holds the lock, no writer can create one again before the process exits.

use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};

/// A list of temporaries being written.
struct Registry(Mutex<Vec<PathBuf>>);

impl Registry {
    const fn new() -> Registry {
        Registry(Mutex::new(Vec::new()))
    }

    fn lock(&self) -> MutexGuard<'_, Vec<PathBuf>> {
        self.0.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn create(&'static self, path: PathBuf) -> std::io::Result<(Partial, File)> {
        let mut list = self.lock();
        let file = File::create(&path)?;
        list.push(path.clone());
        Ok((Partial { path, registry: self }, file))
    }

    fn stop(&'static self) -> Stopped {
        let mut held = self.lock();
        let list = std::mem::take(&mut *held);
        for p in &list {
            let _ = std::fs::remove_file(p);
        }
        Stopped { removed: list.len(), _held: held }
    }
}

/// The process's temporaries being written now.
static IN_FLIGHT: Registry = Registry::new();

/// A temporary file in flight; it leaves the list when dropped (renamed or removed by then).
pub(crate) struct Partial {
    path: PathBuf,
    registry: &'static Registry,
}

impl Partial {
    /// Creates (or truncates) the temporary file `path`, lists it as being written and returns
    /// the handle to write it through. Blocks while [`stop_writes`] holds the list (the
    /// process is exiting).
    pub(crate) fn create(path: PathBuf) -> std::io::Result<(Partial, File)> {
        IN_FLIGHT.create(path)
    }

    /// Its path.
    pub(crate) fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for Partial {
    fn drop(&mut self) {
        let mut list = self.registry.lock();
        if let Some(i) = list.iter().position(|p| *p == self.path) {
            list.swap_remove(i);
        }
    }
}

/// What [`stop_writes`] did; while it lives no temporary can be created or leave the list.
pub struct Stopped {
    /// How many temporaries were being written (and were removed).
    pub removed: usize,
    _held: MutexGuard<'static, Vec<PathBuf>>,
}

/// Removes every temporary file being written now and keeps any other from being created
/// while the returned value lives: for a process about to exit mid-write (Ctrl-C), which
/// holds it until it exits. Writers still running may fail or block afterwards.
pub fn stop_writes() -> Stopped {
    IN_FLIGHT.stop()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    /// Its own list, so that stopping it touches no other test's files.
    static MINE: Registry = Registry::new();

    #[test]
    fn in_flight_files_are_listed_until_dropped_and_removed_on_request() {
        let dir = std::env::temp_dir().join(format!("voxray-partial-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (a, b) = (dir.join("a.tmp"), dir.join("b.tmp"));
        let (done, mut fa) = MINE.create(a.clone()).unwrap();
        let (writing, mut fb) = MINE.create(b.clone()).unwrap();
        fa.write_all(b"a").unwrap();
        drop(done); // renamed into place by its writer: no longer ours to remove
        assert!(MINE.lock().contains(&b));
        let stopped = MINE.stop();
        assert_eq!(stopped.removed, 1);
        assert!(a.exists() && !b.exists());
        // A writer still holding its handle writes into the removed file, not a new one.
        fb.write_all(b"b").unwrap();
        assert!(!b.exists());
        // While stopped, no temporary can be created.
        let c = dir.join("c.tmp");
        let creator = std::thread::spawn({
            let c = c.clone();
            move || MINE.create(c).map(|(p, _)| p)
        });
        std::thread::sleep(std::time::Duration::from_millis(50));
        assert!(!c.exists() && !creator.is_finished());
        drop(stopped);
        drop(creator.join().unwrap().unwrap());
        assert!(c.exists());
        drop(writing);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
