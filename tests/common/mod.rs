//! Helpers shared by the integration tests.

// Each test binary that includes this uses some of the helpers, not all.
#![allow(dead_code)]

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

/// Two frames agree bit for bit: every pixel's t, instance and normal, and the image.
pub fn assert_same_frames(a: &voxray::render::Frame, b: &voxray::render::Frame, what: &str) {
    for k in 0..a.t.len() {
        assert_eq!(a.t[k].to_bits(), b.t[k].to_bits(), "{what}, pixel {k}: t");
        assert_eq!(a.instance[k], b.instance[k], "{what}, pixel {k}: instance");
        assert_eq!(
            a.normal[k].to_array().map(f32::to_bits),
            b.normal[k].to_array().map(f32::to_bits),
            "{what}, pixel {k}: normal"
        );
    }
    assert_eq!(a.radiance, b.radiance, "{what}: image");
}

/// The GPU device the tests of one binary share (made once); None, with a message, where
/// there is no adapter, except in CI (CI=true), which has the software Vulkan driver and
/// fails without it.
#[cfg(feature = "gpu")]
pub fn gpu_context() -> Option<std::sync::Arc<voxray::gpu::GpuContext>> {
    use std::sync::{Arc, OnceLock};
    use voxray::gpu::GpuContext;
    static CTX: OnceLock<Result<Arc<GpuContext>, String>> = OnceLock::new();
    match CTX.get_or_init(|| GpuContext::headless().map(Arc::new).map_err(|e| e.to_string())) {
        Ok(c) => Some(c.clone()),
        Err(e) if std::env::var("CI").is_ok_and(|v| v == "true") => {
            panic!("CI needs a GPU adapter (software Vulkan): {e}")
        }
        Err(e) => {
            eprintln!("skipping GPU test: {e}");
            None
        }
    }
}
