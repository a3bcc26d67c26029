//! The sparse volume's top tables and the brick allocation (mark, allocate), the GPU side of
//! `gi::sparse`.
//!
//! The pool is sized on the host from a bound that needs nothing from the GPU: the bricks
//! that the instances' boxes of moved voxels cover (their union, one bit per top cell). The
//! mark and allocate passes run in the frame's own command buffer; the count they reach sets
//! the workgroups of the passes that loop over bricks (indirect dispatches written on the
//! GPU) and is copied into their uniforms, where threads past it stop. Only a volume whose bound does not fit
//! ([`UNREAD_LIMIT`]) runs the two passes once more on their own and reads the count back to
//! size the pool exactly.

use super::*;

/// Most bytes a pool sized by the bound (not by a count read back) may take: past it the
/// bound is too loose to allocate (a part whose box covers the whole volume) and the count
/// is read.
pub(super) const UNREAD_LIMIT: u64 = 256 << 20;

/// Bytes of one brick in the pool: its accumulation cells and its three levels.
pub(super) const BRICK_BYTES: u64 = BRICK_CELLS as u64 * STRIDE as u64 * 4 + (512 + 64 + 8) * 16;

/// The sparse volume's tables, sized by the resolution alone.
pub(super) struct SparseTables {
    pub(super) res: u32,
    /// Brick of each top cell (or none), as `SparseVolume::top`.
    pub(super) top: wgpu::Buffer,
    /// Top cell of each brick.
    pub(super) brick_top: wgpu::Buffer,
    /// Bricks allocated, weight outside (`OUT_FIX`).
    pub(super) counters: wgpu::Buffer,
    /// The indirect workgroups of the passes over bricks, from the count: the cell passes,
    /// then the three brick steps (three words each).
    pub(super) dispatch: wgpu::Buffer,
    /// Bricks allocated by the last mark and allocate passes, when they were read back.
    pub(super) counted: Option<u32>,
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
            wgpu::BindGroupEntry { binding: 7, resource: tables.dispatch.as_entire_binding() },
        ],
    })
}

/// An inclusive box of integer coordinates: (lowest, highest) per axis.
pub(super) type CoordBox = ([u32; 3], [u32; 3]);

/// The grid cells (inclusive, unclamped) that a cache's voxels with coordinates in `coords`
/// (inclusive) can write when moved by `job` (its f32 rows, as the shader reads them): an
/// affine map takes its extremes at the box's corners, the split filter writes the cell below
/// and above, and one cell of margin on each side covers the shader's f32 arithmetic.
pub(super) fn job_cells(job: &GpuGiJob, coords: CoordBox) -> ([i64; 3], [i64; 3]) {
    let (lo, hi) = coords;
    let rows = [job.grid_x, job.grid_y, job.grid_z].map(|r| r.map(f64::from));
    let (mut gmin, mut gmax) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for k in 0..8 {
        let c = [0, 1, 2].map(|i| if k & (1 << i) == 0 { lo[i] } else { hi[i] } as f64);
        for (a, r) in rows.iter().enumerate() {
            let g = r[0] * c[0] + r[1] * c[1] + r[2] * c[2] + r[3];
            gmin[a] = gmin[a].min(g);
            gmax[a] = gmax[a].max(g);
        }
    }
    // Rows overflowed to ±∞ (absurd scales) bound nothing: the whole volume, then.
    let cell =
        |v: f64, d: f64, whole: i64| if v.is_finite() { (v.floor() + d).clamp(-1e12, 1e12) as i64 } else { whole };
    ([0, 1, 2].map(|i| cell(gmin[i], -1.0, i64::MIN)), [0, 1, 2].map(|i| cell(gmax[i], 2.0, i64::MAX)))
}

/// Bricks of a `res`³ volume that the cell boxes can touch: the union of the boxes' top
/// cells (an upper bound on what the mark pass marks).
pub(super) fn brick_bound(boxes: &[([i64; 3], [i64; 3])], res: u32) -> u32 {
    let tr = (res / BRICK).max(1) as i64;
    let mut marked = vec![0u64; (tr.pow(3) as usize).div_ceil(64)];
    let mut count = 0u32;
    for (lo, hi) in boxes {
        let r = |i: usize| {
            let a = lo[i].clamp(0, res as i64 - 1) / BRICK as i64;
            let b = hi[i].clamp(0, res as i64 - 1) / BRICK as i64;
            (a, b)
        };
        if (0..3).any(|i| hi[i] < 0 || lo[i] >= res as i64) {
            continue; // wholly outside: its weight goes to the outside counter
        }
        let (x, y, z) = (r(0), r(1), r(2));
        for k in z.0..=z.1 {
            for j in y.0..=y.1 {
                for i in x.0..=x.1 {
                    let t = (i + tr * (j + tr * k)) as usize;
                    if marked[t / 64] & (1 << (t % 64)) == 0 {
                        marked[t / 64] |= 1 << (t % 64);
                        count += 1;
                    }
                }
            }
        }
    }
    count
}

