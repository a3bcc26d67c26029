//! The GPU renderer: the same frame as `render::cpu` (plan, hit buffer, trace then shade),
//! in WGSL. All parts share one node pool and one attribute pool (uploaded once); instances,
//! the BVH and the hit-buffer conditions are uploaded per frame; the hit records stay on the
//! GPU between frames. Pipelines are built per plan variant (WGSL `override` constants) and
//! cached.

use super::context::{GpuContext, GpuError};
use super::layout::*;
use crate::render::hitbuffer::{HitBuffer, HitRecord};
use crate::render::instances::{prepare_changed, Prepared, ToUnit};
use crate::render::visibility::Search;
use crate::render::{Frame, FramePlan, RenderOptions};
use crate::scene::{Camera, Lights, Scene};
use crate::svo::{Attr, PartId, Svo};
use glam::{DMat3, Vec3};
use std::collections::HashMap;
use std::sync::Arc;

/// The WGSL sources, concatenated (WGSL has no includes).
pub fn trace_source() -> String {
    [
        &super::prelude::prelude(),
        include_str!("../../wgsl/shared/layout.wgsl"),
        include_str!("../../wgsl/shared/attr.wgsl"),
        include_str!("../../wgsl/shared/traverse.wgsl"),
        include_str!("../../wgsl/shared/search.wgsl"),
        include_str!("../../wgsl/trace.wgsl"),
        include_str!("../../wgsl/shared/gi_fixed.wgsl"),
        include_str!("../../wgsl/gi_trace.wgsl"),
        include_str!("../../wgsl/splat.wgsl"),
    ]
    .join("\n")
}

/// The ray-list shader.
pub fn rays_source() -> String {
    [
        &super::prelude::prelude(),
        include_str!("../../wgsl/shared/layout.wgsl"),
        include_str!("../../wgsl/shared/traverse.wgsl"),
        include_str!("../../wgsl/rays.wgsl"),
    ]
    .join("\n")
}

/// GPU times of one frame (from timestamp queries, when the adapter has them).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GpuTimes {
    /// Trace pass (the splat passes with the splat renderer), milliseconds.
    pub trace_ms: f64,
    /// Shade pass, milliseconds.
    pub shade_ms: f64,
    /// GI passes (transform, inject, levels), milliseconds; zero without GI.
    pub gi_ms: f64,
    /// A crowd posed on the GPU: its pose and BVH refit passes, milliseconds (None
    /// otherwise).
    pub crowd_ms: Option<f64>,
    /// With radiance caches: their placement, tracing and convolution passes, milliseconds
    /// (their blending is in the shade pass).
    pub cache_ms: Option<[f64; 3]>,
}

/// The parts' octrees as the shaders read them: one node pool and one attribute pool, each
/// in at most two bindings, and a table of where each part starts.
pub(crate) struct Pools {
    /// The parts uploaded, by identity (not address: see [`PartId`]).
    parts: Vec<PartId>,
    pub(crate) nodes: wgpu::Buffer,
    pub(crate) nodes_hi: wgpu::Buffer,
    pub(crate) attrs: wgpu::Buffer,
    pub(crate) attrs_hi: wgpu::Buffer,
    pub(crate) infos: wgpu::Buffer,
    /// First element of each pool in its `_hi` binding (u32::MAX when not split).
    pub(crate) node_split: u32,
    pub(crate) attr_split: u32,
}

impl Pools {
    /// Uploads `parts` into pools whose bindings hold at most `max_binding` bytes each.
    pub(crate) fn upload(ctx: &GpuContext, parts: &[Arc<Svo>], max_binding: u64) -> Result<Pools, GpuError> {
        let ids: Vec<PartId> = parts.iter().map(PartId::of).collect();
        let (mut nodes, mut attrs, mut infos): (Vec<u32>, Vec<Attr>, Vec<GpuPart>) =
            (Vec::new(), Vec::new(), Vec::new());
        for p in parts {
            let (words, masks) = super::layout::part_words(p);
            let base = nodes.len() as u32;
            infos.push(GpuPart {
                node_base: base,
                mask_base: base + masks,
                attr_base: attrs.len() as u32,
                depth: p.depth,
            });
            nodes.extend_from_slice(&words);
            attrs.extend_from_slice(&p.attrs);
        }
        let (n0, n1, node_split) = split_pool("the node pool", &nodes, max_binding)?;
        let (a0, a1, attr_split) = split_pool("the attribute pool", &attrs, max_binding)?;
        let buf = |label, contents: &[u8]| {
            ctx.buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage: wgpu::BufferUsages::STORAGE,
            })
        };
        Ok(Pools {
            parts: ids,
            nodes: buf("nodes", bytemuck::cast_slice(&n0)),
            nodes_hi: buf("nodes (second binding)", bytemuck::cast_slice(&n1)),
            attrs: buf("attrs", bytemuck::cast_slice(&a0)),
            attrs_hi: buf("attrs (second binding)", bytemuck::cast_slice(&a1)),
            infos: buf("parts", bytemuck::cast_slice(&infos)),
            node_split,
            attr_split,
        })
    }
}

/// Splits a pool into at most two bindings of at most `limit` bytes each; returns the two
/// halves and the first index of the second (u32::MAX when it fits in one).
fn split_pool<T: bytemuck::Pod + Default>(
    what: &'static str,
    v: &[T],
    limit: u64,
) -> Result<(Vec<T>, Vec<T>, u32), GpuError> {
    let size = std::mem::size_of::<T>() as u64;
    let per = (limit / size).max(1) as usize;
    if v.len() <= per {
        return Ok((v.to_vec(), vec![T::default()], u32::MAX));
    }
    if v.len() > 2 * per || v.len() > u32::MAX as usize {
        return Err(GpuError::TooLarge { what, size: v.len() as u64 * size, limit: 2 * limit });
    }
    Ok((v[..per].to_vec(), v[per..].to_vec(), per as u32))
}

/// Buffers of the trace and shade passes kept from frame to frame: rewritten in place each
/// frame and replaced only when a frame needs a larger one (or, for the image-sized ones,
/// another size), so a steady animation creates no buffers.
#[derive(Default)]
struct FrameBuffers {
    insts: Option<wgpu::Buffer>,
    frame: Option<wgpu::Buffer>,
    bvh: Option<wgpu::Buffer>,
    items: Option<wgpu::Buffer>,
    moved: Option<wgpu::Buffer>,
    moved_bins: Option<wgpu::Buffer>,
    moved_bvh: Option<wgpu::Buffer>,
    moved_bvh_items: Option<wgpu::Buffer>,
    emitters: Option<wgpu::Buffer>,
    lights: Option<wgpu::Buffer>,
    radiance: Option<wgpu::Buffer>,
    hits_read: Option<wgpu::Buffer>,
    radiance_read: Option<wgpu::Buffer>,
    /// The statistics the passes add up (`GpuStats`), and where they are read.
    stats: Option<wgpu::Buffer>,
    stats_read: Option<wgpu::Buffer>,
    /// Timestamp queries, where to resolve them and where to read them.
    queries: Option<(wgpu::QuerySet, wgpu::Buffer, wgpu::Buffer)>,
    /// The trace/shade bind group; None when a buffer it names was replaced.
    bind: Option<wgpu::BindGroup>,
}

/// Makes `slot` a buffer of at least `size` bytes (exactly `size` when `exact`), creating one
/// only when the one there does not fit; returns whether it did.
pub(crate) fn ensure(
    ctx: &GpuContext,
    slot: &mut Option<wgpu::Buffer>,
    label: &'static str,
    size: u64,
    exact: bool,
    usage: wgpu::BufferUsages,
) -> bool {
    let fits = slot.as_ref().is_some_and(|b| if exact { b.size() == size } else { b.size() >= size });
    if fits {
        return false;
    }
    let size = if exact { size } else { size.next_power_of_two().max(256) };
    *slot = Some(ctx.buffer(&wgpu::BufferDescriptor { label: Some(label), size, usage, mapped_at_creation: false }));
    true
}

