//! `relief fly` in a window: winit for the window and input, egui for the panel, the terrain
//! renderer for the frame, and refinement on its own thread (or synchronous with `--sync`).
//!
//! Controls: drag with a mouse button to look around; W/S forward and back, A/D sideways, Q/E
//! down and up, Shift ×4; the scroll wheel changes the speed; F freezes refinement (fly out and
//! look at the frozen mesh and its culling), T toggles the wireframe, F12 (or P) saves a screenshot, R
//! starts and stops recording the flight path to JSON, Esc quits.

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

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::flight::{FlightPath, PathFrame};
use crate::fly::{save_png, RefineJob, StripSource, Update};
use crate::format::TerrainFile;
use crate::mem;
use crate::progress::Progress;
use crate::refine::RefineOptions;
use crate::render::offscreen::Offscreen;
use crate::render::{DrawStyle, FrameView, Gpu, RendererOptions, TerrainRenderer};

/// Settings of an interactive flight.
#[derive(Clone, Debug)]
pub struct WindowOptions {
    pub width_px: u32,
    pub height_px: u32,
    pub fov_x_deg: f64,
    pub refine: RefineOptions,
    pub wireframe: bool,
    pub threads: usize,
    /// Refine on the render thread before each frame instead of on the refinement thread.
    pub sync: bool,
    /// Where screenshots and recorded paths go.
    pub output_dir: PathBuf,
    /// Start here, looking there (world metres); default: south-west of the DEM, above it.
    pub start: Option<(DVec3, DVec3)>,
    /// Close after this many frames (scripted runs, smoke tests).
    pub exit_after_frames: Option<u64>,
    pub progress: Progress,
}

/// The error for a machine without a display, with what to do instead.
pub fn no_display(reason: &str) -> Error {
    Error::NoDisplay(format!(
        "cannot open a window ({reason}); fly headless instead: \
         relief path flyover FILE --frames 300 --out path.json && relief fly FILE --path path.json --frames-out frames/"
    ))
}

/// Fails early, with the headless alternative, where no X display is set (Linux, BSD).
pub fn check_display() -> Result<()> {
    #[cfg(all(unix, not(target_os = "macos")))]
    if std::env::var_os("DISPLAY").is_none() {
        return Err(no_display("DISPLAY is not set"));
    }
    Ok(())
}

