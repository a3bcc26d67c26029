//! The command line: clap's argument structs of every subcommand.

use super::*;

/// Most worker threads `--threads` takes: more than any machine this runs on has cores, and
/// few enough that starting them cannot hang the process.
pub(crate) const MAX_THREADS: u64 = 1024;

/// Most rays `stability --rays` takes (about 1.3 GB of rays and answers).
pub(crate) const MAX_STABILITY_RAYS: u64 = 100_000_000;

#[derive(Parser)]
#[command(
    name = "voxray",
    version,
    about = "Ray tracing of sparse voxel octrees (Laine–Karras SVOs, Revelles traversal)."
)]
#[command(long_about = "Ray tracing of sparse voxel octrees. With no subcommand, opens the demo window on the \
embedded animated car (`voxray demo`); without a display, renders it to voxray.png (`voxray render`).")]
pub(crate) struct Cli {
    #[command(subcommand)]
    pub(crate) cmd: Option<Cmd>,
    /// Worker threads, 1…1024 (default: one per core).
    #[arg(long, global = true, value_parser = clap::value_parser!(u64).range(1..=MAX_THREADS))]
    pub(crate) threads: Option<u64>,
    /// Memory the large allocations may take together (voxels, frames, AOVs, the reference,
    /// GIF frames, GI volumes), e.g. 512M or 4G; an input that needs more is refused before
    /// allocating (default: 3/4 of the machine's memory or of `ulimit -v`).
    #[arg(long, global = true, value_parser = voxray::memory::parse_size)]
    pub(crate) memory_budget: Option<u64>,
}

#[derive(Subcommand)]
pub(crate) enum Cmd {
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
        /// Rays in the random families, 1…100 000 000 (the adversarial families have fixed
        /// sizes; each ray takes about 13 bytes while the suite runs).
        #[arg(long, default_value_t = 1_000_000, value_parser = clap::value_parser!(u64).range(1..=MAX_STABILITY_RAYS))]
        rays: u64,
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
        /// Which model: `car` (the default car), `box` (the coloured-wall box of the GI tests),
        /// `thick-box` (the box with walls 12 cm thick, sunlit outside: GI's light-leak scene)
        /// or `panel-room` (a closed room lit only by an emissive ceiling panel).
        #[arg(value_parser = ["car", "box", "thick-box", "panel-room"])]
        name: String,
        /// Output folder (default: models/NAME).
        #[arg(long)]
        out_dir: Option<PathBuf>,
    },
}

#[derive(Args, Clone)]
pub(crate) struct SourceArgs {
    /// Scene file: OBJ (several may be given; each object/group is a part), glTF 2.0
    /// (.gltf/.glb, with its node hierarchy and animation) or a voxray .svo; told apart by
    /// content, then extension. Default: the embedded car.
    #[arg(long, visible_alias = "obj", num_args = 1..)]
    pub(crate) scene: Vec<PathBuf>,
    /// The glTF animation to play, by name or 0-based index; `all` plays every animation of
    /// the file together, `none` shows the rest pose (default: the file's first animation).
    #[arg(long)]
    pub(crate) animation: Option<String>,
    /// Voxels along the largest part's longest side, as 2^DEPTH; all parts share that voxel size.
    #[arg(long, default_value_t = 9, conflicts_with = "voxel_size", value_parser = clap::value_parser!(u32).range(1..=20))]
    pub(crate) depth: u32,
    /// Voxel edge length in OBJ units (instead of --depth).
    #[arg(long)]
    pub(crate) voxel_size: Option<f32>,
    /// Fill closed surfaces (depth ≤ 9).
    #[arg(long)]
    pub(crate) solid: bool,
    /// Folder of the SVO cache (default: $VOXRAY_CACHE_DIR, $XDG_CACHE_HOME/voxray or ~/.cache/voxray).
    #[arg(long)]
    pub(crate) cache_dir: Option<PathBuf>,
    /// Always voxelize; neither read nor write the cache.
    #[arg(long)]
    pub(crate) no_cache: bool,
    /// Ignore MTL Ks/Ns: every material purely Lambertian (the shared convention of
    /// DESIGN.md, for comparing images with other renderers).
    #[arg(long)]
    pub(crate) lambertian: bool,
}

