//! The dense level chain copied into a 3D texture with mips (`--gi-levels texture`).

use super::*;

/// The level chain copied into a 3D texture's mips (`LevelStore::Texture`).
pub(super) struct LevelTexture {
    /// Texels per side of mip 0 (res rounded up to a power of two).
    pub(super) size: u32,
    pub(super) view: wgpu::TextureView,
    /// Per level: the copy's bind group and its workgroups per side.
    pub(super) steps: Vec<(wgpu::BindGroup, u32)>,
}

/// A 3D rgba16float texture of `size`³ texels with `mips` levels, sampled by the cones and
/// written by the level copies.
pub(super) fn level_texture(device: &wgpu::Device, size: u32, mips: u32) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some("gi level texture"),
        size: wgpu::Extent3d { width: size, height: size, depth_or_array_layers: size },
        mip_level_count: mips,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D3,
        format: wgpu::TextureFormat::Rgba16Float,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::STORAGE_BINDING,
        view_formats: &[],
    })
}

impl GpuGi {
    /// The level texture of a dense chain and the copies that fill its mips.
    pub(super) fn level_texture_for(
        &self,
        ctx: &GpuContext,
        levels: &wgpu::Buffer,
        offsets: &[u32],
        resolutions: &[u32],
    ) -> Result<LevelTexture, GpuError> {
        let size = resolutions[0].next_power_of_two();
        let mips = offsets.len() as u32;
        if size.trailing_zeros() + 1 != mips || size > ctx.limits.max_texture_dimension_3d {
            return Err(GiError::Settings(format!(
                "a {}³ GI level texture is beyond this device (3D textures up to {}³)",
                size, ctx.limits.max_texture_dimension_3d
            ))
            .into());
        }
        let tex = level_texture(&ctx.device, size, mips);
        let steps = (0..mips as usize)
            .map(|l| {
                let step = GpuGiLevelStep {
                    src_offset: offsets[l],
                    src_res: resolutions[l],
                    dst_res: size >> l,
                    ..Default::default()
                };
                let ubuf = ctx.buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("gi level copy"),
                    contents: bytemuck::bytes_of(&step),
                    usage: wgpu::BufferUsages::UNIFORM,
                });
                let view = tex.create_view(&wgpu::TextureViewDescriptor {
                    label: Some("gi level mip"),
                    dimension: Some(wgpu::TextureViewDimension::D3),
                    base_mip_level: l as u32,
                    mip_level_count: Some(1),
                    ..Default::default()
                });
                let bind = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("gi level copy"),
                    layout: &self.texture_pipe.get_bind_group_layout(0),
                    entries: &[
                        wgpu::BindGroupEntry { binding: 0, resource: levels.as_entire_binding() },
                        wgpu::BindGroupEntry { binding: 1, resource: ubuf.as_entire_binding() },
                        wgpu::BindGroupEntry { binding: 3, resource: wgpu::BindingResource::TextureView(&view) },
                    ],
                });
                (bind, (size >> l).div_ceil(4))
            })
            .collect();
        let view = tex.create_view(&wgpu::TextureViewDescriptor {
            label: Some("gi level texture"),
            dimension: Some(wgpu::TextureViewDimension::D3),
            ..Default::default()
        });
        Ok(LevelTexture { size, view, steps })
    }
}
