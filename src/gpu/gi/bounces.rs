//! More than one bounce: the direct light and the next bounce's level 0, which the bounce
//! and commit passes (`wgsl/gi_trace.wgsl`) gather into and the level chain is made again
//! from; the GPU side of `gi::shade`'s bounces. Past the cells, the next level 0's buffer
//! holds the bounces' tail (`gi::shade::bounce_tail`): its factor, then three sums per
//! workgroup of 64 cells.

use super::volume::stored_cells;
use super::*;

impl GpuGi {
    /// Allocates the bounce passes' two level-0 buffers if a frame needs them.
    pub(super) fn bounce_buffers(&mut self, ctx: &GpuContext) -> Result<(), GpuError> {
        let Some(vol) = self.volume.as_mut().filter(|v| v.bounce.is_none()) else {
            return Ok(());
        };
        let cells = stored_cells(vol.layout, vol.res, vol.capacity);
        let size = cells * 16;
        let next_size = size + (1 + 3 * cells.div_ceil(64)) * 16;
        ctx.check_binding("the GI bounce volume", size)?;
        let held = vol.accum.size() + vol.levels.size();
        ctx.check_memory(
            || format!("the GPU GI volume of {}³ cells with a second bounce", vol.res),
            held + size + next_size,
            "lower the GI resolution or the bounces, or raise the memory budget",
        )?;
        ctx.check_binding("the GI bounce volume with its tail", next_size)?;
        let make = |label, size| {
            ctx.buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            })
        };
        vol.bounce = Some((make("gi direct level 0", size), make("gi next level 0 and bounce tail", next_size)));
        Ok(())
    }
}
