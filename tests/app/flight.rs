//! Flight paths on the real DEMs (../shared/data/dem): the fly-over stays above the terrain in a
//! straight line, the orbit circles the centre, paths survive a save/load round trip bit for bit,
//! bad files fail with one-line messages, and `relief path` works from the command line. Paths
//! about a mesh's bounding box (bunny.off): the orbit stays outside the box looking at its centre,
//! the fly-over crosses above it.

use crate::common;

use common::{dem, mesh, REAL_DEMS};
use std::path::{Path, PathBuf};
use std::process::Command;

use relief::camera::UpAxis;
use relief::flight::{flyover, flyover_box, orbit, orbit_box, FlightPath, FlyoverOptions, OrbitOptions, PathFrame};
use relief::format::terrain::TerrainFile;
use relief::layout::LayoutKind;
use relief::mesh::read_mesh;
use relief::preprocess::convert::{convert, ConvertOptions};
use relief::Error;

/// Converts a real DEM into a terrain file in `dir`.
fn terrain(name: &str, dir: &Path) -> PathBuf {
    let out = dir.join(format!("{name}.relief"));
    convert(&dem(name), &out, &ConvertOptions::new(LayoutKind::Interleaved)).unwrap_or_else(|e| panic!("{name}: {e}"));
    out
}

/// The valid window in world metres: `[x_lo, y_lo, x_hi, y_hi]` (first and last valid posts).
fn window_m(t: &TerrainFile) -> [f64; 4] {
    let h = t.header();
    let [x0, y0, x1, y1] = h.valid_window;
    let [sx, sy] = h.spacing_m;
    [x0 as f64 * sx, y0 as f64 * sy, (x1 - 1) as f64 * sx, (y1 - 1) as f64 * sy]
}

fn diagonal_m(t: &TerrainFile) -> f64 {
    let [a, b, c, d] = window_m(t);
    (c - a).hypot(d - b)
}

/// The highest of the four posts around world point (x, y): every triangulation of the cell lies
/// at or below it. Written here independently of the library's helper.
fn ground_m(t: &TerrainFile, x: f64, y: f64) -> f64 {
    let [sx, sy] = t.header().spacing_m;
    let last = t.grid().size() - 1;
    let (gx, gy) = (x / sx, y / sy);
    assert!(gx >= 0.0 && gy >= 0.0 && gx <= last as f64 && gy <= last as f64, "({x}, {y}) outside the grid");
    let xs = [gx.floor() as u32, (gx.ceil() as u32).min(last)];
    let ys = [gy.floor() as u32, (gy.ceil() as u32).min(last)];
    let mut m = f64::NEG_INFINITY;
    for &px in &xs {
        for &py in &ys {
            m = m.max(t.record_at(px, py).unwrap().z as f64);
        }
    }
    m
}