/// Opens a window and flies over `terrain` until it is closed.
pub fn fly_window(terrain: Arc<TerrainFile>, options: WindowOptions) -> Result<()> {
    check_display()?;
    let event_loop = EventLoop::new().map_err(|e| no_display(&e.to_string()))?;
    let mut app = App { terrain, options, state: None, error: None };
    event_loop.run_app(&mut app).map_err(|e| Error::Gpu(format!("window event loop: {e}")))?;
    match app.error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

struct App {
    terrain: Arc<TerrainFile>,
    options: WindowOptions,
    state: Option<State>,
    error: Option<Error>,
}

/// A first-person camera: position and heading.
#[derive(Clone, Copy, Debug)]
struct FlyCamera {
    eye_in_world: DVec3,
    /// Heading, radians counter-clockwise from east.
    yaw: f64,
    /// Radians above the horizon.
    pitch: f64,
    speed_mps: f64,
}

impl FlyCamera {
    fn forward(&self) -> DVec3 {
        DVec3::new(self.yaw.cos() * self.pitch.cos(), self.yaw.sin() * self.pitch.cos(), self.pitch.sin())
    }

    fn camera(&self, fov_x_deg: f64, w: u32, h: u32) -> Result<Camera> {
        Camera::new(self.eye_in_world, self.eye_in_world + self.forward(), DVec3::Z, fov_x_deg, w.max(1), h.max(1))
    }

    /// At `eye` looking at `look`.
    fn looking(eye: DVec3, look: DVec3, terrain: &TerrainFile) -> FlyCamera {
        let d = look - eye;
        let mut c = FlyCamera::start(terrain);
        c.eye_in_world = eye;
        c.yaw = d.y.atan2(d.x);
        c.pitch = d.z.atan2(d.x.hypot(d.y)).clamp(-1.55, 1.55);
        c
    }

    /// Starts south-west of the DEM, above its highest point, looking at its centre.
    fn start(terrain: &TerrainFile) -> FlyCamera {
        let h = terrain.header();
        let [x0, y0, x1, y1] = h.valid_window;
        let centre = DVec3::new(
            0.5 * (x0 + x1 - 1) as f64 * h.spacing_m[0],
            0.5 * (y0 + y1 - 1) as f64 * h.spacing_m[1],
            h.z_min.max(0.0),
        );
        let size_m = ((x1 - x0) as f64 * h.spacing_m[0]).hypot((y1 - y0) as f64 * h.spacing_m[1]);
        let eye = centre + DVec3::new(-0.45 * size_m, -0.45 * size_m, 0.0);
        let eye = DVec3::new(eye.x, eye.y, h.z_max + 0.15 * size_m);
        let d = centre - eye;
        FlyCamera { eye_in_world: eye, yaw: d.y.atan2(d.x), pitch: d.z.atan2(d.x.hypot(d.y)), speed_mps: size_m / 30.0 }
    }
}

/// Figures shown in the panel.
#[derive(Default)]
struct Stats {
    frame_ms_avg: f64,
    refine_ms: f64,
    /// Bytes sent this frame (strip when new, plus the uniform) and by the last strip upload.
    upload_bytes: u64,
    strip_upload_bytes: u64,
    lag: u64,
    faults_per_s: f64,
    major_faults_per_s: f64,
    last_faults: (u64, u64),
    last_faults_at: Option<Instant>,
}

struct State {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    gpu: Gpu,
    depth_view: wgpu::TextureView,
    renderer: TerrainRenderer,
    source: StripSource,
    egui_ctx: egui::Context,
    egui_state: egui_winit::State,
    egui_renderer: egui_wgpu::Renderer,
    cam: FlyCamera,
    keys: HashSet<KeyCode>,
    dragging: bool,
    last_cursor: Option<(f64, f64)>,
    last_frame: Instant,
    tolerance_px: f64,
    cull: bool,
    wireframe: bool,
    frozen: bool,
    /// The camera the drawn strip was refined for (shown when frozen).
    refined_camera: Option<Camera>,
    recording: Option<Vec<PathFrame>>,
    message: String,
    seq: u64,
    frames: u64,
    stats: Stats,
}

impl App {
    fn init(&mut self, event_loop: &ActiveEventLoop) -> Result<State> {
        let o = &self.options;
        let attrs = Window::default_attributes()
            .with_title(format!("relief — {}", self.terrain.path().display()))
            .with_inner_size(winit::dpi::PhysicalSize::new(o.width_px, o.height_px));
        let window = Arc::new(event_loop.create_window(attrs).map_err(|e| no_display(&e.to_string()))?);
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let surface = instance
            .create_surface(window.clone())
            .map_err(|e| Error::Gpu(format!("cannot draw into the window: {e}")))?;
        let gpu = Gpu::with_instance(instance, Some(&surface))?;
        let caps = surface.get_capabilities(&gpu.adapter);
        let format = caps
            .formats
            .iter()
            .copied()
            .find(|f| f.is_srgb())
            .or(caps.formats.first().copied())
            .ok_or_else(|| Error::Gpu("the window offers no surface format".into()))?;
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
        let renderer = TerrainRenderer::new(&gpu, &self.terrain, format, RendererOptions::default(), o.progress)?;
        let source = StripSource::new(self.terrain.clone(), o.threads, !o.sync)?;
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
        Ok(State {
            window,
            surface,
            config,
            gpu,
            depth_view,
            renderer,
            source,
            egui_ctx,
            egui_state,
            egui_renderer,
            cam: match o.start {
                Some((eye, look)) => FlyCamera::looking(eye, look, &self.terrain),
                None => FlyCamera::start(&self.terrain),
            },
            frames: 0,
            keys: HashSet::new(),
            dragging: false,
            last_cursor: None,
            last_frame: Instant::now(),
            tolerance_px: o.refine.tolerance_px,
            cull: o.refine.cull,
            wireframe: o.wireframe,
            frozen: false,
            refined_camera: None,
            recording: None,
            message: String::new(),
            seq: 0,
            stats: Stats::default(),
        })
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.state.is_some() {
            return;
        }
        match self.init(event_loop) {
            Ok(s) => {
                s.window.request_redraw();
                self.state = Some(s);
            }
            Err(e) => {
                self.error = Some(e);
                event_loop.exit();
            }
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        let Some(s) = self.state.as_mut() else { return };
        let consumed = s.egui_state.on_window_event(&s.window, &event).consumed;
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
                                KeyCode::KeyF => s.frozen = !s.frozen,
                                KeyCode::KeyT => s.wireframe = !s.wireframe,
                                KeyCode::F12 | KeyCode::KeyP => s.message = s.screenshot(&self.terrain, &self.options),
                                KeyCode::KeyR => s.message = s.toggle_recording(&self.options),
                                _ => {}
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
                s.cam.speed_mps = (s.cam.speed_mps * 1.25f64.powf(ticks)).clamp(0.01, 1e7);
            }
            WindowEvent::RedrawRequested => {
                if let Err(e) = s.frame(&self.terrain, &self.options) {
                    self.error = Some(e);
                    event_loop.exit();
                    return;
                }
                s.frames += 1;
                if self.options.exit_after_frames.is_some_and(|n| s.frames >= n) {
                    event_loop.exit();
                    return;
                }
                s.window.request_redraw();
            }
            _ => {}
        }
    }
}

