//! The benchmark matrix: scenarios × settings on one backend (the caller loops over
//! backends). Scenarios follow the animated-SVO paper's static / animated / animated+optimized
//! comparison, then scale instances, resolution and the level of detail (with the image error
//! against the full-depth reference, so error can be read against run time).

use super::{metrics, run_clip, Clip, Record};
use crate::cast::{CastRay, SceneCaster};
use crate::render::{Features, Frame, Renderer, SplatDraw};
use crate::scene::{stage_cars, Camera, Instance, Lights, Scene, Transform};
use crate::session::Session;
use crate::svo::Svo;
use std::sync::Arc;

/// A family of measurements.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scenario {
    /// (a) the car merged into one static SVO, (b) its 8 animated parts with every
    /// optimization off, (c) animated with culling, sorting and the hit buffer, (d) (c) plus
    /// the BVH and shadow rays (everything the default plan uses).
    Paper,
    /// Car count sweep, instance BVH against depth-sorted spheres.
    Instances,
    /// Image size sweep, animated and optimized.
    Resolution,
    /// Level-of-detail sweep with image error against full depth.
    Depth,
    /// Square splats against ray tracing: a car count sweep and a level (voxel count) sweep,
    /// frame time and the splat image's error against the traced one.
    Splat,
    /// A library caller's own rays through the scene caster ([`crate::cast::SceneCaster`], on
    /// the GPU `gpu::cast::GpuSceneCaster`): the car on its ground and a parked crowd on
    /// theirs, every pixel's camera ray and one ambient-occlusion ray from each of their hits,
    /// one batch per call.
    Cast,
}

impl std::str::FromStr for Scenario {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "paper" => Ok(Scenario::Paper),
            "instances" => Ok(Scenario::Instances),
            "resolution" => Ok(Scenario::Resolution),
            "depth" | "lod" => Ok(Scenario::Depth),
            "splat" => Ok(Scenario::Splat),
            "cast" => Ok(Scenario::Cast),
            other => Err(format!(
                "unknown scenario '{other}' (the scenarios: paper, instances, resolution, depth, splat, cast, peers, gi-scaling, gi-volume, gi-accuracy)"
            )),
        }
    }
}

impl Scenario {
    /// The record group name.
    pub fn group(self) -> &'static str {
        match self {
            Scenario::Paper => "paper",
            Scenario::Instances => "instances",
            Scenario::Resolution => "resolution",
            Scenario::Depth => "depth",
            Scenario::Splat => "splat",
            Scenario::Cast => "cast",
        }
    }
}

/// What to measure.
#[derive(Clone, Debug)]
pub struct MatrixConfig {
    /// Scenario families, in order.
    pub scenarios: Vec<Scenario>,
    /// Untimed frames before each measurement.
    pub warmup: usize,
    /// Timed frames of the paper, resolution and depth scenarios and of the instance sweep's
    /// BVH points.
    pub frames: usize,
    /// Image size of the paper and depth scenarios.
    pub size: (u32, u32),
    /// Car counts of the instance sweep.
    pub cars: Vec<usize>,
    /// Timed frames per instance-sweep point with depth-sorted spheres (its BVH points time
    /// [`MatrixConfig::frames`]).
    pub sweep_frames: usize,
    /// Image size of the instance sweep.
    pub sweep_size: (u32, u32),
    /// On the GPU backend, the instance sweep's BVH points pose their cars on the GPU
    /// ([`Clip::pose_on_gpu`]); else on the host, as on the CPU.
    pub crowd_on_gpu: bool,
    /// Image sizes of the resolution sweep.
    pub resolutions: Vec<(u32, u32)>,
    /// LOD levels of the depth sweep (empty: every level from 3 below full depth); full
    /// depth is always measured as the reference.
    pub lod_levels: Vec<u32>,
    /// The command line, stored with every record.
    pub command: String,
    /// The machine, stored with every record.
    pub machine: String,
}

