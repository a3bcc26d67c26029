//! The per-pixel hit buffer: last frame's primary hit per pixel, reused only when that is
//! provably the same answer (DESIGN.md, "The hit buffer must be exact"):
//!
//! - the camera is bit-for-bit the same,
//! - the instance hit did not move (its world transform is bit-for-bit the same), and
//! - no moved instance's old or new bounding sphere crosses the ray before the hit (for a
//!   miss: anywhere on the ray).
//!
//! When only the last condition fails, the stored hit is still the nearest among the
//! instances that did not move, so the ray is searched among the moved instances alone
//! ([`super::visibility::nearest_moved`]) and the nearer of the two wins.
//!
//! A pixel whose record was kept also keeps its colour when every input of it is the same
//! ([`Reuse::shadow_valid`], [`HitBuffer::keep_shading`]), so rendering with the buffer gives
//! the same image as rendering without it. Per 8×8 tile, a mask of the instances its records
//! hit ([`HitBuffer::tiles`]) lets a tile far from every moving part keep all its records
//! without reading them ([`Reuse::tile_kept`]).

use super::beam::TILE;
use super::instances::{sphere_interval, Prepared};
use super::primary::Todo;
use crate::scene::camera::{PixelGrid, PixelRect};
use crate::scene::{Camera, Lights, Scene};
use crate::svo::Attr;
use glam::{DAffine3, DVec3, Vec3};

/// One pixel's primary hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HitRecord {
    /// Ray parameter along the unit camera ray; +∞ for a miss.
    pub t: f32,
    /// Instance hit; −1 for a miss.
    pub instance: i32,
    /// World-space unit normal, facing the camera.
    pub normal: Vec3,
    /// World-space normal of the voxel face entered (zero when the ray started inside).
    pub face_normal: Vec3,
    /// The voxel's attributes.
    pub attr: Attr,
    /// The voxel's edge length in world units (largest stretch), for shadow-ray offsets.
    pub voxel: f32,
}

impl HitRecord {
    /// A miss.
    pub const MISS: HitRecord = HitRecord {
        t: f32::INFINITY,
        instance: -1,
        normal: Vec3::ZERO,
        face_normal: Vec3::ZERO,
        attr: Attr { albedo: 0, normal: 0, emission: 0 },
        voxel: 0.0,
    };

    /// Makes this record [`Self::MISS`], field by field. (Assigned whole, the constant was
    /// first copied onto the stack and then from there into the record, at every missed
    /// pixel of a traced tile; docs/benchmarks.md, step 134.)
    #[inline(always)]
    pub fn set_miss(&mut self) {
        self.t = f32::INFINITY;
        self.instance = -1;
        self.normal = Vec3::ZERO;
        self.face_normal = Vec3::ZERO;
        self.attr = Attr { albedo: 0, normal: 0, emission: 0 };
        self.voxel = 0.0;
    }
}

/// Hit records of the previous frame and what they were computed under.
#[derive(Clone, Debug, Default)]
pub struct HitBuffer {
    /// The camera of the stored frame.
    pub camera: Option<Camera>,
    /// Instance world transforms of the stored frame.
    pub worlds: Vec<DAffine3>,
    /// Instance parts of the stored frame.
    pub parts: Vec<usize>,
    /// Bounding spheres (camera-relative centre, radius) of the stored frame.
    pub spheres: Vec<(DVec3, f64)>,
    /// One record per pixel, row 0 at the top (empty when the records stayed on the GPU:
    /// [`HitBuffer::store_kept_elsewhere`]).
    pub records: Vec<HitRecord>,
    /// Pixels of the stored frame (the records' count, wherever they are kept).
    pub pixels: usize,
    /// Pixels reused in the last frame rendered with this buffer.
    pub reused: u64,
    /// The level of detail the stored frame was traced at (a hit at another level is not
    /// this frame's hit).
    pub max_level: u32,
    /// The instance BVH of the stored frame, refitted by the next one
    /// ([`super::bvh::Bvh::refit_or_build`]).
    pub bvh: Option<super::bvh::Bvh>,
    /// Instance BVHs built from scratch for frames rendered with this buffer.
    pub bvh_builds: u64,
    /// The instances' spheres of the last [`HitBuffer::take_bvh`], kept for the next frame's
    /// (their memory, not their values: a crowd's were megabytes allocated every frame).
    bvh_spheres: Vec<(DVec3, f64)>,
    /// `prepared`'s spheres (camera-relative centre, radius), refilled alongside it.
    pub(crate) prepared_spheres: Vec<(DVec3, f64)>,
    /// The last frame's per-pixel sphere lists, which the next frame's take over where its
    /// camera and spheres are the same ([`super::pixel_spheres::PixelSpheres::rebuild`]).
    pub(crate) pixel_spheres: Option<super::pixel_spheres::PixelSpheres>,
    /// Each pixel's colour in the stored frame.
    pub radiance: Vec<Vec3>,
    /// Each pixel's ambient occlusion in the stored frame (empty without GI).
    pub ao: Vec<f32>,
    /// Per pixel of the stored colours, what blocked its sun shadow ray: an instance (the
    /// first in the instances' order; past the beams' limit, the first the instance BVH's
    /// walk reached), `cpu::SUN_FREE` or `cpu::SUN_UNKNOWN`. A kept record
    /// whose ray an instance that stayed put blocked keeps its colour; one that nothing
    /// blocked asks the moved instances alone.
    pub(crate) sun_blockers: Vec<u32>,
    /// The stored colours' ambient term came from GI's cones, not the flat sky.
    pub lit_by_gi: bool,
    /// The lights the stored colours were computed under.
    pub lights: Option<Lights>,
    /// Whether the stored colours traced shadow rays.
    pub shadows: bool,
    /// A frame handed back by [`HitBuffer::recycle`], whose buffers the next frame fills.
    pub spare: Option<super::cpu::Frame>,
    /// The parts' splat lists, for frames drawn with [`super::Renderer::Splat`].
    pub splats: super::splat::SplatCache,
    /// The last frame's prepared instances: the next frame refills those that changed
    /// ([`super::instances::prepare_changed`]).
    pub(crate) prepared: Vec<Prepared>,
    /// What `prepared` was made from.
    pub(crate) prepared_for: super::instances::PreparedFor,
    /// Per [`TILE`]×[`TILE`] tile of the stored records (row-major), what they hit
    /// ([`TileSummary`]). Empty when not known.
    pub tiles: Vec<TileSummary>,
    /// The last frame rendered with this buffer: when that very frame comes back unmodified
    /// ([`HitBuffer::recycle_as_rendered`]), the next frame writes only the pixels that
    /// changed.
    rendered: Option<Rendered>,
    /// The spare frame came back as it was rendered.
    spare_as_rendered: bool,
    /// Per tile of `records`, the records that the last frame's beams stored as misses, and
    /// the frame's size (see [`HitBuffer::take_records`]).
    records_missed: (Vec<u64>, u32, u32),
}

/// The last frame rendered with a buffer ([`HitBuffer::take_spare`]). Its beam misses are
/// the records' ([`HitBuffer::take_records`]): both come from the same frame.
#[derive(Clone, Debug)]
pub(crate) struct Rendered {
    /// The address of its radiance buffer (never read through): which frame it is.
    at: usize,
    /// The sky colour its misses show.
    pub sky: Vec3,
}

impl Rendered {
    /// `frame`, whose misses show `sky`.
    pub(crate) fn of(frame: &super::cpu::Frame, sky: Vec3) -> Rendered {
        Rendered { at: frame.radiance.as_ptr() as usize, sky }
    }
}

/// What the records of one tile hit, for decisions about the whole tile.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TileSummary {
    /// The instances hit, as [`instance_bit`]s: a tile whose mask holds no moved instance's
    /// bit has no record on a moved instance.
    pub instances: u64,
    /// The least t of a hit (+∞ for none).
    pub t_lo: f32,
    /// The greatest t of a hit (0 for none).
    pub t_hi: f32,
    /// The largest voxel edge of a hit (0 for none): how far its shadow ray starts from it.
    pub voxel: f32,
}

impl TileSummary {
    /// A tile of misses.
    pub const NONE: TileSummary = TileSummary { instances: 0, t_lo: f32::INFINITY, t_hi: 0.0, voxel: 0.0 };

    /// Whether the tile holds a hit (else its records are misses, which cast no shadow rays).
    #[inline]
    pub fn has_hits(&self) -> bool {
        self.t_lo <= self.t_hi
    }

    /// The summary with one more record.
    #[inline]
    pub fn with(self, r: &HitRecord) -> TileSummary {
        if r.instance < 0 {
            return self;
        }
        // Kept non-negative (+∞ for NaN, which then bounds nothing), so that the values
        // order as their bits do for atomic min and max.
        let clean = |v: f32| {
            if v > 0.0 {
                v
            } else if v.is_nan() {
                f32::INFINITY
            } else {
                0.0
            }
        };
        let (t, voxel) = (clean(r.t), clean(r.voxel));
        TileSummary {
            instances: self.instances | instance_bit(r.instance),
            t_lo: self.t_lo.min(t),
            t_hi: self.t_hi.max(t),
            voxel: self.voxel.max(voxel),
        }
    }
}

