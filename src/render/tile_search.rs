//! The nearest-hit search of [`super::visibility`] for a whole tile of primary rays at once:
//! each instance's octree is traversed by the tile's rays as one packet
//! ([`crate::traverse::packet`]) instead of ray by ray; and the same for shadow rays, and
//! for a library caller's runs of rays from points of their own ([`crate::cast`]).
//!
//! The answers are [`super::visibility::nearest_work`]'s bit for bit, in every search mode:
//! every mode finds the plain search's answer (the nearest t, equal t to the lower instance),
//! a trace bounded by the best t so far finds either the unbounded trace's hit or nothing,
//! and the packet finds what the scalar traversal finds. The search differs only in order:
//! the tile visits its instances by beam start, nearest first (or, before them, the one its
//! rays hit last frame), and a ray skips an instance whose beam start or sphere entry lies
//! beyond its best hit.

use super::instances::{sphere_interval, Prepared};
use super::visibility::{keep, widen, FrameInstances, InstanceHit, Search, Work};
use crate::ray::UnitRay;
use crate::svo::Svo;
use crate::traverse::packet::{trace_packet, PacketStack, LANES};
use crate::traverse::{Hit, TraceOptions};
use glam::DVec3;

/// Reusable memory of [`nearest_packet`]: make one per thread, or borrow the thread's own
/// ([`TileScratch::with`]).
pub struct TileScratch {
    stack: PacketStack,
    rays: Vec<Option<UnitRay>>,
    opts: Vec<TraceOptions>,
    hits: Vec<Option<Hit>>,
    order: Vec<(f32, usize)>,
    /// [`nearest_listed_packet`]'s instances: (least sphere entry, instance, lanes listing it).
    listed: Vec<(f64, u32, u64)>,
    /// A tile run's beam starts ([`super::primary::trace_tiles`]).
    pub(super) starts: Vec<f32>,
}

impl Default for TileScratch {
    fn default() -> Self {
        TileScratch {
            stack: PacketStack::default(),
            rays: vec![None; LANES],
            opts: vec![TraceOptions::default(); LANES],
            hits: vec![None; LANES],
            order: Vec::new(),
            listed: Vec::new(),
            starts: Vec::new(),
        }
    }
}

impl TileScratch {
    /// Runs `f` with this thread's scratch, made on the thread's first call and kept for its
    /// next: made afresh per band of tiles, its 48 KiB packet stack was zeroed two dozen times
    /// a frame. What a use leaves in it is never read by the next (each lane is set before it
    /// is traced; the stack's frames are written before they are read). A call made while
    /// the thread's scratch is out (nested) gets one of its own.
    pub fn with<R>(f: impl FnOnce(&mut TileScratch) -> R) -> R {
        thread_local! {
            static KEPT: std::cell::Cell<Option<Box<TileScratch>>> = const { std::cell::Cell::new(None) };
        }
        let mut scratch = KEPT.take().unwrap_or_default();
        let out = f(&mut scratch);
        KEPT.set(Some(scratch));
        out
    }

    /// The rays of the lanes `lanes`, `unit_o + t·d` with `d` the direction `dirs[k]` mapped
    /// into instance `p`'s unit cube: `UnitRay::from_unit`'s rays, set up four at a time
    /// ([`super::ray_setup`]). Their options are set apart.
    fn map_lanes(&mut self, p: &Prepared, unit_o: DVec3, dirs: &[DVec3], lanes: u64) {
        for_fours(lanes, |n, ks| super::ray_setup::map_four(&p.to_unit, unit_o, dirs, n, ks, &mut self.rays));
    }

    /// [`Self::map_lanes`] for rays from points of their own: lane `k`'s from `origins[k]`
    /// (before its map into the cube).
    fn map_lanes_from(&mut self, p: &Prepared, origins: &[DVec3], dirs: &[DVec3], lanes: u64) {
        for_fours(lanes, |n, ks| super::ray_setup::map_four_from(&p.to_unit, origins, dirs, n, ks, &mut self.rays));
    }

    /// Traces the lanes `todo` (each set by [`Self::map_lanes`] or [`Self::map_lanes_from`])
    /// through `svo` as one packet and returns the hits, lowest lane first.
    fn trace(&mut self, svo: &Svo, todo: u64) -> impl Iterator<Item = (usize, Hit)> + '_ {
        if todo != 0 {
            trace_packet(svo, &self.rays, &self.opts, todo, &mut self.stack, &mut self.hits);
        }
        let hits = &self.hits;
        each(todo).filter_map(move |k| hits[k].map(|h| (k, h)))
    }
}

/// `f(n, ks)` for the lanes of `lanes` four at a time: `ks[..n]` the next `n ≤ 4` of them,
/// lowest first (the places past `n` repeat the lowest lane).
#[inline(always)]
fn for_fours(lanes: u64, mut f: impl FnMut(usize, &[usize; 4])) {
    let mut l = lanes;
    while l != 0 {
        let (mut ks, mut n) = ([lanes.trailing_zeros() as usize; 4], 0);
        while l != 0 && n < 4 {
            ks[n] = l.trailing_zeros() as usize;
            l &= l - 1;
            n += 1;
        }
        f(n, &ks);
    }
}

/// The lanes set in `mask`, lowest first.
pub(crate) fn each(mut mask: u64) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (mask != 0).then(|| {
            let k = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            k
        })
    })
}

/// Where a packet's rays start.
#[derive(Clone, Copy, Debug)]
pub enum Origins<'a> {
    /// Every ray at one point (a camera's rays).
    One(DVec3),
    /// Lane `k`'s ray at the `k`-th point (a library caller's rays of its own).
    Each(&'a [DVec3]),
}

