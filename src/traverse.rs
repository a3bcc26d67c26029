//! Revelles' parametric octree traversal (Revelles, Ureña & Lastra 2000), made iterative
//! with a fixed-size explicit stack so that `wgsl/traverse.wgsl` can mirror it step by step.
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

use crate::ray::{Ray, UnitRay};
use crate::svo::{Attr, Svo, MAX_DEPTH};
use glam::Vec3;

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

/// Traces an object-space ray through an SVO. Returns the nearest hit in `[t_min, t_max]`.
pub fn trace(svo: &Svo, ray: &Ray, opts: &TraceOptions) -> Option<Hit> {
    UnitRay::from_object(&svo.bounds, ray).and_then(|r| trace_unit(svo, &r, opts).hit)
}

#[derive(Clone, Copy, Default)]
struct Frame {
    slot: u32,
    /// Next child to visit in mirrored octant numbering; 8 = done.
    child: u32,
    coord: [u32; 3],
    t0: [f32; 3],
    t1: [f32; 3],
    tm: [f32; 3],
}

/// Stack depth needed: one frame per level above the leaves.
const STACK: usize = MAX_DEPTH as usize;

#[inline]
fn max3(v: [f32; 3]) -> f32 {
    v[0].max(v[1]).max(v[2])
}
#[inline]
fn min3(v: [f32; 3]) -> f32 {
    v[0].min(v[1]).min(v[2])
}

/// Midpoint t-values of a node; parallel axes by the side of the midplane (Revelles §3.3).
#[inline]
fn midpoints(ray: &UnitRay, t0: [f32; 3], t1: [f32; 3], level: u32, coord: [u32; 3]) -> [f32; 3] {
    let mut tm = [0.0; 3];
    for i in 0..3 {
        tm[i] = if ray.parallel & (1 << i) != 0 {
            // Exact: (2c+1)/2^(level+1) is a dyadic rational with ≤ 21 significant bits.
            let mid = (2 * coord[i] + 1) as f32 / (1u64 << (level + 1)) as f32;
            if ray.origin[i] >= mid {
                f32::NEG_INFINITY
            } else {
                f32::INFINITY
            }
        } else {
            0.5 * (t0[i] + t1[i])
        };
    }
    tm
}

/// First child entered (Revelles §3.2): bit i set when the i-midpoint lies before the entry.
#[inline]
fn first_node(tm: [f32; 3], t_entry: f32) -> u32 {
    (tm[0] < t_entry) as u32 | ((tm[1] < t_entry) as u32) << 1 | ((tm[2] < t_entry) as u32) << 2
}

/// Axis of the smallest value, ties to the lowest axis.
#[inline]
fn argmin3(v: [f32; 3]) -> u32 {
    if v[0] <= v[1] && v[0] <= v[2] {
        0
    } else if v[1] <= v[2] {
        1
    } else {
        2
    }
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
    let miss = |steps| Traced { hit: None, steps, aborted: false };
    let t_min = ray.to_internal(opts.t_min.max(f32::MIN));
    let t_max = ray.to_internal(opts.t_max);
    if !(t_min <= t_max) {
        return miss(0);
    }
    let max_level = opts.max_level.min(svo.depth);

    let (mut t0, mut t1) = ([0.0f32; 3], [0.0f32; 3]);
    for i in 0..3 {
        if ray.parallel & (1 << i) != 0 {
            if !(ray.origin[i] >= 0.0 && ray.origin[i] < 1.0) {
                return miss(0);
            }
            t0[i] = f32::NEG_INFINITY;
            t1[i] = f32::INFINITY;
        } else {
            t0[i] = -ray.origin[i] * ray.inv_dir[i];
            t1[i] = (1.0 - ray.origin[i]) * ray.inv_dir[i];
        }
    }
    let (t_enter, t_exit) = (max3(t0), min3(t1));
    if t_enter > t_exit || t_exit < t_min || t_enter > t_max {
        return miss(0);
    }
    if max_level == 0 {
        return Traced { hit: finish(ray, t_enter, t_min, 0, [0; 3], svo.attrs[0], t0), steps: 1, aborted: false };
    }

    let mut stack = [Frame::default(); STACK];
    let tm = midpoints(ray, t0, t1, 0, [0; 3]);
    stack[0] = Frame { slot: 0, child: first_node(tm, t_enter.max(t_min)), coord: [0; 3], t0, t1, tm };
    let mut sp = 1usize; // frames on the stack; the top is stack[sp - 1], at level sp - 1
    let bound = step_bound(svo.depth);
    let mut steps = 0u32;
    loop {
        steps += 1;
        if steps > bound {
            return Traced { hit: None, steps, aborted: true };
        }
        let level = (sp - 1) as u32;
        let f = stack[sp - 1];
        if f.child >= 8 {
            sp -= 1;
            if sp == 0 {
                return miss(steps);
            }
            continue;
        }
        let c = f.child;
        let (mut ct0, mut ct1) = ([0.0f32; 3], [0.0f32; 3]);
        for i in 0..3 {
            if c & (1 << i) != 0 {
                ct0[i] = f.tm[i];
                ct1[i] = f.t1[i];
            } else {
                ct0[i] = f.t0[i];
                ct1[i] = f.tm[i];
            }
        }
        // Revelles Table 2: leave through the exit plane; leaving the parent if that bit is set.
        let exit_bit = 1 << argmin3(ct1);
        stack[sp - 1].child = if c & exit_bit != 0 { 8 } else { c | exit_bit };

        let (te, tx) = (max3(ct0), min3(ct1));
        if te > t_max {
            return miss(steps); // children come front to back: nothing later can be closer
        }
        if tx < t_min {
            continue;
        }
        let octant = c ^ ray.mirror;
        let node = svo.nodes[f.slot as usize];
        if node.valid() as u32 & (1 << octant) == 0 {
            continue;
        }
        let child_level = level + 1;
        let coord = [2 * f.coord[0] + (c & 1), 2 * f.coord[1] + ((c >> 1) & 1), 2 * f.coord[2] + ((c >> 2) & 1)];
        if node.leaf() as u32 & (1 << octant) != 0 || child_level >= max_level {
            let attr = svo.child_attr(f.slot as usize, octant);
            return Traced { hit: finish(ray, te, t_min, child_level, coord, attr, ct0), steps, aborted: false };
        }
        let slot = svo.child_slot(f.slot as usize, octant) as u32;
        let tm = midpoints(ray, ct0, ct1, child_level, coord);
        stack[sp] = Frame { slot, child: first_node(tm, te.max(t_min)), coord, t0: ct0, t1: ct1, tm };
        sp += 1;
    }
}

/// Converts a mirrored-space hit back to object space. `te` is the voxel's entry t from the
/// traversal's f32 arithmetic (it decides whether the ray started inside); the reported t is
/// recomputed in f64 from the unrounded ray and the voxel's own entry planes, so neither the
/// midpoint recursion nor rounding the origin to f32 shows in it.
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
