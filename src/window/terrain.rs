//! `relief fly` in a window: the terrain renderer for the frame and refinement on its own thread
//! (or synchronous with `--sync`). Keys besides the shared ones (`window`): F freezes refinement
//! (fly out and look at the frozen mesh and its culling), T toggles the wireframe.

use std::sync::Arc;
use std::time::Instant;

use glam::DVec3;
use winit::keyboard::KeyCode;

use super::{FlyCamera, Scene, WindowSettings};
use crate::camera::{Camera, UpAxis};
use crate::error::Result;
use crate::flight::frame::FrameSource;
use crate::flight::terrain::TerrainSource;
use crate::format::terrain::TerrainFile;
use crate::refine::RefineOptions;
use crate::render::shade::MAX_Z_EXAGGERATION;
use crate::render::terrain::FRAME_UNIFORM_BYTES;
use crate::render::{DrawStyle, FrameView, Gpu, Look, Ramp, RendererOptions, TerrainRenderer};
use crate::sys::mem;
use crate::sys::progress::Progress;

/// Settings of an interactive flight over a terrain.
#[derive(Clone, Debug)]
pub struct WindowOptions {
    /// Size, field of view, output directory, start (default: south-west of the DEM, above it).
    pub window: WindowSettings,
    pub refine: RefineOptions,
    pub wireframe: bool,
    pub threads: usize,
    /// Refine on the render thread before each frame instead of on the refinement thread.
    pub sync: bool,
    /// GPU memory for heights and the height cache's upload budget.
    pub renderer: RendererOptions,
    pub progress: Progress,
}

/// Opens a window and flies over `terrain` until it is closed.
pub fn fly_window(terrain: Arc<TerrainFile>, options: WindowOptions) -> Result<()> {
    let settings = options.window.clone();
    let scene = TerrainScene {
        tolerance_px: options.refine.tolerance_px,
        cull: options.refine.cull,
        wireframe: options.wireframe,
        look: options.renderer.look,
        applied_look: options.renderer.look,
        rescale: None,
        terrain,
        options,
        drawn: None,
        frozen: false,
        refined_camera: None,
        stats: Stats::default(),
    };
    super::run(scene, settings)
}

/// Figures shown in the panel.
#[derive(Default)]
struct Stats {
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

/// The renderer and where its strips come from, once the window's device exists.
struct Drawn {
    renderer: TerrainRenderer,
    source: TerrainSource,
}

struct TerrainScene {
    terrain: Arc<TerrainFile>,
    options: WindowOptions,
    drawn: Option<Drawn>,
    tolerance_px: f64,
    cull: bool,
    wireframe: bool,
    frozen: bool,
    /// The camera the drawn strip was refined for (shown when frozen).
    refined_camera: Option<Camera>,
    stats: Stats,
    /// The look the panel asks for, and the one drawn.
    look: Look,
    applied_look: Look,
    /// The eye's height is to be scaled by this (the exaggeration changed).
    rescale: Option<f64>,
}

/// The labels of the terrain panel's controls (every glyph in the bundled font: see the test in
/// `window/mod.rs`).
pub(super) const CONTROL_LABELS: [&str; 11] = [
    "τ (px)",
    "cull to the view",
    "wireframe (T)",
    "freeze refinement (F)",
    "vertical exaggeration ×",
    "colour ramp",
    "hypsometric",
    "viridis",
    "grey hillshade",
    "sun azimuth (° from north)",
    "sun altitude (°)",
];

/// Starts south-west of the DEM, above its highest point, looking at its centre (in the scene
/// with heights `x` times as high).
fn start_camera(terrain: &TerrainFile, start: Option<(DVec3, DVec3)>, x: f64) -> FlyCamera {
    let h = terrain.header();
    let [x0, y0, x1, y1] = h.valid_window;
    let centre = DVec3::new(
        0.5 * (x0 + x1 - 1) as f64 * h.spacing_m[0],
        0.5 * (y0 + y1 - 1) as f64 * h.spacing_m[1],
        h.z_min.max(0.0) * x,
    );
    let size_m = ((x1 - x0) as f64 * h.spacing_m[0]).hypot((y1 - y0) as f64 * h.spacing_m[1]);
    let (eye, look) = start.unwrap_or_else(|| {
        let eye = centre + DVec3::new(-0.45 * size_m, -0.45 * size_m, 0.0);
        (DVec3::new(eye.x, eye.y, h.z_max * x + 0.15 * size_m), centre)
    });
    FlyCamera::looking(eye, look, size_m / 30.0, UpAxis::Z)
}

impl Scene for TerrainScene {
    fn title(&self) -> String {
        format!("relief — {}", self.terrain.path().display())
    }

