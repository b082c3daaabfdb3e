//! The web viewer in a real browser: Debian's headless Chromium (WebGL2 on SwiftShader, driven by
//! tools/browser.py over the DevTools pipe) opens the page `relief serve --viewer` serves (the
//! library's server, with the viewer tools/web.sh built in target/viewer) on the bundled Zürich
//! terrain. Its screenshot is compared with the native render of the same view by the same
//! pipeline (wgpu on Vulkan, lavapipe here), and the server's log with what the page says it
//! fetched. Bad input must be a message in the page. Run `bash tools/web.sh` first (tools/test.sh
//! does).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;
use std::time::Duration;

use glam::DVec3;
use relief_core::format::terrain::TerrainFile;
use relief_core::layout::LayoutKind;
use relief_core::pager::serve::{Faults, ServeOptions, Server};
use relief_core::preprocess::convert::{convert, ConvertOptions};
use relief_core::refine::{RefineOptions, Refiner, Strip};
use relief_web::draw::{mip_levels, near_for, render_offscreen, FrameUniform};
use relief_web::scene::{look_of, positions, Orbit};

fn checkout() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The built viewer's files, served under their names.
fn viewer_files() -> Vec<(String, PathBuf)> {
    let dir = std::env::var_os("RELIEF_VIEWER_DIR").map_or_else(|| checkout().join("target/viewer"), PathBuf::from);
    ["index.html", "relief_web.js", "relief_web_bg.wasm"]
        .iter()
        .map(|f| {
            let p = dir.join(f);
            assert!(p.is_file(), "{}: missing; build the viewer first: bash tools/web.sh", p.display());
            (f.to_string(), p)
        })
        .collect()
}

fn zurich(dir: &Path) -> PathBuf {
    let out = dir.join("zurich.relief");
    convert(&checkout().join("data/zurich_25m_i16.tif"), &out, &ConvertOptions::new(LayoutKind::Interleaved)).unwrap();
    out
}

fn serve(files: Vec<(String, PathBuf)>, options: ServeOptions) -> Server {
    Server::start(files, "127.0.0.1:0".parse().unwrap(), options).unwrap()
}

/// What tools/browser.py reported.
struct Run {
    code: i32,
    stdout: String,
    stderr: String,
    status: serde_json::Value,
}

/// Opens `url` in headless Chromium at `w × h`; with `expect_error`, succeeds only if the page
/// reports an error containing it.
fn browse(url: &str, dir: &Path, size: (u32, u32), shot: Option<&Path>, expect_error: Option<&str>) -> Run {
    browse_with(url, dir, size, shot, expect_error, &[], &[])
}

/// [`browse`] with more arguments for tools/browser.py and variables for its environment.
fn browse_with(
    url: &str,
    dir: &Path,
    (w, h): (u32, u32),
    shot: Option<&Path>,
    expect_error: Option<&str>,
    args: &[&str],
    env: &[(&str, &str)],
) -> Run {
    let status = dir.join(format!("status-{}.json", std::process::id()));
    let mut c = Command::new("python3");
    c.arg(checkout().join("tools/browser.py")).arg(url).args(["--width", &w.to_string(), "--height", &h.to_string()]);
    c.args(["--timeout", "90", "--status-json"]).arg(&status);
    if let Some(s) = shot {
        c.arg("--out").arg(s);
    }
    if let Some(e) = expect_error {
        c.args(["--expect-error", e]);
    }
    c.args(args).envs(env.iter().copied());
    let out = c.output().expect("python3 runs tools/browser.py");
    let status = std::fs::read_to_string(&status).ok().and_then(|s| serde_json::from_str(&s).ok()).unwrap_or_default();
    Run {
        code: out.status.code().unwrap_or(-1),
        stdout: String::from_utf8_lossy(&out.stdout).into(),
        stderr: String::from_utf8_lossy(&out.stderr).into(),
        status,
    }
}

/// The view the tests fly: over Zürich from its southern edge, looking north.
const EYE: [f64; 3] = [6400.0, 640.0, 1126.0];
const LOOK: [f64; 3] = [6400.0, 7680.0, 393.0];
const SIZE: (u32, u32) = (480, 270);
const TOLERANCE_PX: f64 = 2.0;

/// The native reference: the local file refined for the page's camera and drawn offscreen.
fn native_render(local: &Path) -> (Vec<u8>, u64) {
    let terrain = TerrainFile::open(local).unwrap();
    native_render_of(&terrain, Orbit::looking(DVec3::from(EYE), DVec3::from(LOOK), 1.0), 1.0, None)
}