fn check_flyover(name: &str, t: &TerrainFile, path: &FlightPath, frames: usize, clearance_m: f64) {
    let h = t.header();
    let [x_lo, y_lo, x_hi, y_hi] = window_m(t);
    let diag = diagonal_m(t);
    assert_eq!(path.frames.len(), frames, "{name}");
    let eps = 1e-9 * diag;
    for (k, f) in path.frames.iter().enumerate() {
        let [x, y, z] = f.eye;
        assert!(
            x >= x_lo && x <= x_hi && y >= y_lo && y <= y_hi,
            "{name} frame {k}: eye {:?} outside the window",
            f.eye
        );
        let ground = ground_m(t, x, y);
        assert!(z >= ground + clearance_m / 2.0, "{name} frame {k}: eye z {z} vs ground {ground} + {clearance_m}/2");
        // Low altitude: never higher than the clearance above the highest terrain.
        assert!(z <= h.z_max + clearance_m + eps, "{name} frame {k}: eye z {z} above z_max {} + clearance", h.z_max);
        assert!(f.look[2] < z, "{name} frame {k}: look {:?} not below the horizon of eye {:?}", f.look, f.eye);
        assert!(f.look != f.eye);
    }
    if frames < 2 {
        return;
    }
    // A straight line, south-west to north-east, equal steps in x/y.
    let e = |k: usize| path.frames[k].eye;
    let step = [e(1)[0] - e(0)[0], e(1)[1] - e(0)[1]];
    assert!(step[0] > 0.0 && step[1] > 0.0, "{name}: step {step:?} not towards the north-east");
    for k in 1..frames {
        let d = [e(k)[0] - e(k - 1)[0], e(k)[1] - e(k - 1)[1]];
        assert!(
            (d[0] - step[0]).abs() <= eps && (d[1] - step[1]).abs() <= eps,
            "{name} frame {k}: step {d:?} vs {step:?}"
        );
        // The look point lies ahead along the flight direction.
        let f = &path.frames[k];
        let ahead = [f.look[0] - f.eye[0], f.look[1] - f.eye[1]];
        let along = ahead[0] * step[0] + ahead[1] * step[1];
        let across = ahead[0] * step[1] - ahead[1] * step[0];
        assert!(along > 0.0 && across.abs() <= 1e-9 * along, "{name} frame {k}: look {:?} not ahead", f.look);
    }
    // The path spans most of the diagonal (5% inset at both ends).
    let span = (e(frames - 1)[0] - e(0)[0]).hypot(e(frames - 1)[1] - e(0)[1]);
    assert!((span - 0.9 * diag).abs() <= 1e-6 * diag, "{name}: span {span} of diagonal {diag}");
}

#[test]
fn flyover_stays_above_every_real_dem_in_a_straight_line() {
    let dir = tempfile::tempdir().unwrap();
    for name in REAL_DEMS {
        let t = TerrainFile::open(&terrain(name, dir.path())).unwrap();
        let default_clearance_m = 0.02 * diagonal_m(&t);
        for frames in [1, 2, 7, 240] {
            let path = flyover(&t, &FlyoverOptions::new(frames)).unwrap();
            check_flyover(name, &t, &path, frames, default_clearance_m);
        }
        let clearance_m = 0.002 * diagonal_m(&t);
        let path = flyover(&t, &FlyoverOptions { frames: 500, clearance_m: Some(clearance_m) }).unwrap();
        check_flyover(name, &t, &path, 500, clearance_m);
        // The summary agrees: the least clearance is at least the requested one.
        let s = path.summary(&t).unwrap();
        assert_eq!(s.frames, 500);
        assert!(s.min_clearance_m.unwrap() >= clearance_m, "{name}: {s:?}");
        assert!(s.length_m >= 0.9 * diagonal_m(&t) * (1.0 - 1e-9), "{name}: {s:?}");
        // Every frame makes a camera.
        for k in [0, 250, 499] {
            path.camera(k, 60.0, 640, 480).unwrap();
        }
    }
}

