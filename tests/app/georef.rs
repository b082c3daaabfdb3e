//! Coordinate systems kept end to end (issue 21): what `info` says of a real DEM's CRS, units and
//! placement is what GDAL's `gdalinfo` says of the same file (Debian's gdal-bin, which the test
//! command installs); a feet-based DEM (a real one with its CRS rewritten by `gdal_translate`)
//! converts to metres; `--crs-coords` places a camera given in the CRS where local metres would.

use crate::common;

use common::{dem, relief, stderr_of};
use std::path::Path;
use std::process::Command;

use serde_json::Value;

/// `gdalinfo -json FILE`: the test needs GDAL's own reading to compare with.
fn gdalinfo(file: &Path) -> Value {
    let out = Command::new("gdalinfo")
        .arg("-json")
        .arg(file)
        .output()
        .expect("gdalinfo (Debian's gdal-bin) is needed by this test; tools/test.sh installs it");
    assert!(out.status.success(), "gdalinfo {}: {}", file.display(), stderr_of(&out));
    serde_json::from_slice(&out.stdout).unwrap()
}

fn info(file: &Path) -> Value {
    let out = relief().args(["info", "--json"]).arg(file).output().unwrap();
    assert!(out.status.success(), "{}", stderr_of(&out));
    serde_json::from_slice(&out.stdout).unwrap()
}

fn convert(src: &Path, out: &Path) {
    let o = convert_with(src, out, &[]);
    assert!(o.status.success(), "{}", stderr_of(&o));
}

/// The name of the last unit in a WKT2 CRS: the unit of its last axis.
fn last_wkt_unit(wkt: &str) -> String {
    let at = wkt.rfind("UNIT[\"").expect("a unit in the WKT") + 6;
    wkt[at..].split('"').next().unwrap().to_string()
}

fn close(a: f64, b: f64, what: &str) {
    assert!((a - b).abs() <= 1e-9 * a.abs().max(1.0), "{what}: relief {a}, GDAL {b}");
}

