//! Compressed GeoTIFFs cut from the real DEMs (fixtures in `tests/compressed_tiffs`): ZSTD, LZW and
//! Deflate, with the horizontal (2) and floating-point (3) predictors, in strips and tiles, decode
//! natively to exactly the heights of the uncompressed originals in `../shared/data/dem`; LERC and
//! LZMA need the `gdal` feature (refused with one line naming the file and the compression
//! without it, the same heights with it).
//!
//! The fixtures were written by GDAL 3.6.2 (Debian's gdal-bin) from the real files:
//!
//! ```text
//! Z=zurich_25m_i16.tif  ZW="-srcwin 200 100 96 80"
//! L=lidar_1m_f32.tif    LW="-srcwin 100 100 64 64"
//! T="-co TILED=YES -co BLOCKXSIZE=32 -co BLOCKYSIZE=32"
//! gdal_translate $ZW -co COMPRESS=ZSTD                      $Z zurich_zstd.tif
//! gdal_translate $ZW -co COMPRESS=ZSTD -co PREDICTOR=2 $T   $Z zurich_zstd_p2_tiled.tif
//! gdal_translate $ZW -co COMPRESS=LZW -co PREDICTOR=2       $Z zurich_lzw_p2.tif
//! gdal_translate $ZW -co COMPRESS=DEFLATE -co PREDICTOR=2   $Z zurich_deflate_p2.tif
//! gdal_translate $LW -co COMPRESS=ZSTD -co PREDICTOR=3      $L lidar_zstd_p3.tif
//! gdal_translate $LW -co COMPRESS=ZSTD -co PREDICTOR=2 $T   $L lidar_zstd_p2_tiled.tif
//! gdal_translate $LW -co COMPRESS=LZW -co PREDICTOR=3       $L lidar_lzw_p3.tif
//! gdal_translate $LW -co COMPRESS=DEFLATE -co PREDICTOR=3 $T $L lidar_deflate_p3_tiled.tif
//! gdal_translate -srcwin 200 100 16 16 -co COMPRESS=LERC      $Z zurich_lerc.tif
//! gdal_translate -srcwin 200 100 16 16 -co COMPRESS=LERC_ZSTD $Z zurich_lerc_zstd.tif
//! gdal_translate -srcwin 200 100 16 16 -co COMPRESS=LZMA      $Z zurich_lzma.tif
//! ```

use crate::common;

use std::path::{Path, PathBuf};

use relief_core::dem::{self, DemInfo};

/// A fixture in `tests/compressed_tiffs`.
fn fixture(name: &str) -> PathBuf {
    // This crate is src/core of the checkout.
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/compressed_tiffs").join(name)
}

/// Header and samples (row-major, row 0 north, NaN for nodata) of a DEM.
fn read(path: &Path) -> (DemInfo, Vec<f64>) {
    let mut source = dem::open(path, None).unwrap_or_else(|e| panic!("open: {e}"));
    let info = source.info().clone();
    let w = info.width as usize;
    let mut values = vec![f64::NAN; w * info.height as usize];
    let mut count = 0usize;
    source
        .read(&mut |run| {
            let at = run.row as usize * w + run.x0 as usize;
            values[at..at + run.values.len()].copy_from_slice(run.values);
            count += run.values.len();
            Ok(())
        })
        .unwrap_or_else(|e| panic!("read {}: {e}", path.display()));
    assert_eq!(count, values.len(), "{}: samples delivered", path.display());
    (info, values)
}

