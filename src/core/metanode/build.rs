//! Building the VDT file out of core: El-Sana & Chiang's *spanned sub-mesh simplification*
//! (Eurographics 2000, §3.1.2), with a redb B-tree of edges keyed by the collapse metric.
//!
//! 1. Ingest: every input vertex (state: position, quadric, switch, radius, leaves; and its
//!    triangle ids) and every triangle (current and input corners) go into dense record files
//!    ([`super::dense`]: ids are dense, so a record is one positioned read, no tree), and every
//!    edge (key: metric, then ids; see [`EdgeKey`]) into a scratch redb database beside the
//!    output. The leaves' node records go to a scratch node file. This step holds the whole input mesh (the mesh
//!    readers read whole files); the mesh is dropped before the budgeted build starts.
//! 2. A batch, in one write transaction ([`Region::run`]):
//!    - Spanning: take the smallest edges out of the B-tree as *spanning edges*, loading each
//!      unloaded end (its state, all its live triangles, the states of their other corners)
//!      into a [`Region`]; a union–find over loaded vertices joined by edges tracks the
//!      sub-meshes. Stop before the next load would pass [`BuildOptions::span_fraction`] of the
//!      budget; ℓ is the last spanning key, and every edge left in the B-tree is longer.
//!    - Collapsing, over all loaded sub-meshes at once, in global shortest-first order with one
//!      priority queue. The paper collapses each sub-mesh up to ℓ, which can break the order:
//!      a boundary edge whose loaded end moved may become shorter than ℓ while its other end is
//!      not loaded. Here the next edge is always the smallest pending edge overall (heap or
//!      B-tree); if an end of it is not loaded, that vertex is loaded on demand (the paper's
//!      "load the adjacent triangles" for the extreme case), and the batch ends only when such a
//!      load does not fit in the budget. So the collapses are exactly those of the one-pass
//!      in-memory algorithm, in the same order, whatever the budget: a batched build writes the
//!      same bytes as an unlimited one.
//!    - New node records and the triangles that die at each node are appended to scratch files
//!      in id order; the left-over edges (with their current keys), rejected edges and vertex
//!      and triangle states go back into redb and the record files.
//! 3. Repeat until the B-tree is empty. With a budget that holds the whole mesh, the first batch
//!    loads everything: the "unlimited" build is the same code with one batch.
//! 4. Assemble: the node file is mapped and the children's `parent` fields patched, then header,
//!    nodes, dying triangles (already grouped by m(t) in increasing id) and the triangles still
//!    alive (the base mesh, by triangle id) are written to a temporary file beside the output,
//!    which is renamed over it ([`crate::sys::atomic_file`]).
//!
//! Every batch makes progress: its first spanning edge is the globally smallest pending edge, so
//! it is the first the collapse phase examines (it collapses or is rejected), and loads within a
//! batch are finite (a loaded vertex stays loaded until it is collapsed). Rejected edges come
//! back only when a neighbour collapses, as in the in-memory algorithm, so the build terminates.
//! If the budget cannot hold even the first spanning edge's neighbourhood, the build fails with
//! [`Error::MemoryBudget`].
//!
//! # Memory
//! The budget covers: the redb page cache (an eighth of the budget, at least 32 KiB and at most
//! 256 MiB), the two scratch file buffers (16 KiB each), the union–find and the region
//! ([`Region::used_bytes`], with head-room for the collapse phase, [`Region::committed_bytes`]),
//! and one bit per node id marking the vertices that may have rejected edges in the store (when
//! those bits take at most an eighth of the region's share; else every lookup goes to redb).
//! `peak_accounted_bytes` is the sum of those at their peaks, the cache counted as what it could
//! hold (its size, or the database file's if that is smaller). The sampled peak of anonymous
//! resident memory of the build phase (after ingest) is reported beside it; it also holds what no
//! account sees: the allocator's slack, redb's own bookkeeping, the program itself.

use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

