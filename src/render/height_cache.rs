//! The GPU side of the height cache (`relief_core::heightcache`): the pool of tile slots (an
//! `R32Float` texture array, one slot per layer) and the table buffer `shaders/terrain.wgsl` reads,
//! written from what [`HeightCache::frame`] hands over within the per-frame upload budget.

use std::sync::Arc;

use crate::error::Result;
use crate::format::terrain::TerrainFile;
use crate::heightcache::{CacheBudget, HeightCache, HeightCacheStats, WantView};
use crate::refine::{Morph, StripVertex};
use crate::render::heights::{height_layers, write_layer};

/// GPU memory for heights when none is given: the whole grid stays resident up to this, else the
/// cache takes this much (bounded by the adapter's texture limits).
pub const DEFAULT_GPU_MEMORY: u64 = 2 << 30;
/// CPU → GPU bytes per frame for height tiles when none is given.
pub const DEFAULT_UPLOAD_PER_FRAME: u64 = 16 << 20;

/// The pool, the table and the CPU side that fills them.
pub struct GpuHeightCache {
    pub cache: HeightCache,
    pub texture: wgpu::Texture,
    pub view: wgpu::TextureView,
    pub table: wgpu::Buffer,
    /// Microseconds the last [`Self::sync`] took.
    last_step_us: u64,
}

impl GpuHeightCache {
    /// A pool for `terrain` in tiles of `tile_cells` cells within `budget` (its layer count capped
    /// by the adapter's).
    pub fn new(
        device: &wgpu::Device,
        terrain: Arc<TerrainFile>,
        tile_cells: u32,
        budget: CacheBudget,
    ) -> Result<GpuHeightCache> {
        let cache = HeightCache::new(terrain, tile_cells, budget)?;
        let side = cache.grid().slot_posts();
        let (texture, view) = height_layers(device, "relief height cache", side, cache.slots());
        let table = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("relief height table"),
            size: cache.grid().table_bytes(),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(GpuHeightCache { cache, texture, view, table, last_step_us: 0 })
    }

    /// Tells the loader about a new strip seen from `view`.
    pub fn want(&mut self, vertices: &[StripVertex], heights: &[Morph], view: WantView) {
        self.cache.want(vertices, heights, view);
    }

    /// This frame's uploads: the finished tiles within the budget and the table when it changed.
    /// Never waits for the loader. Returns the bytes written.
    pub fn sync(&mut self, queue: &wgpu::Queue) -> Result<u64> {
        let started = std::time::Instant::now();
        let side = self.cache.grid().slot_posts();
        let mut bytes = 0u64;
        let (tiles, table) = self.cache.frame()?;
        for t in &tiles {
            write_layer(queue, &self.texture, t.slot, side, t.heights);
            bytes += 4 * t.heights.len() as u64;
        }
        if let Some(table) = table {
            let data: &[u8] = bytemuck::cast_slice(table);
            queue.write_buffer(&self.table, 0, data);
            bytes += data.len() as u64;
        }
        self.cache.uploaded();
        self.last_step_us = started.elapsed().as_micros() as u64;
        Ok(bytes)
    }

    pub fn stats(&self) -> HeightCacheStats {
        HeightCacheStats { step_us: self.last_step_us, ..self.cache.stats() }
    }
}
