//! The frame-time benchmark harness (CPU): animation clips rendered with a static camera,
//! per-frame wall times summarized as median / p95 / min, with the frame plan in every record.

use crate::backend::Backend;
use crate::render::{Features, FramePlan, RenderOptions};
use crate::scene::car::{pose, Car};
use crate::scene::{Camera, Lights, Scene, SceneError};
use std::time::Instant;

/// Summary of one scenario.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "json", derive(serde::Serialize))]
pub struct Record {
    /// Scenario name.
    pub name: String,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Frames timed (after one warm-up frame).
    pub frames: usize,
    /// Instances in the scene.
    pub instances: usize,
    /// Median frame time (ms): animate, update transforms, plan, render.
    pub median_ms: f64,
    /// 95th-percentile frame time (ms).
    pub p95_ms: f64,
    /// Fastest frame (ms).
    pub min_ms: f64,
    /// Primary and shadow rays actually traced per second (reused pixels not counted), in millions.
    pub mrays_per_s: f64,
    /// Fraction of pixels reused from the hit buffer.
    pub reused_fraction: f64,
    /// The plan of the last frame.
    pub plan: FramePlan,
    /// Backend (CPU, or the GPU adapter).
    pub backend: String,
    /// Median GPU time of the trace pass (ms), from timestamp queries.
    pub gpu_trace_ms: Option<f64>,
    /// Median GPU time of the shade pass (ms).
    pub gpu_shade_ms: Option<f64>,
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

/// Renders `frames` frames (plus one untimed warm-up) of a clip at `fps`, posing `cars` each
/// frame, and times each whole frame.
#[allow(clippy::too_many_arguments)]
pub fn run_clip(
    name: &str,
    backend: &mut Backend,
    backend_name: &str,
    scene: &mut Scene,
    cars: &[Car],
    camera: &Camera,
    lights: &Lights,
    features: &Features,
    frames: usize,
    fps: f64,
    progress: &dyn Fn(usize),
) -> Result<Record, crate::Error> {
    let scene_err =
        |e: SceneError| crate::Error::Io { path: "scene".into(), source: std::io::Error::other(e.to_string()) };
    let (mut times, mut rays, mut reused, mut busy) = (Vec::new(), 0u64, 0u64, 0.0f64);
    let (mut trace_ms, mut shade_ms) = (Vec::new(), Vec::new());
    let mut plan = None;
    for f in 0..=frames {
        let start = Instant::now();
        let t = f as f64 / fps;
        for car in cars {
            pose(scene, car, t).map_err(scene_err)?;
        }
        scene.update().map_err(scene_err)?;
        let p = backend.plan(scene, camera, lights, features, f == 0);
        let frame = backend.render(scene, camera, lights, &p, &RenderOptions::default(), &|_, _| {})?;
        let secs = start.elapsed().as_secs_f64();
        if f > 0 {
            if let Some((tr, sh)) = backend.pass_times() {
                trace_ms.push(tr);
                shade_ms.push(sh);
            }
            times.push(secs * 1e3);
            rays += frame.primary_rays - frame.reused + frame.shadow_rays;
            reused += frame.reused;
            busy += secs;
        }
        plan = Some(p);
        progress(f);
    }
    let (median_ms, p95_ms, min_ms) = summarize(&times);
    let pixels = (camera.width * camera.height) as f64 * frames as f64;
    Ok(Record {
        name: name.into(),
        width: camera.width,
        height: camera.height,
        frames,
        instances: scene.instances().len(),
        median_ms,
        p95_ms,
        min_ms,
        mrays_per_s: rays as f64 / busy.max(1e-9) / 1e6,
        reused_fraction: reused as f64 / pixels.max(1.0),
        plan: plan.unwrap_or_else(|| FramePlan::new(scene, camera, lights, features, None)),
        backend: backend_name.to_string(),
        gpu_trace_ms: (!trace_ms.is_empty()).then(|| summarize(&trace_ms).0),
        gpu_shade_ms: (!shade_ms.is_empty()).then(|| summarize(&shade_ms).0),
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
    #[test]
    fn percentiles() {
        let (m, p95, min) = super::summarize(&[5.0, 1.0, 3.0, 2.0, 4.0]);
        assert_eq!((m, p95, min), (3.0, 5.0, 1.0));
    }
}
