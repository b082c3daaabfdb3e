//! What the page shows, without the page: a terrain file whose bytes the host fetches
//! ([`HostedFile`]), refined progressively each frame ([`Progressive::hosted`]), the strip turned
//! into positions for [`crate::draw`], and the orbit camera the mouse and touch drive. Natively
//! the same code renders the tests' reference image.

use std::path::Path;
use std::sync::Arc;

use glam::DVec3;

use relief_core::camera::Camera;
use relief_core::format::terrain::{Header, TerrainFile};
use relief_core::pager::hosted::HostedFile;
use relief_core::pager::source::RemoteStats;
use relief_core::pager::Access;
use relief_core::refine::progressive::{HostedRequest, Progressive, ProgressiveFrame, ProgressiveOptions};
use relief_core::refine::{RefineOptions, Refiner, Strip};
use relief_core::Result;

use crate::draw::{Look, Vertex};

/// Bytes of the opening request: the header and the coarse levels (what the native remote
/// reader asks first, too).
pub const FIRST_RANGE_BYTES: u64 = 1 << 20;

/// A terrain being flown: its records as they arrive, and the last frame's strip.
pub struct Scene {
    terrain: Arc<TerrainFile>,
    hosted: Arc<HostedFile>,
    progressive: Progressive,
    refiner: Refiner,
    strip: Strip,
    /// τ (pixels) and the vertical exaggeration; heights are always filled (the page holds no
    /// grid of its own).
    pub options: RefineOptions,
}

impl Scene {
    /// Opens the terrain at `url` (`len` bytes) from its first bytes (`first`, at offset 0):
    /// validated as any terrain file (not a terrain file, a newer version, a truncated header
    /// are errors naming `url`).
    pub fn open(url: &str, len: u64, first: &[u8]) -> Result<Scene> {
        let hosted = Arc::new(HostedFile::new(Path::new(url), len));
        hosted.insert(0, first)?;
        let terrain = Arc::new(TerrainFile::from_source(Path::new(url), hosted.clone(), Access::Read)?);
        let progressive = Progressive::hosted(terrain.clone(), ProgressiveOptions::default())?;
        Ok(Scene {
            terrain,
            hosted,
            progressive,
            refiner: Refiner::new(1)?,
            strip: Strip::new(),
            options: RefineOptions { tolerance_px: 2.0, heights: true, ..Default::default() },
        })
    }

    pub fn terrain(&self) -> &TerrainFile {
        &self.terrain
    }

    /// Refines `camera`'s view (in the exaggerated scene) with what has arrived.
    pub fn refine(&mut self, camera: &Camera) -> Result<ProgressiveFrame> {
        self.progressive.refine(&mut self.refiner, camera, &self.options, &mut self.strip)
    }

    /// What to fetch next (see [`Progressive::take_request`]).
    pub fn take_request(&mut self) -> Result<Option<HostedRequest>> {
        self.progressive.take_request()
    }

    /// The bytes of one fetched range.
    pub fn insert(&self, offset: u64, bytes: &[u8]) -> Result<()> {
        self.hosted.insert(offset, bytes)
    }

    /// A request whose ranges have all been inserted.
    pub fn deliver(&mut self, request: HostedRequest) -> Result<()> {
        self.progressive.deliver(request)
    }

    /// Requests not yet delivered.
    pub fn outstanding(&self) -> u64 {
        self.progressive.outstanding()
    }

    /// What the fetches have brought (requests and bytes the host inserted).
    pub fn network(&self) -> RemoteStats {
        self.terrain.pager().network().unwrap_or_default()
    }

    /// Triangles of the last strip (degenerate ones included, as drawn).
    pub fn triangles(&self) -> u64 {
        (self.strip.vertices.len() as u64).saturating_sub(2)
    }

    /// The look of the scene ([`look_of`]).
    pub fn look(&self) -> Look {
        look_of(self.terrain.header(), self.options.z_exaggeration)
    }

    /// The last strip's vertices (see [`positions`]).
    pub fn positions(&self, look: &Look, uv: Option<[f32; 4]>) -> Vec<Vertex> {
        positions(self.terrain.header(), &self.strip, look, self.options.z_exaggeration, uv)
    }
}