#[test]
fn info_names_the_crs_and_placement_gdal_reads() {
    let dir = tempfile::tempdir().unwrap();
    // (file, what GDAL names it: EPSG code or none)
    for (name, want_epsg) in
        [("lidar_1m_f32.tif", Some(26915)), ("etopo20_world.tif", Some(4326)), ("zurich_25m_i16.tif", None)]
    {
        let src = dem(name);
        let out = dir.path().join(format!("{name}.relief"));
        convert(&src, &out);
        let (ours, gdal) = (info(&out), gdalinfo(&src));
        let crs = &ours["crs"];
        let gdal_epsg = gdal["stac"]["proj:epsg"].as_u64();
        assert_eq!(gdal_epsg, want_epsg, "{name}: GDAL's reading changed");
        assert_eq!(crs["epsg"].as_u64(), gdal_epsg, "{name}: {crs}");
        match gdal["coordinateSystem"]["wkt"].as_str().filter(|w| !w.is_empty()) {
            Some(wkt) => {
                assert_eq!(crs["unit"].as_str(), Some(last_wkt_unit(wkt).as_str()), "{name}: {crs}");
                let kind = if wkt.starts_with("GEOGCRS") { "geographic" } else { "projected" };
                assert_eq!(crs["kind"], kind, "{name}");
                assert_eq!(crs["name"], format!("EPSG:{}", want_epsg.unwrap()));
            }
            None => assert_eq!(crs["kind"], "unknown", "{name}: GDAL names no CRS, {crs}"),
        }
        // Placement: GDAL's geotransform gives the corner of the north-west pixel; relief's
        // origin is the centre of the south-west one (these files are PixelIsArea).
        let gt: Vec<f64> = gdal["geoTransform"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        let [w, h] = [0, 1].map(|k| gdal["size"][k].as_f64().unwrap());
        close(crs["origin"][0].as_f64().unwrap(), gt[0] + 0.5 * gt[1], name);
        close(crs["origin"][1].as_f64().unwrap(), gt[3] + (h - 0.5) * gt[5], name);
        close(crs["step"][0].as_f64().unwrap(), gt[1], name);
        close(crs["step"][1].as_f64().unwrap(), -gt[5], name);
        close(crs["extent"][2].as_f64().unwrap(), gt[0] + (w - 0.5) * gt[1], name);
        close(crs["extent"][3].as_f64().unwrap(), gt[3] + 0.5 * gt[5], name);
        // The data's extent comes first and is the valid window's, not the padded grid's.
        let spacing: Vec<f64> = (0..2).map(|k| ours["spacing_m"][k].as_f64().unwrap()).collect();
        assert_eq!(ours["data_posts"], serde_json::json!([w as u32, h as u32]));
        close(ours["data_extent_m"][0].as_f64().unwrap(), (w - 1.0) * spacing[0], name);
        close(ours["data_extent_m"][1].as_f64().unwrap(), (h - 1.0) * spacing[1], name);
        assert!(ours["extent_m"][0].as_f64().unwrap() > ours["data_extent_m"][0].as_f64().unwrap());
    }
    // The text says it too, data first.
    let out = dir.path().join("lidar_1m_f32.tif.relief");
    let text = String::from_utf8(relief().arg("info").arg(&out).output().unwrap().stdout).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert!(lines[1].starts_with("data          400 x 400 posts, 399.0 x 399.0 m"), "{text}");
    assert!(text.contains("crs           EPSG:26915 (projected, metre)"), "{text}");
    assert!(text.contains("placement     south-west post at 429252.813, 5150485.925"), "{text}");
}

#[test]
fn a_dem_in_us_survey_feet_converts_to_metres() {
    let dir = tempfile::tempdir().unwrap();
    // The lidar DEM's numbers, relabelled as NAD83 / Florida East (ftUS) + NAVD88 height (ftUS):
    // GDAL writes the EPSG codes alone, no unit keys, so the units come from the codes.
    let feet = dir.path().join("lidar_ftus.tif");
    let o = Command::new("gdal_translate")
        .args(["-q", "-a_srs", "EPSG:2236+EPSG:6360"])
        .arg(dem("lidar_1m_f32.tif"))
        .arg(&feet)
        .output()
        .expect("gdal_translate (Debian's gdal-bin)");
    assert!(o.status.success(), "{}", stderr_of(&o));
    let gdal = gdalinfo(&feet);
    let wkt = gdal["coordinateSystem"]["wkt"].as_str().unwrap();
    assert!(wkt.starts_with("COMPOUNDCRS") && last_wkt_unit(wkt) == "US survey foot", "{wkt}");
    let (m, ft) = (dir.path().join("m.relief"), dir.path().join("ft.relief"));
    convert(&dem("lidar_1m_f32.tif"), &m);
    convert(&feet, &ft);
    let (m, ft) = (info(&m), info(&ft));
    let us_ft = 1200.0 / 3937.0;
    for k in 0..2 {
        close(ft["spacing_m"][k].as_f64().unwrap(), us_ft * m["spacing_m"][k].as_f64().unwrap(), "spacing");
    }
    // Heights are stored as f32 metres: within f32 rounding of the metres × 0.3048006.
    for key in ["z_min", "z_max"] {
        let (a, b) = (ft[key].as_f64().unwrap(), us_ft * m[key].as_f64().unwrap());
        assert!((a - b).abs() < 1e-4, "{key}: {a} against {b}");
    }
    let crs = &ft["crs"];
    assert_eq!((crs["epsg"].as_u64(), crs["vertical_epsg"].as_u64()), (Some(2236), Some(6360)), "{crs}");
    assert_eq!((crs["unit"].as_str(), crs["vertical_unit"].as_str()), (Some("US survey foot"), Some("US survey foot")));
    close(ft["z_scale"].as_f64().unwrap(), us_ft, "z_scale");
}

/// `refine --json` triangle count and strip length for a view.
fn refine(file: &Path, eye: &str, look: &str, extra: &[&str]) -> (u64, u64) {
    let o = relief()
        .arg("refine")
        .arg(file)
        .args(["--eye", eye, "--look", look, "--tolerance", "2", "--json"])
        .args(extra)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr_of(&o));
    let j: Value = serde_json::from_slice(&o.stdout).unwrap();
    (j["triangles"].as_u64().unwrap(), j["strip_len"].as_u64().unwrap())
}

