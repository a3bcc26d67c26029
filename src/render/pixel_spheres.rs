//! Per pixel, the instances whose bounding sphere its primary ray meets, with the t at which
//! it enters each, nearest first: found once per frame by projecting every sphere onto the
//! screen and testing the pixel centres inside its projection, instead of walking the
//! instance BVH once per ray.
//!
//! In a crowd, most instances cover a pixel or less and most rays pass between them: a ray's
//! walk tests node after node of the BVH to find that it meets a sphere or two, or none
//! (docs/benchmarks.md, step 51), while a sphere's projection holds zero or one pixel
//! centre. A pixel's list is exactly what the depth-sorted search collects for its ray
//! ([`super::visibility::nearest_listed`]): the same [`sphere_interval`] of the same
//! direction, so the hits are bit for bit those of every other search.
//!
//! When the spheres overlap deeply (more than [`MAX_PER_PIXEL`] pixel tests per pixel on
//! average; a sphere around the eye costs a whole image's), [`PixelSpheres::build`] gives up
//! and the rays walk the BVH as before.

use super::beam::TILE as TILE_SIDE;
use super::instances::sphere_interval;
use crate::scene::camera::{Camera, PixelGrid, PixelRect};
use crate::scene::Scene;
use glam::DVec3;

/// The side of the tiles the lists are indexed by: the renderer's.
const TILE: usize = TILE_SIDE as usize;

/// Pixel tests per pixel, on average over the image, beyond which the lists are not built.
pub const MAX_PER_PIXEL: u64 = 8;

/// Instances per parallel chunk of the projection.
#[cfg(feature = "parallel")]
const CHUNK: usize = 2048;

/// Moved instances per parallel chunk of their projection: a crowd's ten thousand moved
/// instances in five chunks left one of two threads with three.
const MOVED_CHUNK: usize = 512;

/// How many moved instances ahead their spheres are asked for.
const AHEAD: usize = 4;

/// The lists of one frame's primary rays, indexed by the renderer's 8×8 tiles: a crowd's
/// frame lists a few thousand crossings over tens of thousands of pixels, and an index per
/// tile is a sixty-fourth of one per pixel to clear and sum every frame.
#[derive(Clone, Debug, Default)]
pub struct PixelSpheres {
    width: u32,
    height: u32,
    /// Tiles across the image.
    tiles_x: u32,
    /// Per tile (row-major), where its entries start in `entries`; one more at the end.
    tile_start: Vec<u32>,
    /// Per tile, its pixels whose list is not empty: bit (y mod 8)·8 + (x mod 8).
    tile_mask: Vec<u64>,
    /// Per entry, its pixel's bit in its tile's mask: a tile's entries ascend by it.
    local: Vec<u8>,
    /// (sphere entry t, instance): per tile by pixel, per pixel ascending by t, then by
    /// instance.
    entries: Vec<(f64, u32)>,
    /// The entries by pixel bit only, before they are put in tile order (kept for its memory).
    sorting: Vec<(f64, u32, u32)>,
    /// What the next frame's lists may take over: the camera and spheres these were built
    /// for, and every (pixel, entry t, instance) found, by ascending instance.
    camera: Option<Camera>,
    spheres: Vec<(DVec3, f64)>,
    found: Vec<(u32, f64, u32)>,
}

/// The lists of one tile's pixels ([`PixelSpheres::tile`]), by lane: (y mod 8)·8 + (x mod 8).
#[derive(Clone, Copy, Debug)]
pub struct TileLists<'a> {
    /// The lanes whose list is not empty.
    pub mask: u64,
    /// Whether each of those lanes lists one sphere (a crowd's tiles): then a lane's entry is
    /// found by counting the lanes before it.
    one_each: bool,
    entries: &'a [(f64, u32)],
    local: &'a [u8],
}

impl<'a> TileLists<'a> {
    /// A tile whose rays meet no sphere.
    pub const EMPTY: TileLists<'static> = TileLists { mask: 0, one_each: true, entries: &[], local: &[] };

