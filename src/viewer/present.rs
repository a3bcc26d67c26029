//! Drawing frames to the window: the wgpu surface, its pipelines (a CPU frame as a
//! texture, a GPU frame straight from the renderer's radiance buffer) and egui's pass, the
//! window capture for screenshots, and the softbuffer window when there is no adapter.

use super::*;

pub(super) struct Gfx {
    pub(super) window: Arc<Window>,
    pub(super) surface: wgpu::Surface<'static>,
    pub(super) ctx: Arc<GpuContext>,
    pub(super) config: wgpu::SurfaceConfiguration,
    pub(super) pipeline: wgpu::RenderPipeline,
    pub(super) layout: wgpu::BindGroupLayout,
    pub(super) sampler: wgpu::Sampler,
    pub(super) tex_format: wgpu::TextureFormat,
    pub(super) texture: Option<(wgpu::Texture, wgpu::BindGroup, u32, u32)>,
    /// Draws a GPU frame from the renderer's radiance buffer (`fs_radiance`).
    pub(super) radiance_pipeline: wgpu::RenderPipeline,
    pub(super) radiance_layout: wgpu::BindGroupLayout,
    /// The [`PresentInfo`] uniform of `fs_radiance`.
    pub(super) present_info: wgpu::Buffer,
    /// The bind group of the radiance buffer it was made for (rebuilt when the renderer
    /// replaces the buffer).
    pub(super) radiance_bind: Option<(wgpu::Buffer, wgpu::BindGroup)>,
    pub(super) egui: egui::Context,
    pub(super) egui_state: egui_winit::State,
    pub(super) egui_renderer: egui_wgpu::Renderer,
}

/// `PresentInfo` of `wgsl/blit.wgsl`: where a GPU frame's radiance lies in the window.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct PresentInfo {
    pub(super) origin: [u32; 2],
    pub(super) size: [u32; 2],
    pub(super) encode: u32,
    pub(super) pad: [u32; 3],
}

/// The window drawn in software (no GPU adapter at all).
pub(super) struct Soft {
    pub(super) window: Arc<Window>,
    pub(super) surface: softbuffer::Surface<Arc<Window>, Arc<Window>>,
}

/// Copies the frame (rendered at the window's size) into the software window; with
/// `capture`, also returns those pixels, which are exactly what the window shows.
/// Uploads a CPU frame (sRGB bytes) into the texture `fs_main` samples, made anew only when
/// the frame's size changes.
pub(super) fn upload_frame(g: &mut Gfx, frame: &Frame) {
    let device = &g.ctx.device;
    if !g.texture.as_ref().is_some_and(|t| t.2 == frame.width && t.3 == frame.height) {
        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("frame"),
            size: wgpu::Extent3d { width: frame.width, height: frame.height, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: g.tex_format,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        let view = texture.create_view(&Default::default());
        let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("blit"),
            layout: &g.layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: wgpu::BindingResource::TextureView(&view) },
                wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::Sampler(&g.sampler) },
            ],
        });
        g.texture = Some((texture, bind, frame.width, frame.height));
    }
    let Some((texture, _, _, _)) = g.texture.as_ref() else { return };
    let rgba = output::srgba8(frame);
    g.ctx.queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: 0,
            origin: wgpu::Origin3d::ZERO,
            aspect: wgpu::TextureAspect::All,
        },
        &rgba,
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(4 * frame.width),
            rows_per_image: Some(frame.height),
        },
        wgpu::Extent3d { width: frame.width, height: frame.height, depth_or_array_layers: 1 },
    );
}