#[test]
fn crs_coordinates_place_the_camera_where_local_metres_do() {
    let dir = tempfile::tempdir().unwrap();
    let lidar = dir.path().join("lidar.relief");
    convert(&dem("lidar_1m_f32.tif"), &lidar);
    let crs = &info(&lidar)["crs"];
    let [ox, oy] = [0, 1].map(|k| crs["grid_origin"][k].as_f64().unwrap());
    let local = refine(&lidar, "200,-20,480", "200,300,390", &[]);
    let (eye, look) = (format!("{},{},480", ox + 200.0, oy - 20.0), format!("{},{},390", ox + 200.0, oy + 300.0));
    assert_eq!(refine(&lidar, &eye, &look, &["--crs-coords"]), local);
    assert!(local.0 > 100, "{local:?}");
    // A file without a CRS refuses CRS coordinates, naming itself.
    let fuji = dir.path().join("fuji.relief");
    convert(&dem("fuji_terrain_rgb.png"), &fuji);
    let o =
        relief().arg("refine").arg(&fuji).args(["--eye", "1,2,3", "--look", "4,5,6", "--crs-coords"]).output().unwrap();
    let e = stderr_of(&o);
    assert!(!o.status.success() && e.trim_end().lines().count() == 1, "{e}");
    assert!(e.contains("fuji.relief has no coordinate system"), "{e}");
}

fn gdal(tool: &str, args: &[&str], src: &Path, out: &Path) {
    let o = Command::new(tool).arg("-q").args(args).arg(src).arg(out).output().expect("Debian's gdal-bin");
    assert!(o.status.success(), "{tool}: {}", stderr_of(&o));
}

/// The heights of a terrain's data posts, `[column][row from the north]` as in the DEM.
fn heights(file: &Path) -> Vec<Vec<f32>> {
    use relief::layout::Layout;
    let f = relief::format::terrain::TerrainFile::open(file).unwrap();
    let [x0, y0, x1, y1] = f.header().valid_window;
    let records = f.records().unwrap();
    (x0..x1).map(|x| (y0..y1).rev().map(|y| records[f.layout().index(x, y) as usize].z).collect()).collect()
}