    /// Whether no ray of the tile meets a sphere.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.mask == 0
    }

    /// Every instance the tile's lanes list (once per lane that lists it), in no useful order.
    #[inline]
    pub fn instances(&self) -> impl Iterator<Item = u32> + 'a {
        self.entries.iter().map(|e| e.1)
    }

    /// The list of lane `k` (below 64): (sphere entry t, instance), nearest first.
    #[inline]
    pub fn at(&self, k: usize) -> &'a [(f64, u32)] {
        if k >= 64 || self.mask >> k & 1 == 0 {
            return &[];
        }
        // Each listed lane before this one holds at least one entry.
        let before = (self.mask & ((1u64 << k) - 1)).count_ones() as usize;
        if self.one_each {
            return self.entries.get(before..before + 1).unwrap_or(&[]);
        }
        let skip = before.min(self.local.len());
        let first = skip + self.local[skip..].iter().take_while(|&&l| (l as usize) < k).count();
        let end = first + self.local[first..].iter().take_while(|&&l| l as usize == k).count();
        self.entries.get(first..end).unwrap_or(&[])
    }
}

/// What one chunk of instances found: (pixel, entry t, instance), in instance order.
type Found = Vec<(u32, f64, u32)>;

impl PixelSpheres {
    /// The lists for `camera`'s pixels (rays through their centres from the camera-relative
    /// origin, as [`super::primary::trace_tiles`] forms them) among the instances' spheres
    /// (camera-relative centre and radius of each [`Prepared`](super::instances::Prepared),
    /// in instance order); None when the camera is not valid or the spheres would need more
    /// than [`MAX_PER_PIXEL`] tests per pixel.
    pub fn build(camera: &Camera, spheres: &[(DVec3, f64)]) -> Option<PixelSpheres> {
        Self::build_within(None, camera, spheres, None, MAX_PER_PIXEL)
    }

    /// [`PixelSpheres::build`] taking over from `previous` (last frame's lists) what still
    /// holds: with the same camera, a sphere whose centre and radius are the same bits as
    /// then meets the same pixels' rays at the same t, and is not projected again. A crowd
    /// whose cars are posed only where they are seen leaves most spheres as they were.
    pub fn rebuild(previous: Option<PixelSpheres>, camera: &Camera, spheres: &[(DVec3, f64)]) -> Option<PixelSpheres> {
        Self::build_within(previous, camera, spheres, None, MAX_PER_PIXEL)
    }

    /// [`PixelSpheres::rebuild`] for spheres of which only those listed in `moved`
    /// (ascending instances) may differ from the ones `previous` was built for: the others
    /// are not even compared (a crowd's 80 000 spheres were read twice and copied every
    /// frame to find the few thousand that moved). The renderer knows them: they are the
    /// instances it prepared again.
    pub(crate) fn rebuild_moved(
        previous: Option<PixelSpheres>,
        camera: &Camera,
        spheres: &[(DVec3, f64)],
        moved: &[u32],
    ) -> Option<PixelSpheres> {
        Self::build_within(previous, camera, spheres, Some(moved), MAX_PER_PIXEL)
    }

