//! The sparse world volume, the voxel-transformation method's sparse variant: a dense table of
//! top cells, each standing for a brick of 8³ finest cells, and bricks allocated only where a
//! moved voxel writes. Coverage of 1024³ cells fits where the dense volume stops at 512³: the
//! memory follows the surfaces, not the cube.
//!
//! Built in three passes over the moved voxels, the way a GPU builds it with atomics and
//! without locks: mark every top cell written, allocate one brick per marked cell (a counter;
//! here in top-cell order, so the layout is deterministic), then accumulate. Every pass uses
//! [`for_each_target`], the transformation the dense volume uses, so a cell sums the same
//! weights in the same order and holds the same value as in the dense volume; its level chain
//! keeps the bricks' 4³ and 2³ levels sparse and continues densely from the top table (one
//! value per brick) down to one cell, so sampling it gives exactly what the dense chain gives
//! (`tests/gi.rs` checks both).

use super::cache::VoxelCache;
use super::inject::{CellSums, Cells};
use super::levels::{build_from, coarsen, trilinear_with, Chain, Level, Levels};
use super::volume::{for_each_target, Filter, GiError, SplatStats, VolumeSpec};
use glam::{DAffine3, DVec3, Vec3, Vec4};

/// Finest cells per brick side.
pub const BRICK: u32 = 8;
/// Finest cells per brick.
const BRICK_CELLS: usize = (BRICK * BRICK * BRICK) as usize;
/// Levels stored per brick (8³, 4³, 2³); the brick's 1³ level is a cell of the top table.
pub(crate) const BRICK_LEVELS: usize = 3;
/// Largest sparse volume per side.
pub const MAX_SPARSE_RES: u32 = 1024;
/// A top cell without a brick.
pub(crate) const EMPTY: u32 = u32::MAX;

/// Bytes per stored cell of either layout: occupancy and three RGB sums (f32).
pub const CELL_BYTES: u64 = 40;

/// The sparse world volume (CPU).
#[derive(Clone, Debug, PartialEq)]
pub struct SparseVolume {
    /// Placement (cells per side a multiple of [`BRICK`]).
    pub spec: VolumeSpec,
    /// Top cells per side (`spec.res / BRICK`).
    pub top_res: u32,
    /// Brick of each top cell (x fastest), or `u32::MAX` for none.
    pub top: Vec<u32>,
    /// Top cell of each brick.
    pub brick_top: Vec<u32>,
    /// Summed weights, [`BRICK`]³ per brick (x fastest within a brick).
    pub occupancy: Vec<f32>,
    /// Summed weight × linear albedo.
    pub albedo: Vec<Vec3>,
    /// Summed weight × world normal.
    pub normal: Vec<Vec3>,
    /// Summed weight × emitted radiance.
    pub emission: Vec<Vec3>,
}

impl SparseVolume {
    /// Checks that `spec` can be sparse: cells per side a multiple of [`BRICK`], at most
    /// [`MAX_SPARSE_RES`].
    pub fn check_spec(spec: &VolumeSpec) -> Result<(), GiError> {
        if spec.res == 0 || spec.res % BRICK != 0 || spec.res > MAX_SPARSE_RES {
            return Err(GiError::SparseResolution(spec.res));
        }
        Ok(())
    }

    /// Moves every `(cache, world matrix)` into a new sparse volume with `filter`.
    pub fn build(
        spec: VolumeSpec,
        moves: &[(&VoxelCache, DAffine3)],
        filter: Filter,
    ) -> Result<(SparseVolume, SplatStats), GiError> {
        Self::check_spec(&spec)?;
        let top_res = spec.res / BRICK;
        let res = spec.res as i64;
        let inside = |c: [i64; 3]| c.iter().all(|&k| (0..res).contains(&k));
        let top_of = |c: [i64; 3]| {
            let t = [c[0] as u32 / BRICK, c[1] as u32 / BRICK, c[2] as u32 / BRICK];
            t[0] as usize + top_res as usize * (t[1] as usize + top_res as usize * t[2] as usize)
        };
        // Pass 1: mark the top cells written.
        let mut marked = vec![false; (top_res as usize).pow(3)];
        for (cache, world) in moves {
            for_each_target(cache, world, &spec, filter, |c, _, _| {
                if inside(c) {
                    marked[top_of(c)] = true;
                }
            })?;
        }
        // Pass 2: one brick per marked top cell.
        let mut top = vec![EMPTY; marked.len()];
        let mut brick_top = Vec::new();
        for (t, _) in marked.iter().enumerate().filter(|(_, &m)| m) {
            top[t] = brick_top.len() as u32;
            brick_top.push(t as u32);
        }
        let n = brick_top.len() * BRICK_CELLS;
        crate::memory::check(
            &format!("a sparse GI volume of {} bricks ({n} cells) and its level chain", brick_top.len()),
            n as u64 * super::volume::VOLUME_BYTES_PER_CELL,
            "lower the GI resolution or raise the memory budget",
        )?;
        let mut vol = SparseVolume {
            spec,
            top_res,
            top,
            brick_top,
            occupancy: vec![0.0; n],
            albedo: vec![Vec3::ZERO; n],
            normal: vec![Vec3::ZERO; n],
            emission: vec![Vec3::ZERO; n],
        };
        // Pass 3: accumulate, exactly as the dense volume does.
        let mut stats = SplatStats::default();
        for (cache, world) in moves {
            let s = for_each_target(cache, world, &spec, filter, |c, w, v| {
                if !inside(c) {
                    stats.outside += w;
                    return;
                }
                let Some(i) = vol.index([c[0] as u32, c[1] as u32, c[2] as u32]) else {
                    return; // unreachable: pass 1 marked this brick
                };
                let w32 = w as f32;
                vol.occupancy[i] += w32;
                vol.albedo[i] += v.albedo * w32;
                vol.normal[i] += v.normal * w32;
                vol.emission[i] += v.emission * w32;
            })?;
            stats.voxels += s.voxels;
        }
        Ok((vol, stats))
    }

