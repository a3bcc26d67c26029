//! The CPU renderer, in two passes like the GPU's: **trace** finds each pixel's primary hit
//! (or reuses it from the hit buffer), **shade** lights it with the sun (with a shadow ray),
//! the sky and MTL emitters (glowing, and as area lights sampled with shadow rays). Rays start at the camera in camera-relative f64 coordinates.

use super::beam::{TileRays, TILE};
use super::brdf;
use super::bvh::Bvh;
use super::emitters::{emitter_light, EmitterShadows, EmitterTable, ShadowCone};
use super::hitbuffer::{HitBuffer, HitRecord, Rendered, TileSummary};
use super::instances::{prepare_changed, prepare_into, Prepared, ToUnit};
use super::pixel_spheres::PixelSpheres;
use super::plan::FramePlan;
use super::primary::{trace_tiles, Primary, Todo};
use super::visibility::{occluded, FrameInstances, InstanceHit};
use crate::scene::camera::{PixelGrid, PixelRect};
use crate::scene::{Camera, CameraError, Lights, Scene};
use crate::traverse::packet::LANES;
use crate::traverse::TraceOptions;
use glam::{DVec3, Vec3};
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};

/// How a frame finds what each pixel sees.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Renderer {
    /// Primary rays traced through the octrees (exact).
    #[default]
    Trace,
    /// Square splats of the surface voxels with a depth buffer ([`super::splat`]; on the GPU
    /// `wgsl/splat.wgsl`).
    Splat,
}

/// How the GPU draws square splats ([`Renderer::Splat`]); the CPU has one way.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SplatDraw {
    /// Compute passes: one thread per splat writes its square with atomics (nearest depth,
    /// then the lowest splat number at that depth).
    #[default]
    Compute,
    /// The rasterizer: one instanced quad per splat, a depth test keeping the nearest (the
    /// earlier splat at equal depth, as the compute passes), then a copy into their buffers.
    Quads,
}

/// Renderer settings that are not part of the frame plan.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderOptions {
    /// Level-of-detail limit (levels below the root); `u32::MAX` for full detail.
    pub max_level: u32,
    /// Ray tracing or splatting for primary visibility (shading is the same).
    pub renderer: Renderer,
    /// Splats: the square-size factor ([`super::splat::DEFAULT_FACTOR`]).
    pub splat_factor: f32,
    /// Splats on the GPU: compute passes or the rasterizer (the same winners; the CPU
    /// ignores it).
    pub splat_draw: SplatDraw,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            max_level: u32::MAX,
            renderer: Renderer::Trace,
            splat_factor: super::splat::DEFAULT_FACTOR,
            splat_draw: SplatDraw::Compute,
        }
    }
}

/// A rendered image with its AOVs (row 0 at the top).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Frame {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Linear radiance per pixel.
    pub radiance: Vec<Vec3>,
    /// Ray parameter along the unit-length camera ray; +∞ for a miss.
    pub t: Vec<f32>,
    /// Instance index hit; −1 for a miss.
    pub instance: Vec<i32>,
    /// World-space unit normal facing the camera; zero for a miss.
    pub normal: Vec<Vec3>,
    /// Linear albedo of the surface hit; zero for a miss.
    pub albedo: Vec<Vec3>,
    /// Specular reflectance of the surface hit (0: diffuse only, and for a miss).
    pub specular: Vec<f32>,
    /// Phong exponent of the surface hit ([`super::brdf`]).
    pub shininess: Vec<f32>,
    /// Ambient occlusion from GI's diffuse cones: the cosine-weighted fraction of them that
    /// left without meeting anything (1 for a miss); empty without GI's cones.
    pub ao: Vec<f32>,
    /// Primary rays (one per pixel).
    pub primary_rays: u64,
    /// Points where GI's diffuse cones were gathered (fewer than the pixels shaded with
    /// [`super::Gather::Half`] or the radiance caches); the GPU counts them only when its
    /// counting is on (`gpu::GpuRenderer::set_counting`), else 0.
    pub gathers: u64,
    /// Where the radiance caches' time went, when GI gathered with them (CPU).
    pub cache_stages: Option<super::radiance_cache::CacheStages>,
    /// Pixels whose primary hit came from the hit buffer (no ray traced).
    pub reused: u64,
    /// Shadow rays traced.
    pub shadow_rays: u64,
    /// Pixels whose colour came from the hit buffer (nothing about them changed).
    pub shade_reused: u64,
    /// Primary rays searched among the moved instances only: their stored hit, on an
    /// instance that did not move, bounds the search ([`super::visibility::nearest_moved`]).
    pub moved_only: u64,
    /// Instance octrees traversed by the traced (not reused) primary rays.
    pub instances_traced: u64,
    /// Instances skipped because the traced primary rays missed their bounding spheres.
    pub spheres_culled: u64,
    /// The image and AOVs stayed on the GPU (`GpuRenderer::set_read_back(false)`): the
    /// per-pixel vectors are empty, and of the counters only `primary_rays` is set.
    pub on_device: bool,
}

impl Frame {
    /// A `width × height` frame whose per-pixel buffers are `spare`'s when they have that
    /// many pixels (the renderer overwrites every pixel), fresh otherwise; counters zero.
    /// Reusing a frame spares the page faults of ~50 bytes a pixel of new memory each frame.
    pub fn buffers(spare: Option<Frame>, width: u32, height: u32) -> Frame {
        let n = width as usize * height as usize;
        let f = spare
            .filter(|f| {
                [f.radiance.len(), f.normal.len(), f.albedo.len()].iter().all(|&l| l == n)
                    && [f.t.len(), f.instance.len(), f.specular.len(), f.shininess.len()].iter().all(|&l| l == n)
            })
            .unwrap_or_else(|| Frame {
                radiance: vec![Vec3::ZERO; n],
                t: vec![0.0; n],
                instance: vec![0; n],
                normal: vec![Vec3::ZERO; n],
                albedo: vec![Vec3::ZERO; n],
                specular: vec![0.0; n],
                shininess: vec![0.0; n],
                ..Frame::default()
            });
        Frame {
            width,
            height,
            radiance: f.radiance,
            t: f.t,
            instance: f.instance,
            normal: f.normal,
            albedo: f.albedo,
            specular: f.specular,
            shininess: f.shininess,
            ..Frame::default()
        }
    }

    /// Fraction of pixels whose primary hit is at t = 0: the eye sits inside a voxel, which
    /// every ray then hits at once (a uniform image). Worth a warning above about a half.
    pub fn eye_inside_fraction(&self) -> f32 {
        let inside = self.t.iter().zip(&self.instance).filter(|(t, i)| **i >= 0 && **t <= 0.0).count();
        inside as f32 / self.t.len().max(1) as f32
    }
}

/// `f(0..n)` collected in order, in parallel when enabled.
pub(crate) fn par_map<T: Send>(n: usize, f: impl Fn(usize) -> T + Sync + Send) -> Vec<T> {
    #[cfg(feature = "parallel")]
    {
        use rayon::prelude::*;
        (0..n).into_par_iter().map(f).collect()
    }
    #[cfg(not(feature = "parallel"))]
    (0..n).map(f).collect()
}

/// A pixel's shadow ray towards the sun, traced before shading ([`sun_shadows`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum SunRay {
    /// Not traced (the pixel needed none when it was decided).
    Untraced,
    /// Nothing blocks it.
    Free,
    /// This instance blocks it (the first in the instances' order).
    Blocked(u32),
}