impl Origins<'_> {
    /// Where lane `k`'s ray starts.
    #[inline(always)]
    pub(super) fn of(&self, k: usize) -> DVec3 {
        match self {
            Origins::One(o) => *o,
            Origins::Each(at) => at[k],
        }
    }
}

/// What last frame's nearest hits tell a tile's search this frame (the camera the same):
/// lane `k`'s stored hit lay at `t[k]` (−∞ where none is known). An instance that has not
/// moved since lies where it lay, so its nearest hit along the ray is where it was, at `t[k]`
/// or beyond (the stored hit was the nearest of all): it cannot beat a hit found nearer than
/// `t[k]`, and the lane need not trace it then; otherwise the lane's walk through it starts
/// just short of `t[k]`.
#[derive(Clone, Copy, Debug)]
pub struct StoredHits<'a> {
    /// Per lane, the t of its stored hit.
    pub t: &'a [f32; LANES],
    /// Per instance, whether it moved since the stored hits were traced.
    pub moved: &'a [bool],
}

/// The nearest hit of each ray `origins.of(k) + t·dirs[k]` for the lanes `k` of `lanes` (up
/// to [`LANES`]), written to `out[k]`: what [`super::visibility::nearest_work`] answers for
/// the ray. The rays start at one point (a tile's, from the eye) or each at its own (a
/// library caller's). `fi.starts`, when given, holds the tile's beam starts (every ray of
/// `dirs` inside the tile's beam); without them the instances are searched in their order.
/// Instance `first`, when given, is searched before the others (the answer is the same in
/// any order): the instance the rays hit last frame, whose hit then bounds the rest; `stored`,
/// when given, skips the lanes that cannot find a nearer hit on an instance that stayed put.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub fn nearest_packet(
    fi: &FrameInstances,
    origins: Origins,
    dirs: &[DVec3],
    lanes: u64,
    search: Search,
    opts: &TraceOptions,
    work: &mut Work,
    scratch: &mut TileScratch,
    out: &mut [Option<InstanceHit>],
    first: Option<usize>,
    stored: Option<StoredHits>,
) {
    let n = fi.prepared.len();
    let starts = fi.starts.unwrap_or(&[]);
    let start_of = |i: usize| starts.get(i).copied().unwrap_or(opts.t_min);
    for k in each(lanes) {
        out[k] = None;
    }
    // Instances nearest beam start first, so that later ones are mostly skipped.
    // (Taken out of the scratch while its other buffers trace, and put back for the next tile.)
    let mut order = std::mem::take(&mut scratch.order);
    order.clear();
    order.extend((0..n).map(|i| (start_of(i), i)).filter(|&(s, _)| s != f32::INFINITY));
    order.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    if let Some(at) = first.and_then(|f| order.iter().position(|&(_, i)| i == f)) {
        order[..=at].rotate_right(1);
    }
    let beam_culled = (n - order.len()) as u64;
    let rays = lanes.count_ones() as u64;
    if search != Search::Plain {
        work.culled += beam_culled * rays;
    }
    for &(start, i) in order.iter() {
        nearest_instance(fi, i, start, origins, dirs, lanes, search, opts, work, scratch, out, stored);
    }
    scratch.order = order;
    if search == Search::Plain {
        // The plain search counts every instance as traced.
        work.traced += beam_culled * rays;
    }
}

/// [`nearest_listed_packet`] traces a tile's rays as packets only where its lanes list this
/// many instances' spheres apiece or more (a listing lane per instance, on average): below,
/// one ray at a time measured faster.
pub const LISTED_LANES: usize = 4;

/// The nearest hit of each ray `t·dirs[k]` from the origin (the camera) for the lanes `k` of
/// `lanes` (up to [`LANES`]), written to `out[k]`, among the instances of its own list
/// `list(k)` ((sphere entry t, instance), as [`super::pixel_spheres`] lists them): what
/// [`super::visibility::nearest_listed`] answers for the ray. The instances the lanes list
/// are traced nearest entry first, each by the lanes that list it as one packet (where they
/// are few to an instance, each ray alone: [`LISTED_LANES`]).
#[allow(clippy::too_many_arguments)]
pub fn nearest_listed_packet<'l>(
    fi: &FrameInstances,
    dirs: &[DVec3],
    lanes: u64,
    list: impl Fn(usize) -> &'l [(f64, u32)],
    opts: &TraceOptions,
    work: &mut Work,
    scratch: &mut TileScratch,
    out: &mut [Option<InstanceHit>],
) {
    let mut listed = std::mem::take(&mut scratch.listed);
    listed.clear();
    // Instances the lanes do not list (counted as culled when the lanes go as packets).
    let mut unlisted = 0u64;
    for k in each(lanes) {
        out[k] = None;
        let l = list(k);
        unlisted += fi.prepared.len().saturating_sub(l.len()) as u64;
        for &(entry, i) in l {
            // (A tile's lanes list few instances: a crowd's, mostly one each.)
            match listed.iter_mut().find(|e| e.1 == i) {
                Some(e) => {
                    e.0 = e.0.min(entry);
                    e.2 |= 1 << k;
                }
                None => listed.push((entry, i, 1 << k)),
            }
        }
    }
    if (lanes.count_ones() as usize) < LISTED_LANES * listed.len() {
        // Instances a few pixels wide (a far crowd's): one ray at a time is cheaper.
        for k in each(lanes) {
            out[k] = super::visibility::nearest_listed(fi, DVec3::ZERO, dirs[k], list(k), opts, work);
        }
        scratch.listed = listed;
        return;
    }
    work.culled += unlisted;
    listed.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    for &(_, i, by) in &listed {
        let one = Origins::One(DVec3::ZERO);
        let s = Search::CullSort;
        nearest_instance(fi, i as usize, opts.t_min, one, dirs, by, s, opts, work, scratch, out, None);
    }
    scratch.listed = listed;
}

