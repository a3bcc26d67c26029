//! Square splats on the GPU: the twin of [`crate::render::splat`] in `wgsl/splat.wgsl`. The
//! parts' surface-voxel lists are built on the host (the same cached lists and levels as the
//! CPU's) and uploaded to a pool when a frame needs one the pool lacks; each frame uploads
//! one row per drawn instance (its object → camera map, from the same
//! [`Projection`](crate::render::splat::Projection) the CPU uses) and runs three passes: the
//! nearest depth per pixel, the lowest splat number at that depth, and the resolve into the
//! tracer's hit buffer, which the shading pass then reads as if the rays had written it.
//! With [`SplatDraw::Quads`] the rasterizer draws the squares instead of the first two
//! passes (one instanced quad per splat, a depth test) and a copy pass hands its winners to
//! the same resolve.

use super::context::{GpuContext, GpuError};
use super::layout::{GpuSplatEntry, GpuSplatFrame};
use super::renderer::ensure;
use crate::render::instances::Prepared;
use crate::render::splat::{Projection, SplatCache, Splats};
use crate::render::SplatDraw;
use crate::scene::{Camera, Scene};
use crate::svo::Attr;
use std::sync::Arc;

/// The quads' colour target: the depth key and the complemented splat number per pixel.
const WORD_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rg32Uint;

/// The quads' depth buffer: f32, so the depths of `splat_quad_depth` (`wgsl/splat.wgsl`) keep
/// every key apart.
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// Threads per group of the per-splat passes (`@workgroup_size(256)` in `splat.wgsl`).
const GROUP: u32 = 256;

/// Most workgroups along one dispatch dimension (WebGPU's limit).
const MAX_GROUPS: u32 = 65_535;

/// The splat passes' state kept between frames.
pub(crate) struct GpuSplat {
    layout: wgpu::BindGroupLayout,
    pipelines: Option<[wgpu::ComputePipeline; 3]>,
    /// The rasterizer's layout of the quads' target (group 3 of the copy pass).
    raster_layout: wgpu::BindGroupLayout,
    /// The quads' pipeline and the pass that copies their target into the buffers.
    raster: Option<(wgpu::RenderPipeline, wgpu::ComputePipeline)>,
    /// The quads' colour and depth targets, the copy's bind group, and their size.
    targets: Option<(wgpu::TextureView, wgpu::TextureView, wgpu::BindGroup, (u32, u32))>,
    cache: SplatCache,
    /// The lists in the pools, in pool order, with their first element there.
    pooled: Vec<(Arc<Splats>, u32)>,
    centres: Option<wgpu::Buffer>,
    attrs: Option<wgpu::Buffer>,
    entries: Option<wgpu::Buffer>,
    uniforms: Option<wgpu::Buffer>,
    depth: Option<wgpu::Buffer>,
    ids: Option<wgpu::Buffer>,
    bind: Option<wgpu::BindGroup>,
}

/// What one frame's splat passes dispatch.
pub(crate) struct SplatWork {
    /// Workgroups of the per-splat passes (x, y); (0, 0) when nothing is drawn.
    groups: (u32, u32),
    /// Splats drawn (the quads' instance count).
    total: u32,
    /// Bytes of the splat buffers.
    pub bytes: u64,
}

fn entry(binding: u32, ty: wgpu::BufferBindingType) -> wgpu::BindGroupLayoutEntry {
    // What the quads' vertex stage reads is visible to it too (it may not see writable
    // storage).
    let visibility = match ty {
        wgpu::BufferBindingType::Storage { read_only: false } => wgpu::ShaderStages::COMPUTE,
        _ => wgpu::ShaderStages::COMPUTE | wgpu::ShaderStages::VERTEX,
    };
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Buffer { ty, has_dynamic_offset: false, min_binding_size: None },
        count: None,
    }
}