/// A record's instance as a bit of a [`TileSummary::instances`] mask (instance mod 64; none for a
/// miss).
#[inline]
pub fn instance_bit(instance: i32) -> u64 {
    if instance < 0 {
        0
    } else {
        1 << (instance as u32 % 64)
    }
}

/// What the current frame may reuse.
#[derive(Clone, Debug)]
pub struct Reuse {
    /// Per instance: moved since the stored frame.
    pub moved: Vec<bool>,
    /// Old and new spheres of every moved instance, with the pixel rectangle
    /// `[x0, y0, x1, y1]` (inclusive) outside which no pixel's ray can meet the sphere.
    pub moved_spheres: Vec<(DVec3, f64, [u32; 4])>,
    /// The moved instances, ascending (their spheres are `moved_spheres` 2k and 2k + 1).
    pub moved_instances: Vec<u32>,
    /// The moved instances' [`instance_bit`]s.
    pub moved_bits: u64,
    /// A BVH over `moved_spheres` (each box grown by a millionth of the sphere's size and
    /// distance), once there are [`MOVED_BVH_MIN`] of them: the shadow tests of kept pixels
    /// and tiles walk it instead of testing every moved sphere.
    pub moved_bvh: Option<super::bvh::Bvh>,
    /// With the BVH, per tile of the image ([`TILE`]-pixel tiles, row-major, `tiles_x` to a
    /// row), the moved spheres whose pixel rectangles reach it, ascending: see
    /// [`Reuse::tile_bins`] for the layout (the GPU reads it as it is).
    tile_bins: Vec<u32>,
    tiles_x: usize,
}

/// From this many moved spheres on, [`Reuse`] keeps a BVH over them: a crowd of 300 driving
/// cars (4 800 spheres) tested every sphere against every kept pixel's shadow ray, 0.89 s a
/// frame at 1280×768 against 0.23 s without the hit buffer.
pub const MOVED_BVH_MIN: usize = 32;

/// Above this many moved instances, a pixel that a moved sphere crosses is searched among
/// every instance (through the culling or the BVH) rather than among the moved ones in turn.
pub const MOVED_SEARCH_MAX: usize = 64;

/// A conservative pixel rectangle of a sphere: the projection of the corners of its bounding
/// box along the camera's axes (a convex set in front of the camera projects inside their
/// hull), one pixel wider on every side. A box reaching behind the image plane covers the
/// whole image.
pub fn screen_rect(camera: &Camera, centre: DVec3, radius: f64) -> [u32; 4] {
    ScreenRects::new(camera).rect(centre, radius)
}

/// [`screen_rect`] for many spheres under one camera: its basis (a tangent and three
/// normalisations) formed once, not per sphere (a crowd's hit buffer rectangles 158 000 moved
/// spheres a frame).
#[derive(Clone, Copy, Debug)]
pub struct ScreenRects {
    camera: Camera,
    basis: crate::scene::camera::Basis,
}

impl ScreenRects {
    /// The rectangles of `camera`'s image.
    pub fn new(camera: &Camera) -> ScreenRects {
        ScreenRects { camera: *camera, basis: camera.basis() }
    }

    /// [`screen_rect`] of the sphere at `centre` (camera-relative) with `radius`.
    pub fn rect(&self, centre: DVec3, radius: f64) -> [u32; 4] {
        let (camera, b) = (&self.camera, &self.basis);
        let (w, h) = (camera.width as f64, camera.height as f64);
        let full = [0, 0, camera.width - 1, camera.height - 1];
        // The box around the sphere along the camera's own axes (the basis is orthonormal):
        // x/z over it is least and greatest at its corners, and which corner is known from
        // the signs, so two quotients per side replace projecting eight corners.
        let (x, y, z) = (centre.dot(b.right), centre.dot(b.up), centre.dot(b.forward));
        let (near, far) = (z - radius, z + radius);
        if !(near > 1e-9 * (centre.length() + 2.0 * radius)) {
            return full;
        }
        let least = |v: f64| (v / near).min(v / far);
        let most = |v: f64| (v / near).max(v / far);
        let (kx, ky) = (b.tan_half * w / h, b.tan_half);
        // Inverse of the camera's pixel-centre mapping: sx = 2(px + 0.5)/W − 1, sy = 1 − 2(py + 0.5)/H.
        let x0 = (least(x - radius) / kx + 1.0) * 0.5 * w - 0.5;
        let x1 = (most(x + radius) / kx + 1.0) * 0.5 * w - 0.5;
        let y0 = (1.0 - most(y + radius) / ky) * 0.5 * h - 0.5;
        let y1 = (1.0 - least(y - radius) / ky) * 0.5 * h - 0.5;
        if !(x0.is_finite() && y0.is_finite() && x1.is_finite() && y1.is_finite()) {
            return full;
        }
        let clamp = |v: f64, hi: u32| v.clamp(0.0, hi as f64) as u32;
        if x1 < -1.0 || y1 < -1.0 || x0 > w || y0 > h {
            return [1, 1, 0, 0]; // off screen: an empty rectangle
        }
        [
            clamp(x0.floor() - 1.0, camera.width - 1),
            clamp(y0.floor() - 1.0, camera.height - 1),
            clamp(x1.ceil() + 1.0, camera.width - 1),
            clamp(y1.ceil() + 1.0, camera.height - 1),
        ]
    }
}

impl HitBuffer {
    /// An empty buffer.
    pub fn new() -> Self {
        Self::default()
    }

    /// This frame's instance BVH: the stored frame's refitted, or a new one (counted in
    /// [`HitBuffer::bvh_builds`]). Store it back with `self.bvh = Some(..)` after the frame.
    pub fn take_bvh(&mut self, prepared: &[Prepared]) -> super::bvh::Bvh {
        let mut spheres = std::mem::take(&mut self.bvh_spheres);
        spheres.clear();
        spheres.extend(prepared.iter().map(|p| (p.centre, p.radius)));
        let bvh = self.take_bvh_of(&spheres);
        self.bvh_spheres = spheres;
        bvh
    }

    /// [`HitBuffer::take_bvh`] for the instances' spheres (camera-relative centre, radius),
    /// in instance order.
    pub fn take_bvh_of(&mut self, spheres: &[(DVec3, f64)]) -> super::bvh::Bvh {
        let bvh = super::bvh::Bvh::refit_or_build(self.bvh.take(), spheres);
        if bvh.refits == 0 {
            self.bvh_builds += 1;
        }
        bvh
    }

    /// [`HitBuffer::take_bvh_of`] knowing which instances changed since the kept tree was last
    /// fitted (None: any may have): [`super::bvh::Bvh::refit_changed_or_build`], which fills
    /// `dirty` with the nodes recomputed; returns the tree and whether all of it is new.
    /// Without `wide`, the tree has no wide tree (for a tree walked only elsewhere).
    pub fn take_bvh_changed(
        &mut self,
        spheres: &[(DVec3, f64)],
        changed: Option<&[u32]>,
        dirty: &mut Vec<u32>,
        wide: bool,
    ) -> (super::bvh::Bvh, bool) {
        let (bvh, whole) = super::bvh::Bvh::refit_changed_or_build(self.bvh.take(), spheres, changed, dirty, wide);
        if bvh.refits == 0 {
            self.bvh_builds += 1;
        }
        (bvh, whole)
    }

    /// Hands a frame the caller is done with back to the renderer: the next frame of the same
    /// size is written into its buffers instead of fresh memory.
    pub fn recycle(&mut self, frame: super::cpu::Frame) {
        self.spare = Some(frame);
        self.spare_as_rendered = false;
    }

    /// [`HitBuffer::recycle`] for a frame that nobody could have changed since the renderer
    /// returned it (a session's own last frame): if it is the frame of the stored colours,
    /// the next frame leaves the pixels that keep their colour as they are.
    pub(crate) fn recycle_as_rendered(&mut self, frame: super::cpu::Frame) {
        self.spare = Some(frame);
        self.spare_as_rendered = true;
    }

    /// Takes the spare frame and, when it is the last frame rendered, unchanged, what it
    /// holds. (With kept colours, that frame is the one they were stored from.)
    pub(crate) fn take_spare(&mut self) -> (Option<super::cpu::Frame>, Option<Rendered>) {
        let spare = self.spare.take();
        let rendered = self.rendered.take();
        let as_rendered = std::mem::take(&mut self.spare_as_rendered)
            && spare.as_ref().zip(rendered.as_ref()).is_some_and(|(f, r)| r.at == f.radiance.as_ptr() as usize);
        (spare, rendered.filter(|_| as_rendered))
    }