/// [`native_render`] for any orbit and exaggeration, with an image draped (its file, and how
/// much the hillshade lights it) as the page drapes it.
fn native_render_of(terrain: &TerrainFile, orbit: Orbit, z: f64, image: Option<(&Path, f32)>) -> (Vec<u8>, u64) {
    let camera = orbit.camera(SIZE.0, SIZE.1).unwrap();
    let options = RefineOptions { tolerance_px: TOLERANCE_PX, heights: true, z_exaggeration: z, ..Default::default() };
    let mut strip = Strip::new();
    Refiner::new(1).unwrap().refine_file(terrain, &camera, &options, &mut strip).unwrap();
    relief_core::heightcache::exact_heights(terrain, &strip.vertices, &mut strip.morph).unwrap();
    let look = look_of(terrain.header(), z);
    let drape = image.map(|(path, shade)| {
        let rgba = image::open(path).unwrap().to_rgba8();
        let (w, h) = rgba.dimensions();
        let ext = path.extension().unwrap().to_str().unwrap();
        let wf = relief_core::georef::drape::world_file_extensions(ext)
            .iter()
            .map(|e| path.with_extension(e))
            .find(|p| p.exists())
            .map(|p| relief_core::georef::drape::parse_world_file(&std::fs::read_to_string(p).unwrap()).unwrap());
        let (uv, wraps) =
            relief_core::georef::drape::uv_of_grid(w, h, wf, terrain.header().valid_window, terrain.header().georef)
                .unwrap();
        (mip_levels(w, h, rgba.into_raw()), uv, wraps, shade)
    });
    let positions = positions(terrain.header(), &strip, &look, z, drape.as_ref().map(|d| d.1));
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let adapter = pollster::block_on(instance.request_adapter(&Default::default()))
        .expect("a Vulkan adapter (lavapipe: apt-get install mesa-vulkan-drivers)");
    let (device, queue) = pollster::block_on(adapter.request_device(&Default::default())).unwrap();
    let mut uniform = FrameUniform::new(&camera, &look, near_for(orbit.distance_m), true);
    if let Some(d) = &drape {
        uniform = uniform.with_imagery(d.3, d.2);
    }
    let image = drape.as_ref().map(|d| (&d.0[..], d.2));
    let rgba = render_offscreen(&device, &queue, &positions, image, SIZE, &uniform).unwrap();
    (rgba, strip.vertices.len().saturating_sub(2) as u64)
}

/// RGBA8 rows of a PNG.
fn decode_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    let rgba = match info.color_type {
        png::ColorType::Rgba => buf[..info.buffer_size()].to_vec(),
        png::ColorType::Rgb => buf[..info.buffer_size()].chunks(3).flat_map(|p| [p[0], p[1], p[2], 255]).collect(),
        other => panic!("{}: a {other:?} PNG", path.display()),
    };
    (info.width, info.height, rgba)
}

