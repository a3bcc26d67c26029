//! Up to 64 coherent rays (a screen tile's primary rays) traced through one SVO together,
//! with the answers of [`super::trace_unit`] bit for bit.
//!
//! The packet walks the tree depth first and tests eight rays at a time (AVX lanes; four,
//! SSE, on CPUs without AVX: `traverse::lanes`) against each occupied child; a node is
//! entered when any of its rays crosses it, and each ray's t-values come from Revelles'
//! halving exactly as in the scalar loop, so a node's t-values for a ray do not depend on
//! which other rays share its packet.
//!
//! Why the answers are the scalar ones. All rays of a packet share the mirror bits, so in
//! mirrored space every direction component is positive and a ray can only pass from child
//! `a` to child `b` of a node when `b`'s bits contain `a`'s: visiting children in numeric
//! order is front to back for every ray at once, and depth first over the tree the first
//! occupied leaf a ray crosses is its nearest. The packet counts a child as crossed when the
//! closed interval `[max(entry, t_min), exit]` is not empty; Revelles' chain of children
//! (first child, then exit planes, ties to the lowest axis) visits exactly those children
//! except some of zero length (where the ray only touches an edge or corner at one t). A
//! child's interval lies inside its parent's, so a leaf the scalar loop would not reach
//! has a zero-length interval itself: every other leaf the packet reports is on the chain,
//! and being the first in the same order, it is the scalar answer. A leaf of zero length
//! is handed to the scalar loop for that ray.

use super::lanes::Lanes;
#[cfg(target_arch = "x86_64")]
use super::lanes::{avx8_supported, Avx8};
use super::{finish, finish_into, max, min, trace_unit, Below, Cell, Hit, Planes, Reached, TraceOptions, Walk};
use crate::prefetch::prefetch;
use crate::ray::UnitRay;
use crate::svo::{Svo, MAX_DEPTH};
use glam::{Vec3A, Vec4};
use wide::f32x4;

/// Rays in a packet.
pub const LANES: usize = 64;
/// Crossed children with at most this many of the packet's rays are walked ray by ray
/// ([`walk_alone`]): 4 measured faster than 1, 2 and 8 at depths 9 and 11.
const SOLO: u32 = 4;

/// `MIRRORED[m][mask]`: the child mask `mask` renumbered for mirror bits `m` (bit c set when
/// octant `c ^ m` is set), so a node's children are visited front to back in numeric order.
const MIRRORED: [[u8; 256]; 8] = {
    let mut t = [[0u8; 256]; 8];
    let mut m = 0;
    while m < 8 {
        let mut mask = 0;
        while mask < 256 {
            let mut c = 0;
            while c < 8 {
                if mask & (1 << (c ^ m)) != 0 {
                    t[m][mask] |= 1 << c;
                }
                c += 1;
            }
            mask += 1;
        }
        m += 1;
    }
    t
};

/// Per axis, the values of the packet's rays, one vector per group of `V::W` rays (a quad
/// of four, or an octet of eight).
type Axes<V> = [<V as Lanes>::Groups; 3];

/// The t-values of one node for every ray of the packet (Revelles §3.1): entry planes,
/// midplanes, exit planes. Only the groups with rays in the node are written.
#[derive(Clone, Copy)]
struct Frame<V: Lanes> {
    t0: Axes<V>,
    tm: Axes<V>,
    t1: Axes<V>,
}

impl<V: Lanes> Frame<V> {
    const EMPTY: Self = Frame { t0: [V::ZERO_GROUPS; 3], tm: [V::ZERO_GROUPS; 3], t1: [V::ZERO_GROUPS; 3] };

    /// Entry and exit planes on axis `a` of the child in the `upper` half there, for group `q`.
    #[inline(always)]
    fn child(&self, a: usize, upper: bool, q: usize) -> (V, V) {
        if upper {
            (self.tm[a][q], self.t1[a][q])
        } else {
            (self.t0[a][q], self.tm[a][q])
        }
    }

    /// Entry and exit planes per axis of child `c` for the ray in lane `l` of group `q`.
    #[inline(always)]
    fn lane_child(&self, c: u32, q: usize, l: usize) -> ([f32; 3], [f32; 3]) {
        let mut t0 = [0f32; 3];
        let mut t1 = [0f32; 3];
        for a in 0..3 {
            let (a0, a1) = self.child(a, c & (1 << a) != 0, q);
            t0[a] = a0.lane(l);
            t1[a] = a1.lane(l);
        }
        (t0, t1)
    }
}

/// One [`Frame`] per level.
type Frames<V> = [Frame<V>; MAX_DEPTH as usize + 1];