/// Checks that `copy` holds exactly the window of `original` at column `x0`, row `y0` (from the
/// north): the same header (sample type, spacing, nodata, CRS), the window's placement, and
/// bit-identical heights.
fn check_window(copy: &Path, original: &str, x0: u32, y0: u32, want_type: &str) {
    let (orig_info, orig) = read(&common::dem(original));
    let (info, values) = read(copy);
    let name = copy.file_name().unwrap().to_string_lossy();
    let (w, h) = (info.width, info.height);
    assert!(w > 0 && h > 0 && x0 + w <= orig_info.width && y0 + h <= orig_info.height, "{name}: {w} x {h}");
    assert_eq!(info.format, orig_info.format, "{name}");
    assert_eq!(info.sample_type, want_type, "{name}");
    assert_eq!(info.sample_type, orig_info.sample_type, "{name}");
    assert_eq!(info.spacing, orig_info.spacing, "{name}");
    // GDAL rewrites the GDAL_NODATA text (`-3.402823e+38` becomes `-3.4028230607370965e+38`): the
    // same value as a float32 sample.
    let as_f32 = |v: Option<f64>| v.map(|v| v as f32);
    assert_eq!(as_f32(info.nodata), as_f32(orig_info.nodata), "{name}");
    let (g, og) = (info.georef.as_ref().unwrap(), orig_info.georef.as_ref().unwrap());
    assert_eq!((g.kind, g.epsg, g.unit, g.step), (og.kind, og.epsg, og.unit, og.step), "{name}");
    // Post (0, 0) is the south-west one: the window's is the original's column x0, row y0 + h - 1.
    let want_origin =
        [og.origin[0] + f64::from(x0) * og.step[0], og.origin[1] + f64::from(orig_info.height - y0 - h) * og.step[1]];
    for k in 0..2 {
        assert!((g.origin[k] - want_origin[k]).abs() < 1e-6, "{name}: origin {:?}, want {want_origin:?}", g.origin);
    }
    let mut distinct = std::collections::HashSet::new();
    for y in 0..h {
        for x in 0..w {
            let v = values[(y * w + x) as usize];
            let o = orig[((y0 + y) * orig_info.width + x0 + x) as usize];
            assert!(v.to_bits() == o.to_bits(), "{name}: ({x}, {y}) is {v}, the original {o}");
            distinct.insert(v.to_bits());
        }
    }
    // Real terrain, not a constant: the predictors and codecs had something to get wrong.
    assert!(distinct.len() > 10, "{name}: only {} distinct heights", distinct.len());
}

#[test]
fn zstd_lzw_and_deflate_with_predictors_decode_to_the_original_heights() {
    for name in ["zurich_zstd.tif", "zurich_zstd_p2_tiled.tif", "zurich_lzw_p2.tif", "zurich_deflate_p2.tif"] {
        check_window(&fixture(name), "zurich_25m_i16.tif", 200, 100, "int16");
    }
    for name in ["lidar_zstd_p3.tif", "lidar_zstd_p2_tiled.tif", "lidar_lzw_p3.tif", "lidar_deflate_p3_tiled.tif"] {
        check_window(&fixture(name), "lidar_1m_f32.tif", 100, 100, "float32");
    }
}

/// A ZSTD strip cut short, or with its bytes flipped: an error naming the file, or (for a flip
/// the codec cannot see) some heights; never a panic.
#[test]
fn damaged_zstd_tiffs_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(fixture("zurich_zstd.tif")).unwrap();
    let path = dir.path().join("damaged_zstd.tif");
    std::fs::write(&path, &bytes).unwrap();
    let (info, _) = read(&path);
    assert_eq!((info.width, info.height), (96, 80), "the intact copy");
    for cut in [bytes.len() / 2, bytes.len() - 100] {
        std::fs::write(&path, &bytes[..cut]).unwrap();
        let e = dem::open(&path, None).and_then(|mut s| s.read(&mut |_| Ok(()))).expect_err("a truncated file");
        let e = e.to_string();
        assert!(e.contains("damaged_zstd.tif") && !e.contains('\n'), "{e}");
    }
    // The image data follow the header GDAL writes first; flip bytes in the middle of the strips.
    for at in (bytes.len() / 2..bytes.len()).step_by(397) {
        let mut damaged = bytes.clone();
        damaged[at] ^= 0x5a;
        std::fs::write(&path, &damaged).unwrap();
        if let Err(e) = dem::open(&path, None).and_then(|mut s| s.read(&mut |_| Ok(()))) {
            let e = e.to_string();
            assert!(e.contains("damaged_zstd.tif") && !e.contains('\n'), "{e}");
        }
    }
}

/// LERC (plain or with ZSTD inside) and LZMA are GDAL's to decode: without the `gdal` feature
/// they are refused with one line naming the file and the compression and saying what to do.
#[cfg(not(feature = "gdal"))]
#[test]
fn without_gdal_lerc_and_lzma_are_refused_by_name() {
    for (name, codec) in [("zurich_lerc.tif", "LERC"), ("zurich_lerc_zstd.tif", "LERC"), ("zurich_lzma.tif", "LZMA")] {
        let path = fixture(name);
        let e = dem::open(&path, None).err().unwrap_or_else(|| panic!("{name} opened without GDAL"));
        assert_eq!(
            e.to_string(),
            format!(
                "{}: unsupported TIFF compression {codec}: reading it needs GDAL: build relief with \
                 `--features gdal` (and Debian's libgdal-dev)",
                path.display()
            )
        );
    }
}

/// With the `gdal` feature, the lossless LERC and LZMA copies decode to the original heights too.
#[cfg(feature = "gdal")]
#[test]
fn with_gdal_lerc_and_lzma_decode_to_the_original_heights() {
    for name in ["zurich_lerc.tif", "zurich_lerc_zstd.tif", "zurich_lzma.tif"] {
        check_window(&fixture(name), "zurich_25m_i16.tif", 200, 100, "int16");
    }
}