/// Renders frames on the GPU.
pub struct GpuRenderer {
    /// The device.
    pub ctx: Arc<GpuContext>,
    module: wgpu::ShaderModule,
    layout: wgpu::BindGroupLayout,
    pipeline_layout: wgpu::PipelineLayout,
    pipelines: HashMap<(u32, bool, bool), (wgpu::ComputePipeline, wgpu::ComputePipeline)>,
    pools: Option<Pools>,
    hits: Option<(wgpu::Buffer, u32, u32)>,
    /// The CPU-side record of the frame in the GPU hit buffer (camera, transforms, spheres).
    pub state: HitBuffer,
    /// GPU pass times of the last frame, if timestamps are available.
    pub times: Option<GpuTimes>,
    /// Largest binding in bytes (the device's limit unless lowered for tests).
    pub max_binding: u64,
    /// Bytes of GPU buffers the last frame used (part pools, hit buffer, per-frame inputs and
    /// outputs, GI buffers; readback copies not counted).
    pub buffer_bytes: u64,
    gi: Option<super::gi::GpuGi>,
    gi_settings: Option<crate::gi::GiSettings>,
    gi_pipeline_layout: Option<wgpu::PipelineLayout>,
    gi_pipelines: HashMap<(u32, bool, bool, bool, bool, bool), super::gi::GiPipelines>,
    /// What GI did in the last frame (None without GI).
    pub gi_stats: Option<super::gi::GpuGiStats>,
    /// Buffers of the trace and shade passes kept between frames.
    kept: FrameBuffers,
    /// Buffers created and bytes read back by the last frame (GI included).
    pub frame_traffic: (u64, u64),
    /// Read the GI volume back after each frame into [`GpuRenderer::gi_captured`] (slow; for
    /// tests and tools).
    pub gi_capture: bool,
    /// The last frame's GI volume, when `gi_capture` is on.
    pub gi_captured: Option<super::gi::GiCapture>,
    /// Read each frame's image, hit records and pass times back to the host (the default);
    /// off, frames stay on the GPU ([`GpuRenderer::set_read_back`]).
    read_back: bool,
    /// Size of the image in the radiance buffer (the last frame's).
    radiance_size: (u32, u32),
    /// The lights and shadow switch the radiance buffer's colours were shaded under, when
    /// they are the frame in the hit buffer's, shaded by `shade_main` (traced, no GI): the
    /// next frame may keep them ([`GpuFrame::keep_colours`]).
    shaded: Option<(Lights, bool)>,
    /// Add up the frame's statistics on the GPU ([`GpuRenderer::set_counting`]).
    counting: bool,
    /// Tests: fail the next frame just after it was submitted, as a failed read-back would.
    #[cfg(test)]
    fail_after_submit: bool,
    /// The last frame's statistics as the GPU added them up (when counting).
    pub stats: Option<super::layout::GpuStats>,
    /// The host's time on the last frame from its start to its submit (preparing,
    /// converting, refitting and writing what the passes read), milliseconds: with a fast
    /// GPU, most of a crowd's frame.
    pub submit_host_ms: f64,
    /// The last frame's parts, for [`GpuRenderer::eye_inside`].
    parts_kept: Vec<Arc<crate::svo::Svo>>,
    /// The splat renderer's passes and buffers (made on its first frame).
    splat: Option<super::splat::GpuSplat>,
    /// Which of last frame's instances, as uploaded, were flagged as moved (empty when the
    /// instance buffer does not hold last frame's instances): a frame that refills only the
    /// instances that changed converts and rewrites only theirs (a crowd's 80 000 took 1.5 ms
    /// a frame to convert afresh), straight into the upload's memory: no copy of every
    /// instance is kept up to date on the host.
    inst_moved: Vec<bool>,
    /// Memory the instances are converted into when all of them are written (every frame
    /// of a moving camera: kept, not allocated afresh each time).
    inst_scratch: Vec<GpuInstance>,
    /// The passes that put the rewritten instances and BVH nodes in place (made on first
    /// use; each has its own upload buffers, as both are written before the frame runs).
    scatter_insts: Option<super::scatter::ScatterRows>,
    scatter_bvh: Option<super::scatter::ScatterRows>,
    /// How many nodes of last frame's instance BVH (the tree in `state`) the GPU's buffer
    /// holds (0: none, or not known after a failed frame), and scratch for the nodes a refit
    /// recomputed. Those are converted as they are packed for upload: no copy of every
    /// node is kept up to date on the host.
    bvh_uploaded: usize,
    bvh_dirty: Vec<u32>,
    /// Cars posed on the GPU ([`GpuRenderer::set_crowd`]), the time they are posed at, and
    /// which crowd's tree links the BVH buffer holds.
    crowd: Option<super::crowd::GpuCrowd>,
    crowd_time: f64,
    crowd_links: Option<u64>,
}

fn storage(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// One entry point of the tracer's module compiled for a plan variant (its `override` values).
pub(crate) fn plan_pipeline(
    device: &wgpu::Device,
    layout: &wgpu::PipelineLayout,
    module: &wgpu::ShaderModule,
    entry: &str,
    constants: &[(&str, f64)],
) -> wgpu::ComputePipeline {
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(entry),
        layout: Some(layout),
        module,
        entry_point: Some(entry),
        compilation_options: wgpu::PipelineCompilationOptions { constants, zero_initialize_workgroup_memory: false },
        cache: None,
    })
}

/// A BVH's nodes as the shaders walk them: each box grown by more than the f32 slab test
/// can lose, as the spheres are.
pub(crate) fn gpu_bvh_nodes(b: &crate::render::bvh::Bvh) -> Vec<GpuBvhNode> {
    // A crowd's tree has 160 000 nodes.
    #[cfg(feature = "parallel")]
    {
        use rayon::prelude::*;
        b.nodes.par_iter().with_min_len(4096).map(gpu_bvh_node).collect()
    }
    #[cfg(not(feature = "parallel"))]
    {
        b.nodes.iter().map(gpu_bvh_node).collect()
    }
}

/// One node of [`gpu_bvh_nodes`].
fn gpu_bvh_node(nd: &crate::render::bvh::Node) -> GpuBvhNode {
    let slack = glam::DVec3::splat(1e-6 * nd.lo.abs().max(nd.hi.abs()).max_element());
    let (lo, hi) = (nd.lo - slack, nd.hi + slack);
    GpuBvhNode {
        lo: [lo.x as f32, lo.y as f32, lo.z as f32, f32::from_bits(nd.first)],
        hi: [hi.x as f32, hi.y as f32, hi.z as f32, f32::from_bits(nd.count)],
    }
}

fn f4(v: glam::DVec3, w: f64) -> [f32; 4] {
    [v.x as f32, v.y as f32, v.z as f32, w as f32]
}

/// A bounding sphere as the shaders test it, in f32 from the camera: its radius grown by
/// about what that test can lose (|oc|² − r² cancels to ~10⁻⁷·|oc|², the centre rounds by
/// ~10⁻⁷·|oc|), so that a ray that only clips a corner of the occupied box the sphere is
/// tight around still meets it. A larger sphere only culls less.
fn gpu_sphere(centre: glam::DVec3, radius: f64) -> [f32; 4] {
    let far = centre.length();
    let grown = radius + 4e-7 * far * far / radius.max(f64::MIN_POSITIVE) + 1e-6 * far;
    f4(centre, grown * (1.0 + 1e-6))
}