#[test]
fn tiles_cut_from_a_real_dem_convert_to_the_dem() {
    let dir = tempfile::tempdir().unwrap();
    let src = dem("lidar_1m_f32.tif");
    let tiles = dir.path().join("tiles");
    std::fs::create_dir(&tiles).unwrap();
    // 4 × 4 georeferenced tiles of 101 posts sharing their edge posts, as SRTM's do.
    for r in 0..4 {
        for c in 0..4 {
            let (x, y) = (100 * c, 100 * r);
            let (w, h) = (101.min(400 - x), 101.min(400 - y));
            let win = [x, y, w, h].map(|v| v.to_string());
            let args = ["-srcwin", &win[0], &win[1], &win[2], &win[3]];
            gdal("gdal_translate", &args, &src, &tiles.join(format!("tile_{r}_{c}.tif")));
        }
    }
    let whole = dir.path().join("whole.relief");
    convert(&src, &whole);
    let mosaic = dir.path().join("mosaic.relief");
    let o = relief().args(["convert", "--quiet"]).arg(&tiles).arg(&mosaic).output().unwrap();
    assert!(o.status.success(), "{}", stderr_of(&o));
    // The same terrain: the same records, heights range, placement and CRS.
    let (w, m) = (info(&whole), info(&mosaic));
    for key in ["payload_checksum", "z_min", "z_max", "valid_window", "spacing_m", "crs", "nodata_filled"] {
        assert_eq!(w[key], m[key], "{key}");
    }

    // Without the tile at row 1, column 1: its inner 99 × 99 posts are a gap, filled as nodata;
    // every other post is the DEM's.
    let gap = dir.path().join("gap.relief");
    let mut args: Vec<std::path::PathBuf> = Vec::new();
    for r in 0..4 {
        for c in 0..4 {
            if (r, c) != (1, 1) {
                args.push(tiles.join(format!("tile_{r}_{c}.tif")));
            }
        }
    }
    let o = relief().args(["convert", "--quiet"]).args(&args).arg(&gap).output().unwrap();
    assert!(o.status.success(), "{}", stderr_of(&o));
    assert_eq!(info(&gap)["nodata_filled"], 99 * 99);
    assert_eq!(info(&gap)["void_mask"], true);
    assert_eq!(info(&whole)["void_mask"], false);
    // The same tiles as a GDAL virtual raster: the same terrain.
    #[cfg(feature = "gdal")]
    {
        let vrt = dir.path().join("tiles.vrt");
        let mut cmd = Command::new("gdalbuildvrt");
        cmd.arg("-q").arg(&vrt);
        for r in 0..4 {
            for c in 0..4 {
                cmd.arg(tiles.join(format!("tile_{r}_{c}.tif")));
            }
        }
        let o = cmd.output().expect("gdalbuildvrt (Debian's gdal-bin)");
        assert!(o.status.success(), "gdalbuildvrt: {}", stderr_of(&o));
        let from_vrt = dir.path().join("vrt.relief");
        convert(&vrt, &from_vrt);
        let v = info(&from_vrt);
        for key in ["payload_checksum", "z_min", "z_max", "valid_window", "spacing_m", "crs", "nodata_filled"] {
            assert_eq!(w[key], v[key], "from the VRT: {key}");
        }
    }
    let mask = relief::format::terrain::TerrainFile::open(&gap).unwrap().void_mask().unwrap().unwrap();
    // The void is exactly the gap's posts not shared with a neighbour (north-counted rows and
    // columns 101..200 of 400; grid rows count from the south).
    for x in 0..400u32 {
        for y in 0..400u32 {
            let in_gap = (101..200).contains(&x) && (101..200).contains(&(399 - y));
            assert_eq!(mask.is_void(x, y), in_gap, "post {x}, {y}");
        }
    }
    let (hw, hg) = (heights(&whole), heights(&gap));
    let mut compared = 0;
    for x in 0..400 {
        for y in 0..400 {
            if (101..200).contains(&x) && (101..200).contains(&y) {
                continue;
            }
            assert_eq!(hw[x][y], hg[x][y], "post {x}, {y} (north-counted row)");
            compared += 1;
        }
    }
    assert_eq!(compared, 400 * 400 - 99 * 99);

    // A tile in another CRS, or at another posting, is refused by name.
    let utm = dir.path().join("utm15_wgs84.tif");
    gdal("gdalwarp", &["-t_srs", "EPSG:32615"], &tiles.join("tile_0_0.tif"), &utm);
    let coarse = dir.path().join("coarse.tif");
    gdal("gdal_translate", &["-tr", "2", "2"], &tiles.join("tile_0_1.tif"), &coarse);
    for (bad, want) in [(&utm, "its CRS EPSG:32615 differs from EPSG:26915 of"), (&coarse, "its posting 2 x 2 differs")]
    {
        let out = dir.path().join("bad.relief");
        let o = relief().args(["convert", "--quiet"]).args(&args).arg(bad).arg(&out).output().unwrap();
        let e = stderr_of(&o);
        assert!(!o.status.success() && e.trim_end().lines().count() == 1, "{e}");
        assert!(e.contains(&format!("{}: {want}", bad.display())), "{e}");
        assert!(!out.exists());
    }
}

/// Converts `src` with extra flags; the command's output.
fn convert_with(src: &Path, out: &Path, flags: &[&str]) -> std::process::Output {
    relief().args(["convert", "--quiet"]).args(flags).arg(src).arg(out).output().unwrap()
}

