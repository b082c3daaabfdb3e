//! Flying in a window: winit for the window and input, egui for the panel, and a [`Scene`] (a
//! terrain, `terrain.rs`, or a mesh, `mesh.rs`) for what is drawn. This file is what every scene
//! shares: the fly camera and its keys, the panel's frame, screenshots and path recording.
//!
//! Shared controls: drag with a mouse button to look around; W/S forward and back, A/D sideways,
//! Q/E down and up (along the world's up axis), Shift ×4; the scroll wheel changes the speed; F12
//! (or P) saves a screenshot, R starts and stops recording the flight path to JSON, Esc quits.
//! Both scenes add F (freeze the level of detail) and T (wireframe).

mod mesh;
mod terrain;

use std::collections::HashSet;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use glam::DVec3;
use winit::application::ApplicationHandler;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop};
use winit::keyboard::{KeyCode, PhysicalKey};
use winit::window::{Window, WindowId};

use crate::camera::{Camera, UpAxis};
use crate::error::{Error, Result};
use crate::flight::{FlightPath, PathFrame};
use crate::render::offscreen::Offscreen;
use crate::render::save_png;
use crate::render::Gpu;

pub use mesh::{mesh_window, MeshWindowOptions};
pub use terrain::{fly_window, WindowOptions};

/// What every window takes.
#[derive(Clone, Debug)]
pub struct WindowSettings {
    pub width_px: u32,
    pub height_px: u32,
    pub fov_x_deg: f64,
    /// Where screenshots and recorded paths go.
    pub output_dir: PathBuf,
    /// Start here, looking there (world coordinates); default: the scene's own start.
    pub start: Option<(DVec3, DVec3)>,
    /// Close after this many frames (scripted runs, smoke tests).
    pub exit_after_frames: Option<u64>,
    /// Record the flight path from the first frame.
    pub record: bool,
}

/// The error for a machine without a display, with what to do instead.
pub fn no_display(reason: &str) -> Error {
    crate::AppError::NoDisplay(format!(
        "cannot open a window ({reason}); fly headless instead: \
         relief path flyover FILE --frames 300 --out path.json && relief fly FILE --path path.json --frames-out frames/ \
         (a mesh: relief mesh view FILE --path path.json)"
    ))
    .into()
}

/// winit's reason, without the source location it prefixes OS errors with ("os error at
/// …/winit-0.30.13/src/…/mod.rs:788: Failed to …"), and with the display it tried.
fn display_error(reason: &str) -> String {
    let bare = reason
        .strip_prefix("os error at ")
        .and_then(|rest| rest.find(".rs:").map(|i| &rest[i + 4..]))
        .and_then(|rest| rest.split_once(": ").map(|(_, why)| why))
        .unwrap_or(reason);
    match std::env::var("DISPLAY") {
        Ok(d) if !d.is_empty() => format!("{bare} on DISPLAY={d}"),
        _ => bare.to_string(),
    }
}

/// Fails early, with the headless alternative, where no X display is set (Linux, BSD).
pub fn check_display() -> Result<()> {
    #[cfg(all(unix, not(target_os = "macos")))]
    if std::env::var_os("DISPLAY").is_none() {
        return Err(no_display("DISPLAY is not set"));
    }
    Ok(())
}

