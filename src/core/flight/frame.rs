//! The frame protocol of the mesh backends: what a view-dependent simplification implements
//! (adapt to a camera, hand over the triangles), its per-frame figures, and the trivial source
//! ([`StaticMesh`], the whole mesh).

use serde::Serialize;

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::mesh::{Bounds, Mesh};

/// Something that adapts a mesh to a camera each frame (view-dependent simplification).
pub trait MeshFrameSource {
    /// Adapts to `camera` at `tolerance_px` and returns what happened this frame.
    fn update(&mut self, camera: &Camera, tolerance_px: f64) -> Result<MeshFrameStats>;
    /// The current triangles, 3 world positions each.
    fn triangles(&self) -> &[[f32; 3]];
    /// Bounding box of the whole mesh (for paths and the initial view).
    fn bounds(&self) -> Bounds;
    /// The last update's page fetch, for backends that read whole pages per frame (the disk-page
    /// backend, `pages::fetch`); `None` for the others.
    fn page_fetch(&self) -> Option<PageFetchFigures> {
        None
    }
}

/// One frame's fetch of whole pages (`relief pages fly`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct PageFetchFigures {
    /// Pages read this frame (after culling).
    pub pages_requested: u64,
    /// Pages the spatial query named before the per-page box and normal-cone tests.
    pub pages_candidate: u64,
    pub bytes_read: u64,
    /// Σ |page − previous page| over the reads in order, in pages (see `pages::fetch`).
    pub seek_pages: u64,
    /// The whole fetch (query, cull, sort, read, decode), ms.
    pub fetch_ms: f64,
    /// The reads alone, ms.
    pub read_ms: f64,
}

/// Means and totals of [`PageFetchFigures`] over a flight.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct PageFetchSummary {
    pub pages_mean: f64,
    pub pages_candidate_mean: f64,
    pub bytes_mean: f64,
    pub bytes_read: u64,
    pub seek_pages_mean: f64,
    pub fetch_ms_mean: f64,
    pub read_ms_mean: f64,
}

impl PageFetchSummary {
    /// Over the frames that fetched pages; `None` when none did.
    pub fn of_figures(f: &[PageFetchFigures]) -> Option<PageFetchSummary> {
        if f.is_empty() {
            return None;
        }
        let m = |g: fn(&PageFetchFigures) -> f64| mean(f.iter().map(g));
        Some(PageFetchSummary {
            pages_mean: m(|x| x.pages_requested as f64),
            pages_candidate_mean: m(|x| x.pages_candidate as f64),
            bytes_mean: m(|x| x.bytes_read as f64),
            bytes_read: f.iter().map(|x| x.bytes_read).sum(),
            seek_pages_mean: m(|x| x.seek_pages as f64),
            fetch_ms_mean: m(|x| x.fetch_ms),
            read_ms_mean: m(|x| x.read_ms),
        })
    }
}

/// What one [`MeshFrameSource::update`] did. The loops re-upload the triangles when
/// `splits + collapses > 0` (and on the first frame): a source must count every change to its
/// triangle set as a split or a collapse.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct MeshFrameStats {
    pub splits: u64,
    pub collapses: u64,
    /// Meta-node (page) requests not found in memory.
    pub misses: u64,
    /// Triangles after the update.
    pub triangles: u64,
    pub pages_read: u64,
    pub second_chance_hits: u64,
    /// Time the adaptation took, ms.
    pub adapt_ms: f64,
}

impl MeshFrameStats {
    /// Splits and collapses: the adaptation's work, and whether the triangles changed.
    pub fn adapt(&self) -> u64 {
        self.splits + self.collapses
    }

    /// 100 × misses / (adapt + misses), 0 when both are 0.
    pub fn miss_pct(&self) -> f64 {
        pct(self.misses, self.adapt())
    }
}

pub fn pct(misses: u64, adapt: u64) -> f64 {
    let all = misses + adapt;
    if all == 0 {
        0.0
    } else {
        100.0 * misses as f64 / all as f64
    }
}

/// The full mesh, never simplified: every update keeps the same triangles.
pub struct StaticMesh {
    triangles: Vec<[f32; 3]>,
    bounds: Bounds,
}

impl StaticMesh {
    /// All triangles of `mesh`, as f32 world positions (an index out of range is an error).
    pub fn new(mesh: &Mesh) -> Result<StaticMesh> {
        let mut triangles = Vec::with_capacity(3 * mesh.triangles.len());
        for (k, t) in mesh.triangles.iter().enumerate() {
            for &i in t {
                let p = mesh.positions.get(i as usize).ok_or_else(|| {
                    Error::InvalidArgument(format!(
                        "triangle {k}: vertex index {i} out of range ({} vertices)",
                        mesh.positions.len()
                    ))
                })?;
                triangles.push(p.map(|c| c as f32));
            }
        }
        StaticMesh::from_triangles(triangles)
    }

    /// A triangle list (3 positions per triangle); its bounds are those of the positions.
    pub fn from_triangles(triangles: Vec<[f32; 3]>) -> Result<StaticMesh> {
        if triangles.is_empty() || !triangles.len().is_multiple_of(3) {
            return Err(Error::InvalidArgument(format!(
                "a static mesh needs at least one triangle (3 positions each), got {} positions",
                triangles.len()
            )));
        }
        let mut bounds = Bounds { min: [f64::INFINITY; 3], max: [f64::NEG_INFINITY; 3] };
        for p in &triangles {
            for (k, &c) in p.iter().enumerate() {
                bounds.min[k] = bounds.min[k].min(c as f64);
                bounds.max[k] = bounds.max[k].max(c as f64);
            }
        }
        Ok(StaticMesh { triangles, bounds })
    }
}

impl MeshFrameSource for StaticMesh {
    fn update(&mut self, _camera: &Camera, _tolerance_px: f64) -> Result<MeshFrameStats> {
        Ok(MeshFrameStats { triangles: self.triangles.len() as u64 / 3, ..Default::default() })
    }

    fn triangles(&self) -> &[[f32; 3]] {
        &self.triangles
    }

    fn bounds(&self) -> Bounds {
        self.bounds
    }
}

pub fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (sum, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    if n == 0 {
        0.0
    } else {
        sum / n as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn miss_percentage_counts_misses_among_all_requests() {
        let s = MeshFrameStats { splits: 6, collapses: 2, misses: 2, ..Default::default() };
        assert_eq!(s.adapt(), 8);
        assert_eq!(s.miss_pct(), 20.0);
        assert_eq!(MeshFrameStats::default().miss_pct(), 0.0);
    }

    #[test]
    fn a_static_mesh_reports_its_triangles_and_box() {
        let mut m = StaticMesh::from_triangles(vec![[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 3.0, -1.0]]).unwrap();
        assert_eq!(m.bounds(), Bounds { min: [0.0, 0.0, -1.0], max: [2.0, 3.0, 0.0] });
        let cam = Camera::new(glam::DVec3::Z * 5.0, glam::DVec3::ZERO, glam::DVec3::Y, 60.0, 8, 8).unwrap();
        let s = m.update(&cam, 1.0).unwrap();
        assert_eq!((s.triangles, s.adapt()), (1, 0));
        assert!(StaticMesh::from_triangles(vec![[0.0; 3]; 4]).is_err());
        assert!(StaticMesh::from_triangles(Vec::new()).is_err());
    }
}
