//! Rewriting scattered rows of a GPU buffer in one upload: the rows are packed, uploaded
//! with their indices, and a compute pass (`scatter_rows` in `wgsl/scatter.wgsl`) puts each
//! in its place. A crowd's frame rewrites a few thousand of its 80 000 instances, spread over
//! hundreds of runs; a queue write per run cost 1.6 ms of host time a frame on lavapipe.

use super::context::GpuContext;
use super::renderer::ensure;

/// The uniform of `scatter_rows`. WGSL: `ScatterParams`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct ScatterParams {
    rows: u32,
    row_vec4s: u32,
    stride: u32,
    pad: u32,
}

/// Invocations per workgroup of `scatter_rows`.
const GROUP: u32 = 64;

/// The scatter pass with its upload buffers, kept between frames.
pub(crate) struct ScatterRows {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    params: Option<wgpu::Buffer>,
    src: Option<wgpu::Buffer>,
    ids: Option<wgpu::Buffer>,
    /// The bind group and the destination it names (rebuilt when either changes).
    bind: Option<(wgpu::BindGroup, wgpu::Buffer)>,
}

impl ScatterRows {
    /// The pass on `ctx`'s device.
    pub(crate) fn new(ctx: &GpuContext) -> ScatterRows {
        use super::context::{buffer_entry, BufferKind};
        let (pipeline, layout) = ctx.compute_pass(
            "scatter rows",
            include_str!("../../wgsl/scatter.wgsl").into(),
            "scatter_rows",
            &[
                buffer_entry(0, BufferKind::Uniform, None),
                buffer_entry(1, BufferKind::Read, None),
                buffer_entry(2, BufferKind::Read, None),
                buffer_entry(3, BufferKind::Write, None),
            ],
        );
        ScatterRows { pipeline, layout, params: None, src: None, ids: None, bind: None }
    }

    /// Uploads the rows `ids`, each `make(i)` packed straight into the upload's memory (no
    /// copy of every row is kept on the host), and encodes the pass that writes each into row
    /// `i` of `dst`, which must hold the other rows already. Rows are 16-byte multiples (the
    /// pass copies `vec4<u32>` words); ids must be in range and distinct. Nothing is encoded
    /// for no ids.
    pub(crate) fn encode<T: bytemuck::Pod>(
        &mut self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        dst: &wgpu::Buffer,
        ids: &[u32],
        make: impl Fn(u32) -> T,
    ) {
        const { assert!(std::mem::size_of::<T>() % 16 == 0 && std::mem::size_of::<T>() > 0) };
        let row = std::mem::size_of::<T>();
        let Some(bytes) = wgpu::BufferSize::new((ids.len() * row) as u64) else {
            return;
        };
        let storage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        let mut replaced = ensure(ctx, &mut self.src, "scatter rows", bytes.get(), false, storage);
        replaced |= ensure(ctx, &mut self.ids, "scatter ids", (ids.len() * 4) as u64, false, storage);
        let uniform = wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST;
        let params_size = std::mem::size_of::<ScatterParams>() as u64;
        replaced |= ensure(ctx, &mut self.params, "scatter params", params_size, true, uniform);
        let (Some(src), Some(id_buf), Some(params)) = (&self.src, &self.ids, &self.params) else {
            return;
        };
        // Packed straight into the upload's staging memory: no copy of the rows on the host.
        if let Some(mut view) = ctx.queue.write_buffer_with(src, 0, bytes) {
            for (k, &i) in ids.iter().enumerate() {
                view.slice(k * row..(k + 1) * row).copy_from_slice(bytemuck::bytes_of(&make(i)));
            }
        }
        ctx.queue.write_buffer(id_buf, 0, bytemuck::cast_slice(ids));
        let words = ids.len() as u32 * (row / 16) as u32;
        let groups = words.div_ceil(GROUP);
        let x = groups.min(65_535);
        let p = ScatterParams { rows: ids.len() as u32, row_vec4s: (row / 16) as u32, stride: x * GROUP, pad: 0 };
        ctx.queue.write_buffer(params, 0, bytemuck::bytes_of(&p));
        if replaced || self.bind.as_ref().is_none_or(|(_, d)| d != dst) {
            let group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("scatter rows"),
                layout: &self.layout,
                entries: &[
                    wgpu::BindGroupEntry { binding: 0, resource: params.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 1, resource: src.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 2, resource: id_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 3, resource: dst.as_entire_binding() },
                ],
            });
            self.bind = Some((group, dst.clone()));
        }
        if let Some((group, _)) = &self.bind {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("scatter rows"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, group, &[]);
            pass.dispatch_workgroups(x, groups.div_ceil(x), 1);
        }
    }
}