/// The sun's shadow rays of a frame's pixels ([`sun_shadows`]), per tile: none for a frame
/// that traced none.
#[derive(Default)]
struct SunRays {
    /// Tiles per row.
    tiles_x: usize,
    /// Per tile (row-major), the lanes traced, those blocked, and the blocked lanes'
    /// blockers in lane order.
    tiles: Vec<(u64, u64, Vec<u32>)>,
}

impl SunRays {
    /// Pixel (x, y)'s shadow ray.
    fn get(&self, x: usize, y: usize) -> SunRay {
        let t = TILE as usize;
        let Some((lanes, blocked, blockers)) = self.tiles.get((y / t) * self.tiles_x + x / t) else {
            return SunRay::Untraced;
        };
        let bit = 1u64 << ((y % t) * t + x % t);
        match (lanes & bit != 0, blocked & bit != 0) {
            (false, _) => SunRay::Untraced,
            (true, false) => SunRay::Free,
            (true, true) => SunRay::Blocked(blockers[(blocked & (bit - 1)).count_ones() as usize]),
        }
    }
}

/// A pixel's sun shadow ray blocked by no instance (its entry in [`HitBuffer`]'s
/// `sun_blockers`).
pub(crate) const SUN_FREE: u32 = u32::MAX;
/// A pixel's sun shadow ray blocked by an instance not known, or not traced.
pub(crate) const SUN_UNKNOWN: u32 = u32::MAX - 1;

/// The sun's shadow rays (towards `to_sun`, unbounded, down to the frame's `max_level`) of
/// the pixels `needs(x, y)` says, starting at `origin(x, y, d)` (`d` the pixel's ray
/// direction, which `dirs(x0, y0, lanes, out)` writes for a tile's lanes as
/// `ray_setup::tile_dirs` does), traced tile by tile as packets
/// ([`super::tile_search::occluded_tile`]; through the instance BVH together where the frame
/// searches it, [`super::packet_bvh::occluded_tile_bvh`]): per pixel of a `width` × `height`
/// frame. Only a
/// tile's `candidates(tile)` (its lanes; tiles row-major) are asked: a mostly kept frame
/// then looks at its few traced pixels instead of all of them. Of those, the lanes
/// `moved_only(tile)` are asked about the instances that `moved` says moved, alone
/// ([`super::tile_search::MovedOnly`]). `boxes` (or none) bound each instance's cells for
/// the packets that test the instances one by one.
#[allow(clippy::too_many_arguments)]
fn sun_shadows(
    fi: &FrameInstances,
    width: usize,
    height: usize,
    to_sun: DVec3,
    search: super::visibility::Search,
    max_level: u32,
    candidates: impl Fn(usize) -> u64 + Sync + Send,
    moved_only: impl Fn(usize) -> u64 + Sync + Send,
    moved: &[bool],
    boxes: &[(DVec3, DVec3)],
    needs: impl Fn(usize, usize) -> bool + Sync + Send,
    dirs: impl Fn(usize, usize, u64, &mut [DVec3]) + Sync + Send,
    origin: impl Fn(usize, usize, DVec3) -> DVec3 + Sync + Send,
) -> SunRays {
    let t = TILE as usize;
    let tiles_x = width.div_ceil(t);
    // A crowd's tiles walk its instance BVH together. (Up to the beams' limit, the test of each
    // instance's sphere against the tile's cylinder measured faster.)
    let through_bvh =
        search == super::visibility::Search::Bvh && fi.bvh.is_some() && fi.prepared.len() > super::beam::MAX_INSTANCES;
    // Tile by tile (a mostly kept frame's shadow rays lie in a few bands of tiles, too few
    // pieces to share between threads): each tile's rays asked, and the ones blocked.
    let per_tile = crate::pool::map_index(tiles_x * height.div_ceil(t), |tile| {
        let (x0, y0) = ((tile % tiles_x) * t, (tile / tiles_x) * t);
        let mut lanes = 0u64;
        for k in super::tile_search::each(candidates(tile)) {
            let (x, y) = (x0 + k % t, y0 + k / t);
            if x < width && y < height && needs(x, y) {
                lanes |= 1 << k;
            }
        }
        if lanes == 0 {
            return (0, 0, Vec::new());
        }
        // (Filled only for tiles with rays: most of a mostly kept frame's have none.)
        let mut origins = [DVec3::ZERO; (TILE * TILE) as usize];
        let mut d = [DVec3::ZERO; (TILE * TILE) as usize];
        dirs(x0, y0, lanes, &mut d);
        for k in super::tile_search::each(lanes) {
            origins[k] = origin(x0 + k % t, y0 + k / t, d[k]);
        }
        let only = super::tile_search::MovedOnly { lanes: moved_only(tile) & lanes, moved };
        let mut blockers = [0; LANES];
        let (inf, b) = (f64::INFINITY, &mut blockers);
        let blocked = match through_bvh {
            true => super::tile_search::TileScratch::with(|scratch| {
                super::packet_bvh::occluded_tile_bvh(fi, &origins, to_sun, lanes, only, inf, max_level, scratch, b)
            }),
            false => super::tile_search::TileScratch::with(|scratch| {
                super::tile_search::occluded_tile_by(
                    fi, &origins, to_sun, lanes, only, boxes, inf, search, max_level, scratch, b,
                )
            }),
        };
        (lanes, blocked, super::tile_search::each(blocked).map(|k| blockers[k]).collect())
    });
    SunRays { tiles_x, tiles: per_tile }
}

/// The hit record of a nearest hit along unit direction `d`: world normals turned to face the
/// ray (surfaces are two-sided), the voxel's world size for offsets.
pub(crate) fn hit_record(scene: &Scene, prepared: &[Prepared], h: &InstanceHit, d: DVec3) -> HitRecord {
    let mut rec = HitRecord::MISS;
    hit_record_into(&mut rec, scene, prepared, h, d, None);
    rec
}

/// Writes [`hit_record`] into `rec`, in a frame with key `frame`
/// ([`super::unit_normals::frame_key`], taken once `prepared` was filled for it): a turned
/// instance's voxel normals are remembered too. (Written in place: returned, the record was
/// stored on the stack field by field and copied from there into the frame's records by wider
/// loads, which waited on those stores at every hit; docs/benchmarks.md, step 135.)
fn hit_record_into(
    rec: &mut HitRecord,
    scene: &Scene,
    prepared: &[Prepared],
    h: &InstanceHit,
    d: DVec3,
    frame: Option<u64>,
) {
    let p = &prepared[h.instance];
    let to_world = |n: Vec3| p.normal_to_world(n.as_dvec3()).normalize_or_zero().as_vec3();
    // A face normal is an axis (or zero), which an instance without a rotation or scale
    // leaves as it is: `to_world` would give it back bit for bit.
    let (mut normal, face_normal) = match (p.to_unit, frame) {
        (ToUnit::Scale { .. }, _) => (super::unit_normals::unturned(h.hit.attr), h.hit.face_normal),
        (ToUnit::Affine(_), Some(frame)) => {
            (super::unit_normals::turned(frame, h.instance, h.hit.attr, to_world), to_world(h.hit.face_normal))
        }
        (ToUnit::Affine(_), None) => (to_world(h.hit.normal()), to_world(h.hit.face_normal)),
    };
    if !(normal.length_squared() > 0.5) {
        normal = if face_normal != Vec3::ZERO { face_normal } else { -d.as_vec3() };
    }
    // Two-sided surfaces: shade the side facing the camera.
    if normal.dot(d.as_vec3()) > 0.0 {
        normal = -normal;
    }
    let voxel = scene.parts[p.part].bounds.voxel_size(h.hit.level) as f64 * p.max_stretch;
    *rec = HitRecord {
        t: h.hit.t,
        instance: h.instance as i32,
        normal,
        face_normal,
        attr: h.hit.attr,
        voxel: voxel as f32,
    };
}