#[derive(Args, Clone)]
pub(crate) struct RenderArgs {
    #[command(flatten)]
    pub(crate) source: SourceArgs,
    /// Camera JSON (eye, target, up, vfov_deg, width, height). Default: a three-quarter view framing the scene.
    #[arg(long)]
    pub(crate) camera_json: Option<PathBuf>,
    /// Lights JSON (sun, ambient, use_mtl_emitters, emitter_samples, suns, points, spots; docs/lights.md). Default: afternoon sun and a pale sky.
    #[arg(long)]
    pub(crate) lights_json: Option<PathBuf>,
    /// Image width (overrides the camera JSON).
    #[arg(long)]
    pub(crate) width: Option<u32>,
    /// Image height (overrides the camera JSON).
    #[arg(long)]
    pub(crate) height: Option<u32>,
    /// Output: .png (sRGB 8-bit) or .exr (linear float radiance); with --frames, name_0000.png … or one animated .gif.
    #[arg(long, default_value = "voxray.png")]
    pub(crate) out: PathBuf,
    /// Write t.npy, instance.npy and normal.npy into this folder (with --frames: DIR/frame_0000/ …),
    /// and ao.npy (ambient occlusion from the cones) with --gi.
    #[arg(long)]
    pub(crate) aov_dir: Option<PathBuf>,
    /// Level-of-detail: stop this many levels below the root.
    #[arg(long)]
    pub(crate) lod: Option<u32>,
    /// Primary visibility: trace (rays through the octrees, exact) or splat (square splats of
    /// the surface voxels with a depth buffer; CPU and GPU). Shading is the same.
    #[arg(long, default_value = "trace", value_parser = ["trace", "splat"])]
    pub(crate) renderer: String,
    /// Splats: the square's side in units of a voxel's projected edge (at least one pixel).
    #[arg(long, default_value_t = voxray::render::splat::DEFAULT_FACTOR)]
    pub(crate) splat_factor: f32,
    /// Splats on the GPU: compute (atomics in compute passes) or quads (the rasterizer, one
    /// quad per splat and a depth test); the same image. The CPU has one way.
    #[arg(long, default_value = "compute", value_parser = ["compute", "quads"])]
    pub(crate) splat_draw: String,
    /// Frames of the clip (the car, a glTF animation or a .vox flip-book animates; other scenes stay still).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub(crate) frames: u32,
    /// Render only frames A..B of the clip (A included, B not; frame f shows time
    /// --time + f/--fps and is written as name_f.png whatever the range).
    #[arg(long, value_name = "A..B")]
    pub(crate) frame_range: Option<String>,
    /// Render only shard I of N (0-based): the range split into N contiguous blocks, so N
    /// machines (a Slurm job array, a Kubernetes indexed Job, GNU parallel) share a clip with
    /// no coordination.
    #[arg(long, value_name = "I/N")]
    pub(crate) shard: Option<String>,
    /// Skip frames whose image (and AOVs, with --aov-dir) already exist and read back whole:
    /// a rerun finishes what an interrupted one left.
    #[arg(long)]
    pub(crate) resume: bool,
    /// Frames per second of the clip.
    #[arg(long, default_value_t = 30.0)]
    pub(crate) fps: f64,
    /// Clip time of the first frame, in seconds.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub(crate) time: f64,
    /// Cars (default car only): each a figure-eight of its own, with its own time offset.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub(crate) cars: u32,
    /// Keep the car(s) in place (wheels, steering and doors still move).
    #[arg(long)]
    pub(crate) in_place: bool,
    /// The whole car merged into one static SVO (the static baseline; no animation).
    #[arg(long)]
    pub(crate) static_car: bool,
    /// No ground under the default car.
    #[arg(long)]
    pub(crate) no_ground: bool,
    /// Orbit the camera about its target at this many degrees per second (a moving camera).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub(crate) orbit: f64,
    #[command(flatten)]
    pub(crate) switches: Switches,
    /// Print the frame plan (first frame, and whenever it changes).
    #[arg(long)]
    pub(crate) explain: bool,
    /// Voxel-transformation global illumination, on the backend that renders: colour bleeding
    /// and ambient occlusion in place of the flat sky term, and glossy reflections (one
    /// specular cone) on materials with MTL Ks and Ns.
    #[arg(long)]
    pub(crate) gi: bool,
    /// GI world volume cells per side.
    #[arg(long, default_value_t = 128, requires = "gi")]
    pub(crate) gi_res: u32,
    /// GI filtering of moved voxels: nearest or split (8-neighbour).
    #[arg(long, default_value = "split", requires = "gi")]
    pub(crate) gi_filter: voxray::gi::Filter,
    /// GI diffuse cones per pixel (1–64).
    #[arg(long, default_value_t = 6, requires = "gi")]
    pub(crate) gi_cones: u32,
    /// GI world volume edge in scene units (default: 3× the camera's distance to its target).
    #[arg(long, requires = "gi")]
    pub(crate) gi_extent: Option<f64>,
    /// GI bounces (1…8): each bounce past the first cone-traces every occupied cell's incoming light.
    #[arg(long, default_value_t = 1, requires = "gi")]
    pub(crate) gi_bounces: u32,
    /// With more than one GI bounce: on estimates the bounces after the last as a geometric
    /// series (the last bounce's light times r/(1 − r), r from how much of it meets the scene
    /// and the scene's mean albedo; docs/gi.md) and adds them; off gives exactly --gi-bounces.
    #[arg(long, default_value = "on", value_parser = ["on", "off"], requires = "gi")]
    pub(crate) gi_bounce_tail: String,
    /// GI world volume: dense (every cell, up to 512³), sparse (8³ bricks where voxels land,
    /// multiples of 8 up to 1024³) or auto (CPU: sparse above 128³; GPU: sparse above 512³).
    #[arg(long, default_value = "auto", requires = "gi")]
    pub(crate) gi_volume: voxray::gi::shade::VolumeChoice,
    /// Where the GPU's cones read the GI level chain: buffer (filtered in f32 in the shader,
    /// equal to the CPU) or texture (a 3D texture with mips, hardware filtering; dense volume).
    #[arg(long, default_value = "buffer", requires = "gi")]
    pub(crate) gi_levels: voxray::gi::shade::LevelStore,
    /// Where GI's diffuse cones are gathered: pixels (every pixel), half (one pixel in each
    /// 2×2 block, blended at the others from the samples on their own surface) or caches
    /// (clustered radiance caches, diffuse and glossy; docs/gi.md).
    #[arg(long, default_value = "caches", requires = "gi")]
    pub(crate) gi_gather: voxray::render::Gather,
    /// Anisotropic GI levels: each coarse cell keeps what is seen through it along each of the
    /// six axis directions, so less light on a wall's far side leaks through it (both backends;
    /// dense volume, level buffer; 1.1–1.3× the GI time; docs/gi.md).
    #[arg(long, requires = "gi")]
    pub(crate) gi_anisotropic: bool,
    /// Emitters' (MTL Ke) shadows: rays (a shadow ray per light sample) or cones (one cone per
    /// emitter triangle through the GI volume's opacity: smooth, at the volume's resolution;
    /// docs/gi.md). Suns, points and spots keep their rays.
    #[arg(long, default_value = "rays", value_parser = ["rays", "cones"], requires = "gi")]
    pub(crate) gi_shadows: String,
    /// Points each lit GI cell draws on the emitters in light injection, 1…1024 (the pixels
    /// keep the lights JSON's `emitter_samples`): the cones average many cells, so one
    /// suffices (docs/lights.md).
    #[arg(long, default_value_t = 1, requires = "gi")]
    pub(crate) gi_cell_samples: u32,
    /// Radiance caches: tile edge in pixels.
    #[arg(long, default_value_t = 16, requires = "gi")]
    pub(crate) gi_cache_tile: u32,
    /// Radiance caches: most caches per tile (one per dominant normal).
    #[arg(long, default_value_t = 3, requires = "gi")]
    pub(crate) gi_cache_count: u32,
    /// Radiance caches: texels per side of each cache's hemispherical map (4, 8, 16 or 32).
    #[arg(long, default_value_t = 16, requires = "gi")]
    pub(crate) gi_cache_res: u32,
    /// Radiance caches: gathering radius in tiles.
    #[arg(long, default_value_t = voxray::render::radiance_cache::CacheSettings::default().radius, requires = "gi")]
    pub(crate) gi_cache_radius: u32,
    /// Radiance caches: placement, clustered (the tiles' dominant normals) or even (a grid).
    #[arg(long, default_value = "clustered", requires = "gi")]
    pub(crate) gi_cache_placement: voxray::render::radiance_cache::Placement,
    /// Radiance caches: each texel's cone as a percentage (5…100) of the aperture whose solid
    /// angle is the texel's; narrower cones read finer levels of the volume.
    #[arg(long, default_value_t = voxray::render::radiance_cache::CacheSettings::default().cone_percent, requires = "gi")]
    pub(crate) gi_cache_cone: u32,
    /// Path-trace the reference image instead (CPU, progressive; write .exr for linear radiance):
    /// the same voxels, materials and lights, sun + sky + emitters, all bounces unless --bounces.
    #[arg(long, conflicts_with = "gi")]
    pub(crate) reference: bool,
    /// What the reference's rays meet: the voxels (as the renderer) or the source triangles
    /// (a BVH over the mesh: the voxelization's own error shows; needs --no-ground with the
    /// default car, whose ground has no triangles).
    #[arg(long, default_value = "voxels", value_parser = ["voxels", "triangles"], requires = "reference")]
    pub(crate) reference_geometry: String,
    /// Reference samples per pixel.
    #[arg(long, default_value_t = 256, requires = "reference")]
    pub(crate) spp: u32,
    /// Reference indirect bounces (1: the one-bounce image a single GI bounce approximates); default unlimited.
    #[arg(long, requires = "reference")]
    pub(crate) bounces: Option<u32>,
    /// Where to render: cpu, gpu (an error without an adapter) or auto (the GPU on a hardware adapter, else the CPU).
    #[arg(long, env = "VOXRAY_BACKEND", default_value = "auto")]
    pub(crate) backend: voxray::backend::BackendKind,
}