impl GpuRenderer {
    /// A renderer on a device.
    pub fn new(ctx: Arc<GpuContext>) -> GpuRenderer {
        let device = &ctx.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("trace.wgsl"),
            source: wgpu::ShaderSource::Wgsl(trace_source().into()),
        });
        use super::prelude::binding as b;
        let mut entries: Vec<wgpu::BindGroupLayoutEntry> =
            [(b::NODES, true), (b::ATTRS, true), (b::PARTS, true), (b::INSTS, true)]
                .iter()
                .map(|&(b, r)| storage(b, r))
                .collect();
        entries.push(wgpu::BindGroupLayoutEntry {
            binding: b::FRAME,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        });
        entries.extend(
            [
                (b::BVH, true),
                (b::BVH_ITEMS, true),
                (b::HITS, false),
                (b::MOVED, true),
                (b::RADIANCE, false),
                (b::NODES_HI, true),
                (b::ATTRS_HI, true),
                (b::STATS, false),
                (b::EMITTERS, true),
                (b::LIGHTS, true),
                (b::MOVED_BINS, true),
                (b::MOVED_BVH, true),
                (b::MOVED_BVH_ITEMS, true),
            ]
            .iter()
            .map(|&(b, r)| storage(b, r)),
        );
        let layout = device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some("trace"), entries: &entries });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("trace"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        GpuRenderer {
            ctx,
            module,
            layout,
            pipeline_layout,
            pipelines: HashMap::new(),
            pools: None,
            hits: None,
            state: HitBuffer::new(),
            times: None,
            max_binding: 0,
            buffer_bytes: 0,
            gi: None,
            gi_settings: None,
            gi_pipeline_layout: None,
            gi_pipelines: HashMap::new(),
            gi_stats: None,
            kept: FrameBuffers::default(),
            frame_traffic: (0, 0),
            gi_capture: false,
            gi_captured: None,
            read_back: true,
            radiance_size: (0, 0),
            shaded: None,
            counting: false,
            #[cfg(test)]
            fail_after_submit: false,
            stats: None,
            submit_host_ms: 0.0,
            parts_kept: Vec::new(),
            splat: None,
            inst_moved: Vec::new(),
            inst_scratch: Vec::new(),
            scatter_insts: None,
            scatter_bvh: None,
            bvh_uploaded: 0,
            bvh_dirty: Vec::new(),
            crowd: None,
            crowd_time: 0.0,
            crowd_links: None,
        }
        .with_device_limit()
    }

    /// Whether frames are read back to the host. Off, [`GpuRenderer::render`] neither waits
    /// for the GPU nor copies anything from it: the frame it returns has no pixels
    /// ([`Frame::on_device`]), the image stays in [`GpuRenderer::radiance`] for a caller on
    /// the same device to draw (the demo presents it), the hit records stay in the GPU's
    /// hit buffer for the next frame, and no pass times are measured. Turn it on for the
    /// frames whose image, AOVs or statistics are wanted.
    pub fn set_read_back(&mut self, on: bool) {
        self.read_back = on;
    }

    /// Whether the passes add up the frame's statistics on the GPU (atomics into a 32-byte
    /// buffer; off by default). A frame kept on the GPU then reads back only those and the
    /// pass times, and comes with its counters (reused, moved-only, octrees traversed,
    /// spheres culled, shadow rays) filled in; every frame leaves them in
    /// [`GpuRenderer::stats`].
    pub fn set_counting(&mut self, on: bool) {
        self.counting = on;
    }

    /// Poses `crowd`'s cars on the GPU in the frames that follow, at the time
    /// [`GpuRenderer::set_crowd_time`] gives: the host then neither poses them, nor updates
    /// their transforms, nor prepares, converts or uploads their instances, nor refits their
    /// tree; the scene's transforms of those instances are not read (only its other
    /// instances are, prepared on the host each frame). Frames walk the crowd's tree, traced
    /// to its level of detail, without the hit buffer's reuse; GI, splats and sampled
    /// emitters are refused (they read the host's transforms), and
    /// [`GpuRenderer::eye_inside`] knows of no instance (the cars' places are the GPU's).
    /// None: the scene's own transforms again.
    pub fn set_crowd(&mut self, crowd: Option<super::crowd::GpuCrowd>) {
        self.crowd = crowd;
    }

    /// The time the crowd's cars are posed at in the next frames (s).
    pub fn set_crowd_time(&mut self, t: f64) {
        self.crowd_time = t;
    }

    /// The crowd posed on the GPU, if any.
    pub fn crowd(&self) -> Option<&super::crowd::GpuCrowd> {
        self.crowd.as_ref()
    }

    /// Whether frames are read back ([`GpuRenderer::set_read_back`]).
    pub fn reads_back(&self) -> bool {
        self.read_back
    }

    /// The last frame's linear radiance on the GPU, with its width and height: one
    /// `vec4<f32>` per pixel (rgb, then 0), row by row from the top, in a storage buffer that
    /// may be longer than the image. It is rewritten by the next frame.
    pub fn radiance(&self) -> Option<(&wgpu::Buffer, u32, u32)> {
        let (w, h) = self.radiance_size;
        self.kept.radiance.as_ref().filter(|_| w > 0 && h > 0).map(|b| (b, w, h))
    }

    /// Reads the last frame's image back from [`GpuRenderer::radiance`] (for a frame that
    /// stayed on the GPU and is wanted after all, e.g. for a screenshot): linear radiance,
    /// row by row from the top.
    pub fn read_image(&mut self) -> Result<Vec<Vec3>, GpuError> {
        let ctx = self.ctx.clone();
        ctx.scoped(|| {
            let (w, h) = self.radiance_size;
            let src = self.kept.radiance.as_ref().ok_or_else(|| GpuError::Device("no frame rendered yet".into()))?;
            let bytes = w as u64 * h as u64 * 16;
            let mappable = wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST;
            ensure(&ctx, &mut self.kept.radiance_read, "radiance readback", bytes, true, mappable);
            let dst = self.kept.radiance_read.as_ref().ok_or_else(|| GpuError::Device("no readback buffer".into()))?;
            let mut enc =
                ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("read image") });
            enc.copy_buffer_to_buffer(src, 0, dst, 0, bytes);
            ctx.queue.submit([enc.finish()]);
            let rad: Vec<[f32; 4]> = read(&ctx, dst)?;
            Ok(rad.iter().map(|c| Vec3::new(c[0], c[1], c[2])).collect())
        })
    }

    fn with_device_limit(mut self) -> Self {
        self.max_binding = self.ctx.limits.max_storage_buffer_binding_size.min(self.ctx.limits.max_buffer_size);
        self
    }

    /// Builds (once) the pipelines of a plan variant. Both hit-buffer variants are built
    /// together: the second frame of a clip needs the other one, and compiling it then would
    /// show up as a multi-second frame on a software driver.
    fn pipelines(&mut self, search: u32, shadows: bool) {
        for reuse in [false, true] {
            self.pipeline(search, reuse, shadows);
        }
    }

    /// First node and attribute index held by the second binding of each pool (u32::MAX when
    /// a pool fits in one binding).
    pub fn splits(&self) -> (u32, u32) {
        self.pools.as_ref().map_or((u32::MAX, u32::MAX), |p| (p.node_split, p.attr_split))
    }

    /// Turns voxel-cone-traced GI on (with these knobs) or off for the following frames. The
    /// knobs are checked here; the GPU state (caches, volume) is kept while GI stays on.
    pub fn set_gi(&mut self, settings: Option<crate::gi::GiSettings>) -> Result<(), GpuError> {
        if let Some(asked) = &settings {
            asked.validated()?;
            if asked.anisotropic && asked.levels == crate::gi::shade::LevelStore::Texture {
                return Err(crate::gi::GiError::Settings(
                    "anisotropic GI levels are read from the level buffer only: use --gi-levels buffer or leave out \
                     --gi-anisotropic"
                        .into(),
                )
                .into());
            }
            let border = self.ctx.device.features().contains(wgpu::Features::ADDRESS_MODE_CLAMP_TO_BORDER);
            if asked.levels == crate::gi::shade::LevelStore::Texture && !border {
                return Err(crate::gi::GiError::Settings(
                    "texture GI levels need a sampler border (ADDRESS_MODE_CLAMP_TO_BORDER), which this adapter \
                     lacks: use --gi-levels buffer"
                        .into(),
                )
                .into());
            }
        }
        // `auto` as on the CPU where this device can hold a dense volume (VolumeChoice::pick_on_gpu).
        let max_binding = self.ctx.limits.max_storage_buffer_binding_size.min(self.ctx.limits.max_buffer_size);
        let settings = settings.map(|s| crate::gi::GiSettings {
            volume: match s.volume.pick_on_gpu(s.res, max_binding, s.anisotropic) {
                crate::gi::Layout::Dense => crate::gi::shade::VolumeChoice::Dense,
                crate::gi::Layout::Sparse => crate::gi::shade::VolumeChoice::Sparse,
            },
            ..s
        });
        if let Some(s) = settings.filter(|s| s.anisotropic && s.layout() == crate::gi::Layout::Sparse) {
            return Err(crate::gi::GiError::Settings(format!(
                "anisotropic GI levels need the dense volume, and {}³ is sparse on this device: lower --gi-res or \
                 leave out --gi-anisotropic",
                s.res
            ))
            .into());
        }
        if let Some(s) = settings.filter(|s| s.levels == crate::gi::shade::LevelStore::Texture) {
            if s.layout() == crate::gi::Layout::Sparse {
                return Err(crate::gi::GiError::Settings(format!(
                    "texture GI levels need the dense volume, and {}³ is sparse here: use --gi-levels buffer or a \
                     lower --gi-res",
                    s.res
                ))
                .into());
            }
        }
        if settings.is_some() && self.gi.is_none() {
            let gi = super::gi::GpuGi::new(&self.ctx);
            self.gi_pipeline_layout = Some(self.ctx.device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("trace + gi"),
                bind_group_layouts: &[Some(&self.layout), Some(&gi.group1_layout)],
                immediate_size: 0,
            }));
            self.gi = Some(gi);
        }
        self.gi_settings = settings;
        Ok(())
    }

    /// Makes the next frame rebuild its GI volume even if nothing moved (the harness times
    /// whole GI passes on still scenes with it).
    pub fn forget_gi_frame(&mut self) {
        if let Some(gi) = self.gi.as_mut() {
            gi.forget_last_frame();
        }
    }

    /// Bricks the last frame's sparse GI volume allocated, read back from the GPU (None for
    /// a dense volume or without GI). Frames never need it; tools and tests ask for it.
    pub fn gi_bricks(&mut self) -> Result<Option<u32>, GpuError> {
        match self.gi.as_mut() {
            Some(gi) => gi.read_bricks(&self.ctx),
            None => Ok(None),
        }
    }

    /// Most bytes a sparse GI brick pool sized by its bound may take before the frame reads
    /// the brick count back instead (256 MiB; tests lower it to run that path).
    #[doc(hidden)]
    pub fn set_gi_brick_bound_limit(&mut self, bytes: u64) {
        if let Some(gi) = self.gi.as_mut() {
            gi.unread_limit = bytes;
        }
    }

    /// The GI settings in use.
    pub fn gi_settings(&self) -> Option<&crate::gi::GiSettings> {
        self.gi_settings.as_ref()
    }

    /// Builds (once) the injection and GI shading pipelines of a plan variant.
    fn gi_pipeline(
        &mut self,
        search: u32,
        shadows: bool,
        sparse: bool,
        texture: bool,
        aniso: bool,
        cone_shadows: bool,
    ) -> Result<(), GpuError> {
        let (node_split, attr_split) = self.splits();
        let layout = self.gi_pipeline_layout.as_ref().ok_or_else(|| GpuError::Device("GI is off".into()))?;
        let (device, module) = (&self.ctx.device, &self.module);
        self.gi_pipelines.entry((search, shadows, sparse, texture, aniso, cone_shadows)).or_insert_with(|| {
            let constants = [
                ("SEARCH", search as f64),
                ("SHADOWS", shadows as u32 as f64),
                ("GI_SPARSE", sparse as u32 as f64),
                ("GI_TEXTURE", texture as u32 as f64),
                ("GI_ANISO", aniso as u32 as f64),
                ("GI_CONE_SHADOWS", cone_shadows as u32 as f64),
                ("NODE_SPLIT", node_split as f64),
                ("ATTR_SPLIT", attr_split as f64),
            ];
            let make = |entry: &str| plan_pipeline(device, layout, module, entry, &constants);
            super::gi::GiPipelines {
                inject: make("inject_main"),
                shade: make("shade_gi_main"),
                gather: make("gather_half_main"),
                cache_place: make("cache_place_main"),
                cache_trace: make("cache_trace_main"),
                cache_convolve: make("cache_convolve_main"),
                bounce: make("bounce_main"),
                commit: make("bounce_commit_main"),
                tail: make("bounce_tail_main"),
                tail_commit: make("bounce_tail_commit_main"),
            }
        });
        Ok(())
    }

    fn pipeline(&mut self, search: u32, reuse: bool, shadows: bool) -> &(wgpu::ComputePipeline, wgpu::ComputePipeline) {
        let (device, module, layout) = (&self.ctx.device, &self.module, &self.pipeline_layout);
        let (node_split, attr_split) = self.splits();
        self.pipelines.entry((search, reuse, shadows)).or_insert_with(|| {
            let constants = [
                ("SEARCH", search as f64),
                ("REUSE", reuse as u32 as f64),
                ("SHADOWS", shadows as u32 as f64),
                ("NODE_SPLIT", node_split as f64),
                ("ATTR_SPLIT", attr_split as f64),
            ];
            let make = |entry: &str| plan_pipeline(device, layout, module, entry, &constants);
            (make("trace_main"), make("shade_main"))
        })
    }

    /// Uploads the part pools if the scene's parts changed.
    fn upload_parts(&mut self, parts: &[Arc<Svo>]) -> Result<(), GpuError> {
        if self
            .pools
            .as_ref()
            .is_some_and(|p| p.parts.len() == parts.len() && p.parts.iter().zip(parts).all(|(id, s)| id.is(s)))
        {
            return Ok(());
        }
        self.pools = Some(Pools::upload(&self.ctx, parts, self.max_binding)?);
        // The split points are compiled into the pipelines; the bind group names the pools.
        self.kept.bind = None;
        self.pipelines.clear();
        self.gi_pipelines.clear();
        Ok(())
    }

    /// Renders one frame of `scene` as `plan` says (the same contract as `render::render`
    /// with a hit buffer: the GPU keeps the records for the next frame). Errors the device
    /// raises on the way (validation, out of memory, a lost device) are returned, not panics.
    pub fn render(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        lights: &Lights,
        plan: &FramePlan,
        opts: &RenderOptions,
    ) -> Result<Frame, GpuError> {
        let ctx = self.ctx.clone();
        let mut crowd = self.crowd.take();
        let frame = ctx.scoped(|| self.render_frame(scene, camera, lights, plan, opts, crowd.as_mut()));
        self.crowd = crowd;
        if frame.is_err() {
            // A frame that failed after it was submitted (a read-back, or an error its scope
            // caught) may have left its records in the GPU's hit buffer and its colours in the
            // radiance buffer without its conditions stored: the next frame must not reuse
            // them under the older frame's conditions.
            self.state.camera = None;
            self.shaded = None;
        }
        frame
    }

    fn render_frame(
        &mut self,
        scene: &Scene,
        camera: &Camera,
        lights: &Lights,
        plan: &FramePlan,
        opts: &RenderOptions,
        crowd: Option<&mut super::crowd::GpuCrowd>,
    ) -> Result<Frame, GpuError> {
        // Before anything is sized by it (width · height is a u32 product below).
        camera.validate()?;
        let started = std::time::Instant::now();
        let traffic = self.ctx.traffic();
        self.upload_parts(&scene.parts)?;
        let (w, h) = (camera.width, camera.height);
        let n = (w * h) as usize;
        // Last frame's instances, refilled only where they changed when the eye and the rest
        // are the same (the CPU renderer's rule); put back when the frame is done.
        let mut prepared = std::mem::take(&mut self.state.prepared);
        let mut spheres = std::mem::take(&mut self.state.prepared_spheres);
        let splatting = opts.renderer == crate::render::Renderer::Splat;
        let posing = crowd.is_some();
        // A crowd posed on the GPU: only the other instances are prepared here (below).
        let refilled = if posing {
            if splatting || self.gi_settings.is_some() || lights.emitter_sampling() > 0 {
                return Err(GpuError::Crowd(
                    "GI, splats and sampled emitters read the host's transforms: not with cars posed on the GPU".into(),
                ));
            }
            if let Some(c) = crowd.as_deref().filter(|c| c.level() != opts.max_level) {
                return Err(GpuError::Crowd(format!(
                    "the crowd was made for level of detail {}, the frame is traced to {}",
                    c.level(),
                    opts.max_level
                )));
            }
            prepared.clear();
            spheres.clear();
            self.state.prepared_for = Default::default();
            None
        } else {
            prepare_changed(
                scene,
                camera.eye,
                plan.transform,
                opts.max_level,
                &mut prepared,
                &mut spheres,
                &mut self.state.prepared_for,
            )
        };
        // Splatted records are not the ray tracer's: nothing is reused from them, or into them.
        let reuse =
            if plan.hit_buffer && !splatting && !posing && self.hits.as_ref().is_some_and(|b| b.1 == w && b.2 == h) {
                self.state.reuse(camera, scene, &prepared, opts.max_level)
            } else {
                None
            };
        let moved_of = |i: usize| reuse.as_ref().is_some_and(|r| r.moved[i]);
        // (Taken: a frame that fails leaves it empty, so the next one writes every instance.)
        let mut inst_moved = std::mem::take(&mut self.inst_moved);
        // The instances rewritten this frame (ascending; None: all of them).
        let rewritten = match &refilled {
            Some(ids) if inst_moved.len() == prepared.len() => {
                let mut rewritten = ids.clone();
                // An instance that did not change may still enter or leave the moved set (its
                // flag is against the hit buffer's frame, not the last one).
                for (i, was) in inst_moved.iter_mut().enumerate() {
                    let now = moved_of(i);
                    if *was != now {
                        *was = now;
                        rewritten.push(i as u32);
                    }
                }
                if rewritten.len() > ids.len() {
                    rewritten.sort_unstable();
                    rewritten.dedup();
                }
                Some(rewritten)
            }
            _ => {
                inst_moved.clear();
                inst_moved.extend((0..prepared.len()).map(moved_of));
                None
            }
        };
        let moved: Vec<GpuSphere> = reuse.as_ref().map_or(Vec::new(), |r| {
            r.moved_spheres
                .iter()
                .enumerate()
                .map(|(k, &(c, rad, rect))| GpuSphere {
                    sphere: gpu_sphere(c, rad),
                    rect,
                    instance: r.moved_instances[k / 2],
                    pad: [0; 3],
                })
                .collect()
        });
        // Each pixel tests only the moved spheres of its tile's bin (a crowd of 300 driving
        // cars tested 4 800 spheres per pixel); no bins: every sphere.
        let (moved_tiles_x, moved_bins) =
            reuse.as_ref().and_then(|r| r.tile_bins()).map_or((0, &[][..]), |(tx, bins)| (tx as u32, bins));
        // The instance BVH refitted above the instances refilled (when only they changed
        // since it was last fitted: it is last frame's or none), and only its recomputed
        // nodes converted (below); a new or wholly refitted tree is converted whole. It has
        // no wide tree: the GPU walks its own copy.
        let mut bvh_dirty = std::mem::take(&mut self.bvh_dirty);
        let uploaded = std::mem::take(&mut self.bvh_uploaded);
        let bvh = (plan.bvh && !posing)
            .then(|| self.state.take_bvh_changed(&spheres, refilled.as_deref(), &mut bvh_dirty, false));
        let bvh_whole = !matches!(&bvh, Some((b, false)) if uploaded == b.nodes.len());
        let bvh = bvh.map(|(b, _)| b);
        // A crowd posed on the GPU walks its own tree, whose boxes the GPU refits.
        let crowd_tree = crowd.as_deref().map(|c| c.bvh());
        let tree_nodes = crowd_tree.or(bvh.as_ref()).map_or(0, |b| b.nodes.len());
        let items: &[u32] = crowd_tree.or(bvh.as_ref()).map_or(&[], |b| &b.items);
        let instance_count = if posing { scene.instances().len() } else { prepared.len() };
        let emitter_samples = lights.emitter_sampling();
        let emitters = if emitter_samples > 0 { gpu_emitters(scene, camera.eye) } else { Vec::new() };
        let extra_lights = gpu_lights(lights, camera.eye);
        let basis = camera.basis();
        let counting = self.counting;
        let mut frame = GpuFrame {
            forward: f4(basis.forward, basis.tan_half),
            right: f4(basis.right, w as f64 / h as f64),
            up: f4(basis.up, 0.0),
            sun_dir: lights.sun.map_or([0.0; 4], |s| [s.to_sun.x, s.to_sun.y, s.to_sun.z, 1.0]),
            sun_irradiance: lights.sun.map_or([0.0; 4], |s| [s.irradiance.x, s.irradiance.y, s.irradiance.z, 0.0]),
            sky: {
                let s = lights.sky();
                [s.x, s.y, s.z, lights.use_mtl_emitters as u32 as f32]
            },
            width: w,
            height: h,
            instances: instance_count as u32,
            max_level: opts.max_level.min(64),
            moved: moved.len() as u32,
            bvh_nodes: tree_nodes as u32,
            count: counting as u32,
            moved_tiles_x,
            emitters: emitters.len() as u32,
            emitter_samples,
            lights: extra_lights.len() as u32,
            keep_colours: 0,
            moved_bvh_nodes: 0,
            pad4a: 0,
            pad4b: 0,
            pad4c: 0,
        };
        self.ctx.check_binding("the hit buffer", (n * std::mem::size_of::<GpuHit>()) as u64)?;
        // The image-sized buffers: hits and radiance, and their host copies when read back.
        let per_pixel = (std::mem::size_of::<GpuHit>() + 16) as u64 * if self.read_back { 2 } else { 1 };
        self.ctx.check_memory(
            || format!("a {w}×{h} frame on the GPU"),
            n as u64 * per_pixel,
            "lower the resolution or raise the memory budget",
        )?;
        if !self.hits.as_ref().is_some_and(|b| b.1 == w && b.2 == h) {
            let buf = self.ctx.buffer(&wgpu::BufferDescriptor {
                label: Some("hits"),
                size: (n * std::mem::size_of::<GpuHit>()) as u64,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            });
            self.hits = Some((buf, w, h));
            self.kept.bind = None;
        }
        let search = match plan.search() {
            _ if posing => 3,
            Search::Plain => 0,
            Search::Cull => 1,
            Search::CullSort => 2,
            Search::Bvh => 3,
        };
        let reuse_on = reuse.is_some();
        self.pipelines(search, plan.shadows);
        // GI runs where there is light (FramePlan: GI off or no lights at all → skipped; with
        // only the sky the cones still give ambient occlusion).
        let lit = lights.sun.is_some() || lights.has_extra() || lights.use_mtl_emitters || lights.sky() != Vec3::ZERO;
        let gi_work = match (&self.gi_settings, lit) {
            (Some(settings), true) => {
                let settings = *settings;
                let sparse = settings.layout() == crate::gi::Layout::Sparse;
                let texture = settings.levels == crate::gi::shade::LevelStore::Texture;
                self.gi_pipeline(search, plan.shadows, sparse, texture, settings.anisotropic, settings.cone_shadows)?;
                let gi = self.gi.as_mut().ok_or_else(|| GpuError::Device("GI state missing".into()))?;
                Some(gi.prepare(&self.ctx, scene, camera, lights, &settings)?)
            }
            _ => None,
        };
        self.gi_stats = gi_work.as_ref().map(|w| w.stats);
        let splat_work = if splatting {
            let sp = self.splat.get_or_insert_with(|| super::splat::GpuSplat::new(&self.ctx));
            sp.build_pipelines(&self.ctx.device, &self.module, &self.layout, opts.splat_draw);
            Some(sp.prepare(&self.ctx, scene, &prepared, camera, opts.max_level, opts.splat_factor)?)
        } else {
            None
        };
        // Kept hits keep their colours (the CPU's rule, shade_main's twin of it) when the
        // radiance buffer holds the stored frame's colours under the same lights and shadow
        // switch, shaded without GI; emitters and extra lights reach anywhere, and the plain
        // search traces shadow rays without the sphere test the shader's check mirrors, so
        // those frames shade afresh.
        let keep_colours = reuse_on
            && gi_work.is_none()
            && !splatting
            && search != 0
            && emitter_samples == 0
            && !lights.has_extra()
            && self.radiance_size == (w, h)
            && self.shaded.as_ref().is_some_and(|(l, s)| l == lights && *s == plan.shadows);
        frame.keep_colours = keep_colours as u32;
        // Kept pixels' shadow rays walk the moved spheres' BVH when there is one (from
        // MOVED_BVH_MIN spheres on): its tree, with boxes around the spheres as the shader
        // tests them (f32, grown).
        let moved_bvh = reuse.as_ref().and_then(|r| r.moved_bvh.clone()).filter(|_| keep_colours).map(|mut b| {
            let as_tested: Vec<(glam::DVec3, f64)> = moved
                .iter()
                .map(|m| {
                    (glam::DVec3::new(m.sphere[0] as f64, m.sphere[1] as f64, m.sphere[2] as f64), m.sphere[3] as f64)
                })
                .collect();
            b.refit(&as_tested);
            b
        });
        let moved_bvh_nodes = moved_bvh.as_ref().map_or(Vec::new(), gpu_bvh_nodes);
        let moved_bvh_items: Vec<u32> = moved_bvh.as_ref().map_or(Vec::new(), |b| b.items.clone());
        frame.moved_bvh_nodes = moved_bvh_nodes.len() as u32;
        // What the radiance buffer will hold once this frame is submitted (a failed frame
        // leaves it unknown: `render` then forgets it).
        let shaded = (!splatting && gi_work.is_none()).then(|| (lights.clone(), plan.shadows));
        let (trace_pipe, shade_pipe) = &self.pipelines[&(search, reuse_on, plan.shadows)];
        let cone_shadows = self.gi_settings.is_some_and(|s| s.cone_shadows);
        let gi_pipes = gi_work.as_ref().map(|w| {
            let sparse = w.stats.layout == crate::gi::Layout::Sparse;
            &self.gi_pipelines[&(search, plan.shadows, sparse, w.texture, w.aniso, cone_shadows)]
        });
        let ctx = self.ctx.clone();
        let device = &ctx.device;
        // Bindings must not be empty: pad with one zeroed element. Otherwise the bytes are
        // written from where they are (a crowd's instances were copied twice more on the way).
        fn nonempty<T: bytemuck::Pod + Default>(v: &[T]) -> std::borrow::Cow<'_, [u8]> {
            if v.is_empty() {
                std::borrow::Cow::Owned(bytemuck::bytes_of(&T::default()).to_vec())
            } else {
                std::borrow::Cow::Borrowed(bytemuck::cast_slice(v))
            }
        }
        let kept = &mut self.kept;
        let storage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        // The instance buffer holds last frame's instances (a frame that failed dropped its
        // flags, so the next converts and writes them all): only the rewritten ones are sent.
        let inst_size = (instance_count.max(1) * std::mem::size_of::<GpuInstance>()) as u64;
        // (COPY_SRC: the tests read the instances back.)
        let inst_usage = storage | wgpu::BufferUsages::COPY_SRC;
        let mut replaced = ensure(&ctx, &mut kept.insts, "instances", inst_size, false, inst_usage);
        // Up to half of them rewritten, the rewritten ones are scattered into place by a pass
        // (below, once there is an encoder); otherwise all are written, converted straight
        // into memory kept for them (in parallel where the build has threads).
        let scattered =
            rewritten.as_deref().filter(|ids| !replaced && !prepared.is_empty() && ids.len() * 2 <= prepared.len());
        match (kept.insts.as_ref(), crowd.as_deref()) {
            // The crowd's rows are the pose pass's; the others are prepared and written here.
            (Some(buf), Some(crowd)) => write_statics(&ctx, scene, crowd.statics(), camera.eye, opts.max_level, buf),
            (Some(buf), None) if scattered.is_none() => {
                fresh_instances(scene, &prepared, &moved_of, &mut self.inst_scratch);
                ctx.queue.write_buffer(buf, 0, &nonempty(&self.inst_scratch));
            }
            _ => {}
        }
        // Likewise the BVH: its recomputed nodes scattered into place, its items written
        // only with a new tree.
        let nodes_size = (tree_nodes.max(1) * std::mem::size_of::<GpuBvhNode>()) as u64;
        let bvh_replaced = ensure(&ctx, &mut kept.bvh, "bvh", nodes_size, false, storage);
        // The crowd's tree links go up once (its boxes are refitted on the GPU each frame).
        let crowd_links = crowd.as_deref().map(|c| c.id());
        let links_fresh = crowd_links.is_some() && (bvh_replaced || self.crowd_links != crowd_links);
        if let (Some(buf), Some(tree), true) = (kept.bvh.as_ref(), crowd_tree, links_fresh) {
            ctx.queue.write_buffer(buf, 0, &nonempty(&gpu_bvh_nodes(tree)));
        }
        let rewrite = (bvh_whole || bvh_replaced) && !posing;
        let bvh_scattered = Some(&bvh_dirty[..]).filter(|d| !rewrite && !d.is_empty() && d.len() * 2 <= tree_nodes);
        // Unless nothing changed, or the changes are scattered, all of it is converted and
        // written.
        if let (Some(buf), true) =
            (kept.bvh.as_ref(), !posing && (rewrite || (bvh_scattered.is_none() && !bvh_dirty.is_empty())))
        {
            let nodes = bvh.as_ref().map_or_else(Vec::new, gpu_bvh_nodes);
            ctx.queue.write_buffer(buf, 0, &nonempty(&nodes));
        }
        let items_bytes = nonempty(items);
        let items_replaced = ensure(&ctx, &mut kept.items, "bvh items", items_bytes.len() as u64, false, storage);
        if let (Some(buf), true) = (kept.items.as_ref(), (bvh_whole && !posing) || items_replaced || links_fresh) {
            ctx.queue.write_buffer(buf, 0, &items_bytes);
        }
        self.crowd_links = crowd_links;
        replaced |= bvh_replaced | items_replaced;
        let inputs: [Input<'_>; 7] = [
            (
                &mut kept.frame,
                "frame",
                std::borrow::Cow::Borrowed(bytemuck::bytes_of(&frame)),
                wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            ),
            (&mut kept.moved, "moved", nonempty(&moved), storage),
            (&mut kept.moved_bins, "moved bins", nonempty(moved_bins), storage),
            (&mut kept.moved_bvh, "moved bvh", nonempty(&moved_bvh_nodes), storage),
            (&mut kept.moved_bvh_items, "moved bvh items", nonempty(&moved_bvh_items), storage),
            (&mut kept.emitters, "emitters", nonempty(&emitters), storage),
            (&mut kept.lights, "lights", nonempty(&extra_lights), storage),
        ];
        for (slot, label, bytes, usage) in inputs {
            replaced |= ensure(&ctx, slot, label, bytes.len() as u64, false, usage);
            if let Some(buf) = slot.as_ref() {
                ctx.queue.write_buffer(buf, 0, &bytes);
            }
        }
        let image_bytes = (n * 16) as u64;
        let hit_bytes = (n * std::mem::size_of::<GpuHit>()) as u64;
        let copy_src = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC;
        let mappable = wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST;
        replaced |= ensure(&ctx, &mut kept.radiance, "radiance", image_bytes, true, copy_src);
        let stats_bytes = std::mem::size_of::<super::layout::GpuStats>() as u64;
        let stats_usage = copy_src | wgpu::BufferUsages::COPY_DST;
        replaced |= ensure(&ctx, &mut kept.stats, "stats", stats_bytes, true, stats_usage);
        let read_back = self.read_back;
        if counting {
            ensure(&ctx, &mut kept.stats_read, "stats readback", stats_bytes, true, mappable);
        }
        if read_back {
            ensure(&ctx, &mut kept.hits_read, "hits readback", hit_bytes, true, mappable);
            ensure(&ctx, &mut kept.radiance_read, "radiance readback", image_bytes, true, mappable);
        }
        if replaced {
            kept.bind = None;
        }
        let missing = || GpuError::Device("frame buffers missing".into());
        let (inst_buf, frame_buf, bvh_buf, item_buf, moved_buf, radiance_buf) = (
            kept.insts.as_ref().ok_or_else(missing)?,
            kept.frame.as_ref().ok_or_else(missing)?,
            kept.bvh.as_ref().ok_or_else(missing)?,
            kept.items.as_ref().ok_or_else(missing)?,
            kept.moved.as_ref().ok_or_else(missing)?,
            kept.radiance.as_ref().ok_or_else(missing)?,
        );
        let stats_buf = kept.stats.as_ref().ok_or_else(missing)?;
        let emitter_buf = kept.emitters.as_ref().ok_or_else(missing)?;
        let light_buf = kept.lights.as_ref().ok_or_else(missing)?;
        let bins_buf = kept.moved_bins.as_ref().ok_or_else(missing)?;
        let moved_bvh_buf = kept.moved_bvh.as_ref().ok_or_else(missing)?;
        let moved_items_buf = kept.moved_bvh_items.as_ref().ok_or_else(missing)?;
        let pools = self.pools.as_ref().ok_or_else(|| GpuError::Device("pools not uploaded".into()))?;
        let hits_buf = &self.hits.as_ref().ok_or_else(|| GpuError::Device("no hit buffer".into()))?.0;
        use super::prelude::binding as b;
        let bind = kept.bind.get_or_insert_with(|| {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("trace"),
                layout: &self.layout,
                entries: &[
                    wgpu::BindGroupEntry { binding: b::NODES, resource: pools.nodes.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::ATTRS, resource: pools.attrs.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::PARTS, resource: pools.infos.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::INSTS, resource: inst_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::FRAME, resource: frame_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::BVH, resource: bvh_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::BVH_ITEMS, resource: item_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::HITS, resource: hits_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::MOVED, resource: moved_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::RADIANCE, resource: radiance_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::NODES_HI, resource: pools.nodes_hi.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::ATTRS_HI, resource: pools.attrs_hi.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::STATS, resource: stats_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::EMITTERS, resource: emitter_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::LIGHTS, resource: light_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::MOVED_BINS, resource: bins_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::MOVED_BVH, resource: moved_bvh_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: b::MOVED_BVH_ITEMS, resource: moved_items_buf.as_entire_binding() },
                ],
            })
        });
        let buffer_bytes: u64 = [
            &pools.nodes,
            &pools.attrs,
            &pools.infos,
            &pools.nodes_hi,
            &pools.attrs_hi,
            inst_buf,
            frame_buf,
            bvh_buf,
            item_buf,
            hits_buf,
            moved_buf,
            radiance_buf,
            stats_buf,
            emitter_buf,
            light_buf,
            bins_buf,
            moved_bvh_buf,
            moved_items_buf,
        ]
        .iter()
        .map(|b| b.size())
        .sum();
        if ctx.timestamps && (read_back || counting) && kept.queries.is_none() {
            let set = device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("passes"),
                ty: wgpu::QueryType::Timestamp,
                count: 12,
            });
            let resolve = ctx.buffer(&wgpu::BufferDescriptor {
                label: Some("timestamps"),
                size: 96,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            });
            let read_back = ctx.buffer(&wgpu::BufferDescriptor {
                label: Some("timestamps readback"),
                size: 96,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            kept.queries = Some((set, resolve, read_back));
        }
        // Pass times are read back too: not measured in frames that stay on the GPU.
        let queries = kept.queries.as_ref().filter(|_| read_back || counting);
        let ts = |k: u32| {
            queries.map(|(set, _, _)| wgpu::ComputePassTimestampWrites {
                query_set: set,
                beginning_of_pass_write_index: Some(2 * k),
                end_of_pass_write_index: Some(2 * k + 1),
            })
        };
        let mut enc = device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("frame") });
        if let Some(ids) = scattered {
            let scatter = self.scatter_insts.get_or_insert_with(|| super::scatter::ScatterRows::new(&ctx));
            scatter.encode(&ctx, &mut enc, inst_buf, ids, |i| {
                gpu_instance(scene, &prepared[i as usize], moved_of(i as usize))
            });
        }
        if let Some(ids) = bvh_scattered {
            let scatter = self.scatter_bvh.get_or_insert_with(|| super::scatter::ScatterRows::new(&ctx));
            let nodes = bvh.as_ref().map_or(&[][..], |b| &b.nodes[..]);
            scatter.encode(&ctx, &mut enc, bvh_buf, ids, |n| gpu_bvh_node(&nodes[n as usize]));
        }
        if let Some(crowd) = crowd {
            // The cars posed into their rows, then the tree refitted around them.
            // Timed in the GI passes' query slots (a crowd's frames have no GI), from the
            // pose pass's start to the refit's end.
            let (start, end) = match queries {
                Some((set, _, _)) => (
                    Some(wgpu::ComputePassTimestampWrites {
                        query_set: set,
                        beginning_of_pass_write_index: Some(4),
                        end_of_pass_write_index: None,
                    }),
                    Some(wgpu::ComputePassTimestampWrites {
                        query_set: set,
                        beginning_of_pass_write_index: None,
                        end_of_pass_write_index: Some(5),
                    }),
                ),
                None => (None, None),
            };
            crowd.encode(scene, &mut enc, self.crowd_time, camera.eye, inst_buf, start)?;
            crowd.encode_refit(&mut enc, inst_buf, bvh_buf, end)?;
        }
        if counting {
            enc.clear_buffer(stats_buf, 0, None);
        }
        let groups = (w.div_ceil(8), h.div_ceil(8));
        match (&splat_work, self.splat.as_mut()) {
            (Some(work), Some(sp)) => sp.encode(&ctx, &mut enc, bind, work, (w, h), opts.splat_draw, ts(0))?,
            _ => {
                let mut pass = enc
                    .begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("trace"), timestamp_writes: ts(0) });
                pass.set_pipeline(trace_pipe);
                pass.set_bind_group(0, &*bind, &[]);
                pass.dispatch_workgroups(groups.0, groups.1, 1);
            }
        }
        if let (Some(work), Some(pipes), Some(gi)) = (&gi_work, gi_pipes, &self.gi) {
            gi.encode(work, &mut enc, pipes, bind, ts(2))?;
        }
        // The radiance caches before the shading that reads them: placed per tile, traced,
        // convolved, each its own pass with its own timestamps.
        if let (Some(work), Some(pipes)) = (&gi_work, gi_pipes) {
            if let Some(dims) = work.caches {
                let passes = [
                    ("cache placement", &pipes.cache_place),
                    ("cache tracing", &pipes.cache_trace),
                    ("cache convolution", &pipes.cache_convolve),
                ];
                for (k, ((label, pipe), d)) in passes.into_iter().zip(dims).enumerate() {
                    let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                        label: Some(label),
                        timestamp_writes: ts(3 + k as u32),
                    });
                    pass.set_bind_group(0, &*bind, &[]);
                    pass.set_bind_group(1, &work.group1, &[]);
                    pass.set_pipeline(pipe);
                    if d.0 > 0 && d.1 > 0 {
                        pass.dispatch_workgroups(d.0, d.1, 1);
                    }
                }
            }
        }
        {
            let mut pass =
                enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("shade"), timestamp_writes: ts(1) });
            match (&gi_work, gi_pipes) {
                (Some(work), Some(pipes)) => {
                    pass.set_bind_group(0, &*bind, &[]);
                    pass.set_bind_group(1, &work.group1, &[]);
                    if work.half {
                        // The samples first, one per 2×2 block (in the same pass: its time is
                        // the shading's, and each dispatch sees the one before's writes).
                        pass.set_pipeline(&pipes.gather);
                        pass.dispatch_workgroups(w.div_ceil(2).div_ceil(8), h.div_ceil(2).div_ceil(8), 1);
                    }
                    pass.set_pipeline(&pipes.shade);
                }
                _ => {
                    pass.set_pipeline(shade_pipe);
                    pass.set_bind_group(0, &*bind, &[]);
                }
            }
            pass.dispatch_workgroups(groups.0, groups.1, 1);
        }
        let capture = match (&self.gi, &gi_work) {
            (Some(gi), Some(work)) if self.gi_capture => gi.copy_capture(&self.ctx, work, &mut enc),
            _ => None,
        };
        let n_ts = match &gi_work {
            Some(w) if w.caches.is_some() => 12,
            Some(_) => 6,
            None if posing => 6,
            None => 4,
        };
        let readbacks = if read_back {
            let (hits_rb, rad_rb) =
                (kept.hits_read.as_ref().ok_or_else(missing)?, kept.radiance_read.as_ref().ok_or_else(missing)?);
            enc.copy_buffer_to_buffer(hits_buf, 0, hits_rb, 0, hit_bytes);
            enc.copy_buffer_to_buffer(radiance_buf, 0, rad_rb, 0, image_bytes);
            Some((hits_rb, rad_rb))
        } else {
            None
        };
        let stats_rb = match (counting, kept.stats_read.as_ref()) {
            (true, Some(rb)) => {
                enc.copy_buffer_to_buffer(stats_buf, 0, rb, 0, stats_bytes);
                Some(rb)
            }
            _ => None,
        };
        // Only the passes that ran wrote their timestamps.
        let ts_rb = queries.map(|(set, resolve, read_back)| {
            enc.resolve_query_set(set, 0..n_ts, resolve, 0);
            enc.copy_buffer_to_buffer(resolve, 0, read_back, 0, 8 * n_ts as u64);
            read_back
        });
        self.ctx.queue.submit([enc.finish()]);
        self.submit_host_ms = started.elapsed().as_secs_f64() * 1e3;
        // From here the host waits for the device: a pool thread kept spinning for the
        // frame's host work would only take a core from the driver.
        crate::pool::rest();
        #[cfg(test)]
        if std::mem::take(&mut self.fail_after_submit) {
            return Err(GpuError::Readback("failed on purpose after the submit (test)".into()));
        }
        self.radiance_size = (w, h);
        self.shaded = shaded;
        self.stats = match stats_rb {
            Some(rb) => read::<super::layout::GpuStats>(&self.ctx, rb)?.first().copied(),
            None => None,
        };
        let times = match ts_rb {
            Some(b) => {
                // Only the passes that ran wrote their timestamps; only those are read.
                let ts: Vec<u64> = read_first(&self.ctx, b, 8 * n_ts as u64)?;
                let period = self.ctx.queue.get_timestamp_period() as f64 * 1e-6;
                Some(GpuTimes {
                    trace_ms: ts[1].saturating_sub(ts[0]) as f64 * period,
                    shade_ms: ts[3].saturating_sub(ts[2]) as f64 * period,
                    gi_ms: if gi_work.is_some() { ts[5].saturating_sub(ts[4]) as f64 * period } else { 0.0 },
                    crowd_ms: posing.then(|| ts[5].saturating_sub(ts[4]) as f64 * period),
                    cache_ms: (n_ts == 12).then(|| [6, 8, 10].map(|k| ts[k + 1].saturating_sub(ts[k]) as f64 * period)),
                })
            }
            None => None,
        };
        let Some((hits_rb, rad_rb)) = readbacks else {
            // The frame stays on the GPU: nothing is waited for or copied but what counting
            // asked for. The next frame reuses the records in the GPU's hit buffer under the
            // conditions kept here.
            self.times = times;
            self.gi_captured = match (capture, &self.gi, &gi_work) {
                (Some(bufs), Some(gi), Some(work)) => Some(gi.read_capture(&self.ctx, work, &bufs)?),
                _ => None,
            };
            self.state.reused = 0;
            if plan.keep_hits && !splatting && !posing {
                self.state.store_kept_elsewhere(camera, scene, &prepared, opts.max_level);
            } else {
                // Nothing to keep (splatted records are not the ray tracer's, or the hit
                // buffer is off: a crowd's copy of every world transform cost 2 ms a frame):
                // a later frame with reuse starts afresh.
                self.state.camera = None;
            }
            self.state.bvh = bvh;
            self.buffer_bytes =
                buffer_bytes + self.gi_stats.map_or(0, |g| g.bytes) + splat_work.as_ref().map_or(0, |s| s.bytes);
            let now = self.ctx.traffic();
            self.frame_traffic = (now.0 - traffic.0, now.1 - traffic.1);
            self.keep_instances(&scene.parts, prepared, spheres, inst_moved);
            (self.bvh_uploaded, self.bvh_dirty) = (if posing { 0 } else { tree_nodes }, bvh_dirty);
            let st = self.stats.unwrap_or_default();
            return Ok(Frame {
                width: w,
                height: h,
                primary_rays: n as u64,
                reused: st.reused as u64,
                moved_only: st.moved_only as u64,
                instances_traced: st.instances_traced as u64,
                spheres_culled: st.spheres_culled as u64,
                shadow_rays: st.shadow_rays as u64,
                shade_reused: st.shade_reused as u64,
                gathers: st.gathers as u64,
                on_device: true,
                ..Frame::default()
            });
        };
        let hits: Vec<GpuHit> = read(&self.ctx, hits_rb)?;
        let rad: Vec<[f32; 4]> = read(&self.ctx, rad_rb)?;
        self.times = times;

        self.gi_captured = match (capture, &self.gi, &gi_work) {
            (Some(bufs), Some(gi), Some(work)) => Some(gi.read_capture(&self.ctx, work, &bufs)?),
            _ => None,
        };
        let records: Vec<HitRecord> = hits
            .iter()
            .map(|g| {
                if g.instance < 0 {
                    HitRecord::MISS
                } else {
                    HitRecord {
                        t: g.t,
                        instance: g.instance,
                        normal: Vec3::new(g.nx, g.ny, g.nz),
                        face_normal: Vec3::new(g.fx, g.fy, g.fz),
                        attr: Attr { albedo: g.albedo, normal: g.material, emission: g.emission },
                        voxel: g.voxel,
                    }
                }
            })
            .collect();
        // Counted by the passes when counting is on; otherwise the sun's (one per pixel facing
        // it), which leaves out the emitters' rays.
        let shadow_rays = match (self.stats, lights.sun.filter(|_| plan.shadows)) {
            (Some(st), _) => st.shadow_rays as u64,
            (None, Some(sun)) => {
                records.iter().filter(|r| r.instance >= 0 && r.normal.dot(sun.to_sun) > 0.0).count() as u64
            }
            (None, None) => 0,
        };
        let f = Frame {
            width: w,
            height: h,
            radiance: rad.iter().map(|c| Vec3::new(c[0], c[1], c[2])).collect(),
            t: records.iter().map(|r| r.t).collect(),
            instance: records.iter().map(|r| r.instance).collect(),
            normal: records.iter().map(|r| r.normal).collect(),
            albedo: records.iter().map(|r| if r.instance >= 0 { r.attr.albedo_linear() } else { Vec3::ZERO }).collect(),
            specular: records.iter().map(|r| if r.instance >= 0 { r.attr.specular() } else { 0.0 }).collect(),
            shininess: records
                .iter()
                .map(|r| crate::render::brdf::shininess_of_gloss_bits(r.attr.gloss_bits()))
                .collect(),
            primary_rays: n as u64,
            // The low two bits say how the record was found; 8, that its colour was kept.
            reused: hits.iter().filter(|g| g.reused & 3 == 1).count() as u64,
            shadow_rays,
            shade_reused: hits.iter().filter(|g| g.reused & 8 != 0).count() as u64,
            moved_only: hits.iter().filter(|g| g.reused & 3 == 2).count() as u64,
            instances_traced: hits.iter().map(|g| (g.work & 0xFFFF) as u64).sum(),
            spheres_culled: hits.iter().map(|g| (g.work >> 16) as u64).sum(),
            on_device: false,
            // The GI shading writes the cones' open fraction into the radiance's w.
            ao: if self.gi_stats.is_some() { rad.iter().map(|c| c[3]).collect() } else { Vec::new() },
            // Counted by the GI passes when counting is on (0 otherwise).
            gathers: self.stats.map_or(0, |st| st.gathers as u64),
            cache_stages: None,
        };
        self.state.reused = f.reused;
        if plan.keep_hits && !splatting && !posing {
            self.state.store(camera, scene, &prepared, records, opts.max_level);
        } else {
            // Nothing to keep: a later frame with reuse starts afresh.
            self.state.camera = None;
        }
        self.state.bvh = bvh;
        self.buffer_bytes =
            buffer_bytes + self.gi_stats.map_or(0, |g| g.bytes) + splat_work.as_ref().map_or(0, |s| s.bytes);
        let now = self.ctx.traffic();
        self.frame_traffic = (now.0 - traffic.0, now.1 - traffic.1);
        self.keep_instances(&scene.parts, prepared, spheres, inst_moved);
        (self.bvh_uploaded, self.bvh_dirty) = (if posing { 0 } else { tree_nodes }, bvh_dirty);
        Ok(f)
    }

    /// Keeps a finished frame's instances for the next frame to refill (a failed frame's are
    /// dropped, and the next frame prepares every instance afresh).
    fn keep_instances(
        &mut self,
        parts: &[Arc<crate::svo::Svo>],
        prepared: Vec<Prepared>,
        spheres: Vec<(glam::DVec3, f64)>,
        inst_moved: Vec<bool>,
    ) {
        self.state.prepared = prepared;
        self.state.prepared_spheres = spheres;
        self.inst_moved = inst_moved;
        self.parts_kept.clear();
        self.parts_kept.extend_from_slice(parts);
    }

    /// Whether the last frame's eye lies inside a voxel
    /// ([`crate::render::instances::eye_inside`]): what frames kept on the GPU say only
    /// there, in their t values. Found when asked, not every frame (a crowd's 80 000
    /// spheres took 0.2 ms a frame to read).
    pub fn eye_inside(&self) -> bool {
        crate::render::instances::eye_inside_listed(
            &self.parts_kept,
            &self.state.prepared,
            &self.state.prepared_spheres,
        )
    }
}

