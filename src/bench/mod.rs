//! The frame-time benchmark harness: animation clips rendered with a static camera after a
//! warm-up, per-frame wall times summarized as median / p95 / min, with GPU pass times,
//! rays per second, memory, image error against a reference and the frame plan in every
//! record. [`matrix`] runs the scenarios × settings × backends; [`report`] writes JSON, CSV
//! and the Markdown tables; `chart` draws the PNG charts; `peers` times other ray casters on
//! the same car.

pub mod gi;
pub mod matrix;
pub mod metrics;
pub mod report;

#[cfg(feature = "charts")]
pub mod chart;
#[cfg(feature = "peers")]
pub mod peers;

use crate::render::{Features, Frame, FramePlan, RenderOptions};
use crate::scene::car::{Car, SeenCars};
use crate::scene::{Camera, FrameRays, Lights, Scene, Sight};
use crate::session::Session;
use std::time::Instant;

/// One measured configuration: a scenario, one setting of it, one backend.
#[derive(Clone, Debug, PartialEq, Default)]
#[cfg_attr(feature = "json", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "json", serde(default))]
pub struct Record {
    /// Scenario family: `paper`, `instances`, `resolution`, `depth` or `peers`.
    pub group: String,
    /// Human-readable name of this configuration.
    pub name: String,
    /// The setting within the family (e.g. `BVH`, `level 6`, `embree`).
    pub setting: String,
    /// The swept quantity (cars, pixels, level; 0 where nothing is swept).
    pub x: f64,
    /// `cpu`, `gpu`, or a peer's name.
    pub backend_kind: String,
    /// The backend in words (CPU model or GPU adapter).
    pub backend: String,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Untimed warm-up frames.
    pub warmup: usize,
    /// Timed frames.
    pub frames: usize,
    /// Instances in the scene.
    pub instances: usize,
    /// Median frame time (ms): animate, update transforms, plan, render.
    pub median_ms: f64,
    /// 95th-percentile frame time (ms).
    pub p95_ms: f64,
    /// Fastest frame (ms).
    pub min_ms: f64,
    /// Primary and shadow rays actually traced per second (reused pixels not counted), in
    /// millions, over the timed frames.
    pub mrays_per_s: f64,
    /// Fraction of pixels reused from the hit buffer.
    pub reused_fraction: f64,
    /// Instance octrees traversed per traced (not reused) primary ray.
    pub instances_per_ray: f64,
    /// Instances skipped by a missed bounding sphere per traced primary ray.
    pub culled_per_ray: f64,
    /// Median GPU time of the trace pass (ms), from timestamp queries.
    pub gpu_trace_ms: Option<f64>,
    /// Median GPU time of the shade pass (ms).
    pub gpu_shade_ms: Option<f64>,
    /// Bytes of the SVOs in the scene (geometry and attributes).
    pub svo_bytes: u64,
    /// Bytes of the SVOs' geometry: what traversal reads (child masks, links above the
    /// deepest level).
    pub geometry_bytes: u64,
    /// Bytes of the SVOs' attributes: read only for hits.
    pub attribute_bytes: u64,
    /// Voxels of the SVOs in the scene (each part once).
    pub voxels: u64,
    /// Bytes of GPU buffers the renderer used (GPU backend only).
    pub gpu_bytes: Option<u64>,
    /// Median host time per frame outside the GPU passes (ms): wall time minus the
    /// timestamped trace, GI and shade passes and a crowd's pose and refit passes (GPU
    /// backend with timestamps only).
    pub gpu_host_ms: Option<f64>,
    /// Median host time of a GPU frame's render up to its submit (ms): preparing the changed
    /// instances, refitting the BVH, converting and uploading them, encoding the passes
    /// (`GpuRenderer::submit_host_ms`; GPU backend only).
    pub gpu_submit_ms: Option<f64>,
    /// Median GPU time of a crowd's pose and refit passes per frame (ms; a crowd posed on the
    /// GPU, with timestamps).
    pub gpu_crowd_ms: Option<f64>,
    /// Median time per frame spent posing the clip and updating the scene's transforms (ms),
    /// the host's scene work before the render (each backend).
    pub pose_ms: Option<f64>,
    /// Buffers created per timed frame, on average (GPU backend only).
    pub gpu_buffers_per_frame: Option<f64>,
    /// Bytes read back to the host per timed frame, on average (GPU backend only).
    pub gpu_read_back_per_frame: Option<f64>,
    /// Bytes of the GI world volume's cells (gi-volume scenario).
    pub volume_bytes: Option<u64>,
    /// Image error against the reference of this scenario (depth sweep), see [`metrics`].
    pub error: Option<metrics::ImageError>,
    /// Error against the reference traced through the source triangles instead of the voxels
    /// (gi-accuracy, scenes made from a mesh): the voxelization's own error included.
    #[cfg_attr(feature = "json", serde(default))]
    pub error_triangles: Option<metrics::ImageError>,
    /// Frame-to-frame change of the indirect light over a clip (gi-accuracy's flicker rows).
    #[cfg_attr(feature = "json", serde(default))]
    pub flicker: Option<metrics::Flicker>,
    /// Milliseconds of GI's gather at the pixels (the ambient pass: cones, or caches and
    /// their blending), median (gi-accuracy, CPU).
    #[cfg_attr(feature = "json", serde(default))]
    pub gather_ms: Option<f64>,
    /// Where the radiance caches' time went (gi-accuracy rows that gather with caches).
    #[cfg_attr(feature = "json", serde(default))]
    pub cache_stages: Option<crate::render::radiance_cache::CacheStages>,
    /// The plan of the last frame.
    pub plan: Option<FramePlan>,
    /// The machine (CPU model and threads).
    pub machine: String,
    /// The command that produced the record.
    pub command: String,
}

