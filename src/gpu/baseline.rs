//! The voxel transformation and the re-voxelization baseline as standalone GPU passes, for the
//! harness (`voxray bench --scenarios gi-scaling --backends gpu`) and the tests: both write the
//! same fixed-point volume (`wgsl/gi_transform.wgsl`, `wgsl/gi_revoxelize.wgsl`), timed by
//! timestamp queries where the adapter has them (wall clock of submit-and-wait otherwise).
//! Caches, triangles and instance matrices are uploaded before the timed passes.

use super::context::{GpuContext, GpuError};
use super::gi::{row, splat_dispatch, transform_job, transform_source, volume_from_accum};
use super::layout::{GpuGiJob, GpuGiTri};
use super::renderer::read;
use crate::gi::volume::check_world;
use crate::gi::{Filter, GiError, Volume, VolumeSpec, VoxelCache};
use crate::mesh::Mesh;
use glam::{DAffine3, DVec3};
use std::sync::Arc;
use std::time::Instant;

/// The re-voxelization shader.
pub fn revoxelize_source() -> String {
    [
        &super::prelude::prelude(),
        include_str!("../../wgsl/shared/layout.wgsl"),
        include_str!("../../wgsl/shared/gi_fixed.wgsl"),
        include_str!("../../wgsl/shared/gi_splat.wgsl"),
        include_str!("../../wgsl/gi_revoxelize.wgsl"),
    ]
    .join("\n")
}

/// One timed GPU volume pass.
#[derive(Clone, Debug)]
pub struct Timed {
    /// Milliseconds per repetition.
    pub ms: Vec<f64>,
    /// Whether the times come from timestamp queries (else wall clock, submit to done).
    pub timestamps: bool,
    /// The volume the last repetition wrote.
    pub volume: Volume,
    /// Voxels or triangles moved per repetition.
    pub work: u64,
}

/// GPU voxel transformation and re-voxelization into one volume.
pub struct GpuVolumePasses {
    ctx: Arc<GpuContext>,
    // One layout for the three entry points (finish_main uses only two of the bindings).
    layout: wgpu::BindGroupLayout,
    splat: wgpu::ComputePipeline,
    tri: wgpu::ComputePipeline,
    finish: wgpu::ComputePipeline,
}

fn pipeline(
    device: &wgpu::Device,
    layout: &wgpu::PipelineLayout,
    label: &str,
    src: String,
    entry: &str,
) -> wgpu::ComputePipeline {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(src.into()),
    });
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(entry),
        layout: Some(layout),
        module: &module,
        entry_point: Some(entry),
        compilation_options: Default::default(),
        cache: None,
    })
}

