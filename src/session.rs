//! One renderer session per caller: the backend (CPU or GPU) with its hit buffer, the GI
//! settings and caches, and the last frame. The CLI's render loop, the demo and the harness
//! drive their frames through [`Session::frame`], so the plan, the render and GI run in one
//! place and in one order for all of them.

use crate::backend::{Backend, BackendKind};
use crate::gi::{GiCaches, GiReuse, GiSettings, GiStats};
use crate::render::plan::GiPlan;
use crate::render::{Features, Frame, FramePlan, RenderOptions};
use crate::scene::{Camera, Lights, Scene};

/// What one frame did.
#[derive(Clone, Debug)]
pub struct FrameReport {
    /// What ran, and why.
    pub plan: FramePlan,
    /// The CPU GI pass's timings and volume (None without GI, or when the backend ran GI).
    pub gi: Option<GiStats>,
    /// What GI kept from the frame before, on either backend (None without GI).
    pub gi_reuse: Option<GiReuse>,
    /// GPU: buffers created and bytes read back by this frame (None on the CPU).
    pub gpu_traffic: Option<(u64, u64)>,
    /// GPU: the trace and shade passes' milliseconds, when timestamps were read back.
    pub gpu_pass_ms: Option<(f64, f64)>,
}

/// A backend and everything kept between its frames.
pub struct Session {
    backend: Backend,
    description: String,
    gi: Option<GiSettings>,
    /// The backend runs GI itself (the GPU); otherwise the CPU frame is rendered with
    /// [`crate::gi::render_with_gi`].
    gi_in_backend: bool,
    gi_caches: GiCaches,
    /// The next frame has no previous one to reuse.
    first: bool,
    frame: Option<Frame>,
    /// `frame` is as the backend rendered it (the caller only ever saw it borrowed), so the
    /// next frame may leave its unchanged pixels as they are.
    frame_as_rendered: bool,
}

impl Session {
    /// A session on `backend`, described by `description` (a line for the user).
    pub fn new(backend: Backend, description: String) -> Session {
        Session {
            backend,
            description,
            gi: None,
            gi_in_backend: false,
            gi_caches: GiCaches::new(),
            first: true,
            frame: None,
            frame_as_rendered: false,
        }
    }

    /// A session on the backend `kind` asks for ([`Backend::open`]).
    pub fn open(kind: BackendKind) -> Result<Session, crate::Error> {
        let (backend, description) = Backend::open(kind)?;
        Ok(Session::new(backend, description))
    }

    /// What the backend is (the adapter, or why the CPU was chosen).
    pub fn description(&self) -> &str {
        &self.description
    }

    /// The backend, for what it measured (GPU pass times, buffer bytes, GI volume).
    pub fn backend(&self) -> &Backend {
        &self.backend
    }

    /// The backend, to change (a GPU renderer's crowd posed on the GPU, say).
    pub fn backend_mut(&mut self) -> &mut Backend {
        &mut self.backend
    }

    /// Bricks the last frame's sparse GPU GI volume allocated, read back on request (None on
    /// the CPU, without GI or for a dense volume).
    pub fn gi_bricks(&mut self) -> Result<Option<u32>, crate::Error> {
        self.backend.gi_bricks()
    }

    /// Sets the GI knobs for the following frames (None: GI off). Checked here; on an error
    /// GI is off.
    pub fn set_gi(&mut self, gi: Option<GiSettings>) -> Result<(), crate::Error> {
        self.gi = None;
        self.gi_in_backend = false;
        if let Some(g) = &gi {
            g.validated()?;
        }
        self.gi_in_backend = self.backend.set_gi(gi)?;
        self.gi = gi;
        Ok(())
    }

    /// Has `hook` told what the CPU's GI passes are doing before a frame's pixels
    /// ([`crate::gi::GiCaches::on_stage`]).
    pub fn on_gi_stage(&mut self, hook: impl Fn(&str) + Send + Sync + 'static) {
        self.gi_caches.on_stage(hook);
    }

    /// The GI knobs in use (None: GI off).
    pub fn gi(&self) -> Option<&GiSettings> {
        self.gi.as_ref()
    }

    /// Whether the backend runs GI itself (the GPU) rather than the session on the CPU.
    pub fn gi_in_backend(&self) -> bool {
        self.gi_in_backend
    }

