//! The path-traced reference that GI is measured against: the same SVO instances, materials
//! and lights as the renderer (DESIGN.md's units), the renderer's two-sided surface model
//! ([`crate::render::brdf`]: Lambertian plus an optional Phong lobe), the sun by next-event
//! estimation with a shadow ray at every vertex, the uniform sky when a path escapes, MTL
//! emitters by next-event estimation too when they are sampled as lights (one point on them
//! per vertex, drawn as [`crate::render::emitters`] does; a path that then hits an emitter
//! does not count its glow again), else when a path hits them. Unbiased: each bounce samples the surface model (lobe by
//! reflectance, then cosine- or lobe-weighted) and, when the bounce count is unlimited,
//! Russian roulette ends paths. Progressive: each [`PathTracer::pass`]
//! adds one sample per pixel and [`PathTracer::frame`] is the estimate so far.
//!
//! Primary rays go through pixel centres, exactly as the renderer's, so the reference and a
//! GI frame share every primary hit and differ only in the light they gather; the sun's and
//! the glow's light at the primary hit is deterministic and computed once.

use super::triangles::TriangleScene;
use crate::render::brdf;
use crate::render::bvh::Bvh;
use crate::render::cpu::{hit_record, leave, par_map};
use crate::render::emitters::{emitter_light, EmitterShadows, EmitterTable};
use crate::render::hitbuffer::HitRecord;
use crate::render::instances::{prepare, Prepared};
use crate::render::visibility::{nearest, occluded, FrameInstances, Search};
use crate::render::Frame;
use crate::rng::Rng;
use crate::scene::{Camera, Lights, Scene};
use crate::traverse::TraceOptions;
use glam::{DVec3, Vec3};

/// Most samples per pixel one reference may ask for.
pub const MAX_SPP: u32 = 1 << 20;
/// Most bounces a bounded reference may ask for.
pub const MAX_BOUNCES: u32 = 64;
/// Bounces before Russian roulette may end an unbounded path.
const ROULETTE_AFTER: u32 = 3;

/// How the reference is computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReferenceSettings {
    /// Samples per pixel.
    pub spp: u32,
    /// Indirect bounces: `Some(1)` is the one-bounce image a single GI bounce approximates
    /// (the light arriving at a surface was emitted or sent by the sun from one other
    /// surface); `None` follows paths until Russian roulette ends them (all bounces).
    pub bounces: Option<u32>,
    /// Seed of the sample sequence.
    pub seed: u64,
}

impl Default for ReferenceSettings {
    fn default() -> Self {
        ReferenceSettings { spp: 256, bounces: None, seed: 1 }
    }
}

/// Invalid reference settings.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ReferenceError {
    /// Samples per pixel out of range.
    #[error("samples per pixel must be 1…{MAX_SPP}, not {0}")]
    Spp(u32),
    /// Too many bounces.
    #[error("bounces must be 0…{MAX_BOUNCES} (leave them unset for unlimited), not {0}")]
    Bounces(u32),
    /// The source triangles cannot stand in for the scene.
    #[error(transparent)]
    Triangles(#[from] super::triangles::TriangleSceneError),
}

impl ReferenceSettings {
    /// Checks the settings.
    pub fn validated(self) -> Result<Self, ReferenceError> {
        if !(1..=MAX_SPP).contains(&self.spp) {
            return Err(ReferenceError::Spp(self.spp));
        }
        if let Some(b) = self.bounces.filter(|&b| b > MAX_BOUNCES) {
            return Err(ReferenceError::Bounces(b));
        }
        Ok(self)
    }
}

/// A progressive path tracer over one posed scene and camera.
pub struct PathTracer<'a> {
    scene: &'a Scene,
    lights: Lights,
    settings: ReferenceSettings,
    prepared: Vec<Prepared>,
    bvh: Option<Bvh>,
    search: Search,
    /// Primary hits, one per pixel.
    records: Vec<HitRecord>,
    /// The emitters as lights (empty when they are not sampled).
    emitters: EmitterTable,
    /// The source triangles, when the paths are traced through them instead of the voxels.
    triangles: Option<TriangleScene>,
    /// The camera's eye (hit points are relative to it).
    eye: DVec3,
    /// Camera-relative primary hit points.
    points: Vec<DVec3>,
    /// Deterministic part of each pixel: emission and sun at the primary hit, or the sky.
    direct: Vec<Vec3>,
    /// Summed indirect estimates (light leaving the primary hit towards the eye).
    sum: Vec<DVec3>,
    width: u32,
    height: u32,
    passes: u32,
    rays: u64,
}