    fn start(&mut self, gpu: &Gpu, format: wgpu::TextureFormat, start: Option<(DVec3, DVec3)>) -> Result<FlyCamera> {
        let o = &self.options;
        let renderer = TerrainRenderer::new(gpu, &self.terrain, format, o.renderer.clone(), o.progress)?;
        let refine = RefineOptions { heights: renderer.cached(), ..o.refine };
        let source = TerrainSource::new(self.terrain.clone(), refine, o.threads, !o.sync)?;
        self.options.refine = refine;
        self.drawn = Some(Drawn { renderer, source });
        Ok(start_camera(&self.terrain, start, self.applied_look.z_exaggeration))
    }

    fn key(&mut self, code: KeyCode) {
        match code {
            KeyCode::KeyF => self.frozen = !self.frozen,
            KeyCode::KeyT => self.wireframe = !self.wireframe,
            _ => {}
        }
    }

    fn update(&mut self, gpu: &Gpu, cam: &Camera) -> Result<()> {
        let Some(d) = self.drawn.as_mut() else { return Ok(()) };
        // Frozen: outline the view the drawn strip was refined (and culled) for.
        let outline = match (self.frozen, self.refined_camera) {
            (true, Some(c)) => {
                let [ex, ey] = self.terrain.header().extent_m();
                c.frustum_outline(0.3 * ex.max(ey)).to_vec()
            }
            _ => Vec::new(),
        };
        d.renderer.set_overlay_lines(gpu, &outline);
        if self.look != self.applied_look {
            d.renderer.set_look(&self.look);
            self.options.refine.z_exaggeration = self.look.z_exaggeration;
            self.applied_look = self.look;
        }
        if !self.frozen {
            d.source.set_options(RefineOptions { cull: self.cull, ..self.options.refine });
            let u = d.source.update(cam, self.tolerance_px)?;
            let strip_bytes = if u.changed { d.renderer.upload_strip(gpu, d.source.strip())? } else { 0 };
            let height_bytes = d.renderer.sync_heights(gpu, cam, u.changed.then(|| d.source.strip()))?;
            let upload_bytes = strip_bytes + height_bytes;
            self.stats.upload_bytes = upload_bytes + FRAME_UNIFORM_BYTES;
            self.stats.lag = u.lag_frames;
            if u.changed {
                self.stats.refine_ms = u.update_ms.unwrap_or(0.0);
                self.stats.strip_upload_bytes = upload_bytes;
                self.refined_camera = Some(*cam);
            }
        } else {
            self.stats.upload_bytes = FRAME_UNIFORM_BYTES;
        }
        self.sample_faults(Instant::now());
        Ok(())
    }

    fn encode(
        &self,
        gpu: &Gpu,
        encoder: &mut wgpu::CommandEncoder,
        colour: &wgpu::TextureView,
        depth: &wgpu::TextureView,
        camera: &Camera,
    ) {
        if let Some(d) = &self.drawn {
            let view = FrameView::new(&self.terrain, *camera, d.renderer.shade_params().z_exaggeration);
            d.renderer.encode(gpu, encoder, colour, depth, &view, DrawStyle { wireframe: self.wireframe });
        }
    }