/// A buffer the frame writes: its slot, label, bytes and usage.
type Input<'a> = (&'a mut Option<wgpu::Buffer>, &'static str, std::borrow::Cow<'a, [u8]>, wgpu::BufferUsages);

/// Prepares the instances `ids` (ascending) for a camera at `eye` and writes their rows of
/// `buf`, a queue write per run of consecutive ones (the instances a crowd posed on the GPU
/// does not place: a ground, a few props).
fn write_statics(ctx: &GpuContext, scene: &Scene, ids: &[u32], eye: glam::DVec3, max_level: u32, buf: &wgpu::Buffer) {
    if ids.is_empty() {
        return;
    }
    let boxes = crate::render::instances::part_boxes(scene, max_level);
    let mut slot = Prepared::BLANK;
    let row = std::mem::size_of::<GpuInstance>() as u64;
    let mut run: Vec<GpuInstance> = Vec::new();
    let mut start = ids[0];
    for (k, &i) in ids.iter().enumerate() {
        // Each instance's own map, as prepare_into makes it (with transforms).
        crate::render::instances::fill_slot(scene, eye, true, &boxes, i as usize, &mut slot);
        run.push(gpu_instance(scene, &slot, false));
        if ids.get(k + 1) != Some(&(i + 1)) {
            ctx.queue.write_buffer(buf, start as u64 * row, bytemuck::cast_slice(&run));
            run.clear();
            start = ids.get(k + 1).copied().unwrap_or(0);
        }
    }
}

