//! End-to-end conversion of the real DEMs in ../shared/data/dem into every layout, with `info` and
//! `verify` agreeing, and the file-level guarantees (atomic output, exact errors for bad input).

use crate::common;

use common::{dem, fails_with, REAL_DEMS};
use std::path::Path;
use std::process::Command;

use relief::format::terrain::TerrainFile;
use relief::layout::{Layout, LayoutKind};
use relief::preprocess::convert::{convert, ConvertOptions};
use relief::preprocess::inspect;
use relief::sys::progress::Progress;

fn relief() -> Command {
    Command::new(env!("CARGO_BIN_EXE_relief"))
}

/// Files in `dir` (to prove nothing half-written or temporary is left behind).
fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}

#[test]
fn every_real_dem_converts_to_every_layout_and_verifies() {
    let dir = tempfile::tempdir().unwrap();
    for name in REAL_DEMS {
        let mut reference: Option<(TerrainFile, Vec<relief::format::terrain::Record>)> = None;
        for kind in LayoutKind::ALL {
            let out = dir.path().join(format!("{name}.{kind}.relief"));
            let report =
                convert(&dem(name), &out, &ConvertOptions::new(kind)).unwrap_or_else(|e| panic!("{name} {kind}: {e}"));
            let file = TerrainFile::open(&out).unwrap();
            let info = inspect::info(&file);
            // info agrees with the conversion report and the header.
            assert_eq!(info.layout, kind.name());
            assert_eq!(info.grid_size, report.grid_size);
            assert_eq!(info.records, report.records);
            assert_eq!(info.records, file.layout().records());
            assert_eq!(info.vertices, (report.grid_size as u64).pow(2));
            assert_eq!(info.valid_window, [0, 0, report.source_width, report.source_height]);
            assert_eq!(info.nodata_filled, report.nodata_filled);
            assert_eq!(info.file_bytes, std::fs::metadata(&out).unwrap().len());
            assert_eq!((info.z_min, info.z_max), (report.z_min, report.z_max));
            assert!(report.grid_size >= report.source_width.max(report.source_height));
            assert!(
                (report.grid_size - 1) / 2 < report.source_width.max(report.source_height),
                "not the smallest grid"
            );
            // verify: checksums and nesting over every vertex.
            let v = inspect::verify(&file, Progress::hidden()).unwrap();
            assert!(v.ok, "{name} {kind}: {:?}", v.problems);
            assert_eq!(v.vertices_checked, info.vertices);
            // Every layout stores the same record for the same grid post.
            let g = file.grid();
            let recs: Vec<_> = (0..g.size())
                .flat_map(|y| (0..g.size()).map(move |x| (x, y)))
                .map(|(x, y)| file.record_at(x, y).unwrap())
                .collect();
            match &reference {
                None => reference = Some((file, recs)),
                Some((_, r)) => assert!(r == &recs, "{name}: {kind} stores different records than row-major"),
            }
        }
    }
}

#[test]
fn heights_and_spacing_come_from_the_files() {
    let dir = tempfile::tempdir().unwrap();
    let conv = |name: &str| {
        let out = dir.path().join(format!("{name}.relief"));
        convert(&dem(name), &out, &ConvertOptions::new(LayoutKind::Hz)).unwrap();
        inspect::info(&TerrainFile::open(&out).unwrap())
    };
    let z = conv("zurich_25m_i16.tif");
    assert_eq!(z.spacing_m, [25.0, 25.0]);
    assert!(!z.spacing_assumed && z.geographic.is_none());
    assert_eq!((z.z_min, z.z_max), (393.0, 870.0));
    assert_eq!(z.grid_size, 513);
    assert_eq!(z.extent_m, [512.0 * 25.0, 512.0 * 25.0]);

    let e = conv("etopo20_world.tif");
    let g = e.geographic.expect("etopo20 is geographic");
    assert!((g.spacing_deg[0] - 1.0 / 3.0).abs() < 1e-6, "{:?}", g.spacing_deg);
    assert!(g.centre_lat_deg.abs() < 0.5, "{}", g.centre_lat_deg);
    // 1/3 degree of latitude is about 37.06 km; at the equator longitude is the same.
    assert!((e.spacing_m[1] - 37_065.0).abs() < 50.0, "{:?}", e.spacing_m);
    assert!((e.spacing_m[0] - e.spacing_m[1]).abs() < 10.0);
    assert!(e.z_min < -9000.0 && e.z_max > 6200.0, "bathymetry kept: {} {}", e.z_min, e.z_max);

    let f = conv("fuji_terrain_rgb.png");
    assert!(f.spacing_assumed, "Terrain-RGB carries no spacing");
    assert!((f.z_min - 13.7).abs() < 0.2 && (f.z_max - 3751.0).abs() < 1.0, "{} {}", f.z_min, f.z_max);

    let h = conv("hugo_site_nodata.asc");
    assert!(h.nodata_filled > 0, "hugo has NODATA cells");
    assert!(h.z_min >= 1660.0 - 0.5 && h.z_max <= 1711.0 + 0.5);
}

