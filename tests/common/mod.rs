//! Helpers shared by the integration tests.
#![allow(dead_code, reason = "each test binary uses its own subset of the helpers")]

use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

use relief::camera::Camera;
use relief::flight::frame::{fly, FlightOptions, FlightReport, FrameSource};
use relief::flight::terrain::TerrainSource;
use relief::format::terrain::TerrainFile;
use relief::refine::RefineOptions;
use relief::render::{DrawStyle, Gpu, TerrainPresenter};

pub mod crack;

/// The real DEMs in ../shared/data/dem (see its README).
pub const REAL_DEMS: [&str; 6] = [
    "zurich_25m_i16.tif",
    "lidar_1m_f32.tif",
    "etopo20_world.tif",
    "fuji_terrain_rgb.png",
    "terrarium.png",
    "hugo_site_nodata.asc",
];

/// Path of a real DEM in ../shared/data/dem.
pub fn dem(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/dem").join(name)
}

/// A mesh in ../shared/data/mesh (see its README).
pub fn mesh(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/mesh").join(name)
}

/// One device for the whole test binary (software Vulkan starts slowly), used by one test at a
/// time.
pub fn gpu() -> std::sync::MutexGuard<'static, Gpu> {
    static GPU: OnceLock<Mutex<Gpu>> = OnceLock::new();
    GPU.get_or_init(|| {
        Mutex::new(Gpu::headless().unwrap_or_else(|e| {
            panic!("{e}\nthe rendering tests need a Vulkan adapter: run `bash tools/test.sh`, which installs lavapipe")
        }))
    })
    .lock()
    .unwrap_or_else(|p| p.into_inner())
}

/// Flies `terrain` headless along `cameras` (all `w` × `h`), drawing every frame as `relief fly
/// --path` does: refined on the calling thread, or on the refinement thread with `threaded`.
pub fn fly_terrain(
    gpu: &Gpu,
    terrain: &std::sync::Arc<TerrainFile>,
    cameras: &[Camera],
    refine: RefineOptions,
    threaded: bool,
    frames_out: Option<PathBuf>,
) -> FlightReport {
    let (w, h) = (cameras[0].width_px, cameras[0].height_px);
    let mut source = TerrainSource::new(terrain.clone(), refine, 1, threaded).unwrap();
    let mut presenter = TerrainPresenter::new(
        gpu,
        terrain.clone(),
        w,
        h,
        DrawStyle::default(),
        Default::default(),
        relief::sys::progress::Progress::hidden(),
    )
    .unwrap();
    let mut options = FlightOptions::new(w, h, refine.tolerance_px);
    options.frames_out = frames_out;
    fly(&mut source as &mut dyn FrameSource, cameras, Some(&mut presenter), &options).unwrap()
}

/// Tolerance: lavapipe renders deterministically for one Mesa/LLVM build, but another build (or
/// a GPU) may round the shading differently by a level or two and break ties at triangle and
/// wireframe edges differently, which changes isolated pixels a lot. So: the mean absolute
/// channel difference stays under 1.5 levels of 255, and at most 1% of pixels differ by more
/// than 24 levels in any channel. A wrong ramp, light, fog, tiling or geometry moves far more.
pub fn compare(got: &image::RgbaImage, want: &image::RgbaImage) -> Result<(), String> {
    if got.dimensions() != want.dimensions() {
        return Err(format!("size {:?}, golden {:?}", got.dimensions(), want.dimensions()));
    }
    let (mut sum, mut big) = (0u64, 0usize);
    for (a, b) in got.pixels().zip(want.pixels()) {
        let d = (0..3).map(|c| (a[c] as i32 - b[c] as i32).unsigned_abs()).max().unwrap_or(0);
        sum += (0..3).map(|c| (a[c] as i32 - b[c] as i32).unsigned_abs() as u64).sum::<u64>();
        big += (d > 24) as usize;
    }
    let pixels = (got.width() * got.height()) as f64;
    let mean = sum as f64 / (3.0 * pixels);
    let frac_big = big as f64 / pixels;
    if mean > 1.5 || frac_big > 0.01 {
        return Err(format!("mean difference {mean:.3} levels, {:.3}% of pixels off by > 24", 100.0 * frac_big));
    }
    Ok(())
}

