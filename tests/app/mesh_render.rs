//! Mesh rendering: golden images of the Stanford bunny, the GPU's shading of known triangles against
//! the CPU reference (`render::mesh_shade`), precision far from the origin, upload sizes, the
//! headless mesh flight and its JSON, `relief mesh view` and its errors, and the mesh window under
//! Xvfb. The WGSL itself is validated with every other shader in tests/render.rs. Regenerate the
//! golden images with `RELIEF_BLESS=1`.

use crate::common;

use common::{check_golden, compare, gpu, mesh, relief, stderr_of, window_session};
use glam::DVec3;
use relief::camera::{Camera, UpAxis};
use relief::error::Result;
use relief::flight::frame::{fly, FlightOptions, Frame, FrameSource, FrameStats, StaticMesh};
use relief::flight::{orbit_box, OrbitOptions};
use relief::mesh::{read_mesh, Bounds};
use relief::render::mesh::MESH_FRAME_UNIFORM_BYTES;
use relief::render::mesh::MESH_VERTEX_BYTES;
use relief::render::mesh_shade::{self, MeshShadeParams};
use relief::render::offscreen::OFFSCREEN_FORMAT;
use relief::render::{Gpu, MeshRenderer, MeshStyle};
use relief::render::{MeshPresenter, MeshStage};
use relief::sys::progress::Progress;

fn bunny() -> StaticMesh {
    StaticMesh::new(&read_mesh(&mesh("bunny.off")).unwrap()).unwrap()
}

/// One frame of `source` seen by `camera`, drawn offscreen.
fn still(gpu: &Gpu, source: &mut dyn FrameSource, camera: &Camera, up: UpAxis, style: MeshStyle) -> image::RgbaImage {
    let mut stage = MeshStage::new(gpu, OFFSCREEN_FORMAT, source.bounds(), up).unwrap();
    source.update(camera, 1.0).unwrap();
    stage.sync(gpu, source.frame(), true, camera).unwrap();
    stage.still(gpu, camera, OFFSCREEN_FORMAT, style).unwrap()
}

/// Frame `frame` of the bunny's default orbit of `frames` (y up, guessed from its box), 320 × 200.
fn bunny_camera(source: &StaticMesh, frame: usize, frames: usize, fov_x_deg: f64) -> Camera {
    let up = UpAxis::guess(source.bounds().extent());
    assert_eq!(up, UpAxis::Y, "the bunny stands on y");
    let path = orbit_box(&source.bounds(), up, &OrbitOptions::new(frames)).unwrap();
    path.camera_with_up(frame, up, fov_x_deg, 320, 200).unwrap()
}

#[test]
fn golden_images_of_the_bunny() {
    let gpu = gpu();
    let mut source = bunny();
    let mut failures = Vec::new();
    // Side view; and a quarter turn on, zoomed in (triangles a few pixels across) with the
    // wireframe.
    for (name, frame, fov, wireframe) in [("bunny", 0, 60.0, false), ("bunny_wire", 1, 20.0, true)] {
        let cam = bunny_camera(&source, frame, 4, fov);
        let img = still(&gpu, &mut source, &cam, UpAxis::Y, MeshStyle { wireframe });
        // The bunny (grey, a little warm) covers a good part of the image, the sky (blue-grey) the
        // rest.
        let sky = img.pixels().filter(|p| p[2] as i32 > p[0] as i32 + 8).count();
        let share = sky as f64 / (320.0 * 200.0);
        let want = if wireframe { 0.02..0.5 } else { 0.5..0.95 };
        assert!(want.contains(&share), "{name}: sky is {:.0}% of the image", 100.0 * share);
        if let Err(e) = check_golden(name, &img) {
            failures.push(e);
        }
    }
    assert!(failures.is_empty(), "golden images differ:\n{}", failures.join("\n"));
}

#[test]
fn the_bunny_golden_comparison_catches_real_changes() {
    let gpu = gpu();
    let mut source = bunny();
    let cam = bunny_camera(&source, 0, 4, 60.0);
    let img = still(&gpu, &mut source, &cam, UpAxis::Y, MeshStyle::default());
    assert!(compare(&img, &img).is_ok());
    let wire = still(&gpu, &mut source, &cam, UpAxis::Y, MeshStyle { wireframe: true });
    assert!(compare(&wire, &img).is_err(), "the wireframe looked the same");
    let turned = bunny_camera(&source, 1, 64, 60.0);
    let other = still(&gpu, &mut source, &turned, UpAxis::Y, MeshStyle::default());
    assert!(compare(&other, &img).is_err(), "a view 5.6° on looked the same");
    let z_up = still(&gpu, &mut source, &cam, UpAxis::Z, MeshStyle::default());
    assert!(compare(&z_up, &img).is_err(), "another sun and sky looked the same");
}

