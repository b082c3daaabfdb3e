//! DEM readers: the real files in `../shared/data/dem`, fixtures written here for every format and
//! sample type, and malformed input (which must give an error naming the file, never a panic).

use std::collections::HashSet;
use std::io::Write;
use std::path::{Path, PathBuf};

use relief::dem::{self, DemFormat, DemInfo, SourceSpacing};

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data/dem");

fn data(name: &str) -> PathBuf {
    Path::new(DATA).join(name)
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
