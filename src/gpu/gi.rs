//! Voxel-transformation GI on the GPU: the WGSL twins of `gi::volume` (transformation with
//! fixed-point atomics, `wgsl/gi_transform.wgsl`), `gi::inject` and `gi::cone`
//! (`wgsl/gi_trace.wgsl`, part of the tracer's module so injection reuses its shadow rays) and
//! `gi::levels` (`wgsl/gi_levels.wgsl`). Caches are built on the CPU once per part and
//! uploaded once; each frame uploads only one job per instance (its matrices) and runs
//! transform → inject → levels → cone-traced shading without a readback.

use super::context::{GpuContext, GpuError};
use super::layout::{GpuGiFrame, GpuGiJob, GpuGiLevelStep, GpuGiSplat};
use super::renderer::read;
use crate::gi::levels::{Level, Levels};
use crate::gi::shade::plan_volume;
use crate::gi::{
    CacheVoxel, ConeSettings, Filter, GiCaches, GiError, GiReuse, GiSettings, Volume, VolumeKey, VolumeSpec,
};
use crate::scene::{Camera, Lights, Scene};
use glam::{DAffine3, DMat3, DVec3, Vec3, Vec4};
use std::collections::HashMap;
use wgpu::util::DeviceExt;

/// Fixed-point scale of occupancy, weighted albedo and weighted normal sums (per unit weight);
/// the WGSL side is `wgsl/gi_fixed.wgsl`.
pub const FIX: f64 = 65536.0;
/// Fixed-point scale of weighted emission (up to 16× the albedo).
pub const EMIT_FIX: f64 = 4096.0;
/// Fixed-point scale of the weight that fell outside the volume.
pub const OUT_FIX: f64 = 256.0;
/// Words per cell in the accumulation buffer.
const STRIDE: usize = 10;
/// Levels the shaders can address (a 512³ volume has 10).
const MAX_LEVELS: usize = 12;

/// The transformation shader.
pub fn transform_source() -> String {
    [
        include_str!("../../wgsl/layout.wgsl"),
        include_str!("../../wgsl/attr.wgsl"),
        include_str!("../../wgsl/gi_fixed.wgsl"),
        include_str!("../../wgsl/gi_splat.wgsl"),
        include_str!("../../wgsl/gi_transform.wgsl"),
    ]
    .join("\n")
}

/// The level-chain shader.
pub fn levels_source() -> String {
    [include_str!("../../wgsl/layout.wgsl"), include_str!("../../wgsl/gi_levels.wgsl")].join("\n")
}

/// The GI volume of the last frame, read back from the GPU (for tests and tools: the render
/// path never reads it back).
#[derive(Clone, Debug)]
pub struct GiCapture {
    /// The transformed voxels, the fixed-point sums converted back to floats.
    pub volume: Volume,
    /// Weight that fell outside the volume.
    pub outside: f64,
    /// The injected light and the level chain.
    pub levels: Levels,
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
    /// Bytes of the GI buffers (voxel pool, accumulation, levels).
    pub bytes: u64,
    /// What was kept from the frame before (the passes not run).
    pub reuse: GiReuse,
}

struct VolumeBuffers {
    res: u32,
    accum: wgpu::Buffer,
    levels: wgpu::Buffer,
    offsets: Vec<u32>,
    resolutions: Vec<u32>,
    steps: Vec<wgpu::BindGroup>,
    /// The direct and next level 0 of the bounce passes (allocated when a frame asks for more
    /// than one bounce).
    bounce: Option<(wgpu::Buffer, wgpu::Buffer)>,
}

struct Pool {
    keys: Vec<(usize, u32)>,
    voxels: wgpu::Buffer,
    /// (first voxel, count) per key.
    ranges: HashMap<(usize, u32), (u32, u32)>,
}

/// One frame's GI work, ready to encode.
pub(crate) struct GiWork {
    splat_bind: wgpu::BindGroup,
    splat_groups: (u32, u32),
    /// Bind group 1 of the tracer's GI entry points.
    pub group1: wgpu::BindGroup,
    spec: VolumeSpec,
    bounces: u32,
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
    /// Layout of bind group 1 (accumulation, levels, GI uniforms) of the tracer's GI entries.
    pub group1_layout: wgpu::BindGroupLayout,
    volume: Option<VolumeBuffers>,
    /// Bound in place of the bounce buffers when a frame has one bounce.
    placeholder: wgpu::Buffer,
    /// What the volume on the GPU was made from, and the bounces (with their cones) its chain
    /// was gathered with.
    last: Option<(VolumeKey, Lights, (u32, ConeSettings))>,
}

