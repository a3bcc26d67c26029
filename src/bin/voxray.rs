//! `voxray`: render, voxelize, inspect and test sparse voxel octrees from the command line.
//! With no subcommand it opens the demo window (without a display: renders `voxray.png`).

use clap::{Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Instant;
use voxray::backend::Backend;
use voxray::cache::SvoCache;
use voxray::mesh::Mesh;
use voxray::mesh::Part;
use voxray::pipeline::{build_part, shared_resolution};
use voxray::render::{output, Features, Frame, FramePlan, RenderOptions};
use voxray::scene::car::pose_all;
use voxray::scene::{add_ground, stage_cars, Camera, Instance, Lights, Scene, Staged, Transform};
use voxray::svo::Svo;
use voxray::voxelize::{Resolution, VoxelizeOptions};
use voxray::Error;

#[derive(Parser)]
#[command(
    name = "voxray",
    version,
    about = "Ray tracing of sparse voxel octrees (Laine–Karras SVOs, Revelles traversal)."
)]
#[command(long_about = "Ray tracing of sparse voxel octrees. With no subcommand, opens the demo window on the \
embedded animated car (`voxray demo`); without a display, renders it to voxray.png (`voxray render`).")]
struct Cli {
    #[command(subcommand)]
    cmd: Option<Cmd>,
    /// Worker threads (default: one per core).
    #[arg(long, global = true)]
    threads: Option<usize>,
}