/// A [`TileSummary`] that the rows of a tile, shaded on any thread, add to.
struct TileAcc {
    instances: AtomicU64,
    t_lo: AtomicU32,
    t_hi: AtomicU32,
    voxel: AtomicU32,
}

impl TileAcc {
    fn new(s: TileSummary) -> TileAcc {
        TileAcc {
            instances: AtomicU64::new(s.instances),
            t_lo: AtomicU32::new(s.t_lo.to_bits()),
            t_hi: AtomicU32::new(s.t_hi.to_bits()),
            voxel: AtomicU32::new(s.voxel.to_bits()),
        }
    }

    /// Adds a part of the tile. Its values are non-negative (or +∞), whose bits order as
    /// the numbers do.
    fn add(&self, s: &TileSummary) {
        if s.instances == 0 {
            return;
        }
        self.instances.fetch_or(s.instances, Ordering::Relaxed);
        self.t_lo.fetch_min(s.t_lo.to_bits(), Ordering::Relaxed);
        self.t_hi.fetch_max(s.t_hi.to_bits(), Ordering::Relaxed);
        self.voxel.fetch_max(s.voxel.to_bits(), Ordering::Relaxed);
    }

    fn load(&self) -> TileSummary {
        TileSummary {
            instances: self.instances.load(Ordering::Relaxed),
            t_lo: f32::from_bits(self.t_lo.load(Ordering::Relaxed)),
            t_hi: f32::from_bits(self.t_hi.load(Ordering::Relaxed)),
            voxel: f32::from_bits(self.voxel.load(Ordering::Relaxed)),
        }
    }
}

/// One row of a frame's per-pixel buffers.
struct FrameRow<'a> {
    radiance: &'a mut [Vec3],
    t: &'a mut [f32],
    instance: &'a mut [i32],
    normal: &'a mut [Vec3],
    albedo: &'a mut [Vec3],
    specular: &'a mut [f32],
    shininess: &'a mut [f32],
    /// What blocks each pixel's sun shadow ray ([`SUN_FREE`], [`SUN_UNKNOWN`] or an instance).
    sun_blocker: &'a mut [u32],
}

impl FrameRow<'_> {
    /// Writes pixel `x`'s surface data (the AOVs) from its hit record, and returns its albedo,
    /// specular reflectance and Phong exponent as written. (Shading reads them from here: read
    /// back from the row, the wide load of the albedo waited on the narrower stores that had
    /// just written it, a store-forwarding stall at every pixel.)
    // Always inlined: as a call from its two places in the shading pass, whole frames
    // measured 5 % slower.
    #[inline(always)]
    fn surface(&mut self, x: usize, r: &HitRecord) -> (Vec3, f32, f32) {
        self.t[x] = r.t;
        self.instance[x] = r.instance;
        self.normal[x] = r.normal;
        let (albedo, ks) =
            if r.instance >= 0 { (r.attr.albedo_linear(), r.attr.specular()) } else { (Vec3::ZERO, 0.0) };
        let shininess = brdf::shininess_of_gloss_bits(r.attr.gloss_bits());
        (self.albedo[x], self.specular[x], self.shininess[x]) = (albedo, ks, shininess);
        (albedo, ks, shininess)
    }
}

/// Runs `f(y, row)` over the rows of a frame's per-pixel buffers and of `sun_blocker` (as
/// many pixels), in parallel when enabled ([`crate::pool::for_each_index`]: a band of
/// [`TILE`] rows each), and returns the sums of what it returns; `band_done(rows)` hears of
/// each band as it finishes. (Summed per thread and added once: counters shared by every row
/// cost a mostly kept frame's shading pass more than its two threads gained.)
fn for_frame_rows(
    f: &mut Frame,
    sun_blocker: &mut [u32],
    each: impl Fn(usize, FrameRow) -> [u64; 2] + Sync + Send,
    band_done: impl Fn(usize) + Sync + Send,
) -> [u64; 2] {
    use crate::pool::Disjoint;
    let (w, h) = (f.width as usize, f.height as usize);
    let radiance = Disjoint::new(&mut f.radiance);
    let t = Disjoint::new(&mut f.t);
    let instance = Disjoint::new(&mut f.instance);
    let normal = Disjoint::new(&mut f.normal);
    let albedo = Disjoint::new(&mut f.albedo);
    let specular = Disjoint::new(&mut f.specular);
    let shininess = Disjoint::new(&mut f.shininess);
    let sun_blocker = Disjoint::new(sun_blocker);
    let sums = [AtomicU64::new(0), AtomicU64::new(0)];
    let band = TILE as usize;
    let add = |sum: [u64; 2]| {
        for (total, part) in sums.iter().zip(sum) {
            total.fetch_add(part, Ordering::Relaxed);
        }
    };
    crate::pool::for_each_index_with(
        h.div_ceil(band),
        || [0u64; 2],
        |sum, b| {
            let rows = b * band..((b + 1) * band).min(h);
            for y in rows.clone() {
                let at = y * w;
                // SAFETY: row y's pixels are this call's alone.
                let row = unsafe {
                    FrameRow {
                        radiance: radiance.run(at, w),
                        t: t.run(at, w),
                        instance: instance.run(at, w),
                        normal: normal.run(at, w),
                        albedo: albedo.run(at, w),
                        specular: specular.run(at, w),
                        shininess: shininess.run(at, w),
                        sun_blocker: sun_blocker.run(at, w),
                    }
                };
                let [a, b] = each(y, row);
                *sum = [sum[0] + a, sum[1] + b];
            }
            band_done(rows.len());
        },
        add,
    );
    sums.map(AtomicU64::into_inner)
}

/// Where a secondary ray from hit `r` at (camera-relative) `at` starts: one voxel along the
/// normal and a little along the entered face, so the hit voxel does not occlude its own rays.
pub(crate) fn leave(r: &HitRecord, at: DVec3) -> DVec3 {
    let v = r.voxel as f64;
    at + r.normal.as_dvec3() * v + r.face_normal.as_dvec3() * (0.1 * v)
}

/// The ambient term of one hit: (record, point, ray direction, diffuse light, glossy light
/// from radiance caches) → both lobes' light, reflectance included.
pub type AmbientTerm<'a> = dyn Fn(&HitRecord, DVec3, DVec3, Vec3, Option<Vec3>) -> Vec3 + Sync + 'a;

