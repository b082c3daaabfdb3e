//! The level-of-detail test every backend shares (Lindstrom & Pascucci 2001, §3.2; the same
//! test decides El-Sana & Chiang's splits): a vertex or node at position p with nested
//! object-space error δ and nested bounding radius r is refined when
//!
//! ```text
//!     (κ δ + r)² > D(p − e)²        κ = w / (2 τ tan(φ/2))
//! ```
//!
//! (e the eye, D the error metric's distance: Euclidean, or projected on the view direction; w
//! the viewport width in pixels, φ the horizontal field of view, τ the tolerance in pixels), and
//! its bounding sphere is not wholly outside a frustum plane. Nested errors and radii make the
//! test monotone (a parent passes whenever a child does), so top-down refinement never cracks.
//! Rounding could break that at the sphere boundaries; callers add a slack to the radius that
//! grows strictly from child to parent (a vertex's level, a node's id) and far exceeds the f64
//! rounding of the test, so it cannot.
//!
//! Culling rides on the same spheres with an inherited plane mask: a sphere known to be inside a
//! plane is not tested against it again below.

use glam::DVec3;

use crate::camera::{Camera, PLANES};
use metric::{ErrorMetric, Isotropic};

pub mod metric;

/// What the test says of one vertex or node.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Test {
    /// The error, seen from the eye, is within the tolerance.
    Inactive,
    /// The error asks for refinement but the sphere is outside the frustum.
    Culled,
    /// Refine; `mask`: the planes the sphere is not yet known to be inside of.
    Active { mask: u8 },
}

/// One frame's test: eye, κ, frustum and metric, in world units.
#[derive(Clone, Debug)]
pub struct Lod<M: ErrorMetric = Isotropic> {
    pub metric: M,
    pub eye: DVec3,
    /// κ: the factor that turns an object-space error into its reach, for the tolerance.
    pub kappa: f64,
    /// Inward normals of the frustum planes through the eye.
    pub normals: [DVec3; PLANES],
}

/// The mask with every plane still to test.
pub const ALL_PLANES: u8 = (1u8 << PLANES) - 1;

impl<M: ErrorMetric> Lod<M> {
    /// The test for `camera` at `tolerance_px` pixels with `metric`.
    pub fn new(camera: &Camera, tolerance_px: f64, metric: M) -> Lod<M> {
        Lod { metric, eye: camera.eye_in_world, kappa: camera.kappa(tolerance_px), normals: camera.frustum_normals() }
    }

    /// The test of a vertex at `rel` = p − e with error `error` and radius `radius` (slack
    /// included), culling against the planes in `mask` when `CULL`.
    #[inline(always)]
    pub fn test<const CULL: bool>(&self, rel: DVec3, error: f64, radius: f64, mask: u8) -> Test {
        let reach = self.kappa * error + radius;
        // Written so that a NaN anywhere (a corrupt or missing record) reads as inactive.
        let active = reach * reach > self.metric.distance_sq(rel);
        if !active {
            return Test::Inactive;
        }
        let mut mask = mask;
        if CULL && mask != 0 {
            for (k, n) in self.normals.iter().enumerate() {
                let bit = 1u8 << k;
                if mask & bit != 0 {
                    let s = n.dot(rel);
                    if s < -radius {
                        return Test::Culled;
                    }
                    if s > radius {
                        mask &= !bit;
                    }
                }
            }
        }
        Test::Active { mask }
    }

    /// Whether a sphere at `position` with `error` and `radius` is refined, culled against every
    /// plane.
    #[inline]
    pub fn wants(&self, position: DVec3, error: f64, radius: f64) -> bool {
        matches!(self.test::<true>(position - self.eye, error, radius, ALL_PLANES), Test::Active { .. })
    }

    /// Whether the un-nested error `error_m` at `p` projects over the tolerance (`κ δ > D`).
    pub fn error_projects_over(&self, p: DVec3, error_m: f64) -> bool {
        let reach = self.kappa * error_m;
        reach * reach > self.metric.distance_sq(p - self.eye)
    }

    /// Whether a point lies inside the frustum.
    pub fn point_in_frustum(&self, p: DVec3) -> bool {
        self.normals.iter().all(|n| n.dot(p - self.eye) >= 0.0)
    }
}

/// The slack per step of depth (a vertex level, a node id) for a scene whose coordinates reach
/// `scale` (metres or mesh units): 2⁻⁴⁰ of it, about 10⁴ times the f64 rounding of the test and
/// still below a micrometre on a 100 km terrain.
pub fn margin_for_scale(scale: f64) -> f64 {
    scale.max(1.0) * (2f64).powi(-40)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> Camera {
        Camera::new(DVec3::new(0.0, -100.0, 10.0), DVec3::new(0.0, 0.0, 0.0), DVec3::Z, 60.0, 640, 480).unwrap()
    }

    #[test]
    fn the_reach_against_the_distance_decides() {
        let lod = Lod::new(&camera(), 1.0, Isotropic);
        let p = DVec3::new(0.0, 0.0, 0.0);
        let d = (p - lod.eye).length();
        // Reach just over and just under the distance, with no error: the radius alone.
        assert!(lod.wants(p, 0.0, d * 1.000_001));
        assert!(!lod.wants(p, 0.0, d * 0.999_999));
        // An error of δ reaches κδ.
        assert!(lod.wants(p, d / lod.kappa * 1.01, 0.0));
        assert!(!lod.wants(p, d / lod.kappa * 0.99, 0.0));
        assert!(!lod.wants(p, f64::NAN, d * 2.0), "NaN is never active");
        assert!(lod.error_projects_over(p, d / lod.kappa * 1.01));
    }

    #[test]
    fn spheres_behind_the_eye_are_culled_and_inside_ones_drop_their_planes() {
        let lod = Lod::new(&camera(), 1.0, Isotropic);
        let behind = DVec3::new(0.0, -200.0, 10.0) - lod.eye;
        assert_eq!(lod.test::<true>(behind, 1e9, 1.0, ALL_PLANES), Test::Culled);
        assert!(matches!(lod.test::<false>(behind, 1e9, 1.0, ALL_PLANES), Test::Active { .. }), "no culling");
        let ahead = DVec3::new(0.0, 0.0, 10.0) - lod.eye;
        assert_eq!(
            lod.test::<true>(ahead, 1e9, 1.0, ALL_PLANES),
            Test::Active { mask: 0 },
            "well inside: no planes left"
        );
        assert!(lod.point_in_frustum(DVec3::new(0.0, 0.0, 10.0)));
        assert!(!lod.point_in_frustum(DVec3::new(0.0, -200.0, 10.0)));
    }
}