/// Median, 95th percentile and minimum of a list of times.
pub fn summarize(times: &[f64]) -> (f64, f64, f64) {
    let mut v = times.to_vec();
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        return (0.0, 0.0, 0.0);
    }
    let pick = |q: f64| v[((q * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)];
    (pick(0.5), pick(0.95), v[0])
}

/// What a clip renders and how often.
pub struct Clip<'a> {
    /// The scene (posed each frame).
    pub scene: &'a mut Scene,
    /// The cars to pose.
    pub cars: &'a [Car],
    /// A scene file's hierarchy and clip to pose (None: only the cars move).
    pub animated: Option<&'a crate::scene::Animated>,
    /// Ray tracing or square splats for primary visibility.
    pub renderer: crate::render::Renderer,
    /// How the GPU draws splats (compute passes or quads).
    pub splat_draw: crate::render::SplatDraw,
    /// The (static) camera.
    pub camera: &'a Camera,
    /// The lights.
    pub lights: &'a Lights,
    /// Technique switches.
    pub features: Features,
    /// Level of detail (`u32::MAX`: full detail).
    pub lod: u32,
    /// Untimed frames first (caches, pipelines, hit buffer).
    pub warmup: usize,
    /// Timed frames.
    pub frames: usize,
    /// Clip frames per second (the animation step).
    pub fps: f64,
    /// On the GPU backend, pose the cars and refit their tree on the GPU
    /// (`gpu::crowd`): the host then only sets each frame's time. Ignored on the
    /// CPU, and with a scene file's clip.
    pub pose_on_gpu: bool,
}