/// Where the lighting's ambient term comes from when it is not the flat sky (GI's cones,
/// [`crate::gi::render_with_gi`]): the diffuse light gathered at a hit, at every pixel or at
/// half resolution ([`super::gather`]), and the term that makes both lobes' ambient light of
/// it, reflectance included.
pub struct AmbientLight<'a> {
    /// The diffuse cones' light at a hit (its record and world-space point) before the
    /// albedo, and the cosine-weighted fraction of the cones that escaped.
    pub diffuse: &'a (dyn Fn(&HitRecord, DVec3) -> (Vec3, f32) + Sync),
    /// The ambient term of one hit (record, point, ray direction) given its diffuse light and,
    /// where radiance caches gave it, its glossy light (else the term traces its own
    /// specular cone): both lobes, reflectance included.
    pub term: &'a AmbientTerm<'a>,
    /// One cone through the light (for radiance caches; None: they gather per pixel).
    pub cone: Option<super::gather::ConeFn<'a>>,
    /// Where the diffuse light is gathered: every pixel, half resolution or radiance caches.
    pub gather: super::Gather,
    /// The term gives what it gave in the stored frame (the same light, gathered the same
    /// way), so colours kept by the hit buffer stay valid.
    pub unchanged: bool,
    /// Emitters' shadows as cones through the GI volume instead of shadow rays
    /// (`GiSettings::cone_shadows`), from a world point; None: rays.
    pub shadow_cone: Option<&'a ShadowCone<'a>>,
}

/// The light a hit receives besides the ambient term (WGSL's `direct_light`): the sun, when
/// the surface faces it and its shadow ray is free, the other suns, points and spots the same
/// way, the emitters' light sampled at `key`'s points ([`emitter_light`]), then the hit's own
/// emission. `visible(start, direction, distance, sun)` says whether a shadow ray gets
/// through; `sun` says that it is the scene's sun's (`Lights::sun`), whose answer the frame's
/// sun pass may hold. With `cone`, the emitters' shadows are cones instead. `d` is the
/// primary ray's unit direction from the camera at `eye`; `surface` is the hit's albedo,
/// specular reflectance and Phong exponent, as the shading loop decoded them for the surface
/// data. (The sun's ray is told, not found by comparing directions: the direction, handed
/// over on the stack in narrower stores, stalled the wide load that compared it at every lit
/// pixel.)
#[allow(clippy::too_many_arguments)]
fn direct_light(
    r: &HitRecord,
    surface: (Vec3, f32, f32),
    eye: DVec3,
    d: DVec3,
    lights: &Lights,
    emitters: &EmitterTable,
    key: u32,
    visible: &mut dyn FnMut(DVec3, DVec3, f64, bool) -> bool,
    cone: Option<&ShadowCone>,
) -> Vec3 {
    let mut c = Vec3::ZERO;
    let at = d * r.t as f64;
    let (albedo, ks, shininess) = surface;
    if let Some(sun) = lights.sun {
        let cos = r.normal.dot(sun.to_sun);
        if cos > 0.0 && visible(leave(r, at), sun.to_sun.as_dvec3(), f64::INFINITY, true) {
            c += brdf::facing_response(albedo, ks, shininess, r.normal, d.as_vec3(), sun.to_sun, cos) * sun.irradiance;
        }
    }
    if lights.has_extra() {
        for inc in lights.incident_extra(eye + at) {
            let l = inc.to_light.as_vec3();
            if r.normal.dot(l) > 0.0 && visible(leave(r, at), inc.to_light, inc.distance, false) {
                c += brdf::sun_response(albedo, ks, shininess, r.normal, d.as_vec3(), l) * inc.irradiance;
            }
        }
    }
    let samples = lights.emitter_sampling();
    if samples > 0 {
        let mut emitter_visible = |start, dir, t_max| visible(start, dir, t_max, false);
        c += emitter_light(
            emitters,
            samples,
            key,
            at,
            leave(r, at),
            r.normal,
            d.as_vec3(),
            albedo,
            ks,
            shininess,
            match cone {
                Some(cone) => EmitterShadows::Cones(cone),
                None => EmitterShadows::Rays(&mut emitter_visible),
            },
        );
    }
    if lights.use_mtl_emitters {
        c += r.attr.emission();
    }
    c
}

/// Renders one frame of `scene` as `plan` says. With a hit buffer, pixels are reused where
/// the plan allows it and the buffer is refreshed for the next frame. `progress(rows, of)` is
/// called as rows finish (both passes count). The ambient term is the flat sky. A camera that
/// [`Camera::validate`] refuses is refused here, before anything is allocated.
pub fn render(
    scene: &Scene,
    camera: &Camera,
    lights: &Lights,
    plan: &FramePlan,
    opts: &RenderOptions,
    hits: Option<&mut HitBuffer>,
    progress: &(dyn Fn(u32, u32) + Sync),
) -> Result<Frame, CameraError> {
    Ok(render_lit(scene, camera, lights, plan, opts, hits, None, progress)?.0)
}

/// [`render`] with the ambient term from `ambient` instead of the flat sky; also returns the
/// milliseconds spent gathering it. The steps and their order are the WGSL renderer's:
/// trace → hit records (the G-buffer: t, normal, albedo, material, instance) → lighting,
/// where a hit's colour is its ambient term (the sky's, or `ambient`'s, clamped at zero)
/// plus its direct light (the sun with its shadow ray, then its emission).
#[allow(clippy::too_many_arguments)]
pub fn render_lit(
    scene: &Scene,
    camera: &Camera,
    lights: &Lights,
    plan: &FramePlan,
    opts: &RenderOptions,
    hits: Option<&mut HitBuffer>,
    ambient: Option<&AmbientLight>,
    progress: &(dyn Fn(u32, u32) + Sync),
) -> Result<(Frame, f64), CameraError> {
    // A crowd's frame runs its passes' parallel loops from one of the pool's threads, the
    // others kept awake (crate::pool); a few instances' frame has too few loops to repay the
    // hand-over.
    if scene.instances().len() > super::beam::MAX_INSTANCES {
        crate::pool::run_awake(|| render_lit_here(scene, camera, lights, plan, opts, hits, ambient, progress))
    } else {
        render_lit_here(scene, camera, lights, plan, opts, hits, ambient, progress)
    }
}