/// Compares `got` with the golden image `tests/golden/NAME.png` ([`compare`]), or writes it there
/// with `RELIEF_BLESS=1`. On a difference, saves the actual image beside the test binary's
/// temporary files and says where.
pub fn check_golden(name: &str, got: &image::RgbaImage) -> Result<(), String> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden").join(format!("{name}.png"));
    if std::env::var_os("RELIEF_BLESS").is_some() {
        got.save(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        return Ok(());
    }
    let want = match image::open(&path) {
        Ok(i) => i.to_rgba8(),
        Err(e) => return Err(format!("{}: {e} (create the golden images with RELIEF_BLESS=1)", path.display())),
    };
    compare(got, &want).map_err(|e| {
        let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("{name}.actual.png"));
        let saved = got.save(&out).map(|_| out.display().to_string()).unwrap_or_else(|e| e.to_string());
        format!("{name}: {e} (actual image: {saved})")
    })
}

/// The relief binary, with a private runtime directory (Mesa warns on stderr without a valid one,
/// and tests assert on stderr).
pub fn relief() -> std::process::Command {
    let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_relief"));
    let rt = Path::new(env!("CARGO_TARGET_TMPDIR")).join("xdg-runtime");
    let _ = std::fs::create_dir_all(&rt);
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let _ = std::fs::set_permissions(&rt, std::fs::Permissions::from_mode(0o700));
    }
    c.env("XDG_RUNTIME_DIR", rt);
    c
}

