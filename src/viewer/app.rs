//! One frame of the demo: animate, apply the panel's choices, render through the session,
//! present, record the statistics.

use super::*;

impl App {
    pub(super) fn draw(&mut self, event_loop: &ActiveEventLoop) -> Result<(), ViewerError> {
        let now = Instant::now();
        let dt = (now - self.last).as_secs_f64();
        self.last = now;
        if self.playing {
            // Scripted runs advance by a fixed step so their frames do not depend on speed.
            self.time += self.ui.speed * if self.opts.frames.is_some() { 1.0 / 30.0 } else { dt.min(0.1) };
        }
        if self.ui.reset {
            self.ui.reset = false;
            self.orbit = self.home.clone();
        }
        self.apply_choices()?;
        self.fly(dt.min(0.1));
        for c in &mut self.cars {
            c.travel = self.ui.travel;
        }
        let (w, h, panel) = match (&self.gfx, &self.soft) {
            (Some(g), _) => (g.config.width, g.config.height, self.panel_pixels(g)),
            (None, Some(s)) => {
                let size = s.window.inner_size();
                (size.width.max(1), size.height.max(1), 0)
            }
            (None, None) => return Ok(()),
        };
        let camera = self.camera(w.saturating_sub(panel).max(1), h);
        let done = self.opts.exit && self.opts.frames.is_some_and(|n| self.report.frames + 1 >= n);
        let shoot = self.want_screenshot || (done && self.opts.screenshot.is_some());
        // A GPU frame is drawn from the renderer's radiance buffer and read back only when
        // asked: statistics on, or a screenshot the window cannot be copied for.
        let can_capture = self.gfx.as_ref().is_some_and(|g| g.config.usage.contains(wgpu::TextureUsages::COPY_SRC));
        let start = Instant::now();
        let session = self.session.as_mut().ok_or_else(|| ViewerError::Other("no renderer".into()))?;
        session.set_read_back(self.ui.read_all || (shoot && !can_capture) || self.gfx.is_none());
        session.set_counting(self.ui.gpu_stats);
        let other = |e: crate::Error| ViewerError::Other(e.to_string());
        // GI knobs this device cannot run (a volume past its binding limit, texture levels on a
        // sparse volume) switch GI off with the reason in the panel instead of ending the demo.
        if let Err(e) = session.set_gi(self.ui.gi_on.then_some(self.ui.gi)) {
            self.ui.gi_error = Some(e.to_string());
            self.ui.gi_on = false;
            session.set_gi(None).map_err(other)?;
        }
        let renderer = if self.ui.splat { crate::render::Renderer::Splat } else { crate::render::Renderer::Trace };
        let opts =
            RenderOptions { max_level: self.ui.lod, renderer, splat_draw: self.ui.splat_draw, ..Default::default() };
        let features = self.opts.features;
        // Only the cars some ray of this frame can reach are posed (the picture is the same).
        let sight = if features.pose_seen && self.opts.animated.is_none() && !self.cars.is_empty() {
            let key = (self.scene.part_edits(), self.ui.lod, self.ui.travel, self.cars.len());
            let surfaces = match self.surfaces {
                Some((k, surfaces)) if k == key => surfaces,
                _ => crate::scene::stage::surfaces(&self.scene, &self.cars, self.ui.lod).map_err(other)?,
            };
            self.surfaces = Some((key, surfaces));
            let rays = FrameRays::of(&self.scene, &features, session.gi().is_some(), &opts);
            Sight::new(&camera, &self.lights, rays, surfaces).ok()
        } else {
            None
        };
        let scene_error = |e: crate::scene::SceneError| ViewerError::Other(e.to_string());
        let (scene, seen, cars, lights) = (&mut self.scene, &mut self.seen, &self.cars, &self.lights);
        let (time, lod, animated) = (self.time, self.ui.lod, &self.opts.animated);
        let stages = || -> Result<_, ViewerError> {
            let posed = seen.pose(scene, cars, time, sight.as_ref(), lod).map_err(scene_error)?;
            if let Some(a) = animated {
                a.rig.pose(scene, a.clip, time).map_err(|e| ViewerError::Other(e.to_string()))?;
            }
            scene.update().map_err(scene_error)?;
            Ok((posed, session.frame(scene, &camera, lights, &features, &opts, &|_, _| {})))
        };
        let (posed, rendered) = crate::pool::run_awake(stages)?;
        self.ui.posed = (posed, self.cars.len());
        let report = match rendered {
            Ok(r) => r,
            Err(e) if session.gi().is_some() => {
                self.ui.gi_error = Some(e.to_string());
                self.ui.gi_on = false;
                session.set_gi(None).map_err(other)?;
                session.frame(&self.scene, &camera, &self.lights, &features, &opts, &|_, _| {}).map_err(other)?
            }
            Err(e) => return Err(other(e)),
        };
        if self.ui.gi_on {
            self.ui.gi_error = None;
        }
        let gi_in_backend = session.gi_in_backend();
        self.ui.gi_on_gpu = gi_in_backend && session.gi().is_some();
        self.ui.gi_ms = match &report.gi {
            Some(g) => Some(g.caches_ms + g.transform_ms + g.inject_ms + g.levels_ms + g.cones_ms),
            None => session.backend().gi_pass_ms(),
        };
        let gpu_ms = report.gpu_pass_ms;
        let gpu_traffic = report.gpu_traffic;
        let plan = report.plan;
        // Out of the session while it is shown; handed back at the end for the next frame's
        // memory.
        let frame = session.take_frame().ok_or_else(|| ViewerError::Other("the renderer kept no frame".into()))?;
        self.ui.on_device = frame.on_device && !self.ui.gpu_stats;
        self.ui.eye_inside = if frame.on_device {
            session.backend().gpu().is_some_and(|g| g.eye_inside())
        } else {
            frame.eye_inside_fraction() > 0.5
        };
        // The render call alone (a GPU frame that stays on the GPU returns once submitted).
        let secs = start.elapsed().as_secs_f64();
        // A frame's time is from one frame's start to the next (rendering, panel, present):
        // the rate the window shows, whichever backend.
        if self.report.frames > 0 {
            self.times.push(dt * 1e3);
            self.ui.frame_ms.push_back((dt * 1e3) as f32);
        }
        self.ui.gpu_ms = gpu_ms;
        if self.ui.frame_ms.len() > 180 {
            self.ui.frame_ms.pop_front();
        }
        let pixels = frame.primary_rays.max(1) as f64;
        self.ui.reused = frame.reused as f64 / pixels;
        let traced_rays = (frame.primary_rays - frame.reused).max(1) as f64;
        self.ui.per_ray = (frame.instances_traced as f64 / traced_rays, frame.spheres_culled as f64 / traced_rays);
        self.ui.mrays = (frame.primary_rays - frame.reused + frame.shadow_rays) as f64 / secs.max(1e-9) / 1e6;
        self.ui.plan = Some(plan);
        let ui_paint = self.build_ui();
        let captured = self.present(&frame, shoot, ui_paint)?;
        // Errors the window's device raised while presenting (outside the renderer's scopes).
        if let Some(g) = self.gfx.as_ref() {
            g.ctx.check().map_err(|e| ViewerError::Other(e.to_string()))?;
        }
        let captured_kind = captured.is_some();
        if let Some(t) = gpu_traffic.filter(|_| !shoot && self.report.frames >= TRAFFIC_WARMUP) {
            self.report.gpu_traffic.push(t);
        }
        self.report.frames += 1;
        if self.report.frames % 10 == 1 {
            if let Some(window) = self.window() {
                let ms = self.times.last().copied().unwrap_or(0.0);
                let reused = if frame.on_device && !self.ui.gpu_stats {
                    "frame kept on the GPU".to_string()
                } else {
                    format!("{:.0}% reused", 100.0 * frame.reused as f64 / frame.primary_rays.max(1) as f64)
                };
                window.set_title(&format!(
                    "voxray — {:.1} ms/frame, {reused}, t = {:.1} s{} — {}",
                    ms,
                    self.time,
                    if self.playing { "" } else { " (paused)" },
                    self.report.backend
                ));
            }
        }
        if shoot {
            self.want_screenshot = false;
            let path = self
                .opts
                .screenshot
                .clone()
                .unwrap_or_else(|| PathBuf::from(format!("voxray-{:04}.png", self.report.frames)));
            match captured {
                // The window's own pixels.
                Some((w, h, rgb)) => image::RgbImage::from_raw(w, h, rgb)
                    .ok_or_else(|| ViewerError::Other("window capture size mismatch".into()))?
                    .save(&path)
                    .map_err(|e| ViewerError::Other(format!("{}: {e}", path.display())))?,
                // The surface cannot be read back: the frame that was drawn to it.
                None => output::write_image(&frame, &path).map_err(|e| ViewerError::Other(e.to_string()))?,
            }
            eprintln!(
                "demo: wrote {} ({})",
                path.display(),
                if captured_kind { "window capture" } else { "rendered frame" }
            );
            self.report.screenshots.push(path);
        }
        if let Some(s) = self.session.as_mut() {
            s.give_back(frame);
        }
        if done {
            event_loop.exit();
        }
        Ok(())
    }