/// sRGB encoding of a linear channel, in levels of 255 (what the 8-bit sRGB target stores).
fn srgb_levels(linear: f64) -> f64 {
    let c = linear.clamp(0.0, 1.0);
    let s = if c <= 0.0031308 { 12.92 * c } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 };
    255.0 * s
}

/// The world point under the centre of pixel (`px`, `py`) on the plane of triangle `t`.
fn point_under_pixel(cam: &Camera, t: [DVec3; 3], px: u32, py: u32) -> DVec3 {
    let (r, u, f) = cam.basis();
    let ndc_x = (px as f64 + 0.5) / cam.width_px as f64 * 2.0 - 1.0;
    let ndc_y = 1.0 - (py as f64 + 0.5) / cam.height_px as f64 * 2.0;
    let tx = (cam.fov_x_deg.to_radians() / 2.0).tan();
    let ty = (cam.fov_y_deg().to_radians() / 2.0).tan();
    let dir = f + r * (tx * ndc_x) + u * (ty * ndc_y);
    let n = (t[1] - t[0]).cross(t[2] - t[0]);
    let s = n.dot(t[0] - cam.eye_in_world) / n.dot(dir);
    cam.eye_in_world + dir * s
}

/// One big triangle, seen from the front, from behind, obliquely, with the sun glancing and far
/// enough for fog: the centre pixel the GPU draws equals the CPU reference within 2 levels of 255
/// per channel (8-bit rounding, half a level, plus f32 shading and the derivative normal).
#[test]
fn gpu_shading_of_a_triangle_matches_the_cpu_reference() {
    let gpu = gpu();
    let (w, h) = (64, 48);
    let tri = [DVec3::new(-4.0, -3.0, 0.0), DVec3::new(4.0, -3.0, 0.0), DVec3::new(0.0, 5.0, 0.0)];
    let centroid = (tri[0] + tri[1] + tri[2]) / 3.0;
    let cases = [
        ("front, head-on", DVec3::new(0.0, 0.0, 3.0), UpAxis::Y),
        ("back, head-on", DVec3::new(0.0, 0.0, -3.0), UpAxis::Y),
        ("front, oblique", DVec3::new(1.5, -2.0, 2.0), UpAxis::Y),
        ("back, oblique, z up", DVec3::new(-2.0, 1.0, -1.5), UpAxis::Z),
        ("front, in fog", DVec3::new(0.3, 0.2, 30.0), UpAxis::X),
    ];
    for (name, offset, up) in cases {
        let eye = centroid + offset;
        let cam = Camera::new(eye, centroid, up.vector(), 60.0, w, h).unwrap();
        let positions: Vec<[f32; 3]> = tri.iter().map(|p| p.as_vec3().to_array()).collect();
        let mut source = StaticMesh::from_triangles(positions).unwrap();
        let img = still(&gpu, &mut source, &cam, up, MeshStyle::default());
        let (px, py) = (w / 2, h / 2);
        let rel = point_under_pixel(&cam, tri, px, py) - eye;
        let params = MeshShadeParams::for_bounds(&source.bounds(), up);
        let n = mesh_shade::face_normal(tri[0], tri[1], tri[2], rel);
        let front = mesh_shade::is_front_facing(tri[0], tri[1], tri[2], eye);
        assert_eq!(front, name.starts_with("front"), "{name}");
        let want = mesh_shade::shade(&params, n, rel, front);
        let got = img.get_pixel(px, py);
        for c in 0..3 {
            let d = (got[c] as f64 - srgb_levels(want[c])).abs();
            assert!(
                d <= 2.0,
                "{name}: channel {c}: GPU {} vs CPU {:.2} levels ({got:?}, {want})",
                got[c],
                srgb_levels(want[c])
            );
        }
    }
}

/// A mesh far from the origin (a terrain exported as a mesh is tens of kilometres across) renders
/// as the same mesh near it: positions are uploaded relative to the eye, so no precision is lost.
#[test]
fn large_world_coordinates_render_like_small_ones() {
    let gpu = gpu();
    let render = |offset: DVec3| {
        // Exactly representable in f32 at both places (multiples of 1/64 below 2^17).
        let corners = [[-1.0, -0.75, 0.25], [1.0, -1.0, 0.0], [0.0, 1.0, 0.5], [-1.0, 1.0, 0.0], [1.0, 0.5, 0.25]];
        let tris = [[0, 1, 2], [0, 2, 3], [1, 4, 2]];
        let positions: Vec<[f32; 3]> =
            tris.iter().flatten().map(|&i| (DVec3::from(corners[i]) + offset).as_vec3().to_array()).collect();
        let mut source = StaticMesh::from_triangles(positions).unwrap();
        // An eye that f32 cannot hold at 40 km (its spacing there is 4 mm).
        let eye = offset + DVec3::new(0.123_456_7, -0.234_567_8, 2.5);
        let cam = Camera::new(eye, offset, DVec3::Y, 60.0, 160, 100).unwrap();
        still(&gpu, &mut source, &cam, UpAxis::Z, MeshStyle { wireframe: true })
    };
    let near = render(DVec3::ZERO);
    let far = render(DVec3::new(30_000.0, 40_000.0, 1_000.0));
    let differing = near.pixels().zip(far.pixels()).filter(|(a, b)| a != b).count();
    assert!(differing <= 20, "{differing} of 16000 pixels differ between the mesh at the origin and at 50 km");
}

