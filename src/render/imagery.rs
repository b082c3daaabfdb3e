//! Imagery draped on a terrain (`--imagery FILE`): a north-up PNG or JPEG with a world file
//! (`.pgw`, `.jgw`, `.pngw`, `.jpgw` or `.wld`: pixel size, rotation terms, the centre of the
//! upper-left pixel, in the terrain's CRS units), a GeoTIFF (or any raster GDAL reads, in builds
//! with GDAL) placed by its geotransform, or an image of exactly the DEM's extent; or an imagery
//! tile file (`relief imagery`, `relief_core::format::imagery`) made once from any of them.
//!
//! A decoded image is held whole on the GPU with its mip levels (down-sampled first when larger
//! than the GPU's texture limit). A tile file is paged: its tiles live on the GPU as a pool of
//! slots filled by the tile cache the heights use (`relief_core::heightcache::TileCache`,
//! following the strip), so neither memory nor GPU memory holds the image. The fragment shader
//! samples either at each fragment's CRS position and lights it with the hillshade as asked.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::error::{Error, Result};
use crate::format::imagery::ImageryFile;
use crate::format::terrain::{Header, TerrainFile};
use crate::heightcache::{CacheBudget, HeightCacheStats, ImageryTiles, TileCache, WantView};
use crate::refine::{Morph, StripVertex};
use crate::render::gpu::Gpu;
use crate::render::height_cache::GpuTileCache;

/// The largest image held whole (decoded RGBA, before its mip levels): larger ones are paged from
/// an imagery tile file.
pub const WHOLE_MAX_BYTES: u64 = 512 << 20;

/// An image to drape and where it lies.
pub struct Imagery {
    pub path: PathBuf,
    /// Level-0 size, texels.
    pub width: u32,
    pub height: u32,
    pub pixels: Pixels,
    /// World file: x of the upper-left pixel's centre, pixel width; y of that centre, pixel height
    /// (positive; rows go south). `None`: the image spans the DEM's valid window.
    pub placement: Option<[f64; 4]>,
}

/// Where an image's texels are.
pub enum Pixels {
    /// Decoded, held whole.
    Whole(image::RgbaImage),
    /// In an imagery tile file (at [`Imagery::path`]), paged.
    Tiled,
}

/// Whether `path` starts as a PNG or a JPEG does (`None`: it has fewer than 4 bytes); other
/// images go to GDAL.
fn png_or_jpeg(path: &Path) -> Result<Option<bool>> {
    let mut magic = [0u8; 4];
    match std::fs::File::open(path).and_then(|mut f| std::io::Read::read_exact(&mut f, &mut magic)) {
        Ok(()) => Ok(Some(magic == *b"\x89PNG" || magic[..3] == [0xff, 0xd8, 0xff])),
        Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => Ok(None),
        Err(e) => Err(Error::io(path, e)),
    }
}

/// The world file beside `path`, by the conventions GIS tools use.
fn world_file(path: &Path) -> Option<PathBuf> {
    let ext = path.extension()?.to_str()?.to_ascii_lowercase();
    relief_core::georef::drape::world_file_extensions(&ext).iter().map(|e| path.with_extension(e)).find(|p| p.exists())
}

impl std::fmt::Debug for Imagery {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let tiled = matches!(self.pixels, Pixels::Tiled);
        write!(
            f,
            "Imagery({}, {} x {}, tiled {tiled}, {:?})",
            self.path.display(),
            self.width,
            self.height,
            self.placement
        )
    }
}