    /// Takes the records for a `width` × `height` frame to update in place (MISS records when
    /// they are not that size), with per tile the ones known to be misses stored by the last
    /// frame's beams (empty when not known).
    pub(crate) fn take_records(&mut self, width: u32, height: u32) -> (Vec<HitRecord>, Vec<u64>) {
        let mut records = std::mem::take(&mut self.records);
        let (missed, w, h) = std::mem::take(&mut self.records_missed);
        let n = width as usize * height as usize;
        if records.len() != n {
            records.clear();
            records.resize(n, HitRecord::MISS);
        }
        (records, if (w, h) == (width, height) { missed } else { Vec::new() })
    }

    /// Notes which of the records the frame's beams stored as misses (per tile, for a
    /// `width` × `height` frame), after the records are put back.
    pub(crate) fn records_missed(&mut self, missed: Vec<u64>, width: u32, height: u32) {
        self.records_missed = (missed, width, height);
    }

    /// Remembers the last frame rendered (see [`HitBuffer::take_spare`]).
    pub(crate) fn rendered(&mut self, frame: Rendered) {
        self.rendered = Some(frame);
    }

    /// Whether the stored frame was seen by exactly this camera.
    pub fn same_camera(&self, camera: &Camera) -> bool {
        self.camera.as_ref() == Some(camera) && self.pixels == (camera.width * camera.height) as usize
    }

    /// The reuse conditions for the current frame traced at `max_level`, or None if nothing
    /// can be reused (other camera, other instances, other level of detail).
    pub fn reuse(&self, camera: &Camera, scene: &Scene, prepared: &[Prepared], max_level: u32) -> Option<Reuse> {
        let instances = scene.instances();
        let same_parts =
            self.parts.len() == instances.len() && self.parts.iter().zip(instances).all(|(&p, i)| p == i.part);
        if !self.same_camera(camera) || !same_parts || self.max_level != max_level {
            return None;
        }
        let mut moved = vec![false; instances.len()];
        let mut moved_spheres = Vec::new();
        let mut moved_instances = Vec::new();
        let rects = ScreenRects::new(camera);
        for (i, w) in scene.worlds().iter().enumerate() {
            if *w != self.worlds[i] {
                moved[i] = true;
                moved_instances.push(i as u32);
                for (c, r) in [self.spheres[i], (prepared[i].centre, prepared[i].radius)] {
                    moved_spheres.push((c, r, rects.rect(c, r)));
                }
            }
        }
        Some(Reuse::new(moved, moved_spheres, moved_instances).with_tiles(camera.width, camera.height))
    }

    /// Keeps a frame's colours, its ambient occlusion (GI) and what they were lit by, so that
    /// the next frame under the same lights can keep them ([`Reuse::shadow_valid`]).
    pub fn keep_shading(&mut self, lights: &Lights, shadows: bool, radiance: &[Vec3], ao: &[f32]) {
        self.lights = Some(lights.clone());
        self.shadows = shadows;
        self.radiance.clear();
        self.radiance.extend_from_slice(radiance);
        self.ao.clear();
        self.ao.extend_from_slice(ao);
    }

    /// [`HitBuffer::keep_shading`] for a frame whose kept colours came from this buffer (under
    /// the same lights and shadow switch): only the pixels shaded afresh (`shaded`, per tile
    /// as in [`super::primary::Traced::stored`]) are copied.
    pub fn keep_shading_changed(&mut self, radiance: &[Vec3], ao: &[f32], width: usize, shaded: &[u64]) {
        let tiles_x = width.div_ceil(TILE as usize);
        for (t, &mask) in shaded.iter().enumerate() {
            for k in super::tile_search::each(mask) {
                let (x, y) = (
                    (t % tiles_x) * TILE as usize + k % TILE as usize,
                    (t / tiles_x) * TILE as usize + k / TILE as usize,
                );
                let i = y * width + x;
                if let (Some(dst), Some(src)) = (self.radiance.get_mut(i), radiance.get(i)) {
                    *dst = *src;
                }
            }
        }
        self.ao.clear();
        self.ao.extend_from_slice(ao);
    }

    /// Stores a frame's records and conditions.
    pub fn store(
        &mut self,
        camera: &Camera,
        scene: &Scene,
        prepared: &[Prepared],
        records: Vec<HitRecord>,
        max_level: u32,
    ) {
        self.store_kept_elsewhere(camera, scene, prepared, max_level);
        self.records = records;
    }

    /// Stores a frame's conditions whose records are kept elsewhere (in the GPU's hit
    /// buffer, not read back): the next frame's [`HitBuffer::reuse`] needs only these.
    pub fn store_kept_elsewhere(&mut self, camera: &Camera, scene: &Scene, prepared: &[Prepared], max_level: u32) {
        self.camera = Some(*camera);
        self.pixels = (camera.width * camera.height) as usize;
        self.records.clear();
        self.records_missed = Default::default();
        self.tiles.clear();
        self.rendered = None;
        self.max_level = max_level;
        // Refilled in place: with tens of thousands of instances, fresh vectors every frame
        // cost more in page faults than the copies themselves.
        self.worlds.clear();
        self.worlds.extend_from_slice(scene.worlds());
        self.parts.clear();
        self.parts.extend(scene.instances().iter().map(|i| i.part));
        self.spheres.clear();
        self.spheres.extend(prepared.iter().map(|p| (p.centre, p.radius)));
    }
}

impl Reuse {
    /// A reuse of these moved instances and spheres, with its BVH when there are many.
    pub fn new(moved: Vec<bool>, moved_spheres: Vec<(DVec3, f64, [u32; 4])>, moved_instances: Vec<u32>) -> Reuse {
        let moved_bits = moved_instances.iter().fold(0, |m, &i| m | instance_bit(i as i32));
        let moved_bvh = (moved_spheres.len() >= MOVED_BVH_MIN).then(|| {
            let grown: Vec<(DVec3, f64)> =
                moved_spheres.iter().map(|&(c, r, _)| (c, r + 1e-6 * (r + c.length()))).collect();
            // Walked only by `any_item` (and on the GPU as its own copy): no wide tree, whose
            // collapse was a tenth of building a crowd's 158 000-sphere tree every frame.
            super::bvh::Bvh::build_sorted(&grown, false)
        });
        Reuse { moved, moved_spheres, moved_instances, moved_bits, moved_bvh, tile_bins: Vec::new(), tiles_x: 0 }
    }

    /// Sorts the moved spheres into the tiles of a `width` × `height` image once there are
    /// [`MOVED_BVH_MIN`] of them, for [`Reuse::spheres_in`] (which otherwise tests every
    /// sphere's rectangle for every tile: a third of a 300-car frame).
    pub fn with_tiles(mut self, width: u32, height: u32) -> Reuse {
        if self.moved_spheres.len() < MOVED_BVH_MIN || width == 0 || height == 0 {
            return self;
        }
        let (tx, ty) = (width.div_ceil(TILE) as usize, height.div_ceil(TILE) as usize);
        // The tile ranges each sphere's rectangle covers (None: wholly off the image).
        let ranges = |&(_, _, [x0, y0, x1, y1]): &(DVec3, f64, [u32; 4])| {
            let (a, c) = ((x0 / TILE) as usize, ((x1 / TILE) as usize).min(tx - 1));
            let (b, d) = ((y0 / TILE) as usize, ((y1 / TILE) as usize).min(ty - 1));
            (a <= c && b <= d).then_some((a, b, c, d))
        };
        // Two passes, counting then filling, so that the bins are one flat array.
        let mut bins = vec![0u32; tx * ty + 1];
        for (a, b, c, d) in self.moved_spheres.iter().filter_map(ranges) {
            for row in b..=d {
                for n in &mut bins[row * tx + a..=row * tx + c] {
                    *n += 1;
                }
            }
        }
        let mut start = bins.len() as u32;
        for n in &mut bins {
            (*n, start) = (start, start + *n);
        }
        bins.resize(start as usize, 0);
        let mut fill: Vec<u32> = bins[..tx * ty].to_vec();
        for (k, (a, b, c, d)) in self.moved_spheres.iter().map(ranges).enumerate().filter_map(|(k, r)| Some((k, r?))) {
            for row in b..=d {
                for f in &mut fill[row * tx + a..=row * tx + c] {
                    bins[*f as usize] = k as u32;
                    *f += 1;
                }
            }
        }
        self.tile_bins = bins;
        self.tiles_x = tx;
        self
    }

    /// The tiles' bins, when [`Reuse::with_tiles`] made them: tiles to a row, and one array
    /// whose first `tiles + 1` entries are offsets into the array itself (tile t's spheres
    /// are the entries `bins[bins[t]..bins[t + 1]]`, indices into `moved_spheres`, ascending).
    pub fn tile_bins(&self) -> Option<(usize, &[u32])> {
        (!self.tile_bins.is_empty()).then_some((self.tiles_x, &self.tile_bins))
    }

