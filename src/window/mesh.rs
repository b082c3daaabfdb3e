//! `relief mesh view` (and every mesh backend) in a window: a [`FrameSource`] adapted to the
//! camera each frame and drawn by the mesh renderer. Keys besides the shared ones (`window`): F
//! freezes the adaptation (fly out and look at the adapted mesh), T toggles the wireframe.

use glam::DVec3;
use winit::keyboard::KeyCode;

use super::{FlyCamera, Scene, WindowSettings};
use crate::camera::{Camera, UpAxis};
use crate::error::Result;
use crate::flight::frame::{FrameSource, FrameStats, PAGE_CHANGES};
use crate::flight::{orbit_box, OrbitOptions};
use crate::render::mesh::MESH_FRAME_UNIFORM_BYTES;
use crate::render::MeshStage;
use crate::render::{Gpu, MeshStyle};

/// Settings of an interactive flight around a mesh.
#[derive(Clone, Debug)]
pub struct MeshWindowOptions {
    /// Size, field of view, output directory, start (default: the first frame of the default
    /// orbit, `flight::orbit_box`).
    pub window: WindowSettings,
    /// Screen-space tolerance handed to the source, pixels (a slider in the panel).
    pub tolerance_px: f64,
    pub wireframe: bool,
    pub up: UpAxis,
    /// The panel's title for the source ("static", "ext", …).
    pub source_name: String,
}

/// Opens a window and flies around what `source` adapts until the window is closed.
pub fn mesh_window(source: &mut dyn FrameSource, title: &str, options: MeshWindowOptions) -> Result<()> {
    let settings = options.window.clone();
    let scene = MeshScene {
        source,
        title: format!("relief — {title}"),
        tolerance_px: options.tolerance_px,
        wireframe: options.wireframe,
        options,
        stage: None,
        frozen: false,
        last: FrameStats::default(),
        upload_bytes: 0,
        pages_read_total: 0,
    };
    super::run(scene, settings)
}

/// The labels of the mesh panel's controls (every glyph in the bundled font: see the test in
/// `window/mod.rs`).
pub(super) const CONTROL_LABELS: [&str; 3] = ["τ (px)", "wireframe (T)", "freeze adaptation (F)"];

struct MeshScene<'a> {
    source: &'a mut dyn FrameSource,
    title: String,
    options: MeshWindowOptions,
    stage: Option<MeshStage>,
    tolerance_px: f64,
    wireframe: bool,
    frozen: bool,
    /// The last update's figures.
    last: FrameStats,
    /// Triangle bytes uploaded this frame.
    upload_bytes: u64,
    pages_read_total: u64,
}

impl Scene for MeshScene<'_> {
    fn title(&self) -> String {
        self.title.clone()
    }

    fn start(&mut self, gpu: &Gpu, format: wgpu::TextureFormat, start: Option<(DVec3, DVec3)>) -> Result<FlyCamera> {
        let bounds = self.source.bounds();
        let up = self.options.up;
        self.stage = Some(MeshStage::new(gpu, format, bounds, up)?);
        let (eye, look) = match start {
            Some(s) => s,
            None => {
                let f = orbit_box(&bounds, up, &OrbitOptions::new(1))?.frames[0];
                (f.eye_in_world(), f.look_at_world())
            }
        };
        // Across the box in about ten seconds.
        Ok(FlyCamera::looking(eye, look, (bounds.diagonal() / 10.0).max(1e-6), up))
    }

    fn key(&mut self, code: KeyCode) {
        match code {
            KeyCode::KeyF => self.frozen = !self.frozen,
            KeyCode::KeyT => self.wireframe = !self.wireframe,
            _ => {}
        }
    }

    fn update(&mut self, gpu: &Gpu, camera: &Camera) -> Result<()> {
        let Some(stage) = self.stage.as_mut() else { return Ok(()) };
        self.upload_bytes = 0;
        if !self.frozen {
            self.last = self.source.update(camera, self.tolerance_px)?;
            self.pages_read_total += self.last.pages_read;
            self.upload_bytes = stage.sync(gpu, self.source.frame(), self.last.changed, camera)?;
        }
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
        if let Some(stage) = &self.stage {
            stage.encode(gpu, encoder, colour, depth, camera, MeshStyle { wireframe: self.wireframe });
        }
    }

    fn stats(&self) -> Vec<(&'static str, String)> {
        let s = &self.last;
        let triangles = self.stage.as_ref().map_or(0, |st| st.renderer.triangles());
        vec![
            ("source", self.options.source_name.clone()),
            if self.source.changes() == PAGE_CHANGES {
                ("pages", format!("{} gained, {} lost", s.pages_gained, s.pages_lost))
            } else {
                ("adapt", format!("{} ({} splits, {} collapses)", s.splits + s.collapses, s.splits, s.collapses))
            },
            ("adapt time", format!("{:.2} ms", s.update_ms.unwrap_or(0.0))),
            ("triangles", format!("{triangles}")),
            ("misses", format!("{} ({:.1}%)", s.misses, s.miss_pct())),
            ("pages read", format!("{} ({} in all)", s.pages_read, self.pages_read_total)),
            ("upload", format!("{:.1} KiB this frame", (self.upload_bytes + MESH_FRAME_UNIFORM_BYTES) as f64 / 1024.0)),
        ]
    }

    fn controls(&mut self, ui: &mut egui::Ui) {
        let [tau, wire, freeze] = CONTROL_LABELS;
        ui.add(egui::Slider::new(&mut self.tolerance_px, 0.25..=32.0).logarithmic(true).text(tau));
        ui.checkbox(&mut self.wireframe, wire);
        ui.checkbox(&mut self.frozen, freeze);
    }
}
