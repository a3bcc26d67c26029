//! The level chain: each coarser level averages 2×2×2 cells of the finer one. Opacity is
//! surface coverage — the children's summed alpha / 4, clamped to 1 — so a wall one cell thick
//! (4 of the 8 children) stays opaque at every level instead of fading to 1/2, 1/4, …;
//! premultiplied radiance scales with the same clamp so the colour stays the children's mean.

use super::inject::Injected;
use super::volume::grid_i64;
use glam::{DVec3, Vec4};

/// One level of the chain.
#[derive(Clone, Debug, PartialEq)]
pub struct Level {
    /// Cells per side.
    pub res: u32,
    /// Cell edge (world units).
    pub cell: f64,
    /// (radiance × alpha, alpha) per cell, x fastest.
    pub rgba: Vec<Vec4>,
}

impl Level {
    /// Index of cell `c`.
    pub fn index(&self, c: [u32; 3]) -> usize {
        let r = self.res as usize;
        c[0] as usize + r * (c[1] as usize + r * c[2] as usize)
    }
}

/// Level 0 (the injected volume) and every coarser level down to one cell.
#[derive(Clone, Debug, PartialEq)]
pub struct Levels {
    /// World corner shared by all levels.
    pub min: DVec3,
    /// Finest first.
    pub levels: Vec<Level>,
}

/// What sampling needs of a level chain, dense ([`Levels`]) or sparse
/// ([`super::sparse::SparseLevels`]): level 0 finest, each level half the resolution of the
/// one before; a cell outside the volume or not stored is empty.
pub trait Chain: Sync {
    /// World corner shared by all levels.
    fn min(&self) -> DVec3;
    /// Number of levels.
    fn count(&self) -> usize;
    /// Cells per side of level `l`.
    fn res(&self, l: usize) -> u32;
    /// Cell edge of level `l` (world units).
    fn cell(&self, l: usize) -> f64;
    /// (radiance × alpha, alpha) of cell `c` (inside the level) of level `l`.
    fn value(&self, l: usize, c: [u32; 3]) -> Vec4;
    /// Trilinear sample of level `l` at world point `p` (cell centres hold the cell values;
    /// outside the volume is empty). A layout may override it to find its storage once per
    /// sample instead of once per corner; the result must not change.
    fn trilinear(&self, l: usize, p: DVec3) -> Vec4 {
        trilinear_with(self.min(), self.cell(l), self.res(l), p, |c| self.value(l, c))
    }
    /// Trilinear sample of level `l` at `p` as a cone whose direction has the face weights
    /// `faces` ([`face_weights`], found once per cone) sees it: the same as
    /// [`Chain::trilinear`] for an isotropic chain; an anisotropic one blends those faces.
    fn trilinear_dir(&self, l: usize, p: DVec3, faces: &FaceWeights) -> Vec4 {
        let _ = faces;
        self.trilinear(l, p)
    }
}

/// The trilinear sample at `p` of a level with corner `min`, cell edge `cell` and `res` cells
/// per side whose cells `fetch` returns: the corners' values weighted by their overlaps, in a
/// fixed corner order, corners outside the level skipped.
pub fn trilinear_with(min: DVec3, cell: f64, res: u32, p: DVec3, mut fetch: impl FnMut([u32; 3]) -> Vec4) -> Vec4 {
    let g = (p - min) / cell - DVec3::splat(0.5);
    let base = g.floor();
    let f = (g - base).as_vec3();
    let r = res as i64;
    let mut out = Vec4::ZERO;
    for k in 0..8 {
        let (dx, dy, dz) = (k & 1, (k >> 1) & 1, k >> 2);
        let c = [grid_i64(base.x) + dx, grid_i64(base.y) + dy, grid_i64(base.z) + dz];
        if c.iter().any(|&v| v < 0 || v >= r) {
            continue;
        }
        let w = if dx == 1 { f.x } else { 1.0 - f.x }
            * if dy == 1 { f.y } else { 1.0 - f.y }
            * if dz == 1 { f.z } else { 1.0 - f.z };
        out += fetch([c[0] as u32, c[1] as u32, c[2] as u32]) * w;
    }
    out
}

impl Chain for Levels {
    fn min(&self) -> DVec3 {
        self.min
    }
    fn count(&self) -> usize {
        self.levels.len()
    }
    fn res(&self, l: usize) -> u32 {
        self.levels[l].res
    }
    fn cell(&self, l: usize) -> f64 {
        self.levels[l].cell
    }
    fn value(&self, l: usize, c: [u32; 3]) -> Vec4 {
        let level = &self.levels[l];
        level.rgba[level.index(c)]
    }
}

