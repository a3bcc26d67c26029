//! GI scenarios of the harness. **gi-scaling**: the voxel transformation against the
//! re-voxelization baseline, moving N cars into one world volume (the voxel-transformation
//! paper's scaling figure). **gi-accuracy**: every GI knob swept on the coloured-wall box,
//! each setting's run time next to its error (RMSE and FLIP) against the path-traced reference
//! (docs/accuracy.md).

use super::metrics::{compare, ImageError};
use super::{summarize, Record};
use crate::gi::{
    render_with_gi, Filter, GiCaches, GiSettings, PathTracer, ReferenceSettings, Volume, VolumeSpec, VoxelCache,
};
use crate::mesh::{Mesh, Part};
use crate::render::{render, Features, Frame, FramePlan, RenderOptions};
use crate::scene::car::pose_all;
use crate::scene::{stage_cars, Instance, Scene, Transform};
use crate::svo::{Cube, Svo};
use crate::voxelize::voxelize_in;
use std::sync::Arc;
use std::time::Instant;

/// What the scaling scenario measures.
#[derive(Clone, Debug)]
pub struct ScalingConfig {
    /// Car counts.
    pub cars: Vec<usize>,
    /// World volume cells per side (a power of two: the re-voxelizer's grid is 2^depth).
    pub res: u32,
    /// Timed repetitions per count (the median is kept).
    pub repeats: usize,
    /// The command line, for the records.
    pub command: String,
    /// The machine, for the records.
    pub machine: String,
}

/// Times moving `cars` cars into one volume both ways. `mesh` holds the car's triangles
/// (parts in the same order as `parts`, the SVOs).
pub fn scaling(
    cfg: &ScalingConfig,
    mesh: &Mesh,
    parts: &[Arc<Svo>],
    progress: &mut dyn FnMut(&str),
) -> Result<Vec<Record>, crate::Error> {
    let depth = cfg.res.trailing_zeros();
    let spec = scaling_volume(cfg, parts)?;
    let mut out = Vec::new();
    for &n in &cfg.cars {
        progress(&format!("gi-scaling: {n} cars"));
        let (st, caches, instances) = scaling_scene(parts, n)?;
        let cube = Cube { min: spec.min.as_vec3(), size: (spec.cell * cfg.res as f64) as f32 };
        let mut vol = Volume::new(spec);
        let mut time =
            |f: &mut dyn FnMut(&mut Volume) -> Result<u64, crate::Error>| -> Result<(f64, u64), crate::Error> {
                let mut times = Vec::new();
                let mut work = 0;
                for _ in 0..cfg.repeats.max(1) {
                    vol.clear();
                    let t0 = Instant::now();
                    work = f(&mut vol)?;
                    times.push(t0.elapsed().as_secs_f64() * 1e3);
                }
                Ok((summarize(&times).0, work))
            };
        for filter in [Filter::Split, Filter::Nearest] {
            let (ms, voxels) = time(&mut |vol: &mut Volume| {
                let mut moved = 0;
                for (part, world) in &instances {
                    moved += vol.splat(&caches[*part], world, filter)?.voxels;
                }
                Ok(moved)
            })?;
            out.push(record(
                cfg,
                n,
                &format!("transformation ({filter:?})").to_lowercase(),
                ms,
                voxels,
                st.scene.instances().len(),
            ));
        }
        let (ms, triangles) = time(&mut |vol: &mut Volume| {
            let mut tris = 0u64;
            for (part, world) in &instances {
                let moved = Part {
                    name: String::new(),
                    triangles: mesh.parts[*part]
                        .triangles
                        .iter()
                        .map(|t| {
                            let mut t = *t;
                            for p in &mut t.positions {
                                *p = world.transform_point3(p.as_dvec3()).as_vec3();
                            }
                            t
                        })
                        .collect(),
                };
                tris += moved.triangles.len() as u64;
                // A part wholly outside the volume is simply empty.
                if let Ok(grid) = voxelize_in(&moved, &mesh.materials, cube, depth, false, &|_, _| {}) {
                    vol.write_grid(&grid)?;
                }
            }
            Ok(tris)
        })?;
        out.push(record(cfg, n, "re-voxelization", ms, triangles, st.scene.instances().len()));
    }
    Ok(out)
}

/// One volume for every count: the box the most cars ever drive in, so the cell size (and
/// with it the caches) is the same at every count and only the number of cars changes.
fn scaling_volume(cfg: &ScalingConfig, parts: &[Arc<Svo>]) -> Result<VolumeSpec, crate::Error> {
    if !cfg.res.is_power_of_two() {
        return Err(crate::gi::GiError::Resolution(cfg.res).into());
    }
    let most = cfg.cars.iter().copied().max().unwrap_or(1);
    let (lo, hi) = stage_cars(parts, most, true, false)?.bounds;
    Ok(VolumeSpec::following((lo + hi) * 0.5, (hi - lo).max_element() * 1.02, cfg.res)?)
}

/// `n` driving cars posed mid-clip, the parts' caches and every instance's (part, world).
type ScalingScene = (crate::scene::Staged, Vec<VoxelCache>, Vec<(usize, glam::DAffine3)>);

fn scaling_scene(parts: &[Arc<Svo>], n: usize) -> Result<ScalingScene, crate::Error> {
    let mut st = stage_cars(parts, n, true, false)?;
    pose_all(&mut st.scene, &st.cars, 1.7)?;
    st.scene.update()?;
    // Caches at a fixed voxel size, 1/64 of the first part (the body), at every count — the
    // volume's cells grow with the area the cars cover and would otherwise shrink the caches
    // to a voxel or two. Built once (load time, not timed).
    let voxel = parts.first().map_or(1.0, |p| p.bounds.size as f64 / 64.0);
    let caches: Vec<VoxelCache> = parts
        .iter()
        .map(|p| {
            let level = (p.bounds.size as f64 / voxel).log2().round().clamp(0.0, 10.0) as u32;
            VoxelCache::from_svo(p, level)
        })
        .collect::<Result<_, _>>()
        .map_err(|e| crate::gi::GiError::Settings(e.to_string()))?;
    let instances = st.scene.instances().iter().enumerate().map(|(i, inst)| (inst.part, st.scene.world(i))).collect();
    Ok((st, caches, instances))
}