/// One instance's step of a packet's nearest-hit search ([`nearest_packet`],
/// [`super::packet_bvh::nearest_packet_bvh`]): the lanes of `lanes` whose ray meets instance
/// `i`'s sphere (every lane, in the plain search) no later than its best hit so far `out[k]`
/// are traced through its octree from `start` (its beam start, or `opts.t_min`) up to that
/// hit, and a hit found replaces the best where it is nearer, or as near on a lower instance.
/// With `stored`, a lane whose best so far is nearer than its stored hit skips the instance
/// when it has not moved, and traces it from just short of the stored hit otherwise
/// ([`StoredHits`]).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn nearest_instance(
    fi: &FrameInstances,
    i: usize,
    start: f32,
    origins: Origins,
    dirs: &[DVec3],
    lanes: u64,
    search: Search,
    opts: &TraceOptions,
    work: &mut Work,
    scratch: &mut TileScratch,
    out: &mut [Option<InstanceHit>],
    stored: Option<StoredHits>,
) {
    let p = &fi.prepared[i];
    let t_min = if start > opts.t_min { start } else { opts.t_min };
    // The stored hits' t where this instance stayed put (else none).
    let stayed = stored.filter(|s| search != Search::Plain && s.moved.get(i).is_some_and(|m| !m)).map(|s| s.t);
    let mut todo = 0u64;
    for k in each(lanes) {
        let d = dirs[k];
        let bound = out[k].map_or(opts.t_max, |b| b.hit.t);
        if stayed.is_some_and(|t| t[k] > bound) {
            continue;
        }
        if search != Search::Plain {
            let Some((entry, _)) = sphere_interval(p.centre, p.radius, origins.of(k), d) else {
                work.culled += 1;
                continue;
            };
            if entry > bound as f64 {
                continue;
            }
        }
        if start > bound {
            continue;
        }
        work.traced += 1;
        scratch.opts[k] = TraceOptions { t_min, t_max: widen(bound), ..*opts };
        todo |= 1 << k;
    }
    match origins {
        Origins::One(o) => scratch.map_lanes(p, p.to_unit.point(o), dirs, todo),
        Origins::Each(at) => scratch.map_lanes_from(p, at, dirs, todo),
    }
    if let Some(t) = stayed {
        // Nor can it be hit before the stored hit: its walk starts just short of it.
        for k in each(todo) {
            if let Some(r) = scratch.rays[k].as_ref() {
                let late = late_start(t[k], r.t_scale);
                if late > scratch.opts[k].t_min {
                    scratch.opts[k].t_min = late;
                }
            }
        }
    }
    for (k, h) in scratch.trace(&fi.parts[p.part], todo) {
        keep(&mut out[k], i, h);
    }
}

/// How far short of a stored hit an instance that stayed put starts its walk
/// ([`late_start`]), in the internal t of its ray (about unit-cube lengths, the cube entered
/// within a few units of t = 0). The walk's plane crossings round by at most a unit and a half
/// in the last place at the root and half a unit per halving below, about 5·10⁻⁶ at depth 16;
/// 2⁻¹⁴ is twelve times that, and under a twentieth of a voxel at depth 9. (The random
/// scenes' walks at depth 6 needed 10⁻⁶: `late_starts_find_the_stored_hits_bit_for_bit`.)
const LATE_MARGIN: f64 = 1.0 / 16384.0;

/// The t (world units) at which a ray whose stored hit lay at `t` may start its walk through
/// an instance that has not moved since, its internal t scaled by `t_scale`
/// ([`UnitRay::t_scale`]); −∞ where no hit is known. The instance's own nearest hit `t_i`
/// (the same f32 value as when stored) is no nearer than the stored hit, the nearest of all,
/// so its f64 entry lies within half a unit in the last place of `t` below it. The start lies
/// a whole unit in the last place and [`LATE_MARGIN`] internal units below that, rounded
/// down: the walk's f32 entry of the hit voxel, within its rounding of the exact entry, lies
/// beyond it. Then the walk visits the voxels it visited from an earlier start, less those
/// it leaves before the start (none of which it reported), and reports the hit unclamped,
/// the same bits: raising `t_min` changes a walk only by what it skips and clamps.
#[inline]
fn late_start(t: f32, t_scale: f64) -> f32 {
    if !(t.is_finite() && t > 0.0) {
        return f32::NEG_INFINITY;
    }
    // (The unit above `t`: below a power of two the one below is half as large.)
    let ulp = f32::from_bits(t.to_bits() + 1) - t;
    let s = (t as f64 - ulp as f64 - LATE_MARGIN * t_scale) as f32;
    // One unit lower again, for the rounding of the cast (towards +∞ at worst).
    if s > 0.0 {
        f32::from_bits(s.to_bits() - 1)
    } else {
        f32::NEG_INFINITY
    }
}

/// Whether each ray `origins[k] + t·dir`, `0 ≤ t ≤ t_max`, for the lanes `k` of `lanes` (up to
/// [`LANES`]), hits an instance: bit `k` of the result set when it does. What
/// [`super::visibility::occluded`] answers for each ray (down to `max_level`), the octrees
/// traversed by the rays together (shadow rays towards one sun, from a tile's surface points).
#[allow(clippy::too_many_arguments)]
pub fn occluded_tile(
    fi: &FrameInstances,
    origins: &[DVec3],
    dir: DVec3,
    lanes: u64,
    t_max: f64,
    search: Search,
    max_level: u32,
    scratch: &mut TileScratch,
) -> u64 {
    let only = MovedOnly { lanes: 0, moved: &[] };
    let mut blockers = [0; LANES];
    occluded_tile_by(fi, origins, dir, lanes, only, &[], t_max, search, max_level, scratch, &mut blockers)
}