impl Imagery {
    /// Reads `path` (PNG or JPEG; any raster GDAL reads, a GeoTIFF orthophoto say, in builds
    /// with GDAL) and its world file, if any (else, through GDAL, its geotransform).
    pub fn open(path: &Path) -> Result<Imagery> {
        let bad = |problem: String| Error::BadDem { path: path.into(), problem };
        if crate::format::sniff(path)? == Some(crate::format::FileKind::Imagery) {
            let file = ImageryFile::open(path, crate::pager::Access::Map)?;
            let h = file.header();
            let (width, height, placement) = (h.width, h.height, h.placement);
            return Ok(Imagery { path: path.into(), width, height, pixels: Pixels::Tiled, placement });
        }
        // A file too short to say is left to the decoder to refuse.
        if let Ok(Some(false)) = png_or_jpeg(path) {
            return Imagery::through_gdal(path);
        }
        let reader = || -> Result<image::ImageReader<std::io::BufReader<std::fs::File>>> {
            image::ImageReader::open(path)
                .map_err(|e| Error::io(path, e))?
                .with_guessed_format()
                .map_err(|e| Error::io(path, e))
        };
        if let Ok((w, h)) = reader()?.into_dimensions() {
            let bytes = 4 * w as u64 * h as u64;
            if bytes > WHOLE_MAX_BYTES {
                let (mib, max_mib) = (bytes as f64 / (1u64 << 20) as f64, WHOLE_MAX_BYTES >> 20);
                return Err(bad(format!(
                    "a {w} x {h} image takes {mib:.1} MiB decoded, more than the {max_mib} MiB an image held \
                     whole may; cut it once with `relief imagery {} OUT.rimg` and drape OUT.rimg, which is paged",
                    path.display()
                )));
            }
        }
        let image =
            reader()?.decode().map_err(|e| bad(format!("not a PNG or JPEG image this build reads ({e})")))?.to_rgba8();
        if image.width() == 0 || image.height() == 0 {
            return Err(bad("the image is empty".into()));
        }
        let placement = Imagery::world_file_placement(path)?;
        Ok(Imagery::whole(path, image, placement))
    }

    /// An image GDAL reads, placed by its world file or else its geotransform.
    #[cfg(feature = "gdal")]
    fn through_gdal(path: &Path) -> Result<Imagery> {
        let relief_core::dem::RgbaRaster { width, height, rgba, placement: transform } =
            relief_core::dem::read_rgba(path)?;
        let image = image::RgbaImage::from_raw(width, height, rgba).ok_or_else(|| Error::BadDem {
            path: path.into(),
            problem: "GDAL's pixels do not fill the image".into(),
        })?;
        let placement = Imagery::world_file_placement(path)?.or(transform);
        Ok(Imagery::whole(path, image, placement))
    }

    #[cfg(not(feature = "gdal"))]
    fn through_gdal(path: &Path) -> Result<Imagery> {
        Err(no_gdal(path))
    }

    fn whole(path: &Path, image: image::RgbaImage, placement: Option<[f64; 4]>) -> Imagery {
        let (width, height) = image.dimensions();
        Imagery { path: path.into(), width, height, pixels: Pixels::Whole(image), placement }
    }

    /// The decoded image (`None` for a tile file).
    pub fn image(&self) -> Option<&image::RgbaImage> {
        match &self.pixels {
            Pixels::Whole(i) => Some(i),
            Pixels::Tiled => None,
        }
    }

    /// The placement a world file beside `path` gives, if there is one.
    pub fn world_file_placement(path: &Path) -> Result<Option<[f64; 4]>> {
        Ok(match world_file(path) {
            None => None,
            Some(wf) => {
                let text = std::fs::read_to_string(&wf).map_err(|e| Error::io(&wf, e))?;
                let placement = relief_core::georef::drape::parse_world_file(&text)
                    .map_err(|what| Error::BadDem { path: wf.clone(), problem: what.into() })?;
                Some(placement)
            }
        })
    }

    /// Texture coordinates of grid posts: `u = a0 + a1·x`, `v = b0 + b1·y` (0..1 over the
    /// image, v down), and whether u wraps (a world image on a geographic terrain).
    pub fn uv_of_grid(&self, h: &Header) -> Result<([f32; 4], bool)> {
        relief_core::georef::drape::uv_of_grid(self.width, self.height, self.placement, h.valid_window, h.georef)
            .ok_or_else(|| {
                Error::InvalidArgument(format!(
                    "{}: a world file places the image in a CRS, and the terrain has none; drop the world file to \
                 stretch the image over the DEM",
                    self.path.display()
                ))
            })
    }

