//! Numeric edge cases end to end (issue 8): flat ground, a single spike, 10 km cliffs, void-only
//! rows, 2×2 and 3×3 grids each convert in every layout, verify, refine crack-free for random
//! cameras and render; the largest grid the index type allows, (2^31 + 1)², is checked through a
//! virtual record source (every layout's index arithmetic, crack-free refinement down to single
//! posts), since its file cannot exist; grids whose file could not be mapped, and grids larger than
//! the index type allows, are refused before anything is allocated. Inputs are ESRI ASCII grids
//! written here (small, exact, readable).

use crate::common;

use std::path::{Path, PathBuf};

use common::crack::{convert_all, crack_free_everywhere};
use glam::DVec3;
use relief::camera::Camera;
use relief::format::terrain::{Record, TerrainFile};
use relief::layout::hierarchy::{split_children, split_children_at, Grid, VertexKind, MAX_N};
use relief::layout::{AnyLayout, Layout, LayoutKind, LayoutVisitor};
use relief::preprocess::inspect::verify;
use relief::refine::check::{check_strip, MeshCheck};
use relief::refine::metric::Isotropic;
use relief::refine::{RecordSource, RefineOptions, Refiner, Strip, View};
use relief::render::render_still;
use relief::sys::progress::Progress;

/// Writes an ASCII grid of `rows` (north first); `None` is the nodata value −9999.
fn asc(dir: &Path, name: &str, rows: &[Vec<Option<f64>>], cellsize_m: f64) -> PathBuf {
    let path = dir.join(format!("{name}.asc"));
    let mut s = format!(
        "ncols {}\nnrows {}\nxllcorner 0\nyllcorner 0\ncellsize {cellsize_m}\nNODATA_value -9999\n",
        rows[0].len(),
        rows.len()
    );
    for row in rows {
        let line: Vec<String> = row.iter().map(|v| v.map_or("-9999".to_string(), |z| format!("{z}"))).collect();
        s.push_str(&line.join(" "));
        s.push('\n');
    }
    std::fs::write(&path, s).unwrap();
    path
}

fn grid(side: usize, f: impl Fn(usize, usize) -> Option<f64>) -> Vec<Vec<Option<f64>>> {
    (0..side).map(|r| (0..side).map(|c| f(r, c)).collect()).collect()
}

/// Converts in every layout, verifies each file, checks refinement over random cameras, renders
/// one view of the first layout (the terrain must cover at least 5% of it); returns the first
/// file.
fn end_to_end(dir: &Path, name: &str, input: &Path, min_mean_triangles: u64, look_z_m: f64) -> TerrainFile {
    let files = convert_all(input, dir, name);
    for f in &files {
        let report = verify(f, Progress::hidden()).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(report.ok, "{name}: {report:?}");
    }
    crack_free_everywhere(&files, 150, name.len() as u64 * 7919, min_mean_triangles);
    let h = files[0].header();
    assert!(h.z_min.is_finite() && h.z_max.is_finite(), "{name}: z range {} .. {}", h.z_min, h.z_max);
    // One view from the south and above, at the middle of the terrain at height `look_z_m` (near
    // enough that the fog, which grows with distance, leaves the ground visible).
    let [ex, ey] = h.extent_m();
    let size = ex.max(ey);
    let look = glam::DVec3::new(0.5 * ex, 0.5 * ey, look_z_m);
    let eye = look + glam::DVec3::new(0.0, -1.1 * ey, 0.8 * size);
    let camera = relief::camera::Camera::new(eye, look, glam::DVec3::Z, 60.0, 160, 100).unwrap();
    let gpu = common::gpu();
    let options = RefineOptions { tolerance_px: 1.0, ..RefineOptions::default() };
    let (image, still) = render_still(
        &gpu,
        std::sync::Arc::new(relief::format::terrain::TerrainFile::open(files[0].path()).unwrap()),
        &camera,
        &options,
        relief::render::StillOptions::default(),
        Progress::hidden(),
    )
    .unwrap_or_else(|e| panic!("{name}: {e}"));
    assert!(still.triangles >= 2, "{name}: {} triangles drawn", still.triangles);
    let sky = *image.get_pixel(80, 0);
    let ground = image.pixels().filter(|p| **p != sky).count();
    if std::env::var_os("EDGE_SAVE").is_some() {
        image.save(format!("/tmp/edge_{name}.png")).unwrap();
    }
    assert!(ground > 160 * 100 / 20, "{name}: only {ground} pixels differ from the sky");
    files.into_iter().next().unwrap()
}