    /// Tile `tile`'s bin, if there are bins and it is a tile of the image.
    fn bin(&self, tile: usize) -> Option<&[u32]> {
        // The first offset is the number of tiles plus one.
        let tiles = (*self.tile_bins.first()? as usize).checked_sub(1)?;
        if tile >= tiles {
            return None;
        }
        self.tile_bins.get(self.tile_bins[tile] as usize..self.tile_bins[tile + 1] as usize)
    }

    /// Whether `sphere(k)` holds for some moved sphere k that `node(lo, hi)` does not rule
    /// out: through the BVH when there is one (a box ruled out holds no such sphere), else
    /// sphere by sphere.
    fn any_moved(&self, node: impl Fn(DVec3, DVec3) -> bool, sphere: impl Fn(usize) -> bool) -> bool {
        let every = || (0..self.moved_spheres.len()).any(&sphere);
        match &self.moved_bvh {
            Some(bvh) => bvh.any_item(usize::MAX, node, |k| sphere(k as usize)).unwrap_or_else(every),
            None => every(),
        }
    }

    /// The moved instances that a [`Todo::Moved`] pixel searches: all of them, or none when
    /// there are more than [`MOVED_SEARCH_MAX`] (such pixels then search every instance).
    pub fn moved_search(&self) -> &[u32] {
        if self.moved_instances.len() <= MOVED_SEARCH_MAX {
            &self.moved_instances
        } else {
            &[]
        }
    }

    /// The moved spheres whose pixel rectangles meet pixels `x0..x1` × `y0..y1`.
    pub fn spheres_in(&self, [x0, y0, x1, y1]: [u32; 4]) -> Vec<u32> {
        let reaches = |&k: &u32| {
            let [a, b, c, d] = self.moved_spheres[k as usize].2;
            a < x1 && c >= x0 && b < y1 && d >= y0
        };
        // Within one tile, its bin holds every sphere that can reach the rectangle.
        let tile = (x0 / TILE) as usize + (y0 / TILE) as usize * self.tiles_x;
        let one_tile = x1 > x0
            && y1 > y0
            && (x1 - 1) / TILE == x0 / TILE
            && (y1 - 1) / TILE == y0 / TILE
            && ((x0 / TILE) as usize) < self.tiles_x;
        match self.bin(tile).filter(|_| one_tile) {
            Some(bin) => bin.iter().copied().filter(reaches).collect(),
            None => (0..self.moved_spheres.len() as u32).filter(reaches).collect(),
        }
    }

    /// Whether every pixel of a tile keeps its stored hit ([`Todo::Keep`]) without looking at
    /// its records: no moved sphere reaches it (`spheres`, [`Reuse::spheres_in`]) and its
    /// records' mask (`tile`, [`HitBuffer::tiles`]) holds no moved instance.
    #[inline]
    pub fn tile_kept(&self, tile: &TileSummary, spheres: &[u32]) -> bool {
        spheres.is_empty() && tile.instances & self.moved_bits == 0
    }

    /// Whether every kept record of a tile passes [`Reuse::shadow_valid`] towards `to_sun`
    /// without being looked at: the tile's hits (`tile`, on the rays `rays` of its pixels)
    /// and the points their shadow rays start from lie in one ball (and in a capsule within
    /// it), and the shadow rays from there cannot meet any moved sphere. Conservative:
    /// margins far above the rounding of [`sphere_interval`] keep a sphere that any of those
    /// rays could meet.
    pub fn tile_shadows_valid(&self, tile: &TileSummary, rays: &super::beam::TileRays, to_sun: DVec3) -> bool {
        match ShadowBall::of(tile, rays) {
            ShadowBall::NoRays => true,
            ShadowBall::Unknown => false,
            ShadowBall::Around(ball) => !self.any_moved(
                |lo, hi| !ball.clears_box(lo, hi, to_sun),
                |k| {
                    let (c, r, _) = self.moved_spheres[k];
                    !ball.clears(c, r, to_sun)
                },
            ),
        }
    }

    /// Per moved sphere, the pixels whose kept record's shadow ray towards the sun (`to_sun`,
    /// unit) may meet it, when every kept record's shadow ray starts within `reach` of the eye
    /// ([`shadow_reach`]). A ray from `o` along `to_sun` meets the sphere (c, r) only where
    /// `o` lies in the sphere or in the half-infinite cylinder of radius r behind it (away
    /// from the sun); within `reach` of the eye that cylinder ends `c·to_sun + reach` behind
    /// c. So `o` lies in the capsule around that segment, and the pixel's ray passes within
    /// r of it ([`PixelGrid::near`]; r and the segment padded a millionth, far above the
    /// rounding of [`sphere_interval`] and of the projection). A tile none of whose pixels
    /// any of these holds keeps every stored shadow ray's answer without a test.
    pub fn shadow_rects(&self, grid: &PixelGrid, to_sun: DVec3, reach: f64) -> Vec<PixelRect> {
        self.moved_spheres
            .iter()
            .map(|&(c, r, _)| {
                let pad = 1e-6 * (r + c.length() + reach);
                let behind = (c.dot(to_sun) + reach).max(0.0) * (1.0 + 1e-6) + pad;
                grid.near(&[c, c - to_sun * behind], r * (1.0 + 1e-6) + pad)
            })
            .collect()
    }

    /// The moved spheres that a kept record's shadow ray from a tile may still meet, as a
    /// mask over [`Reuse::moved_spheres`] (bit k: sphere k): those that the ball of
    /// [`Reuse::tile_shadows_valid`] does not clear. Zero when that test passes the tile;
    /// with more than 64 moved spheres, zero when it does and None otherwise. A pixel of
    /// the tile asks [`Reuse::shadow_valid_among`] about these spheres alone, and gets
    /// [`Reuse::shadow_valid`]'s answer: a sphere the ball clears meets none of its rays.
    pub fn tile_shadow_suspects(&self, tile: &TileSummary, rays: &super::beam::TileRays, to_sun: DVec3) -> Option<u64> {
        let n = self.moved_spheres.len();
        if n > 64 {
            return self.tile_shadows_valid(tile, rays, to_sun).then_some(0);
        }
        let every = if n == 64 { u64::MAX } else { (1u64 << n) - 1 };
        let ball = match ShadowBall::of(tile, rays) {
            ShadowBall::NoRays => return Some(0),
            ShadowBall::Unknown => return Some(every),
            ShadowBall::Around(ball) => ball,
        };
        let suspect = |k: usize| {
            let (c, r, _) = self.moved_spheres[k];
            !ball.clears(c, r, to_sun)
        };
        let walked = self.moved_bvh.as_ref().and_then(|bvh| {
            let found = std::cell::Cell::new(0u64);
            // (Never true: the walk goes on to every sphere its boxes let through.)
            let all = bvh.any_item(
                usize::MAX,
                |lo, hi| !ball.clears_box(lo, hi, to_sun),
                |k| {
                    if suspect(k as usize) {
                        found.set(found.get() | 1 << k);
                    }
                    false
                },
            );
            all.map(|_| found.get())
        });
        // Without the tree, or past its walk's limits, sphere by sphere.
        Some(walked.unwrap_or_else(|| (0..n).filter(|&k| suspect(k)).fold(0, |m, k| m | 1 << k)))
    }

    /// What a pixel with stored record `r` needs this frame, where `entry` is the nearest
    /// entry of its ray into the moved spheres that may reach it ([`Reuse::tile_entries`]).
    #[inline]
    pub fn todo(&self, r: &HitRecord, entry: f64) -> Todo {
        if r.instance >= 0 && self.moved[r.instance as usize] {
            return Todo::Again { instance: r.instance as u32, t: r.t };
        }
        // An entry of +∞: no moved sphere meets the ray (a stored miss's t is +∞ too).
        let crossed = entry < f64::INFINITY && entry <= r.t as f64;
        match (crossed, self.moved_search().is_empty()) {
            (false, _) => Todo::Keep,
            (true, true) => Todo::All,
            (true, false) => Todo::Moved { t: r.t, instance: r.instance },
        }
    }

