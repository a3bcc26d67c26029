//! Tracing an arbitrary list of rays through one SVO on the GPU (`wgsl/rays.wgsl`): the GPU
//! side of the stability suite, compared with the CPU ray by ray.

use super::context::{GpuContext, GpuError};
use super::layout::{GpuPart, GpuRay, GpuRayHit};
use super::renderer::{rays_source, read};
use crate::svo::Svo;

/// Traces `rays` (in the SVO's unit cube) and returns one result per ray.
pub fn trace_rays(ctx: &GpuContext, svo: &Svo, rays: &[GpuRay]) -> Result<Vec<GpuRayHit>, GpuError> {
    ctx.scoped(|| trace_rays_unscoped(ctx, svo, rays))
}

fn trace_rays_unscoped(ctx: &GpuContext, svo: &Svo, rays: &[GpuRay]) -> Result<Vec<GpuRayHit>, GpuError> {
    if rays.is_empty() {
        return Ok(Vec::new());
    }
    let (words, mask_base) = super::layout::part_words(svo);
    ctx.check_binding("the node pool", (words.len() * 4) as u64)?;
    ctx.check_binding("the attribute pool", (svo.attrs.len() * 8) as u64)?;
    ctx.check_binding("the ray list", std::mem::size_of_val(rays) as u64)?;
    let device = &ctx.device;
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("rays.wgsl"),
        source: wgpu::ShaderSource::Wgsl(rays_source().into()),
    });
    let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some("rays"),
        layout: None,
        module: &module,
        entry_point: Some("rays_main"),
        compilation_options: Default::default(),
        cache: None,
    });
    let buf = |label, contents: &[u8], usage| {
        ctx.buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents, usage })
    };
    let part = [GpuPart { node_base: 0, mask_base, attr_base: 0, depth: svo.depth }];
    let nodes = buf("nodes", bytemuck::cast_slice(&words), wgpu::BufferUsages::STORAGE);
    let attrs = buf("attrs", bytemuck::cast_slice(&svo.attrs), wgpu::BufferUsages::STORAGE);
    let parts = buf("parts", bytemuck::cast_slice(&part), wgpu::BufferUsages::STORAGE);
    let input = buf("rays", bytemuck::cast_slice(rays), wgpu::BufferUsages::STORAGE);
    let nodes_hi = buf("nodes (unused)", bytemuck::bytes_of(&0u32), wgpu::BufferUsages::STORAGE);
    let attrs_hi = buf("attrs (unused)", bytemuck::bytes_of(&crate::svo::Attr::default()), wgpu::BufferUsages::STORAGE);
    let size = std::mem::size_of_val(rays) as u64 / std::mem::size_of::<GpuRay>() as u64
        * std::mem::size_of::<GpuRayHit>() as u64;
    let output = ctx.buffer(&wgpu::BufferDescriptor {
        label: Some("hits"),
        size,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    let staging = ctx.buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("rays"),
        layout: &pipeline.get_bind_group_layout(0),
        entries: &[
            wgpu::BindGroupEntry { binding: 0, resource: nodes.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 1, resource: attrs.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 2, resource: parts.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 3, resource: input.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 4, resource: output.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 5, resource: nodes_hi.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 6, resource: attrs_hi.as_entire_binding() },
        ],
    });
    let mut enc = device.create_command_encoder(&Default::default());
    {
        let mut pass =
            enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("rays"), timestamp_writes: None });
        pass.set_pipeline(&pipeline);
        pass.set_bind_group(0, &bind, &[]);
        // At most 65 535 workgroups per dimension: spread over y.
        let groups = (rays.len() as u32).div_ceil(64);
        pass.dispatch_workgroups(groups.min(65_535), groups.div_ceil(65_535), 1);
    }
    enc.copy_buffer_to_buffer(&output, 0, &staging, 0, size);
    ctx.queue.submit([enc.finish()]);
    read(ctx, &staging)
}
