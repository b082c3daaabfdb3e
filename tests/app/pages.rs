//! The disk-page backend on real data: the bunny, the armadillo and the Zürich DEM exported as
//! triangles, written as page files in every layout. Every input triangle comes back from exactly
//! one page; the k-d tree with the per-page tests finds every page a view sees (against brute
//! force); the 2-factor and Hilbert layouts need fewer pages and shorter seeks than the input
//! order; and the `relief pages build | fly` commands, their JSON and their errors.

use crate::common;

use std::collections::HashSet;
use std::path::Path;

use glam::DVec3;
use relief::camera::{Camera, UpAxis};
use relief::diskpages::build::{build_page_file, PageBuildOptions};
use relief::diskpages::fetch::{FetchOptions, PageSource};
use relief::diskpages::kdtree::{box_in_frustum, query_frustum};
use relief::flight::frame::FrameSource;
use relief::flight::{flyover_box, FlyoverOptions};
use relief::format::pagefile::{PageFile, PageLayout};
use relief::format::terrain::TerrainFile;
use relief::layout::LayoutKind;
use relief::mesh::{read_mesh, terrain_mesh, Mesh};
use relief::preprocess::convert::{convert, ConvertOptions};

/// Every triangle as its three corners' f32 bits, in winding order.
type Corners = [[u32; 3]; 3];

fn input_triangles(mesh: &Mesh) -> Vec<Corners> {
    let mut t: Vec<Corners> =
        mesh.triangles.iter().map(|t| t.map(|i| mesh.positions[i as usize].map(|c| (c as f32).to_bits()))).collect();
    t.sort_unstable();
    t
}

/// Every page read back whole (pread) and decoded; asserts each page agrees with the map and its
/// directory box holds its vertices.
fn decoded_triangles(f: &PageFile) -> Vec<Corners> {
    let (mut out, mut all) = (Vec::new(), Vec::new());
    let read = PageFile::open_with(f.path(), relief::pager::Access::Read).unwrap();
    for p in 0..f.header().pages as u32 {
        let buf = read.page(p).unwrap();
        assert_eq!(&*buf, &*f.page(p).unwrap());
        let view = f.decode(p, &buf).unwrap();
        let e = &f.directory()[p as usize];
        for i in 0..view.vertices() {
            let q = view.position(i);
            assert!(
                (0..3).all(|k| e.box_min[k] <= q[k] && q[k] <= e.box_max[k]),
                "page {p} vertex {i} outside its box"
            );
        }
        out.clear();
        view.append_triangles(&mut out);
        assert_eq!(out.len(), 3 * f.counts()[p as usize].0 as usize);
        all.extend(out.chunks_exact(3).map(|c| [c[0], c[1], c[2]].map(|v| v.map(f32::to_bits))));
    }
    all.sort_unstable();
    all
}

fn zurich_terrain_mesh(dir: &Path) -> Mesh {
    let terrain = dir.join("zurich.relief");
    convert(&common::dem("zurich_25m_i16.tif"), &terrain, &ConvertOptions::new(LayoutKind::ALL[0])).unwrap();
    terrain_mesh(&TerrainFile::open(&terrain).unwrap(), 2).unwrap()
}

#[test]
fn every_triangle_of_the_real_meshes_comes_back_from_exactly_one_page() {
    let dir = tempfile::tempdir().unwrap();
    let meshes = [
        ("bunny", read_mesh(&common::mesh("bunny.off")).unwrap()),
        ("armadillo", read_mesh(&common::mesh("armadillo.off")).unwrap()),
        ("zurich", zurich_terrain_mesh(dir.path())),
    ];
    for (name, mesh) in &meshes {
        let want = input_triangles(mesh);
        assert!(want.len() > 50_000, "{name}: {} triangles", want.len());
        for layout in PageLayout::ALL {
            for page_bytes in [4096u32, 65536] {
                let out = dir.path().join(format!("{name}.{}.{page_bytes}.rpg", layout.name()));
                let r = build_page_file(mesh, &out, &PageBuildOptions::new(page_bytes, layout)).unwrap();
                let f = PageFile::open(&out).unwrap();
                let got = decoded_triangles(&f);
                // Multisets equal: none lost, none duplicated, corners and winding kept.
                assert!(got == want, "{name} {} {page_bytes}: pages do not decode back to the input", layout.name());
                assert_eq!(r.triangles, want.len() as u64);
                // The k-d tree names every page at least once.
                let named: HashSet<u32> = f.kd_refs().iter().copied().collect();
                assert_eq!(named.len() as u64, f.header().pages, "{name} {}", layout.name());
                assert!(
                    r.fill_mean > 0.8,
                    "{name} {} {page_bytes}: pages {:.0}% full",
                    layout.name(),
                    r.fill_mean * 100.0
                );
            }
        }
    }
}