#[test]
fn spacing_and_z_scale_options_apply() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t.relief");
    let mut o = ConvertOptions::new(LayoutKind::Interleaved);
    o.spacing_m = Some([2.0, 3.0]);
    o.z_scale = 0.5;
    o.z_offset = -100.0;
    let r = convert(&dem("zurich_25m_i16.tif"), &out, &o).unwrap();
    assert_eq!(r.spacing_m, [2.0, 3.0]);
    assert_eq!((r.z_min, r.z_max), (393.0 * 0.5 - 100.0, 870.0 * 0.5 - 100.0));
    assert!(inspect::verify(&TerrainFile::open(&out).unwrap(), Progress::hidden()).unwrap().ok);
}

#[test]
fn cli_convert_info_verify_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("z.relief");
    let st = relief()
        .args(["convert", "--quiet", "--layout", "embedded"])
        .arg(dem("zurich_25m_i16.tif"))
        .arg(&out)
        .output()
        .unwrap();
    assert!(st.status.success(), "{}", String::from_utf8_lossy(&st.stderr));
    let info = relief().args(["info", "--json"]).arg(&out).output().unwrap();
    assert!(info.status.success());
    let j: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    for key in [
        "grid_size",
        "levels",
        "layout",
        "records",
        "vertices",
        "waste_ratio",
        "spacing_m",
        "extent_m",
        "z_min",
        "z_max",
        "valid_window",
        "nodata_filled",
        "file_bytes",
    ] {
        assert!(j.get(key).is_some(), "info --json lacks {key}");
    }
    assert_eq!(j["layout"], "embedded");
    assert_eq!(j["grid_size"], 513);
    assert_eq!(j["levels"], 18);
    let v = relief().args(["verify", "--json"]).arg(&out).output().unwrap();
    assert!(v.status.success());
    let j: serde_json::Value = serde_json::from_slice(&v.stdout).unwrap();
    assert_eq!(j["ok"], true);
    assert_eq!(listing(dir.path()), vec!["z.relief"]);
}

#[test]
fn bad_inputs_give_one_line_errors_and_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("out.relief");
    let os = |p: &Path| p.as_os_str().to_owned();

    // Unknown format.
    let junk = d.join("junk.bin");
    std::fs::write(&junk, b"this is not a DEM at all, just some text").unwrap();
    fails_with(&["convert".as_ref(), &os(&junk), &os(&out)], "junk.bin");
    // Truncated GeoTIFF.
    let bytes = std::fs::read(dem("zurich_25m_i16.tif")).unwrap();
    let trunc = d.join("trunc.tif");
    std::fs::write(&trunc, &bytes[..bytes.len() / 2]).unwrap();
    fails_with(&["convert".as_ref(), &os(&trunc), &os(&out)], "trunc.tif");
    // A DEM with no valid sample.
    let void = d.join("void.asc");
    std::fs::write(&void, "ncols 3\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 10\nNODATA_value -9999\n-9999 -9999 -9999\n-9999 -9999 -9999\n").unwrap();
    fails_with(&["convert".as_ref(), &os(&void), &os(&out)], "no valid sample");
    // An output path that cannot be written.
    let nowhere = d.join("no/such/dir/out.relief");
    fails_with(&["convert".as_ref(), &os(&dem("hugo_site_nodata.asc")), &os(&nowhere)], "no/such/dir");
    // Bad options.
    fails_with(
        &["convert".as_ref(), &os(&dem("hugo_site_nodata.asc")), &os(&out), "--spacing=-3".as_ref()],
        "--spacing",
    );
    fails_with(
        &[
            "convert".as_ref(),
            &os(&dem("hugo_site_nodata.asc")),
            &os(&out),
            "--layout".as_ref(),
            "tiled".as_ref(),
            "--tile".as_ref(),
            "12".as_ref(),
        ],
        "power of two",
    );
    assert_eq!(listing(d), vec!["junk.bin", "trunc.tif", "void.asc"], "no output or temporary file left");

    // Damaged terrain files.
    let good = d.join("good.relief");
    convert(&dem("hugo_site_nodata.asc"), &good, &ConvertOptions::new(LayoutKind::Interleaved)).unwrap();
    let bytes = std::fs::read(&good).unwrap();
    let variant = |name: &str, f: &dyn Fn(&mut Vec<u8>)| {
        let p = d.join(name);
        let mut b = bytes.clone();
        f(&mut b);
        std::fs::write(&p, b).unwrap();
        p
    };
    let p = variant("magic.relief", &|b| b[1] = b'X');
    fails_with(&["info".as_ref(), &os(&p)], "not a relief terrain file");
    let p = variant("version.relief", &|b| b[8] = 7);
    fails_with(&["info".as_ref(), &os(&p)], "version 7");
    let p = variant("header.relief", &|b| b[110] ^= 0x40);
    fails_with(&["info".as_ref(), &os(&p)], "header checksum");
    let p = variant("short.relief", &|b| b.truncate(b.len() - 12));
    fails_with(&["verify".as_ref(), &os(&p)], "truncated");
    let p = variant("tiny.relief", &|b| b.truncate(10));
    fails_with(&["info".as_ref(), &os(&p)], "tiny.relief");
    fails_with(&["info".as_ref(), &os(&d.join("missing.relief"))], "missing.relief");
    // A flipped payload byte opens (the payload checksum is checked on demand) but fails verify.
    let p = variant("payload.relief", &|b| {
        let k = b.len() - 100;
        b[k] ^= 1
    });
    assert!(relief().arg("info").arg(&p).output().unwrap().status.success());
    let v = relief().args(["verify", "--json"]).arg(&p).output().unwrap();
    assert!(!v.status.success());
    let j: serde_json::Value = serde_json::from_slice(&v.stdout).unwrap();
    assert_eq!(j["payload_checksum_ok"], false);
}

