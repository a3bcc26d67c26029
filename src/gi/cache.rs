//! Voxel caches: a part's voxels as a flat list, built once at load time with the same
//! voxelizer as the SVOs. Coordinates are integers relative to the part's cube corner, packed
//! 10 bits per axis (so a cache is at most 1024 voxels per side — GI voxels are coarse); the
//! attributes are the SVO's packed albedo, normal and emission words.

use crate::mesh::{Material, Part};
use crate::svo::format::morton_decode;
use crate::svo::Attr;
use crate::voxelize::{voxelize, Resolution, VoxelGrid, VoxelizeError, VoxelizeOptions};
use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// Bits per axis of a packed cache coordinate.
pub const COORD_BITS: u32 = 10;
/// Deepest grid a cache can hold (2^10 = 1024 voxels per side).
pub const MAX_CACHE_DEPTH: u32 = COORD_BITS;

/// One cached voxel (16 bytes, the same layout on the GPU).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct CacheVoxel {
    /// x | y << 10 | z << 20, relative to the cube corner.
    pub coord: u32,
    /// Albedo word, as [`Attr::albedo`].
    pub albedo: u32,
    /// Octahedral normal and specular lobe, as [`Attr::normal`].
    pub normal: u32,
    /// Emitted radiance (RGB9E5), as [`Attr::emission`].
    pub emission: u32,
}

impl CacheVoxel {
    /// Integer coordinates.
    pub fn coord(&self) -> [u32; 3] {
        let m = (1u32 << COORD_BITS) - 1;
        [self.coord & m, (self.coord >> COORD_BITS) & m, (self.coord >> (2 * COORD_BITS)) & m]
    }
    /// The packed attributes.
    pub fn attr(&self) -> Attr {
        Attr { albedo: self.albedo, normal: self.normal, emission: self.emission }
    }
}

/// Why a cache could not be built.
#[derive(Debug, thiserror::Error)]
pub enum CacheError {
    /// The grid is finer than the packed coordinates allow.
    #[error("a voxel cache holds at most 2^{MAX_CACHE_DEPTH} voxels per side; depth {0} is too deep")]
    TooDeep(u32),
    /// Voxelizing the part failed.
    #[error(transparent)]
    Voxelize(#[from] VoxelizeError),
}

/// A part's voxels for GI.
#[derive(Clone, Debug, PartialEq)]
pub struct VoxelCache {
    /// Object-space corner of the grid.
    pub corner: Vec3,
    /// Edge of one voxel (object units).
    pub voxel_size: f32,
    /// Grid depth (2^depth voxels per side).
    pub depth: u32,
    /// The voxels.
    pub voxels: Vec<CacheVoxel>,
}

impl VoxelCache {
    /// A cache holding `grid`'s voxels.
    pub fn from_grid(grid: &VoxelGrid) -> Result<Self, CacheError> {
        if grid.depth > MAX_CACHE_DEPTH {
            return Err(CacheError::TooDeep(grid.depth));
        }
        let voxels = grid
            .voxels
            .iter()
            .map(|v| {
                let [x, y, z] = morton_decode(v.code);
                let a = Attr::pack_glossy(v.albedo, v.normal, v.emission, v.specular, v.gloss);
                CacheVoxel {
                    coord: x | (y << COORD_BITS) | (z << (2 * COORD_BITS)),
                    albedo: a.albedo,
                    normal: a.normal,
                    emission: a.emission,
                }
            })
            .collect();
        Ok(VoxelCache {
            corner: grid.bounds.min,
            voxel_size: grid.bounds.voxel_size(grid.depth),
            depth: grid.depth,
            voxels,
        })
    }

    /// Voxelizes `part` at `depth` (2^depth voxels along its longest side) into a cache.
    pub fn build(part: &Part, materials: &[Material], depth: u32) -> Result<Self, CacheError> {
        if depth > MAX_CACHE_DEPTH {
            return Err(CacheError::TooDeep(depth));
        }
        let opts = VoxelizeOptions { resolution: Resolution::Depth(depth), solid: false };
        Self::from_grid(&voxelize(part, materials, &opts, &|_, _| {})?)
    }

    /// The part's voxels as its SVO holds them at `level` (every node there, with the
    /// attributes the SVO averaged for it): the cache of a part with no mesh at hand (the
    /// ground), or at a coarser GI resolution than the SVO, without voxelizing again.
    pub fn from_svo(svo: &crate::svo::Svo, level: u32) -> Result<Self, CacheError> {
        let level = level.min(svo.depth);
        if level > MAX_CACHE_DEPTH {
            return Err(CacheError::TooDeep(level));
        }
        let voxels = svo
            .at_level(level)
            .into_iter()
            .map(|(c, a)| CacheVoxel {
                coord: c[0] | (c[1] << COORD_BITS) | (c[2] << (2 * COORD_BITS)),
                albedo: a.albedo,
                normal: a.normal,
                emission: a.emission,
            })
            .collect();
        Ok(VoxelCache { corner: svo.bounds.min, voxel_size: svo.bounds.voxel_size(level), depth: level, voxels })
    }

    /// Object-space centre of a voxel.
    pub fn centre(&self, v: &CacheVoxel) -> Vec3 {
        let [x, y, z] = v.coord();
        self.corner + (Vec3::new(x as f32, y as f32, z as f32) + 0.5) * self.voxel_size
    }

    /// Bytes of the voxel list.
    pub fn bytes(&self) -> usize {
        std::mem::size_of_val(self.voxels.as_slice())
    }
}