#[test]
fn flat_spike_and_cliff_terrains_convert_refine_crack_free_and_render() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Flat: every nested error is 0, so a view needs only the two base triangles, never cracks.
    let flat = end_to_end(d, "flat", &asc(d, "flat", &grid(65, |_, _| Some(100.0)), 30.0), 1, 100.0);
    assert_eq!((flat.header().z_min, flat.header().z_max), (100.0, 100.0));
    // One 5 km spike on flat ground: its error propagates to every ancestor.
    let spike = end_to_end(
        d,
        "spike",
        &asc(d, "spike", &grid(65, |r, c| Some(if (r, c) == (32, 32) { 5000.0 } else { 0.0 })), 30.0),
        2,
        0.0,
    );
    assert_eq!(spike.header().z_max, 5000.0);
    // 10 km cliffs: a step across the middle and a pit.
    let cliff = end_to_end(
        d,
        "cliff",
        &asc(
            d,
            "cliff",
            &grid(65, |r, c| {
                Some(if c >= 32 {
                    10_000.0
                } else if r < 8 && c < 8 {
                    -10_000.0
                } else {
                    0.0
                })
            }),
            30.0,
        ),
        2,
        10_000.0,
    );
    assert_eq!((cliff.header().z_min, cliff.header().z_max), (-10_000.0, 10_000.0));
}

#[test]
fn void_only_rows_are_filled_and_an_all_void_grid_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // The first row and rows 10–19 void; a ramp elsewhere. Filled posts lie within the valid range.
    let rows = grid(65, |r, c| if r == 0 || (10..20).contains(&r) { None } else { Some((r + c) as f64) });
    let t = end_to_end(d, "voidrows", &asc(d, "voidrows", &rows, 10.0), 2, 64.0);
    assert!(t.header().z_min >= 1.0 && t.header().z_max <= 128.0, "{:?}", (t.header().z_min, t.header().z_max));
    // Nothing valid: one line naming the file, no output.
    let all_void = asc(d, "allvoid", &grid(9, |_, _| None), 10.0);
    let out = d.join("allvoid.relief");
    let o = common::relief().arg("convert").arg(&all_void).arg(&out).arg("--quiet").output().unwrap();
    let e = common::stderr_of(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(e.trim_end().lines().count() == 1 && e.contains("allvoid.asc") && e.contains("no valid sample"), "{e}");
    assert!(!out.exists());
}

#[test]
fn two_by_two_and_three_by_three_grids_work() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let two = end_to_end(
        d,
        "two",
        &asc(d, "two", &[vec![Some(0.0), Some(10.0)], vec![Some(5.0), Some(20.0)]], 100.0),
        1,
        10.0,
    );
    assert_eq!(two.grid().size(), 3, "2×2 posts are padded to the smallest grid, 3×3");
    let three =
        end_to_end(d, "three", &asc(d, "three", &grid(3, |r, c| Some((r * 3 + c) as f64 * 7.0)), 100.0), 1, 28.0);
    assert_eq!(three.grid().size(), 3);
}