#[test]
fn interrupted_conversion_leaves_old_file_or_new_one() {
    // Interrupt a conversion of a SYNTHETIC 2049² DEM with SIGINT: the final name must hold the
    // previous complete file (or, if conversion won the race, the new complete file), and no
    // temporary file may remain.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let synth = d.join("synthetic_2049.tif");
    let st = Command::new(env!("CARGO_BIN_EXE_relief-synth"))
        .arg(&synth)
        .args(["--size", "2049", "--seed", "3"])
        .output()
        .unwrap();
    assert!(st.status.success());
    let out = d.join("t.relief");
    convert(&dem("hugo_site_nodata.asc"), &out, &ConvertOptions::new(LayoutKind::Hz)).unwrap();
    let mut old = std::fs::read(&out).unwrap();
    // Ctrl-C, and what timeout, systemd and docker send (SIGTERM) and a closed terminal (SIGHUP):
    // each is handled the same way.
    for (signal, delay_ms) in [(libc::SIGINT, 20u64), (libc::SIGTERM, 80), (libc::SIGHUP, 200), (libc::SIGTERM, 20)] {
        let child = relief()
            .args(["convert", "--quiet", "--layout", "interleaved"])
            .arg(&synth)
            .arg(&out)
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        // Counted from when relief catches the signal (its SigCgt bit): before `main` no process
        // can, and loading the shared libraries (libgdal's many, with the `gdal` feature) takes
        // a varying part of the first 20 ms.
        let caught = |pid: u32| {
            let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
            let mask = status.lines().find_map(|l| l.strip_prefix("SigCgt:")).map(str::trim).unwrap_or("0");
            u64::from_str_radix(mask, 16).unwrap_or(0) & (1 << (signal - 1)) != 0
        };
        let started = std::time::Instant::now();
        while !caught(child.id()) && started.elapsed() < std::time::Duration::from_secs(10) {
            std::thread::sleep(std::time::Duration::from_micros(200));
        }
        std::thread::sleep(std::time::Duration::from_millis(delay_ms));
        // SAFETY: kill(2) on our own child's pid; no memory is involved.
        unsafe { libc::kill(child.id() as i32, signal) };
        let res = child.wait_with_output().unwrap();
        let now = std::fs::read(&out).unwrap();
        if res.status.success() {
            let f = TerrainFile::open(&out).unwrap();
            assert!(inspect::verify(&f, Progress::hidden()).unwrap().ok);
        } else {
            assert_eq!(res.status.code(), Some(1), "signal {signal}: killed, not handled");
            assert_eq!(String::from_utf8_lossy(&res.stderr), "relief: interrupted\n");
            assert_eq!(now, old, "interrupted at {delay_ms} ms but the file changed");
        }
        assert_eq!(listing(d), vec!["synthetic_2049.tif", "t.relief"], "signal {signal}: temporary files left");
        old = now;
    }
}

