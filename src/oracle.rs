//! Reference implementations the optimized code is tested against: a brute-force
//! Amanatides–Woo voxel walk (DDA) over a plain set of voxel coordinates, and the exact
//! closed-box interval of one voxel. Double precision, no octree.

use crate::ray::parallel_axes;
use crate::voxelize::VoxelGrid;
use glam::DVec3;
use std::collections::HashSet;

/// A plain set of occupied voxels of a 2^depth grid over the unit cube.
#[derive(Clone, Debug)]
pub struct VoxelSet {
    /// Grid depth.
    pub depth: u32,
    cells: HashSet<[u32; 3]>,
    lo: [u32; 3],
    hi: [u32; 3],
}

impl VoxelSet {
    /// A set from coordinates.
    pub fn new(depth: u32, coords: impl IntoIterator<Item = [u32; 3]>) -> Self {
        let cells: HashSet<[u32; 3]> = coords.into_iter().collect();
        let (mut lo, mut hi) = ([u32::MAX; 3], [0u32; 3]);
        for c in &cells {
            for i in 0..3 {
                lo[i] = lo[i].min(c[i]);
                hi[i] = hi[i].max(c[i]);
            }
        }
        VoxelSet { depth, cells, lo, hi }
    }
    /// The voxels of a grid.
    pub fn from_grid(grid: &VoxelGrid) -> Self {
        Self::new(grid.depth, grid.coords())
    }
    /// The set coarsened to `level` (a cell is occupied when any voxel inside it is).
    pub fn coarsen(&self, level: u32) -> Self {
        let s = self.depth - level.min(self.depth);
        Self::new(level.min(self.depth), self.cells.iter().map(|c| c.map(|v| v >> s)))
    }
    /// Whether a voxel is occupied.
    pub fn contains(&self, c: [u32; 3]) -> bool {
        self.cells.contains(&c)
    }
    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.cells.len()
    }
    /// Whether the set is empty.
    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }
}

/// The oracle's answer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OracleHit {
    /// Ray parameter of the hit.
    pub t: f64,
    /// Voxel coordinates.
    pub coord: [u32; 3],
    /// Axis of the face entered, None when the ray started inside the voxel.
    pub face_axis: Option<usize>,
}

/// How the oracle treats voxels the ray only touches.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Contact {
    /// Closed boxes: every voxel the ray touches counts, including every voxel sharing an
    /// edge or corner the ray passes through exactly.
    Closed,
    /// A voxel counts only if the ray stays inside it for longer than this t-span.
    MinOverlap(f64),
}