impl GpuSplat {
    pub(crate) fn new(ctx: &GpuContext) -> GpuSplat {
        use super::prelude::binding as b;
        use wgpu::BufferBindingType::{Storage, Uniform};
        let layout = ctx.device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("splats (tracer group 2)"),
            entries: &[
                entry(b::SPLAT_FRAME, Uniform),
                entry(b::SPLAT_ENTRIES, Storage { read_only: true }),
                entry(b::SPLAT_CENTRES, Storage { read_only: true }),
                entry(b::SPLAT_ATTRS, Storage { read_only: true }),
                entry(b::SPLAT_DEPTH, Storage { read_only: false }),
                entry(b::SPLAT_IDS, Storage { read_only: false }),
            ],
        });
        let raster_layout = ctx.device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("splat quads' target (group 3)"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: super::prelude::binding::SPLAT_RASTER,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Uint,
                    view_dimension: wgpu::TextureViewDimension::D2,
                    multisampled: false,
                },
                count: None,
            }],
        });
        GpuSplat {
            layout,
            pipelines: None,
            raster_layout,
            raster: None,
            targets: None,
            cache: SplatCache::default(),
            pooled: Vec::new(),
            centres: None,
            attrs: None,
            entries: None,
            uniforms: None,
            depth: None,
            ids: None,
            bind: None,
        }
    }

    /// Builds (once) the three passes from the tracer's module, whose group 0 they share, and
    /// (once) the quads' pipelines when `draw` asks for them.
    pub(crate) fn build_pipelines(
        &mut self,
        device: &wgpu::Device,
        module: &wgpu::ShaderModule,
        trace_layout: &wgpu::BindGroupLayout,
        draw: SplatDraw,
    ) {
        if draw == SplatDraw::Quads {
            self.build_raster(device, module, trace_layout);
        }
        if self.pipelines.is_some() {
            return;
        }
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("trace + splats"),
            bind_group_layouts: &[Some(trace_layout), None, Some(&self.layout)],
            immediate_size: 0,
        });
        let make = |entry: &str| super::renderer::plan_pipeline(device, &layout, module, entry, &[]);
        self.pipelines = Some([make("splat_depth_main"), make("splat_id_main"), make("splat_resolve_main")]);
    }

    /// Builds (once) the quads' pipeline and their copy pass from the tracer's module.
    fn build_raster(
        &mut self,
        device: &wgpu::Device,
        module: &wgpu::ShaderModule,
        trace_layout: &wgpu::BindGroupLayout,
    ) {
        if self.raster.is_some() {
            return;
        }
        let quads_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("splat quads"),
            bind_group_layouts: &[None, None, Some(&self.layout)],
            immediate_size: 0,
        });
        let quads = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("splat quads"),
            layout: Some(&quads_layout),
            vertex: wgpu::VertexState {
                module,
                entry_point: Some("splat_quad_vertex"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState { cull_mode: None, ..Default::default() },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(true),
                // Strictly nearer: at equal depth the earlier quad, the lower splat number,
                // keeps the pixel (primitives are depth-tested in order).
                depth_compare: Some(wgpu::CompareFunction::Less),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module,
                entry_point: Some("splat_quad_fragment"),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format: WORD_FORMAT,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        });
        let copy_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("splat quads' copy"),
            bind_group_layouts: &[Some(trace_layout), None, Some(&self.layout), Some(&self.raster_layout)],
            immediate_size: 0,
        });
        let copy = super::renderer::plan_pipeline(device, &copy_layout, module, "splat_copy_main", &[]);
        self.raster = Some((quads, copy));
    }

    /// The quads' targets at `size`, made when the size changes; an image wider or taller
    /// than the device's textures is refused.
    fn targets(&mut self, ctx: &GpuContext, (width, height): (u32, u32)) -> Result<(), GpuError> {
        if self.targets.as_ref().is_some_and(|t| t.3 == (width, height)) {
            return Ok(());
        }
        let max = ctx.limits.max_texture_dimension_2d;
        if width.max(height) > max {
            return Err(GpuError::Device(format!(
                "splat quads draw into a {width}×{height} target, and this device's textures have at most \
                 {max} pixels per side: use --splat-draw compute"
            )));
        }
        let texture = |label, format, usage| {
            ctx.device
                .create_texture(&wgpu::TextureDescriptor {
                    label: Some(label),
                    size: wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format,
                    usage,
                    view_formats: &[],
                })
                .create_view(&Default::default())
        };
        let word = texture(
            "splat quads' words",
            WORD_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
        );
        let depth = texture("splat quads' depth", DEPTH_FORMAT, wgpu::TextureUsages::RENDER_ATTACHMENT);
        let bind = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("splat quads' words"),
            layout: &self.raster_layout,
            entries: &[wgpu::BindGroupEntry {
                binding: super::prelude::binding::SPLAT_RASTER,
                resource: wgpu::BindingResource::TextureView(&word),
            }],
        });
        self.targets = Some((word, depth, bind, (width, height)));
        Ok(())
    }

    /// Uploads what this frame draws: the lists it needs (when the pool lacks one), one row
    /// per drawn instance, and image-sized depth and id buffers.
    pub(crate) fn prepare(
        &mut self,
        ctx: &GpuContext,
        scene: &Scene,
        prepared: &[Prepared],
        camera: &Camera,
        max_level: u32,
        factor: f32,
    ) -> Result<SplatWork, GpuError> {
        let lists = self.cache.for_frame(scene, prepared, camera, max_level);
        let proj = Projection::new(camera, prepared);
        let drawn: Vec<usize> = (0..prepared.len()).filter(|&i| !proj.culled(&prepared[i])).collect();
        let pooled = |pool: &[(Arc<Splats>, u32)], s: &Arc<Splats>| {
            pool.iter().find(|(p, _)| Arc::ptr_eq(p, s)).map(|&(_, base)| base)
        };
        if drawn.iter().any(|&i| pooled(&self.pooled, &lists[i]).is_none()) {
            self.upload_pool(ctx, drawn.iter().map(|&i| &lists[i]))?;
        }
        let mut rows = Vec::with_capacity(drawn.len());
        let mut total = 0u64;
        for &i in &drawn {
            let s = &lists[i];
            if s.centres.is_empty() {
                continue;
            }
            let base =
                pooled(&self.pooled, s).ok_or_else(|| GpuError::Device("a splat list missing from the pool".into()))?;
            let v = proj.instance(scene, camera, i, &prepared[i], s, factor);
            let m = v.to_camera;
            let row = |k: usize| [m.matrix3.x_axis[k], m.matrix3.y_axis[k], m.matrix3.z_axis[k], m.translation[k]];
            rows.push(GpuSplatEntry {
                view_x: row(0),
                view_y: row(1),
                view_z: row(2),
                first: total as u32,
                base,
                count: s.centres.len() as u32,
                instance: i as u32,
                half_px: v.half_px as f32,
                half_depth: v.half_depth as f32,
                voxel: v.voxel as f32,
                pad: 0,
            });
            total += s.centres.len() as u64;
            // Splat numbers are stored complemented in 32 bits: u32::MAX is left for "none".
            if total >= u32::MAX as u64 {
                return Err(GpuError::TooLarge {
                    what: "the splats of one frame",
                    size: total * std::mem::size_of::<[f32; 4]>() as u64,
                    limit: (u32::MAX as u64 - 1) * std::mem::size_of::<[f32; 4]>() as u64,
                });
            }
        }
        let pixels = camera.width as u64 * camera.height as u64;
        ctx.check_binding("the splat depth buffer", pixels * 4)?;
        let groups_needed = total.div_ceil(GROUP as u64);
        let gx = groups_needed.min(MAX_GROUPS as u64) as u32;
        let gy = if gx == 0 { 0 } else { groups_needed.div_ceil(gx as u64) };
        if gy > MAX_GROUPS as u64 {
            return Err(GpuError::TooLarge {
                what: "the splats of one frame",
                size: total,
                limit: GROUP as u64 * MAX_GROUPS as u64 * MAX_GROUPS as u64,
            });
        }
        let basis = camera.basis();
        let uniforms = GpuSplatFrame {
            entries: rows.len() as u32,
            total: total as u32,
            row_threads: gx * GROUP,
            near: proj.near as f32,
            width: camera.width,
            height: camera.height,
            // As the frame's forward.w and right.w, so the squares are the same.
            tan_half: basis.tan_half as f32,
            aspect: (camera.width as f64 / camera.height as f64) as f32,
        };
        if rows.is_empty() {
            rows.push(GpuSplatEntry::default());
        }
        let storage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        let entry_bytes: &[u8] = bytemuck::cast_slice(&rows);
        let mut replaced = ensure(ctx, &mut self.entries, "splat entries", entry_bytes.len() as u64, false, storage);
        replaced |= ensure(
            ctx,
            &mut self.uniforms,
            "splat frame",
            std::mem::size_of::<GpuSplatFrame>() as u64,
            true,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        );
        replaced |= ensure(ctx, &mut self.depth, "splat depth", pixels * 4, true, storage);
        replaced |= ensure(ctx, &mut self.ids, "splat ids", pixels * 4, true, storage);
        if replaced {
            self.bind = None;
        }
        let missing = || GpuError::Device("splat buffers missing".into());
        let (entries, uniform_buf) =
            (self.entries.as_ref().ok_or_else(missing)?, self.uniforms.as_ref().ok_or_else(missing)?);
        ctx.queue.write_buffer(entries, 0, entry_bytes);
        ctx.queue.write_buffer(uniform_buf, 0, bytemuck::bytes_of(&uniforms));
        let bytes = [&self.centres, &self.attrs, &self.entries, &self.uniforms, &self.depth, &self.ids]
            .iter()
            .filter_map(|b| b.as_ref().map(|b| b.size()))
            .sum();
        Ok(SplatWork { groups: (gx, gy as u32), total: total as u32, bytes })
    }

    /// Replaces the pools with the lists `needed` (each once).
    fn upload_pool<'a>(
        &mut self,
        ctx: &GpuContext,
        needed: impl Iterator<Item = &'a Arc<Splats>>,
    ) -> Result<(), GpuError> {
        let mut pool: Vec<(Arc<Splats>, u32)> = Vec::new();
        let mut n = 0u64;
        for s in needed {
            if !pool.iter().any(|(p, _)| Arc::ptr_eq(p, s)) {
                pool.push((s.clone(), n as u32));
                n += s.centres.len() as u64;
            }
        }
        let centre_bytes = n * 16;
        let attr_bytes = n * std::mem::size_of::<Attr>() as u64;
        ctx.check_binding("the splat centres", centre_bytes)?;
        ctx.check_binding("the splat attributes", attr_bytes)?;
        ctx.check_memory(
            || format!("{n} splats on the GPU"),
            centre_bytes + attr_bytes,
            "lower --lod or use the ray tracer",
        )?;
        let mut centres: Vec<[f32; 4]> = Vec::with_capacity(n as usize + 1);
        let mut attrs: Vec<Attr> = Vec::with_capacity(n as usize + 1);
        for (s, _) in &pool {
            centres.extend(s.centres.iter().map(|c| [c.x, c.y, c.z, 0.0]));
            attrs.extend_from_slice(&s.attrs);
        }
        // Bindings must not be empty.
        if centres.is_empty() {
            centres.push([0.0; 4]);
            attrs.push(Attr::default());
        }
        let init = |label, contents: &[u8]| {
            ctx.buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage: wgpu::BufferUsages::STORAGE,
            })
        };
        self.centres = Some(init("splat centres", bytemuck::cast_slice(&centres)));
        self.attrs = Some(init("splat attributes", bytemuck::cast_slice(&attrs)));
        self.pooled = pool;
        self.bind = None;
        Ok(())
    }

    /// Records the passes: clear, nearest depth, lowest splat number (or the quads and their
    /// copy), resolve into the hit buffer (group 0's), timed as one pass.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn encode(
        &mut self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        group0: &wgpu::BindGroup,
        work: &SplatWork,
        (width, height): (u32, u32),
        draw: SplatDraw,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) -> Result<(), GpuError> {
        if draw == SplatDraw::Quads {
            self.targets(ctx, (width, height))?;
        }
        let missing = || GpuError::Device("splat passes not prepared".into());
        let [depth_pipe, id_pipe, resolve_pipe] = self.pipelines.as_ref().ok_or_else(missing)?;
        let (depth, ids) = (self.depth.as_ref().ok_or_else(missing)?, self.ids.as_ref().ok_or_else(missing)?);
        if self.bind.is_none() {
            use super::prelude::binding as b;
            fn res(buf: &Option<wgpu::Buffer>) -> Result<wgpu::BindingResource<'_>, GpuError> {
                buf.as_ref()
                    .map(|b| b.as_entire_binding())
                    .ok_or_else(|| GpuError::Device("splat buffers missing".into()))
            }
            self.bind = Some(ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("splats"),
                layout: &self.layout,
                entries: &[
                    wgpu::BindGroupEntry { binding: b::SPLAT_FRAME, resource: res(&self.uniforms)? },
                    wgpu::BindGroupEntry { binding: b::SPLAT_ENTRIES, resource: res(&self.entries)? },
                    wgpu::BindGroupEntry { binding: b::SPLAT_CENTRES, resource: res(&self.centres)? },
                    wgpu::BindGroupEntry { binding: b::SPLAT_ATTRS, resource: res(&self.attrs)? },
                    wgpu::BindGroupEntry { binding: b::SPLAT_DEPTH, resource: res(&self.depth)? },
                    wgpu::BindGroupEntry { binding: b::SPLAT_IDS, resource: res(&self.ids)? },
                ],
            }));
        }
        let bind = self.bind.as_ref().ok_or_else(missing)?;
        if draw == SplatDraw::Quads {
            return self.encode_quads(enc, group0, bind, resolve_pipe, work, (width, height), timestamps);
        }
        // Zero is "nothing drawn here" for both (they hold complements).
        enc.clear_buffer(depth, 0, None);
        enc.clear_buffer(ids, 0, None);
        let mut pass =
            enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("splat"), timestamp_writes: timestamps });
        pass.set_bind_group(0, group0, &[]);
        pass.set_bind_group(2, bind, &[]);
        if work.groups.0 > 0 {
            // Each dispatch sees the one before's writes.
            for pipe in [depth_pipe, id_pipe] {
                pass.set_pipeline(pipe);
                pass.dispatch_workgroups(work.groups.0, work.groups.1, 1);
            }
        }
        pass.set_pipeline(resolve_pipe);
        pass.dispatch_workgroups(width.div_ceil(8), height.div_ceil(8), 1);
        Ok(())
    }

    /// [`Self::encode`] with the rasterizer (its targets made for this size): the quads into
    /// their cleared targets (the timestamps' start), then one compute pass that copies the
    /// winners into the depth and id buffers and resolves them (the timestamps' end).
    #[allow(clippy::too_many_arguments)]
    fn encode_quads(
        &self,
        enc: &mut wgpu::CommandEncoder,
        group0: &wgpu::BindGroup,
        bind: &wgpu::BindGroup,
        resolve: &wgpu::ComputePipeline,
        work: &SplatWork,
        (width, height): (u32, u32),
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) -> Result<(), GpuError> {
        let missing = || GpuError::Device("splat quads not prepared".into());
        let (quads, copy) = self.raster.as_ref().ok_or_else(missing)?;
        let (word, depth, raster_bind, _) = self.targets.as_ref().ok_or_else(missing)?;
        let (query_set, start, end) = match &timestamps {
            Some(t) => (Some(t.query_set), t.beginning_of_pass_write_index, t.end_of_pass_write_index),
            None => (None, None, None),
        };
        {
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("splat quads"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: word,
                    depth_slice: None,
                    resolve_target: None,
                    // Zero is "nothing drawn here", as in the compute passes' buffers.
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: depth,
                    depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(1.0), store: wgpu::StoreOp::Discard }),
                    stencil_ops: None,
                }),
                timestamp_writes: query_set.map(|query_set| wgpu::RenderPassTimestampWrites {
                    query_set,
                    beginning_of_pass_write_index: start,
                    end_of_pass_write_index: None,
                }),
                occlusion_query_set: None,
                multiview_mask: None,
            });
            if work.total > 0 {
                pass.set_pipeline(quads);
                pass.set_bind_group(2, bind, &[]);
                pass.draw(0..6, 0..work.total);
            }
        }
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("splat quads' copy and resolve"),
            timestamp_writes: query_set.map(|query_set| wgpu::ComputePassTimestampWrites {
                query_set,
                beginning_of_pass_write_index: None,
                end_of_pass_write_index: end,
            }),
        });
        pass.set_bind_group(0, group0, &[]);
        pass.set_bind_group(2, bind, &[]);
        pass.set_bind_group(3, raster_bind, &[]);
        pass.set_pipeline(copy);
        pass.dispatch_workgroups(width.div_ceil(8), height.div_ceil(8), 1);
        pass.set_pipeline(resolve);
        pass.dispatch_workgroups(width.div_ceil(8), height.div_ceil(8), 1);
        Ok(())
    }
}
