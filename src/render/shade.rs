//! CPU reference of the terrain fragment shader (`shaders/terrain.wgsl`: `surface_at`, `ramp`,
//! `sky`, `shade`): the same maths in f64, so a test can check what the GPU computes pixel by
//! pixel. Keep the two in step.

use glam::DVec3;

/// The colour ramp a terrain's heights are tinted with.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Ramp {
    /// Hypsometric tints: blue water below 0 m, green lowland to brown, grey and white peaks.
    #[default]
    Hypsometric,
    /// Viridis (perceptually uniform, colour-blind safe) from the lowest to the highest point,
    /// water included.
    Viridis,
    /// No tint: a plain grey hillshade.
    Grey,
}

impl Ramp {
    /// The shader's code (`Frame.looks.y`).
    pub fn code(self) -> u32 {
        match self {
            Ramp::Hypsometric => 0,
            Ramp::Viridis => 1,
            Ramp::Grey => 2,
        }
    }
}

/// How a terrain is drawn, chosen at render time (nothing of it is in the file): the colour ramp,
/// where the sun stands, and the vertical exaggeration of the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Look {
    pub ramp: Ramp,
    /// Clockwise from north, degrees.
    pub sun_azimuth_deg: f64,
    /// Above the horizon, degrees (0..=90).
    pub sun_altitude_deg: f64,
    /// Heights are drawn this many times as high (≥ 1); cameras and paths scale with them.
    pub z_exaggeration: f64,
}

impl Default for Look {
    fn default() -> Look {
        Look::DEFAULT
    }
}

/// The largest vertical exaggeration accepted.
pub const MAX_Z_EXAGGERATION: f64 = 1000.0;

impl Look {
    /// The cartographic convention: hypsometric tints, sun from the north-west 45° up; no
    /// exaggeration.
    pub const DEFAULT: Look =
        Look { ramp: Ramp::Hypsometric, sun_azimuth_deg: 315.0, sun_altitude_deg: 45.0, z_exaggeration: 1.0 };

    /// The unit vector towards the sun (x east, y north, z up).
    pub fn sun_dir(&self) -> DVec3 {
        let (az, alt) = (self.sun_azimuth_deg.to_radians(), self.sun_altitude_deg.to_radians());
        // Azimuth clockwise from north: x = sin, y = cos.
        DVec3::new(az.sin() * alt.cos(), az.cos() * alt.cos(), alt.sin())
    }

    /// `camera` (in the terrain's metres) in the exaggerated scene: heights of the eye and of the
    /// point looked at scale with the terrain's.
    pub fn scene_camera(&self, camera: &crate::camera::Camera) -> crate::camera::Camera {
        let x = self.z_exaggeration;
        let scale = |p: DVec3| DVec3::new(p.x, p.y, p.z * x);
        crate::camera::Camera {
            eye_in_world: scale(camera.eye_in_world),
            look_at_world: scale(camera.look_at_world),
            ..*camera
        }
    }

    /// Checks the values a user gave; the message names the option.
    pub fn validate(&self) -> Result<(), String> {
        let x = self.z_exaggeration;
        if !(x.is_finite() && (1.0..=MAX_Z_EXAGGERATION).contains(&x)) {
            return Err(format!(
                "--z-exaggeration must be between 1 and {MAX_Z_EXAGGERATION} (got {x}); flatten a terrain at \
                 conversion with --z-scale"
            ));
        }
        if !(self.sun_altitude_deg.is_finite() && (0.0..=90.0).contains(&self.sun_altitude_deg)) {
            return Err(format!("--sun-altitude must be 0 to 90 degrees (got {})", self.sun_altitude_deg));
        }
        if !self.sun_azimuth_deg.is_finite() {
            return Err(format!("--sun-azimuth must be a number of degrees (got {})", self.sun_azimuth_deg));
        }
        Ok(())
    }
}

/// The shading constants of one terrain (uniform fields of the same names in the shader).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShadeParams {
    /// Metres per post in x and y.
    pub spacing_m: [f64; 2],
    pub posts: u32,
    /// Deepest point (water ramp), lowest land (land ramp start), highest point, metres.
    pub z_min: f64,
    pub z_land_lo: f64,
    pub z_max: f64,
    /// Distance at which fog reaches 1 − 1/e, metres.
    pub fog_distance_m: f64,
    /// Unit vector towards the sun.
    pub sun_dir: DVec3,
    pub ramp: Ramp,
    /// Heights are drawn (and normals computed) this many times as high.
    pub z_exaggeration: f64,
}