/// Reusable memory for tracing packets (about 50 KB: one `Frame` per level); make one per
/// thread and pass it to every [`trace_packet`]. It also fixes the vector width: eight lanes
/// where the CPU has AVX, else four.
pub struct PacketStack {
    frames: StackFrames,
}

enum StackFrames {
    Four(Box<Frames<f32x4>>),
    #[cfg(target_arch = "x86_64")]
    Eight(Box<Frames<Avx8>>),
}

impl Default for PacketStack {
    fn default() -> Self {
        #[cfg(target_arch = "x86_64")]
        if avx8_supported() {
            return PacketStack { frames: StackFrames::Eight(Box::new([Frame::EMPTY; MAX_DEPTH as usize + 1])) };
        }
        PacketStack::four_lanes()
    }
}

impl PacketStack {
    /// A stack for packets tested four lanes at a time, whatever the CPU has (the answers are
    /// the same; tests use it to cover both widths).
    pub(crate) fn four_lanes() -> Self {
        PacketStack { frames: StackFrames::Four(Box::new([Frame::EMPTY; MAX_DEPTH as usize + 1])) }
    }
}

/// A packet's kernel, compiled for the instructions of its vector type: the tree walk and
/// the pass's set-up run inside it. Recursion goes through [`Kernel::visit`], so every level
/// runs compiled for the same instructions.
trait Kernel: Lanes {
    /// [`Pass::visit_body`].
    ///
    /// # Safety
    /// The CPU runs the vector type's instructions.
    unsafe fn visit(pass: &mut Pass<'_, Self>, level: usize, node: usize, coord: [u32; 3], lanes: u64);
    /// [`Pass::run_body`].
    ///
    /// # Safety
    /// As for [`Kernel::visit`].
    unsafe fn run(pass: &mut Pass<'_, Self>, lanes: u64);
    /// [`walk_alone`], compiled for the same instructions (its sibling ranks are population
    /// counts, one instruction where the CPU has it).
    ///
    /// # Safety
    /// As for [`Kernel::visit`].
    unsafe fn walk(svo: &Svo, mirror: u32, start: Below, t_min: f32, t_max: f32, max_level: u32) -> Walk;
}

impl Kernel for f32x4 {
    unsafe fn visit(pass: &mut Pass<'_, Self>, level: usize, node: usize, coord: [u32; 3], lanes: u64) {
        pass.visit_body(level, node, coord, lanes)
    }
    unsafe fn run(pass: &mut Pass<'_, Self>, lanes: u64) {
        pass.run_body(lanes)
    }
    unsafe fn walk(svo: &Svo, mirror: u32, start: Below, t_min: f32, t_max: f32, max_level: u32) -> Walk {
        walk_alone(svo, mirror, start, t_min, t_max, max_level)
    }
}

// AVX for the vectors; the bit-manipulation instructions of the same generation for the
// lane masks (no FMA: a fused multiply-add would round differently from the four-lane code).
#[cfg(target_arch = "x86_64")]
impl Kernel for Avx8 {
    #[target_feature(enable = "avx,avx2,bmi1,bmi2,lzcnt,popcnt")]
    unsafe fn visit(pass: &mut Pass<'_, Self>, level: usize, node: usize, coord: [u32; 3], lanes: u64) {
        pass.visit_body(level, node, coord, lanes)
    }
    #[target_feature(enable = "avx,avx2,bmi1,bmi2,lzcnt,popcnt")]
    unsafe fn run(pass: &mut Pass<'_, Self>, lanes: u64) {
        pass.run_body(lanes)
    }
    #[target_feature(enable = "avx,avx2,bmi1,bmi2,lzcnt,popcnt")]
    unsafe fn walk(svo: &Svo, mirror: u32, start: Below, t_min: f32, t_max: f32, max_level: u32) -> Walk {
        walk_alone_body(svo, mirror, start, t_min, t_max, max_level)
    }
}

/// The rays of one pass over the tree (one mirror value).
struct Pass<'a, V: Lanes> {
    svo: &'a Svo,
    rays: &'a [Option<UnitRay>],
    opts: &'a [TraceOptions],
    out: &'a mut [Option<Hit>],
    frames: &'a mut Frames<V>,
    origin: Axes<V>,
    inv: Axes<V>,
    t_min: V::Groups,
    t_max: V::Groups,
    mirror: u32,
    max_level: u32,
    /// Rays still without an answer.
    active: u64,
    /// Answers whose attributes are still to be read, from `attr_at`: read together after
    /// the walk, so their cache misses overlap instead of stalling it one by one.
    pending: u64,
    attr_at: [u32; LANES],
}

/// Groups of `W` lanes holding a ray of `lanes`: bit `W·q` set when group q has one.
#[inline(always)]
fn groups_of<V: Lanes>(lanes: u64) -> u64 {
    let mut x = lanes;
    let mut s = 1;
    while s < V::W {
        x |= x >> s;
        s *= 2;
    }
    // The lowest lane of every group.
    x & (u64::MAX / ((1u64 << V::W) - 1))
}

/// The next group of a [`groups_of`] mask, removed from it.
#[inline(always)]
fn next_group<V: Lanes>(groups: &mut u64) -> usize {
    let q = groups.trailing_zeros() as usize / V::W;
    *groups &= *groups - 1;
    q
}

impl<V: Kernel> Pass<'_, V> {
    /// Visits the children of `node` (level `level`, mirrored coordinates `coord`) for the rays
    /// `lanes`, whose t-values for the node are `frames[level]`.
    ///
    /// The last child that any of the rays cross is entered in place (the loop goes on with
    /// it as its node), not by a call: nothing is left to do here once it is done.
    #[inline(always)]
    fn visit_body(&mut self, mut level: usize, mut node: usize, mut coord: [u32; 3], mut lanes: u64) {
        'node: loop {
            // Occupied children in mirrored numbering (bit c: octant c ^ mirror holds geometry).
            let occupied = MIRRORED[self.mirror as usize][self.svo.masks[node] as usize] as u32;
            let crossed = self.crossed(level, lanes, occupied);
            // The children some ray crosses (fewer may be left when their turn comes).
            let mut met = 0u32;
            for (c, &x) in crossed.iter().enumerate() {
                met |= ((x != 0) as u32) << c;
            }
            let mut todo = occupied & met;
            while todo != 0 {
                let c = todo.trailing_zeros();
                todo &= todo - 1;
                let live = lanes & self.active;
                if live == 0 {
                    return;
                }
                let crossed = crossed[c as usize] & live;
                if crossed == 0 {
                    continue;
                }
                let octant = c ^ self.mirror;
                let (up_x, up_y, up_z) = (c & 1 != 0, c & 2 != 0, c & 4 != 0);
                let child_level = level as u32 + 1;
                let cc = [2 * coord[0] + up_x as u32, 2 * coord[1] + up_y as u32, 2 * coord[2] + up_z as u32];
                if child_level >= self.max_level {
                    self.hits(level, node, c, cc, crossed);
                    continue;
                }
                if crossed.count_ones() <= SOLO {
                    self.solo(level, node, c, cc, crossed);
                    continue;
                }
                let (lo, hi) = self.frames.split_at_mut(level + 1);
                let (f, g) = (&lo[level], &mut hi[0]);
                let mut quads = groups_of::<V>(crossed);
                while quads != 0 {
                    let q = next_group::<V>(&mut quads);
                    for (a, up) in [up_x, up_y, up_z].into_iter().enumerate() {
                        let (t0, t1) = f.child(a, up, q);
                        g.t0[a][q] = t0;
                        g.t1[a][q] = t1;
                        // Revelles §3.1: the midplanes halfway in t (as the scalar loop).
                        g.tm[a][q] = (t0 + t1) * V::splat(0.5);
                    }
                }
                let child = self.svo.child_node(node, octant);
                if todo == 0 {
                    (level, node, coord, lanes) = (level + 1, child, cc, crossed);
                    continue 'node;
                }
                // SAFETY: this runs inside `V::visit` or `V::run`, so the CPU has V's instructions.
                unsafe { V::visit(self, level + 1, child, cc, crossed) };
            }
            return;
        }
    }

    /// Per child c (mirrored numbering) of the node whose t-values are `frames[level]`, the rays
    /// of `lanes` that cross it: the closed interval `[max(entry, t_min), exit]` is not empty
    /// and `entry ≤ t_max`. Only the children of `occupied` are filled in.
    ///
    /// All children at once, sharing the work: a child's entry is the largest of its three
    /// axes' entry planes, so the x-and-y maxima are formed once for the four (x, y) halves
    /// and `t_min` is folded into the two z entries; exits likewise with `t_max`. The values
    /// compared are the same maxima and minima as child by child (max and min are exact), and
    /// `max(entry, t_min) ≤ min(exit, t_max)` is `max(entry, t_min) ≤ exit` and
    /// `entry ≤ t_max` because every live ray has `t_min ≤ t_max`.
    #[inline(always)]
    fn crossed(&self, level: usize, lanes: u64, occupied: u32) -> [u64; 8] {
        let f = &self.frames[level];
        let mut crossed = [0u64; 8];
        let mut quads = groups_of::<V>(lanes);
        while quads != 0 {
            let q = next_group::<V>(&mut quads);
            let (x0, xm, x1) = (f.t0[0][q], f.tm[0][q], f.t1[0][q]);
            let (y0, ym, y1) = (f.t0[1][q], f.tm[1][q], f.t1[1][q]);
            let (z0, zm, z1) = (f.t0[2][q], f.tm[2][q], f.t1[2][q]);
            let (t_min, t_max) = (self.t_min[q], self.t_max[q]);
            let entry_xy = [x0.fast_max(y0), xm.fast_max(y0), x0.fast_max(ym), xm.fast_max(ym)];
            let exit_xy = [xm.fast_min(ym), x1.fast_min(ym), xm.fast_min(y1), x1.fast_min(y1)];
            let entry_z = [z0.fast_max(t_min), zm.fast_max(t_min)];
            let exit_z = [zm.fast_min(t_max), z1.fast_min(t_max)];
            for (c, out) in crossed.iter_mut().enumerate() {
                if occupied & (1 << c) == 0 {
                    continue;
                }
                let te = entry_xy[c & 3].fast_max(entry_z[c >> 2]);
                let tx = exit_xy[c & 3].fast_min(exit_z[c >> 2]);
                *out |= te.le_bits(tx) << (V::W * q);
            }
        }
        crossed
    }

    /// Walks each ray of `lanes` alone below child `c` of `node` (mirrored coordinates `cc`),
    /// from its t-values there, as a packet of one ([`walk_alone`]): a leaf of non-zero
    /// length it reaches is the answer (see the module notes); a ray that leaves the child
    /// stays in the packet.
    #[inline(always)]
    fn solo(&mut self, level: usize, node: usize, c: u32, cc: [u32; 3], mut lanes: u64) {
        let child = self.svo.child_node(node, c ^ self.mirror);
        while lanes != 0 {
            let k = lanes.trailing_zeros() as usize;
            lanes &= lanes - 1;
            let Some(ray) = self.rays[k].as_ref() else { continue };
            let (q, l) = (k / V::W, k % V::W);
            let (t0, t1) = self.frames[level].lane_child(c, q, l);
            let (t_min, t_max) = (self.t_min[q].lane(l), self.t_max[q].lane(l));
            let start = Below::new(level as u32 + 1, child, cc, t0, t1);
            // SAFETY: this runs inside `V::visit`, so the CPU has V's instructions.
            match unsafe { V::walk(self.svo, self.mirror, start, t_min, t_max, self.max_level) } {
                Walk::Left => continue,
                // Zero length: the chain from the root may not enter this child at all.
                Walk::Reached(r) if r.te.max(t_min) == r.tx => {
                    self.out[k] = trace_unit(self.svo, ray, &self.opts[k]).hit
                }
                Walk::Reached(r) => {
                    self.defer_attr(k, r.attr as u32);
                    finish_into(&mut self.out[k], ray, r.te, t_min, r.level, r.coord, r.ct0.to_array());
                }
                // (Not returned by `walk_alone`, whose stack is bounded by the depth.)
                Walk::Aborted => self.out[k] = trace_unit(self.svo, ray, &self.opts[k]).hit,
            }
            self.active &= !(1 << k);
        }
    }

    /// Notes that lane `k`'s answer takes the attributes at `attrs[at]`, read after the walk.
    #[inline(always)]
    fn defer_attr(&mut self, k: usize, at: u32) {
        self.pending |= 1 << k;
        self.attr_at[k] = at;
        prefetch(self.svo.attrs.as_ptr().wrapping_add(at as usize));
    }

    /// Reports child `c` of `node` as the hit of the rays `lanes`.
    #[inline(always)]
    fn hits(&mut self, level: usize, node: usize, c: u32, cc: [u32; 3], mut lanes: u64) {
        let attr = self.svo.child_attr_index(node, c ^ self.mirror) as u32;
        while lanes != 0 {
            let k = lanes.trailing_zeros() as usize;
            lanes &= lanes - 1;
            self.active &= !(1 << k);
            let (q, l) = (k / V::W, k % V::W);
            let (ct0, ct1) = self.frames[level].lane_child(c, q, l);
            let te = ct0[0].max(ct0[1]).max(ct0[2]);
            let tx = ct1[0].min(ct1[1]).min(ct1[2]);
            let t_min = self.t_min[q].lane(l);
            let Some(ray) = self.rays[k].as_ref() else { continue };
            if te.max(t_min) == tx {
                // Zero length: Revelles' chain may pass this leaf by (see the module notes).
                self.out[k] = trace_unit(self.svo, ray, &self.opts[k]).hit;
            } else {
                self.defer_attr(k, attr);
                finish_into(&mut self.out[k], ray, te, t_min, level as u32 + 1, cc, ct0);
            }
        }
    }
}

