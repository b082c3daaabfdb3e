//! DEM readers: the real files in `../shared/data/dem`, fixtures written here for every format and
//! sample type, and malformed input (which must give an error naming the file, never a panic).

use crate::common;

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use relief_core::dem::{self, DemFormat, DemInfo, SourceSpacing};

fn data(name: &str) -> PathBuf {
    common::dem(name)
}

/// Everything a read delivered: the grid (row-major, NaN for nodata) and the header.
struct Grid {
    info: DemInfo,
    values: Vec<f64>,
}

impl Grid {
    fn at(&self, x: u32, y: u32) -> f64 {
        self.values[y as usize * self.info.width as usize + x as usize]
    }

    fn nan_count(&self) -> usize {
        self.values.iter().filter(|v| v.is_nan()).count()
    }

    /// Min and max over the valid samples.
    fn range(&self) -> (f64, f64) {
        self.values
            .iter()
            .filter(|v| !v.is_nan())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| (lo.min(v), hi.max(v)))
    }
}

/// Opens and reads `path`, checking that every sample arrives exactly once.
fn read(path: &Path, format: Option<DemFormat>) -> Grid {
    let mut source = dem::open(path, format).unwrap_or_else(|e| panic!("open: {e}"));
    let info = source.info().clone();
    let (w, h) = (info.width as usize, info.height as usize);
    let mut values = vec![f64::NAN; w * h];
    let mut seen = HashSet::new();
    let mut count = 0usize;
    source
        .read(&mut |run| {
            assert!(run.row < info.height, "row {} out of range", run.row);
            assert!(run.x0 as usize + run.values.len() <= w, "run past the row end");
            for (k, &v) in run.values.iter().enumerate() {
                let x = run.x0 as usize + k;
                assert!(seen.insert((run.row, x)), "sample ({x}, {}) delivered twice", run.row);
                values[run.row as usize * w + x] = v;
            }
            count += run.values.len();
            Ok(())
        })
        .unwrap_or_else(|e| panic!("read: {e}"));
    assert_eq!(count, w * h, "samples delivered");
    Grid { info, values }
}

/// The error of opening and reading `path`, which must not succeed.
fn read_error(path: &Path, format: Option<DemFormat>) -> String {
    let result = dem::open(path, format).and_then(|mut s| s.read(&mut |_| Ok(())));
    match result {
        Ok(()) => panic!("{} was read without error", path.display()),
        Err(e) => {
            let message = e.to_string();
            assert!(!message.contains('\n'), "multi-line message: {message}");
            let name = path.file_name().unwrap().to_str().unwrap();
            assert!(message.contains(name), "message does not name the file: {message}");
            message
        }
    }
}

fn assert_close(a: f64, b: f64, tolerance: f64, what: &str) {
    assert!((a - b).abs() <= tolerance, "{what}: {a} is not within {tolerance} of {b}");
}

// ---------------------------------------------------------------------------------------------
// Real data

#[test]
fn zurich_geotiff_int16() {
    let g = read(&data("zurich_25m_i16.tif"), None);
    assert_eq!(g.info.format, DemFormat::GeoTiff);
    assert_eq!((g.info.width, g.info.height), (399, 366));
    assert_eq!(g.info.nodata, Some(-9999.0));
    assert_eq!(g.info.spacing, Some(SourceSpacing::Metres { x: 25.0, y: 25.0 }));
    let (lo, hi) = g.range();
    assert_close(lo, 393.0, 0.5, "min");
    assert_close(hi, 870.0, 0.5, "max");
    eprintln!("zurich: {} nodata samples, type {}", g.nan_count(), g.info.sample_type);
}

#[test]
fn lidar_geotiff_float32() {
    let g = read(&data("lidar_1m_f32.tif"), None);
    assert_eq!(g.info.format, DemFormat::GeoTiff);
    assert_eq!((g.info.width, g.info.height), (400, 400));
    assert_eq!(g.info.spacing, Some(SourceSpacing::Metres { x: 1.0, y: 1.0 }));
    let (lo, hi) = g.range();
    assert_close(lo, 379.7, 0.5, "min");
    assert_close(hi, 410.8, 0.5, "max");
    eprintln!("lidar: {} nodata samples, nodata {:?}, type {}", g.nan_count(), g.info.nodata, g.info.sample_type);
}

#[test]
fn etopo_geotiff_degrees() {
    let g = read(&data("etopo20_world.tif"), None);
    assert_eq!(g.info.format, DemFormat::GeoTiff);
    assert_eq!((g.info.width, g.info.height), (1081, 540));
    match g.info.spacing {
        Some(SourceSpacing::Degrees { x, y, centre_lat_deg }) => {
            assert_close(x, 1.0 / 3.0, 1e-6, "x spacing");
            assert_close(y, 1.0 / 3.0, 1e-6, "y spacing");
            assert_close(centre_lat_deg, 0.0, 0.5, "centre latitude");
        }
        other => panic!("spacing {other:?}"),
    }
    let (lo, hi) = g.range();
    assert_close(lo, -9026.6, 0.5, "min");
    assert_close(hi, 6228.8, 0.5, "max");
    eprintln!("etopo: {} nodata samples, type {}", g.nan_count(), g.info.sample_type);
}

#[test]
fn fuji_terrain_rgb() {
    let g = read(&data("fuji_terrain_rgb.png"), None);
    assert_eq!(g.info.format, DemFormat::TerrainRgb);
    assert_eq!((g.info.width, g.info.height), (512, 512));
    let (lo, hi) = g.range();
    assert_close(lo, 13.7, 0.5, "min");
    assert_close(hi, 3751.0, 0.5, "max");
    eprintln!("fuji: {} nodata samples, type {}", g.nan_count(), g.info.sample_type);
}

