//! Heights resident on the GPU: the whole grid as an `R32Float` 2-D texture array, tiled so that
//! every tile fits the adapter's texture limits, uploaded once from the mapped terrain file.
//!
//! The renderer never re-reads the file after this: per frame only the strip crosses the bus.
//! [`HeightTiling`] is the address map the shaders use (`post_height` in `shaders/terrain.wgsl`).

use rayon::prelude::*;

use crate::error::Result;
use crate::format::terrain::{Record, TerrainFile};
use crate::layout::{Layout, LayoutVisitor};
use crate::sys::progress::Progress;

/// How the grid's posts are spread over the layers of a texture array: post `(x, y)` lives in
/// layer `(y / tile) · tiles_per_row + x / tile` at texel `(x mod tile, y mod tile)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HeightTiling {
    /// Posts per side of the grid.
    pub posts: u32,
    /// Posts per side of one tile (texture width and height).
    pub tile_posts: u32,
    pub tiles_per_row: u32,
}

impl HeightTiling {
    /// The tiling that needs the least texture memory within `max_dim` texels per side and
    /// `max_layers` layers: a single layer when the grid fits, else square power-of-two tiles.
    pub fn plan(posts: u32, max_dim: u32, max_layers: u32) -> Result<HeightTiling> {
        let mut best: Option<(u64, HeightTiling)> = None;
        let mut consider = |tile_posts: u32| {
            let tiles_per_row = posts.div_ceil(tile_posts);
            let layers = tiles_per_row as u64 * tiles_per_row as u64;
            if tile_posts > max_dim || layers > max_layers as u64 {
                return;
            }
            let texels = layers * tile_posts as u64 * tile_posts as u64;
            let t = HeightTiling { posts, tile_posts, tiles_per_row };
            if best.is_none_or(|(b, _)| texels < b) {
                best = Some((texels, t));
            }
        };
        consider(posts);
        let mut tile = 64u32;
        while tile <= max_dim && tile < posts {
            consider(tile);
            tile *= 2;
        }
        best.map(|(_, t)| t).ok_or_else(|| {
            crate::app_error::gpu(format!(
                "a grid of {posts} x {posts} posts does not fit the GPU's textures \
                 ({max_dim} texels per side, {max_layers} layers)"
            ))
        })
    }

    /// A tiling with a given tile size (tests use small tiles to cross many tile borders).
    pub fn with_tile(posts: u32, tile_posts: u32) -> HeightTiling {
        HeightTiling { posts, tile_posts: tile_posts.max(1), tiles_per_row: posts.div_ceil(tile_posts.max(1)) }
    }

    pub fn layers(&self) -> u32 {
        self.tiles_per_row * self.tiles_per_row
    }

    /// Bytes of GPU memory the heights take (4 per texel, padding included).
    pub fn bytes(&self) -> u64 {
        self.layers() as u64 * self.tile_posts as u64 * self.tile_posts as u64 * 4
    }

    /// `(layer, texel x, texel y)` of post `(x, y)`.
    pub fn address(&self, x: u32, y: u32) -> (u32, u32, u32) {
        let (tx, ty) = (x / self.tile_posts, y / self.tile_posts);
        (ty * self.tiles_per_row + tx, x - tx * self.tile_posts, y - ty * self.tile_posts)
    }
}

/// Fills one tile (row-major, `tile_posts²` heights, padding beyond the grid replicated from the
/// border so filtering-free reads never see garbage).
pub fn fill_tile(records: &[Record], terrain: &TerrainFile, tiling: &HeightTiling, layer: u32, out: &mut [f32]) {
    struct Fill<'a> {
        terrain: &'a TerrainFile,
        records: &'a [Record],
        tiling: &'a HeightTiling,
        layer: u32,
        out: &'a mut [f32],
    }
    impl LayoutVisitor for Fill<'_> {
        type Output = ();
        fn visit<L: Layout>(self, layout: &L) {
            let t = self.tiling.tile_posts;
            let x0 = (self.layer % self.tiling.tiles_per_row) * t;
            let y0 = (self.layer / self.tiling.tiles_per_row) * t;
            let last = self.tiling.posts - 1;
            let records = self.records;
            let h = self.terrain.header();
            self.out.par_chunks_mut(t as usize).enumerate().for_each(|(row, dst)| {
                let y = (y0 + row as u32).min(last);
                for (col, out) in dst.iter_mut().enumerate() {
                    let x = (x0 + col as u32).min(last);
                    let (x, y) = h.data_post(x, y);
                    *out = records[layout.index(x, y) as usize].z;
                }
            });
        }
    }
    terrain.layout().visit(Fill { terrain, records, tiling, layer, out });
}

/// An `R32Float` texture array of `layers` square layers of `side` texels, written with
/// [`write_layer`], and its array view: the resident grid's tiles.
pub fn height_layers(device: &wgpu::Device, label: &str, side: u32, layers: u32) -> (wgpu::Texture, wgpu::TextureView) {
    texture_layers(device, label, side, layers, wgpu::TextureFormat::R32Float)
}