    /// The image and its mip levels (each half the size, box-filtered), the first no larger than
    /// `max_side` texels a side.
    pub fn levels(&self, max_side: u32) -> Vec<image::RgbaImage> {
        let Some(image) = self.image() else { return vec![image::RgbaImage::new(1, 1)] };
        let mut first = image.clone();
        let (w, h) = first.dimensions();
        if w.max(h) > max_side {
            let k = max_side as f64 / w.max(h) as f64;
            let (nw, nh) = (((w as f64 * k) as u32).max(1), ((h as f64 * k) as u32).max(1));
            first = image::imageops::resize(&first, nw, nh, image::imageops::FilterType::Triangle);
        }
        let mut levels = vec![first];
        loop {
            let last = levels.last().expect("one level");
            let (w, h) = last.dimensions();
            if w == 1 && h == 1 {
                break;
            }
            let next =
                image::imageops::resize(last, (w / 2).max(1), (h / 2).max(1), image::imageops::FilterType::Triangle);
            levels.push(next);
        }
        levels
    }
}

/// GPU memory for paged imagery's slots when none is given (1,023 tiles of 256² texels).
pub const DEFAULT_IMAGERY_GPU_MEMORY: u64 = 256 << 20;

/// The draped image on the GPU, as the terrain shader's bindings 4–6 read it: whole (one layer
/// with its mip levels), paged (the imagery cache's slots and table), or absent (one texel).
pub struct GpuImagery {
    pub view: wgpu::TextureView,
    pub sampler: wgpu::Sampler,
    /// The cache's table, or a small unused buffer.
    table: wgpu::Buffer,
    _texture: Option<wgpu::Texture>,
    cache: Option<Box<GpuTileCache<ImageryTiles>>>,
    /// `Frame.imagery_uv`, `Frame.imagery`, `Frame.imagery_pages` of the shader.
    pub uv: [f32; 4],
    pub params: [f32; 4],
    pub pages: [f32; 4],
}