#[test]
fn terrarium_png() {
    let g = read(&data("terrarium.png"), None);
    assert_eq!(g.info.format, DemFormat::Terrarium);
    assert_eq!((g.info.width, g.info.height), (256, 256));
    let (lo, hi) = g.range();
    assert_close(lo, 715.0, 0.5, "min");
    assert_close(hi, 2489.0, 0.5, "max");
    eprintln!("terrarium: {} nodata samples, type {}", g.nan_count(), g.info.sample_type);
}

#[test]
fn hugo_asc_with_nodata() {
    let g = read(&data("hugo_site_nodata.asc"), None);
    assert_eq!(g.info.format, DemFormat::Asc);
    assert_eq!((g.info.width, g.info.height), (76, 55));
    assert_eq!(g.info.nodata, Some(-9999.0));
    let (lo, hi) = g.range();
    assert_close(lo, 1660.0, 0.5, "min");
    assert_close(hi, 1711.0, 0.5, "max");
    eprintln!("hugo: {} nodata samples, spacing {:?}", g.nan_count(), g.info.spacing);
}

#[test]
fn real_data_counts() {
    // What the files actually contain: zurich declares nodata but has no nodata post; hugo has
    // 2028 of them (its whole margin).
    assert_eq!(read(&data("zurich_25m_i16.tif"), None).nan_count(), 0);
    assert_eq!(read(&data("hugo_site_nodata.asc"), None).nan_count(), 2028);
    assert_eq!(read(&data("lidar_1m_f32.tif"), None).nan_count(), 0);
}

// ---------------------------------------------------------------------------------------------
// Fixtures

/// The test value at (x, y) of a small grid: distinct, and fitting in every sample type.
fn value(x: u32, y: u32) -> i64 {
    i64::from(y) * 10 + i64::from(x) + 1
}

mod tiff_fixtures {
    use super::*;
    use tiff::encoder::{colortype, Compression, DeflateLevel, TiffEncoder};
    use tiff::tags::Tag;

    pub const W: u32 = 5;
    pub const H: u32 = 7;

    /// Writes a W x H TIFF of sample type `C` in strips of 2 rows, with pixel scale 25 m and
    /// GDAL_NODATA "-9999"... for signed types, or "3" for unsigned (so that value 3 becomes NaN).
    pub fn write<C: colortype::ColorType>(
        path: &Path,
        compression: Compression,
        nodata: &str,
        convert: impl Fn(i64) -> C::Inner,
    ) where
        [C::Inner]: tiff::encoder::TiffValue,
    {
        let file = std::fs::File::create(path).unwrap();
        let mut encoder = TiffEncoder::new(file).unwrap().with_compression(compression);
        let mut image = encoder.new_image::<C>(W, H).unwrap();
        image.rows_per_strip(2).unwrap();
        image.encoder().write_tag(Tag::ModelPixelScaleTag, &[25.0f64, 25.0, 0.0][..]).unwrap();
        image.encoder().write_tag(Tag::GdalNodata, nodata).unwrap();
        let data: Vec<C::Inner> = (0..H).flat_map(|y| (0..W).map(move |x| value(x, y))).map(&convert).collect();
        image.write_data(&data).unwrap();
    }