#[test]
fn the_largest_grid_is_computed_without_overflow_and_a_larger_one_is_refused_at_once() {
    let g = Grid::new(MAX_N).unwrap();
    assert_eq!(g.size() as u64, (1u64 << MAX_N) + 1);
    assert_eq!(g.vertices(), ((1u64 << MAX_N) + 1).pow(2));
    assert_eq!(Grid::covering((1u64 << MAX_N) + 1, 1).map(|g| g.n()), Some(MAX_N));
    assert!(Grid::covering((1u64 << MAX_N) + 2, 1).is_none());
    assert!(Grid::new(MAX_N + 1).is_none());
    // A header that declares one post more than the largest grid: refused from the header
    // alone (the body is three numbers), one line, no output.
    let dir = tempfile::tempdir().unwrap();
    let huge = dir.path().join("huge.asc");
    std::fs::write(
        &huge,
        format!("ncols {}\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2 3\n", (1u64 << MAX_N) + 2),
    )
    .unwrap();
    let out = dir.path().join("huge.relief");
    let o = common::relief().arg("convert").arg(&huge).arg(&out).arg("--quiet").output().unwrap();
    let e = common::stderr_of(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(e.trim_end().lines().count() == 1 && e.contains("huge.asc"), "{e}");
    assert!(!out.exists());
    // Grids inside the index type whose file could not be mapped (more than 128 TiB: the terrain
    // file, 12 B a record, or the 12 B a post of conversion scratch), up to the largest, n = 31,
    // whose byte counts overflow u64: refused from the header, before any file is created.
    for (n, layout) in [(22, "hz"), (22, "row-major"), (30, "interleaved"), (MAX_N, "interleaved"), (MAX_N, "hz")] {
        let asc = dir.path().join(format!("wide{n}_{layout}.asc"));
        let side = (1u64 << n) + 1;
        std::fs::write(&asc, format!("ncols {side}\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2 3\n")).unwrap();
        let out = dir.path().join(format!("wide{n}_{layout}.relief"));
        let o =
            common::relief().arg("convert").arg(&asc).arg(&out).args(["--quiet", "--layout", layout]).output().unwrap();
        let e = common::stderr_of(&o);
        assert_eq!(o.status.code(), Some(1), "n = {n}: {e}");
        assert!(e.trim_end().lines().count() == 1, "n = {n}: {e}");
        assert!(
            e.contains(&format!("wide{n}_{layout}.asc: a {side}² grid needs"))
                && e.contains("128.00 TiB one process can map"),
            "{e}"
        );
        assert!(!out.exists());
    }
    let leftovers: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(leftovers.len(), 1 + 5, "only the inputs remain: {leftovers:?}");
}

/// A virtual terrain on the largest grid (2^31 + 1)²: flat ground whose records carry nested
/// errors and radii that depend only on the vertex's step, so nesting holds by construction:
/// error `0.05·h` (×1.5 for square centres, which are a half level coarser) and radius `c·h` with
/// `c = 4.6` for square centres and `3.2` for edge midpoints, where `h` is the step in posts at
/// 1 m spacing. A square centre's children are edge midpoints at the same step, `h` away
/// (4.6 ≥ 1 + 3.2); an edge midpoint's are square centres at `h/2`, `h/√2` away (3.2 ≥ 0.71 +
/// 2.3). The file such a grid needs (4.6·10^18 posts × 12 B) cannot exist, so this is how the
/// layouts and the refinement are checked at the index type's limit.
struct LargestGridRecords<L: Layout> {
    layout: L,
}

impl<L: Layout> LargestGridRecords<L> {
    fn at(&self, x: u32, y: u32) -> Record {
        let grid = self.layout.grid();
        let (scale, c) = match grid.kind(x, y) {
            VertexKind::Corner => return Record { z: 0.0, error: f32::INFINITY, radius: f32::INFINITY },
            VertexKind::SquareCentre { step } => (step as f64, (1.5, 4.6)),
            VertexKind::EdgeMidpoint { step } => (step as f64, (1.0, 3.2)),
        };
        Record { z: 0.0, error: (0.05 * c.0 * scale) as f32, radius: (c.1 * scale) as f32 }
    }
}

impl<L: Layout> RecordSource for LargestGridRecords<L> {
    fn record(&self, index: u64) -> Record {
        let (x, y) = self.layout.coords(index).unwrap_or_else(|| panic!("index {index} holds no vertex"));
        self.at(x, y)
    }
}

/// Every layout's index arithmetic at n = MAX_N: indices in range, distinct, and mapped back to
/// their posts; the layouts' child shortcuts equal the coordinate rule; refinement from eyes near
/// the far corner, the centre and the west edge gives the same strip in every layout, and that
/// strip is a crack-free mesh of exactly the active vertices, reaching level 1 (single posts).
#[test]
fn the_largest_grid_refines_crack_free_in_every_layout() {
    let grid = Grid::new(MAX_N).unwrap();
    let m = grid.max_coord();
    let layouts: Vec<AnyLayout> = LayoutKind::ALL
        .iter()
        .map(|&k| AnyLayout::new(k, grid, 0, relief::format::terrain::RECORD_BYTES).unwrap())
        .collect();
    let mut samples: Vec<(u32, u32)> = Vec::new();
    // The posts of the four 24 × 24 corner blocks, the centre's block and a block on each edge.
    let h = m / 2;
    for (x0, y0) in [(0, 0), (m - 23, 0), (0, m - 23), (m - 23, m - 23), (h - 12, h - 12), (h - 12, 0), (0, h - 12)] {
        for dy in 0..24 {
            for dx in 0..24 {
                samples.push((x0 + dx, y0 + dy));
            }
        }
    }
    let mut rng = common::crack::Rng(31);
    for _ in 0..20_000 {
        let (x, y) = ((rng.next() % (m as u64 + 1)) as u32, (rng.next() % (m as u64 + 1)) as u32);
        samples.push((x, y));
    }
    for layout in &layouts {
        let name = layout.kind().name();
        assert!(layout.records() >= grid.vertices(), "{name}: {} records", layout.records());
        let mut seen = std::collections::HashMap::new();
        for &(x, y) in &samples {
            let i = layout.index(x, y);
            assert!(i < layout.records(), "{name}: ({x}, {y}) → {i} ≥ {}", layout.records());
            assert_eq!(layout.coords(i), Some((x, y)), "{name}: index {i}");
            if let Some(other) = seen.insert(i, (x, y)) {
                assert_eq!(other, (x, y), "{name}: ({x}, {y}) and {other:?} share index {i}");
            }
        }
        assert_eq!(layout.coords(layout.records()), None, "{name}: one past the end");
        // Random descents from the root triangles to level 1: the layout's child computation (an
        // index shortcut in some layouts) gives the coordinate rule's posts and their indices.
        let (c, mids) = (grid.centre(), grid.edge_midpoints());
        for d in 0..2_000 {
            let (mut apex, mut split) = (layout.vertex(c.0, c.1), {
                let e = mids[d % 4];
                layout.vertex(e.0, e.1)
            });
            while grid.level(split.x, split.y) > 1 {
                let children = layout.split_children(apex, split);
                let want = split_children((apex.x, apex.y), (split.x, split.y)).map(|(x, y)| layout.vertex(x, y));
                assert_eq!(children, want, "{name}: children of {split:?} from {apex:?}");
                let level = grid.level(split.x, split.y);
                let at = split_children_at((apex.x, apex.y), (split.x, split.y), level);
                assert_eq!(at, want.map(|v| (v.x, v.y)), "{name}: children at level {level}");
                if apex.x != c.0 || apex.y != c.1 {
                    // Below the root triangles: the refinement's index shortcut.
                    let inner = layout.inner_child_indices(apex.index, split.index, at[0], at[1]);
                    assert_eq!(inner, want.map(|v| v.index), "{name}: inner children of {split:?} from {apex:?}");
                }
                if let (Some(first), true) = (layout.quadtree_children(split.index), level > 2) {
                    // The grandchildren on split's side lie in split's four quadtree children.
                    for child in children {
                        for g in layout.split_children(split, child) {
                            assert!((first..first + 4).contains(&g.index), "{name}: {g:?} not in {first}..+4");
                        }
                    }
                }
                (apex, split) = (split, children[(rng.next() % 2) as usize]);
            }
        }
    }

    let views = [
        (DVec3::new(m as f64 - 300.0, m as f64 - 200.0, 6.0), DVec3::new(m as f64 - 5000.0, m as f64 - 9000.0, 0.0)),
        (DVec3::new(h as f64 + 0.5, h as f64 - 100.0, 3.0), DVec3::new(h as f64 + 3000.0, h as f64 + 5000.0, 0.0)),
        (DVec3::new(30.0, h as f64 + 7.0, 4.0), DVec3::new(2000.0, h as f64 - 900.0, 0.0)),
    ];
    let mut refiner = Refiner::new(1).unwrap();
    for (k, (eye, look)) in views.into_iter().enumerate() {
        let camera = Camera::new(eye, look, DVec3::Z, 60.0, 640, 400).unwrap();
        for cull in [true, false] {
            let options = RefineOptions { tolerance_px: 1.0, cull, ..RefineOptions::default() };
            let view = View::new(&camera, &options, Isotropic, [1.0, 1.0], [m as f64, m as f64], [0.0, 0.0]);
            let mut first: Option<Strip> = None;
            for layout in &layouts {
                struct Go<'a> {
                    refiner: &'a mut Refiner,
                    view: &'a View<Isotropic>,
                    strip: &'a mut Strip,
                }
                impl LayoutVisitor for Go<'_> {
                    type Output = MeshCheck;
                    fn visit<L: Layout>(self, layout: &L) -> MeshCheck {
                        let records = LargestGridRecords { layout: layout.clone() };
                        self.refiner.refine(layout, &records, self.view, self.strip);
                        let grid = layout.grid();
                        check_strip(grid, self.strip, |x, y| {
                            self.view.is_active(x, y, grid.level(x, y), records.at(x, y))
                        })
                    }
                }
                let mut strip = Strip::new();
                let c = layout.visit(Go { refiner: &mut refiner, view: &view, strip: &mut strip });
                let name = layout.kind().name();
                assert!(c.crack_free && c.inactive_vertices == 0, "view {k} cull {cull} {name}: {c:?}");
                match &first {
                    None => {
                        let finest = strip.vertices.iter().map(|v| grid.level(v.x, v.y)).min().unwrap();
                        assert_eq!(finest, 1, "view {k}: the mesh reaches single posts near the eye");
                        assert!(c.triangles > 1_000, "view {k}: {} triangles", c.triangles);
                        first = Some(strip);
                    }
                    Some(s) => assert_eq!(s.vertices, strip.vertices, "view {k} cull {cull}: {name} differs"),
                }
            }
        }
    }
}