/// The children of a node that one ray crosses, as [`Pass::crossed`] finds them for a lane,
/// among `occupied` (mirrored numbering): the eight entries and exits in two four-lane
/// vectors, the x-and-y halves once and the z halves with `t_min` and `t_max` folded in.
#[inline(always)]
fn crossed_alone(cell: &Cell, t_min: f32, t_max: f32, occupied: u32) -> u32 {
    let (t0, tm, t1) = (cell.t0, cell.tm, cell.t1);
    let entry_xy = Vec4::new(t0.x, tm.x, t0.x, tm.x).max(Vec4::new(t0.y, t0.y, tm.y, tm.y));
    let exit_xy = Vec4::new(tm.x, t1.x, tm.x, t1.x).min(Vec4::new(tm.y, tm.y, t1.y, t1.y));
    let low = entry_xy.max(Vec4::splat(max(t0.z, t_min))).cmple(exit_xy.min(Vec4::splat(min(tm.z, t_max))));
    let high = entry_xy.max(Vec4::splat(max(tm.z, t_min))).cmple(exit_xy.min(Vec4::splat(min(t1.z, t_max))));
    (low.bitmask() | (high.bitmask() << 4)) & occupied
}

/// One ray's walk below `start` as a packet of one: depth first, each node's crossed occupied
/// children ([`crossed_alone`]) in numeric order, which is front to back (module notes). The
/// first leaf reached is the scalar loop's answer unless its length is zero (the caller
/// checks, as for the packet's own leaves); [`Walk::Left`] when the ray crosses no leaf below
/// `start`. All t-values are Revelles' halvings, as the scalar loop forms them.
fn walk_alone(svo: &Svo, mirror: u32, start: Below, t_min: f32, t_max: f32, max_level: u32) -> Walk {
    walk_alone_body(svo, mirror, start, t_min, t_max, max_level)
}