    /// Per lane `k` of the 8×8 tile whose top left pixel is (x0, y0) (pixel
    /// (x0 + k % 8, y0 + k / 8), its ray from the eye along `dirs[k]`), the least entry t
    /// into the moved spheres of `spheres` ([`Reuse::spheres_in`] of the tile) whose pixel
    /// rectangle holds the pixel and that the ray meets, +∞ where none: [`sphere_interval`]'s
    /// operations in its order, so the same t. [`Reuse::todo`] compares it with the stored
    /// hit. Formed for the whole tile at once, in vectors (four lanes in AVX2 where the CPU
    /// has it): asked pixel by pixel, a mostly kept frame's test took a tenth of its primary
    /// rays' time (docs/benchmarks.md, step 143).
    ///
    /// # Panics
    /// When `dirs` holds fewer than 64 directions.
    pub fn tile_entries(&self, spheres: &[u32], x0: u32, y0: u32, dirs: &[DVec3]) -> [f64; 64] {
        let mut d = [[0.0; 64]; 3];
        for (k, v) in dirs[..64].iter().enumerate() {
            (d[0][k], d[1][k], d[2][k]) = (v.x, v.y, v.z);
        }
        let mut out = [f64::INFINITY; 64];
        let axis =
            |lo: u32, hi: u32, at: u32| (0..8).filter(|&i| at + i >= lo && at + i <= hi).fold(0u64, |m, i| m | 1 << i);
        for &k in spheres {
            let (c, radius, [rx0, ry0, rx1, ry1]) = self.moved_spheres[k as usize];
            // The lanes inside the sphere's rectangle: its columns in every row it holds.
            let (columns, rows) = (axis(rx0, rx1, x0), axis(ry0, ry1, y0));
            let inside = (0..8).filter(|&r| rows & 1 << r != 0).fold(0u64, |m, r| m | columns << (8 * r));
            if inside != 0 {
                #[cfg(target_arch = "x86_64")]
                if super::ray_setup::avx2() {
                    // SAFETY: the CPU has AVX and AVX2 (checked above).
                    unsafe { nearest_entries_avx2(c, radius, inside, &d, &mut out) };
                    continue;
                }
                nearest_entries(c, radius, inside, &d, &mut out);
            }
        }
        out
    }

    /// Of the lanes `lanes` of a tile, those whose shadow ray, from (`from[0][k]`,
    /// `from[1][k]`, `from[2][k]`) towards the sun along unit `to_sun`, meets one of the
    /// moved spheres of the mask `suspects` ([`Reuse::tile_shadow_suspects`]), as
    /// [`sphere_interval`] answers it: its operations in its order
    /// (`tile_search::entering`, with no box and no end), so the same answers as
    /// [`Reuse::shadow_valid_among`] gives lane by lane. All 64 lanes at once, in vectors:
    /// lane by lane, this test of a mostly kept frame's kept shadows took about 4 % of its
    /// time (docs/benchmarks.md, step 144).
    pub fn tile_shadows_met(&self, suspects: u64, lanes: u64, from: &[[f64; 64]; 3], to_sun: DVec3) -> u64 {
        let mut met = 0u64;
        for k in super::tile_search::each(suspects) {
            let Some(&(c, radius, _)) = self.moved_spheres.get(k) else { continue };
            let ray = super::tile_search::Entry {
                dir: to_sun,
                inv: to_sun.recip(),
                cells: None,
                ball: (c, radius),
                t_max: f64::INFINITY,
            };
            met |= super::tile_search::entering(from, &ray);
        }
        met & lanes
    }

    /// Whether the shadow ray of record `r` (the same record as the stored frame's, under the
    /// same lights) still finds what it found: from where [`super::cpu`] starts it towards
    /// the sun it crosses no moved instance's old or new sphere, so every instance that could
    /// block it is where it was.
    #[inline]
    pub fn shadow_valid(
        &self,
        r: &HitRecord,
        lights: &Lights,
        camera: &Camera,
        basis: &crate::scene::camera::Basis,
        x: u32,
        y: u32,
    ) -> bool {
        self.shadow_valid_among(r, lights, || camera.ray_dir(basis, x, y), None)
    }

    /// [`Reuse::shadow_valid`] for a record of a tile whose
    /// [`Reuse::tile_shadow_suspects`] are `suspects`: the shadow ray is tested against
    /// those spheres alone (None: against every moved sphere). `dir` gives the unit direction
    /// of the pixel's ray from the eye ([`Camera::ray_dir`]), asked for only when the record
    /// casts a shadow ray.
    #[inline]
    pub fn shadow_valid_among(
        &self,
        r: &HitRecord,
        lights: &Lights,
        dir: impl Fn() -> DVec3,
        suspects: Option<u64>,
    ) -> bool {
        if suspects == Some(0) {
            return true;
        }
        let sun = lights.sun.filter(|s| r.instance >= 0 && r.normal.dot(s.to_sun) > 0.0);
        let Some(to_sun) = sun.map(|s| s.to_sun.as_dvec3()) else {
            // No shadow ray: the colour depends on the record and the lights alone.
            return true;
        };
        // Where super::cpu starts the shadow ray.
        let from = super::cpu::leave(r, dir() * r.t as f64);
        let meets = |k: usize| {
            let (c, rad, _) = self.moved_spheres[k];
            sphere_interval(c, rad, from, to_sun).is_some()
        };
        match suspects {
            Some(m) => !super::tile_search::each(m).any(meets),
            None => {
                // The slab test rounds by a few units in 2⁻⁵² of the distances it spans: boxes
                // grow by far more, relative to this ray's origin too.
                let (inv, slack) = (to_sun.recip(), DVec3::splat(1e-9 * from.length()));
                !self.any_moved(
                    |lo, hi| super::bvh::box_entry(lo - slack, hi + slack, from, inv, f64::INFINITY).is_some(),
                    meets,
                )
            }
        }
    }
}

/// How far from the eye the shadow rays of the records that `tiles` summarize may start: a
/// hit at t along its unit ray, its shadow ray at most 1.1 voxels from it (`cpu::leave`: a
/// unit normal and a tenth of a unit face normal), grown a millionth. None when a summary
/// holds a t that is not finite.
pub fn shadow_reach(tiles: &[TileSummary]) -> Option<f64> {
    let far = tiles.iter().filter(|t| t.has_hits()).map(|t| t.t_hi as f64 + 1.1 * t.voxel as f64).fold(0.0, f64::max);
    far.is_finite().then_some(far * (1.0 + 1e-6))
}

/// Whether one of `rects` holds a pixel of the rectangle `[x0, y0, x1, y1]` (inclusive).
pub fn rects_meet(rects: &[PixelRect], [x0, y0, x1, y1]: [u32; 4]) -> bool {
    rects.iter().any(|r| match *r {
        PixelRect::Empty => false,
        PixelRect::Unbounded => true,
        PixelRect::Pixels { x0: a, y0: b, x1: c, y1: d } => a <= x1 && x0 <= c && b <= y1 && y0 <= d,
    })
}

/// Where the shadow rays of a tile's kept records start, for the tile tests of [`Reuse`].
enum ShadowBall {
    /// The tile holds misses only: no shadow rays.
    NoRays,
    /// The tile's rays have no axis: nothing is known.
    Unknown,
    /// Every start lies in this ball.
    Around(Ball),
}

/// A ball holding the starts of a tile's shadow rays, and within it a capsule that holds
/// them too: the points within `reach` of the segment `near`–`far` (the tile's rays' axis
/// between its nearest and farthest hit). Where a tile's hits spread far in depth (an edge
/// with the ground behind it) the capsule is much the thinner.
struct Ball {
    mid: DVec3,
    radius: f64,
    near: DVec3,
    far: DVec3,
    reach: f64,
}

impl ShadowBall {
    /// The ball of a tile's hits (`tile`, on the rays `rays` of its pixels).
    fn of(tile: &TileSummary, rays: &super::beam::TileRays) -> ShadowBall {
        if !tile.has_hits() {
            return ShadowBall::NoRays;
        }
        let (lo, hi) = (tile.t_lo as f64, tile.t_hi as f64);
        let axis = rays.corners.iter().copied().sum::<DVec3>().normalize_or_zero();
        if axis == DVec3::ZERO {
            return ShadowBall::Unknown;
        }
        // A pixel's hit is d·t with d inside the corners' spherical quadrilateral (no farther
        // from the axis than its farthest corner) and t in [lo, hi]; its shadow ray starts at
        // most 1.1 voxels from there (cpu::leave: a unit normal and a tenth of a unit face
        // normal).
        // Such a hit lies within hi·spread of the point at the same t on the axis.
        let spread = rays.corners.iter().map(|d| (*d - axis).length()).fold(0.0, f64::max);
        let mid = axis * (0.5 * (lo + hi));
        let grow = |r: f64| r * (1.0 + 1e-6) + 1e-9 * hi;
        let radius = grow(hi * spread + 0.5 * (hi - lo) + 1.1 * tile.voxel as f64);
        let reach = grow(hi * spread + 1.1 * tile.voxel as f64);
        ShadowBall::Around(Ball { mid, radius, near: axis * lo, far: axis * hi, reach })
    }
}

impl Ball {
    /// Whether every shadow ray towards `to_sun` from the ball passes wide of the sphere
    /// (`c`, `r`), or the sphere lies wholly behind where each of them starts, with margins
    /// far above the rounding of [`sphere_interval`].
    fn clears(&self, c: DVec3, r: f64, to_sun: DVec3) -> bool {
        let margin = self.margin(c, r);
        self.clears_by(c, r, to_sun, margin) || self.capsule_clears(c, r, to_sun, margin)
    }