#[derive(Subcommand)]
enum Cmd {
    /// Render OBJ parts (default: the embedded car) to PNG/EXR, with optional AOVs.
    Render(RenderArgs),
    /// Voxelize OBJ parts and write one .svo file per part, with size statistics.
    Voxelize(VoxelizeArgs),
    /// Validate an .svo file and print its statistics.
    Info {
        /// The .svo file.
        file: PathBuf,
    },
    /// Run the numerical stability suite against the brute-force DDA oracle.
    Stability {
        /// Rays in the random families (the adversarial families have fixed sizes).
        #[arg(long, default_value_t = 1_000_000)]
        rays: usize,
        /// Also write the table, with the command that produced it, to this Markdown file.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Time the animated car: static vs animated vs animated+optimized, and instance counts.
    Bench(BenchArgs),
    /// Open a window with the animated car (what `voxray` with no subcommand does): left-drag
    /// orbits, right-drag pans, wheel zooms, F toggles fly mode (W A S D, Q E, Shift), Space
    /// pauses, R resets the view, P writes a screenshot, H hides the panel, Esc quits.
    Demo(DemoArgs),
    /// Regenerate a built-in model's files.
    Model {
        /// Which model: `car` (the default car) or `box` (the coloured-wall box of the GI tests).
        #[arg(value_parser = ["car", "box"])]
        name: String,
        /// Output folder (default: models/NAME).
        #[arg(long)]
        out_dir: Option<PathBuf>,
    },
}

#[derive(Args, Clone)]
struct SourceArgs {
    /// OBJ files; each object/group (or file) is a part. Default: the embedded car.
    #[arg(long, num_args = 1..)]
    obj: Vec<PathBuf>,
    /// Voxels along the largest part's longest side, as 2^DEPTH; all parts share that voxel size.
    #[arg(long, default_value_t = 9, conflicts_with = "voxel_size", value_parser = clap::value_parser!(u32).range(1..=20))]
    depth: u32,
    /// Voxel edge length in OBJ units (instead of --depth).
    #[arg(long)]
    voxel_size: Option<f32>,
    /// Fill closed surfaces (depth ≤ 9).
    #[arg(long)]
    solid: bool,
    /// Folder of the SVO cache (default: $VOXRAY_CACHE_DIR, $XDG_CACHE_HOME/voxray or ~/.cache/voxray).
    #[arg(long)]
    cache_dir: Option<PathBuf>,
    /// Always voxelize; neither read nor write the cache.
    #[arg(long)]
    no_cache: bool,
    /// Ignore MTL Ks/Ns: every material purely Lambertian (the shared convention of
    /// DESIGN.md, for comparing images with other renderers).
    #[arg(long)]
    lambertian: bool,
}

#[derive(Args, Clone)]
struct RenderArgs {
    #[command(flatten)]
    source: SourceArgs,
    /// Camera JSON (eye, target, up, vfov_deg, width, height). Default: a three-quarter view framing the scene.
    #[arg(long)]
    camera_json: Option<PathBuf>,
    /// Lights JSON (sun, ambient, use_mtl_emitters). Default: afternoon sun and a pale sky.
    #[arg(long)]
    lights_json: Option<PathBuf>,
    /// Image width (overrides the camera JSON).
    #[arg(long)]
    width: Option<u32>,
    /// Image height (overrides the camera JSON).
    #[arg(long)]
    height: Option<u32>,
    /// Output: .png (sRGB 8-bit) or .exr (linear float radiance); with --frames, name_0000.png … or one animated .gif.
    #[arg(long, default_value = "voxray.png")]
    out: PathBuf,
    /// Write t.npy, instance.npy and normal.npy into this folder (with --frames: DIR/frame_0000/ …).
    #[arg(long)]
    aov_dir: Option<PathBuf>,
    /// Level-of-detail: stop this many levels below the root.
    #[arg(long)]
    lod: Option<u32>,
    /// Frames to render (the car animates; other scenes stay still).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    frames: u32,
    /// Frames per second of the clip.
    #[arg(long, default_value_t = 30.0)]
    fps: f64,
    /// Clip time of the first frame, in seconds.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    time: f64,
    /// Cars (default car only): each a figure-eight of its own, with its own time offset.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    cars: u32,
    /// Keep the car(s) in place (wheels, steering and doors still move).
    #[arg(long)]
    in_place: bool,
    /// The whole car merged into one static SVO (the static baseline; no animation).
    #[arg(long)]
    static_car: bool,
    /// No ground under the default car.
    #[arg(long)]
    no_ground: bool,
    /// Orbit the camera about its target at this many degrees per second (a moving camera).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    orbit: f64,
    #[command(flatten)]
    switches: Switches,
    /// Print the frame plan (first frame, and whenever it changes).
    #[arg(long)]
    explain: bool,
    /// Voxel-transformation global illumination, on the backend that renders: colour bleeding
    /// and ambient occlusion in place of the flat sky term, and glossy reflections (one
    /// specular cone) on materials with MTL Ks and Ns.
    #[arg(long)]
    gi: bool,
    /// GI world volume cells per side.
    #[arg(long, default_value_t = 128, requires = "gi")]
    gi_res: u32,
    /// GI filtering of moved voxels: nearest or split (8-neighbour).
    #[arg(long, default_value = "split", requires = "gi")]
    gi_filter: voxray::gi::Filter,
    /// GI diffuse cones per pixel (1–64).
    #[arg(long, default_value_t = 6, requires = "gi")]
    gi_cones: u32,
    /// GI world volume edge in scene units (default: 3× the camera's distance to its target).
    #[arg(long, requires = "gi")]
    gi_extent: Option<f64>,
    /// GI bounces (1…8): each bounce past the first cone-traces every occupied cell's incoming light.
    #[arg(long, default_value_t = 1, requires = "gi")]
    gi_bounces: u32,
    /// GI world volume: dense (every cell, up to 512³), sparse (8³ bricks where voxels land,
    /// multiples of 8 up to 1024³) or auto (CPU: sparse above 128³; GPU: sparse above 512³).
    #[arg(long, default_value = "auto", requires = "gi")]
    gi_volume: voxray::gi::shade::VolumeChoice,
    /// Where the GPU's cones read the GI level chain: buffer (filtered in f32 in the shader,
    /// equal to the CPU) or texture (a 3D texture with mips, hardware filtering; dense volume).
    #[arg(long, default_value = "buffer", requires = "gi")]
    gi_levels: voxray::gi::shade::LevelStore,
    /// Path-trace the reference image instead (CPU, progressive; write .exr for linear radiance):
    /// the same voxels, materials and lights, sun + sky + emitters, all bounces unless --bounces.
    #[arg(long, conflicts_with = "gi")]
    reference: bool,
    /// Reference samples per pixel.
    #[arg(long, default_value_t = 256, requires = "reference")]
    spp: u32,
    /// Reference indirect bounces (1: the one-bounce image a single GI bounce approximates); default unlimited.
    #[arg(long, requires = "reference")]
    bounces: Option<u32>,
    /// Where to render: cpu, gpu (an error without an adapter) or auto (the GPU on a hardware adapter, else the CPU).
    #[arg(long, env = "VOXRAY_BACKEND", default_value = "auto")]
    backend: voxray::backend::BackendKind,
}

/// The technique switches (`FramePlan` features), shared by `render` and `demo`.
#[derive(Args, Clone)]
struct Switches {
    /// No bounding-sphere culling.
    #[arg(long)]
    no_cull: bool,
    /// No depth-sorted early-out.
    #[arg(long)]
    no_sort: bool,
    /// No instance BVH.
    #[arg(long)]
    no_bvh: bool,
    /// No per-pixel hit buffer.
    #[arg(long)]
    no_hit_buffer: bool,
    /// No shadow rays.
    #[arg(long)]
    no_shadows: bool,
    /// No beams (primary rays start at the eye instead of where their tile's cone first
    /// meets each instance; the image is the same).
    #[arg(long)]
    no_beams: bool,
}

impl Switches {
    fn features(&self) -> Features {
        Features {
            cull: !self.no_cull,
            sort: !self.no_sort,
            bvh: !self.no_bvh,
            hit_buffer: !self.no_hit_buffer,
            shadows: !self.no_shadows,
            beams: !self.no_beams,
        }
    }
}

#[derive(Args, Clone)]
struct BenchArgs {
    #[command(flatten)]
    source: SourceArgs,
    /// Scenario families: paper (static vs animated vs optimized), instances, resolution,
    /// depth (LOD error vs time), peers (Embree / parry3d; needs `--features peers`), gi-scaling
    /// (voxel transformation vs re-voxelization), gi-volume (dense vs sparse GI volume: time and
    /// memory), gi-accuracy (GI knobs vs the path-traced box; writes docs/accuracy.md).
    #[arg(long, value_delimiter = ',', default_value = "paper,instances,resolution,depth")]
    scenarios: Vec<String>,
    /// Backends to run every scenario on: cpu, gpu, auto (gpu is skipped with a note when there is no adapter).
    #[arg(long, value_delimiter = ',', env = "VOXRAY_BACKEND", default_value = "auto")]
    backends: Vec<voxray::backend::BackendKind>,
    /// Untimed warm-up frames before each measurement.
    #[arg(long, default_value_t = 3)]
    warmup: usize,
    /// Timed frames per measurement (paper, resolution, depth, peers).
    #[arg(long, default_value_t = 30, value_parser = clap::value_parser!(u64).range(1..=100_000))]
    frames: u64,
    /// Image width of the paper, depth and peers scenarios.
    #[arg(long, default_value_t = 1280)]
    width: u32,
    /// Image height of the paper, depth and peers scenarios.
    #[arg(long, default_value_t = 768)]
    height: u32,
    /// Car counts of the instance sweep (8 instances per car).
    #[arg(long, value_delimiter = ',', default_value = "1,10,100,1000,10000")]
    sweep_cars: Vec<usize>,
    /// Timed frames per instance-sweep point.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u64).range(1..=100_000))]
    sweep_frames: u64,
    /// Image width of the instance sweep.
    #[arg(long, default_value_t = 320)]
    sweep_width: u32,
    /// Image height of the instance sweep.
    #[arg(long, default_value_t = 192)]
    sweep_height: u32,
    /// Image sizes of the resolution sweep, WxH.
    #[arg(long, value_delimiter = ',', default_value = "320x192,640x384,1280x768,1920x1152")]
    resolutions: Vec<String>,
    /// LOD levels of the depth sweep (default: the three levels above full depth).
    #[arg(long, value_delimiter = ',')]
    lod_levels: Vec<u32>,
    /// Folder for bench.json and bench.csv (records of earlier runs for other backends or scenarios are kept).
    #[arg(long, default_value = "docs/data")]
    out_dir: PathBuf,
    /// Folder for the PNG charts.
    #[arg(long, default_value = "docs/images")]
    charts_dir: PathBuf,
    /// Markdown file whose generated section is rewritten from the records.
    #[arg(long, default_value = "docs/benchmarks.md")]
    docs: PathBuf,
    /// Do not touch the Markdown file.
    #[arg(long)]
    no_docs: bool,
    /// Measure nothing: redraw the tables and charts from the records in --out-dir.
    #[arg(long)]
    report_only: bool,
    /// GI scaling scenario: moving car counts.
    #[arg(long, value_delimiter = ',', default_value = "1,16,64,256")]
    gi_cars: Vec<usize>,
    /// GI scaling scenario: world volume cells per side (a power of two).
    #[arg(long, default_value_t = 128)]
    gi_res: u32,
    /// GI scenarios: timed runs per setting (the median is kept).
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u64).range(1..=1000))]
    gi_repeats: u64,
    /// GI accuracy scenario: path-traced reference samples per pixel.
    #[arg(long, default_value_t = 512)]
    spp: u32,
    /// GI accuracy scenario: image size.
    #[arg(long, default_value = "160x120")]
    accuracy_size: String,
    /// GI accuracy scenario: the Markdown file whose generated section is rewritten.
    #[arg(long, default_value = "docs/accuracy.md")]
    accuracy_docs: PathBuf,
    /// Forget earlier records instead of merging this run into them.
    #[arg(long)]
    fresh: bool,
}