impl ShadeParams {
    /// Defaults for a terrain: sun from the north-west 45° up (the cartographic convention), fog
    /// at twice the terrain's diagonal so the far side stays visible.
    pub fn for_terrain(spacing_m: [f64; 2], posts: u32, z_min: f64, z_max: f64) -> ShadeParams {
        let side = (posts.max(2) - 1) as f64;
        let diagonal_m = ((side * spacing_m[0]).powi(2) + (side * spacing_m[1]).powi(2)).sqrt();
        let look = Look::default();
        ShadeParams {
            spacing_m,
            posts,
            z_min,
            z_land_lo: z_min.max(0.0),
            z_max,
            fog_distance_m: 2.0 * diagonal_m.max(1.0),
            sun_dir: look.sun_dir(),
            ramp: look.ramp,
            z_exaggeration: look.z_exaggeration,
        }
    }

    /// These constants drawn with `look`.
    pub fn with_look(self, look: &Look) -> ShadeParams {
        ShadeParams { sun_dir: look.sun_dir(), ramp: look.ramp, z_exaggeration: look.z_exaggeration, ..self }
    }
}

/// Height and unit normal of the full-resolution bilinear surface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Surface {
    pub height_m: f64,
    pub normal: DVec3,
}

fn mix(a: f64, b: f64, t: f64) -> f64 {
    a + (b - a) * t
}

fn mix3(a: DVec3, b: DVec3, t: f64) -> DVec3 {
    a + (b - a) * t
}

/// Unit normal at post `(x, y)` by central differences (one-sided at the border).
pub fn post_normal(p: &ShadeParams, height: &impl Fn(i32, i32) -> f64, x: i32, y: i32) -> DVec3 {
    let last = p.posts as i32 - 1;
    let (x0, x1) = ((x - 1).max(0), (x + 1).min(last));
    let (y0, y1) = ((y - 1).max(0), (y + 1).min(last));
    // Of the exaggerated surface: slopes scale with the heights.
    let dz_dx = p.z_exaggeration * (height(x1, y) - height(x0, y)) / ((x1 - x0) as f64 * p.spacing_m[0]);
    let dz_dy = p.z_exaggeration * (height(x, y1) - height(x, y0)) / ((y1 - y0) as f64 * p.spacing_m[1]);
    DVec3::new(-dz_dx, -dz_dy, 1.0).normalize()
}

/// The surface at grid position `grid` (posts): bilinear heights and bilinear post normals.
/// `height(x, y)` must clamp to the grid as the shader does.
pub fn surface_at(p: &ShadeParams, height: &impl Fn(i32, i32) -> f64, grid: [f64; 2]) -> Surface {
    let last = (p.posts - 1) as f64;
    let g = [grid[0].clamp(0.0, last), grid[1].clamp(0.0, last)];
    let base = [g[0].floor().min(last - 1.0), g[1].floor().min(last - 1.0)];
    let f = [g[0] - base[0], g[1] - base[1]];
    let (x, y) = (base[0] as i32, base[1] as i32);
    let h = mix(mix(height(x, y), height(x + 1, y), f[0]), mix(height(x, y + 1), height(x + 1, y + 1), f[0]), f[1]);
    let n = mix3(
        mix3(post_normal(p, height, x, y), post_normal(p, height, x + 1, y), f[0]),
        mix3(post_normal(p, height, x, y + 1), post_normal(p, height, x + 1, y + 1), f[0]),
        f[1],
    );
    Surface { height_m: h, normal: n.normalize() }
}

/// Viridis at 9 stops (matplotlib's, sRGB decoded to linear), interpolated linearly.
const VIRIDIS: [(f64, [f64; 3]); 9] = [
    (0.000, [0.057805, 0.000304, 0.088656]),
    (0.125, [0.064803, 0.021219, 0.187821]),
    (0.250, [0.048172, 0.066626, 0.250158]),
    (0.375, [0.030713, 0.138432, 0.270498]),
    (0.500, [0.019382, 0.223228, 0.270498]),
    (0.625, [0.013702, 0.341914, 0.250158]),
    (0.750, [0.035601, 0.473531, 0.191202]),
    (0.875, [0.155926, 0.617207, 0.097587]),
    (1.000, [0.982251, 0.799103, 0.018500]),
];

/// The albedo of the grey hillshade.
pub const GREY: f64 = 0.8;