    /// Whether the following frames are read back to the host (on by default). Off, a GPU
    /// frame stays on the GPU: [`Session::last_frame`] has no pixels ([`Frame::on_device`])
    /// and the image is the GPU renderer's radiance buffer. CPU frames are always on the host.
    pub fn set_read_back(&mut self, on: bool) {
        self.backend.set_read_back(on);
    }

    /// Whether the GPU adds up each frame's statistics itself (off by default): frames kept on
    /// the GPU then come with their counters for 32 bytes (and the pass times) read back.
    pub fn set_counting(&mut self, on: bool) {
        self.backend.set_counting(on);
    }

    /// Lets the next frame reuse nothing from the frames before (a new clip).
    pub fn restart(&mut self) {
        self.first = true;
    }

    /// Renders one frame: plans it from the previous one, renders it on the backend, and adds
    /// GI when the backend does not run it. The image and surface AOVs are then
    /// [`Session::last_frame`]'s. `progress(done, of)` hears of rows as they finish.
    pub fn frame(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        lights: &Lights,
        features: &Features,
        opts: &RenderOptions,
        progress: &(dyn Fn(u32, u32) + Sync),
    ) -> Result<FrameReport, crate::Error> {
        let mut plan = self.backend.plan(scene, camera, lights, features, self.first);
        // The last frame's memory is refilled instead of fresh pages faulted in.
        if let Some(old) = self.frame.take() {
            if self.frame_as_rendered {
                self.backend.recycle_as_rendered(old);
            } else {
                self.backend.recycle(old);
            }
        }
        let (mut gi, mut gi_reuse) = (None, None);
        let frame = match (&self.gi, self.gi_in_backend, &mut self.backend) {
            // The CPU lights the frame with the cones itself (the same steps as the GPU's).
            (Some(g), false, Backend::Cpu(hits)) => {
                let (frame, stats) = crate::gi::render_with_gi(
                    scene,
                    camera,
                    lights,
                    &plan,
                    opts,
                    Some(hits),
                    g,
                    &mut self.gi_caches,
                    progress,
                )?;
                gi = Some(stats);
                frame
            }
            _ => self.backend.render(scene, camera, lights, &plan, opts, progress)?,
        };
        self.first = false;
        if self.gi.is_some() {
            let layout = match &gi {
                Some(stats) => {
                    gi_reuse = Some(stats.reuse);
                    stats.layout
                }
                None => {
                    gi_reuse = self.backend.gi_reuse();
                    self.backend.gi_volume().map(|v| v.0)
                }
            };
            if let Some(reuse) = gi_reuse {
                plan.with_gi(GiPlan { reuse, layout: layout.unwrap_or_default() });
            }
        }
        self.frame = Some(frame);
        self.frame_as_rendered = true;
        let (gpu_traffic, gpu_pass_ms) = (self.backend.gpu_traffic(), self.backend.pass_times());
        Ok(FrameReport { plan, gi, gi_reuse, gpu_traffic, gpu_pass_ms })
    }

    /// The last frame rendered: its image and surface AOVs.
    pub fn last_frame(&self) -> Option<&Frame> {
        self.frame.as_ref()
    }

    /// The last frame's image (linear radiance, row by row from the top), read from the GPU
    /// when the frame stayed there ([`Session::set_read_back`]); None before any frame.
    pub fn image(&mut self) -> Result<Option<Vec<glam::Vec3>>, crate::Error> {
        let Some(frame) = self.frame.as_ref() else { return Ok(None) };
        if !frame.on_device {
            return Ok(Some(frame.radiance.clone()));
        }
        match &mut self.backend {
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => Ok(Some(g.read_image()?)),
            _ => Ok(None),
        }
    }

    /// Takes the last frame out of the session (it is then not recycled).
    pub fn take_frame(&mut self) -> Option<Frame> {
        self.frame.take()
    }

    /// Hands back a frame taken with [`Session::take_frame`]: it is the last frame again, and
    /// the next frame reuses its memory.
    pub fn give_back(&mut self, frame: Frame) {
        self.frame = Some(frame);
        // The caller may have changed it: its memory is reused, its pixels are not.
        self.frame_as_rendered = false;
    }
}
