//! Imagery draped on a terrain (`--imagery FILE`): a north-up PNG or JPEG with a world file
//! (`.pgw`, `.jgw`, `.pngw`, `.jpgw` or `.wld`: pixel size, rotation terms, the centre of the
//! upper-left pixel, in the terrain's CRS units), a GeoTIFF (or any raster GDAL reads, in builds
//! with GDAL) placed by its geotransform, or an image of exactly the DEM's extent. The image is held whole on the GPU with its mip levels (down-sampled
//! first when larger than the GPU's texture limit); the fragment shader samples it at each
//! fragment's CRS position and lights it with the hillshade as much as asked.

use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::format::terrain::Header;

/// A decoded image and where it lies.
pub struct Imagery {
    pub path: PathBuf,
    pub image: image::RgbaImage,
    /// World file: x of the upper-left pixel's centre, pixel width; y of that centre, pixel height
    /// (positive; rows go south). `None`: the image spans the DEM's valid window.
    pub placement: Option<[f64; 4]>,
}

/// The world file beside `path`, by the conventions GIS tools use.
fn world_file(path: &Path) -> Option<PathBuf> {
    let ext = path.extension()?.to_str()?.to_ascii_lowercase();
    let short = match ext.as_str() {
        "png" => "pgw",
        "jpg" | "jpeg" => "jgw",
        _ => "wld",
    };
    let long = format!("{ext}w");
    [short, long.as_str(), "wld"].iter().map(|e| path.with_extension(e)).find(|p| p.exists())
}

impl std::fmt::Debug for Imagery {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (w, h) = self.image.dimensions();
        write!(f, "Imagery({}, {w} x {h}, {:?})", self.path.display(), self.placement)
    }
}

impl Imagery {
    /// Reads `path` (PNG or JPEG; any raster GDAL reads, a GeoTIFF orthophoto say, in builds
    /// with GDAL) and its world file, if any (else, through GDAL, its geotransform).
    pub fn open(path: &Path) -> Result<Imagery> {
        let bad = |problem: String| Error::BadDem { path: path.into(), problem };
        let mut magic = [0u8; 4];
        let head = std::fs::File::open(path)
            .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut magic))
            .map_err(|e| Error::io(path, e));
        let is_png_or_jpeg = head.is_ok() && (magic == *b"\x89PNG" || magic[..3] == [0xff, 0xd8, 0xff]);
        if head.is_ok() && !is_png_or_jpeg {
            return Imagery::through_gdal(path);
        }
        let image = image::ImageReader::open(path)
            .map_err(|e| Error::io(path, e))?
            .with_guessed_format()
            .map_err(|e| Error::io(path, e))?
            .decode()
            .map_err(|e| bad(format!("not a PNG or JPEG image this build reads ({e})")))?
            .to_rgba8();
        if image.width() == 0 || image.height() == 0 {
            return Err(bad("the image is empty".into()));
        }
        let placement = Imagery::world_file_placement(path)?;
        Ok(Imagery { path: path.into(), image, placement })
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
        Ok(Imagery { path: path.into(), image, placement })
    }

    #[cfg(not(feature = "gdal"))]
    fn through_gdal(path: &Path) -> Result<Imagery> {
        Err(Error::BadDem {
            path: path.into(),
            problem: "not a PNG or JPEG image; other imagery (GeoTIFF, …) needs GDAL: build relief with \
                      `--features gdal`"
                .into(),
        })
    }

    /// The placement a world file beside `path` gives, if there is one.
    fn world_file_placement(path: &Path) -> Result<Option<[f64; 4]>> {
        Ok(match world_file(path) {
            None => None,
            Some(wf) => {
                let text = std::fs::read_to_string(&wf).map_err(|e| Error::io(&wf, e))?;
                let v: Vec<f64> = text.split_whitespace().filter_map(|t| t.parse().ok()).collect();
                let bad_wf = |what: &str| Error::BadDem { path: wf.clone(), problem: what.into() };
                if v.len() != 6 || !v.iter().all(|x| x.is_finite()) {
                    return Err(bad_wf("a world file has six numbers (A D B E C F)"));
                }
                let [a, d, b, e, c, f] = [v[0], v[1], v[2], v[3], v[4], v[5]];
                if d != 0.0 || b != 0.0 {
                    return Err(bad_wf("a rotated image is not supported (its world file has rotation terms)"));
                }
                if !(a > 0.0 && e < 0.0) {
                    return Err(bad_wf("the image must be north up: pixel width > 0, height < 0"));
                }
                Some([c, a, f, -e])
            }
        })
    }

    /// Texture coordinates of grid posts: `u = a0 + a1·x`, `v = b0 + b1·y` (0..1 over the
    /// image, v down), and whether u wraps (a world image on a geographic terrain).
    pub fn uv_of_grid(&self, h: &Header) -> Result<([f32; 4], bool)> {
        let (w, ht) = (self.image.width() as f64, self.image.height() as f64);
        let Some([x0, dx, y0, dy]) = self.placement else {
            // The image spans the DEM's posts (first to last post, pixel edges at the ends).
            let [_, _, x1, y1] = h.valid_window;
            let (sx, sy) = ((x1.max(2) - 1) as f64, (y1.max(2) - 1) as f64);
            return Ok(([0.0, (1.0 / sx) as f32, 1.0, (-1.0 / sy) as f32], false));
        };
        let Some(g) = h.georef else {
            return Err(Error::InvalidArgument(format!(
                "{}: a world file places the image in a CRS, and the terrain has none; drop the world file to \
                 stretch the image over the DEM",
                self.path.display()
            )));
        };
        let (left, top) = (x0 - 0.5 * dx, y0 + 0.5 * dy);
        let (span_x, span_y) = (w * dx, ht * dy);
        let uv = [
            ((g.origin[0] - left) / span_x) as f32,
            (g.step[0] / span_x) as f32,
            ((top - g.origin[1]) / span_y) as f32,
            (-g.step[1] / span_y) as f32,
        ];
        let wraps = g.kind == crate::georef::CrsKind::Geographic && (span_x - 360.0).abs() < 1e-6 * 360.0;
        Ok((uv, wraps))
    }

    /// The image and its mip levels (each half the size, box-filtered), the first no larger than
    /// `max_side` texels a side.
    pub fn levels(&self, max_side: u32) -> Vec<image::RgbaImage> {
        let mut first = self.image.clone();
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