impl GpuVolumePasses {
    /// The pipelines on `ctx`.
    pub fn new(ctx: Arc<GpuContext>) -> Self {
        let d = &ctx.device;
        let entry = |binding, ty| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer { ty, has_dynamic_offset: false, min_binding_size: None },
            count: None,
        };
        let layout = d.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("gi volume pass"),
            entries: &[
                entry(0, wgpu::BufferBindingType::Storage { read_only: true }),
                entry(1, wgpu::BufferBindingType::Storage { read_only: true }),
                entry(2, wgpu::BufferBindingType::Storage { read_only: false }),
                entry(3, wgpu::BufferBindingType::Uniform),
            ],
        });
        let pl = d.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("gi volume pass"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        GpuVolumePasses {
            splat: pipeline(d, &pl, "gi_transform.wgsl", transform_source(), "splat_main"),
            tri: pipeline(d, &pl, "gi_revoxelize.wgsl", revoxelize_source(), "tri_main"),
            finish: pipeline(d, &pl, "gi_revoxelize.wgsl", revoxelize_source(), "finish_main"),
            layout,
            ctx,
        }
    }

    /// Moves `caches[part]` by each instance's world matrix into `spec`, `repeats` times.
    pub fn transform(
        &self,
        caches: &[VoxelCache],
        instances: &[(usize, DAffine3)],
        spec: &VolumeSpec,
        filter: Filter,
        repeats: usize,
    ) -> Result<Timed, GpuError> {
        let mut pool = Vec::new();
        let mut ranges = Vec::new();
        for c in caches {
            ranges.push((pool.len() as u32, c.voxels.len() as u32));
            pool.extend_from_slice(&c.voxels);
        }
        let mut jobs = Vec::new();
        let mut threads = 0u64;
        for &(part, world) in instances {
            let (cache, &range) = match (caches.get(part), ranges.get(part)) {
                (Some(c), Some(r)) => (c, r),
                _ => return Err(GiError::Settings(format!("instance of part {part}: no such cache")).into()),
            };
            jobs.push(transform_job(&world, cache, spec, range, threads)?);
            threads += range.1 as u64;
        }
        self.run(bytemuck::cast_slice(&pool), jobs, threads, spec, filter, repeats, false)
    }

    /// Voxelizes each instance's triangles of `mesh.parts[part]`, moved by its world matrix,
    /// into `spec`'s cells, `repeats` times. Materials give flat albedo and emission (textures
    /// are not sampled).
    pub fn revoxelize(
        &self,
        mesh: &Mesh,
        instances: &[(usize, DAffine3)],
        spec: &VolumeSpec,
        repeats: usize,
    ) -> Result<Timed, GpuError> {
        let mut tris: Vec<GpuGiTri> = Vec::new();
        let mut ranges = Vec::new();
        for p in &mesh.parts {
            ranges.push((tris.len() as u32, p.triangles.len() as u32));
            for t in &p.triangles {
                let m = mesh.materials.get(t.material as usize);
                let a = m.map_or(glam::Vec3::splat(0.7), |m| m.albedo);
                let e = m
                    .map_or(glam::Vec3::ZERO, |m| m.emission)
                    .min(glam::Vec3::splat(crate::gi::volume::GI_MAX_EMISSION));
                let v = |k: usize, w: f32| [t.positions[k].x, t.positions[k].y, t.positions[k].z, w];
                tris.push(GpuGiTri { a: v(0, a.x), b: v(1, a.y), c: v(2, a.z), emission: [e.x, e.y, e.z, 0.0] });
            }
        }
        let mut jobs = Vec::new();
        let mut threads = 0u64;
        // Object point → grid coordinate with cell c spanning [c, c + 1).
        let to_grid = DAffine3::from_scale(DVec3::splat(1.0 / spec.cell)) * DAffine3::from_translation(-spec.min);
        for &(part, world) in instances {
            check_world(&world)?;
            let &(base, count) = ranges
                .get(part)
                .ok_or_else(|| GiError::Settings(format!("instance of part {part}: no such mesh part")))?;
            let g = to_grid * world;
            jobs.push(GpuGiJob {
                grid_x: row(g.matrix3, g.translation, 0),
                grid_y: row(g.matrix3, g.translation, 1),
                grid_z: row(g.matrix3, g.translation, 2),
                voxel_base: base,
                voxel_count: count,
                first_thread: threads as u32,
                ..Default::default()
            });
            threads += count as u64;
        }
        self.run(bytemuck::cast_slice(&tris), jobs, threads, spec, Filter::Split, repeats, true)
    }

    #[allow(clippy::too_many_arguments)]
    fn run(
        &self,
        items: &[u8],
        mut jobs: Vec<GpuGiJob>,
        threads: u64,
        spec: &VolumeSpec,
        filter: Filter,
        repeats: usize,
        revoxelize: bool,
    ) -> Result<Timed, GpuError> {
        let (ctx, device) = (&self.ctx, &self.ctx.device);
        let cells = (spec.res as u64).pow(3);
        let accum_size = (cells * 10 + 1) * 4;
        ctx.check_binding("the GI accumulation volume", accum_size)?;
        ctx.check_binding("the GI voxel or triangle pool", items.len() as u64)?;
        let (splat, dims) = splat_dispatch(spec.res, jobs.len(), threads, filter)?;
        if jobs.is_empty() {
            jobs.push(GpuGiJob::default());
        }
        let items: Vec<u8> = if items.is_empty() { vec![0; 64] } else { items.to_vec() };
        let init = |label, contents: &[u8], usage| {
            ctx.buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents, usage })
        };
        let items_buf = init("gi items", &items, wgpu::BufferUsages::STORAGE);
        let jobs_buf = init("gi jobs", bytemuck::cast_slice(&jobs), wgpu::BufferUsages::STORAGE);
        let splat_buf = init("gi splat", bytemuck::bytes_of(&splat), wgpu::BufferUsages::UNIFORM);
        let accum = ctx.buffer(&wgpu::BufferDescriptor {
            label: Some("gi accumulation"),
            size: accum_size,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let first = if revoxelize { &self.tri } else { &self.splat };
        let bind = || {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("gi volume pass"),
                layout: &self.layout,
                entries: &[
                    wgpu::BindGroupEntry { binding: 0, resource: items_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 1, resource: jobs_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 2, resource: accum.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 3, resource: splat_buf.as_entire_binding() },
                ],
            })
        };
        let first_bind = bind();
        let finish_bind = revoxelize.then(&bind);
        let queries = ctx.timestamps.then(|| {
            let set = device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("gi volume pass"),
                ty: wgpu::QueryType::Timestamp,
                count: 2,
            });
            let resolve = ctx.buffer(&wgpu::BufferDescriptor {
                label: Some("timestamps"),
                size: 16,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            });
            let rb = ctx.buffer(&wgpu::BufferDescriptor {
                label: Some("timestamps readback"),
                size: 16,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            (set, resolve, rb)
        });
        let mut ms = Vec::new();
        for _ in 0..repeats.max(1) {
            let mut enc = device.create_command_encoder(&Default::default());
            enc.clear_buffer(&accum, 0, None);
            {
                let timestamp_writes = queries.as_ref().map(|(set, _, _)| wgpu::ComputePassTimestampWrites {
                    query_set: set,
                    beginning_of_pass_write_index: Some(0),
                    end_of_pass_write_index: Some(1),
                });
                let mut pass =
                    enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("gi volume"), timestamp_writes });
                if threads > 0 {
                    pass.set_pipeline(first);
                    pass.set_bind_group(0, &first_bind, &[]);
                    pass.dispatch_workgroups(dims.0, dims.1, 1);
                }
                if let Some(fb) = &finish_bind {
                    let g = spec.res.div_ceil(4);
                    pass.set_pipeline(&self.finish);
                    pass.set_bind_group(0, fb, &[]);
                    pass.dispatch_workgroups(g, g, g);
                }
            }
            if let Some((set, resolve, rb)) = &queries {
                enc.resolve_query_set(set, 0..2, resolve, 0);
                enc.copy_buffer_to_buffer(resolve, 0, rb, 0, 16);
            }
            let t0 = Instant::now();
            ctx.queue.submit([enc.finish()]);
            ctx.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| GpuError::Readback(e.to_string()))?;
            let wall = t0.elapsed().as_secs_f64() * 1e3;
            ms.push(match &queries {
                Some((_, _, rb)) => {
                    let ts: Vec<u64> = read(ctx, rb)?;
                    ts[1].saturating_sub(ts[0]) as f64 * ctx.queue.get_timestamp_period() as f64 * 1e-6
                }
                None => wall,
            });
        }
        let rb = ctx.buffer(&wgpu::BufferDescriptor {
            label: Some("gi volume readback"),
            size: accum_size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(&accum, 0, &rb, 0, accum_size);
        ctx.queue.submit([enc.finish()]);
        let words: Vec<u32> = read(ctx, &rb)?;
        let (volume, _) = volume_from_accum(&words, *spec);
        Ok(Timed { ms, timestamps: queries.is_some(), volume, work: threads })
    }
}
