//! Refitting the instance BVH on the GPU (`bvh_refit_main` in `wgsl/refit.wgsl`): every box
//! recomputed from the instances' spheres in the instance buffer, one dispatch per level of
//! the tree, deepest first, so that each level reads the boxes the one before wrote. A crowd
//! posed on the GPU ([`super::crowd`]) has its spheres only there; its tree keeps the
//! topology it was built with, and only the boxes follow the cars.

use super::context::{GpuContext, GpuError};
use super::layout::GpuRefitLevel;
use crate::render::bvh::Bvh;

/// Invocations per workgroup of `bvh_refit_main`.
const GROUP: u32 = 64;

/// The shader source: the prelude, the shared structs and the pass.
pub fn refit_source() -> String {
    [&super::prelude::prelude(), include_str!("../../wgsl/shared/layout.wgsl"), include_str!("../../wgsl/refit.wgsl")]
        .join("\n")
}

/// Per node of `bvh`, its depth (the root's is 0; children follow their parents).
fn depths(bvh: &Bvh) -> Vec<u32> {
    let mut depth = vec![0u32; bvh.nodes.len()];
    for n in 0..bvh.nodes.len() {
        let node = bvh.nodes[n];
        if node.count == 0 {
            let below = depth[n] + 1;
            for c in [node.first as usize, node.first as usize + 1] {
                if let Some(d) = depth.get_mut(c) {
                    *d = below;
                }
            }
        }
    }
    depth
}

/// The refit pass for one tree's topology, with its node order and levels uploaded.
pub struct GpuRefit {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    /// One [`GpuRefitLevel`] per level at `stride` bytes apart (read with dynamic offsets).
    levels: wgpu::Buffer,
    stride: u64,
    /// Nodes per level, deepest first.
    counts: Vec<u32>,
    order: wgpu::Buffer,
    items: wgpu::Buffer,
    /// Nodes and items of the tree.
    shape: (usize, usize),
    /// The bind group and the instance and node buffers it names.
    bind: Option<(wgpu::BindGroup, wgpu::Buffer, wgpu::Buffer)>,
}