    pub fn compressions() -> [(&'static str, Compression); 3] {
        [
            ("none", Compression::Uncompressed),
            ("deflate", Compression::Deflate(DeflateLevel::Balanced)),
            ("lzw", Compression::Lzw),
        ]
    }
}

/// Checks a TIFF fixture written by `tiff_fixtures::write` with nodata value 3.
fn check_tiff_fixture(path: &Path, sample_type: &str) {
    let g = read(path, None);
    assert_eq!(g.info.format, DemFormat::GeoTiff);
    assert_eq!((g.info.width, g.info.height), (tiff_fixtures::W, tiff_fixtures::H));
    assert_eq!(g.info.sample_type, sample_type);
    assert_eq!(g.info.nodata, Some(3.0));
    assert_eq!(g.info.spacing, Some(SourceSpacing::Metres { x: 25.0, y: 25.0 }));
    for y in 0..tiff_fixtures::H {
        for x in 0..tiff_fixtures::W {
            let v = g.at(x, y);
            if value(x, y) == 3 {
                assert!(v.is_nan(), "{sample_type} ({x}, {y}): nodata gave {v}");
            } else {
                assert_eq!(v, value(x, y) as f64, "{sample_type} ({x}, {y})");
            }
        }
    }
}

#[test]
fn tiff_every_sample_type_and_compression() {
    use tiff::encoder::colortype::*;
    let dir = tempfile::tempdir().unwrap();
    for (name, compression) in tiff_fixtures::compressions() {
        let p = |t: &str| dir.path().join(format!("{t}_{name}.tif"));
        tiff_fixtures::write::<Gray8>(&p("u8"), compression, "3", |v| v as u8);
        check_tiff_fixture(&p("u8"), "uint8");
        tiff_fixtures::write::<GrayI8>(&p("i8"), compression, "3", |v| v as i8);
        check_tiff_fixture(&p("i8"), "int8");
        tiff_fixtures::write::<Gray16>(&p("u16"), compression, "3", |v| v as u16);
        check_tiff_fixture(&p("u16"), "uint16");
        tiff_fixtures::write::<GrayI16>(&p("i16"), compression, "3", |v| v as i16);
        check_tiff_fixture(&p("i16"), "int16");
        tiff_fixtures::write::<Gray32>(&p("u32"), compression, "3", |v| v as u32);
        check_tiff_fixture(&p("u32"), "uint32");
        tiff_fixtures::write::<GrayI32>(&p("i32"), compression, "3", |v| v as i32);
        check_tiff_fixture(&p("i32"), "int32");
        tiff_fixtures::write::<Gray64>(&p("u64"), compression, "3", |v| v as u64);
        check_tiff_fixture(&p("u64"), "uint64");
        tiff_fixtures::write::<GrayI64>(&p("i64"), compression, "3", |v| v);
        check_tiff_fixture(&p("i64"), "int64");
        tiff_fixtures::write::<Gray32Float>(&p("f32"), compression, "3.0", |v| v as f32);
        check_tiff_fixture(&p("f32"), "float32");
        tiff_fixtures::write::<Gray64Float>(&p("f64"), compression, "3", |v| v as f64);
        check_tiff_fixture(&p("f64"), "float64");
    }
}

#[test]
fn tiff_float_nodata_and_non_finite() {
    use tiff::encoder::{colortype::Gray32Float, TiffEncoder};
    use tiff::tags::Tag;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("f32_nodata.tif");
    let data = [1.5f32, f32::MIN, f32::NAN, f32::INFINITY, -2.25, f32::NEG_INFINITY];
    let mut encoder = TiffEncoder::new(std::fs::File::create(&path).unwrap()).unwrap();
    let mut image = encoder.new_image::<Gray32Float>(3, 2).unwrap();
    // GDAL writes f32::MIN as this f64 text; it must match after casting to f32.
    image.encoder().write_tag(Tag::GdalNodata, "-3.4028234663852886e+38").unwrap();
    image.write_data(&data).unwrap();
    let g = read(&path, None);
    assert_eq!(g.info.spacing, None);
    assert_eq!(g.values[0], 1.5);
    assert_eq!(g.values[4], -2.25);
    for k in [1, 2, 3, 5] {
        assert!(g.values[k].is_nan(), "sample {k} = {}", g.values[k]);
    }
    // Printed with few digits, the sentinel still matches f32::MIN.
    let path = dir.path().join("f32_short_nodata.tif");
    let mut encoder = TiffEncoder::new(std::fs::File::create(&path).unwrap()).unwrap();
    let mut image = encoder.new_image::<Gray32Float>(3, 2).unwrap();
    image.encoder().write_tag(Tag::GdalNodata, "-3.40282e+38").unwrap();
    image.write_data(&data).unwrap();
    let g = read(&path, None);
    assert_eq!(g.values[0], 1.5);
    assert_eq!(g.values[4], -2.25);
    for k in [1, 2, 3, 5] {
        assert!(g.values[k].is_nan(), "sample {k} = {}", g.values[k]);
    }
}

#[test]
fn tiff_multi_sample_takes_first() {
    use tiff::encoder::{colortype::RGB16, TiffEncoder};
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rgb16.tif");
    let (w, h) = (4u32, 3u32);
    let data: Vec<u16> = (0..h).flat_map(|y| (0..w).flat_map(move |x| [value(x, y) as u16, 60000, 60001])).collect();
    let mut encoder = TiffEncoder::new(std::fs::File::create(&path).unwrap()).unwrap();
    encoder.write_image::<RGB16>(w, h, &data).unwrap();
    let g = read(&path, None);
    assert!(g.info.sample_type.contains("first of 3"), "{}", g.info.sample_type);
    for y in 0..h {
        for x in 0..w {
            assert_eq!(g.at(x, y), value(x, y) as f64);
        }
    }
}

/// Assembles a little-endian, uncompressed, tiled u16 TIFF by hand (the encoder writes strips
/// only). Tiles are `tile` x `tile`, padded at the right and bottom edges; `samples` per pixel,
/// interleaved (`planar` false) or in separate planes. Sample s of pixel (x, y) is
/// `value(x, y) + 1000 s`. Optional geo tags: pixel scale, tie point and a GeoKeyDirectory.
fn tiled_tiff(width: u32, height: u32, tile: u32, samples: u16, planar: bool, geo: bool) -> Vec<u8> {
    let across = width.div_ceil(tile);
    let down = height.div_ceil(tile);
    let planes = if planar { u32::from(samples) } else { 1 };
    let spp_in_tile = if planar { 1 } else { u32::from(samples) };
    let tile_bytes = tile * tile * spp_in_tile * 2;
    let tile_count = across * down * planes;

    // Pixel data first, right after the 8-byte header.
    let mut out = Vec::new();
    out.extend_from_slice(b"II*\0");
    out.extend_from_slice(&0u32.to_le_bytes()); // IFD offset, patched below
    let mut offsets = Vec::new();
    for plane in 0..planes {
        for ty in 0..down {
            for tx in 0..across {
                offsets.push(out.len() as u32);
                for row in 0..tile {
                    for col in 0..tile {
                        for s in 0..spp_in_tile {
                            let (x, y) = (tx * tile + col, ty * tile + row);
                            let sample = if planar { plane } else { s };
                            let v = if x < width && y < height {
                                value(x, y) as u16 + 1000 * sample as u16
                            } else {
                                0xdead // padding, must never be emitted
                            };
                            out.extend_from_slice(&v.to_le_bytes());
                        }
                    }
                }
            }
        }
    }
    // Out-of-line arrays.
    let offsets_at = out.len() as u32;
    for o in &offsets {
        out.extend_from_slice(&o.to_le_bytes());
    }
    let counts_at = out.len() as u32;
    for _ in 0..tile_count {
        out.extend_from_slice(&tile_bytes.to_le_bytes());
    }
    let bits_at = out.len() as u32;
    for _ in 0..samples {
        out.extend_from_slice(&16u16.to_le_bytes());
    }
    let scale_at = out.len() as u32;
    for v in [0.5f64, 0.25, 0.0] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    let tie_at = out.len() as u32;
    for v in [0.0f64, 0.0, 0.0, 8.0, 47.0, 0.0] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    let keys_at = out.len() as u32;
    for v in [1u16, 1, 0, 1, 1024, 0, 1, 2] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    if out.len() % 2 == 1 {
        out.push(0);
    }
    let ifd_at = out.len() as u32;
    out[4..8].copy_from_slice(&ifd_at.to_le_bytes());

    // (tag, type, count, value or offset); types: 3 SHORT, 4 LONG, 12 DOUBLE.
    let mut entries: Vec<(u16, u16, u32, u32)> = vec![
        (256, 4, 1, width),
        (257, 4, 1, height),
        (
            258,
            3,
            u32::from(samples),
            match samples {
                1 => 16,
                2 => 16 | 16 << 16, // two SHORTs fit inline
                _ => bits_at,
            },
        ),
        (259, 3, 1, 1),
        (262, 3, 1, 1),
        (277, 3, 1, u32::from(samples)),
        (284, 3, 1, if planar { 2 } else { 1 }),
        (322, 4, 1, tile),
        (323, 4, 1, tile),
        (324, 4, tile_count, if tile_count == 1 { offsets[0] } else { offsets_at }),
        (325, 4, tile_count, if tile_count == 1 { tile_bytes } else { counts_at }),
    ];
    if samples > 1 {
        entries.push((338, 3, 1, 0)); // ExtraSamples: unspecified
    }
    if geo {
        entries.push((33550, 12, 3, scale_at));
        entries.push((33922, 12, 6, tie_at));
        entries.push((34735, 3, 8, keys_at));
    }
    entries.sort_by_key(|e| e.0);
    out.extend_from_slice(&(entries.len() as u16).to_le_bytes());
    for (tag, ty, count, v) in entries {
        out.extend_from_slice(&tag.to_le_bytes());
        out.extend_from_slice(&ty.to_le_bytes());
        out.extend_from_slice(&count.to_le_bytes());
        if ty == 3 && count == 1 {
            out.extend_from_slice(&(v as u16).to_le_bytes());
            out.extend_from_slice(&[0, 0]);
        } else {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out.extend_from_slice(&0u32.to_le_bytes());
    out
}

fn check_tiled(bytes: &[u8], width: u32, height: u32, name: &str) -> Grid {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).unwrap();
    let g = read(&path, None);
    assert_eq!((g.info.width, g.info.height), (width, height));
    for y in 0..height {
        for x in 0..width {
            assert_eq!(g.at(x, y), value(x, y) as f64, "{name} ({x}, {y})");
        }
    }
    g
}

#[test]
fn tiff_tiled_with_partial_edge_tiles() {
    // 5 x 3 in 4 x 4 tiles: the right tile has 1 valid column, both have 3 valid rows.
    let g = check_tiled(&tiled_tiff(5, 3, 4, 1, false, false), 5, 3, "tiled.tif");
    assert_eq!(g.info.spacing, None);
    check_tiled(&tiled_tiff(9, 10, 4, 1, false, false), 9, 10, "tiled_3x3.tif");
    check_tiled(&tiled_tiff(3, 2, 16, 1, false, false), 3, 2, "one_tile.tif");
}

#[test]
fn tiff_tiled_multi_sample_chunky_and_planar() {
    check_tiled(&tiled_tiff(5, 3, 4, 2, false, false), 5, 3, "chunky2.tif");
    check_tiled(&tiled_tiff(5, 3, 4, 2, true, false), 5, 3, "planar2.tif");
    check_tiled(&tiled_tiff(6, 9, 4, 3, true, false), 6, 9, "planar3.tif");
}

#[test]
fn tiff_geographic_spacing() {
    // Pixel scale 0.5° x 0.25°, tie point (0, 0) -> (8°E, 47°N), 8 rows: the centre is at
    // 47 - 0.25 * 4 = 46°N.
    let g = check_tiled(&tiled_tiff(5, 8, 4, 1, false, true), 5, 8, "geo.tif");
    assert_eq!(g.info.spacing, Some(SourceSpacing::Degrees { x: 0.5, y: 0.25, centre_lat_deg: 46.0 }));
}

// PNG -----------------------------------------------------------------------------------------

fn write_png(path: &Path, w: u32, h: u32, colour: png::ColorType, depth: png::BitDepth, data: &[u8]) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut encoder = png::Encoder::new(file, w, h);
    encoder.set_color(colour);
    encoder.set_depth(depth);
    let mut writer = encoder.write_header().unwrap();
    writer.write_image_data(data).unwrap();
    writer.finish().unwrap();
}

#[test]
fn png_gray8_gray16_and_alpha() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (5u32, 4u32);

