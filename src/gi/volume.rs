//! The dense world volume and the voxel transformation: each instance's cached voxels are
//! moved by its world matrix and written into world cells, either to the nearest cell or
//! split over the 8 cells around the moved centre by trilinear weights (DESIGN.md, "8-neighbour
//! split filtering"). Occupancy, weighted albedo, normal and emission accumulate; a cell's
//! attributes are its sums divided by its occupancy, so overlapping voxels average by weight.

use super::cache::VoxelCache;
use crate::voxelize::VoxelGrid;
use glam::{DAffine3, DMat3, DVec3, Vec3};

/// Emitted radiance a voxel brings into the GI volume, per channel, at most. Emitters sampled
/// as lights ([`crate::render::emitters`]) do not enter the volume at all; this bounds the
/// glow of unsampled ones, which the GPU sums in 32-bit fixed point at 1/4096
/// (`gpu::gi::EMIT_FIX`): 1024 leaves room for 512 voxels' full weight in one cell.
pub const GI_MAX_EMISSION: f32 = 1024.0;

/// Largest dense volume per side (512³ cells × 28 bytes = 3.5 GiB); finer coverage needs the
/// sparse volume.
pub const MAX_DENSE_RES: u32 = 512;

/// Where the world volume lies.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VolumeSpec {
    /// Cells per side.
    pub res: u32,
    /// World-space minimum corner.
    pub min: DVec3,
    /// Cell edge (world units).
    pub cell: f64,
}

/// Filtering of moved voxels into world cells.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Filter {
    /// The one cell containing the moved centre.
    Nearest,
    /// The 8 cells around the moved centre, by trilinear overlap weights.
    Split,
}

impl std::str::FromStr for Filter {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "nearest" => Ok(Filter::Nearest),
            "split" => Ok(Filter::Split),
            other => Err(format!("unknown GI filter '{other}' (use nearest or split)")),
        }
    }
}

/// How the world volume is stored.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "json", derive(serde::Serialize, serde::Deserialize))]
pub enum Layout {
    /// Every cell (up to [`MAX_DENSE_RES`] per side).
    #[default]
    Dense,
    /// A top table and 8³ bricks where voxels land ([`super::sparse`], up to
    /// [`super::sparse::MAX_SPARSE_RES`] per side, a multiple of 8).
    Sparse,
}

impl Layout {
    /// Largest resolution this layout holds.
    pub fn max_res(self) -> u32 {
        match self {
            Layout::Dense => MAX_DENSE_RES,
            Layout::Sparse => super::sparse::MAX_SPARSE_RES,
        }
    }
}