/// The scaling scenario on the GPU: the same volume, cars, caches and triangles, the voxel
/// transformation (`gi_transform.wgsl`) against the GPU re-voxelizer (`gi_revoxelize.wgsl`),
/// pass times from timestamp queries (uploads not included).
#[cfg(feature = "gpu")]
pub fn scaling_gpu(
    cfg: &ScalingConfig,
    mesh: &Mesh,
    parts: &[Arc<Svo>],
    ctx: Arc<crate::gpu::GpuContext>,
    progress: &mut dyn FnMut(&str),
) -> Result<Vec<Record>, crate::Error> {
    let spec = scaling_volume(cfg, parts)?;
    let backend = format!("GPU: {}", ctx.describe());
    let passes = crate::gpu::baseline::GpuVolumePasses::new(ctx);
    let mut out = Vec::new();
    for &n in &cfg.cars {
        progress(&format!("gi-scaling (GPU): {n} cars"));
        let (st, caches, instances) = scaling_scene(parts, n)?;
        let count = st.scene.instances().len();
        let mut push = |name: &str, t: crate::gpu::baseline::Timed| {
            let mut r = record(cfg, n, name, summarize(&t.ms).0, t.work, count);
            r.backend_kind = "gpu".into();
            r.backend = format!("{backend}{}", if t.timestamps { "" } else { " (wall clock)" });
            out.push(r);
        };
        for filter in [Filter::Split, Filter::Nearest] {
            // One untimed run first: pipeline warm-up and first-touch of the buffers.
            passes.transform(&caches, &instances, &spec, filter, 1)?;
            let t = passes.transform(&caches, &instances, &spec, filter, cfg.repeats.max(1))?;
            push(&format!("transformation ({filter:?})").to_lowercase(), t);
        }
        passes.revoxelize(mesh, &instances, &spec, 1)?;
        push("re-voxelization", passes.revoxelize(mesh, &instances, &spec, cfg.repeats.max(1))?);
    }
    Ok(out)
}

fn record(cfg: &ScalingConfig, cars: usize, name: &str, ms: f64, work: u64, instances: usize) -> Record {
    Record {
        group: "gi-scaling".into(),
        name: name.into(),
        setting: format!("{work} {}", if name.starts_with("re-") { "triangles" } else { "voxels" }),
        x: cars as f64,
        backend_kind: "cpu".into(),
        backend: "CPU reference".into(),
        instances,
        median_ms: ms,
        p95_ms: ms,
        min_ms: ms,
        frames: cfg.repeats,
        machine: cfg.machine.clone(),
        command: cfg.command.clone(),
        ..Default::default()
    }
}

/// The coloured-wall box as a scene: its three parts at the identity, voxelized at `depth`.
pub fn room_scene(depth: u32) -> Result<Scene, crate::Error> {
    scene_of(&crate::model::room::mesh(), depth)
}

/// The box with thick walls ([`crate::model::room::thick_mesh`]): the light-leak scene.
pub fn thick_room_scene(depth: u32) -> Result<Scene, crate::Error> {
    scene_of(&crate::model::room::thick_mesh(), depth)
}

/// [`room_scene`] with glossy white surfaces ([`crate::model::room::glossy_mesh`]).
pub fn glossy_room_scene(depth: u32) -> Result<Scene, crate::Error> {
    scene_of(&crate::model::room::glossy_mesh(), depth)
}

fn scene_of(mesh: &Mesh, depth: u32) -> Result<Scene, crate::Error> {
    let parts = crate::pipeline::build_parts(mesh, crate::voxelize::Resolution::Depth(depth))?;
    let mut scene = Scene::new(parts);
    for part in 0..scene.parts.len() {
        scene.add(Instance { part, parent: None, local: Transform::IDENTITY })?;
    }
    scene.update()?;
    Ok(scene)
}

/// The dense and the sparse world volume on the box on the GPU (`--scenarios gi-volume
/// --backends gpu`): per frame with the volume rebuilt, the GPU time of the GI passes and the
/// shade pass (which holds the cones) from timestamp queries, plus, sparse where the pool is
/// sized by the count read back, the wall-clock time of that submit and read; memory is all
/// the GI buffers. A resolution whose
/// buffers exceed the device's binding limit is left out, with a message.
#[cfg(feature = "gpu")]
pub fn layouts_gpu(
    cfg: &LayoutConfig,
    ctx: Arc<crate::gpu::GpuContext>,
    progress: &mut dyn FnMut(&str),
) -> Result<Vec<Record>, crate::Error> {
    use crate::gi::shade::VolumeChoice;
    let scene = room_scene(8)?;
    let camera = crate::model::room::camera(cfg.size.0, cfg.size.1);
    let lights = crate::model::room::lights();
    let plan = FramePlan::new(&scene, &camera, &lights, &Features::default(), None);
    let backend = format!("GPU: {}", ctx.describe());
    let mut out = Vec::new();
    for &res in &cfg.resolutions {
        for (choice, name) in [(VolumeChoice::Dense, "dense"), (VolumeChoice::Sparse, "sparse")] {
            let s = GiSettings { res, volume: choice, ..GiSettings::default() };
            if s.validated().is_err() {
                continue;
            }
            progress(&format!("gi-volume (GPU): {name} {res}³"));
            let run = match gpu_gi_frames(&ctx, &s, &scene, &camera, &lights, &plan, cfg.repeats) {
                Err(crate::Error::Gpu(e @ crate::gpu::GpuError::TooLarge { .. })) => {
                    progress(&format!("gi-volume (GPU): {name} {res}³ left out: {e}"));
                    continue;
                }
                other => other?,
            };
            let (times, st, timed) = (run.times, run.stats, run.timed);
            let mut r = layout_record(cfg, name, res, &times, st.bytes, scene.instances().len());
            r.setting = match run.bricks {
                Some(n) => format!("{n} bricks"),
                None => String::new(),
            };
            r.backend_kind = "gpu".into();
            r.backend = format!("{backend}{}", if timed { "" } else { " (wall clock)" });
            out.push(r);
        }
    }
    Ok(out)
}

/// What [`gpu_gi_frames`] measured.
#[cfg(feature = "gpu")]
struct GpuGiRun {
    /// Per timed frame: GPU milliseconds of the GI and shade passes plus any brick count's
    /// read (wall clock of the frame where the adapter has no timestamps).
    times: Vec<f64>,
    /// Whether `times` came from timestamp queries.
    timed: bool,
    /// The last frame.
    frame: Frame,
    /// Its GI statistics.
    stats: crate::gpu::gi::GpuGiStats,
    /// Bricks of its sparse volume (read back after the timed frames; None dense).
    bricks: Option<u32>,
}