/// Cameras around and inside the box, looking every way.
fn random_cameras(f: &PageFile, n: usize, seed: u64) -> Vec<Camera> {
    let b = f.header().bounds;
    let (lo, hi) = (DVec3::from(b.min), DVec3::from(b.max));
    let mut s = seed;
    let mut unit = move || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..n)
        .map(|_| {
            let pick = |u: f64, v: f64, w: f64| lo + (hi - lo) * DVec3::new(u, v, w);
            let eye = pick(unit() * 2.0 - 0.5, unit() * 2.0 - 0.5, unit() * 2.0 - 0.5);
            let look = pick(unit(), unit(), unit());
            let fov = 30.0 + 60.0 * unit();
            Camera::new(eye, look, DVec3::Y, fov, 640, 360).unwrap()
        })
        .collect()
}

#[test]
fn the_fetch_finds_every_page_a_view_sees() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = read_mesh(&common::mesh("bunny.off")).unwrap();
    for layout in PageLayout::ALL {
        let out = dir.path().join(format!("bunny.{}.rpg", layout.name()));
        build_page_file(&mesh, &out, &PageBuildOptions::new(4096, layout)).unwrap();
        let f = PageFile::open(&out).unwrap();
        // Every vertex of every page, to test pages against the exact frustum.
        let vertices: Vec<Vec<DVec3>> = (0..f.header().pages as u32)
            .map(|p| {
                let buf = f.page(p).unwrap();
                let v = f.decode(p, &buf).unwrap();
                (0..v.vertices()).map(|i| DVec3::from(v.position(i).map(f64::from))).collect()
            })
            .collect();
        let mut source = PageSource::new(
            PageFile::open(&out).unwrap(),
            FetchOptions { backface_cull: false, ..FetchOptions::default() },
        );
        let (mut candidates, mut stack) = (Vec::new(), Vec::new());
        let (mut seen_total, mut views_seeing) = (0usize, 0usize);
        for camera in random_cameras(&f, 300, 11 + layout as u64) {
            let eye = camera.eye_in_world;
            let planes = camera.frustum_normals();
            query_frustum(f.kd_nodes(), f.kd_refs(), eye, &planes, &mut candidates, &mut stack);
            // Brute force over the directory: the same box test on every page.
            let brute: Vec<u32> = (0..f.header().pages as u32)
                .filter(|&p| {
                    box_in_frustum(f.directory()[p as usize].box_min, f.directory()[p as usize].box_max, eye, &planes)
                })
                .collect();
            let got: Vec<u32> = candidates
                .iter()
                .copied()
                .filter(|&p| {
                    box_in_frustum(f.directory()[p as usize].box_min, f.directory()[p as usize].box_max, eye, &planes)
                })
                .collect();
            assert_eq!(got, brute, "{}: k-d query differs from brute force", layout.name());
            source.update(&camera, 1.0).unwrap();
            assert_eq!(source.pages(), &brute[..], "{}: fetched pages", layout.name());
            // Every page with a vertex inside the exact frustum is fetched.
            let fetched: HashSet<u32> = source.pages().iter().copied().collect();
            for (p, vs) in vertices.iter().enumerate() {
                if vs.iter().any(|&q| planes.iter().all(|n| n.dot(q - eye) > 0.0)) {
                    assert!(fetched.contains(&(p as u32)), "{}: page {p} is seen but not fetched", layout.name());
                    seen_total += 1;
                }
            }
            views_seeing += usize::from(!source.pages().is_empty());
            assert_eq!(
                source.triangles().len() as u64 / 3,
                source.pages().iter().map(|&p| f.counts()[p as usize].0 as u64).sum::<u64>()
            );
        }
        assert!(views_seeing > 100 && seen_total > 1000, "{}: {views_seeing} views see pages", layout.name());
    }
}

/// Pages and seek distance per frame of a low fly-over, per layout.
fn flyover_figures(file: &Path, frames: usize) -> (f64, f64, u64) {
    let f = PageFile::open(file).unwrap();
    let path = flyover_box(&f.header().bounds, UpAxis::Y, &FlyoverOptions::new(frames)).unwrap();
    let mut source = PageSource::new(f, FetchOptions::default());
    let (mut pages, mut seek, mut triangles) = (0u64, 0u64, 0u64);
    for frame in &path.frames {
        let camera = Camera::new(DVec3::from(frame.eye), DVec3::from(frame.look), DVec3::Y, 60.0, 640, 360).unwrap();
        let fetch = source.update(&camera, 1.0).unwrap();
        pages += fetch.pages_requested;
        seek += fetch.seek_pages;
        triangles += source.triangles().len() as u64 / 3;
    }
    (pages as f64 / frames as f64, seek as f64 / frames as f64, triangles)
}

