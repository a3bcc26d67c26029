//! Rays against a posed scene, for a library caller with rays of its own (picking, physics,
//! visibility queries, ambient occlusion): nearest hits and occlusion, one ray or a batch in
//! parallel, on the CPU.
//!
//! A [`SceneCaster`] is made once per pose of the scene: it prepares every instance (the ray
//! map into its octree and its bounding sphere, relative to a reference point kept in f64)
//! and, from [`BVH_MIN_INSTANCES`] instances on, builds the instance BVH over the spheres.
//! Each ray then goes through [`render::visibility`](crate::render::visibility) as the
//! renderer's own rays do, and a batch goes in runs of 64 rays through the tiles' packet
//! search ([`render::tile_search`](crate::render::tile_search); with an instance BVH, the
//! run walks it together: [`render::packet_bvh`](crate::render::packet_bvh)), so a hit
//! is bit for bit the one the frame's search would find (every search agrees with the plain
//! "trace every instance" one; the tests hold both to the DDA oracle).
//!
//! ```
//! use glam::{DVec3, Vec3};
//! use std::sync::Arc;
//! use voxray::cast::{CastRay, SceneCaster};
//! use voxray::scene::{Instance, Scene, Transform};
//! use voxray::svo::{self, Cube};
//! use voxray::voxelize::VoxelGrid;
//!
//! // A 4³ block of voxels in the unit cube, placed twice: at the origin and 3 units up x.
//! let coords = (0..64u32).map(|i| [i % 4, i / 4 % 4, i / 16]);
//! let grid = VoxelGrid::from_coords(2, Cube { min: Vec3::ZERO, size: 1.0 }, coords, Vec3::ONE);
//! let mut scene = Scene::new(vec![Arc::new(svo::build(&grid)?)]);
//! for x in [0.0, 3.0] {
//!     let local = Transform::from_translation(DVec3::new(x, 0.0, 0.0));
//!     scene.add(Instance { part: 0, parent: None, local })?;
//! }
//! scene.update()?;
//!
//! let caster = SceneCaster::new(&scene)?;
//! // Along −x from x = 10: the second block's face at x = 4 comes first.
//! let hit = caster.nearest(DVec3::new(10.0, 0.5, 0.5), DVec3::NEG_X).expect("a hit");
//! assert_eq!(hit.instance, 1);
//! assert!((hit.t - 6.0).abs() < 1e-4);
//! // A batch, in parallel: the same answers.
//! let rays = [CastRay::new(DVec3::new(10.0, 0.5, 0.5), DVec3::NEG_X), CastRay::new(DVec3::splat(0.5), DVec3::Y)];
//! let hits = caster.nearest_all(&rays);
//! assert_eq!(hits[0].map(|h| h.instance), Some(1));
//! // The second ray starts inside the first block: it hits where it starts.
//! assert_eq!(hits[1].map(|h| (h.instance, h.t)), Some((0, 0.0)));
//! // Occlusion up to a distance: from between the blocks, towards the second, 1 unit away.
//! let towards = CastRay::new(DVec3::new(2.0, 0.5, 0.5), DVec3::X);
//! assert_eq!(caster.occluded_all(&[towards.up_to(0.5), towards.up_to(1.5)]), [false, true]);
//! # Ok::<(), voxray::Error>(())
//! ```

use crate::render::bvh::Bvh;
use crate::render::instances::{prepare_into, Prepared};
use crate::render::packet_bvh::{nearest_packet_bvh, occluded_rays_bvh};
use crate::render::plan::BVH_MIN_INSTANCES;
use crate::render::tile_search::{each, nearest_packet, occluded_rays, Origins, TileScratch};
use crate::render::visibility::{nearest, occluded, FrameInstances, InstanceHit, Search, Work};
use crate::scene::Scene;
use crate::svo::Svo;
use crate::traverse::packet::LANES;
use crate::traverse::{Hit, TraceOptions};
use glam::{DVec3, Vec3};
use std::sync::Arc;

/// Why a [`SceneCaster`] could not be made.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CastError {
    /// Instances were changed and [`Scene::update`] not called since: their world
    /// transforms are last pose's.
    #[error("the scene has changes not yet applied: call Scene::update before casting rays")]
    NotUpdated,
    /// The reference point is not finite.
    #[error("the reference point must be finite, got {0:?}")]
    Reference([f64; 3]),
}

