//! Scene files other than OBJ: glTF 2.0 (`.gltf` with its buffers and images, `.glb`; feature
//! `gltf`) and MagicaVoxel `.vox` (feature `vox`), with their node hierarchy and animation as
//! a [`Rig`]. Which loader a file needs is
//! told by its first bytes, then by its extension ([`SceneKind::of`]).

#[cfg(feature = "gltf")]
pub mod gltf;
#[cfg(feature = "vox")]
pub mod vox;

use crate::mesh::Mesh;
use crate::scene::animation::Rig;
use std::path::Path;

/// Largest glTF JSON, GLB or external buffer read.
pub const MAX_GLTF_BYTES: u64 = 2 << 30;
/// Largest image file a glTF material may refer to.
pub const MAX_IMAGE_BYTES: u64 = 256 << 20;

/// Why a scene file could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    /// Reading the file (or a file it refers to) failed or it was too large.
    #[error(transparent)]
    Input(#[from] crate::input::InputError),
    /// The file is malformed or uses what voxray does not support; `element` names where.
    #[error("{path}: {element}: {message}")]
    Invalid {
        /// The file.
        path: String,
        /// The element: "buffer 2", "mesh 'wheel' primitive 0", "animation 'drive' channel 3".
        element: String,
        /// What is wrong.
        message: String,
    },
    /// The build lacks the loader.
    #[error("{path}: reading {what} needs the `{feature}` feature, which this build lacks")]
    Unsupported {
        /// The file.
        path: String,
        /// The format.
        what: &'static str,
        /// The cargo feature.
        feature: &'static str,
    },
}

/// The formats of scene files.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SceneKind {
    /// Wavefront OBJ (with MTL).
    Obj,
    /// glTF 2.0, JSON or binary.
    Gltf,
    /// MagicaVoxel.
    Vox,
    /// voxray's own SVO file.
    Svo,
}

impl SceneKind {
    /// The format of `path`: by its first bytes (GLB, `.svo` and MagicaVoxel magic numbers,
    /// a JSON object with a glTF `asset`), else by extension, else OBJ (which has no magic
    /// number, and was the only format before the others: its loader says what is wrong).
    pub fn of(path: &Path) -> Result<SceneKind, ImportError> {
        let mut head = [0u8; 4096];
        let n = {
            use std::io::Read;
            let mut f = std::fs::File::open(path).map_err(|source| match source.kind() {
                std::io::ErrorKind::NotFound => crate::input::InputError::NotFound { path: path.display().to_string() },
                _ => crate::input::InputError::Io { path: path.display().to_string(), source },
            })?;
            let mut n = 0;
            while n < head.len() {
                match f.read(&mut head[n..]) {
                    Ok(0) => break,
                    Ok(k) => n += k,
                    Err(source) => {
                        return Err(crate::input::InputError::Io { path: path.display().to_string(), source }.into())
                    }
                }
            }
            n
        };
        let head = &head[..n];
        if head.starts_with(b"glTF") {
            return Ok(SceneKind::Gltf);
        }
        if head.starts_with(b"VOX ") {
            return Ok(SceneKind::Vox);
        }
        if head.starts_with(&crate::svo::io::MAGIC) {
            return Ok(SceneKind::Svo);
        }
        let ext = path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
        let text = String::from_utf8_lossy(head);
        let json_gltf = text.trim_start().starts_with('{') && text.contains("\"asset\"");
        match ext.as_str() {
            "gltf" | "glb" => Ok(SceneKind::Gltf),
            "svo" => Ok(SceneKind::Svo),
            "vox" => Ok(SceneKind::Vox),
            "obj" => Ok(SceneKind::Obj),
            _ if json_gltf => Ok(SceneKind::Gltf),
            _ => Ok(SceneKind::Obj),
        }
    }
}

/// A scene file's triangles and the hierarchy that places and animates them: node `k` with
/// `part: Some(p)` places `mesh.parts[p]`.
#[derive(Clone, Debug, Default)]
pub struct Imported {
    /// The parts, one per mesh the scene uses, and their materials.
    pub mesh: Mesh,
    /// Nodes and animation clips.
    pub rig: Rig,
}

/// Loads a glTF 2.0 file (`.gltf` or `.glb`).
pub fn load_gltf(path: &Path) -> Result<Imported, ImportError> {
    #[cfg(feature = "gltf")]
    {
        gltf::load(path)
    }
    #[cfg(not(feature = "gltf"))]
    {
        Err(ImportError::Unsupported { path: path.display().to_string(), what: "glTF", feature: "gltf" })
    }
}

/// Loads a MagicaVoxel `.vox` file: its models as SVOs, its scene graph as a rig.
#[cfg(feature = "vox")]
pub fn load_vox(path: &Path) -> Result<vox::VoxScene, ImportError> {
    vox::load(path)
}

/// [`load_vox`], calling `progress(models built, models)` as each model's SVO is done.
#[cfg(feature = "vox")]
pub fn load_vox_with_progress(path: &Path, progress: &dyn Fn(usize, usize)) -> Result<vox::VoxScene, ImportError> {
    vox::load_with_progress(path, progress)
}