/// The tint of height `z_m` (linear RGB) under the ramp of `p`: hypsometric (water below 0 m,
/// land from `z_land_lo` to `z_max`), viridis over `z_min..z_max`, or grey.
pub fn ramp(p: &ShadeParams, z_m: f64) -> DVec3 {
    let c = |r, g, b| DVec3::new(r, g, b);
    match p.ramp {
        Ramp::Hypsometric => {}
        Ramp::Grey => return DVec3::splat(GREY),
        Ramp::Viridis => {
            let t = ((z_m - p.z_min) / (p.z_max - p.z_min).max(1.0)).clamp(0.0, 1.0);
            let k = ((t * 8.0).floor() as usize).min(7);
            let (a, b) = (VIRIDIS[k], VIRIDIS[k + 1]);
            return mix3(DVec3::from(a.1), DVec3::from(b.1), (t - a.0) * 8.0);
        }
    }
    if z_m < 0.0 {
        let t = (z_m / p.z_min.min(-1.0)).clamp(0.0, 1.0);
        return mix3(c(0.30, 0.55, 0.75), c(0.02, 0.07, 0.25), t);
    }
    let t = ((z_m - p.z_land_lo) / (p.z_max - p.z_land_lo).max(1.0)).clamp(0.0, 1.0);
    let stops = [
        (0.0, c(0.13, 0.32, 0.10)),
        (0.3, c(0.45, 0.50, 0.22)),
        (0.6, c(0.42, 0.30, 0.17)),
        (0.85, c(0.55, 0.53, 0.52)),
        (1.0, c(0.95, 0.95, 0.97)),
    ];
    for w in stops.windows(2) {
        if t < w[1].0 || w[1].0 == 1.0 {
            return mix3(w[0].1, w[1].1, (t - w[0].0) / (w[1].0 - w[0].0));
        }
    }
    stops[4].1
}

/// Sky colour along an eye-relative direction.
pub fn sky(dir: DVec3) -> DVec3 {
    sky_about(dir, DVec3::Z)
}

/// Sky colour along an eye-relative direction with `zenith` (a unit vector) up: the mesh
/// renderer's sky (`shaders/mesh.wgsl`), the terrain's with `zenith` = +z.
pub fn sky_about(dir: DVec3, zenith: DVec3) -> DVec3 {
    let up = dir.normalize().dot(zenith).clamp(-1.0, 1.0);
    let horizon = DVec3::new(0.72, 0.80, 0.88);
    if up < 0.0 {
        return mix3(horizon, DVec3::new(0.45, 0.50, 0.55), (-up * 4.0).min(1.0));
    }
    mix3(horizon, DVec3::new(0.16, 0.34, 0.68), up.powf(0.6))
}

