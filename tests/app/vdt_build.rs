//! `relief mesh build` (`metanode::build`): the out-of-core VDT build on the real meshes in
//! ../shared/data/mesh.
//!
//! - Global shortest-first order: an independent replay of the file's collapses, in id order,
//!   over the whole input mesh. At each collapse, every current edge shorter than the collapsed
//!   one must fail the foldover test (in both directions). Lengths are recomputed here from the
//!   input's f64 positions with the same formula as the build, and ties are broken by (smaller
//!   id, larger id) as in the build, so the tolerance is 0: a violation is any edge with a
//!   smaller (length, id, id) that passes. The replay only re-tests an edge after a triangle at
//!   one of its ends changed (its test result depends on nothing else). A batched build (several
//!   memory loads) must also be byte-identical to the unlimited one.
//! - The forest is well formed (links, leaf counts, nested switch values and radii, every input
//!   triangle once, m(t) = the deepest pairwise lowest common ancestor of t's corners).
//! - Memory: the accounted peak stays within the budget, and the sampled peak of anonymous
//!   resident memory of the build phase within the budget plus [`RSS_OVERHEAD_BYTES`].
//! - Bad input gives one-line errors.
//!
//! The dragon (202k triangles) is in an ignored test (`cargo test --test app vdt_build -- --ignored`):
//! its builds take about a minute.

use std::collections::{BTreeSet, HashMap};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use relief::mesh::{read_mesh, Mesh};
use relief::metanode::build::{build_vdt_from_mesh, BuildOptions, BuildReport};
use relief::metanode::{VdtFile, VdtMetric, NONE};

/// What the sampled anonymous RSS of the build phase may exceed the budget by: the process's own
/// anonymous memory before the build (runtime, libraries, what the mesh reader's allocations
/// left in the allocator: about 1 MiB here), allocator slack and redb's bookkeeping outside its
/// page cache.
const RSS_OVERHEAD_BYTES: u64 = 2 << 20;

fn real_mesh(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/mesh").join(name)
}

fn scratch() -> tempfile::TempDir {
    tempfile::tempdir().expect("temporary directory")
}

/// A build kept for several tests.
struct Built {
    mesh: Mesh,
    path: PathBuf,
    report: BuildReport,
    _dir: tempfile::TempDir,
}

fn build_lib(name: &str, memory_bytes: u64, metric: VdtMetric) -> Built {
    let mesh = read_mesh(&real_mesh(name)).unwrap_or_else(|e| panic!("{e}"));
    let dir = scratch();
    let path = dir.path().join("out.vdt");
    let report = build_vdt_from_mesh(mesh.clone(), &path, &BuildOptions::new(memory_bytes, metric))
        .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("{name} {metric:?} {memory_bytes} B: {report:?}");
    Built { mesh, path, report, _dir: dir }
}

/// Through the binary, so the memory figures are those of a process doing nothing else.
fn build_cli(name: &str, memory: &str, metric: &str) -> Built {
    build_cli_with(name, memory, metric, &[])
}