/// [`walk_alone`]'s body, inlined into each of its builds ([`Kernel::walk`]).
#[inline(always)]
fn walk_alone_body(svo: &Svo, mirror: u32, start: Below, t_min: f32, t_max: f32, max_level: u32) -> Walk {
    // One entry per level below `start` (`level − start.level` of them).
    let mut stack = AloneStack::new();
    let Below { mut level, mut node, mut coord, mut cell } = start;
    let mut todo = crossed_alone(&cell, t_min, t_max, MIRRORED[mirror as usize][svo.masks[node] as usize] as u32);
    loop {
        if todo == 0 {
            // Back to the nearest ancestor with children left (only those are on the stack).
            let Some((parent, parent_todo, parent_level, parent_cell)) = stack.pop() else {
                return Walk::Left;
            };
            let up = level - parent_level as u32;
            level = parent_level as u32;
            (node, todo, cell) = (parent as usize, parent_todo as u32, parent_cell);
            coord = coord.map(|v| v >> up);
            continue;
        }
        let c = todo.trailing_zeros();
        todo &= todo - 1;
        let (ct0, ct1) = cell.child(c);
        let child_level = level + 1;
        let cc = [0, 1, 2].map(|i| 2 * coord[i] + ((c >> i) & 1));
        let octant = c ^ mirror;
        if child_level >= max_level {
            let attr = svo.child_attr_index(node, octant);
            let (te, tx) = (ct0.max_element(), ct1.min_element());
            return Walk::Reached(Reached { te, tx, level: child_level, coord: cc, attr, ct0 });
        }
        // A node whose crossed children are all taken is not returned to.
        if todo != 0 {
            stack.push((node as u32, todo as u8, level as u8, cell));
        }
        node = svo.child_node(node, octant);
        coord = cc;
        level = child_level;
        // Revelles §3.1: the midplanes halfway in t.
        cell = Cell { t0: ct0, tm: (ct0 + ct1) * 0.5, t1: ct1 };
        todo = crossed_alone(&cell, t_min, t_max, MIRRORED[mirror as usize][svo.masks[node] as usize] as u32);
    }
}