/// Renders a clip's warm-up and timed frames, timing each whole frame; returns the record
/// (group, name and setting left for the caller) and the frame of the clip's time 0.
///
/// The frames are the clip's, one `1 / fps` apart, with its time 0 at the last warm-up
/// frame (the warm-up leads up to it from negative times, which the clips loop or extend):
/// every timed frame then moves from the frame before it, as an animation's frames do,
/// and the picture of time 0 is the same whatever the warm-up (the depth sweep compares it
/// with a reference). Without a warm-up the first timed frame is time 0.
///
/// GPU frames stay on the GPU, as the demo's do: the GPU adds up each frame's statistics and
/// only those and the pass times are read back (which also waits for the frame, so the wall
/// time is the whole frame's). The picture is read back from the frame of time 0 and copied
/// outside the timed frames, so that the session still recycles that frame's memory.
pub fn run_clip(session: &mut Session, backend_name: &str, clip: Clip<'_>) -> Result<(Record, Frame), crate::Error> {
    run_clip_timed(session, backend_name, clip).map(|(r, f, _)| (r, f))
}

/// [`run_clip`], also returning each timed frame's wall time (ms), for callers that pool the
/// frames of several clips ([`pool_rounds`]).
pub fn run_clip_timed(
    session: &mut Session,
    backend_name: &str,
    clip: Clip<'_>,
) -> Result<(Record, Frame, Vec<f64>), crate::Error> {
    let (mut times, mut rays, mut reused, mut busy) = (Vec::new(), 0u64, 0u64, 0.0f64);
    let (mut traced, mut culled) = (0u64, 0u64);
    let (mut trace_ms, mut shade_ms) = (Vec::new(), Vec::new());
    let (mut host_ms, mut traffic) = (Vec::new(), Vec::new());
    let (mut submit_ms, mut pose_ms) = (Vec::new(), Vec::new());
    let mut crowd_ms = Vec::new();
    let mut plan = None;
    let mut first: Option<Frame> = None;
    let frames = clip.frames.max(1);
    // A clip starts afresh: nothing is reused from the session's frames before it.
    session.restart();
    let gpu = session.backend().kind_name() == "gpu";
    // The frame of the clip's time 0: the last warm-up frame, or the first timed one.
    let picture_at = clip.warmup.saturating_sub(1);
    session.set_counting(gpu);
    // Only the cars some ray of the frame can reach are posed (as the demo and `render` do),
    // unless the switches say otherwise or a scene file's clip moves too.
    let opts = RenderOptions {
        max_level: clip.lod,
        renderer: clip.renderer,
        splat_draw: clip.splat_draw,
        ..Default::default()
    };
    let sight = if clip.features.pose_seen && clip.animated.is_none() && !clip.cars.is_empty() {
        let rays = FrameRays::of(clip.scene, &clip.features, session.gi().is_some(), &opts);
        let surfaces = crate::scene::stage::surfaces(clip.scene, clip.cars, clip.lod)?;
        Sight::new(clip.camera, clip.lights, rays, surfaces).ok()
    } else {
        None
    };
    let mut seen = SeenCars::default();
    // The cars posed on the GPU: made once for the clip, the renderer's until it ends.
    #[cfg(feature = "gpu")]
    let on_gpu = match session.backend_mut().gpu_mut() {
        Some(g) if clip.pose_on_gpu && clip.animated.is_none() && !clip.cars.is_empty() => {
            let crowd = crate::gpu::crowd::GpuCrowd::new(g.ctx.clone(), clip.scene, clip.cars, clip.lod)?;
            g.set_crowd(Some(crowd));
            true
        }
        _ => false,
    };
    #[cfg(not(feature = "gpu"))]
    let on_gpu = false;
    let mut frames_of_clip = || -> Result<(), crate::Error> {
        for f in 0..clip.warmup + frames {
            session.set_read_back(!gpu || f == picture_at);
            let start = Instant::now();
            // (Timed frames that replayed the warm-up's pose were frames where nothing moved:
            // the first of each instance-sweep round, half of its frames at --frames 10.)
            let t = (f as f64 - picture_at as f64) / clip.fps;
            let frame = || -> Result<_, crate::Error> {
                if on_gpu {
                    // The frame's pass poses the cars at t.
                    #[cfg(feature = "gpu")]
                    if let Some(g) = session.backend_mut().gpu_mut() {
                        g.set_crowd_time(t);
                    }
                } else {
                    seen.pose(clip.scene, clip.cars, t, sight.as_ref(), clip.lod)?;
                    if let Some(a) = clip.animated {
                        a.rig.pose(clip.scene, a.clip, t)?;
                    }
                    clip.scene.update()?;
                }
                let posed = start.elapsed().as_secs_f64() * 1e3;
                Ok((posed, session.frame(clip.scene, clip.camera, clip.lights, &clip.features, &opts, &|_, _| {})?))
            };
            let (posed_ms, report) = crate::pool::run_awake(frame)?;
            let secs = start.elapsed().as_secs_f64();
            if f >= clip.warmup {
                pose_ms.push(posed_ms);
                if let Some(ms) = session.backend().submit_host_ms() {
                    submit_ms.push(ms);
                }
                if let Some((tr, sh)) = session.backend().pass_times() {
                    trace_ms.push(tr);
                    shade_ms.push(sh);
                    let gi = session.backend().gi_pass_ms().unwrap_or(0.0);
                    // (A crowd posed on the GPU: its passes are the GPU's time, not the host's.)
                    let crowd = session.backend().crowd_pass_ms();
                    host_ms.push(secs * 1e3 - tr - sh - gi - crowd.unwrap_or(0.0));
                    crowd_ms.extend(crowd);
                }
                if let Some(t) = session.backend().gpu_traffic() {
                    traffic.push(t);
                }
                times.push(secs * 1e3);
                let frame = session.last_frame().ok_or_else(|| crate::Error::Io {
                    path: "bench".into(),
                    source: std::io::Error::other("the session kept no frame"),
                })?;
                rays += frame.primary_rays - frame.reused + frame.shadow_rays;
                reused += frame.reused;
                traced += frame.instances_traced;
                culled += frame.spheres_culled;
                busy += secs;
            }
            if f == picture_at {
                first = session.last_frame().cloned();
            }
            plan = Some(report.plan);
        }
        Ok(())
    };
    let result = frames_of_clip();
    #[cfg(feature = "gpu")]
    if on_gpu {
        if let Some(g) = session.backend_mut().gpu_mut() {
            g.set_crowd(None);
        }
    }
    result?;
    if let (true, Some(p)) = (on_gpu, plan.as_mut()) {
        p.reasons.push("pose: on the GPU (the frame's passes pose the cars and refit their instance BVH, which the frame walks whatever the search above)".into());
    }
    session.set_read_back(true);
    session.set_counting(false);
    let (median_ms, p95_ms, min_ms) = summarize(&times);
    let pixels = (clip.camera.width * clip.camera.height) as f64 * frames as f64;
    let stats: Vec<_> = clip.scene.parts.iter().map(|p| p.stats()).collect();
    let geometry_bytes = stats.iter().map(|s| s.geometry_bytes).sum::<u64>();
    let attribute_bytes = stats.iter().map(|s| s.attribute_bytes).sum::<u64>();
    let record = Record {
        width: clip.camera.width,
        height: clip.camera.height,
        warmup: clip.warmup,
        frames,
        instances: clip.scene.instances().len(),
        median_ms,
        p95_ms,
        min_ms,
        mrays_per_s: rays as f64 / busy.max(1e-9) / 1e6,
        reused_fraction: reused as f64 / pixels.max(1.0),
        instances_per_ray: traced as f64 / (pixels - reused as f64).max(1.0),
        culled_per_ray: culled as f64 / (pixels - reused as f64).max(1.0),
        backend: backend_name.to_string(),
        backend_kind: session.backend().kind_name().to_string(),
        gpu_trace_ms: (!trace_ms.is_empty()).then(|| summarize(&trace_ms).0),
        gpu_shade_ms: (!shade_ms.is_empty()).then(|| summarize(&shade_ms).0),
        svo_bytes: geometry_bytes + attribute_bytes,
        geometry_bytes,
        attribute_bytes,
        voxels: stats.iter().map(|s| s.voxels).sum(),
        gpu_bytes: session.backend().gpu_bytes(),
        gpu_host_ms: (!host_ms.is_empty()).then(|| summarize(&host_ms).0),
        gpu_submit_ms: (!submit_ms.is_empty()).then(|| summarize(&submit_ms).0),
        pose_ms: (!pose_ms.is_empty()).then(|| summarize(&pose_ms).0),
        gpu_crowd_ms: (!crowd_ms.is_empty()).then(|| summarize(&crowd_ms).0),
        gpu_buffers_per_frame: (!traffic.is_empty())
            .then(|| traffic.iter().map(|t| t.0).sum::<u64>() as f64 / traffic.len() as f64),
        gpu_read_back_per_frame: (!traffic.is_empty())
            .then(|| traffic.iter().map(|t| t.1).sum::<u64>() as f64 / traffic.len() as f64),
        plan,
        ..Record::default()
    };
    let first = first.ok_or_else(|| crate::Error::Io {
        path: "bench".into(),
        source: std::io::Error::other("no frame was rendered"),
    })?;
    Ok((record, first, times))
}

