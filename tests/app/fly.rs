//! Flying: headless fly-throughs along real paths (frames, stats, both refinement modes), the
//! `render` and `fly` command lines and their errors, and the window under Xvfb where available.

use crate::common;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use common::{dem, fly_terrain, gpu, relief, stderr_of, window_session};
use relief::flight::{flyover, FlyoverOptions};
use relief::format::terrain::TerrainFile;
use relief::layout::LayoutKind;
use relief::preprocess::convert::{convert, ConvertOptions};
use relief::refine::RefineOptions;
use relief::render::terrain::{FRAME_UNIFORM_BYTES, VERTEX_BYTES};
use relief::sys::progress::Progress;

fn zurich(dir: &Path) -> PathBuf {
    let out = dir.join("zurich.relief");
    let mut opts = ConvertOptions::new(LayoutKind::Hz);
    opts.progress = Progress::hidden();
    convert(&dem("zurich_25m_i16.tif"), &out, &opts).unwrap();
    out
}

#[test]
fn headless_flight_renders_every_frame_in_both_refinement_modes() {
    let dir = tempfile::tempdir().unwrap();
    let file = zurich(dir.path());
    let terrain = Arc::new(TerrainFile::open(&file).unwrap());
    let path = flyover(&terrain, &FlyoverOptions::new(6)).unwrap();
    let cameras: Vec<_> = (0..path.frames.len()).map(|k| path.camera(k, 60.0, 160, 100).unwrap()).collect();
    let frames_dir = dir.path().join("frames");
    let refine = RefineOptions { tolerance_px: 1.0, ..Default::default() };
    let gpu = gpu();
    let sync = fly_terrain(&gpu, &terrain, &cameras, refine, false, Some(frames_dir.clone()));
    assert_eq!(sync.frames.len(), 6);
    for f in &sync.frames {
        let png = frames_dir.join(format!("frame_{:05}.png", f.frame));
        let img = image::open(&png).unwrap().to_rgba8();
        assert_eq!(img.dimensions(), (160, 100));
        // A low fly-over sees terrain: many pixels are not sky blue-grey.
        let ground = img.pixels().filter(|p| p[1] as i32 > p[2] as i32).count();
        assert!(ground > 1000, "{}: only {ground} terrain-coloured pixels", png.display());
        // Synchronous: every frame refines its own view and uploads exactly that strip.
        let s = &f.stats;
        assert!(s.update_ms.is_some() && s.triangles > 0 && s.lag_frames == 0 && s.changed);
        assert_eq!(f.upload_bytes, s.strip_len * VERTEX_BYTES + FRAME_UNIFORM_BYTES);
    }
    assert_eq!(sync.summary.frames, 6);
    assert!(sync.summary.fps > 0.0);

    // With the refinement thread the render loop never waits after the first frame, so a frame
    // may draw an older strip; it still draws one, and uploads only when a strip is new.
    let threaded = fly_terrain(&gpu, &terrain, &cameras, refine, true, None);
    assert_eq!(threaded.frames.len(), 6);
    assert_eq!(threaded.frames[0].stats.strip_len, sync.frames[0].stats.strip_len, "first frame waits for its strip");
    for f in &threaded.frames {
        assert!(f.stats.strip_len > 2);
        let strip_bytes = f.upload_bytes - FRAME_UNIFORM_BYTES;
        assert!(strip_bytes == 0 || strip_bytes == f.stats.strip_len * VERTEX_BYTES, "{f:?}");
        assert_eq!(f.stats.update_ms.is_some(), strip_bytes > 0);
    }
}

