//! The interactive window (`voxray demo`): the animated scene rendered every frame by the CPU
//! or GPU renderer and drawn to a wgpu surface, with an egui panel for the animation, every
//! technique switch, the renderer (GPU or CPU), the number of cars, the frame plan and live
//! statistics. Left-drag orbits (looks around in fly mode), right- or middle-drag pans, the
//! wheel zooms, W A S D (and Q E for down/up, Shift for faster) fly, F toggles fly mode,
//! Space pauses, R resets the view, P writes a screenshot, H hides the panel, Esc quits.
//! `frames` + `exit` and `screenshot` make scripted runs (tests, recordings).
//!
//! Without any GPU adapter (not even a software Vulkan driver) the window is drawn by
//! softbuffer instead of wgpu: the CPU renderer fills the whole window, the panel is off
//! (egui needs wgpu here), the keys and mouse still work and the title carries the stats.

use crate::backend::{Backend, BackendKind};
use crate::gpu::{GpuContext, GpuError};
use crate::render::{output, Features, Frame, FramePlan, RenderOptions};
use crate::scene::car::{pose_all, Car};
use crate::scene::{stage_cars, Camera, Lights, Scene, Staged};
use crate::session::Session;
use crate::svo::Svo;
use glam::{DQuat, DVec3};
use std::collections::{HashSet, VecDeque};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;
use winit::application::ApplicationHandler;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop};
use winit::keyboard::{Key, KeyCode, NamedKey, PhysicalKey};
use winit::window::{Window, WindowId};

/// What the demo shows and how it runs.
pub struct DemoOptions {
    /// Initial window width.
    pub width: u32,
    /// Initial window height.
    pub height: u32,
    /// Stop after this many frames (with `exit`).
    pub frames: Option<u64>,
    /// Quit after `frames`.
    pub exit: bool,
    /// Write the last frame (or each P press) here as PNG.
    pub screenshot: Option<PathBuf>,
    /// Renderer choice.
    pub backend: BackendKind,
    /// Technique switches.
    pub features: Features,
    /// The car's parts, so the car count can change while running (None: a fixed scene).
    pub car_parts: Option<CarParts>,
    /// Start with voxel-transformation GI on (it can be switched in the panel).
    pub gi: bool,
    /// Start with GPU frames read back for the statistics (switchable in the panel; off,
    /// GPU frames stay on the GPU).
    pub gpu_read_back: bool,
}

/// What the demo needs to re-stage the cars when their number changes.
pub struct CarParts {
    /// The eight parts of the car.
    pub parts: Vec<Arc<Svo>>,
    /// Whether there is a ground under the cars.
    pub ground: bool,
}

/// What a finished run did.
#[derive(Clone, Debug, Default)]
pub struct DemoReport {
    /// Frames drawn.
    pub frames: u64,
    /// Backend used.
    pub backend: String,
    /// Median frame time (ms).
    pub median_ms: f64,
    /// Screenshots written.
    pub screenshots: Vec<PathBuf>,
    /// With the GPU renderer: per frame after the first few, leaving out frames that wrote a
    /// screenshot, the buffers it created and the bytes it read back.
    pub gpu_traffic: Vec<(u64, u64)>,
}

/// Frames at the start of a run that set up buffers and are left out of
/// [`DemoReport::gpu_traffic`].
pub const TRAFFIC_WARMUP: u64 = 3;

impl DemoReport {
    /// `gpu steady state: read back B B/frame, created N buffers/frame` (averages over
    /// [`DemoReport::gpu_traffic`]), or None without GPU frames.
    pub fn gpu_steady_state(&self) -> Option<String> {
        let n = self.gpu_traffic.len() as f64;
        (n > 0.0).then(|| {
            let created = self.gpu_traffic.iter().map(|t| t.0).sum::<u64>() as f64 / n;
            let read = self.gpu_traffic.iter().map(|t| t.1).sum::<u64>() as f64 / n;
            format!("gpu steady state: read back {read:.0} B/frame, created {created:.2} buffers/frame")
        })
    }
}

/// Why the demo could not run.
#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    /// No display to open a window on.
    #[error("cannot open a window ({0}); without a display use `voxray render` (e.g. `voxray render --frames 60 --out car.gif`)")]
    NoDisplay(String),
    /// GPU setup for the window failed.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// Other failure while running.
    #[error("{0}")]
    Other(String),
}

struct Gfx {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    ctx: Arc<GpuContext>,
    config: wgpu::SurfaceConfiguration,
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    sampler: wgpu::Sampler,
    tex_format: wgpu::TextureFormat,
    texture: Option<(wgpu::Texture, wgpu::BindGroup, u32, u32)>,
    /// Draws a GPU frame from the renderer's radiance buffer (`fs_radiance`).
    radiance_pipeline: wgpu::RenderPipeline,
    radiance_layout: wgpu::BindGroupLayout,
    /// The [`PresentInfo`] uniform of `fs_radiance`.
    present_info: wgpu::Buffer,
    /// The bind group of the radiance buffer it was made for (rebuilt when the renderer
    /// replaces the buffer).
    radiance_bind: Option<(wgpu::Buffer, wgpu::BindGroup)>,
    egui: egui::Context,
    egui_state: egui_winit::State,
    egui_renderer: egui_wgpu::Renderer,
}

/// `PresentInfo` of `wgsl/blit.wgsl`: where a GPU frame's radiance lies in the window.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct PresentInfo {
    origin: [u32; 2],
    size: [u32; 2],
    encode: u32,
    pad: [u32; 3],
}

/// Most cars the panel offers (80 000 instances).
const MAX_CARS: usize = 10_000;

/// The window drawn in software (no GPU adapter at all).
struct Soft {
    window: Arc<Window>,
    surface: softbuffer::Surface<Arc<Window>, Arc<Window>>,
}

/// Width of the panel in logical pixels (fixed, so the image can be rendered beside it).
const PANEL_WIDTH: f32 = 280.0;