/// Renders `repeats` + 1 GPU frames with GI `s`, each rebuilding the volume; the first
/// (pipeline compilation, first touch of the buffers) is not timed.
#[cfg(feature = "gpu")]
fn gpu_gi_frames(
    ctx: &Arc<crate::gpu::GpuContext>,
    s: &GiSettings,
    scene: &Scene,
    camera: &crate::scene::Camera,
    lights: &crate::scene::Lights,
    plan: &FramePlan,
    repeats: usize,
) -> Result<GpuGiRun, crate::Error> {
    let mut gpu = crate::gpu::GpuRenderer::new(ctx.clone());
    gpu.set_gi(Some(*s))?;
    let (mut times, mut timed) = (Vec::new(), true);
    for k in 0..repeats.max(1) + 1 {
        gpu.forget_gi_frame();
        let t0 = Instant::now();
        let frame = gpu.render(scene, camera, lights, plan, &RenderOptions::default())?;
        let wall = t0.elapsed().as_secs_f64() * 1e3;
        let stats = gpu.gi_stats.ok_or_else(|| crate::gi::GiError::Settings("GI did not run".into()))?;
        if k > 0 {
            times.push(gpu.times.map_or(wall, |t| t.gi_ms + t.shade_ms + stats.bricks_ms));
            timed &= gpu.times.is_some();
        }
        if k == repeats.max(1) {
            let bricks = gpu.gi_bricks()?;
            return Ok(GpuGiRun { times, timed, frame, stats, bricks });
        }
    }
    Err(crate::gi::GiError::Settings("no GPU frame".into()).into())
}

/// What the accuracy scenario measures.
#[derive(Clone, Debug)]
pub struct AccuracyConfig {
    /// Image size.
    pub size: (u32, u32),
    /// SVO depth of the box.
    pub depth: u32,
    /// Reference samples per pixel.
    pub spp: u32,
    /// Timed GI runs per setting (median kept).
    pub repeats: usize,
    /// Volume resolutions swept (6 cones, split filtering).
    pub resolutions: Vec<u32>,
    /// Cone counts swept (at 128³).
    pub cones: Vec<u32>,
    /// Bounce counts swept, against the all-bounce reference (empty: that reference is not
    /// traced).
    pub bounces: Vec<u32>,
    /// The command line, for the records.
    pub command: String,
    /// The machine, for the records.
    pub machine: String,
}

/// One GI setting measured against the reference: (median GI milliseconds, frame). The
/// frame is rendered with the cones as its ambient term ([`crate::gi::render_with_gi`]);
/// GI's time is its passes' (caches, transformation, injection, levels, cones), not the
/// primary rays and sun.
pub fn gi_frame(
    scene: &Scene,
    camera: &crate::scene::Camera,
    lights: &crate::scene::Lights,
    plan: &FramePlan,
    settings: &GiSettings,
    repeats: usize,
) -> Result<(f64, Frame), crate::Error> {
    gi_frame_timed(scene, camera, lights, plan, settings, repeats).map(|(ms, _, f)| (ms, f))
}

/// [`gi_frame`], with the median milliseconds of the gather at the pixels too.
pub fn gi_frame_timed(
    scene: &Scene,
    camera: &crate::scene::Camera,
    lights: &crate::scene::Lights,
    plan: &FramePlan,
    settings: &GiSettings,
    repeats: usize,
) -> Result<(f64, f64, Frame), crate::Error> {
    let mut caches = GiCaches::new();
    let mut times = Vec::new();
    let mut gathers = Vec::new();
    let mut last = None;
    // One untimed run builds the caches (load-time work). Every run is timed as a first
    // frame: reusing the last frame's chain would time the cones alone.
    for k in 0..repeats.max(1) + 1 {
        caches.forget_last_frame();
        let opts = RenderOptions::default();
        let (f, stats) = render_with_gi(scene, camera, lights, plan, &opts, None, settings, &mut caches, &|_, _| {})?;
        if k > 0 {
            times.push(gi_ms(&stats));
            gathers.push(stats.cones_ms);
        }
        last = Some(f);
    }
    let frame = last.ok_or_else(|| crate::gi::GiError::Settings("no GI frame".into()))?;
    Ok((summarize(&times).0, summarize(&gathers).0, frame))
}

/// Milliseconds of a CPU frame's GI passes.
fn gi_ms(s: &crate::gi::GiStats) -> f64 {
    s.caches_ms + s.transform_ms + s.inject_ms + s.levels_ms + s.cones_ms
}

/// The GPU's own GI knobs against the path tracer (`--scenarios gi-accuracy --backends gpu`),
/// on the CPU sweep's three scenes (the box, the car on its ground, the panel room; rows
/// named as the CPU's, "car on ground: …" and "panel room: …"): the volume resolution, the
/// cone count, the filter, the level chain read from the f32 buffer or from the 3D texture,
/// the gathers, anisotropic levels and, in the panel room, the light samples (shadow rays and
/// cone shadows), about the defaults at a dense volume (sparse at 256³), against the one-bounce reference of
/// the CPU sweep (same samples and seed);
/// and two bounces with and without the bounces' tail against the all-bounce reference. Each
/// row's time is the GPU time of the GI passes and the shade pass that traces the cones
/// (timestamp queries; wall clock of the frame where the adapter has none), the volume rebuilt
/// per frame.
#[cfg(feature = "gpu")]
pub fn accuracy_gpu(
    cfg: &AccuracyConfig,
    ctx: Arc<crate::gpu::GpuContext>,
    progress: &mut dyn FnMut(&str),
) -> Result<Vec<Record>, crate::Error> {
    let mut out = Vec::new();
    let room = room_scene(cfg.depth)?;
    let room_camera = crate::model::room::camera(cfg.size.0, cfg.size.1);
    out.extend(accuracy_gpu_on("", false, &room, &room_camera, &crate::model::room::lights(), cfg, &ctx, progress)?);
    let (car, car_camera) = car_on_ground(cfg)?;
    out.extend(accuracy_gpu_on(CAR, false, &car, &car_camera, &crate::scene::Lights::default(), cfg, &ctx, progress)?);
    let panel = panel_room_scene(cfg.depth)?;
    let panel_camera = crate::model::panel_room::camera(cfg.size.0, cfg.size.1);
    let panel_lights = crate::model::panel_room::lights();
    out.extend(accuracy_gpu_on("panel room: ", true, &panel, &panel_camera, &panel_lights, cfg, &ctx, progress)?);
    Ok(out)
}