/// The look of a terrain's scene: origin at the grid's centre, ramp over the file's heights.
pub fn look_of(h: &Header, z_exaggeration: f64) -> Look {
    let [w, d] = h.extent_m();
    Look {
        origin_in_scene: DVec3::new(0.5 * w, 0.5 * d, 0.0),
        z_lo: h.z_min * z_exaggeration,
        z_hi: h.z_max * z_exaggeration,
        fog_distance_m: 4.0 * w.max(d),
    }
}

/// A strip's vertices (with heights, `RefineOptions::heights`) in scene metres relative to
/// `look.origin_in_scene`, heights `z_exaggeration` times as high. Posts of the padding outside
/// the DEM's own window are drawn on its edge (their triangles vanish); a vertex without a
/// height yet stands at the terrain's mid height. With `uv` (a draped image's `[a0, a1, b0, b1]`,
/// `relief_core::georef::drape::uv_of_grid`) each vertex carries `u = a0 + a1·x`, `v = b0 + b1·y`.
pub fn positions(h: &Header, strip: &Strip, look: &Look, z_exaggeration: f64, uv: Option<[f32; 4]>) -> Vec<Vertex> {
    let [a0, a1, b0, b1] = uv.unwrap_or_default();
    let [x0, y0, x1, y1] = h.valid_window;
    let [sx, sy] = h.spacing_m;
    let mid = 0.5 * (h.z_min + h.z_max);
    let o = look.origin_in_scene;
    strip
        .vertices
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let (px, py) = (v.x.clamp(x0, x1.saturating_sub(1).max(x0)), v.y.clamp(y0, y1.saturating_sub(1).max(y0)));
            let (x, y) = (px as f64 * sx - o.x, py as f64 * sy - o.y);
            let z = strip.morph.get(i).map_or(mid, |m| m.z_m as f64) * z_exaggeration - o.z;
            Vertex { in_scene: [x as f32, y as f32, z as f32], uv: [a0 + a1 * px as f32, b0 + b1 * py as f32] }
        })
        .collect()
}

/// An orbit camera: a target on the terrain, looked at from `distance_m` along a direction
/// given by yaw (degrees from north, clockwise) and pitch (degrees below the horizon).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Orbit {
    pub target_in_scene: DVec3,
    pub distance_m: f64,
    pub yaw_deg: f64,
    pub pitch_deg: f64,
    pub fov_x_deg: f64,
}

impl Orbit {
    /// Over the middle of `terrain`'s DEM, from the south, all of it in view.
    pub fn overview(terrain: &TerrainFile, z_exaggeration: f64) -> Orbit {
        let h = terrain.header();
        let [x0, y0, x1, y1] = h.valid_window.map(f64::from);
        let [sx, sy] = h.spacing_m;
        let (w, d) = ((x1 - x0 - 1.0).max(1.0) * sx, (y1 - y0 - 1.0).max(1.0) * sy);
        let z = 0.5 * (h.z_min + h.z_max) * z_exaggeration;
        Orbit {
            target_in_scene: DVec3::new(0.5 * (x0 + x1 - 1.0) * sx, 0.5 * (y0 + y1 - 1.0) * sy, z),
            distance_m: 1.1 * w.max(d),
            yaw_deg: 0.0,
            pitch_deg: 35.0,
            fov_x_deg: 60.0,
        }
    }

    /// The orbit that sees `look` from `eye` (local metres, heights as in the file), in the
    /// scene exaggerated `z_exaggeration` times.
    pub fn looking(eye: DVec3, look: DVec3, z_exaggeration: f64) -> Orbit {
        let x = z_exaggeration;
        let (eye, look) = (DVec3::new(eye.x, eye.y, eye.z * x), DVec3::new(look.x, look.y, look.z * x));
        let d = look - eye;
        let distance_m = d.length().max(1e-6);
        Orbit {
            target_in_scene: look,
            distance_m,
            yaw_deg: d.x.atan2(d.y).to_degrees(),
            pitch_deg: (-d.z / distance_m).asin().to_degrees(),
            fov_x_deg: 60.0,
        }
    }

