//! Which instance a ray hits first. Four ways, chosen by the frame plan, that must give
//! bit-identical answers:
//!
//! - **plain** (the oracle): trace every instance over the whole ray, keep the nearest;
//! - **culling**: trace only instances whose bounding sphere the ray crosses;
//! - **culling + depth sort**: visit those instances by sphere entry t, trace each only up to
//!   the best t so far, and stop once the next entry lies beyond it (early-out);
//! - **BVH**: descend the instance BVH nearer box first, skipping boxes entered beyond the
//!   best t.
//!
//! The nearest hit wins; equal t goes to the lower instance index, in every mode.

use super::bvh::{box_entry, Bvh};
use super::bvh_wide::{WideRay, WideStack};
use super::instances::{sphere_interval, Prepared};
use crate::ray::UnitRay;
use crate::svo::Svo;
use crate::traverse::packet::trace_single;
use crate::traverse::{Hit, TraceOptions};
use glam::DVec3;
use std::sync::Arc;

/// How to find the nearest instance.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Search {
    /// Every instance, whole ray.
    Plain,
    /// Bounding-sphere culling.
    Cull,
    /// Culling plus depth-sorted early-out.
    CullSort,
    /// Instance BVH with early-out.
    Bvh,
}

/// The instances of one frame.
#[derive(Clone, Copy)]
pub struct FrameInstances<'a> {
    /// Part octrees.
    pub parts: &'a [Arc<Svo>],
    /// Prepared instances.
    pub prepared: &'a [Prepared],
    /// The BVH, when the plan uses one.
    pub bvh: Option<&'a Bvh>,
    /// Per instance, where this ray's beam lets it start ([`super::beam::starts`]), when the
    /// caller traces a tile of primary rays with beams.
    pub starts: Option<&'a [f32]>,
}

impl FrameInstances<'_> {
    /// Asks the cache for what tracing instance `i` reads first (its part and ray map), if
    /// there is such an instance; the caller goes on meanwhile.
    #[inline(always)]
    pub fn prefetch_ray_map(&self, i: usize) {
        if let Some(p) = self.prepared.get(i) {
            crate::prefetch::prefetch_bytes(p, std::mem::offset_of!(Prepared, centre));
        }
    }
}

/// The nearest hit of a ray among the instances.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InstanceHit {
    /// Instance index.
    pub instance: usize,
    /// The voxel hit (t along the camera-relative ray).
    pub hit: Hit,
}

#[inline]
fn trace_one(fi: &FrameInstances, i: usize, o: DVec3, d: DVec3, opts: &TraceOptions) -> Option<Hit> {
    if let Some(starts) = fi.starts {
        // Beam start (see `super::beam`): no hit before it; none at all at infinity.
        let start = starts[i];
        if start == f32::INFINITY {
            return None;
        }
        if start > opts.t_min {
            return trace_unit_at(fi, i, o, d, &TraceOptions { t_min: start, ..*opts });
        }
    }
    trace_unit_at(fi, i, o, d, opts)
}

#[inline]
fn trace_unit_at(fi: &FrameInstances, i: usize, o: DVec3, d: DVec3, opts: &TraceOptions) -> Option<Hit> {
    let p = &fi.prepared[i];
    let svo = &fi.parts[p.part];
    let (o, d) = (p.to_unit.point(o), p.to_unit.vector(d));
    // A ray through the instance's sphere that passes beside its part's voxels (most of a
    // crowd's, whose spheres are round and cars flat) is not walked down the tree.
    if line_misses_occupied(svo, opts.max_level, o, d) {
        return None;
    }
    let ur = UnitRay::from_unit(o, d)?;
    trace_single(svo, &ur, opts)
}

/// Padding of a part's occupied box (unit-cube coordinates) for [`line_misses_occupied`].
/// [`UnitRay::from_unit`] moves a ray's origin onto the cube before it becomes f32, so inside
/// the cube the traversal's ray strays from the f64 line by about 10⁻⁶ at most: 10⁻⁴ (a
/// twentieth of a voxel at depth 9) is far beyond it.
const OCCUPIED_PAD: f64 = 1e-4;

