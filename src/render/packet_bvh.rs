//! A packet of up to [`LANES`] rays walking the instance BVH together (its four-wide f32
//! tree, [`super::bvh_wide`], or the binary f64 one for origins the f32 tree does not cover):
//! a library caller's runs of rays in a scene of many instances ([`crate::cast::SceneCaster`])
//! and the sun's shadow rays of a tile in a crowd, each instance the walk reaches traced by
//! the lanes that need it as one packet through its octree ([`super::tile_search`]), where one
//! ray at a time would walk the tree and traverse each octree alone.
//!
//! The answers are the one-ray search's bit for bit ([`super::visibility::nearest_work`] and
//! [`super::visibility::occluded`] with [`Search::Bvh`]). The walk only culls: a lane leaves a
//! box only when its ray misses it within the lane's best hit so far (the f32 boxes are
//! widened past the rounding for every origin the tree covers; the binary tree's are tested
//! as the one-ray walk tests them), and each instance reached takes the one-instance step of
//! the packets of few instances, whose answer does not depend on the order in which
//! instances come.

use super::bvh::{box_entry, Bvh};
use super::bvh_wide::WideRay;
use super::cpu::SUN_UNKNOWN;
use super::tile_search::{each, nearest_instance, occluded_instance, MovedOnly, Origins, TileScratch};
use super::visibility::{nearest_work, occluded, FrameInstances, InstanceHit, Search, Work};
use crate::traverse::packet::LANES;
use crate::traverse::TraceOptions;
use crate::uninit_stack::UninitStack;
use glam::{DVec3, Vec4};
use std::cell::Cell;

/// Marks a stack entry as a leaf child (wide node · 4 + child) rather than a node.
const LEAF_BIT: u32 = 1 << 31;

/// The wide walk's stack: (node or leaf child, the lanes that enter it, their smallest entry
/// t). As the one-ray walk's ([`super::bvh_wide::WideStack`]): at most three siblings wait per
/// level of a tree at most 32 binary levels deep.
type WideStack = UninitStack<(u32, u64, f32), 128>;

/// The binary walk's stack: at most one sibling waits per level.
type BinaryStack = UninitStack<(u32, u64, f64), 64>;

/// Walks the wide tree for the lanes `lanes` front to back (children by the smallest entry
/// of their lanes), calling `items(first, count, lanes)` for each leaf child's instances
/// (`bvh.items[first..first + count]`) with the lanes whose ray enters its box within
/// `bound(k)`. The bounds may shrink as the walk goes (each lane's best hit); `open()` is
/// asked for the lanes still searching (all but the blocked, for shadow rays), and the walk
/// ends when none is.
fn walk_wide(
    bvh: &Bvh,
    rays: &[WideRay; LANES],
    lanes: u64,
    bound: &impl Fn(usize) -> f32,
    open: &impl Fn() -> u64,
    items: &mut impl FnMut(usize, usize, u64),
) {
    let mut stack = WideStack::new();
    stack.push((0, lanes, 0.0));
    while let Some((n, mut mask, entry)) = stack.pop() {
        mask &= open();
        // Every lane's box entry is at least `entry`: a box beyond every lane's bound is skipped.
        if mask == 0 || each(mask).all(|k| entry > bound(k)) {
            continue;
        }
        if n & LEAF_BIT != 0 {
            let (w, c) = (((n & !LEAF_BIT) / 4) as usize, (n % 4) as usize);
            let node = &bvh.wide.nodes[w];
            items(node.child[c] as usize, node.count[c] as usize, mask);
            continue;
        }
        let node = &bvh.wide.nodes[n as usize];
        let mut entered = [0u64; 4];
        let mut nearest = Vec4::INFINITY;
        for k in each(mask) {
            let (hit, t0) = rays[k].test(node, bound(k));
            for (c, e) in entered.iter_mut().enumerate() {
                *e |= u64::from(hit >> c & 1) << k;
            }
            nearest = nearest.min(t0);
        }
        let mut next = [(0u32, 0u64, 0.0f32); 4];
        let mut len = 0;
        for c in 0..4 {
            if entered[c] != 0 {
                let id = if node.count[c] == 0 { node.child[c] } else { LEAF_BIT | (n * 4 + c as u32) };
                next[len] = (id, entered[c], nearest[c]);
                len += 1;
            }
        }
        // The farthest pushed first, so that the nearest is walked first.
        next[..len].sort_unstable_by(|a, b| b.2.total_cmp(&a.2));
        for &e in &next[..len] {
            stack.push(e);
        }
    }
}