/// A conversion killed at any moment (SIGKILL: no clean-up runs) leaves the output path holding
/// either the old file or the new one, each whole (it verifies); never a mix or a half file.
#[test]
fn a_conversion_killed_at_any_moment_leaves_the_old_file_or_the_new_one() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("out.relief");
    // The old file: a small real DEM. The new one: a SYNTHETIC 1025² DEM (a conversion of a
    // few hundred ms here, so kills land in every phase).
    let o = common::relief()
        .arg("convert")
        .arg(common::dem("hugo_site_nodata.asc"))
        .arg(&out)
        .arg("--quiet")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", common::stderr_of(&o));
    let old = std::fs::read(&out).unwrap();
    let synth = d.join("synthetic_1025.tif");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_relief-synth"))
        .arg(&synth)
        .args(["--size", "1025", "--seed", "3"])
        .output()
        .unwrap();
    assert!(o.status.success());
    let new_path = d.join("new.relief");
    let o = common::relief().arg("convert").arg(&synth).arg(&new_path).arg("--quiet").output().unwrap();
    assert!(o.status.success(), "{}", common::stderr_of(&o));
    let new = std::fs::read(&new_path).unwrap();
    let t0 = std::time::Instant::now();
    let o = common::relief().arg("convert").arg(&synth).arg(d.join("timing.relief")).arg("--quiet").output().unwrap();
    assert!(o.status.success());
    let full_ms = t0.elapsed().as_millis() as u64;
    let (mut saw_old, mut saw_new) = (0, 0);
    // Spread 24 kills over the whole conversion (and a little past it). A loaded machine (CI runs
    // tests side by side on two cores) converts slower than the timing run, so while no kill has
    // landed after the rename yet, further rounds double the delay (up to 8 more rounds).
    let mut k = 0u64;
    while k < 24 || (saw_new == 0 && k < 32) {
        let delay_ms = if k < 24 { k * (full_ms + 50) / 23 } else { (full_ms + 50) << (k - 23) };
        let mut child = common::relief().arg("convert").arg(&synth).arg(&out).arg("--quiet").spawn().unwrap();
        std::thread::sleep(std::time::Duration::from_millis(delay_ms));
        let _ = child.kill();
        let _ = child.wait();
        let now = std::fs::read(&out).unwrap();
        if now == old {
            saw_old += 1;
        } else if now == new {
            saw_new += 1;
            // Put the old file back for the next round.
            std::fs::write(&out, &old).unwrap();
        } else {
            panic!("kill {k}: the output is neither the old file nor the new one ({} bytes)", now.len());
        }
        let t = TerrainFile::open(&out).unwrap();
        assert!(verify(&t, Progress::hidden()).unwrap().ok);
        k += 1;
    }
    assert!(saw_old > 0 && saw_new > 0, "kills landed before ({saw_old}) and after ({saw_new}) the rename");
}

