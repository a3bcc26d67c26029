//! Voxel-transformation GI on the GPU: the WGSL twins of `gi::volume` (transformation with
//! fixed-point atomics, `wgsl/gi_transform.wgsl`), `gi::sparse` (`wgsl/gi_sparse_cell.wgsl`),
//! `gi::inject` and `gi::cone` (`wgsl/gi_trace.wgsl`, part of the tracer's module so injection
//! reuses its shadow rays) and `gi::levels` (`wgsl/gi_levels.wgsl`). Caches are built on the CPU
//! once per part and uploaded once; each frame uploads only one job per instance (its matrices)
//! and runs transform → inject → levels → cone-traced shading.
//!
//! Neither volume needs a readback. The sparse one sizes its brick pool from a bound on the
//! bricks the moved voxels can touch, allocates them on the GPU within the frame and copies
//! the count into the uniforms of the passes that need it (`sparse`); only a volume whose
//! bound is too loose to allocate reads the count back (the pool then grows with a quarter's
//! slack, so it is reallocated only when the surfaces in the volume grow past it).

use super::context::{GpuContext, GpuError};
use super::layout::{GpuGiFrame, GpuGiJob, GpuGiLevelStep, GpuGiSplat};
use super::prelude::binding as b;
use super::renderer::{ensure, read};
use crate::gi::levels::{Level, Levels};
use crate::gi::shade::plan_volume;
use crate::gi::shade::LevelStore;
use crate::gi::sparse::BRICK;
use crate::gi::{CacheVoxel, Filter, GiCaches, GiError, GiReuse, GiSettings, Layout, Volume, VolumeKey, VolumeSpec};
use crate::scene::{Camera, Lights, Scene};
use crate::svo::PartId;
use glam::{DAffine3, DMat3, DVec3, Vec3, Vec4};
use std::collections::HashMap;

mod bounces;
mod capture;
mod frame;
mod sparse;
mod texture;
mod volume;

pub use capture::GiCapture;
use frame::{bind_cached, GiFrameBuffers};
use sparse::{brick_bound, job_cells, sparse_bind, Allocation, CoordBox, SparseTables, BRICK_BYTES, UNREAD_LIMIT};
use texture::{level_texture, LevelTexture};
use volume::{level_step_bind_with, VolumeBuffers};

/// Fixed-point scale of occupancy, weighted albedo and weighted normal sums (per unit weight);
/// the WGSL side is `wgsl/shared/gi_fixed.wgsl`.
pub const FIX: f64 = 65536.0;

/// Fixed-point scale of weighted emission (each voxel's at most [`crate::gi::volume::GI_MAX_EMISSION`]).
pub const EMIT_FIX: f64 = 4096.0;

/// Fixed-point scale of the weight that fell outside the volume.
pub const OUT_FIX: f64 = 256.0;

/// Words per cell in the accumulation buffer.
pub(crate) const STRIDE: usize = 10;

/// Levels the shaders can address (a 512³ volume has 10, a sparse 1024³ one 11).
const MAX_LEVELS: usize = 12;

/// Finest cells per brick.
const BRICK_CELLS: u32 = BRICK * BRICK * BRICK;

/// Brick levels stored per brick (8³, 4³, 2³), as `gi::sparse`.
const BRICK_LEVELS: usize = 3;

/// Fewest bricks the pool holds.
const MIN_BRICKS: u32 = 8;

/// The transformation shader into the dense volume.
pub fn transform_source() -> String {
    transform_source_for(include_str!("../../../wgsl/gi_dense_cell.wgsl"))
}

/// The transformation shader into the sparse volume (with its allocate pass).
pub fn sparse_transform_source() -> String {
    transform_source_for(include_str!("../../../wgsl/gi_sparse_cell.wgsl"))
}

fn transform_source_for(cells: &str) -> String {
    [
        &super::prelude::prelude(),
        include_str!("../../../wgsl/shared/layout.wgsl"),
        include_str!("../../../wgsl/shared/attr.wgsl"),
        include_str!("../../../wgsl/shared/gi_fixed.wgsl"),
        include_str!("../../../wgsl/shared/gi_splat.wgsl"),
        cells,
        include_str!("../../../wgsl/gi_transform.wgsl"),
    ]
    .join("\n")
}

/// Workgroups of 64 threads for `threads` threads, spread over y past 65 535 groups, and the
/// threads per row.
fn flat_groups(threads: u32) -> ((u32, u32), u32) {
    let groups = threads.div_ceil(64);
    let dims = (groups.clamp(1, 65_535), groups.div_ceil(65_535));
    (if threads == 0 { (0, 0) } else { dims }, dims.0 * 64)
}

/// The level-chain shader.
pub fn levels_source() -> String {
    [
        &super::prelude::prelude(),
        include_str!("../../../wgsl/shared/layout.wgsl"),
        include_str!("../../../wgsl/gi_levels.wgsl"),
    ]
    .join("\n")
}

/// What the GPU GI did in the last frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GpuGiStats {
    /// Cache voxels moved.
    pub voxels: u64,
    /// Instances moved (jobs).
    pub jobs: u32,
    /// Volume cells per side.
    pub res: u32,
    /// Levels in the chain.
    pub levels: u32,
    /// Bytes of the GI buffers (voxel pool, accumulation, levels, the sparse tables).
    pub bytes: u64,
    /// What was kept from the frame before (the passes not run).
    pub reuse: GiReuse,
    /// How the volume is stored.
    pub layout: Layout,
    /// Bricks the sparse pool holds (0 for dense): at least the bricks allocated.
    pub brick_capacity: u32,
    /// Bricks allocated, when this frame read the count back (a sparse volume whose bound
    /// was too loose to size the pool by); `GpuGi::read_bricks` reads it on request.
    pub bricks_counted: Option<u32>,
    /// Sparse, volume rebuilt with the count read back: wall-clock milliseconds of that
    /// extra submit and read (outside the GI pass's timestamps; 0 otherwise).
    pub bricks_ms: f64,
}

