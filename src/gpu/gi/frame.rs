//! Per-frame GI inputs kept between frames, and bind groups made again only when a buffer
//! they name was replaced.

use super::*;

/// Per-frame GI inputs kept from frame to frame: rewritten in place, replaced only when a
/// frame needs a larger one, and bind groups made again only when a buffer they name was
/// replaced, so a steady animation with GI creates no buffers either.
#[derive(Default)]
pub(super) struct GiFrameBuffers {
    /// The instances' transformation jobs.
    pub(super) jobs: Option<wgpu::Buffer>,
    /// The splat uniforms, and their copy with `mark` set for the sparse allocation.
    pub(super) splat: Option<wgpu::Buffer>,
    pub(super) mark: Option<wgpu::Buffer>,
    /// The GI frame uniforms of the tracer's entries.
    pub(super) frame: Option<wgpu::Buffer>,
    /// The half-resolution gather's samples (light, and 1 where the sample pixel is a hit).
    pub(super) samples: Option<wgpu::Buffer>,
    /// The radiance caches' points and maps.
    pub(super) cache_points: Option<wgpu::Buffer>,
    pub(super) cache_maps: Option<wgpu::Buffer>,
    /// The sparse brick steps' uniforms (8³ → 4³ → 2³ → top table).
    pub(super) brick_steps: Vec<Option<wgpu::Buffer>>,
    /// Where the sparse brick count is read back.
    pub(super) brick_count: Option<wgpu::Buffer>,
    /// Bind groups by name (and step), with the buffers they were made over.
    pub(super) binds: HashMap<(&'static str, usize), (Vec<wgpu::Buffer>, wgpu::BindGroup)>,
}

impl GiFrameBuffers {
    /// The buffer in `slot` (exactly `bytes` long for a uniform, else at least), made only
    /// when the one there does not fit, with `bytes` written into it.
    pub(super) fn write(
        ctx: &GpuContext,
        slot: &mut Option<wgpu::Buffer>,
        label: &'static str,
        bytes: &[u8],
        usage: wgpu::BufferUsages,
    ) -> Result<wgpu::Buffer, GpuError> {
        let exact = usage.contains(wgpu::BufferUsages::UNIFORM);
        ensure(ctx, slot, label, bytes.len() as u64, exact, usage | wgpu::BufferUsages::COPY_DST);
        let buf = slot.clone().ok_or_else(|| GpuError::Device(format!("{label} missing")))?;
        ctx.queue.write_buffer(&buf, 0, bytes);
        Ok(buf)
    }
}

/// The bind group `name` over the buffers in `key`: the one made before when it was made
/// over the same buffers, a new one from `make` otherwise.
pub(super) fn bind_cached(
    binds: &mut HashMap<(&'static str, usize), (Vec<wgpu::Buffer>, wgpu::BindGroup)>,
    name: (&'static str, usize),
    key: Vec<wgpu::Buffer>,
    make: impl FnOnce() -> wgpu::BindGroup,
) -> wgpu::BindGroup {
    match binds.get(&name) {
        Some((k, bind)) if *k == key => bind.clone(),
        _ => {
            let bind = make();
            binds.insert(name, (key, bind.clone()));
            bind
        }
    }
}