impl GpuRefit {
    /// The pass for `bvh`'s topology (its boxes are not read).
    pub fn new(ctx: &GpuContext, bvh: &Bvh) -> Result<GpuRefit, GpuError> {
        let depth = depths(bvh);
        let levels = depth.iter().max().map_or(0, |&d| d as usize + 1);
        // Node indices by level, deepest first.
        let mut by_level: Vec<Vec<u32>> = vec![Vec::new(); levels];
        for (n, &d) in depth.iter().enumerate() {
            by_level[levels - 1 - d as usize].push(n as u32);
        }
        let counts: Vec<u32> = by_level.iter().map(|l| l.len() as u32).collect();
        let order: Vec<u32> = by_level.concat();
        ctx.check_binding("the BVH refit's node order", (order.len() * 4) as u64)?;
        ctx.check_binding("the BVH items", (bvh.items.len() * 4) as u64)?;
        let stride = (ctx.limits.min_uniform_buffer_offset_alignment as u64).max(16);
        let mut level_bytes = vec![0u8; (stride as usize * levels).max(16)];
        let mut first = 0;
        for (k, &count) in counts.iter().enumerate() {
            let rec = GpuRefitLevel { first, count, pad0: 0, pad1: 0 };
            let at = k * stride as usize;
            level_bytes[at..at + 16].copy_from_slice(bytemuck::bytes_of(&rec));
            first += count;
        }
        let init = |label, contents: &[u8], usage| {
            let padded = if contents.is_empty() { &[0u8; 16][..] } else { contents };
            ctx.buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents: padded, usage })
        };
        let levels_buf = init("refit levels", &level_bytes, wgpu::BufferUsages::UNIFORM);
        let order_buf = init("refit order", bytemuck::cast_slice(&order), wgpu::BufferUsages::STORAGE);
        let items_buf = init("refit items", bytemuck::cast_slice(&bvh.items), wgpu::BufferUsages::STORAGE);
        use super::context::{buffer_entry, BufferKind};
        let (pipeline, layout) = ctx.compute_pass(
            "bvh refit",
            refit_source(),
            "bvh_refit_main",
            &[
                // One level's record at a time, at its offset.
                buffer_entry(0, BufferKind::Uniform, Some(16)),
                buffer_entry(1, BufferKind::Read, None),
                buffer_entry(2, BufferKind::Read, None),
                buffer_entry(3, BufferKind::Read, None),
                buffer_entry(4, BufferKind::Write, None),
            ],
        );
        Ok(GpuRefit {
            pipeline,
            layout,
            levels: levels_buf,
            stride,
            counts,
            order: order_buf,
            items: items_buf,
            shape: (bvh.nodes.len(), bvh.items.len()),
            bind: None,
        })
    }

    /// Levels of the tree (dispatches a refit takes).
    pub fn levels(&self) -> usize {
        self.counts.len()
    }

    /// Encodes the refit of `nodes` (the tree's nodes as [`super::layout::GpuBvhNode`]s,
    /// their links already in place) from the spheres of `insts`, one compute pass with a
    /// dispatch per level (`timestamps`: written by that pass, which runs even for an empty
    /// tree). Refused when the buffers are too small for the tree.
    pub fn encode(
        &mut self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        insts: &wgpu::Buffer,
        nodes: &wgpu::Buffer,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) -> Result<(), GpuError> {
        let node_bytes = (self.shape.0 * std::mem::size_of::<super::layout::GpuBvhNode>()) as u64;
        if nodes.size() < node_bytes {
            return Err(GpuError::Device(format!("the BVH buffer holds {} bytes, {node_bytes} needed", nodes.size())));
        }
        if self.bind.as_ref().is_none_or(|(_, i, n)| i != insts || n != nodes) {
            let group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("bvh refit"),
                layout: &self.layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                            buffer: &self.levels,
                            offset: 0,
                            size: wgpu::BufferSize::new(16),
                        }),
                    },
                    wgpu::BindGroupEntry { binding: 1, resource: self.order.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 2, resource: self.items.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 3, resource: insts.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 4, resource: nodes.as_entire_binding() },
                ],
            });
            self.bind = Some((group, insts.clone(), nodes.clone()));
        }
        let Some((group, _, _)) = &self.bind else { return Ok(()) };
        // (A tree without nodes still runs the pass: its timestamps are written.)
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("bvh refit"),
            timestamp_writes: timestamps,
        });
        pass.set_pipeline(&self.pipeline);
        for (k, &count) in self.counts.iter().enumerate() {
            pass.set_bind_group(0, group, &[(k as u64 * self.stride) as u32]);
            let groups = count.div_ceil(GROUP);
            pass.dispatch_workgroups(groups.min(65_535), groups.div_ceil(65_535), 1);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::layout::{GpuBvhNode, GpuInstance};
    use glam::DVec3;

    use crate::gpu::context::test_context as context;

    /// Every box the GPU refits holds the host's refit of the same (f32) spheres, their radii
    /// before the f32 test's growth, and is no wider than its slack; links are kept. The tree is built on other spheres (the
    /// topology of a crowd built once), then refitted on moved ones.
    #[test]
    fn the_gpu_refits_the_bvh_as_the_host_does() {
        let Some(ctx) = context() else { return };
        let mut rng = crate::rng::Rng::new(11);
        let sphere = |rng: &mut crate::rng::Rng, spread: f64| {
            let c = DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 2.0 - 1.0;
            (c * spread + DVec3::new(3e4, -50.0, 0.0), 0.05 + 3.0 * rng.f64())
        };
        let built: Vec<(DVec3, f64)> = (0..5000).map(|_| sphere(&mut rng, 400.0)).collect();
        let bvh = Bvh::build_with(&built, false);
        // Each sphere moved by up to a few units, as a car drives: the tree stays valid.
        let moved: Vec<(DVec3, f64)> = built
            .iter()
            .map(|&(c, r)| {
                let (d, _) = sphere(&mut rng, 5.0);
                (c + d - DVec3::new(3e4, -50.0, 0.0), r * 1.5)
            })
            .collect();
        let insts: Vec<GpuInstance> = moved
            .iter()
            // (The sphere as grown for the f32 test is wider: boxes fit the radius before.)
            .map(|&(c, r)| GpuInstance {
                sphere: [c.x as f32, c.y as f32, c.z as f32, 4.0 * r as f32],
                radius: r as f32,
                ..Default::default()
            })
            .collect();
        // The host's refit of the spheres as the GPU reads them.
        let as_read: Vec<(DVec3, f64)> = insts
            .iter()
            .map(|g| (DVec3::new(g.sphere[0] as f64, g.sphere[1] as f64, g.sphere[2] as f64), g.radius as f64))
            .collect();
        let mut host = bvh.clone();
        host.refit(&as_read);
        // Links in place, boxes zeroed: the pass must write every one.
        let blank: Vec<GpuBvhNode> = crate::gpu::renderer::gpu_bvh_nodes(&bvh)
            .into_iter()
            .map(|n| GpuBvhNode { lo: [0.0, 0.0, 0.0, n.lo[3]], hi: [0.0, 0.0, 0.0, n.hi[3]] })
            .collect();
        let storage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC;
        let inst_buf = ctx.buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("insts"),
            contents: bytemuck::cast_slice(&insts),
            usage: storage,
        });
        let node_buf = ctx.buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("nodes"),
            contents: bytemuck::cast_slice(&blank),
            usage: storage,
        });
        let read = ctx.buffer(&wgpu::BufferDescriptor {
            label: Some("nodes read"),
            size: node_buf.size(),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut refit = GpuRefit::new(&ctx, &bvh).expect("refit");
        assert!(refit.levels() > 10, "{} levels", refit.levels());
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        refit.encode(&ctx, &mut enc, &inst_buf, &node_buf, None).expect("encode");
        enc.copy_buffer_to_buffer(&node_buf, 0, &read, 0, node_buf.size());
        ctx.queue.submit([enc.finish()]);
        let nodes: Vec<GpuBvhNode> = crate::gpu::renderer::read(&ctx, &read).expect("read back");
        for (k, ((g, h), b)) in nodes.iter().zip(&host.nodes).zip(&blank).enumerate() {
            assert_eq!(
                (g.lo[3].to_bits(), g.hi[3].to_bits()),
                (b.lo[3].to_bits(), b.hi[3].to_bits()),
                "node {k} links"
            );
            let (lo, hi) = (DVec3::new(g.lo[0] as f64, g.lo[1] as f64, g.lo[2] as f64), {
                DVec3::new(g.hi[0] as f64, g.hi[1] as f64, g.hi[2] as f64)
            });
            assert!(
                lo.cmple(h.lo).all() && hi.cmpge(h.hi).all(),
                "node {k}: {lo} {hi} does not hold {} {}",
                h.lo,
                h.hi
            );
            // Slack: 10⁻⁶ of the largest coordinate per level below, at most.
            let room = 1e-6 * h.lo.abs().max(h.hi.abs()).max_element() * (refit.levels() as f64 + 2.0);
            assert!((h.lo - lo).max_element() <= room && (hi - h.hi).max_element() <= room, "node {k} too wide");
        }
    }
}