use redb::{Database, Durability, ReadableTable, Table, TableDefinition};
use serde::Serialize;

use super::dense::DenseRecords;
use super::simplify::{
    add_quadrics, collapse_options, cost, plane_quadric, EdgeKey, Quadric, Region, Store, VertexState,
};
use super::{VdtNode, NONE};
use crate::error::{Error, IoContext, Result};
use crate::format::vdt::{write_header, VdtHeader, VdtMetric, HEADER_BYTES, NODE_BYTES};
use crate::mesh::{read_mesh, Mesh};
use crate::sys::progress::Progress;
use crate::sys::scratch::ScratchMap;

/// Pending edges: the B-tree ordered by collapse key.
const EDGES: TableDefinition<u128, ()> = TableDefinition::new("edges");
/// Rejected edges, both orientations: `a << 32 | b`.
const REJECTED: TableDefinition<u64, ()> = TableDefinition::new("rejected");
/// Buffer of each scratch output file, bytes.
const WRITER_BYTES: usize = 16 << 10;
/// The smallest redb cache, bytes.
const MIN_CACHE_BYTES: u64 = 32 << 10;
/// The largest redb cache, bytes.
const MAX_CACHE_BYTES: u64 = 256 << 20;
/// Small fixed allocations besides the accounted structures (scratch vectors, one vertex record
/// read for the estimate), bytes.
const MISC_BYTES: u64 = 16 << 10;

/// [`BuildOptions::span_fraction`]'s default.
pub const DEFAULT_SPAN_FRACTION: f64 = 0.5;

/// Below this, no region can hold an edge's neighbourhood: refused before ingest, bytes.
const SMALLEST_REGION_BYTES: u64 = 32 << 10;

/// How to build.
#[derive(Clone, Debug)]
pub struct BuildOptions {
    /// Memory for the build phase, bytes (see the module docs for what it covers).
    pub memory_budget_bytes: u64,
    pub metric: VdtMetric,
    /// Where the scratch database and files go (default: the output's directory).
    pub scratch_dir: Option<PathBuf>,
    /// Each batch first grows sub-meshes from the shortest edges until this fraction of the
    /// budget is committed, then collapses, loading more as the order needs it (0 to 1).
    pub span_fraction: f64,
    /// Build through the scratch B-tree in batches even when the budget holds the whole mesh
    /// ([`super::collapse`]); the bytes are the same (for measurements and tests).
    pub always_batched: bool,
    pub progress: Progress,
}

impl BuildOptions {
    pub fn new(memory_budget_bytes: u64, metric: VdtMetric) -> Self {
        BuildOptions {
            memory_budget_bytes,
            metric,
            scratch_dir: None,
            span_fraction: DEFAULT_SPAN_FRACTION,
            always_batched: false,
            progress: Progress::hidden(),
        }
    }
}

/// What a build did (`relief mesh build --json`).
#[derive(Clone, Debug, Serialize)]
pub struct BuildReport {
    pub metric: VdtMetric,
    /// Input vertices.
    pub leaves: u64,
    /// Leaves plus collapses.
    pub nodes: u64,
    pub roots: u64,
    /// Input triangles (all in the triangle section).
    pub triangles: u64,
    /// Triangles that never die.
    pub base_triangles: u64,
    pub collapses: u64,
    /// Collapse attempts refused by the foldover test (both directions), counting repeats.
    pub rejections: u64,
    /// Load-and-collapse rounds (1: the whole mesh fitted).
    pub batches: u64,
    /// Connected components of loaded vertices after each batch's spanning phase, summed.
    pub sub_meshes: u64,
    /// Vertices loaded into memory, summed over the batches.
    pub loads: u64,
    pub vdt_bytes: u64,
    /// The input mesh in memory: 24 bytes a vertex, 12 a triangle.
    pub mesh_bytes: u64,
    /// Reading the mesh and filling the scratch database.
    pub ingest_ms: f64,
    /// The budgeted build: batches and assembly.
    pub build_ms: f64,
    pub memory_budget_bytes: u64,
    pub redb_cache_bytes: u64,
    /// Largest accounted memory of the build phase (see the module docs).
    pub peak_accounted_bytes: u64,
    /// Sampled peak anonymous resident memory of the build phase (whole process; 0 where
    /// /proc is unavailable).
    pub peak_rss_anon_bytes: u64,
    /// Anonymous resident memory when the build phase started (after ingest).
    pub rss_anon_baseline_bytes: u64,
}

