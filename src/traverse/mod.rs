//! Revelles' parametric octree traversal (Revelles, Ureña & Lastra 2000), made iterative
//! with a fixed-size explicit stack so that `wgsl/shared/traverse.wgsl` can mirror it step by step.
//!
//! The ray is mirrored so every moving direction component is positive (§3.2, the `a`
//! mask); a child's t-interval comes from its parent's entry, midpoint and exit t-values
//! (§3.1), the first child from the entry plane (§3.2, Table 1 expressed as "bit i set when
//! the i-midpoint comes before the entry t"), and the next child from the exit plane (Table 2:
//! the axis of the smallest exit t, ties to the lowest axis). Parallel axes follow §3.3: their
//! midpoint t is −∞ or +∞ by which side of the midplane the origin lies on.
//!
//! Voxels are closed boxes: a ray that only touches a voxel (along a face, an edge, a corner)
//! hits it. A ray on a midplane of a parallel axis belongs to the upper child (half-open cells,
//! the same rule as `floor` in the DDA oracle).
//!
//! Revelles keeps the three t-vectors of every level on the stack and halves them on the way
//! down. A child repeats two of its parent's three values per axis, so a frame here keeps
//! only the third (see `trace_impl`) and a pop rebuilds the parent's vectors from the child's
//! with selects, bit for bit. The three lanes of a vector live in one SSE register.

mod lanes;
pub mod packet;

use crate::ray::{Ray, UnitRay};
use crate::svo::{Attr, Svo, MAX_DEPTH};
use glam::{BVec3A, Vec3, Vec3A};

/// Options of one traversal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TraceOptions {
    /// Hits before this t are ignored (a hit inside a voxel at `t_min` is reported at `t_min`).
    pub t_min: f32,
    /// Hits after this t are ignored.
    pub t_max: f32,
    /// Stop descending at this level and report the node there as the hit (level of detail).
    /// Values at or beyond the tree depth mean full detail.
    pub max_level: u32,
}

impl Default for TraceOptions {
    fn default() -> Self {
        TraceOptions { t_min: 0.0, t_max: f32::INFINITY, max_level: MAX_DEPTH }
    }
}

/// The nearest voxel a ray hits.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter of the hit (entry into the voxel, or `t_min` when the ray starts inside).
    pub t: f32,
    /// Level of the voxel (the tree depth unless `max_level` stopped earlier).
    pub level: u32,
    /// Integer coordinates of the voxel at `level`, in 0..2^level per axis.
    pub coord: [u32; 3],
    /// The voxel's stored attributes.
    pub attr: Attr,
    /// Unit normal of the voxel face the ray entered through (object space, axis-aligned),
    /// or zero when the ray started inside the voxel.
    pub face_normal: Vec3,
}

impl Hit {
    /// Linear albedo of the hit voxel.
    pub fn albedo(&self) -> Vec3 {
        self.attr.albedo_linear()
    }
    /// Stored (smooth) surface normal of the hit voxel, object space.
    pub fn normal(&self) -> Vec3 {
        self.attr.normal()
    }
}

/// A traversal's result with its loop count.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Traced {
    /// The nearest hit, if any.
    pub hit: Option<Hit>,
    /// Loop iterations taken.
    pub steps: u32,
    /// True when the loop reached [`step_bound`] (never observed; reported as a miss).
    pub aborted: bool,
}

/// Proven upper bound on the loop iterations for a tree of `depth` levels.
///
/// A line meets at most 3·2^l + 1 cells of a 2^l grid (each step crosses one plane); a node
/// frame processes at most 4 children (its exit mask gains a bit per step, 3 bits) and is
/// popped once, so iterations ≤ 5·Σ_{l<depth}(3·2^l + 1) + 1.
pub fn step_bound(depth: u32) -> u32 {
    let d = depth.min(MAX_DEPTH) as u64;
    (5 * (3 * ((1u64 << d) - 1) + d) + 1) as u32
}

/// Traces an object-space ray through an SVO. Returns the nearest hit in `[t_min, t_max]`:
/// [`trace_unit`]'s answer, found by the faster [`packet::trace_single`].
pub fn trace(svo: &Svo, ray: &Ray, opts: &TraceOptions) -> Option<Hit> {
    UnitRay::from_object(&svo.bounds, ray).and_then(|r| packet::trace_single(svo, &r, opts))
}

/// Stack depth needed: one frame per level above the leaves.
const STACK: usize = MAX_DEPTH as usize;