/// Lanes of a shadow packet that are asked about the moved instances alone: their rays, the
/// same as last frame's, were blocked by no instance then, so no instance that stayed put
/// blocks them now.
#[derive(Clone, Copy, Debug)]
pub struct MovedOnly<'a> {
    /// The lanes asked about the moved instances alone.
    pub lanes: u64,
    /// Per instance, whether it moved (an instance past its end counts as moved).
    pub moved: &'a [bool],
}

/// [`occluded_tile`], with the lanes of `only` tested against the moved instances alone, and
/// `blockers[k]` set to the instance that blocked lane `k` (where bit `k` of the result is
/// set; the first in the order of `fi.prepared`). `boxes`, unless empty, holds per instance a
/// box around its occupied cells ([`super::instances::occupied_world_boxes`]): every search
/// but the plain one skips the instances whose box a ray misses.
#[allow(clippy::too_many_arguments)]
pub fn occluded_tile_by(
    fi: &FrameInstances,
    origins: &[DVec3],
    dir: DVec3,
    lanes: u64,
    only: MovedOnly,
    boxes: &[(DVec3, DVec3)],
    t_max: f64,
    search: Search,
    max_level: u32,
    scratch: &mut TileScratch,
    blockers: &mut [u32; LANES],
) -> u64 {
    let opts = TraceOptions { t_max: t_max as f32, max_level, ..TraceOptions::default() };
    // The rays are parallel: they lie in a cylinder around the line through the centre of
    // their origins' bounding box, as wide as the box's half-diagonal. An instance whose
    // sphere that cylinder misses is missed by every ray (and its octree lies inside it).
    let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    for k in each(lanes) {
        lo = lo.min(origins[k]);
        hi = hi.max(origins[k]);
    }
    let (centre, width) = ((lo + hi) * 0.5, (hi - lo).length() * 0.5);
    let dirs = [dir; LANES];
    let inv = dir.recip();
    // The origins by axis, for the test of every lane against an instance at once.
    let mut from = [[0.0; LANES]; 3];
    for k in each(lanes) {
        (from[0][k], from[1][k], from[2][k]) = (origins[k].x, origins[k].y, origins[k].z);
    }
    let mut open = lanes;
    for (i, p) in fi.prepared.iter().enumerate() {
        let asked = if only.moved.get(i).is_some_and(|m| !m) { open & !only.lanes } else { open };
        if asked == 0 || sphere_interval(p.centre, p.radius + width, centre, dir).is_none() {
            continue;
        }
        // The slab test rounds by a few units in 2⁻⁵² of the distances it spans; the box is
        // grown by far more (as `Reuse::shadow_valid_among` grows the moved boxes).
        let cells = boxes.get(i).filter(|_| search != Search::Plain).map(|&(lo, hi)| {
            let slack = DVec3::splat(1e-9 * (centre.length() + width + lo.length() + hi.length()));
            (lo - slack, hi + slack)
        });
        // Every search but the plain one skips instances whose box or sphere the ray misses
        // (or enters beyond t_max): that changes no answer, the octree lies inside both.
        let todo = match search {
            Search::Plain => asked,
            _ => asked & entering(&from, &Entry { dir, inv, cells, ball: (p.centre, p.radius), t_max }),
        };
        for k in each(todo) {
            scratch.opts[k] = opts;
        }
        scratch.map_lanes_from(p, origins, &dirs, todo);
        for (k, _) in scratch.trace(&fi.parts[p.part], todo) {
            open &= !(1 << k);
            blockers[k] = i as u32;
        }
        if open == 0 {
            break;
        }
    }
    lanes & !open
}

/// What [`entering`] tests a tile's parallel rays against: the rays run along `dir` (its
/// reciprocal `inv`) up to `t_max`; the instance's cells lie in the box `cells` (when given)
/// and in the sphere `ball` (centre, radius).
#[derive(Clone, Copy)]
pub(crate) struct Entry {
    pub dir: DVec3,
    pub inv: DVec3,
    pub cells: Option<(DVec3, DVec3)>,
    pub ball: (DVec3, f64),
    pub t_max: f64,
}

/// The lanes whose ray from (`from[0][k]`, `from[1][k]`, `from[2][k]`) enters what `e` holds
/// within its `t_max`: [`super::bvh::box_entry`]'s and [`sphere_interval`]'s operations in
/// their order, so their answers, for all 64 lanes at once in vectors (four lanes in AVX2
/// where the CPU has it). Lane by lane, these tests took about 3 % of a mostly kept frame's
/// time, a tenth of its shadow rays' (docs/benchmarks.md, step 146).
pub(crate) fn entering(from: &[[f64; LANES]; 3], e: &Entry) -> u64 {
    #[cfg(target_arch = "x86_64")]
    if super::ray_setup::avx2() {
        // SAFETY: the CPU has AVX and AVX2 (checked above).
        return unsafe { entering_avx2(from, e) };
    }
    entering_lanes(from, e)
}

/// [`entering`] compiled for AVX2.
///
/// # Safety
/// The CPU has AVX and AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx,avx2")]
unsafe fn entering_avx2(from: &[[f64; LANES]; 3], e: &Entry) -> u64 {
    entering_lanes(from, e)
}