#[test]
fn an_upload_is_three_vertices_of_12_bytes_per_triangle() {
    let gpu = gpu();
    let source = bunny();
    let mut r =
        MeshRenderer::new(&gpu, OFFSCREEN_FORMAT, MeshShadeParams::for_bounds(&source.bounds(), UpAxis::Y)).unwrap();
    let triangles = source.triangles().len() as u64 / 3;
    assert_eq!(triangles, read_mesh(&mesh("bunny.off")).unwrap().triangles.len() as u64);
    let bytes = r.upload(&gpu, source.triangles(), DVec3::ZERO).unwrap();
    assert_eq!(MESH_VERTEX_BYTES, 12);
    assert_eq!(bytes, triangles * 3 * MESH_VERTEX_BYTES);
    assert_eq!((r.triangles(), r.last_upload_bytes()), (triangles, bytes));
    // Fewer triangles reuse the buffer and send only themselves.
    assert_eq!(r.upload(&gpu, &source.triangles()[..30], DVec3::ONE).unwrap(), 10 * 36);
    assert_eq!(r.triangles(), 10);
    let e = r.upload(&gpu, &source.triangles()[..4], DVec3::ZERO).unwrap_err().to_string();
    assert!(e.contains("3 positions per triangle"), "{e}");
    assert_eq!(r.triangles(), 10, "a refused upload keeps the previous mesh");
    gpu.wait_idle().unwrap();
}

/// A source that adapts every other frame: the first and every changed frame upload the triangles,
/// the others nothing.
struct Alternating {
    inner: StaticMesh,
    frame: u64,
}

impl FrameSource for Alternating {
    fn update(&mut self, _camera: &Camera, _tolerance_px: f64) -> Result<FrameStats> {
        self.frame += 1;
        let changed = self.frame.is_multiple_of(2);
        Ok(FrameStats {
            update_ms: Some(0.5),
            changed,
            splits: if changed { 3 } else { 0 },
            collapses: if changed { 1 } else { 0 },
            misses: if changed { 1 } else { 0 },
            triangles: self.inner.triangles().len() as u64 / 3,
            pages_read: 2,
            ..FrameStats::default()
        })
    }

    fn frame(&self) -> Frame<'_> {
        self.inner.frame()
    }

    fn bounds(&self) -> Bounds {
        self.inner.bounds()
    }

    fn describe(&self) -> String {
        "alternating".into()
    }
}

#[test]
fn headless_mesh_flight_writes_frames_and_the_json_report() {
    let gpu = gpu();
    let dir = tempfile::tempdir().unwrap();
    let mut source = Alternating { inner: bunny(), frame: 0 };
    let up = UpAxis::guess(source.bounds().extent());
    let path = orbit_box(&source.bounds(), up, &OrbitOptions::new(4)).unwrap();
    let cameras: Vec<Camera> = (0..4).map(|k| path.camera_with_up(k, up, 60.0, 96, 64).unwrap()).collect();
    let (frames_dir, stats) = (dir.path().join("frames"), dir.path().join("stats.json"));
    let mut options = FlightOptions::new(96, 64, 1.0);
    options.frames_out = Some(frames_dir.clone());
    options.stats_out = Some(stats.clone());
    options.progress = Progress::hidden();
    let mut presenter = MeshPresenter::new(&gpu, source.bounds(), up, 96, 64, MeshStyle::default()).unwrap();
    let report = fly(&mut source, &cameras, Some(&mut presenter), &options).unwrap();
    let triangles = source.inner.triangles().len() as u64 / 3;
    let uploads: Vec<u64> = report.frames.iter().map(|f| f.upload_bytes).collect();
    let (full, u) = (triangles * 3 * MESH_VERTEX_BYTES, MESH_FRAME_UNIFORM_BYTES);
    assert_eq!(uploads, [full + u, full + u, u, full + u], "first frame, then only frames that adapted");
    for k in 0..4 {
        let img = image::open(frames_dir.join(format!("frame_{k:05}.png"))).unwrap().to_rgba8();
        assert_eq!(img.dimensions(), (96, 64));
    }
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(&stats).unwrap()).unwrap();
    let top: Vec<&String> = json.as_object().unwrap().keys().collect();
    assert_eq!(top, ["frames", "summary"]);
    let frames = json["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 4);
    for key in [
        "changed",
        "splits",
        "collapses",
        "triangles",
        "misses",
        "miss_pct",
        "pages_read",
        "update_ms",
        "render_ms",
        "frame_ms",
        "upload_bytes",
    ] {
        assert!(frames.iter().all(|f| f.get(key).is_some()), "frames lack {key}");
    }
    assert_eq!((frames[1]["splits"].as_u64(), frames[1]["collapses"].as_u64()), (Some(3), Some(1)));
    assert_eq!(frames[1]["miss_pct"], 20.0);
    assert_eq!(frames[0]["miss_pct"], 0.0);
    let s = &json["summary"];
    for key in ["frame_ms", "triangles", "pages_read", "render_ms", "update_ms", "splits", "misses"] {
        for stat in ["mean", "median", "max", "total"] {
            assert!(s[key][stat].is_number(), "summary lacks {key}.{stat}: {s}");
        }
    }
    assert_eq!(s["pages_read"]["total"], 8.0);
    assert_eq!(s["splits"]["mean"].as_f64().unwrap() + s["collapses"]["mean"].as_f64().unwrap(), 2.0);
    assert_eq!(s["miss_pct"], 20.0, "2 misses among 8 adaptations and 2 misses");
    assert_eq!(s["triangles"]["mean"], triangles as f64);
    assert_eq!(s["source"], "alternating");
}