    fn stats(&self) -> Vec<(&'static str, String)> {
        let Some(d) = &self.drawn else { return Vec::new() };
        let st = &self.stats;
        let r = &d.renderer;
        let mut rows = vec![
            ("refine", format!("{:.2} ms{}", st.refine_ms, if self.options.sync { " (sync)" } else { "" })),
            ("triangles", format!("{}", r.triangles())),
            ("strip length", format!("{}", r.strip_len())),
            ("upload", format!("{} B this frame", st.upload_bytes)),
            ("strip upload", format!("{:.1} KiB (last)", st.strip_upload_bytes as f64 / 1024.0)),
            ("GPU heights", {
                let h = r.height_stats();
                if h.cached {
                    format!(
                        "cache {:.1} of {:.1} MiB",
                        h.in_use_bytes as f64 / 1048576.0,
                        h.budget_bytes as f64 / 1048576.0
                    )
                } else {
                    format!("{:.1} MiB (whole grid)", r.heights_bytes() as f64 / 1048576.0)
                }
            }),
            ("height tiles", {
                let h = r.height_stats();
                format!(
                    "{} resident, {} wanted, {} coarser, +{} ({:.1} MiB) this frame",
                    h.tiles_resident,
                    h.wanted,
                    h.fallbacks,
                    h.tiles_uploaded,
                    h.upload_bytes as f64 / 1048576.0
                )
            }),
            ("resident", format!("{:.1} MiB", mem::rss_bytes().unwrap_or(0) as f64 / 1048576.0)),
            ("page faults", format!("{:.0}/s ({:.0} major/s)", st.faults_per_s, st.major_faults_per_s)),
            ("strip lag", format!("{} frames", st.lag)),
        ];
        let i = r.imagery_stats();
        if i.cached {
            rows.insert(
                7,
                (
                    "imagery tiles",
                    format!(
                        "{} resident ({:.1} of {:.1} MiB), {} wanted, {} coarser, +{} this frame",
                        i.tiles_resident,
                        i.in_use_bytes as f64 / 1048576.0,
                        i.budget_bytes as f64 / 1048576.0,
                        i.wanted,
                        i.fallbacks,
                        i.tiles_uploaded
                    ),
                ),
            );
        }
        rows
    }

    fn controls(&mut self, ui: &mut egui::Ui) {
        let [tau, cull, wire, freeze, exaggeration, ramp, hyps, viridis, grey, azimuth, altitude] = CONTROL_LABELS;
        ui.add(egui::Slider::new(&mut self.tolerance_px, 0.25..=32.0).logarithmic(true).text(tau));
        ui.checkbox(&mut self.cull, cull);
        ui.checkbox(&mut self.wireframe, wire);
        ui.checkbox(&mut self.frozen, freeze);
        let before = self.look.z_exaggeration;
        let x = egui::Slider::new(&mut self.look.z_exaggeration, 1.0..=MAX_Z_EXAGGERATION.min(100.0)).logarithmic(true);
        if ui.add(x.text(exaggeration)).changed() && before > 0.0 {
            // The eye rises and sinks with the scene, so the view stays about the same.
            self.rescale = Some(self.rescale.unwrap_or(1.0) * self.look.z_exaggeration / before);
        }
        egui::ComboBox::from_label(ramp)
            .selected_text(match self.look.ramp {
                Ramp::Hypsometric => hyps,
                Ramp::Viridis => viridis,
                Ramp::Grey => grey,
            })
            .show_ui(ui, |ui| {
                ui.selectable_value(&mut self.look.ramp, Ramp::Hypsometric, hyps);
                ui.selectable_value(&mut self.look.ramp, Ramp::Viridis, viridis);
                ui.selectable_value(&mut self.look.ramp, Ramp::Grey, grey);
            });
        ui.add(egui::Slider::new(&mut self.look.sun_azimuth_deg, 0.0..=360.0).text(azimuth));
        ui.add(egui::Slider::new(&mut self.look.sun_altitude_deg, 0.0..=90.0).text(altitude));
    }

    fn take_rescale(&mut self) -> Option<f64> {
        self.rescale.take()
    }

    fn path_point(&self, p: DVec3) -> DVec3 {
        DVec3::new(p.x, p.y, p.z / self.look.z_exaggeration)
    }
}

impl TerrainScene {
    fn sample_faults(&mut self, now: Instant) {
        let faults = mem::page_faults();
        let st = &mut self.stats;
        match st.last_faults_at {
            Some(t) if (now - t).as_secs_f64() >= 1.0 => {
                let s = (now - t).as_secs_f64();
                st.major_faults_per_s = (faults.0 - st.last_faults.0) as f64 / s;
                st.faults_per_s = (faults.1 - st.last_faults.1) as f64 / s;
                st.last_faults = faults;
                st.last_faults_at = Some(now);
            }
            None => {
                st.last_faults = faults;
                st.last_faults_at = Some(now);
            }
            _ => {}
        }
    }
}