#[test]
fn fly_cli_writes_frames_and_stats() {
    let dir = tempfile::tempdir().unwrap();
    let file = zurich(dir.path());
    let path = dir.path().join("path.json");
    common::make_path("flyover", &file, 3, &path);
    let frames = dir.path().join("frames");
    let stats = dir.path().join("stats.json");
    let o = relief()
        .arg("fly")
        .arg(&file)
        .arg("--path")
        .arg(&path)
        .arg("--frames-out")
        .arg(&frames)
        .arg("--stats")
        .arg(&stats)
        .args(["--width", "128", "--height", "80", "--json"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr_of(&o));
    // --json prints the report --stats writes: the same schema for every backend.
    let printed: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let summary = &printed["summary"];
    for key in ["frames", "fps"] {
        assert!(summary[key].is_number(), "summary lacks {key}: {summary}");
    }
    for key in ["update_ms", "render_ms", "frame_ms", "triangles", "upload_bytes", "major_faults"] {
        assert!(summary[key]["median"].is_number() && summary[key]["mean"].is_number(), "summary lacks {key}");
    }
    assert_eq!(summary["frames"], 3);
    // A terrain's strip is refined anew each frame: its figure is the strip, not splits.
    assert_eq!(summary["changes"], "strip vertices");
    assert!(summary["strip_len"]["mean"].as_f64().is_some_and(|x| x > 0.0), "{summary}");
    let text =
        relief().arg("fly").arg(&file).arg("--path").arg(&path).args(["--no-render", "--quiet"]).output().unwrap();
    let line = String::from_utf8_lossy(&text.stdout);
    assert!(line.contains(" strip vertices per frame (mean)") && !line.contains("splits"), "{line}");
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(&stats).unwrap()).unwrap();
    let per_frame = report["frames"].as_array().unwrap();
    assert_eq!(per_frame.len(), 3);
    assert_eq!(printed["frames"].as_array().unwrap().len(), 3);
    for key in ["update_ms", "render_ms", "triangles", "strip_len", "upload_bytes", "major_faults", "minor_faults"] {
        assert!(per_frame[0].get(key).is_some(), "frame lacks {key}");
    }
    for k in 0..3 {
        assert!(frames.join(format!("frame_{k:05}.png")).is_file());
    }
}

#[test]
fn render_cli_writes_a_png_and_reports_the_frame() {
    let dir = tempfile::tempdir().unwrap();
    let file = zurich(dir.path());
    let out = dir.path().join("view.png");
    let o = relief()
        .arg("render")
        .arg(&file)
        .args(["--eye", "2000,-1500,1500", "--look", "5000,4500,500", "--width", "200", "--height", "120"])
        .arg("--out")
        .arg(&out)
        .arg("--json")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr_of(&o));
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let strip_len = r["strip_len"].as_u64().unwrap();
    assert_eq!(r["upload_bytes"].as_u64().unwrap(), strip_len * VERTEX_BYTES + FRAME_UNIFORM_BYTES);
    assert_eq!(image::open(&out).unwrap().to_rgba8().dimensions(), (200, 120));
}

/// Bad input: one line naming the problem, exit status 1, no output file.
#[test]
fn bad_input_gives_one_line_errors_and_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let file = zurich(dir.path());
    let out = dir.path().join("never.png");
    let render = |args: &[&str], f: &Path| {
        let o = relief().arg("render").arg(f).args(args).arg("--out").arg(&out).output().unwrap();
        assert_eq!(o.status.code(), Some(1), "{args:?}");
        assert!(!out.exists(), "{args:?} left an output");
        let e = stderr_of(&o);
        assert_eq!(e.trim_end().lines().count(), 1, "{args:?}: {e}");
        e
    };
    let e = render(&["--eye", "1,2,3", "--look", "4,5,6"], &dir.path().join("missing.relief"));
    assert!(e.contains("missing.relief") && e.contains("No such file"), "{e}");
    let e = render(&["--eye", "1,2", "--look", "4,5,6"], &file);
    assert!(e.contains("--eye"), "{e}");
    let e = render(&["--eye", "1,2,3", "--look", "1,2,3"], &file);
    assert!(e.contains("look point equals the eye"), "{e}");
    let e = render(&["--eye", "1,2,3", "--look", "4,5,6", "--width", "100000"], &file);
    assert!(e.contains("image size"), "{e}");
    let e = render(&["--eye", "1,2,3", "--look", "4,5,6", "--tolerance", "0"], &file);
    assert!(e.contains("--tolerance"), "{e}");

    // A path file that is not a path.
    let bad = dir.path().join("bad.json");
    std::fs::write(&bad, "[]").unwrap();
    let frames = dir.path().join("frames");
    let o = relief().arg("fly").arg(&file).arg("--path").arg(&bad).arg("--frames-out").arg(&frames).output().unwrap();
    assert_eq!(o.status.code(), Some(1));
    let e = stderr_of(&o);
    assert_eq!(e.trim_end().lines().count(), 1, "{e}");
    assert!(e.contains("bad.json") && e.contains("no frames"), "{e}");
    assert!(!frames.exists());
}