    /// Applies the renderer and car-count choices made in the panel.
    pub(super) fn apply_choices(&mut self) -> Result<(), ViewerError> {
        if self.ui.backend_wanted != self.ui.backend {
            if let Some(g) = &self.gfx {
                let (backend, name) = Backend::on_device(self.ui.backend_wanted, g.ctx.clone());
                eprintln!("demo: now rendering on {name}");
                // A new session: no previous frame to reuse, GI state of its own.
                self.session = Some(Session::new(backend, name.clone()));
                self.report.backend = name;
                self.ui.backend = self.ui.backend_wanted;
            }
        }
        let n = self.ui.cars_wanted.max(1);
        if n != self.ui.cars && !self.ui.cars_dragging {
            if let Some(cp) = &self.opts.car_parts {
                let st: Staged =
                    stage_cars(&cp.parts, n, true, cp.ground).map_err(|e| ViewerError::Other(e.to_string()))?;
                let (lo, hi) = if self.ui.travel { st.bounds } else { st.cars_bounds() };
                let (w, h) = self.gfx.as_ref().map_or((self.opts.width, self.opts.height), |g| {
                    (g.config.width.saturating_sub(self.panel_pixels(g)).max(1), g.config.height)
                });
                self.home = Orbit::of(&Camera::framing(lo.as_vec3(), hi.as_vec3(), w, h));
                self.orbit = self.home.clone();
                self.scene = st.scene;
                self.cars = st.cars;
                // Other instances: nothing to reuse (the old parts' GI caches go when the next
                // new cache is built, as their parts are gone).
                if let Some(s) = self.session.as_mut() {
                    s.restart();
                }
                eprintln!("demo: {n} cars, {} instances", self.scene.instances().len());
            }
            self.ui.cars = n;
            self.ui.cars_wanted = n;
        }
        Ok(())
    }

    /// Moves the camera by the held W A S D / Q E keys (Shift: four times faster).
    pub(super) fn fly(&mut self, dt: f64) {
        let held = |k| self.keys.contains(&k) as i32 as f64;
        let forward = held(KeyCode::KeyW) - held(KeyCode::KeyS);
        let side = held(KeyCode::KeyD) - held(KeyCode::KeyA);
        let lift = held(KeyCode::KeyE) - held(KeyCode::KeyQ);
        if forward == 0.0 && side == 0.0 && lift == 0.0 {
            return;
        }
        let fast =
            if self.keys.contains(&KeyCode::ShiftLeft) || self.keys.contains(&KeyCode::ShiftRight) { 4.0 } else { 1.0 };
        // Half the home view distance per second: the same feel for one car or a city of them.
        let speed = 0.5 * self.home.offset.length() * fast;
        let ahead = -self.orbit.offset.normalize_or_zero();
        let right = ahead.cross(self.orbit.up).normalize_or_zero();
        self.orbit.target += (ahead * forward + right * side + self.orbit.up * lift) * speed * dt;
    }
}
