//! Where frames are rendered: the CPU renderer or the GPU renderer, behind one call with the
//! same contract (plan from the previous frame, hit buffer kept between frames).

use crate::render::{render, Features, Frame, FramePlan, HitBuffer, RenderOptions};
use crate::scene::{Camera, Lights, Scene};

/// Which backend to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BackendKind {
    /// The CPU renderer.
    Cpu,
    /// The GPU renderer (an error if there is no adapter).
    Gpu,
    /// The GPU renderer on a hardware adapter; otherwise the CPU renderer (a software
    /// Vulkan driver such as lavapipe runs the GPU path 5–20× slower than the CPU renderer).
    Auto,
}

impl std::str::FromStr for BackendKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "cpu" => Ok(BackendKind::Cpu),
            "gpu" => Ok(BackendKind::Gpu),
            "auto" => Ok(BackendKind::Auto),
            other => Err(format!("unknown backend '{other}' (use cpu, gpu or auto)")),
        }
    }
}

/// A renderer with its state between frames.
pub enum Backend {
    /// CPU, with its hit buffer.
    Cpu(Box<HitBuffer>),
    /// GPU.
    #[cfg(feature = "gpu")]
    Gpu(Box<crate::gpu::GpuRenderer>),
}

impl Backend {
    /// Opens a backend; returns it and a line describing it (or why the GPU was not used).
    pub fn open(kind: BackendKind) -> Result<(Backend, String), crate::Error> {
        match kind {
            BackendKind::Cpu => Ok((Backend::Cpu(Box::default()), "CPU".into())),
            #[cfg(feature = "gpu")]
            BackendKind::Gpu | BackendKind::Auto => match crate::gpu::GpuContext::headless() {
                Ok(ctx) if kind == BackendKind::Auto && ctx.info.device_type == wgpu::DeviceType::Cpu => Ok((
                    Backend::Cpu(Box::default()),
                    format!(
                        "CPU (the only GPU adapter is the software {}; use --backend gpu to run the GPU path on it)",
                        ctx.info.name
                    ),
                )),
                Ok(ctx) => {
                    let d = format!("GPU: {}", ctx.describe());
                    Ok((Backend::Gpu(Box::new(crate::gpu::GpuRenderer::new(std::sync::Arc::new(ctx)))), d))
                }
                Err(e) if kind == BackendKind::Auto => Ok((Backend::Cpu(Box::default()), format!("CPU ({e})"))),
                Err(e) => Err(e.into()),
            },
            #[cfg(not(feature = "gpu"))]
            BackendKind::Gpu => Err(crate::Error::NoGpuSupport),
            #[cfg(not(feature = "gpu"))]
            BackendKind::Auto => Ok((Backend::Cpu(Box::default()), "CPU (built without the `gpu` feature)".into())),
        }
    }

    /// A backend on an existing device (the viewer shares its window's device): the GPU
    /// renderer for `Gpu`, and for `Auto` on a hardware adapter; the CPU renderer otherwise.
    #[cfg(feature = "gpu")]
    pub fn on_device(kind: BackendKind, ctx: std::sync::Arc<crate::gpu::GpuContext>) -> (Backend, String) {
        let software = ctx.info.device_type == wgpu::DeviceType::Cpu;
        match kind {
            BackendKind::Gpu => {
                (Backend::Gpu(Box::new(crate::gpu::GpuRenderer::new(ctx.clone()))), format!("GPU: {}", ctx.describe()))
            }
            BackendKind::Auto if !software => {
                (Backend::Gpu(Box::new(crate::gpu::GpuRenderer::new(ctx.clone()))), format!("GPU: {}", ctx.describe()))
            }
            BackendKind::Auto => (Backend::Cpu(Box::default()), format!("CPU (software adapter {})", ctx.info.name)),
            BackendKind::Cpu => (Backend::Cpu(Box::default()), "CPU".into()),
        }
    }

    /// The frame plan for the next frame (`first`: no previous frame to reuse).
    pub fn plan(&self, scene: &Scene, camera: &Camera, lights: &Lights, features: &Features, first: bool) -> FramePlan {
        // Without the `gpu` feature the match has one arm.
        #[cfg_attr(not(feature = "gpu"), allow(clippy::infallible_destructuring_match))]
        let prev = match self {
            Backend::Cpu(h) => h,
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => &g.state,
        };
        #[cfg_attr(not(feature = "gpu"), allow(unused_mut))]
        let mut plan = FramePlan::new(scene, camera, lights, features, (!first).then_some(prev));
        #[cfg(feature = "gpu")]
        if matches!(self, Backend::Gpu(_)) && (plan.beams || plan.bvh_beams) {
            plan.without_beams("the GPU backend traces every primary ray from the eye");
        }
        plan
    }

    /// Renders a frame.
    pub fn render(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        lights: &Lights,
        plan: &FramePlan,
        opts: &RenderOptions,
        progress: &(dyn Fn(u32, u32) + Sync),
    ) -> Result<Frame, crate::Error> {
        match self {
            Backend::Cpu(h) => Ok(render(scene, camera, lights, plan, opts, Some(h), progress)?),
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => Ok(g.render(scene, camera, lights, plan, opts)?),
        }
    }

    /// Hands back a frame the caller is done with, so that the next one reuses its memory
    /// (the CPU renderer; the GPU renderer's frames are read back into their own buffers).
    pub fn recycle(&mut self, frame: Frame) {
        match self {
            Backend::Cpu(h) => h.recycle(frame),
            #[cfg(feature = "gpu")]
            Backend::Gpu(_) => drop(frame),
        }
    }