    /// The margin of [`Ball::clears`] for the sphere (`c`, `r`).
    fn margin(&self, c: DVec3, r: f64) -> f64 {
        (r + self.radius) * 1e-6 + 1e-7 * ((c - self.mid).length() + self.radius)
    }

    /// The test of [`Ball::clears`] for the capsule: seen along `to_sun`, the sphere's disc
    /// lies wide of the capsule's (a segment's, within `reach`), or the sphere lies wholly
    /// behind the capsule's lowest point along `to_sun`. Worked out from the ball's centre,
    /// so that `margin` (the ball's) bounds its rounding too.
    fn capsule_clears(&self, c: DVec3, r: f64, to_sun: DVec3, margin: f64) -> bool {
        let flat = |p: DVec3| p - to_sun * p.dot(to_sun);
        let (near, far, c) = (self.near - self.mid, self.far - self.mid, c - self.mid);
        let (a, ab, pc) = (flat(near), flat(far) - flat(near), flat(c));
        let len2 = ab.length_squared();
        // The capsule's point nearest the sphere's centre, seen along `to_sun`.
        let along = if len2 > 0.0 { ((pc - a).dot(ab) / len2).clamp(0.0, 1.0) } else { 0.0 };
        let across = (pc - (a + ab * along)).length();
        let lowest = near.dot(to_sun).min(far.dot(to_sun)) - self.reach;
        across > r + self.reach + margin || c.dot(to_sun) + r + margin < lowest
    }

    /// Whether [`Ball::clears`] holds for every sphere inside the box `lo..hi`.
    fn clears_box(&self, lo: DVec3, hi: DVec3, to_sun: DVec3) -> bool {
        // A sphere inside the box's ball (centre b, radius rb) lies within rb − r of b, so
        // it is clear if that ball is, with the margin of the largest sphere it can hold.
        let (b, rb) = ((lo + hi) * 0.5, (hi - lo).length() * 0.5);
        let margin = (rb + self.radius) * 1e-6 + 1e-7 * ((b - self.mid).length() + self.radius);
        self.clears_by(b, rb, to_sun, margin + 1e-7 * rb)
    }

    /// The test of [`Ball::clears`] with the margin given.
    fn clears_by(&self, c: DVec3, r: f64, to_sun: DVec3, margin: f64) -> bool {
        let oc = c - self.mid;
        let along = oc.dot(to_sun);
        let across = (oc - to_sun * along).length();
        across > r + self.radius + margin || along + r + self.radius + margin < 0.0
    }
}

/// [`Reuse::tile_entries`] for one sphere (centre `c`, `radius`) and the lanes of `inside`:
/// lowers `out[k]` to the ray's entry t where the ray along (`d[0][k]`, `d[1][k]`, `d[2][k]`)
/// meets the sphere ahead of the eye, as [`sphere_interval`] answers it from the eye.
/// Branch-free over the 64 lanes, so that it compiles to vectors.
#[inline(always)]
fn nearest_entries(c: DVec3, radius: f64, inside: u64, d: &[[f64; 64]; 3], out: &mut [f64; 64]) {
    // `sphere_interval`'s c from the origin: the centre's squared length less r².
    let cc = c.length_squared() - radius * radius;
    for k in 0..64 {
        let b = c.x * d[0][k] + c.y * d[1][k] + c.z * d[2][k];
        let disc = b * b - cc;
        let s = disc.sqrt();
        let (t0, t1) = (b - s, b + s);
        let meets = (inside >> k) & 1 != 0 && disc >= 0.0 && t1 >= 0.0 && t0 < out[k];
        out[k] = if meets { t0 } else { out[k] };
    }
}