#[test]
fn orbit_circles_the_centre_above_the_highest_terrain() {
    let dir = tempfile::tempdir().unwrap();
    for name in REAL_DEMS {
        let t = TerrainFile::open(&terrain(name, dir.path())).unwrap();
        let h = t.header();
        let [x_lo, y_lo, x_hi, y_hi] = window_m(&t);
        let centre = [(x_lo + x_hi) / 2.0, (y_lo + y_hi) / 2.0];
        let half_diag = diagonal_m(&t) / 2.0;
        let eps = 1e-9 * half_diag;
        for (frames, radius_m, altitude_m) in
            [(36, 0.6 * half_diag, h.z_max + 0.3 * half_diag), (1, 0.6 * half_diag, h.z_max + 0.3 * half_diag)]
        {
            let path = orbit(&t, &OrbitOptions::new(frames)).unwrap();
            assert_eq!(path.frames.len(), frames, "{name}");
            for (k, f) in path.frames.iter().enumerate() {
                let [x, y, z] = f.eye;
                let (dx, dy) = (x - centre[0], y - centre[1]);
                assert!((dx.hypot(dy) - radius_m).abs() <= eps, "{name} frame {k}: radius {}", dx.hypot(dy));
                assert_eq!(z, altitude_m, "{name} frame {k}");
                assert!(z > h.z_max, "{name} frame {k}");
                // Evenly spaced over one turn, counter-clockwise from due east.
                let angle = std::f64::consts::TAU * k as f64 / frames as f64;
                assert!((dx - radius_m * angle.cos()).abs() <= eps && (dy - radius_m * angle.sin()).abs() <= eps);
                assert!((f.look[0] - centre[0]).abs() <= eps && (f.look[1] - centre[1]).abs() <= eps, "{name}");
                assert!(f.look[2] >= h.z_min && f.look[2] <= h.z_max, "{name}: look {:?}", f.look);
                assert_eq!(f.look, path.frames[0].look);
            }
        }
        // Explicit radius and altitude.
        let path = orbit(&t, &OrbitOptions { frames: 5, radius_m: Some(half_diag), altitude_m: Some(h.z_max + 10.0) })
            .unwrap();
        for f in &path.frames {
            assert!(((f.eye[0] - centre[0]).hypot(f.eye[1] - centre[1]) - half_diag).abs() <= eps);
            assert_eq!(f.eye[2], h.z_max + 10.0);
        }
        // An altitude under the terrain is refused, not flown.
        let e =
            orbit(&t, &OrbitOptions { frames: 8, radius_m: Some(0.1 * half_diag), altitude_m: Some(h.z_min - 1.0) })
                .unwrap_err();
        assert!(e.to_string().contains("is not above the terrain"), "{name}: {e}");
    }
}

#[test]
fn generators_reject_bad_options() {
    let dir = tempfile::tempdir().unwrap();
    let t = TerrainFile::open(&terrain("hugo_site_nodata.asc", dir.path())).unwrap();
    let msg = |r: relief::Result<FlightPath>| match r {
        Err(e @ Error::OutOfRange { .. }) => e.to_string(),
        other => panic!("expected OutOfRange, got {other:?}"),
    };
    assert_eq!(msg(flyover(&t, &FlyoverOptions::new(0))), "frames must be between 1 and 1000000, got 0");
    assert_eq!(msg(orbit(&t, &OrbitOptions::new(0))), "frames must be between 1 and 1000000, got 0");
    assert_eq!(
        msg(flyover(&t, &FlyoverOptions { frames: 3, clearance_m: Some(0.0) })),
        "clearance must be a positive number of metres, got 0"
    );
    assert_eq!(
        msg(flyover(&t, &FlyoverOptions { frames: 3, clearance_m: Some(f64::NAN) })),
        "clearance must be a positive number of metres, got NaN"
    );
    assert_eq!(
        msg(orbit(&t, &OrbitOptions { frames: 3, radius_m: Some(-5.0), altitude_m: None })),
        "radius must be a positive number of metres, got -5"
    );
    assert_eq!(
        msg(orbit(&t, &OrbitOptions { frames: 3, radius_m: Some(f64::INFINITY), altitude_m: None })),
        "radius must be a positive number of metres, got inf"
    );
    assert_eq!(
        msg(orbit(&t, &OrbitOptions { frames: 3, radius_m: None, altitude_m: Some(f64::NAN) })),
        "altitude must be a finite number of metres, got NaN"
    );
}