    let p8 = dir.path().join("gray8.png");
    let data: Vec<u8> = (0..h).flat_map(|y| (0..w).map(move |x| value(x, y) as u8)).collect();
    write_png(&p8, w, h, png::ColorType::Grayscale, png::BitDepth::Eight, &data);
    let g = read(&p8, None);
    assert_eq!(g.info.format, DemFormat::Png);
    assert_eq!(g.info.sample_type, "uint8 gray");
    assert_eq!(g.at(4, 3), value(4, 3) as f64);
    assert_eq!(g.nan_count(), 0);

    let p16 = dir.path().join("gray16.png");
    let data: Vec<u8> =
        (0..h).flat_map(|y| (0..w).flat_map(move |x| (value(x, y) as u16 * 1000).to_be_bytes())).collect();
    write_png(&p16, w, h, png::ColorType::Grayscale, png::BitDepth::Sixteen, &data);
    let g = read(&p16, None);
    assert_eq!(g.info.sample_type, "uint16 gray");
    for y in 0..h {
        for x in 0..w {
            assert_eq!(g.at(x, y), (value(x, y) * 1000) as f64);
        }
    }

    let pa = dir.path().join("gray_alpha.png");
    let data: Vec<u8> = (0..h)
        .flat_map(|y| (0..w).flat_map(move |x| [value(x, y) as u8, if (x, y) == (2, 1) { 0 } else { 255 }]))
        .collect();
    write_png(&pa, w, h, png::ColorType::GrayscaleAlpha, png::BitDepth::Eight, &data);
    let g = read(&pa, None);
    assert!(g.at(2, 1).is_nan());
    assert_eq!(g.nan_count(), 1);
    assert_eq!(g.at(3, 1), value(3, 1) as f64);
}