    /// [`PixelSpheres::rebuild`] (or [`PixelSpheres::rebuild_moved`]) with at most
    /// `per_pixel` tests per pixel on average.
    fn build_within(
        previous: Option<PixelSpheres>,
        camera: &Camera,
        spheres: &[(DVec3, f64)],
        moved: Option<&[u32]>,
        per_pixel: u64,
    ) -> Option<PixelSpheres> {
        camera.validate().ok()?;
        let mut kept = previous.unwrap_or_default();
        // Last frame's spheres and findings, when they were made for these rays.
        let same = kept.camera == Some(*camera) && kept.spheres.len() == spheres.len();
        if !same {
            kept.spheres.clear();
            kept.found.clear();
        }
        let (w, h) = (camera.width, camera.height);
        let pixels = w as u64 * h as u64;
        if pixels > u32::MAX as u64 || spheres.len() > u32::MAX as usize {
            return None;
        }
        let basis = camera.basis();
        let limit = per_pixel.saturating_mul(pixels);
        let grid = PixelGrid::new(camera, &basis);
        let (columns, rows) = camera.screen_slopes(&basis);
        // One sphere, tested pixel by pixel inside its projection: its findings and the
        // pixels tested.
        let project = |i: u32, (centre, radius): (DVec3, f64), found: &mut Found| -> u64 {
            // A centre that is not finite gives no interval for any ray; a radius that is not
            // a number neither.
            if !centre.is_finite() || radius.is_nan() {
                return 0;
            }
            let rect = match grid.near(&[centre], padded(centre, radius)) {
                PixelRect::Empty => return 0,
                PixelRect::Unbounded => PixelRect::Pixels { x0: 0, y0: 0, x1: w - 1, y1: h - 1 },
                rect => rect,
            };
            let PixelRect::Pixels { x0, y0, x1, y1 } = rect else { return 0 };
            let tested = rect.area(camera);
            // Past the limit the lists are not made: not worth testing its pixels.
            if tested <= limit {
                for y in y0..=y1 {
                    for x in x0..=x1 {
                        let d = basis.dir(columns[x as usize], rows[y as usize]);
                        if let Some((t0, _)) = sphere_interval(centre, radius, DVec3::ZERO, d) {
                            found.push((y * w + x, t0, i));
                        }
                    }
                }
            }
            tested
        };
        // (The merge below takes the moved instances in ascending order; any other list is
        // rebuilt whole.)
        let ascending = |m: &&[u32]| m.windows(2).all(|w| w[0] < w[1]);
        let found = match moved.filter(|_| same).filter(ascending) {
            Some(moved) => {
                // The listed spheres that changed, projected again and written over last
                // frame's copy while it is in the cache: (findings, which, tested) per chunk,
                // in instance order. Each chunk's ascending instances own the stretch of the
                // copy up to the next chunk's first.
                let pieces = super::instances::stretches(moved, MOVED_CHUNK, &mut kept.spheres[..]);
                let each =
                    |(ids, offset, copy): (&[u32], usize, &mut [(DVec3, f64)])| -> Option<(Found, Vec<u32>, u64)> {
                        let (mut found, mut again, mut tested) = (Vec::new(), Vec::new(), 0u64);
                        for (j, &i) in ids.iter().enumerate() {
                            // Scattered over megabytes (a crowd's cars in sight): asked for
                            // ahead, they load while the spheres before them are projected.
                            if let Some(&next) = ids.get(j + AHEAD) {
                                if let Some(s) = spheres.get(next as usize) {
                                    crate::prefetch::prefetch_bytes(s, std::mem::size_of::<(DVec3, f64)>());
                                }
                                if let Some(s) = copy.get((next as usize).wrapping_sub(offset)) {
                                    crate::prefetch::prefetch_bytes(s, std::mem::size_of::<(DVec3, f64)>());
                                }
                            }
                            let (Some(&now), Some(then)) = (spheres.get(i as usize), copy.get_mut(i as usize - offset))
                            else {
                                continue;
                            };
                            // Written, not compared: a listed instance has almost always
                            // moved, and reading last frame's copy stalled on the cache.
                            *then = now;
                            again.push(i);
                            tested += project(i, now, &mut found);
                            if tested > limit {
                                return None;
                            }
                        }
                        Some((found, again, tested))
                    };
                let parts: Vec<(Found, Vec<u32>, u64)> =
                    crate::pool::map_owned(pieces, each).into_iter().collect::<Option<_>>()?;
                if parts.iter().map(|p| p.2).sum::<u64>() > limit {
                    return None;
                }
                // Last frame's findings but those of the spheres projected again, merged
                // with theirs by instance.
                let mut fresh = parts.iter().flat_map(|p| p.0.iter().copied()).peekable();
                let mut again = parts.iter().flat_map(|p| p.1.iter().copied()).peekable();
                let mut merged = Vec::with_capacity(kept.found.len());
                for &f in &kept.found {
                    while let Some(n) = fresh.next_if(|n| n.2 < f.2) {
                        merged.push(n);
                    }
                    while again.next_if(|&a| a < f.2).is_some() {}
                    if again.peek() != Some(&f.2) {
                        merged.push(f);
                    }
                }
                merged.extend(fresh);
                merged
            }
            None => {
                let (old_spheres, old_found) = (&kept.spheres[..], &kept.found[..]);
                // One chunk's spheres; None beyond the limit (each chunk stops early; the
                // chunks' sum is checked below).
                let each = |first: usize, chunk: &[(DVec3, f64)]| -> Option<(Found, u64)> {
                    let mut found = Vec::new();
                    let mut tested = 0u64;
                    // Last frame's findings for this chunk's instances, walked alongside.
                    let from = old_found.partition_point(|f| (f.2 as usize) < first);
                    let mut old = &old_found[from..];
                    for (k, &sphere) in chunk.iter().enumerate() {
                        let i = (first + k) as u32;
                        while old.first().is_some_and(|f| f.2 < i) {
                            old = &old[1..];
                        }
                        if old_spheres.get(i as usize).is_some_and(|&o| same_bits(o, sphere)) {
                            while let Some(&f) = old.first().filter(|f| f.2 == i) {
                                found.push(f);
                                old = &old[1..];
                            }
                            continue;
                        }
                        tested += project(i, sphere, &mut found);
                        if tested > limit {
                            return None;
                        }
                    }
                    Some((found, tested))
                };
                #[cfg(feature = "parallel")]
                let parts: Vec<(Found, u64)> = {
                    use rayon::prelude::*;
                    spheres
                        .par_chunks(CHUNK)
                        .enumerate()
                        .map(|(c, chunk)| each(c * CHUNK, chunk))
                        .collect::<Option<_>>()?
                };
                #[cfg(not(feature = "parallel"))]
                let parts: Vec<(Found, u64)> = vec![each(0, spheres)?];
                if parts.iter().map(|p| p.1).sum::<u64>() > limit {
                    return None;
                }
                kept.spheres.clear();
                kept.spheres.extend_from_slice(spheres);
                let mut all = std::mem::take(&mut kept.found);
                all.clear();
                for (found, _) in parts {
                    all.extend_from_slice(&found);
                }
                all
            }
        };
        kept.width = w;
        kept.height = h;
        kept.sort_by_tile(&found);
        kept.camera = Some(*camera);
        kept.found = found;
        Some(kept)
    }