/// What a window draws: a scene renders itself for a camera, the shell does the rest.
trait Scene {
    fn title(&self) -> String;
    /// Builds the renderer for the window's device and colour format; returns the start camera
    /// (`start` when given: eye and look point).
    fn start(&mut self, gpu: &Gpu, format: wgpu::TextureFormat, start: Option<(DVec3, DVec3)>) -> Result<FlyCamera>;
    /// A key pressed that the shell does not handle.
    fn key(&mut self, code: KeyCode);
    /// Brings the scene up to date for `camera` (refine or adapt, upload) before it is drawn.
    fn update(&mut self, gpu: &Gpu, camera: &Camera) -> Result<()>;
    /// Records the scene seen by `camera` into `colour` and `depth` (both cleared).
    fn encode(
        &self,
        gpu: &Gpu,
        encoder: &mut wgpu::CommandEncoder,
        colour: &wgpu::TextureView,
        depth: &wgpu::TextureView,
        camera: &Camera,
    );
    /// The scene's rows of the panel's figures (name, value), after fps.
    fn stats(&self) -> Vec<(&'static str, String)>;
    /// The scene's controls, below the figures.
    fn controls(&mut self, ui: &mut egui::Ui);
    /// A factor the eye's height is to be scaled by now (the scene was exaggerated more or less),
    /// once.
    fn take_rescale(&mut self) -> Option<f64> {
        None
    }
    /// A point of the scene as a recorded path keeps it (the terrain's metres, whatever the
    /// exaggeration drawn).
    fn path_point(&self, p: DVec3) -> DVec3 {
        p
    }
}

/// The panel's help lines.
pub const HELP: [&str; 2] = ["drag: look · WASD/QE: move · wheel: speed", "F12/P: screenshot · R: record path"];
/// Shown while recording (every glyph in the bundled font: see the test).
pub const RECORDING: &str = "REC · recording the path (R: stop and save)";

/// Opens a window on `scene` and runs it until it is closed.
fn run<S: Scene>(scene: S, settings: WindowSettings) -> Result<()> {
    check_display()?;
    let event_loop = EventLoop::new().map_err(|e| no_display(&display_error(&e.to_string())))?;
    let mut app = App { scene, settings, shell: None, error: None };
    event_loop.run_app(&mut app).map_err(|e| crate::app_error::gpu(format!("window event loop: {e}")))?;
    // Closed while recording (Esc, the window's close button, a signal, an error): the path so
    // far is saved, and said so.
    if let Some(s) = app.shell.as_mut() {
        if let Some(frames) = s.recording.take().filter(|f| !f.is_empty()) {
            eprintln!("relief: closed while recording; {}", save_path(frames, &app.settings));
        }
    }
    match app.error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

/// Saves a recorded path beside the screenshots; what happened, in a line.
fn save_path(frames: Vec<PathFrame>, o: &WindowSettings) -> String {
    // Two recordings in one second keep both.
    let stamp = timestamp();
    let path = (1..)
        .map(|k| match k {
            1 => o.output_dir.join(format!("relief-path-{stamp}.json")),
            k => o.output_dir.join(format!("relief-path-{stamp}-{k}.json")),
        })
        .find(|p| !p.exists())
        .expect("a free name");
    let n = frames.len();
    match (FlightPath { frames }).save(&path) {
        Ok(()) => format!("path: {} ({n} frames)", path.display()),
        Err(e) => format!("saving the path failed: {e}"),
    }
}

struct App<S> {
    scene: S,
    settings: WindowSettings,
    shell: Option<Shell>,
    error: Option<Error>,
}

/// A first-person camera: position and heading about the world's up axis.
#[derive(Clone, Copy, Debug)]
struct FlyCamera {
    eye_in_world: DVec3,
    /// Heading, radians counter-clockwise from the up frame's first horizontal axis (east for z up).
    yaw: f64,
    /// Radians above the horizon.
    pitch: f64,
    /// World units per second.
    speed_mps: f64,
    up: UpAxis,
}

impl FlyCamera {
    /// At `eye` looking at `look`, moving `speed_mps`.
    fn looking(eye: DVec3, look: DVec3, speed_mps: f64, up: UpAxis) -> FlyCamera {
        let (e1, e2, u) = up.frame();
        let d = look - eye;
        let (x, y) = (d.dot(e1), d.dot(e2));
        FlyCamera {
            eye_in_world: eye,
            yaw: y.atan2(x),
            pitch: d.dot(u).atan2(x.hypot(y)).clamp(-1.55, 1.55),
            speed_mps,
            up,
        }
    }

    fn forward(&self) -> DVec3 {
        let (e1, e2, u) = self.up.frame();
        (e1 * self.yaw.cos() + e2 * self.yaw.sin()) * self.pitch.cos() + u * self.pitch.sin()
    }

    /// Horizontal, to the right of the heading.
    fn right(&self) -> DVec3 {
        let (e1, e2, _) = self.up.frame();
        e1 * self.yaw.sin() - e2 * self.yaw.cos()
    }

    fn camera(&self, fov_x_deg: f64, w: u32, h: u32) -> Result<Camera> {
        let eye = self.eye_in_world;
        Camera::new(eye, eye + self.forward(), self.up.vector(), fov_x_deg, w.max(1), h.max(1))
    }
}

/// The window, its device and the panel, the camera and what the keys have done.
struct Shell {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    gpu: Gpu,
    depth_view: wgpu::TextureView,
    egui_ctx: egui::Context,
    egui_state: egui_winit::State,
    egui_renderer: egui_wgpu::Renderer,
    cam: FlyCamera,
    keys: HashSet<KeyCode>,
    dragging: bool,
    last_cursor: Option<(f64, f64)>,
    last_frame: Instant,
    frame_ms_avg: f64,
    recording: Option<Vec<PathFrame>>,
    message: String,
    frames: u64,
    /// Pointer events on their way to the panel.
    panel_input: PanelInput,
}

/// Whether `e` is a mouse button press / release.
fn is_button(e: &WindowEvent, pressed: bool) -> bool {
    matches!(e, WindowEvent::MouseInput { state, .. } if (*state == ElementState::Pressed) == pressed)
}

/// Paces pointer events into the panel. A press and its release reaching egui in one frame read
/// as a click where the press was, so a drag of a slider quicker than a frame (at lavapipe's frame
/// rates an ordinary flick) was lost: a release after a press the panel has not yet had a frame
/// with, and every pointer event after it, wait for the next frame.
#[derive(Default)]
struct PanelInput {
    held: Vec<WindowEvent>,
    /// A button press reached the panel since its last frame.
    pressed: bool,
}

impl PanelInput {
    /// Whether `event` may go to the panel now (else it is held).
    fn offer(&mut self, event: &WindowEvent) -> bool {
        let pointer = matches!(event, WindowEvent::CursorMoved { .. } | WindowEvent::MouseInput { .. });
        if pointer && (!self.held.is_empty() || (self.pressed && is_button(event, false))) {
            self.held.push(event.clone());
            return false;
        }
        self.pressed |= is_button(event, true);
        true
    }

    /// After a frame: the held events that go to the panel now, up to the next release that would
    /// again follow a press within one frame.
    fn frame_done(&mut self) -> Vec<WindowEvent> {
        self.pressed = false;
        let mut now = Vec::new();
        let mut held = std::mem::take(&mut self.held).into_iter();
        while let Some(e) = held.next() {
            if self.pressed && is_button(&e, false) {
                self.held.push(e);
                self.held.extend(held);
                break;
            }
            self.pressed |= is_button(&e, true);
            now.push(e);
        }
        now
    }
}

impl<S: Scene> App<S> {
    fn init(&mut self, event_loop: &ActiveEventLoop) -> Result<Shell> {
        let o = &self.settings;
        let attrs = Window::default_attributes()
            .with_title(self.scene.title())
            .with_inner_size(winit::dpi::PhysicalSize::new(o.width_px, o.height_px));
        let window = Arc::new(event_loop.create_window(attrs).map_err(|e| no_display(&e.to_string()))?);
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let surface = instance
            .create_surface(window.clone())
            .map_err(|e| crate::app_error::gpu(format!("cannot draw into the window: {e}")))?;
        let gpu = Gpu::with_instance(instance, Some(&surface))?;
        let caps = surface.get_capabilities(&gpu.adapter);
        let format = caps
            .formats
            .iter()
            .copied()
            .find(|f| f.is_srgb())
            .or(caps.formats.first().copied())
            .ok_or_else(|| crate::app_error::gpu("the window offers no surface format"))?;
        let size = window.inner_size();
        let config = wgpu::SurfaceConfiguration {
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            format,
            width: size.width.max(1),
            height: size.height.max(1),
            // Mailbox (newest frame, no tearing) where offered, else vsync.
            present_mode: if caps.present_modes.contains(&wgpu::PresentMode::Mailbox) {
                wgpu::PresentMode::Mailbox
            } else {
                wgpu::PresentMode::AutoVsync
            },
            desired_maximum_frame_latency: 2,
            alpha_mode: caps.alpha_modes.first().copied().unwrap_or(wgpu::CompositeAlphaMode::Auto),
            view_formats: vec![],
            color_space: wgpu::SurfaceColorSpace::Auto,
        };
        surface.configure(&gpu.device, &config);
        let depth_view =
            crate::render::offscreen::depth_target(&gpu, config.width, config.height).create_view(&Default::default());
        let cam = self.scene.start(&gpu, format, o.start)?;
        let egui_ctx = egui::Context::default();
        let egui_state = egui_winit::State::new(
            egui_ctx.clone(),
            egui::ViewportId::ROOT,
            &window,
            Some(window.scale_factor() as f32),
            None,
            Some(gpu.device.limits().max_texture_dimension_2d as usize),
        );
        let egui_renderer = egui_wgpu::Renderer::new(
            &gpu.device,
            format,
            egui_wgpu::RendererOptions { depth_stencil_format: None, msaa_samples: 1, ..Default::default() },
        );
        Ok(Shell {
            window,
            surface,
            config,
            gpu,
            depth_view,
            egui_ctx,
            egui_state,
            egui_renderer,
            cam,
            keys: HashSet::new(),
            dragging: false,
            last_cursor: None,
            last_frame: Instant::now(),
            frame_ms_avg: 0.0,
            recording: self.settings.record.then(Vec::new),
            message: String::new(),
            frames: 0,
            panel_input: PanelInput::default(),
        })
    }
}

impl<S: Scene> ApplicationHandler for App<S> {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.shell.is_some() {
            return;
        }
        match self.init(event_loop) {
            Ok(s) => {
                s.window.request_redraw();
                self.shell = Some(s);
            }
            Err(e) => {
                self.error = Some(e);
                event_loop.exit();
            }
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        let Some(s) = self.shell.as_mut() else { return };
        let scene = &mut self.scene;
        let consumed = s.offer_panel(&event);
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(size) => {
                s.config.width = size.width.max(1);
                s.config.height = size.height.max(1);
                s.surface.configure(&s.gpu.device, &s.config);
                s.depth_view = crate::render::offscreen::depth_target(&s.gpu, s.config.width, s.config.height)
                    .create_view(&Default::default());
            }
            WindowEvent::KeyboardInput { event, .. } if !consumed || !s.egui_ctx.egui_wants_keyboard_input() => {
                if let PhysicalKey::Code(code) = event.physical_key {
                    if event.state == ElementState::Pressed {
                        if !event.repeat {
                            match code {
                                KeyCode::Escape => event_loop.exit(),
                                KeyCode::F12 | KeyCode::KeyP => s.message = s.screenshot(scene, &self.settings),
                                KeyCode::KeyR => s.message = s.toggle_recording(&self.settings),
                                _ => scene.key(code),
                            }
                        }
                        s.keys.insert(code);
                    } else {
                        s.keys.remove(&code);
                    }
                }
            }
            WindowEvent::MouseInput { state, button, .. } if !consumed || state == ElementState::Released => {
                if matches!(button, MouseButton::Left | MouseButton::Right) {
                    s.dragging = state == ElementState::Pressed;
                }
            }
            WindowEvent::CursorMoved { position, .. } => {
                if let (true, Some((x, y))) = (s.dragging, s.last_cursor) {
                    // 0.2° per pixel.
                    let k = 0.2f64.to_radians();
                    s.cam.yaw -= (position.x - x) * k;
                    s.cam.pitch = (s.cam.pitch - (position.y - y) * k).clamp(-1.55, 1.55);
                }
                s.last_cursor = Some((position.x, position.y));
            }
            WindowEvent::MouseWheel { delta, .. } if !consumed => {
                let ticks = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y as f64,
                    MouseScrollDelta::PixelDelta(p) => p.y / 40.0,
                };
                s.cam.speed_mps = (s.cam.speed_mps * 1.25f64.powf(ticks)).clamp(1e-6, 1e7);
            }
            WindowEvent::RedrawRequested => {
                // Ctrl-C, SIGTERM or SIGHUP: close like Escape, and say why.
                if let Err(e) = crate::sys::cancel::check() {
                    self.error = Some(e);
                    event_loop.exit();
                    return;
                }
                if let Err(e) = s.frame(scene, &self.settings) {
                    self.error = Some(e);
                    event_loop.exit();
                    return;
                }
                s.panel_frame_done();
                s.frames += 1;
                if self.settings.exit_after_frames.is_some_and(|n| s.frames >= n) {
                    event_loop.exit();
                    return;
                }
                s.window.request_redraw();
            }
            _ => {}
        }
    }
}