#[test]
fn spatial_layouts_read_fewer_pages_and_seek_less_than_the_input_order() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = read_mesh(&common::mesh("armadillo.off")).unwrap();
    let mut figures = Vec::new();
    for layout in PageLayout::ALL {
        let out = dir.path().join(format!("armadillo.{}.rpg", layout.name()));
        build_page_file(&mesh, &out, &PageBuildOptions::new(4096, layout)).unwrap();
        figures.push((layout, flyover_figures(&out, 40)));
    }
    let raster = figures.iter().find(|f| f.0 == PageLayout::Raster).unwrap().1;
    for &(layout, (pages, seek, triangles)) in &figures {
        assert!(triangles > 0, "{}: nothing drawn", layout.name());
        if layout != PageLayout::Raster {
            assert!(pages < 0.8 * raster.0, "{}: {pages:.0} pages a frame, raster {:.0}", layout.name(), raster.0);
            assert!(seek < 0.8 * raster.1, "{}: seek {seek:.0} pages a frame, raster {:.0}", layout.name(), raster.1);
        }
    }
}

fn json_of(o: &std::process::Output) -> serde_json::Value {
    assert!(o.status.success(), "{}", common::stderr_of(o));
    serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&o.stdout)))
}

#[test]
fn pages_build_and_fly_commands() {
    let dir = tempfile::tempdir().unwrap();
    let d = |name: &str| dir.path().join(name);
    let bunny = common::mesh("bunny.off");
    let built = common::relief()
        .args(["pages", "build"])
        .arg(&bunny)
        .arg(d("bunny.rpg"))
        .args(["--layout", "hilbert", "--page-size", "8K", "--json", "--quiet"])
        .output()
        .unwrap();
    let r = json_of(&built);
    assert_eq!(r["page_bytes"], 8192);
    assert_eq!(r["triangles"], read_mesh(&bunny).unwrap().triangles.len() as u64);
    assert_eq!(r["pages"], PageFile::open(&d("bunny.rpg")).unwrap().header().pages);
    // A path about the page file's box, then a headless flight with the figures in JSON.
    common::make_path("flyover", &d("bunny.rpg"), 12, &d("p.json"));
    let flown = common::relief()
        .args(["pages", "fly"])
        .arg(d("bunny.rpg"))
        .arg("--path")
        .arg(d("p.json"))
        .args(["--width", "320", "--height", "200", "--json", "--quiet", "--frames-out"])
        .arg(d("frames"))
        .output()
        .unwrap();
    let v = json_of(&flown);
    let frames = v["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 12);
    for f in frames {
        for key in ["pages_requested", "bytes_read", "seek_pages", "update_ms", "read_ms", "triangles", "frame_ms"] {
            assert!(f[key].is_number(), "frame key {key}: {f}");
        }
        assert_eq!(f["bytes_read"].as_u64().unwrap(), 8192 * f["pages_requested"].as_u64().unwrap());
    }
    // Pages gained and lost: the working set's changes, frame to frame (the first frame gains its
    // whole set); nothing is split or collapsed.
    let n = |f: &serde_json::Value, key: &str| f[key].as_u64().unwrap_or_else(|| panic!("frame key {key}: {f}"));
    assert!(n(&frames[0], "pages_gained") > 0, "{}", frames[0]);
    assert_eq!(n(&frames[0], "pages_gained"), n(&frames[0], "pages_requested"));
    assert_eq!(n(&frames[0], "pages_lost"), 0);
    for w in frames.windows(2) {
        let set = n(&w[0], "pages_requested") + n(&w[1], "pages_gained") - n(&w[1], "pages_lost");
        assert_eq!(set, n(&w[1], "pages_requested"), "{} then {}", w[0], w[1]);
        assert!(n(&w[1], "pages_lost") <= n(&w[0], "pages_requested"));
    }
    assert!(frames.iter().all(|f| n(f, "splits") == 0 && n(f, "collapses") == 0));
    assert!(frames.iter().skip(1).any(|f| n(f, "pages_gained") + n(f, "pages_lost") > 0), "a flyover changes pages");
    let s = &v["summary"];
    for key in ["pages_gained", "pages_lost"] {
        assert!(s[key]["mean"].is_number() && s[key]["total"].is_number(), "summary key {key}: {s}");
    }
    assert!(s["pages_gained"]["total"].as_f64().unwrap() >= s["pages_lost"]["total"].as_f64().unwrap());
    for key in ["pages_requested", "seek_pages", "update_ms", "frame_ms", "triangles"] {
        assert!(s[key]["mean"].as_f64().is_some_and(|x| x > 0.0), "summary key {key}: {s}");
    }
    // The stats say what this backend's changes are.
    assert_eq!(s["changes"], "pages gained + lost");
    let text = common::relief()
        .args(["pages", "fly"])
        .arg(d("bunny.rpg"))
        .arg("--path")
        .arg(d("p.json"))
        .args(["--no-render", "--quiet"])
        .output()
        .unwrap();
    let line = String::from_utf8_lossy(&text.stdout);
    assert!(line.contains(" pages gained + lost per frame") && !line.contains("splits"), "{line}");
    assert!(line.contains(" gained, ") && line.contains(" lost, means)") && !line.contains("misses"), "{line}");
    assert_eq!(std::fs::read_dir(d("frames")).unwrap().count(), 12);
    // The first frame shows the bunny: not only sky.
    let first = image::open(d("frames").join("frame_00000.png")).unwrap().to_rgba8();
    let distinct: HashSet<[u8; 4]> = first.pixels().map(|p| p.0).collect();
    assert!(distinct.len() > 50, "{} colours in the first frame", distinct.len());
}

#[test]
fn pages_commands_refuse_bad_input_with_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = |name: &str| dir.path().join(name);
    let bunny = common::mesh("bunny.off");
    let fails = |args: &[&std::ffi::OsStr], needle: &str| {
        let o = common::relief().args(args).output().unwrap();
        let e = common::stderr_of(&o);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {e}");
        assert!(e.contains(needle) && e.trim_end().lines().count() == 1 && !e.contains("panicked"), "{args:?}: {e}");
    };
    let out = d("out.rpg");
    fails(
        &[
            "pages".as_ref(),
            "build".as_ref(),
            bunny.as_os_str(),
            out.as_os_str(),
            "--page-size".as_ref(),
            "3000".as_ref(),
        ],
        "power of two",
    );
    fails(&["pages".as_ref(), "build".as_ref(), d("missing.off").as_os_str(), out.as_os_str()], "missing.off");
    std::fs::write(d("junk.off"), "OFF\n3 1 0\n0 0 0\n1 0 0\n").unwrap();
    fails(&["pages".as_ref(), "build".as_ref(), d("junk.off").as_os_str(), out.as_os_str()], "junk.off");
    assert!(!out.exists(), "no output after a failed build");
    let p = d("p.json");
    std::fs::write(d("junk.rpg"), b"\x89RLFPGS\nnot really").unwrap();
    fails(
        &[
            "path".as_ref(),
            "orbit".as_ref(),
            d("junk.rpg").as_os_str(),
            "--frames".as_ref(),
            "3".as_ref(),
            "--out".as_ref(),
            p.as_os_str(),
        ],
        "junk.rpg",
    );
    assert!(!p.exists());
    // A good file with one flipped byte in a page: the flight stops naming the file and the page.
    let good = d("good.rpg");
    let o = common::relief()
        .args(["pages", "build"])
        .arg(&bunny)
        .arg(&good)
        .args(["--quiet", "--layout", "raster"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", common::stderr_of(&o));
    let f = PageFile::open(&good).unwrap();
    let first_page = f.header().data_offset as usize;
    drop(f);
    let mut bytes = std::fs::read(&good).unwrap();
    bytes[first_page + 4] = 7; // index bytes: neither 1 nor 2
    std::fs::write(d("bad-page.rpg"), &bytes).unwrap();
    let o =
        common::relief().args(["path", "orbit"]).arg(&good).args(["--frames", "4", "--out"]).arg(&p).output().unwrap();
    assert!(o.status.success(), "{}", common::stderr_of(&o));
    fails(&["pages".as_ref(), "fly".as_ref(), d("junk.rpg").as_os_str(), "--path".as_ref(), p.as_os_str()], "junk.rpg");
    fails(
        &[
            "pages".as_ref(),
            "fly".as_ref(),
            d("bad-page.rpg").as_os_str(),
            "--path".as_ref(),
            p.as_os_str(),
            "--quiet".as_ref(),
        ],
        &format!("corrupt page file at byte {first_page}: page 0"),
    );
}

#[test]
fn pages_fly_window_runs_under_xvfb() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bunny.rpg");
    build_page_file(
        &read_mesh(&common::mesh("bunny.off")).unwrap(),
        &out,
        &PageBuildOptions::new(4096, PageLayout::TwoFactor),
    )
    .unwrap();
    common::window_session(&["pages".as_ref(), "fly".as_ref(), out.as_os_str()]);
}