#[test]
fn save_then_load_gives_identical_frames() {
    let dir = tempfile::tempdir().unwrap();
    let t = TerrainFile::open(&terrain("zurich_25m_i16.tif", dir.path())).unwrap();
    let mut paths = vec![flyover(&t, &FlyoverOptions::new(97)).unwrap(), orbit(&t, &OrbitOptions::new(13)).unwrap()];
    // Awkward numbers: shortest round-trip representations, extremes, subnormals, negative zero.
    paths.push(FlightPath {
        frames: vec![
            PathFrame { eye: [0.1 + 0.2, 1.0 / 3.0, -0.0], look: [f64::MAX, f64::MIN_POSITIVE, 5e-324] },
            PathFrame { eye: [-1e300, 123_456_789.123_456_79, 2.0f64.sqrt()], look: [1e-300, 0.0, -2.5] },
        ],
    });
    for (k, path) in paths.iter().enumerate() {
        let file = dir.path().join(format!("p{k}.json"));
        path.save(&file).unwrap();
        let back = FlightPath::load(&file).unwrap();
        assert_eq!(back.frames.len(), path.frames.len());
        for (a, b) in path.frames.iter().zip(&back.frames) {
            let bits = |f: &PathFrame| (f.eye.map(f64::to_bits), f.look.map(f64::to_bits));
            assert_eq!(bits(a), bits(b), "{a:?} vs {b:?}");
        }
        // One frame per line between the brackets.
        let text = std::fs::read_to_string(&file).unwrap();
        assert_eq!(text.lines().count(), path.frames.len() + 2, "{text}");
        // Saving again over the file replaces it.
        path.save(&file).unwrap();
        assert_eq!(std::fs::read_to_string(&file).unwrap(), text);
    }
}

#[test]
fn save_refuses_paths_it_could_not_load_and_leaves_the_old_file() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("p.json");
    let good = FlightPath { frames: vec![PathFrame { eye: [0.0, 0.0, 10.0], look: [1.0, 0.0, 9.0] }] };
    good.save(&file).unwrap();
    let before = std::fs::read(&file).unwrap();
    let nan = FlightPath { frames: vec![good.frames[0], PathFrame { eye: [f64::NAN, 0.0, 1.0], look: [0.0; 3] }] };
    let e = nan.save(&file).unwrap_err();
    assert_eq!(e.to_string(), format!("{}: frame 1: eye [NaN, 0.0, 1.0] has a non-finite coordinate", file.display()));
    let empty = FlightPath { frames: vec![] };
    assert_eq!(empty.save(&file).unwrap_err().to_string(), format!("{}: flight path has no frames", file.display()));
    assert_eq!(std::fs::read(&file).unwrap(), before);
    // A missing directory is an I/O error naming the file; nothing is left behind.
    let missing = dir.path().join("no/such/dir/p.json");
    assert!(matches!(good.save(&missing), Err(Error::Io { .. })));
    let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(names, vec![std::ffi::OsString::from("p.json")], "temporary files left: {names:?}");
}

#[test]
fn load_reports_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let load = |name: &str, text: Option<&str>| {
        let p = dir.path().join(name);
        if let Some(text) = text {
            std::fs::write(&p, text).unwrap();
        }
        let e = FlightPath::load(&p).unwrap_err();
        let msg = e.to_string();
        assert_eq!(msg.lines().count(), 1, "{msg}");
        // Every message names the file first.
        msg.strip_prefix(&format!("{}: ", p.display())).unwrap_or_else(|| panic!("{msg}")).to_string()
    };
    assert_eq!(load("missing.json", None), "No such file or directory (os error 2)");
    assert_eq!(load("text.json", Some("<html>\n")), "expected value at line 1 column 1");
    assert_eq!(load("truncated.json", Some("[{\"eye\":[1,2,3],\n")), "EOF while parsing an object at line 2 column 0");
    assert_eq!(
        load("object.json", Some("{\"eye\":[1,2,3]}")),
        "invalid type: map, expected a sequence at line 1 column 0"
    );
    assert_eq!(load("empty.json", Some("[]\n")), "flight path has no frames");
    assert_eq!(
        load("no_look.json", Some("[\n  {\"eye\":[1,2,3],\"look\":[4,5,6]},\n  {\"eye\":[1,2,3]}\n]\n")),
        "frame 1: missing field `look` at line 3 column 17"
    );
    assert_eq!(
        load(
            "huge.json",
            Some("[\n  {\"eye\":[1,2,3],\"look\":[4,5,6]},\n  {\"eye\":[1,2,1e999],\"look\":[4,5,6]}\n]\n")
        ),
        "frame 1: number out of range at line 3 column 19"
    );
    assert_eq!(
        load("same.json", Some("[{\"eye\":[1,2,3],\"look\":[1,2,3]}]")),
        "frame 0: look point equals the eye (1, 2, 3)"
    );
    assert_eq!(
        load("typo.json", Some("[{\"eye\":[1,2,3],\"lok\":[4,5,6]}]")),
        "frame 0: unknown field `lok`, expected `eye` or `look` at line 1 column 21"
    );
    assert_eq!(
        load("short.json", Some("[{\"eye\":[1,2],\"look\":[4,5,6]}]")),
        "frame 0: invalid length 2, expected an array of length 3 at line 1 column 13"
    );
    let binary = dir.path().join("binary.json");
    std::fs::write(&binary, b"[\xff\xfe]").unwrap();
    assert_eq!(
        FlightPath::load(&binary).unwrap_err().to_string(),
        format!("{}: not UTF-8 text: invalid utf-8 sequence of 1 bytes from index 1", binary.display())
    );
}