/// What the panel shows and changes.
struct Ui {
    show: bool,
    fly: bool,
    cars: usize,
    cars_wanted: usize,
    cars_dragging: bool,
    backend: BackendKind,
    backend_wanted: BackendKind,
    note: String,
    speed: f64,
    travel: bool,
    lod: u32,
    frame_ms: VecDeque<f32>,
    plan: Option<FramePlan>,
    reused: f64,
    mrays: f64,
    per_ray: (f64, f64),
    gi_on: bool,
    gi: crate::gi::GiSettings,
    gi_ms: Option<f64>,
    // GI ran in the backend (the GPU passes), not on the CPU after it.
    gi_on_gpu: bool,
    /// Why GI was switched off (knobs this device cannot run), shown in the panel.
    gi_error: Option<String>,
    // Most rays hit at t = 0 last frame.
    eye_inside: bool,
    gpu_ms: Option<(f64, f64)>,
    /// Read GPU frames back for the statistics and pass times (off: frames stay on the GPU
    /// and are presented from its radiance buffer).
    gpu_stats: bool,
    /// The last frame stayed on the GPU: no per-pixel statistics.
    on_device: bool,
    reset: bool,
}

/// egui output of one frame, ready to paint.
struct UiPaint {
    jobs: Vec<egui::ClippedPrimitive>,
    textures: egui::TexturesDelta,
    screen: egui_wgpu::ScreenDescriptor,
}

struct Orbit {
    target: DVec3,
    offset: DVec3,
    up: DVec3,
    vfov: f64,
}

struct App {
    opts: DemoOptions,
    scene: Scene,
    cars: Vec<Car>,
    lights: Lights,
    home: Orbit,
    orbit: Orbit,
    gfx: Option<Gfx>,
    soft: Option<Soft>,
    /// The renderer with its hit buffer, GI caches and last frame.
    session: Option<Session>,
    report: DemoReport,
    error: Option<ViewerError>,
    time: f64,
    playing: bool,
    last: Instant,
    drag: Option<(f64, f64)>,
    pan: Option<(f64, f64)>,
    keys: HashSet<KeyCode>,
    cursor: (f64, f64),
    times: Vec<f64>,
    want_screenshot: bool,
    ui: Ui,
}

impl App {
    fn camera(&self, w: u32, h: u32) -> Camera {
        Camera {
            eye: self.orbit.target + self.orbit.offset,
            target: self.orbit.target,
            up: self.orbit.up,
            vfov_deg: self.orbit.vfov,
            width: w.max(1),
            height: h.max(1),
        }
    }