/// Builds the VDT file `output` from the mesh file `input` (see the module docs). The output is
/// replaced atomically; scratch files are removed whatever happens.
pub fn build_vdt(input: &Path, output: &Path, options: &BuildOptions) -> Result<BuildReport> {
    let start = Instant::now();
    check_budget(options.memory_budget_bytes)?;
    let mesh = read_mesh(input)?;
    build_vdt_timed(mesh, output, options, start)
}

/// [`build_vdt`] from a mesh in memory; it is dropped once ingested, before the budgeted phase.
pub fn build_vdt_from_mesh(mesh: Mesh, output: &Path, options: &BuildOptions) -> Result<BuildReport> {
    build_vdt_timed(mesh, output, options, Instant::now())
}

/// The fixed part of the budget: redb's cache, the output buffers, small scratch.
fn fixed_bytes(budget: u64) -> (u64, u64) {
    let cache = (budget / 8).clamp(MIN_CACHE_BYTES, MAX_CACHE_BYTES);
    (cache, cache + 2 * WRITER_BYTES as u64 + MISC_BYTES)
}

/// The least memory budget a build accepts (see [`BuildOptions::new`]): redb's smallest cache,
/// the output buffers, small scratch and one small edge neighbourhood.
pub fn least_budget_bytes() -> u64 {
    fixed_bytes(0).1 + SMALLEST_REGION_BYTES
}

/// Refuses a budget below the fixed part plus the smallest region.
fn check_budget(budget: u64) -> Result<()> {
    let (cache_bytes, fixed) = fixed_bytes(budget);
    let smallest = fixed + SMALLEST_REGION_BYTES;
    if budget < smallest {
        return Err(Error::MemoryBudget {
            budget_bytes: budget,
            problem: format!(
                "at least {smallest} bytes are needed (redb cache {cache_bytes}, scratch buffers and one small edge neighbourhood)"
            ),
        });
    }
    Ok(())
}