    /// Puts `found` (pixel, entry t, instance) into the tile index: a stable counting sort
    /// by the pixel's bit in its tile, then one by tile (each over the entries and a bucket
    /// per bit or tile, never per pixel), then each pixel's entries with more than one by t
    /// and instance.
    fn sort_by_tile(&mut self, found: &[(u32, f64, u32)]) {
        let (w, h) = (self.width as usize, self.height as usize);
        let tiles_x = w.div_ceil(TILE);
        let tiles = tiles_x * h.div_ceil(TILE);
        self.tiles_x = tiles_x as u32;
        let tile_of = |px: u32| (px as usize / w / TILE) * tiles_x + (px as usize % w) / TILE;
        let bit_of = |px: u32| ((px as usize / w) % TILE * TILE + (px as usize % w) % TILE) as u32;
        // By bit: (t, instance, tile · 64 + bit).
        let mut bits = [0u32; 65];
        for &(px, _, _) in found {
            bits[bit_of(px) as usize + 1] += 1;
        }
        for k in 1..bits.len() {
            bits[k] += bits[k - 1];
        }
        let sorting = &mut self.sorting;
        sorting.clear();
        sorting.resize(found.len(), (0.0, 0, 0));
        for &(px, t0, i) in found {
            let bit = bit_of(px);
            let slot = &mut bits[bit as usize];
            sorting[*slot as usize] = (t0, i, (tile_of(px) as u32) << 6 | bit);
            *slot += 1;
        }
        // By tile, keeping the bits' order.
        let start = &mut self.tile_start;
        start.clear();
        start.resize(tiles + 1, 0);
        let mask = &mut self.tile_mask;
        mask.clear();
        mask.resize(tiles, 0);
        for &(_, _, key) in sorting.iter() {
            start[(key >> 6) as usize + 1] += 1;
            mask[(key >> 6) as usize] |= 1 << (key & 63);
        }
        for k in 1..start.len() {
            start[k] += start[k - 1];
        }
        self.entries.clear();
        self.entries.resize(found.len(), (0.0, 0));
        self.local.clear();
        self.local.resize(found.len(), 0);
        // Each entry to the end of its tile's stretch, from the last: the stretch's start
        // moves down to where it began while the entries keep their order.
        for &(t0, i, key) in sorting.iter().rev() {
            let end = &mut start[(key >> 6) as usize + 1];
            *end -= 1;
            self.entries[*end as usize] = (t0, i);
            self.local[*end as usize] = (key & 63) as u8;
        }
        // start[tile + 1] now holds where the tile's entries begin: one place back.
        start.copy_within(1.., 0);
        start[tiles] = found.len() as u32;
        // A tile with no more entries than listed pixels (a crowd's tiles, whose rays meet
        // one sphere or none) has no pixel with two: nothing to sort.
        for tile in 0..tiles {
            let (a, b) = (start[tile] as usize, start[tile + 1] as usize);
            if b - a <= self.tile_mask[tile].count_ones() as usize {
                continue;
            }
            let mut run = a;
            while run < b {
                let end = run + self.local[run..b].iter().take_while(|&&l| l == self.local[run]).count();
                if end - run > 1 {
                    self.entries[run..end].sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                }
                run = end;
            }
        }
    }