fn relief() -> Command {
    Command::new(env!("CARGO_BIN_EXE_relief"))
}

#[test]
fn cli_path_writes_files_that_load_and_fails_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let t = terrain("fuji_terrain_rgb.png", dir.path());
    let out = dir.path().join("fly.json");
    let o = relief().args(["path", "flyover"]).arg(&t).args(["--frames", "30", "--out"]).arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("30 frames") && stdout.contains("min clearance above terrain"), "{stdout}");
    assert_eq!(FlightPath::load(&out).unwrap().frames.len(), 30);

    let orbit_out = dir.path().join("orbit.json");
    let o = relief()
        .args(["path", "orbit"])
        .arg(&t)
        .args(["--frames", "12", "--radius", "100", "--json", "--out"])
        .arg(&orbit_out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(j["frames"], 12);
    assert!(j["length_m"].as_f64().unwrap() > 0.0);
    assert!(j["min_clearance_m"].as_f64().unwrap() > 0.0);
    assert_eq!(j["out"], orbit_out.display().to_string());
    assert_eq!(FlightPath::load(&orbit_out).unwrap().frames.len(), 12);

    // Failures: one line on stderr, non-zero exit, no output file.
    let zero = dir.path().join("zero.json");
    let o = relief().args(["path", "flyover"]).arg(&t).args(["--frames", "0", "--out"]).arg(&zero).output().unwrap();
    assert!(!o.status.success());
    assert_eq!(String::from_utf8_lossy(&o.stderr), "relief: frames must be between 1 and 1000000, got 0\n");
    assert!(o.stdout.is_empty());
    assert!(!zero.exists());
    let missing = dir.path().join("missing.relief");
    let o =
        relief().args(["path", "orbit"]).arg(&missing).args(["--frames", "3", "--out"]).arg(&zero).output().unwrap();
    assert!(!o.status.success());
    assert_eq!(
        String::from_utf8_lossy(&o.stderr),
        format!("relief: {}: No such file or directory (os error 2)\n", missing.display())
    );
    assert!(!zero.exists());
}

