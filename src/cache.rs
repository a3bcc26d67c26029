//! An on-disk cache of built SVOs, keyed by a hash of everything that determines the
//! result: the part's triangles and materials (so an edited OBJ, MTL or texture misses),
//! the voxelizer settings and the format and builder versions.

use crate::mesh::{Material, Part};
use crate::svo::io::{load, save, SvoFileError, VERSION};
use crate::svo::Svo;
use crate::voxelize::{Resolution, VoxelizeOptions};
use std::path::PathBuf;

/// Bump when the voxelizer or builder changes what they produce for the same input.
pub const BUILDER_VERSION: u32 = 2;

/// A folder of cached `.svo` files.
#[derive(Clone, Debug)]
pub struct SvoCache {
    /// Where the files live.
    pub dir: PathBuf,
}

impl SvoCache {
    /// The default folder: `$VOXRAY_CACHE_DIR`, else `$XDG_CACHE_HOME/voxray`, else
    /// `$HOME/.cache/voxray`.
    pub fn default_dir() -> Option<PathBuf> {
        if let Some(d) = std::env::var_os("VOXRAY_CACHE_DIR") {
            return Some(PathBuf::from(d));
        }
        if let Some(d) = std::env::var_os("XDG_CACHE_HOME") {
            return Some(PathBuf::from(d).join("voxray"));
        }
        std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache").join("voxray"))
    }

    /// The file a key maps to.
    pub fn path(&self, key: u64) -> PathBuf {
        self.dir.join(format!("{key:016x}.svo"))
    }

    /// A cached SVO: `None` if absent, `Some(Err)` if present but unreadable or corrupt.
    pub fn load(&self, key: u64) -> Option<Result<Svo, SvoFileError>> {
        let p = self.path(key);
        p.exists().then(|| load(&p))
    }

    /// Stores an SVO (atomically; creates the folder).
    pub fn store(&self, key: u64, svo: &Svo) -> Result<(), SvoFileError> {
        std::fs::create_dir_all(&self.dir)
            .map_err(|source| SvoFileError::Io { path: self.dir.display().to_string(), source })?;
        save(svo, &self.path(key))
    }
}

/// 64-bit FNV-1a, streamed.
struct Fnv(u64);
impl Fnv {
    fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 = (self.0 ^ x as u64).wrapping_mul(0x100_0000_01b3);
        }
    }
    fn f32s(&mut self, v: &[f32]) {
        for x in v {
            self.bytes(&x.to_le_bytes());
        }
    }
}

/// The cache key of a part voxelized with `opts`.
pub fn part_key(part: &Part, materials: &[Material], opts: &VoxelizeOptions) -> u64 {
    let mut h = Fnv(0xcbf2_9ce4_8422_2325);
    h.bytes(&VERSION.to_le_bytes());
    h.bytes(&BUILDER_VERSION.to_le_bytes());
    match opts.resolution {
        Resolution::Depth(d) => h.bytes(&[b'd', d as u8]),
        Resolution::VoxelSize(v) => {
            h.bytes(b"v");
            h.f32s(&[v]);
        }
    }
    h.bytes(&[opts.solid as u8]);
    h.bytes(part.name.as_bytes());
    for t in &part.triangles {
        for p in t.positions {
            h.f32s(&p.to_array());
        }
        if let Some(uv) = t.uvs {
            for u in uv {
                h.f32s(&u.to_array());
            }
        }
        h.bytes(&t.material.to_le_bytes());
    }
    for m in materials {
        h.f32s(&m.albedo.to_array());
        h.f32s(&m.emission.to_array());
        h.f32s(&[m.specular, m.shininess]);
        if let Some(t) = &m.texture {
            h.bytes(&t.width.to_le_bytes());
            for c in &t.texels {
                h.f32s(&c.to_array());
            }
        }
    }
    h.0
}