    /// Storage index of finest cell `c`, or None where no brick is allocated.
    pub fn index(&self, c: [u32; 3]) -> Option<usize> {
        let t = self.top[self.top_cell([c[0] / BRICK, c[1] / BRICK, c[2] / BRICK])];
        (t != EMPTY).then(|| {
            let l = [c[0] % BRICK, c[1] % BRICK, c[2] % BRICK];
            t as usize * BRICK_CELLS + (l[0] + BRICK * (l[1] + BRICK * l[2])) as usize
        })
    }

    fn top_cell(&self, t: [u32; 3]) -> usize {
        let r = self.top_res as usize;
        t[0] as usize + r * (t[1] as usize + r * t[2] as usize)
    }

    /// Finest cell coordinates of storage index `i`.
    pub fn coords(&self, i: usize) -> [u32; 3] {
        let (b, l) = (i / BRICK_CELLS, (i % BRICK_CELLS) as u32);
        let t = self.brick_top[b] as usize;
        let r = self.top_res as usize;
        let tc = [(t % r) as u32, ((t / r) % r) as u32, (t / (r * r)) as u32];
        [tc[0] * BRICK + l % BRICK, tc[1] * BRICK + (l / BRICK) % BRICK, tc[2] * BRICK + l / (BRICK * BRICK)]
    }

    /// Allocated bricks.
    pub fn bricks(&self) -> usize {
        self.brick_top.len()
    }

    /// Bytes held: the top table and the bricks' cells.
    pub fn bytes(&self) -> u64 {
        self.top.len() as u64 * 4 + self.occupancy.len() as u64 * CELL_BYTES
    }

    /// Bytes a dense volume of `res`³ cells holds, for comparison.
    pub fn dense_bytes(res: u32) -> u64 {
        (res as u64).pow(3) * CELL_BYTES
    }
}

impl Cells for SparseVolume {
    fn spec(&self) -> VolumeSpec {
        self.spec
    }
    fn cell_count(&self) -> usize {
        self.occupancy.len()
    }
    fn sums(&self, i: usize) -> CellSums {
        CellSums {
            occupancy: self.occupancy[i],
            albedo: self.albedo[i],
            normal: self.normal[i],
            emission: self.emission[i],
            centre: self.spec.cell_centre(self.coords(i)),
        }
    }
}

/// The level chain of a sparse volume: the bricks' 8³, 4³ and 2³ levels sparse, then the top
/// table (one value per brick) and its coarser levels dense.
#[derive(Clone, Debug, PartialEq)]
pub struct SparseLevels {
    min: DVec3,
    res0: u32,
    cell0: f64,
    top_res: u32,
    top: Vec<u32>,
    /// Level l's values, (8 >> l)³ per brick.
    bricks: [Vec<Vec4>; BRICK_LEVELS],
    /// The top table's level and the coarser ones.
    coarse: Levels,
}