/// One coarse cell from the sum of its (up to 8) children: coverage alpha = sum / 4, clamped
/// to 1, the premultiplied colour scaled by the same clamp.
pub fn coarsen(sum: Vec4) -> Vec4 {
    let a = sum.w / 4.0;
    if a > 0.0 {
        let keep = a.min(1.0) / a;
        (sum.truncate() / 4.0 * keep).extend(a.min(1.0))
    } else {
        Vec4::ZERO
    }
}

/// Builds the chain from the injected volume.
pub fn build(inj: &Injected) -> Levels {
    build_from(Level { res: inj.res, cell: inj.cell, rgba: inj.rgba.clone() }, inj.min)
}

/// Builds the chain from its finest level, down to one cell.
pub fn build_from(finest: Level, min: DVec3) -> Levels {
    let mut levels = vec![finest];
    while let Some(fine) = levels.last().filter(|l| l.res > 1) {
        let res = fine.res.div_ceil(2);
        let mut coarse = Level { res, cell: fine.cell * 2.0, rgba: vec![Vec4::ZERO; (res as usize).pow(3)] };
        for z in 0..res {
            for y in 0..res {
                for x in 0..res {
                    let mut sum = Vec4::ZERO;
                    for k in 0..8u32 {
                        let c = [2 * x + (k & 1), 2 * y + ((k >> 1) & 1), 2 * z + (k >> 2)];
                        if c.iter().all(|&v| v < fine.res) {
                            sum += fine.rgba[fine.index(c)];
                        }
                    }
                    let i = coarse.index([x, y, z]);
                    coarse.rgba[i] = coarsen(sum);
                }
            }
        }
        levels.push(coarse);
    }
    Levels { min, levels }
}

/// The six directions a cone can travel along an axis, in face order: +x, −x, +y, −y, +z, −z.
pub const FACES: usize = 6;

/// One coarse level of an anisotropic chain: per cell, what a cone travelling along each of
/// the six axis directions sees through it — the cell's 2×2×2 children composited front to
/// back along that direction, column by column, and the four columns averaged. A wall's lit
/// outer face then stays behind its dark inner face for a cone leaving the room, where the
/// isotropic average blends the two (the leak through walls thinner than a coarse cell).
#[derive(Clone, Debug, PartialEq)]
pub struct FaceLevel {
    /// Cells per side.
    pub res: u32,
    /// Cell edge (world units).
    pub cell: f64,
    /// Per cell (x fastest), its (radiance × alpha, alpha) per face in [`FACES`] order (a
    /// cell's faces side by side: a sample reads three of them).
    pub cells: Vec<[Vec4; FACES]>,
}

/// A level chain with directional coarse levels: level 0 (the injected volume, isotropic) and
/// [`FaceLevel`]s down to one cell.
#[derive(Clone, Debug, PartialEq)]
pub struct AnisoLevels {
    /// World corner shared by all levels.
    pub min: DVec3,
    /// Level 0.
    pub finest: Level,
    /// Levels 1 and coarser.
    pub coarse: Vec<FaceLevel>,
}

/// Bytes the directional levels of a `res`³ chain take beyond an isotropic chain's: six
/// values instead of one in every coarse cell.
pub fn aniso_extra_bytes(res: u32) -> u64 {
    let mut cells = 0u64;
    let mut r = res as u64;
    while r > 1 {
        r = r.div_ceil(2);
        cells += r * r * r;
    }
    cells * (FACES as u64 - 1) * std::mem::size_of::<Vec4>() as u64
}

/// `front` over `back`, premultiplied.
fn over(front: Vec4, back: Vec4) -> Vec4 {
    front + back * (1.0 - front.w)
}

/// The faces of one coarse cell from its children's values: `fetch(face, child)` gives child
/// `child` (x + 2y + 4z) as seen along face `face` (empty outside the finer level).
pub fn coarsen_faces(mut fetch: impl FnMut(usize, u32) -> Vec4) -> [Vec4; FACES] {
    std::array::from_fn(|face| {
        let axis = face / 2;
        // Travelling +axis (even faces), the child at the lower coordinate is in front.
        let front_bit = (face % 2) as u32;
        let mut sum = Vec4::ZERO;
        for k in 0..8u32 {
            if (k >> axis) & 1 != front_bit {
                continue;
            }
            let back = k ^ (1 << axis);
            sum += over(fetch(face, k), fetch(face, back));
        }
        sum * 0.25
    })
}