fn build_vdt_timed(mesh: Mesh, output: &Path, options: &BuildOptions, start: Instant) -> Result<BuildReport> {
    let budget = options.memory_budget_bytes;
    check_budget(budget)?;
    let (cache_bytes, fixed) = fixed_bytes(budget);
    let n = mesh.positions.len();
    let t = mesh.triangles.len();
    // Node ids must stay below NONE: at most 2n − 1 nodes.
    if n == 0 || n as u64 > (NONE as u64) / 2 || t as u64 >= NONE as u64 {
        return Err(Error::InvalidArgument(format!(
            "a VDT needs 1 to 2^31 vertices and fewer than 2^32 − 1 triangles; this mesh has {n} and {t}"
        )));
    }
    let bounds = mesh.bounds().ok_or_else(|| Error::InvalidArgument("mesh without vertices".into()))?;
    if !options.always_batched && super::collapse::needed_bytes(n as u64, t as u64, options.metric) <= budget {
        return build_in_memory(mesh, output, options, start, bounds);
    }
    let out_dir = match output.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let scratch_parent = options.scratch_dir.clone().unwrap_or(out_dir);
    let scratch = tempfile::Builder::new().prefix(".relief-vdt-").tempdir_in(&scratch_parent).at(&scratch_parent)?;
    let db_path = scratch.path().join("build.redb");
    let db = Database::builder().set_cache_size(cache_bytes as usize).create(&db_path).db(&db_path)?;
    let mut out = Output::new(scratch.path())?;

    let mut records = DenseRecords::new(scratch.path(), n as u32, t as u32)?;
    let edges = ingest(&mesh, &db, &db_path, &mut records, &mut out, options.metric)?;
    let mesh_bytes = n as u64 * 24 + t as u64 * 12;
    drop(mesh);
    release_freed_memory();
    let ingest_ms = start.elapsed().as_secs_f64() * 1e3;

    let baseline = crate::sys::mem::rss_anon_bytes().unwrap_or(0);
    let sampler = crate::sys::mem::AnonSampler::start();
    let build_start = Instant::now();
    // The rejected-id bits, if they take at most an eighth of the region's share.
    let bits_bytes = (2 * n as u64).div_ceil(64) * 8;
    let bits_fit = bits_bytes <= (budget - fixed) / 8;
    let region_budget = budget - fixed - if bits_fit { bits_bytes } else { 0 };
    let max_heap = (2 * edges + 256).min((region_budget / cost::HEAP_ENTRY) as usize);
    let mut builder = Builder {
        db: &db,
        db_path: &db_path,
        out: &mut out,
        records: &mut records,
        region: Region::new(
            options.metric,
            region_budget,
            n as u32,
            n.min((region_budget / cost::VERTEX_SLOT) as usize),
            t.min((region_budget / cost::TRIANGLE_SLOT) as usize),
            max_heap,
        ),
        span_fraction: options.span_fraction,
        batches: 0,
        max_db_bytes: std::fs::metadata(&db_path).map_or(0, |m| m.len()),
        min_pending: None,
        may_have_rejected: bits_fit.then(|| vec![0; bits_bytes as usize / 8]),
    };
    let bar = options.progress.bar("vdt build", n.saturating_sub(1) as u64, "collapses");
    while builder.batch()? {
        bar.set_position(builder.region.stats().collapses);
        bar.set_message(format!("batch {}", builder.batches));
    }
    bar.finish_and_clear();
    let stats = builder.region.stats();
    // The cache cannot hold more than the database's pages: count what it could hold.
    let db_bytes = builder.max_db_bytes.max(std::fs::metadata(&db_path).map_or(0, |m| m.len()));
    let peak_accounted = fixed - cache_bytes
        + cache_bytes.min(db_bytes)
        + if bits_fit { bits_bytes } else { 0 }
        + builder.region.peak_bytes();
    let batches = builder.batches;
    let nodes = builder.region.next_id() as u64;
    drop(builder);

    let (dying, base, vdt_bytes) = assemble(output, &records, out, n as u64, nodes, t as u64, options.metric, bounds)?;
    let peak_rss = sampler.finish();
    Ok(BuildReport {
        metric: options.metric,
        leaves: n as u64,
        nodes,
        roots: n as u64 - stats.collapses,
        triangles: dying + base,
        base_triangles: base,
        collapses: stats.collapses,
        rejections: stats.rejections,
        batches,
        sub_meshes: stats.sub_meshes,
        loads: stats.loads,
        vdt_bytes,
        mesh_bytes,
        ingest_ms,
        build_ms: build_start.elapsed().as_secs_f64() * 1e3,
        memory_budget_bytes: budget,
        redb_cache_bytes: cache_bytes,
        peak_accounted_bytes: peak_accounted,
        peak_rss_anon_bytes: peak_rss,
        rss_anon_baseline_bytes: baseline,
    })
}

