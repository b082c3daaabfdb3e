//! The navigator as a [`MeshFrameSource`]: what `relief mesh fly` renders.

use std::time::Instant;

use super::navigate::{MetaStore, Navigator};
use crate::camera::Camera;
use crate::error::Result;
use crate::flight::frame::{MeshFrameSource, MeshFrameStats};
use crate::mesh::Bounds;

/// A [`Navigator`] with the counters `relief mesh fly` reports per frame.
pub struct NavSource<S: MetaStore> {
    pub navigator: Navigator<S>,
    bounds: Bounds,
    pages_read: u64,
    second_chance_hits: u64,
}

impl<S: MetaStore> NavSource<S> {
    pub fn new(navigator: Navigator<S>, bounds: Bounds) -> NavSource<S> {
        let pages_read = navigator.store().pages_read();
        let second_chance_hits = navigator.store().second_chance_hits();
        NavSource { navigator, bounds, pages_read, second_chance_hits }
    }
}

impl<S: MetaStore> MeshFrameSource for NavSource<S> {
    fn update(&mut self, camera: &Camera, tolerance_px: f64) -> Result<MeshFrameStats> {
        let started = Instant::now();
        let s = self.navigator.update(camera, tolerance_px)?;
        let adapt_ms = started.elapsed().as_secs_f64() * 1e3;
        let (pages, second) = (self.navigator.store().pages_read(), self.navigator.store().second_chance_hits());
        let stats = MeshFrameStats {
            splits: s.splits,
            collapses: s.collapses,
            misses: s.misses,
            triangles: s.triangles,
            pages_read: pages - self.pages_read,
            second_chance_hits: second - self.second_chance_hits,
            adapt_ms,
        };
        self.pages_read = pages;
        self.second_chance_hits = second;
        Ok(stats)
    }

    fn triangles(&self) -> &[[f32; 3]] {
        self.navigator.triangles()
    }

    fn bounds(&self) -> Bounds {
        self.bounds
    }
}