/// One ray: origin and direction in world space, and how far it reaches. The direction need
/// not have unit length; distances are along it normalized.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CastRay {
    /// Where the ray starts (world space).
    pub origin: DVec3,
    /// Where it goes (world space, any length but zero).
    pub dir: DVec3,
    /// How far it reaches: a hit farther away is none, and occlusion is tested up to here
    /// (∞: the whole ray; not above 0, or not a number: nothing).
    pub t_max: f64,
}

impl CastRay {
    /// A ray from `origin` along `dir`, as far as it goes.
    pub fn new(origin: DVec3, dir: DVec3) -> CastRay {
        CastRay { origin, dir, t_max: f64::INFINITY }
    }

    /// This ray reaching only up to distance `t_max` (a shadow ray towards a light at that
    /// distance, an ambient-occlusion radius).
    pub fn up_to(self, t_max: f64) -> CastRay {
        CastRay { t_max, ..self }
    }
}

/// What a ray hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneHit {
    /// The instance hit (its index in the scene).
    pub instance: usize,
    /// The part that instance places.
    pub part: usize,
    /// Distance from the ray's origin to where it enters the voxel (0 when it starts
    /// inside one).
    pub t: f64,
    /// The entry point, world space.
    pub position: DVec3,
    /// The voxel's stored surface normal, world space, unit length.
    pub normal: DVec3,
    /// The voxel's linear albedo.
    pub albedo: Vec3,
    /// The voxel as the octree holds it (object-space normals, level, coordinates,
    /// attributes).
    pub voxel: Hit,
}

/// Casts rays at one pose of a scene: see the module documentation.
pub struct SceneCaster {
    parts: Vec<Arc<Svo>>,
    prepared: Vec<Prepared>,
    bvh: Option<Bvh>,
    /// The point the instances were prepared relative to.
    reference: DVec3,
    opts: TraceOptions,
}

impl SceneCaster {
    /// Prepares `scene` (updated) for rays down to its voxels, relative to the centre of its
    /// bounds.
    pub fn new(scene: &Scene) -> Result<SceneCaster, CastError> {
        let (lo, hi) = scene.bounds();
        let centre = 0.5 * (lo + hi);
        Self::with(scene, if centre.is_finite() { centre } else { DVec3::ZERO }, u32::MAX)
    }

    /// [`SceneCaster::new`] with the instances prepared relative to `reference` (rays and
    /// hits stay in world space; a reference near the rays' origins keeps the most precision,
    /// as the renderer prepares its instances relative to the eye) and traversal stopped at
    /// octree level `max_level` (level of detail; `u32::MAX`: the voxels).
    pub fn with(scene: &Scene, reference: DVec3, max_level: u32) -> Result<SceneCaster, CastError> {
        if scene.is_dirty() {
            return Err(CastError::NotUpdated);
        }
        if !reference.is_finite() {
            return Err(CastError::Reference(reference.to_array()));
        }
        let mut prepared = Vec::new();
        prepare_into(scene, reference, true, max_level, &mut prepared);
        let bvh = (prepared.len() >= BVH_MIN_INSTANCES)
            .then(|| Bvh::build(&prepared.iter().map(|p| (p.centre, p.radius)).collect::<Vec<_>>()));
        Ok(SceneCaster {
            parts: scene.parts.clone(),
            prepared,
            bvh,
            reference,
            opts: TraceOptions { max_level, ..TraceOptions::default() },
        })
    }

    /// How many instances it casts against.
    pub fn instances(&self) -> usize {
        self.prepared.len()
    }