#[derive(Args, Clone)]
struct DemoArgs {
    #[command(flatten)]
    source: SourceArgs,
    /// Window width.
    #[arg(long, default_value_t = 1280)]
    width: u32,
    /// Window height.
    #[arg(long, default_value_t = 768)]
    height: u32,
    /// Draw this many frames (the clip advances 1/30 s per frame), then stop with --exit.
    #[arg(long)]
    frames: Option<u64>,
    /// Quit after --frames.
    #[arg(long, requires = "frames")]
    exit: bool,
    /// Write the last frame (and each P press) to this PNG.
    #[arg(long)]
    screenshot: Option<PathBuf>,
    /// Cars, each on its own figure-eight.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    cars: u32,
    /// Keep the car(s) in place (wheels, steering and doors still move).
    #[arg(long)]
    in_place: bool,
    /// No ground.
    #[arg(long)]
    no_ground: bool,
    #[command(flatten)]
    switches: Switches,
    /// Start with voxel-transformation GI on (on the backend that renders; switchable in the panel).
    #[arg(long)]
    gi: bool,
    /// Where to render: cpu, gpu or auto (the GPU on a hardware adapter, else the CPU).
    #[arg(long, env = "VOXRAY_BACKEND", default_value = "auto")]
    backend: voxray::backend::BackendKind,
    /// GPU renderer: read every frame back for the panel's statistics and pass times (the
    /// default keeps frames on the GPU and draws them from its radiance buffer; switchable in
    /// the panel).
    #[arg(long)]
    gpu_read_back: bool,
}