/// Every instance converted for upload, in parallel where the build has threads.
fn fresh_instances(
    scene: &Scene,
    prepared: &[Prepared],
    moved_of: &(dyn Fn(usize) -> bool + Sync),
    out: &mut Vec<GpuInstance>,
) {
    #[cfg(feature = "parallel")]
    {
        use rayon::prelude::*;
        prepared.par_iter().enumerate().map(|(i, p)| gpu_instance(scene, p, moved_of(i))).collect_into_vec(out);
    }
    #[cfg(not(feature = "parallel"))]
    {
        out.clear();
        out.extend(prepared.iter().enumerate().map(|(i, p)| gpu_instance(scene, p, moved_of(i))));
    }
}

/// The frame's suns, points and spots besides the sun, camera-relative.
fn gpu_lights(lights: &Lights, eye: glam::DVec3) -> Vec<GpuLight> {
    let v = |v: Vec3, w: f32| [v.x, v.y, v.z, w];
    let suns = lights.suns.iter().map(|s| GpuLight { a: v(s.to_sun, 0.0), b: v(s.irradiance, 0.0), c: [0.0; 4] });
    let points =
        lights.points.iter().map(|p| GpuLight { a: f4(p.position - eye, 1.0), b: v(p.intensity, 0.0), c: [0.0; 4] });
    let spots = lights.spots.iter().map(|s| GpuLight {
        a: f4(s.position - eye, 2.0),
        b: v(s.intensity, s.inner_deg.to_radians().cos()),
        c: v(s.direction, s.outer_deg.to_radians().cos()),
    });
    suns.chain(points).chain(spots).collect()
}