/// Without a display, `fly` says so in one line and how to fly headless (no panic).
#[test]
fn fly_without_a_display_explains_how_to_fly_headless() {
    let dir = tempfile::tempdir().unwrap();
    let file = zurich(dir.path());
    let o = relief().arg("fly").arg(&file).env_remove("DISPLAY").env_remove("WAYLAND_DISPLAY").output().unwrap();
    assert_eq!(o.status.code(), Some(1));
    let e = stderr_of(&o);
    assert_eq!(e.trim_end().lines().count(), 1, "{e}");
    assert!(e.contains("cannot open a window") && e.contains("--path"), "{e}");
    assert!(!e.contains("panicked"), "{e}");
}

/// The window opens, draws frames with the panel and closes cleanly under Xvfb; keys work: R
/// starts and stops recording a path that loads back, F freezes, T shows the wireframe, P saves a
/// screenshot, Escape quits (see `common::window_session`).
#[test]
fn fly_window_runs_under_xvfb_and_keys_record_and_screenshot() {
    let dir = tempfile::tempdir().unwrap();
    let file = zurich(dir.path());
    window_session(&["fly".as_ref(), file.as_os_str()]);
}

/// The same session with heights paged through a height cache of two 256-cell tiles (the grid
/// needs 1 MiB resident): the window's frames, panel and keys work the same.
#[test]
fn fly_window_runs_with_the_height_cache() {
    let dir = tempfile::tempdir().unwrap();
    let file = zurich(dir.path());
    window_session(&["fly".as_ref(), file.as_os_str(), "--gpu-memory".as_ref(), "600K".as_ref()]);
}

/// Closing the window while recording saves the path and says so (`--record` starts recording at
/// the first frame; `--exit-after-frames` closes the window as Escape would); with an exaggerated
/// scene the path keeps the terrain's metres, so it replays the same with the same exaggeration.
#[test]
fn closing_the_window_while_recording_saves_the_path() {
    use std::process::Command;
    if Command::new("xvfb-run").arg("--help").output().is_err() {
        eprintln!("note: xvfb-run not installed; window test skipped");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let file = zurich(dir.path());
    let out = dir.path().join("out");
    std::fs::create_dir(&out).unwrap();
    let rt = dir.path().join("rt");
    std::fs::create_dir(&rt).unwrap();
    std::fs::set_permissions(&rt, std::os::unix::fs::PermissionsExt::from_mode(0o700)).unwrap();
    // Display numbers of its own (see `common::xvfb_run`).
    let display = |attempt: u32| 600 + (std::process::id() % 300) + 41 * attempt;
    let (o, e) = common::xvfb_run(display, &out, |c| {
        c.arg(env!("CARGO_BIN_EXE_relief"))
            .args(["fly".as_ref(), file.as_os_str()])
            .args(["--record", "--exit-after-frames", "12", "--width", "320", "--height", "200", "--quiet"])
            .args(["--z-exaggeration", "2", "--output-dir"])
            .arg(&out)
            .env("XDG_RUNTIME_DIR", &rt);
    });
    assert!(o.status.success(), "{e}");
    let saved: Vec<PathBuf> = std::fs::read_dir(&out).unwrap().map(|d| d.unwrap().path()).collect();
    assert_eq!(saved.len(), 1, "{saved:?}");
    let want = format!("relief: closed while recording; path: {} (", saved[0].display());
    assert!(e.contains(&want), "{e}");
    let path = relief::flight::FlightPath::load(&saved[0]).unwrap();
    assert!(path.frames.len() >= 10, "{} frames", path.frames.len());
    // The start view (no key pressed: the eye stays), in the terrain's metres: above the highest
    // point by 0.15 of the DEM's diagonal in the scene, so by half that in the terrain.
    let t = TerrainFile::open(&file).unwrap();
    let h = t.header();
    let [_, _, x1, y1] = h.valid_window;
    let diagonal = (x1 as f64 * h.spacing_m[0]).hypot(y1 as f64 * h.spacing_m[1]);
    let want_z = h.z_max + 0.075 * diagonal;
    for f in &path.frames {
        assert!((f.eye[2] - want_z).abs() < 1e-6, "eye {:?}, want z {want_z}", f.eye);
    }
}
