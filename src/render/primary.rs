//! Primary rays of a frame, traced tile by tile: each [`TILE`]×[`TILE`] tile first gets its
//! beam starts ([`super::beam`]), then its rays run the nearest-hit search from there. The CPU
//! renderer's trace pass and library users who only want the hits share this loop.

use super::beam::{self, TilePyramid, TileRays, BEAM_WIDTH, TILE};
use super::pixel_spheres::{PixelSpheres, TileLists};
use super::tile_search::{
    each, nearest_listed_packet, nearest_moved_tile, nearest_packet, Origins, StoredHits, TileScratch,
};
use super::visibility::{nearest_listed_moved, nearest_moved, nearest_work, FrameInstances, InstanceHit, Search, Work};
use crate::scene::camera::Camera;
use crate::traverse::TraceOptions;
use glam::DVec3;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};

/// What the primary rays of one frame search.
#[derive(Clone, Copy)]
pub struct Primary<'a> {
    /// The frame's instances (without beam starts: each tile adds its own).
    pub instances: FrameInstances<'a>,
    /// The camera (rays through pixel centres, from the camera-relative origin).
    pub camera: &'a Camera,
    /// The search among instances.
    pub search: Search,
    /// Level limit and t range of every ray.
    pub opts: TraceOptions,
    /// Start rays at their tile's beam (the same hits, fewer steps).
    pub beams: bool,
    /// Settle the tiles whose rays' pyramid meets no instance through the instance BVH (for
    /// crowds, where `beams` is off): their rays miss without a search.
    pub bvh_beams: bool,
    /// Per pixel, the instances whose sphere its ray meets ([`PixelSpheres`]): when given
    /// (and `beams` is off), [`Todo::All`] and [`Todo::Again`] pixels search their list
    /// instead of the BVH (a tile's rays as packets, [`nearest_listed_packet`]), and
    /// [`Todo::Moved`] pixels the moved instances of their list.
    pub lists: Option<&'a PixelSpheres>,
    /// The instances that moved since the stored hits were traced (ascending), searched by
    /// [`Todo::Moved`] pixels.
    pub moved: &'a [u32],
    /// Per instance, whether it is one of `moved` (or empty): with `lists`, a
    /// [`Todo::Moved`] pixel then traces the moved instances of its own list.
    pub moved_flags: &'a [bool],
    /// Per tile (as [`Traced::stored`]), the pixels whose item already holds a miss (last
    /// frame's [`Traced::missed`]): such a miss is not stored again.
    pub missed_before: &'a [u64],
}

/// What [`trace_tiles`] did.
#[derive(Clone, Debug, Default)]
pub struct Traced {
    /// What the searches cost.
    pub work: Work,
    /// Rays traced ([`Todo::All`], [`Todo::Again`] and [`Todo::Moved`] pixels).
    pub rays: u64,
    /// Of those, the rays searched among the moved instances only.
    pub moved_only: u64,
    /// Per tile (row-major, `width.div_ceil(TILE)` tiles to a row), a mask of the pixels
    /// stored: bit `ty·TILE + tx` for the pixel at (tx, ty) in the tile.
    pub stored: Vec<u64>,
    /// Per tile as `stored`, the pixels stored as misses without a search: their tile's beam
    /// met no instance, or their list holds no sphere (a subset of `stored`; empty without
    /// beams or lists).
    pub missed: Vec<u64>,
}

/// What a pixel's primary ray needs this frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Todo {
    /// Nothing: its stored hit still holds.
    Keep,
    /// A search among every instance.
    All,
    /// A search among every instance, for a pixel whose stored hit is on `instance`, which
    /// moved: its new hit is usually near the old one, so it is searched first (the answer
    /// is [`Todo::All`]'s).
    Again {
        /// The instance of the stored hit.
        instance: u32,
        /// Ray parameter of the stored hit. No instance that stayed put is hit before it (the
        /// stored hit was the nearest of all), so such an instance need not be traced where
        /// a hit nearer than this is found first.
        t: f32,
    },
    /// A search among the moved instances ([`Primary::moved`]) only, against the nearest hit
    /// `(t, instance)` among all the others (+∞ and −1 for none): the stored hit, when it is
    /// on an instance that did not move.
    Moved {
        /// Ray parameter of the nearest hit among the instances that did not move.
        t: f32,
        /// Its instance (−1 for none).
        instance: i32,
    },
}