/// The car as the matrix needs it.
pub struct CarModel {
    /// The eight parts ([`crate::model::car::PART_NAMES`] order).
    pub parts: Vec<Arc<Svo>>,
    /// The whole car merged into one SVO (the static baseline).
    pub merged: Arc<Svo>,
}

impl MatrixConfig {
    /// Measurements [`run`] will make (for a progress bar).
    pub fn steps(&self) -> usize {
        self.scenarios
            .iter()
            .map(|s| match s {
                Scenario::Paper => 4,
                Scenario::Instances => 2 * self.cars.len(),
                Scenario::Resolution => self.resolutions.len(),
                Scenario::Depth => 1 + self.lod_levels.len().max(3),
                Scenario::Splat => 2 * (self.cars.len() + 1 + self.lod_levels.len().max(3)),
                Scenario::Cast => 6,
            })
            .sum()
    }
}

/// What the scenarios measure: the default car (every scenario), or a scene file as staged
/// with its animation (the paper comparison against its merged triangles, and the resolution
/// and depth sweeps; the instance sweep is built around the car's figure-eights and is
/// skipped). A file's records go to the groups `scene-paper`, `scene-resolution` and
/// `scene-depth`, named after it, apart from the car's.
pub enum Subject<'a> {
    /// The default car's parts and its merged static SVO.
    Car(&'a CarModel),
    /// A staged scene file and its name.
    File {
        /// The scene, its animation and the bounds of its whole clip.
        staged: &'a mut crate::scene::Staged,
        /// The file's name, for the records.
        name: String,
        /// Its triangles at time 0 merged into one SVO, the paper comparison's static
        /// baseline (None for a file without triangles: the comparison is skipped).
        merged: Option<Arc<Svo>>,
    },
}

/// The scene a sweep runs on: the file's, or one car on its ground staged into `slot`; and
/// the prefix of its records' names.
fn sweep_scene<'s>(
    file: Option<(&'s mut crate::scene::Staged, &str, Option<Arc<Svo>>)>,
    car: Option<&CarModel>,
    slot: &'s mut Option<crate::scene::Staged>,
) -> Result<(&'s mut crate::scene::Staged, String), crate::Error> {
    match file {
        Some((st, name, _)) => Ok((st, format!("{name}: "))),
        None => {
            let car = car.ok_or(crate::Error::CarParts { got: 0 })?;
            Ok((slot.insert(stage_cars(&car.parts, 1, false, true)?), String::new()))
        }
    }
}

/// A record named for its place in the matrix.
fn label(r: Record, cfg: &MatrixConfig, group: &str, name: String, setting: String, x: f64) -> Record {
    Record { group: group.into(), name, setting, x, command: cfg.command.clone(), machine: cfg.machine.clone(), ..r }
}

/// One crowd's clip for the instance sweep: with the BVH or with depth-sorted spheres,
/// primary rays only, no hit buffer.
fn crowd_clip<'a>(
    st: &'a mut crate::scene::Staged,
    camera: &'a Camera,
    lights: &'a Lights,
    bvh: bool,
    on_gpu: bool,
    warmup: usize,
    frames: usize,
) -> Clip<'a> {
    Clip {
        scene: &mut st.scene,
        cars: &st.cars,
        animated: None,
        renderer: Renderer::Trace,
        splat_draw: SplatDraw::Compute,
        camera,
        lights,
        features: Features { bvh, hit_buffer: false, shadows: false, ..Features::default() },
        lod: u32::MAX,
        warmup,
        frames,
        fps: 30.0,
        // The GPU poses the crowd and refits its tree itself (the walk it needs).
        pose_on_gpu: bvh && on_gpu,
    }
}

/// Rounds the instance sweep's BVH points are timed in (see [`run`]).
pub const INSTANCE_ROUNDS: usize = 5;