/// The frame's emitter rows ([`crate::render::emitters::EmitterTable`] made for the eye).
fn gpu_emitters(scene: &Scene, eye: glam::DVec3) -> Vec<GpuEmitter> {
    let table = crate::render::emitters::EmitterTable::new(scene, eye);
    let mut before = 0.0;
    table
        .emitters
        .iter()
        .zip(&table.cdf)
        .map(|(e, &c)| {
            let p = c - before;
            before = c;
            GpuEmitter {
                a: f4(e.a, e.margin),
                e1: f4(e.e1, e.area),
                e2: f4(e.e2, c),
                normal: f4(e.normal, p),
                emission: [e.emission.x, e.emission.y, e.emission.z, 0.0],
            }
        })
        .collect()
}

pub(crate) fn gpu_instance(scene: &Scene, p: &Prepared, moved: bool) -> GpuInstance {
    let (m, t) = match p.to_unit {
        ToUnit::Affine(a) => (a.matrix3, a.translation),
        ToUnit::Scale { offset, inv_size } => (DMat3::from_diagonal(glam::DVec3::splat(inv_size)), offset),
    };
    let row = |i: usize| [m.col(0)[i] as f32, m.col(1)[i] as f32, m.col(2)[i] as f32, t[i] as f32];
    // Normals map by the transpose of the ray map's linear part (Prepared::normal_to_world),
    // scaled to entries about 1 so that f32 holds it at any instance scale: row i is column i.
    let big = m.x_axis.abs().max(m.y_axis.abs()).max(m.z_axis.abs()).max_element();
    let unit = if big > 0.0 && big.is_finite() { 1.0 / big } else { 1.0 };
    let nrow = |i: usize| {
        let c = m.col(i) * unit;
        [c.x as f32, c.y as f32, c.z as f32, 0.0]
    };
    GpuInstance {
        to_unit_x: row(0),
        to_unit_y: row(1),
        to_unit_z: row(2),
        normal_x: nrow(0),
        normal_y: nrow(1),
        normal_z: nrow(2),
        sphere: gpu_sphere(p.centre, p.radius),
        part: p.part as u32,
        stretch_size: (p.max_stretch * scene.parts[p.part].bounds.size as f64) as f32,
        moved: moved as u32,
        radius: p.radius as f32,
    }
}