impl Shell {
    /// Hands a window event to the panel (now, or after the next frame: [`PanelInput`]); returns
    /// whether the panel takes it.
    fn offer_panel(&mut self, event: &WindowEvent) -> bool {
        if !self.panel_input.offer(event) {
            return self.egui_ctx.egui_wants_pointer_input();
        }
        self.egui_state.on_window_event(&self.window, event).consumed
    }

    /// After a frame: the held events the panel may have now.
    fn panel_frame_done(&mut self) {
        for e in self.panel_input.frame_done() {
            let _ = self.egui_state.on_window_event(&self.window, &e);
        }
    }

    fn camera(&self, o: &WindowSettings) -> Result<Camera> {
        self.cam.camera(o.fov_x_deg, self.config.width, self.config.height)
    }

    /// Draws the scene as it stands (no panel, no update) into an image file.
    fn screenshot(&mut self, scene: &impl Scene, o: &WindowSettings) -> String {
        let go = || -> Result<PathBuf> {
            let cam = self.camera(o)?;
            let target = Offscreen::with_format(&self.gpu, cam.width_px, cam.height_px, self.config.format)?;
            let mut enc = self.gpu.device.create_command_encoder(&Default::default());
            scene.encode(&self.gpu, &mut enc, &target.colour_view, &target.depth_view, &cam);
            self.gpu.queue.submit([enc.finish()]);
            let image = target.read_rgba(&self.gpu)?;
            let path = o.output_dir.join(format!("relief-{}.png", timestamp()));
            save_png(&image, &path)?;
            Ok(path)
        };
        match go() {
            Ok(p) => format!("screenshot: {}", p.display()),
            Err(e) => format!("screenshot failed: {e}"),
        }
    }