/// The whole mesh in memory ([`super::collapse`]): no scratch database, one batch, the same
/// bytes as a batched build.
fn build_in_memory(
    mesh: Mesh,
    output: &Path,
    options: &BuildOptions,
    start: Instant,
    bounds: crate::mesh::Bounds,
) -> Result<BuildReport> {
    let (n, t) = (mesh.positions.len() as u64, mesh.triangles.len() as u64);
    let baseline = crate::sys::mem::rss_anon_bytes().unwrap_or(0);
    let sampler = crate::sys::mem::AnonSampler::start();
    let ingest_ms = start.elapsed().as_secs_f64() * 1e3;
    let build_start = Instant::now();
    let forest = super::collapse::collapse(&mesh, options.metric, &options.progress)?;
    drop(mesh);
    let header = VdtHeader {
        metric: options.metric,
        leaves: n,
        nodes: forest.nodes.len() as u64,
        triangles: t,
        base_triangles: forest.base.len() as u64,
        bounds,
    };
    if forest.dying.len() as u64 + header.base_triangles != t {
        return Err(Error::Internal {
            stage: "the VDT build",
            problem: format!(
                "{} dying and {} base triangles for {t} input triangles",
                forest.dying.len(),
                header.base_triangles
            ),
        });
    }
    crate::sys::atomic_file::write(output, |w| {
        write_header(w, &header)?;
        w.write_all(bytemuck::cast_slice(&forest.nodes))?;
        w.write_all(bytemuck::cast_slice(&forest.dying))?;
        w.write_all(bytemuck::cast_slice(&forest.base))
    })?;
    let stats = forest.stats;
    let peak_rss = sampler.finish();
    Ok(BuildReport {
        metric: options.metric,
        leaves: n,
        nodes: header.nodes,
        roots: n - stats.collapses,
        triangles: t,
        base_triangles: header.base_triangles,
        collapses: stats.collapses,
        rejections: stats.rejections,
        batches: 1,
        sub_meshes: stats.sub_meshes,
        loads: stats.loads,
        vdt_bytes: header.file_bytes(),
        mesh_bytes: n * 24 + t * 12,
        ingest_ms,
        build_ms: build_start.elapsed().as_secs_f64() * 1e3,
        memory_budget_bytes: options.memory_budget_bytes,
        redb_cache_bytes: 0,
        peak_accounted_bytes: super::collapse::needed_bytes(n, t, options.metric),
        peak_rss_anon_bytes: peak_rss,
        rss_anon_baseline_bytes: baseline,
    })
}

/// Hands memory freed by ingest back to the kernel, so the build phase's resident figure starts
/// from what it holds, not from the allocator's free lists.
fn release_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free heap pages to the kernel; it touches no live
    // allocation and is safe to call at any time.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// redb errors carry no path: name the scratch database.
trait ScratchContext<T> {
    fn db(self, path: &Path) -> Result<T>;
}

impl<T, E: std::fmt::Display> ScratchContext<T> for std::result::Result<T, E> {
    fn db(self, path: &Path) -> Result<T> {
        self.map_err(|e| Error::Scratch { path: path.to_path_buf(), problem: e.to_string() })
    }
}

/// The scratch output: node records and dying triangles, appended in id order.
struct Output {
    nodes: BufWriter<File>,
    triangles: BufWriter<File>,
    dir: PathBuf,
    nodes_written: u64,
    triangles_written: u64,
}

impl Output {
    fn new(dir: &Path) -> Result<Output> {
        let file = || tempfile::tempfile_in(dir).at(dir);
        Ok(Output {
            nodes: BufWriter::with_capacity(WRITER_BYTES, file()?),
            triangles: BufWriter::with_capacity(WRITER_BYTES, file()?),
            dir: dir.to_path_buf(),
            nodes_written: 0,
            triangles_written: 0,
        })
    }

    fn node(&mut self, node: &VdtNode) -> Result<()> {
        self.nodes.write_all(bytemuck::bytes_of(node)).at(&self.dir)?;
        self.nodes_written += 1;
        Ok(())
    }
}

