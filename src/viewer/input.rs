//! Window events: keys, mouse, resizing, and winit's application callbacks.

use super::*;

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.gfx.is_none() && self.soft.is_none() {
            if let Err(e) = self.init(event_loop) {
                self.fail(event_loop, e);
            }
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        // The panel sees every event first; input it uses does not reach the camera.
        if let Some(g) = self.gfx.as_mut() {
            let consumed = g.egui_state.on_window_event(&g.window, &event).consumed;
            let input = matches!(
                event,
                WindowEvent::MouseInput { .. }
                    | WindowEvent::CursorMoved { .. }
                    | WindowEvent::MouseWheel { .. }
                    | WindowEvent::KeyboardInput { .. }
            );
            if consumed && input && self.ui.show {
                return;
            }
        }
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(size) => {
                if let Some(g) = self.gfx.as_mut() {
                    g.config.width = size.width.max(1);
                    g.config.height = size.height.max(1);
                    g.surface.configure(&g.ctx.device, &g.config);
                }
            }
            WindowEvent::MouseInput { state, button: MouseButton::Left, .. } => {
                self.drag = (state == ElementState::Pressed).then_some(self.cursor);
            }
            WindowEvent::MouseInput { state, button: MouseButton::Right | MouseButton::Middle, .. } => {
                self.pan = (state == ElementState::Pressed).then_some(self.cursor);
            }
            WindowEvent::Focused(false) => self.keys.clear(),
            WindowEvent::CursorMoved { position, .. } => {
                self.cursor = (position.x, position.y);
                if let Some((x0, y0)) = self.drag {
                    let (dx, dy) = (position.x - x0, position.y - y0);
                    self.drag = Some(self.cursor);
                    // Orbit: the camera circles the target. Fly: it turns in place (the
                    // rotation runs the other way so the view follows the mouse).
                    let k = if self.ui.fly { 0.003 } else { -0.005 };
                    let yaw = DQuat::from_axis_angle(self.orbit.up, k * dx);
                    let right = self.orbit.offset.cross(self.orbit.up).normalize_or_zero();
                    let pitch = DQuat::from_axis_angle(right, k * dy);
                    let eye = self.orbit.target + self.orbit.offset;
                    let mut next = pitch * (yaw * self.orbit.offset);
                    // Stay off the poles, where the up vector would become parallel to the view.
                    if next.normalize().dot(self.orbit.up).abs() >= 0.98 {
                        next = yaw * self.orbit.offset;
                    }
                    self.orbit.offset = next;
                    if self.ui.fly {
                        self.orbit.target = eye - next;
                    }
                }
                if let Some((x0, y0)) = self.pan {
                    let (dx, dy) = (position.x - x0, position.y - y0);
                    self.pan = Some(self.cursor);
                    let ahead = -self.orbit.offset.normalize_or_zero();
                    let right = ahead.cross(self.orbit.up).normalize_or_zero();
                    let up = right.cross(ahead);
                    // Scaled by the view distance so the scene follows the mouse at any zoom.
                    let k = self.orbit.offset.length() * 0.0015;
                    self.orbit.target += (-right * dx + up * dy) * k;
                }
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let lines = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y as f64,
                    MouseScrollDelta::PixelDelta(p) => p.y / 40.0,
                };
                self.orbit.offset *= 0.9f64.powf(lines);
            }
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Released => {
                if let PhysicalKey::Code(code) = event.physical_key {
                    self.keys.remove(&code);
                }
            }
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Pressed => {
                if let PhysicalKey::Code(code) = event.physical_key {
                    self.keys.insert(code);
                }
                self.key(event_loop, event.logical_key)
            }
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.draw(event_loop) {
                    self.fail(event_loop, e);
                }
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, _event_loop: &ActiveEventLoop) {
        if let Some(window) = self.window() {
            window.request_redraw();
        }
    }
}

impl App {
    pub(super) fn key(&mut self, event_loop: &ActiveEventLoop, key: Key) {
        match key {
            Key::Named(NamedKey::Escape) => event_loop.exit(),
            Key::Named(NamedKey::Space) => self.playing = !self.playing,
            Key::Character(c) if c.eq_ignore_ascii_case("r") => self.orbit = self.home.clone(),
            Key::Character(c) if c.eq_ignore_ascii_case("p") => self.want_screenshot = true,
            Key::Character(c) if c.eq_ignore_ascii_case("h") => self.ui.show = !self.ui.show,
            Key::Character(c) if c.eq_ignore_ascii_case("f") => self.ui.fly = !self.ui.fly,
            _ => {}
        }
    }
}