/// Lit, tinted and fogged colour of `s` seen along `rel` (world − eye, metres), linear RGB.
pub fn shade(p: &ShadeParams, s: Surface, rel: DVec3) -> DVec3 {
    let lambert = s.normal.dot(p.sun_dir).max(0.0);
    let lit = ramp(p, s.height_m) * (0.30 + 0.70 * lambert);
    let d = rel.length() / p.fog_distance_m;
    let fog = 1.0 - (-d * d).exp();
    mix3(lit, sky(rel), fog)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_plane_has_its_own_normal_everywhere() {
        // z = 0.5 x_m − 0.25 y_m on 10 m posts: normal ∝ (−0.5, 0.25, 1).
        let p = ShadeParams::for_terrain([10.0, 10.0], 9, 0.0, 100.0);
        let h = |x: i32, y: i32| {
            let (x, y) = (x.clamp(0, 8), y.clamp(0, 8));
            0.5 * 10.0 * x as f64 - 0.25 * 10.0 * y as f64
        };
        let want = DVec3::new(-0.5, 0.25, 1.0).normalize();
        for g in [[0.0, 0.0], [3.3, 7.9], [8.0, 8.0], [4.5, 0.25]] {
            let s = surface_at(&p, &h, g);
            assert!((s.normal - want).length() < 1e-12, "{g:?}: {:?}", s.normal);
            assert!((s.height_m - (5.0 * g[0] - 2.5 * g[1])).abs() < 1e-9);
        }
    }

    #[test]
    fn ramp_is_continuous_and_separates_water_from_land() {
        let p = ShadeParams::for_terrain([1.0, 1.0], 3, -4000.0, 3000.0);
        let mut prev = ramp(&p, 0.0);
        for k in 1..=3000 {
            let c = ramp(&p, k as f64);
            assert!((c - prev).length() < 0.01, "jump at {k} m");
            prev = c;
        }
        assert!(ramp(&p, -1.0).z > ramp(&p, -1.0).x, "water is blue");
        assert!(ramp(&p, -3999.0).length() < ramp(&p, -10.0).length(), "deep water is darker");
        assert_eq!(ramp(&p, 1e9), ramp(&p, 3000.0));
    }

    #[test]
    fn fog_fades_to_the_sky() {
        let p = ShadeParams::for_terrain([30.0, 30.0], 1025, 0.0, 1000.0);
        let s = Surface { height_m: 500.0, normal: DVec3::Z };
        let far = DVec3::new(1e9, 0.0, -1.0);
        assert!((shade(&p, s, far) - sky(far)).length() < 1e-9);
        let near = DVec3::new(1.0, 0.0, -1.0);
        let lit = ramp(&p, 500.0) * (0.30 + 0.70 * p.sun_dir.z);
        assert!((shade(&p, s, near) - lit).length() < 1e-6);
    }

    #[test]
    fn viridis_and_grey_ramps() {
        let p = ShadeParams::for_terrain([1.0, 1.0], 3, -100.0, 900.0)
            .with_look(&Look { ramp: Ramp::Viridis, ..Look::DEFAULT });
        assert!((ramp(&p, -100.0) - DVec3::from(VIRIDIS[0].1)).length() < 1e-12);
        assert!((ramp(&p, 900.0) - DVec3::from(VIRIDIS[8].1)).length() < 1e-12);
        assert!((ramp(&p, 400.0) - DVec3::from(VIRIDIS[4].1)).length() < 1e-12, "the middle stop at the middle");
        let mut prev = ramp(&p, -100.0);
        for k in -99..=900 {
            let c = ramp(&p, k as f64);
            assert!((c - prev).length() < 0.01, "jump at {k} m");
            prev = c;
        }
        let g = p.with_look(&Look { ramp: Ramp::Grey, ..Look::DEFAULT });
        assert_eq!((ramp(&g, -50.0), ramp(&g, 800.0)), (DVec3::splat(GREY), DVec3::splat(GREY)));
    }

    #[test]
    fn looks_are_checked_and_the_sun_stands_where_asked() {
        assert!(Look::DEFAULT.validate().is_ok());
        let bad = |l: Look| l.validate().unwrap_err();
        assert!(bad(Look { z_exaggeration: 0.5, ..Look::DEFAULT }).starts_with("--z-exaggeration must be between 1"));
        assert!(bad(Look { z_exaggeration: f64::NAN, ..Look::DEFAULT }).starts_with("--z-exaggeration"));
        assert!(bad(Look { sun_altitude_deg: 91.0, ..Look::DEFAULT }).starts_with("--sun-altitude"));
        assert!(bad(Look { sun_azimuth_deg: f64::INFINITY, ..Look::DEFAULT }).starts_with("--sun-azimuth"));
        // From the south-east, 30° up: pointing east-south and up.
        let d = Look { sun_azimuth_deg: 135.0, sun_altitude_deg: 30.0, ..Look::DEFAULT }.sun_dir();
        assert!((d.length() - 1.0).abs() < 1e-12 && d.x > 0.0 && d.y < 0.0 && (d.z - 0.5).abs() < 1e-12);
        // Exaggeration steepens the normals of a slope.
        let h = |x: i32, _y: i32| 10.0 * x.clamp(0, 8) as f64;
        let p = ShadeParams::for_terrain([10.0, 10.0], 9, 0.0, 80.0);
        let n1 = post_normal(&p, &h, 4, 4);
        let n3 = post_normal(&p.with_look(&Look { z_exaggeration: 3.0, ..Look::DEFAULT }), &h, 4, 4);
        assert!((n1 - DVec3::new(-1.0, 0.0, 1.0).normalize()).length() < 1e-12);
        assert!((n3 - DVec3::new(-3.0, 0.0, 1.0).normalize()).length() < 1e-12);
        let scene = Look { z_exaggeration: 3.0, ..Look::DEFAULT }.scene_camera(
            &crate::camera::Camera::new(DVec3::new(1.0, 2.0, 3.0), DVec3::new(4.0, 5.0, -1.0), DVec3::Z, 60.0, 10, 10)
                .unwrap(),
        );
        assert_eq!((scene.eye_in_world, scene.look_at_world), (DVec3::new(1.0, 2.0, 9.0), DVec3::new(4.0, 5.0, -3.0)));
    }
}