/// Invalid GI settings or inputs.
#[derive(Debug, thiserror::Error)]
pub enum GiError {
    /// Resolution outside 1..=MAX_DENSE_RES.
    #[error("GI volume resolution {0} must be 1…{MAX_DENSE_RES} (finer coverage needs the sparse volume)")]
    Resolution(u32),
    /// Sparse resolution not a multiple of 8 or above the sparse limit.
    #[error("sparse GI volume resolution {0} must be a multiple of 8 from 8 to {max}", max = super::sparse::MAX_SPARSE_RES)]
    SparseResolution(u32),
    /// Cell size or corner not finite / not positive.
    #[error("GI volume: cell size {cell} and corner {min:?} must be finite, the cell positive")]
    Placement {
        /// Cell edge.
        cell: f64,
        /// Corner.
        min: DVec3,
    },
    /// Another invalid GI setting.
    #[error("GI: {0}")]
    Settings(String),
    /// A world matrix with NaN/∞ or a singular linear part.
    #[error("instance transform is not finite and invertible: {0:?}")]
    Transform(DAffine3),
    /// The camera of the frame.
    #[error(transparent)]
    Camera(#[from] crate::scene::CameraError),
    /// The memory budget refused the volume.
    #[error(transparent)]
    Memory(#[from] crate::memory::MemoryError),
}

/// Bytes per cell of a volume with its level chain: the accumulation cell
/// ([`super::sparse::CELL_BYTES`]) and an RGBA f32 texel per cell of every level (8/7 of the
/// finest's count).
pub const VOLUME_BYTES_PER_CELL: u64 = super::sparse::CELL_BYTES + 16 * 8 / 7 + 1;

/// Checks that a world matrix can move voxels: finite, with an invertible linear part (the
/// normals move by its inverse transpose).
pub fn check_world(world: &DAffine3) -> Result<(), GiError> {
    let lin = world.matrix3;
    if world.translation.is_finite() && lin.is_finite() && lin.determinant().abs() > 0.0 {
        Ok(())
    } else {
        Err(GiError::Transform(*world))
    }
}

impl VolumeSpec {
    /// A checked placement of a dense volume.
    pub fn new(res: u32, min: DVec3, cell: f64) -> Result<Self, GiError> {
        Self::with_layout(res, min, cell, Layout::Dense)
    }

    /// A checked placement for `layout`.
    pub fn with_layout(res: u32, min: DVec3, cell: f64, layout: Layout) -> Result<Self, GiError> {
        match layout {
            Layout::Dense if res == 0 || res > MAX_DENSE_RES => return Err(GiError::Resolution(res)),
            Layout::Sparse if res == 0 || res % super::sparse::BRICK != 0 || res > layout.max_res() => {
                return Err(GiError::SparseResolution(res))
            }
            _ => {}
        }
        if !(min.is_finite() && cell.is_finite() && cell > 0.0) {
            return Err(GiError::Placement { cell, min });
        }
        if layout == Layout::Dense {
            crate::memory::check(
                &format!("a dense GI volume of {res}³ cells and its level chain"),
                (res as u64).pow(3) * VOLUME_BYTES_PER_CELL,
                "lower the GI resolution, use the sparse volume, or raise the memory budget",
            )?;
        }
        // Cells must stay apart in f64 at the volume's coordinates (and far from overflowing
        // the integer cell numbers): a smaller cell would put every voxel in one cell or none.
        let magnitude = min.abs().max(min + DVec3::splat(cell * res as f64)).abs().max_element();
        if cell < magnitude * 1e-12 {
            return Err(GiError::Settings(format!(
                "volume cells of {cell:e} cannot be told apart at coordinates of {magnitude:e}: use a larger extent"
            )));
        }
        Ok(VolumeSpec { res, min, cell })
    }

    /// A volume of `extent` world units per side centred near `centre`, its corner snapped
    /// to whole cells so that following a moving camera does not make the voxels swim.
    pub fn following(centre: DVec3, extent: f64, res: u32) -> Result<Self, GiError> {
        Self::following_with(centre, extent, res, Layout::Dense)
    }

    /// [`VolumeSpec::following`] for `layout`.
    pub fn following_with(centre: DVec3, extent: f64, res: u32, layout: Layout) -> Result<Self, GiError> {
        let cell = extent / res.max(1) as f64;
        if !(cell.is_finite() && cell > 0.0) {
            return Err(GiError::Placement { cell, min: centre });
        }
        let min = ((centre - DVec3::splat(extent * 0.5)) / cell).floor() * cell;
        Self::with_layout(res, min, cell, layout)
    }

    /// World-space centre of cell `c`.
    pub fn cell_centre(&self, c: [u32; 3]) -> DVec3 {
        self.min + (DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) + 0.5) * self.cell
    }
}

/// What one transformation wrote.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SplatStats {
    /// Cache voxels moved.
    pub voxels: u64,
    /// Occupancy weight that fell outside the volume and was dropped.
    pub outside: f64,
}

/// A cache voxel moved into world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MovedVoxel {
    /// Linear albedo.
    pub albedo: Vec3,
    /// Unit world normal (zero when degenerate).
    pub normal: Vec3,
    /// Emitted radiance.
    pub emission: Vec3,
}

