//! A checkered ground: one layer of voxels whose top is the plane y = 0, built directly as a
//! voxel grid (a mesh voxelizer would be wasted on a plane). It gives the animated car a floor
//! to drive on and to cast shadows on.

use crate::svo::{self, Cube, Svo};
use crate::voxelize::{Voxel, VoxelGrid};
use glam::{DVec3, Vec3};

/// Builds a ground covering the box `lo..hi` (x and z), with tiles of `tile` units and voxels
/// no smaller than `min_voxel`; at most 1024 voxels per side.
pub fn ground(lo: DVec3, hi: DVec3, tile: f64, min_voxel: f64) -> Result<Svo, svo::BuildError> {
    let extent = (hi.x - lo.x).max(hi.z - lo.z).max(1e-3);
    let depth = 10u32;
    let n = 1u64 << depth;
    let voxel = (extent / n as f64).max(min_voxel);
    let size = voxel * n as f64;
    let centre = (lo + hi) * 0.5;
    // Layer j = n/2 − 1 has its top face at y = 0.
    let min = DVec3::new(centre.x - size * 0.5, -voxel * (n / 2) as f64, centre.z - size * 0.5);
    let cells = ((extent / voxel).ceil() as u64).min(n);
    let first = (n - cells) / 2;
    let j = (n / 2 - 1) as u32;
    let mut coords = Vec::with_capacity((cells * cells) as usize);
    for z in first..first + cells {
        for x in first..first + cells {
            coords.push([x as u32, j, z as u32]);
        }
    }
    let mut grid = VoxelGrid::from_coords(depth, Cube { min: min.as_vec3(), size: size as f32 }, coords, Vec3::ZERO);
    for v in &mut grid.voxels {
        let [x, _, z] = svo::format::morton_decode(v.code);
        let p = min + DVec3::new(x as f64 + 0.5, 0.0, z as f64 + 0.5) * voxel;
        let checker = ((p.x / tile).floor() + (p.z / tile).floor()) as i64 % 2 == 0;
        *v = Voxel { albedo: if checker { Vec3::splat(0.30) } else { Vec3::splat(0.42) }, normal: Vec3::Y, ..*v };
    }
    svo::build(&grid)
}
