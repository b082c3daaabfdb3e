//! Meta-node trees on the real meshes: a small-memory build against the unlimited one along a
//! path, the navigation's bookkeeping and foldovers on random views, the buffer pool under a tiny
//! K, and the `relief mesh build | fly` commands.

use crate::common;

use std::path::Path;

use glam::DVec3;
use relief::camera::{Camera, UpAxis};
use relief::flight::{orbit_box, OrbitOptions};
use relief::format::metanode::MetaNodeFile;
use relief::mesh::read_mesh;
use relief::metanode::blocking::{write_metanode_file, BlockingOptions, Forest};
use relief::metanode::build::{build_vdt_from_mesh, BuildOptions};
use relief::metanode::navigate::{MetaStore, NavOptions, Navigator, PagedStore, Prefetch};
use relief::metanode::{VdtFile, VdtMetric};
use relief::pager::Access;

/// Builds `mesh` with `memory_bytes` into `dir/name.vdt` and `dir/name.rmn`.
fn build(mesh: &Path, memory_bytes: u64, dir: &Path, name: &str, blocking: BlockingOptions) -> (u64, MetaNodeFile) {
    let m = read_mesh(mesh).unwrap();
    let vdt = dir.join(format!("{name}.vdt"));
    let report = build_vdt_from_mesh(m, &vdt, &BuildOptions::new(memory_bytes, VdtMetric::Length)).unwrap();
    let f = VdtFile::open(&vdt).unwrap();
    let forest = Forest {
        nodes: f.nodes(),
        triangles: f.triangles(),
        base_triangles: f.base_triangles().len(),
        leaves: f.leaves() as u32,
        metric: f.metric() as u32,
        bounds: f.bounds(),
    };
    let out = dir.join(format!("{name}.rmn"));
    write_metanode_file(&forest, blocking, &out).unwrap();
    (report.batches, MetaNodeFile::open(&out).unwrap())
}

fn orbit_cameras(f: &MetaNodeFile, frames: usize) -> Vec<Camera> {
    let b = f.header().bounds;
    let path = orbit_box(&b, UpAxis::Y, &OrbitOptions::new(frames)).unwrap();
    (0..frames).map(|k| path.camera_with_up(k, UpAxis::Y, 60.0, 1280, 720).unwrap()).collect()
}

/// Random views around and inside the bounding box.
fn random_cameras(f: &MetaNodeFile, n: usize, seed: u64) -> Vec<(Camera, f64)> {
    let b = f.header().bounds;
    let (c, d) = (b.centre(), b.diagonal());
    let mut s = seed;
    let mut rnd = move || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    (0..n)
        .map(|_| {
            let eye = c + DVec3::new(rnd(), rnd(), rnd()) * 2.0 * d;
            let look = c + DVec3::new(rnd(), rnd(), rnd()) * 0.5 * d;
            let tol = [0.5, 2.0, 8.0, 32.0][((rnd() + 0.5) * 3.99) as usize];
            (Camera::new(eye, look, DVec3::Y, 60.0, 640, 360).unwrap(), tol)
        })
        .filter(|(c, _)| c.eye_in_world.distance(c.look_at_world) > 1e-6)
        .collect()
}

#[test]
fn small_memory_build_matches_the_unlimited_build_along_a_path() {
    let dir = tempfile::tempdir().unwrap();
    let input = common::mesh("armadillo.off");
    let m = read_mesh(&input).unwrap();
    let mesh_bytes = m.positions.len() as u64 * 24 + m.triangles.len() as u64 * 12;
    let blocking = BlockingOptions::default();
    let (batches_small, small) = build(&input, mesh_bytes / 4, dir.path(), "small", blocking);
    let (batches_all, all) = build(&input, 1 << 32, dir.path(), "all", blocking);
    assert!(batches_small >= 3, "{batches_small} batches: the budget should force several");
    assert_eq!(batches_all, 1);
    let cameras = orbit_cameras(&all, 16);
    let mut a = Navigator::new(&small, PagedStore::new(&small), NavOptions::default()).unwrap();
    let mut b = Navigator::new(&all, PagedStore::new(&all), NavOptions::default()).unwrap();
    for (k, cam) in cameras.iter().enumerate() {
        for tol in [1.0, 4.0] {
            let (sa, sb) = (a.update(cam, tol).unwrap(), b.update(cam, tol).unwrap());
            let (ta, tb) = (sa.triangles as f64, sb.triangles as f64);
            assert!((ta - tb).abs() <= 0.02 * tb, "frame {k}, τ {tol}: {ta} vs {tb} triangles");
        }
    }
    // In fact the spanned sub-mesh build keeps the global order exactly, so the trees agree.
    let (va, vb) =
        (VdtFile::open(&dir.path().join("small.vdt")).unwrap(), VdtFile::open(&dir.path().join("all.vdt")).unwrap());
    assert_eq!(va.nodes(), vb.nodes());
    assert_eq!(va.triangles(), vb.triangles());
}