/// The ancestors [`walk_alone`] returns to: node, children still to visit, level, t-values;
/// at most one entry per level (only nodes with children left), so the tree's depth bounds it. Uninitialized storage: a lone walk starts
/// for every ray that leaves its packet.
type AloneStack = crate::uninit_stack::UninitStack<(u32, u8, u8, Cell), { MAX_DEPTH as usize }>;

/// [`walk_alone`] in the eight-lane kernel's build where the CPU runs it (asked once).
fn walk_single(svo: &Svo, mirror: u32, start: Below, t_min: f32, t_max: f32, max_level: u32) -> Walk {
    #[cfg(target_arch = "x86_64")]
    {
        static AVX8: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
        if *AVX8.get_or_init(avx8_supported) {
            // SAFETY: the CPU has the eight-lane kernel's instructions (checked above).
            return unsafe { Avx8::walk(svo, mirror, start, t_min, t_max, max_level) };
        }
    }
    walk_alone(svo, mirror, start, t_min, t_max, max_level)
}

/// `trace_unit(svo, ray, opts).hit`, found as a packet of one ray (`walk_alone` from the
/// root): the same answer (module notes), at a lower cost per node than Revelles' chain.
/// Rays with a parallel axis, whole-tree level limits and zero-length leaves take
/// [`trace_unit`].
pub fn trace_single(svo: &Svo, ray: &UnitRay, opts: &TraceOptions) -> Option<Hit> {
    let max_level = opts.max_level.min(svo.depth);
    if ray.parallel != 0 || max_level == 0 {
        return trace_unit(svo, ray, opts).hit;
    }
    let (t_min, t_max) = (ray.to_internal(opts.t_min.max(f32::MIN)), ray.to_internal(opts.t_max));
    if !(t_min <= t_max) {
        return None;
    }
    // The root's planes as the scalar loop computes them.
    let planes = Planes { origin: Vec3A::from(ray.origin), inv_dir: Vec3A::from(ray.inv_dir), parallel: 0 };
    let cell = Cell::new::<false>(&planes, [0; 3], 1.0);
    let (te, tx) = (cell.t0.max_element(), cell.t1.min_element());
    if !(te <= tx && t_min <= tx && te <= t_max) {
        // A miss of the cube: the children's test would cross none either; this leaves early.
        return None;
    }
    let root = Below { level: 0, node: 0, coord: [0; 3], cell };
    match walk_single(svo, ray.mirror, root, t_min, t_max, max_level) {
        Walk::Left => None,
        Walk::Reached(r) if r.te.max(t_min) != r.tx => {
            finish(ray, r.te, t_min, r.level, r.coord, svo.attrs[r.attr], r.ct0.to_array())
        }
        // Zero length: Revelles' chain may pass this leaf by (see the module notes).
        Walk::Reached(_) | Walk::Aborted => trace_unit(svo, ray, opts).hit,
    }
}