/// Builds the anisotropic chain from its finest level, down to one cell.
pub fn build_aniso_from(finest: Level, min: DVec3) -> AnisoLevels {
    let mut coarse: Vec<FaceLevel> = Vec::new();
    let (mut res, mut cell) = (finest.res, finest.cell);
    while res > 1 {
        let fine_res = res;
        res = res.div_ceil(2);
        cell *= 2.0;
        let n = (res as usize).pow(3);
        let prev = coarse.last();
        let r = res as usize;
        let fr = fine_res as usize;
        let cells: Vec<[Vec4; FACES]> = crate::render::cpu::par_map(n, |i| {
            let (x, y, z) = ((i % r) as u32, ((i / r) % r) as u32, (i / (r * r)) as u32);
            // The children's indices once (each is read once per face).
            let child: [Option<usize>; 8] = std::array::from_fn(|k| {
                let k = k as u32;
                let c = [2 * x + (k & 1), 2 * y + ((k >> 1) & 1), 2 * z + (k >> 2)];
                c.iter().all(|&v| v < fine_res).then(|| c[0] as usize + fr * (c[1] as usize + fr * c[2] as usize))
            });
            coarsen_faces(|face, k| match (child[k as usize], prev) {
                (None, _) => Vec4::ZERO,
                (Some(j), Some(p)) => p.cells[j][face],
                (Some(j), None) => finest.rgba[j],
            })
        });
        coarse.push(FaceLevel { res, cell, cells });
    }
    AnisoLevels { min, finest, coarse }
}

/// The three faces a cone reads ([`FACES`] order) and their weights (summing to 1).
pub type FaceWeights = [(usize, f32); 3];

/// The three faces a cone along unit `dir` reads and their weights: the direction's
/// components to the eighth power, normalized to sum to 1. A face holds what is seen along
/// its axis, so the faces across a cone's direction show what lies beside each other there
/// as if side by side in its path (half dark, half sunlit through a ceiling and the roof
/// above it); leaning on the nearest axis lets less of that through than the squared
/// components do (thick-walled box: mean FLIP 0.339 with squares, 0.314 with eighth powers;
/// the powers measured in docs/gi.md, "Anisotropic levels").
pub fn face_weights(dir: DVec3) -> FaceWeights {
    let d = dir.as_vec3();
    let eighth = |v: f32| {
        let v2 = v * v;
        let v4 = v2 * v2;
        v4 * v4
    };
    let (x, y, z) = (eighth(d.x), eighth(d.y), eighth(d.z));
    let sum = x + y + z;
    [
        (if d.x >= 0.0 { 0 } else { 1 }, x / sum),
        (if d.y >= 0.0 { 2 } else { 3 }, y / sum),
        (if d.z >= 0.0 { 4 } else { 5 }, z / sum),
    ]
}

impl Chain for AnisoLevels {
    fn min(&self) -> DVec3 {
        self.min
    }
    fn count(&self) -> usize {
        1 + self.coarse.len()
    }
    fn res(&self, l: usize) -> u32 {
        if l == 0 {
            self.finest.res
        } else {
            self.coarse[l - 1].res
        }
    }
    fn cell(&self, l: usize) -> f64 {
        if l == 0 {
            self.finest.cell
        } else {
            self.coarse[l - 1].cell
        }
    }
    /// The mean of the six faces (what a cone sees averaged over the axis directions).
    fn value(&self, l: usize, c: [u32; 3]) -> Vec4 {
        if l == 0 {
            return self.finest.rgba[self.finest.index(c)];
        }
        let level = &self.coarse[l - 1];
        let r = level.res as usize;
        let i = c[0] as usize + r * (c[1] as usize + r * c[2] as usize);
        level.cells[i].iter().sum::<Vec4>() / FACES as f32
    }
    fn trilinear_dir(&self, l: usize, p: DVec3, w: &FaceWeights) -> Vec4 {
        if l == 0 {
            return self.trilinear(0, p);
        }
        let level = &self.coarse[l - 1];
        let r = level.res as usize;
        trilinear_with(self.min, level.cell, level.res, p, |c| {
            let i = c[0] as usize + r * (c[1] as usize + r * c[2] as usize);
            let v = &level.cells[i];
            v[w[0].0] * w[0].1 + v[w[1].0] * w[1].1 + v[w[2].0] * w[2].1
        })
    }
}