#[test]
fn random_navigation_on_a_real_mesh_keeps_its_books_without_foldovers() {
    let dir = tempfile::tempdir().unwrap();
    let (_, f) = build(&common::mesh("bunny.off"), 1 << 32, dir.path(), "bunny", BlockingOptions::default());
    let mut nav =
        Navigator::new(&f, PagedStore::new(&f), NavOptions { check_foldover: true, ..NavOptions::default() }).unwrap();
    let (mut splits, mut collapses) = (0, 0);
    for (k, (cam, tol)) in random_cameras(&f, 60, 5).iter().enumerate() {
        let s = nav.update(cam, *tol).unwrap();
        nav.check().unwrap_or_else(|e| panic!("view {k}: {e}"));
        splits += s.splits;
        collapses += s.collapses;
    }
    assert_eq!(nav.foldovers(), 0, "a split or collapse flipped a triangle");
    assert!(splits > 20_000 && collapses > 20_000, "{splits} splits, {collapses} collapses");
}

#[test]
fn a_tiny_buffer_pool_never_evicts_a_meta_node_in_use() {
    let dir = tempfile::tempdir().unwrap();
    // Small pages, so the tree has many meta-nodes and the pool churns.
    let blocking = BlockingOptions { levels_per_node: 4, page_bytes: 1024 };
    let (_, f) = build(&common::mesh("armadillo.off"), 1 << 32, dir.path(), "arma", blocking);
    // A pool of 1/16 of the meta-nodes: the far views release blocks, the near ones want them back.
    let holders = f.header().metanodes as usize / 16;
    assert!(holders > f.header().root_metanodes as usize + 8);
    // Every prefetch policy: they reference different blocks, the pool's rules are the same.
    for prefetch in [Prefetch::Paper, Prefetch::Parent, Prefetch::Frontier] {
        let bytes = (holders as u64 + 1) * f.header().holder_bytes;
        let pooled = relief::format::metanode::MetaNodeFile::open_with(f.path(), Access::Pool { bytes }).unwrap();
        let pool = pooled.pager().pool().unwrap();
        let mut nav =
            Navigator::new(&pooled, PagedStore::new(&pooled), NavOptions { check_foldover: true, prefetch }).unwrap();
        let (mut misses, mut adapts) = (0, 0);
        for (k, (cam, tol)) in random_cameras(&f, 200, 11).iter().enumerate() {
            let s = nav.update(cam, *tol).unwrap();
            misses += s.misses;
            adapts += s.splits + s.collapses;
            nav.check().unwrap_or_else(|e| panic!("{prefetch:?}, view {k}: {e}"));
            pool.check_invariants().unwrap_or_else(|e| panic!("{prefetch:?}, view {k}: {e}"));
            if k % 4 == 0 {
                pool.drain().unwrap();
            }
        }
        let stats = pool.stats();
        assert!(misses > 0 && adapts > 0, "{prefetch:?}: {misses} misses, {adapts} adapts");
        assert!(stats.evictions > 0 && stats.second_chance_hits > 0, "{prefetch:?}: {stats:?}");
        assert_eq!(nav.store().second_chance_hits(), stats.second_chance_hits);
        assert_eq!(nav.foldovers(), 0, "{prefetch:?}");
    }
}