/// ZSTD, LZW and Deflate copies (with the horizontal or floating-point predictor, in strips or
/// tiles), decoded by relief's own TIFF reader in every build, convert to the very same file as
/// the uncompressed original.
#[test]
fn zstd_lzw_and_deflate_copies_convert_natively_to_the_original() {
    let dir = tempfile::tempdir().unwrap();
    let tiled = ["-co", "TILED=YES"];
    for (name, predictors) in [("zurich_25m_i16.tif", ["1", "2"]), ("lidar_1m_f32.tif", ["2", "3"])] {
        let src = dem(name);
        let original = dir.path().join("original.relief");
        convert(&src, &original);
        let original_bytes = std::fs::read(&original).unwrap();
        for codec in ["ZSTD", "LZW", "DEFLATE"] {
            for (k, predictor) in predictors.iter().enumerate() {
                let (compress, predict) = (format!("COMPRESS={codec}"), format!("PREDICTOR={predictor}"));
                let mut args = vec!["-co", compress.as_str(), "-co", predict.as_str()];
                if k == 1 {
                    args.extend(tiled);
                }
                let copy = dir.path().join(format!("copy_{codec}_{predictor}.tif"));
                gdal("gdal_translate", &args, &src, &copy);
                let out = copy.with_extension("relief");
                convert(&copy, &out);
                assert!(std::fs::read(&out).unwrap() == original_bytes, "{name} {args:?}: not the same file");
            }
        }
    }
}

/// Copies compressed by codecs the native TIFF reader lacks (LERC), read through GDAL, convert to
/// the very same file as the original; a VRT and a NetCDF copy to the same records.
#[cfg(feature = "gdal")]
#[test]
fn lerc_vrt_and_netcdf_copies_convert_to_the_original() {
    let dir = tempfile::tempdir().unwrap();
    for (name, copies) in [
        ("zurich_25m_i16.tif", vec![vec!["-co", "COMPRESS=LERC_ZSTD"]]),
        (
            "lidar_1m_f32.tif",
            vec![
                vec!["-co", "COMPRESS=LERC", "-co", "MAX_Z_ERROR=0", "-co", "TILED=YES"],
                vec!["-co", "COMPRESS=LERC_DEFLATE", "-co", "MAX_Z_ERROR=0"],
                // Tiles whose first ZSTD block spans more than a few KiB.
                vec!["-co", "COMPRESS=LERC_ZSTD", "-co", "MAX_Z_ERROR=0", "-co", "TILED=YES"],
            ],
        ),
    ] {
        let src = dem(name);
        let original = dir.path().join("original.relief");
        convert(&src, &original);
        let original_bytes = std::fs::read(&original).unwrap();
        for (k, args) in copies.iter().enumerate() {
            let copy = dir.path().join(format!("copy{k}.tif"));
            gdal("gdal_translate", args, &src, &copy);
            let out = dir.path().join(format!("copy{k}.relief"));
            convert(&copy, &out);
            assert!(std::fs::read(&out).unwrap() == original_bytes, "{name} {args:?}: not the same file");
        }
        // Other containers GDAL reads: the same records, placement and CRS (only the source
        // format recorded in the header differs).
        for (ext, args) in [("vrt", ["-of", "VRT"]), ("nc", ["-of", "netCDF"])] {
            let copy = dir.path().join(format!("copy.{ext}"));
            gdal("gdal_translate", &args, &src, &copy);
            let out = dir.path().join(format!("copy_{ext}.relief"));
            convert(&copy, &out);
            let (a, b) = (info(&original), info(&out));
            for key in ["payload_checksum", "z_min", "z_max", "valid_window", "spacing_m", "crs"] {
                assert_eq!(a[key], b[key], "{name} as .{ext}: {key}");
            }
            assert_eq!(b["source_format"], "gdal");
        }
    }
    // A broken VRT: one line naming it.
    let bad = dir.path().join("bad.vrt");
    std::fs::write(&bad, "<VRTDataset rasterXSize=").unwrap();
    let o = convert_with(&bad, &dir.path().join("bad.relief"), &[]);
    let e = stderr_of(&o);
    assert!(!o.status.success() && e.trim_end().lines().count() == 1, "{e}");
    assert!(e.contains(&format!("{}: GDAL: ", bad.display())) && e.contains("expected attribute value"), "{e}");
}