    /// The eye, in scene coordinates.
    pub fn eye_in_scene(&self) -> DVec3 {
        let (yaw, pitch) = (self.yaw_deg.to_radians(), self.pitch_deg.to_radians());
        // Looking along (sin yaw, cos yaw) horizontally, `pitch` down: the eye is behind and up.
        let back = DVec3::new(-yaw.sin() * pitch.cos(), -yaw.cos() * pitch.cos(), pitch.sin());
        self.target_in_scene + back * self.distance_m
    }

    /// The camera for a `width × height` image.
    pub fn camera(&self, width_px: u32, height_px: u32) -> Result<Camera> {
        Camera::new(
            self.eye_in_scene(),
            self.target_in_scene,
            DVec3::Z,
            self.fov_x_deg,
            width_px.max(1),
            height_px.max(1),
        )
    }

    /// Turns by a drag of (`dx`, `dy`) pixels.
    pub fn rotate(&mut self, dx: f64, dy: f64) {
        self.yaw_deg = (self.yaw_deg + 0.3 * dx).rem_euclid(360.0);
        self.pitch_deg = (self.pitch_deg + 0.3 * dy).clamp(2.0, 89.0);
    }

    /// Moves the target by a drag of (`dx`, `dy`) pixels, across the view and along the ground.
    pub fn pan(&mut self, dx: f64, dy: f64, height_px: u32) {
        let metres_per_px = self.distance_m / height_px.max(1) as f64;
        let yaw = self.yaw_deg.to_radians();
        let (right, ahead) = (DVec3::new(yaw.cos(), -yaw.sin(), 0.0), DVec3::new(yaw.sin(), yaw.cos(), 0.0));
        self.target_in_scene += (-dx * right + dy * ahead) * metres_per_px;
    }

    /// Flies: the target, and the eye with it, moves `ahead` and `right` times a tenth of the
    /// distance along the ground (the view's heading), and `up` times that in height.
    pub fn fly(&mut self, ahead: f64, right: f64, up: f64) {
        let step = 0.1 * self.distance_m;
        let yaw = self.yaw_deg.to_radians();
        let (forward, side) = (DVec3::new(yaw.sin(), yaw.cos(), 0.0), DVec3::new(yaw.cos(), -yaw.sin(), 0.0));
        self.target_in_scene += (ahead * forward + right * side + up * DVec3::Z) * step;
    }

    /// Nearer (`steps` > 0) or farther, by 10 % a step.
    pub fn zoom(&mut self, steps: f64) {
        self.distance_m = (self.distance_m * 0.9f64.powf(steps)).clamp(10.0, 1e8);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_orbit_looks_at_its_target_from_its_distance() {
        let o = Orbit {
            target_in_scene: DVec3::new(100.0, 200.0, 50.0),
            distance_m: 1000.0,
            yaw_deg: 90.0,
            pitch_deg: 30.0,
            fov_x_deg: 60.0,
        };
        let eye = o.eye_in_scene();
        assert!(((eye - o.target_in_scene).length() - 1000.0).abs() < 1e-9);
        // Yaw 90°: looking east, so the eye is west of the target, and above it.
        assert!(eye.x < o.target_in_scene.x && (eye.y - 200.0).abs() < 1e-9 && eye.z > 50.0);
        let mut p = o;
        p.rotate(0.0, 1000.0);
        assert_eq!(p.pitch_deg, 89.0, "pitch stays above the horizon and short of the zenith");
        p.zoom(1.0);
        assert!((p.distance_m - 900.0).abs() < 1e-9);
        let mut f = o;
        f.fly(1.0, 0.0, 0.0);
        assert!((f.target_in_scene.x - 200.0).abs() < 1e-9, "flying ahead moves east at yaw 90°");
        let (before, after) = (o.eye_in_scene(), f.eye_in_scene());
        assert!(((after - before).length() - 100.0).abs() < 1e-9, "the eye moves with the target");
        let mut q = o;
        q.pan(0.0, 100.0, 1000);
        assert!((q.target_in_scene.x - 200.0).abs() < 1e-9, "dragging down moves the target ahead (east)");
    }
}