/// Step 1: the scratch database and the leaves' node records. Returns the number of edges.
fn ingest(
    mesh: &Mesh,
    db: &Database,
    db_path: &Path,
    records: &mut DenseRecords,
    out: &mut Output,
    metric: VdtMetric,
) -> Result<usize> {
    let n = mesh.positions.len();
    // Vertex → triangle adjacency (CSR).
    let mut first = vec![0u32; n + 1];
    for tri in &mesh.triangles {
        for &c in tri {
            first[c as usize + 1] += 1;
        }
    }
    for v in 0..n {
        first[v + 1] += first[v];
    }
    let mut fill = first.clone();
    let mut incident = vec![0u32; 3 * mesh.triangles.len()];
    for (t, tri) in mesh.triangles.iter().enumerate() {
        for &c in tri {
            incident[fill[c as usize] as usize] = t as u32;
            fill[c as usize] += 1;
        }
    }
    drop(fill);
    let tris_of = |v: usize| &incident[first[v] as usize..first[v + 1] as usize];
    let quadrics: Vec<Quadric> = match metric {
        VdtMetric::Length => Vec::new(),
        VdtMetric::Quadric => (0..n)
            .map(|v| {
                tris_of(v).iter().fold([0.0; 10], |q, &t| {
                    let [a, b, c] = mesh.triangles[t as usize].map(|i| mesh.positions[i as usize]);
                    plane_quadric(a, b, c).map_or(q, |p| add_quadrics(&q, &p))
                })
            })
            .collect(),
    };
    let state = |v: usize| VertexState::leaf(mesh.positions[v], quadrics.get(v).copied().unwrap_or([0.0; 10]));

    records.ingest((0..n).map(|v| (state(v), tris_of(v))), mesh.triangles.iter().copied())?;
    let mut txn = db.begin_write().db(db_path)?;
    txn.set_durability(Durability::None).db(db_path)?;
    let mut edges = 0;
    {
        let mut table = txn.open_table(EDGES).db(db_path)?;
        let mut nbrs = Vec::new();
        for v in 0..n {
            nbrs.clear();
            for &t in tris_of(v) {
                nbrs.extend(mesh.triangles[t as usize].iter().copied().filter(|&c| c as usize > v));
            }
            nbrs.sort_unstable();
            nbrs.dedup();
            let sv = state(v);
            for &c in &nbrs {
                let value = collapse_options(metric, v as u32, &sv, c, &state(c as usize)).0;
                table.insert(super::simplify::edge_key(value, v as u32, c), ()).db(db_path)?;
            }
            edges += nbrs.len();
        }
        txn.open_table(REJECTED).db(db_path)?;
    }
    txn.commit().db(db_path)?;
    for p in &mesh.positions {
        out.node(&VdtNode {
            position: p.map(|c| c as f32),
            children: [NONE, NONE],
            parent: NONE,
            leaves: 1,
            ..VdtNode::default()
        })?;
    }
    Ok(edges)
}

/// The batch loop's state.
struct Builder<'a> {
    db: &'a Database,
    db_path: &'a Path,
    out: &'a mut Output,
    records: &'a mut DenseRecords,
    region: Region,
    /// [`Region::run`]'s spanning phase stops at this fraction of the region's budget.
    span_fraction: f64,
    batches: u64,
    /// The scratch database's largest size after a batch, bytes.
    max_db_bytes: u64,
    /// The store's smallest pending edge, when known ([`Disk::pending_min`]).
    min_pending: Option<Option<EdgeKey>>,
    /// One bit per node id: set once the id has rejected edges in the store, cleared when they
    /// are taken out. A clear bit answers [`Store::take_rejected`] without a B-tree descent
    /// (about 1% of edges are ever rejected, and a load or collapse asks for several vertices).
    may_have_rejected: Option<Vec<u64>>,
}