impl GpuImagery {
    /// Uploads `imagery` (with how much the hillshade lights it) for `terrain`: whole now, or as
    /// a cache within `budget` whose coarsest tile is uploaded by the first [`Self::sync`].
    pub fn new(
        gpu: &Gpu,
        terrain: &Arc<TerrainFile>,
        imagery: Option<&(Arc<Imagery>, f32)>,
        budget: CacheBudget,
    ) -> Result<GpuImagery> {
        let device = &gpu.device;
        let max_side = device.limits().max_texture_dimension_2d;
        let table_words = crate::heightcache::TABLE_HEADER as u64;
        let small_table = || {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("relief imagery table (unused)"),
                size: 4 * table_words,
                usage: wgpu::BufferUsages::STORAGE,
                mapped_at_creation: false,
            })
        };
        let (uv, wraps, shade) = match imagery {
            Some((img, shade)) => {
                let (uv, wraps) = img.uv_of_grid(terrain.header())?;
                (uv, wraps, shade.clamp(0.0, 1.0))
            }
            None => ([0.0; 4], false, 0.0),
        };
        let on = if imagery.is_some() { 1.0 } else { 0.0 };
        if let Some((img, _)) = imagery.filter(|(i, _)| matches!(i.pixels, Pixels::Tiled)) {
            let file = ImageryFile::open(&img.path, crate::pager::Access::Map)?;
            let g = file.grid().clone();
            let set = ImageryTiles { file, terrain: terrain.clone(), uv: uv.map(|v| v as f64), wraps };
            let cache = TileCache::of(set, budget, "imagery")?;
            let pool = GpuTileCache::of(device, cache, wgpu::TextureFormat::Rgba8UnormSrgb)?;
            // Slots carry their borders: never wrap or filter past them.
            let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
                label: Some("relief imagery tiles"),
                mag_filter: wgpu::FilterMode::Linear,
                min_filter: wgpu::FilterMode::Linear,
                ..Default::default()
            });
            let view = pool.view.clone();
            let table = pool.table.clone();
            return Ok(GpuImagery {
                view,
                sampler,
                table,
                _texture: None,
                cache: Some(Box::new(pool)),
                uv,
                params: [on, shade, wraps as u8 as f32, 1.0],
                pages: [g.width as f32, g.height as f32, g.tile as f32, g.levels.len() as f32],
            });
        }
        let levels = match imagery {
            Some((img, _)) => img.levels(max_side),
            None => vec![image::RgbaImage::new(1, 1)],
        };
        let (w, h) = levels[0].dimensions();
        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("relief imagery"),
            size: wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
            mip_level_count: levels.len() as u32,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba8UnormSrgb,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        for (k, level) in levels.iter().enumerate() {
            let (lw, lh) = level.dimensions();
            gpu.queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &texture,
                    mip_level: k as u32,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::All,
                },
                level.as_raw(),
                wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(4 * lw), rows_per_image: Some(lh) },
                wgpu::Extent3d { width: lw, height: lh, depth_or_array_layers: 1 },
            );
        }
        let view = texture.create_view(&wgpu::TextureViewDescriptor {
            label: Some("relief imagery"),
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        let address_u = if wraps { wgpu::AddressMode::Repeat } else { wgpu::AddressMode::ClampToEdge };
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("relief imagery"),
            address_mode_u: address_u,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Linear,
            ..Default::default()
        });
        Ok(GpuImagery {
            view,
            sampler,
            table: small_table(),
            _texture: Some(texture),
            cache: None,
            uv,
            params: [on, shade, wraps as u8 as f32, 0.0],
            pages: [w as f32, h as f32, 0.0, 0.0],
        })
    }

    /// The table binding.
    pub fn table(&self) -> &wgpu::Buffer {
        &self.table
    }

    /// Whether the image is paged.
    pub fn paged(&self) -> bool {
        self.cache.is_some()
    }

    /// The imagery cache's step for a frame: tells the loader about `new_strip` seen from
    /// `view` (its heights, if it has them; the loader reads them otherwise), then writes the
    /// finished tiles within the upload budget, never waiting. Returns the bytes sent.
    pub fn sync(
        &mut self,
        queue: &wgpu::Queue,
        new_strip: Option<(&[StripVertex], &[Morph])>,
        view: WantView,
    ) -> Result<u64> {
        let Some(pool) = &mut self.cache else { return Ok(0) };
        if let Some((vertices, heights)) = new_strip {
            pool.want(vertices, heights, view);
        }
        pool.sync(queue)
    }

    /// The imagery cache's figures of the last frame (zero when the image is whole or absent).
    pub fn stats(&self) -> HeightCacheStats {
        self.cache.as_ref().map(|c| c.stats()).unwrap_or_default()
    }

    /// Whether every wanted tile is resident and blended in (always, when whole).
    pub fn converged(&self) -> bool {
        self.cache.as_ref().is_none_or(|c| c.cache.converged())
    }

    /// GPU bytes the image takes: the pool and table, or the whole image with its mip levels.
    pub fn gpu_bytes(&self) -> u64 {
        match (&self.cache, &self._texture) {
            _ if self.params[0] == 0.0 => 0,
            (Some(c), _) => c.cache.pool_bytes(),
            (None, Some(t)) => {
                let (w, h) = (t.width() as u64, t.height() as u64);
                (0..t.mip_level_count()).map(|k| (w >> k).max(1) * (h >> k).max(1) * 4).sum()
            }
            _ => 0,
        }
    }
}

/// [`make_tiles`] of a raster GDAL reads: read 256 rows at a time into scratch.
#[cfg(feature = "gdal")]
fn tiles_through_gdal(
    path: &Path,
    out: &Path,
    scratch_dir: &Path,
    progress: crate::sys::progress::Progress,
) -> Result<crate::format::imagery::TilingReport> {
    let reader = relief_core::dem::RgbaReader::open(path)?;
    let (w, h) = (reader.width, reader.height);
    let mut map = crate::sys::scratch::ScratchMap::new(scratch_dir, 4 * w as u64 * h as u64)?;
    {
        let texels: &mut [[u8; 4]] = map.slice_mut();
        for (k, rows) in texels.chunks_mut(256 * w as usize).enumerate() {
            crate::sys::cancel::check()?;
            reader.read_rows(256 * k as u32, rows)?;
        }
    }
    let placement = Imagery::world_file_placement(path)?.or(reader.placement);
    crate::format::imagery::write(out, map.slice(), w, h, placement, scratch_dir, progress)
}

#[cfg(not(feature = "gdal"))]
fn tiles_through_gdal(
    path: &Path,
    _out: &Path,
    _scratch_dir: &Path,
    _progress: crate::sys::progress::Progress,
) -> Result<crate::format::imagery::TilingReport> {
    Err(no_gdal(path))
}