    fn init(&mut self, event_loop: &ActiveEventLoop) -> Result<(), ViewerError> {
        let attrs = Window::default_attributes()
            .with_title("voxray")
            .with_inner_size(winit::dpi::PhysicalSize::new(self.opts.width, self.opts.height));
        let window = Arc::new(event_loop.create_window(attrs).map_err(|e| ViewerError::NoDisplay(e.to_string()))?);
        let mut desc =
            wgpu::InstanceDescriptor::new_with_display_handle_from_env(Box::new(event_loop.owned_display_handle()));
        GpuContext::restrict_backends(&mut desc);
        let instance = wgpu::Instance::new(desc);
        let surface = match instance.create_surface(window.clone()) {
            Ok(s) => s,
            Err(e) => return self.init_soft(window, format!("no wgpu surface: {e}")),
        };
        let (ctx, adapter) = match GpuContext::with_surface(&instance, Some(&surface)) {
            Ok(x) => x,
            Err(GpuError::NoAdapter(why)) => return self.init_soft(window, why),
            Err(e) => return Err(e.into()),
        };
        let size = window.inner_size();
        let mut config = surface
            .get_default_config(&adapter, size.width.max(1), size.height.max(1))
            .ok_or_else(|| ViewerError::Other("the adapter cannot present to this window".into()))?;
        // Screenshots read the window's own image back when the surface allows copying from it.
        if surface.get_capabilities(&adapter).usages.contains(wgpu::TextureUsages::COPY_SRC) {
            config.usage |= wgpu::TextureUsages::COPY_SRC;
        }
        surface.configure(&ctx.device, &config);
        // Frames arrive as sRGB bytes: an sRGB texture decodes them and an sRGB surface
        // re-encodes; a linear surface gets the bytes as they are.
        let tex_format =
            if config.format.is_srgb() { wgpu::TextureFormat::Rgba8UnormSrgb } else { wgpu::TextureFormat::Rgba8Unorm };
        let device = &ctx.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("blit.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("../wgsl/blit.wgsl").into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("blit"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let radiance_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("present radiance"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Storage { read_only: true },
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 3,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
            ],
        });
        let make_pipeline = |layout: &wgpu::BindGroupLayout, label: &str, fragment: &str| {
            let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(label),
                bind_group_layouts: &[Some(layout)],
                immediate_size: 0,
            });
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(label),
                layout: Some(&pl),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some("vs_main"),
                    compilation_options: Default::default(),
                    buffers: &[],
                },
                primitive: wgpu::PrimitiveState::default(),
                depth_stencil: None,
                multisample: wgpu::MultisampleState::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some(fragment),
                    compilation_options: Default::default(),
                    targets: &[Some(wgpu::ColorTargetState {
                        format: config.format,
                        blend: None,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let pipeline = make_pipeline(&layout, "blit", "fs_main");
        let radiance_pipeline = make_pipeline(&radiance_layout, "present radiance", "fs_radiance");
        let present_info = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("present info"),
            size: std::mem::size_of::<PresentInfo>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor { label: Some("blit"), ..Default::default() });
        let egui_ctx = egui::Context::default();
        let egui_state = egui_winit::State::new(
            egui_ctx.clone(),
            egui::ViewportId::ROOT,
            &window,
            Some(window.scale_factor() as f32),
            None,
            Some(ctx.limits.max_texture_dimension_2d as usize),
        );
        let egui_renderer = egui_wgpu::Renderer::new(device, config.format, egui_wgpu::RendererOptions::default());
        let ctx = Arc::new(ctx);
        let (backend, name) = Backend::on_device(self.opts.backend, ctx.clone());
        eprintln!("demo: window on {}; rendering on {name}", ctx.describe());
        let kind = if matches!(backend, Backend::Cpu(_)) { BackendKind::Cpu } else { BackendKind::Gpu };
        (self.ui.backend, self.ui.backend_wanted) = (kind, kind);
        if ctx.info.device_type == wgpu::DeviceType::Cpu {
            self.ui.note = format!(
                "No hardware GPU: {} (software Vulkan) presents the window. The CPU renderer is faster here; \
                 the GPU renderer runs on the software driver when chosen.",
                ctx.info.name
            );
        }
        self.report.backend = name.clone();
        self.session = Some(Session::new(backend, name));
        self.gfx = Some(Gfx {
            window,
            surface,
            ctx,
            config,
            pipeline,
            layout,
            sampler,
            tex_format,
            texture: None,
            radiance_pipeline,
            radiance_layout,
            present_info,
            radiance_bind: None,
            egui: egui_ctx,
            egui_state,
            egui_renderer,
        });
        self.last = Instant::now();
        Ok(())
    }

    /// No GPU adapter: the CPU renderer, drawn to the window through softbuffer.
    fn init_soft(&mut self, window: Arc<Window>, why: String) -> Result<(), ViewerError> {
        let soft_err = |e: softbuffer::SoftBufferError| ViewerError::Other(format!("software window: {e}"));
        let context = softbuffer::Context::new(window.clone()).map_err(soft_err)?;
        let surface = softbuffer::Surface::new(&context, window.clone()).map_err(soft_err)?;
        eprintln!(
            "demo: no GPU adapter ({why}); rendering on the CPU and drawing the window in software, without the \
             panel (install a Vulkan driver, e.g. Debian's mesa-vulkan-drivers, for the panel)"
        );
        self.report.backend = "CPU (no GPU adapter; software window, no panel)".into();
        self.session = Some(Session::new(Backend::Cpu(Box::default()), self.report.backend.clone()));
        (self.ui.backend, self.ui.backend_wanted) = (BackendKind::Cpu, BackendKind::Cpu);
        self.ui.show = false;
        self.soft = Some(Soft { window, surface });
        self.last = Instant::now();
        Ok(())
    }

    /// The window, however it is drawn.
    fn window(&self) -> Option<&Arc<Window>> {
        self.gfx.as_ref().map(|g| &g.window).or(self.soft.as_ref().map(|s| &s.window))
    }

    fn draw(&mut self, event_loop: &ActiveEventLoop) -> Result<(), ViewerError> {
        let now = Instant::now();
        let dt = (now - self.last).as_secs_f64();
        self.last = now;
        if self.playing {
            // Scripted runs advance by a fixed step so their frames do not depend on speed.
            self.time += self.ui.speed * if self.opts.frames.is_some() { 1.0 / 30.0 } else { dt.min(0.1) };
        }
        if self.ui.reset {
            self.ui.reset = false;
            self.orbit = self.home.clone();
        }
        self.apply_choices()?;
        self.fly(dt.min(0.1));
        for c in &mut self.cars {
            c.travel = self.ui.travel;
        }
        let other = |e: crate::scene::SceneError| ViewerError::Other(e.to_string());
        pose_all(&mut self.scene, &self.cars, self.time).map_err(other)?;
        self.scene.update().map_err(other)?;
        let (w, h, panel) = match (&self.gfx, &self.soft) {
            (Some(g), _) => (g.config.width, g.config.height, self.panel_pixels(g)),
            (None, Some(s)) => {
                let size = s.window.inner_size();
                (size.width.max(1), size.height.max(1), 0)
            }
            (None, None) => return Ok(()),
        };
        let camera = self.camera(w.saturating_sub(panel).max(1), h);
        let done = self.opts.exit && self.opts.frames.is_some_and(|n| self.report.frames + 1 >= n);
        let shoot = self.want_screenshot || (done && self.opts.screenshot.is_some());
        // A GPU frame is drawn from the renderer's radiance buffer and read back only when
        // asked: statistics on, or a screenshot the window cannot be copied for.
        let can_capture = self.gfx.as_ref().is_some_and(|g| g.config.usage.contains(wgpu::TextureUsages::COPY_SRC));
        let start = Instant::now();
        let session = self.session.as_mut().ok_or_else(|| ViewerError::Other("no renderer".into()))?;
        session.set_read_back(self.ui.gpu_stats || (shoot && !can_capture) || self.gfx.is_none());
        let other = |e: crate::Error| ViewerError::Other(e.to_string());
        // GI knobs this device cannot run (a volume past its binding limit, texture levels on a
        // sparse volume) switch GI off with the reason in the panel instead of ending the demo.
        if let Err(e) = session.set_gi(self.ui.gi_on.then_some(self.ui.gi)) {
            self.ui.gi_error = Some(e.to_string());
            self.ui.gi_on = false;
            session.set_gi(None).map_err(other)?;
        }
        let opts = RenderOptions { max_level: self.ui.lod };
        let features = self.opts.features;
        let report = match session.frame(&self.scene, &camera, &self.lights, &features, &opts, &|_, _| {}) {
            Ok(r) => r,
            Err(e) if session.gi().is_some() => {
                self.ui.gi_error = Some(e.to_string());
                self.ui.gi_on = false;
                session.set_gi(None).map_err(other)?;
                session.frame(&self.scene, &camera, &self.lights, &features, &opts, &|_, _| {}).map_err(other)?
            }
            Err(e) => return Err(other(e)),
        };
        if self.ui.gi_on {
            self.ui.gi_error = None;
        }
        let gi_in_backend = session.gi_in_backend();
        self.ui.gi_on_gpu = gi_in_backend && session.gi().is_some();
        self.ui.gi_ms = match &report.gi {
            Some(g) => Some(g.caches_ms + g.transform_ms + g.inject_ms + g.levels_ms + g.cones_ms),
            None => session.backend().gi_pass_ms(),
        };
        let gpu_ms = session.backend().pass_times();
        let gpu_traffic = session.backend().gpu_traffic();
        let plan = report.plan;
        // Out of the session while it is shown; handed back at the end for the next frame's
        // memory.
        let frame = session.take_frame().ok_or_else(|| ViewerError::Other("the renderer kept no frame".into()))?;
        self.ui.on_device = frame.on_device;
        self.ui.eye_inside = if frame.on_device {
            crate::render::instances::eye_inside(&self.scene, camera.eye)
        } else {
            frame.eye_inside_fraction() > 0.5
        };
        // The render call alone (a GPU frame that stays on the GPU returns once submitted).
        let secs = start.elapsed().as_secs_f64();
        // A frame's time is from one frame's start to the next (rendering, panel, present):
        // the rate the window shows, whichever backend.
        if self.report.frames > 0 {
            self.times.push(dt * 1e3);
            self.ui.frame_ms.push_back((dt * 1e3) as f32);
        }
        self.ui.gpu_ms = gpu_ms;
        if self.ui.frame_ms.len() > 180 {
            self.ui.frame_ms.pop_front();
        }
        let pixels = frame.primary_rays.max(1) as f64;
        self.ui.reused = frame.reused as f64 / pixels;
        let traced_rays = (frame.primary_rays - frame.reused).max(1) as f64;
        self.ui.per_ray = (frame.instances_traced as f64 / traced_rays, frame.spheres_culled as f64 / traced_rays);
        self.ui.mrays = (frame.primary_rays - frame.reused + frame.shadow_rays) as f64 / secs.max(1e-9) / 1e6;
        self.ui.plan = Some(plan);
        let ui_paint = self.build_ui();
        let captured = self.present(&frame, shoot, ui_paint)?;
        // Errors the window's device raised while presenting (outside the renderer's scopes).
        if let Some(g) = self.gfx.as_ref() {
            g.ctx.check().map_err(|e| ViewerError::Other(e.to_string()))?;
        }
        let captured_kind = captured.is_some();
        if let Some(t) = gpu_traffic.filter(|_| !shoot && self.report.frames >= TRAFFIC_WARMUP) {
            self.report.gpu_traffic.push(t);
        }
        self.report.frames += 1;
        if self.report.frames % 10 == 1 {
            if let Some(window) = self.window() {
                let ms = self.times.last().copied().unwrap_or(0.0);
                let reused = if frame.on_device {
                    "frame kept on the GPU".to_string()
                } else {
                    format!("{:.0}% reused", 100.0 * frame.reused as f64 / frame.primary_rays.max(1) as f64)
                };
                window.set_title(&format!(
                    "voxray — {:.1} ms/frame, {reused}, t = {:.1} s{} — {}",
                    ms,
                    self.time,
                    if self.playing { "" } else { " (paused)" },
                    self.report.backend
                ));
            }
        }
        if shoot {
            self.want_screenshot = false;
            let path = self
                .opts
                .screenshot
                .clone()
                .unwrap_or_else(|| PathBuf::from(format!("voxray-{:04}.png", self.report.frames)));
            match captured {
                // The window's own pixels.
                Some((w, h, rgb)) => image::RgbImage::from_raw(w, h, rgb)
                    .ok_or_else(|| ViewerError::Other("window capture size mismatch".into()))?
                    .save(&path)
                    .map_err(|e| ViewerError::Other(format!("{}: {e}", path.display())))?,
                // The surface cannot be read back: the frame that was drawn to it.
                None => output::write_image(&frame, &path).map_err(|e| ViewerError::Other(e.to_string()))?,
            }
            eprintln!(
                "demo: wrote {} ({})",
                path.display(),
                if captured_kind { "window capture" } else { "rendered frame" }
            );
            self.report.screenshots.push(path);
        }
        if let Some(s) = self.session.as_mut() {
            s.give_back(frame);
        }
        if done {
            event_loop.exit();
        }
        Ok(())
    }

    /// Draws the frame to the window; with `capture`, also returns the window's image as RGB
    /// bytes (width, height, data) when the surface can be copied from.
    fn present(
        &mut self,
        frame: &Frame,
        capture: bool,
        mut ui: Option<UiPaint>,
    ) -> Result<Option<(u32, u32, Vec<u8>)>, ViewerError> {
        if let Some(s) = self.soft.as_mut() {
            return present_soft(s, frame, capture);
        }
        // A frame kept on the GPU: the renderer's radiance buffer, on this device.
        let radiance = if frame.on_device {
            let gpu = self.session.as_ref().and_then(|s| s.backend().gpu());
            let found = gpu.and_then(|r| r.radiance()).map(|(b, w, h)| (b.clone(), w, h));
            Some(found.ok_or_else(|| ViewerError::Other("the GPU frame has no radiance buffer".into()))?)
        } else {
            None
        };
        let Some(g) = self.gfx.as_mut() else { return Ok(None) };
        let device = &g.ctx.device;
        match &radiance {
            Some((buf, w, h)) => {
                if g.radiance_bind.as_ref().is_none_or(|(b, _)| b != buf) {
                    let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
                        label: Some("present radiance"),
                        layout: &g.radiance_layout,
                        entries: &[
                            wgpu::BindGroupEntry { binding: 2, resource: buf.as_entire_binding() },
                            wgpu::BindGroupEntry { binding: 3, resource: g.present_info.as_entire_binding() },
                        ],
                    });
                    g.radiance_bind = Some((buf.clone(), bind));
                }
                let info = PresentInfo {
                    origin: [g.config.width.saturating_sub(*w), 0],
                    size: [*w, *h],
                    encode: (!g.config.format.is_srgb()) as u32,
                    pad: [0; 3],
                };
                g.ctx.queue.write_buffer(&g.present_info, 0, bytemuck::bytes_of(&info));
            }
            None => upload_frame(g, frame),
        }
        let device = &g.ctx.device;
        // egui's texture changes must be applied (or freed) every frame, even one that is not
        // presented: take them out now.
        let mut free_ids = Vec::new();
        if let Some(t) = ui.as_mut().map(|u| &mut u.textures) {
            for (id, deltas) in &t.set {
                for delta in deltas {
                    g.egui_renderer.update_texture(device, &g.ctx.queue, *id, delta);
                }
            }
            free_ids = t.free.drain().collect();
            // Applied: tell egui so (it checks that no delta is dropped unapplied).
            t.clear();
        }
        let free = |g: &mut Gfx| {
            for id in &free_ids {
                g.egui_renderer.free_texture(id);
            }
        };
        let target = match g.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t) | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                g.surface.configure(&g.ctx.device, &g.config);
                free(g);
                return Ok(None);
            }
            _ => {
                free(g); // timeout or occluded: skip this frame
                return Ok(None);
            }
        };
        let view = target.texture.create_view(&Default::default());
        let (w, h) = (target.texture.width(), target.texture.height());
        let mut enc = device.create_command_encoder(&Default::default());
        if let Some(ui) = &ui {
            let extra = g.egui_renderer.update_buffers(device, &g.ctx.queue, &mut enc, &ui.jobs, &ui.screen);
            g.ctx.queue.submit(extra);
        }
        {
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("blit"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            match (&radiance, &g.radiance_bind, &g.texture) {
                (Some(_), Some((_, bind)), _) => {
                    pass.set_pipeline(&g.radiance_pipeline);
                    pass.set_bind_group(0, bind, &[]);
                }
                (None, _, Some((_, bind, _, _))) => {
                    pass.set_pipeline(&g.pipeline);
                    pass.set_bind_group(0, bind, &[]);
                }
                _ => return Err(ViewerError::Other("nothing to draw the frame from".into())),
            }
            // The frame fills the window right of the panel (it was rendered that size).
            let x0 = w.saturating_sub(frame.width) as f32;
            pass.set_viewport(x0, 0.0, frame.width.min(w) as f32, frame.height.min(h) as f32, 0.0, 1.0);
            pass.draw(0..3, 0..1);
            pass.set_viewport(0.0, 0.0, w as f32, h as f32, 0.0, 1.0);
            if let Some(ui) = &ui {
                let mut pass = pass.forget_lifetime();
                g.egui_renderer.render(&mut pass, &ui.jobs, &ui.screen);
            }
        }
        let row = (4 * w).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let readback = (capture && g.config.usage.contains(wgpu::TextureUsages::COPY_SRC)).then(|| {
            let buf = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("window capture"),
                size: (row * h) as u64,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            enc.copy_texture_to_buffer(
                target.texture.as_image_copy(),
                wgpu::TexelCopyBufferInfo {
                    buffer: &buf,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(row),
                        rows_per_image: Some(h),
                    },
                },
                wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
            );
            buf
        });
        g.ctx.queue.submit([enc.finish()]);
        let captured = match readback {
            Some(buf) => {
                let bytes: Vec<u8> = crate::gpu::renderer::read(&g.ctx, &buf).map_err(ViewerError::Gpu)?;
                let bgra =
                    matches!(g.config.format, wgpu::TextureFormat::Bgra8Unorm | wgpu::TextureFormat::Bgra8UnormSrgb);
                let mut rgb = Vec::with_capacity((3 * w * h) as usize);
                for y in 0..h as usize {
                    for px in bytes[y * row as usize..][..4 * w as usize].chunks_exact(4) {
                        rgb.extend_from_slice(&if bgra { [px[2], px[1], px[0]] } else { [px[0], px[1], px[2]] });
                    }
                }
                Some((w, h, rgb))
            }
            None => None,
        };
        g.ctx.queue.present(target);
        free(g);
        Ok(captured)
    }

    /// Applies the renderer and car-count choices made in the panel.
    fn apply_choices(&mut self) -> Result<(), ViewerError> {
        if self.ui.backend_wanted != self.ui.backend {
            if let Some(g) = &self.gfx {
                let (backend, name) = Backend::on_device(self.ui.backend_wanted, g.ctx.clone());
                eprintln!("demo: now rendering on {name}");
                // A new session: no previous frame to reuse, GI state of its own.
                self.session = Some(Session::new(backend, name.clone()));
                self.report.backend = name;
                self.ui.backend = self.ui.backend_wanted;
            }
        }
        let n = self.ui.cars_wanted.max(1);
        if n != self.ui.cars && !self.ui.cars_dragging {
            if let Some(cp) = &self.opts.car_parts {
                let st: Staged =
                    stage_cars(&cp.parts, n, true, cp.ground).map_err(|e| ViewerError::Other(e.to_string()))?;
                let (lo, hi) = if self.ui.travel { st.bounds } else { st.cars_bounds() };
                let (w, h) = self.gfx.as_ref().map_or((self.opts.width, self.opts.height), |g| {
                    (g.config.width.saturating_sub(self.panel_pixels(g)).max(1), g.config.height)
                });
                self.home = Orbit::of(&Camera::framing(lo.as_vec3(), hi.as_vec3(), w, h));
                self.orbit = self.home.clone();
                self.scene = st.scene;
                self.cars = st.cars;
                // Other instances: nothing to reuse (the old parts' GI caches go when the next
                // new cache is built, as their parts are gone).
                if let Some(s) = self.session.as_mut() {
                    s.restart();
                }
                eprintln!("demo: {n} cars, {} instances", self.scene.instances().len());
            }
            self.ui.cars = n;
            self.ui.cars_wanted = n;
        }
        Ok(())
    }

    /// Moves the camera by the held W A S D / Q E keys (Shift: four times faster).
    fn fly(&mut self, dt: f64) {
        let held = |k| self.keys.contains(&k) as i32 as f64;
        let forward = held(KeyCode::KeyW) - held(KeyCode::KeyS);
        let side = held(KeyCode::KeyD) - held(KeyCode::KeyA);
        let lift = held(KeyCode::KeyE) - held(KeyCode::KeyQ);
        if forward == 0.0 && side == 0.0 && lift == 0.0 {
            return;
        }
        let fast =
            if self.keys.contains(&KeyCode::ShiftLeft) || self.keys.contains(&KeyCode::ShiftRight) { 4.0 } else { 1.0 };
        // Half the home view distance per second: the same feel for one car or a city of them.
        let speed = 0.5 * self.home.offset.length() * fast;
        let ahead = -self.orbit.offset.normalize_or_zero();
        let right = ahead.cross(self.orbit.up).normalize_or_zero();
        self.orbit.target += (ahead * forward + right * side + self.orbit.up * lift) * speed * dt;
    }

    /// Physical width the panel takes (0 when hidden or the window is too small for it).
    fn panel_pixels(&self, g: &Gfx) -> u32 {
        if self.ui.show && g.config.width >= 480 {
            (PANEL_WIDTH * g.window.scale_factor() as f32).ceil() as u32
        } else {
            0
        }
    }

    /// Runs the panel for this frame; None when it is hidden (or the window too small for it).
    fn build_ui(&mut self) -> Option<UiPaint> {
        let g = self.gfx.as_ref()?;
        if self.panel_pixels(g) == 0 {
            return None;
        }
        let g = self.gfx.as_mut()?;
        let raw = g.egui_state.take_egui_input(&g.window);
        let ui = &mut self.ui;
        let (playing, time, shot) = (&mut self.playing, &mut self.time, &mut self.want_screenshot);
        let backend = self.report.backend.clone();
        let instances = self.scene.instances().len();
        let can_restage = self.opts.car_parts.is_some();
        let (w, h) = (g.config.width, g.config.height);
        let render_w = w.saturating_sub((PANEL_WIDTH * g.window.scale_factor() as f32).ceil() as u32);
        let output = g.egui.run_ui(raw, |root| {
            egui::Panel::left("controls").exact_size(PANEL_WIDTH).resizable(false).show(root, |ui_| {
                egui::ScrollArea::vertical().show(ui_, |ui_| {
                    ui_.heading("voxray");
                    ui_.label(backend.as_str());
                    ui_.horizontal(|row| {
                        row.label("renderer:");
                        row.radio_value(&mut ui.backend_wanted, BackendKind::Gpu, "GPU");
                        row.radio_value(&mut ui.backend_wanted, BackendKind::Cpu, "CPU");
                    });
                    if !ui.note.is_empty() {
                        ui_.small(ui.note.as_str());
                    }
                    ui_.separator();
                    ui_.strong("Scene");
                    if can_restage {
                        let r = ui_
                            .add(egui::Slider::new(&mut ui.cars_wanted, 1..=MAX_CARS).logarithmic(true).text("cars"));
                        // Re-stage when the slider is let go, not on every step of a drag.
                        ui.cars_dragging = r.dragged() && !r.drag_stopped();
                    }
                    ui_.label(format!("{instances} instances"));
                    ui_.separator();
                    ui_.strong("Camera");
                    ui_.checkbox(&mut ui.fly, "fly mode (F): drag looks around");
                    ui_.small("W A S D move, Q E down/up, Shift faster; right-drag pans");
                    ui_.separator();
                    ui_.strong("Animation");
                    ui_.checkbox(playing, "play (Space)");
                    ui_.add(egui::Slider::new(time, 0.0..=120.0).text("time (s)"));
                    ui_.add(egui::Slider::new(&mut ui.speed, 0.0..=4.0).text("speed"));
                    ui_.checkbox(&mut ui.travel, "drive along the figure-eight");
                    ui_.separator();
                    ui_.strong("Techniques");
                    let f = &mut self.opts.features;
                    ui_.checkbox(&mut f.cull, "bounding-sphere culling");
                    ui_.checkbox(&mut f.sort, "depth-sorted early-out");
                    ui_.checkbox(&mut f.bvh, "instance BVH");
                    ui_.checkbox(&mut f.hit_buffer, "hit buffer");
                    ui_.checkbox(&mut f.shadows, "shadows");
                    ui_.checkbox(&mut ui.gi_on, "global illumination");
                    if ui.gi_on {
                        // Steps of 8: every value suits both volume layouts.
                        ui_.add(egui::Slider::new(&mut ui.gi.res, 16..=512).step_by(8.0).text("GI volume cells"));
                        ui_.add(egui::Slider::new(&mut ui.gi.cones.diffuse_cones, 1..=16).text("GI cones"));
                        ui_.add(
                            egui::Slider::new(&mut ui.gi.bounces, 1..=crate::gi::shade::MAX_BOUNCES).text("GI bounces"),
                        );
                        ui_.horizontal(|row| {
                            row.label("GI filter:");
                            row.radio_value(&mut ui.gi.filter, crate::gi::Filter::Split, "split");
                            row.radio_value(&mut ui.gi.filter, crate::gi::Filter::Nearest, "nearest");
                        });
                        ui_.horizontal(|row| {
                            use crate::gi::shade::VolumeChoice;
                            row.label("GI volume:");
                            row.radio_value(&mut ui.gi.volume, VolumeChoice::Auto, "auto");
                            row.radio_value(&mut ui.gi.volume, VolumeChoice::Dense, "dense");
                            row.radio_value(&mut ui.gi.volume, VolumeChoice::Sparse, "sparse");
                        });
                        ui_.horizontal(|row| {
                            use crate::gi::shade::LevelStore;
                            row.label("GI levels (GPU):");
                            row.radio_value(&mut ui.gi.levels, LevelStore::Buffer, "buffer");
                            row.radio_value(&mut ui.gi.levels, LevelStore::Texture, "texture");
                        });
                    }
                    if let Some(e) = &ui.gi_error {
                        ui_.colored_label(egui::Color32::from_rgb(230, 110, 90), format!("GI off: {e}"));
                    }
                    let mut full = ui.lod == u32::MAX;
                    ui_.checkbox(&mut full, "full detail");
                    if full {
                        ui.lod = u32::MAX;
                    } else {
                        if ui.lod == u32::MAX {
                            ui.lod = 6;
                        }
                        ui_.add(egui::Slider::new(&mut ui.lod, 1..=12).text("LOD level"));
                    }
                    ui_.separator();
                    ui_.strong("Frame plan");
                    if let Some(p) = &ui.plan {
                        for r in &p.reasons {
                            ui_.small(r);
                        }
                    }
                    ui_.separator();
                    ui_.strong("Statistics");
                    let last = ui.frame_ms.back().copied().unwrap_or(0.0);
                    ui_.label(format!("frame {last:.1} ms, {render_w}×{h}, {instances} instances"));
                    if ui.eye_inside {
                        ui_.colored_label(
                            egui::Color32::from_rgb(230, 160, 60),
                            "the eye is inside a voxel: move the camera out of the geometry",
                        );
                    }
                    if let Some(ms) = ui.gi_ms {
                        if ui.gi_on_gpu {
                            ui_.label(format!("GI passes on the GPU: {ms:.2} ms (cones in shade)"));
                        } else {
                            ui_.label(format!("GI (CPU): {ms:.0} ms of the frame"));
                        }
                    }
                    if ui.backend == BackendKind::Gpu {
                        ui_.checkbox(&mut ui.gpu_stats, "read GPU frames back (statistics, pass times)");
                    }
                    if ui.on_device {
                        ui_.small("frames stay on the GPU and are drawn from its radiance buffer");
                    } else {
                        if let Some((tr, sh)) = ui.gpu_ms {
                            ui_.label(format!("GPU passes: trace {tr:.2} ms, shade {sh:.2} ms"));
                        }
                        ui_.label(format!("{:.2} Mrays/s traced, {:.1}% pixels reused", ui.mrays, 100.0 * ui.reused));
                        ui_.label(format!(
                            "per traced ray: {:.2} instances traversed, {:.2} spheres culled",
                            ui.per_ray.0, ui.per_ray.1
                        ));
                    }
                    // Frame-time graph, last 180 frames, scaled to the slowest.
                    let (rect, _) =
                        ui_.allocate_exact_size(egui::vec2(ui_.available_width(), 60.0), egui::Sense::hover());
                    let max = ui.frame_ms.iter().copied().fold(1.0f32, f32::max);
                    let n = ui.frame_ms.len().max(2) as f32;
                    let pts: Vec<egui::Pos2> = ui
                        .frame_ms
                        .iter()
                        .enumerate()
                        .map(|(i, v)| {
                            egui::pos2(
                                rect.left() + rect.width() * i as f32 / (n - 1.0),
                                rect.bottom() - rect.height() * v / max,
                            )
                        })
                        .collect();
                    ui_.painter().rect_stroke(
                        rect,
                        0.0,
                        egui::Stroke::new(1.0, egui::Color32::GRAY),
                        egui::StrokeKind::Inside,
                    );
                    ui_.painter().add(egui::Shape::line(pts, egui::Stroke::new(1.5, egui::Color32::LIGHT_GREEN)));
                    ui_.small(format!("frame time, max {max:.0} ms"));
                    ui_.separator();
                    ui_.horizontal(|row| {
                        if row.button("reset view (R)").clicked() {
                            ui.reset = true;
                        }
                        if row.button("screenshot (P)").clicked() {
                            *shot = true;
                        }
                    });
                    ui_.small("drag: orbit · wheel: zoom · H: hide panel · Esc: quit");
                });
            });
        });
        g.egui_state.handle_platform_output(&g.window, output.platform_output);
        let jobs = g.egui.tessellate(output.shapes, output.pixels_per_point);
        Some(UiPaint {
            jobs,
            textures: output.textures_delta,
            screen: egui_wgpu::ScreenDescriptor { size_in_pixels: [w, h], pixels_per_point: output.pixels_per_point },
        })
    }

    fn key(&mut self, event_loop: &ActiveEventLoop, key: Key) {
        match key {
            Key::Named(NamedKey::Escape) => event_loop.exit(),
            Key::Named(NamedKey::Space) => self.playing = !self.playing,
            Key::Character(c) if c.eq_ignore_ascii_case("r") => self.orbit = self.home.clone(),
            Key::Character(c) if c.eq_ignore_ascii_case("p") => self.want_screenshot = true,
            Key::Character(c) if c.eq_ignore_ascii_case("h") => self.ui.show = !self.ui.show,
            Key::Character(c) if c.eq_ignore_ascii_case("f") => self.ui.fly = !self.ui.fly,
            _ => {}
        }
    }

    fn fail(&mut self, event_loop: &ActiveEventLoop, e: ViewerError) {
        self.error = Some(e);
        event_loop.exit();
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.gfx.is_none() && self.soft.is_none() {
            if let Err(e) = self.init(event_loop) {
                self.fail(event_loop, e);
            }
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        // The panel sees every event first; input it uses does not reach the camera.
        if let Some(g) = self.gfx.as_mut() {
            let consumed = g.egui_state.on_window_event(&g.window, &event).consumed;
            let input = matches!(
                event,
                WindowEvent::MouseInput { .. }
                    | WindowEvent::CursorMoved { .. }
                    | WindowEvent::MouseWheel { .. }
                    | WindowEvent::KeyboardInput { .. }
            );
            if consumed && input && self.ui.show {
                return;
            }
        }
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(size) => {
                if let Some(g) = self.gfx.as_mut() {
                    g.config.width = size.width.max(1);
                    g.config.height = size.height.max(1);
                    g.surface.configure(&g.ctx.device, &g.config);
                }
            }
            WindowEvent::MouseInput { state, button: MouseButton::Left, .. } => {
                self.drag = (state == ElementState::Pressed).then_some(self.cursor);
            }
            WindowEvent::MouseInput { state, button: MouseButton::Right | MouseButton::Middle, .. } => {
                self.pan = (state == ElementState::Pressed).then_some(self.cursor);
            }
            WindowEvent::Focused(false) => self.keys.clear(),
            WindowEvent::CursorMoved { position, .. } => {
                self.cursor = (position.x, position.y);
                if let Some((x0, y0)) = self.drag {
                    let (dx, dy) = (position.x - x0, position.y - y0);
                    self.drag = Some(self.cursor);
                    // Orbit: the camera circles the target. Fly: it turns in place (the
                    // rotation runs the other way so the view follows the mouse).
                    let k = if self.ui.fly { 0.003 } else { -0.005 };
                    let yaw = DQuat::from_axis_angle(self.orbit.up, k * dx);
                    let right = self.orbit.offset.cross(self.orbit.up).normalize_or_zero();
                    let pitch = DQuat::from_axis_angle(right, k * dy);
                    let eye = self.orbit.target + self.orbit.offset;
                    let mut next = pitch * (yaw * self.orbit.offset);
                    // Stay off the poles, where the up vector would become parallel to the view.
                    if next.normalize().dot(self.orbit.up).abs() >= 0.98 {
                        next = yaw * self.orbit.offset;
                    }
                    self.orbit.offset = next;
                    if self.ui.fly {
                        self.orbit.target = eye - next;
                    }
                }
                if let Some((x0, y0)) = self.pan {
                    let (dx, dy) = (position.x - x0, position.y - y0);
                    self.pan = Some(self.cursor);
                    let ahead = -self.orbit.offset.normalize_or_zero();
                    let right = ahead.cross(self.orbit.up).normalize_or_zero();
                    let up = right.cross(ahead);
                    // Scaled by the view distance so the scene follows the mouse at any zoom.
                    let k = self.orbit.offset.length() * 0.0015;
                    self.orbit.target += (-right * dx + up * dy) * k;
                }
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let lines = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y as f64,
                    MouseScrollDelta::PixelDelta(p) => p.y / 40.0,
                };
                self.orbit.offset *= 0.9f64.powf(lines);
            }
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Released => {
                if let PhysicalKey::Code(code) = event.physical_key {
                    self.keys.remove(&code);
                }
            }
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Pressed => {
                if let PhysicalKey::Code(code) = event.physical_key {
                    self.keys.insert(code);
                }
                self.key(event_loop, event.logical_key)
            }
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.draw(event_loop) {
                    self.fail(event_loop, e);
                }
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, _event_loop: &ActiveEventLoop) {
        if let Some(window) = self.window() {
            window.request_redraw();
        }
    }
}