/// One record of the same clip timed in several rounds (each with its own warm-up, in turn
/// with other clips): the median, 95th percentile and minimum of all their frames together,
/// the per-frame averages (rays per second, reuse, instances per ray) averaged over the
/// rounds by their frames, the GPU's pass and host times and the posing time the median of
/// the rounds' medians, the rest from the first round. None without rounds.
pub fn pool_rounds(rounds: Vec<(Record, Vec<f64>)>) -> Option<Record> {
    let frames: usize = rounds.iter().map(|(r, _)| r.frames).sum();
    let times: Vec<f64> = rounds.iter().flat_map(|(_, t)| t.iter().copied()).collect();
    let mean = |field: fn(&Record) -> f64| {
        rounds.iter().map(|(r, _)| field(r) * r.frames as f64).sum::<f64>() / frames.max(1) as f64
    };
    let (mrays_per_s, reused_fraction) = (mean(|r| r.mrays_per_s), mean(|r| r.reused_fraction));
    let (instances_per_ray, culled_per_ray) = (mean(|r| r.instances_per_ray), mean(|r| r.culled_per_ray));
    // The GPU's pass times: the median of the rounds' medians.
    let median_of = |field: fn(&Record) -> Option<f64>| {
        let v: Vec<f64> = rounds.iter().filter_map(|(r, _)| field(r)).collect();
        (!v.is_empty()).then(|| summarize(&v).0)
    };
    let (gpu_trace_ms, gpu_shade_ms) = (median_of(|r| r.gpu_trace_ms), median_of(|r| r.gpu_shade_ms));
    let gpu_host_ms = median_of(|r| r.gpu_host_ms);
    let (gpu_submit_ms, pose_ms) = (median_of(|r| r.gpu_submit_ms), median_of(|r| r.pose_ms));
    let gpu_crowd_ms = median_of(|r| r.gpu_crowd_ms);
    let (first, _) = rounds.into_iter().next()?;
    let (median_ms, p95_ms, min_ms) = summarize(&times);
    Some(Record {
        frames,
        median_ms,
        p95_ms,
        min_ms,
        mrays_per_s,
        reused_fraction,
        instances_per_ray,
        culled_per_ray,
        gpu_trace_ms,
        gpu_shade_ms,
        gpu_host_ms,
        gpu_submit_ms,
        pose_ms,
        gpu_crowd_ms,
        ..first
    })
}