#[test]
fn mesh_box_orbit_stays_outside_looking_at_the_centre() {
    let bunny = read_mesh(&mesh("bunny.off")).unwrap();
    let b = bunny.bounds().unwrap();
    let centre = b.centre();
    for up in UpAxis::ALL {
        let path = orbit_box(&b, up, &OrbitOptions::new(90)).unwrap();
        assert_eq!(path.frames.len(), 90);
        let radius = 1.2 * b.diagonal();
        for (k, f) in path.frames.iter().enumerate() {
            let eye = f.eye_in_world();
            assert!(b.distance_to(eye) > 0.1 * b.diagonal(), "{up:?} frame {k}: eye {eye} near or in the box");
            assert_eq!(f.look_at_world(), centre, "{up:?} frame {k}");
            // On the circle about the up axis through the centre, at one height.
            let d = eye - centre;
            let u = up.vector();
            assert!(((d - u * d.dot(u)).length() - radius).abs() < 1e-9 * radius, "{up:?} frame {k}");
            assert!((d.dot(u) - 0.4 * b.diagonal()).abs() < 1e-12, "{up:?} frame {k}");
        }
        // Counter-clockwise seen from above: the second eye is a little towards e2.
        let (e1, e2, _) = up.frame();
        let (a, c) = (path.frames[0].eye_in_world() - centre, path.frames[1].eye_in_world() - centre);
        assert!(a.dot(e1) > 0.0 && c.dot(e2) > 0.0, "{up:?}");
    }
    let s = orbit_box(&b, UpAxis::Y, &OrbitOptions::new(10)).unwrap().summary_box(&b);
    assert!(s.min_clearance_m.unwrap() > 0.0);
    let e = orbit_box(&b, UpAxis::Y, &OrbitOptions { frames: 3, radius_m: Some(-1.0), altitude_m: None }).unwrap_err();
    assert!(e.to_string().contains("radius"), "{e}");
}

#[test]
fn mesh_box_flyover_crosses_above_the_box() {
    let b = read_mesh(&mesh("bunny.off")).unwrap().bounds().unwrap();
    let path = flyover_box(&b, UpAxis::Y, &FlyoverOptions::new(50)).unwrap();
    let top = b.max[1];
    let (first, last) = (path.frames[0].eye_in_world(), path.frames[49].eye_in_world());
    for f in &path.frames {
        assert!(f.eye[1] > top, "eye {:?} not above the box's top {top}", f.eye);
        assert!(f.look[1] < f.eye[1], "looks down");
        // Within the box's horizontal extent: it passes across it.
        for k in [0, 2] {
            assert!(f.eye[k] > b.min[k] && f.eye[k] < b.max[k], "{:?}", f.eye);
        }
    }
    // From near one horizontal corner to near the opposite one (z and x for y up).
    assert!(first.x < b.centre().x && first.z < b.centre().z && last.x > b.centre().x && last.z > b.centre().z);
    assert!(path.length_m() > 0.8 * (b.extent()[0].hypot(b.extent()[2])));
}

#[test]
fn cli_path_about_a_mesh_loads_back() {
    let dir = tempfile::tempdir().unwrap();
    let b = read_mesh(&mesh("bunny.off")).unwrap().bounds().unwrap();
    for kind in ["orbit", "flyover"] {
        let out = dir.path().join(format!("{kind}.json"));
        let o = relief()
            .args(["path", kind])
            .arg(mesh("bunny.off"))
            .args(["--frames", "12", "--json", "--out"])
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(j["up"], "y", "the bunny stands on y");
        assert!(j["min_clearance_m"].as_f64().unwrap() > 0.0, "{j}");
        let path = FlightPath::load(&out).unwrap();
        assert_eq!(path.frames.len(), 12);
        if kind == "orbit" {
            assert!(path
                .frames
                .iter()
                .all(|f| f.look_at_world() == b.centre() && b.distance_to(f.eye_in_world()) > 0.0));
        }
    }
    // --up chooses another axis; a terrain cannot take one but z.
    let out = dir.path().join("z.json");
    let o = relief()
        .args(["path", "orbit"])
        .arg(mesh("bunny.off"))
        .args(["--frames", "4", "--up", "z", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success());
    assert!(String::from_utf8_lossy(&o.stdout).contains("z up"));
    let f = FlightPath::load(&out).unwrap().frames[0];
    assert!((f.eye[2] - b.centre().z - 0.4 * b.diagonal()).abs() < 1e-9);
}