impl Builder<'_> {
    /// One load-and-collapse round; false once nothing is left to collapse.
    fn batch(&mut self) -> Result<bool> {
        crate::sys::cancel::check()?;
        let db_path = self.db_path;
        let mut txn = self.db.begin_write().db(db_path)?;
        txn.set_durability(Durability::None).db(db_path)?;
        let more;
        {
            let mut disk = Disk {
                path: db_path,
                edges: txn.open_table(EDGES).db(db_path)?,
                rejected: txn.open_table(REJECTED).db(db_path)?,
                records: &mut *self.records,
                out: &mut *self.out,
                min_pending: &mut self.min_pending,
                may_have_rejected: self.may_have_rejected.as_deref_mut(),
            };
            if disk.pending_min()?.is_none() {
                return Ok(false);
            }
            self.region.run(self.span_fraction, &mut disk)?;
            self.region.write_back(&mut disk)?;
            more = disk.pending_min()?.is_some();
        }
        txn.commit().db(db_path)?;
        self.batches += 1;
        self.max_db_bytes = self.max_db_bytes.max(std::fs::metadata(db_path).map_or(0, |m| m.len()));
        Ok(more)
    }
}

/// The region's [`Store`]: the scratch database's tables in the batch's write transaction.
struct Disk<'t> {
    path: &'t Path,
    edges: Table<'t, u128, ()>,
    rejected: Table<'t, u64, ()>,
    records: &'t mut DenseRecords,
    out: &'t mut Output,
    min_pending: &'t mut Option<Option<EdgeKey>>,
    may_have_rejected: Option<&'t mut [u64]>,
}

impl Store for Disk<'_> {
    fn vertex(&mut self, v: u32) -> Result<(VertexState, Vec<u32>)> {
        self.records.vertex(v)
    }

    fn vertex_state(&mut self, v: u32) -> Result<VertexState> {
        self.records.vertex_state(v)
    }

    fn triangle(&mut self, t: u32) -> Result<Option<([u32; 3], [u32; 3])>> {
        self.records.triangle(t)
    }

    fn take_pending(&mut self, key: EdgeKey) -> Result<bool> {
        let taken = self.edges.remove(key).db(self.path)?.is_some();
        if taken && *self.min_pending == Some(Some(key)) {
            *self.min_pending = None;
        }
        Ok(taken)
    }

    fn put_pending(&mut self, key: EdgeKey) -> Result<()> {
        self.edges.insert(key, ()).db(self.path)?;
        if let Some(min) = self.min_pending {
            *min = Some(min.map_or(key, |m| m.min(key)));
        }
        Ok(())
    }

    /// Cached between calls: only [`Self::take_pending`] of the minimum itself makes it unknown.
    fn pending_min(&mut self) -> Result<Option<EdgeKey>> {
        if let Some(min) = *self.min_pending {
            return Ok(min);
        }
        let min = self.edges.first().db(self.path)?.map(|(k, _)| k.value());
        *self.min_pending = Some(min);
        Ok(min)
    }

    fn take_rejected(&mut self, v: u32, others: &mut Vec<u32>) -> Result<()> {
        if let Some(bits) = self.may_have_rejected.as_deref_mut() {
            let (word, bit) = (v as usize / 64, 1u64 << (v % 64));
            match bits.get_mut(word) {
                Some(w) if *w & bit == 0 => return Ok(()),
                Some(w) => *w &= !bit, // all of v's entries are taken below
                None => {}
            }
        }
        let from = others.len();
        let lo = (v as u64) << 32;
        for entry in self.rejected.range(lo..=lo | u32::MAX as u64).db(self.path)? {
            let (k, _) = entry.db(self.path)?;
            others.push(k.value() as u32);
        }
        for &d in &others[from..] {
            self.rejected.remove(lo | d as u64).db(self.path)?;
            self.rejected.remove((d as u64) << 32 | v as u64).db(self.path)?;
        }
        Ok(())
    }

    fn put_rejected(&mut self, a: u32, b: u32) -> Result<()> {
        if let Some(bits) = self.may_have_rejected.as_deref_mut() {
            for x in [a, b] {
                if let Some(w) = bits.get_mut(x as usize / 64) {
                    *w |= 1 << (x % 64);
                }
            }
        }
        self.rejected.insert((a as u64) << 32 | b as u64, ()).db(self.path)?;
        self.rejected.insert((b as u64) << 32 | a as u64, ()).db(self.path)?;
        Ok(())
    }

    fn put_vertex(&mut self, v: u32, state: &VertexState, triangles: &[u32]) -> Result<()> {
        self.records.put_vertex(v, state, triangles)
    }

    fn put_triangle(&mut self, t: u32, c: [u32; 3], l: [u32; 3]) -> Result<()> {
        self.records.put_triangle(t, c, l)
    }

    fn remove_vertex(&mut self, v: u32) -> Result<()> {
        self.records.remove_vertex(v)
    }

    fn remove_triangle(&mut self, t: u32) -> Result<()> {
        self.records.remove_triangle(t)
    }

    fn emit(&mut self, node: &VdtNode, dying: &[[u32; 3]]) -> Result<()> {
        let out = &mut *self.out;
        let node = VdtNode { tri_start: out.triangles_written as u32, ..*node };
        out.node(&node)?;
        for t in dying {
            out.triangles.write_all(bytemuck::cast_slice(t)).at(&out.dir)?;
        }
        out.triangles_written += dying.len() as u64;
        Ok(())
    }
}

