//! The GPU side of the tile caches (`relief_core::heightcache`): the pool of tile slots (a texture
//! array, one slot per layer: `R32Float` heights, or `Rgba8UnormSrgb` imagery) and the table
//! buffer `shaders/terrain.wgsl` reads, written from what [`TileCache::frame`] hands over within
//! the per-frame upload budget.

use std::sync::Arc;

use crate::error::Result;
use crate::format::terrain::TerrainFile;
use crate::heightcache::{CacheBudget, HeightCache, HeightCacheStats, TerrainTiles, TileCache, TileSet, WantView};
use crate::refine::{Morph, StripVertex};
use crate::render::heights::{texture_layers, write_layer_bytes};

/// GPU memory for heights when none is given: the whole grid stays resident up to this, else the
/// cache takes this much (bounded by the adapter's texture limits).
pub const DEFAULT_GPU_MEMORY: u64 = 2 << 30;
/// CPU → GPU bytes per frame for height tiles when none is given.
pub const DEFAULT_UPLOAD_PER_FRAME: u64 = 16 << 20;

/// The pool, the table and the CPU side that fills them.
pub struct GpuTileCache<S: TileSet> {
    pub cache: TileCache<S>,
    pub texture: wgpu::Texture,
    pub view: wgpu::TextureView,
    pub table: wgpu::Buffer,
    /// Microseconds the last [`Self::sync`] took.
    last_step_us: u64,
}

/// The height cache on the GPU.
pub type GpuHeightCache = GpuTileCache<TerrainTiles>;

impl GpuHeightCache {
    /// A pool for `terrain` in tiles of `tile_cells` cells within `budget` (its layer count capped
    /// by the adapter's).
    pub fn new(
        device: &wgpu::Device,
        terrain: Arc<TerrainFile>,
        tile_cells: u32,
        budget: CacheBudget,
    ) -> Result<GpuHeightCache> {
        GpuTileCache::of(device, HeightCache::new(terrain, tile_cells, budget)?, wgpu::TextureFormat::R32Float)
    }
}

impl<S: TileSet> GpuTileCache<S>
where
    S::Texel: bytemuck::Pod,
{
    /// The GPU pool and table of `cache`, slots of `format` (whose texels are `S::Texel`).
    pub fn of(device: &wgpu::Device, cache: TileCache<S>, format: wgpu::TextureFormat) -> Result<GpuTileCache<S>> {
        let side = cache.set().slot_side();
        let label =
            if format == wgpu::TextureFormat::R32Float { "relief height cache" } else { "relief imagery cache" };
        let (texture, view) = texture_layers(device, label, side, cache.slots(), format);
        let table = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("relief tile table"),
            size: cache.set().table_bytes(),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(GpuTileCache { cache, texture, view, table, last_step_us: 0 })
    }

    /// Tells the loader about a new strip seen from `view`.
    pub fn want(&mut self, vertices: &[StripVertex], heights: &[Morph], view: WantView) {
        self.cache.want(vertices, heights, view);
    }

    /// This frame's uploads: the finished tiles within the budget and the table when it changed.
    /// Never waits for the loader. Returns the bytes written.
    pub fn sync(&mut self, queue: &wgpu::Queue) -> Result<u64> {
        let started = std::time::Instant::now();
        let side = self.cache.set().slot_side();
        let mut bytes = 0u64;
        let (tiles, table) = self.cache.frame()?;
        for t in &tiles {
            let texels: &[u8] = bytemuck::cast_slice(t.texels);
            write_layer_bytes(queue, &self.texture, t.slot, side, texels);
            bytes += texels.len() as u64;
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