/// Copies the frame (rendered at the window's size) into the software window; with
/// `capture`, also returns those pixels, which are exactly what the window shows.
/// Uploads a CPU frame (sRGB bytes) into the texture `fs_main` samples, made anew only when
/// the frame's size changes.
fn upload_frame(g: &mut Gfx, frame: &Frame) {
    let device = &g.ctx.device;
    if !g.texture.as_ref().is_some_and(|t| t.2 == frame.width && t.3 == frame.height) {
        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("frame"),
            size: wgpu::Extent3d { width: frame.width, height: frame.height, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: g.tex_format,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        let view = texture.create_view(&Default::default());
        let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("blit"),
            layout: &g.layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: wgpu::BindingResource::TextureView(&view) },
                wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::Sampler(&g.sampler) },
            ],
        });
        g.texture = Some((texture, bind, frame.width, frame.height));
    }
    let Some((texture, _, _, _)) = g.texture.as_ref() else { return };
    let rgba: Vec<u8> = output::srgb8(frame).chunks_exact(3).flat_map(|c| [c[0], c[1], c[2], 255]).collect();
    g.ctx.queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: 0,
            origin: wgpu::Origin3d::ZERO,
            aspect: wgpu::TextureAspect::All,
        },
        &rgba,
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(4 * frame.width),
            rows_per_image: Some(frame.height),
        },
        wgpu::Extent3d { width: frame.width, height: frame.height, depth_or_array_layers: 1 },
    );
}