struct Pool {
    keys: Vec<(PartId, u32)>,
    voxels: wgpu::Buffer,
    /// (first voxel, count) per key.
    ranges: HashMap<(PartId, u32), (u32, u32)>,
    /// The box of the voxels' integer coordinates per key (None: no voxels).
    boxes: HashMap<(PartId, u32), Option<CoordBox>>,
}

/// One frame's GI work, ready to encode.
pub(crate) struct GiWork {
    splat_bind: wgpu::BindGroup,
    splat_groups: (u32, u32),
    /// The cell passes' workgroups (one thread per stored cell).
    cell_groups: (u32, u32),
    /// Sparse: the brick steps down the chain (8³ → 4³ → 2³ → top table) and their workgroups.
    brick_steps: Vec<(wgpu::BindGroup, (u32, u32))>,
    /// Sparse, volume rebuilt: the mark and allocate passes to record first.
    allocation: Option<Allocation>,
    /// Sparse: the uniform buffers and byte offsets that receive the brick count.
    count_to: Vec<(wgpu::Buffer, u64)>,
    /// Whether the chain is copied into the level texture after each levels pass (and the
    /// cones sample it there).
    pub texture: bool,
    /// The chain's coarse levels hold six faces (`GiSettings::anisotropic`).
    pub aniso: bool,
    /// Bind group 1 of the tracer's GI entry points.
    pub group1: wgpu::BindGroup,
    /// The diffuse cones are gathered at half resolution (`gather_half_main` runs first).
    pub half: bool,
    /// Radiance caches: the workgroups of placement (one per tile), cache tracing and
    /// convolution, run before the shading.
    pub caches: Option<[(u32, u32); 3]>,
    spec: VolumeSpec,
    bounces: u32,
    /// The last bounce adds the bounces' tail.
    tail: bool,
    /// Stored cells (where the tail's sums begin in the next level 0's buffer).
    cells: u32,
    /// What this frame does.
    pub stats: GpuGiStats,
}

/// The GPU GI state kept between frames: CPU caches, their upload, pipelines and the volume.
pub(crate) struct GpuGi {
    /// The parts' voxel caches (built on the CPU once).
    pub caches: GiCaches,
    pool: Option<Pool>,
    splat_pipe: wgpu::ComputePipeline,
    levels_pipe: wgpu::ComputePipeline,
    /// One step down an anisotropic chain (six faces per coarse cell).
    levels_aniso_pipe: wgpu::ComputePipeline,
    /// The sparse volume's mark/accumulate and allocate passes, and its brick level steps.
    sparse_splat_pipe: wgpu::ComputePipeline,
    sparse_alloc_pipe: wgpu::ComputePipeline,
    /// Writes the indirect dispatches of the passes over bricks from the count.
    sparse_dispatch_pipe: wgpu::ComputePipeline,
    sparse_layout: wgpu::BindGroupLayout,
    brick_levels_pipe: wgpu::ComputePipeline,
    sparse: Option<SparseTables>,
    /// The copy of a level into the level texture's mip.
    texture_pipe: wgpu::ComputePipeline,
    /// Bound in place of the level texture when the cones read the buffer.
    placeholder_tex: wgpu::TextureView,
    /// The level texture's sampler: trilinear within and linear between mips, a transparent
    /// black border where the device has one.
    sampler: wgpu::Sampler,
    /// Layout of bind group 1 (accumulation, levels, GI uniforms) of the tracer's GI entries.
    pub group1_layout: wgpu::BindGroupLayout,
    volume: Option<VolumeBuffers>,
    /// Bound in place of the bounce buffers when a frame has one bounce (read-write) and of
    /// the sparse tables for a dense volume (read-only).
    placeholder: wgpu::Buffer,
    placeholder_ro: wgpu::Buffer,
    /// What the volume on the GPU was made from, and the bounces (with their cones) its chain
    /// was gathered with, whether it is anisotropic and the emitter samples its cells drew.
    last: Option<(VolumeKey, Lights, crate::gi::shade::ChainKey)>,
    /// Per-frame inputs and bind groups kept between frames.
    kept: GiFrameBuffers,
    /// Most bytes of a brick pool sized by the bound ([`UNREAD_LIMIT`] unless a test lowers it).
    pub(crate) unread_limit: u64,
}

/// The tracer's GI entry points of one plan variant.
pub(crate) struct GiPipelines {
    /// Light injection.
    pub inject: wgpu::ComputePipeline,
    /// Shading with cone tracing.
    pub shade: wgpu::ComputePipeline,
    /// The half-resolution gather's samples, before shading.
    pub gather: wgpu::ComputePipeline,
    /// The radiance caches: placement, tracing, convolution, before shading.
    pub cache_place: wgpu::ComputePipeline,
    /// Their texels' cones.
    pub cache_trace: wgpu::ComputePipeline,
    /// Their mips and irradiance maps.
    pub cache_convolve: wgpu::ComputePipeline,
    /// One more bounce into the next level 0.
    pub bounce: wgpu::ComputePipeline,
    /// The next level 0 into the chain.
    pub commit: wgpu::ComputePipeline,
    /// The bounces' tail factor from the last bounce's sums (one workgroup).
    pub tail: wgpu::ComputePipeline,
    /// The last bounce's level 0 with its tail into the chain.
    pub tail_commit: wgpu::ComputePipeline,
}

/// Row `i` of the affine map (m, t) as xyz = linear, w = translation, in f32.
pub(crate) fn row(m: DMat3, t: DVec3, i: usize) -> [f32; 4] {
    [m.col(0)[i] as f32, m.col(1)[i] as f32, m.col(2)[i] as f32, t[i] as f32]
}