/// What a build without GDAL says of imagery it cannot decode.
#[cfg(not(feature = "gdal"))]
fn no_gdal(path: &Path) -> Error {
    Error::BadDem {
        path: path.into(),
        problem: "not a PNG or JPEG image; other imagery (GeoTIFF, …) needs GDAL: build relief with `--features gdal`"
            .into(),
    }
}

/// Makes the imagery tile file `out` of the image at `path` (what `--imagery` reads, placed by its
/// world file or geotransform, else spanning the DEM). PNG and JPEG are decoded straight into a
/// scratch file in `scratch_dir` (paged by the kernel, not held in memory); other rasters (builds
/// with GDAL) are read into it 256 rows at a time.
pub fn make_tiles(
    path: &Path,
    out: &Path,
    scratch_dir: &Path,
    progress: crate::sys::progress::Progress,
) -> Result<crate::format::imagery::TilingReport> {
    let bad = |problem: String| Error::BadDem { path: path.into(), problem };
    if crate::format::sniff(path)? == Some(crate::format::FileKind::Imagery) {
        return Err(bad("is already an imagery tile file".into()));
    }
    match png_or_jpeg(path)? {
        Some(true) => {}
        Some(false) => return tiles_through_gdal(path, out, scratch_dir, progress),
        None => {
            return Err(Error::io(
                path,
                std::io::Error::new(std::io::ErrorKind::UnexpectedEof, "failed to fill whole buffer"),
            ))
        }
    }
    use image::ImageDecoder;
    let mut reader = image::ImageReader::open(path).map_err(|e| Error::io(path, e))?;
    reader.no_limits();
    let decoder = reader
        .with_guessed_format()
        .map_err(|e| Error::io(path, e))?
        .into_decoder()
        .map_err(|e| bad(format!("not a PNG or JPEG image this build reads ({e})")))?;
    let (w, h) = decoder.dimensions();
    let colour = decoder.color_type();
    let texels = w as u64 * h as u64;
    let total = decoder.total_bytes();
    if texels == 0 {
        return Err(bad("the image is empty".into()));
    }
    let bpp = (total / texels) as usize;
    let mut map = crate::sys::scratch::ScratchMap::new(scratch_dir, total.max(4 * texels))?;
    {
        let bytes: &mut [u8] = map.slice_mut();
        decoder.read_image(&mut bytes[..total as usize]).map_err(|e| bad(format!("cannot decode it ({e})")))?;
        // To RGBA8 in place: pixel i moves from byte i·bpp to byte 4i, so a narrower source is
        // expanded from the end and a wider one from the start, never overwriting what is unread.
        let px = |src: &[u8]| -> [u8; 4] {
            use image::ColorType as C;
            let hi = |k: usize| src[2 * k + 1]; // 16-bit samples are native-endian (little here)
            match colour {
                C::L8 => [src[0], src[0], src[0], 255],
                C::La8 => [src[0], src[0], src[0], src[1]],
                C::Rgb8 => [src[0], src[1], src[2], 255],
                C::Rgba8 => [src[0], src[1], src[2], src[3]],
                C::L16 => [hi(0), hi(0), hi(0), 255],
                C::La16 => [hi(0), hi(0), hi(0), hi(1)],
                C::Rgb16 => [hi(0), hi(1), hi(2), 255],
                _ => [hi(0), hi(1), hi(2), hi(3)],
            }
        };
        if !matches!(
            colour,
            image::ColorType::L8
                | image::ColorType::La8
                | image::ColorType::Rgb8
                | image::ColorType::Rgba8
                | image::ColorType::L16
                | image::ColorType::La16
                | image::ColorType::Rgb16
                | image::ColorType::Rgba16
        ) {
            return Err(bad(format!("{colour:?} pixels are not supported (8- or 16-bit grey, RGB or RGBA)")));
        }
        let n = texels as usize;
        let mut put = |i: usize| {
            let p = px(&bytes[i * bpp..(i + 1) * bpp]);
            bytes[4 * i..4 * i + 4].copy_from_slice(&p);
        };
        if bpp < 4 {
            (0..n).rev().for_each(&mut put);
        } else {
            (0..n).for_each(&mut put);
        }
    }
    let placement = Imagery::world_file_placement(path)?;
    crate::format::imagery::write(out, map.slice(), w, h, placement, scratch_dir, progress)
}