fn present_soft(s: &mut Soft, frame: &Frame, capture: bool) -> Result<Option<(u32, u32, Vec<u8>)>, ViewerError> {
    let soft_err = |e: softbuffer::SoftBufferError| ViewerError::Other(format!("software window: {e}"));
    let (Some(w), Some(h)) = (std::num::NonZeroU32::new(frame.width), std::num::NonZeroU32::new(frame.height)) else {
        return Ok(None);
    };
    s.surface.resize(w, h).map_err(soft_err)?;
    let rgb = output::srgb8(frame);
    let mut buffer = s.surface.buffer_mut().map_err(soft_err)?;
    for (px, c) in buffer.iter_mut().zip(rgb.chunks_exact(3)) {
        *px = (c[0] as u32) << 16 | (c[1] as u32) << 8 | c[2] as u32;
    }
    buffer.present().map_err(soft_err)?;
    Ok(capture.then_some((frame.width, frame.height, rgb)))
}

impl Orbit {
    fn of(camera: &Camera) -> Orbit {
        Orbit { target: camera.target, offset: camera.eye - camera.target, up: camera.up, vfov: camera.vfov_deg }
    }
}

impl Clone for Orbit {
    fn clone(&self) -> Self {
        Orbit { target: self.target, offset: self.offset, up: self.up, vfov: self.vfov }
    }
}