/// A terrain file truncated by another process during a flight: the next read past its new end
/// faults (SIGBUS), and relief stops with one line naming the file and exit status 1 — no core
/// dump, no panic.
#[test]
fn a_terrain_truncated_during_a_flight_stops_with_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let terrain = d.join("zurich.relief");
    let o = common::relief()
        .arg("convert")
        .arg(common::dem("zurich_25m_i16.tif"))
        .arg(&terrain)
        .arg("--quiet")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", common::stderr_of(&o));
    let path = d.join("long.json");
    common::make_path("flyover", &terrain, 20000, &path);
    let mut child = common::relief()
        .arg("fly")
        .arg(&terrain)
        .arg("--path")
        .arg(&path)
        .args(["--width", "64", "--height", "40", "--quiet"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(2500));
    assert!(child.try_wait().unwrap().is_none(), "the flight ended before the truncation");
    std::fs::OpenOptions::new().write(true).open(&terrain).unwrap().set_len(4096).unwrap();
    let t0 = std::time::Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if t0.elapsed() > std::time::Duration::from_secs(60) {
            let _ = child.kill();
            panic!("the flight went on for 60 s over a truncated file");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    let mut e = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut e).unwrap();
    assert_eq!(status.code(), Some(1), "{status:?}: {e}");
    assert!(e.trim_end().lines().count() == 1 && e.contains("zurich.relief") && e.contains("SIGBUS"), "{e}");
    assert!(!e.contains("panicked"), "{e}");
}
