//! The layout page-fault experiment (`relief layouts`) on real DEMs: the instrumented refinement
//! is the plain one, counts are deterministic, hierarchical layouts fault less than row-major,
//! re-laying out a terrain file equals converting its DEM, and bad input fails in one line.

use crate::common;

use std::path::Path;
use std::process::Command;

use common::dem;
use relief::faults::run_terrain;
use relief::flight::{flyover, FlyoverOptions};
use relief::format::terrain::TerrainFile;
use relief::layout::LayoutKind;
use relief::pager::{LruCache, LruTrace, NoTrace, PageGeometry};
use relief::preprocess::convert::{convert, relayout, ConvertOptions};
use relief::refine::MappedRecords;
use relief::refine::{RefineOptions, Refiner, Strip};

fn relief() -> Command {
    Command::new(env!("CARGO_BIN_EXE_relief"))
}

fn convert_to(dem_name: &str, dir: &Path, kind: LayoutKind) -> TerrainFile {
    let out = dir.join(format!("{dem_name}.{}.relief", kind.name()));
    convert(&dem(dem_name), &out, &ConvertOptions::new(kind)).unwrap();
    TerrainFile::open(&out).unwrap()
}

#[test]
fn instrumented_refinement_gives_the_plain_strip() {
    let dir = tempfile::tempdir().unwrap();
    for kind in LayoutKind::ALL {
        let t = convert_to("lidar_1m_f32.tif", dir.path(), kind);
        let path = flyover(&t, &FlyoverOptions::new(12)).unwrap();
        let geometry = PageGeometry::new(4096).unwrap();
        let trace = LruTrace::new(LruCache::new(64 * 4096, geometry).unwrap(), geometry);
        let records = t.mapped_records().unwrap();
        let traced = MappedRecords::new(records, t.header().payload_offset, &trace);
        let untraced = MappedRecords::new(records, t.header().payload_offset, NoTrace);
        let mut refiner = Refiner::new(1).unwrap();
        let options = RefineOptions { tolerance_px: 1.0, ..Default::default() };
        for k in 0..path.frames.len() {
            let cam = path.camera(k, 60.0, 1280, 720).unwrap();
            let (mut a, mut b, mut c) = (Strip::new(), Strip::new(), Strip::new());
            let ca = refiner.refine_file_counted(&t, &cam, &options, &mut a).unwrap();
            let cb = refiner.refine_source_counted(&t, &traced, &cam, &options, &mut b);
            let cc = refiner.refine_source_counted(&t, &untraced, &cam, &options, &mut c);
            assert_eq!(a.vertices, b.vertices, "{kind} frame {k}");
            assert_eq!(a.vertices, c.vertices, "{kind} frame {k}");
            assert_eq!((ca.visited, ca.culled), (cb.visited, cb.culled));
            assert_eq!((ca.visited, ca.culled), (cc.visited, cc.culled));
            assert!(ca.visited > 0, "{kind} frame {k}: the counted pass counts");
            // The uncounted loop (a separate monomorph) makes the same strip.
            let mut d = Strip::new();
            refiner.refine_file(&t, &cam, &options, &mut d).unwrap();
            assert_eq!(a.vertices, d.vertices, "{kind} frame {k}: counted and uncounted");
        }
        assert!(trace.stats().misses > 0);
    }
}

#[test]
fn fault_counts_are_deterministic_and_hierarchical_layouts_fault_less() {
    let dir = tempfile::tempdir().unwrap();
    let geometry = PageGeometry::new(4096).unwrap();
    let mut faults = Vec::new();
    for kind in LayoutKind::ALL {
        let t = convert_to("zurich_25m_i16.tif", dir.path(), kind);
        let path = flyover(&t, &FlyoverOptions::new(60)).unwrap();
        let cams: Vec<_> = (0..60).map(|k| path.camera(k, 60.0, 1920, 1080).unwrap()).collect();
        // Memory: 1/16 of the terrain's data.
        let memory = t.grid().vertices() * 12 / 16;
        let a = run_terrain(t.path(), &cams, 1.0, memory, geometry).unwrap();
        let b = run_terrain(t.path(), &cams, 1.0, memory, geometry).unwrap();
        assert_eq!(a.faults_per_frame, b.faults_per_frame, "{kind}: counts differ between runs");
        assert_eq!((a.faults, a.distinct_pages, a.lower_bound), (b.faults, b.distinct_pages, b.lower_bound));
        assert!(a.lower_bound <= a.distinct_pages && a.distinct_pages <= a.faults, "{kind}: {a:?}");
        assert_eq!(a.faults_per_frame.iter().sum::<u64>(), a.faults);
        faults.push((kind, a.faults));
    }
    let row_major = faults[0].1 as f64;
    for (kind, f) in &faults {
        if matches!(kind, LayoutKind::Interleaved | LayoutKind::Embedded | LayoutKind::Hz) {
            // The paper's claim, measured on a real DEM: several times fewer faults.
            assert!((*f as f64) < 0.5 * row_major, "{kind}: {f} faults vs row-major {row_major}");
        }
    }
}