/// Walks the grid cell by cell along a unit-cube ray (`origin + t·dir`), restricted to the
/// bounding box of the set (nothing outside it can be hit), and returns the first occupied
/// cell in `[t_min, t_max]` under the given [`Contact`] rule. Parallel axes use the same
/// rule as the traversal ([`crate::ray::parallel_axes`]); at an exact edge or corner
/// crossing all axes involved step together, after (in `Closed` mode) checking every cell
/// touched at that point.
pub fn dda(set: &VoxelSet, origin: DVec3, dir: DVec3, t_min: f64, t_max: f64, contact: Contact) -> Option<OracleHit> {
    if set.is_empty() || !origin.is_finite() || !dir.is_finite() || dir.abs().max_element() == 0.0 {
        return None;
    }
    let n = (1u64 << set.depth) as f64;
    let p = origin * n;
    let d = dir * n;
    let par = parallel_axes(dir);
    let mut c = [0i64; 3];
    let (mut t_start, mut t_end) = (t_min, t_max);
    let mut near = [f64::NEG_INFINITY; 3];
    for i in 0..3 {
        let (lo, hi) = (set.lo[i] as f64, set.hi[i] as f64 + 1.0);
        if par & (1 << i) != 0 {
            if !(p[i] >= lo && p[i] < hi) {
                return None;
            }
            c[i] = p[i].floor() as i64;
        } else {
            let (a, b) = ((lo - p[i]) / d[i], (hi - p[i]) / d[i]);
            near[i] = a.min(b);
            t_start = t_start.max(near[i]);
            t_end = t_end.min(a.max(b));
        }
    }
    if !(t_start <= t_end) {
        return None;
    }
    // Entered through a face when the slab entry is not before t_min; else started inside.
    let entry_axis = (near[argmax(near)] >= t_min).then(|| argmax(near));
    for i in 0..3 {
        if par & (1 << i) != 0 {
            continue;
        }
        let (lo, hi) = (set.lo[i] as i64, set.hi[i] as i64);
        c[i] = if entry_axis == Some(i) {
            if d[i] > 0.0 {
                lo
            } else {
                hi
            }
        } else {
            let q = p[i] + t_start * d[i];
            // On a boundary the ray is in the cell it leaves (closed boxes: a touch hits).
            let ci = if d[i] > 0.0 { q.ceil() as i64 - 1 } else { q.floor() as i64 };
            ci.clamp(lo, hi)
        };
    }
    let occupied = |c: [i64; 3]| {
        (0..3).all(|i| c[i] >= set.lo[i] as i64 && c[i] <= set.hi[i] as i64)
            && set.contains([c[0] as u32, c[1] as u32, c[2] as u32])
    };
    let step = |i: usize| if d[i] > 0.0 { 1 } else { -1 };
    let mut t_cell = t_start;
    let mut face = entry_axis;
    let max_steps = 3 * (1u64 << set.depth) + 3;
    for _ in 0..max_steps {
        let mut tn = [f64::INFINITY; 3];
        for i in 0..3 {
            if par & (1 << i) == 0 {
                let b = if d[i] > 0.0 { c[i] + 1 } else { c[i] } as f64;
                tn[i] = (b - p[i]) / d[i];
            }
        }
        let t_next = tn[argmin(tn)].max(t_cell);
        if occupied(c) {
            let counts = match contact {
                Contact::Closed => true,
                Contact::MinOverlap(m) => t_next.min(t_end) - t_cell > m,
            };
            if counts {
                return Some(OracleHit { t: t_cell, coord: c.map(|v| v as u32), face_axis: face });
            }
        }
        if t_next > t_end {
            return None;
        }
        let ties: Vec<usize> = (0..3).filter(|&i| tn[i] <= t_next).collect();
        if contact == Contact::Closed && ties.len() > 1 {
            // Cells sharing only the crossed edge/corner: touched at t_next alone.
            for mask in 1..(1u32 << ties.len()) - 1 {
                let mut cc = c;
                for (k, &i) in ties.iter().enumerate() {
                    if mask & (1 << k) != 0 {
                        cc[i] += step(i);
                    }
                }
                if occupied(cc) {
                    let axis = ties.iter().enumerate().find(|(k, _)| mask & (1 << k) != 0).map(|(_, &i)| i);
                    return Some(OracleHit { t: t_next, coord: cc.map(|v| v as u32), face_axis: axis });
                }
            }
        }
        for &i in &ties {
            c[i] += step(i);
            if c[i] < set.lo[i] as i64 || c[i] > set.hi[i] as i64 {
                return None;
            }
        }
        t_cell = t_next;
        face = ties.first().copied();
    }
    None
}

/// The closed interval of t over which a unit-cube ray is inside voxel `coord` of a
/// 2^depth grid (empty when `enter > exit`). Parallel axes use half-open cells, as the
/// traversal does.
pub fn voxel_interval(depth: u32, coord: [u32; 3], origin: DVec3, dir: DVec3) -> (f64, f64) {
    voxel_interval_grown(depth, coord, origin, dir, 0.0)
}

/// [`voxel_interval`] of the voxel grown by `grow` (unit-cube units) on every side.
pub fn voxel_interval_grown(depth: u32, coord: [u32; 3], origin: DVec3, dir: DVec3, grow: f64) -> (f64, f64) {
    let n = (1u64 << depth) as f64;
    let (p, d) = (origin * n, dir * n);
    let par = parallel_axes(dir);
    let g = grow * n;
    let (mut enter, mut exit) = (f64::NEG_INFINITY, f64::INFINITY);
    for i in 0..3 {
        let (lo, hi) = (coord[i] as f64 - g, coord[i] as f64 + 1.0 + g);
        if par & (1 << i) != 0 {
            if !(p[i] >= lo && p[i] < hi) {
                return (f64::INFINITY, f64::NEG_INFINITY);
            }
        } else {
            let (a, b) = ((lo - p[i]) / d[i], (hi - p[i]) / d[i]);
            enter = enter.max(a.min(b));
            exit = exit.min(a.max(b));
        }
    }
    (enter, exit)
}

fn argmin(v: [f64; 3]) -> usize {
    if v[0] <= v[1] && v[0] <= v[2] {
        0
    } else if v[1] <= v[2] {
        1
    } else {
        2
    }
}

fn argmax(v: [f64; 3]) -> usize {
    if v[0] >= v[1] && v[0] >= v[2] {
        0
    } else if v[1] >= v[2] {
        1
    } else {
        2
    }
}