#[test]
fn mesh_view_cli_flies_headless_and_reports_json() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("orbit.json");
    let o = relief()
        .args(["path", "orbit"])
        .arg(mesh("bunny.off"))
        .args(["--frames", "3", "--out"])
        .arg(&path)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr_of(&o));
    let frames = dir.path().join("frames");
    let o = relief()
        .args(["mesh", "view"])
        .arg(mesh("bunny.off"))
        .arg("--path")
        .arg(&path)
        .arg("--frames-out")
        .arg(&frames)
        .args(["--width", "64", "--height", "48", "--json", "--quiet"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr_of(&o));
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(report["frames"].as_array().unwrap().len(), 3);
    assert_eq!(report["summary"]["width"], 64);
    assert!(report["summary"]["triangles"]["mean"].as_f64().unwrap() > 60_000.0);
    assert!(frames.join("frame_00002.png").is_file());
}

/// Bad input: one line naming the problem, exit status 1, no frames written.
#[test]
fn mesh_view_bad_input_gives_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let good_path = dir.path().join("orbit.json");
    let source = bunny();
    orbit_box(&source.bounds(), UpAxis::Y, &OrbitOptions::new(2)).unwrap().save(&good_path).unwrap();
    let empty = dir.path().join("empty.json");
    std::fs::write(&empty, "[]").unwrap();
    let frames = dir.path().join("frames");
    let fails = |input: &std::path::Path, path: &std::path::Path, extra: &[&str]| {
        let o = relief()
            .args(["mesh", "view"])
            .arg(input)
            .arg("--path")
            .arg(path)
            .arg("--frames-out")
            .arg(&frames)
            .args(extra)
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(1), "{input:?} {path:?} {extra:?}");
        assert!(!frames.exists(), "frames were written");
        let e = stderr_of(&o);
        assert_eq!(e.trim_end().lines().count(), 1, "{e}");
        assert!(!e.contains("panicked"), "{e}");
        e
    };
    let e = fails(&dir.path().join("missing.off"), &good_path, &[]);
    assert!(e.contains("missing.off") && e.contains("No such file"), "{e}");
    let e = fails(&mesh("bunny.off"), &empty, &[]);
    assert!(e.contains("empty.json") && e.contains("no frames"), "{e}");
    let e = fails(&mesh("bunny.off"), &dir.path().join("nopath.json"), &[]);
    assert!(e.contains("nopath.json"), "{e}");
    let not_a_mesh = dir.path().join("notes.txt");
    std::fs::write(&not_a_mesh, "hello\n").unwrap();
    let e = fails(&not_a_mesh, &good_path, &[]);
    assert!(e.contains("notes.txt") && e.contains("unknown mesh format"), "{e}");
    let e = fails(&mesh("bunny.off"), &good_path, &["--tolerance", "0"]);
    assert!(e.contains("--tolerance"), "{e}");
}

/// The mesh window opens on the bunny, takes the shared keys and closes on Escape.
#[test]
fn mesh_window_runs_under_xvfb_and_keys_record_and_screenshot() {
    let bunny = mesh("bunny.off");
    window_session(&["mesh".as_ref(), "view".as_ref(), bunny.as_os_str()]);
}
