//! The world volume's GPU buffers (accumulation, the level chain, the bounce levels) and the
//! dense steps down the chain; the GPU side of `gi::volume` and `gi::levels`.

use super::*;

pub(super) struct VolumeBuffers {
    pub(super) layout: Layout,
    /// The chain's texture copy, when the cones read it from a texture.
    pub(super) texture: Option<LevelTexture>,
    /// Levels 1 and coarser hold six faces each (`GiSettings::anisotropic`; dense only).
    pub(super) aniso: bool,
    pub(super) res: u32,
    /// Bricks the sparse buffers hold (0 for dense).
    pub(super) capacity: u32,
    /// STRIDE words per stored cell (then, dense, the outside counter).
    pub(super) accum: wgpu::Buffer,
    pub(super) levels: wgpu::Buffer,
    pub(super) offsets: Vec<u32>,
    pub(super) resolutions: Vec<u32>,
    /// The dense steps down the chain (sparse: from the top table's level on).
    pub(super) steps: Vec<wgpu::BindGroup>,
    /// The direct and next level 0 of the bounce passes (allocated when a frame asks for more
    /// than one bounce).
    pub(super) bounce: Option<(wgpu::Buffer, wgpu::Buffer)>,
}

/// Finest cells stored: every cell (dense) or `capacity` bricks' (sparse).
pub(super) fn stored_cells(layout: Layout, res: u32, capacity: u32) -> u64 {
    match layout {
        Layout::Dense => (res as u64).pow(3),
        Layout::Sparse => capacity as u64 * BRICK_CELLS as u64,
    }
}

/// The bind group of one step down the level chain (`brick_top` for a brick step), with its
/// uniforms in `ubuf`.
pub(super) fn level_step_bind_with(
    ctx: &GpuContext,
    pipe: &wgpu::ComputePipeline,
    levels: &wgpu::Buffer,
    ubuf: &wgpu::Buffer,
    brick_top: Option<&wgpu::Buffer>,
) -> wgpu::BindGroup {
    let mut entries = vec![
        wgpu::BindGroupEntry { binding: 0, resource: levels.as_entire_binding() },
        wgpu::BindGroupEntry { binding: 1, resource: ubuf.as_entire_binding() },
    ];
    if let Some(b) = brick_top {
        entries.push(wgpu::BindGroupEntry { binding: 2, resource: b.as_entire_binding() });
    }
    ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("gi level step"),
        layout: &pipe.get_bind_group_layout(0),
        entries: &entries,
    })
}

/// The bind group of one step down the dense chain, with uniforms of its own (made once per
/// volume).
pub(super) fn level_step_bind(
    ctx: &GpuContext,
    pipe: &wgpu::ComputePipeline,
    levels: &wgpu::Buffer,
    step: &GpuGiLevelStep,
) -> wgpu::BindGroup {
    let ubuf = ctx.buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("gi level step"),
        contents: bytemuck::bytes_of(step),
        usage: wgpu::BufferUsages::UNIFORM,
    });
    level_step_bind_with(ctx, pipe, levels, &ubuf, None)
}

impl GpuGi {
    /// Allocates the accumulation and level buffers for `res` cells per side: every cell
    /// (dense) or `capacity` bricks (sparse); `aniso` (dense buffer store only, which
    /// `GpuRenderer::set_gi` ensures) gives each coarse level six faces.
    pub(super) fn volume_buffers(
        &mut self,
        ctx: &GpuContext,
        layout: Layout,
        res: u32,
        capacity: u32,
        texture: bool,
        aniso: bool,
    ) -> Result<(), GpuError> {
        if self.volume.as_ref().is_some_and(|v| {
            v.layout == layout
                && v.res == res
                && v.capacity == capacity
                && v.texture.is_some() == texture
                && v.aniso == aniso
        }) {
            return Ok(());
        }
        self.volume = None; // free the old volume before allocating the new one
        let cells = stored_cells(layout, res, capacity);
        let accum_size = (cells * STRIDE as u64 + 1) * 4;
        ctx.check_binding("the GI accumulation volume", accum_size)?;
        let (mut offsets, mut resolutions, mut total) = (Vec::new(), Vec::new(), 0u64);
        let mut r = res;
        if layout == Layout::Sparse {
            // The bricks' levels, then the dense chain from the top table.
            for l in 0..BRICK_LEVELS {
                offsets.push(total as u32);
                resolutions.push(res >> l);
                total += capacity as u64 * ((BRICK >> l) as u64).pow(3);
            }
            r = res / BRICK;
        }
        let first_dense = offsets.len();
        loop {
            offsets.push(total as u32);
            resolutions.push(r);
            // An anisotropic chain's coarse levels hold six faces, one after another.
            let faces = if aniso && offsets.len() > 1 { 6 } else { 1 };
            total += faces * (r as u64).pow(3);
            if r == 1 {
                break;
            }
            r = r.div_ceil(2);
        }
        if offsets.len() > MAX_LEVELS {
            return Err(GiError::Resolution(res).into());
        }
        ctx.check_binding("the GI level chain", total * 16)?;
        // The level texture, where used: the whole volume in rgba16float with its mips.
        let texture_bytes = if texture { (res.next_power_of_two() as u64).pow(3) * 8 * 8 / 7 } else { 0 };
        ctx.check_memory(
            || format!("the GPU GI volume of {res}³ cells ({layout:?}) and its level chain"),
            accum_size + total * 16 + texture_bytes,
            "lower the GI resolution, use the sparse volume, or raise the memory budget",
        )?;
        let accum = ctx.buffer(&wgpu::BufferDescriptor {
            label: Some("gi accumulation"),
            size: accum_size,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let levels = ctx.buffer(&wgpu::BufferDescriptor {
            label: Some("gi levels"),
            size: total * 16,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let steps = (first_dense + 1..offsets.len())
            .map(|l| {
                let step = GpuGiLevelStep {
                    src_offset: offsets[l - 1],
                    src_res: resolutions[l - 1],
                    dst_offset: offsets[l],
                    dst_res: resolutions[l],
                    src_faces: (aniso && l > 1) as u32,
                    ..Default::default()
                };
                let pipe = if aniso { &self.levels_aniso_pipe } else { &self.levels_pipe };
                level_step_bind(ctx, pipe, &levels, &step)
            })
            .collect();
        let texture = match texture {
            true => Some(self.level_texture_for(ctx, &levels, &offsets, &resolutions)?),
            false => None,
        };
        self.volume = Some(VolumeBuffers {
            layout,
            texture,
            aniso,
            res,
            capacity,
            accum,
            levels,
            offsets,
            resolutions,
            steps,
            bounce: None,
        });
        Ok(())
    }
}