/// Fails fast, before any scene is built, when there is plainly no display to open a window
/// on (Linux/BSD with neither `DISPLAY` nor `WAYLAND_DISPLAY` set).
pub fn check_display() -> Result<(), ViewerError> {
    let unix_desktop = cfg!(all(unix, not(target_os = "macos"), not(target_os = "android"), not(target_os = "ios")));
    let set = |v: &str| std::env::var_os(v).is_some_and(|x| !x.is_empty());
    if unix_desktop && !set("DISPLAY") && !set("WAYLAND_DISPLAY") {
        return Err(ViewerError::NoDisplay("neither DISPLAY nor WAYLAND_DISPLAY is set".into()));
    }
    Ok(())
}

/// Opens the window and runs until it is closed (or `frames` are drawn with `exit`).
pub fn run(
    opts: DemoOptions,
    scene: Scene,
    cars: Vec<Car>,
    lights: Lights,
    camera: Camera,
) -> Result<DemoReport, ViewerError> {
    let event_loop = EventLoop::new().map_err(|e| ViewerError::NoDisplay(e.to_string()))?;
    let home = Orbit::of(&camera);
    let cars_n = cars.len().max(1);
    let mut app = App {
        opts,
        scene,
        cars,
        lights,
        orbit: home.clone(),
        home,
        gfx: None,
        soft: None,
        session: None,
        report: DemoReport::default(),
        error: None,
        time: 0.0,
        playing: true,
        last: Instant::now(),
        drag: None,
        pan: None,
        keys: HashSet::new(),
        cursor: (0.0, 0.0),
        times: Vec::new(),
        want_screenshot: false,
        ui: Ui {
            show: true,
            fly: false,
            cars: cars_n,
            cars_wanted: cars_n,
            cars_dragging: false,
            backend: BackendKind::Auto,
            backend_wanted: BackendKind::Auto,
            note: String::new(),
            speed: 1.0,
            travel: false,
            lod: u32::MAX,
            frame_ms: VecDeque::new(),
            plan: None,
            reused: 0.0,
            mrays: 0.0,
            per_ray: (0.0, 0.0),
            gi_on: false,
            gi: crate::gi::GiSettings { res: 64, ..Default::default() },
            gi_ms: None,
            gi_on_gpu: false,
            gi_error: None,
            eye_inside: false,
            gpu_ms: None,
            gpu_stats: false,
            on_device: false,
            reset: false,
        },
    };
    app.ui.travel = app.cars.first().is_some_and(|c| c.travel);
    app.ui.gi_on = app.opts.gi;
    app.ui.gpu_stats = app.opts.gpu_read_back;
    event_loop.run_app(&mut app).map_err(|e| ViewerError::Other(e.to_string()))?;
    if let Some(e) = app.error {
        return Err(e);
    }
    app.report.median_ms = crate::bench::summarize(&app.times).0;
    Ok(app.report)
}