/// [`render_lit`] on the calling thread.
#[allow(clippy::too_many_arguments)]
fn render_lit_here(
    scene: &Scene,
    camera: &Camera,
    lights: &Lights,
    plan: &FramePlan,
    opts: &RenderOptions,
    hits: Option<&mut HitBuffer>,
    ambient: Option<&AmbientLight>,
    progress: &(dyn Fn(u32, u32) + Sync),
) -> Result<(Frame, f64), CameraError> {
    camera.validate()?;
    let (w, h) = (camera.width as usize, camera.height as usize);
    let basis = camera.basis();
    // `camera.ray_dir` of every pixel, with each column's and row's share formed once: a
    // mostly kept frame forms the directions of its pixels near moving parts several times
    // (their reuse, shadow and shading tests), three divisions each.
    let (columns, rows) = camera.screen_slopes(&basis);
    let ray_dir = |x: usize, y: usize| basis.dir(columns[x], rows[y]);
    // `ray_dir` of the lanes `lanes` of the 8×8 tile at (x0, y0), four at a time, into `out`
    // (pixels past the image's edges take its last column's or row's: they are not asked).
    let tile_dirs = |x0: usize, y0: usize, lanes: u64, out: &mut [DVec3]| {
        let sx: [f64; TILE as usize] = std::array::from_fn(|i| columns[(x0 + i).min(w - 1)]);
        let sy: [f64; TILE as usize] = std::array::from_fn(|i| rows[(y0 + i).min(h - 1)]);
        super::ray_setup::tile_dirs(&basis, &sx, &sy, lanes, out);
    };
    // `TileRays::new` of pixels x0..x1 × y0..y1, from the same slopes.
    let tile_rays = |x0: u32, y0: u32, x1: u32, y1: u32| TileRays::from_slopes(&basis, &columns, &rows, x0, y0, x1, y1);
    let mut hits = hits;
    // Last frame's instances' memory, refilled.
    let mut prepared = hits.as_deref_mut().map(|h| std::mem::take(&mut h.prepared)).unwrap_or_default();
    // Their spheres, for the lists and the BVH.
    let mut spheres = hits.as_deref_mut().map(|h| std::mem::take(&mut h.prepared_spheres)).unwrap_or_default();
    let splatting = opts.renderer == Renderer::Splat;
    // A crowd's primary rays search the spheres their pixel meets, not the BVH.
    let want_lists = plan.sphere_lists && !splatting;
    let refilled = match hits.as_deref_mut() {
        // Only the instances changed since last frame, when the eye and the rest are the same
        // (and only their spheres: a crowd's 80 000 prepared instances are not read again).
        Some(h) => prepare_changed(
            scene,
            camera.eye,
            plan.transform,
            opts.max_level,
            &mut prepared,
            &mut spheres,
            &mut h.prepared_for,
        ),
        None => {
            prepare_into(scene, camera.eye, plan.transform, opts.max_level, &mut prepared);
            if plan.bvh || want_lists {
                spheres.extend(prepared.iter().map(|p| (p.centre, p.radius)));
            }
            None
        }
    };
    let lists = match hits.as_deref_mut() {
        _ if !want_lists => None,
        // Last frame's lists were made with the spheres of last frame's prepared instances:
        // only those prepared again may have moved.
        Some(h) => match &refilled {
            Some(moved) => PixelSpheres::rebuild_moved(h.pixel_spheres.take(), camera, &spheres, moved),
            None => PixelSpheres::rebuild(h.pixel_spheres.take(), camera, &spheres),
        },
        None => PixelSpheres::build(camera, &spheres),
    };
    // Shadow rays search the BVH, and so do primary rays without lists; a frame with neither
    // leaves it as it was (the next one that needs it refits every box).
    let bvh = (plan.bvh && (plan.shadows || lists.is_none())).then(|| match hits.as_deref_mut() {
        Some(h) => h.take_bvh_of(&spheres),
        None => Bvh::build(&spheres),
    });
    let fi = FrameInstances { parts: &scene.parts, prepared: &prepared, bvh: bvh.as_ref(), starts: None };
    let search = plan.search();
    let trace_opts = TraceOptions { max_level: opts.max_level, ..TraceOptions::default() };
    // The parts' splat lists live in the hit buffer between frames.
    let mut splat_cache = hits.as_deref_mut().map(|h| std::mem::take(&mut h.splats)).unwrap_or_default();
    // Splatted records are not the ray tracer's: nothing is reused from them, or into them.
    let reuse = hits
        .as_deref()
        .filter(|_| plan.hit_buffer && !splatting)
        .and_then(|b| b.reuse(camera, scene, &prepared, opts.max_level));
    // Last frame's records are updated in place: a kept pixel is not touched at all, and no
    // fresh pages are faulted in every frame. With reuse on, they are this camera's size.
    // Of those, per tile, the misses that last frame's beams stored: a beam miss there is
    // already in place.
    let (mut records, records_missed) = match hits.as_deref_mut() {
        Some(b) => b.take_records(camera.width, camera.height),
        None => (vec![HitRecord::MISS; w * h], Vec::new()),
    };
    let tiles_x = w.div_ceil(TILE as usize);
    let tile_count = tiles_x * h.div_ceil(TILE as usize);
    // Last frame's per-tile instance masks (with reuse): a tile none of whose records is on
    // a moved instance, and that no moved sphere reaches, keeps them without their being read.
    let old_tiles = hits.as_deref_mut().map(|h| std::mem::take(&mut h.tiles)).unwrap_or_default();
    let old_tiles = if reuse.is_some() && old_tiles.len() == tile_count { old_tiles } else { Vec::new() };
    let (spare, as_rendered) = hits.as_deref_mut().map(|b| b.take_spare()).unwrap_or((None, None));
    let spare_at = spare.as_ref().map(|f| f.radiance.as_ptr() as usize);
    // What blocked each stored colour's sun shadow ray; the pixels this frame shades write
    // theirs.
    let mut sun_blockers = hits.as_deref_mut().map(|h| std::mem::take(&mut h.sun_blockers)).unwrap_or_default();
    let previous = hits.as_deref().filter(|_| plan.hit_buffer);
    let done = AtomicU32::new(0);
    let ticks = |n: usize| progress(done.fetch_add(n as u32, Ordering::Relaxed) + n as u32, 2 * h as u32);

    // Pass 1: primary visibility, tile by tile (beams start each tile's rays late); reused
    // pixels are decided first, so a tile that reuses all traces nothing.
    let moved = reuse.as_ref().map_or(&[][..], |r| r.moved_search());
    let moved_flags = reuse.as_ref().filter(|_| !moved.is_empty()).map_or(&[][..], |r| &r.moved[..]);
    let primary = Primary {
        lists: lists.as_ref(),
        instances: fi,
        camera,
        search,
        opts: trace_opts,
        beams: plan.beams,
        bvh_beams: plan.bvh_beams,
        moved,
        moved_flags,
        missed_before: &records_missed,
    };
    // Per tile whose pixels may need tracing, each pixel's nearest entry into the moved
    // spheres whose pixel rectangles reach into it (usually none; `Reuse::tile_entries`).
    let no_entries = [f64::INFINITY; (TILE * TILE) as usize];
    let tile_spheres = |rect: [u32; 4]| match &reuse {
        Some(r) => {
            let mut spheres = r.spheres_in(rect);
            let [x0, y0, x1, y1] = rect;
            if !spheres.is_empty() {
                // The rectangles are loose (a box's projection, a pixel wider): the tile's
                // cone drops the spheres none of its rays can meet.
                let cone = super::beam::TileCone::new(&tile_rays(x0, y0, x1, y1));
                spheres.retain(|&k| {
                    let (c, radius, _) = r.moved_spheres[k as usize];
                    cone.meets_ball(c, radius)
                });
            }
            let t = (y0 / TILE) as usize * tiles_x + (x0 / TILE) as usize;
            match old_tiles.get(t) {
                Some(tile) if r.tile_kept(tile, &spheres) => None,
                _ if spheres.is_empty() => Some(no_entries),
                _ => {
                    let mut dirs = [DVec3::ZERO; (TILE * TILE) as usize];
                    tile_dirs(x0 as usize, y0 as usize, u64::MAX, &mut dirs);
                    Some(r.tile_entries(&spheres, x0, y0, &dirs))
                }
            }
        }
        None => Some(no_entries),
    };
    let pending = |entries: &[f64; (TILE * TILE) as usize], x: u32, y: u32, rec: &mut HitRecord| match &reuse {
        // `rec` still holds last frame's record of this pixel.
        Some(r) => r.todo(rec, entries[((y % TILE) * TILE + x % TILE) as usize]),
        None => Todo::All,
    };
    // The instances are prepared for this frame and stay so while it traces.
    let frame_key = super::unit_normals::frame_key();
    let store = |rec: &mut HitRecord, hit: Option<(&InstanceHit, DVec3)>| match hit {
        Some((hit, d)) => hit_record_into(rec, scene, &prepared, hit, d, Some(frame_key)),
        None => rec.set_miss(),
    };
    let traced = if splatting {
        let per_instance = splat_cache.for_frame(scene, &prepared, camera, opts.max_level);
        super::splat::rasterize(scene, &prepared, &per_instance, camera, opts.splat_factor, &mut records);
        ticks(h);
        let tiles = w.div_ceil(TILE as usize) * h.div_ceil(TILE as usize);
        // Every pixel is drawn afresh: none counts as reused.
        super::primary::Traced {
            work: Default::default(),
            rays: (w * h) as u64,
            moved_only: 0,
            stored: vec![u64::MAX; tiles],
            missed: Vec::new(),
        }
    } else {
        trace_tiles(&primary, &mut records, tile_spheres, pending, store, ticks)
    };

    // Pass 2: shading. A pixel keeps last frame's colour when it kept its hit record (it was
    // not traced), the lights and shadow switch are the same, and (with shadows) its shadow
    // ray crosses no moved instance's sphere, old or new: then every input of the colour is
    // the same.
    let kept_hit = |x: usize, y: usize| {
        let tile = traced.stored[(y / TILE as usize) * tiles_x + x / TILE as usize];
        tile & (1 << ((y % TILE as usize) * TILE as usize + x % TILE as usize)) == 0
    };
    let sky = lights.sky();
    // Emitters light the frame when there are any and they are sampled.
    let emitters =
        if lights.emitter_sampling() > 0 { EmitterTable::new(scene, camera.eye) } else { EmitterTable::default() };
    let n = w * h;
    if sun_blockers.len() != n {
        sun_blockers.clear();
        sun_blockers.resize(n, SUN_UNKNOWN);
    }
    let shade_from = reuse.as_ref().zip(previous).filter(|(_, prev)| {
        prev.lights.as_ref() == Some(lights)
            && prev.shadows == plan.shadows
            && prev.radiance.len() == n
            && prev.lit_by_gi == ambient.is_some()
            && ambient.is_none_or(|a| a.unchanged)
            // Emitter samples and extra lights reach anywhere: a kept colour would need all
            // their shadow rays checked against the moved instances (not built: such frames
            // shade afresh).
            && emitters.is_empty()
            && !lights.has_extra()
    });
    let mut f = Frame {
        primary_rays: n as u64,
        reused: 0,
        shadow_rays: 0,
        shade_reused: 0,
        moved_only: traced.moved_only,
        instances_traced: traced.work.traced,
        spheres_culled: traced.work.culled,
        ..Frame::buffers(spare, camera.width, camera.height)
    };
    // Pass 2a (GI): the ambient term of every hit to be shaded, from the G-buffer alone.
    let ambient_start = std::time::Instant::now();
    let kept_colour = |x: usize, y: usize| shade_from.is_some() && kept_hit(x, y);
    let ambient_terms: Vec<Vec3> = match ambient {
        Some(a) => {
            let needed = |x: usize, y: usize| records[y * w + x].instance >= 0 && !kept_colour(x, y);
            let g = super::gather::gather(a.gather, &records, camera, &basis, a.diffuse, a.cone, &needed);
            f.gathers = g.gathers;
            f.cache_stages = g.stages;
            // Kept colours keep last frame's occlusion too.
            f.ao = g.open;
            if let Some(prev) = previous.filter(|p| shade_from.is_some() && p.ao.len() == n) {
                for (k, o) in f.ao.iter_mut().enumerate() {
                    if records[k].instance >= 0 && kept_colour(k % w, k / w) {
                        *o = prev.ao[k];
                    }
                }
            }
            par_map(n, |k| {
                let (x, y) = (k % w, k / w);
                if !needed(x, y) {
                    return Vec3::ZERO;
                }
                let d = ray_dir(x, y);
                let glossy = g.glossy.get(k).copied().flatten();
                (a.term)(&records[k], camera.eye + d * records[k].t as f64, d, g.light[k], glossy).max(Vec3::ZERO)
            })
        }
        None => Vec::new(),
    };
    let ambient_ms = ambient_start.elapsed().as_secs_f64() * 1e3;
    // Cone-traced emitter shadows only where shadows are traced at all; emitter_light works
    // camera-relative.
    let world_cone = ambient.and_then(|a| a.shadow_cone).filter(|_| plan.shadows);
    let relative_cone = world_cone.map(|c| {
        move |at: DVec3, n: DVec3, d: DVec3, aperture: f64, end: crate::gi::cone::ConeEnd| {
            c(camera.eye + at, n, d, aperture, end)
        }
    });
    let shadow_cone = relative_cone.as_ref().map(|c| c as &ShadowCone);
    // Per moved sphere, the pixels whose kept records' shadow rays may meet it (none without
    // the sun, all where the records' summaries are not known).
    let shadow_rects = match (shade_from, lights.sun) {
        (Some((reuse, _)), Some(sun)) if plan.shadows => match super::hitbuffer::shadow_reach(&old_tiles) {
            Some(reach) if !old_tiles.is_empty() => {
                reuse.shadow_rects(&PixelGrid::new(camera, &basis), sun.to_sun.as_dvec3(), reach)
            }
            _ => vec![PixelRect::Unbounded],
        },
        _ => Vec::new(),
    };
    // Per tile, the kept records whose shadow ray may now meet a moved sphere (their pixels
    // are shaded afresh): decided before the sun's shadow packets, so that those rays go in
    // the packets instead of one by one in the shading pass. Of those, the ones that no
    // instance blocked (`.1`): only a moved instance can block them now.
    let reshade_tiles: Vec<(u64, u64)> = match shade_from {
        Some((reuse, _)) if plan.shadows => crate::pool::map_index(tile_count, |t| {
            let (x0, y0) = ((t % tiles_x) * TILE as usize, (t / tiles_x) * TILE as usize);
            // The tile's kept records: the pixels of the image its trace did not store.
            let (tw, th) = ((w - x0).min(TILE as usize), (h - y0).min(TILE as usize));
            let row = (1u64 << tw) - 1;
            let inside = (0..th).fold(0u64, |m, ty| m | row << (ty * TILE as usize));
            let kept = inside & !traced.stored[t];
            // No kept pixel, or no moved sphere's shadow reaches the tile: every stored shadow
            // answer stands, and the tile's rays need not be formed to say so.
            let rect = [x0 as u32, y0 as u32, (x0 + tw - 1) as u32, (y0 + th - 1) as u32];
            if kept == 0 || !super::hitbuffer::rects_meet(&shadow_rects, rect) {
                return (0, 0);
            }
            // The moved spheres their shadow rays may meet (Reuse::tile_shadow_suspects; none
            // needs no test of its own). Its records' summary is last frame's, which bounds
            // the records it keeps whether or not others were traced afresh.
            let suspects = match (lights.sun, old_tiles.get(t)) {
                // Sky: no shadow rays, and no need to form the tile's rays to say so.
                (Some(_), Some(old)) if !old.has_hits() => Some(0),
                (Some(sun), Some(old)) => {
                    let (x0, y0) = (x0 as u32, y0 as u32);
                    let rays = tile_rays(x0, y0, x0 + tw as u32, y0 + th as u32);
                    reuse.tile_shadow_suspects(old, &rays, sun.to_sun.as_dvec3())
                }
                _ => None,
            };
            if suspects == Some(0) {
                return (0, 0);
            }
            // The same ray, blocked by an instance that stayed where it was: blocked still.
            let blocked_still = |blocker: u32| reuse.moved.get(blocker as usize).is_some_and(|m| !m);
            if let (Some(suspects), Some(sun)) = (suspects, lights.sun) {
                // The kept records that cast a shadow ray (`Reuse::shadow_valid_among`'s), and
                // of those the ones that no instance blocked.
                let (mut asked, mut free) = (0u64, 0u64);
                for k in super::tile_search::each(kept) {
                    let at = (y0 + k / TILE as usize) * w + x0 + k % TILE as usize;
                    let (r, blocker) = (&records[at], sun_blockers[at]);
                    if !blocked_still(blocker) && r.instance >= 0 && r.normal.dot(sun.to_sun) > 0.0 {
                        asked |= 1 << k;
                        free |= ((blocker == SUN_FREE) as u64) << k;
                    }
                }
                if asked == 0 {
                    return (0, 0);
                }
                // Their starts, where the shading pass starts them, and the tile's test of all
                // of them against each suspect at once.
                let mut dirs = [DVec3::ZERO; (TILE * TILE) as usize];
                tile_dirs(x0, y0, asked, &mut dirs);
                let mut from = [[0.0; (TILE * TILE) as usize]; 3];
                for k in super::tile_search::each(asked) {
                    let r = &records[(y0 + k / TILE as usize) * w + x0 + k % TILE as usize];
                    let o = leave(r, dirs[k] * r.t as f64);
                    (from[0][k], from[1][k], from[2][k]) = (o.x, o.y, o.z);
                }
                let out = reuse.tile_shadows_met(suspects, asked, &from, sun.to_sun.as_dvec3());
                return (out, out & free);
            }
            let (mut out, mut free) = (0u64, 0u64);
            for k in super::tile_search::each(kept) {
                let (x, y) = (x0 + k % TILE as usize, y0 + k / TILE as usize);
                let blocker = sun_blockers[y * w + x];
                if blocked_still(blocker) {
                    continue;
                }
                let r = &records[y * w + x];
                if !reuse.shadow_valid_among(r, lights, || ray_dir(x, y), suspects) {
                    out |= 1 << k;
                    if blocker == SUN_FREE {
                        free |= 1 << k;
                    }
                }
            }
            (out, free)
        }),
        _ => Vec::new(),
    };
    // Tile t's kept records shaded afresh for their shadow ray.
    let reshade = |t: usize| reshade_tiles.get(t).map_or(0, |r| r.0);
    // Whether pixel (x, y), its hit kept, is shaded afresh for its shadow ray.
    let reshaded = |x: usize, y: usize| {
        let t = (y / TILE as usize) * tiles_x + x / TILE as usize;
        reshade(t) & (1 << ((y % TILE as usize) * TILE as usize + x % TILE as usize)) != 0
    };
    // The sun's shadow rays of the pixels to be shaded, a tile's rays as packets (the same
    // answers as one by one).
    let sun_rays = match lights.sun {
        // (Few instances: with beams, or with sphere lists where they are small on screen;
        // more: through the instance BVH.)
        Some(sun)
            if plan.shadows
                && if prepared.len() <= super::beam::MAX_INSTANCES {
                    plan.beams || plan.sphere_lists
                } else {
                    search == super::visibility::Search::Bvh && fi.bvh.is_some()
                } =>
        {
            // (A kept colour's record is not read: most of the frame's records stay untouched.)
            let needs = |x: usize, y: usize| {
                (!kept_colour(x, y) || reshaded(x, y)) && {
                    let r = &records[y * w + x];
                    r.instance >= 0 && r.normal.dot(sun.to_sun) > 0.0
                }
            };
            let origin = |x: usize, y: usize, d: DVec3| {
                let r = &records[y * w + x];
                leave(r, d * r.t as f64)
            };
            // Only a pixel traced this frame, or reshaded, can be without its kept colour.
            let candidates = |t: usize| {
                if shade_from.is_some() {
                    traced.stored[t] | reshade(t)
                } else {
                    u64::MAX
                }
            };
            let (to_sun, height) = (sun.to_sun.as_dvec3(), camera.height as usize);
            let moved_only = |t: usize| reshade_tiles.get(t).map_or(0, |r| r.1);
            let moved = reuse.as_ref().map_or(&[][..], |r| &r.moved[..]);
            let max_level = opts.max_level;
            // Boxes around the instances' cells, for the packets that test each instance
            // (not those through the BVH).
            let boxes = match prepared.len() <= super::beam::MAX_INSTANCES {
                true => super::instances::occupied_world_boxes(scene, camera.eye, max_level),
                false => Vec::new(),
            };
            let (b, cand) = (&boxes, candidates);
            sun_shadows(&fi, w, height, to_sun, search, max_level, cand, moved_only, moved, b, needs, tile_dirs, origin)
        }
        _ => SunRays::default(),
    };
    // A frame that is the stored colours' own frame, back unchanged, already holds every
    // kept pixel's colour and surface data: only the other pixels are written.
    let same_buffers = as_rendered.is_some() && spare_at == Some(f.radiance.as_ptr() as usize);
    let patch = same_buffers && shade_from.is_some();
    // Per tile, the pixels that the frame being refilled showed as the same misses (the same
    // sky) that this frame's beams store: those need no writing either. (That frame's beam
    // misses are the records'.)
    let shown_missed: &[u64] = match &as_rendered {
        Some(r) if same_buffers && r.sky == sky => &records_missed,
        _ => &[],
    };
    // This frame's tile masks, when its records are kept: a tile none of whose records
    // changed keeps last frame's.
    let keeping = plan.keep_hits && !splatting && hits.is_some();
    // Tile t's records are last frame's.
    let same_records = |t: usize| !old_tiles.is_empty() && traced.stored[t] == 0;
    let fresh = |t: usize| keeping && !same_records(t);
    // Per tile, the pixels shaded afresh, when the buffer's colours are to be updated there.
    let shaded: Vec<AtomicU64> = match shade_from {
        Some(_) => (0..tile_count).map(|_| AtomicU64::new(0)).collect(),
        None => Vec::new(),
    };
    // Per band of tiles, the columns of the tiles whose rows the shading pass visits, and how
    // many pixels a row of the band has in the others. Where the frame's colours are patched,
    // a tile neither traced nor reshaded (most of a mostly kept frame's) keeps every pixel as
    // the frame holds it: asked row by row, such tiles cost a mostly kept frame's shading
    // 2 % of its time (docs/benchmarks.md, step 145). In the same pass, the tiles whose
    // summaries this frame forms (`fresh`, most often the few traced), each with a slot of
    // `new_tiles` (`fresh_slot[t]`): the others keep last frame's (step 147).
    let bands = h.div_ceil(TILE as usize);
    let mut row_tiles: Vec<u32> = Vec::new();
    let mut band_tiles = Vec::with_capacity(bands);
    let (all_fresh, mut fresh_tiles) = (keeping && old_tiles.is_empty(), Vec::new());
    let mut fresh_slot = vec![u32::MAX; if keeping { tile_count } else { 0 }];
    let all_visited = !patch || all_fresh;
    for ty in 0..bands {
        let start = row_tiles.len();
        let mut idle = 0;
        let band = ty * tiles_x..(ty + 1) * tiles_x;
        let reshaded = |tx: usize| reshade_tiles.get(band.start + tx).map_or(0, |r| r.0);
        for (tx, &stored) in traced.stored[band.clone()].iter().enumerate() {
            if keeping && (all_fresh || stored != 0) {
                fresh_slot[band.start + tx] = fresh_tiles.len() as u32;
                fresh_tiles.push((band.start + tx) as u32);
            }
            if all_visited || stored != 0 || reshaded(tx) != 0 {
                row_tiles.push(tx as u32);
            } else {
                idle += (w - tx * TILE as usize).min(TILE as usize) as u64;
            }
        }
        band_tiles.push((start..row_tiles.len(), idle));
    }
    let new_tiles: Vec<TileAcc> = fresh_tiles.iter().map(|_| TileAcc::new(TileSummary::NONE)).collect();
    // Shading, with each pixel's surface data (the AOVs) written in the same pass over the
    // records: one read of them instead of two.
    let shading = |y: usize, mut row: FrameRow| {
        // (Counted per row and added once per band: one shared counter per shadow ray, bumped
        // from every thread, cost 6 % of a mostly kept frame in cache-line traffic.)
        let (mut kept, mut row_shadow_rays) = (0, 0);
        // This row's bits in a tile's pixel masks.
        let (ty, row_shift) = (y / TILE as usize, (y % TILE as usize) * TILE as usize);
        let (visited, idle) = band_tiles[ty].clone();
        // Every pixel of the others keeps its colour, which the frame holds.
        kept += idle;
        for &tx in &row_tiles[visited] {
            let tx = tx as usize;
            let t = ty * tiles_x + tx;
            let fresh = fresh(t);
            let reshade_row = (reshade(t) >> row_shift) & ((1 << TILE) - 1);
            let span = tx * TILE as usize..((tx + 1) * TILE as usize).min(w);
            if patch && !fresh && (traced.stored[t] >> row_shift) & ((1 << TILE) - 1) == 0 && reshade_row == 0 {
                // Every pixel of this tile row keeps its colour, which the frame holds.
                kept += span.len() as u64;
                continue;
            }
            let row_bits = ((1u64 << span.len()) - 1) << row_shift;
            if traced.missed.get(t).is_some_and(|&m| m & row_bits == row_bits) {
                // The tile's beam met no instance: these pixels were stored as misses, and
                // their records need not be read back.
                if shown_missed.get(t).is_none_or(|&m| m & row_bits != row_bits) {
                    for x in span {
                        row.surface(x, &HitRecord::MISS);
                        row.radiance[x] = sky;
                    }
                }
                if shade_from.is_some() {
                    shaded[t].fetch_or(row_bits, Ordering::Relaxed);
                }
                continue;
            }
            let (mut summary, mut shaded_here) = (TileSummary::NONE, 0u64);
            // Misses stored without a search, and of those the ones this frame already shows.
            let missed = traced.missed.get(t).copied().unwrap_or(0);
            let shown = shown_missed.get(t).copied().unwrap_or(0);
            // The span's ray directions: the first row of the tile at (span.start, y).
            let mut dirs = [DVec3::ZERO; (TILE * TILE) as usize];
            tile_dirs(span.start, y, (1 << TILE) - 1, &mut dirs);
            for x in span {
                let k = y * w + x;
                let bit = 1 << (row_shift + x % TILE as usize);
                if missed & bit != 0 {
                    if shown & bit == 0 {
                        row.surface(x, &HitRecord::MISS);
                        row.radiance[x] = sky;
                    }
                    shaded_here |= bit;
                    continue;
                }
                if let Some((_, prev)) = shade_from {
                    if kept_hit(x, y) && (reshade_row >> (x % TILE as usize)) & 1 == 0 {
                        kept += 1;
                        if fresh {
                            summary = summary.with(&records[k]);
                        }
                        if !patch {
                            row.surface(x, &records[k]);
                            row.radiance[x] = prev.radiance[k];
                        }
                        continue;
                    }
                }
                let r = &records[k];
                summary = summary.with(r);
                shaded_here |= bit;
                let (albedo, ks, shininess) = row.surface(x, r);
                row.radiance[x] = if r.instance < 0 {
                    sky
                } else {
                    let ambient_term = match ambient {
                        Some(_) => ambient_terms[k],
                        // The sky is uniform, so the ambient term of either lobe is its
                        // reflectance × sky.
                        None => (albedo + Vec3::splat(ks)) * sky,
                    };
                    let d = dirs[x % TILE as usize];
                    let mut blocker = SUN_FREE;
                    let radiance = direct_light(
                        r,
                        (albedo, ks, shininess),
                        camera.eye,
                        d,
                        lights,
                        &emitters,
                        k as u32,
                        &mut |start, dir, t_max, sun_ray| {
                            if !plan.shadows {
                                return true;
                            }
                            row_shadow_rays += 1;
                            if sun_ray {
                                match sun_rays.get(x, y) {
                                    SunRay::Free => return true,
                                    SunRay::Blocked(i) => {
                                        blocker = i;
                                        return false;
                                    }
                                    SunRay::Untraced => {}
                                }
                            }
                            let blocked = occluded(&fi, start, dir, t_max, search, opts.max_level);
                            if sun_ray && blocked {
                                // Traced alone: which instance blocked it is not known.
                                blocker = SUN_UNKNOWN;
                            }
                            !blocked
                        },
                        shadow_cone,
                    );
                    row.sun_blocker[x] = blocker;
                    ambient_term + radiance
                };
            }
            if fresh {
                new_tiles[fresh_slot[t] as usize].add(&summary);
            }
            if shaded_here != 0 && shade_from.is_some() {
                shaded[t].fetch_or(shaded_here, Ordering::Relaxed);
            }
        }
        [kept, row_shadow_rays]
    };
    let [shade_reused, shadow_rays] = for_frame_rows(&mut f, &mut sun_blockers, shading, ticks);
    let colours_from_buffer = shade_from.is_some();
    f.reused = n as u64 - traced.rays;
    f.shadow_rays = shadow_rays;
    f.shade_reused = shade_reused;
    if let Some(b) = hits {
        b.reused = f.reused;
        b.splats = splat_cache;
        if plan.keep_hits && !splatting {
            b.store(camera, scene, &prepared, records, opts.max_level);
            // Last frame's summaries, but where formed afresh.
            let mut tiles = match old_tiles.len() == tile_count {
                true => old_tiles,
                false => vec![TileSummary::NONE; tile_count],
            };
            for (acc, &t) in new_tiles.iter().zip(&fresh_tiles) {
                tiles[t as usize] = acc.load();
            }
            b.tiles = tiles;
            if colours_from_buffer {
                // Its colours are this frame's but where pixels were shaded afresh.
                let shaded: Vec<u64> = shaded.into_iter().map(AtomicU64::into_inner).collect();
                b.keep_shading_changed(&f.radiance, &f.ao, w, &shaded);
            } else {
                b.keep_shading(lights, plan.shadows, &f.radiance, &f.ao);
            }
            b.lit_by_gi = ambient.is_some();
        } else {
            // Nothing to keep: a later frame with the buffer switched on starts afresh. The
            // records' memory stays for the next frame to overwrite (every pixel is written
            // when nothing is reused), which spares the page faults of fresh memory.
            b.camera = None;
            b.records = records;
        }
        b.records_missed(traced.missed, camera.width, camera.height);
        b.rendered(Rendered::of(&f, sky));
        if bvh.is_some() || !plan.bvh {
            b.bvh = bvh;
        }
        b.pixel_spheres = lists;
        b.sun_blockers = sun_blockers;
        b.prepared = prepared;
        b.prepared_spheres = spheres;
    }
    Ok((f, ambient_ms))
}