/// The technique switches (`FramePlan` features), shared by `render` and `demo`.
#[derive(Args, Clone)]
pub(crate) struct Switches {
    /// No bounding-sphere culling.
    #[arg(long)]
    pub(crate) no_cull: bool,
    /// No depth-sorted early-out.
    #[arg(long)]
    pub(crate) no_sort: bool,
    /// No instance BVH.
    #[arg(long)]
    pub(crate) no_bvh: bool,
    /// No per-pixel hit buffer.
    #[arg(long)]
    pub(crate) no_hit_buffer: bool,
    /// No shadow rays.
    #[arg(long)]
    pub(crate) no_shadows: bool,
    /// No beams (primary rays start at the eye instead of where their tile's cone first
    /// meets each instance; the image is the same).
    #[arg(long)]
    pub(crate) no_beams: bool,
    /// Pose every car every frame, also those no ray of the frame can reach (by default they
    /// are left as they were; the image is the same).
    #[arg(long)]
    pub(crate) pose_all: bool,
}

impl Switches {
    pub(crate) fn features(&self) -> Features {
        Features {
            cull: !self.no_cull,
            sort: !self.no_sort,
            bvh: !self.no_bvh,
            hit_buffer: !self.no_hit_buffer,
            shadows: !self.no_shadows,
            beams: !self.no_beams,
            pose_seen: !self.pose_all,
        }
    }
}