/// CPU model and thread count, for records.
pub fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    format!("{cpu}, {threads} hardware threads")
}

#[cfg(test)]
mod tests {
    use super::{run_clip, Clip, Features, Frame, Session};
    use crate::scene::{Camera, Lights};
    /// Rounds pool their frames: the median of all of them (not of the rounds' medians), the
    /// averages weighted by frames, the GPU times the median of the rounds'.
    #[test]
    fn rounds_pool_their_frames() {
        use super::{pool_rounds, Record};
        let round = |frames: usize, mrays: f64, gpu: Option<f64>, times: &[f64]| {
            let r = Record {
                frames,
                mrays_per_s: mrays,
                gpu_trace_ms: gpu,
                gpu_submit_ms: gpu.map(|g| g * 10.0),
                pose_ms: gpu.map(|g| g + 0.5),
                name: "crowd".into(),
                ..Record::default()
            };
            (r, times.to_vec())
        };
        let pooled = pool_rounds(vec![
            round(3, 10.0, Some(2.0), &[1.0, 1.1, 1.2]),
            round(1, 30.0, Some(4.0), &[9.0]),
            round(3, 10.0, Some(3.0), &[5.0, 5.1, 5.2]),
        ])
        .expect("rounds");
        // The rounds' medians are 1.1, 9 and 5.1 (their median 5.1); all seven frames' is 5.
        assert_eq!((pooled.median_ms, pooled.min_ms, pooled.p95_ms), (5.0, 1.0, 9.0));
        assert_eq!(pooled.frames, 7);
        assert!((pooled.mrays_per_s - 90.0 / 7.0).abs() < 1e-12);
        assert_eq!(pooled.gpu_trace_ms, Some(3.0));
        assert_eq!((pooled.gpu_submit_ms, pooled.pose_ms), (Some(30.0), Some(3.5)));
        assert_eq!(pooled.name, "crowd");
        assert!(pool_rounds(Vec::new()).is_none());
    }

