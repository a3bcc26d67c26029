//! The sparse volume's top tables and the brick allocation (mark, allocate, one 4-byte read);
//! the GPU side of `gi::sparse`.

use super::*;

/// The sparse volume's tables, sized by the resolution alone.
pub(super) struct SparseTables {
    pub(super) res: u32,
    /// Brick of each top cell (or none), as `SparseVolume::top`.
    pub(super) top: wgpu::Buffer,
    /// Top cell of each brick.
    pub(super) brick_top: wgpu::Buffer,
    /// Bricks allocated, weight outside (`OUT_FIX`).
    pub(super) counters: wgpu::Buffer,
    /// Bricks allocated by the last mark and allocate passes.
    pub(super) bricks: u32,
}

/// The bind group of the sparse passes.
pub(super) fn sparse_bind(
    ctx: &GpuContext,
    layout: &wgpu::BindGroupLayout,
    [voxels, jobs, accum, ubuf]: [&wgpu::Buffer; 4],
    tables: &SparseTables,
) -> wgpu::BindGroup {
    ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("gi sparse volume"),
        layout,
        entries: &[
            wgpu::BindGroupEntry { binding: 0, resource: voxels.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 1, resource: jobs.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 2, resource: accum.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 3, resource: ubuf.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 4, resource: tables.top.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 5, resource: tables.counters.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 6, resource: tables.brick_top.as_entire_binding() },
        ],
    })
}

impl GpuGi {
    /// Allocates the sparse volume's top tables for `res` cells per side.
    pub(super) fn sparse_tables(&mut self, ctx: &GpuContext, res: u32) -> Result<(), GpuError> {
        if self.sparse.as_ref().is_some_and(|t| t.res == res) {
            return Ok(());
        }
        let top_cells = ((res / BRICK) as u64).pow(3).max(1);
        ctx.check_binding("the GI top table", top_cells * 4)?;
        let make = |label, size, usage| {
            ctx.buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage: wgpu::BufferUsages::STORAGE | usage,
                mapped_at_creation: false,
            })
        };
        let copy = wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC;
        self.sparse = Some(SparseTables {
            res,
            top: make("gi top table", top_cells * 4, copy),
            brick_top: make("gi brick top cells", top_cells * 4, copy),
            counters: make("gi sparse counters", 16, copy),
            bricks: 0,
        });
        Ok(())
    }

    /// Marks and allocates the sparse volume's bricks for `threads` moved voxels (submitted at
    /// once) and reads back how many there are.
    pub(super) fn allocate_bricks(
        &mut self,
        ctx: &GpuContext,
        voxels: &wgpu::Buffer,
        jobs: &wgpu::Buffer,
        splat: GpuGiSplat,
        groups: (u32, u32),
    ) -> Result<(u32, f64), GpuError> {
        let t0 = std::time::Instant::now();
        let tables = self.sparse.as_ref().ok_or_else(|| GpuError::Device("GI top table missing".into()))?;
        let device = &ctx.device;
        let kept = &mut self.kept;
        let mark = GpuGiSplat { mark: 1, ..splat };
        let ubuf = GiFrameBuffers::write(
            ctx,
            &mut kept.mark,
            "gi mark",
            bytemuck::bytes_of(&mark),
            wgpu::BufferUsages::UNIFORM,
        )?;
        let key = vec![voxels.clone(), jobs.clone(), ubuf.clone(), tables.top.clone(), tables.brick_top.clone()];
        let (layout, placeholder) = (&self.sparse_layout, &self.placeholder);
        let bind = bind_cached(&mut kept.binds, ("mark", 0), key, || {
            sparse_bind(ctx, layout, [voxels, jobs, placeholder, &ubuf], tables)
        });
        let mut enc = device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("gi bricks") });
        enc.clear_buffer(&tables.top, 0, None);
        enc.clear_buffer(&tables.counters, 0, None);
        {
            let mut pass = enc
                .begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("gi bricks"), timestamp_writes: None });
            pass.set_bind_group(0, &bind, &[]);
            if groups.0 > 0 {
                pass.set_pipeline(&self.sparse_splat_pipe);
                pass.dispatch_workgroups(groups.0, groups.1, 1);
            }
            let g = (tables.res / BRICK).div_ceil(4);
            pass.set_pipeline(&self.sparse_alloc_pipe);
            pass.dispatch_workgroups(g, g, g);
        }
        let mappable = wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST;
        ensure(ctx, &mut kept.brick_count, "gi brick count", 4, true, mappable);
        let readback =
            kept.brick_count.as_ref().ok_or_else(|| GpuError::Device("brick count buffer missing".into()))?;
        enc.copy_buffer_to_buffer(&tables.counters, 0, readback, 0, 4);
        ctx.queue.submit([enc.finish()]);
        let count: Vec<u32> = read(ctx, readback)?;
        Ok((count.first().copied().unwrap_or(0), t0.elapsed().as_secs_f64() * 1e3))
    }
}
