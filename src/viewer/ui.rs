//! The egui panel: what it shows and what it changes.

use super::*;

/// What the panel shows and changes.
pub(super) struct Ui {
    pub(super) show: bool,
    pub(super) fly: bool,
    pub(super) cars: usize,
    pub(super) cars_wanted: usize,
    pub(super) cars_dragging: bool,
    pub(super) backend: BackendKind,
    pub(super) backend_wanted: BackendKind,
    pub(super) note: String,
    pub(super) speed: f64,
    pub(super) travel: bool,
    pub(super) lod: u32,
    /// Primary visibility: rays or square splats.
    pub(super) splat: bool,
    /// How the GPU draws them.
    pub(super) splat_draw: crate::render::SplatDraw,
    pub(super) frame_ms: VecDeque<f32>,
    pub(super) plan: Option<FramePlan>,
    pub(super) reused: f64,
    pub(super) mrays: f64,
    pub(super) per_ray: (f64, f64),
    /// Cars posed this frame (those some ray can reach) and all cars.
    pub(super) posed: (usize, usize),
    pub(super) gi_on: bool,
    pub(super) gi: crate::gi::GiSettings,
    pub(super) gi_ms: Option<f64>,
    // GI ran in the backend (the GPU passes), not on the CPU after it.
    pub(super) gi_on_gpu: bool,
    /// Why GI was switched off (knobs this device cannot run), shown in the panel.
    pub(super) gi_error: Option<String>,
    // Most rays hit at t = 0 last frame.
    pub(super) eye_inside: bool,
    pub(super) gpu_ms: Option<(f64, f64)>,
    /// Count GPU frames' statistics on the GPU (32 bytes and the pass times read back a
    /// frame; the frames still stay on the GPU).
    pub(super) gpu_stats: bool,
    /// Read every GPU frame back whole (`--gpu-read-back`: the path before frames stayed on
    /// the GPU, for comparisons).
    pub(super) read_all: bool,
    /// The last frame has no statistics (it stayed on the GPU and nothing was counted).
    pub(super) on_device: bool,
    pub(super) reset: bool,
}

/// egui output of one frame, ready to paint.
pub(super) struct UiPaint {
    pub(super) jobs: Vec<egui::ClippedPrimitive>,
    pub(super) textures: egui::TexturesDelta,
    pub(super) screen: egui_wgpu::ScreenDescriptor,
}

impl App {
    /// Physical width the panel takes (0 when hidden or the window is too small for it).
    pub(super) fn panel_pixels(&self, g: &Gfx) -> u32 {
        if self.ui.show && g.config.width >= 480 {
            (PANEL_WIDTH * g.window.scale_factor() as f32).ceil() as u32
        } else {
            0
        }
    }