    fn toggle_recording(&mut self, o: &WindowSettings) -> String {
        match self.recording.take() {
            None => {
                self.recording = Some(Vec::new());
                "recording the flight path (R to stop)".into()
            }
            Some(frames) if frames.is_empty() => "recording stopped: no frames".into(),
            Some(frames) => save_path(frames, o),
        }
    }

    fn frame(&mut self, scene: &mut impl Scene, o: &WindowSettings) -> Result<()> {
        let now = Instant::now();
        let dt = (now - self.last_frame).as_secs_f64().min(0.25);
        self.last_frame = now;
        self.frame_ms_avg = if self.frame_ms_avg == 0.0 { dt * 1e3 } else { 0.9 * self.frame_ms_avg + 0.1 * dt * 1e3 };
        if let Some(f) = scene.take_rescale() {
            self.cam.eye_in_world.z *= f;
        }
        self.fly(dt);
        let cam = self.camera(o)?;
        if let Some(rec) = &mut self.recording {
            let (eye, look) = (scene.path_point(cam.eye_in_world), scene.path_point(cam.look_at_world));
            rec.push(PathFrame { eye: eye.to_array(), look: look.to_array() });
        }
        scene.update(&self.gpu, &cam)?;

        let frame = match self.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(f) | wgpu::CurrentSurfaceTexture::Suboptimal(f) => f,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                self.surface.configure(&self.gpu.device, &self.config);
                return Ok(());
            }
            other => return Err(crate::app_error::gpu(format!("cannot get the window's next image: {other:?}"))),
        };
        let view = frame.texture.create_view(&Default::default());
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        scene.encode(&self.gpu, &mut encoder, &view, &self.depth_view, &cam);
        self.draw_panel(&mut encoder, &view, scene);
        self.gpu.queue.submit([encoder.finish()]);
        self.window.pre_present_notify();
        self.gpu.queue.present(frame);
        self.gpu.check()
    }

    fn fly(&mut self, dt: f64) {
        let (f, right, up) = (self.cam.forward(), self.cam.right(), self.cam.up.vector());
        let mut v = DVec3::ZERO;
        let k = |c: KeyCode| self.keys.contains(&c) as i32 as f64;
        v += f * (k(KeyCode::KeyW) - k(KeyCode::KeyS));
        v += right * (k(KeyCode::KeyD) - k(KeyCode::KeyA));
        v += up * (k(KeyCode::KeyE) - k(KeyCode::KeyQ));
        let boost =
            if self.keys.contains(&KeyCode::ShiftLeft) || self.keys.contains(&KeyCode::ShiftRight) { 4.0 } else { 1.0 };
        self.cam.eye_in_world += v * self.cam.speed_mps * boost * dt;
    }

    fn draw_panel(&mut self, encoder: &mut wgpu::CommandEncoder, view: &wgpu::TextureView, scene: &mut impl Scene) {
        let input = self.egui_state.take_egui_input(&self.window);
        let ctx = self.egui_ctx.clone();
        let mut output = ctx.run_ui(input, |ui| {
            egui::Window::new("relief")
                .default_pos([12.0, 12.0])
                .resizable(false)
                .show(ui.ctx(), |ui| self.panel(ui, scene));
        });
        self.egui_state.handle_platform_output(&self.window, output.platform_output);
        let ppp = output.pixels_per_point;
        let jobs = ctx.tessellate(output.shapes, ppp);
        let screen = egui_wgpu::ScreenDescriptor {
            size_in_pixels: [self.config.width, self.config.height],
            pixels_per_point: ppp,
        };
        let mut textures = std::mem::take(&mut output.textures_delta);
        for (id, deltas) in &textures.set {
            for delta in deltas {
                self.egui_renderer.update_texture(&self.gpu.device, &self.gpu.queue, *id, delta);
            }
        }
        let extra = self.egui_renderer.update_buffers(&self.gpu.device, &self.gpu.queue, encoder, &jobs, &screen);
        if !extra.is_empty() {
            self.gpu.queue.submit(extra);
        }
        {
            let pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("egui"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations { load: wgpu::LoadOp::Load, store: wgpu::StoreOp::Store },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            self.egui_renderer.render(&mut pass.forget_lifetime(), &jobs, &screen);
        }
        for id in &textures.free {
            self.egui_renderer.free_texture(id);
        }
        // Applied above; egui checks (in debug builds) that no delta is dropped unapplied.
        textures.clear();
    }

    fn panel(&mut self, ui: &mut egui::Ui, scene: &mut impl Scene) {
        let fps = if self.frame_ms_avg > 0.0 { 1e3 / self.frame_ms_avg } else { 0.0 };
        // Enough decimals for the scale flown at: metres over a terrain, millimetres by a bunny.
        let decimals = (2.0 - self.cam.speed_mps.log10().floor()).clamp(0.0, 6.0) as usize;
        egui::Grid::new("stats").num_columns(2).show(ui, |ui| {
            let mut row = |k: &str, v: String| {
                ui.label(k);
                ui.label(v);
                ui.end_row();
            };
            row("fps", format!("{fps:.1} ({:.1} ms)", self.frame_ms_avg));
            for (k, v) in scene.stats() {
                row(k, v);
            }
            row("speed", format!("{:.decimals$} m/s", self.cam.speed_mps));
            let e = self.cam.eye_in_world;
            row("eye", format!("{:.decimals$}, {:.decimals$}, {:.decimals$} m", e.x, e.y, e.z));
        });
        ui.separator();
        scene.controls(ui);
        for line in HELP {
            ui.label(line);
        }
        if self.recording.is_some() {
            ui.colored_label(egui::Color32::RED, RECORDING);
        }
        if !self.message.is_empty() {
            ui.label(&self.message);
        }
    }
}