/// The formats not among the real DEMs (SRTM .hgt, 16-bit PNG, OpenEXR) go through `convert`
/// end to end from small fixtures written here: heights land on the right posts, voids are
/// filled and counted, geographic spacing is converted, and the file verifies.
#[test]
fn hgt_png16_and_exr_fixtures_convert_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let height_at = |x: u32, row: u32| ((x * 7 + row * 13) % 500) as f32 + 100.0;

    // SRTM 3″ tile N47E008: 1201², big-endian i16, two voids.
    let side = 1201u32;
    let mut bytes = Vec::with_capacity((side * side * 2) as usize);
    for row in 0..side {
        for x in 0..side {
            let v: i16 = if (x, row) == (10, 20) || (x, row) == (600, 600) { -32768 } else { height_at(x, row) as i16 };
            bytes.extend_from_slice(&v.to_be_bytes());
        }
    }
    let hgt = d.join("N47E008.hgt");
    std::fs::write(&hgt, &bytes).unwrap();
    let out = d.join("hgt.relief");
    let r = convert(&hgt, &out, &ConvertOptions::new(LayoutKind::Interleaved)).unwrap();
    assert_eq!(r.nodata_filled, 2);
    let f = TerrainFile::open(&out).unwrap();
    let i = inspect::info(&f);
    let g = i.geographic.as_ref().expect("hgt is geographic");
    assert!((g.centre_lat_deg - 47.5).abs() < 1e-9);
    // 3″ of latitude ≈ 92.66 m; of longitude at 47.5° ≈ 62.6 m.
    assert!((i.spacing_m[1] - 92.66).abs() < 0.05 && (i.spacing_m[0] - 62.60).abs() < 0.05, "{:?}", i.spacing_m);
    // Image row r is grid row side − 1 − r.
    assert_eq!(f.record_at(5, side - 1 - 7).unwrap().z, height_at(5, 7));
    let filled = f.record_at(10, side - 1 - 20).unwrap().z;
    assert!((height_at(10, 20) - 20.0..height_at(10, 20) + 20.0).contains(&filled), "filled void {filled}");
    assert!(inspect::verify(&f, Progress::hidden()).unwrap().ok);

    // 16-bit grayscale PNG, 17 × 9, with --spacing.
    let (w, h) = (17u32, 9u32);
    let png = d.join("gray16.png");
    let img = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(w, h, |x, y| {
        image::Luma([height_at(x, y) as u16 * 100])
    });
    img.save(&png).unwrap();
    let out = d.join("png.relief");
    let mut o = ConvertOptions::new(LayoutKind::Embedded);
    o.spacing_m = Some([5.0, 5.0]);
    o.z_scale = 0.01;
    convert(&png, &out, &o).unwrap();
    let f = TerrainFile::open(&out).unwrap();
    assert_eq!(f.record_at(3, h - 1 - 4).unwrap().z, height_at(3, 4));
    assert_eq!(f.grid().size(), 17);
    assert!(inspect::verify(&f, Progress::hidden()).unwrap().ok);

    // Single-channel f32 OpenEXR, 33 × 20, one NaN.
    use exr::prelude::*;
    let (w, h) = (33usize, 20usize);
    let mut samples: Vec<f32> = (0..h).flat_map(|y| (0..w).map(move |x| height_at(x as u32, y as u32))).collect();
    samples[3 * w + 4] = f32::NAN;
    let exr_path = d.join("z.exr");
    let layer = Layer::new(
        (w, h),
        LayerAttributes::named("height"),
        Encoding::FAST_LOSSLESS,
        AnyChannels::sort(vec![AnyChannel::new("Z", FlatSamples::F32(samples))].into()),
    );
    Image::from_layer(layer).write().to_file(&exr_path).unwrap();
    let out = d.join("exr.relief");
    let r = convert(&exr_path, &out, &ConvertOptions::new(LayoutKind::Hz)).unwrap();
    assert_eq!((r.format.as_str(), r.nodata_filled, r.grid_size), ("exr", 1, 33));
    let f = TerrainFile::open(&out).unwrap();
    assert_eq!(f.record_at(30, (h - 1 - 11) as u32).unwrap().z, height_at(30, 11));
    assert!(inspect::verify(&f, Progress::hidden()).unwrap().ok);
}