/// [`accuracy_gpu`] on one scene; `label` starts every record's name; `light_samples` adds
/// the light-sample rows (a scene lit by its emitters).
#[cfg(feature = "gpu")]
#[allow(clippy::too_many_arguments)]
fn accuracy_gpu_on(
    label: &str,
    light_samples: bool,
    scene: &Scene,
    camera: &crate::scene::Camera,
    lights: &crate::scene::Lights,
    cfg: &AccuracyConfig,
    ctx: &Arc<crate::gpu::GpuContext>,
    progress: &mut dyn FnMut(&str),
) -> Result<Vec<Record>, crate::Error> {
    use crate::gi::shade::{LevelStore, VolumeChoice};
    let plan = FramePlan::new(scene, camera, lights, &Features::default(), None);
    progress(&format!("gi-accuracy (GPU): {label}reference, {} spp", cfg.spp));
    let reference = one_bounce_reference(scene, camera, lights, cfg)?.0;
    let backend = format!("GPU: {}", ctx.describe());
    let mut out = Vec::new();
    // The level store, then the gather (with the buffer store), each against the reference.
    // The per-pixel gather but where the gather is the knob (these rows predate the caches'
    // being the default, and keep their meaning).
    let dense =
        GiSettings { volume: VolumeChoice::Dense, gather: crate::render::Gather::Pixels, ..GiSettings::default() };
    let half = crate::render::Gather::Half;
    let c = crate::render::radiance_cache::CacheSettings::default();
    let caches = crate::render::Gather::Caches(c);
    let caches8 = crate::render::Gather::Caches(crate::render::radiance_cache::CacheSettings { res: 8, ..c });
    // The knobs the CPU sweeps about the defaults (the caches' gather; per-pixel cones for
    // the cone count), at the default dense layout up to 256³.
    let d = GiSettings { volume: VolumeChoice::Dense, ..GiSettings::default() };
    let mut runs: Vec<(&str, String, f64, GiSettings)> = Vec::new();
    for res in [32u32, 64, 128, 256] {
        // 256³ dense needs more than llvmpipe binds (128 MiB): sparse, as the CPU's auto picks.
        let (volume, how) = if res > 128 { (VolumeChoice::Sparse, " sparse") } else { (VolumeChoice::Dense, "") };
        let s = GiSettings { res, volume, ..d };
        runs.push(("volume resolution (GPU)", format!("{res}³{how}"), res as f64, s));
    }
    for n in [1u32, 3, 6, 9, 16] {
        let cones = crate::gi::ConeSettings { diffuse_cones: n, ..d.cones };
        let s = GiSettings { cones, gather: crate::render::Gather::Pixels, ..d };
        runs.push(("diffuse cones (GPU, 128³)", format!("{n}"), n as f64, s));
    }
    for (filter, x) in [(Filter::Nearest, 0.0), (Filter::Split, 1.0)] {
        let name = format!("{filter:?}").to_lowercase();
        runs.push(("filter (GPU, 128³)", name, x, GiSettings { filter, ..d }));
    }
    let fixed = [
        ("level chain store (GPU, 128³)", "buffer", 0.0, dense),
        ("level chain store (GPU, 128³)", "texture", 1.0, GiSettings { levels: LevelStore::Texture, ..dense }),
        ("gather (GPU, 128³)", "pixels", 1.0, dense),
        ("gather (GPU, 128³)", "half", 0.5, GiSettings { gather: half, ..dense }),
        ("gather (GPU, 128³)", "caches", 0.25, GiSettings { gather: caches, ..dense }),
        ("gather (GPU, 128³)", "caches 8²", 0.125, GiSettings { gather: caches8, ..dense }),
        ("anisotropic (GPU, 128³)", "off", 0.0, dense),
        ("anisotropic (GPU, 128³)", "on", 1.0, GiSettings { anisotropic: true, ..dense }),
    ];
    runs.extend(fixed.into_iter().map(|(k, n, x, s)| (k, n.to_string(), x, s)));
    // A GPU row: the CPU's record with the GPU named.
    let gpu_record = |name: &str, setting: String, x: f64, run: &GpuGiRun, error: ImageError| {
        let mut r = accuracy_record(cfg, scene.instances().len(), name, setting, x, summarize(&run.times).0, error);
        r.backend_kind = "gpu".into();
        r.backend = format!("{backend}{}", if run.timed { "" } else { " (wall clock)" });
        r
    };
    for (knob, name, x, s) in runs {
        progress(&format!("gi-accuracy (GPU): {label}{knob}, {name}"));
        let run = gpu_gi_frames(ctx, &s, scene, camera, lights, &plan, cfg.repeats)?;
        let error = compare_to(&run.frame, &reference)?;
        out.push(gpu_record(&format!("{label}{knob}"), name, x, &run, error));
    }
    // Where the scene's light is its emitters (the panel room): the pixels' light samples,
    // with shadow rays and with cone shadows (the whole frame's GPU time).
    if light_samples {
        for cone_shadows in [false, true] {
            let how = if cone_shadows { "cone shadows" } else { "shadow rays" };
            for samples in [1u32, 4, 16] {
                progress(&format!("gi-accuracy (GPU): {label}{samples} light samples, {how}"));
                let lit = crate::scene::Lights { emitter_samples: samples, ..lights.clone() };
                let s = GiSettings { cone_shadows, ..d };
                let run = gpu_gi_frames(ctx, &s, scene, camera, &lit, &plan, cfg.repeats)?;
                let error = compare_to(&run.frame, &reference)?;
                let knob = format!("{label}light samples, {how} (GPU, 128³)");
                out.push(gpu_record(&knob, format!("{samples}"), samples as f64, &run, error));
            }
        }
    }
    if cfg.bounces.is_empty() {
        return Ok(out);
    }
    // Two bounces, with the bounces' tail (the default) and without, against all bounces
    // (the CPU sweep's reference: same samples and seed).
    progress(&format!("gi-accuracy (GPU): {label}all-bounce reference, {} spp", cfg.spp));
    let mut pt = PathTracer::new(scene, camera, lights, ReferenceSettings { spp: cfg.spp, bounces: None, seed: 2 })
        .map_err(|e| crate::gi::GiError::Settings(e.to_string()))?;
    pt.run(&mut |_, _| {});
    let all = pt.frame();
    for (tail, what) in [(true, ""), (false, " without the tail")] {
        progress(&format!("gi-accuracy (GPU): {label}2 bounces{what}"));
        let s = GiSettings { bounces: 2, bounce_tail: tail, volume: VolumeChoice::Dense, ..GiSettings::default() };
        let run = gpu_gi_frames(ctx, &s, scene, camera, lights, &plan, cfg.repeats)?;
        let error = compare_to(&run.frame, &all)?;
        let name = format!("{label}bounces{what} (GPU, 128³, vs all-bounce reference)");
        out.push(gpu_record(&name, "2".into(), 2.0, &run, error));
    }
    Ok(out)
}

fn compare_to(frame: &Frame, reference: &Frame) -> Result<ImageError, crate::Error> {
    compare(frame, reference).map_err(|e| crate::gi::GiError::Settings(e.to_string()).into())
}

/// One record of the accuracy sweep.
fn accuracy_record(
    cfg: &AccuracyConfig,
    instances: usize,
    name: &str,
    setting: String,
    x: f64,
    ms: f64,
    error: ImageError,
) -> Record {
    Record {
        group: "gi-accuracy".into(),
        name: name.into(),
        setting,
        x,
        backend_kind: "cpu".into(),
        backend: "CPU reference".into(),
        width: cfg.size.0,
        height: cfg.size.1,
        frames: cfg.repeats,
        instances,
        median_ms: ms,
        p95_ms: ms,
        min_ms: ms,
        error: Some(error),
        machine: cfg.machine.clone(),
        command: cfg.command.clone(),
        ..Default::default()
    }
}