#[derive(Args, Clone)]
pub(crate) struct BenchArgs {
    #[command(flatten)]
    pub(crate) source: SourceArgs,
    /// Scenario families: paper (static vs animated vs optimized), instances, resolution,
    /// depth (LOD error vs time), splat (square splats vs ray tracing over cars and voxel
    /// counts, CPU), cast (a library caller's camera and ambient-occlusion rays through the
    /// scene caster), peers (Embree / parry3d; needs `--features peers`), gi-scaling
    /// (voxel transformation vs re-voxelization), gi-volume (dense vs sparse GI volume: time and
    /// memory), gi-accuracy (GI knobs vs the path-traced box; writes docs/accuracy.md).
    #[arg(long, value_delimiter = ',', default_value = "paper,instances,resolution,depth")]
    pub(crate) scenarios: Vec<String>,
    /// Backends to run every scenario on: cpu, gpu, auto (gpu is skipped with a note when there is no adapter).
    #[arg(long, value_delimiter = ',', env = "VOXRAY_BACKEND", default_value = "auto")]
    pub(crate) backends: Vec<voxray::backend::BackendKind>,
    /// Untimed warm-up frames before each measurement: the clip's lead-in up to its time 0,
    /// so that every timed frame moves.
    #[arg(long, default_value_t = 3)]
    pub(crate) warmup: usize,
    /// Timed frames per measurement (paper, resolution, depth, peers, and the instance
    /// sweep's BVH points).
    #[arg(long, default_value_t = 30, value_parser = clap::value_parser!(u64).range(1..=100_000))]
    pub(crate) frames: u64,
    /// Image width of the paper, depth and peers scenarios.
    #[arg(long, default_value_t = 1280)]
    pub(crate) width: u32,
    /// Image height of the paper, depth and peers scenarios.
    #[arg(long, default_value_t = 768)]
    pub(crate) height: u32,
    /// Car counts of the instance sweep (8 instances per car).
    #[arg(long, value_delimiter = ',', default_value = "1,10,100,1000,10000")]
    pub(crate) sweep_cars: Vec<usize>,
    /// Timed frames per instance-sweep point with depth-sorted spheres (the BVH points time
    /// --frames)
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u64).range(1..=100_000))]
    pub(crate) sweep_frames: u64,
    /// Who poses the instance sweep's cars on the GPU backend (its BVH points): `gpu`, the
    /// frame's own passes (the host only sets the time), or `host`, as the CPU does (the
    /// cars seen posed, their instances prepared and uploaded, the tree refitted)
    #[arg(long, value_enum, default_value = "gpu")]
    pub(crate) crowd_posing: CrowdPosing,
    /// Image width of the instance sweep.
    #[arg(long, default_value_t = 320)]
    pub(crate) sweep_width: u32,
    /// Image height of the instance sweep.
    #[arg(long, default_value_t = 192)]
    pub(crate) sweep_height: u32,
    /// Image sizes of the resolution sweep, WxH.
    #[arg(long, value_delimiter = ',', default_value = "320x192,640x384,1280x768,1920x1152")]
    pub(crate) resolutions: Vec<String>,
    /// LOD levels of the depth sweep (default: the three levels above full depth).
    #[arg(long, value_delimiter = ',')]
    pub(crate) lod_levels: Vec<u32>,
    /// Folder for bench.json and bench.csv (records of earlier runs for other backends or scenarios are kept).
    #[arg(long, default_value = "docs/data")]
    pub(crate) out_dir: PathBuf,
    /// Folder for the PNG charts [default: docs/images; with --no-docs, --out-dir, so that
    /// the charts the docs show are not redrawn from records they do not show].
    #[arg(long)]
    pub(crate) charts_dir: Option<PathBuf>,
    /// Markdown file whose generated section is rewritten from the records.
    #[arg(long, default_value = "docs/benchmarks.md")]
    pub(crate) docs: PathBuf,
    /// Do not touch the Markdown files, nor the charts they show (see --charts-dir).
    #[arg(long)]
    pub(crate) no_docs: bool,
    /// Measure nothing: redraw the tables and charts from the records in --out-dir.
    #[arg(long)]
    pub(crate) report_only: bool,
    /// GI scaling scenario: moving car counts.
    #[arg(long, value_delimiter = ',', default_value = "1,16,64,256")]
    pub(crate) gi_cars: Vec<usize>,
    /// GI scaling scenario: world volume cells per side (a power of two).
    #[arg(long, default_value_t = 128)]
    pub(crate) gi_res: u32,
    /// GI scenarios: timed runs per setting (the median is kept).
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u64).range(1..=1000))]
    pub(crate) gi_repeats: u64,
    /// GI accuracy scenario: path-traced reference samples per pixel.
    #[arg(long, default_value_t = 512)]
    pub(crate) spp: u32,
    /// GI accuracy scenario: image size.
    #[arg(long, default_value = "160x120")]
    pub(crate) accuracy_size: String,
    /// GI accuracy scenario: the Markdown file whose generated section is rewritten.
    #[arg(long, default_value = "docs/accuracy.md")]
    pub(crate) accuracy_docs: PathBuf,
    /// Forget earlier records instead of merging this run into them.
    #[arg(long)]
    pub(crate) fresh: bool,
}

