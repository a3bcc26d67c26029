//! Voxel-transformation global illumination (see DESIGN.md): every part is voxelized once
//! more, coarsely, into a linear [`VoxelCache`]; each frame the caches of the instances are
//! transformed by their world matrices into a world [`Volume`] with nearest or 8-neighbour
//! split filtering. This module is the CPU reference of those passes; light injection, the
//! level chain and cone tracing build on it.

pub mod cache;
pub mod volume;

pub use cache::{CacheError, CacheVoxel, VoxelCache};
pub use volume::{Filter, GiError, SplatStats, Volume, VolumeSpec};