    fn frame(&self) -> FrameInstances<'_> {
        FrameInstances { parts: &self.parts, prepared: &self.prepared, bvh: self.bvh.as_ref(), starts: None }
    }

    fn search(&self) -> Search {
        if self.bvh.is_some() {
            Search::Bvh
        } else {
            Search::CullSort
        }
    }

    /// The ray relative to the reference point with a unit direction, or None when it has
    /// none (an origin or direction not finite, a zero direction): such a ray hits nothing.
    fn relative(&self, origin: DVec3, dir: DVec3) -> Option<(DVec3, DVec3)> {
        let d = dir.normalize_or_zero();
        (origin.is_finite() && d != DVec3::ZERO).then(|| (origin - self.reference, d))
    }

    /// The nearest hit along the ray from `origin` in direction `dir` (world space); None
    /// when it hits nothing (or has no direction: see [`CastRay`]).
    pub fn nearest(&self, origin: DVec3, dir: DVec3) -> Option<SceneHit> {
        self.nearest_ray(&CastRay::new(origin, dir))
    }

    /// [`SceneCaster::nearest`] of one [`CastRay`], within its `t_max`.
    pub fn nearest_ray(&self, r: &CastRay) -> Option<SceneHit> {
        let (o, d) = self.relative(r.origin, r.dir)?;
        let found = nearest(&self.frame(), o, d, self.search(), &self.opts)?;
        self.scene_hit(r, d, found)
    }

    /// What ray `r` (unit direction `d`) hit, given its nearest hit `found`: None beyond its
    /// reach.
    fn scene_hit(&self, r: &CastRay, d: DVec3, found: InstanceHit) -> Option<SceneHit> {
        let p = &self.prepared[found.instance];
        let t = found.hit.t as f64;
        // (The nearest hit beyond the reach: none within it. Compared in f64 as the GPU's.)
        if !(t <= r.t_max) {
            return None;
        }
        let n = p.normal_to_world(found.hit.normal().as_dvec3()).normalize_or_zero();
        Some(SceneHit {
            instance: found.instance,
            part: p.part,
            t,
            position: r.origin + d * t,
            normal: n,
            albedo: found.hit.albedo(),
            voxel: found.hit,
        })
    }

    /// Up to [`LANES`] rays relative to the reference point with unit directions, written to
    /// `origins` and `dirs`: the lanes that have one (see [`Self::relative`]).
    fn packet(&self, rays: &[CastRay], origins: &mut [DVec3; LANES], dirs: &mut [DVec3; LANES]) -> u64 {
        let mut lanes = 0u64;
        for (k, r) in rays.iter().enumerate().take(LANES) {
            if let Some((o, d)) = self.relative(r.origin, r.dir) {
                (origins[k], dirs[k]) = (o, d);
                lanes |= 1 << k;
            }
        }
        lanes
    }

    /// Whether anything lies on the ray from `origin` in direction `dir` within distance
    /// `t_max` (∞: anywhere along it); false for a ray without direction or a `t_max` that
    /// is not above 0.
    pub fn occluded(&self, origin: DVec3, dir: DVec3, t_max: f64) -> bool {
        match self.relative(origin, dir) {
            Some((o, d)) if t_max > 0.0 => occluded(&self.frame(), o, d, t_max, self.search(), self.opts.max_level),
            _ => false,
        }
    }

    /// [`SceneCaster::nearest_ray`] of every ray, in parallel (with the `parallel` feature).
    ///
    /// Runs of [`LANES`] consecutive rays go through each octree together, as packets (the
    /// renderer's tiles do, [`crate::traverse::packet`]), with the same answers as one by
    /// one: rays in an order that keeps neighbours close (a camera's, row by row; each hit's
    /// own rays in turn) trace fastest. In a scene of [`BVH_MIN_INSTANCES`] instances or more
    /// a run walks the instance BVH together, each instance it reaches traced as one packet
    /// ([`crate::render::packet_bvh`]).
    pub fn nearest_all(&self, rays: &[CastRay]) -> Vec<Option<SceneHit>> {
        collect_runs(rays, |run, out| self.nearest_run(run, out))
    }

    /// [`Self::nearest_all`] written into `out` (resized to the rays' count): a caller that
    /// casts batch after batch keeps one buffer, whose memory is then not faulted in again
    /// for each (a third of a batch of camera rays' time, `docs/benchmarks.md`).
    pub fn nearest_into(&self, rays: &[CastRay], out: &mut Vec<Option<SceneHit>>) {
        fill_runs(rays, out, |run, out| self.nearest_run(run, out));
    }

    /// [`SceneCaster::occluded`] of every ray within its `t_max`, in parallel (with the
    /// `parallel` feature); as [`Self::nearest_all`], runs of consecutive rays as packets.
    pub fn occluded_all(&self, rays: &[CastRay]) -> Vec<bool> {
        collect_runs(rays, |run, out| self.occluded_run(run, out))
    }

    /// [`Self::occluded_all`] written into `out` (resized to the rays' count), as
    /// [`Self::nearest_into`].
    pub fn occluded_into(&self, rays: &[CastRay], out: &mut Vec<bool>) {
        fill_runs(rays, out, |run, out| self.occluded_run(run, out));
    }

    /// The nearest hits of a run of up to [`LANES`] rays, into `out` (as long as the run).
    fn nearest_run(&self, run: &[CastRay], out: &mut [Option<SceneHit>]) {
        let (mut origins, mut dirs) = ([DVec3::ZERO; LANES], [DVec3::ZERO; LANES]);
        let lanes = self.packet(run, &mut origins, &mut dirs);
        // Rays from one point (a camera's) are set up four at a time.
        let first = origins[lanes.trailing_zeros().min(LANES as u32 - 1) as usize];
        let bits = |o: DVec3| o.to_array().map(f64::to_bits);
        let origins = match each(lanes).all(|k| bits(origins[k]) == bits(first)) {
            true => Origins::One(first),
            false => Origins::Each(&origins),
        };
        let mut found = [None; LANES];
        let (fi, w) = (self.frame(), &mut Work::default());
        match self.bvh {
            Some(_) => {
                TileScratch::with(|s| nearest_packet_bvh(&fi, origins, &dirs, lanes, &self.opts, w, s, &mut found))
            }
            None => TileScratch::with(|s| {
                nearest_packet(&fi, origins, &dirs, lanes, self.search(), &self.opts, w, s, &mut found, None, None)
            }),
        }
        for (k, o) in out.iter_mut().enumerate() {
            *o = found[k].and_then(|f| self.scene_hit(&run[k], dirs[k], f));
        }
    }

    /// Whether each ray of a run of up to [`LANES`] is blocked within its reach, into `out`
    /// (as long as the run).
    fn occluded_run(&self, run: &[CastRay], out: &mut [bool]) {
        let (mut origins, mut dirs) = ([DVec3::ZERO; LANES], [DVec3::ZERO; LANES]);
        let mut lanes = self.packet(run, &mut origins, &mut dirs);
        let mut t_max = [0.0; LANES];
        for k in each(lanes) {
            t_max[k] = run[k].t_max;
            // (Nothing within a reach that is not above 0, or not a number.)
            if !(t_max[k] > 0.0) {
                lanes &= !(1 << k);
            }
        }
        let (fi, search, max_level) = (self.frame(), self.search(), self.opts.max_level);
        let blocked = match self.bvh {
            Some(_) => TileScratch::with(|s| occluded_rays_bvh(&fi, &origins, &dirs, &t_max, lanes, max_level, s)),
            None => TileScratch::with(|s| occluded_rays(&fi, &origins, &dirs, &t_max, lanes, search, max_level, s)),
        };
        for (k, o) in out.iter_mut().enumerate() {
            *o = blocked >> k & 1 != 0;
        }
    }
}