// t-values are never NaN ((p − o)·inv with finite operands; parallel axes are replaced by
// ±∞), so a plain comparison does, without f32::max's NaN handling.
#[inline(always)]
fn max(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

#[inline(always)]
fn min(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

/// The ray's t at planes: `(p − o)·inv` per axis, three lanes at a time.
#[derive(Clone, Copy)]
struct Planes {
    origin: Vec3A,
    inv_dir: Vec3A,
    /// Bit i: axis i is parallel; its planes give −∞ below the origin and +∞ on or above
    /// it (Revelles §3.3: a ray on a midplane belongs to the upper cell).
    parallel: u32,
}

/// Lane masks of the eight children: lane i set when child k lies in the upper half on axis i.
const UPPER: [BVec3A; 8] = {
    let mut m = [BVec3A::FALSE; 8];
    let mut k = 0;
    while k < 8 {
        m[k] = BVec3A::new(k & 1 != 0, k & 2 != 0, k & 4 != 0);
        k += 1;
    }
    m
};

impl Planes {
    /// t at the planes `k·size` of each axis (exact positions: k < 2^21, size a power of
    /// two). `PAR`: the ray may have parallel axes.
    #[inline(always)]
    fn at<const PAR: bool>(&self, k: [u32; 3], size: f32) -> Vec3A {
        let p = Vec3A::new(k[0] as i32 as f32, k[1] as i32 as f32, k[2] as i32 as f32) * size;
        let t = (p - self.origin) * self.inv_dir;
        if PAR && self.parallel != 0 {
            let par = BVec3A::new(self.parallel & 1 != 0, self.parallel & 2 != 0, self.parallel & 4 != 0);
            let side = Vec3A::select(self.origin.cmpge(p), Vec3A::NEG_INFINITY, Vec3A::INFINITY);
            return Vec3A::select(par, side, t);
        }
        t
    }
}

/// The t-values of the cell `c` of a level with cells of `size`: entry planes, midplanes
/// and exit planes (Revelles §3.1). On a parallel axis the traversal only visits cells whose
/// slab holds the ray, so their entry and exit are −∞ and +∞.
#[derive(Clone, Copy)]
struct Cell {
    t0: Vec3A,
    tm: Vec3A,
    t1: Vec3A,
}

impl Cell {
    #[inline(always)]
    fn new<const PAR: bool>(planes: &Planes, c: [u32; 3], size: f32) -> Cell {
        let mut t0 = planes.at::<false>(c, size);
        let mut t1 = planes.at::<false>(c.map(|v| v + 1), size);
        if PAR && planes.parallel != 0 {
            let p = planes.parallel;
            let par = BVec3A::new(p & 1 != 0, p & 2 != 0, p & 4 != 0);
            t0 = Vec3A::select(par, Vec3A::NEG_INFINITY, t0);
            t1 = Vec3A::select(par, Vec3A::INFINITY, t1);
        }
        Cell { t0, tm: planes.at::<PAR>(c.map(|v| 2 * v + 1), 0.5 * size), t1 }
    }
    /// Entry and exit planes of child `k` (bit i: the upper half on axis i).
    #[inline(always)]
    fn child(&self, k: u32) -> (Vec3A, Vec3A) {
        let upper = UPPER[k as usize & 7];
        (Vec3A::select(upper, self.tm, self.t0), Vec3A::select(upper, self.t1, self.tm))
    }
}

/// 2^−level, the edge of a cell at `level` (≤ 21) in the unit cube, from its exponent bits.
#[inline(always)]
fn cell_size(level: u32) -> f32 {
    f32::from_bits((127 - level) << 23)
}

/// First child entered (Revelles §3.2): bit i set when the i-midplane comes before the
/// entry (on a parallel axis: when the origin lies on or above it, §3.3).
#[inline(always)]
fn first_node(tm: Vec3A, t_entry: f32) -> u32 {
    tm.cmplt(Vec3A::splat(t_entry)).bitmask()
}

/// Revelles Table 2: the bit of the axis whose exit plane comes first, ties to the lowest
/// axis.
#[inline(always)]
fn exit_plane(t1: Vec3A) -> u32 {
    let at = t1.cmpeq(Vec3A::splat(t1.min_element())).bitmask();
    at & at.wrapping_neg()
}

/// Axis of the largest value, ties to the lowest axis.
#[inline]
fn argmax3(v: [f32; 3]) -> u32 {
    if v[0] >= v[1] && v[0] >= v[2] {
        0
    } else if v[1] >= v[2] {
        1
    } else {
        2
    }
}

/// Traces a prepared ray; see [`UnitRay`].
pub fn trace_unit(svo: &Svo, ray: &UnitRay, opts: &TraceOptions) -> Traced {
    // Rays with a parallel axis take the same loop with the §3.3 cases compiled in.
    if ray.parallel == 0 {
        trace_impl::<false>(svo, ray, opts)
    } else {
        trace_impl::<true>(svo, ray, opts)
    }
}

fn trace_impl<const PAR: bool>(svo: &Svo, ray: &UnitRay, opts: &TraceOptions) -> Traced {
    let miss = |steps| Traced { hit: None, steps, aborted: false };
    let t_min = ray.to_internal(opts.t_min.max(f32::MIN));
    let t_max = ray.to_internal(opts.t_max);
    if !(t_min <= t_max) {
        return miss(0);
    }
    let max_level = opts.max_level.min(svo.depth);
    let planes = Planes { origin: Vec3A::from(ray.origin), inv_dir: Vec3A::from(ray.inv_dir), parallel: ray.parallel };
    if PAR {
        for i in 0..3 {
            if ray.parallel & (1 << i) != 0 && !(ray.origin[i] >= 0.0 && ray.origin[i] < 1.0) {
                return miss(0);
            }
        }
    }
    let cell = Cell::new::<PAR>(&planes, [0; 3], 1.0);
    let (t_enter, t_exit) = (cell.t0.max_element(), cell.t1.min_element());
    if t_enter > t_exit || t_exit < t_min || t_enter > t_max {
        return miss(0);
    }
    if max_level == 0 {
        let t0 = cell.t0.to_array();
        return Traced { hit: finish(ray, t_enter, t_min, 0, [0; 3], svo.attrs[0], t0), steps: 1, aborted: false };
    }

    let mut steps = 0u32;
    let walked = walk::<PAR>(
        svo,
        ray,
        &planes,
        Below { level: 0, node: 0, coord: [0; 3], cell },
        t_min,
        t_max,
        max_level,
        &mut steps,
    );
    match walked {
        Walk::Reached(r) => {
            let attr = svo.attrs[r.attr];
            Traced { hit: finish(ray, r.te, t_min, r.level, r.coord, attr, r.ct0.to_array()), steps, aborted: false }
        }
        Walk::Left => miss(steps),
        Walk::Aborted => Traced { hit: None, steps, aborted: true },
    }
}

/// A node to walk below: its level, number, mirrored coordinates and t-values.
#[derive(Clone, Copy)]
pub(crate) struct Below {
    pub(crate) level: u32,
    pub(crate) node: usize,
    pub(crate) coord: [u32; 3],
    cell: Cell,
}

impl Below {
    /// A node whose t-values per axis are `t0` (entry planes) and `t1` (exit planes), with
    /// its midplanes halfway in t as Revelles §3.1 (for rays without parallel axes).
    #[inline(always)]
    pub(crate) fn new(level: u32, node: usize, coord: [u32; 3], t0: [f32; 3], t1: [f32; 3]) -> Below {
        let (t0, t1) = (Vec3A::from(t0), Vec3A::from(t1));
        Below { level, node, coord, cell: Cell { t0, tm: (t0 + t1) * 0.5, t1 } }
    }
}

/// The first leaf (or node at the level limit) a walk reached.
#[derive(Clone, Copy)]
pub(crate) struct Reached {
    /// Its entry t (the largest entry plane).
    pub(crate) te: f32,
    /// Its exit t (the smallest exit plane).
    pub(crate) tx: f32,
    pub(crate) level: u32,
    /// Mirrored coordinates.
    pub(crate) coord: [u32; 3],
    /// Index of its attributes in `attrs`.
    pub(crate) attr: usize,
    /// Its entry planes.
    ct0: Vec3A,
}

/// How a walk below a node ended.
pub(crate) enum Walk {
    /// The first leaf on the ray's chain below the node.
    Reached(Reached),
    /// The ray left the node (or passed `t_max`) without reaching a leaf.
    Left,
    /// The loop reached [`step_bound`] (never observed).
    Aborted,
}

/// Revelles' chain below `start` for a ray whose t-values there are `start.cell`: the same
/// steps, in the same order and with the same arithmetic, as the walk from the root takes
/// below that node when it enters it. `steps` counts the loop's iterations.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn walk<const PAR: bool>(
    svo: &Svo,
    ray: &UnitRay,
    planes: &Planes,
    start: Below,
    t_min: f32,
    t_max: f32,
    max_level: u32,
    steps: &mut u32,
) -> Walk {
    // Frames of the levels above the current node: its number, which of its children is
    // being visited, and per axis the one t-value of it that this child's t-values do not
    // repeat (its exit plane where the child is the lower half, its entry plane where the
    // upper): from those a pop rebuilds the node's t-values exactly, without arithmetic.
    let mut stack_node = [0u32; STACK];
    let mut stack_child = [0u8; STACK];
    let mut stack_keep = [Vec3A::ZERO; STACK];
    let Below { mut level, mut node, mut coord, mut cell } = start;
    let base = level;
    let mut child = first_node(cell.tm, max(cell.t0.max_element(), t_min));
    let bound = step_bound(svo.depth);
    loop {
        *steps += 1;
        if *steps > bound {
            return Walk::Aborted;
        }
        let (ct0, ct1) = cell.child(child);
        let te = ct0.max_element();
        if te > t_max {
            return Walk::Left; // children come front to back: nothing later can be closer
        }
        let octant = child ^ ray.mirror;
        let mask = svo.masks[node];
        if mask as u32 & (1 << octant) != 0 && ct1.min_element() >= t_min {
            let child_level = level + 1;
            let c = [0, 1, 2].map(|i| 2 * coord[i] + ((child >> i) & 1));
            if child_level >= max_level {
                let attr = svo.child_attr_index(node, octant);
                let tx = ct1.min_element();
                return Walk::Reached(Reached { te, tx, level: child_level, coord: c, attr, ct0 });
            }
            stack_node[level as usize] = node as u32;
            stack_child[level as usize] = child as u8;
            stack_keep[level as usize] = Vec3A::select(UPPER[child as usize], cell.t0, cell.t1);
            node = svo.child_node(node, octant);
            coord = c;
            level = child_level;
            // Revelles §3.1: the midplanes halfway in t.
            let mut tm = (ct0 + ct1) * 0.5;
            if PAR && ray.parallel != 0 {
                // §3.3: ±∞ by the origin's side (the halfway value of −∞ and ∞ is NaN).
                let side = planes.at::<true>(c.map(|v| 2 * v + 1), cell_size(level + 1));
                let p = ray.parallel;
                tm = Vec3A::select(BVec3A::new(p & 1 != 0, p & 2 != 0, p & 4 != 0), side, tm);
            }
            cell = Cell { t0: ct0, tm, t1: ct1 };
            child = first_node(tm, max(te, t_min));
            continue;
        }
        // Revelles Table 2: leave through the exit plane; leaving the parent if that bit is set.
        let mut exit_bit = exit_plane(ct1);
        while child & exit_bit != 0 {
            if level == base {
                return Walk::Left;
            }
            *steps += 1;
            level -= 1;
            // The parent's t-values from this node's and the kept ones.
            let k = stack_child[level as usize] as u32;
            let (upper, keep) = (UPPER[k as usize], stack_keep[level as usize]);
            let t1 = cell.t1;
            cell = Cell {
                t0: Vec3A::select(upper, keep, cell.t0),
                tm: Vec3A::select(upper, cell.t0, cell.t1),
                t1: Vec3A::select(upper, cell.t1, keep),
            };
            node = stack_node[level as usize] as usize;
            coord = coord.map(|v| v >> 1);
            // Where this node (child k of the parent) is left decides the parent's next child.
            child = k;
            exit_bit = exit_plane(t1);
        }
        child |= exit_bit;
    }
}

/// [`finish`] with default attributes, written into `out` in place. Returned, the hit was
/// copied from the stack into the packet's answers by wide loads that waited on `finish`'s
/// narrower stores (a store-forwarding stall on every hit; docs/benchmarks.md, step 47).
#[inline(never)]
fn finish_into(out: &mut Option<Hit>, ray: &UnitRay, te: f32, t_min: f32, level: u32, coord: [u32; 3], ct0: [f32; 3]) {
    *out = finish(ray, te, t_min, level, coord, Attr::default(), ct0);
}

/// Converts a mirrored-space hit back to object space. `te` is the voxel's entry t from the
/// traversal's f32 arithmetic (it decides whether the ray started inside); the reported t is
/// recomputed in f64 from the unrounded ray and the voxel's own entry planes, so neither the
/// midpoint recursion nor rounding the origin to f32 shows in it.
#[inline(always)]
fn finish(ray: &UnitRay, te: f32, t_min: f32, level: u32, coord: [u32; 3], attr: Attr, ct0: [f32; 3]) -> Option<Hit> {
    let inv_size = 1.0 / (1u64 << level) as f64;
    let mut t_entry = f64::NEG_INFINITY;
    for i in 0..3 {
        if ray.parallel & (1 << i) == 0 {
            t_entry = t_entry.max((coord[i] as f64 * inv_size - ray.origin64[i]) / ray.dir64[i]);
        }
    }
    let entered = te >= t_min;
    let t_internal = if entered { t_entry.max(t_min as f64) } else { t_min as f64 };
    let t = (ray.t_offset + t_internal * ray.t_scale) as f32;
    if !t.is_finite() {
        return None;
    }
    let top = (1u32 << level) - 1;
    let mut real = coord;
    for (i, r) in real.iter_mut().enumerate() {
        if ray.mirror & (1 << i) != 0 {
            *r = top - *r;
        }
    }
    let mut face_normal = Vec3::ZERO;
    if entered {
        let axis = argmax3(ct0) as usize;
        // Entering through the low face of a mirrored axis is entering the high face for real.
        face_normal[axis] = if ray.mirror & (1 << axis) != 0 { 1.0 } else { -1.0 };
    }
    Some(Hit { t, level, coord: real, attr, face_normal })
}