/// The tracer's GI entry points of one plan variant.
pub(crate) struct GiPipelines {
    /// Light injection.
    pub inject: wgpu::ComputePipeline,
    /// Shading with cone tracing.
    pub shade: wgpu::ComputePipeline,
    /// One more bounce into the next level 0.
    pub bounce: wgpu::ComputePipeline,
    /// The next level 0 into the chain.
    pub commit: wgpu::ComputePipeline,
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
    let groups = (threads as u32).div_ceil(64);
    let dims = (groups.min(65_535), groups.div_ceil(65_535));
    let splat = GpuGiSplat {
        res,
        jobs: jobs as u32,
        threads: threads as u32,
        row_threads: dims.0 * 64,
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
    pub(crate) fn new(device: &wgpu::Device) -> GpuGi {
        let make = |label: &str, src: String, entry: &str| {
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(src.into()),
            });
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: None,
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        let group1_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("gi (tracer group 1)"),
            entries: &[
                gi_layout_entry(0, wgpu::BufferBindingType::Storage { read_only: true }),
                gi_layout_entry(1, wgpu::BufferBindingType::Storage { read_only: false }),
                gi_layout_entry(2, wgpu::BufferBindingType::Uniform),
                gi_layout_entry(3, wgpu::BufferBindingType::Storage { read_only: false }),
                gi_layout_entry(4, wgpu::BufferBindingType::Storage { read_only: false }),
            ],
        });
        let placeholder = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("gi bounce placeholder"),
            size: 16,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        GpuGi {
            caches: GiCaches::new(),
            pool: None,
            splat_pipe: make("gi_transform.wgsl", transform_source(), "splat_main"),
            levels_pipe: make("gi_levels.wgsl", levels_source(), "levels_main"),
            group1_layout,
            volume: None,
            placeholder,
            last: None,
        }
    }

    /// Uploads the caches of `keys` if they are not the ones on the GPU.
    fn upload_pool(&mut self, ctx: &GpuContext, scene: &Scene, keys: Vec<(usize, u32)>) -> Result<(), GpuError> {
        if self.pool.as_ref().is_some_and(|p| p.keys == keys) {
            return Ok(());
        }
        let mut all: Vec<CacheVoxel> = Vec::new();
        let mut ranges = HashMap::new();
        for (p, &(key_ptr, level)) in scene.parts.iter().zip(&keys) {
            if ranges.contains_key(&(key_ptr, level)) {
                continue;
            }
            let cache = self.caches.get(p, level)?;
            ranges.insert((key_ptr, level), (all.len() as u32, cache.voxels.len() as u32));
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
        let voxels = ctx.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("gi voxels"),
            contents: bytemuck::cast_slice(&all),
            usage: wgpu::BufferUsages::STORAGE,
        });
        self.pool = Some(Pool { keys, voxels, ranges });
        Ok(())
    }

    /// Allocates the accumulation and level buffers for `res` cells per side.
    fn volume_buffers(&mut self, ctx: &GpuContext, res: u32) -> Result<(), GpuError> {
        if self.volume.as_ref().is_some_and(|v| v.res == res) {
            return Ok(());
        }
        self.volume = None; // free the old volume before allocating the new one
        let cells = (res as u64).pow(3);
        let accum_size = (cells * STRIDE as u64 + 1) * 4;
        ctx.check_binding("the GI accumulation volume", accum_size)?;
        let (mut offsets, mut resolutions, mut total) = (Vec::new(), Vec::new(), 0u64);
        let mut r = res;
        loop {
            offsets.push(total as u32);
            resolutions.push(r);
            total += (r as u64).pow(3);
            if r == 1 {
                break;
            }
            r = r.div_ceil(2);
        }
        if offsets.len() > MAX_LEVELS {
            return Err(GiError::Resolution(res).into());
        }
        ctx.check_binding("the GI level chain", total * 16)?;
        let device = &ctx.device;
        let accum = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("gi accumulation"),
            size: accum_size,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let levels = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("gi levels"),
            size: total * 16,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let steps = (1..offsets.len())
            .map(|l| {
                let step = GpuGiLevelStep {
                    src_offset: offsets[l - 1],
                    src_res: resolutions[l - 1],
                    dst_offset: offsets[l],
                    dst_res: resolutions[l],
                };
                let ubuf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("gi level step"),
                    contents: bytemuck::bytes_of(&step),
                    usage: wgpu::BufferUsages::UNIFORM,
                });
                device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("gi level step"),
                    layout: &self.levels_pipe.get_bind_group_layout(0),
                    entries: &[
                        wgpu::BindGroupEntry { binding: 0, resource: levels.as_entire_binding() },
                        wgpu::BindGroupEntry { binding: 1, resource: ubuf.as_entire_binding() },
                    ],
                })
            })
            .collect();
        self.volume = Some(VolumeBuffers { res, accum, levels, offsets, resolutions, steps, bounce: None });
        Ok(())
    }

    /// Allocates the bounce passes' two level-0 buffers if a frame needs them.
    fn bounce_buffers(&mut self, ctx: &GpuContext) -> Result<(), GpuError> {
        let Some(vol) = self.volume.as_mut().filter(|v| v.bounce.is_none()) else {
            return Ok(());
        };
        let size = (vol.res as u64).pow(3) * 16;
        ctx.check_binding("the GI bounce volume", size)?;
        let make = |label| {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage: wgpu::BufferUsages::STORAGE,
                mapped_at_creation: false,
            })
        };
        vol.bounce = Some((make("gi direct level 0"), make("gi next level 0")));
        Ok(())
    }

    /// Places this frame's volume, uploads what changed and the instances' jobs.
    pub(crate) fn prepare(
        &mut self,
        ctx: &GpuContext,
        scene: &Scene,
        camera: &Camera,
        lights: &Lights,
        s: &GiSettings,
    ) -> Result<GiWork, GpuError> {
        let cones = s.cones.validated().map_err(|e| GiError::Settings(e.to_string()))?;
        let (spec, levels_of) = plan_volume(scene, camera, s, &mut self.caches)?;
        let key = VolumeKey::new(scene, spec, crate::gi::Layout::Dense, s.filter, &levels_of);
        // Decided before any upload: a changed pool or volume size changes the key too.
        let mut reuse = GiReuse::decide(self.last.as_ref().map(|(k, l, _)| (k, l)), &key, lights);
        let bounce_key = (s.bounces, if s.bounces > 1 { cones } else { ConeSettings::default() });
        if reuse == GiReuse::Levels && self.last.as_ref().is_some_and(|l| l.2 != bounce_key) {
            reuse = GiReuse::Volume; // the chain was gathered with other bounces
        }
        self.last = None; // until this frame's passes are encoded
        let keys: Vec<(usize, u32)> =
            scene.parts.iter().zip(&levels_of).map(|(p, &l)| (std::sync::Arc::as_ptr(p) as usize, l)).collect();
        self.upload_pool(ctx, scene, keys.clone())?;
        self.volume_buffers(ctx, spec.res)?;
        if s.bounces > 1 {
            self.bounce_buffers(ctx)?;
        }
        let (pool, vol) = match (&self.pool, &self.volume) {
            (Some(p), Some(v)) => (p, v),
            _ => return Err(GpuError::Device("GI buffers missing".into())),
        };
        let mut jobs = Vec::new();
        let mut threads = 0u64;
        for (i, inst) in scene.instances().iter().enumerate() {
            let key = keys[inst.part];
            let range = pool.ranges[&key];
            let cache = self.caches.get(&scene.parts[inst.part], key.1)?;
            let job = transform_job(&scene.world(i), cache, &spec, range, threads)?;
            if range.1 > 0 {
                jobs.push(job);
                threads += range.1 as u64;
            }
        }
        let (splat, splat_groups) = splat_dispatch(spec.res, jobs.len(), threads, s.filter)?;
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
            pad1: 0,
        };
        let device = &ctx.device;
        let jobs_len = jobs.len();
        if jobs.is_empty() {
            jobs.push(GpuGiJob::default());
        }
        ctx.check_binding("the GI jobs", std::mem::size_of_val(jobs.as_slice()) as u64)?;
        let init = |label, contents: &[u8], usage| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents, usage })
        };
        let jobs_buf = init("gi jobs", bytemuck::cast_slice(&jobs), wgpu::BufferUsages::STORAGE);
        let splat_buf = init("gi splat", bytemuck::bytes_of(&splat), wgpu::BufferUsages::UNIFORM);
        let frame_buf = init("gi frame", bytemuck::bytes_of(&gframe), wgpu::BufferUsages::UNIFORM);
        let splat_bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("gi splat"),
            layout: &self.splat_pipe.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: pool.voxels.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: jobs_buf.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 2, resource: vol.accum.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 3, resource: splat_buf.as_entire_binding() },
            ],
        });
        let (direct, next) = match (&vol.bounce, s.bounces > 1) {
            (Some((d, n)), true) => (d, n),
            _ => (&self.placeholder, &self.placeholder),
        };
        let group1 = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("gi (tracer group 1)"),
            layout: &self.group1_layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: vol.accum.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: vol.levels.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 2, resource: frame_buf.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 3, resource: direct.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 4, resource: next.as_entire_binding() },
            ],
        });
        let stats = GpuGiStats {
            voxels: threads,
            jobs: jobs_len as u32,
            res: spec.res,
            levels: vol.offsets.len() as u32,
            bytes: pool.voxels.size()
                + vol.accum.size()
                + vol.levels.size()
                + jobs_buf.size()
                + vol.bounce.as_ref().map_or(0, |(d, n)| d.size() + n.size()),
            reuse,
        };
        self.last = Some((key, *lights, bounce_key));
        let splat_groups = if threads == 0 { (0, 0) } else { splat_groups };
        Ok(GiWork { splat_bind, splat_groups, group1, spec, bounces: s.bounces, stats })
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
        if reuse == GiReuse::Nothing {
            enc.clear_buffer(&vol.accum, 0, None);
        }
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("gi"), timestamp_writes });
        if reuse == GiReuse::Levels {
            return Ok(()); // the pass stays for its timestamps
        }
        if work.splat_groups.0 > 0 && reuse == GiReuse::Nothing {
            pass.set_pipeline(&self.splat_pipe);
            pass.set_bind_group(0, &work.splat_bind, &[]);
            pass.dispatch_workgroups(work.splat_groups.0, work.splat_groups.1, 1);
        }
        let g = vol.res.div_ceil(4);
        let tracer = |pass: &mut wgpu::ComputePass, pipe: &wgpu::ComputePipeline| {
            pass.set_pipeline(pipe);
            pass.set_bind_group(0, group0, &[]);
            pass.set_bind_group(1, &work.group1, &[]);
            pass.dispatch_workgroups(g, g, g);
        };
        let levels = |pass: &mut wgpu::ComputePass| {
            pass.set_pipeline(&self.levels_pipe);
            for (l, step) in vol.steps.iter().enumerate() {
                let g = vol.resolutions[l + 1].div_ceil(4);
                pass.set_bind_group(0, step, &[]);
                pass.dispatch_workgroups(g, g, g);
            }
        };
        tracer(&mut pass, &pipes.inject);
        levels(&mut pass);
        for _ in 1..work.bounces {
            tracer(&mut pass, &pipes.bounce);
            tracer(&mut pass, &pipes.commit);
            levels(&mut pass);
        }
        Ok(())
    }

    /// Copies the volume to readback buffers (submit `enc`, then [`GpuGi::read_capture`]).
    pub(crate) fn copy_capture(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
    ) -> Option<(wgpu::Buffer, wgpu::Buffer)> {
        let vol = self.volume.as_ref()?;
        let copy = |enc: &mut wgpu::CommandEncoder, src: &wgpu::Buffer| {
            let dst = ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("gi readback"),
                size: src.size(),
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            enc.copy_buffer_to_buffer(src, 0, &dst, 0, src.size());
            dst
        };
        Some((copy(enc, &vol.accum), copy(enc, &vol.levels)))
    }

    /// Reads the copies of [`GpuGi::copy_capture`] back into CPU structures.
    pub(crate) fn read_capture(
        &self,
        ctx: &GpuContext,
        work: &GiWork,
        bufs: &(wgpu::Buffer, wgpu::Buffer),
    ) -> Result<GiCapture, GpuError> {
        let vol = self.volume.as_ref().ok_or_else(|| GpuError::Device("GI volume missing".into()))?;
        let accum: Vec<u32> = read(ctx, &bufs.0)?;
        let rgba: Vec<[f32; 4]> = read(ctx, &bufs.1)?;
        let (volume, outside) = volume_from_accum(&accum, work.spec);
        let levels = vol
            .offsets
            .iter()
            .zip(&vol.resolutions)
            .enumerate()
            .map(|(l, (&off, &res))| {
                let n = (res as usize).pow(3);
                Level {
                    res,
                    cell: work.spec.cell * (1u64 << l) as f64,
                    rgba: rgba[off as usize..off as usize + n].iter().map(|&v| Vec4::from_array(v)).collect(),
                }
            })
            .collect();
        Ok(GiCapture { volume, outside, levels: Levels { min: work.spec.min, levels } })
    }
}