/// [`build_cli`] with more arguments (`--batched`).
fn build_cli_with(name: &str, memory: &str, metric: &str, more: &[&str]) -> Built {
    let dir = scratch();
    let path = dir.path().join("out.vdt");
    // OUTPUT is the meta-node file; --vdt keeps the forest this test reads.
    let out = Command::new(env!("CARGO_BIN_EXE_relief"))
        .args(["mesh", "build"])
        .arg(real_mesh(name))
        .arg(dir.path().join("out.rmn"))
        .arg("--vdt")
        .arg(&path)
        .args(["--memory", memory, "--metric", metric, "--json"])
        .args(more)
        .output()
        .expect("run relief");
    assert!(out.status.success(), "relief mesh build failed: {}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON report");
    eprintln!("{name} {metric} --memory {memory}: {v}");
    let n = |k: &str| v[k].as_u64().unwrap_or_else(|| panic!("{k} in {v}"));
    let report = BuildReport {
        metric: if metric == "quadric" { VdtMetric::Quadric } else { VdtMetric::Length },
        leaves: n("leaves"),
        nodes: n("nodes"),
        roots: n("roots"),
        triangles: n("triangles"),
        base_triangles: n("base_triangles"),
        collapses: n("collapses"),
        rejections: n("rejections"),
        batches: n("batches"),
        sub_meshes: n("sub_meshes"),
        loads: n("loads"),
        vdt_bytes: n("vdt_bytes"),
        mesh_bytes: n("mesh_bytes"),
        ingest_ms: v["ingest_ms"].as_f64().unwrap_or(0.0),
        build_ms: v["build_ms"].as_f64().unwrap_or(0.0),
        memory_budget_bytes: n("memory_budget_bytes"),
        redb_cache_bytes: n("redb_cache_bytes"),
        peak_accounted_bytes: n("peak_accounted_bytes"),
        peak_rss_anon_bytes: n("peak_rss_anon_bytes"),
        rss_anon_baseline_bytes: n("rss_anon_baseline_bytes"),
    };
    let mesh = read_mesh(&real_mesh(name)).unwrap_or_else(|e| panic!("{e}"));
    Built { mesh, path, report, _dir: dir }
}

/// Armadillo, length metric: in 3 MiB (about 20 batches), through the binary, and unlimited.
fn armadillo_batched() -> &'static Built {
    static B: OnceLock<Built> = OnceLock::new();
    B.get_or_init(|| build_cli("armadillo.off", "3M", "length"))
}

fn armadillo_unlimited() -> &'static Built {
    static B: OnceLock<Built> = OnceLock::new();
    B.get_or_init(|| build_lib("armadillo.off", 1 << 30, VdtMetric::Length))
}

// ---------------------------------------------------------------------------------------------
// The independent replay.

fn length(a: [f64; 3], b: [f64; 3]) -> f64 {
    let (dx, dy, dz) = (a[0] - b[0], a[1] - b[1], a[2] - b[2]);
    ((dx * dx + dy * dy) + dz * dz).sqrt()
}

