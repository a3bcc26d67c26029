//! A caller's own rays against a posed scene on the GPU (`wgsl/cast.wgsl`): the twin of
//! [`crate::cast::SceneCaster`], with the same preparation (instances relative to a reference
//! point, the instance BVH from [`BVH_MIN_INSTANCES`] on) and the frame renderer's instance
//! searches (`wgsl/shared/search.wgsl`), in f32 on the device. Its answers are the CPU's up to
//! f32 rounding: `tests/gpu.rs` requires 99.9 % of them identical and every other one valid
//! against the DDA oracle, as for the renderer's rays.
//!
//! ```no_run
//! # fn main() -> Result<(), voxray::Error> {
//! # let scene = voxray::scene::Scene::new(Vec::new());
//! use glam::DVec3;
//! use voxray::cast::CastRay;
//! use voxray::gpu::{cast::GpuSceneCaster, GpuContext};
//!
//! let ctx = std::sync::Arc::new(GpuContext::headless()?);
//! let caster = GpuSceneCaster::new(ctx, &scene)?;
//! let hits = caster.nearest_all(&[CastRay::new(DVec3::new(0.0, 5.0, 0.0), DVec3::NEG_Y)])?;
//! # Ok(())
//! # }
//! ```

use super::context::{GpuContext, GpuError};
use super::layout::{GpuCastHit, GpuFrame, GpuRay};
use super::prelude::binding as b;
use super::renderer::{gpu_bvh_nodes, gpu_instance, read, Pools};
use crate::cast::{CastError, CastRay, SceneHit};
use crate::render::bvh::Bvh;
use crate::render::instances::{prepare_into, Prepared};
use crate::render::plan::BVH_MIN_INSTANCES;
use crate::scene::Scene;
use crate::svo::Attr;
use crate::traverse::Hit;
use glam::DVec3;
use std::sync::Arc;

/// The caster's shader: the prelude, the shared layouts, traversal and instance searches,
/// and `wgsl/cast.wgsl`.
pub fn cast_source() -> String {
    [
        &super::prelude::prelude(),
        include_str!("../../wgsl/shared/layout.wgsl"),
        include_str!("../../wgsl/shared/traverse.wgsl"),
        include_str!("../../wgsl/shared/search.wgsl"),
        include_str!("../../wgsl/cast.wgsl"),
    ]
    .join("\n")
}

/// Casts rays at one pose of a scene on the GPU: see the module documentation.
pub struct GpuSceneCaster {
    ctx: Arc<GpuContext>,
    prepared: Vec<Prepared>,
    reference: DVec3,
    /// The scene's buffers, bound as `wgsl/cast.wgsl` names them (the rays and results are
    /// added per batch).
    pools: Pools,
    insts: wgpu::Buffer,
    frame: wgpu::Buffer,
    bvh: wgpu::Buffer,
    items: wgpu::Buffer,
    nearest: wgpu::ComputePipeline,
    occluded: wgpu::ComputePipeline,
}

impl GpuSceneCaster {
    /// Uploads `scene` (updated) for rays down to its voxels, relative to the centre of its
    /// bounds, as [`crate::cast::SceneCaster::new`] prepares it.
    pub fn new(ctx: Arc<GpuContext>, scene: &Scene) -> Result<GpuSceneCaster, crate::Error> {
        let (lo, hi) = scene.bounds();
        let centre = 0.5 * (lo + hi);
        Self::with(ctx, scene, if centre.is_finite() { centre } else { DVec3::ZERO }, u32::MAX)
    }

    /// [`GpuSceneCaster::new`] relative to `reference` and down to level `max_level`, as
    /// [`crate::cast::SceneCaster::with`].
    pub fn with(
        ctx: Arc<GpuContext>,
        scene: &Scene,
        reference: DVec3,
        max_level: u32,
    ) -> Result<GpuSceneCaster, crate::Error> {
        if scene.is_dirty() {
            return Err(CastError::NotUpdated.into());
        }
        if !reference.is_finite() {
            return Err(CastError::Reference(reference.to_array()).into());
        }
        let c = ctx.clone();
        Ok(ctx.scoped(|| Self::upload(c, scene, reference, max_level))?)
    }