/// The page's first complete frame is the native render of the same view: mean channel
/// difference ≤ 1 level of 255, and ≤ 1 % of pixels off by more than 24 levels in any channel
/// (SwiftShader and lavapipe rasterise edges independently; measured here: 0.07 levels, 0.1 %).
/// The opening request is 64 KiB, so the rest comes progressively: in a few round trips, each
/// byte once, as the server's log shows.
#[test]
fn the_page_draws_zurich_as_the_native_renderer_does_fetching_each_byte_once() {
    let dir = tempfile::tempdir().unwrap();
    let local = zurich(dir.path());
    let mut files = viewer_files();
    files.push(("zurich.relief".into(), local.clone()));
    let server = serve(files, ServeOptions::default());
    let [ex, ey, ez] = EYE;
    let [lx, ly, lz] = LOOK;
    let url = format!(
        "{}#zurich.relief&eye={ex},{ey},{ez}&look={lx},{ly},{lz}&tau={TOLERANCE_PX}&hud=0&first=65536&gpu=webgl2",
        server.url("")
    );
    let shot = dir.path().join("page.png");
    let run = browse(&url, dir.path(), SIZE, Some(&shot), None);
    assert_eq!(run.code, 0, "{url}\n{}\n{}", run.stdout, run.stderr);
    let s = &run.status;
    eprintln!("page status: {s}");
    assert_eq!(s["complete"], true, "{s}");
    assert!(s["backend"].as_str().unwrap_or_default().starts_with("Gl:"), "drawn with WebGL2: {s}");

    let (native, native_triangles) = native_render(&local);
    assert_eq!(s["triangles"].as_u64(), Some(native_triangles), "the page refined the native strip: {s}");
    let (w, h, page) = decode_png(&shot);
    assert_eq!((w, h), SIZE, "the screenshot's size");
    compare_with_native(&page, &native, "page");
    // A sky-only frame would pass a comparison of two sky-only frames: the terrain covers much.
    let sky = native.chunks(4).filter(|p| p[..3] == native[..3]).count();
    assert!(sky < (w * h) as usize * 7 / 10, "the view shows terrain ({sky} sky pixels)");

    // The server's log: each terrain byte sent once, the page's ranges those of the log.
    let log: Vec<(u64, u64)> =
        server.log().iter().filter(|l| l.name == "zurich.relief").filter_map(|l| l.range).collect();
    let mut sorted = log.clone();
    sorted.sort_unstable();
    assert!(sorted.windows(2).all(|p| p[0].1 <= p[1].0), "a byte fetched twice: {sorted:?}");
    let page_ranges: Vec<(u64, u64)> = serde_json::from_value(s["ranges"].clone()).unwrap();
    let mut page_sorted = page_ranges.clone();
    page_sorted.sort_unstable();
    assert_eq!(page_sorted, sorted, "the page fetched what the server sent");
    let rounds = s["first_complete_round_trips"].as_u64().unwrap();
    assert!((2..=4).contains(&rounds), "first complete frame within a few round trips: {s}");
    assert!(s["frames"].as_u64().unwrap() >= 2, "coarser frames were drawn while the data came: {s}");
    assert!(
        server.log().iter().all(|l| l.status == 200 || l.status == 206),
        "every request answered: {:?}",
        server.log()
    );
}

/// `page` (RGBA8, [`SIZE`]) is `native` within the tolerance the tests state; else both are kept
/// in target/web-test for a look.
fn compare_with_native(page: &[u8], native: &[u8], what: &str) {
    let (w, h) = SIZE;
    assert_eq!(page.len(), native.len(), "{what}: image sizes");
    let diffs: Vec<u8> =
        page.iter().zip(native).enumerate().filter(|(i, _)| i % 4 != 3).map(|(_, (a, b))| a.abs_diff(*b)).collect();
    let mean = diffs.iter().map(|&d| d as f64).sum::<f64>() / diffs.len() as f64;
    let off = page.chunks(4).zip(native.chunks(4)).filter(|(a, b)| (0..3).any(|k| a[k].abs_diff(b[k]) > 24)).count();
    let off_share = off as f64 / (w * h) as f64;
    eprintln!("{what} vs native: mean difference {mean:.2} levels, {:.2} % of pixels off by > 24", 100.0 * off_share);
    if mean > 1.0 || off_share > 0.01 {
        let keep = checkout().join("target/web-test");
        std::fs::create_dir_all(&keep).unwrap();
        for (name, rgba) in [(format!("{what}.png"), page), ("native.png".to_string(), native)] {
            let mut enc = png::Encoder::new(std::fs::File::create(keep.join(name)).unwrap(), w, h);
            enc.set_color(png::ColorType::Rgba);
            enc.write_header().unwrap().write_image_data(rgba).unwrap();
        }
        panic!("{what} differs from the native render (mean {mean:.2}, {off} pixels off): see {}", keep.display());
    }
}

/// Opens Zürich at the tests' view with `#readback=1&gpu=GPU` (Chromium's environment `env`),
/// waits for the page's read-back of its first complete frame and compares those pixels with
/// the native render; returns the page's status.
fn read_back_and_compare(gpu: &str, env: &[(&str, &str)], what: &str) -> serde_json::Value {
    let dir = tempfile::tempdir().unwrap();
    let local = zurich(dir.path());
    let mut files = viewer_files();
    files.push(("zurich.relief".into(), local.clone()));
    let server = serve(files, ServeOptions::default());
    let [ex, ey, ez] = EYE;
    let [lx, ly, lz] = LOOK;
    let url = format!(
        "{}#zurich.relief&eye={ex},{ey},{ez}&look={lx},{ly},{lz}&tau={TOLERANCE_PX}&hud=0&readback=1&gpu={gpu}",
        server.url("")
    );
    let run = browse_with(
        &url,
        dir.path(),
        SIZE,
        None,
        None,
        &[
            "--ready-expr",
            "window.relief && window.relief.status().readback_done === true",
            "--status-expr",
            "JSON.stringify({status: window.relief.status(), pixels: window.relief.pixels()})",
        ],
        env,
    );
    assert_eq!(run.code, 0, "{url}\n{}\n{}", run.stdout, run.stderr);
    let s = run.status["status"].clone();
    use base64::Engine;
    let pixels = base64::engine::general_purpose::STANDARD.decode(run.status["pixels"].as_str().unwrap()).unwrap();
    let (native, native_triangles) = native_render(&local);
    assert_eq!(s["triangles"].as_u64(), Some(native_triangles), "the page refined the native strip: {s}");
    compare_with_native(&pixels, &native, what);
    s
}