fn cross(u: [f64; 3], v: [f64; 3]) -> [f64; 3] {
    [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn normal(p: [[f64; 3]; 3]) -> [f64; 3] {
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    cross(sub(p[1], p[0]), sub(p[2], p[0]))
}

/// The current mesh while replaying collapses.
struct Replay {
    pos: HashMap<u32, [f64; 3]>,
    tris: Vec<[u32; 3]>,
    alive: Vec<bool>,
    incident: HashMap<u32, Vec<usize>>,
    /// Edges not known to fail the foldover test, by (length bits, smaller id, larger id).
    candidates: BTreeSet<(u64, u32, u32)>,
}

impl Replay {
    fn new(mesh: &Mesh) -> Self {
        let mut r = Replay {
            pos: mesh.positions.iter().enumerate().map(|(i, &p)| (i as u32, p)).collect(),
            tris: mesh.triangles.clone(),
            alive: vec![true; mesh.triangles.len()],
            incident: HashMap::new(),
            candidates: BTreeSet::new(),
        };
        for (t, tri) in mesh.triangles.iter().enumerate() {
            for &c in tri {
                r.incident.entry(c).or_default().push(t);
            }
        }
        let vs: Vec<u32> = r.incident.keys().copied().collect();
        for v in vs {
            r.add_edges_of(v);
        }
        r
    }

    fn neighbours(&self, v: u32) -> Vec<u32> {
        let mut n: Vec<u32> =
            self.incident.get(&v).into_iter().flatten().flat_map(|&t| self.tris[t]).filter(|&c| c != v).collect();
        n.sort_unstable();
        n.dedup();
        n
    }

    fn key(&self, a: u32, b: u32) -> (u64, u32, u32) {
        (length(self.pos[&a], self.pos[&b]).to_bits(), a.min(b), a.max(b))
    }

    fn add_edges_of(&mut self, v: u32) {
        for c in self.neighbours(v) {
            self.candidates.insert(self.key(v, c));
        }
    }

    /// Whether moving `v` onto `s` flips or degenerates no surviving triangle.
    fn passes(&self, s: u32, v: u32) -> bool {
        let target = self.pos[&s];
        self.incident[&v].iter().all(|&t| {
            let c = self.tris[t];
            if c.contains(&s) {
                return true;
            }
            let before = c.map(|x| self.pos[&x]);
            let after = c.map(|x| if x == v { target } else { self.pos[&x] });
            let (n0, n1) = (normal(before), normal(after));
            dot(n0, n1) > 0.0 && dot(n1, n1) > 1e-12 * dot(n0, n0)
        })
    }

    /// Candidates below `key` must fail both ways; those that do are known to fail until a
    /// triangle at one of their ends changes.
    fn check_below(&mut self, key: (u64, u32, u32), what: &str) {
        let below: Vec<_> = self.candidates.range(..key).copied().collect();
        for e in below {
            let (_, a, b) = e;
            assert!(
                !self.passes(a, b) && !self.passes(b, a),
                "{what}: edge ({a}, {b}) of length {} passes the foldover test and is shorter than the collapsed edge (length {})",
                f64::from_bits(e.0),
                f64::from_bits(key.0)
            );
            self.candidates.remove(&e);
        }
    }

    fn collapse(&mut self, p: u32, s: u32, v: u32) {
        let ring: Vec<u32> =
            self.neighbours(s).into_iter().chain(self.neighbours(v)).filter(|&c| c != s && c != v).collect();
        for x in [s, v] {
            for c in self.neighbours(x) {
                let k = self.key(x, c);
                self.candidates.remove(&k);
            }
        }
        let mut list = Vec::new();
        for x in [s, v] {
            for t in self.incident.remove(&x).unwrap_or_default() {
                if !self.alive[t] {
                    continue;
                }
                if self.tris[t].contains(&s) && self.tris[t].contains(&v) {
                    self.alive[t] = false;
                    for c in self.tris[t] {
                        if let Some(l) = self.incident.get_mut(&c) {
                            l.retain(|&u| u != t);
                        }
                    }
                } else {
                    for c in self.tris[t].iter_mut().filter(|c| **c == x) {
                        *c = p;
                    }
                    list.push(t);
                }
            }
        }
        list.sort_unstable();
        list.dedup();
        self.pos.insert(p, self.pos[&s]);
        self.pos.remove(&s);
        self.pos.remove(&v);
        self.incident.insert(p, list);
        self.add_edges_of(p);
        for c in ring {
            self.add_edges_of(c);
        }
    }
}

/// Replays the file's collapses over the input mesh (length metric), checking the order.
fn check_global_order(vdt: &VdtFile, mesh: &Mesh, what: &str) {
    assert_eq!(vdt.metric(), VdtMetric::Length);
    let mut r = Replay::new(mesh);
    let leaves = vdt.leaves() as u32;
    for (id, node) in vdt.nodes().iter().enumerate().skip(leaves as usize) {
        let [s, v] = node.children;
        assert!(r.neighbours(s).contains(&v), "{what}: node {id}: children {s}, {v} share no triangle");
        let key = r.key(s, v);
        r.check_below(key, &format!("{what}: node {id}"));
        assert!(r.passes(s, v), "{what}: node {id}: the collapse of {v} onto {s} folds over");
        if s > v {
            // The smaller id is tried as the survivor first.
            assert!(!r.passes(v, s), "{what}: node {id}: {v} onto {s} was chosen though {s} onto {v} passes");
        }
        r.candidates.remove(&key);
        r.collapse(id as u32, s, v);
    }
    // Nothing collapsible is left.
    r.check_below((u64::MAX, u32::MAX, u32::MAX), &format!("{what}: after the last collapse"));
}

// ---------------------------------------------------------------------------------------------
// Well-formedness.

fn lca(parent: &[u32], mut x: u32, mut y: u32) -> Option<u32> {
    while x != y {
        if x < y {
            x = parent[x as usize];
            if x == NONE {
                return None;
            }
        } else {
            y = parent[y as usize];
            if y == NONE {
                return None;
            }
        }
    }
    Some(x)
}

fn check_well_formed(vdt: &VdtFile, mesh: &Mesh, report: &BuildReport, what: &str) {
    let nodes = vdt.nodes();
    let n = mesh.positions.len();
    assert_eq!(vdt.leaves(), n as u64, "{what}");
    assert_eq!(nodes.len() as u64, report.nodes, "{what}");
    assert_eq!(vdt.triangles().len(), mesh.triangles.len(), "{what}");
    assert_eq!(vdt.base_triangles().len() as u64, report.base_triangles, "{what}");
    assert_eq!(vdt.roots().count() as u64, report.roots, "{what}");
    assert_eq!(vdt.bounds(), mesh.bounds().expect("bounds"), "{what}");
    let b = vdt.bounds();
    let diagonal = length(b.min, b.max);
    let parent: Vec<u32> = nodes.iter().map(|x| x.parent).collect();
    for (id, node) in nodes.iter().enumerate() {
        let id32 = id as u32;
        if node.parent != NONE {
            assert!(node.parent > id32, "{what}: node {id}: parent {}", node.parent);
            assert!(
                nodes[node.parent as usize].children.contains(&id32),
                "{what}: node {id} is not a child of its parent"
            );
        }
        if id < n {
            assert_eq!(node.position, mesh.positions[id].map(|c| c as f32), "{what}: leaf {id}");
            assert_eq!(
                (node.leaves, node.switch, node.radius, node.children),
                (1, 0.0, 0.0, [NONE, NONE]),
                "{what}: leaf {id}"
            );
            continue;
        }
        let [c0, c1] = node.children;
        assert!(c0 < id32 && c1 < id32, "{what}: node {id}: children {c0}, {c1}");
        let (a, b) = (&nodes[c0 as usize], &nodes[c1 as usize]);
        assert_eq!(a.parent, id32, "{what}: node {id}: child {c0}");
        assert_eq!(b.parent, id32, "{what}: node {id}: child {c1}");
        assert_eq!(node.leaves, a.leaves + b.leaves, "{what}: node {id}: leaves");
        assert_eq!(node.position, a.position, "{what}: node {id}: position is children[0]'s");
        assert!(node.switch >= a.switch && node.switch >= b.switch, "{what}: node {id}: switch not nested");
        assert!(node.switch > 0.0 || report.metric == VdtMetric::Quadric, "{what}: node {id}: zero switch");
    }
    // Every leaf lies within each ancestor's radius of the ancestor's position (f32 positions
    // as written; the build rounds radii up to f32).
    let p64 = |id: u32| nodes[id as usize].position.map(|c| c as f64);
    for leaf in 0..n as u32 {
        let mut a = parent[leaf as usize];
        while a != NONE {
            let d = length(p64(a), p64(leaf));
            assert!(
                d <= nodes[a as usize].radius as f64 + 1e-12 * diagonal,
                "{what}: leaf {leaf} is {d} from ancestor {a} (radius {})",
                nodes[a as usize].radius
            );
            a = parent[a as usize];
        }
    }
    // Every input triangle exactly once.
    let mut count: HashMap<[u32; 3], i64> = HashMap::new();
    for t in &mesh.triangles {
        *count.entry(*t).or_default() += 1;
    }
    for t in vdt.triangles() {
        *count.entry(t.corners).or_default() -= 1;
    }
    assert!(count.values().all(|&c| c == 0), "{what}: the triangle section is not the input's triangles, each once");
    // m(t): the deepest (smallest-id) pairwise lowest common ancestor.
    let m = |c: [u32; 3]| {
        [(c[0], c[1]), (c[1], c[2]), (c[0], c[2])].into_iter().filter_map(|(x, y)| lca(&parent, x, y)).min()
    };
    for id in n as u32..nodes.len() as u32 {
        for t in vdt.node_triangles(id) {
            assert_eq!(m(t.corners), Some(id), "{what}: triangle {:?} listed under node {id}", t.corners);
        }
    }
    for t in vdt.base_triangles() {
        assert_eq!(m(t.corners), None, "{what}: base triangle {:?} dies", t.corners);
    }
}

// ---------------------------------------------------------------------------------------------

#[test]
fn batched_build_is_the_unlimited_build_and_keeps_the_global_order() {
    let (small, full) = (armadillo_batched(), armadillo_unlimited());
    assert!(small.report.batches >= 3, "{:?}", small.report);
    assert_eq!(full.report.batches, 1, "{:?}", full.report);
    for (built, what) in [(full, "armadillo unlimited"), (small, "armadillo in 3 MiB")] {
        let vdt = VdtFile::open(&built.path).unwrap_or_else(|e| panic!("{e}"));
        check_global_order(&vdt, &built.mesh, what);
    }
    let (a, b) = (std::fs::read(&small.path).unwrap(), std::fs::read(&full.path).unwrap());
    assert!(a == b, "the batched and unlimited builds differ");
}

/// Issue 23: three budgets, three code paths, the same bytes. The whole mesh in memory (no
/// B-tree: one batch, no redb cache, the accounted peak the in-memory estimate), the B-tree path
/// in one batch (`--batched`), and an eighth of the mesh's size in many batches: the VDT forest
/// and the meta-node file are byte-identical.
#[test]
fn three_budgets_build_the_same_bytes_in_memory_batched_and_in_an_eighth() {
    let in_memory = build_cli("armadillo.off", "4G", "length");
    let one_batch = build_cli_with("armadillo.off", "4G", "length", &["--batched"]);
    let eighth = build_cli("armadillo.off", "1/8", "length");
    let r = &in_memory.report;
    assert!(r.batches == 1 && r.redb_cache_bytes == 0 && r.peak_accounted_bytes > 0, "{r:?}");
    assert!(r.peak_accounted_bytes < r.memory_budget_bytes, "{r:?}");
    let r = &one_batch.report;
    assert!(r.batches == 1 && r.redb_cache_bytes > 0, "{r:?}");
    let r = &eighth.report;
    assert!(r.batches >= 3 && r.peak_accounted_bytes <= r.memory_budget_bytes, "{r:?}");
    assert!(r.memory_budget_bytes <= in_memory.report.mesh_bytes / 8 + 1, "{r:?}");
    let bytes = |b: &Built, ext: &str| std::fs::read(b.path.with_extension(ext)).unwrap();
    for ext in ["vdt", "rmn"] {
        let a = bytes(&in_memory, ext);
        assert!(a.len() > 1000, "{ext}: {} bytes", a.len());
        assert!(a == bytes(&one_batch, ext), "{ext}: the in-memory and the one-batch B-tree builds differ");
        assert!(a == bytes(&eighth, ext), "{ext}: the in-memory build and the build in 1/8 differ");
    }
}

#[test]
fn forest_is_well_formed() {
    for (built, what) in [(armadillo_batched(), "armadillo in 3 MiB"), (armadillo_unlimited(), "armadillo unlimited")] {
        let vdt = VdtFile::open(&built.path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(vdt.header().file_bytes(), built.report.vdt_bytes);
        check_well_formed(&vdt, &built.mesh, &built.report, what);
    }
}

#[test]
fn quadric_metric_batched_equals_unlimited() {
    let full = build_lib("bunny.off", 1 << 30, VdtMetric::Quadric);
    let small = build_lib("bunny.off", 6 << 20, VdtMetric::Quadric);
    assert!(small.report.batches >= 3, "{:?}", small.report);
    assert!(std::fs::read(&small.path).unwrap() == std::fs::read(&full.path).unwrap(), "bunny quadric: builds differ");
    let vdt = VdtFile::open(&small.path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(vdt.metric(), VdtMetric::Quadric);
    check_well_formed(&vdt, &small.mesh, &small.report, "bunny quadric in 6 MiB");
}

#[test]
fn memory_stays_within_the_budget() {
    let r = &armadillo_batched().report;
    assert_eq!(r.memory_budget_bytes, 3 << 20);
    assert!(
        r.peak_accounted_bytes <= r.memory_budget_bytes,
        "accounted {} > budget {}",
        r.peak_accounted_bytes,
        r.memory_budget_bytes
    );
    assert!(r.redb_cache_bytes <= r.memory_budget_bytes / 8, "{r:?}");
    if r.peak_rss_anon_bytes > 0 {
        // The build phase's growth: what the process held before it (libraries' relocated data:
        // linking libgdal, with the `gdal` feature, put it over the budget) is not the build's.
        let grown = r.peak_rss_anon_bytes.saturating_sub(r.rss_anon_baseline_bytes);
        assert!(
            grown <= r.memory_budget_bytes + RSS_OVERHEAD_BYTES,
            "sampled peak anonymous RSS {} grew {grown} over the baseline {} > budget {} + {RSS_OVERHEAD_BYTES}",
            r.peak_rss_anon_bytes,
            r.rss_anon_baseline_bytes,
            r.memory_budget_bytes
        );
    }
}

#[test]
#[ignore = "about a minute: cargo test --test app vdt_build -- --ignored"]
fn dragon_in_an_eighth_of_its_size() {
    let full = build_lib("dragon_202k.ply.gz", 1 << 30, VdtMetric::Length);
    let small = build_cli("dragon_202k.ply.gz", "1/8", "length");
    assert!(small.report.batches >= 3);
    assert!(small.report.peak_accounted_bytes <= small.report.memory_budget_bytes);
    assert!(
        small.report.peak_rss_anon_bytes <= small.report.memory_budget_bytes + RSS_OVERHEAD_BYTES,
        "{:?}",
        small.report
    );
    assert!(std::fs::read(&small.path).unwrap() == std::fs::read(&full.path).unwrap(), "dragon: builds differ");
    let vdt = VdtFile::open(&small.path).unwrap_or_else(|e| panic!("{e}"));
    check_well_formed(&vdt, &small.mesh, &small.report, "dragon in 1/8");
    check_global_order(&vdt, &small.mesh, "dragon in 1/8");
}

// ---------------------------------------------------------------------------------------------
// Bad input.

fn relief(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_relief")).args(args).output().expect("run relief");
    (out.status.success(), String::from_utf8_lossy(&out.stderr).into_owned())
}

#[test]
fn missing_input_is_a_one_line_error() {
    let dir = scratch();
    let missing = dir.path().join("nope.off");
    let out = dir.path().join("out.vdt");
    let e =
        relief::metanode::build::build_vdt(&missing, &out, &BuildOptions::new(1 << 20, VdtMetric::Length)).unwrap_err();
    assert_eq!(e.to_string(), format!("{}: No such file or directory (os error 2)", missing.display()));
    let (ok, stderr) = relief(&["mesh", "build", missing.to_str().unwrap(), out.to_str().unwrap(), "--memory", "1M"]);
    assert!(!ok);
    assert_eq!(stderr, format!("relief: {}: No such file or directory (os error 2)\n", missing.display()));
    assert!(!out.exists());
}

#[test]
fn bad_memory_budgets_are_refused() {
    let dir = scratch();
    let out = dir.path().join("out.vdt");
    let input = real_mesh("armadillo.off");
    let (ok, stderr) = relief(&["mesh", "build", input.to_str().unwrap(), out.to_str().unwrap(), "--memory", "0"]);
    assert!(!ok);
    assert_eq!(stderr, "relief: --memory must be more than 0 bytes\n");
    let (ok, stderr) = relief(&["mesh", "build", input.to_str().unwrap(), out.to_str().unwrap(), "--memory", "lots"]);
    assert!(!ok);
    assert_eq!(stderr, "relief: --memory: expected bytes such as 4096, 64K or 1G, got 'lots'\n");
    let mesh = Mesh { positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], triangles: vec![[0, 1, 2]] };
    let e = build_vdt_from_mesh(mesh, &out, &BuildOptions::new(10_000, VdtMetric::Length)).unwrap_err();
    let msg = e.to_string();
    assert!(msg.starts_with("memory budget of 10000 bytes is too small: at least "), "{msg}");
    assert_eq!(msg.lines().count(), 1);
    assert!(!out.exists());
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "scratch files left behind");
}

/// A budget below the least a build needs (a small mesh's fraction) is raised to it with a
/// one-line warning, and the tree is the one a large budget builds.
#[test]
fn a_budget_below_the_least_is_raised_with_a_warning() {
    let dir = scratch();
    let input = real_mesh("bunny.off");
    let least = relief::metanode::build::least_budget_bytes();
    let build = |memory: &str, name: &str| {
        let out = dir.path().join(name);
        let o = Command::new(env!("CARGO_BIN_EXE_relief"))
            .args(["mesh", "build"])
            .arg(&input)
            .arg(&out)
            .args(["--memory", memory, "--quiet", "--json"])
            .output()
            .expect("run relief");
        assert!(o.status.success(), "--memory {memory}: {}", String::from_utf8_lossy(&o.stderr));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON report");
        (std::fs::read(&out).unwrap(), String::from_utf8_lossy(&o.stderr).into_owned(), v)
    };
    let (tiny, warning, report) = build("2K", "tiny.rmn");
    assert_eq!(
        warning,
        format!(
            "relief: warning: --memory 2K is 2048 bytes, below the least a build needs; building in {least} bytes (112.0 KiB)\n"
        )
    );
    assert_eq!(report["memory_budget_bytes"].as_u64(), Some(least), "{report}");
    let (large, quiet, _) = build("4G", "large.rmn");
    assert!(quiet.is_empty(), "{quiet}");
    assert!(tiny == large, "the raised build differs from the unlimited one");
}

#[test]
fn corrupt_vdt_files_are_one_line_errors() {
    let good = std::fs::read(&armadillo_unlimited().path).unwrap();
    let dir = scratch();
    let path = dir.path().join("bad.vdt");
    let open_err = |bytes: &[u8]| {
        std::fs::write(&path, bytes).unwrap();
        let e = VdtFile::open(&path).err().expect("an error");
        let msg = e.to_string();
        assert_eq!(msg.lines().count(), 1, "{msg}");
        msg
    };
    let p = path.display();
    let mut bad = good.clone();
    bad[1] = b'X';
    assert_eq!(open_err(&bad), format!("{p}: not a relief VDT file (bad magic)"));
    assert_eq!(open_err(b""), format!("{p}: not a relief VDT file (bad magic)"));
    assert_eq!(open_err(&good[..100]), format!("{p}: truncated VDT file: expected 256 bytes, found 100"));
    assert_eq!(
        open_err(&good[..good.len() - 5]),
        format!("{p}: truncated VDT file: expected {} bytes, found {}", good.len(), good.len() - 5)
    );
    let mut longer = good.clone();
    longer.extend_from_slice(&[0; 7]);
    assert_eq!(
        open_err(&longer),
        format!("{p}: VDT file has 7 bytes past its end (expected {} bytes, found {})", good.len(), good.len() + 7)
    );
    let mut bad = good.clone();
    bad[8] = 9;
    assert_eq!(open_err(&bad), format!("{p}: VDT file version 9 is not supported (this build reads version 2)"));
    let mut bad = good.clone();
    bad[30] ^= 1;
    assert!(open_err(&bad).starts_with(&format!("{p}: VDT file: header checksum mismatch (stored ")));
    // The first internal node's first child pointing at itself.
    let leaves = u64::from_le_bytes(good[16..24].try_into().unwrap()) as usize;
    let mut bad = good.clone();
    let at = 256 + leaves * 48 + 20;
    bad[at..at + 4].copy_from_slice(&(leaves as u32).to_le_bytes());
    let msg = open_err(&bad);
    // Named with the byte offset of the node's record (where `xxd -s` finds it).
    let node_at = 256 + leaves * 48;
    assert!(msg.starts_with(&format!("{p}: corrupt VDT file at byte {node_at}: node {leaves}: ")), "{msg}");
    let missing = dir.path().join("missing.vdt");
    assert_eq!(
        VdtFile::open(&missing).err().expect("an error").to_string(),
        format!("{}: No such file or directory (os error 2)", missing.display())
    );
}