/// The job moving `cache` (its voxels at `range` = (first, count) of the pool) by `world` into
/// `spec`, its threads starting at `first_thread`.
pub(crate) fn transform_job(
    world: &DAffine3,
    cache: &crate::gi::VoxelCache,
    spec: &VolumeSpec,
    range: (u32, u32),
    first_thread: u64,
) -> Result<GpuGiJob, GpuError> {
    crate::gi::volume::check_world(world)?;
    if first_thread + range.1 as u64 >= u32::MAX as u64 {
        let size = first_thread + range.1 as u64;
        return Err(GpuError::TooLarge { what: "the GI voxel transformation", size, limit: u32::MAX as u64 });
    }
    let (m, t) = grid_map(world, cache.corner, cache.voxel_size, spec);
    let n = world.matrix3.inverse().transpose();
    Ok(GpuGiJob {
        grid_x: row(m, t, 0),
        grid_y: row(m, t, 1),
        grid_z: row(m, t, 2),
        normal_x: row(n, DVec3::ZERO, 0),
        normal_y: row(n, DVec3::ZERO, 1),
        normal_z: row(n, DVec3::ZERO, 2),
        voxel_base: range.0,
        voxel_count: range.1,
        first_thread: first_thread as u32,
        pad: 0,
    })
}

/// The uniforms of a one-thread-per-item pass over `threads` items of `jobs` jobs, and its
/// workgroups (64 threads each, spread over y past 65 535 groups).
pub(crate) fn splat_dispatch(
    res: u32,
    jobs: usize,
    threads: u64,
    filter: Filter,
) -> Result<(GpuGiSplat, (u32, u32)), GpuError> {
    if threads >= u32::MAX as u64 {
        return Err(GpuError::TooLarge { what: "the GI volume pass", size: threads, limit: u32::MAX as u64 });
    }
    let (dims, row_threads) = flat_groups(threads as u32);
    let splat = GpuGiSplat {
        res,
        jobs: jobs as u32,
        threads: threads as u32,
        row_threads,
        nearest: (filter == Filter::Nearest) as u32,
        ..Default::default()
    };
    Ok((splat, dims))
}

/// The map integer cache coordinate → grid coordinate of `spec` (cell c's centre at c) for a
/// cache with corner `corner` and voxel edge `voxel` moved by `world`, composed in f64.
pub fn grid_map(world: &DAffine3, corner: Vec3, voxel: f32, spec: &VolumeSpec) -> (DMat3, DVec3) {
    let vs = voxel as f64;
    let lin = world.matrix3 * (vs / spec.cell);
    let origin = world.transform_point3(corner.as_dvec3() + DVec3::splat(0.5 * vs));
    (lin, (origin - spec.min) / spec.cell - DVec3::splat(0.5))
}

/// The volume in an accumulation buffer read back (the fixed-point sums as floats) and the
/// weight that fell outside it.
pub fn volume_from_accum(accum: &[u32], spec: VolumeSpec) -> (Volume, f64) {
    let mut volume = Volume::new(spec);
    let fix = |w: u32, scale: f64| (w as i32) as f64 / scale;
    for (i, c) in accum.chunks_exact(STRIDE).enumerate().take(volume.occupancy.len()) {
        let v3 = |k: usize, scale: f64| {
            Vec3::new(fix(c[k], scale) as f32, fix(c[k + 1], scale) as f32, fix(c[k + 2], scale) as f32)
        };
        volume.occupancy[i] = (c[0] as f64 / FIX) as f32;
        volume.albedo[i] = v3(1, FIX);
        volume.normal[i] = v3(4, FIX);
        volume.emission[i] = v3(7, EMIT_FIX);
    }
    let outside = accum.last().copied().unwrap_or(0) as f64 / OUT_FIX;
    (volume, outside)
}

fn gi_layout_entry(binding: u32, ty: wgpu::BufferBindingType) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer { ty, has_dynamic_offset: false, min_binding_size: None },
        count: None,
    }
}