    /// [`Backend::recycle`] for a frame exactly as this backend rendered it: the CPU's next
    /// frame then writes only the pixels that changed into it.
    pub(crate) fn recycle_as_rendered(&mut self, frame: Frame) {
        match self {
            Backend::Cpu(h) => h.recycle_as_rendered(frame),
            #[cfg(feature = "gpu")]
            Backend::Gpu(_) => drop(frame),
        }
    }

    /// Sets the GI knobs for the following frames (None: GI off). Returns true when the
    /// backend runs GI itself (the GPU: transform, injection, levels and cones in WGSL, dense
    /// or sparse volume); false when the caller adds it to each frame with `gi::apply` (the CPU).
    pub fn set_gi(&mut self, gi: Option<crate::gi::GiSettings>) -> Result<bool, crate::Error> {
        match self {
            Backend::Cpu(_) => {
                // The session adds GI on the CPU; nothing to keep here.
                let _ = gi;
                Ok(false)
            }
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => {
                g.set_gi(gi)?;
                Ok(gi.is_some())
            }
        }
    }

    /// GPU time of the last frame's GI passes (transform, injection, levels), when measured.
    pub fn gi_pass_ms(&self) -> Option<f64> {
        match self {
            Backend::Cpu(_) => None,
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => g.gi_stats.and(g.times.map(|t| t.gi_ms)),
        }
    }

    /// GPU time of the last frame's crowd passes (posing the cars, refitting their tree), when
    /// the GPU posed a crowd and measured it.
    pub fn crowd_pass_ms(&self) -> Option<f64> {
        match self {
            Backend::Cpu(_) => None,
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => g.times.and_then(|t| t.crowd_ms),
        }
    }

    /// The layout, brick pool (sparse; 0 dense) and bytes of the backend's own GI volume in
    /// the last frame (None on the CPU or without GI).
    pub fn gi_volume(&self) -> Option<(crate::gi::Layout, u32, u64)> {
        match self {
            Backend::Cpu(_) => None,
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => g.gi_stats.map(|s| (s.layout, s.brick_capacity, s.bytes)),
        }
    }

    /// Bricks the backend's own sparse GI volume allocated in the last frame, read back on
    /// request (None on the CPU, without GI or for a dense volume).
    pub fn gi_bricks(&mut self) -> Result<Option<u32>, crate::Error> {
        match self {
            Backend::Cpu(_) => Ok(None),
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => Ok(g.gi_bricks()?),
        }
    }

    /// What the backend's own GI kept from the frame before (None on the CPU or without GI).
    pub fn gi_reuse(&self) -> Option<crate::gi::GiReuse> {
        match self {
            Backend::Cpu(_) => None,
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => g.gi_stats.map(|s| s.reuse),
        }
    }

    /// `cpu` or `gpu`.
    pub fn kind_name(&self) -> &'static str {
        match self {
            Backend::Cpu(_) => "cpu",
            #[cfg(feature = "gpu")]
            Backend::Gpu(_) => "gpu",
        }
    }

    /// Bytes of GPU buffers the last frame used (None on the CPU).
    pub fn gpu_bytes(&self) -> Option<u64> {
        match self {
            Backend::Cpu(_) => None,
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => Some(g.buffer_bytes),
        }
    }

    /// The host's time on the last frame up to its submit, in milliseconds (None on the CPU;
    /// see `gpu::GpuRenderer::submit_host_ms`).
    pub fn submit_host_ms(&self) -> Option<f64> {
        match self {
            Backend::Cpu(_) => None,
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => Some(g.submit_host_ms),
        }
    }

    /// Buffers created and bytes read back by the last frame (None on the CPU).
    pub fn gpu_traffic(&self) -> Option<(u64, u64)> {
        match self {
            Backend::Cpu(_) => None,
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => Some(g.frame_traffic),
        }
    }

    /// Whether the GPU reads each frame back to the host (the default; see
    /// `gpu::GpuRenderer::set_read_back`). The CPU's frames are always on the host.
    #[cfg_attr(not(feature = "gpu"), allow(unused_variables))]
    pub fn set_read_back(&mut self, on: bool) {
        match self {
            Backend::Cpu(_) => {}
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => g.set_read_back(on),
        }
    }

    /// Whether the GPU adds up each frame's statistics itself, so that frames kept on the
    /// GPU still come with their counters (`gpu::GpuRenderer::set_counting`).
    #[cfg_attr(not(feature = "gpu"), allow(unused_variables))]
    pub fn set_counting(&mut self, on: bool) {
        match self {
            Backend::Cpu(_) => {}
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => g.set_counting(on),
        }
    }

    /// The GPU renderer, for callers that draw its frames on its device.
    #[cfg(feature = "gpu")]
    pub fn gpu(&self) -> Option<&crate::gpu::GpuRenderer> {
        match self {
            Backend::Cpu(_) => None,
            Backend::Gpu(g) => Some(g),
        }
    }

    /// The GPU renderer, to change (None on the CPU).
    #[cfg(feature = "gpu")]
    pub fn gpu_mut(&mut self) -> Option<&mut crate::gpu::GpuRenderer> {
        match self {
            Backend::Cpu(_) => None,
            Backend::Gpu(g) => Some(g),
        }
    }

    /// The radiance caches' GPU pass times of the last frame (placement, tracing, convolution)
    /// in milliseconds, when measured.
    pub fn cache_pass_times(&self) -> Option<[f64; 3]> {
        match self {
            Backend::Cpu(_) => None,
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => g.times.and_then(|t| t.cache_ms),
        }
    }

    /// GPU pass times of the last frame (trace, shade) in milliseconds, when measured.
    pub fn pass_times(&self) -> Option<(f64, f64)> {
        match self {
            Backend::Cpu(_) => None,
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => g.times.map(|t| (t.trace_ms, t.shade_ms)),
        }
    }
}