fn terrain_rgb_pixel(h: f64) -> [u8; 3] {
    let v = ((h + 10000.0) * 10.0).round() as u32;
    [(v >> 16) as u8, (v >> 8) as u8, v as u8]
}

fn terrarium_pixel(h: f64) -> [u8; 3] {
    let v = h + 32768.0;
    [(v / 256.0).floor() as u8, (v.floor() as u32 % 256) as u8, (v.fract() * 256.0) as u8]
}

/// Heights exactly representable in both encodings (multiples of 0.5 m... and of 1/256).
const HEIGHTS: [f64; 6] = [0.0, 123.5, 3776.0, -50.5, 2489.0, 715.5];

fn write_encoded(path: &Path, encode: fn(f64) -> [u8; 3], alpha: bool) {
    // 3 x 2 pixels of HEIGHTS; with alpha, the last pixel is transparent.
    let mut data = Vec::new();
    for (k, &h) in HEIGHTS.iter().enumerate() {
        data.extend_from_slice(&encode(h));
        if alpha {
            data.push(if k == 5 { 0 } else { 255 });
        }
    }
    let colour = if alpha { png::ColorType::Rgba } else { png::ColorType::Rgb };
    write_png(path, 3, 2, colour, png::BitDepth::Eight, &data);
}

fn check_encoded(path: &Path, format: DemFormat, alpha: bool) {
    let g = read(path, None);
    assert_eq!(g.info.format, format, "{}", path.display());
    for (k, &h) in HEIGHTS.iter().enumerate() {
        if alpha && k == 5 {
            assert!(g.values[k].is_nan());
        } else {
            assert_close(g.values[k], h, 1e-6, "decoded height");
        }
    }
}

#[test]
fn png_terrain_rgb_and_terrarium_by_name_and_content() {
    let dir = tempfile::tempdir().unwrap();
    let d = |n: &str| dir.path().join(n);
    // By content (neutral names).
    write_encoded(&d("a.png"), terrain_rgb_pixel, false);
    check_encoded(&d("a.png"), DemFormat::TerrainRgb, false);
    write_encoded(&d("b.png"), terrarium_pixel, true);
    check_encoded(&d("b.png"), DemFormat::Terrarium, true);
    write_encoded(&d("c.png"), terrain_rgb_pixel, true);
    check_encoded(&d("c.png"), DemFormat::TerrainRgb, true);
    // By name: the hint wins even over content that suggests the other encoding.
    write_encoded(&d("tile_terrarium.png"), terrarium_pixel, false);
    check_encoded(&d("tile_terrarium.png"), DemFormat::Terrarium, false);
    write_encoded(&d("Mapbox_Terrain-RGB.png"), terrain_rgb_pixel, false);
    check_encoded(&d("Mapbox_Terrain-RGB.png"), DemFormat::TerrainRgb, false);
    let g = read(&d("a.png"), Some(DemFormat::Terrarium));
    assert_eq!(g.info.format, DemFormat::Terrarium);
}

#[test]
fn png_detection_and_forced_mismatches() {
    let dir = tempfile::tempdir().unwrap();
    let gray = dir.path().join("gray.png");
    write_png(&gray, 2, 2, png::ColorType::Grayscale, png::BitDepth::Eight, &[1, 2, 3, 4]);
    let m = read_error(&gray, Some(DemFormat::TerrainRgb));
    assert!(m.contains("grayscale"), "{m}");
    let rgb = dir.path().join("rgb.png");
    write_encoded(&rgb, terrain_rgb_pixel, false);
    let m = read_error(&rgb, Some(DemFormat::Png));
    assert!(m.contains("colour PNG"), "{m}");
    let palette = dir.path().join("palette.png");
    {
        let file = std::fs::File::create(&palette).unwrap();
        let mut encoder = png::Encoder::new(file, 2, 1);
        encoder.set_color(png::ColorType::Indexed);
        encoder.set_palette(vec![0u8, 0, 0, 255, 255, 255]);
        let mut writer = encoder.write_header().unwrap();
        writer.write_image_data(&[0, 1]).unwrap();
    }
    let m = read_error(&palette, None);
    assert!(m.contains("unsupported") && m.contains("palette"), "{m}");
}

#[test]
fn png_corrupted_idat() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("corrupt.png");
    let data: Vec<u8> = (0..64 * 64).map(|i| (i % 251) as u8).collect();
    write_png(&path, 64, 64, png::ColorType::Grayscale, png::BitDepth::Eight, &data);
    let mut bytes = std::fs::read(&path).unwrap();
    let idat = bytes.windows(4).position(|w| w == b"IDAT").unwrap();
    for b in &mut bytes[idat + 10..idat + 20] {
        *b ^= 0x5a;
    }
    std::fs::write(&path, &bytes).unwrap();
    let m = read_error(&path, None);
    assert!(m.contains("PNG"), "{m}");
}