/// A texture array of `layers` square layers of `side` texels of `format` (one mip level) and its
/// array view: the resident grid's tiles, the tile caches' slots.
pub fn texture_layers(
    device: &wgpu::Device,
    label: &str,
    side: u32,
    layers: u32,
    format: wgpu::TextureFormat,
) -> (wgpu::Texture, wgpu::TextureView) {
    let texture = device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d { width: side, height: side, depth_or_array_layers: layers },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    let view = texture.create_view(&wgpu::TextureViewDescriptor {
        label: Some(label),
        dimension: Some(wgpu::TextureViewDimension::D2Array),
        ..Default::default()
    });
    (texture, view)
}

/// Writes one layer (`side²` heights, row-major) of a [`height_layers`] texture.
pub fn write_layer(queue: &wgpu::Queue, texture: &wgpu::Texture, layer: u32, side: u32, heights: &[f32]) {
    write_layer_bytes(queue, texture, layer, side, bytemuck::cast_slice(heights));
}

/// Writes one layer (`side²` texels, row-major, `texels.len() / side²` bytes each) of a
/// [`texture_layers`] texture.
pub fn write_layer_bytes(queue: &wgpu::Queue, texture: &wgpu::Texture, layer: u32, side: u32, texels: &[u8]) {
    let texel_bytes = (texels.len() / (side as usize * side as usize)) as u32;
    queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: 0,
            origin: wgpu::Origin3d { x: 0, y: 0, z: layer },
            aspect: wgpu::TextureAspect::All,
        },
        texels,
        wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(texel_bytes * side), rows_per_image: Some(side) },
        wgpu::Extent3d { width: side, height: side, depth_or_array_layers: 1 },
    );
}

/// The heights texture array and its tiling.
pub struct GpuHeights {
    pub tiling: HeightTiling,
    pub texture: wgpu::Texture,
    pub view: wgpu::TextureView,
}

impl GpuHeights {
    /// Uploads every post of `terrain`, one tile at a time (bounded staging memory), with a
    /// progress bar in posts.
    pub fn upload(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        terrain: &TerrainFile,
        tiling: HeightTiling,
        progress: Progress,
    ) -> Result<GpuHeights> {
        // Every height goes to the GPU: the mapped records, or the file read whole.
        let records = terrain.records()?;
        let t = tiling.tile_posts;
        let (texture, view) = height_layers(device, "relief heights", t, tiling.layers());
        let bar = progress.bar("upload", tiling.posts as u64 * tiling.posts as u64, "posts");
        let mut tile = vec![0f32; t as usize * t as usize];
        for layer in 0..tiling.layers() {
            fill_tile(&records, terrain, &tiling, layer, &mut tile);
            write_layer(queue, &texture, layer, t, &tile);
            // Submit per tile so staging memory stays at one tile.
            queue.submit([]);
            let inside_x = (tiling.posts - (layer % tiling.tiles_per_row) * t).min(t) as u64;
            let inside_y = (tiling.posts - (layer / tiling.tiles_per_row) * t).min(t) as u64;
            bar.inc(inside_x * inside_y);
        }
        bar.finish_and_clear();
        Ok(GpuHeights { tiling, texture, view })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plan_prefers_one_layer_when_the_grid_fits() {
        let t = HeightTiling::plan(513, 8192, 256).unwrap();
        assert_eq!((t.tile_posts, t.tiles_per_row, t.layers()), (513, 1, 1));
        assert_eq!(t.bytes(), 513 * 513 * 4);
    }

    #[test]
    fn plan_tiles_a_grid_larger_than_the_texture_limit() {
        // 16385 posts, 16384 texels: tiles of 2048 (9 × 9 = 81 layers) waste least.
        let t = HeightTiling::plan(16385, 16384, 256).unwrap();
        assert_eq!((t.tile_posts, t.tiles_per_row), (2048, 9));
        // 1024-post tiles need 17² = 289 layers, over a 256-layer limit; with 2048 layers allowed,
        // 512-post tiles (33² layers, 285.5 M texels) beat 1024 (303 M) and 2048 (340 M).
        let t = HeightTiling::plan(16385, 8192, 2048).unwrap();
        assert_eq!((t.tile_posts, t.tiles_per_row), (512, 33));
        assert!(HeightTiling::plan(1 << 20 | 1, 2048, 16).is_err());
    }

    #[test]
    fn addresses_cover_every_texel_once() {
        let t = HeightTiling::with_tile(10, 4);
        let mut seen = std::collections::HashSet::new();
        for y in 0..10 {
            for x in 0..10 {
                let (layer, tx, ty) = t.address(x, y);
                assert!(layer < t.layers() && tx < 4 && ty < 4);
                assert!(seen.insert((layer, tx, ty)));
            }
        }
        assert_eq!(t.address(9, 5), (5, 1, 1));
    }
}