/// Step 4: patches the parents, writes the VDT file atomically. Returns the dying and base
/// triangle counts and the file's size.
#[allow(clippy::too_many_arguments, reason = "internal; each argument is a distinct input")]
fn assemble(
    output: &Path,
    records: &DenseRecords,
    out: Output,
    leaves: u64,
    nodes: u64,
    triangles: u64,
    metric: VdtMetric,
    bounds: crate::mesh::Bounds,
) -> Result<(u64, u64, u64)> {
    let Output { nodes: node_writer, triangles: tri_writer, dir, nodes_written, triangles_written } = out;
    if nodes_written != nodes {
        return Err(Error::Scratch {
            path: dir,
            problem: format!("{nodes_written} node records written for {nodes} nodes"),
        });
    }
    let node_file = node_writer.into_inner().map_err(|e| Error::io(&dir, e.into_error()))?;
    let mut tri_file = tri_writer.into_inner().map_err(|e| Error::io(&dir, e.into_error()))?;
    let mut map = ScratchMap::from_unlinked(node_file, &dir)?;
    let node_bytes = map.slice::<u8>().len();
    if node_bytes as u64 != nodes * NODE_BYTES as u64 {
        return Err(Error::Scratch {
            path: dir,
            problem: format!("node file of {node_bytes} bytes for {nodes} nodes"),
        });
    }
    {
        let records: &mut [VdtNode] = map.slice_mut();
        for id in leaves as usize..records.len() {
            for c in records[id].children {
                records[c as usize].parent = id as u32;
            }
        }
    }
    let base = records.live_triangles();
    if triangles_written + base != triangles {
        return Err(Error::Scratch {
            path: dir,
            problem: format!("{triangles_written} dying and {base} base triangles for {triangles} input triangles"),
        });
    }
    let header = VdtHeader { metric, leaves, nodes, triangles, base_triangles: base, bounds };
    use std::io::Seek;
    tri_file.seek(std::io::SeekFrom::Start(0)).at(&dir)?;
    crate::sys::atomic_file::write(output, |w| {
        write_header(w, &header)?;
        w.write_all(map.slice::<u8>())?;
        let copied = std::io::copy(&mut (&tri_file).take(triangles_written * 12), w)?;
        if copied != triangles_written * 12 {
            return Err(std::io::Error::other("scratch triangle file is short"));
        }
        if records.write_live_triangles(w)? != base {
            return Err(std::io::Error::other("scratch triangle records changed"));
        }
        Ok(())
    })?;
    debug_assert_eq!(header.file_bytes(), HEADER_BYTES as u64 + nodes * NODE_BYTES as u64 + triangles * 12);
    Ok((triangles_written, base, header.file_bytes()))
}
