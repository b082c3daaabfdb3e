//! A pinhole camera in world space and its view frustum.
//!
//! World space is metres with the origin at the grid's south-west corner, x east, y north, z up
//! (as `relief info` reports extents). The frustum is kept as planes through the eye with inward
//! unit normals, so a point's signed distance to a plane is `normal · (p − eye)`; refinement culls
//! bounding spheres against them (`relief::refine`).

use glam::DVec3;

use crate::error::{Error, Result};

/// Frustum planes: near (through the eye), left, right, bottom, top. No far plane: terrain is
/// drawn to the horizon.
pub const PLANES: usize = 5;

/// A perspective camera: where it is, where it looks, and the image it makes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub eye_in_world: DVec3,
    pub look_at_world: DVec3,
    pub up_in_world: DVec3,
    /// Horizontal field of view, degrees.
    pub fov_x_deg: f64,
    pub width_px: u32,
    pub height_px: u32,
}

impl Camera {
    /// Validates and builds a camera: finite coordinates, `look ≠ eye`, `up` not parallel to the
    /// view direction, `0 < fov < 180`, non-empty image.
    pub fn new(eye: DVec3, look: DVec3, up: DVec3, fov_x_deg: f64, width_px: u32, height_px: u32) -> Result<Camera> {
        let bad = |m: String| Err(Error::InvalidArgument(m));
        if !(eye.is_finite() && look.is_finite() && up.is_finite()) {
            return bad("camera eye, look and up must be finite numbers".into());
        }
        let forward = look - eye;
        if forward.length_squared() == 0.0 {
            return bad(format!("camera look point equals the eye ({eye})"));
        }
        if up.length_squared() == 0.0 || forward.normalize().cross(up.normalize()).length() < 1e-9 {
            return bad(format!("camera up {up} is parallel to the view direction {}", forward.normalize()));
        }
        if !(fov_x_deg > 0.0 && fov_x_deg < 180.0) {
            return bad(format!("field of view must be between 0 and 180 degrees, got {fov_x_deg}"));
        }
        if width_px == 0 || height_px == 0 {
            return bad(format!("image size must be at least 1 x 1 pixels, got {width_px} x {height_px}"));
        }
        Ok(Camera { eye_in_world: eye, look_at_world: look, up_in_world: up, fov_x_deg, width_px, height_px })
    }

    /// Unit view direction.
    pub fn forward(&self) -> DVec3 {
        (self.look_at_world - self.eye_in_world).normalize()
    }

    /// Orthonormal camera basis `(right, up, forward)`.
    pub fn basis(&self) -> (DVec3, DVec3, DVec3) {
        let f = self.forward();
        let r = f.cross(self.up_in_world).normalize();
        let u = r.cross(f);
        (r, u, f)
    }

    /// Vertical field of view in degrees, from the horizontal one and the aspect ratio.
    pub fn fov_y_deg(&self) -> f64 {
        let tan_x = (self.fov_x_deg.to_radians() / 2.0).tan();
        (2.0 * (tan_x * self.height_px as f64 / self.width_px as f64).atan()).to_degrees()
    }

    /// κ = w / (2 τ tan(φ/2)): an object-space error δ at distance d projects to δ·κ/d·τ pixels, so
    /// it exceeds τ pixels exactly when κ δ > d.
    pub fn kappa(&self, tolerance_px: f64) -> f64 {
        self.width_px as f64 / (2.0 * tolerance_px * (self.fov_x_deg.to_radians() / 2.0).tan())
    }

    /// Clip space from eye-relative world space (world − eye), in f32 as the GPU takes it:
    /// rotation into the view, then a reversed-z perspective (1 at `near_m`, 0 at infinity) with
    /// no far plane. Eye-relative input keeps precision near the eye on large worlds.
    pub fn clip_from_rel(&self, near_m: f64) -> glam::Mat4 {
        let (_, up, forward) = self.basis();
        let view = glam::camera::rh::view::look_to_mat4(glam::Vec3::ZERO, forward.as_vec3(), up.as_vec3());
        let aspect = self.width_px as f32 / self.height_px as f32;
        let proj = glam::camera::rh::proj::directx::perspective_infinite_reverse(
            self.fov_y_deg().to_radians() as f32,
            aspect,
            near_m as f32,
        );
        proj * view
    }