/// The sparse volume's allocation of one rebuilt frame, recorded into its command buffer.
pub(super) struct Allocation {
    /// The mark pass's bind group (the allocate pass shares it).
    pub(super) bind: wgpu::BindGroup,
    /// Workgroups of the mark pass (one thread per moved voxel).
    pub(super) splat_groups: (u32, u32),
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
            dispatch: make("gi sparse dispatch", 48, wgpu::BufferUsages::INDIRECT),
            counted: None,
        });
        Ok(())
    }

    /// The mark pass's uniforms and bind group for this frame's moved voxels.
    pub(super) fn allocation(
        &mut self,
        ctx: &GpuContext,
        voxels: &wgpu::Buffer,
        jobs: &wgpu::Buffer,
        splat: GpuGiSplat,
        splat_groups: (u32, u32),
    ) -> Result<Allocation, GpuError> {
        let tables = self.sparse.as_ref().ok_or_else(|| GpuError::Device("GI top table missing".into()))?;
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
        Ok(Allocation { bind, splat_groups })
    }

    /// Records the mark and allocate passes: afterwards `counters[0]` holds the bricks and the
    /// top table each marked cell's brick.
    pub(super) fn record_allocation(
        &self,
        enc: &mut wgpu::CommandEncoder,
        alloc: &Allocation,
        timestamp_writes: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) -> Result<(), GpuError> {
        let tables = self.sparse.as_ref().ok_or_else(|| GpuError::Device("GI top table missing".into()))?;
        enc.clear_buffer(&tables.top, 0, None);
        enc.clear_buffer(&tables.counters, 0, None);
        let mut pass =
            enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("gi bricks"), timestamp_writes });
        pass.set_bind_group(0, &alloc.bind, &[]);
        if alloc.splat_groups.0 > 0 {
            pass.set_pipeline(&self.sparse_splat_pipe);
            pass.dispatch_workgroups(alloc.splat_groups.0, alloc.splat_groups.1, 1);
        }
        let g = (tables.res / BRICK).div_ceil(4);
        pass.set_pipeline(&self.sparse_alloc_pipe);
        pass.dispatch_workgroups(g, g, g);
        pass.set_pipeline(&self.sparse_dispatch_pipe);
        pass.dispatch_workgroups(1, 1, 1);
        Ok(())
    }

    /// Runs the mark and allocate passes on their own and reads back how many bricks they
    /// allocated (the volumes whose bound is too loose to size the pool by). Returns the count
    /// and the wall-clock milliseconds of the submit and the read.
    pub(super) fn count_bricks(&mut self, ctx: &GpuContext, alloc: &Allocation) -> Result<(u32, f64), GpuError> {
        let t0 = std::time::Instant::now();
        let mut enc = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("gi bricks") });
        self.record_allocation(&mut enc, alloc, None)?;
        let count = self.read_counter(ctx, enc)?;
        Ok((count, t0.elapsed().as_secs_f64() * 1e3))
    }

    /// Bricks the last frame's volume holds, read back (None for a dense volume): for tools
    /// and tests, the render path never needs it.
    pub(crate) fn read_bricks(&mut self, ctx: &GpuContext) -> Result<Option<u32>, GpuError> {
        if !self.volume.as_ref().is_some_and(|v| v.layout == Layout::Sparse) || self.sparse.is_none() {
            return Ok(None);
        }
        let enc = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("gi bricks") });
        self.read_counter(ctx, enc).map(Some)
    }

    /// Submits `enc` with a copy of the brick counter and reads it.
    fn read_counter(&mut self, ctx: &GpuContext, mut enc: wgpu::CommandEncoder) -> Result<u32, GpuError> {
        let mappable = wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST;
        ensure(ctx, &mut self.kept.brick_count, "gi brick count", 4, true, mappable);
        let tables = self.sparse.as_ref().ok_or_else(|| GpuError::Device("GI top table missing".into()))?;
        let readback =
            self.kept.brick_count.as_ref().ok_or_else(|| GpuError::Device("brick count buffer missing".into()))?;
        enc.copy_buffer_to_buffer(&tables.counters, 0, readback, 0, 4);
        ctx.queue.submit([enc.finish()]);
        let count: Vec<u32> = read(ctx, readback)?;
        Ok(count.first().copied().unwrap_or(0))
    }
}