/// `f` of every run of [`LANES`] consecutive rays (writing the run's answers), collected in
/// order: in parallel with the `parallel` feature, each run's answers written where they
/// stay by the thread that found them (filled on one thread first, the fresh pages cost a
/// tenth of a batch of camera rays).
fn collect_runs<T: Send + Default + Copy>(rays: &[CastRay], f: impl Fn(&[CastRay], &mut [T]) + Sync + Send) -> Vec<T> {
    let run = |r: &[CastRay]| {
        let mut out = [T::default(); LANES];
        f(r, &mut out[..r.len()]);
        out
    };
    #[cfg(feature = "parallel")]
    let runs: Vec<[T; LANES]> = {
        use rayon::prelude::*;
        rays.par_chunks(LANES).with_min_len(4).map(run).collect()
    };
    #[cfg(not(feature = "parallel"))]
    let runs: Vec<[T; LANES]> = rays.chunks(LANES).map(run).collect();
    let mut out = runs.into_flattened();
    out.truncate(rays.len());
    out
}

/// `f` of every run of [`LANES`] consecutive rays, writing the run's answers into `out`
/// (resized to the rays' count): in parallel with the `parallel` feature.
fn fill_runs<T: Send + Default + Clone>(
    rays: &[CastRay],
    out: &mut Vec<T>,
    f: impl Fn(&[CastRay], &mut [T]) + Sync + Send,
) {
    out.resize(rays.len(), T::default());
    #[cfg(feature = "parallel")]
    {
        use rayon::prelude::*;
        out.par_chunks_mut(LANES).zip(rays.par_chunks(LANES)).with_min_len(4).for_each(|(o, r)| f(r, o));
    }
    #[cfg(not(feature = "parallel"))]
    for (o, r) in out.chunks_mut(LANES).zip(rays.chunks(LANES)) {
        f(r, o);
    }
}