    /// Inward unit normals of the frustum planes (see [`PLANES`]); every plane passes through the
    /// eye, so a point is inside iff `normal · (p − eye) ≥ 0` for all of them.
    pub fn frustum_normals(&self) -> [DVec3; PLANES] {
        let (r, u, f) = self.basis();
        let ax = self.fov_x_deg.to_radians() / 2.0;
        let ay = self.fov_y_deg().to_radians() / 2.0;
        [
            f,
            r * ax.cos() + f * ax.sin(),
            -r * ax.cos() + f * ax.sin(),
            u * ay.cos() + f * ay.sin(),
            -u * ay.cos() + f * ay.sin(),
        ]
    }
}

/// Which world axis points up: +z for terrains (x east, y north), commonly +y for scanned
/// objects and OBJ/glTF files. Fixes the sky's zenith, the sun, the fly camera's horizon and the
/// orbit's axis.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum UpAxis {
    X,
    Y,
    #[default]
    Z,
}

impl UpAxis {
    pub const ALL: [UpAxis; 3] = [UpAxis::X, UpAxis::Y, UpAxis::Z];

    pub fn name(self) -> &'static str {
        match self {
            UpAxis::X => "x",
            UpAxis::Y => "y",
            UpAxis::Z => "z",
        }
    }

    pub fn from_name(name: &str) -> Option<UpAxis> {
        UpAxis::ALL.into_iter().find(|a| a.name() == name)
    }

    /// Index of the axis (0, 1, 2).
    pub fn index(self) -> usize {
        self as usize
    }

    /// A right-handed frame `(e1, e2, up)`: the two horizontal axes follow `up` cyclically
    /// (z up: x, y; y up: z, x; x up: y, z), so for z up e1 is east and e2 north, the terrain's
    /// own convention.
    pub fn frame(self) -> (DVec3, DVec3, DVec3) {
        let axes = [DVec3::X, DVec3::Y, DVec3::Z];
        let k = self.index();
        (axes[(k + 1) % 3], axes[(k + 2) % 3], axes[k])
    }

    pub fn vector(self) -> DVec3 {
        self.frame().2
    }

    /// The up axis of a box by default: a flat box (its smallest extent at most half the middle
    /// one, such as a terrain) stands on its smallest axis; otherwise +y, the convention of the
    /// Stanford scans and of OBJ/glTF.
    pub fn guess(extent: [f64; 3]) -> UpAxis {
        let mut order = [0, 1, 2];
        order.sort_by(|&a, &b| extent[a].total_cmp(&extent[b]));
        if extent[order[0]] <= 0.5 * extent[order[1]] {
            UpAxis::ALL[order[0]]
        } else {
            UpAxis::Y
        }
    }
}