/// The read-back path (`#readback=1`: the first complete frame drawn again into a texture and
/// read back in the page, what the WebGPU test needs since a screenshot does not show it), here
/// on WebGL2: its pixels are the native render's within the same tolerance.
#[test]
fn the_page_reads_back_what_the_native_renderer_draws() {
    let s = read_back_and_compare("webgl2", &[], "readback");
    assert!(s["backend"].as_str().unwrap_or_default().starts_with("Gl:"), "drawn with WebGL2: {s}");
}

/// Imagery: NASA's Visible Earth image (data/imagery, placed by its world file) draped on the
/// real ETOPO world DEM at 40× exaggeration, in the page as natively (the image decoded by the
/// browser there, by the `image` crate here; mip levels by the same code), within the same
/// tolerance.
#[test]
fn the_page_drapes_imagery_as_the_native_renderer_does() {
    let dir = tempfile::tempdir().unwrap();
    let world = dir.path().join("world.relief");
    let dem = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/dem/etopo20_world.tif");
    convert(&dem, &world, &ConvertOptions::new(LayoutKind::Interleaved)).unwrap();
    let imagery = checkout().join("data/imagery");
    let mut files = viewer_files();
    files.push(("world.relief".into(), world.clone()));
    files.push(("earth_2048.jpg".into(), imagery.join("earth_2048.jpg")));
    files.push(("earth_2048.jgw".into(), imagery.join("earth_2048.jgw")));
    let server = serve(files, ServeOptions::default());
    let url = format!(
        "{}#world.relief&z=40&tau={TOLERANCE_PX}&hud=0&imagery=earth_2048.jpg&shade=0.7&gpu=webgl2",
        server.url("")
    );
    let shot = dir.path().join("imagery.png");
    let run = browse(&url, dir.path(), SIZE, Some(&shot), None);
    assert_eq!(run.code, 0, "{url}\n{}\n{}", run.stdout, run.stderr);
    let terrain = TerrainFile::open(&world).unwrap();
    let (native, native_triangles) =
        native_render_of(&terrain, Orbit::overview(&terrain, 40.0), 40.0, Some((&imagery.join("earth_2048.jpg"), 0.7)));
    assert_eq!(run.status["triangles"].as_u64(), Some(native_triangles), "{}", run.status);
    let (_, _, page) = decode_png(&shot);
    compare_with_native(&page, &native, "imagery");
    // The image is drawn: blue oceans somewhere, not the height ramp's greens alone.
    let blue = native.chunks(4).filter(|p| p[2] > p[0].saturating_add(40) && p[2] > p[1]).count();
    assert!(blue > (SIZE.0 * SIZE.1 / 20) as usize, "oceans from the image ({blue} blue pixels)");
}

/// The WebGPU path (Chromium's `--enable-unsafe-webgpu`: WebGPU on SwiftShader, whose canvas a
/// screenshot does not show, and which refuses mappings once a WebGPU canvas showed a frame):
/// the page refines as ever, draws its first complete frame into a texture, reads it back, and
/// the pixels are the native render's within the same tolerance.
#[test]
fn the_webgpu_path_reads_back_what_the_native_renderer_draws() {
    let s = read_back_and_compare("webgpu", &[("RELIEF_CHROMIUM_FLAGS", "--enable-unsafe-webgpu")], "webgpu");
    assert!(s["backend"].as_str().unwrap_or_default().starts_with("BrowserWebGpu"), "drawn with WebGPU: {s}");
}