/// Whether the line `o + t·d` (unit-cube coordinates, f64) passes outside `svo`'s occupied
/// box at the traced level (`max_level`, capped by the depth), grown by [`OCCUPIED_PAD`]:
/// then no ray traced along it to that level can hit a voxel. False whenever unsure: a
/// ray that is not finite, runs parallel to an axis as [`UnitRay::from_unit`] counts it
/// (the traversal then holds that coordinate fixed), or a level with no box.
pub(crate) fn line_misses_occupied(svo: &Svo, max_level: u32, o: DVec3, d: DVec3) -> bool {
    let level = max_level.min(svo.depth);
    let Some(&[lo, hi]) = svo.occupied_unit().get(level as usize) else { return false };
    if !(o.is_finite() && d.is_finite()) || crate::ray::parallel_axes_finite(d) != 0 || lo.cmpge(hi).any() {
        return false;
    }
    let (mut enter, mut exit, mut nan) = (f64::NEG_INFINITY, f64::INFINITY, false);
    for k in 0..3 {
        let (a, b) = (lo[k] - OCCUPIED_PAD, hi[k] + OCCUPIED_PAD);
        // No component is zero here (none is parallel). A reciprocal and two products round
        // within a few units of 2⁻⁵² of the quotients, far inside the padding. Selects that
        // compile to minsd and maxsd instead of `f64::min`'s NaN handling; a NaN (the
        // reciprocal of a subnormal component overflowed, times a zero) is caught after.
        let inv = 1.0 / d[k];
        let (t0, t1) = ((a - o[k]) * inv, (b - o[k]) * inv);
        nan |= t0.is_nan() | t1.is_nan();
        let near = if t0 < t1 { t0 } else { t1 };
        let far = if t0 > t1 { t0 } else { t1 };
        enter = if near > enter { near } else { enter };
        exit = if far < exit { far } else { exit };
    }
    !nan && enter > exit
}

/// Whether the ray's tile beam rules instance `i` out (see [`FrameInstances::starts`]).
#[inline]
fn beam_misses(fi: &FrameInstances, i: usize) -> bool {
    fi.starts.is_some_and(|s| s[i] == f32::INFINITY)
}

/// The `t_max` for tracing an instance that must find any hit at or before `t`, the best so
/// far: the trace compares in its ray's internal units, and the conversion rounds, so a hit
/// at exactly `t` could fall an ulp outside. Four ulps more cannot miss it (the offset into
/// internal units is never negative); `keep` then compares the t found with `t` exactly.
#[inline]
pub fn widen(t: f32) -> f32 {
    if t.is_finite() && t >= 0.0 {
        f32::from_bits(t.to_bits() + 4)
    } else {
        t
    }
}

#[inline]
pub(super) fn keep(best: &mut Option<InstanceHit>, i: usize, hit: Hit) {
    let better = match best {
        None => true,
        Some(b) => hit.t < b.hit.t || (hit.t == b.hit.t && i < b.instance),
    };
    if better {
        *best = Some(InstanceHit { instance: i, hit });
    }
}

/// A fixed-size stack for walking the instance BVH (no allocation per ray).
struct Stack<T: Copy + Default> {
    items: [T; 64],
    len: usize,
}

impl<T: Copy + Default> Stack<T> {
    fn new() -> Self {
        Stack { items: [T::default(); 64], len: 0 }
    }
    #[inline]
    fn push(&mut self, v: T) {
        // Median splits bound the tree's depth by 32 and a walk holds at most one waiting
        // sibling per level, so this is never full; the check keeps memory safe regardless.
        debug_assert!(self.len < self.items.len(), "BVH deeper than median splits allow");
        if self.len < self.items.len() {
            self.items[self.len] = v;
            self.len += 1;
        }
    }
    #[inline]
    fn pop(&mut self) -> Option<T> {
        self.len = self.len.checked_sub(1)?;
        Some(self.items[self.len])
    }
}

/// What a nearest-hit search cost: the statistics the demo shows per ray.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Work {
    /// Instances whose octree the ray was traversed through.
    pub traced: u64,
    /// Instances whose bounding sphere the ray missed (not traversed).
    pub culled: u64,
}

/// The nearest instance hit along `o + t·d` (camera-relative origin, unit direction).
pub fn nearest(fi: &FrameInstances, o: DVec3, d: DVec3, search: Search, opts: &TraceOptions) -> Option<InstanceHit> {
    nearest_work(fi, o, d, search, opts, &mut Work::default())
}