/// [`entering`], branch-free over the lanes so that it compiles to vectors.
#[inline(always)]
fn entering_lanes(from: &[[f64; LANES]; 3], e: &Entry) -> u64 {
    let Entry { dir, inv, cells, ball: (centre, radius), t_max } = *e;
    let mut met = [true; LANES];
    if let Some((lo, hi)) = cells {
        let (mut t0, mut t1) = ([0.0f64; LANES], [t_max; LANES]);
        for i in 0..3 {
            let (o, lo, hi, inv) = (&from[i], lo[i], hi[i], inv[i]);
            if inv.is_infinite() {
                // Parallel to the slab: inside it or not, by position.
                for k in 0..LANES {
                    met[k] &= !(o[k] < lo || o[k] > hi);
                }
            } else {
                for k in 0..LANES {
                    let (a, b) = ((lo - o[k]) * inv, (hi - o[k]) * inv);
                    t0[k] = t0[k].max(a.min(b));
                    t1[k] = t1[k].min(a.max(b));
                }
            }
        }
        for k in 0..LANES {
            met[k] &= t0[k] <= t1[k];
        }
    }
    let rr = radius * radius;
    let mut out = 0u64;
    for k in 0..LANES {
        let oc = [centre.x - from[0][k], centre.y - from[1][k], centre.z - from[2][k]];
        let b = oc[0] * dir.x + oc[1] * dir.y + oc[2] * dir.z;
        let c = (oc[0] * oc[0] + oc[1] * oc[1] + oc[2] * oc[2]) - rr;
        let disc = b * b - c;
        let s = disc.sqrt();
        let (e0, e1) = (b - s, b + s);
        out |= ((met[k] && disc >= 0.0 && e1 >= 0.0 && e0 <= t_max) as u64) << k;
    }
    out
}

/// Whether each ray `origins[k] + t·dirs[k]`, `0 ≤ t ≤ t_max[k]`, for the lanes `k` of
/// `lanes` (up to [`LANES`]), hits an instance: bit `k` of the result set when it does. What
/// [`super::visibility::occluded`] answers for each ray, the octrees traversed by the rays
/// together (a library caller's batch: [`crate::cast::SceneCaster::occluded_all`]).
#[allow(clippy::too_many_arguments)]
pub fn occluded_rays(
    fi: &FrameInstances,
    origins: &[DVec3],
    dirs: &[DVec3],
    t_max: &[f64],
    lanes: u64,
    search: Search,
    max_level: u32,
    scratch: &mut TileScratch,
) -> u64 {
    let mut open = lanes;
    for p in fi.prepared {
        open &= !occluded_instance(fi, p, origins, dirs, t_max, open, search, max_level, scratch);
        if open == 0 {
            break;
        }
    }
    lanes & !open
}

/// One instance's step of [`occluded_rays`] (and [`super::packet_bvh::occluded_rays_bvh`]):
/// the lanes of `open` whose ray `origins[k] + t·dirs[k]` meets instance `p` within
/// `t_max[k]`, as a bit mask.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn occluded_instance(
    fi: &FrameInstances,
    p: &Prepared,
    origins: &[DVec3],
    dirs: &[DVec3],
    t_max: &[f64],
    open: u64,
    search: Search,
    max_level: u32,
    scratch: &mut TileScratch,
) -> u64 {
    let mut todo = 0u64;
    for k in each(open) {
        let (o, d) = (origins[k], dirs[k]);
        // As `occluded_tile_by`: the octree lies inside the sphere.
        if search != Search::Plain && !sphere_interval(p.centre, p.radius, o, d).is_some_and(|(t0, _)| t0 <= t_max[k]) {
            continue;
        }
        scratch.opts[k] = TraceOptions { t_max: t_max[k] as f32, max_level, ..TraceOptions::default() };
        todo |= 1 << k;
    }
    scratch.map_lanes_from(p, origins, dirs, todo);
    scratch.trace(&fi.parts[p.part], todo).fold(0, |blocked, (k, _)| blocked | 1 << k)
}