    /// Runs the panel for this frame; None when it is hidden (or the window too small for it).
    pub(super) fn build_ui(&mut self) -> Option<UiPaint> {
        let g = self.gfx.as_ref()?;
        if self.panel_pixels(g) == 0 {
            return None;
        }
        let g = self.gfx.as_mut()?;
        let raw = g.egui_state.take_egui_input(&g.window);
        let ui = &mut self.ui;
        let (playing, time, shot) = (&mut self.playing, &mut self.time, &mut self.want_screenshot);
        let backend = self.report.backend.clone();
        let instances = self.scene.instances().len();
        let can_restage = self.opts.car_parts.is_some();
        let has_cars = !self.cars.is_empty();
        let clip = self
            .opts
            .animated
            .as_ref()
            .and_then(|a| a.clip.and_then(|c| a.rig.clips.get(c)))
            .map(|c| (c.name.clone(), c.duration));
        let (w, h) = (g.config.width, g.config.height);
        let render_w = w.saturating_sub((PANEL_WIDTH * g.window.scale_factor() as f32).ceil() as u32);
        let output = g.egui.run_ui(raw, |root| {
            egui::Panel::left("controls").exact_size(PANEL_WIDTH).resizable(false).show(root, |ui_| {
                egui::ScrollArea::vertical().show(ui_, |ui_| {
                    ui_.heading("voxray");
                    ui_.label(backend.as_str());
                    ui_.horizontal(|row| {
                        row.label("renderer:");
                        row.radio_value(&mut ui.backend_wanted, BackendKind::Gpu, "GPU");
                        row.radio_value(&mut ui.backend_wanted, BackendKind::Cpu, "CPU");
                    });
                    if !ui.note.is_empty() {
                        ui_.small(ui.note.as_str());
                    }
                    ui_.horizontal(|row| {
                        row.label("primary:");
                        row.radio_value(&mut ui.splat, false, "rays");
                        row.radio_value(&mut ui.splat, true, "square splats");
                    });
                    if ui.splat && ui.backend == BackendKind::Gpu {
                        ui_.horizontal(|row| {
                            use crate::render::SplatDraw;
                            row.label("GPU splats:");
                            row.radio_value(&mut ui.splat_draw, SplatDraw::Compute, "compute");
                            row.radio_value(&mut ui.splat_draw, SplatDraw::Quads, "quads");
                        });
                    }
                    ui_.separator();
                    ui_.strong("Scene");
                    if can_restage {
                        let r = ui_
                            .add(egui::Slider::new(&mut ui.cars_wanted, 1..=MAX_CARS).logarithmic(true).text("cars"));
                        // Re-stage when the slider is let go, not on every step of a drag.
                        ui.cars_dragging = r.dragged() && !r.drag_stopped();
                    }
                    ui_.label(format!("{instances} instances"));
                    ui_.separator();
                    ui_.strong("Camera");
                    ui_.checkbox(&mut ui.fly, "fly mode (F): drag looks around");
                    ui_.small("W A S D move, Q E down/up, Shift faster; right-drag pans");
                    ui_.separator();
                    ui_.strong("Animation");
                    ui_.checkbox(playing, "play (Space)");
                    match &clip {
                        // A scene file's clip: scrub within one loop of it.
                        Some((name, duration)) if *duration > 0.0 => {
                            let duration = *duration;
                            ui_.label(format!("clip '{name}', {duration:.2} s, looping"));
                            let mut phase = time.rem_euclid(duration);
                            if ui_.add(egui::Slider::new(&mut phase, 0.0..=duration).text("time (s)")).changed() {
                                *time = phase;
                            }
                        }
                        _ => {
                            ui_.add(egui::Slider::new(time, 0.0..=120.0).text("time (s)"));
                        }
                    }
                    ui_.add(egui::Slider::new(&mut ui.speed, 0.0..=4.0).text("speed"));
                    if has_cars {
                        ui_.checkbox(&mut ui.travel, "drive along the figure-eight");
                    }
                    ui_.separator();
                    ui_.strong("Techniques");
                    let f = &mut self.opts.features;
                    ui_.checkbox(&mut f.cull, "bounding-sphere culling");
                    ui_.checkbox(&mut f.sort, "depth-sorted early-out");
                    ui_.checkbox(&mut f.bvh, "instance BVH");
                    ui_.checkbox(&mut f.hit_buffer, "hit buffer");
                    ui_.checkbox(&mut f.shadows, "shadows");
                    ui_.checkbox(&mut ui.gi_on, "global illumination");
                    if ui.gi_on {
                        // Steps of 8: every value suits both volume layouts.
                        ui_.add(egui::Slider::new(&mut ui.gi.res, 16..=512).step_by(8.0).text("GI volume cells"));
                        ui_.add(egui::Slider::new(&mut ui.gi.cones.diffuse_cones, 1..=16).text("GI cones"));
                        ui_.add(
                            egui::Slider::new(&mut ui.gi.bounces, 1..=crate::gi::shade::MAX_BOUNCES).text("GI bounces"),
                        );
                        if ui.gi.bounces > 1 {
                            ui_.checkbox(&mut ui.gi.bounce_tail, "estimate the bounces after the last");
                        }
                        ui_.horizontal(|row| {
                            row.label("GI filter:");
                            row.radio_value(&mut ui.gi.filter, crate::gi::Filter::Split, "split");
                            row.radio_value(&mut ui.gi.filter, crate::gi::Filter::Nearest, "nearest");
                        });
                        // Wrapped: three choices are wider than the panel.
                        ui_.horizontal_wrapped(|row| {
                            use crate::render::Gather;
                            row.label("GI gather:");
                            row.radio_value(&mut ui.gi.gather, Gather::Pixels, "every pixel");
                            row.radio_value(&mut ui.gi.gather, Gather::Half, "half resolution");
                            let caches = Gather::Caches(Default::default());
                            row.radio_value(&mut ui.gi.gather, caches, "radiance caches");
                        });
                        ui_.horizontal(|row| {
                            use crate::gi::shade::VolumeChoice;
                            row.label("GI volume:");
                            row.radio_value(&mut ui.gi.volume, VolumeChoice::Auto, "auto");
                            row.radio_value(&mut ui.gi.volume, VolumeChoice::Dense, "dense");
                            row.radio_value(&mut ui.gi.volume, VolumeChoice::Sparse, "sparse");
                        });
                        ui_.horizontal(|row| {
                            use crate::gi::shade::LevelStore;
                            row.label("GI levels (GPU):");
                            row.radio_value(&mut ui.gi.levels, LevelStore::Buffer, "buffer");
                            row.radio_value(&mut ui.gi.levels, LevelStore::Texture, "texture");
                        });
                        // Dense volume and level buffer only: other choices turn GI off with
                        // the reason (shown below as "GI off: …").
                        ui_.checkbox(&mut ui.gi.anisotropic, "GI anisotropic levels").on_hover_text(
                            "six faces per coarse cell: less light leaks through walls lit on their far side",
                        );
                        ui_.checkbox(&mut ui.gi.cone_shadows, "emitter shadows by cones").on_hover_text(
                            "one cone per emitter triangle through the GI volume instead of a shadow ray per \
                             light sample: smooth soft shadows at the volume's resolution",
                        );
                    }
                    if let Some(e) = &ui.gi_error {
                        ui_.colored_label(egui::Color32::from_rgb(230, 110, 90), format!("GI off: {e}"));
                    }
                    let mut full = ui.lod == u32::MAX;
                    ui_.checkbox(&mut full, "full detail");
                    if full {
                        ui.lod = u32::MAX;
                    } else {
                        if ui.lod == u32::MAX {
                            ui.lod = 6;
                        }
                        ui_.add(egui::Slider::new(&mut ui.lod, 1..=12).text("LOD level"));
                    }
                    ui_.separator();
                    ui_.strong("Frame plan");
                    if let Some(p) = &ui.plan {
                        for r in &p.reasons {
                            ui_.small(r);
                        }
                    }
                    ui_.separator();
                    ui_.strong("Statistics");
                    let last = ui.frame_ms.back().copied().unwrap_or(0.0);
                    ui_.label(format!("frame {last:.1} ms, {render_w}×{h}, {instances} instances"));
                    if ui.eye_inside {
                        ui_.colored_label(
                            egui::Color32::from_rgb(230, 160, 60),
                            "the eye is inside a voxel: move the camera out of the geometry",
                        );
                    }
                    if let Some(ms) = ui.gi_ms {
                        if ui.gi_on_gpu {
                            ui_.label(format!("GI passes on the GPU: {ms:.2} ms (cones in shade)"));
                        } else {
                            ui_.label(format!("GI (CPU): {ms:.0} ms of the frame"));
                        }
                    }
                    if ui.backend == BackendKind::Gpu {
                        ui_.checkbox(&mut ui.gpu_stats, "GPU statistics (counted on the GPU, 80 B read back)");
                    }
                    if ui.on_device {
                        ui_.small("frames stay on the GPU and are drawn from its radiance buffer; tick GPU statistics for the counts and pass times");
                    } else {
                        if let Some((tr, sh)) = ui.gpu_ms {
                            ui_.label(format!("GPU passes: trace {tr:.2} ms, shade {sh:.2} ms"));
                        }
                        ui_.label(format!("{:.2} Mrays/s traced, {:.1}% pixels reused", ui.mrays, 100.0 * ui.reused));
                        ui_.label(format!(
                            "per traced ray: {:.2} instances traversed, {:.2} spheres culled",
                            ui.per_ray.0, ui.per_ray.1
                        ));
                    }
                    if ui.posed.1 > 0 {
                        ui_.label(format!(
                            "cars posed: {} of {} (the others no ray reaches)",
                            ui.posed.0, ui.posed.1
                        ));
                    }
                    // Frame-time graph, last 180 frames, scaled to the slowest.
                    let (rect, _) =
                        ui_.allocate_exact_size(egui::vec2(ui_.available_width(), 60.0), egui::Sense::hover());
                    let max = ui.frame_ms.iter().copied().fold(1.0f32, f32::max);
                    let n = ui.frame_ms.len().max(2) as f32;
                    let pts: Vec<egui::Pos2> = ui
                        .frame_ms
                        .iter()
                        .enumerate()
                        .map(|(i, v)| {
                            egui::pos2(
                                rect.left() + rect.width() * i as f32 / (n - 1.0),
                                rect.bottom() - rect.height() * v / max,
                            )
                        })
                        .collect();
                    ui_.painter().rect_stroke(
                        rect,
                        0.0,
                        egui::Stroke::new(1.0, egui::Color32::GRAY),
                        egui::StrokeKind::Inside,
                    );
                    ui_.painter().add(egui::Shape::line(pts, egui::Stroke::new(1.5, egui::Color32::LIGHT_GREEN)));
                    ui_.small(format!("frame time, max {max:.0} ms"));
                    ui_.separator();
                    ui_.horizontal(|row| {
                        if row.button("reset view (R)").clicked() {
                            ui.reset = true;
                        }
                        if row.button("screenshot (P)").clicked() {
                            *shot = true;
                        }
                    });
                    ui_.small("drag: orbit · wheel: zoom · H: hide panel · Esc: quit");
                });
            });
        });
        g.egui_state.handle_platform_output(&g.window, output.platform_output);
        let jobs = g.egui.tessellate(output.shapes, output.pixels_per_point);
        Some(UiPaint {
            jobs,
            textures: output.textures_delta,
            screen: egui_wgpu::ScreenDescriptor { size_in_pixels: [w, h], pixels_per_point: output.pixels_per_point },
        })
    }
}