pub fn stderr_of(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Runs `relief ARGS…`, expects failure with one stderr line containing `needle`; returns it.
pub fn fails_with(args: &[&std::ffi::OsStr], needle: &str) -> String {
    let out = relief().args(args).output().unwrap();
    let err = stderr_of(&out);
    assert!(!out.status.success(), "expected failure for {args:?}");
    assert_eq!(err.trim_end().lines().count(), 1, "one line expected: {err}");
    assert!(err.contains(needle), "'{needle}' not in: {err}");
    assert!(!err.contains("panicked"), "{err}");
    err
}

/// Runs `relief path KIND FILE --frames FRAMES --out OUT` (a camera path about FILE's box) and
/// asserts that it succeeded.
pub fn make_path(kind: &str, file: &Path, frames: u32, out: &Path) {
    let o = relief()
        .args(["path", kind])
        .arg(file)
        .args(["--frames", &frames.to_string(), "--out"])
        .arg(out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr_of(&o));
}

/// Runs `xvfb-run` on display `display(attempt)` with the command `then` sets up, and returns its
/// output and stderr. `xvfb-run -a` picks the first free display from 99 up, and two test binaries
/// (or another user of the machine) starting at once can race for it: then the window cannot
/// connect. So each caller starts from display numbers of its own, and on that failure only tries
/// again (up to three times) on another, with `out` emptied first.
pub fn xvfb_run(
    display: impl Fn(u32) -> u32,
    out: &Path,
    then: impl Fn(&mut std::process::Command),
) -> (std::process::Output, String) {
    let mut attempt = 0u32;
    loop {
        let mut c = std::process::Command::new("xvfb-run");
        c.args(["-a", "-n", &display(attempt).to_string(), "-s", "-screen 0 800x600x24"]);
        then(&mut c);
        let o = c.output().unwrap();
        let e = stderr_of(&o);
        attempt += 1;
        if attempt < 3 && !o.status.success() && e.contains("connection to X server") {
            eprintln!("note: the X server was not reachable (attempt {attempt}); trying another display");
            for f in std::fs::read_dir(out).unwrap() {
                let _ = std::fs::remove_file(f.unwrap().path());
            }
            continue;
        }
        return (o, e);
    }
}

/// Runs `relief ARGS… --width 480 --height 300 …` in a window under Xvfb and presses keys: R
/// twice (records a path), F (freeze) and T (wireframe), P (a screenshot), then Escape, which must
/// close it. Asserts that it ran cleanly, that the recorded path loads back with at least two
/// frames and that the screenshot is 480 × 300. Skipped, with a note, where xvfb-run or xdotool
/// is not installed (tools/test.sh installs both).
pub fn window_session(args: &[&std::ffi::OsStr]) {
    use std::process::Command;
    let have = |tool: &str| Command::new(tool).arg("--help").output().is_ok();
    if !have("xvfb-run") || !have("xdotool") {
        eprintln!("note: xvfb-run or xdotool not installed; window test skipped");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let rt = dir.path().join("rt");
    std::fs::create_dir(&rt).unwrap();
    std::fs::set_permissions(&rt, std::os::unix::fs::PermissionsExt::from_mode(0o700)).unwrap();
    let out = dir.path().join("out");
    std::fs::create_dir(&out).unwrap();
    // One shell under xvfb-run: start the window, press keys once it is mapped, wait for it.
    let script = r#"
        "$RELIEF" "$@" --width 480 --height 300 --exit-after-frames 100000 --output-dir "$OUT" --quiet &
        pid=$!
        for _ in $(seq 100); do w=$(xdotool search --name '^relief' 2>/dev/null | head -1); [ -n "$w" ] && break; sleep 0.1; done
        [ -n "$w" ] || { echo "no window"; kill $pid; exit 3; }
        sleep 1
        # XTEST key events to the focused window (winit ignores synthetic sent events).
        xdotool windowfocus --sync "$w"; sleep 0.5
        # Xvfb without a window manager now and then drops a key event: retry until a path exists.
        for _ in 1 2 3; do
          xdotool key r; sleep 1.5; xdotool key r; sleep 0.5
          ls "$OUT"/*.json >/dev/null 2>&1 && break
        done
        # Freeze (a terrain draws the frozen view's frustum) and wireframe, then a screenshot.
        xdotool key f; xdotool key t; sleep 0.5
        for _ in 1 2 3; do xdotool key p; sleep 1; ls "$OUT"/*.png >/dev/null 2>&1 && break; done
        for _ in 1 2 3; do
          xdotool key Escape
          for _ in $(seq 30); do kill -0 $pid 2>/dev/null || break; sleep 0.1; done
          kill -0 $pid 2>/dev/null || break
        done
        kill -0 $pid 2>/dev/null && { echo "Escape did not close the window"; kill $pid; exit 4; }
        wait $pid
    "#;
    let display = |attempt: u32| 100 + (std::process::id() % 400) + 37 * attempt;
    let (o, e) = xvfb_run(display, &out, |c| {
        c.args(["sh", "-c", script, "sh"])
            .args(args)
            .env("RELIEF", env!("CARGO_BIN_EXE_relief"))
            .env("OUT", &out)
            .env("XDG_RUNTIME_DIR", &rt);
    });
    assert!(o.status.success(), "window flight failed ({:?}): {e}{}", o.status, String::from_utf8_lossy(&o.stdout));
    assert!(!e.contains("panicked"), "{e}");
    let files: Vec<PathBuf> = std::fs::read_dir(&out).unwrap().map(|d| d.unwrap().path()).collect();
    let path = files.iter().find(|p| p.extension().is_some_and(|x| x == "json")).expect("a recorded path");
    let recorded = relief::flight::FlightPath::load(path).unwrap();
    assert!(recorded.frames.len() >= 2, "{} frames recorded", recorded.frames.len());
    let shot = files.iter().find(|p| p.extension().is_some_and(|x| x == "png")).expect("a screenshot");
    assert_eq!(image::open(shot).unwrap().to_rgba8().dimensions(), (480, 300));
}