// OpenEXR -------------------------------------------------------------------------------------

fn write_exr(
    path: &Path,
    w: usize,
    h: usize,
    channels: Vec<exr::prelude::AnyChannel<exr::prelude::FlatSamples>>,
    encoding: exr::prelude::Encoding,
) {
    use exr::prelude::*;
    let layer = Layer::new((w, h), LayerAttributes::named("height"), encoding, AnyChannels::sort(channels.into()));
    Image::from_layer(layer).write().to_file(path).unwrap();
}

#[test]
fn exr_f32_f16_u32_scanlines_and_tiles() {
    use exr::prelude::*;
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (7usize, 37usize);
    let heights: Vec<f32> = (0..h).flat_map(|y| (0..w).map(move |x| value(x as u32, y as u32) as f32 * 0.5)).collect();
    let mut with_nan = heights.clone();
    with_nan[3] = f32::NAN;
    with_nan[4] = f32::INFINITY;
    let tiles = Encoding {
        compression: Compression::ZIP1,
        blocks: Blocks::Tiles(Vec2(4, 4)),
        line_order: LineOrder::Unspecified,
    };

    let cases = [
        (
            "f32.exr",
            vec![AnyChannel::new("Z", FlatSamples::F32(with_nan.clone()))],
            Encoding::SMALL_LOSSLESS,
            "float32 channel Z",
        ),
        ("f32_tiles.exr", vec![AnyChannel::new("Z", FlatSamples::F32(with_nan.clone()))], tiles, "float32 channel Z"),
        (
            "f16.exr",
            vec![AnyChannel::new("Y", FlatSamples::F16(with_nan.iter().map(|&v| f16::from_f32(v)).collect()))],
            Encoding::UNCOMPRESSED,
            "float16 channel Y",
        ),
        (
            "u32.exr",
            vec![AnyChannel::new("depth", FlatSamples::U32(heights.iter().map(|&v| (v * 2.0) as u32).collect()))],
            Encoding::FAST_LOSSLESS,
            "uint32 channel depth",
        ),
        // Several channels: "height" is chosen over "A" and "B".
        (
            "multi.exr",
            vec![
                AnyChannel::new("A", FlatSamples::F32(vec![-1.0; w * h])),
                AnyChannel::new("B", FlatSamples::F16(vec![f16::from_f32(-2.0); w * h])),
                AnyChannel::new("height", FlatSamples::F32(with_nan.clone())),
            ],
            tiles,
            "float32 channel height",
        ),
    ];
    for (name, channels, encoding, sample_type) in cases {
        let path = dir.path().join(name);
        write_exr(&path, w, h, channels, encoding);
        let g = crate::dem_readers::read(&path, None);
        assert_eq!(g.info.format, DemFormat::Exr, "{name}");
        assert_eq!((g.info.width, g.info.height), (w as u32, h as u32), "{name}");
        assert_eq!(g.info.sample_type, sample_type, "{name}");
        for (k, &v) in heights.iter().enumerate() {
            let want = if name == "u32.exr" { f64::from(v * 2.0) } else { f64::from(v) };
            if name != "u32.exr" && (k == 3 || k == 4) {
                assert!(g.values[k].is_nan(), "{name} sample {k}");
            } else {
                assert_eq!(g.values[k], want, "{name} sample {k}");
            }
        }
    }
}

// SRTM .hgt ------------------------------------------------------------------------------------

fn hgt_bytes(side: u32, voids: &[(u32, u32)]) -> Vec<u8> {
    let mut out = Vec::with_capacity((2 * side * side) as usize);
    for y in 0..side {
        for x in 0..side {
            let v = if voids.contains(&(x, y)) { -32768 } else { (x as i32 - y as i32) as i16 };
            out.extend_from_slice(&v.to_be_bytes());
        }
    }
    out
}

#[test]
fn hgt_tiles() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("N47E008.hgt");
    std::fs::write(&path, hgt_bytes(1201, &[(0, 0), (600, 700)])).unwrap();
    let g = read(&path, None);
    assert_eq!(g.info.format, DemFormat::Hgt);
    assert_eq!((g.info.width, g.info.height), (1201, 1201));
    assert_eq!(g.info.spacing, Some(SourceSpacing::Degrees { x: 1.0 / 1200.0, y: 1.0 / 1200.0, centre_lat_deg: 47.5 }));
    assert_eq!(g.nan_count(), 2);
    assert!(g.at(600, 700).is_nan());
    assert_eq!(g.at(1200, 3), 1197.0);
    assert_eq!(g.at(5, 1200), -1195.0);

    // Any square side, lower-case southern name; detection by extension.
    let small = dir.path().join("s12w077.HGT");
    std::fs::write(&small, hgt_bytes(3, &[])).unwrap();
    let g = read(&small, None);
    assert_eq!(g.info.spacing, Some(SourceSpacing::Degrees { x: 0.5, y: 0.5, centre_lat_deg: -11.5 }));
    assert_eq!(g.values, vec![0.0, 1.0, 2.0, -1.0, 0.0, 1.0, -2.0, -1.0, 0.0]);

    // Unparseable name: no spacing. Detection by size alone (2·1201² bytes, no extension).
    let plain = dir.path().join("tile.bin");
    std::fs::write(&plain, hgt_bytes(1201, &[])).unwrap();
    let g = read(&plain, None);
    assert_eq!(g.info.format, DemFormat::Hgt);
    assert_eq!(g.info.spacing, None);

    let bad = dir.path().join("N00E000.hgt");
    std::fs::write(&bad, vec![0u8; 2 * 1201 * 1201 - 2]).unwrap();
    let m = read_error(&bad, None);
    assert!(m.contains("not that of a square .hgt tile"), "{m}");
}