/// The emissive-panel room as a scene ([`crate::model::panel_room`]), voxelized at `depth`.
pub fn panel_room_scene(depth: u32) -> Result<Scene, crate::Error> {
    scene_of(&crate::model::panel_room::mesh(), depth)
}

/// Sweeps the GI knobs against the one-bounce path-traced reference on the box (sun and sky
/// through its skylight) and on the emissive-panel room (lit by its panel alone, rows named
/// "panel room: …", with the light samples per pixel as one more knob).
pub fn accuracy(cfg: &AccuracyConfig, progress: &mut dyn FnMut(&str)) -> Result<Vec<Record>, crate::Error> {
    let mut out = accuracy_on(
        "",
        false,
        &room_scene(cfg.depth)?,
        Some(&crate::model::room::mesh()),
        &crate::model::room::camera(cfg.size.0, cfg.size.1),
        &crate::model::room::lights(),
        cfg,
        progress,
    )?;
    // The car on its ground under the sun and sky: the outdoor case.
    let (car, camera) = car_on_ground(cfg)?;
    // (Its ground is made as voxels, with no triangles: no triangle reference.)
    out.extend(accuracy_on(CAR, false, &car, None, &camera, &crate::scene::Lights::default(), cfg, progress)?);
    let panel = panel_room_scene(cfg.depth)?;
    let camera = crate::model::panel_room::camera(cfg.size.0, cfg.size.1);
    let lights = crate::model::panel_room::lights();
    let panel_mesh = crate::model::panel_room::mesh();
    out.extend(accuracy_on("panel room: ", false, &panel, Some(&panel_mesh), &camera, &lights, cfg, progress)?);
    // The box with thick walls, sunlit outside: what leaks through them.
    let thick = thick_room_scene(cfg.depth)?;
    out.extend(accuracy_on(
        THICK,
        true,
        &thick,
        Some(&crate::model::room::thick_mesh()),
        &crate::model::room::camera(cfg.size.0, cfg.size.1),
        &crate::model::room::lights(),
        cfg,
        progress,
    )?);
    // Light samples: the whole frame's time (they are drawn by the shading and injection).
    // With cone shadows the pixels' samples need no shadow rays (the injection's still do):
    // those rows time the pixels alone too, a second frame on the kept volume.
    let reference = one_bounce_reference(&panel, &camera, &lights, cfg)?.0;
    progress("gi-accuracy: panel room, triangle reference for the light samples");
    let triangles = one_bounce_reference_on(&panel, Some(&panel_mesh), &camera, &lights, cfg)?.0;
    let plan = FramePlan::new(&panel, &camera, &lights, &Features::default(), None);
    // The pixels' samples with shadow rays and with cone shadows, then the cells' samples in
    // light injection (the pixels keeping the default 4).
    let runs = [
        (false, 1u32, 1u32),
        (false, 4, 1),
        (false, 16, 1),
        (false, 64, 1),
        (true, 1, 1),
        (true, 4, 1),
        (true, 16, 1),
        (true, 64, 1),
        (false, 4, 4),
        (false, 4, 16),
    ];
    for (cone_shadows, samples, cell_light_samples) in runs {
        let how = if cone_shadows { "cone shadows" } else { "shadow rays" };
        progress(&format!("gi-accuracy: panel room, {samples} light samples, {how}, {cell_light_samples} per cell"));
        let lights = crate::scene::Lights { emitter_samples: samples, ..lights.clone() };
        let s = GiSettings { cone_shadows, cell_light_samples, ..GiSettings::default() };
        let by_cells = cell_light_samples > 1 || (samples == 4 && !cone_shadows);
        let mut caches = GiCaches::new();
        let (mut whole, mut pixels) = (Vec::new(), Vec::new());
        let mut last = None;
        for k in 0..cfg.repeats.max(1) + 1 {
            caches.forget_last_frame();
            for kept in [false, true] {
                let t0 = Instant::now();
                let (f, _) = render_with_gi(
                    &panel,
                    &camera,
                    &lights,
                    &plan,
                    &RenderOptions::default(),
                    None,
                    &s,
                    &mut caches,
                    &|_, _| {},
                )?;
                if k > 0 {
                    if kept { &mut pixels } else { &mut whole }.push(t0.elapsed().as_secs_f64() * 1e3);
                }
                last = Some(f);
            }
        }
        let frame = last.ok_or_else(|| crate::gi::GiError::Settings("no frame".into()))?;
        let error = compare_to(&frame, &reference)?;
        let error_triangles = compare_to(&frame, &triangles)?;
        let mut rows = Vec::new();
        if cell_light_samples == 1 {
            for (name, times) in [("whole frame ms", &whole), ("pixels ms, volume kept", &pixels)] {
                rows.push((format!("panel room: light samples, {how} ({name})"), samples, times));
            }
        }
        if by_cells {
            rows.push(("panel room: light samples per GI cell (whole frame ms)".into(), cell_light_samples, &whole));
        }
        for (name, setting, times) in rows {
            let mut rec = accuracy_record(
                cfg,
                panel.instances().len(),
                &name,
                format!("{setting}"),
                setting as f64,
                summarize(times).0,
                error,
            );
            rec.error_triangles = Some(error_triangles);
            rec.frames = cfg.repeats.max(1);
            out.push(rec);
        }
    }
    Ok(out)
}

/// The one-bounce path-traced reference of a scene, and its milliseconds.
fn one_bounce_reference(
    scene: &Scene,
    camera: &crate::scene::Camera,
    lights: &crate::scene::Lights,
    cfg: &AccuracyConfig,
) -> Result<(Frame, f64), crate::Error> {
    one_bounce_reference_on(scene, None, camera, lights, cfg)
}

/// [`one_bounce_reference`], through `mesh`'s triangles when given instead of the voxels.
fn one_bounce_reference_on(
    scene: &Scene,
    mesh: Option<&Mesh>,
    camera: &crate::scene::Camera,
    lights: &crate::scene::Lights,
    cfg: &AccuracyConfig,
) -> Result<(Frame, f64), crate::Error> {
    let t0 = Instant::now();
    let settings = ReferenceSettings { spp: cfg.spp, bounces: Some(1), seed: 1 };
    let pt = match mesh {
        Some(m) => PathTracer::on_triangles(scene, m, camera, lights, settings),
        None => PathTracer::new(scene, camera, lights, settings),
    };
    let mut pt = pt.map_err(|e| crate::gi::GiError::Settings(e.to_string()))?;
    pt.run(&mut |_, _| {});
    Ok((pt.frame(), t0.elapsed().as_secs_f64() * 1e3))
}