/// [`nearest`], adding what the search cost to `work`.
pub fn nearest_work(
    fi: &FrameInstances,
    o: DVec3,
    d: DVec3,
    search: Search,
    opts: &TraceOptions,
    work: &mut Work,
) -> Option<InstanceHit> {
    let mut best: Option<InstanceHit> = None;
    let bound = |best: &Option<InstanceHit>| best.map_or(opts.t_max, |b| b.hit.t);
    match search {
        Search::Plain => {
            for i in 0..fi.prepared.len() {
                work.traced += 1;
                if let Some(h) = trace_one(fi, i, o, d, opts) {
                    keep(&mut best, i, h);
                }
            }
        }
        Search::Cull => {
            for (i, p) in fi.prepared.iter().enumerate() {
                if !beam_misses(fi, i) && sphere_interval(p.centre, p.radius, o, d).is_some() {
                    work.traced += 1;
                    if let Some(h) = trace_one(fi, i, o, d, opts) {
                        keep(&mut best, i, h);
                    }
                } else {
                    work.culled += 1;
                }
            }
        }
        Search::CullSort => {
            let mut cands: Vec<(f64, u32)> = fi
                .prepared
                .iter()
                .enumerate()
                .filter(|&(i, _)| !beam_misses(fi, i))
                .filter_map(|(i, p)| sphere_interval(p.centre, p.radius, o, d).map(|(t0, _)| (t0, i as u32)))
                .collect();
            cands.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            return nearest_listed(fi, o, d, &cands, opts, work);
        }
        Search::Bvh => {
            let Some(bvh) = fi.bvh else { return nearest_work(fi, o, d, Search::CullSort, opts, work) };
            if bvh.nodes.is_empty() {
                return None;
            }
            if bvh.wide.covers_origin(o) {
                nearest_wide(fi, bvh, o, d, opts, work, &mut best);
                return best;
            }
            let inv = d.recip();
            // Median splits halve the items per level, so the tree is at most 32 deep and at
            // most one sibling per level waits: no allocation per ray.
            let mut stack = Stack::<(u32, f64)>::new();
            if let Some(t) = box_entry(bvh.nodes[0].lo, bvh.nodes[0].hi, o, inv, f64::INFINITY) {
                stack.push((0, t));
            }
            while let Some((n, entry)) = stack.pop() {
                let t_max = bound(&best);
                if entry > t_max as f64 {
                    continue;
                }
                let node = bvh.nodes[n as usize];
                if node.count > 0 {
                    for &i in &bvh.items[node.first as usize..(node.first + node.count) as usize] {
                        visit_item(fi, i as usize, o, d, opts, work, &mut best);
                    }
                } else {
                    let t_max = bound(&best) as f64;
                    let (l, r) = (node.first, node.first + 1);
                    let el = box_entry(bvh.nodes[l as usize].lo, bvh.nodes[l as usize].hi, o, inv, t_max);
                    let er = box_entry(bvh.nodes[r as usize].lo, bvh.nodes[r as usize].hi, o, inv, t_max);
                    // Push the farther child first so the nearer one is popped first.
                    match (el, er) {
                        (Some(a), Some(b)) if a <= b => {
                            stack.push((r, b));
                            stack.push((l, a));
                        }
                        (Some(a), Some(b)) => {
                            stack.push((l, a));
                            stack.push((r, b));
                        }
                        (Some(a), None) => stack.push((l, a)),
                        (None, Some(b)) => stack.push((r, b)),
                        (None, None) => {}
                    }
                }
            }
        }
    }
    best
}