// ESRI ASCII grid --------------------------------------------------------------------------------

#[test]
fn asc_wrapped_rows_nodata_and_header_variants() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("grid.asc");
    // 4 x 3, keys in odd order and case, centre-registered, rows wrapped across lines.
    let text = "NROWS 3\nncols   4\nCellSize 2.5\nxllcenter 100\nYLLCENTER 200\nnodata_value -1\n\
                1 2 3\n4 5\n-1 7 8 9 10\n11\n12\n";
    std::fs::write(&path, text).unwrap();
    let g = read(&path, None);
    assert_eq!(g.info.format, DemFormat::Asc);
    assert_eq!((g.info.width, g.info.height), (4, 3));
    assert_eq!(g.info.nodata, Some(-1.0));
    assert_eq!(g.info.spacing, Some(SourceSpacing::Metres { x: 2.5, y: 2.5 }));
    assert!(g.values[5].is_nan());
    let rest: Vec<f64> = g.values.iter().copied().filter(|v| !v.is_nan()).collect();
    assert_eq!(rest, vec![1.0, 2.0, 3.0, 4.0, 5.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0]);

    // A geographic .prj turns the spacing into degrees; dx/dy instead of cellsize.
    let geo = dir.path().join("geo.asc");
    std::fs::write(&geo, "ncols 2\nnrows 2\nxllcorner 8\nyllcorner 46\ndx 0.5\ndy 0.25\n1 2\n3 4\n").unwrap();
    std::fs::write(dir.path().join("geo.prj"), "GEOGCS[\"WGS 84\",DATUM[\"WGS_1984\"]]").unwrap();
    let g = read(&geo, None);
    assert_eq!(g.info.nodata, None);
    assert_eq!(g.info.spacing, Some(SourceSpacing::Degrees { x: 0.5, y: 0.25, centre_lat_deg: 46.25 }));
    assert_eq!(g.values, vec![1.0, 2.0, 3.0, 4.0]);
}

#[test]
fn asc_errors_say_what_and_where() {
    let dir = tempfile::tempdir().unwrap();
    let case = |name: &str, text: &str| {
        let path = dir.path().join(name);
        std::fs::write(&path, text).unwrap();
        read_error(&path, Some(DemFormat::Asc))
    };
    let header = "ncols 3\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n";
    let m = case("no_cellsize.asc", "ncols 3\nnrows 2\nxllcorner 0\nyllcorner 0\n1 2 3\n4 5 6\n");
    assert!(m.contains("'cellsize' missing"), "{m}");
    let m = case("not_number.asc", &format!("{header}1 2 3\n4 abc 6\n"));
    assert!(m.contains("line 7: 'abc' is not a number"), "{m}");
    let m = case("too_few.asc", &format!("{header}1 2 3\n4 5\n"));
    assert!(m.contains("expected 6 values (3 x 2), found 5"), "{m}");
    let m = case("too_many.asc", &format!("{header}1 2 3\n4 5 6 7\n"));
    assert!(m.contains("more than the 6 values"), "{m}");
    let m = case("bad_ncols.asc", "ncols -3\nnrows 2\n");
    assert!(m.contains("line 1: ncols '-3' is not a positive integer"), "{m}");
    let m = case("huge.asc", "ncols 4000000000\nnrows 4000000000\nxllcorner 0\nyllcorner 0\ncellsize 1\n1\n");
    assert!(m.contains("absurd dimensions"), "{m}");
}

// Malformed input -------------------------------------------------------------------------------

#[test]
fn unknown_empty_and_missing_files() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("empty.tif");
    std::fs::write(&empty, b"").unwrap();
    let m = read_error(&empty, None);
    assert!(m.contains("unknown DEM format") && m.contains("empty file"), "{m}");

    let random = dir.path().join("noise.xyz");
    std::fs::write(&random, [0u8, 1, 2, 3, 4, 5, 6, 7, 8]).unwrap();
    let m = read_error(&random, None);
    assert!(m.contains("first bytes 00 01 02 03, extension .xyz"), "{m}");

    let missing = dir.path().join("missing.tif");
    match dem::open(&missing, None) {
        Err(e @ relief_core::Error::Io { .. }) => assert!(e.to_string().contains("missing.tif")),
        Err(e) => panic!("wrong error {e}"),
        Ok(_) => panic!("opened a missing file"),
    }
}

#[test]
fn truncated_real_files_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    for name in common::REAL_DEMS {
        let bytes = std::fs::read(data(name)).unwrap();
        // (Not "all but the last byte": in lidar's padded edge tiles that byte is never needed.)
        for len in [100, bytes.len() / 2, bytes.len() * 3 / 4] {
            let path = dir.path().join(name);
            std::fs::write(&path, &bytes[..len]).unwrap();
            let m = read_error(&path, None);
            eprintln!("{name}[..{len}]: {m}");
        }
    }
}

#[test]
fn forced_formats_that_do_not_match() {
    for (name, format) in [
        ("zurich_25m_i16.tif", DemFormat::Png),
        ("zurich_25m_i16.tif", DemFormat::Asc),
        ("zurich_25m_i16.tif", DemFormat::Exr),
        ("zurich_25m_i16.tif", DemFormat::Hgt),
        ("terrarium.png", DemFormat::GeoTiff),
        ("hugo_site_nodata.asc", DemFormat::Terrarium),
        ("hugo_site_nodata.asc", DemFormat::GeoTiff),
    ] {
        let m = read_error(&data(name), Some(format));
        eprintln!("{name} as {format}: {m}");
    }
}