/// Seconds since the epoch, for file names.
fn timestamp() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A drag quicker than a frame (press, moves, release before the panel's next frame) reaches
    /// the panel as a press and moves in one frame and the release in the next, so egui sees a
    /// drag and not a click; events held keep their order, and a second quick click waits too.
    #[test]
    fn a_release_waits_for_a_frame_after_its_press() {
        use winit::event::{DeviceId, MouseButton};
        let button = |state| WindowEvent::MouseInput { device_id: DeviceId::dummy(), state, button: MouseButton::Left };
        let moved = |x: f64| WindowEvent::CursorMoved {
            device_id: DeviceId::dummy(),
            position: winit::dpi::PhysicalPosition::new(x, 10.0),
        };
        let (press, release) = (button(ElementState::Pressed), button(ElementState::Released));
        let mut p = PanelInput::default();
        assert!(p.offer(&moved(49.0)) && p.offer(&press) && p.offer(&moved(80.0)) && p.offer(&moved(110.0)));
        assert!(!p.offer(&release), "the release waits for the next frame");
        assert!(
            !p.offer(&moved(120.0)) && !p.offer(&press) && !p.offer(&release),
            "later pointer events queue behind it"
        );
        assert!(p.offer(&WindowEvent::Focused(true)), "other events are not held");
        // Next frame: the release, the move and the second press; its release one frame later.
        assert_eq!(p.frame_done(), vec![release.clone(), moved(120.0), press.clone()]);
        assert!(!p.offer(&moved(130.0)));
        assert_eq!(p.frame_done(), vec![release.clone(), moved(130.0)]);
        assert!(p.frame_done().is_empty());
        // A slow click (the release a frame or more after the press) is never held.
        assert!(p.offer(&press));
        assert!(p.frame_done().is_empty());
        assert!(p.offer(&release));
    }

    #[test]
    fn display_errors_lose_winit_source_locations() {
        let why = display_error(
            "os error at /root/.cargo/registry/src/index.crates.io-1949cf8c6b5b557f/winit-0.30.13/src/platform_impl/linux/mod.rs:788: Failed to open connection to X server",
        );
        assert!(why.starts_with("Failed to open connection to X server"), "{why}");
        assert!(!why.contains(".cargo") && !why.contains(".rs:"), "{why}");
        assert!(display_error("no backend").starts_with("no backend"));
    }

    #[test]
    fn fly_camera_keeps_its_heading_about_any_up_axis() {
        for up in UpAxis::ALL {
            let (e1, e2, u) = up.frame();
            let eye = DVec3::new(1.0, 2.0, 3.0);
            let look = eye + e1 * 3.0 + e2 * 4.0 + u * 5.0;
            let c = FlyCamera::looking(eye, look, 1.0, up);
            assert!((c.forward() - (look - eye).normalize()).length() < 1e-12, "{up:?}");
            assert!(c.right().dot(c.forward()).abs() < 1e-12 && c.right().dot(u) == 0.0);
            // Right is to the right: forward × up.
            assert!(c.right().dot(c.forward().cross(u)) > 0.0);
            let cam = c.camera(60.0, 64, 48).unwrap();
            assert!((cam.basis().0 - c.right()).length() < 1e-9, "{up:?}");
        }
    }

    /// Every fixed string the panels show is drawn from the bundled fonts, no glyph missing (a
    /// missing one draws as a box: the recording marker was "● recording", and egui's fonts have
    /// no U+25CF).
    #[test]
    fn the_panels_text_has_every_glyph_in_the_bundled_font() {
        let ctx = egui::Context::default();
        // The fonts are loaded by the first frame.
        let mut output = ctx.run_ui(egui::RawInput::default(), |_| {});
        output.textures_delta.clear(); // nothing is drawn here
        let texts: Vec<&str> = HELP
            .iter()
            .chain([RECORDING].iter())
            .chain(terrain::CONTROL_LABELS.iter())
            .chain(mesh::CONTROL_LABELS.iter())
            .copied()
            .collect();
        for font in [egui::FontId::proportional(14.0), egui::FontId::monospace(14.0)] {
            for t in &texts {
                let missing: String = t.chars().filter(|&c| !ctx.fonts_mut(|f| f.has_glyph(&font, c))).collect();
                assert!(missing.is_empty(), "{t:?}: {missing:?} not in the {:?} font", font.family);
            }
        }
    }
}