/// The nearest hit along `o + t·d` among the instances `listed` as (sphere entry t,
/// instance), ascending by t then instance: when the list holds every instance whose sphere
/// the ray meets (and the tile's beam lets through), the nearest hit among all instances.
/// Visits them in order, each traced up to the best hit so far, and stops at the first whose
/// sphere starts beyond it (the depth-sorted early-out). The others count as culled.
pub fn nearest_listed(
    fi: &FrameInstances,
    o: DVec3,
    d: DVec3,
    listed: &[(f64, u32)],
    opts: &TraceOptions,
    work: &mut Work,
) -> Option<InstanceHit> {
    let mut best: Option<InstanceHit> = None;
    work.culled += fi.prepared.len().saturating_sub(listed.len()) as u64;
    for (j, &(entry, i)) in listed.iter().enumerate() {
        let t_max = best.map_or(opts.t_max, |b| b.hit.t);
        if entry > t_max as f64 {
            break; // every later sphere starts beyond the nearest hit
        }
        if let Some(&(_, next)) = listed.get(j + 1) {
            fi.prefetch_ray_map(next as usize);
        }
        work.traced += 1;
        if let Some(h) = trace_one(fi, i as usize, o, d, &TraceOptions { t_max: widen(t_max), ..*opts }) {
            keep(&mut best, i as usize, h);
        }
    }
    best
}

/// [`nearest_moved`] through a pixel's sphere list ([`nearest_listed`]'s `listed`, nearest
/// entry first): of the listed instances, only those `moved` marks (one flag per instance)
/// are traced, nearest entry first, up to the nearer of the best hit and the bound `(t,
/// instance)`. The list holds every instance whose sphere the ray meets, so this is the
/// answer [`nearest_moved`] gives, without testing every moved instance's sphere.
#[allow(clippy::too_many_arguments)]
pub fn nearest_listed_moved(
    fi: &FrameInstances,
    o: DVec3,
    d: DVec3,
    listed: &[(f64, u32)],
    moved: &[bool],
    moved_count: usize,
    t: f32,
    instance: i32,
    opts: &TraceOptions,
    work: &mut Work,
) -> Option<InstanceHit> {
    let mut beat = Beating::new(t, instance);
    let is_moved = |i: u32| moved.get(i as usize).copied().unwrap_or(false);
    // The moved instances whose sphere the ray meets (the others count as culled).
    let mut met = 0;
    for (j, &(entry, i)) in listed.iter().enumerate() {
        if !is_moved(i) {
            continue;
        }
        if entry > beat.t_max(opts) as f64 {
            // Every later sphere starts beyond the nearest hit.
            met += listed[j..].iter().filter(|&&(_, i)| is_moved(i)).count();
            break;
        }
        met += 1;
        beat.trace(fi, i as usize, o, d, opts, work);
    }
    work.culled += moved_count.saturating_sub(met) as u64;
    beat.best
}

/// A moved-only search's nearest hit so far, which must beat the bound set by the instances
/// that did not move (equal t: the lower index wins, as in [`nearest`]).
struct Beating {
    t: f32,
    instance: usize,
    best: Option<InstanceHit>,
}

impl Beating {
    /// The bound `(t, instance)` (instance −1: none).
    fn new(t: f32, instance: i32) -> Self {
        Beating { t, instance: usize::try_from(instance).unwrap_or(usize::MAX), best: None }
    }

    /// How far a ray is traced: the nearer of the bound and `opts.t_max`.
    fn t_max(&self, opts: &TraceOptions) -> f32 {
        self.t.min(opts.t_max)
    }

    /// Traces instance `i` up to [`Beating::t_max`] and keeps its hit if it beats the bound.
    fn trace(&mut self, fi: &FrameInstances, i: usize, o: DVec3, d: DVec3, opts: &TraceOptions, work: &mut Work) {
        work.traced += 1;
        let t_max = widen(self.t_max(opts));
        if let Some(h) = trace_one(fi, i, o, d, &TraceOptions { t_max, ..*opts }) {
            if h.t < self.t || (h.t == self.t && i < self.instance) {
                (self.t, self.instance) = (h.t, i);
                self.best = Some(InstanceHit { instance: i, hit: h });
            }
        }
    }
}

/// One BVH leaf item of a nearest-hit search: culled by the tile's beam or its sphere, skipped
/// when its sphere starts beyond the best hit, traced up to the best hit otherwise.
#[inline]
fn visit_item(
    fi: &FrameInstances,
    i: usize,
    o: DVec3,
    d: DVec3,
    opts: &TraceOptions,
    work: &mut Work,
    best: &mut Option<InstanceHit>,
) {
    let p = &fi.prepared[i];
    let sphere = if beam_misses(fi, i) { None } else { sphere_interval(p.centre, p.radius, o, d) };
    let Some((t0, _)) = sphere else {
        work.culled += 1;
        return;
    };
    let t_max = best.map_or(opts.t_max, |b| b.hit.t);
    if t0 > t_max as f64 {
        return;
    }
    work.traced += 1;
    if let Some(h) = trace_one(fi, i, o, d, &TraceOptions { t_max: widen(t_max), ..*opts }) {
        keep(best, i, h);
    }
}