    /// The list of pixel (x, y): (sphere entry t, instance), nearest first; empty outside the
    /// image.
    #[inline]
    pub fn at(&self, x: u32, y: u32) -> &[(f64, u32)] {
        if x >= self.width || y >= self.height {
            return &[];
        }
        let tile = (x as usize % TILE, y as usize % TILE);
        self.tile(x - tile.0 as u32, y - tile.1 as u32).at(tile.1 * TILE + tile.0)
    }

    /// The lists of the tile whose top-left pixel is (x0, y0) (multiples of the tile's side,
    /// [`super::beam::TILE`]): a tile's rays look their lists up by lane without finding the
    /// tile again for each.
    #[inline]
    pub fn tile(&self, x0: u32, y0: u32) -> TileLists<'_> {
        debug_assert!(x0 as usize % TILE == 0 && y0 as usize % TILE == 0, "({x0}, {y0}) starts no tile");
        let tile = (y0 as usize / TILE) * self.tiles_x as usize + x0 as usize / TILE;
        match (
            x0 < self.width && y0 < self.height,
            self.tile_mask.get(tile),
            self.tile_start.get(tile),
            self.tile_start.get(tile + 1),
        ) {
            (true, Some(&mask), Some(&a), Some(&b)) if mask != 0 => {
                let (a, b) = (a as usize, b as usize);
                TileLists {
                    mask,
                    one_each: b - a == mask.count_ones() as usize,
                    entries: self.entries.get(a..b).unwrap_or(&[]),
                    local: self.local.get(a..b).unwrap_or(&[]),
                }
            }
            _ => TileLists::EMPTY,
        }
    }

    /// Whether the rays of every pixel in x0..x1 × y0..y1 (clipped to the image) meet no
    /// sphere: each tile's mask, against the window's pixels in it.
    pub fn all_empty(&self, x0: u32, y0: u32, x1: u32, y1: u32) -> bool {
        let (x1, y1) = (x1.min(self.width) as usize, y1.min(self.height) as usize);
        let (x0, y0) = (x0 as usize, y0 as usize);
        if x0 >= x1 || y0 >= y1 {
            return true;
        }
        for ty in y0 / TILE..=(y1 - 1) / TILE {
            // The window's rows in this tile row, as bits of a tile's mask.
            let (r0, r1) = (y0.max(ty * TILE) - ty * TILE, y1.min((ty + 1) * TILE) - ty * TILE);
            let rows = (u64::MAX >> (64 - TILE * (r1 - r0))) << (TILE * r0);
            for tx in x0 / TILE..=(x1 - 1) / TILE {
                let (c0, c1) = (x0.max(tx * TILE) - tx * TILE, x1.min((tx + 1) * TILE) - tx * TILE);
                let columns = ((1u64 << (c1 - c0)) - 1) << c0;
                let window = rows & (columns * 0x0101_0101_0101_0101);
                if self.tile_mask.get(ty * self.tiles_x as usize + tx).is_some_and(|&m| m & window != 0) {
                    return false;
                }
            }
        }
        true
    }

    /// Whether these are the lists of `camera`'s pixels (a search through lists made for
    /// another camera would find other rays' spheres).
    pub fn is_for(&self, camera: &Camera) -> bool {
        self.camera.as_ref() == Some(camera)
    }

    /// Entries over all pixels (how many ray–sphere crossings the frame's rays have).
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether no pixel's ray meets any sphere.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
}