impl Camera {
    /// The frustum's edges out to `distance_m` along the view direction, as line segments (eye to
    /// the four corners, then the far rectangle): what `relief fly` draws around a frozen view.
    pub fn frustum_outline(&self, distance_m: f64) -> [[DVec3; 2]; 8] {
        let (r, u, f) = self.basis();
        let tx = (self.fov_x_deg.to_radians() / 2.0).tan() * distance_m;
        let ty = (self.fov_y_deg().to_radians() / 2.0).tan() * distance_m;
        let e = self.eye_in_world;
        let c = f * distance_m;
        let corners =
            [c + r * tx + u * ty, c - r * tx + u * ty, c - r * tx - u * ty, c + r * tx - u * ty].map(|v| e + v);
        let mut lines = [[e, e]; 8];
        for k in 0..4 {
            lines[k] = [e, corners[k]];
            lines[4 + k] = [corners[k], corners[(k + 1) % 4]];
        }
        lines
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frustum_outline_runs_along_the_side_planes() {
        let c = cam();
        let n = c.frustum_normals();
        let lines = c.frustum_outline(50.0);
        // Each corner ray lies on two side planes (and inside the others).
        for [a, b] in &lines[..4] {
            assert_eq!(*a, c.eye_in_world);
            let d: Vec<f64> = n[1..].iter().map(|n| n.dot(*b - c.eye_in_world)).collect();
            assert_eq!(d.iter().filter(|x| x.abs() < 1e-9).count(), 2, "{d:?}");
            assert!(d.iter().all(|x| *x > -1e-9));
            assert!(((*b - c.eye_in_world).dot(c.forward()) - 50.0).abs() < 1e-9);
        }
        // The far rectangle is closed.
        assert_eq!(lines[7][1], lines[4][0]);
    }

    fn cam() -> Camera {
        Camera::new(DVec3::new(0.0, 0.0, 10.0), DVec3::new(100.0, 0.0, 10.0), DVec3::Z, 90.0, 200, 100).unwrap()
    }

    #[test]
    fn frustum_contains_what_projects_into_the_image() {
        let c = cam();
        let n = c.frustum_normals();
        let inside = |p: DVec3| n.iter().all(|n| n.dot(p - c.eye_in_world) >= 0.0);
        // Forward along +x; 90° horizontal → ±45°; aspect 2:1 → tan(ay) = 0.5.
        assert!(inside(DVec3::new(10.0, 0.0, 10.0)));
        assert!(inside(DVec3::new(10.0, 9.9, 10.0)));
        assert!(!inside(DVec3::new(10.0, 10.1, 10.0)));
        assert!(!inside(DVec3::new(10.0, -10.1, 10.0)));
        assert!(inside(DVec3::new(10.0, 0.0, 14.9)));
        assert!(!inside(DVec3::new(10.0, 0.0, 15.1)));
        assert!(!inside(DVec3::new(-1.0, 0.0, 10.0)));
        assert!((c.fov_y_deg() - 2.0 * 0.5f64.atan().to_degrees()).abs() < 1e-9);
        for p in n {
            assert!((p.length() - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn kappa_matches_the_projection() {
        // 90°, 200 px wide: at distance d, 1 m spans 100/d px; δ = 1 m is 1 px at d = 100.
        let c = cam();
        assert!((c.kappa(1.0) - 100.0).abs() < 1e-9);
        assert!((c.kappa(2.0) - 50.0).abs() < 1e-9);
    }

    #[test]
    fn up_frames_are_right_handed_and_guesses_follow_the_box() {
        for a in UpAxis::ALL {
            let (e1, e2, up) = a.frame();
            assert_eq!(e1.cross(e2), up, "{a:?}");
            assert_eq!(UpAxis::from_name(a.name()), Some(a));
        }
        assert_eq!(UpAxis::Z.frame(), (DVec3::X, DVec3::Y, DVec3::Z));
        assert_eq!(UpAxis::guess([50e3, 40e3, 3e3]), UpAxis::Z, "a terrain");
        assert_eq!(UpAxis::guess([1.0, 0.99, 0.77]), UpAxis::Y, "the bunny's box");
        assert_eq!(UpAxis::guess([1.0, 0.1, 1.0]), UpAxis::Y, "a flat box on y");
        assert_eq!(UpAxis::guess([0.1, 1.0, 1.0]), UpAxis::X);
    }

    #[test]
    fn rejects_degenerate_cameras() {
        let e = DVec3::ZERO;
        assert!(Camera::new(e, e, DVec3::Z, 60.0, 10, 10).is_err());
        assert!(Camera::new(e, DVec3::Z, DVec3::Z, 60.0, 10, 10).is_err());
        assert!(Camera::new(e, DVec3::X, DVec3::Z, 180.0, 10, 10).is_err());
        assert!(Camera::new(e, DVec3::X, DVec3::Z, 60.0, 0, 10).is_err());
        assert!(Camera::new(DVec3::new(f64::NAN, 0.0, 0.0), DVec3::X, DVec3::Z, 60.0, 10, 10).is_err());
    }
}