#[test]
fn relayout_of_a_terrain_file_equals_converting_its_dem() {
    let dir = tempfile::tempdir().unwrap();
    let from_dem = convert_to("hugo_site_nodata.asc", dir.path(), LayoutKind::Hz);
    let source = convert_to("hugo_site_nodata.asc", dir.path(), LayoutKind::RowMajor);
    let out = dir.path().join("relaid.relief");
    relayout(&source, &out, &ConvertOptions::new(LayoutKind::Hz)).unwrap();
    let relaid = TerrainFile::open(&out).unwrap();
    assert_eq!(relaid.mapped_payload(), from_dem.mapped_payload(), "records differ");
    let (a, b) = (relaid.header(), from_dem.header());
    assert_eq!((a.valid_window, a.spacing_m, a.z_min, a.z_max), (b.valid_window, b.spacing_m, b.z_min, b.z_max));
    // The void mask goes along: the same posts, the same count.
    let mask = relaid.void_mask().unwrap().expect("hugo's voids are kept");
    assert_eq!(Some(&mask), from_dem.void_mask().unwrap().as_ref());
    assert_eq!((mask.count(), a.nodata_filled), (b.nodata_filled, b.nodata_filled));
    relaid.verify_payload().unwrap();
    assert!(relayout(&source, source.path(), &ConvertOptions::new(LayoutKind::Hz)).is_err());
}

#[test]
fn cli_reports_every_layout_and_os_faults_or_why_not() {
    let dir = tempfile::tempdir().unwrap();
    let t = convert_to("zurich_25m_i16.tif", dir.path(), LayoutKind::Interleaved);
    let path = dir.path().join("p.json");
    flyover(&t, &FlyoverOptions::new(20)).unwrap().save(&path).unwrap();
    let o = relief()
        .arg("layouts")
        .arg(t.path())
        .arg("--path")
        .arg(&path)
        .args(["--memory", "1/16", "--tolerance", "1,4", "--os", "--json", "--cache-dir"])
        .arg(dir.path().join("cache"))
        .arg("--plot")
        .arg(dir.path().join("faults.png"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // Two τ values: both panels.
    let plot = image::open(dir.path().join("faults.png")).unwrap();
    assert_eq!((plot.width(), plot.height()), relief::plot::TWO_PANEL_SIZE);
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let runs = r["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 10);
    for run in runs {
        assert_eq!(run["backend"], "terrain");
        for key in [
            "layout",
            "tolerance",
            "faults",
            "faults_per_frame_mean",
            "faults_per_frame_max",
            "distinct_pages",
            "bytes_read",
            "update_ms_per_frame",
            "lower_bound",
            "ratio_to_first",
        ] {
            assert!(run.get(key).is_some(), "missing {key}");
        }
        assert_eq!(run["bytes_read"].as_u64().unwrap(), run["faults"].as_u64().unwrap() * 4096);
    }
    // --os either measured (cold runs must fault) or says why not.
    let note = r["os_note"].as_str().unwrap();
    if note.starts_with("OS faults not measured") {
        eprintln!("note: {note}");
    } else {
        assert!(runs.iter().all(|x| x["os"]["major"].as_u64().is_some()), "{note}");
        // Every cold run reads its pages from storage: each mapped layout faults (a file that
        // stayed resident, e.g. paged in whole by the header read's readahead, would show 0).
        for x in runs {
            assert!(x["os"]["major"].as_u64().unwrap() > 0, "cold run never faulted: {x}");
        }
    }
}

/// `--os-cap` runs the cold runs under a cgroup memory limit, or says plainly why it cannot
/// (no root, no cgroup v1 memory controller) and still reports the model.
#[test]
fn os_cap_works_or_says_why() {
    let dir = tempfile::tempdir().unwrap();
    let t = convert_to("lidar_1m_f32.tif", dir.path(), LayoutKind::Hz);
    let path = dir.path().join("p.json");
    flyover(&t, &FlyoverOptions::new(10)).unwrap().save(&path).unwrap();
    let o = relief()
        .arg("layouts")
        .arg(t.path())
        .arg("--path")
        .arg(&path)
        .args(["--memory", "1/16", "--layouts", "hz", "--os", "--os-cap", "64M", "--json", "--cache-dir"])
        .arg(dir.path().join("cache"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let note = r["os_note"].as_str().unwrap();
    let run = &r["runs"][0];
    assert!(run["faults"].as_u64().unwrap() > 0);
    if note.contains("under a cgroup v1 memory cap of 67108864 bytes") {
        assert!(run["os"]["major"].as_u64().unwrap() > 0, "{run}");
        assert_eq!(run["os"]["major_per_frame"].as_array().unwrap().len(), 10);
    } else {
        assert!(note.starts_with("OS faults not measured: cannot set a memory cap: "), "{note}");
        assert!(run["os"].is_null());
    }
}

#[test]
fn bad_input_fails_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let t = convert_to("zurich_25m_i16.tif", dir.path(), LayoutKind::Hz);
    let good = dir.path().join("p.json");
    flyover(&t, &FlyoverOptions::new(3)).unwrap().save(&good).unwrap();
    let empty = dir.path().join("empty.json");
    std::fs::write(&empty, "[]").unwrap();
    let broken = dir.path().join("broken.json");
    std::fs::write(&broken, "[{\"eye\": [1, 2, 3]").unwrap();
    let cases: [(&Path, &[&str], &str); 6] = [
        (&dir.path().join("missing.json"), &["--memory", "1M"], "missing.json"),
        (&empty, &["--memory", "1M"], "no frames"),
        (&broken, &["--memory", "1M"], "broken.json"),
        (&good, &["--memory", "100"], "smaller than one 4096-byte page"),
        (&good, &["--memory", "1M", "--page-size", "3000"], "power of two"),
        (&good, &["--memory", "1M", "--layouts", "zigzag"], "unknown layout 'zigzag'"),
    ];
    for (path, args, want) in cases {
        let o = relief()
            .arg("layouts")
            .arg(t.path())
            .arg("--path")
            .arg(path)
            .args(args)
            .arg("--cache-dir")
            .arg(dir.path().join("cache"))
            .output()
            .unwrap();
        let e = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {e}");
        assert_eq!(e.trim_end().lines().count(), 1, "{args:?}: {e}");
        assert!(e.contains(want) && !e.contains("panicked"), "{args:?}: want '{want}' in {e}");
    }
}