/// Lossy codecs are refused with one line naming the file and the codec, nothing written; with
/// `--allow-lossy` they convert.
#[test]
fn lossy_compressed_dems_need_allow_lossy() {
    let dir = tempfile::tempdir().unwrap();
    let src = dem("zurich_25m_i16.tif");
    let jpeg = dir.path().join("jpeg.tif");
    gdal("gdal_translate", &["-ot", "Byte", "-scale", "-co", "COMPRESS=JPEG"], &src, &jpeg);
    let mut cases = vec![(jpeg, "JPEG compression is lossy".to_string())];
    if cfg!(feature = "gdal") {
        let lerc = dir.path().join("lerc.tif");
        gdal("gdal_translate", &["-co", "COMPRESS=LERC_ZSTD", "-co", "MAX_Z_ERROR=2"], &src, &lerc);
        cases.push((lerc, "LERC compression with a maximum error of 2 is lossy".into()));
        let lidar = dir.path().join("lerc_f32.tif");
        let args = ["-co", "COMPRESS=LERC_DEFLATE", "-co", "MAX_Z_ERROR=0.01"];
        gdal("gdal_translate", &args, &dem("lidar_1m_f32.tif"), &lidar);
        cases.push((lidar, "LERC compression with a maximum error of 0.01 is lossy".into()));
        // A VRT is as lossy as its sources: the JPEG tile behind it is named.
        let vrt = dir.path().join("over_jpeg.vrt");
        let jpeg = &cases[0].0;
        let o = Command::new("gdalbuildvrt").arg("-q").arg(&vrt).arg(jpeg).output().expect("gdalbuildvrt");
        assert!(o.status.success(), "gdalbuildvrt: {}", stderr_of(&o));
        let what = format!("its source {}: JPEG compression is lossy", jpeg.display());
        cases.push((vrt, what));
    }
    for (file, what) in cases {
        let out = file.with_extension("relief");
        let o = convert_with(&file, &out, &[]);
        let e = stderr_of(&o);
        assert!(!o.status.success() && e.trim_end().lines().count() == 1, "{e}");
        let want = format!("{}: {what}; pass --allow-lossy to convert it anyway", file.display());
        assert!(e.contains(&want), "{e}\nwanted: {want}");
        assert!(!out.exists(), "a refused conversion wrote {}", out.display());
        let o = convert_with(&file, &out, &["--allow-lossy"]);
        assert!(o.status.success(), "{}", stderr_of(&o));
        assert!(info(&out)["z_max"].as_f64().unwrap() > info(&out)["z_min"].as_f64().unwrap());
    }
}

/// Without GDAL, a LERC GeoTIFF (even one with ZSTD inside) is refused with one line naming the
/// file and the compression and saying what to do about it; nothing is written.
#[cfg(not(feature = "gdal"))]
#[test]
fn without_gdal_a_lerc_tiff_says_how_to_read_it() {
    let dir = tempfile::tempdir().unwrap();
    let lerc = dir.path().join("lerc.tif");
    gdal("gdal_translate", &["-co", "COMPRESS=LERC_ZSTD"], &dem("zurich_25m_i16.tif"), &lerc);
    let out = dir.path().join("out.relief");
    let o = convert_with(&lerc, &out, &[]);
    let e = stderr_of(&o);
    assert!(!o.status.success() && e.trim_end().lines().count() == 1, "{e}");
    let want = format!(
        "{}: unsupported TIFF compression LERC: reading it needs GDAL: build relief with `--features gdal` \
         (and Debian's libgdal-dev)",
        lerc.display()
    );
    assert!(e.contains(&want), "{e}\nwanted: {want}");
    assert!(!out.exists(), "a refused conversion wrote {}", out.display());
}