/// The mean area in pixels of the rectangles that bound where the instances' spheres (about
/// their occupied boxes at full depth, as [`super::instances::prepare`] bounds them) project
/// in `camera`'s image: how many pixel tests per instance sphere lists would make. None
/// without instances or with a camera that is not valid.
pub fn mean_instance_area(scene: &Scene, camera: &Camera) -> Option<f64> {
    camera.validate().ok()?;
    let n = scene.instances().len();
    if n == 0 {
        return None;
    }
    let basis = camera.basis();
    let grid = PixelGrid::new(camera, &basis);
    let boxes = super::instances::part_boxes(scene, u32::MAX);
    let total: u64 = scene
        .instances()
        .iter()
        .zip(scene.worlds())
        .filter_map(|(inst, w)| {
            let &super::instances::PartBox { centre, half, .. } = boxes.get(inst.part)?;
            let c = w.transform_point3(centre) - camera.eye;
            let r = super::instances::farthest_corner(&w.matrix3, half);
            (c.is_finite() && r.is_finite()).then(|| grid.near(&[c], r).area(camera))
        })
        .sum();
    Some(total as f64 / n as f64)
}

/// Whether two spheres are the same bits (NaN included).
#[inline]
fn same_bits(a: (DVec3, f64), b: (DVec3, f64)) -> bool {
    a.0.to_array().map(f64::to_bits) == b.0.to_array().map(f64::to_bits) && a.1.to_bits() == b.1.to_bits()
}