/// [`accuracy`] on one scene; `label` starts every record's name. `leak_only` stops after the
/// baseline rows and the anisotropic knob (the thick-walled box measures only the leak).
#[allow(clippy::too_many_arguments)]
fn accuracy_on(
    label: &str,
    leak_only: bool,
    scene: &Scene,
    mesh: Option<&Mesh>,
    camera: &crate::scene::Camera,
    lights: &crate::scene::Lights,
    cfg: &AccuracyConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<Vec<Record>, crate::Error> {
    let (scene, camera, lights) = (scene, *camera, lights.clone());
    let plan = FramePlan::new(scene, &camera, &lights, &Features::default(), None);
    let t0 = Instant::now();
    let base = render(scene, &camera, &lights, &plan, &RenderOptions::default(), None, &|_, _| {})?;
    let base_ms = t0.elapsed().as_secs_f64() * 1e3;
    progress(&format!("gi-accuracy: {label}reference, {} spp", cfg.spp));
    let (reference, ref_ms) = one_bounce_reference(scene, &camera, &lights, cfg)?;
    let mut out = Vec::new();
    let instances = scene.instances().len();
    // The same reference through the source triangles, where the scene has them.
    let triangles = match mesh {
        Some(m) => {
            progress(&format!("gi-accuracy: {label}triangle reference, {} spp", cfg.spp));
            Some(one_bounce_reference_on(scene, Some(m), &camera, &lights, cfg)?)
        }
        None => None,
    };
    let mut push = |name: &str,
                    setting: String,
                    x: f64,
                    ms: f64,
                    gather_ms: Option<f64>,
                    frame: &Frame|
     -> Result<(), crate::Error> {
        let name = format!("{label}{name}");
        let mut r = accuracy_record(cfg, instances, &name, setting, x, ms, compare_to(frame, &reference)?);
        r.cache_stages = frame.cache_stages;
        r.gather_ms = gather_ms;
        if let Some((t, _)) = &triangles {
            r.error_triangles = Some(compare_to(frame, t)?);
        }
        out.push(r);
        Ok(())
    };
    push("no GI (flat sky term)", "renderer only".into(), 0.0, base_ms, None, &base)?;
    push("reference", format!("{} spp, 1 bounce", cfg.spp), cfg.spp as f64, ref_ms, None, &reference)?;
    if let Some((t, ms)) = &triangles {
        push("reference (triangles)", format!("{} spp, 1 bounce", cfg.spp), cfg.spp as f64, *ms, None, t)?;
    }
    let default = GiSettings::default();
    // Anisotropic levels, with per-pixel cones and with the radiance caches.
    let caches_gather = crate::render::Gather::Caches(crate::render::radiance_cache::CacheSettings::default());
    // (The first rows per pixel, as before the caches became the default gather.)
    for (knob, gather) in
        [("anisotropic", crate::render::Gather::Pixels), ("anisotropic, caches gather", caches_gather)]
    {
        for (anisotropic, setting) in [(false, "off"), (true, "on")] {
            progress(&format!("gi-accuracy: {label}{knob} {setting}"));
            let s = GiSettings { anisotropic, gather, ..default };
            let (ms, g, f) = gi_frame_timed(scene, &camera, &lights, &plan, &s, cfg.repeats)?;
            push(knob, setting.into(), anisotropic as u32 as f64, ms, Some(g), &f)?;
        }
    }
    if leak_only {
        return Ok(out);
    }
    for &res in &cfg.resolutions {
        progress(&format!("gi-accuracy: {res}³"));
        let (ms, g, f) = gi_frame_timed(scene, &camera, &lights, &plan, &GiSettings { res, ..default }, cfg.repeats)?;
        push("volume resolution", format!("{res}³"), res as f64, ms, Some(g), &f)?;
    }
    for &cones in &cfg.cones {
        progress(&format!("gi-accuracy: {cones} cones"));
        // The per-pixel cones' count (the caches trace their own texel cones).
        let knob = crate::gi::ConeSettings { diffuse_cones: cones, ..default.cones };
        let s = GiSettings { cones: knob, gather: crate::render::Gather::Pixels, ..default };
        let (ms, g, f) = gi_frame_timed(scene, &camera, &lights, &plan, &s, cfg.repeats)?;
        push("diffuse cones", format!("{cones}"), cones as f64, ms, Some(g), &f)?;
    }
    let caches = crate::render::radiance_cache::CacheSettings::default();
    for (what, gather) in [
        ("pixels", crate::render::Gather::Pixels),
        ("half", crate::render::Gather::Half),
        ("caches", crate::render::Gather::Caches(caches)),
    ] {
        progress(&format!("gi-accuracy: {what} gather"));
        let (ms, gather_ms, f) =
            gi_frame_timed(scene, &camera, &lights, &plan, &GiSettings { gather, ..default }, cfg.repeats)?;
        let x = match gather {
            crate::render::Gather::Half => 0.5,
            crate::render::Gather::Caches(_) => 0.25,
            crate::render::Gather::Pixels => 1.0,
        };
        push("gather", what.into(), x, ms, Some(gather_ms), &f)?;
    }
    // Each radiance-cache knob about the defaults.
    use crate::render::radiance_cache::{CacheSettings, Placement};
    let with = |f: &dyn Fn(&mut CacheSettings)| {
        let mut c = caches;
        f(&mut c);
        c
    };
    let mut knobs: Vec<(&str, String, f64, CacheSettings)> = Vec::new();
    for n in [1u32, 2, 3, 4] {
        knobs.push(("caches: per tile", format!("{n}"), n as f64, with(&|c| c.per_tile = n)));
    }
    for t in [8u32, 16, 32] {
        knobs.push(("caches: tile", format!("{t} px"), t as f64, with(&|c| c.tile = t)));
    }
    for r in [8u32, 16, 32] {
        knobs.push(("caches: map resolution", format!("{r}²"), r as f64, with(&|c| c.res = r)));
    }
    for r in [1u32, 2, 3] {
        knobs.push(("caches: radius", format!("{r} tiles"), r as f64, with(&|c| c.radius = r)));
    }
    for p in [Placement::Clustered, Placement::Even] {
        let x = (p == Placement::Clustered) as u32 as f64;
        knobs.push(("caches: placement", format!("{p:?}").to_lowercase(), x, with(&|c| c.placement = p)));
    }
    for w in [100u32, 50, 25, 12] {
        knobs.push(("caches: cone width", format!("{w} %"), w as f64, with(&|c| c.cone_percent = w)));
    }
    for (knob, setting, x, c) in knobs {
        progress(&format!("gi-accuracy: {knob} {setting}"));
        let s = GiSettings { gather: crate::render::Gather::Caches(c), ..default };
        let (ms, gather_ms, f) = gi_frame_timed(scene, &camera, &lights, &plan, &s, cfg.repeats)?;
        push(knob, setting, x, ms, Some(gather_ms), &f)?;
    }
    for filter in [Filter::Nearest, Filter::Split] {
        let (ms, g, f) =
            gi_frame_timed(scene, &camera, &lights, &plan, &GiSettings { filter, ..default }, cfg.repeats)?;
        let x = if filter == Filter::Split { 1.0 } else { 0.0 };
        push("filter", format!("{filter:?}").to_lowercase(), x, ms, Some(g), &f)?;
    }
    if !cfg.bounces.is_empty() {
        // More bounces approach the light after all bounces, not after one: they are measured
        // against the unbounded reference.
        progress(&format!("gi-accuracy: all-bounce reference, {} spp", cfg.spp));
        let t0 = Instant::now();
        let mut pt =
            PathTracer::new(scene, &camera, &lights, ReferenceSettings { spp: cfg.spp, bounces: None, seed: 2 })
                .map_err(|e| crate::gi::GiError::Settings(e.to_string()))?;
        pt.run(&mut |_, _| {});
        let all = pt.frame();
        let all_ms = t0.elapsed().as_secs_f64() * 1e3;
        let setting = format!("{} spp, all bounces", cfg.spp);
        let error = compare_to(&all, &all)?;
        let name = format!("{label}reference (all bounces)");
        out.push(accuracy_record(cfg, instances, &name, setting, cfg.spp as f64, all_ms, error));
        // What light after N bounces can reach at best: the path tracer stopped after N
        // bounces (its own samples and seed) against the unbounded one.
        for &bounces in &cfg.bounces {
            progress(&format!("gi-accuracy: reference with {bounces} bounces, {} spp", cfg.spp));
            let t0 = Instant::now();
            let settings = ReferenceSettings { spp: cfg.spp, bounces: Some(bounces), seed: 3 };
            let mut pt = PathTracer::new(scene, &camera, &lights, settings)
                .map_err(|e| crate::gi::GiError::Settings(e.to_string()))?;
            pt.run(&mut |_, _| {});
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            let error = compare_to(&pt.frame(), &all)?;
            let name = format!("{label}reference with N bounces (vs all-bounce reference)");
            let setting = format!("{} spp, {bounces}", cfg.spp);
            out.push(accuracy_record(cfg, instances, &name, setting, bounces as f64, ms, error));
        }
        // With the bounces' tail (the default) and without it (exactly N bounces).
        for (tail, what) in [(true, ""), (false, " without the tail")] {
            for &bounces in &cfg.bounces {
                progress(&format!("gi-accuracy: {bounces} bounces{what}"));
                let s = GiSettings { bounces, bounce_tail: tail, ..default };
                let (ms, f) = gi_frame(scene, &camera, &lights, &plan, &s, cfg.repeats)?;
                let error = compare_to(&f, &all)?;
                let name = format!("{label}bounces{what} (vs all-bounce reference)");
                out.push(accuracy_record(cfg, instances, &name, format!("{bounces}"), bounces as f64, ms, error));
            }
        }
    }
    Ok(out)
}

/// What the volume-layout scenario measures.
#[derive(Clone, Debug)]
pub struct LayoutConfig {
    /// Image size.
    pub size: (u32, u32),
    /// Resolutions: dense up to 512, sparse all.
    pub resolutions: Vec<u32>,
    /// Timed runs per setting (the median is kept).
    pub repeats: usize,
    /// The command line, for the records.
    pub command: String,
    /// The machine, for the records.
    pub machine: String,
}

/// One gi-volume record (CPU; the GPU's overrides backend and setting).
fn layout_record(cfg: &LayoutConfig, name: &str, res: u32, times: &[f64], bytes: u64, instances: usize) -> Record {
    let (median, p95, min) = summarize(times);
    Record {
        group: "gi-volume".into(),
        name: name.into(),
        x: res as f64,
        backend_kind: "cpu".into(),
        backend: "CPU reference".into(),
        width: cfg.size.0,
        height: cfg.size.1,
        frames: cfg.repeats,
        instances,
        median_ms: median,
        p95_ms: p95,
        min_ms: min,
        volume_bytes: Some(bytes),
        machine: cfg.machine.clone(),
        command: cfg.command.clone(),
        ..Default::default()
    }
}

/// The dense and the sparse world volume on the box at each resolution: the whole GI pass per
/// frame and the bytes of the volume's cells (`--scenarios gi-volume`).
pub fn layouts(cfg: &LayoutConfig, progress: &mut dyn FnMut(&str)) -> Result<Vec<Record>, crate::Error> {
    use crate::gi::shade::VolumeChoice;
    let scene = room_scene(8)?;
    let camera = crate::model::room::camera(cfg.size.0, cfg.size.1);
    let lights = crate::model::room::lights();
    let plan = FramePlan::new(&scene, &camera, &lights, &Features::default(), None);
    let mut out = Vec::new();
    for &res in &cfg.resolutions {
        for (choice, name) in [(VolumeChoice::Dense, "dense"), (VolumeChoice::Sparse, "sparse")] {
            let s = GiSettings { res, volume: choice, ..GiSettings::default() };
            if s.validated().is_err() {
                continue; // dense past 512³, or a resolution the sparse bricks do not divide
            }
            progress(&format!("gi-volume: {name} {res}³"));
            let mut caches = GiCaches::new();
            let mut times = Vec::new();
            let mut stats = crate::gi::GiStats::default();
            for k in 0..cfg.repeats.max(1) + 1 {
                caches.forget_last_frame();
                let opts = RenderOptions::default();
                stats = render_with_gi(&scene, &camera, &lights, &plan, &opts, None, &s, &mut caches, &|_, _| {})?.1;
                if k > 0 {
                    times.push(gi_ms(&stats));
                }
            }
            let mut r = layout_record(cfg, name, res, &times, stats.volume_bytes, scene.instances().len());
            r.setting = format!("{} occupied cells", stats.occupied);
            out.push(r);
        }
    }
    Ok(out)
}

/// Prefix of the accuracy records of the car on its ground.
pub const CAR: &str = "car on ground: ";

/// Name prefix of the accuracy records of the thick-walled box ([`thick_room_scene`]).
pub const THICK: &str = "thick walls: ";

/// The default car standing on its ground, at `cfg`'s depth, and a camera that frames it
/// from the front quarter at `cfg`'s size.
fn car_on_ground(cfg: &AccuracyConfig) -> Result<(Scene, crate::scene::Camera), crate::Error> {
    let mesh = crate::model::car::mesh();
    let parts = crate::pipeline::build_parts(&mesh, crate::voxelize::Resolution::Depth(cfg.depth))?;
    let st = stage_cars(&parts, 1, false, true)?;
    let (lo, hi) = st.cars_bounds();
    let pad = glam::DVec3::new(0.6, 0.0, 0.6);
    let camera = crate::scene::Camera::framing((lo - pad).as_vec3(), (hi + pad).as_vec3(), cfg.size.0, cfg.size.1);
    Ok((st.scene, camera))
}

/// Frames of the flicker clip (at 60 frames a second: a quarter of a second of driving).
const FLICKER_FRAMES: usize = 16;

/// One frame of the flicker clip: the hits and the indirect light.
struct ClipFrame {
    instance: Vec<i32>,
    t: Vec<f32>,
    /// GI's frame minus the same frame with the flat sky term: the cones' light minus a
    /// constant per surface, the direct light cancelled.
    indirect: Vec<glam::Vec3>,
    /// The instances' world transforms.
    worlds: Vec<glam::DAffine3>,
}

/// Temporal stability, the voxel-transformation paper's argument for split filtering: the
/// default car drives over the ground under sun and sky for `FLICKER_FRAMES` frames at 60
/// frames a second, rendered with GI under nearest and split filtering and with the
/// half-resolution gather; on the pixels whose geometry stayed the same (a still instance hit
/// at the same t) the indirect light's first and second differences from frame to frame
/// ([`super::metrics::Flicker`]). Each frame builds its volume afresh, as a moving car makes
/// it.
pub fn flicker(cfg: &AccuracyConfig, progress: &mut dyn FnMut(&str)) -> Result<Vec<Record>, crate::Error> {
    use crate::render::Gather;
    let mesh = crate::model::car::mesh();
    let parts = crate::pipeline::build_parts(&mesh, crate::voxelize::Resolution::Depth(cfg.depth))?;
    let lights = crate::scene::Lights::default();
    let (w, h) = (cfg.size.0 * 2, cfg.size.1 * 2);
    let mut out = Vec::new();
    // The radiance caches too: their placement follows the G-buffer, so it moves with the car.
    let settings = [
        (Filter::Nearest, Gather::Pixels),
        (Filter::Split, Gather::Pixels),
        (Filter::Split, Gather::Half),
        (Filter::Split, Gather::Caches(crate::render::radiance_cache::CacheSettings::default())),
    ];
    for (filter, gather) in settings {
        let how = match gather {
            Gather::Pixels => "pixels",
            Gather::Half => "half",
            Gather::Caches(_) => "caches",
        };
        let name = format!("{}, {how} gather", format!("{filter:?}").to_lowercase());
        progress(&format!("gi-accuracy: flicker, {name}"));
        let mut st = stage_cars(&parts, 1, true, true)?;
        pose_all(&mut st.scene, &st.cars, 0.0)?;
        st.scene.update()?;
        let (lo, hi) = st.cars_bounds();
        let pad = glam::DVec3::splat(2.0);
        let camera = crate::scene::Camera::framing((lo - pad).as_vec3(), (hi + pad).as_vec3(), w, h);
        let s = GiSettings { filter, gather, ..GiSettings::default() };
        let mut caches = GiCaches::new();
        let (mut frames, mut times) = (Vec::<ClipFrame>::new(), Vec::new());
        let (mut change, mut jerk, mut still, mut pairs, mut triples) = (0.0, 0.0, 0.0, 0usize, 0usize);
        for k in 0..FLICKER_FRAMES {
            pose_all(&mut st.scene, &st.cars, k as f64 / 60.0)?;
            st.scene.update()?;
            let plan = FramePlan::new(&st.scene, &camera, &lights, &Features::default(), None);
            let opts = RenderOptions::default();
            let flat = render(&st.scene, &camera, &lights, &plan, &opts, None, &|_, _| {})?;
            let (f, stats) =
                render_with_gi(&st.scene, &camera, &lights, &plan, &opts, None, &s, &mut caches, &|_, _| {})?;
            times.push(gi_ms(&stats));
            let indirect = f.radiance.iter().zip(&flat.radiance).map(|(a, b)| *a - *b).collect();
            frames.push(ClipFrame { instance: f.instance, t: f.t, indirect, worlds: st.scene.worlds().to_vec() });
            let n = frames.len();
            // Still in frames a..=b: a hit on an instance that did not move, at the same t.
            let is_still = |p: usize, a: usize, b: usize| {
                let i = frames[b].instance[p];
                i >= 0
                    && (a..b).all(|j| {
                        frames[j].instance[p] == i
                            && frames[j].t[p].to_bits() == frames[b].t[p].to_bits()
                            && frames[j].worlds[i as usize] == frames[b].worlds[i as usize]
                    })
            };
            let mean = |f: &dyn Fn(usize) -> Option<f64>| {
                let (sum, count) = (0..(w * h) as usize).filter_map(f).fold((0.0, 0usize), |(s, c), v| (s + v, c + 1));
                (sum / count.max(1) as f64, count as f64 / (w * h) as f64)
            };
            let abs = |v: glam::Vec3| v.abs().element_sum() as f64 / 3.0;
            if n >= 2 {
                let (c, _) = mean(&|p| {
                    is_still(p, n - 2, n - 1).then(|| abs(frames[n - 1].indirect[p] - frames[n - 2].indirect[p]))
                });
                change += c;
                pairs += 1;
            }
            if n >= 3 {
                let (j, frac) = mean(&|p| {
                    is_still(p, n - 3, n - 1).then(|| {
                        abs(frames[n - 1].indirect[p] - 2.0 * frames[n - 2].indirect[p] + frames[n - 3].indirect[p])
                    })
                });
                jerk += j;
                still += frac;
                triples += 1;
            }
        }
        let (median_ms, p95_ms, min_ms) = summarize(&times);
        out.push(Record {
            group: "gi-flicker".into(),
            name: "flicker: the driving car".into(),
            setting: name,
            x: (filter == Filter::Split) as u32 as f64
                + match gather {
                    Gather::Pixels => 0.0,
                    Gather::Half => 1.0,
                    Gather::Caches(_) => 2.0,
                },
            backend_kind: "cpu".into(),
            backend: "CPU reference".into(),
            width: w,
            height: h,
            frames: FLICKER_FRAMES,
            instances: st.scene.instances().len(),
            median_ms,
            p95_ms,
            min_ms,
            flicker: Some(super::metrics::Flicker {
                change: change / pairs.max(1) as f64,
                jerk: jerk / triples.max(1) as f64,
                still: still / triples.max(1) as f64,
            }),
            machine: cfg.machine.clone(),
            command: cfg.command.clone(),
            ..Record::default()
        });
    }
    Ok(out)
}