/// Maps a MAP_READ buffer and copies it out.
pub fn read<T: bytemuck::Pod>(ctx: &GpuContext, buf: &wgpu::Buffer) -> Result<Vec<T>, GpuError> {
    read_first(ctx, buf, buf.size())
}

/// Maps the first `bytes` of a MAP_READ buffer and copies them out.
pub fn read_first<T: bytemuck::Pod>(ctx: &GpuContext, buf: &wgpu::Buffer, bytes: u64) -> Result<Vec<T>, GpuError> {
    let slice = buf.slice(..bytes);
    let (tx, rx) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    ctx.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| GpuError::Readback(e.to_string()))?;
    rx.recv().map_err(|e| GpuError::Readback(e.to_string()))?.map_err(|e| GpuError::Readback(e.to_string()))?;
    let data = slice.get_mapped_range().map_err(|e| GpuError::Readback(e.to_string()))?;
    ctx.note_read_back(data.len() as u64);
    let out = bytemuck::cast_slice(&data).to_vec();
    drop(data);
    buf.unmap();
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::Features;
    use crate::scene::{Instance, Transform};
    use crate::svo::Cube;
    use glam::DVec3;

    /// The first `n` instances of the GPU's instance buffer, as the last frame left it.
    fn uploaded_instances(gpu: &GpuRenderer, n: usize) -> Vec<GpuInstance> {
        let ctx = &gpu.ctx;
        let src = gpu.kept.insts.as_ref().expect("an instance buffer");
        let bytes = (n * std::mem::size_of::<GpuInstance>()) as u64;
        let rb = ctx.buffer(&wgpu::BufferDescriptor {
            label: Some("instances read back"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        enc.copy_buffer_to_buffer(src, 0, &rb, 0, bytes);
        ctx.queue.submit([enc.finish()]);
        read(ctx, &rb).expect("instances read back")
    }

    use crate::gpu::context::test_context as context;

    /// A camera in front of [`two_blocks`].
    fn blocks_camera() -> Camera {
        Camera {
            eye: DVec3::new(0.0, 1.0, 6.0),
            target: DVec3::new(0.0, 0.5, 0.0),
            up: DVec3::Y,
            vfov_deg: 50.0,
            width: 64,
            height: 40,
        }
    }

    /// A 4×4×4 block of voxels as a scene of two instances side by side.
    fn two_blocks() -> Scene {
        let coords: Vec<[u32; 3]> = (0..64).map(|i| [i % 4, i / 4 % 4, i / 16]).collect();
        let grid = crate::voxelize::VoxelGrid::from_coords(2, Cube { min: Vec3::ZERO, size: 1.0 }, coords, Vec3::ONE);
        let mut scene = Scene::new(vec![Arc::new(crate::svo::build(&grid).expect("block"))]);
        for x in [-1.5, 0.5] {
            let local = Transform::from_translation(DVec3::new(x, 0.0, 0.0));
            scene.add(Instance { part: 0, parent: None, local }).expect("instance");
        }
        scene.update().expect("update");
        scene
    }

    /// A frame kept on the GPU says whether its eye is inside a voxel when asked: a block's
    /// eye inside it, then outside, then inside again (frames read back too). Each frame
    /// gives its host time up to the submit.
    #[test]
    fn the_eye_inside_a_block_is_found_after_a_frame_on_the_gpu() {
        let Some(ctx) = context() else { return };
        let scene = two_blocks();
        let lights = Lights::default();
        let opts = RenderOptions::default();
        let mut gpu = GpuRenderer::new(ctx);
        assert!(!gpu.eye_inside(), "no frame yet");
        // The second block spans x 0.5…1.5 (and y, z 0…1).
        for (f, (x, inside, read_back)) in
            [(1.0, true, false), (3.0, false, false), (0.9, true, false), (1.1, true, true)].into_iter().enumerate()
        {
            gpu.set_read_back(read_back);
            let camera = Camera { eye: DVec3::new(x, 0.5, 0.5), target: DVec3::new(x, 0.5, -5.0), ..blocks_camera() };
            let plan = FramePlan::new(&scene, &camera, &lights, &Features::default(), Some(&gpu.state));
            gpu.submit_host_ms = -1.0;
            gpu.render(&scene, &camera, &lights, &plan, &opts).expect("frame");
            assert_eq!(gpu.eye_inside(), inside, "frame {f}");
            assert!(gpu.submit_host_ms >= 0.0 && gpu.submit_host_ms.is_finite(), "frame {f}: no host time");
        }
    }

    /// A frame that fails after its submit (as a failed read-back would) leaves its records in
    /// the GPU's hit buffer: the frame after it, back where the last good frame was, must not
    /// keep them as that frame's. Without the reset in `render` the third frame showed the
    /// failed frame's block.
    #[test]
    fn a_frame_failed_after_its_submit_is_not_reused() {
        let Some(ctx) = context() else { return };
        let mut scene = two_blocks();
        let camera = blocks_camera();
        let lights = Lights::default();
        let opts = RenderOptions::default();
        let mut gpu = GpuRenderer::new(ctx.clone());
        let plan = |scene: &Scene, gpu: &GpuRenderer| {
            FramePlan::new(scene, &camera, &lights, &Features::default(), Some(&gpu.state))
        };
        let first = gpu.render(&scene, &camera, &lights, &plan(&scene, &gpu), &opts).expect("first frame");
        let here = Transform::from_translation(DVec3::new(0.5, 0.0, 0.0));
        scene.set_local(1, Transform::from_translation(DVec3::new(0.5, 2.0, 0.0))).expect("move");
        scene.update().expect("update");
        gpu.fail_after_submit = true;
        assert!(gpu.render(&scene, &camera, &lights, &plan(&scene, &gpu), &opts).is_err());
        scene.set_local(1, here).expect("move back");
        scene.update().expect("update");
        let third = gpu.render(&scene, &camera, &lights, &plan(&scene, &gpu), &opts).expect("third frame");
        assert!(first.instance.iter().filter(|&&i| i == 1).count() > 50, "the second block is in view");
        let differ = first.instance.iter().zip(&third.instance).filter(|(a, b)| a != b).count();
        assert_eq!(differ, 0, "{differ} pixels show another instance than the first frame");
        assert_eq!(first.radiance, third.radiance);
    }

    /// The instances a frame uploads, converted only where they changed, equal every instance
    /// converted afresh with the moved flags the hit buffer gives: over a block that moves,
    /// stops (its flag must fall though nothing was refilled), moves again, and a camera
    /// that moves (everything refilled).
    #[test]
    fn instances_converted_where_they_changed_equal_fresh_ones() {
        let Some(ctx) = context() else { return };
        let mut scene = two_blocks();
        let mut camera = blocks_camera();
        let lights = Lights::default();
        let opts = RenderOptions::default();
        let mut gpu = GpuRenderer::new(ctx);
        let heights = [0.0, 0.3, 0.3, 0.6, 0.6, 0.6];
        for (f, &y) in heights.iter().enumerate() {
            scene.set_local(1, Transform::from_translation(DVec3::new(0.5, y, 0.0))).expect("move");
            scene.update().expect("update");
            if f == 5 {
                camera.eye.x += 0.25;
            }
            let plan = FramePlan::new(&scene, &camera, &lights, &Features::default(), Some(&gpu.state));
            let prepared = crate::render::instances::prepare(&scene, camera.eye, plan.transform);
            let moved = match gpu.state.reuse(&camera, &scene, &prepared, opts.max_level) {
                Some(r) if f > 0 => r.moved,
                _ => vec![false; prepared.len()],
            };
            gpu.render(&scene, &camera, &lights, &plan, &opts).expect("frame");
            let fresh: Vec<GpuInstance> =
                prepared.iter().zip(&moved).map(|(p, &m)| gpu_instance(&scene, p, m)).collect();
            assert_eq!(uploaded_instances(&gpu, fresh.len()), fresh, "frame {f}");
            assert_eq!(gpu.inst_moved, moved, "frame {f}");
        }
    }

    /// With few of many instances changed, only theirs are written to the GPU's instance
    /// buffer, and only the BVH nodes above them refitted and written (both scattered into
    /// place by a pass): a row of 40 blocks where one or two move a frame (apart, and side by
    /// side) renders what a renderer that writes everything afresh renders.
    #[test]
    fn instances_written_where_they_changed_render_as_fresh_ones() {
        let Some(ctx) = context() else { return };
        let mut scene = two_blocks();
        let at = |i: usize, y: f64| Transform::from_translation(DVec3::new(i as f64 * 1.25 - 25.0, y, 0.0));
        for i in 2..40 {
            scene.add(Instance { part: 0, parent: None, local: at(i, 0.0) }).expect("instance");
        }
        for i in 0..2 {
            scene.set_local(i, at(i, 0.0)).expect("place");
        }
        scene.update().expect("update");
        let camera = Camera {
            eye: DVec3::new(0.0, 6.0, 30.0),
            target: DVec3::new(0.0, 0.0, 0.0),
            up: DVec3::Y,
            vfov_deg: 60.0,
            width: 160,
            height: 48,
        };
        let lights = Lights::default();
        let opts = RenderOptions::default();
        let features = Features { hit_buffer: false, ..Features::default() };
        let mut kept = GpuRenderer::new(ctx.clone());
        let moves: [&[usize]; 4] = [&[], &[7], &[7, 30], &[20, 21]];
        for (f, ids) in moves.iter().enumerate() {
            for &i in ids.iter() {
                scene.set_local(i, at(i, 0.5 * f as f64)).expect("move");
            }
            scene.update().expect("update");
            let plan = FramePlan::new(&scene, &camera, &lights, &features, None);
            let a = kept.render(&scene, &camera, &lights, &plan, &opts).expect("kept frame");
            let b = GpuRenderer::new(ctx.clone()).render(&scene, &camera, &lights, &plan, &opts).expect("fresh frame");
            for &i in ids.iter() {
                assert!(b.instance.contains(&(i as i32)), "frame {f}: block {i} is out of view");
            }
            assert_eq!(a.instance, b.instance, "frame {f}");
            assert_eq!(a.t, b.t, "frame {f}");
        }
    }
}