impl State {
    fn camera(&self, o: &WindowOptions) -> Result<Camera> {
        self.cam.camera(o.fov_x_deg, self.config.width, self.config.height)
    }

    /// Draws the current strip (frozen or not) without the panel into an image file.
    fn screenshot(&mut self, terrain: &TerrainFile, o: &WindowOptions) -> String {
        let go = || -> Result<PathBuf> {
            let cam = self.camera(o)?;
            let target = Offscreen::with_format(&self.gpu, cam.width_px, cam.height_px, self.config.format)?;
            let mut enc = self.gpu.device.create_command_encoder(&Default::default());
            let view = FrameView::new(terrain, cam);
            let style = DrawStyle { wireframe: self.wireframe };
            self.renderer.encode(&self.gpu, &mut enc, &target.colour_view, &target.depth_view, &view, style);
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

    fn toggle_recording(&mut self, o: &WindowOptions) -> String {
        match self.recording.take() {
            None => {
                self.recording = Some(Vec::new());
                "recording the flight path (R to stop)".into()
            }
            Some(frames) if frames.is_empty() => "recording stopped: no frames".into(),
            Some(frames) => {
                let path = o.output_dir.join(format!("relief-path-{}.json", timestamp()));
                let n = frames.len();
                match (FlightPath { frames }).save(&path) {
                    Ok(()) => format!("path: {} ({n} frames)", path.display()),
                    Err(e) => format!("saving the path failed: {e}"),
                }
            }
        }
    }

    fn frame(&mut self, terrain: &TerrainFile, o: &WindowOptions) -> Result<()> {
        let now = Instant::now();
        let dt = (now - self.last_frame).as_secs_f64().min(0.25);
        self.last_frame = now;
        self.stats.frame_ms_avg =
            if self.stats.frame_ms_avg == 0.0 { dt * 1e3 } else { 0.9 * self.stats.frame_ms_avg + 0.1 * dt * 1e3 };
        self.fly(dt);
        let cam = self.camera(o)?;
        if let Some(rec) = &mut self.recording {
            rec.push(PathFrame { eye: cam.eye_in_world.to_array(), look: cam.look_at_world.to_array() });
        }
        // Frozen: outline the view the drawn strip was refined (and culled) for.
        let outline = match (self.frozen, self.refined_camera) {
            (true, Some(c)) => {
                let [ex, ey] = terrain.header().extent_m();
                c.frustum_outline(0.3 * ex.max(ey)).to_vec()
            }
            _ => Vec::new(),
        };
        self.renderer.set_overlay_lines(&self.gpu, &outline);
        if !self.frozen {
            self.seq += 1;
            let options = RefineOptions { tolerance_px: self.tolerance_px, cull: self.cull, ..o.refine };
            let job = RefineJob { camera: cam, options, seq: self.seq };
            let first = self.refined_camera.is_none();
            let u: Update = self.source.update(&self.gpu, &mut self.renderer, job, first);
            self.stats.upload_bytes = u.upload_bytes + crate::render::terrain::FRAME_UNIFORM_BYTES;
            if u.uploaded {
                self.stats.refine_ms = u.refine_ms.unwrap_or(0.0);
                self.stats.strip_upload_bytes = u.upload_bytes;
                self.stats.lag = u.lag;
                self.refined_camera = Some(cam);
            }
        } else {
            self.stats.upload_bytes = crate::render::terrain::FRAME_UNIFORM_BYTES;
        }
        self.sample_faults(now);

        let frame = match self.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(f) | wgpu::CurrentSurfaceTexture::Suboptimal(f) => f,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                self.surface.configure(&self.gpu.device, &self.config);
                return Ok(());
            }
            other => return Err(Error::Gpu(format!("cannot get the window's next image: {other:?}"))),
        };
        let view = frame.texture.create_view(&Default::default());
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        let style = DrawStyle { wireframe: self.wireframe };
        let frame_view = FrameView::new(terrain, cam);
        self.renderer.encode(&self.gpu, &mut encoder, &view, &self.depth_view, &frame_view, style);
        self.draw_panel(&mut encoder, &view, o);
        self.gpu.queue.submit([encoder.finish()]);
        self.window.pre_present_notify();
        self.gpu.queue.present(frame);
        self.gpu.check()
    }

