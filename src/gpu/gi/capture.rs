//! Reading the GI volume back (tests and tools).

use super::*;

/// The GI volume of the last frame, read back from the GPU (for tests and tools: the render
/// path never reads it back).
#[derive(Clone, Debug)]
pub struct GiCapture {
    /// The transformed voxels, the fixed-point sums converted back to floats.
    pub volume: Volume,
    /// Weight that fell outside the volume.
    pub outside: f64,
    /// The injected light and the level chain (with anisotropic levels, each coarse level as
    /// its +x face: the other five follow it in the GPU's buffer and are not read back).
    pub levels: Levels,
    /// The factor the last bounce's light was scaled by for the bounces after it
    /// (`gi::shade::bounce_tail`), when the frame added the tail.
    pub tail: Option<Vec3>,
}

/// Bytes of one vec4 of the level buffers.
const VEC4: u64 = 16;

/// Whether [`GpuGi::copy_capture`] copies the tail's factor (the frame added the tail, and
/// the next level 0's buffer holds the slot after its cells).
fn tail_copied(vol: &VolumeBuffers, work: &GiWork) -> bool {
    work.tail && vol.bounce.as_ref().is_some_and(|(_, next)| (work.cells as u64 + 1) * VEC4 <= next.size())
}

impl GpuGi {
    /// Copies the volume to readback buffers (submit `enc`, then [`GpuGi::read_capture`]).
    pub(crate) fn copy_capture(
        &self,
        ctx: &GpuContext,
        work: &GiWork,
        enc: &mut wgpu::CommandEncoder,
    ) -> Option<Vec<wgpu::Buffer>> {
        let vol = self.volume.as_ref()?;
        let copy = |enc: &mut wgpu::CommandEncoder, src: &wgpu::Buffer, offset: u64, size: u64| {
            let dst = ctx.buffer(&wgpu::BufferDescriptor {
                label: Some("gi readback"),
                size,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            enc.copy_buffer_to_buffer(src, offset, &dst, 0, size);
            dst
        };
        let whole = |enc: &mut wgpu::CommandEncoder, src: &wgpu::Buffer| copy(enc, src, 0, src.size());
        let mut out = vec![whole(enc, &vol.accum), whole(enc, &vol.levels)];
        if let Some(t) = self.sparse.as_ref().filter(|_| vol.layout == Layout::Sparse) {
            out.extend([whole(enc, &t.brick_top), whole(enc, &t.counters)]);
        }
        // Last: the bounces' tail factor, the one vec4 after the cells of the next level 0.
        if let Some((_, next)) = vol.bounce.as_ref().filter(|_| tail_copied(vol, work)) {
            out.push(copy(enc, next, work.cells as u64 * VEC4, VEC4));
        }
        Some(out)
    }

    /// Reads the copies of [`GpuGi::copy_capture`] back into CPU structures; a sparse volume
    /// comes back scattered into the dense layout (cells and levels without a brick empty), so
    /// both compare with the CPU's dense volume.
    pub(crate) fn read_capture(
        &self,
        ctx: &GpuContext,
        work: &GiWork,
        bufs: &[wgpu::Buffer],
    ) -> Result<GiCapture, GpuError> {
        let vol = self.volume.as_ref().ok_or_else(|| GpuError::Device("GI volume missing".into()))?;
        let missing = || GpuError::Readback("GI capture incomplete".into());
        let mut accum: Vec<u32> = read(ctx, bufs.first().ok_or_else(missing)?)?;
        let mut rgba: Vec<[f32; 4]> = read(ctx, bufs.get(1).ok_or_else(missing)?)?;
        let mut offsets = vol.offsets.clone();
        let tail = match bufs.last().filter(|_| tail_copied(vol, work)) {
            Some(factor) => {
                let f: Vec<[f32; 4]> = read(ctx, factor)?;
                let f = f.first().ok_or_else(missing)?;
                Some(Vec3::new(f[0], f[1], f[2]))
            }
            None => None,
        };
        if vol.layout == Layout::Sparse {
            let brick_top: Vec<u32> = read(ctx, bufs.get(2).ok_or_else(missing)?)?;
            let counters: Vec<u32> = read(ctx, bufs.get(3).ok_or_else(missing)?)?;
            let bricks = (counters.first().copied().unwrap_or(0) as usize).min(work.stats.brick_capacity as usize);
            let (res, tr) = (vol.res as usize, (vol.res / BRICK) as usize);
            // The finest cell (dense index) of cell k of brick level l's brick b.
            let dense_index = |l: usize, b: usize, k: usize| {
                let (side, r) = ((BRICK >> l) as usize, res >> l);
                let t = brick_top[b] as usize;
                let c = [
                    (t % tr) * side + k % side,
                    ((t / tr) % tr) * side + (k / side) % side,
                    (t / (tr * tr)) * side + k / (side * side),
                ];
                c[0] + r * (c[1] + r * c[2])
            };
            let mut dense_accum = vec![0u32; res.pow(3) * STRIDE + 1];
            for b in 0..bricks {
                for k in 0..BRICK_CELLS as usize {
                    let (src, dst) = ((b * BRICK_CELLS as usize + k) * STRIDE, dense_index(0, b, k) * STRIDE);
                    dense_accum[dst..dst + STRIDE].copy_from_slice(&accum[src..src + STRIDE]);
                }
            }
            dense_accum[res.pow(3) * STRIDE] = counters.get(1).copied().unwrap_or(0);
            accum = dense_accum;
            let mut dense_rgba = Vec::new();
            offsets.clear();
            for l in 0..BRICK_LEVELS {
                offsets.push(dense_rgba.len() as u32);
                let n = (BRICK >> l).pow(3) as usize;
                let base = dense_rgba.len();
                dense_rgba.resize(base + (res >> l).pow(3), [0.0; 4]);
                for b in 0..bricks {
                    for k in 0..n {
                        dense_rgba[base + dense_index(l, b, k)] = rgba[vol.offsets[l] as usize + b * n + k];
                    }
                }
            }
            // The coarse levels follow the scattered brick levels (a pool may be larger than
            // the dense levels it scatters into, so no signed shift).
            let (dense_end, pool_end) = (dense_rgba.len() as u32, vol.offsets[BRICK_LEVELS]);
            offsets.extend(vol.offsets[BRICK_LEVELS..].iter().map(|o| dense_end + (o - pool_end)));
            dense_rgba.extend_from_slice(&rgba[vol.offsets[BRICK_LEVELS] as usize..]);
            rgba = dense_rgba;
        }
        let (volume, outside) = volume_from_accum(&accum, work.spec);
        let levels = offsets
            .iter()
            .zip(&vol.resolutions)
            .enumerate()
            .map(|(l, (&off, &res))| {
                let n = (res as usize).pow(3);
                Level {
                    res,
                    cell: work.spec.cell * (1u64 << l) as f64,
                    rgba: rgba[off as usize..off as usize + n].iter().map(|&v| Vec4::from_array(v)).collect(),
                }
            })
            .collect();
        Ok(GiCapture { volume, outside, levels: Levels { min: work.spec.min, levels }, tail })
    }
}