/// Every kind of bad input is a one-line message in the page, never a blank canvas.
#[test]
fn bad_input_is_a_message_in_the_page() {
    let dir = tempfile::tempdir().unwrap();
    let local = zurich(dir.path());
    // A file newer than the viewer: the version field (bytes 8..12) raised.
    let newer = dir.path().join("newer.relief");
    let mut bytes = std::fs::read(&local).unwrap();
    bytes[8..12].copy_from_slice(&99u32.to_le_bytes());
    std::fs::write(&newer, &bytes).unwrap();
    let mut files = viewer_files();
    files.push(("zurich.relief".into(), local.clone()));
    files.push(("newer.relief".into(), newer));
    let server = serve(files.clone(), ServeOptions::default());
    let base = server.url("");
    // A server that ignores Range.
    let faults = Arc::new(Faults::default());
    faults.ignore_range.store(true, std::sync::atomic::Ordering::SeqCst);
    let no_ranges = serve(files, ServeOptions { faults, latency: Duration::ZERO, uploads: None });
    // A server on another origin that sends no CORS headers: Python's.
    let other = tempfile::tempdir().unwrap();
    std::fs::copy(&local, other.path().join("zurich.relief")).unwrap();
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    drop(listener);
    let mut python = Command::new("python3")
        .args(["-m", "http.server", &port.to_string(), "--bind", "127.0.0.1"])
        .current_dir(other.path())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    for _ in 0..100 {
        if std::net::TcpStream::connect(("127.0.0.1", port)).is_ok() {
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let cases = [
        (format!("{base}#relief_web.js"), "not a relief terrain file"),
        (format!("{base}#newer.relief"), "newer than this viewer"),
        (format!("{base}#missing.relief"), "answered 404"),
        (format!("{}#zurich.relief", no_ranges.url("")), "does not support range requests"),
        (format!("{base}#http://127.0.0.1:{port}/zurich.relief"), "refuses cross-origin reads"),
        (format!("{base}#zurich.relief&tau=fast"), "#tau=fast: not a number"),
        (base.clone(), "No terrain named"),
        (format!("{base}#zurich.relief&imagery=missing.jpg"), "missing.jpg: the server answered 404"),
        (format!("{base}#zurich.relief&imagery=relief_web.js"), "not an image this browser decodes"),
    ];
    let mut failures = Vec::new();
    for (url, want) in &cases {
        let run = browse(url, dir.path(), (320, 200), None, Some(want));
        let error = run.status["error"].as_str().unwrap_or_default().to_string();
        eprintln!("{url}: {error}");
        if run.code != 0 || error.lines().count() != 1 {
            failures
                .push(format!("{url}: wanted an error with '{want}', got '{error}'\n{}\n{}", run.stdout, run.stderr));
        }
    }
    let _ = python.kill();
    let _ = python.wait();
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The shader's colour is the CPU reference's (`draw::shade`): a flat square seen from above,
/// with and without an image (one white texel stretched over it), at its centre pixel.
#[test]
fn the_shader_colours_as_the_cpu_reference() {
    use relief_core::camera::Camera;
    use relief_web::draw::{shade, srgb_encode, Look, Vertex};
    let square: Vec<Vertex> = [(-1000.0, -1000.0), (1000.0, -1000.0), (-1000.0, 1000.0), (1000.0, 1000.0)]
        .iter()
        .map(|&(x, y)| Vertex { in_scene: [x, y, 0.0], uv: [0.5, 0.5] })
        .collect();
    let look = Look { origin_in_scene: DVec3::ZERO, z_lo: -100.0, z_hi: 300.0, fog_distance_m: 4000.0 };
    let camera = Camera::new(DVec3::new(0.0, -1.0, 1000.0), DVec3::ZERO, DVec3::Z, 60.0, 64, 64).unwrap();
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let adapter = pollster::block_on(instance.request_adapter(&Default::default())).expect("a Vulkan adapter");
    let (device, queue) = pollster::block_on(adapter.request_device(&Default::default())).unwrap();
    let white = [(1, 1, vec![255u8; 4])];
    for imagery in [false, true] {
        let mut u = FrameUniform::new(&camera, &look, 1.0, true);
        if imagery {
            u = u.with_imagery(0.5, false);
        }
        let image = imagery.then_some((&white[..], false));
        let rgba = render_offscreen(&device, &queue, &square, image, (64, 64), &u).unwrap();
        let centre = &rgba[(32 * 64 + 32) * 4..][..3];
        let want = shade(&u, [0.0, 0.0, 1.0], 0.0, 1000.0, [1.0; 3]).map(|c| (srgb_encode(c) * 255.0).round() as u8);
        assert!(
            centre.iter().zip(want).all(|(&g, w)| g.abs_diff(w) <= 1),
            "imagery {imagery}: GPU {centre:?}, CPU reference {want:?}"
        );
    }
}