/// A radius that holds every ray [`sphere_interval`] lets through in f64: it accepts a ray
/// whose squared distance from the centre exceeds r² by its rounding, a few units of 2⁻⁵²
/// times the squared distance L² of the centre; 10⁻¹³ L² is far beyond that, and the
/// relative 10⁻⁹ covers the rectangle's own rounding.
fn padded(centre: DVec3, r: f64) -> f64 {
    // (r + a·L₁)² ≥ r² + a²L² with a² > 10⁻¹³ and the L¹ norm above L: no root per sphere.
    r * (1.0 + 1e-9) + 3.2e-7 * centre.abs().element_sum() + f64::MIN_POSITIVE
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn sphere(centre: DVec3, radius: f64) -> (DVec3, f64) {
        (centre, radius)
    }

    fn camera(w: u32, h: u32) -> Camera {
        let mut c = Camera::framing(glam::Vec3::splat(-10.0), glam::Vec3::splat(10.0), w, h);
        c.eye = DVec3::ZERO;
        c.target = DVec3::new(0.3, -0.2, 1.0);
        c
    }

    /// Every pixel's list against every sphere tested with every pixel's ray: the same
    /// instances, entries and order. Tiny far spheres (between pixel centres or on one), large
    /// ones, spheres behind the eye, beside the view, around the eye and at the rim.
    #[test]
    fn the_lists_are_every_sphere_each_pixel_ray_meets() {
        let cam = camera(37, 23);
        let basis = cam.basis();
        let mut rng = Rng::new(11);
        let mut spheres: Vec<(DVec3, f64)> = (0..3000)
            .map(|k| {
                let dir = DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() * 1.2 - 0.2);
                let dist = [0.5, 3.0, 40.0, 2000.0][k % 4] * (0.5 + rng.f64());
                let radius = dist * [1e-4, 3e-3, 0.02, 0.2][(k / 4) % 4] * rng.f64();
                sphere(dir.normalize_or_zero() * dist, radius)
            })
            .collect();
        // Exactly tangent-ish, the eye inside, non-finite.
        spheres.push(sphere(DVec3::new(0.0, 0.0, 0.5), 1.0));
        spheres.push(sphere(DVec3::new(f64::NAN, 0.0, 1.0), 1.0));
        spheres.push(sphere(DVec3::new(0.0, 0.0, -5.0), 1.0));
        let lists = PixelSpheres::build_within(None, &cam, &spheres, None, u64::MAX).expect("no limit");
        let mut crossings = 0;
        for y in 0..cam.height {
            for x in 0..cam.width {
                let d = basis.dir(cam.screen_x(&basis, x), cam.screen_y(&basis, y));
                let mut want: Vec<(f64, u32)> = spheres
                    .iter()
                    .enumerate()
                    .filter_map(|(i, &(c, r))| sphere_interval(c, r, DVec3::ZERO, d).map(|(t0, _)| (t0, i as u32)))
                    .collect();
                want.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                crossings += want.len();
                assert_eq!(lists.at(x, y), &want[..], "pixel ({x}, {y})");
            }
        }
        assert_eq!(lists.len(), crossings);
        assert!(crossings > 851 * 4, "the spheres should cross many rays ({crossings})");
        // Each tile's instances (what the trace asks memory for ahead): those its lanes list.
        for y0 in (0..cam.height).step_by(TILE) {
            for x0 in (0..cam.width).step_by(TILE) {
                let tile = lists.tile(x0, y0);
                let mut want: Vec<u32> = (0..64).flat_map(|k| tile.at(k).iter().map(|e| e.1)).collect();
                let mut got: Vec<u32> = tile.instances().collect();
                want.sort_unstable();
                got.sort_unstable();
                assert_eq!(got, want, "tile ({x0}, {y0})");
            }
        }
    }

    /// Lists rebuilt from last frame's equal lists built afresh: some spheres moved, some
    /// not, one turned NaN, then the camera turned, then an instance more.
    #[test]
    fn rebuilt_lists_equal_fresh_ones() {
        let cam = camera(41, 29);
        let mut rng = Rng::new(5);
        let mut spheres: Vec<(DVec3, f64)> = (0..4000)
            .map(|_| {
                let dir = DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, 1.0);
                (dir * (5.0 + 50.0 * rng.f64()), 0.02 + 0.3 * rng.f64())
            })
            .collect();
        let same = |a: &PixelSpheres, b: &PixelSpheres, what: &str| {
            assert_eq!(a.len(), b.len(), "{what}");
            for y in 0..29 {
                for x in 0..41 {
                    assert_eq!(a.at(x, y), b.at(x, y), "{what}: pixel ({x}, {y})");
                }
            }
        };
        let mut lists = PixelSpheres::build(&cam, &spheres);
        let mut cam = cam;
        for step in 0..4 {
            match step {
                0 => {
                    for (k, s) in spheres.iter_mut().enumerate() {
                        if k % 3 == 0 {
                            s.0.x += 0.4;
                        }
                    }
                    spheres[7].1 = f64::NAN;
                }
                1 => cam.target.x += 0.01,
                2 => spheres.push((DVec3::new(0.0, 0.0, 9.0), 1.0)),
                _ => {}
            }
            let rebuilt = PixelSpheres::rebuild(lists, &cam, &spheres).expect("within the limit");
            let fresh = PixelSpheres::build(&cam, &spheres).expect("within the limit");
            same(&rebuilt, &fresh, &format!("step {step}"));
            assert!(rebuilt.len() > 500, "step {step}: {} crossings", rebuilt.len());
            lists = Some(rebuilt);
        }
    }

    /// Lists rebuilt from the spheres listed as moved equal fresh ones: over steps where some
    /// listed spheres moved (onto the screen, off it, into NaN), some listed ones did not,
    /// the last step's moves were undone, none moved, the camera turned (then nothing is
    /// taken over), an instance past the end was listed, and the list was out of order.
    #[test]
    fn lists_rebuilt_from_the_moved_equal_fresh_ones() {
        let mut cam = camera(43, 27);
        let mut rng = Rng::new(9);
        let place = |rng: &mut Rng| {
            // In front, beside the view or behind the eye.
            let dir = DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, [1.0, 0.6, -1.0][rng.below(3) as usize]);
            (dir * (20.0 + 60.0 * rng.f64()), 0.1 + 0.7 * rng.f64())
        };
        // Enough for the moved to span several parallel chunks.
        let mut spheres: Vec<(DVec3, f64)> = (0..10_000).map(|_| place(&mut rng)).collect();
        let mut lists = Some(PixelSpheres::build(&cam, &spheres).expect("within the limit"));
        let (mut before, mut last_moved) = (spheres.clone(), Vec::new());
        for step in 0..7 {
            let mut moved: Vec<u32> = Vec::new();
            let now = spheres.clone();
            match step {
                2 => {
                    spheres = before.clone();
                    moved = last_moved.clone();
                }
                4 => cam.target.y += 0.02,
                5 => {}
                _ => {
                    for i in 0..spheres.len() {
                        match rng.below(10) {
                            0 => spheres[i] = place(&mut rng),
                            1 => spheres[i].0.x += 0.3,
                            // Listed, not moved.
                            2 => {}
                            _ => continue,
                        }
                        moved.push(i as u32);
                    }
                    spheres[3 * step + 1].1 = f64::NAN;
                    moved.push(3 * step as u32 + 1);
                    moved.sort_unstable();
                    moved.dedup();
                    match step {
                        // An instance past the end.
                        3 => moved.push(spheres.len() as u32 + 5),
                        // Out of order: rebuilt whole.
                        6 => moved.reverse(),
                        _ => {}
                    }
                }
            }
            (before, last_moved) = (now, moved.clone());
            let rebuilt = PixelSpheres::rebuild_moved(lists, &cam, &spheres, &moved).expect("within the limit");
            let fresh = PixelSpheres::build(&cam, &spheres).expect("within the limit");
            assert_eq!(rebuilt.len(), fresh.len(), "step {step}");
            for y in 0..cam.height {
                for x in 0..cam.width {
                    assert_eq!(rebuilt.at(x, y), fresh.at(x, y), "step {step}: pixel ({x}, {y})");
                }
            }
            assert!(rebuilt.len() > 300, "step {step}: {} crossings", rebuilt.len());
            lists = Some(rebuilt);
        }
    }

    /// Lists know their camera, and a pixel outside their image has none.
    #[test]
    fn lists_belong_to_their_camera() {
        let cam = camera(12, 8);
        let lists = PixelSpheres::build(&cam, &[(DVec3::new(0.3, -0.2, 1.0) * 10.0, 8.0)]).expect("within the limit");
        assert!(lists.is_for(&cam));
        assert!(!lists.is_for(&Camera { eye: cam.eye + DVec3::X, ..cam }));
        assert!(!lists.at(5, 4).is_empty(), "the sphere fills the view");
        assert!(lists.at(12, 0).is_empty() && lists.at(0, 8).is_empty() && lists.at(u32::MAX, u32::MAX).is_empty());
    }

    /// A window's emptiness against its pixels' lists one by one: windows of every size at
    /// every place over a few small spheres, some reaching past the image's edges.
    #[test]
    fn empty_windows_are_those_whose_every_list_is_empty() {
        let cam = camera(21, 13);
        let mut rng = Rng::new(3);
        let mut spheres: Vec<(DVec3, f64)> = (0..12)
            .map(|_| (DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, 1.0) * 30.0, 0.3 + 0.5 * rng.f64()))
            .collect();
        // On the left edge: a window past the right edge must not read the next row's lists.
        let basis = cam.basis();
        spheres.extend([2, 7, 12].map(|y| (cam.ray_dir(&basis, 0, y) * 30.0, 0.2)));
        let lists = PixelSpheres::build(&cam, &spheres).expect("within the limit");
        let (mut empty, mut not) = (0, 0);
        for (y0, y1) in (0..16).flat_map(|a| (a..16).map(move |b| (a, b))) {
            for (x0, x1) in (0..24).flat_map(|a| (a..24).map(move |b| (a, b))) {
                let want = (y0..y1).all(|y| (x0..x1).all(|x| lists.at(x, y).is_empty()));
                assert_eq!(lists.all_empty(x0, y0, x1, y1), want, "pixels {x0}..{x1} × {y0}..{y1}");
                if x0 < x1 && y0 < y1 && y0 < cam.height && x0 < cam.width {
                    if want {
                        empty += 1;
                    } else {
                        not += 1;
                    }
                }
            }
        }
        assert!(empty > 1000 && not > 1000, "{empty} empty windows, {not} others");
    }

    /// Spheres that would need more tests than the limit: no lists (the rays walk the BVH).
    #[test]
    fn deep_overlap_gives_up() {
        let cam = camera(16, 16);
        let big: Vec<(DVec3, f64)> =
            (0..MAX_PER_PIXEL + 1).map(|k| sphere(DVec3::new(0.0, 0.0, 5.0 + k as f64), 50.0)).collect();
        assert!(PixelSpheres::build(&cam, &big).is_none());
        assert!(PixelSpheres::build(&cam, &big[..MAX_PER_PIXEL as usize]).is_some());
        let mut bad = cam;
        bad.width = 0;
        assert!(PixelSpheres::build(&bad, &big[..1]).is_none());
    }
}