/// [`super::visibility::nearest_moved`] for each ray `o + t·dirs[k]` of the lanes `k` of
/// `lanes`, against its bound `bounds[k]` (the nearest hit `(t, instance)` among the
/// instances that did not move), the moved instances' octrees traversed by the rays
/// together: `out[k]` is the moved instances' hit that beats the bound, if any. The
/// instances are visited in the order of `moved`, as one ray at a time does, so every ray
/// traces them with the same bounds and finds the same hit.
#[allow(clippy::too_many_arguments)]
pub fn nearest_moved_tile(
    fi: &FrameInstances,
    o: DVec3,
    dirs: &[DVec3],
    lanes: u64,
    moved: &[u32],
    bounds: &[(f32, i32)],
    opts: &TraceOptions,
    work: &mut Work,
    scratch: &mut TileScratch,
    out: &mut [Option<InstanceHit>],
) {
    let mut best = [(0f32, 0usize); LANES];
    for k in each(lanes) {
        let (t, instance) = bounds[k];
        best[k] = (t, if instance < 0 { usize::MAX } else { instance as usize });
        out[k] = None;
    }
    for &i in moved {
        let i = i as usize;
        let p = &fi.prepared[i];
        if fi.starts.is_some_and(|s| s[i] == f32::INFINITY) {
            work.culled += lanes.count_ones() as u64;
            continue;
        }
        let unit_o = p.to_unit.point(o);
        let mut todo = 0u64;
        for k in each(lanes) {
            let Some((t0, _)) = sphere_interval(p.centre, p.radius, o, dirs[k]) else {
                work.culled += 1;
                continue;
            };
            let t_max = best[k].0.min(opts.t_max);
            if t0 > t_max as f64 {
                continue;
            }
            work.traced += 1;
            let start = fi.starts.map_or(opts.t_min, |s| s[i]);
            let t_min = if start > opts.t_min { start } else { opts.t_min };
            scratch.opts[k] = TraceOptions { t_min, t_max: widen(t_max), ..*opts };
            todo |= 1 << k;
        }
        scratch.map_lanes(p, unit_o, dirs, todo);
        for (k, h) in scratch.trace(&fi.parts[p.part], todo) {
            let (best_t, best_i) = best[k];
            if h.t < best_t || (h.t == best_t && i < best_i) {
                best[k] = (h.t, i);
                out[k] = Some(InstanceHit { instance: i, hit: h });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::instances::prepare;
    use crate::render::visibility::nearest_work;
    use crate::rng::Rng;
    use crate::scene::{Instance, Scene, Transform};
    use crate::svo::Cube;
    use glam::{DQuat, Vec3};
    use std::sync::Arc;

    /// A scene of `n` turned and scaled copies of a random part (seeded), seen from the origin.
    fn scene(seed: u64, n: usize) -> Scene {
        let mut rng = Rng::new(seed);
        let coords: Vec<[u32; 3]> = (0..3000).map(|_| [0; 3].map(|_| 16 + rng.below(32) as u32)).collect();
        let grid = crate::voxelize::VoxelGrid::from_coords(6, Cube { min: Vec3::ZERO, size: 1.0 }, coords, Vec3::ONE);
        let mut scene = Scene::new(vec![Arc::new(crate::svo::build(&grid).expect("a valid grid"))]);
        for k in 0..n {
            let at = DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, -3.0 - k as f64 * 0.4);
            let turn = DQuat::from_rotation_y(rng.f64() * 6.0) * DQuat::from_rotation_x(rng.f64());
            let local = Transform::new(at, turn, DVec3::splat(0.5 + rng.f64())).expect("a valid transform");
            scene.add(Instance { part: 0, parent: None, local }).expect("room for it");
        }
        scene.update().expect("well-conditioned");
        scene
    }

    /// A tile's 64 rays from the origin, fanned towards −z (seeded).
    fn tile(seed: u64) -> Vec<DVec3> {
        let mut rng = Rng::new(seed);
        let (cx, cy) = ((rng.f64() - 0.5) * 0.3, (rng.f64() - 0.5) * 0.3);
        (0..LANES).map(|k| DVec3::new(cx + (k % 8) as f64 * 0.01, cy + (k / 8) as f64 * 0.01, -1.0)).collect()
    }

    /// A search told last frame's nearest hits ([`StoredHits`]) finds this frame's nearest hits,
    /// lane for lane, though it skips the instances that stayed put wherever a hit nearer
    /// than the stored one turns up first: some instances moved since (each towards the eye,
    /// so that they are often hit nearer than before), the others stayed.
    #[test]
    fn stored_hits_skip_only_what_cannot_be_nearer() {
        let opts = TraceOptions::default();
        let (mut checked, mut skipped) = (0, 0);
        for seed in 0..12u64 {
            let mut scene = scene(seed + 40, 6);
            let dirs = tile(seed + 7);
            let before = prepare(&scene, DVec3::ZERO, true);
            let fi = FrameInstances { parts: &scene.parts, prepared: &before, bvh: None, starts: None };
            let mut t = [f32::NEG_INFINITY; LANES];
            for (k, t) in t.iter_mut().enumerate() {
                let hit = nearest_work(&fi, DVec3::ZERO, dirs[k], Search::Plain, &opts, &mut Work::default());
                *t = hit.map_or(f32::NEG_INFINITY, |h| h.hit.t);
            }
            // Every other instance moves a little towards the eye and turns.
            let mut moved = vec![false; 6];
            for i in (seed as usize % 2..6).step_by(2) {
                let mut local = scene.instances()[i].local;
                local.translation *= 0.8;
                local.rotation *= DQuat::from_rotation_z(0.3);
                scene.set_local(i, local).expect("a valid transform");
                moved[i] = true;
            }
            scene.update().expect("well-conditioned");
            let now = prepare(&scene, DVec3::ZERO, true);
            let fi = FrameInstances { parts: &scene.parts, prepared: &now, bvh: None, starts: None };
            let (mut out, mut plain_out) = ([None; LANES], [None; LANES]);
            let (mut work, mut plain_work) = (Work::default(), Work::default());
            let stored = Some(StoredHits { t: &t, moved: &moved });
            let one = Origins::One(DVec3::ZERO);
            TileScratch::with(|s| {
                nearest_packet(
                    &fi,
                    one,
                    &dirs,
                    u64::MAX,
                    Search::CullSort,
                    &opts,
                    &mut work,
                    s,
                    &mut out,
                    None,
                    stored,
                );
                let w = &mut plain_work;
                nearest_packet(&fi, one, &dirs, u64::MAX, Search::CullSort, &opts, w, s, &mut plain_out, None, None);
            });
            for (k, &d) in dirs.iter().enumerate() {
                let want = nearest_work(&fi, DVec3::ZERO, d, Search::Plain, &opts, &mut Work::default());
                assert_eq!(out[k], want, "seed {seed}, lane {k}");
                assert_eq!(plain_out[k], want, "seed {seed}, lane {k}, without stored hits");
                checked += want.is_some() as usize;
            }
            skipped += plain_work.traced - work.traced;
        }
        assert!(checked > 100, "{checked} hits");
        assert!(skipped > 50, "{skipped} instance traces skipped");
    }

    /// Walks through instances that stayed put, started just short of the stored hits
    /// ([`late_start`]), find those hits bit for bit: every instance is told it stayed and
    /// every lane its own nearest hit, so each lane walks each instance it is not skipped
    /// for from just short of that hit. Seen from the scene's side and from far away, where
    /// a unit in the last place of t is large against the instances.
    #[test]
    fn late_starts_find_the_stored_hits_bit_for_bit() {
        let opts = TraceOptions::default();
        let (mut checked, mut late) = (0, 0);
        for seed in 0..16u64 {
            let scene = scene(seed + 70, 5);
            for far in [0.0, 200.0 * (1 + seed) as f64] {
                let eye = DVec3::new(0.0, 0.0, far);
                // The tile's fan narrowed to meet the scene from `eye`.
                let narrow = 4.0 / (4.0 + far);
                let dirs: Vec<DVec3> =
                    tile(seed + 3).iter().map(|d| DVec3::new(d.x * narrow, d.y * narrow, -1.0)).collect();
                let prepared = prepare(&scene, eye, true);
                let fi = FrameInstances { parts: &scene.parts, prepared: &prepared, bvh: None, starts: None };
                let one = Origins::One(DVec3::ZERO);
                let mut t = [f32::NEG_INFINITY; LANES];
                let mut want = [None; LANES];
                for k in 0..LANES {
                    want[k] = nearest_work(&fi, DVec3::ZERO, dirs[k], Search::Plain, &opts, &mut Work::default());
                    t[k] = want[k].map_or(f32::NEG_INFINITY, |h| h.hit.t);
                }
                let stayed = vec![false; 5];
                let mut out = [None; LANES];
                TileScratch::with(|s| {
                    let stored = Some(StoredHits { t: &t, moved: &stayed });
                    let w = &mut Work::default();
                    nearest_packet(&fi, one, &dirs, u64::MAX, Search::CullSort, &opts, w, s, &mut out, None, stored);
                    for i in 0..5 {
                        // The lanes that would walk instance i from later than without.
                        let p = &prepared[i];
                        s.map_lanes(p, p.to_unit.point(DVec3::ZERO), &dirs, u64::MAX);
                        late += (0..LANES)
                            .filter(|&k| s.rays[k].is_some_and(|r| late_start(t[k], r.t_scale) > opts.t_min))
                            .count();
                    }
                });
                for k in 0..LANES {
                    assert_eq!(out[k], want[k], "seed {seed}, eye {eye}, lane {k}");
                    checked += want[k].is_some() as usize;
                }
            }
        }
        assert!(checked > 500, "{checked} hits");
        assert!(late > 1000, "{late} late starts");
    }

    /// `late_start`'s start, taken into a ray's internal t, lies at least [`LATE_MARGIN`]
    /// below the exact t of every f64 entry that rounds to the stored hit or beyond, for
    /// stored hits across the binades and internal scales from far below one to far above.
    #[test]
    fn late_starts_keep_their_margin_below_every_entry_that_rounds_to_the_hit() {
        let mut rng = Rng::new(5);
        for _ in 0..20_000 {
            let t = (rng.f64() * 40.0 - 20.0).exp2() as f32;
            let t_scale = (rng.below(40) as f64 - 20.0).exp2();
            let start = late_start(t, t_scale) as f64;
            // The least f64 that rounds to `t` as f32: half way to the f32 below.
            let below = f32::from_bits(t.to_bits() - 1) as f64;
            let least = (below + t as f64) * 0.5;
            assert!(start.is_finite() || t as f64 <= 2.0 * LATE_MARGIN * t_scale, "t {t}");
            assert!((least - start) / t_scale >= LATE_MARGIN, "t {t}, scale {t_scale}, start {start}");
        }
        assert_eq!(late_start(f32::NEG_INFINITY, 1.0), f32::NEG_INFINITY);
        assert_eq!(late_start(0.0, 1.0), f32::NEG_INFINITY);
        assert_eq!(late_start(f32::MAX, 1.0), f32::NEG_INFINITY);
        assert_eq!(late_start(f32::NAN, 1.0), f32::NEG_INFINITY);
    }

    /// Shadow packets told the boxes around the instances' cells
    /// ([`super::super::instances::occupied_world_boxes`]) answer as the plain one-ray test,
    /// lane for lane, for rays from points in and around the instances in every direction;
    /// the boxes turn many rays away.
    #[test]
    fn shadow_packets_skip_only_instances_whose_cells_a_ray_misses() {
        let (mut blocked, mut checked, mut turned_away) = (0, 0, 0);
        for seed in 0..16u64 {
            let scene = scene(seed + 90, 5);
            let prepared = prepare(&scene, DVec3::ZERO, true);
            let fi = FrameInstances { parts: &scene.parts, prepared: &prepared, bvh: None, starts: None };
            let boxes = crate::render::instances::occupied_world_boxes(&scene, DVec3::ZERO, u32::MAX);
            let mut rng = Rng::new(seed);
            for _ in 0..8 {
                // Origins around one instance's cells; one direction for the packet.
                let (lo, hi) = boxes[rng.below(5) as usize];
                let origins: Vec<DVec3> = (0..LANES)
                    .map(|_| lo + (hi - lo) * DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 1.4 - (hi - lo) * 0.2)
                    .collect();
                let dir = DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5).normalize();
                let only = MovedOnly { lanes: 0, moved: &[] };
                let mut b = [0; LANES];
                let got = TileScratch::with(|s| {
                    occluded_tile_by(&fi, &origins, dir, u64::MAX, only, &boxes, 2.0, Search::Cull, u32::MAX, s, &mut b)
                });
                for (k, &o) in origins.iter().enumerate() {
                    let want = crate::render::visibility::occluded(&fi, o, dir, 2.0, Search::Plain, u32::MAX);
                    assert_eq!(got & (1 << k) != 0, want, "seed {seed}, lane {k}");
                    blocked += want as usize;
                    checked += 1;
                    let inv = dir.recip();
                    turned_away += boxes
                        .iter()
                        .zip(&prepared)
                        .filter(|((lo, hi), p)| {
                            sphere_interval(p.centre, p.radius, o, dir).is_some_and(|(t0, _)| t0 <= 2.0)
                                && crate::render::bvh::box_entry(*lo, *hi, o, inv, 2.0).is_none()
                        })
                        .count();
                }
            }
        }
        assert!(blocked > checked / 10 && blocked < checked * 9 / 10, "{blocked} of {checked} rays blocked");
        assert!(turned_away > 200, "{turned_away} instances turned away by their boxes, {checked} rays");
    }

    /// The test of all 64 lanes against an instance at once answers lane by lane as
    /// `box_entry` and `sphere_interval` do: directions with components of zero (slabs
    /// tested by position), origins on the boxes' faces, spheres grazed to within a few
    /// roundings, ahead of the origins, behind them and past `t_max`.
    #[test]
    fn every_lanes_entry_test_answers_as_its_own() {
        let mut rng = Rng::new(41);
        let (mut entered, mut by_box, mut by_ball) = (0, 0, 0);
        for round in 0..3000 {
            let mut dir = DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5);
            // Some directions along a face or an axis.
            for i in 0..3 {
                if rng.below(6) == 0 {
                    dir[i] = 0.0;
                }
            }
            let dir = dir.try_normalize().unwrap_or(DVec3::X);
            let inv = dir.recip();
            let lo = DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 4.0 - 2.0;
            let hi = lo + DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 3.0;
            let cells = (round % 5 != 0).then_some((lo, hi));
            let radius = 0.05 + rng.f64() * 2.0;
            let t_max = if round % 3 == 0 { f64::INFINITY } else { rng.f64() * 6.0 };
            let mut from = [[0.0; LANES]; 3];
            let origins: Vec<DVec3> = (0..LANES)
                .map(|k| {
                    let mut o = lo + (hi - lo) * DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 2.0 - (hi - lo) * 0.5;
                    // Some origins on a face of the box.
                    if rng.below(4) == 0 {
                        let i = rng.below(3) as usize;
                        o[i] = if rng.below(2) == 0 { lo[i] } else { hi[i] };
                    }
                    (from[0][k], from[1][k], from[2][k]) = (o.x, o.y, o.z);
                    o
                })
                .collect();
            // A sphere that one lane's ray grazes, from inside or out, ahead of it or behind.
            let o = origins[rng.below(LANES as u64) as usize];
            let side = DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5).reject_from(dir);
            let graze = radius * (1.0 + (rng.f64() - 0.5) * 10f64.powi(-(rng.below(16) as i32)));
            let centre = o + dir * (rng.f64() * 8.0 - 2.0) + side.normalize_or_zero() * graze;
            let got = entering(&from, &Entry { dir, inv, cells, ball: (centre, radius), t_max });
            for (k, &o) in origins.iter().enumerate() {
                let in_box =
                    cells.is_none_or(|(lo, hi)| crate::render::bvh::box_entry(lo, hi, o, inv, t_max).is_some());
                let in_ball = sphere_interval(centre, radius, o, dir).is_some_and(|(t0, _)| t0 <= t_max);
                assert_eq!(got & 1 << k != 0, in_box && in_ball, "round {round}, lane {k}");
                entered += (in_box && in_ball) as usize;
                by_box += (!in_box && in_ball) as usize;
                by_ball += (in_box && !in_ball) as usize;
            }
        }
        assert!(entered > 5_000 && by_box > 5_000 && by_ball > 5_000, "{entered} {by_box} {by_ball}");
    }

    /// The thread's kept scratch finds what the one-ray search finds, lane for lane, after it
    /// traced other tiles of other scenes with other lanes (what a use leaves in it is never
    /// read), for nearest hits and for shadow rays alike.
    #[test]
    fn a_kept_scratch_traces_as_a_fresh_one() {
        let scenes = [scene(1, 6), scene(2, 3)];
        let prepared: Vec<Vec<Prepared>> = scenes.iter().map(|s| prepare(s, DVec3::ZERO, true)).collect();
        let opts = TraceOptions::default();
        let (mut hits, mut checked) = (0, 0);
        for round in 0..24u64 {
            let k = (round % 2) as usize;
            let fi = FrameInstances { parts: &scenes[k].parts, prepared: &prepared[k], bvh: None, starts: None };
            let dirs = tile(round);
            // Every lane in some rounds, scattered lanes in others.
            let lanes = if round % 3 == 0 { u64::MAX } else { Rng::new(round + 100).next_u64() };
            let mut out = [None; LANES];
            TileScratch::with(|s| {
                nearest_packet(
                    &fi,
                    Origins::One(DVec3::ZERO),
                    &dirs,
                    lanes,
                    Search::CullSort,
                    &opts,
                    &mut Work::default(),
                    s,
                    &mut out,
                    None,
                    None,
                )
            });
            // Any instance searched first, the same answers.
            let mut first_out = [None; LANES];
            let first = (round as usize * 5) % fi.prepared.len();
            TileScratch::with(|s| {
                let (w, o) = (&mut Work::default(), &mut first_out);
                let one = Origins::One(DVec3::ZERO);
                nearest_packet(&fi, one, &dirs, lanes, Search::CullSort, &opts, w, s, o, Some(first), None)
            });
            let origins: Vec<DVec3> = dirs.iter().map(|d| *d * 0.5).collect();
            let blocked = TileScratch::with(|s| {
                occluded_tile(&fi, &origins, DVec3::Z, lanes, f64::INFINITY, Search::Cull, u32::MAX, s)
            });
            for l in each(lanes) {
                let one = nearest_work(&fi, DVec3::ZERO, dirs[l], Search::Plain, &opts, &mut Work::default());
                assert_eq!(out[l], one, "round {round}, lane {l}");
                assert_eq!(first_out[l], one, "round {round}, lane {l}, instance {first} first");
                hits += one.is_some() as usize;
                let up = crate::render::visibility::occluded(
                    &fi,
                    origins[l],
                    DVec3::Z,
                    f64::INFINITY,
                    Search::Plain,
                    u32::MAX,
                );
                assert_eq!(blocked & (1 << l) != 0, up, "round {round}, lane {l}: shadow ray");
                checked += 1;
            }
        }
        assert!(hits > checked / 10 && hits < checked, "{hits} hits of {checked} rays");
    }
}
