//! Screen-space error metrics for refinement (Lindstrom & Pascucci 2001, §4).
//!
//! A vertex with nested object-space error δ and nested bounding radius r, at `rel = p − eye`, is
//! active iff `(κ δ + r)² > D(rel)`, where κ comes from the camera and tolerance
//! ([`crate::camera::Camera::kappa`]) and `D` is the metric's squared distance. Any `D` whose square
//! root is 1-Lipschitz in `p` keeps the test monotone under nesting (a parent is active whenever a
//! child is, because the child's sphere lies inside the parent's), so refinement stays crack-free.
//! A new metric is therefore one function.

use glam::DVec3;

/// The squared distance an error metric compares against the reach `κ δ + r`.
pub trait ErrorMetric: Clone + Send + Sync + 'static {
    /// Whether [`Self::distance_sq`] is `rel_m.length_squared()`, which refinement then evaluates
    /// for two vertices at once (with the same operations, so the same result).
    const EUCLIDEAN: bool = false;
    /// Squared distance, m², for a vertex at `rel_m = p − eye`. `sqrt` of it must be 1-Lipschitz.
    fn distance_sq(&self, rel_m: DVec3) -> f64;
}

/// The paper's default: Euclidean distance to the eye, independent of the view direction.
#[derive(Clone, Copy, Debug, Default)]
pub struct Isotropic;

impl ErrorMetric for Isotropic {
    const EUCLIDEAN: bool = true;
    #[inline(always)]
    fn distance_sq(&self, rel_m: DVec3) -> f64 {
        rel_m.length_squared()
    }
}

/// Perspective-projected: distance along the view axis (|depth|), which is what a planar
/// projection divides by. Refines more towards the image's edges than [`Isotropic`], exactly as
/// much as the projection magnifies there.
#[derive(Clone, Copy, Debug)]
pub struct Projected {
    pub forward: DVec3,
}

impl ErrorMetric for Projected {
    #[inline(always)]
    fn distance_sq(&self, rel_m: DVec3) -> f64 {
        let depth = rel_m.dot(self.forward);
        depth * depth
    }
}

/// The metrics available by name (command line, JSON).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum MetricKind {
    #[default]
    Isotropic,
    Projected,
}

impl MetricKind {
    pub const ALL: [MetricKind; 2] = [MetricKind::Isotropic, MetricKind::Projected];

    pub fn name(self) -> &'static str {
        match self {
            MetricKind::Isotropic => "isotropic",
            MetricKind::Projected => "projected",
        }
    }

    pub fn from_name(name: &str) -> Option<MetricKind> {
        MetricKind::ALL.into_iter().find(|k| k.name() == name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Monotonicity under nesting needs sqrt(D) to be 1-Lipschitz: |√D(a) − √D(b)| ≤ ‖a − b‖.
    #[test]
    fn distances_are_one_lipschitz() {
        let proj = Projected { forward: DVec3::new(1.0, 2.0, -0.5).normalize() };
        let mut s = 12345u64;
        let mut rnd = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) * 2000.0 - 1000.0
        };
        for _ in 0..10_000 {
            let a = DVec3::new(rnd(), rnd(), rnd());
            let b = DVec3::new(rnd(), rnd(), rnd());
            let l = (a - b).length() * (1.0 + 1e-12);
            assert!((Isotropic.distance_sq(a).sqrt() - Isotropic.distance_sq(b).sqrt()).abs() <= l);
            assert!((proj.distance_sq(a).sqrt() - proj.distance_sq(b).sqrt()).abs() <= l);
        }
    }

    #[test]
    fn names_round_trip() {
        for k in MetricKind::ALL {
            assert_eq!(MetricKind::from_name(k.name()), Some(k));
        }
    }
}