/// Traces `rays[k]` with `opts[k]` for every lane `k` of `lanes` (at most [`LANES`] rays, all
/// three slices as long) and writes `trace_unit(svo, ray, opts).hit` into `out[k]`; lanes
/// without a ray get `None`. Every ray's `max_level` must be the same.
pub fn trace_packet(
    svo: &Svo,
    rays: &[Option<UnitRay>],
    opts: &[TraceOptions],
    lanes: u64,
    stack: &mut PacketStack,
    out: &mut [Option<Hit>],
) {
    let n = rays.len().min(LANES).min(opts.len()).min(out.len());
    let lanes = if n == LANES { lanes } else { lanes & ((1u64 << n) - 1) };
    let mut todo = 0u64;
    let mut l = lanes;
    while l != 0 {
        let k = l.trailing_zeros() as usize;
        l &= l - 1;
        out[k] = None;
        match &rays[k] {
            // Rays along an axis, and whole-tree level limits, take the scalar loop.
            Some(r) if r.parallel == 0 && opts[k].max_level.min(svo.depth) > 0 => todo |= 1 << k,
            Some(r) => out[k] = trace_unit(svo, r, &opts[k]).hit,
            None => {}
        }
    }
    while todo != 0 {
        // One pass per mirror value: numeric child order is front to back only for rays that
        // share it.
        let mirror = rays[todo.trailing_zeros() as usize].as_ref().map_or(0, |r| r.mirror);
        let max_level = opts[todo.trailing_zeros() as usize].max_level.min(svo.depth);
        let mut pass_lanes = 0u64;
        let mut l = todo;
        while l != 0 {
            let k = l.trailing_zeros() as usize;
            l &= l - 1;
            if rays[k].as_ref().is_some_and(|r| r.mirror == mirror) && opts[k].max_level.min(svo.depth) == max_level {
                pass_lanes |= 1 << k;
            }
        }
        todo &= !pass_lanes;
        // The stack's frames fix the vector width.
        match &mut stack.frames {
            StackFrames::Four(frames) => run_pass(svo, rays, opts, pass_lanes, mirror, max_level, frames, out),
            #[cfg(target_arch = "x86_64")]
            StackFrames::Eight(frames) => run_pass(svo, rays, opts, pass_lanes, mirror, max_level, frames, out),
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn run_pass<V: Kernel>(
    svo: &Svo,
    rays: &[Option<UnitRay>],
    opts: &[TraceOptions],
    lanes: u64,
    mirror: u32,
    max_level: u32,
    frames: &mut Frames<V>,
    out: &mut [Option<Hit>],
) {
    let mut pass = Pass {
        svo,
        rays,
        opts,
        out,
        frames,
        origin: [V::ZERO_GROUPS; 3],
        inv: [V::ZERO_GROUPS; 3],
        t_min: V::ZERO_GROUPS,
        t_max: V::ZERO_GROUPS,
        mirror,
        max_level,
        active: 0,
        pending: 0,
        attr_at: [0; LANES],
    };
    // SAFETY: a stack holds frames of a vector type only where the CPU runs its instructions
    // (`PacketStack::default`; four lanes are x86-64's baseline).
    unsafe { V::run(&mut pass, lanes) };
    let mut l = pass.pending;
    while l != 0 {
        let k = l.trailing_zeros() as usize;
        l &= l - 1;
        if let Some(hit) = pass.out[k].as_mut() {
            hit.attr = svo.attrs[pass.attr_at[k] as usize];
        }
    }
}

impl<V: Kernel> Pass<'_, V> {
    /// Loads the rays of `lanes` into the pass's vectors and walks the tree from the root.
    #[inline(always)]
    fn run_body(&mut self, lanes: u64) {
        let (rays, opts) = (self.rays, self.opts);
        let mut l = lanes;
        let mut live = 0u64;
        while l != 0 {
            let k = l.trailing_zeros() as usize;
            l &= l - 1;
            let Some(r) = rays[k].as_ref() else { continue };
            let (q, j) = (k / V::W, k % V::W);
            // As the scalar loop: t range in internal units, empty ranges miss.
            let (lo, hi) = (r.to_internal(opts[k].t_min.max(f32::MIN)), r.to_internal(opts[k].t_max));
            if !(lo <= hi) {
                continue;
            }
            for a in 0..3 {
                self.origin[a][q].set_lane(j, r.origin[a]);
                self.inv[a][q].set_lane(j, r.inv_dir[a]);
            }
            self.t_min[q].set_lane(j, lo);
            self.t_max[q].set_lane(j, hi);
            live |= 1 << k;
        }
        // The root's planes as the scalar loop computes them: (p − o)·inv at p = 0, ½, 1.
        let mut entered = 0u64;
        let mut groups = groups_of::<V>(live);
        while groups != 0 {
            let q = next_group::<V>(&mut groups);
            let f = &mut self.frames[0];
            for a in 0..3 {
                let (o, i) = (self.origin[a][q], self.inv[a][q]);
                f.t0[a][q] = (V::splat(0.0) - o) * i;
                f.tm[a][q] = (V::splat(0.5) - o) * i;
                f.t1[a][q] = (V::splat(1.0) - o) * i;
            }
            let te = f.t0[0][q].fast_max(f.t0[1][q]).fast_max(f.t0[2][q]);
            let tx = f.t1[0][q].fast_min(f.t1[1][q]).fast_min(f.t1[2][q]);
            let ok = te.le_bits(tx) & self.t_min[q].le_bits(tx) & te.le_bits(self.t_max[q]);
            entered |= ok << (V::W * q);
        }
        entered &= live;
        self.active = entered;
        if entered != 0 {
            self.visit_body(0, 0, [0; 3], entered);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use crate::stability::{make_case, scene_blobs, standard_cases, Case, CaseRay};
    use crate::voxelize::VoxelGrid;
    use glam::Vec3;

    /// The lone walk's stack gives back what was pushed, last first, every field intact, and
    /// then nothing: a walk ends exactly when it is back at its start.
    #[test]
    fn the_lone_stack_pops_what_was_pushed_last_first() {
        let cell = |k: u32| {
            let v = Vec3A::splat(k as f32);
            Cell { t0: v, tm: v * 2.0, t1: v * 3.0 }
        };
        let mut stack = AloneStack::new();
        assert!(stack.pop().is_none());
        for round in 0..2u32 {
            for k in 0..MAX_DEPTH {
                stack.push((k + round, (k * 7) as u8, k as u8, cell(k + round)));
            }
            for k in (0..MAX_DEPTH).rev() {
                let (node, todo, level, c) = stack.pop().expect("pushed");
                assert_eq!((node, todo, level), (k + round, (k * 7) as u8, k as u8));
                assert_eq!((c.t0, c.tm, c.t1), (cell(k + round).t0, cell(k + round).tm, cell(k + round).t1));
            }
            assert!(stack.pop().is_none());
        }
    }

    fn opts_of(case: &Case, r: &CaseRay) -> TraceOptions {
        TraceOptions { t_min: r.t_min, t_max: r.t_max, max_level: case.max_level.unwrap_or(u32::MAX) }
    }

    /// Traces `rays` in packets of 64 and one by one; returns how many answers differ (and the
    /// first that does). Packets are traced at both vector widths: the CPU's (eight lanes
    /// where it has AVX) and four.
    fn differences(case: &Case, rays: &[CaseRay]) -> (usize, Option<String>) {
        let (n, first) = differences_with(case, rays, PacketStack::default());
        let (m, other) = differences_with(case, rays, PacketStack::four_lanes());
        (n + m, first.or(other))
    }

    fn differences_with(case: &Case, rays: &[CaseRay], mut stack: PacketStack) -> (usize, Option<String>) {
        let (mut n, mut first) = (0, None);
        for chunk in rays.chunks(LANES) {
            let units: Vec<_> =
                chunk.iter().map(|r| UnitRay::from_unit(r.origin.as_dvec3(), r.dir.as_dvec3())).collect();
            let opts: Vec<_> = chunk.iter().map(|r| opts_of(case, r)).collect();
            let mut out = vec![None; chunk.len()];
            let lanes = if chunk.len() == LANES { u64::MAX } else { (1u64 << chunk.len()) - 1 };
            trace_packet(&case.svo, &units, &opts, lanes, &mut stack, &mut out);
            for (k, r) in chunk.iter().enumerate() {
                let want = units[k].and_then(|u| trace_unit(&case.svo, &u, &opts[k]).hit);
                if out[k] != want {
                    n += 1;
                    first.get_or_insert_with(|| {
                        format!("{}: ray {r:?}: packet {:?}, scalar {want:?}", case.name, out[k])
                    });
                }
            }
        }
        (n, first)
    }

    /// Traces `rays` with [`trace_single`] and with `trace_unit`; returns how many answers
    /// differ (and the first that does).
    fn single_differences(case: &Case, rays: &[CaseRay]) -> (usize, Option<String>) {
        let (mut n, mut first) = (0, None);
        for r in rays {
            let Some(u) = UnitRay::from_unit(r.origin.as_dvec3(), r.dir.as_dvec3()) else { continue };
            let opts = opts_of(case, r);
            let (got, want) = (trace_single(&case.svo, &u, &opts), trace_unit(&case.svo, &u, &opts).hit);
            if got != want {
                n += 1;
                first.get_or_insert_with(|| format!("{}: ray {r:?}: single {got:?}, scalar {want:?}", case.name));
            }
        }
        (n, first)
    }

    #[test]
    fn single_rays_answer_as_the_scalar_loop_on_the_stability_suite() {
        for case in standard_cases(20_000) {
            let (n, first) = single_differences(&case, &case.rays);
            assert_eq!(n, 0, "{first:?}");
        }
    }

    #[test]
    fn packets_answer_as_the_scalar_loop_on_the_stability_suite() {
        for case in standard_cases(20_000) {
            let (n, first) = differences(&case, &case.rays);
            assert_eq!(n, 0, "{first:?}");
        }
    }

    /// Tiles of rays from one eye through a grid of points on voxel corners and edges: coherent
    /// like primary rays, and full of exact contacts (rays through edges and corners of
    /// voxels), where the packet must hand zero-length leaves to the scalar loop.
    #[test]
    fn coherent_tiles_through_voxel_corners_answer_as_the_scalar_loop() {
        let depth = 6;
        let mut case = make_case("blobs", depth, scene_blobs(depth, 7), Vec::new(), None);
        // Every voxel its own colour, so an answer with another voxel's attributes differs.
        let coords = scene_blobs(depth, 7);
        let mut grid = VoxelGrid::from_coords(depth, case.svo.bounds, coords, Vec3::ONE);
        for v in &mut grid.voxels {
            let c = v.code.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 40;
            v.albedo = Vec3::new((c & 255) as f32, ((c >> 8) & 255) as f32, (c >> 16) as f32) / 255.0;
        }
        case.svo = crate::svo::build(&grid).expect("blobs are not empty");
        let mut rng = Rng::new(5);
        let cell = 1.0 / (1u32 << depth) as f32;
        let mut rays = Vec::new();
        for _ in 0..400 {
            let eye = Vec3::new(
                rng.below(3) as f32 - 1.0 + 0.5,
                rng.below(3) as f32 - 1.0 + 0.5,
                rng.below(2) as f32 * 2.0 - 0.5,
            );
            // Eyes on lattice points too, so many rays pass exactly through voxel corners.
            let eye = if rng.below(2) == 0 { (eye / cell).round() * cell } else { eye };
            let base = [0, 1, 2].map(|_| rng.below(1 << depth) as f32);
            let step = [1.0f32, 0.5, 0.25][rng.below(3) as usize];
            for y in 0..8 {
                for x in 0..8 {
                    let p = Vec3::new(base[0] + x as f32 * step, base[1] + y as f32 * step, base[2]) * cell;
                    rays.push(CaseRay { origin: eye, dir: p - eye, t_min: 0.0, t_max: f32::INFINITY });
                }
            }
        }
        let (n, first) = differences(&case, &rays);
        assert_eq!(n, 0, "{first:?}");
        let (n, first) = single_differences(&case, &rays);
        assert_eq!(n, 0, "{first:?}");
    }
}