/// [`nearest_entries`] compiled for AVX2.
///
/// # Safety
/// The CPU has AVX and AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx,avx2")]
unsafe fn nearest_entries_avx2(c: DVec3, radius: f64, inside: u64, d: &[[f64; 64]; 3], out: &mut [f64; 64]) {
    nearest_entries(c, radius, inside, d, out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use crate::scene::lights::Sun;

    /// The pixels `Reuse::shadow_rects` gives each moved sphere hold every pixel whose shadow
    /// ray (from its hit, moved off it as `cpu::leave` moves it, within the reach) meets the
    /// sphere: spheres placed so that such a ray from a random pixel's hit just grazes them,
    /// from inside or just outside, in front of its start or behind it, for cameras and suns
    /// of every direction. Most rectangles are bounded, and they leave pixels out.
    #[test]
    fn shadow_rects_hold_every_pixel_whose_shadow_ray_meets_a_sphere() {
        let mut rng = Rng::new(71);
        let (mut met, mut bounded, mut left_out) = (0, 0, 0);
        let unit = |rng: &mut Rng| {
            let v = DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5);
            if v.length() > 0.01 {
                v.normalize()
            } else {
                DVec3::Y
            }
        };
        for round in 0..4000 {
            let camera = Camera {
                eye: DVec3::ZERO,
                target: unit(&mut rng),
                up: unit(&mut rng),
                vfov_deg: 20.0 + rng.f64() * 100.0,
                width: 16 + rng.below(300) as u32,
                height: 16 + rng.below(300) as u32,
            };
            let Ok(()) = camera.validate() else { continue };
            let basis = camera.basis();
            let (x, y) = (rng.below(camera.width as u64) as u32, rng.below(camera.height as u64) as u32);
            let d = camera.ray_dir(&basis, x, y);
            // The pixel's hit and its shadow ray's start, 1.1 voxels off it at most.
            let (t, voxel) = (0.5 + rng.f64() * 30.0, rng.f64() * 0.2);
            let o = d * t + unit(&mut rng) * voxel + unit(&mut rng) * (0.1 * voxel);
            let to_sun = unit(&mut rng);
            // A sphere the ray from o towards the sun grazes, its surface within a billionth
            // of the ray (inside or out), somewhere from just behind o to far ahead.
            let r = 0.05 + rng.f64() * 3.0;
            let side = unit(&mut rng).reject_from(to_sun).normalize_or_zero();
            let graze = r * (1.0 + (rng.f64() - 0.5) * 2e-9);
            let c = o + to_sun * ((rng.f64() * 1.2 - 0.2) * 40.0) + side * graze;
            let spheres = vec![(c, r, [0; 4]), (unit(&mut rng) * 20.0, 1.0, [0; 4])];
            let reuse = Reuse::new(vec![true], spheres, vec![0]);
            let reach = (t + 1.1 * voxel) * (1.0 + 1e-6);
            let rects = reuse.shadow_rects(&PixelGrid::new(&camera, &basis), to_sun, reach);
            if sphere_interval(c, r, o, to_sun).is_some() {
                met += 1;
                assert!(rects_meet(&rects[..1], [x, y, x, y]), "round {round}: {:?} leaves out ({x}, {y})", rects[0]);
            }
            bounded += matches!(rects[0], PixelRect::Pixels { .. }) as usize;
            let PixelRect::Pixels { x0, y0, x1, y1 } = rects[0] else { continue };
            left_out += ((x1 - x0 + 1) * (y1 - y0 + 1) < camera.width * camera.height) as usize;
        }
        assert!(met > 1000, "{met} rays meet their sphere");
        assert!(bounded > 1500 && left_out > 1000, "{bounded} bounded rectangles, {left_out} leave pixels out");
    }

    /// A record made a miss in place is `MISS` bit for bit, whatever it held before.
    #[test]
    fn a_record_made_a_miss_is_the_miss() {
        let bits = |r: &HitRecord| {
            let v = |v: Vec3| v.to_array().map(f32::to_bits);
            (r.t.to_bits(), r.instance, v(r.normal), v(r.face_normal), r.attr, r.voxel.to_bits())
        };
        let mut rng = Rng::new(3);
        for _ in 0..100 {
            let mut f = || rng.f64() as f32 * 2.0 - 1.0;
            let mut r = HitRecord {
                t: f() + 2.0,
                instance: 5,
                normal: Vec3::new(f(), f(), f()),
                face_normal: Vec3::new(f(), f(), f()),
                attr: Attr { albedo: 0x00AB_CDEF, normal: 0x1234_5678, emission: 9 },
                voxel: f() + 2.0,
            };
            r.set_miss();
            assert_eq!(bits(&r), bits(&HitRecord::MISS));
        }
    }

    /// Whenever a tile's shadow rays are taken as valid at once, every kept record of the
    /// tile passes its own test: random tiles, hits and moved spheres, many of the spheres
    /// placed to graze the hits' shadow rays.
    #[test]
    fn a_tile_passed_whole_passes_pixel_by_pixel() {
        let mut rng = Rng::new(7);
        let camera = Camera {
            eye: DVec3::new(3.0, 2.0, 9.0),
            target: DVec3::ZERO,
            up: DVec3::Y,
            vfov_deg: 50.0,
            width: 96,
            height: 64,
        };
        let basis = camera.basis();
        let (mut whole, mut blocked, mut grazing, mut by_capsule) = (0, 0, 0, 0);
        for _ in 0..3000 {
            let to_sun = rng.unit_vector();
            let lights = Lights { sun: Some(Sun { to_sun, irradiance: Vec3::ONE }), ..Lights::default() };
            let (x0, y0) = (rng.below(12) as u32 * TILE, rng.below(8) as u32 * TILE);
            let t_base = rng.range(2.0, 20.0);
            // Voxels from far below to far above the tile's spread in t and across; in half
            // the tiles the hits spread far in depth (an edge with the ground behind it).
            let t_spread = if rng.below(2) == 0 { rng.range(0.0, 0.1) } else { rng.range(0.1, 0.9) };
            let voxel_max = [0.01, 0.3, 2.0][rng.below(3) as usize];
            let records: Vec<(u32, u32, HitRecord)> = (0..TILE * TILE)
                .map(|k| {
                    let (x, y) = (x0 + k % TILE, y0 + k / TILE);
                    let n = rng.unit_vector();
                    let r = HitRecord {
                        t: t_base * (1.0 + rng.range(-t_spread, t_spread)),
                        instance: 0,
                        // Facing the sun, so every record has a shadow ray.
                        normal: if n.dot(to_sun) > 0.0 { n } else { -n },
                        face_normal: rng.unit_vector(),
                        attr: Attr { albedo: 0, normal: 0, emission: 0 },
                        voxel: rng.range(0.0, voxel_max),
                    };
                    (x, y, r)
                })
                .collect();
            let tile = records.iter().fold(TileSummary::NONE, |s, (_, _, r)| s.with(r));
            // A sphere near one record's shadow ray, just off it or just across it.
            let (x, y, r) = records[rng.below(records.len() as u64) as usize];
            let from = super::super::cpu::leave(&r, camera.ray_dir(&basis, x, y) * r.t as f64);
            let radius = rng.range(0.01, 1.0) as f64;
            let side = rng.unit_vector().as_dvec3().cross(to_sun.as_dvec3()).normalize_or_zero();
            let off = radius * rng.range(0.5, 6.0) as f64;
            let centre = from + to_sun.as_dvec3() * rng.range(-2.0, 8.0) as f64 + side * off;
            let reuse = Reuse::new(vec![false], vec![(centre, radius, [0, 0, 0, 0])], vec![1]);
            let rays = super::super::beam::TileRays::new(&camera, &basis, x0, y0, x0 + TILE, y0 + TILE);
            let each_valid = records.iter().all(|(x, y, r)| reuse.shadow_valid(r, &lights, &camera, &basis, *x, *y));
            let suspects = reuse.tile_shadow_suspects(&tile, &rays, to_sun.as_dvec3());
            let each_among = records
                .iter()
                .all(|(x, y, r)| reuse.shadow_valid_among(r, &lights, || camera.ray_dir(&basis, *x, *y), suspects));
            assert_eq!(each_among, each_valid, "a record tested against its tile's suspects alone");
            if reuse.tile_shadows_valid(&tile, &rays, to_sun.as_dvec3()) {
                assert_eq!(suspects, Some(0));
                whole += 1;
                assert!(each_valid, "a tile passed whole has a record whose shadow ray meets a moved sphere");
                // Passed by the capsule where the ball alone would not have passed it.
                if let ShadowBall::Around(ball) = ShadowBall::of(&tile, &rays) {
                    let s = to_sun.as_dvec3();
                    by_capsule += !ball.clears_by(centre, radius, s, ball.margin(centre, radius)) as u32;
                }
            } else if !each_valid {
                blocked += 1;
            }
            grazing += (off < radius * 1.5) as u32;
        }
        assert!(whole > 300 && blocked > 300 && grazing > 100, "{whole} tiles passed whole, {blocked} blocked");
        assert!(by_capsule > 50, "{by_capsule} tiles passed by the capsule alone");
    }

    /// The tiles' bins give every tile, and any rectangle within one, the spheres that
    /// testing every sphere's rectangle gives: rectangles anywhere on and off the image.
    #[test]
    fn tile_bins_list_what_every_rectangle_lists() {
        let mut rng = Rng::new(5);
        let (w, h) = (100u32, 61u32);
        let spheres: Vec<(DVec3, f64, [u32; 4])> = (0..300)
            .map(|_| {
                // Some reach past the image's edges, some lie wholly beyond them.
                let (x0, y0) = (rng.below(w as u64 + 30) as u32, rng.below(h as u64 + 30) as u32);
                let (x1, y1) = (x0 + rng.below(40) as u32, y0 + rng.below(40) as u32);
                (DVec3::ZERO, 1.0, [x0, y0, x1, y1])
            })
            .collect();
        let binned = Reuse::new(vec![false], spheres, vec![1]).with_tiles(w, h);
        assert!(!binned.tile_bins.is_empty());
        let plain = Reuse { tile_bins: Vec::new(), ..binned.clone() };
        let mut rects: Vec<[u32; 4]> = Vec::new();
        for y0 in (0..h).step_by(TILE as usize) {
            for x0 in (0..w).step_by(TILE as usize) {
                rects.push([x0, y0, (x0 + TILE).min(w), (y0 + TILE).min(h)]);
            }
        }
        for _ in 0..500 {
            let (x0, y0) = (rng.below(w as u64 + 20) as u32, rng.below(h as u64 + 20) as u32);
            rects.push([x0, y0, x0 + 1 + rng.below(20) as u32, y0 + 1 + rng.below(20) as u32]);
        }
        for r in rects {
            assert_eq!(binned.spheres_in(r), plain.spheres_in(r), "{r:?}");
        }
    }

    /// A tile's kept shadows tested against its suspects for all 64 lanes at once answer lane
    /// by lane as `sphere_interval` does (and so as `Reuse::shadow_valid_among`): rays from
    /// scattered starts, spheres ahead of them, behind them and around them, many grazed to
    /// within a few roundings of their surface.
    #[test]
    fn tile_shadows_met_answers_as_each_lanes_sphere_test() {
        let mut rng = Rng::new(29);
        let (mut met, mut missed, mut behind) = (0, 0, 0);
        for round in 0..1000 {
            // (Unit in f64, so that the spheres placed along it graze its rays.)
            let to_sun = rng.unit_vector().as_dvec3().normalize();
            let mut from = [[0.0; 64]; 3];
            let starts: Vec<DVec3> = (0..64)
                .map(|k| {
                    let o = rng.unit_vector().as_dvec3() * rng.range(0.0, 5.0) as f64;
                    (from[0][k], from[1][k], from[2][k]) = (o.x, o.y, o.z);
                    o
                })
                .collect();
            let spheres: Vec<(DVec3, f64, [u32; 4])> = (0..2 + rng.below(11))
                .map(|_| {
                    // Grazing a lane's ray (from inside or out), ahead of its start or behind it.
                    let o = starts[rng.below(64) as usize];
                    let radius = rng.range(0.01, 3.0) as f64;
                    let side = rng.unit_vector().as_dvec3().reject_from(to_sun).normalize_or_zero();
                    let graze = radius * (1.0 + (rng.f64() - 0.5) * 10f64.powi(-(rng.below(16) as i32)));
                    let along = rng.range(-2.0 * radius as f32 - 1.0, 10.0) as f64;
                    (o + to_sun * along + side * graze, radius, [0; 4])
                })
                .collect();
            let n = spheres.len() as u32;
            let reuse = Reuse::new(vec![false], spheres.clone(), vec![1]);
            let suspects = (0..n).filter(|_| rng.below(4) != 0).fold(0u64, |m, k| m | 1 << k);
            let lanes = rng.below(u64::MAX);
            let got = reuse.tile_shadows_met(suspects, lanes, &from, to_sun);
            for (k, o) in starts.iter().enumerate() {
                let meets = |i: usize| sphere_interval(spheres[i].0, spheres[i].1, *o, to_sun);
                let want = lanes & 1 << k != 0 && super::super::tile_search::each(suspects).any(|i| meets(i).is_some());
                assert_eq!(got & 1 << k != 0, want, "round {round}, lane {k}");
                let any_line = (0..n as usize).any(|i| {
                    let oc = spheres[i].0 - *o;
                    oc.length_squared() - oc.dot(to_sun).powi(2) <= spheres[i].1 * spheres[i].1
                });
                match (want, any_line) {
                    (true, _) => met += 1,
                    (false, true) => behind += 1,
                    (false, false) => missed += 1,
                }
            }
        }
        assert!(met > 2000 && missed > 2000 && behind > 200, "{met} met, {missed} missed, {behind} behind");
    }

    /// A tile's nearest sphere entries, formed for its 64 lanes at once, are pixel by pixel
    /// the least entry t of `sphere_interval` (the same bits) among the spheres whose
    /// rectangle holds the pixel, and a stored hit or miss is kept or traced as the test of
    /// each sphere would have it: spheres around, behind and holding the eye, grazed by the
    /// tile's rays, their rectangles cutting across it.
    #[test]
    fn tile_entries_are_each_pixels_nearest_sphere_entry() {
        let mut rng = Rng::new(23);
        let camera = Camera {
            eye: DVec3::new(1.0, 2.0, 9.0),
            target: DVec3::ZERO,
            up: DVec3::Y,
            vfov_deg: 50.0,
            width: 80,
            height: 48,
        };
        let basis = camera.basis();
        let (mut met, mut missed) = (0, 0);
        for round in 0..300 {
            let (x0, y0) = (rng.below(10) as u32 * TILE, rng.below(6) as u32 * TILE);
            let dirs: Vec<DVec3> = (0..64).map(|k| camera.ray_dir(&basis, x0 + k % TILE, y0 + k / TILE)).collect();
            let spheres: Vec<(DVec3, f64, [u32; 4])> = (0..1 + rng.below(5))
                .map(|_| {
                    // Centred on a lane's ray (some grazed by it), or around the eye.
                    let d = dirs[rng.below(64) as usize];
                    let radius = rng.range(0.01, 2.0) as f64;
                    let off = rng.unit_vector().as_dvec3() * radius * rng.range(0.0, 1.2) as f64;
                    let c = if round % 7 == 0 { off } else { d * rng.range(-3.0, 15.0) as f64 + off };
                    let (a, b) = (x0 + rng.below(12) as u32, y0 + rng.below(12) as u32);
                    let rect = [a.saturating_sub(6), b.saturating_sub(6), a, b];
                    (c, radius, rect)
                })
                .collect();
            let n = spheres.len() as u32;
            let reuse = Reuse::new(vec![false], spheres.clone(), vec![1]);
            let listed: Vec<u32> = (0..n).filter(|_| rng.below(5) != 0).collect();
            let entries = reuse.tile_entries(&listed, x0, y0, &dirs);
            for (k, d) in dirs.iter().enumerate() {
                let (x, y) = (x0 + k as u32 % TILE, y0 + k as u32 / TILE);
                let want = listed
                    .iter()
                    .map(|&i| spheres[i as usize])
                    .filter(|&(_, _, [a, b, c, e])| x >= a && x <= c && y >= b && y <= e)
                    .filter_map(|(c, r, _)| sphere_interval(c, r, DVec3::ZERO, *d).map(|(t0, _)| t0))
                    .fold(f64::INFINITY, f64::min);
                assert_eq!(entries[k].to_bits(), want.to_bits(), "round {round}, lane {k}");
                // What the pixel needs, for stored hits before, at and past the entry and for
                // a stored miss: traced where a listed sphere holding the pixel is entered no
                // later than the stored hit.
                for t in [want as f32 * 0.999, want as f32, want as f32 * 1.001, f32::INFINITY] {
                    let rec = HitRecord { t, instance: 0, ..HitRecord::MISS };
                    let crossed = listed.iter().map(|&i| spheres[i as usize]).any(|(c, r, [a, b, cx, e])| {
                        x >= a && x <= cx && y >= b && y <= e && {
                            sphere_interval(c, r, DVec3::ZERO, *d).is_some_and(|(t0, _)| t0 <= t as f64)
                        }
                    });
                    let todo = if crossed { Todo::Moved { t, instance: 0 } } else { Todo::Keep };
                    assert_eq!(reuse.todo(&rec, entries[k]), todo, "round {round}, lane {k}, stored t {t}");
                }
                if want.is_finite() {
                    met += 1;
                } else {
                    missed += 1;
                }
            }
        }
        assert!(met > 2000 && missed > 2000, "{met} lanes met a sphere, {missed} none");
    }

    /// With many moved spheres the shadow tests walk a BVH over them: pixel by pixel and
    /// tile by tile they answer as testing every sphere does, over crowds of spheres of
    /// every size scattered around random tiles' hits, many grazing their shadow rays.
    #[test]
    fn the_moved_spheres_bvh_answers_as_every_sphere() {
        let mut rng = Rng::new(11);
        let camera = Camera {
            eye: DVec3::new(-4.0, 3.0, 12.0),
            target: DVec3::ZERO,
            up: DVec3::Y,
            vfov_deg: 60.0,
            width: 96,
            height: 64,
        };
        let basis = camera.basis();
        let (mut valid, mut invalid, mut tiles_whole, mut tiles_not, mut partial) = (0, 0, 0, 0, 0);
        for round in 0..400 {
            let to_sun = rng.unit_vector();
            let lights = Lights { sun: Some(Sun { to_sun, irradiance: Vec3::ONE }), ..Lights::default() };
            let (x0, y0) = (rng.below(12) as u32 * TILE, rng.below(8) as u32 * TILE);
            let t = rng.range(3.0, 25.0);
            // Every other round the far spheres are small, so that whole tiles pass too.
            let far_size = if round % 2 == 0 { 1.0 } else { 0.02 };
            let records: Vec<(u32, u32, HitRecord)> = (0..TILE * TILE)
                .map(|k| {
                    let n = rng.unit_vector();
                    let r = HitRecord {
                        t: t * (1.0 + rng.range(-0.05, 0.05)),
                        instance: 0,
                        normal: if n.dot(to_sun) > 0.0 { n } else { -n },
                        face_normal: rng.unit_vector(),
                        attr: Attr { albedo: 0, normal: 0, emission: 0 },
                        voxel: rng.range(0.0, 0.2),
                    };
                    (x0 + k % TILE, y0 + k / TILE, r)
                })
                .collect();
            // Spheres near the shadow rays of some records (just off them or across them),
            // and others anywhere.
            let count = MOVED_BVH_MIN + rng.below(100) as usize;
            let near = if round % 4 == 1 { 0 } else { rng.below(24) };
            let spheres: Vec<(DVec3, f64, [u32; 4])> = (0..count)
                .map(|_| {
                    let radius = [0.005, 0.1, 1.0, 4.0][rng.below(4) as usize] * rng.range(0.5, 1.0) as f64;
                    let far = rng.below(24) >= near;
                    let radius = if far { radius * far_size } else { radius };
                    let centre = if far {
                        rng.unit_vector().as_dvec3() * rng.range(0.0, 60.0) as f64
                    } else {
                        let (x, y, r) = records[rng.below(records.len() as u64) as usize];
                        let from = super::super::cpu::leave(&r, camera.ray_dir(&basis, x, y) * r.t as f64);
                        let side = rng.unit_vector().as_dvec3().cross(to_sun.as_dvec3()).normalize_or_zero();
                        from + to_sun.as_dvec3() * rng.range(-3.0, 30.0) as f64
                            + side * radius * rng.range(0.9, 1.1) as f64
                    };
                    (centre, radius, [0, 0, 0, 0])
                })
                .collect();
            let with = Reuse::new(vec![false], spheres, vec![1]);
            assert!(with.moved_bvh.is_some());
            let without = Reuse { moved_bvh: None, ..with.clone() };
            for (x, y, r) in &records {
                let a = with.shadow_valid(r, &lights, &camera, &basis, *x, *y);
                assert_eq!(a, without.shadow_valid(r, &lights, &camera, &basis, *x, *y), "pixel {x},{y}");
                if a {
                    valid += 1;
                } else {
                    invalid += 1;
                }
            }
            let tile = records.iter().fold(TileSummary::NONE, |s, (_, _, r)| s.with(r));
            let rays = super::super::beam::TileRays::new(&camera, &basis, x0, y0, x0 + TILE, y0 + TILE);
            let whole = with.tile_shadows_valid(&tile, &rays, to_sun.as_dvec3());
            assert_eq!(whole, without.tile_shadows_valid(&tile, &rays, to_sun.as_dvec3()));
            // The tile's suspects, walked through the BVH or sphere by sphere, are the same,
            // and each record tested against them alone answers as against every sphere.
            let suspects = with.tile_shadow_suspects(&tile, &rays, to_sun.as_dvec3());
            assert_eq!(suspects, without.tile_shadow_suspects(&tile, &rays, to_sun.as_dvec3()));
            assert_eq!(suspects == Some(0), whole);
            match suspects {
                Some(m) => {
                    partial += (m != 0 && (m.count_ones() as usize) < count) as usize;
                    for (x, y, r) in &records {
                        assert_eq!(
                            with.shadow_valid_among(r, &lights, || camera.ray_dir(&basis, *x, *y), Some(m)),
                            with.shadow_valid(r, &lights, &camera, &basis, *x, *y),
                            "pixel {x},{y}"
                        );
                    }
                }
                None => assert!(count > 64 && !whole),
            }
            if whole {
                tiles_whole += 1;
            } else {
                tiles_not += 1;
            }
        }
        assert!(valid > 400 && invalid > 400, "{valid} valid, {invalid} invalid pixels");
        assert!(tiles_whole > 20 && tiles_not > 20, "{tiles_whole} tiles whole, {tiles_not} not");
        assert!(partial > 20, "{partial} tiles suspect some moved spheres but not all");
    }
}
