//! Mesh parts to SVOs: one voxel size for all parts of a model, the disk cache, timings.

use crate::cache::{part_key, SvoCache};
use crate::mesh::Mesh;
use crate::svo::{self, Svo};
use crate::voxelize::{bounding_cube, voxelize, Resolution, VoxelizeOptions};
use crate::Error;
use std::time::{Duration, Instant};

/// Turns a resolution that is relative to one part (a depth) into one voxel size for every
/// part of the mesh: `Depth(d)` means 2^d voxels along the largest part's longest side, so
/// small parts (a wheel) get the same voxel size as the body instead of 2^d of their own.
pub fn shared_resolution(mesh: &Mesh, res: Resolution) -> Result<Resolution, Error> {
    match res {
        Resolution::VoxelSize(_) => Ok(res),
        Resolution::Depth(d) => {
            let mut size = 0.0f32;
            for p in &mesh.parts {
                size = size.max(bounding_cube(p, Resolution::Depth(d))?.0.size);
            }
            // A hair above size/2^d so the largest part lands exactly on depth d.
            Ok(Resolution::VoxelSize(size / (1u64 << d) as f32 * (1.0 + 1e-6)))
        }
    }
}

/// One part's SVO and how it was obtained.
pub struct BuiltPart {
    /// The octree.
    pub svo: Svo,
    /// Loaded from the cache.
    pub cached: bool,
    /// Time spent voxelizing (zero when cached).
    pub voxelize: Duration,
    /// Time spent building (zero when cached).
    pub build: Duration,
    /// A problem with the cache that did not stop the build (e.g. a corrupt file replaced).
    pub cache_warning: Option<String>,
}

/// Voxelizes and builds one part of `mesh`, through the cache when given.
pub fn build_part(
    mesh: &Mesh,
    index: usize,
    opts: &VoxelizeOptions,
    cache: Option<&SvoCache>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<BuiltPart, Error> {
    let part = &mesh.parts[index];
    let key = part_key(part, &mesh.materials, opts);
    let mut cache_warning = None;
    if let Some(c) = cache {
        match c.load(key) {
            Some(Ok(svo)) => {
                return Ok(BuiltPart {
                    svo,
                    cached: true,
                    voxelize: Duration::ZERO,
                    build: Duration::ZERO,
                    cache_warning,
                })
            }
            Some(Err(e)) => {
                cache_warning = Some(format!("cached SVO {} unusable ({e}); rebuilding", c.path(key).display()))
            }
            None => {}
        }
    }
    let t0 = Instant::now();
    let grid = voxelize(part, &mesh.materials, opts, progress)?;
    let t1 = Instant::now();
    let svo = svo::build(&grid)?;
    let t2 = Instant::now();
    if let Some(c) = cache {
        if let Err(e) = c.store(key, &svo) {
            cache_warning = Some(format!("could not write the SVO cache: {e}"));
        }
    }
    Ok(BuiltPart { svo, cached: false, voxelize: t1 - t0, build: t2 - t1, cache_warning })
}

/// Every part of `mesh` voxelized at one shared voxel size (see [`shared_resolution`]) and
/// built, without the cache: the one call a library user needs to go from a mesh to parts.
pub fn build_parts(mesh: &Mesh, res: Resolution) -> Result<Vec<std::sync::Arc<Svo>>, Error> {
    let opts = VoxelizeOptions { resolution: shared_resolution(mesh, res)?, solid: false };
    (0..mesh.parts.len()).map(|i| Ok(std::sync::Arc::new(build_part(mesh, i, &opts, None, &|_, _| {})?.svo))).collect()
}