#[derive(Args)]
struct VoxelizeArgs {
    #[command(flatten)]
    source: SourceArgs,
    /// Where to write <part>.svo files.
    #[arg(long, default_value = "svo")]
    out_dir: PathBuf,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if let Some(n) = cli.threads {
        if let Err(e) = rayon::ThreadPoolBuilder::new().num_threads(n.max(1)).build_global() {
            eprintln!("warning: could not set {n} threads: {e}");
        }
    }
    let result = match cli.cmd {
        None => default_cmd(),
        Some(Cmd::Render(a)) => render_cmd(a),
        Some(Cmd::Voxelize(a)) => voxelize_cmd(a),
        Some(Cmd::Info { file }) => info_cmd(&file),
        Some(Cmd::Stability { rays, out }) => stability_cmd(rays, out),
        Some(Cmd::Bench(a)) => bench_cmd(a),
        Some(Cmd::Demo(a)) => demo_cmd(a),
        Some(Cmd::Model { name, out_dir }) => model_cmd(&name, out_dir.as_deref()),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// A subcommand's arguments with every option at its default (environment variables such as
/// VOXRAY_BACKEND still apply).
fn defaults<T: clap::Args + clap::FromArgMatches>() -> Result<T, Error> {
    let cmd = T::augment_args(clap::Command::new("voxray"));
    T::from_arg_matches(&cmd.get_matches_from(["voxray"])).map_err(|e| usage(&e.to_string()))
}

/// No subcommand: the demo window; without a display, a still of the car to voxray.png.
fn default_cmd() -> Result<(), Error> {
    if let Err(e) = voxray::viewer::check_display() {
        eprintln!("voxray: {e}");
        eprintln!("voxray: rendering the default car to voxray.png instead (see `voxray render --help`)");
        return render_cmd(defaults()?);
    }
    demo_cmd(defaults()?)
}

/// The GPU for a GI scenario's GPU rows: on `--backends gpu`, and on `auto` where the adapter
/// is hardware (as `Backend::open` decides); None (saying why where it failed) otherwise.
#[cfg(feature = "gpu")]
fn bench_gpu(
    backends: &[voxray::backend::BackendKind],
    pb: &ProgressBar,
    scenario: &str,
) -> Option<std::sync::Arc<voxray::gpu::GpuContext>> {
    use voxray::backend::BackendKind;
    match voxray::gpu::GpuContext::headless() {
        Ok(ctx) if backends.contains(&BackendKind::Gpu) || ctx.info.device_type != wgpu::DeviceType::Cpu => {
            Some(std::sync::Arc::new(ctx))
        }
        Ok(_) => None,
        Err(e) => {
            pb.suspend(|| eprintln!("skipping GPU {scenario}: {e}"));
            None
        }
    }
}

fn bar(len: u64, what: &str) -> ProgressBar {
    let b = ProgressBar::new(len);
    b.set_style(
        ProgressStyle::with_template("{msg:>24} [{bar:40}] {pos}/{len} ({eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    b.set_message(what.to_string());
    b
}

fn load_mesh(src: &SourceArgs) -> Result<Mesh, Error> {
    let mut mesh = if src.obj.is_empty() {
        voxray::model::embedded::load_default_car()?
    } else {
        let mut m = Mesh::default();
        for p in &src.obj {
            m.append(voxray::mesh::load_obj(p)?);
        }
        m
    };
    if src.lambertian {
        mesh.make_lambertian();
    }
    for w in &mesh.warnings {
        eprintln!("warning: {w}");
    }
    if mesh.degenerate_skipped > 0 {
        eprintln!("note: skipped {} degenerate triangles", mesh.degenerate_skipped);
    }
    Ok(mesh)
}

/// Voxelizes and builds every part, printing a statistics table.
fn build_parts(mesh: &Mesh, src: &SourceArgs) -> Result<Vec<Arc<Svo>>, Error> {
    let res = match src.voxel_size {
        Some(v) => Resolution::VoxelSize(v),
        None => Resolution::Depth(src.depth),
    };
    let opts = VoxelizeOptions { resolution: shared_resolution(mesh, res)?, solid: src.solid };
    let cache = if src.no_cache {
        None
    } else {
        src.cache_dir.clone().or_else(SvoCache::default_dir).map(|dir| SvoCache { dir })
    };
    eprintln!(
        "{:<16} {:>9} {:>6} {:>10} {:>9} {:>9} {:>9} {:>8}",
        "part", "triangles", "depth", "voxels", "nodes", "geom B/v", "attr B/v", "time"
    );
    let mut out = Vec::new();
    for (i, part) in mesh.parts.iter().enumerate() {
        let pb = bar(part.triangles.len() as u64, &part.name);
        let built = build_part(mesh, i, &opts, cache.as_ref(), &|d, _| pb.set_position(d as u64))?;
        pb.finish_and_clear();
        if let Some(w) = &built.cache_warning {
            eprintln!("warning: {w}");
        }
        let s = built.svo.stats();
        let time = if built.cached {
            "cached".to_string()
        } else {
            format!("{:.2}s", (built.voxelize + built.build).as_secs_f64())
        };
        eprintln!(
            "{:<16} {:>9} {:>6} {:>10} {:>9} {:>9.2} {:>9.2} {:>8}",
            part.name,
            part.triangles.len(),
            s.depth,
            s.voxels,
            s.nodes,
            s.geometry_bytes_per_voxel(),
            s.attribute_bytes_per_voxel(),
            time
        );
        out.push(Arc::new(built.svo));
    }
    Ok(out)
}

fn read_text(p: &Path) -> Result<String, Error> {
    std::fs::read_to_string(p).map_err(|source| Error::Io { path: p.display().to_string(), source })
}

/// Loads the parts and places them: the default car animated (or merged into one static SVO),
/// or the given OBJ parts at the identity.
fn stage(src: &SourceArgs, cars: u32, in_place: bool, static_car: bool, with_ground: bool) -> Result<Staged, Error> {
    let default_car = src.obj.is_empty();
    if !default_car && (cars > 1 || static_car || in_place) {
        return Err(usage("--cars, --in-place and --static-car apply to the default car only"));
    }
    let mut mesh = load_mesh(src)?;
    if default_car && !static_car {
        let parts = build_parts(&mesh, src)?;
        return stage_cars(&parts, cars as usize, !in_place, with_ground);
    }
    if static_car {
        let merged: Vec<_> = mesh.parts.iter().flat_map(|p| p.triangles.iter().copied()).collect();
        mesh.parts = vec![Part { name: "car (static)".into(), triangles: merged }];
    }
    let mut scene = Scene::new(build_parts(&mesh, src)?);
    for part in 0..scene.parts.len() {
        scene.add(Instance { part, parent: None, local: Transform::IDENTITY })?;
    }
    scene.update()?;
    let bounds = scene.bounds();
    if default_car && with_ground {
        add_ground(&mut scene, bounds)?;
    }
    Ok(Staged { scene, cars: Vec::new(), bounds })
}

fn usage(msg: &str) -> Error {
    Error::Io {
        path: "arguments".into(),
        source: std::io::Error::new(std::io::ErrorKind::InvalidInput, msg.to_string()),
    }
}

/// `car.png` → `car_0007.png` for frame 7 of a sequence.
fn numbered(path: &Path, frame: u32) -> PathBuf {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let ext = path.extension().map(|e| format!(".{}", e.to_string_lossy())).unwrap_or_default();
    path.with_file_name(format!("{stem}_{frame:04}{ext}"))
}

fn orbit(camera: &Camera, degrees: f64) -> Camera {
    let q = glam::DQuat::from_axis_angle(camera.up.normalize(), degrees.to_radians());
    Camera { eye: camera.target + q * (camera.eye - camera.target), ..*camera }
}

fn render_cmd(a: RenderArgs) -> Result<(), Error> {
    let t0 = Instant::now();
    let is_gif = a.out.extension().is_some_and(|e| e.eq_ignore_ascii_case("gif"));
    if is_gif && a.frames < 2 {
        return Err(usage("a .gif output needs --frames 2 or more"));
    }
    if !(a.fps.is_finite() && a.fps > 0.0 && a.time.is_finite() && a.orbit.is_finite()) {
        return Err(usage("--fps must be positive; --time and --orbit finite"));
    }
    let lights = match &a.lights_json {
        Some(p) => Lights::from_json(&read_text(p)?).map_err(|e| with_path(p, e))?,
        None => Lights::default(),
    };
    let camera_json = a
        .camera_json
        .as_ref()
        .map(|p| read_text(p).and_then(|t| Camera::from_json(&t).map_err(|e| with_path(p, e))))
        .transpose()?;
    let mut st = stage(&a.source, a.cars, a.in_place, a.static_car, !a.no_ground)?;
    let mut camera = camera_json.unwrap_or_else(|| {
        if a.frames == 1 {
            // One frame: frame the car(s) as posed, seen from the front left of the first car.
            let _ = pose_all(&mut st.scene, &st.cars, a.time);
            let _ = st.scene.update();
            let heading = st
                .cars
                .first()
                .map_or(glam::DQuat::IDENTITY, |c| st.scene.world(c.body).to_scale_rotation_translation().1);
            let (lo, hi) = st.cars_bounds();
            Camera::framing_from(lo.as_vec3(), hi.as_vec3(), 1280, 768, heading * glam::DVec3::new(0.95, 0.36, -0.9))
        } else {
            Camera::framing(st.bounds.0.as_vec3(), st.bounds.1.as_vec3(), 1280, 768)
        }
    });
    camera.width = a.width.unwrap_or(camera.width);
    camera.height = a.height.unwrap_or(camera.height);
    camera.validate()?;
    let t_setup = t0.elapsed();

    if a.reference {
        return reference_cmd(&a, &st, &camera, &lights, t_setup);
    }
    let features = a.switches.features();
    let opts = RenderOptions { max_level: a.lod.unwrap_or(u32::MAX) };
    let gi = a.gi.then(|| voxray::gi::GiSettings {
        res: a.gi_res,
        filter: a.gi_filter,
        cones: voxray::gi::ConeSettings { diffuse_cones: a.gi_cones, ..Default::default() },
        extent: a.gi_extent,
        bounces: a.gi_bounces,
        volume: a.gi_volume,
        levels: a.gi_levels,
    });
    if let Some(g) = &gi {
        // Check the knobs before any frame is rendered.
        g.validated().map_err(|e| usage(&e.to_string()))?;
    }
    let mut session = voxray::session::Session::open(a.backend)?;
    eprintln!("backend: {}", session.description());
    session.set_gi(gi)?;
    let mut gpu_times = Vec::new();
    let mut last_plan: Option<FramePlan> = None;
    let mut gif_frames = Vec::new();
    let (mut times, mut traced, mut reused) = (Vec::new(), 0u64, 0u64);
    let pb = if a.frames > 1 { bar(a.frames as u64, "frames") } else { bar(2 * camera.height as u64, "rendering") };
    for f in 0..a.frames {
        let start = Instant::now();
        let t = a.time + f as f64 / a.fps;
        pose_all(&mut st.scene, &st.cars, t)?;
        st.scene.update()?;
        let cam = orbit(&camera, a.orbit * (t - a.time));
        let report = session.frame(&st.scene, &cam, &lights, &features, &opts, &|d, _| {
            if a.frames == 1 {
                pb.set_position(d as u64)
            }
        })?;
        let plan = report.plan;
        if a.explain && last_plan.as_ref().is_none_or(|p| p.reasons != plan.reasons) {
            pb.suspend(|| eprintln!("frame {f}: {}", plan.explain()));
        }
        let frame = session.last_frame().ok_or_else(|| usage("the renderer kept no frame"))?;
        if f == 0 && frame.eye_inside_fraction() > 0.5 {
            pb.suspend(|| {
                eprintln!(
                    "warning: the eye is inside a voxel ({:.0} % of the rays hit at t = 0), so the image is one flat \
                     colour: move the camera (--camera-json) out of the geometry",
                    100.0 * frame.eye_inside_fraction()
                )
            });
        }
        let backend = session.backend();
        match (session.gi(), &report.gi, f) {
            (Some(g), Some(s), 0) => pb.suspend(|| {
                eprintln!(
                    "GI: {} voxels into {} of {}³ cells; caches {:.0} ms, transform {:.0} ms, inject {:.0} ms, levels {:.0} ms, cones {:.0} ms",
                    s.voxels, s.occupied, g.res, s.caches_ms, s.transform_ms, s.inject_ms, s.levels_ms, s.cones_ms
                );
                let mb = |b: u64| b as f64 / (1u64 << 20) as f64;
                eprintln!(
                    "GI volume: {:?}, {:.1} MiB of cells (dense {}³: {:.1} MiB)",
                    s.layout.unwrap_or(voxray::gi::Layout::Dense),
                    mb(s.volume_bytes),
                    g.res,
                    mb(s.dense_bytes),
                )
            }),
            (Some(g), None, 0) => {
                let ms = backend.gi_pass_ms().map_or("not timed".to_string(), |ms| format!("{ms:.2} ms"));
                let volume = match backend.gi_volume() {
                    Some((voxray::gi::Layout::Sparse, bricks, bytes)) => {
                        format!(
                            "sparse {}³ volume ({bricks} bricks, {:.1} MiB of GI buffers)",
                            g.res,
                            bytes as f64 / 1048576.0
                        )
                    }
                    Some((_, _, bytes)) => {
                        format!("dense {}³ volume ({:.1} MiB of GI buffers)", g.res, bytes as f64 / 1048576.0)
                    }
                    None => format!("{}³ volume", g.res),
                };
                pb.suspend(|| {
                    eprintln!(
                        "GI on the GPU: {volume}; transform + inject + levels{} {ms} (cones are in the shade pass)",
                        if g.bounces > 1 { format!(" + {} more bounces", g.bounces - 1) } else { String::new() }
                    )
                });
            }
            _ => {}
        }
        times.push(start.elapsed().as_secs_f64());
        if let Some(t) = backend.pass_times() {
            gpu_times.push(t);
        }
        traced += frame.primary_rays - frame.reused + frame.shadow_rays;
        reused += frame.reused;
        last_plan = Some(plan);
        write_frame(&a, frame, f, is_gif, &mut gif_frames)?;
        if a.frames > 1 {
            pb.inc(1);
        }
    }
    pb.finish_and_clear();
    if is_gif {
        output::write_gif(&a.out, camera.width, camera.height, a.fps, gif_frames)?;
    }
    let total: f64 = times.iter().sum();
    let (median, p95, _) = voxray::bench::summarize(&times);
    let pixels = camera.width as u64 * camera.height as u64 * a.frames as u64;
    eprintln!(
        "timings: setup (load, voxelize, build) {:.2}s | {} frame(s) {:.3}s, median {:.1} ms, p95 {:.1} ms",
        t_setup.as_secs_f64(),
        a.frames,
        total,
        median * 1e3,
        p95 * 1e3
    );
    if !gpu_times.is_empty() {
        let (tr, _, _) = voxray::bench::summarize(&gpu_times.iter().map(|t| t.0).collect::<Vec<_>>());
        let (sh, _, _) = voxray::bench::summarize(&gpu_times.iter().map(|t| t.1).collect::<Vec<_>>());
        eprintln!("GPU passes (timestamp queries, median): trace {tr:.2} ms, shade {sh:.2} ms");
    }
    eprintln!(
        "rays: {traced} traced ({:.1}% of pixels reused from the hit buffer) = {:.2} Mrays/s on {} ({}x{}, {} instances)",
        100.0 * reused as f64 / pixels as f64,
        traced as f64 / total / 1e6,
        if matches!(session.backend(), Backend::Cpu(_)) {
            format!("{} threads", rayon::current_num_threads())
        } else {
            "the GPU".into()
        },
        camera.width,
        camera.height,
        st.scene.instances().len()
    );
    Ok(())
}

/// `voxray render --reference`: path-traces the first frame, writing the estimate so far each
/// time another tenth of the samples is done (stop it early and the image is still there).
fn reference_cmd(
    a: &RenderArgs,
    st: &Staged,
    camera: &Camera,
    lights: &Lights,
    t_setup: std::time::Duration,
) -> Result<(), Error> {
    if a.frames > 1 {
        return Err(usage("--reference renders one frame; drop --frames"));
    }
    let settings = voxray::gi::ReferenceSettings { spp: a.spp, bounces: a.bounces, seed: 1 };
    let start = Instant::now();
    let mut pt = voxray::gi::PathTracer::new(&st.scene, camera, lights, settings).map_err(|e| usage(&e.to_string()))?;
    let pb = bar(a.spp as u64, "samples per pixel");
    let checkpoint = a.spp.div_ceil(10);
    while pt.samples() < a.spp {
        pt.pass();
        pb.set_position(pt.samples() as u64);
        if pt.samples() % checkpoint == 0 || pt.samples() == a.spp {
            output::write_image(&pt.frame(), &a.out)?;
        }
    }
    pb.finish_and_clear();
    let secs = start.elapsed().as_secs_f64();
    eprintln!("wrote {} ({} samples per pixel)", a.out.display(), pt.samples());
    eprintln!(
        "timings: setup (load, voxelize, build) {:.2}s | path tracing {:.2}s, {} rays = {:.2} Mrays/s",
        t_setup.as_secs_f64(),
        secs,
        pt.rays(),
        pt.rays() as f64 / secs / 1e6
    );
    Ok(())
}

fn write_frame(a: &RenderArgs, frame: &Frame, f: u32, is_gif: bool, gif: &mut Vec<Vec<u8>>) -> Result<(), Error> {
    if is_gif {
        gif.push(output::srgb8(frame));
    } else {
        let path = if a.frames > 1 { numbered(&a.out, f) } else { a.out.clone() };
        output::write_image(frame, &path)?;
        if a.frames == 1 {
            println!("wrote {}", path.display());
        } else if f + 1 == a.frames {
            println!("wrote {} … {}", numbered(&a.out, 0).display(), path.display());
        }
    }
    if let Some(dir) = &a.aov_dir {
        let d = if a.frames > 1 { dir.join(format!("frame_{f:04}")) } else { dir.clone() };
        output::write_aovs(frame, &d)?;
        if f + 1 == a.frames {
            println!("wrote AOVs (t, instance, normal .npy) under {}", dir.display());
        }
    }
    Ok(())
}

fn demo_cmd(a: DemoArgs) -> Result<(), Error> {
    use voxray::viewer::{check_display, run, CarParts, DemoOptions, ViewerError};
    let demo_err = |e: ViewerError| Error::Io { path: "demo".into(), source: std::io::Error::other(e.to_string()) };
    check_display().map_err(demo_err)?;
    let st = stage(&a.source, a.cars, a.in_place, false, !a.no_ground)?;
    let (lo, hi) = if st.cars.is_empty() || a.in_place { st.cars_bounds() } else { st.bounds };
    let camera = Camera::framing(lo.as_vec3(), hi.as_vec3(), a.width, a.height);
    // The default car can be re-staged with another car count from the panel.
    let car_parts =
        (!st.cars.is_empty()).then(|| CarParts { parts: st.scene.parts[..8].to_vec(), ground: !a.no_ground });
    let opts = DemoOptions {
        width: a.width,
        height: a.height,
        frames: a.frames,
        exit: a.exit,
        screenshot: a.screenshot.clone(),
        backend: a.backend,
        features: a.switches.features(),
        car_parts,
        gi: a.gi,
        gpu_read_back: a.gpu_read_back,
    };
    let report = run(opts, st.scene, st.cars, Lights::default(), camera).map_err(demo_err)?;
    eprintln!("demo: {} frames on {}, median {:.1} ms/frame", report.frames, report.backend, report.median_ms);
    if let Some(line) = report.gpu_steady_state() {
        println!("{line}");
    }
    Ok(())
}

fn bench_cmd(a: BenchArgs) -> Result<(), Error> {
    use voxray::bench::matrix::{self, CarModel, MatrixConfig, Scenario};
    use voxray::bench::{machine, Record};
    if a.report_only {
        return write_records(&a, Vec::new());
    }
    if !a.source.obj.is_empty() {
        return Err(usage("bench uses the default car"));
    }
    let command = std::env::args()
        .enumerate()
        .map(|(i, s)| if i == 0 { "voxray".to_string() } else { s })
        .collect::<Vec<_>>()
        .join(" ");
    let mut scenarios = Vec::new();
    let (mut peers, mut gi_scaling, mut gi_accuracy, mut gi_volume) = (false, false, false, false);
    for s in &a.scenarios {
        if s.eq_ignore_ascii_case("peers") {
            peers = true;
        } else if s.eq_ignore_ascii_case("gi-scaling") {
            gi_scaling = true;
        } else if s.eq_ignore_ascii_case("gi-accuracy") {
            gi_accuracy = true;
        } else if s.eq_ignore_ascii_case("gi-volume") {
            gi_volume = true;
        } else {
            scenarios.push(s.parse::<Scenario>().map_err(|e| usage(&e))?);
        }
    }
    if peers && !cfg!(feature = "peers") {
        return Err(usage(
            "the peers scenario needs a build with `--features peers` (and Debian's libembree-dev for Embree)",
        ));
    }
    let resolutions = a
        .resolutions
        .iter()
        .map(|r| {
            let (w, h) = r.split_once(['x', '×']).ok_or_else(|| usage(&format!("resolution '{r}' is not WxH")))?;
            let p = |v: &str| v.trim().parse::<u32>().ok().filter(|&v| (1..=16384).contains(&v));
            match (p(w), p(h)) {
                (Some(w), Some(h)) => Ok((w, h)),
                _ => Err(usage(&format!("resolution '{r}': width and height must be 1…16384"))),
            }
        })
        .collect::<Result<Vec<_>, Error>>()?;
    for (w, h) in [(a.width, a.height), (a.sweep_width, a.sweep_height)] {
        if !(1..=16384).contains(&w) || !(1..=16384).contains(&h) {
            return Err(usage("image sizes must be 1…16384"));
        }
    }
    if let Some(&n) = a.sweep_cars.iter().find(|&&n| n == 0 || n > 100_000) {
        return Err(usage(&format!("--sweep-cars {n}: car counts must be 1…100000")));
    }
    let cfg = MatrixConfig {
        scenarios,
        warmup: a.warmup,
        frames: a.frames as usize,
        size: (a.width, a.height),
        cars: a.sweep_cars.clone(),
        sweep_frames: a.sweep_frames as usize,
        sweep_size: (a.sweep_width, a.sweep_height),
        resolutions,
        lod_levels: a.lod_levels.clone(),
        command: command.clone(),
        machine: machine(),
    };
    // The car: its parts, and all of it merged into one SVO for the static baseline.
    let mesh = load_mesh(&a.source)?;
    let parts = build_parts(&mesh, &a.source)?;
    let mut merged_mesh = mesh.clone();
    let all: Vec<_> = mesh.parts.iter().flat_map(|p| p.triangles.iter().copied()).collect();
    merged_mesh.parts = vec![Part { name: "car (static)".into(), triangles: all }];
    let merged = build_parts(&merged_mesh, &a.source)?.remove(0);
    let car = CarModel { parts, merged };

    let mut records: Vec<Record> = Vec::new();
    let mut kinds = a.backends.clone();
    kinds.dedup();
    let pb = bar(
        (cfg.steps() * kinds.len()) as u64
            + if peers { 4 } else { 0 }
            + gi_scaling as u64
            + gi_accuracy as u64
            + gi_volume as u64,
        "measurements",
    );
    for kind in kinds {
        let mut session = match voxray::session::Session::open(kind) {
            Ok(s) => s,
            Err(e) => {
                pb.suspend(|| eprintln!("skipping backend {kind:?}: {e}"));
                pb.inc(cfg.steps() as u64);
                continue;
            }
        };
        let name = session.description().to_string();
        pb.suspend(|| eprintln!("backend: {name}"));
        let mut progress = |what: &str| {
            pb.set_message(what.to_string());
            pb.inc(1);
        };
        records.extend(matrix::run(&cfg, &car, &mut session, &name, &mut progress)?);
    }
    #[cfg(feature = "peers")]
    if peers {
        pb.set_message("peers: building the views");
        let car_triangles: Vec<[glam::Vec3; 3]> =
            mesh.parts.iter().flat_map(|p| p.triangles.iter().map(|t| t.positions)).collect();
        let scene = matrix::static_scene(car.merged.clone())?;
        let (lo, hi) = scene.bounds();
        let camera = Camera::framing(lo.as_vec3(), hi.as_vec3(), a.width, a.height);
        // Close up: the same direction, near enough that the car covers most pixels.
        let close = Camera { eye: camera.target + (camera.eye - camera.target) * 0.4, ..camera };
        // The body alone, voxelized 2^11 along its longest side.
        let body_index = mesh.parts.iter().position(|p| p.name == "body").unwrap_or(0);
        let mut body_mesh = mesh.clone();
        body_mesh.parts = vec![mesh.parts[body_index].clone()];
        let body_source = SourceArgs { depth: 11, voxel_size: None, ..a.source.clone() };
        let body = build_parts(&body_mesh, &body_source)?.remove(0);
        let body_triangles: Vec<[glam::Vec3; 3]> = body_mesh.parts[0].triangles.iter().map(|t| t.positions).collect();
        let (blo, bhi) = matrix::static_scene(body.clone())?.bounds();
        let body_camera = Camera::framing(blo.as_vec3(), bhi.as_vec3(), a.width, a.height);
        let views = vec![
            voxray::bench::peers::PeerView {
                name: "default".into(),
                triangles: &car_triangles,
                svo: car.merged.clone(),
                camera,
                whole_frame: true,
            },
            voxray::bench::peers::PeerView {
                name: "close-up".into(),
                triangles: &car_triangles,
                svo: car.merged.clone(),
                camera: close,
                whole_frame: false,
            },
            voxray::bench::peers::PeerView {
                name: format!("body at depth {}", body.depth),
                triangles: &body_triangles,
                svo: body,
                camera: body_camera,
                whole_frame: false,
            },
        ];
        let mut threads = vec![1, rayon::current_num_threads()];
        threads.dedup();
        let input = voxray::bench::peers::PeerScene {
            views,
            threads,
            warmup: a.warmup,
            frames: a.frames as usize,
            command: command.clone(),
            machine: cfg.machine.clone(),
        };
        records.extend(voxray::bench::peers::run(&input, &mut |w| pb.set_message(w.to_string()))?);
        pb.inc(4);
    }
    if gi_scaling {
        let sc = voxray::bench::gi::ScalingConfig {
            cars: a.gi_cars.clone(),
            res: a.gi_res,
            repeats: a.gi_repeats as usize,
            command: command.clone(),
            machine: cfg.machine.clone(),
        };
        use voxray::backend::BackendKind;
        // The CPU reference for cpu and auto; the GPU passes for gpu, and for auto on a
        // hardware adapter (as Backend::open decides).
        if a.backends.iter().any(|k| *k != BackendKind::Gpu) {
            records.extend(voxray::bench::gi::scaling(&sc, &mesh, &car.parts, &mut |w| pb.set_message(w.to_string()))?);
        }
        #[cfg(feature = "gpu")]
        if a.backends.iter().any(|k| *k != BackendKind::Cpu) {
            if let Some(ctx) = bench_gpu(&a.backends, &pb, "gi-scaling") {
                records.extend(voxray::bench::gi::scaling_gpu(&sc, &mesh, &car.parts, ctx, &mut |w| {
                    pb.set_message(w.to_string())
                })?);
            }
        }
        pb.inc(1);
    }
    if gi_volume {
        let lc = voxray::bench::gi::LayoutConfig {
            size: (160, 120),
            resolutions: vec![64, 128, 256, 512, 1024],
            repeats: a.gi_repeats as usize,
            command: command.clone(),
            machine: cfg.machine.clone(),
        };
        use voxray::backend::BackendKind;
        // As gi-scaling: the CPU for cpu and auto, the GPU for gpu and auto on a hardware adapter.
        if a.backends.iter().any(|k| *k != BackendKind::Gpu) {
            records.extend(voxray::bench::gi::layouts(&lc, &mut |w| pb.set_message(w.to_string()))?);
        }
        #[cfg(feature = "gpu")]
        if a.backends.iter().any(|k| *k != BackendKind::Cpu) {
            if let Some(ctx) = bench_gpu(&a.backends, &pb, "gi-volume") {
                let mut say = |w: &str| {
                    if w.contains("left out") {
                        pb.suspend(|| eprintln!("{w}"));
                    } else {
                        pb.set_message(w.to_string());
                    }
                };
                records.extend(voxray::bench::gi::layouts_gpu(&lc, ctx, &mut say)?);
            }
        }
        pb.inc(1);
    }
    if gi_accuracy {
        let (w, h) = a
            .accuracy_size
            .split_once(['x', '×'])
            .and_then(|(w, h)| Some((w.trim().parse::<u32>().ok()?, h.trim().parse::<u32>().ok()?)))
            .filter(|&(w, h)| (1..=4096).contains(&w) && (1..=4096).contains(&h))
            .ok_or_else(|| usage(&format!("--accuracy-size '{}' must be WxH, each 1…4096", a.accuracy_size)))?;
        let ac = voxray::bench::gi::AccuracyConfig {
            size: (w, h),
            depth: 8,
            spp: a.spp,
            repeats: a.gi_repeats as usize,
            resolutions: vec![32, 64, 128, 256],
            cones: vec![1, 3, 6, 9, 16],
            bounces: vec![1, 2, 3],
            command: command.clone(),
            machine: cfg.machine.clone(),
        };
        use voxray::backend::BackendKind;
        // As gi-scaling: the CPU sweep for cpu and auto, the GPU's own knob for gpu and auto on
        // a hardware adapter.
        if a.backends.iter().any(|k| *k != BackendKind::Gpu) {
            records.extend(voxray::bench::gi::accuracy(&ac, &mut |w| pb.set_message(w.to_string()))?);
        }
        #[cfg(feature = "gpu")]
        if a.backends.iter().any(|k| *k != BackendKind::Cpu) {
            if let Some(ctx) = bench_gpu(&a.backends, &pb, "gi-accuracy") {
                records.extend(voxray::bench::gi::accuracy_gpu(&ac, ctx, &mut |w| pb.set_message(w.to_string()))?);
            }
        }
        pb.inc(1);
    }
    pb.finish_and_clear();

    write_records(&a, records)
}

/// Merges `records` with the earlier ones in `--out-dir`, then writes the JSON, the CSV, the
/// charts and the Markdown sections.
fn write_records(a: &BenchArgs, records: Vec<voxray::bench::Record>) -> Result<(), Error> {
    use voxray::bench::{report, Record};
    // Merge with earlier records, then JSON, CSV, charts and the Markdown section.
    let json_path = a.out_dir.join("bench.json");
    let old: Vec<Record> = if a.fresh {
        Vec::new()
    } else {
        match std::fs::read_to_string(&json_path) {
            Ok(text) => serde_json::from_str(&text).map_err(|e| with_path(&json_path, e))?,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
            Err(source) => return Err(Error::Io { path: json_path.display().to_string(), source }),
        }
    };
    let all = report::merge(old, &records);
    let write = |p: &Path, text: &str| -> Result<(), Error> {
        if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|source| Error::Io { path: dir.display().to_string(), source })?;
        }
        std::fs::write(p, text).map_err(|source| Error::Io { path: p.display().to_string(), source })
    };
    let json = serde_json::to_string_pretty(&all).map_err(|e| with_path(&json_path, e))?;
    write(&json_path, &json)?;
    let csv_path = a.out_dir.join("bench.csv");
    write(&csv_path, &report::to_csv(&all))?;
    let charts = voxray::bench::chart::draw_all(&all, &a.charts_dir).map_err(|e| usage(&e.to_string()))?;
    // Chart links relative to the Markdown file's folder.
    let doc_dir = a.docs.parent().map(Path::to_path_buf).unwrap_or_default();
    let rel = relative(&doc_dir, &a.charts_dir);
    let links: Vec<(String, String)> =
        charts.iter().map(|(g, f)| (g.clone(), rel.join(f).to_string_lossy().replace('\\', "/"))).collect();
    let md = report::markdown(&all, &links);
    println!("{}", report::markdown(&records, &[]));
    println!("wrote {} and {} ({} records)", json_path.display(), csv_path.display(), all.len());
    for (_, f) in &charts {
        println!("wrote {}", a.charts_dir.join(f).display());
    }
    if !a.no_docs {
        let doc = match std::fs::read_to_string(&a.docs) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => "# Benchmarks\n".to_string(),
            Err(source) => return Err(Error::Io { path: a.docs.display().to_string(), source }),
        };
        write(&a.docs, &report::splice(&doc, &md))?;
        println!("regenerated {}", a.docs.display());
        if all.iter().any(|r| r.group == "gi-accuracy") {
            let acc_dir = a.accuracy_docs.parent().map(Path::to_path_buf).unwrap_or_default();
            let rel = relative(&acc_dir, &a.charts_dir);
            let links: Vec<(String, String)> =
                charts.iter().map(|(g, f)| (g.clone(), rel.join(f).to_string_lossy().replace('\\', "/"))).collect();
            let doc = match std::fs::read_to_string(&a.accuracy_docs) {
                Ok(t) => t,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => "# GI accuracy\n".to_string(),
                Err(source) => return Err(Error::Io { path: a.accuracy_docs.display().to_string(), source }),
            };
            write(&a.accuracy_docs, &report::splice(&doc, &report::accuracy_markdown(&all, &links)))?;
            println!("regenerated {}", a.accuracy_docs.display());
        }
    }
    Ok(())
}

/// `to` relative to `from` when both are relative paths under the same root (e.g. docs and
/// docs/images → images); otherwise `to` as given.
fn relative(from: &Path, to: &Path) -> PathBuf {
    match to.strip_prefix(from) {
        Ok(r) => r.to_path_buf(),
        Err(_) if from.is_relative() && to.is_relative() => {
            let ups = from.components().count();
            let mut p = PathBuf::new();
            for _ in 0..ups {
                p.push("..");
            }
            p.join(to)
        }
        Err(_) => to.to_path_buf(),
    }
}

fn with_path<E: std::fmt::Display>(p: &Path, e: E) -> Error {
    Error::Io {
        path: p.display().to_string(),
        source: std::io::Error::new(std::io::ErrorKind::InvalidData, e.to_string()),
    }
}

fn voxelize_cmd(a: VoxelizeArgs) -> Result<(), Error> {
    let mesh = load_mesh(&a.source)?;
    let parts = build_parts(&mesh, &a.source)?;
    std::fs::create_dir_all(&a.out_dir)
        .map_err(|source| Error::Io { path: a.out_dir.display().to_string(), source })?;
    for (part, svo) in mesh.parts.iter().zip(&parts) {
        let safe: String =
            part.name.chars().map(|c| if c.is_alphanumeric() || c == '_' || c == '-' { c } else { '_' }).collect();
        let path = a.out_dir.join(format!("{safe}.svo"));
        voxray::svo::io::save(svo, &path)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

fn info_cmd(file: &Path) -> Result<(), Error> {
    let svo = voxray::svo::io::load(file)?;
    let s = svo.stats();
    match voxray::svo::io::file_version(file) {
        Some(v) if v < voxray::svo::io::VERSION => println!(
            "{}: valid, format version {v}, converted on load to version {} (`voxray voxelize` writes the current version)",
            file.display(),
            voxray::svo::io::VERSION
        ),
        _ => println!("{}: valid", file.display()),
    }
    println!("  bounds: min {:?}, size {}", svo.bounds.min, svo.bounds.size);
    println!("  depth {}, voxel size {}", s.depth, svo.bounds.voxel_size(s.depth));
    println!("  voxels {}, nodes {}, attributes {}", s.voxels, s.nodes, s.attributes);
    println!(
        "  geometry (what traversal reads) {} B ({:.2} B/voxel), attributes (read for hits) {} B ({:.2} B/voxel)",
        s.geometry_bytes,
        s.geometry_bytes_per_voxel(),
        s.attribute_bytes,
        s.attribute_bytes_per_voxel()
    );
    Ok(())
}

fn stability_cmd(rays: usize, out: Option<PathBuf>) -> Result<(), Error> {
    use voxray::stability::{run_case, run_transform_case, standard_cases, table, transform_cases};
    let t = Instant::now();
    let cases = standard_cases(rays);
    let tcases = transform_cases(24_000);
    let pb = bar((cases.len() + tcases.len()) as u64, "stability cases");
    let mut reports: Vec<_> = cases
        .iter()
        .map(|c| {
            let r = run_case(c);
            pb.inc(1);
            r
        })
        .collect();
    reports.extend(tcases.iter().map(|c| {
        let r = run_transform_case(c);
        pb.inc(1);
        r
    }));
    pb.finish_and_clear();
    let tbl = table(&reports);
    println!("{tbl}");
    let bad: u64 = reports.iter().map(|r| r.mismatches + r.nan + r.aborted).sum();
    println!(
        "{} rays in {:.1}s; {bad} failures",
        reports.iter().map(|r| r.rays).sum::<u64>(),
        t.elapsed().as_secs_f64()
    );
    if let Some(p) = out {
        let md = format!(
            "# Stability suite\n\nProduced by `voxray stability --rays {rays} --out {}` (release build; `cargo test` runs \
             the same cases through `tests/stability.rs` and fails on any NaN, mismatch or aborted loop).\n\n\
             Each row traces a family of stiff or adversarial rays through an SVO and compares every ray with the \
             brute-force Amanatides–Woo DDA oracle (`src/oracle.rs`, f64, no octree). Columns:\n\n\
             - **oracle hits**: rays the oracle says hit a voxel (the rest must miss).\n\
             - **NaN**: results with a non-finite t or normal.\n\
             - **misses vs oracle**: wrong voxel, wrong t, or hit/miss disagreement.\n\
             - **accepted ties**: the ray passes exactly through an edge or corner (or starts on a face), so several \
             voxels are touched at the same t; the answer is accepted only if the voxel named is occupied, touched \
             within 10⁻⁶ (relative) at that t, and no voxel is entered for longer than that before it.\n\
             - **max rel. |Δt|**: largest |t − exact f64 entry t of the voxel| / max(|t|, one cube width in t); the \
             bound is 10⁻⁵.\n\
             - **max loop count / loop bound**: iterations of the traversal loop against the proven bound \
             5·(3·(2^depth − 1) + depth) + 1 (`traverse::step_bound`; not recorded for the instance rows).\n\n\
             The `instance:` rows place the SVO with a transform (or a parent and a child transform) and trace \
             world rays the way the renderer does (camera-relative f64 maps, the instance search of \
             `render::visibility`); the oracle walks the same ray mapped into the unit cube in f64.\n\n{tbl}",
            p.display()
        );
        std::fs::write(&p, md).map_err(|source| Error::Io { path: p.display().to_string(), source })?;
        println!("wrote {}", p.display());
    }
    if bad > 0 {
        return Err(Error::Io {
            path: "stability".into(),
            source: std::io::Error::other(format!("{bad} rays disagree with the oracle")),
        });
    }
    Ok(())
}

fn model_cmd(model: &str, out_dir: Option<&Path>) -> Result<(), Error> {
    let out_dir = out_dir.map_or_else(|| Path::new("models").join(model), Path::to_path_buf);
    std::fs::create_dir_all(&out_dir).map_err(|source| Error::Io { path: out_dir.display().to_string(), source })?;
    let files = if model == "box" { voxray::model::room::files() } else { voxray::model::car::files() };
    for (name, text) in files {
        let p = out_dir.join(&name);
        std::fs::write(&p, text).map_err(|source| Error::Io { path: p.display().to_string(), source })?;
        println!("wrote {}", p.display());
    }
    Ok(())
}