impl<'a> PathTracer<'a> {
    /// Prepares the instances and traces the primary rays.
    pub fn new(
        scene: &'a Scene,
        camera: &Camera,
        lights: &Lights,
        settings: ReferenceSettings,
    ) -> Result<Self, ReferenceError> {
        Self::with_geometry(scene, None, camera, lights, settings)
    }

    /// [`PathTracer::new`] with every ray, primary ones included, traced through `mesh`'s
    /// triangles placed as the scene's instances (part i of the mesh at the scene's part i)
    /// instead of the voxels: an image independent of the voxelization. The lights, the
    /// materials (packed as the voxels pack them) and the emitters are the same.
    pub fn on_triangles(
        scene: &'a Scene,
        mesh: &crate::mesh::Mesh,
        camera: &Camera,
        lights: &Lights,
        settings: ReferenceSettings,
    ) -> Result<Self, ReferenceError> {
        let triangles = TriangleScene::new(mesh, scene, camera.eye)?;
        Self::with_geometry(scene, Some(triangles), camera, lights, settings)
    }

    fn with_geometry(
        scene: &'a Scene,
        triangles: Option<TriangleScene>,
        camera: &Camera,
        lights: &Lights,
        settings: ReferenceSettings,
    ) -> Result<Self, ReferenceError> {
        let settings = settings.validated()?;
        let prepared = prepare(scene, camera.eye, true);
        let (bvh, search) = Bvh::when_worthwhile(&prepared);
        let mut pt = PathTracer {
            scene,
            lights: lights.clone(),
            settings,
            prepared,
            bvh,
            search,
            records: Vec::new(),
            eye: camera.eye,
            emitters: if lights.emitter_sampling() > 0 {
                EmitterTable::new(scene, camera.eye)
            } else {
                EmitterTable::default()
            },
            triangles,
            points: Vec::new(),
            direct: Vec::new(),
            sum: Vec::new(),
            width: camera.width,
            height: camera.height,
            passes: 0,
            rays: 0,
        };
        let basis = camera.basis();
        let w = camera.width as usize;
        let n = w * camera.height as usize;
        let fi = pt.instances();
        let primary: Vec<(HitRecord, DVec3, Vec3, u64)> = par_map(n, |k| {
            let d = camera.ray_dir(&basis, (k % w) as u32, (k / w) as u32);
            match pt.cast(&fi, DVec3::ZERO, d) {
                None => (HitRecord::MISS, DVec3::ZERO, pt.lights.sky(), 1),
                Some(r) => {
                    let at = d * r.t as f64;
                    let (light, rays) = pt.surface_light(&fi, &r, at, d, true);
                    (r, at, light, 1 + rays)
                }
            }
        });
        pt.rays = primary.iter().map(|p| p.3).sum();
        pt.records = primary.iter().map(|p| p.0).collect();
        pt.points = primary.iter().map(|p| p.1).collect();
        pt.direct = primary.iter().map(|p| p.2).collect();
        pt.sum = vec![DVec3::ZERO; n];
        Ok(pt)
    }