impl GpuGi {
    pub(crate) fn new(ctx: &GpuContext) -> GpuGi {
        let device = &ctx.device;
        let make_with = |label: &str, src: String, entries: &[&str], layout: Option<&wgpu::PipelineLayout>| {
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(src.into()),
            });
            entries
                .iter()
                .map(|entry| {
                    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                        label: Some(entry),
                        layout,
                        module: &module,
                        entry_point: Some(entry),
                        compilation_options: Default::default(),
                        cache: None,
                    })
                })
                .collect::<Vec<_>>()
        };
        let make = |label: &str, src: String, entry: &str| make_with(label, src, &[entry], None).remove(0);
        // The sparse passes share one bind group, so their layout is explicit.
        let rw = wgpu::BufferBindingType::Storage { read_only: false };
        let ro = wgpu::BufferBindingType::Storage { read_only: true };
        let sparse_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("gi sparse volume"),
            entries: &[
                gi_layout_entry(0, ro),
                gi_layout_entry(1, ro),
                gi_layout_entry(2, rw),
                gi_layout_entry(3, wgpu::BufferBindingType::Uniform),
                gi_layout_entry(4, rw),
                gi_layout_entry(5, rw),
                gi_layout_entry(6, rw),
                gi_layout_entry(7, rw),
            ],
        });
        let sparse_pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("gi sparse volume"),
            bind_group_layouts: &[Some(&sparse_layout)],
            immediate_size: 0,
        });
        let mut sparse_pipes = make_with(
            "gi_sparse_cell.wgsl",
            sparse_transform_source(),
            &["splat_main", "alloc_main", "dispatch_main"],
            Some(&sparse_pl),
        );
        let sparse_dispatch_pipe = sparse_pipes.remove(2);
        let sparse_alloc_pipe = sparse_pipes.remove(1);
        let sparse_splat_pipe = sparse_pipes.remove(0);
        let group1_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("gi (tracer group 1)"),
            entries: &[
                gi_layout_entry(b::GI_ACCUM, wgpu::BufferBindingType::Storage { read_only: true }),
                gi_layout_entry(b::GI_LEVELS, wgpu::BufferBindingType::Storage { read_only: false }),
                gi_layout_entry(b::GI_FRAME, wgpu::BufferBindingType::Uniform),
                gi_layout_entry(b::GI_DIRECT, rw),
                gi_layout_entry(b::GI_NEXT, rw),
                gi_layout_entry(b::GI_TOP, ro),
                gi_layout_entry(b::GI_BRICK_TOP, ro),
                gi_layout_entry(b::GI_SAMPLES, rw),
                gi_layout_entry(b::GI_CACHE_POINTS, rw),
                gi_layout_entry(b::GI_CACHE_MAPS, rw),
                wgpu::BindGroupLayoutEntry {
                    binding: b::GI_TEX,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D3,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: b::GI_SAMPLER,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let border = device.features().contains(wgpu::Features::ADDRESS_MODE_CLAMP_TO_BORDER);
        let address = if border { wgpu::AddressMode::ClampToBorder } else { wgpu::AddressMode::ClampToEdge };
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("gi levels"),
            address_mode_u: address,
            address_mode_v: address,
            address_mode_w: address,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Linear,
            border_color: border.then_some(wgpu::SamplerBorderColor::TransparentBlack),
            ..Default::default()
        });
        let placeholder_tex = level_texture(device, 1, 1).create_view(&Default::default());
        let placeholder_of = |label| {
            ctx.buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: 16,
                usage: wgpu::BufferUsages::STORAGE,
                mapped_at_creation: false,
            })
        };
        GpuGi {
            caches: GiCaches::new(),
            pool: None,
            splat_pipe: make("gi_transform.wgsl", transform_source(), "splat_main"),
            levels_pipe: make("gi_levels.wgsl", levels_source(), "levels_main"),
            levels_aniso_pipe: make("gi_levels.wgsl", levels_source(), "levels_aniso_main"),
            sparse_splat_pipe,
            sparse_alloc_pipe,
            sparse_dispatch_pipe,
            sparse_layout,
            brick_levels_pipe: make("gi_levels.wgsl", levels_source(), "brick_levels_main"),
            sparse: None,
            texture_pipe: make("gi_levels.wgsl", levels_source(), "texture_main"),
            placeholder_tex,
            sampler,
            group1_layout,
            volume: None,
            placeholder: placeholder_of("gi bounce placeholder"),
            placeholder_ro: placeholder_of("gi sparse table placeholder"),
            last: None,
            kept: GiFrameBuffers::default(),
            unread_limit: UNREAD_LIMIT,
        }
    }

    /// Forgets what the last frame built, so the next one rebuilds the volume (for timing the
    /// whole pass on a still scene).
    pub(crate) fn forget_last_frame(&mut self) {
        self.last = None;
    }

    /// Uploads the caches of `keys` if they are not the ones on the GPU.
    fn upload_pool(&mut self, ctx: &GpuContext, scene: &Scene, keys: Vec<(PartId, u32)>) -> Result<(), GpuError> {
        if self.pool.as_ref().is_some_and(|p| p.keys == keys) {
            return Ok(());
        }
        let mut all: Vec<CacheVoxel> = Vec::new();
        let mut ranges = HashMap::new();
        let mut boxes = HashMap::new();
        for (p, (id, level)) in scene.parts.iter().zip(&keys) {
            let key = (id.clone(), *level);
            if ranges.contains_key(&key) {
                continue;
            }
            let cache = self.caches.get(p, *level)?;
            ranges.insert(key.clone(), (all.len() as u32, cache.voxels.len() as u32));
            let coords = cache.voxels.iter().map(CacheVoxel::coord);
            let b = coords.fold(None, |b: Option<CoordBox>, c| {
                Some(b.map_or((c, c), |(lo, hi)| {
                    ([0, 1, 2].map(|i| lo[i].min(c[i])), [0, 1, 2].map(|i| hi[i].max(c[i])))
                }))
            });
            boxes.insert(key, b);
            all.extend_from_slice(&cache.voxels);
        }
        if all.len() >= u32::MAX as usize {
            return Err(GpuError::TooLarge {
                what: "the GI voxel pool",
                size: all.len() as u64 * 16,
                limit: u32::MAX as u64,
            });
        }
        if all.is_empty() {
            all.push(CacheVoxel::default());
        }
        ctx.check_binding("the GI voxel pool", std::mem::size_of_val(all.as_slice()) as u64)?;
        let voxels = ctx.buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("gi voxels"),
            contents: bytemuck::cast_slice(&all),
            usage: wgpu::BufferUsages::STORAGE,
        });
        self.pool = Some(Pool { keys, voxels, ranges, boxes });
        Ok(())
    }

    /// Places this frame's volume, uploads what changed and the instances' jobs; for a sparse
    /// volume to rebuild, also sizes its brick pool (reading the count back only where the
    /// bound on it is too loose).
    pub(crate) fn prepare(
        &mut self,
        ctx: &GpuContext,
        scene: &Scene,
        camera: &Camera,
        lights: &Lights,
        s: &GiSettings,
    ) -> Result<GiWork, GpuError> {
        let cones = s.cones.validated().map_err(|e| GiError::Settings(e.to_string()))?;
        let half = s.gather == crate::render::Gather::Half;
        let caches = match s.gather {
            crate::render::Gather::Caches(c) => Some(c.validated().map_err(GiError::Settings)?),
            _ => None,
        };
        let layout = s.layout();
        let (spec, levels_of) = plan_volume(scene, camera, s, &mut self.caches)?;
        let key = VolumeKey::new(scene, spec, layout, s.filter, &levels_of);
        // Decided before any upload: a changed pool or volume size changes the key too.
        let mut reuse = GiReuse::decide(self.last.as_ref().map(|(k, l, _)| (k, l)), &key, lights);
        let bounce_key = s.chain_key();
        if reuse == GiReuse::Levels && self.last.as_ref().is_some_and(|l| l.2 != bounce_key) {
            reuse = GiReuse::Volume; // the chain was gathered with other bounces
        }
        let texture = s.levels == LevelStore::Texture;
        if self.volume.as_ref().is_some_and(|v| v.texture.is_some() != texture || v.aniso != s.anisotropic) {
            reuse = GiReuse::Nothing; // the buffers are allocated afresh
        }
        self.last = None; // until this frame's passes are encoded
        let keys: Vec<(PartId, u32)> = scene.parts.iter().zip(&levels_of).map(|(p, &l)| (PartId::of(p), l)).collect();
        self.upload_pool(ctx, scene, keys.clone())?;
        let pool = self.pool.as_ref().ok_or_else(|| GpuError::Device("GI voxel pool missing".into()))?;
        let mut jobs = Vec::new();
        let mut cell_boxes = Vec::new();
        let mut threads = 0u64;
        for (i, inst) in scene.instances().iter().enumerate() {
            let key = &keys[inst.part];
            let range = pool.ranges[key];
            let cache = self.caches.get(&scene.parts[inst.part], key.1)?;
            let job = transform_job(&scene.world(i), cache, &spec, range, threads)?;
            if let (true, Some(Some(coords))) = (range.1 > 0, pool.boxes.get(key)) {
                if layout == Layout::Sparse {
                    cell_boxes.push(job_cells(&job, *coords));
                }
                jobs.push(job);
                threads += range.1 as u64;
            }
        }
        let (splat, splat_groups) = splat_dispatch(spec.res, jobs.len(), threads, s.filter)?;
        let device = &ctx.device;
        let jobs_len = jobs.len();
        if jobs.is_empty() {
            jobs.push(GpuGiJob::default());
        }
        ctx.check_binding("the GI jobs", std::mem::size_of_val(jobs.as_slice()) as u64)?;
        let jobs_buf = GiFrameBuffers::write(
            ctx,
            &mut self.kept.jobs,
            "gi jobs",
            bytemuck::cast_slice(&jobs),
            wgpu::BufferUsages::STORAGE,
        )?;
        let voxels = pool.voxels.clone();
        // The sparse volume's bricks: allocated on the GPU when the volume is rebuilt, kept
        // otherwise. The pool is sized by the bound on what the moved voxels can touch, or,
        // where that bound is too loose to allocate, by the count read back; it grows with a
        // quarter's slack and shrinks when 4× too large.
        let (mut capacity, mut bricks_ms, mut allocation) = (0, 0.0, None);
        if layout == Layout::Sparse {
            self.sparse_tables(ctx, spec.res)?;
            // The slack stops where it alone would break the device's binding limit.
            let limit = ctx.limits.max_storage_buffer_binding_size.min(ctx.limits.max_buffer_size);
            let fit = (limit.saturating_sub(4) / (BRICK_CELLS as u64 * STRIDE as u64 * 4)).min(u32::MAX as u64) as u32;
            let want = |bricks: u32| (bricks + bricks / 4).max(MIN_BRICKS).min(fit.max(bricks));
            let kept_capacity = self.volume.as_ref().filter(|v| v.layout == Layout::Sparse && v.res == spec.res);
            let kept_capacity = kept_capacity.map(|v| v.capacity);
            if kept_capacity.is_none() {
                reuse = GiReuse::Nothing; // no bricks to keep
            }
            capacity = match kept_capacity.filter(|_| reuse != GiReuse::Nothing) {
                Some(c) => c,
                None => {
                    let alloc = self.allocation(ctx, &voxels, &jobs_buf, splat, splat_groups)?;
                    let bound = brick_bound(&cell_boxes, spec.res);
                    let counted = if bound <= fit && bound as u64 * BRICK_BYTES <= self.unread_limit {
                        None
                    } else {
                        let (n, ms) = self.count_bricks(ctx, &alloc)?;
                        bricks_ms = ms;
                        Some(n)
                    };
                    if let Some(t) = self.sparse.as_mut() {
                        t.counted = counted;
                    }
                    allocation = Some(alloc);
                    let need = counted.unwrap_or(bound);
                    match kept_capacity {
                        Some(c) if c >= need && c <= 4 * want(need) => c,
                        _ => want(need),
                    }
                }
            };
        }
        self.volume_buffers(ctx, layout, spec.res, capacity, texture, s.anisotropic)?;
        if s.bounces > 1 {
            self.bounce_buffers(ctx)?;
        }
        let (pool, vol) = match (&self.pool, &self.volume) {
            (Some(p), Some(v)) => (p, v),
            _ => return Err(GpuError::Device("GI buffers missing".into())),
        };
        let tables = self.sparse.as_ref().filter(|_| layout == Layout::Sparse);
        // The passes over bricks are dispatched for the whole pool and stop at the count the
        // GPU copies into their uniforms (`count_to`); the host writes the count it knows.
        let bricks = tables.and_then(|t| t.counted).unwrap_or(0);
        let cells = volume::stored_cells(layout, spec.res, capacity);
        if cells >= u32::MAX as u64 {
            return Err(GpuError::TooLarge { what: "the GI cell passes", size: cells, limit: u32::MAX as u64 });
        }
        let (cell_groups, cell_row) = flat_groups(cells as u32);
        let quad = |v: &[u32], k: usize| {
            let mut q = [0u32; 4];
            for (j, slot) in q.iter_mut().enumerate() {
                *slot = v.get(4 * k + j).copied().unwrap_or(0);
            }
            q
        };
        let rel = spec.min - camera.eye;
        let gframe = GpuGiFrame {
            min_cell: [rel.x as f32, rel.y as f32, rel.z as f32, spec.cell as f32],
            offsets_a: quad(&vol.offsets, 0),
            offsets_b: quad(&vol.offsets, 1),
            offsets_c: quad(&vol.offsets, 2),
            res_a: quad(&vol.resolutions, 0),
            res_b: quad(&vol.resolutions, 1),
            res_c: quad(&vol.resolutions, 2),
            res: spec.res,
            levels: vol.offsets.len() as u32,
            cones: cones.diffuse_cones,
            bounces: s.bounces,
            spread: (2.0 * (cones.aperture_deg.to_radians() * 0.5).tan()) as f32,
            tilt: cones.aperture_deg.to_radians().min(80f64.to_radians()) as f32,
            max_distance: if cones.max_distance.is_finite() { cones.max_distance as f32 } else { f32::MAX },
            cells: cells as u32,
            row_threads: cell_row,
            top_res: spec.res / BRICK,
            tex_size: vol.texture.as_ref().map_or(0, |t| t.size),
            specular_cone: cones.specular_cone as u32,
            bricks,
            half: half as u32,
            half_width: camera.width.div_ceil(2),
            cell_samples: s.cell_light_samples,
            tail: s.tail() as u32,
            ..Default::default()
        };
        // The caches' slots (per tile) and maps: the texels, the mips down to 1², the
        // irradiance map at half the resolution.
        let mut gframe = gframe;
        let cache_dispatch = match caches {
            Some(c) => {
                let tiles_x = camera.width.div_ceil(c.tile);
                let tiles = tiles_x * camera.height.div_ceil(c.tile);
                let slots = tiles * c.per_tile;
                let mips: u32 = (0..=c.res.trailing_zeros()).map(|k| (c.res >> k) * (c.res >> k)).sum();
                let irr = (c.res / 2).max(2);
                let stride = mips + irr * irr;
                const ROW: u32 = 1024 * 64;
                let dims = |threads: u64| (threads.div_ceil(64).min(1024) as u32, threads.div_ceil(ROW as u64) as u32);
                // Tracing: a thread per texel; convolution: a workgroup per cache.
                let trace = dims(slots as u64 * (c.res * c.res) as u64);
                let convolve = (slots.min(65_535), slots.div_ceil(65_535));
                if trace.1 > 65_535 || convolve.1 > 65_535 {
                    return Err(GpuError::TooLarge {
                        what: "the GI caches' passes",
                        size: slots as u64,
                        limit: 65_535,
                    });
                }
                gframe.caches = 1;
                gframe.cache_tile = c.tile;
                gframe.cache_res = c.res;
                gframe.cache_radius = c.radius;
                gframe.cache_per_tile = c.per_tile;
                gframe.cache_tiles_x = tiles_x;
                gframe.cache_slots = slots;
                gframe.cache_stride = stride;
                gframe.cache_placement = (c.placement == crate::render::radiance_cache::Placement::Even) as u32;
                let aperture = c.cone_aperture();
                gframe.cache_spread = (2.0 * (aperture * 0.5).tan()) as f32;
                gframe.cache_row_threads = ROW;
                Some((slots as u64, stride as u64, [(tiles.min(65_535), tiles.div_ceil(65_535)), trace, convolve]))
            }
            None => None,
        };
        let kept = &mut self.kept;
        let uniform = wgpu::BufferUsages::UNIFORM;
        let (cache_points, cache_maps) = match cache_dispatch {
            Some((slots, stride, _)) => {
                let (points, maps) = (slots * 32, slots * stride * 16);
                ctx.check_binding("the GI caches' maps", maps)?;
                ctx.check_memory(
                    || format!("{slots} GI cache slots of {stride} texels"),
                    points + maps,
                    "use fewer or smaller caches (--gi-cache-count, --gi-cache-res, --gi-cache-tile)",
                )?;
                let usage = wgpu::BufferUsages::STORAGE;
                ensure(ctx, &mut kept.cache_points, "gi cache points", points, false, usage);
                ensure(ctx, &mut kept.cache_maps, "gi cache maps", maps, false, usage);
                let missing = || GpuError::Device("gi cache buffers missing".into());
                (kept.cache_points.clone().ok_or_else(missing)?, kept.cache_maps.clone().ok_or_else(missing)?)
            }
            None => (self.placeholder.clone(), self.placeholder.clone()),
        };
        // One vec4 per 2×2 block of pixels with the half-resolution gather.
        let samples = if half {
            let n = camera.width.div_ceil(2) as u64 * camera.height.div_ceil(2) as u64;
            ctx.check_binding("the GI gather's samples", n * 16)?;
            ctx.check_memory(
                || format!("the half-resolution GI gather's samples for a {}×{} frame", camera.width, camera.height),
                n * 16,
                "lower the resolution, use --gi-gather pixels, or raise the memory budget",
            )?;
            ensure(ctx, &mut kept.samples, "gi gather samples", n * 16, false, wgpu::BufferUsages::STORAGE);
            kept.samples.clone().ok_or_else(|| GpuError::Device("gi gather samples missing".into()))?
        } else {
            self.placeholder.clone()
        };
        let splat_buf = GiFrameBuffers::write(ctx, &mut kept.splat, "gi splat", bytemuck::bytes_of(&splat), uniform)?;
        let frame_buf = GiFrameBuffers::write(ctx, &mut kept.frame, "gi frame", bytemuck::bytes_of(&gframe), uniform)?;
        let splat_key = vec![pool.voxels.clone(), jobs_buf.clone(), vol.accum.clone(), splat_buf.clone()];
        let splat_bind = match tables {
            Some(t) => {
                let key = [splat_key, vec![t.top.clone(), t.brick_top.clone()]].concat();
                let bufs = [&pool.voxels, &jobs_buf, &vol.accum, &splat_buf];
                bind_cached(&mut kept.binds, ("sparse splat", 0), key, || {
                    sparse_bind(ctx, &self.sparse_layout, bufs, t)
                })
            }
            None => bind_cached(&mut kept.binds, ("splat", 0), splat_key, || {
                device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("gi splat"),
                    layout: &self.splat_pipe.get_bind_group_layout(0),
                    entries: &[
                        wgpu::BindGroupEntry { binding: 0, resource: pool.voxels.as_entire_binding() },
                        wgpu::BindGroupEntry { binding: 1, resource: jobs_buf.as_entire_binding() },
                        wgpu::BindGroupEntry { binding: 2, resource: vol.accum.as_entire_binding() },
                        wgpu::BindGroupEntry { binding: 3, resource: splat_buf.as_entire_binding() },
                    ],
                })
            }),
        };
        // Sparse: 8³ → 4³ → 2³ within each brick, then 2³ → the top table's level.
        kept.brick_steps.resize(BRICK_LEVELS, None);
        let mut brick_steps = Vec::new();
        let mut count_to = Vec::new();
        if tables.is_some() {
            count_to.push((frame_buf.clone(), std::mem::offset_of!(GpuGiFrame, bricks) as u64));
        }
        if let Some(t) = tables {
            for l in 1..=BRICK_LEVELS {
                let side = BRICK >> l;
                let (groups, row_threads) = flat_groups(capacity * side.pow(3));
                let step = GpuGiLevelStep {
                    src_offset: vol.offsets[l - 1],
                    src_res: BRICK >> (l - 1),
                    dst_offset: vol.offsets[l],
                    dst_res: side,
                    bricks,
                    row_threads,
                    ..Default::default()
                };
                let ubuf = GiFrameBuffers::write(
                    ctx,
                    &mut kept.brick_steps[l - 1],
                    "gi brick step",
                    bytemuck::bytes_of(&step),
                    uniform,
                )?;
                let key = vec![vol.levels.clone(), ubuf.clone(), t.brick_top.clone()];
                let bind = bind_cached(&mut kept.binds, ("brick step", l), key, || {
                    level_step_bind_with(ctx, &self.brick_levels_pipe, &vol.levels, &ubuf, Some(&t.brick_top))
                });
                count_to.push((ubuf, std::mem::offset_of!(GpuGiLevelStep, bricks) as u64));
                brick_steps.push((bind, groups));
            }
        }
        let (direct, next) = match (&vol.bounce, s.bounces > 1) {
            (Some((d, n)), true) => (d, n),
            _ => (&self.placeholder, &self.placeholder),
        };
        let (top, brick_top) = match tables {
            Some(t) => (&t.top, &t.brick_top),
            None => (&self.placeholder_ro, &self.placeholder_ro),
        };
        // The level texture is made with the volume's buffers, so the levels buffer in the key
        // stands for it too.
        let group1_key =
            [&vol.accum, &vol.levels, &frame_buf, direct, next, top, brick_top, &samples, &cache_points, &cache_maps]
                .map(|b| b.clone())
                .to_vec();
        let group1 = bind_cached(&mut kept.binds, ("group 1", vol.texture.is_some() as usize), group1_key, || {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("gi (tracer group 1)"),
                layout: &self.group1_layout,
                entries: &[
                    wgpu::BindGroupEntry { binding: b::GI_ACCUM, resource: vol.accum.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::GI_LEVELS, resource: vol.levels.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::GI_FRAME, resource: frame_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::GI_DIRECT, resource: direct.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::GI_NEXT, resource: next.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::GI_TOP, resource: top.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::GI_BRICK_TOP, resource: brick_top.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::GI_SAMPLES, resource: samples.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::GI_CACHE_POINTS, resource: cache_points.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::GI_CACHE_MAPS, resource: cache_maps.as_entire_binding() },
                    wgpu::BindGroupEntry {
                        binding: b::GI_TEX,
                        resource: wgpu::BindingResource::TextureView(
                            vol.texture.as_ref().map_or(&self.placeholder_tex, |t| &t.view),
                        ),
                    },
                    wgpu::BindGroupEntry {
                        binding: b::GI_SAMPLER,
                        resource: wgpu::BindingResource::Sampler(&self.sampler),
                    },
                ],
            })
        });
        let stats = GpuGiStats {
            voxels: threads,
            jobs: jobs_len as u32,
            res: spec.res,
            levels: vol.offsets.len() as u32,
            bytes: pool.voxels.size()
                + cache_dispatch.map_or(0, |_| cache_points.size() + cache_maps.size())
                + vol.accum.size()
                + vol.levels.size()
                + jobs_buf.size()
                + vol.bounce.as_ref().map_or(0, |(d, n)| d.size() + n.size())
                + tables.map_or(0, |t| t.top.size() + t.brick_top.size() + t.counters.size())
                + vol.texture.as_ref().map_or(0, |t| (t.size as u64).pow(3) * 8 * 8 / 7),
            reuse,
            layout,
            brick_capacity: capacity,
            bricks_counted: tables.and_then(|t| t.counted),
            bricks_ms,
        };
        self.last = Some((key, lights.clone(), bounce_key));
        Ok(GiWork {
            splat_bind,
            splat_groups,
            cell_groups,
            brick_steps,
            allocation,
            count_to,
            texture,
            aniso: s.anisotropic,
            group1,
            half,
            caches: cache_dispatch.map(|d| d.2),
            spec,
            bounces: s.bounces,
            tail: s.tail(),
            cells: cells as u32,
            stats,
        })
    }

    /// Records the GI passes: clear, transform, inject (the tracer's pipelines, with its bind
    /// group 0), levels, and per further bounce: bounce, commit, levels.
    pub(crate) fn encode(
        &self,
        work: &GiWork,
        enc: &mut wgpu::CommandEncoder,
        pipes: &GiPipelines,
        group0: &wgpu::BindGroup,
        timestamp_writes: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) -> Result<(), GpuError> {
        let vol = self.volume.as_ref().ok_or_else(|| GpuError::Device("GI volume missing".into()))?;
        let reuse = work.stats.reuse;
        // A rebuilt sparse volume allocates its bricks first; the pair of passes shares the
        // GI pass's timestamps (the first pass writes the start, the GI pass the end).
        let mut timestamp_writes = timestamp_writes;
        if let Some(alloc) = &work.allocation {
            let ts = timestamp_writes.as_ref().map(|t| wgpu::ComputePassTimestampWrites {
                query_set: t.query_set,
                beginning_of_pass_write_index: t.beginning_of_pass_write_index,
                end_of_pass_write_index: None,
            });
            self.record_allocation(enc, alloc, ts)?;
            if let Some(t) = timestamp_writes.as_mut() {
                t.beginning_of_pass_write_index = None;
            }
        }
        if let Some(tables) = self.sparse.as_ref().filter(|_| vol.layout == Layout::Sparse) {
            // The uniforms were written with the count the host knows, if any: the GPU's own
            // replaces it (every frame, since the host writes them every frame).
            for (buf, offset) in &work.count_to {
                enc.copy_buffer_to_buffer(&tables.counters, 0, buf, *offset, 4);
            }
        }
        if reuse == GiReuse::Nothing {
            enc.clear_buffer(&vol.accum, 0, None);
        }
        if let (true, Some((_, next))) = (work.tail && reuse != GiReuse::Levels, &vol.bounce) {
            // The tail's workgroup sums: slots no workgroup writes this frame read zero.
            enc.clear_buffer(next, work.cells as u64 * 16, None);
        }
        if reuse != GiReuse::Levels && vol.layout == Layout::Sparse {
            // Top cells without a brick this frame must read empty.
            let (off, r) = (vol.offsets[BRICK_LEVELS] as u64, vol.resolutions[BRICK_LEVELS] as u64);
            enc.clear_buffer(&vol.levels, off * 16, Some(r.pow(3) * 16));
        }
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("gi"), timestamp_writes });
        if reuse == GiReuse::Levels {
            return Ok(()); // the pass stays for its timestamps
        }
        if work.splat_groups.0 > 0 && reuse == GiReuse::Nothing {
            let pipe = match vol.layout {
                Layout::Dense => &self.splat_pipe,
                Layout::Sparse => &self.sparse_splat_pipe,
            };
            pass.set_pipeline(pipe);
            pass.set_bind_group(0, &work.splat_bind, &[]);
            pass.dispatch_workgroups(work.splat_groups.0, work.splat_groups.1, 1);
        }
        let groups = work.cell_groups;
        // A sparse volume's passes over bricks take their workgroups from the GPU's count
        // (`dispatch_main`), a dense one's from the host.
        let indirect = self.sparse.as_ref().filter(|_| vol.layout == Layout::Sparse).map(|t| &t.dispatch);
        let tracer = |pass: &mut wgpu::ComputePass, pipe: &wgpu::ComputePipeline| {
            if groups.0 > 0 {
                pass.set_pipeline(pipe);
                pass.set_bind_group(0, group0, &[]);
                pass.set_bind_group(1, &work.group1, &[]);
                match indirect {
                    Some(args) => pass.dispatch_workgroups_indirect(args, 0),
                    None => pass.dispatch_workgroups(groups.0, groups.1, 1),
                }
            }
        };
        let levels = |pass: &mut wgpu::ComputePass| {
            for (l, (step, g)) in work.brick_steps.iter().enumerate().filter(|(_, (_, g))| g.0 > 0) {
                pass.set_pipeline(&self.brick_levels_pipe);
                pass.set_bind_group(0, step, &[]);
                match indirect {
                    Some(args) => pass.dispatch_workgroups_indirect(args, 12 * (l as u64 + 1)),
                    None => pass.dispatch_workgroups(g.0, g.1, 1),
                }
            }
            pass.set_pipeline(if vol.aniso { &self.levels_aniso_pipe } else { &self.levels_pipe });
            let first = vol.resolutions.len() - vol.steps.len();
            for (l, step) in vol.steps.iter().enumerate() {
                let g = vol.resolutions[first + l].div_ceil(4);
                pass.set_bind_group(0, step, &[]);
                pass.dispatch_workgroups(g, g, g);
            }
            if let Some(t) = vol.texture.as_ref().filter(|_| work.texture) {
                pass.set_pipeline(&self.texture_pipe);
                for (bind, g) in &t.steps {
                    pass.set_bind_group(0, bind, &[]);
                    pass.dispatch_workgroups(*g, *g, *g);
                }
            }
        };
        tracer(&mut pass, &pipes.inject);
        levels(&mut pass);
        for b in 1..work.bounces {
            tracer(&mut pass, &pipes.bounce);
            if work.tail && b + 1 == work.bounces {
                pass.set_pipeline(&pipes.tail);
                pass.set_bind_group(0, group0, &[]);
                pass.set_bind_group(1, &work.group1, &[]);
                pass.dispatch_workgroups(1, 1, 1);
                tracer(&mut pass, &pipes.tail_commit);
            } else {
                tracer(&mut pass, &pipes.commit);
            }
            levels(&mut pass);
        }
        Ok(())
    }
}