/// Truncated and bit-flipped fixtures must give `Ok` or an error naming the file, never a panic.
#[test]
fn mutated_fixtures_never_panic() {
    use std::panic::{catch_unwind, AssertUnwindSafe};
    use tiff::encoder::colortype::GrayI16;
    use tiff::encoder::{Compression, DeflateLevel};

    let dir = tempfile::tempdir().unwrap();
    let d = |n: &str| dir.path().join(n);

    // The fixtures.
    tiff_fixtures::write::<GrayI16>(&d("strips.tif"), Compression::Deflate(DeflateLevel::Fast), "3", |v| v as i16);
    tiff_fixtures::write::<GrayI16>(&d("lzw.tif"), Compression::Lzw, "3", |v| v as i16);
    std::fs::write(d("tiled.tif"), tiled_tiff(5, 3, 4, 2, true, true)).unwrap();
    let gray16: Vec<u8> = (0..6 * 5u16).flat_map(|v| (v * 300).to_be_bytes()).collect();
    write_png(&d("gray16.png"), 6, 5, png::ColorType::Grayscale, png::BitDepth::Sixteen, &gray16);
    write_encoded(&d("rgba.png"), terrain_rgb_pixel, true);
    {
        use exr::prelude::*;
        let tiles = Encoding {
            compression: Compression::ZIP1,
            blocks: Blocks::Tiles(Vec2(4, 4)),
            line_order: LineOrder::Unspecified,
        };
        let samples: Vec<f32> = (0..7 * 6).map(|v| v as f32).collect();
        write_exr(&d("tiles.exr"), 7, 6, vec![AnyChannel::new("Z", FlatSamples::F32(samples.clone()))], tiles);
        write_exr(&d("lines.exr"), 7, 6, vec![AnyChannel::new("Y", FlatSamples::F32(samples))], Encoding::UNCOMPRESSED);
    }
    std::fs::write(
        d("grid.asc"),
        "ncols 3\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\nNODATA_value -9\n1 2 -9\n4 5 6\n",
    )
    .unwrap();
    std::fs::write(d("s12w077.hgt"), hgt_bytes(3, &[(1, 1)])).unwrap();

    let mut rng = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        rng
    };
    let mut failures = Vec::new();
    let mut errors = 0;
    let mut runs = 0;
    for name in [
        "strips.tif",
        "lzw.tif",
        "tiled.tif",
        "gray16.png",
        "rgba.png",
        "tiles.exr",
        "lines.exr",
        "grid.asc",
        "s12w077.hgt",
    ] {
        let original = std::fs::read(d(name)).unwrap();
        let target = dir.path().join("mutant").join(name);
        std::fs::create_dir_all(target.parent().unwrap()).unwrap();
        let mut mutants: Vec<(String, Vec<u8>)> = Vec::new();
        for k in 0..24 {
            let len = original.len() * k / 24;
            mutants.push((format!("first {len} bytes"), original[..len].to_vec()));
        }
        for _ in 0..250 {
            let mut bytes = original.clone();
            let mut what = Vec::new();
            for _ in 0..1 + next() % 3 {
                let at = (next() % bytes.len() as u64) as usize;
                let bit = 1u8 << (next() % 8);
                bytes[at] ^= bit;
                what.push(format!("byte {at} ^= {bit:#04x}"));
            }
            mutants.push((what.join(", "), bytes));
        }
        for (what, bytes) in mutants {
            std::fs::write(&target, &bytes).unwrap();
            for format in [None, Some(DemFormat::GeoTiff), Some(DemFormat::Png), Some(DemFormat::Exr)] {
                runs += 1;
                let outcome = catch_unwind(AssertUnwindSafe(|| {
                    dem::open(&target, format).and_then(|mut s| {
                        let mut n = 0u64;
                        s.read(&mut |run| {
                            n += run.values.len() as u64;
                            Ok(())
                        })
                    })
                }));
                match outcome {
                    Err(_) => failures.push(format!("{name} ({what}) as {format:?}: panicked")),
                    Ok(Err(e)) => {
                        errors += 1;
                        let m = e.to_string();
                        if !m.contains(name) || m.contains('\n') {
                            failures.push(format!("{name} ({what}): bad message {m:?}"));
                        }
                    }
                    Ok(Ok(())) => {}
                }
            }
        }
    }
    eprintln!("{runs} runs, {errors} errors");
    assert!(failures.is_empty(), "{} failures:\n{}", failures.len(), failures.join("\n"));
}

/// Options out of range are typed errors with the limit, for callers that act on them.
#[test]
fn a_spacing_out_of_range_is_a_typed_error_with_its_limit() {
    use relief_core::preprocess::convert::{convert, ConvertOptions};
    use relief_core::Error;
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("z.relief");
    let mut options = ConvertOptions::new(relief_core::layout::LayoutKind::Interleaved);
    options.spacing_m = Some([25.0, -1.0]);
    let e = convert(&common::dem("zurich_25m_i16.tif"), &out, &options).unwrap_err();
    assert!(
        matches!(&e, Error::OutOfRange { what: "post spacing", allowed, got } if allowed == "positive metres" && got == "25,-1"),
        "{e:?}"
    );
    assert_eq!(e.to_string(), "post spacing must be positive metres, got 25,-1");
    assert!(!out.exists(), "no output");
}