/// Calls `f(cell, weight, voxel)` for every world cell (cell-index coordinates, possibly outside
/// the volume) that `cache`'s voxels moved by `world` write with `filter`, in cache order and,
/// per voxel, in a fixed neighbour order — the one definition of the transformation that the
/// dense and the sparse volume share, so they sum the same weights in the same order. Zero
/// weights are skipped. Returns the voxel count (`outside` is the caller's to count).
pub fn for_each_target(
    cache: &VoxelCache,
    world: &DAffine3,
    spec: &VolumeSpec,
    filter: Filter,
    mut f: impl FnMut([i64; 3], f64, &MovedVoxel),
) -> Result<SplatStats, GiError> {
    check_world(world)?;
    // Normals move by the inverse transpose.
    let normal_m: DMat3 = world.matrix3.inverse().transpose();
    for v in &cache.voxels {
        let p = world.transform_point3(cache.centre(v).as_dvec3());
        // Cell-centre coordinates: cell c's centre sits at g = c.
        let g = (p - spec.min) / spec.cell - DVec3::splat(0.5);
        let attr = v.attr();
        let moved = MovedVoxel {
            albedo: attr.albedo_linear(),
            normal: (normal_m * attr.normal().as_dvec3()).normalize_or_zero().as_vec3(),
            emission: attr.emission().min(Vec3::splat(GI_MAX_EMISSION)),
        };
        match filter {
            Filter::Nearest => {
                let c = (g + DVec3::splat(0.5)).floor();
                f([grid_i64(c.x), grid_i64(c.y), grid_i64(c.z)], 1.0, &moved);
            }
            Filter::Split => {
                let base = g.floor();
                let fr = g - base;
                for k in 0..8 {
                    let (dx, dy, dz) = (k & 1, (k >> 1) & 1, k >> 2);
                    let w = if dx == 1 { fr.x } else { 1.0 - fr.x }
                        * if dy == 1 { fr.y } else { 1.0 - fr.y }
                        * if dz == 1 { fr.z } else { 1.0 - fr.z };
                    if w != 0.0 {
                        f([grid_i64(base.x) + dx, grid_i64(base.y) + dy, grid_i64(base.z) + dz], w, &moved);
                    }
                }
            }
        }
    }
    Ok(SplatStats { voxels: cache.voxels.len() as u64, outside: 0.0 })
}

/// A dense world volume (the CPU reference).
#[derive(Clone, Debug, PartialEq)]
pub struct Volume {
    /// Placement.
    pub spec: VolumeSpec,
    /// Summed weights per cell (x fastest, then y, then z).
    pub occupancy: Vec<f32>,
    /// Summed weight × linear albedo per cell.
    pub albedo: Vec<Vec3>,
    /// Summed weight × world normal per cell.
    pub normal: Vec<Vec3>,
    /// Summed weight × emitted radiance (MTL `Ke`) per cell.
    pub emission: Vec<Vec3>,
}

impl Volume {
    /// An empty volume.
    pub fn new(spec: VolumeSpec) -> Self {
        let n = (spec.res as usize).pow(3);
        Volume {
            spec,
            occupancy: vec![0.0; n],
            albedo: vec![Vec3::ZERO; n],
            normal: vec![Vec3::ZERO; n],
            emission: vec![Vec3::ZERO; n],
        }
    }

    /// Empties every cell.
    pub fn clear(&mut self) {
        self.occupancy.fill(0.0);
        self.albedo.fill(Vec3::ZERO);
        self.normal.fill(Vec3::ZERO);
        self.emission.fill(Vec3::ZERO);
    }

    /// Index of cell `c`.
    pub fn index(&self, c: [u32; 3]) -> usize {
        let r = self.spec.res as usize;
        c[0] as usize + r * (c[1] as usize + r * c[2] as usize)
    }

    /// Moves `cache`'s voxels by `world` (object → world) into the volume.
    pub fn splat(&mut self, cache: &VoxelCache, world: &DAffine3, filter: Filter) -> Result<SplatStats, GiError> {
        let spec = self.spec;
        let res = spec.res as i64;
        let mut outside = 0.0;
        let stats = for_each_target(cache, world, &spec, filter, |c, w, v| {
            if c.iter().any(|&k| k < 0 || k >= res) {
                outside += w;
                return;
            }
            let i = self.index([c[0] as u32, c[1] as u32, c[2] as u32]);
            let w32 = w as f32;
            self.occupancy[i] += w32;
            self.albedo[i] += v.albedo * w32;
            self.normal[i] += v.normal * w32;
            self.emission[i] += v.emission * w32;
        })?;
        Ok(SplatStats { outside, ..stats })
    }