/// The BVH search of [`nearest_work`] over the four-wide f32 tree (the same answer: it only
/// culls, never skipping a box the ray crosses): children nearer first, boxes entered beyond
/// the best t skipped.
fn nearest_wide(
    fi: &FrameInstances,
    bvh: &Bvh,
    o: DVec3,
    d: DVec3,
    opts: &TraceOptions,
    work: &mut Work,
    best: &mut Option<InstanceHit>,
) {
    let bound = |best: &Option<InstanceHit>| best.map_or(opts.t_max, |b| b.hit.t);
    let ray = WideRay::new(o, d);
    let mut stack = WideStack::new();
    stack.push((0, 0.0));
    while let Some((n, entry)) = stack.pop() {
        // The entry is a lower bound (the boxes are widened), so this skips only boxes
        // wholly beyond the best hit.
        if entry > bound(best) {
            continue;
        }
        if n & LEAF_BIT != 0 {
            // A leaf child: lane n % 4 of node n / 4.
            let (w, k) = (((n & !LEAF_BIT) / 4) as usize, (n % 4) as usize);
            let node = &bvh.wide.nodes[w];
            let first = node.child[k] as usize;
            for &i in &bvh.items[first..first + node.count[k] as usize] {
                visit_item(fi, i as usize, o, d, opts, work, best);
            }
            continue;
        }
        let node = &bvh.wide.nodes[n as usize];
        let (mut hit, t0) = ray.test(node, bound(best));
        // Children nearer first, leaves and inner nodes alike (as the binary walk orders them).
        let mut next = [(0u32, 0.0f32); 4];
        let mut len = 0;
        while hit != 0 {
            let k = hit.trailing_zeros() as usize;
            hit &= hit - 1;
            let id = if node.count[k] == 0 { node.child[k] } else { LEAF_BIT | (n * 4 + k as u32) };
            next[len] = (id, t0[k]);
            len += 1;
        }
        // Push the farthest first so the nearest is popped first.
        next[..len].sort_unstable_by(|a, b| b.1.total_cmp(&a.1));
        for &c in &next[..len] {
            stack.push(c);
        }
    }
}

/// Marks a wide-walk stack entry as a leaf child (node · 4 + lane) rather than a node.
const LEAF_BIT: u32 = 1 << 31;

/// The nearest hit along `o + t·d` among the instances `moved` that beats `(t, instance)`:
/// the nearest hit among all the other instances (t = +∞ and instance −1 when they have
/// none). Together they are the nearest hit among all instances, exactly as [`nearest`]
/// finds it (equal t to the lower index), without tracing the others again. The hit
/// buffer uses this for a pixel whose stored hit is on an instance that did not move while
/// some moved instance's sphere crosses its ray: only the moved instances can have changed.
#[allow(clippy::too_many_arguments)]
pub fn nearest_moved(
    fi: &FrameInstances,
    o: DVec3,
    d: DVec3,
    moved: &[u32],
    t: f32,
    instance: i32,
    opts: &TraceOptions,
    work: &mut Work,
) -> Option<InstanceHit> {
    let mut beat = Beating::new(t, instance);
    for &i in moved {
        let i = i as usize;
        let p = &fi.prepared[i];
        let sphere = if beam_misses(fi, i) { None } else { sphere_interval(p.centre, p.radius, o, d) };
        let Some((t0, _)) = sphere else {
            work.culled += 1;
            continue;
        };
        if t0 > beat.t_max(opts) as f64 {
            continue;
        }
        beat.trace(fi, i, o, d, opts, work);
    }
    beat.best
}

