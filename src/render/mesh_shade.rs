//! CPU reference of the mesh fragment shader (`shaders/mesh.wgsl`: `face_normal`, `shade`, `sky`):
//! the same maths in f64, so a test can check what the GPU computes. Keep the two in step.
//!
//! The material is neutral: a light warm grey on front (counter-clockwise) faces and a darker
//! terracotta on back faces, so the inside of a scanned mesh seen through a hole reads as such.
//! Light: ambient, a headlight (the eye's direction, so every visible face is lit) and a sun.

use glam::DVec3;

use crate::camera::UpAxis;
use crate::mesh::Bounds;
use crate::render::shade::sky_about;

/// Linear RGB of front faces.
pub const FRONT_ALBEDO: DVec3 = DVec3::new(0.72, 0.71, 0.68);
/// Linear RGB of back faces.
pub const BACK_ALBEDO: DVec3 = DVec3::new(0.55, 0.30, 0.22);
/// Weights of the ambient, headlight and sun terms (they sum to 1: a face lit head-on by both is
/// its albedo).
pub const AMBIENT: f64 = 0.18;
pub const HEADLIGHT: f64 = 0.47;
pub const SUN: f64 = 0.35;
/// Fog distance as a multiple of the bounding box's diagonal. Objects are looked at from about a
/// diagonal away, where the terrain's 2 × diagonal would haze them; at 5 × the far side of an
/// orbited object is about 15% fog, a depth cue rather than a veil.
pub const FOG_DISTANCE_OF_DIAGONAL: f64 = 5.0;

/// The shading constants of one mesh (uniform fields of the same names in the shader).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeshShadeParams {
    /// Unit vector up: the sky's zenith.
    pub zenith: DVec3,
    /// Unit vector towards the sun.
    pub sun_dir: DVec3,
    /// Distance at which fog reaches 1 − 1/e, world units.
    pub fog_distance_m: f64,
    pub front_albedo: DVec3,
    pub back_albedo: DVec3,
}

impl MeshShadeParams {
    /// Defaults for a mesh in `bounds` with `up` up: the sun from the "north-west" (azimuth 315°
    /// from the frame's second horizontal axis towards its first, [`UpAxis::frame`]: the terrain's
    /// sun for z up) 45° high, fog at [`FOG_DISTANCE_OF_DIAGONAL`] diagonals.
    pub fn for_bounds(bounds: &Bounds, up: UpAxis) -> MeshShadeParams {
        let (e1, e2, zenith) = up.frame();
        let (az, alt) = (315f64.to_radians(), 45f64.to_radians());
        let sun_dir = e1 * (az.sin() * alt.cos()) + e2 * (az.cos() * alt.cos()) + zenith * alt.sin();
        let diagonal = bounds.diagonal();
        MeshShadeParams {
            zenith,
            sun_dir,
            fog_distance_m: FOG_DISTANCE_OF_DIAGONAL
                * if diagonal > 0.0 && diagonal.is_finite() { diagonal } else { 1.0 },
            front_albedo: FRONT_ALBEDO,
            back_albedo: BACK_ALBEDO,
        }
    }
}

/// Whether triangle `(a, b, c)` shows its front (counter-clockwise) side to an eye at `eye`.
pub fn is_front_facing(a: DVec3, b: DVec3, c: DVec3, eye: DVec3) -> bool {
    (b - a).cross(c - a).dot(eye - a) > 0.0
}

/// Unit normal of triangle `(a, b, c)` turned towards the eye (two-sided lighting), for a point
/// seen along `rel` (point − eye): what the shader gets from the derivatives of `rel`.
pub fn face_normal(a: DVec3, b: DVec3, c: DVec3, rel: DVec3) -> DVec3 {
    let n = (b - a).cross(c - a).normalize();
    if n.dot(rel) > 0.0 {
        -n
    } else {
        n
    }
}

/// Lit and fogged colour (linear RGB) of a face with unit normal `n` (towards the eye) seen along
/// `rel` (point − eye), from its front or back side.
pub fn shade(p: &MeshShadeParams, n: DVec3, rel: DVec3, front: bool) -> DVec3 {
    let albedo = if front { p.front_albedo } else { p.back_albedo };
    let headlight = n.dot(-rel.normalize()).max(0.0);
    let sun = n.dot(p.sun_dir).max(0.0);
    let lit = albedo * (AMBIENT + HEADLIGHT * headlight + SUN * sun);
    let d = rel.length() / p.fog_distance_m;
    let fog = 1.0 - (-d * d).exp();
    lit + (sky_about(rel, p.zenith) - lit) * fog
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_box() -> Bounds {
        Bounds { min: [-0.5; 3], max: [0.5; 3] }
    }

    #[test]
    fn z_up_sun_is_the_terrain_sun() {
        let p = MeshShadeParams::for_bounds(&unit_box(), UpAxis::Z);
        let t = crate::render::shade::ShadeParams::for_terrain([1.0, 1.0], 3, 0.0, 1.0);
        assert!((p.sun_dir - t.sun_dir).length() < 1e-12);
        for up in UpAxis::ALL {
            let p = MeshShadeParams::for_bounds(&unit_box(), up);
            assert!((p.sun_dir.length() - 1.0).abs() < 1e-12);
            assert!((p.sun_dir.dot(up.vector()) - 0.5f64.sqrt()).abs() < 1e-12, "45° high");
        }
    }

    #[test]
    fn normals_face_the_eye_and_faces_know_their_side() {
        let (a, b, c) = (DVec3::ZERO, DVec3::X, DVec3::Y);
        let (above, below) = (DVec3::new(0.2, 0.2, 1.0), DVec3::new(0.2, 0.2, -1.0));
        let centroid = (a + b + c) / 3.0;
        assert_eq!(face_normal(a, b, c, centroid - above), DVec3::Z);
        assert_eq!(face_normal(a, b, c, centroid - below), -DVec3::Z);
        assert!(is_front_facing(a, b, c, above));
        assert!(!is_front_facing(a, b, c, below));
    }

    #[test]
    fn head_on_faces_show_their_albedo_and_fog_fades_to_the_sky() {
        let mut p = MeshShadeParams::for_bounds(&unit_box(), UpAxis::Z);
        // Sun behind the eye: both lights head-on.
        p.sun_dir = DVec3::Z;
        let rel = DVec3::new(0.0, 0.0, -1e-6);
        assert!((shade(&p, DVec3::Z, rel, true) - FRONT_ALBEDO).length() < 1e-9);
        assert!((shade(&p, DVec3::Z, rel, false) - BACK_ALBEDO).length() < 1e-9);
        let far = DVec3::new(1e9, 0.0, -1.0);
        assert!((shade(&p, DVec3::X, far, true) - sky_about(far, DVec3::Z)).length() < 1e-9);
    }
}