    /// Every timed frame of a clip moves from the frame before it: with the hit buffer on,
    /// a frame that replayed the warm-up's pose reused every pixel (the first of each
    /// instance-sweep round did). And the picture is of the clip's time 0 whatever the
    /// warm-up: the same image with three warm-up frames, one, or none.
    #[test]
    fn timed_frames_move_and_the_picture_is_time_zero() {
        use crate::backend::Backend;
        let mesh = crate::model::car::mesh();
        let parts = crate::pipeline::build_parts(&mesh, crate::voxelize::Resolution::Depth(5)).expect("parts");
        let mut st = crate::scene::stage_cars(&parts, 1, true, false).expect("a car");
        let (lo, hi) = st.cars_bounds();
        let camera = Camera::framing(lo.as_vec3(), hi.as_vec3(), 48, 32);
        let lights = Lights::default();
        let mut session = Session::new(Backend::Cpu(Box::default()), "CPU".into());
        let mut run = |warmup: usize, frames: usize| {
            let clip = Clip {
                scene: &mut st.scene,
                cars: &st.cars,
                animated: None,
                renderer: crate::render::Renderer::Trace,
                splat_draw: crate::render::SplatDraw::Compute,
                camera: &camera,
                lights: &lights,
                features: Features { shadows: false, ..Features::default() },
                lod: u32::MAX,
                warmup,
                frames,
                fps: 30.0,
                pose_on_gpu: false,
            };
            run_clip(&mut session, "CPU", clip).expect("the clip renders")
        };
        let (record, picture) = run(3, 1);
        assert!(record.reused_fraction < 0.99, "the timed frame reused {} of the pixels", record.reused_fraction);
        // The image and the hits (the counters say how it was rendered: reused or traced).
        let seen = |f: &Frame| (f.radiance.clone(), f.t.clone(), f.instance.clone());
        assert!(picture.instance.iter().any(|&i| i >= 0), "the car is in the picture");
        for warmup in [1, 0] {
            assert!(seen(&run(warmup, 2).1) == seen(&picture), "the picture after {warmup} warm-up frames differs");
        }
    }

    #[test]
    fn percentiles() {
        let (m, p95, min) = super::summarize(&[5.0, 1.0, 3.0, 2.0, 4.0]);
        assert_eq!((m, p95, min), (3.0, 5.0, 1.0));
    }
}