/// Whether anything blocks `o + t·d` for t in (0, `t_max`] (shadow rays; `d` unit length, so
/// `t_max` is a distance; ∞ for the sun), traced down to octree level `max_level` (the
/// frame's level of detail, as its primary rays and the GPU's shadow rays; `u32::MAX`: the
/// voxels): any hit ends the search.
pub fn occluded(fi: &FrameInstances, o: DVec3, d: DVec3, t_max: f64, search: Search, max_level: u32) -> bool {
    let opts = TraceOptions { t_max: t_max as f32, max_level, ..TraceOptions::default() };
    match (search, fi.bvh) {
        (Search::Plain, _) => (0..fi.prepared.len()).any(|i| trace_one(fi, i, o, d, &opts).is_some()),
        (Search::Bvh, Some(bvh)) if !bvh.nodes.is_empty() => {
            let inv = d.recip();
            let mut stack = Stack::<u32>::new();
            stack.push(0);
            while let Some(n) = stack.pop() {
                let node = bvh.nodes[n as usize];
                if box_entry(node.lo, node.hi, o, inv, t_max).is_none() {
                    continue;
                }
                if node.count == 0 {
                    stack.push(node.first);
                    stack.push(node.first + 1);
                    continue;
                }
                for &i in &bvh.items[node.first as usize..(node.first + node.count) as usize] {
                    let p = &fi.prepared[i as usize];
                    if sphere_interval(p.centre, p.radius, o, d).is_some_and(|(t0, _)| t0 <= t_max)
                        && trace_one(fi, i as usize, o, d, &opts).is_some()
                    {
                        return true;
                    }
                }
            }
            false
        }
        _ => fi.prepared.iter().enumerate().any(|(i, p)| {
            sphere_interval(p.centre, p.radius, o, d).is_some_and(|(t0, _)| t0 <= t_max)
                && trace_one(fi, i, o, d, &opts).is_some()
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use crate::svo::Cube;
    use glam::Vec3;

    /// A line [`line_misses_occupied`] rules out is hit by no traversal: rays aimed just
    /// inside and just outside a face of the occupied box (at the full depth and coarser
    /// levels), from close by and from far away, over sparse and fuller parts. Many are ruled
    /// out and many of the others hit right at the box's faces.
    #[test]
    fn lines_beside_the_occupied_box_hit_nothing() {
        let mut rng = Rng::new(17);
        let depth = 6;
        let (mut ruled_out, mut at_faces) = (0, 0);
        for set in 0..6u32 {
            let coords: Vec<[u32; 3]> = (0..3 + set * 20).map(|_| [0; 3].map(|_| 10 + rng.below(30) as u32)).collect();
            let grid = crate::voxelize::VoxelGrid::from_coords(
                depth,
                Cube { min: Vec3::ZERO, size: 1.0 },
                coords.iter().copied(),
                Vec3::ONE,
            );
            let svo = crate::svo::build(&grid).expect("a valid grid");
            for level in [depth, 4, 2] {
                let [lo, hi] = svo.occupied_cells()[level as usize];
                let cell = 1.0 / (1u64 << level) as f64;
                let (blo, bhi) = (DVec3::from(lo.map(|c| c as f64 * cell)), DVec3::from(hi.map(|c| c as f64 * cell)));
                let opts = TraceOptions { max_level: level, ..TraceOptions::default() };
                for _ in 0..3000 {
                    // A point of the box, moved onto one face and then up to a fiftieth of the
                    // cube in or out of it.
                    let mut target = blo + (bhi - blo) * DVec3::new(rng.f64(), rng.f64(), rng.f64());
                    let axis = rng.below(3) as usize;
                    let face = if rng.below(2) == 0 { blo[axis] } else { bhi[axis] };
                    target[axis] = face + (rng.f64() - 0.5) * 0.04;
                    let away = DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5).normalize_or(DVec3::X);
                    let from = target + away * [0.8, 20.0, 1e4][rng.below(3) as usize];
                    let d = target - from;
                    let hit = UnitRay::from_unit(from, d).and_then(|r| trace_single(&svo, &r, &opts));
                    if line_misses_occupied(&svo, level, from, d) {
                        ruled_out += 1;
                        assert_eq!(hit, None, "level {level}: from {from} towards {target}");
                    } else if let Some(h) = hit {
                        let p = from + d * h.t as f64;
                        if (0..3).any(|k| (p[k] - blo[k]).abs().min((p[k] - bhi[k]).abs()) < 0.01) {
                            at_faces += 1;
                        }
                    }
                }
            }
        }
        assert!(ruled_out > 1000 && at_faces > 1000, "{ruled_out} ruled out, {at_faces} hits at the faces");
    }
}