/// `n` cars driving their figure-eights with no ground, and the sweep's camera framing them all.
fn crowd(car: &CarModel, n: usize, cfg: &MatrixConfig) -> Result<(crate::scene::Staged, Camera), crate::Error> {
    let st = stage_cars(&car.parts, n, true, false)?;
    let camera = Camera::framing(st.bounds.0.as_vec3(), st.bounds.1.as_vec3(), cfg.sweep_size.0, cfg.sweep_size.1);
    Ok((st, camera))
}

/// The box a sweep's camera frames: a file's whole clip, the parked car as it stands.
fn framed(st: &crate::scene::Staged) -> (glam::DVec3, glam::DVec3) {
    if st.animated.is_some() {
        st.bounds
    } else {
        st.cars_bounds()
    }
}

/// What a batch of the cast scenario asks of each ray.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Query {
    /// Its nearest hit (`nearest_into`).
    Nearest,
    /// Whether anything lies within its reach (`occluded_into`).
    Occluded,
}

/// One batch of the cast scenario: its name, what it asks and its rays.
type CastBatch = (&'static str, Query, Vec<CastRay>);

/// How far the cast scenario's occlusion rays reach: half a metre on the car (a part's
/// neighbourhood, as ambient occlusion asks).
const OCCLUSION_REACH: f64 = 0.5;

/// Cars of the cast scenario's crowd: parked in rows on their ground, 801 instances, past
/// the scene caster's instance-BVH threshold ([`crate::render::plan::BVH_MIN_INSTANCES`]).
const CAST_CROWD_CARS: usize = 100;

/// The cast scenario's three batches: every pixel's camera ray, and from each of their hits
/// (found by the CPU's caster, so that both backends cast the same rays) one ray into the
/// hemisphere around its normal, from just off the surface, asked for its nearest hit and,
/// within [`OCCLUSION_REACH`], for any.
fn cast_rays(scene: &Scene, camera: &Camera) -> Result<[CastBatch; 3], crate::Error> {
    // Per pixel: its camera ray, its hit and at most two ambient-occlusion rays and an answer.
    let per_ray = 3 * std::mem::size_of::<CastRay>() + std::mem::size_of::<Option<crate::cast::SceneHit>>() + 1;
    crate::memory::check(
        "the cast scenario's rays and hits",
        camera.width as u64 * camera.height as u64 * per_ray as u64,
        "lower --width/--height or raise --memory-budget",
    )?;
    let basis = camera.basis();
    let camera_rays: Vec<CastRay> = (0..camera.height)
        .flat_map(|y| (0..camera.width).map(move |x| (x, y)))
        .map(|(x, y)| CastRay::new(camera.eye, camera.ray_dir(&basis, x, y)))
        .collect();
    let ao_rays = ambient_occlusion_rays(&SceneCaster::new(scene)?, &camera_rays);
    let reach = ao_rays.iter().map(|r| r.up_to(OCCLUSION_REACH)).collect();
    Ok([
        ("camera rays", Query::Nearest, camera_rays),
        ("ambient-occlusion rays", Query::Nearest, ao_rays),
        ("ambient-occlusion rays, any hit within 0.5", Query::Occluded, reach),
    ])
}

/// From each hit of `rays` (through `caster`), one ray into the hemisphere around the hit's
/// normal, from just off the surface, in a fixed random sequence: the cast scenario's and
/// the criterion bench's ambient-occlusion rays (short, incoherent).
pub fn ambient_occlusion_rays(caster: &SceneCaster, rays: &[CastRay]) -> Vec<CastRay> {
    let mut rng = crate::rng::Rng::new(1);
    caster
        .nearest_all(rays)
        .into_iter()
        .flatten()
        .map(|h| {
            let d = rng.unit_vector().as_dvec3();
            let d = if d.dot(h.normal) < 0.0 { -d } else { d };
            CastRay::new(h.position + h.normal * 1e-3, d)
        })
        .collect()
}

/// Wall times (ms) of `cfg.frames` casts of `rays` after `cfg.warmup` untimed ones, asking
/// `query`, through the session's backend's caster (made once, outside the timing) into one
/// buffer of answers kept between the casts, as a caller casting batch after batch keeps it:
/// the CPU's on the thread pool, the GPU's with the rays' upload and the answers' read-back.
fn time_casts(
    session: &Session,
    scene: &Scene,
    rays: &[CastRay],
    query: Query,
    cfg: &MatrixConfig,
) -> Result<Vec<f64>, crate::Error> {
    let frames = cfg.frames.max(1);
    type Cast<'r> = Box<dyn FnMut() -> Result<usize, crate::Error> + 'r>;
    #[cfg(feature = "gpu")]
    let on_gpu: Option<Cast> = match session.backend().gpu() {
        Some(g) => {
            let caster = crate::gpu::cast::GpuSceneCaster::new(g.ctx.clone(), scene)?;
            let (mut hits, mut blocked) = (Vec::new(), Vec::new());
            Some(Box::new(move || match query {
                Query::Nearest => {
                    caster.nearest_into(rays, &mut hits)?;
                    Ok(hits.iter().flatten().count())
                }
                Query::Occluded => {
                    caster.occluded_into(rays, &mut blocked)?;
                    Ok(blocked.iter().filter(|&&b| b).count())
                }
            }))
        }
        None => None,
    };
    #[cfg(not(feature = "gpu"))]
    let on_gpu: Option<Cast> = {
        let _ = session;
        None
    };
    let mut cast: Cast = match on_gpu {
        Some(c) => c,
        None => {
            let (caster, mut hits, mut blocked) = (SceneCaster::new(scene)?, Vec::new(), Vec::new());
            Box::new(move || match query {
                Query::Nearest => {
                    crate::pool::run_awake(|| caster.nearest_into(rays, &mut hits));
                    Ok(hits.iter().flatten().count())
                }
                Query::Occluded => {
                    crate::pool::run_awake(|| caster.occluded_into(rays, &mut blocked));
                    Ok(blocked.iter().filter(|&&b| b).count())
                }
            })
        }
    };
    let mut times = Vec::with_capacity(frames);
    for f in 0..cfg.warmup + frames {
        let start = std::time::Instant::now();
        std::hint::black_box(cast()?);
        if f >= cfg.warmup {
            times.push(start.elapsed().as_secs_f64() * 1e3);
        }
    }
    Ok(times)
}

/// One static instance of `svo` at the identity.
pub fn static_scene(svo: Arc<Svo>) -> Result<Scene, crate::Error> {
    let mut scene = Scene::new(vec![svo]);
    scene.add(Instance { part: 0, parent: None, local: Transform::IDENTITY })?;
    scene.update()?;
    Ok(scene)
}

/// Runs the configured scenarios on `session`'s backend; `progress` hears each measurement's
/// name as it starts.
pub fn run(
    cfg: &MatrixConfig,
    subject: &mut Subject<'_>,
    session: &mut Session,
    backend_name: &str,
    progress: &mut dyn FnMut(&str),
) -> Result<Vec<Record>, crate::Error> {
    let lights = Lights::default();
    let mut out = Vec::new();
    let gpu = session.backend().kind_name() == "gpu";
    let measure = |session: &mut Session,
                   group: &str,
                   name: String,
                   setting: String,
                   x: f64,
                   clip: Clip<'_>,
                   progress: &mut dyn FnMut(&str)|
     -> Result<(Record, Frame), crate::Error> {
        progress(&name);
        let (r, frame) = run_clip(session, backend_name, clip)?;
        Ok((label(r, cfg, group, name, setting, x), frame))
    };
    for &scenario in &cfg.scenarios {
        let group = scenario.group();
        let (car, file) = match subject {
            Subject::Car(car) => (Some(*car), None),
            Subject::File { staged, name, merged } => (None, Some((&mut **staged, name.as_str(), merged.clone()))),
        };
        let group = match &file {
            Some(_) => format!("scene-{group}"),
            None => group.to_string(),
        };
        let group = group.as_str();
        match scenario {
            Scenario::Instances | Scenario::Splat | Scenario::Cast if car.is_none() => {}
            Scenario::Cast => {
                let car = car.ok_or(crate::Error::CarParts { got: 0 })?;
                // The car alone (8 instances: packets through each octree) and a parked crowd
                // (past `BVH_MIN_INSTANCES`: its instance BVH), each on its ground.
                for cars in [1, CAST_CROWD_CARS] {
                    let st = stage_cars(&car.parts, cars, false, true)?;
                    let (lo, hi) = framed(&st);
                    let camera = Camera::framing(lo.as_vec3(), hi.as_vec3(), cfg.size.0, cfg.size.1);
                    let scene_name = if cars == 1 { String::new() } else { format!("{cars} cars: ") };
                    for (what, query, rays) in cast_rays(&st.scene, &camera)? {
                        let setting = format!("{scene_name}{what}");
                        let name = format!("{setting}, {} rays", rays.len());
                        progress(&name);
                        let times = time_casts(session, &st.scene, &rays, query, cfg)?;
                        let (median_ms, p95_ms, min_ms) = super::summarize(&times);
                        let r = Record {
                            width: camera.width,
                            height: camera.height,
                            warmup: cfg.warmup,
                            frames: times.len(),
                            instances: st.scene.instances().len(),
                            median_ms,
                            p95_ms,
                            min_ms,
                            mrays_per_s: rays.len() as f64 / median_ms.max(1e-9) / 1e3,
                            backend: backend_name.to_string(),
                            backend_kind: session.backend().kind_name().to_string(),
                            ..Record::default()
                        };
                        out.push(label(r, cfg, group, name, setting, rays.len() as f64));
                    }
                }
            }
            Scenario::Splat => {
                let car = car.ok_or(crate::Error::CarParts { got: 0 })?;
                let features = Features { hit_buffer: false, ..Features::default() };
                // Both renderers on one clip; the splat frame's error against the traced one.
                let mut pair = |st: &mut crate::scene::Staged,
                                camera: &Camera,
                                lod: u32,
                                what: String,
                                x: f64,
                                progress: &mut dyn FnMut(&str)|
                 -> Result<(), crate::Error> {
                    let mut traced: Option<Frame> = None;
                    // On the GPU the splats are drawn both ways: compute passes and quads.
                    let ways = [
                        (Renderer::Trace, SplatDraw::Compute, "trace"),
                        (Renderer::Splat, SplatDraw::Compute, "splat"),
                        (Renderer::Splat, SplatDraw::Quads, "splat (quads)"),
                    ];
                    for (renderer, splat_draw, setting) in ways.into_iter().take(if gpu { 3 } else { 2 }) {
                        let clip = Clip {
                            scene: &mut st.scene,
                            cars: &st.cars,
                            animated: None,
                            renderer,
                            splat_draw,
                            camera,
                            lights: &lights,
                            features,
                            lod,
                            warmup: cfg.warmup.min(2),
                            frames: cfg.sweep_frames,
                            fps: 30.0,
                            pose_on_gpu: false,
                        };
                        let name = format!("{what}: {setting}");
                        let (mut r, frame) = measure(session, group, name, setting.into(), x, clip, progress)?;
                        match &traced {
                            None => traced = Some(frame),
                            Some(t) => {
                                r.error = Some(metrics::compare(&frame, t).map_err(|e| crate::Error::Io {
                                    path: "bench".into(),
                                    source: std::io::Error::other(e.to_string()),
                                })?)
                            }
                        }
                        out.push(r);
                    }
                    Ok(())
                };
                // Cars driving, no ground: what the squares cost as the crowd grows (each car
                // splatted at the level whose voxels are about a pixel).
                for &n in &cfg.cars {
                    let (mut st, camera) = crowd(car, n, cfg)?;
                    pair(&mut st, &camera, u32::MAX, format!("{n} cars"), n as f64, progress)?;
                }
                // One car, its voxels limited to each level: the voxel count sweep.
                let mut st = stage_cars(&car.parts, 1, false, false)?;
                let (lo, hi) = st.cars_bounds();
                let camera = Camera::framing(lo.as_vec3(), hi.as_vec3(), cfg.size.0, cfg.size.1);
                let full = car.parts.iter().map(|p| p.depth).max().unwrap_or(0);
                let levels: Vec<u32> = if cfg.lod_levels.is_empty() {
                    (full.saturating_sub(3).max(1)..=full).collect()
                } else {
                    cfg.lod_levels.iter().copied().filter(|&l| l <= full).chain([full]).collect()
                };
                for level in levels {
                    let voxels: usize = car.parts.iter().map(|p| p.at_level(level).len()).sum();
                    let lod = if level == full { u32::MAX } else { level };
                    pair(&mut st, &camera, lod, format!("level {level}, {voxels} voxels"), voxels as f64, progress)?;
                }
            }
            Scenario::Paper if file.as_ref().is_some_and(|f| f.2.is_none()) => {}
            Scenario::Paper => {
                let mut staged_car;
                let (animated, merged_svo, label, what_static) = match file {
                    Some((st, name, Some(m))) => (st, m, format!("{name}: "), "static single-SVO scene"),
                    _ => {
                        let car = car.ok_or(crate::Error::CarParts { got: 0 })?;
                        staged_car = stage_cars(&car.parts, 1, false, false)?;
                        (&mut staged_car, car.merged.clone(), String::new(), "static single-SVO car")
                    }
                };
                let mut merged = static_scene(merged_svo)?;
                let (lo, hi) = framed(animated);
                let camera = Camera::framing(lo.as_vec3(), hi.as_vec3(), cfg.size.0, cfg.size.1);
                let primary = Features { shadows: false, ..Features::default() };
                let settings = [
                    ("a", what_static, Features { hit_buffer: false, ..primary }, true),
                    ("b", "animated parts, no optimizations", Features::NONE, false),
                    ("c", "animated, culling + sorting + hit buffer", Features { bvh: false, ..primary }, false),
                    ("d", "animated, every optimization + shadow rays", Features::default(), false),
                ];
                for (i, (tag, what, features, is_static)) in settings.into_iter().enumerate() {
                    let (scene, cars, rig) = if is_static {
                        (&mut merged, &[][..], None)
                    } else {
                        (&mut animated.scene, &animated.cars[..], animated.animated.as_ref())
                    };
                    let clip = Clip {
                        scene,
                        cars,
                        animated: rig,
                        renderer: crate::render::Renderer::Trace,
                        splat_draw: SplatDraw::Compute,
                        camera: &camera,
                        lights: &lights,
                        features,
                        lod: u32::MAX,
                        warmup: cfg.warmup,
                        frames: cfg.frames,
                        fps: 30.0,
                        pose_on_gpu: false,
                    };
                    let name = format!("{label}{tag}: {what}");
                    out.push(measure(session, group, name, tag.into(), i as f64, clip, progress)?.0);
                }
            }
            Scenario::Instances => {
                let car = car.ok_or(crate::Error::CarParts { got: 0 })?;
                let mut crowds =
                    cfg.cars.iter().map(|&n| crowd(car, n, cfg).map(|c| (n, c))).collect::<Result<Vec<_>, _>>()?;
                // The BVH points, whose ratios to one car are the sweep's figure, are timed in
                // rounds, each count in turn, so that every count's frames spread over the
                // same stretch of the run: timed one after another, a one-car median moved
                // by 2× between runs with the host's load (0.46–0.91 ms) and every ratio
                // with it. Each round warms up afresh and replays the same frames.
                let rounds = INSTANCE_ROUNDS.min(cfg.frames).max(1);
                let per_round = cfg.frames.div_ceil(rounds);
                let mut timed: Vec<Vec<(Record, Vec<f64>)>> = crowds.iter().map(|_| Vec::new()).collect();
                for round in 0..rounds {
                    for ((n, (st, camera)), timed) in crowds.iter_mut().zip(&mut timed) {
                        progress(&format!("{n} cars, BVH (round {} of {rounds})", round + 1));
                        let (r, _, times) = super::run_clip_timed(
                            session,
                            backend_name,
                            crowd_clip(st, camera, &lights, true, cfg.crowd_on_gpu, cfg.warmup, per_round),
                        )?;
                        timed.push((r, times));
                    }
                }
                for ((n, (st, camera)), timed) in crowds.iter_mut().zip(timed) {
                    if let Some(r) = super::pool_rounds(timed) {
                        out.push(label(r, cfg, group, format!("{n} cars, BVH"), "BVH".into(), *n as f64));
                    }
                    let setting = "sorted spheres";
                    let name = format!("{n} cars, {setting}");
                    progress(&name);
                    // (Sorting 80 000 spheres per ray takes seconds a frame.)
                    let c = crowd_clip(st, camera, &lights, false, false, cfg.warmup.min(2), cfg.sweep_frames);
                    let (r, _) = run_clip(session, backend_name, c)?;
                    out.push(label(r, cfg, group, name, setting.into(), *n as f64));
                }
            }
            Scenario::Resolution => {
                let mut slot = None;
                let (st, label) = sweep_scene(file, car, &mut slot)?;
                let (lo, hi) = framed(st);
                for &(w, h) in &cfg.resolutions {
                    let camera = Camera::framing(lo.as_vec3(), hi.as_vec3(), w, h);
                    let clip = Clip {
                        scene: &mut st.scene,
                        cars: &st.cars,
                        animated: st.animated.as_ref(),
                        renderer: crate::render::Renderer::Trace,
                        splat_draw: SplatDraw::Compute,
                        camera: &camera,
                        lights: &lights,
                        features: Features::default(),
                        lod: u32::MAX,
                        warmup: cfg.warmup,
                        frames: cfg.frames,
                        fps: 30.0,
                        pose_on_gpu: false,
                    };
                    let name = format!("{w}×{h}");
                    out.push(
                        measure(session, group, format!("{label}{name}"), name, (w * h) as f64, clip, progress)?.0,
                    );
                }
            }
            Scenario::Depth => {
                let mut slot = None;
                let (st, label) = sweep_scene(file, car, &mut slot)?;
                let (lo, hi) = framed(st);
                let camera = Camera::framing(lo.as_vec3(), hi.as_vec3(), cfg.size.0, cfg.size.1);
                let full = st.scene.parts.iter().map(|p| p.depth).max().unwrap_or(0);
                let levels: Vec<u32> = if cfg.lod_levels.is_empty() {
                    (full.saturating_sub(3).max(1)..full).collect()
                } else {
                    cfg.lod_levels.iter().copied().filter(|&l| l < full).collect()
                };
                // Full depth first: it is the reference the coarser levels are compared with.
                let mut reference: Option<Frame> = None;
                for level in std::iter::once(full).chain(levels) {
                    let clip = Clip {
                        scene: &mut st.scene,
                        cars: &st.cars,
                        animated: st.animated.as_ref(),
                        renderer: crate::render::Renderer::Trace,
                        splat_draw: SplatDraw::Compute,
                        camera: &camera,
                        lights: &lights,
                        features: Features { hit_buffer: false, ..Features::default() },
                        lod: if level == full { u32::MAX } else { level },
                        warmup: cfg.warmup,
                        frames: cfg.frames,
                        fps: 30.0,
                        pose_on_gpu: false,
                    };
                    let setting =
                        if level == full { format!("level {level} (full)") } else { format!("level {level}") };
                    let name = format!("{label}LOD {setting}");
                    let (mut r, frame) = measure(session, group, name, setting, level as f64, clip, progress)?;
                    let reference = reference.get_or_insert(frame.clone());
                    r.error = Some(metrics::compare(&frame, reference).map_err(|e| crate::Error::Io {
                        path: "bench".into(),
                        source: std::io::Error::other(e.to_string()),
                    })?);
                    out.push(r);
                }
            }
        }
    }
    Ok(out)
}