/// [`walk_wide`] over the binary f64 tree, for lanes whose origin the wide tree does not
/// cover (a camera far from the scene): each box tested as the one-ray walk tests it
/// ([`box_entry`], from the lane's origin with its direction's reciprocals `inv[k]`).
fn walk_binary(
    bvh: &Bvh,
    origins: Origins,
    inv: &[DVec3; LANES],
    lanes: u64,
    bound: &impl Fn(usize) -> f32,
    open: &impl Fn() -> u64,
    items: &mut impl FnMut(usize, usize, u64),
) {
    let Some(root) = bvh.nodes.first() else { return };
    let mut mask = 0u64;
    let mut nearest = f64::INFINITY;
    for k in each(lanes) {
        if let Some(t) = box_entry(root.lo, root.hi, origins.of(k), inv[k], f64::INFINITY) {
            mask |= 1 << k;
            nearest = nearest.min(t);
        }
    }
    let mut stack = BinaryStack::new();
    if mask != 0 {
        stack.push((0, mask, nearest));
    }
    while let Some((n, mut mask, entry)) = stack.pop() {
        mask &= open();
        if mask == 0 || each(mask).all(|k| entry > bound(k) as f64) {
            continue;
        }
        let node = &bvh.nodes[n as usize];
        if node.count > 0 {
            items(node.first as usize, node.count as usize, mask);
            continue;
        }
        let mut next = [(0u32, 0u64, f64::INFINITY); 2];
        for (c, e) in next.iter_mut().enumerate() {
            let child = node.first + c as u32;
            let b = &bvh.nodes[child as usize];
            e.0 = child;
            for k in each(mask) {
                if let Some(t) = box_entry(b.lo, b.hi, origins.of(k), inv[k], bound(k) as f64) {
                    e.1 |= 1 << k;
                    e.2 = e.2.min(t);
                }
            }
        }
        // The farther pushed first, so that the nearer is walked first.
        if next[0].2 <= next[1].2 {
            next.swap(0, 1);
        }
        for e in next {
            if e.1 != 0 {
                stack.push(e);
            }
        }
    }
}

/// Walks `bvh` for the lanes of `lanes`: those whose origin the wide tree covers through it
/// ([`walk_wide`]), the others through the binary tree ([`walk_binary`]).
#[allow(clippy::too_many_arguments)]
fn walk(
    bvh: &Bvh,
    origins: Origins,
    dirs: &[DVec3],
    lanes: u64,
    bound: impl Fn(usize) -> f32,
    open: impl Fn() -> u64,
    mut items: impl FnMut(usize, usize, u64),
) {
    let mut rays = [WideRay::new(DVec3::ZERO, DVec3::X); LANES];
    let mut covered = 0u64;
    for k in each(lanes) {
        let o = origins.of(k);
        if bvh.wide.covers_origin(o) {
            rays[k] = WideRay::new(o, dirs[k]);
            covered |= 1 << k;
        }
    }
    if covered != 0 {
        walk_wide(bvh, &rays, covered, &bound, &open, &mut items);
    }
    if lanes & !covered != 0 {
        let mut inv = [DVec3::ZERO; LANES];
        for k in each(lanes & !covered) {
            inv[k] = dirs[k].recip();
        }
        walk_binary(bvh, origins, &inv, lanes & !covered, &bound, &open, &mut items);
    }
}

/// The nearest hit of each ray `origins.of(k) + t·dirs[k]` for the lanes `k` of `lanes` (up
/// to [`LANES`]), written to `out[k]`: what [`nearest_work`] answers with [`Search::Bvh`]
/// through `fi.bvh` (without beam starts; without a tree, one ray at a time).
#[allow(clippy::too_many_arguments)]
pub fn nearest_packet_bvh(
    fi: &FrameInstances,
    origins: Origins,
    dirs: &[DVec3],
    lanes: u64,
    opts: &TraceOptions,
    work: &mut Work,
    scratch: &mut TileScratch,
    out: &mut [Option<InstanceHit>],
) {
    let Some(bvh) = fi.bvh else {
        for k in each(lanes) {
            out[k] = nearest_work(fi, origins.of(k), dirs[k], Search::Bvh, opts, work);
        }
        return;
    };
    for k in each(lanes) {
        out[k] = None;
    }
    // The lanes' best hits so far, as the walk reads them while `out` is being written.
    let bounds: [Cell<f32>; LANES] = std::array::from_fn(|_| Cell::new(opts.t_max));
    walk(
        bvh,
        origins,
        dirs,
        lanes,
        |k| bounds[k].get(),
        || lanes,
        |first, count, mask| {
            for &i in &bvh.items[first..first + count] {
                let i = i as usize;
                nearest_instance(fi, i, opts.t_min, origins, dirs, mask, Search::Bvh, opts, work, scratch, out, None);
            }
            for k in each(mask) {
                if let Some(b) = out[k] {
                    bounds[k].set(b.hit.t);
                }
            }
        },
    );
}