#[derive(Args, Clone)]
pub(crate) struct DemoArgs {
    #[command(flatten)]
    pub(crate) source: SourceArgs,
    /// Window width.
    #[arg(long, default_value_t = 1280)]
    pub(crate) width: u32,
    /// Window height.
    #[arg(long, default_value_t = 768)]
    pub(crate) height: u32,
    /// Primary visibility at start: trace or splat (switchable in the panel).
    #[arg(long, default_value = "trace", value_parser = ["trace", "splat"])]
    pub(crate) renderer: String,
    /// GPU splats at start: compute or quads (switchable in the panel; the same image).
    #[arg(long, default_value = "compute", value_parser = ["compute", "quads"])]
    pub(crate) splat_draw: String,
    /// Draw this many frames (the clip advances 1/30 s per frame), then stop with --exit.
    #[arg(long)]
    pub(crate) frames: Option<u64>,
    /// Quit after --frames.
    #[arg(long, requires = "frames")]
    pub(crate) exit: bool,
    /// Write the last frame (and each P press) to this PNG.
    #[arg(long)]
    pub(crate) screenshot: Option<PathBuf>,
    /// Lights JSON (as `render --lights-json`; docs/lights.md). Default: afternoon sun and a pale sky.
    #[arg(long)]
    pub(crate) lights_json: Option<PathBuf>,
    /// Cars, each on its own figure-eight.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub(crate) cars: u32,
    /// Keep the car(s) in place (wheels, steering and doors still move).
    #[arg(long)]
    pub(crate) in_place: bool,
    /// No ground.
    #[arg(long)]
    pub(crate) no_ground: bool,
    #[command(flatten)]
    pub(crate) switches: Switches,
    /// Start with voxel-transformation GI on (on the backend that renders; switchable in the panel).
    #[arg(long)]
    pub(crate) gi: bool,
    /// Where GI's diffuse light is gathered at start: pixels, half or caches (radiance caches
    /// with their default knobs; switchable in the panel).
    #[arg(long, default_value = "half")]
    pub(crate) gi_gather: voxray::render::Gather,
    /// Where to render: cpu, gpu or auto (the GPU on a hardware adapter, else the CPU).
    #[arg(long, env = "VOXRAY_BACKEND", default_value = "auto")]
    pub(crate) backend: voxray::backend::BackendKind,
    /// GPU renderer: read every frame back whole and present it through the host, as before
    /// frames stayed on the GPU (for comparisons; the default draws the GPU's radiance
    /// buffer directly).
    #[arg(long)]
    pub(crate) gpu_read_back: bool,
    /// GPU renderer: count each frame's statistics on the GPU for the panel (32 bytes and the
    /// pass times read back a frame; switchable in the panel).
    #[arg(long)]
    pub(crate) gpu_stats: bool,
}

#[derive(Args)]
pub(crate) struct VoxelizeArgs {
    #[command(flatten)]
    pub(crate) source: SourceArgs,
    /// Where to write <part>.svo files.
    #[arg(long, default_value = "svo")]
    pub(crate) out_dir: PathBuf,
}

/// Who poses the instance sweep's cars on the GPU backend (`voxray bench --crowd-posing`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum CrowdPosing {
    /// The frame's own passes (`gpu::crowd`).
    Gpu,
    /// The host, as for the CPU backend.
    Host,
}
