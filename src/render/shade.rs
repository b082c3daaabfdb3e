//! CPU reference of the terrain fragment shader (`shaders/terrain.wgsl`: `surface_at`, `ramp`,
//! `sky`, `shade`): the same maths in f64, so a test can check what the GPU computes pixel by
//! pixel. Keep the two in step.

use glam::DVec3;

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
}

impl ShadeParams {
    /// Defaults for a terrain: sun from the north-west 45° up (the cartographic convention), fog
    /// at twice the terrain's diagonal so the far side stays visible.
    pub fn for_terrain(spacing_m: [f64; 2], posts: u32, z_min: f64, z_max: f64) -> ShadeParams {
        let side = (posts.max(2) - 1) as f64;
        let diagonal_m = ((side * spacing_m[0]).powi(2) + (side * spacing_m[1]).powi(2)).sqrt();
        let (az, alt) = (315f64.to_radians(), 45f64.to_radians());
        // Azimuth clockwise from north: x = sin, y = cos.
        let sun_dir = DVec3::new(az.sin() * alt.cos(), az.cos() * alt.cos(), alt.sin());
        ShadeParams {
            spacing_m,
            posts,
            z_min,
            z_land_lo: z_min.max(0.0),
            z_max,
            fog_distance_m: 2.0 * diagonal_m.max(1.0),
            sun_dir,
        }
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
    let dz_dx = (height(x1, y) - height(x0, y)) / ((x1 - x0) as f64 * p.spacing_m[0]);
    let dz_dy = (height(x, y1) - height(x, y0)) / ((y1 - y0) as f64 * p.spacing_m[1]);
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

/// Hypsometric tint (linear RGB): water below 0 m, land from `z_land_lo` to `z_max`.
pub fn ramp(p: &ShadeParams, z_m: f64) -> DVec3 {
    let c = |r, g, b| DVec3::new(r, g, b);
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
}