    /// Writes a grid voxelized in this volume's own cells (the re-voxelization baseline: the
    /// moved triangles voxelized straight into world cells), one unit of occupancy per voxel.
    pub fn write_grid(&mut self, grid: &VoxelGrid) -> Result<(), GiError> {
        let res = self.spec.res;
        let same_cells = (1u64 << grid.depth) == res as u64
            && (grid.bounds.min.as_dvec3() - self.spec.min).abs().max_element() <= self.spec.cell * 1e-3
            && ((grid.bounds.size as f64 / res as f64) - self.spec.cell).abs() <= self.spec.cell * 1e-3;
        if !same_cells {
            return Err(GiError::Settings(format!(
                "a grid of 2^{} cells over {:?} does not match the volume's {}³ cells from {:?}",
                grid.depth, grid.bounds, res, self.spec.min
            )));
        }
        for v in &grid.voxels {
            let i = self.index(crate::svo::format::morton_decode(v.code));
            let n = v.normal.normalize_or_zero();
            self.occupancy[i] += 1.0;
            self.albedo[i] += v.albedo;
            self.normal[i] += n;
            self.emission[i] += v.emission.min(Vec3::splat(GI_MAX_EMISSION));
        }
        Ok(())
    }

    /// Sum of all occupancy.
    pub fn total_occupancy(&self) -> f64 {
        self.occupancy.iter().map(|&o| o as f64).sum()
    }

    /// Cells with any occupancy.
    pub fn occupied(&self) -> Vec<[u32; 3]> {
        let r = self.spec.res;
        let mut out = Vec::new();
        for z in 0..r {
            for y in 0..r {
                for x in 0..r {
                    if self.occupancy[self.index([x, y, z])] > 0.0 {
                        out.push([x, y, z]);
                    }
                }
            }
        }
        out
    }

    /// Weighted mean albedo of a cell (zero when empty).
    pub fn mean_albedo(&self, c: [u32; 3]) -> Vec3 {
        let i = self.index(c);
        if self.occupancy[i] > 0.0 {
            self.albedo[i] / self.occupancy[i]
        } else {
            Vec3::ZERO
        }
    }
}

/// A grid coordinate (already floored) as a cell number: values far outside any grid (and
/// NaN) become numbers far outside too, without the overflow a plain `as i64` plus an offset
/// would risk.
#[inline]
pub fn grid_i64(v: f64) -> i64 {
    if (-4.0..=4.0e9).contains(&v) {
        v as i64
    } else if v > 0.0 {
        i64::MAX / 4
    } else {
        i64::MIN / 4
    }
}

#[cfg(test)]
mod precision_tests {
    use super::*;
    use glam::Vec4;

    /// Far coordinates with cells too small to tell apart are refused; a tiny volume near the
    /// origin is fine; grid numbers never overflow, whatever the point.
    #[test]
    fn cells_must_be_resolvable_and_numbers_bounded() {
        let far = VolumeSpec::following(DVec3::splat(1e9), 1e-6, 128);
        assert!(far.unwrap_err().to_string().contains("cannot be told apart"));
        assert!(VolumeSpec::following(DVec3::splat(1e6), 4.0, 128).is_ok());
        assert!(VolumeSpec::following(DVec3::ZERO, 1e-30, 128).is_ok());
        for v in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 1e300, -1e300, 6e31] {
            let c = grid_i64(v);
            assert!(c.checked_add(1).is_some() && !(0..1 << 20).contains(&c), "{v} -> {c}");
        }
        assert_eq!((grid_i64(3.0), grid_i64(-1.0)), (3, -1));
        // The level chain samples a point far outside a tiny volume without overflowing.
        let s = super::super::levels::trilinear_with(DVec3::ZERO, 1e-33, 4, DVec3::splat(0.5), |_| Vec4::ONE);
        assert_eq!(s, Vec4::ZERO);
    }
}