/// `relief mesh build bunny.off OUT ARGS… --quiet`, which must succeed.
fn cli_build_bunny(out: &Path, args: &[&str]) -> std::process::Output {
    let o = common::relief()
        .args(["mesh", "build"])
        .arg(common::mesh("bunny.off"))
        .arg(out)
        .args(args)
        .arg("--quiet")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", common::stderr_of(&o));
    o
}

#[test]
fn mesh_build_and_fly_commands() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bunny.rmn");
    let o = cli_build_bunny(&out, &["--memory", "1/2", "--json"]);
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    for key in ["leaves", "nodes", "batches", "vdt_bytes", "build_ms", "peak_accounted_bytes", "memory_budget_bytes"] {
        assert!(r[key].is_number(), "{key} missing in {r}");
    }
    for key in ["metanodes", "mnt_bytes", "data_bytes", "holder_bytes", "build_ms"] {
        assert!(r["metanode"][key].is_number(), "metanode.{key} missing in {r}");
    }
    assert!(std::fs::read_dir(dir.path()).unwrap().count() == 1, "the intermediate forest is removed");
    let path = dir.path().join("orbit.json");
    common::make_path("orbit", &out, 6, &path);
    // The paper's two modes by name, and every access by --access.
    for flags in
        [["--mode", "ext"], ["--mode", "virt"], ["--access", "map"], ["--access", "read"], ["--access", "pool"]]
    {
        let o = common::relief()
            .args(["mesh", "fly"])
            .arg(&out)
            .args(flags)
            .args(["--memory", "1M", "--no-render", "--json", "--quiet", "--path"])
            .arg(&path)
            .output()
            .unwrap();
        assert!(o.status.success(), "{flags:?}: {}", common::stderr_of(&o));
        let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(r["frames"].as_array().unwrap().len(), 6);
        assert!(r["summary"]["miss_pct"].is_number(), "{flags:?}: summary.miss_pct missing");
        for key in ["frame_ms", "splits", "collapses", "triangles", "pages_read", "major_faults"] {
            assert!(r["summary"][key]["mean"].is_number(), "{flags:?}: summary.{key} missing");
        }
        for key in ["splits", "collapses", "triangles", "misses", "frame_ms", "pages_read", "update_ms"] {
            assert!(r["frames"][0][key].is_number(), "{flags:?}: frame key {key} missing");
        }
        let source = r["summary"]["source"].as_str().unwrap();
        assert!(source.starts_with("meta-node trees"), "{source}");
        assert_eq!(r["summary"]["changes"], "splits + collapses");
    }
    // Bad input: one line, exit 1.
    let bad = dir.path().join("bad.rmn");
    std::fs::write(&bad, b"not a meta-node file").unwrap();
    for (args, what) in [
        (vec!["mesh", "fly", bad.to_str().unwrap(), "--path", path.to_str().unwrap()], "magic"),
        (
            vec!["mesh", "fly", out.to_str().unwrap(), "--path", path.to_str().unwrap(), "--memory", "8K"],
            "place holders",
        ),
        (vec!["mesh", "build", "/nonexistent.off", out.to_str().unwrap(), "--memory", "1M"], "nonexistent"),
    ] {
        let o = common::relief().args(&args).output().unwrap();
        let err = common::stderr_of(&o);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.trim().lines().count() == 1 && err.contains(what), "{args:?}: {err}");
    }
}

/// `relief mesh fly` in a window under Xvfb (the buffer pool's I/O thread beside the event loop):
/// it opens, takes the shared keys (record, freeze, wireframe, screenshot) and closes on Escape.
#[test]
fn mesh_fly_window_runs_under_xvfb() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bunny.rmn");
    cli_build_bunny(&out, &["--memory", "64M"]);
    common::window_session(&["mesh".as_ref(), "fly".as_ref(), out.as_os_str(), "--memory".as_ref(), "2M".as_ref()]);
}

