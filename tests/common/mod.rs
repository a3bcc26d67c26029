//! Helpers shared by the integration tests.

use std::path::{Path, PathBuf};

/// A scratch folder of one test, removed when the test ends (pass or fail).
pub struct TempDir(PathBuf);

impl TempDir {
    /// An empty folder `<temp>/<prefix>-<process>-<name>` (what an earlier run left there is
    /// removed first).
    pub fn new(prefix: &str, name: &str) -> TempDir {
        let d = std::env::temp_dir().join(format!("{prefix}-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        TempDir(d)
    }
}

impl std::ops::Deref for TempDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for TempDir {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}