impl SparseLevels {
    /// The chain of `vol` whose stored cells were lit to `rgba` (one per stored cell).
    pub fn build(vol: &SparseVolume, rgba: Vec<Vec4>) -> SparseLevels {
        let bricks_n = vol.bricks();
        let mut bricks: [Vec<Vec4>; BRICK_LEVELS] = [rgba, Vec::new(), Vec::new()];
        for l in 1..BRICK_LEVELS {
            let (fine_side, side) = (BRICK >> (l - 1), BRICK >> l);
            let (fine_n, n) = ((fine_side as usize).pow(3), (side as usize).pow(3));
            let mut out = vec![Vec4::ZERO; bricks_n * n];
            for b in 0..bricks_n {
                let fine = &bricks[l - 1][b * fine_n..(b + 1) * fine_n];
                for z in 0..side {
                    for y in 0..side {
                        for x in 0..side {
                            out[b * n + (x + side * (y + side * z)) as usize] =
                                coarsen(children(fine, fine_side, [x, y, z]));
                        }
                    }
                }
            }
            bricks[l] = out;
        }
        let mut top_level = Level {
            res: vol.top_res,
            cell: vol.spec.cell * BRICK as f64,
            rgba: vec![Vec4::ZERO; (vol.top_res as usize).pow(3)],
        };
        let last_side = BRICK >> (BRICK_LEVELS - 1);
        let last_n = (last_side as usize).pow(3);
        for (b, &t) in vol.brick_top.iter().enumerate() {
            top_level.rgba[t as usize] =
                coarsen(children(&bricks[BRICK_LEVELS - 1][b * last_n..], last_side, [0, 0, 0]));
        }
        SparseLevels {
            min: vol.spec.min,
            res0: vol.spec.res,
            cell0: vol.spec.cell,
            top_res: vol.top_res,
            top: vol.top.clone(),
            bricks,
            coarse: build_from(top_level, vol.spec.min),
        }
    }

    /// Bytes held.
    pub fn bytes(&self) -> u64 {
        let sparse: usize = self.bricks.iter().map(Vec::len).sum();
        let dense: usize = self.coarse.levels.iter().map(|l| l.rgba.len()).sum();
        (sparse + dense) as u64 * 16 + self.top.len() as u64 * 4
    }
}

/// The sum of the 8 children of cell `c` in a brick level of `fine_side` cells per side, in the
/// order the dense chain sums them.
fn children(fine: &[Vec4], fine_side: u32, c: [u32; 3]) -> Vec4 {
    let mut sum = Vec4::ZERO;
    for k in 0..8u32 {
        let f = [2 * c[0] + (k & 1), 2 * c[1] + ((k >> 1) & 1), 2 * c[2] + (k >> 2)];
        sum += fine[(f[0] + fine_side * (f[1] + fine_side * f[2])) as usize];
    }
    sum
}

impl Chain for SparseLevels {
    fn min(&self) -> DVec3 {
        self.min
    }
    fn count(&self) -> usize {
        BRICK_LEVELS + self.coarse.levels.len()
    }
    fn res(&self, l: usize) -> u32 {
        if l < BRICK_LEVELS {
            self.res0 >> l
        } else {
            self.coarse.levels[l - BRICK_LEVELS].res
        }
    }
    fn cell(&self, l: usize) -> f64 {
        if l < BRICK_LEVELS {
            self.cell0 * (1u32 << l) as f64
        } else {
            self.coarse.levels[l - BRICK_LEVELS].cell
        }
    }
    fn value(&self, l: usize, c: [u32; 3]) -> Vec4 {
        if l >= BRICK_LEVELS {
            return self.coarse.value(l - BRICK_LEVELS, c);
        }
        let shift = (BRICK_LEVELS - l) as u32;
        let t = [c[0] >> shift, c[1] >> shift, c[2] >> shift];
        let r = self.top_res as usize;
        let b = self.top[t[0] as usize + r * (t[1] as usize + r * t[2] as usize)];
        if b == EMPTY {
            return Vec4::ZERO;
        }
        let side = BRICK >> l;
        let local = [c[0] % side, c[1] % side, c[2] % side];
        self.bricks[l][b as usize * (side as usize).pow(3) + (local[0] + side * (local[1] + side * local[2])) as usize]
    }
    // When the 8 corners lie in one brick (most samples at the finest level), its table entry
    // is read once.
    fn trilinear(&self, l: usize, p: DVec3) -> Vec4 {
        let (cell, res) = (self.cell(l), self.res(l));
        if l >= BRICK_LEVELS {
            return self.coarse.trilinear(l - BRICK_LEVELS, p);
        }
        let base = ((p - self.min) / cell - DVec3::splat(0.5)).floor();
        let side = BRICK >> l;
        let inside = base.min_element() >= 0.0 && base.max_element() + 1.0 < res as f64;
        let b = [base.x as u32, base.y as u32, base.z as u32];
        if !(inside && b.iter().all(|&v| v % side != side - 1)) {
            return trilinear_with(self.min, cell, res, p, |c| self.value(l, c));
        }
        let r = self.top_res as usize;
        let t = [b[0] / side, b[1] / side, b[2] / side];
        let brick = self.top[t[0] as usize + r * (t[1] as usize + r * t[2] as usize)];
        if brick == EMPTY {
            return trilinear_with(self.min, cell, res, p, |_| Vec4::ZERO);
        }
        let cells = &self.bricks[l][brick as usize * (side as usize).pow(3)..];
        trilinear_with(self.min, cell, res, p, |c| {
            cells[(c[0] % side + side * (c[1] % side + side * (c[2] % side))) as usize]
        })
    }
}