pub(super) fn present_soft(
    s: &mut Soft,
    frame: &Frame,
    capture: bool,
) -> Result<Option<(u32, u32, Vec<u8>)>, ViewerError> {
    let soft_err = |e: softbuffer::SoftBufferError| ViewerError::Other(format!("software window: {e}"));
    let (Some(w), Some(h)) = (std::num::NonZeroU32::new(frame.width), std::num::NonZeroU32::new(frame.height)) else {
        return Ok(None);
    };
    s.surface.resize(w, h).map_err(soft_err)?;
    let rgba = output::srgba8(frame);
    let mut buffer = s.surface.buffer_mut().map_err(soft_err)?;
    for (px, c) in buffer.iter_mut().zip(rgba.chunks_exact(4)) {
        *px = (c[0] as u32) << 16 | (c[1] as u32) << 8 | c[2] as u32;
    }
    buffer.present().map_err(soft_err)?;
    Ok(capture.then(|| (frame.width, frame.height, rgba.chunks_exact(4).flat_map(|c| [c[0], c[1], c[2]]).collect())))
}

impl App {
    pub(super) fn init(&mut self, event_loop: &ActiveEventLoop) -> Result<(), ViewerError> {
        let attrs = Window::default_attributes()
            .with_title("voxray")
            .with_inner_size(winit::dpi::PhysicalSize::new(self.opts.width, self.opts.height));
        let window = Arc::new(event_loop.create_window(attrs).map_err(|e| ViewerError::NoDisplay(e.to_string()))?);
        let mut desc =
            wgpu::InstanceDescriptor::new_with_display_handle_from_env(Box::new(event_loop.owned_display_handle()));
        GpuContext::restrict_backends(&mut desc);
        let instance = wgpu::Instance::new(desc);
        let surface = match instance.create_surface(window.clone()) {
            Ok(s) => s,
            Err(e) => return self.init_soft(window, format!("no wgpu surface: {e}")),
        };
        let (ctx, adapter) = match GpuContext::with_surface(&instance, Some(&surface)) {
            Ok(x) => x,
            Err(GpuError::NoAdapter(why)) => return self.init_soft(window, why),
            Err(e) => return Err(e.into()),
        };
        let size = window.inner_size();
        let mut config = surface
            .get_default_config(&adapter, size.width.max(1), size.height.max(1))
            .ok_or_else(|| ViewerError::Other("the adapter cannot present to this window".into()))?;
        // Screenshots read the window's own image back when the surface allows copying from it.
        if surface.get_capabilities(&adapter).usages.contains(wgpu::TextureUsages::COPY_SRC) {
            config.usage |= wgpu::TextureUsages::COPY_SRC;
        }
        surface.configure(&ctx.device, &config);
        // Frames arrive as sRGB bytes: an sRGB texture decodes them and an sRGB surface
        // re-encodes; a linear surface gets the bytes as they are.
        let tex_format =
            if config.format.is_srgb() { wgpu::TextureFormat::Rgba8UnormSrgb } else { wgpu::TextureFormat::Rgba8Unorm };
        let device = &ctx.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("blit.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("../../wgsl/blit.wgsl").into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("blit"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let radiance_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("present radiance"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Storage { read_only: true },
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 3,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
            ],
        });
        let make_pipeline = |layout: &wgpu::BindGroupLayout, label: &str, fragment: &str| {
            let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(label),
                bind_group_layouts: &[Some(layout)],
                immediate_size: 0,
            });
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(label),
                layout: Some(&pl),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some("vs_main"),
                    compilation_options: Default::default(),
                    buffers: &[],
                },
                primitive: wgpu::PrimitiveState::default(),
                depth_stencil: None,
                multisample: wgpu::MultisampleState::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some(fragment),
                    compilation_options: Default::default(),
                    targets: &[Some(wgpu::ColorTargetState {
                        format: config.format,
                        blend: None,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let pipeline = make_pipeline(&layout, "blit", "fs_main");
        let radiance_pipeline = make_pipeline(&radiance_layout, "present radiance", "fs_radiance");
        let present_info = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("present info"),
            size: std::mem::size_of::<PresentInfo>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor { label: Some("blit"), ..Default::default() });
        let egui_ctx = egui::Context::default();
        let egui_state = egui_winit::State::new(
            egui_ctx.clone(),
            egui::ViewportId::ROOT,
            &window,
            Some(window.scale_factor() as f32),
            None,
            Some(ctx.limits.max_texture_dimension_2d as usize),
        );
        let egui_renderer = egui_wgpu::Renderer::new(device, config.format, egui_wgpu::RendererOptions::default());
        let ctx = Arc::new(ctx);
        let (backend, name) = Backend::on_device(self.opts.backend, ctx.clone());
        eprintln!("demo: window on {}; rendering on {name}", ctx.describe());
        let kind = if matches!(backend, Backend::Cpu(_)) { BackendKind::Cpu } else { BackendKind::Gpu };
        (self.ui.backend, self.ui.backend_wanted) = (kind, kind);
        if ctx.info.device_type == wgpu::DeviceType::Cpu {
            self.ui.note = format!(
                "No hardware GPU: {} (software Vulkan) presents the window. The CPU renderer is faster here; \
                 the GPU renderer runs on the software driver when chosen.",
                ctx.info.name
            );
        }
        self.report.backend = name.clone();
        self.session = Some(Session::new(backend, name));
        self.gfx = Some(Gfx {
            window,
            surface,
            ctx,
            config,
            pipeline,
            layout,
            sampler,
            tex_format,
            texture: None,
            radiance_pipeline,
            radiance_layout,
            present_info,
            radiance_bind: None,
            egui: egui_ctx,
            egui_state,
            egui_renderer,
        });
        self.last = Instant::now();
        Ok(())
    }

    /// No GPU adapter: the CPU renderer, drawn to the window through softbuffer.
    pub(super) fn init_soft(&mut self, window: Arc<Window>, why: String) -> Result<(), ViewerError> {
        let soft_err = |e: softbuffer::SoftBufferError| ViewerError::Other(format!("software window: {e}"));
        let context = softbuffer::Context::new(window.clone()).map_err(soft_err)?;
        let surface = softbuffer::Surface::new(&context, window.clone()).map_err(soft_err)?;
        eprintln!(
            "demo: no GPU adapter ({why}); rendering on the CPU and drawing the window in software, without the \
             panel (install a Vulkan driver, e.g. Debian's mesa-vulkan-drivers, for the panel)"
        );
        self.report.backend = "CPU (no GPU adapter; software window, no panel)".into();
        self.session = Some(Session::new(Backend::Cpu(Box::default()), self.report.backend.clone()));
        (self.ui.backend, self.ui.backend_wanted) = (BackendKind::Cpu, BackendKind::Cpu);
        self.ui.show = false;
        self.soft = Some(Soft { window, surface });
        self.last = Instant::now();
        Ok(())
    }

    /// Draws the frame to the window; with `capture`, also returns the window's image as RGB
    /// bytes (width, height, data) when the surface can be copied from.
    pub(super) fn present(
        &mut self,
        frame: &Frame,
        capture: bool,
        mut ui: Option<UiPaint>,
    ) -> Result<Option<(u32, u32, Vec<u8>)>, ViewerError> {
        if let Some(s) = self.soft.as_mut() {
            return present_soft(s, frame, capture);
        }
        // A frame kept on the GPU: the renderer's radiance buffer, on this device.
        let radiance = if frame.on_device {
            let gpu = self.session.as_ref().and_then(|s| s.backend().gpu());
            let found = gpu.and_then(|r| r.radiance()).map(|(b, w, h)| (b.clone(), w, h));
            Some(found.ok_or_else(|| ViewerError::Other("the GPU frame has no radiance buffer".into()))?)
        } else {
            None
        };
        let Some(g) = self.gfx.as_mut() else { return Ok(None) };
        let device = &g.ctx.device;
        match &radiance {
            Some((buf, w, h)) => {
                if g.radiance_bind.as_ref().is_none_or(|(b, _)| b != buf) {
                    let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
                        label: Some("present radiance"),
                        layout: &g.radiance_layout,
                        entries: &[
                            wgpu::BindGroupEntry { binding: 2, resource: buf.as_entire_binding() },
                            wgpu::BindGroupEntry { binding: 3, resource: g.present_info.as_entire_binding() },
                        ],
                    });
                    g.radiance_bind = Some((buf.clone(), bind));
                }
                let info = PresentInfo {
                    origin: [g.config.width.saturating_sub(*w), 0],
                    size: [*w, *h],
                    encode: (!g.config.format.is_srgb()) as u32,
                    pad: [0; 3],
                };
                g.ctx.queue.write_buffer(&g.present_info, 0, bytemuck::bytes_of(&info));
            }
            None => upload_frame(g, frame),
        }
        let device = &g.ctx.device;
        // egui's texture changes must be applied (or freed) every frame, even one that is not
        // presented: take them out now.
        let mut free_ids = Vec::new();
        if let Some(t) = ui.as_mut().map(|u| &mut u.textures) {
            for (id, deltas) in &t.set {
                for delta in deltas {
                    g.egui_renderer.update_texture(device, &g.ctx.queue, *id, delta);
                }
            }
            free_ids = t.free.drain().collect();
            // Applied: tell egui so (it checks that no delta is dropped unapplied).
            t.clear();
        }
        let free = |g: &mut Gfx| {
            for id in &free_ids {
                g.egui_renderer.free_texture(id);
            }
        };
        let target = match g.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t) | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                g.surface.configure(&g.ctx.device, &g.config);
                free(g);
                return Ok(None);
            }
            _ => {
                free(g); // timeout or occluded: skip this frame
                return Ok(None);
            }
        };
        let view = target.texture.create_view(&Default::default());
        let (w, h) = (target.texture.width(), target.texture.height());
        let mut enc = device.create_command_encoder(&Default::default());
        if let Some(ui) = &ui {
            let extra = g.egui_renderer.update_buffers(device, &g.ctx.queue, &mut enc, &ui.jobs, &ui.screen);
            g.ctx.queue.submit(extra);
        }
        {
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("blit"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            match (&radiance, &g.radiance_bind, &g.texture) {
                (Some(_), Some((_, bind)), _) => {
                    pass.set_pipeline(&g.radiance_pipeline);
                    pass.set_bind_group(0, bind, &[]);
                }
                (None, _, Some((_, bind, _, _))) => {
                    pass.set_pipeline(&g.pipeline);
                    pass.set_bind_group(0, bind, &[]);
                }
                _ => return Err(ViewerError::Other("nothing to draw the frame from".into())),
            }
            // The frame fills the window right of the panel (it was rendered that size).
            let x0 = w.saturating_sub(frame.width) as f32;
            pass.set_viewport(x0, 0.0, frame.width.min(w) as f32, frame.height.min(h) as f32, 0.0, 1.0);
            pass.draw(0..3, 0..1);
            pass.set_viewport(0.0, 0.0, w as f32, h as f32, 0.0, 1.0);
            if let Some(ui) = &ui {
                let mut pass = pass.forget_lifetime();
                g.egui_renderer.render(&mut pass, &ui.jobs, &ui.screen);
            }
        }
        let row = (4 * w).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let readback = (capture && g.config.usage.contains(wgpu::TextureUsages::COPY_SRC)).then(|| {
            let buf = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("window capture"),
                size: (row * h) as u64,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            enc.copy_texture_to_buffer(
                target.texture.as_image_copy(),
                wgpu::TexelCopyBufferInfo {
                    buffer: &buf,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(row),
                        rows_per_image: Some(h),
                    },
                },
                wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
            );
            buf
        });
        g.ctx.queue.submit([enc.finish()]);
        let captured = match readback {
            Some(buf) => {
                let bytes: Vec<u8> = crate::gpu::renderer::read(&g.ctx, &buf).map_err(ViewerError::Gpu)?;
                let bgra =
                    matches!(g.config.format, wgpu::TextureFormat::Bgra8Unorm | wgpu::TextureFormat::Bgra8UnormSrgb);
                let mut rgb = Vec::with_capacity((3 * w * h) as usize);
                for y in 0..h as usize {
                    for px in bytes[y * row as usize..][..4 * w as usize].chunks_exact(4) {
                        rgb.extend_from_slice(&if bgra { [px[2], px[1], px[0]] } else { [px[0], px[1], px[2]] });
                    }
                }
                Some((w, h, rgb))
            }
            None => None,
        };
        g.ctx.queue.present(target);
        free(g);
        Ok(captured)
    }
}