    fn instances(&self) -> FrameInstances<'_> {
        FrameInstances { parts: &self.scene.parts, prepared: &self.prepared, bvh: self.bvh.as_ref(), starts: None }
    }

    /// The nearest hit from camera-relative `o` along unit `d`: the voxels' or the triangles'.
    fn cast(&self, fi: &FrameInstances, o: DVec3, d: DVec3) -> Option<HitRecord> {
        match &self.triangles {
            Some(t) => t.nearest(o, d),
            None => nearest(fi, o, d, self.search, &TraceOptions::default())
                .map(|h| hit_record(self.scene, &self.prepared, &h, d)),
        }
    }

    /// Whether something lies between `o` and `o + d·t_max`.
    fn blocked(&self, fi: &FrameInstances, o: DVec3, d: DVec3, t_max: f64) -> bool {
        match &self.triangles {
            Some(t) => t.occluded(o, d, t_max),
            None => occluded(fi, o, d, t_max, self.search, u32::MAX),
        }
    }

    /// Light leaving a surface towards the viewer (looking along `d`) that does not depend on
    /// other surfaces: its emission and the sun (when visible). Returns it and the shadow rays
    /// traced. When the emitters are sampled as lights ([`Self::emitter_sample`]), a path
    /// that reaches one after a bounce must not count its glow again: only the eye's own hit
    /// (`seen_by_eye`) shows it.
    fn surface_light(&self, fi: &FrameInstances, r: &HitRecord, at: DVec3, d: DVec3, seen_by_eye: bool) -> (Vec3, u64) {
        let glow = self.lights.use_mtl_emitters && (seen_by_eye || self.emitters.is_empty());
        let mut out = if glow { r.attr.emission() } else { Vec3::ZERO };
        let mut rays = 0;
        if let Some(sun) = self.lights.sun {
            if r.normal.dot(sun.to_sun) > 0.0 {
                rays += 1;
                if !self.blocked(fi, leave(r, at), sun.to_sun.as_dvec3(), f64::INFINITY) {
                    let shininess = brdf::shininess_of_gloss(r.attr.gloss());
                    let (albedo, ks) = (r.attr.albedo_linear(), r.attr.specular());
                    out +=
                        brdf::sun_response(albedo, ks, shininess, r.normal, d.as_vec3(), sun.to_sun) * sun.irradiance;
                }
            }
        }
        for inc in self.lights.incident_extra(self.eye + at) {
            let l = inc.to_light.as_vec3();
            if r.normal.dot(l) > 0.0 {
                rays += 1;
                if !self.blocked(fi, leave(r, at), inc.to_light, inc.distance) {
                    let shininess = brdf::shininess_of_gloss(r.attr.gloss());
                    let (albedo, ks) = (r.attr.albedo_linear(), r.attr.specular());
                    out += brdf::sun_response(albedo, ks, shininess, r.normal, d.as_vec3(), l) * inc.irradiance;
                }
            }
        }
        (out, rays)
    }

    /// One sample of the emitters' light reflected at hit `r` (at `at`, seen along `d`), with
    /// fresh random numbers, and the shadow rays it traced.
    fn emitter_sample(&self, fi: &FrameInstances, r: &HitRecord, at: DVec3, d: DVec3, rng: &mut Rng) -> (DVec3, u64) {
        if self.emitters.is_empty() {
            return (DVec3::ZERO, 0);
        }
        let mut rays = 0;
        let shininess = brdf::shininess_of_gloss(r.attr.gloss());
        let (albedo, ks) = (r.attr.albedo_linear(), r.attr.specular());
        let light = emitter_light(
            &self.emitters,
            1,
            rng.next_u64() as u32,
            at,
            leave(r, at),
            r.normal,
            d.as_vec3(),
            albedo,
            ks,
            shininess,
            EmitterShadows::Rays(&mut |o, dir, len| {
                rays += 1;
                !self.blocked(fi, o, dir, len)
            }),
        );
        (light.as_dvec3(), rays)
    }

    /// One estimate of the light leaving primary hit `k` towards the eye that depends on
    /// other surfaces (the surface model sampled at every vertex, the emitters sampled at
    /// every vertex, the primary one included), and the rays it traced.
    fn indirect(&self, fi: &FrameInstances, k: usize, rng: &mut Rng) -> (DVec3, u64) {
        let mut r = self.records[k];
        let mut at = self.points[k];
        let mut d = at.normalize();
        let mut beta = DVec3::ONE;
        let (mut light, mut rays) = self.emitter_sample(fi, &r, at, d, rng);
        let mut bounce = 1u32;
        loop {
            if self.settings.bounces.is_some_and(|b| bounce > b) {
                break;
            }
            let shininess = brdf::shininess_of_gloss(r.attr.gloss());
            let Some(s) =
                brdf::sample(r.attr.albedo_linear(), r.attr.specular(), shininess, r.normal.as_dvec3(), d, rng)
            else {
                break;
            };
            beta *= s.weight;
            let from = leave(&r, at);
            d = s.dir;
            rays += 1;
            let Some(hit) = self.cast(fi, from, d) else {
                light += beta * self.lights.sky().as_dvec3();
                break;
            };
            r = hit;
            at = from + d * r.t as f64;
            let (l, shadow) = self.surface_light(fi, &r, at, d, false);
            let (e, emitter_rays) = self.emitter_sample(fi, &r, at, d, rng);
            rays += shadow + emitter_rays;
            light += beta * (l.as_dvec3() + e);
            if self.settings.bounces.is_none() && bounce >= ROULETTE_AFTER {
                let keep = beta.max_element().clamp(0.05, 0.95);
                if rng.f64() >= keep {
                    break;
                }
                beta /= keep;
            }
            if beta == DVec3::ZERO {
                break;
            }
            bounce += 1;
        }
        (light, rays)
    }

    /// Adds one sample to every pixel that hit something.
    pub fn pass(&mut self) {
        let fi = self.instances();
        let pass = self.passes as u64;
        let seed = self.settings.seed;
        let samples: Vec<(DVec3, u64)> = par_map(self.records.len(), |k| {
            if self.records[k].instance < 0 {
                return (DVec3::ZERO, 0);
            }
            // A stream per pixel and pass, so the image does not depend on the thread count.
            let mut rng = Rng::new(seed ^ (pass << 40) ^ (k as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
            rng.next_u64();
            self.indirect(&fi, k, &mut rng)
        });
        for (s, (l, rays)) in self.sum.iter_mut().zip(samples) {
            *s += l;
            self.rays += rays;
        }
        self.passes += 1;
    }

    /// Runs the remaining passes up to the settings' sample count, calling `progress(done,
    /// of)` after each.
    pub fn run(&mut self, progress: &mut dyn FnMut(u32, u32)) {
        while self.passes < self.settings.spp {
            self.pass();
            progress(self.passes, self.settings.spp);
        }
    }

    /// Samples per pixel so far.
    pub fn samples(&self) -> u32 {
        self.passes
    }

    /// Rays traced so far (primary, shadow and bounce rays).
    pub fn rays(&self) -> u64 {
        self.rays
    }

    /// The estimate so far, with the primary hits' AOVs.
    pub fn frame(&self) -> Frame {
        let inv = 1.0 / self.passes.max(1) as f64;
        let radiance = self
            .records
            .iter()
            .zip(&self.direct)
            .zip(&self.sum)
            .map(|((r, d), s)| if r.instance < 0 { *d } else { *d + (*s * inv).as_vec3() })
            .collect();
        let n = self.records.len();
        Frame {
            width: self.width,
            height: self.height,
            radiance,
            t: self.records.iter().map(|r| r.t).collect(),
            instance: self.records.iter().map(|r| r.instance).collect(),
            normal: self.records.iter().map(|r| r.normal).collect(),
            albedo: self
                .records
                .iter()
                .map(|r| if r.instance >= 0 { r.attr.albedo_linear() } else { Vec3::ZERO })
                .collect(),
            specular: self.records.iter().map(|r| if r.instance >= 0 { r.attr.specular() } else { 0.0 }).collect(),
            shininess: self.records.iter().map(|r| brdf::shininess_of_gloss(r.attr.gloss())).collect(),
            primary_rays: n as u64,
            ..Frame::default()
        }
    }
}

/// Path-traces `scene` seen by `camera` to `settings.spp` samples per pixel.
pub fn path_trace(
    scene: &Scene,
    camera: &Camera,
    lights: &Lights,
    settings: ReferenceSettings,
    progress: &mut dyn FnMut(u32, u32),
) -> Result<Frame, ReferenceError> {
    let mut pt = PathTracer::new(scene, camera, lights, settings)?;
    pt.run(progress);
    Ok(pt.frame())
}