/// Issue 23, first frames: `relief mesh fly` converges the first view before frame 0 by default
/// (`summary.converge`: updates, ms, how it ended and what was left), so frame 0 of a flight along
/// an orbit has at least 95% of the triangles a still camera at that view reaches after many
/// frames (flown without converging, paced so the pool's I/O thread loads between frames): with
/// map and read access and a pool that holds the view's front. The default pool (a quarter of
/// the tree) does not hold it: converging stops short and says so.
#[test]
fn frame_0_of_a_flight_has_the_triangles_a_still_camera_reaches() {
    let dir = tempfile::tempdir().unwrap();
    let tree = dir.path().join("bunny.rmn");
    cli_build_bunny(&tree, &["--memory", "1/2"]);
    let orbit = dir.path().join("orbit.json");
    common::make_path("orbit", &tree, 6, &orbit);
    let cameras: Vec<serde_json::Value> = serde_json::from_slice(&std::fs::read(&orbit).unwrap()).unwrap();
    let still = dir.path().join("still.json");
    std::fs::write(&still, serde_json::to_vec(&vec![cameras[0].clone(); 40]).unwrap()).unwrap();
    let fly = |path: &Path, args: &[&str]| -> serde_json::Value {
        let o = common::relief()
            .args(["mesh", "fly"])
            .arg(&tree)
            .args(["--tolerance", "8", "--no-render", "--json", "--quiet", "--path"])
            .arg(path)
            .args(args)
            .output()
            .unwrap();
        assert!(o.status.success(), "{args:?}: {}", common::stderr_of(&o));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let triangles = |r: &serde_json::Value, k: usize| r["frames"][k]["triangles"].as_f64().unwrap();
    for access in
        [&["--mode", "virt"][..], &["--access", "read"], &["--mode", "ext", "--memory", "16M"], &["--mode", "ext"]]
    {
        let r = fly(&orbit, access);
        let c = &r["summary"]["converge"];
        let first = triangles(&r, 0);
        let updates = c["updates"].as_u64().unwrap_or_else(|| panic!("{access:?}: no convergence in {}", r["summary"]));
        assert!(updates >= 1 && c["ms"].as_f64().is_some_and(|ms| ms >= 0.0), "{access:?}: {c}");
        assert!(c["ms"].as_f64().unwrap() < 2500.0, "{access:?}: the default bound is 2 s: {c}");
        let end = c["end"].as_str().unwrap();
        let left = c["misses_left"].as_u64().unwrap() + c["changes_left"].as_u64().unwrap();
        if end == "complete" {
            assert_eq!(left, 0, "{access:?}: {c}");
        } else {
            assert!(left > 0, "{access:?}: stopped short ({end}) with nothing left: {c}");
        }
        let held = fly(&still, &[access, &["--no-converge", "--pace", "2"]].concat());
        assert!(held["summary"]["converge"].is_null());
        let reached = triangles(&held, 39);
        eprintln!(
            "{access:?}: frame 0 {first} triangles, converged {} ({end}, {updates} updates, {:.1} ms), still camera {} at frame 0 and {reached} at frame 39",
            c["triangles"], c["ms"].as_f64().unwrap(), triangles(&held, 0)
        );
        if access.len() == 2 && access[0] == "--mode" && access[1] == "ext" {
            // The default pool cannot hold this view's front: loads evict what the next update
            // needs, so where it settles (converged or after 40 frames) depends on the order the
            // I/O thread's loads land in, and only the report is asserted: it says it stopped
            // short and what was left.
            assert_ne!(end, "complete", "{c}");
            continue;
        }
        assert!(first >= 0.95 * reached, "{access:?}: frame 0 has {first} of {reached} triangles");
        // Every access that holds the front converges completely. (Without converging, an Ext
        // frame 0 is coarse or not as the I/O thread's start-up races the first update; with a
        // slow device it always is: tests/app/device.rs.)
        assert_eq!(end, "complete", "{access:?}: {c}");
    }
    // --no-converge and --converge exclude each other.
    let o = common::relief()
        .args(["mesh", "fly"])
        .arg(&tree)
        .args(["--no-render", "--no-converge", "--converge", "1", "--path"])
        .arg(&orbit)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", common::stderr_of(&o));
}