/// Traces every pixel of `out` (row-major, `camera.width` wide) as `pending(&tile, x, y,
/// item)` says ([`Todo`]), and hands a new hit to `store(item, hit)` (the hit with its ray's
/// unit direction); `tile` is what `tile_setup([x0, y0, x1, y1])` made once for the tile
/// holding the pixel (pixels x0..x1 × y0..y1), and a tile for which it returns None keeps
/// every pixel's stored hit without `pending` being asked. A [`Todo::Moved`] pixel is stored only when a
/// moved instance beats its bound. `rows_done(n)` hears of the rows done, a band's worth at a
/// time (the tiles are shared out in runs, not bands).
/// Returns what was traced and which pixels were stored ([`Traced`]).
///
/// # Panics
/// When `out` does not hold one item per pixel of the camera's image.
pub fn trace_tiles<T: Send, S>(
    p: &Primary,
    out: &mut [T],
    tile_setup: impl Fn([u32; 4]) -> Option<S> + Sync + Send,
    pending: impl Fn(&S, u32, u32, &mut T) -> Todo + Sync + Send,
    store: impl Fn(&mut T, Option<(&InstanceHit, DVec3)>) + Sync + Send,
    rows_done: impl Fn(usize) + Sync + Send,
) -> Traced {
    let w = p.camera.width as usize;
    let tiles_x = w.div_ceil(TILE as usize);
    // Per tile: the pixels stored, and of those the ones stored as misses by a beam.
    let mut masks = vec![[0u64; 2]; tiles_x * (p.camera.height as usize).div_ceil(TILE as usize)];
    let basis = p.camera.basis();
    // Lists made for another camera are not this frame's: its rays walk the BVH.
    let lists = p.lists.filter(|l| l.is_for(p.camera));
    // Flags for every instance, or the moved ones are searched one by one.
    let moved_flags = (p.moved_flags.len() == p.instances.prepared.len()).then_some(p.moved_flags);
    let (traced, culled, rays) = (AtomicU64::new(0), AtomicU64::new(0), AtomicU64::new(0));
    let moved_only = AtomicU64::new(0);
    let h = p.camera.height as usize;
    assert_eq!(out.len(), w * h, "one item per pixel");
    // Work items: the tiles of one beam's run of a band (a few tiles). A mostly kept frame's
    // work lies in the few tiles around its moving parts, often in two or three bands:
    // shared out band by band, one thread traced most of it while the other waited.
    let (bands, runs) = (h.div_ceil(TILE as usize), w.div_ceil(BEAM_WIDTH as usize));
    // Runs done, and the rows reported done (runs done × rows per run, rounded down).
    let (runs_done, rows_reported) = (AtomicUsize::new(0), AtomicUsize::new(0));
    let report = |n: usize| {
        let done = runs_done.fetch_add(n, Ordering::Relaxed) + n;
        let rows = done * h / (bands * runs);
        let before = rows_reported.fetch_max(rows, Ordering::Relaxed);
        if rows > before {
            rows_done(rows - before);
        }
    };
    let cells = crate::pool::Disjoint::new(out);
    let tile_masks = crate::pool::Disjoint::new(&mut masks);
    // One run of tiles, with the thread's scratch.
    let run_with = |item: usize, scratch: &mut TileScratch, tally: &mut Tally| {
        let (band, run) = (item / runs, item % runs);
        let y0 = band * TILE as usize;
        let tile_h = (h - y0).min(TILE as usize);
        // SAFETY: item `item` touches only the pixels of its own tiles (columns x_lo..x_hi of
        // rows y0..y0 + tile_h) and their masks, and holds one reference to one at a time.
        let rows = |i: usize| unsafe { cells.at(y0 * w + i) };
        let mask = |x0: usize| unsafe { tile_masks.at(band * tiles_x + x0 / TILE as usize) };
        let mut starts = std::mem::take(&mut scratch.starts);
        // Where the beam in `starts` begins (none yet).
        let mut beam_x0 = usize::MAX;
        let mut dirs = [DVec3::ZERO; (TILE * TILE) as usize];
        let mut hits = [None; (TILE * TILE) as usize];
        let x_lo = run * BEAM_WIDTH as usize;
        // The left columns of the run's tiles.
        let run_tiles = (x_lo..(x_lo + BEAM_WIDTH as usize).min(w)).step_by(TILE as usize);
        // The instances the run's tiles list, asked for at once while its first tile's rays
        // are set up: a crowd's lie scattered over megabytes, and each met as its ray reached
        // it was a cache miss waited for alone.
        if let Some(l) = lists {
            for x0 in run_tiles.clone() {
                l.tile(x0 as u32, y0 as u32).instances().for_each(|i| p.instances.prefetch_ray_map(i as usize));
            }
        }
        for x0 in run_tiles {
            let x1 = (x0 + TILE as usize).min(w);
            let Some(setup) = tile_setup([x0 as u32, y0 as u32, x1 as u32, (y0 + tile_h) as u32]) else {
                continue;
            };
            // Pixels to search among all instances, and among the moved ones with their bounds.
            let mut todo = 0u64;
            let mut partial = 0u64;
            let mut bounds = [(0.0f32, 0i32); (TILE * TILE) as usize];
            // The instance most of the tile's Again pixels hit last frame (a vote: one counter
            // that a different instance decrements).
            let (mut first, mut votes) = (None, 0u32);
            // Per lane, the t of its stored hit where that hit's instance moved (else −∞).
            let mut stored_t = [f32::NEG_INFINITY; (TILE * TILE) as usize];
            for ty in 0..tile_h {
                for x in x0..x1 {
                    let k = ty * TILE as usize + x - x0;
                    match pending(&setup, x as u32, (y0 + ty) as u32, rows(ty * w + x)) {
                        Todo::Keep => {}
                        Todo::All => todo |= 1 << k,
                        Todo::Again { instance, t } => {
                            todo |= 1 << k;
                            stored_t[k] = t;
                            if first == Some(instance as usize) {
                                votes += 1;
                            } else if votes == 0 {
                                (first, votes) = (Some(instance as usize), 1);
                            } else {
                                votes -= 1;
                            }
                        }
                        Todo::Moved { t, instance } => {
                            partial |= 1 << k;
                            bounds[k] = (t, instance);
                        }
                    }
                }
            }
            if todo | partial == 0 {
                continue;
            }
            // This tile's pixels whose item holds a miss already.
            let missed_before =
                p.missed_before.get(y0 / TILE as usize * tiles_x + x0 / TILE as usize).copied().unwrap_or(0);
            mask(x0)[0] = todo;
            tally.rays += (todo | partial).count_ones() as u64;
            tally.moved += partial.count_ones() as u64;
            // The tile's sphere lists, by lane.
            let tile_lists = lists.map_or(TileLists::EMPTY, |l| l.tile(x0 as u32, y0 as u32));
            // With beams, a tile whose rays can meet no instance stores misses untraced.
            let (fi, all_miss) = if p.beams {
                // One beam serves the tiles of a [`BEAM_WIDTH`]-pixel run of the band: its cone
                // holds all their rays, so its starts hold for each of them.
                let bx0 = x0 - x0 % BEAM_WIDTH as usize;
                if beam_x0 != bx0 {
                    let bx1 = (bx0 + BEAM_WIDTH as usize).min(w);
                    let tile = TileRays::new(p.camera, &basis, bx0 as u32, y0 as u32, bx1 as u32, (y0 + tile_h) as u32);
                    beam::starts(p.instances.parts, p.instances.prepared, &tile, p.opts.max_level, &mut starts);
                    beam_x0 = bx0;
                }
                // The tile's cone meets no instance's voxels.
                let all_miss = starts.iter().all(|&s| s == f32::INFINITY);
                if all_miss {
                    tally.work.culled += ((todo | partial).count_ones() as usize * starts.len()) as u64;
                }
                (FrameInstances { starts: Some(&starts), ..p.instances }, all_miss)
            } else {
                let settled = match lists {
                    // No ray of the tile meets any sphere: a crowd's sky, most of its tiles.
                    Some(_) => tile_lists.is_empty(),
                    // Through the BVH: the tile's pyramid meets no instance's sphere.
                    None => {
                        p.bvh_beams
                            && p.instances.bvh.is_some_and(|bvh| {
                                let tile = TileRays::new(
                                    p.camera,
                                    &basis,
                                    x0 as u32,
                                    y0 as u32,
                                    x1 as u32,
                                    (y0 + tile_h) as u32,
                                );
                                TilePyramid::new(&tile)
                                    .is_some_and(|pyr| !beam::meets_any(&pyr, bvh, p.instances.prepared))
                            })
                    }
                };
                (p.instances, settled)
            };
            if all_miss {
                // Every pending ray misses (and no moved instance beats a bound); a miss stored
                // there by last frame's beams is already in place.
                mask(x0)[1] = todo;
                todo &= !missed_before;
                while todo != 0 {
                    let k = todo.trailing_zeros() as usize;
                    todo &= todo - 1;
                    store(rows((k / TILE as usize) * w + x0 + k % TILE as usize), None);
                }
                continue;
            }
            // Lane k of the tile: its index in `rows`.
            let at = |k: usize| (k / TILE as usize) * w + x0 + k % TILE as usize;
            // `ray_dir` of the tile's pixels, with each column's and row's share formed once.
            let sx: [f64; TILE as usize] = std::array::from_fn(|i| p.camera.screen_x(&basis, (x0 + i) as u32));
            let sy: [f64; TILE as usize] = std::array::from_fn(|i| p.camera.screen_y(&basis, (y0 + i) as u32));
            let dir = |k: usize| basis.dir(sx[k % TILE as usize], sy[k / TILE as usize]);
            if p.beams {
                // The tile's rays as packets through each instance: the same answers as one by
                // one (below).
                super::ray_setup::tile_dirs(&basis, &sx, &sy, todo | partial, &mut dirs);
                if todo != 0 {
                    let stored = moved_flags.map(|moved| StoredHits { t: &stored_t, moved });
                    nearest_packet(
                        &fi,
                        Origins::One(DVec3::ZERO),
                        &dirs,
                        todo,
                        p.search,
                        &p.opts,
                        &mut tally.work,
                        scratch,
                        &mut hits,
                        first,
                        stored,
                    );
                    for k in each(todo) {
                        store(rows(at(k)), hits[k].as_ref().map(|h| (h, dirs[k])));
                    }
                }
                if partial != 0 {
                    nearest_moved_tile(
                        &fi,
                        DVec3::ZERO,
                        &dirs,
                        partial,
                        p.moved,
                        &bounds,
                        &p.opts,
                        &mut tally.work,
                        scratch,
                        &mut hits,
                    );
                    for k in each(partial) {
                        if let Some(hit) = hits[k] {
                            store(rows(at(k)), Some((&hit, dirs[k])));
                            mask(x0)[0] |= 1 << k;
                        }
                    }
                }
                continue;
            }
            if lists.is_none() {
                for k in each(todo) {
                    let d = dir(k);
                    let hit = nearest_work(&fi, DVec3::ZERO, d, p.search, &p.opts, &mut tally.work).map(|h| (h, d));
                    store(rows(at(k)), hit.as_ref().map(|(h, d)| (h, *d)));
                }
            } else if todo != 0 {
                // A ray whose list holds no sphere misses, without forming its direction, and
                // is not stored again where last frame stored a miss.
                let unlisted = todo & !tile_lists.mask;
                tally.work.culled += unlisted.count_ones() as u64 * fi.prepared.len() as u64;
                mask(x0)[1] |= unlisted;
                for k in each(unlisted & !missed_before) {
                    store(rows(at(k)), None);
                }
                // The others: the instances their lists hold, each traced by its lanes as one
                // packet.
                let listed = todo & tile_lists.mask;
                super::ray_setup::tile_dirs(&basis, &sx, &sy, listed, &mut dirs);
                let list = |k: usize| tile_lists.at(k);
                nearest_listed_packet(&fi, &dirs, listed, list, &p.opts, &mut tally.work, scratch, &mut hits);
                for k in each(listed) {
                    store(rows(at(k)), hits[k].as_ref().map(|h| (h, dirs[k])));
                }
            }
            for k in each(partial) {
                let (t, instance) = bounds[k];
                let found = match (lists, moved_flags) {
                    (Some(_), Some(flags)) => {
                        let listed = tile_lists.at(k);
                        if listed.is_empty() {
                            // No moved sphere meets the ray: the stored hit stands.
                            tally.work.culled += p.moved.len() as u64;
                            continue;
                        }
                        let d = dir(k);
                        nearest_listed_moved(
                            &fi,
                            DVec3::ZERO,
                            d,
                            listed,
                            flags,
                            p.moved.len(),
                            t,
                            instance,
                            &p.opts,
                            &mut tally.work,
                        )
                        .map(|h| (h, d))
                    }
                    _ => {
                        let d = dir(k);
                        nearest_moved(&fi, DVec3::ZERO, d, p.moved, t, instance, &p.opts, &mut tally.work)
                            .map(|h| (h, d))
                    }
                };
                if let Some((hit, d)) = found {
                    store(rows(at(k)), Some((&hit, d)));
                    mask(x0)[0] |= 1 << k;
                }
            }
        }
        scratch.starts = starts;
        // A band's worth of runs done: reported (once per band, not per run).
        tally.runs += 1;
        if tally.runs == runs {
            report(std::mem::take(&mut tally.runs));
        }
    };
    // What a thread traced, added up once it runs out of runs (shared counters bumped per
    // run would move their cache lines between the cores at every run).
    crate::pool::for_each_index_with(
        bands * runs,
        Tally::default,
        |tally, item| TileScratch::with(|s| run_with(item, s, tally)),
        |tally| {
            traced.fetch_add(tally.work.traced, Ordering::Relaxed);
            culled.fetch_add(tally.work.culled, Ordering::Relaxed);
            rays.fetch_add(tally.rays, Ordering::Relaxed);
            moved_only.fetch_add(tally.moved, Ordering::Relaxed);
            report(tally.runs);
        },
    );
    Traced {
        work: Work { traced: traced.into_inner(), culled: culled.into_inner() },
        rays: rays.into_inner(),
        moved_only: moved_only.into_inner(),
        stored: masks.iter().map(|m| m[0]).collect(),
        missed: if p.beams || p.bvh_beams || lists.is_some() {
            masks.iter().map(|m| m[1]).collect()
        } else {
            Vec::new()
        },
    }
}

/// What one thread of [`trace_tiles`] traced.
#[derive(Default)]
struct Tally {
    work: Work,
    /// Rays traced, and of those the moved-only ones.
    rays: u64,
    moved: u64,
    /// Runs done since the last report of rows done.
    runs: usize,
}

/// The nearest hit of every pixel's primary ray (row-major, row 0 at the top).
pub fn nearest_hits(p: &Primary) -> Vec<Option<InstanceHit>> {
    let mut out = vec![None; (p.camera.width * p.camera.height) as usize];
    trace_tiles(p, &mut out, |_| Some(()), |_, _, _, _| Todo::All, |o, hit| *o = hit.map(|h| *h.0), |_| {});
    out
}