    fn fly(&mut self, dt: f64) {
        let f = self.cam.forward();
        let right = DVec3::new(self.cam.yaw.sin(), -self.cam.yaw.cos(), 0.0);
        let mut v = DVec3::ZERO;
        let k = |c: KeyCode| self.keys.contains(&c) as i32 as f64;
        v += f * (k(KeyCode::KeyW) - k(KeyCode::KeyS));
        v += right * (k(KeyCode::KeyD) - k(KeyCode::KeyA));
        v += DVec3::Z * (k(KeyCode::KeyE) - k(KeyCode::KeyQ));
        let boost =
            if self.keys.contains(&KeyCode::ShiftLeft) || self.keys.contains(&KeyCode::ShiftRight) { 4.0 } else { 1.0 };
        self.cam.eye_in_world += v * self.cam.speed_mps * boost * dt;
    }

    fn sample_faults(&mut self, now: Instant) {
        let faults = mem::page_faults();
        match self.stats.last_faults_at {
            Some(t) if (now - t).as_secs_f64() >= 1.0 => {
                let s = (now - t).as_secs_f64();
                self.stats.major_faults_per_s = (faults.0 - self.stats.last_faults.0) as f64 / s;
                self.stats.faults_per_s = (faults.1 - self.stats.last_faults.1) as f64 / s;
                self.stats.last_faults = faults;
                self.stats.last_faults_at = Some(now);
            }
            None => {
                self.stats.last_faults = faults;
                self.stats.last_faults_at = Some(now);
            }
            _ => {}
        }
    }

    fn draw_panel(&mut self, encoder: &mut wgpu::CommandEncoder, view: &wgpu::TextureView, o: &WindowOptions) {
        let input = self.egui_state.take_egui_input(&self.window);
        let ctx = self.egui_ctx.clone();
        let mut output = ctx.run_ui(input, |ui| {
            egui::Window::new("relief")
                .default_pos([12.0, 12.0])
                .resizable(false)
                .show(ui.ctx(), |ui| self.panel(ui, o));
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

    fn panel(&mut self, ui: &mut egui::Ui, o: &WindowOptions) {
        let st = &self.stats;
        let fps = if st.frame_ms_avg > 0.0 { 1e3 / st.frame_ms_avg } else { 0.0 };
        egui::Grid::new("stats").num_columns(2).show(ui, |ui| {
            let mut row = |k: &str, v: String| {
                ui.label(k);
                ui.label(v);
                ui.end_row();
            };
            row("fps", format!("{fps:.1} ({:.1} ms)", st.frame_ms_avg));
            row("refine", format!("{:.2} ms{}", st.refine_ms, if o.sync { " (sync)" } else { "" }));
            row("triangles", format!("{}", self.renderer.triangles()));
            row("strip length", format!("{}", self.renderer.strip_len()));
            row("upload", format!("{} B this frame", st.upload_bytes));
            row("strip upload", format!("{:.1} KiB (last)", st.strip_upload_bytes as f64 / 1024.0));
            row("GPU heights", format!("{:.1} MiB", self.renderer.heights_bytes() as f64 / 1048576.0));
            row("resident", format!("{:.1} MiB", mem::rss_bytes().unwrap_or(0) as f64 / 1048576.0));
            row("page faults", format!("{:.0}/s ({:.0} major/s)", st.faults_per_s, st.major_faults_per_s));
            row("strip lag", format!("{} frames", st.lag));
            row("speed", format!("{:.0} m/s", self.cam.speed_mps));
            let e = self.cam.eye_in_world;
            row("eye", format!("{:.0}, {:.0}, {:.0} m", e.x, e.y, e.z));
        });
        ui.separator();
        ui.add(egui::Slider::new(&mut self.tolerance_px, 0.25..=32.0).logarithmic(true).text("τ (px)"));
        ui.checkbox(&mut self.cull, "cull to the view");
        ui.checkbox(&mut self.wireframe, "wireframe (T)");
        ui.checkbox(&mut self.frozen, "freeze refinement (F)");
        ui.label("drag: look · WASD/QE: move · wheel: speed");
        ui.label("F12/P: screenshot · R: record path");
        if self.recording.is_some() {
            ui.colored_label(egui::Color32::RED, "● recording");
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