    fn upload(
        ctx: Arc<GpuContext>,
        scene: &Scene,
        reference: DVec3,
        max_level: u32,
    ) -> Result<GpuSceneCaster, GpuError> {
        let mut prepared = Vec::new();
        prepare_into(scene, reference, true, max_level, &mut prepared);
        let max_binding = ctx.limits.max_storage_buffer_binding_size.min(ctx.limits.max_buffer_size);
        let pools = Pools::upload(&ctx, &scene.parts, max_binding)?;
        let insts: Vec<_> = prepared.iter().map(|p| gpu_instance(scene, p, false)).collect();
        let bvh = (prepared.len() >= BVH_MIN_INSTANCES)
            .then(|| Bvh::build_with(&prepared.iter().map(|p| (p.centre, p.radius)).collect::<Vec<_>>(), false));
        let (nodes, items) = bvh.as_ref().map_or((Vec::new(), Vec::new()), |t| (gpu_bvh_nodes(t), t.items.clone()));
        ctx.check_binding("the instance list", std::mem::size_of_val(&insts[..]) as u64)?;
        ctx.check_binding("the instance BVH", std::mem::size_of_val(&nodes[..]) as u64)?;
        let frame = GpuFrame {
            instances: insts.len() as u32,
            max_level: max_level.min(64),
            bvh_nodes: nodes.len() as u32,
            ..bytemuck::Zeroable::zeroed()
        };
        let storage = |label, bytes: &[u8], usage| {
            // A binding may not be empty: one zero element stands for none.
            let zero = [0u8; 64];
            let contents = if bytes.is_empty() { &zero[..] } else { bytes };
            ctx.buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents, usage })
        };
        let insts = storage("cast instances", bytemuck::cast_slice(&insts), wgpu::BufferUsages::STORAGE);
        let bvh_buf = storage("cast bvh", bytemuck::cast_slice(&nodes), wgpu::BufferUsages::STORAGE);
        let items = storage("cast bvh items", bytemuck::cast_slice(&items), wgpu::BufferUsages::STORAGE);
        let frame = storage("cast frame", bytemuck::bytes_of(&frame), wgpu::BufferUsages::UNIFORM);
        let module = ctx.device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("cast.wgsl"),
            source: wgpu::ShaderSource::Wgsl(cast_source().into()),
        });
        let search = if bvh.is_some() { 3.0 } else { 2.0 };
        let constants =
            [("SEARCH", search), ("NODE_SPLIT", pools.node_split as f64), ("ATTR_SPLIT", pools.attr_split as f64)];
        let pipeline = |entry: &str| {
            ctx.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: None,
                module: &module,
                entry_point: Some(entry),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants: &constants,
                    zero_initialize_workgroup_memory: false,
                },
                cache: None,
            })
        };
        let (nearest, occluded) = (pipeline("cast_nearest_main"), pipeline("cast_occluded_main"));
        Ok(GpuSceneCaster { ctx, prepared, reference, pools, insts, frame, bvh: bvh_buf, items, nearest, occluded })
    }

    /// How many instances it casts against.
    pub fn instances(&self) -> usize {
        self.prepared.len()
    }

    /// [`crate::cast::SceneCaster::nearest_all`] on the GPU.
    pub fn nearest_all(&self, rays: &[CastRay]) -> Result<Vec<Option<SceneHit>>, GpuError> {
        let mut out = Vec::new();
        self.nearest_into(rays, &mut out)?;
        Ok(out)
    }

    /// [`crate::cast::SceneCaster::nearest_into`] on the GPU: the answers into the caller's
    /// buffer (replacing what it held).
    pub fn nearest_into(&self, rays: &[CastRay], out: &mut Vec<Option<SceneHit>>) -> Result<(), GpuError> {
        let (gpu_rays, dirs) = self.gpu_rays(rays);
        let found = self.ctx.scoped(|| self.run(&self.nearest, &gpu_rays))?;
        out.clear();
        out.extend(rays.iter().zip(&found).zip(dirs).map(|((r, g), d)| {
            let p = self.prepared.get(g.instance as usize).filter(|_| d.is_some())?;
            let d = d?;
            let attr = Attr { albedo: g.attr[0], normal: g.attr[1], emission: g.attr[2] };
            let voxel = Hit {
                t: g.t,
                level: g.level,
                coord: [g.coord[0], g.coord[1], g.coord[2]],
                attr,
                face_normal: glam::Vec3::new(g.face_normal[0], g.face_normal[1], g.face_normal[2]),
            };
            let t = g.t as f64;
            // (The nearest hit beyond the reach: none within it; compared as the CPU's.)
            if !(t <= r.t_max) {
                return None;
            }
            Some(SceneHit {
                instance: g.instance as usize,
                part: p.part,
                t,
                position: r.origin + d * t,
                normal: p.normal_to_world(voxel.normal().as_dvec3()).normalize_or_zero(),
                albedo: voxel.albedo(),
                voxel,
            })
        }));
        Ok(())
    }

    /// [`crate::cast::SceneCaster::occluded_all`] on the GPU.
    pub fn occluded_all(&self, rays: &[CastRay]) -> Result<Vec<bool>, GpuError> {
        let mut out = Vec::new();
        self.occluded_into(rays, &mut out)?;
        Ok(out)
    }

    /// [`crate::cast::SceneCaster::occluded_into`] on the GPU: the answers into the caller's
    /// buffer (replacing what it held).
    pub fn occluded_into(&self, rays: &[CastRay], out: &mut Vec<bool>) -> Result<(), GpuError> {
        let (gpu_rays, dirs) = self.gpu_rays(rays);
        let found = self.ctx.scoped(|| self.run(&self.occluded, &gpu_rays))?;
        out.clear();
        out.extend(found.iter().zip(dirs).zip(rays).map(|((g, d), r)| d.is_some() && r.t_max > 0.0 && g.instance == 0));
        Ok(())
    }

    /// The rays relative to the reference point with unit directions, in f32, and each
    /// one's direction (None: a ray without one, sent as a ray that cannot hit).
    fn gpu_rays(&self, rays: &[CastRay]) -> (Vec<GpuRay>, Vec<Option<DVec3>>) {
        rays.iter()
            .map(|r| {
                let t_max = if r.t_max > 0.0 { r.t_max.min(f32::MAX as f64) as f32 } else { 0.0 };
                let d = r.dir.normalize_or_zero();
                let ok = r.origin.is_finite() && d != DVec3::ZERO;
                let o = if ok { r.origin - self.reference } else { DVec3::ZERO };
                // A ray without direction goes nowhere: zero, which the search rejects.
                let dir = if ok { d } else { DVec3::ZERO };
                let ray = GpuRay {
                    origin: [o.x as f32, o.y as f32, o.z as f32, 0.0],
                    dir: [dir.x as f32, dir.y as f32, dir.z as f32, 0.0],
                    t_min: 0.0,
                    t_max,
                    max_level: 0,
                    pad: 0,
                };
                (ray, ok.then_some(d))
            })
            .unzip()
    }

    /// Runs one entry point over `rays` and reads back its results.
    fn run(&self, pipeline: &wgpu::ComputePipeline, rays: &[GpuRay]) -> Result<Vec<GpuCastHit>, GpuError> {
        if rays.is_empty() {
            return Ok(Vec::new());
        }
        let ctx = &self.ctx;
        let out_size = (rays.len() * std::mem::size_of::<GpuCastHit>()) as u64;
        ctx.check_binding("the ray list", std::mem::size_of_val(rays) as u64)?;
        ctx.check_binding("the results", out_size)?;
        let input = ctx.buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("cast rays"),
            contents: bytemuck::cast_slice(rays),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let output = ctx.buffer(&wgpu::BufferDescriptor {
            label: Some("cast hits"),
            size: out_size,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let staging = ctx.buffer(&wgpu::BufferDescriptor {
            label: Some("cast hits read back"),
            size: out_size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let entries = [
            (b::NODES, &self.pools.nodes),
            (b::ATTRS, &self.pools.attrs),
            (b::PARTS, &self.pools.infos),
            (b::INSTS, &self.insts),
            (b::FRAME, &self.frame),
            (b::BVH, &self.bvh),
            (b::BVH_ITEMS, &self.items),
            (b::NODES_HI, &self.pools.nodes_hi),
            (b::ATTRS_HI, &self.pools.attrs_hi),
            (20, &input),
            (21, &output),
        ]
        .map(|(binding, buf)| wgpu::BindGroupEntry { binding, resource: buf.as_entire_binding() });
        let bind = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("cast"),
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        });
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        {
            let mut pass =
                enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("cast"), timestamp_writes: None });
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &bind, &[]);
            // At most 65 535 workgroups per dimension: spread over y (cast_index).
            let groups = (rays.len() as u32).div_ceil(64);
            pass.dispatch_workgroups(groups.min(65_535), groups.div_ceil(65_535), 1);
        }
        enc.copy_buffer_to_buffer(&output, 0, &staging, 0, out_size);
        ctx.queue.submit([enc.finish()]);
        read(ctx, &staging)
    }
}
