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
use crate::scene::car::{Car, SeenCars};
use crate::scene::{stage_cars, Camera, FrameRays, Lights, Scene, Sight, Staged};
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

mod app;
mod input;
mod present;
mod ui;

use present::{Gfx, Soft};
use ui::{Ui, UiPaint};

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
    /// Where GI's diffuse light is gathered at start (switchable in the panel).
    pub gi_gather: crate::render::Gather,
    /// Read every GPU frame back whole and present it through the host, as before frames
    /// stayed on the GPU (for comparisons; off, the window draws the GPU's radiance buffer).
    pub gpu_read_back: bool,
    /// Start with the GPU counting each frame's statistics (switchable in the panel).
    pub gpu_stats: bool,
    /// A scene file's hierarchy and clip, posed at the demo's time every frame (its
    /// timeline: play, scrub, speed).
    pub animated: Option<crate::scene::Animated>,
    /// Start with square splats for primary visibility (switchable in the panel).
    pub splat: bool,
    /// How the GPU draws the splats (switchable in the panel).
    pub splat_draw: crate::render::SplatDraw,
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

/// Most cars the panel offers (80 000 instances).
const MAX_CARS: usize = 10_000;

/// Width of the panel in logical pixels (fixed, so the image can be rendered beside it).
const PANEL_WIDTH: f32 = 280.0;

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
    /// What posing only the cars a frame can see keeps between frames.
    seen: SeenCars,
    /// The box of visible surfaces, with what it was computed for.
    surfaces: Option<(SurfacesKey, (DVec3, DVec3))>,
}

/// What the box of visible surfaces depends on: part edits, level of detail, travel, cars.
type SurfacesKey = (u64, u32, bool, usize);

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

    /// The window, however it is drawn.
    fn window(&self) -> Option<&Arc<Window>> {
        self.gfx.as_ref().map(|g| &g.window).or(self.soft.as_ref().map(|s| &s.window))
    }

    fn fail(&mut self, event_loop: &ActiveEventLoop, e: ViewerError) {
        self.error = Some(e);
        event_loop.exit();
    }
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
    let splat = opts.splat;
    let splat_draw = opts.splat_draw;
    let gi_gather = opts.gi_gather;
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
            splat,
            splat_draw,
            frame_ms: VecDeque::new(),
            plan: None,
            reused: 0.0,
            mrays: 0.0,
            per_ray: (0.0, 0.0),
            posed: (0, 0),
            gi_on: false,
            // Interactive: by default the half-resolution gather (the same error, a quarter of
            // the cones; docs/accuracy.md), switchable in the panel.
            gi: crate::gi::GiSettings { res: 64, gather: gi_gather, ..Default::default() },
            gi_ms: None,
            gi_on_gpu: false,
            gi_error: None,
            eye_inside: false,
            gpu_ms: None,
            gpu_stats: false,
            read_all: false,
            on_device: false,
            reset: false,
        },
        seen: SeenCars::default(),
        surfaces: None,
    };
    app.ui.travel = app.cars.first().is_some_and(|c| c.travel);
    app.ui.gi_on = app.opts.gi;
    app.ui.read_all = app.opts.gpu_read_back;
    app.ui.gpu_stats = app.opts.gpu_stats;
    event_loop.run_app(&mut app).map_err(|e| ViewerError::Other(e.to_string()))?;
    if let Some(e) = app.error {
        return Err(e);
    }
    app.report.median_ms = crate::bench::summarize(&app.times).0;
    Ok(app.report)
}