/// Whether each ray `origins[k] + t·dirs[k]`, `0 ≤ t ≤ t_max[k]`, for the lanes `k` of `lanes`
/// (up to [`LANES`]), hits an instance: bit `k` of the result set when it does. What
/// [`occluded`] answers with [`Search::Bvh`] through `fi.bvh`, down to `max_level` (without a
/// tree, one ray at a time).
#[allow(clippy::too_many_arguments)]
pub fn occluded_rays_bvh(
    fi: &FrameInstances,
    origins: &[DVec3],
    dirs: &[DVec3],
    t_max: &[f64],
    lanes: u64,
    max_level: u32,
    scratch: &mut TileScratch,
) -> u64 {
    let only = MovedOnly { lanes: 0, moved: &[] };
    occluded_walk(fi, origins, dirs, t_max, lanes, only, max_level, scratch, &mut [0; LANES])
}

/// [`super::tile_search::occluded_tile_by`] through the instance BVH (the sun's shadow rays
/// of a tile in a crowd): whether each ray `origins[k] + t·dir`, `0 ≤ t ≤ t_max`, for the
/// lanes `k` of `lanes` hits an instance (the lanes of `only` asked about the moved instances
/// alone), with `blockers[k]` set to an instance that blocks lane `k` (where bit `k` of the
/// result is set; the first the walk reaches, or [`crate::render::cpu`]'s unknown mark
/// where the lane was asked one ray at a time).
#[allow(clippy::too_many_arguments)]
pub fn occluded_tile_bvh(
    fi: &FrameInstances,
    origins: &[DVec3],
    dir: DVec3,
    lanes: u64,
    only: MovedOnly,
    t_max: f64,
    max_level: u32,
    scratch: &mut TileScratch,
    blockers: &mut [u32; LANES],
) -> u64 {
    occluded_walk(fi, origins, &[dir; LANES], &[t_max; LANES], lanes, only, max_level, scratch, blockers)
}

/// [`occluded_rays_bvh`] with the lanes of `only` asked about the moved instances alone and
/// each blocked lane's blocker written to `blockers` (see [`occluded_tile_bvh`]).
#[allow(clippy::too_many_arguments)]
fn occluded_walk(
    fi: &FrameInstances,
    origins: &[DVec3],
    dirs: &[DVec3],
    t_max: &[f64],
    lanes: u64,
    only: MovedOnly,
    max_level: u32,
    scratch: &mut TileScratch,
    blockers: &mut [u32; LANES],
) -> u64 {
    // (A reach that is not above 0, or not a number, is left to the one-ray search.)
    let reaching = each(lanes).filter(|&k| t_max[k] > 0.0).fold(0u64, |m, k| m | 1 << k);
    let mut blocked = 0u64;
    let one_by_one = if fi.bvh.is_some() { lanes & !reaching } else { lanes };
    for k in each(one_by_one) {
        // (No lane is asked about the moved instances alone without a reach: those come from
        // the sun, at an infinite one.)
        if occluded(fi, origins[k], dirs[k], t_max[k], Search::Bvh, max_level) {
            blocked |= 1 << k;
            blockers[k] = SUN_UNKNOWN;
        }
    }
    let Some(bvh) = fi.bvh else { return blocked };
    // The box tests' reach per lane: rounded up to f32 (the next float above, for a reach
    // above 0 that rounded down), so that no box within it is cut.
    let reach: [f32; LANES] = std::array::from_fn(|k| {
        let r = t_max[k] as f32;
        if (r as f64) < t_max[k] {
            f32::from_bits(r.to_bits() + 1)
        } else {
            r
        }
    });
    let open = Cell::new(reaching);
    walk(
        bvh,
        Origins::Each(origins),
        dirs,
        reaching,
        |k| reach[k],
        || open.get(),
        |first, count, mask| {
            let mut still = mask;
            for &i in &bvh.items[first..first + count] {
                let p = &fi.prepared[i as usize];
                // An instance that stayed put is not asked about the lanes of `only`.
                let asked = if only.moved.get(i as usize).is_some_and(|m| !m) { still & !only.lanes } else { still };
                let hit = occluded_instance(fi, p, origins, dirs, t_max, asked, Search::Bvh, max_level, scratch);
                for k in each(hit) {
                    blockers[k] = i;
                }
                still &= !hit;
                if still == 0 {
                    break;
                }
            }
            open.set(open.get() & !(mask & !still));
        },
    );
    blocked | (reaching & !open.get())
}
