//! Shortest-first edge collapse over a loaded region of a mesh: the in-memory step (3.) of
//! El-Sana & Chiang's *spanned sub-mesh simplification* (Eurographics 2000, §3.1.2), building the
//! view-dependence forest of El-Sana & Varshney as it goes. [`super::build`] loads regions from its
//! disk store and calls [`Region::run`]; everything outside the region stays behind the [`Store`].
//!
//! # The collapse order (the reference algorithm)
//! Every current edge is *pending* or *rejected*. Repeatedly take the pending edge with the
//! smallest [`EdgeKey`] (metric value, then smaller id, then larger id) and try to collapse it:
//! - Half-edge collapse of (a, b) into a new node p with the next id, placed at the survivor
//!   (`children[0]`); the two directions are tried in a fixed order (length: the smaller id
//!   survives first; quadric: the cheaper direction first, ties to the smaller id).
//! - A direction is refused if a triangle that survives and moves (one holding the victim but not
//!   the survivor) flips or degenerates: with n = (p1 − p0) × (p2 − p0) before and n' after,
//!   refused if n·n' ≤ 0 or |n'|² ≤ 10⁻¹²·|n|². Refused both ways, the edge becomes *rejected*.
//! - After a collapse, p's edges are new and pending, and every rejected edge of a vertex of the
//!   old 1-ring of a and b becomes pending again (its neighbourhood changed; a rejected edge
//!   whose neighbourhood did not change would be refused again, so it is not re-examined).
//!
//! So each collapse is of the shortest edge that passes the foldover test at that moment. Node
//! states never change once created (a collapse makes a new id), so an edge's key is fixed for its
//! lifetime and lazy deletion in the heap needs only an "are both ends alive" check.
//!
//! # Metrics
//! - Length: the edge's Euclidean length, `((dx·dx + dy·dy) + dz·dz).sqrt()` in f64.
//! - Quadric (Garland & Heckbert 1997): each leaf sums the plane quadrics of its triangles (not
//!   area-weighted), p's quadric is the sum of its children's; the value of placing p at x is
//!   `sqrt(max(0, xᵀQx))`, mesh units. The edge's key takes the cheaper of the two placements.
//!
//! Switch values nest (p's is the max of its collapse value and its children's) and so do radii
//! (max over children c of ‖p − c‖ + r_c, computed on the f32 positions written to the file and
//! rounded up to f32).
//!
//! # Where edges live while a region is loaded
//! The region holds the *loaded* vertices (state and all their live triangles) and, read-only,
//! the *halo*: the other corners of those triangles. An edge between two loaded vertices lives in
//! the heap (pending) or in the region's rejected set. An edge between a loaded vertex and a halo
//! vertex stays in the store's B-tree if pending and unchanged since loading, and is in the region
//! otherwise. Edges between two unloaded vertices are in the store. So the smallest pending edge
//! overall is the smaller of the heap's top and the store's B-tree minimum: that edge is
//! collapsed (or rejected) next, after loading whichever of its ends is not loaded, which keeps
//! the global order exact (see [`Region::run`]).

use std::cmp::Reverse;
use std::collections::{BTreeMap, BTreeSet, BinaryHeap};

use super::{VdtNode, NONE};
use crate::error::{Error, Result};
use crate::format::vdt::VdtMetric;

/// A plane quadric `[a², ab, ac, ad, b², bc, bd, c², cd, d²]` of the plane ax + by + cz + d = 0.
pub type Quadric = [f64; 10];

/// An edge's place in the collapse order: the metric value as order-preserving bits (high 64
/// bits), then the smaller and the larger vertex id. Unique per edge, so it is also a total order.
pub type EdgeKey = u128;

/// The key of edge (a, b) with metric value `value` (NaN sorts last, as +∞).
pub fn edge_key(value: f64, a: u32, b: u32) -> EdgeKey {
    let (lo, hi) = if a < b { (a, b) } else { (b, a) };
    let value = if value.is_nan() { f64::INFINITY } else { value };
    let bits = value.to_bits();
    let ordered = if bits >> 63 == 1 { !bits } else { bits | 1 << 63 };
    (ordered as u128) << 64 | (lo as u128) << 32 | hi as u128
}

/// The two vertex ids of a key, smaller first.
pub fn key_ends(key: EdgeKey) -> (u32, u32) {
    ((key >> 32) as u32, key as u32)
}

/// The metric value of a key.
pub fn key_value(key: EdgeKey) -> f64 {
    let ordered = (key >> 64) as u64;
    f64::from_bits(if ordered >> 63 == 1 { ordered & !(1 << 63) } else { !ordered })
}

/// Euclidean distance, the length metric (this exact formula: the key order depends on it).
pub fn length(a: [f64; 3], b: [f64; 3]) -> f64 {
    let (dx, dy, dz) = (a[0] - b[0], a[1] - b[1], a[2] - b[2]);
    ((dx * dx + dy * dy) + dz * dz).sqrt()
}

/// The plane quadric of a triangle; `None` for a degenerate one (no plane).
pub fn plane_quadric(p0: [f64; 3], p1: [f64; 3], p2: [f64; 3]) -> Option<Quadric> {
    let n = normal(p0, p1, p2);
    let len = dot(n, n).sqrt();
    if !(len > 0.0 && len.is_finite()) {
        return None;
    }
    let [a, b, c] = n.map(|x| x / len);
    let d = -(a * p0[0] + b * p0[1] + c * p0[2]);
    Some([a * a, a * b, a * c, a * d, b * b, b * c, b * d, c * c, c * d, d * d])
}

/// `q + r`.
pub fn add_quadrics(q: &Quadric, r: &Quadric) -> Quadric {
    std::array::from_fn(|k| q[k] + r[k])
}

/// `xᵀQx` for x = (x, y, z, 1).
pub fn quadric_error(q: &Quadric, p: [f64; 3]) -> f64 {
    let [x, y, z] = p;
    q[0] * x * x
        + 2.0 * q[1] * x * y
        + 2.0 * q[2] * x * z
        + 2.0 * q[3] * x
        + q[4] * y * y
        + 2.0 * q[5] * y * z
        + 2.0 * q[6] * y
        + q[7] * z * z
        + 2.0 * q[8] * z
        + q[9]
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// (p1 − p0) × (p2 − p0).
fn normal(p0: [f64; 3], p1: [f64; 3], p2: [f64; 3]) -> [f64; 3] {
    let (u, v) = (sub(p1, p0), sub(p2, p0));
    [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
}

/// The foldover test for one triangle whose corner moves: `before` and `after` are its corners.
pub fn triangle_survives(before: [[f64; 3]; 3], after: [[f64; 3]; 3]) -> bool {
    let n0 = normal(before[0], before[1], before[2]);
    let n1 = normal(after[0], after[1], after[2]);
    dot(n0, n1) > 0.0 && dot(n1, n1) > 1e-12 * dot(n0, n0)
}

/// A current vertex (a node of the forest that has not been collapsed yet).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct VertexState {
    /// A leaf's position (half-edge collapses keep the survivor's), mesh units.
    pub position: [f64; 3],
    /// Zero for the length metric.
    pub quadric: Quadric,
    /// Nested switch value (0 for leaves), mesh units.
    pub switch: f64,
    /// Nested bounding radius (0 for leaves), mesh units.
    pub radius: f64,
    /// Leaves below (1 for a leaf).
    pub leaves: u32,
}

impl VertexState {
    pub fn leaf(position: [f64; 3], quadric: Quadric) -> Self {
        VertexState { position, quadric, switch: 0.0, radius: 0.0, leaves: 1 }
    }
}

/// The collapse options of edge (a, b): the key's metric value and the two directions
/// `(survivor, victim, value)` in the order they are tried.
pub fn collapse_options(
    metric: VdtMetric,
    a: u32,
    sa: &VertexState,
    b: u32,
    sb: &VertexState,
) -> (f64, [(u32, u32, f64); 2]) {
    let ((lo, slo), (hi, shi)) = if a < b { ((a, sa), (b, sb)) } else { ((b, sb), (a, sa)) };
    match metric {
        VdtMetric::Length => {
            let len = length(slo.position, shi.position);
            (len, [(lo, hi, len), (hi, lo, len)])
        }
        VdtMetric::Quadric => {
            let q = add_quadrics(&slo.quadric, &shi.quadric);
            let e_lo = quadric_error(&q, slo.position).max(0.0).sqrt();
            let e_hi = quadric_error(&q, shi.position).max(0.0).sqrt();
            // NaN (never expected from finite input) counts as the worse choice.
            if e_hi < e_lo {
                (e_hi, [(hi, lo, e_hi), (lo, hi, e_lo)])
            } else {
                (e_lo, [(lo, hi, e_lo), (hi, lo, e_hi)])
            }
        }
    }
}

/// The disk side of a region (see [`super::build`]): the B-tree of pending edges, the table of
/// rejected edges (both orientations), vertex and triangle records, and the output.
pub trait Store {
    /// A vertex's state and its triangle ids (some may have died since they were written).
    fn vertex(&mut self, v: u32) -> Result<(VertexState, Vec<u32>)>;
    /// A vertex's state (it must exist: it is a corner of a live triangle).
    fn vertex_state(&mut self, v: u32) -> Result<VertexState>;
    /// A live triangle's current corners and its input (leaf) corners; `None` once it died.
    fn triangle(&mut self, t: u32) -> Result<Option<([u32; 3], [u32; 3])>>;
    /// Removes a pending edge from the B-tree; false if it was not there.
    fn take_pending(&mut self, key: EdgeKey) -> Result<bool>;
    /// Puts a pending edge into the B-tree.
    fn put_pending(&mut self, key: EdgeKey) -> Result<()>;
    /// The smallest pending edge in the B-tree.
    fn pending_min(&mut self) -> Result<Option<EdgeKey>>;
    /// Removes every rejected edge (v, d) from the store (both orientations), appending the d's.
    fn take_rejected(&mut self, v: u32, others: &mut Vec<u32>) -> Result<()>;
    /// Stores rejected edge (a, b) (both orientations).
    fn put_rejected(&mut self, a: u32, b: u32) -> Result<()>;
    /// Stores a vertex's state and its live triangles.
    fn put_vertex(&mut self, v: u32, state: &VertexState, triangles: &[u32]) -> Result<()>;
    /// Stores a triangle's current and input corners.
    fn put_triangle(&mut self, t: u32, corners: [u32; 3], leaves: [u32; 3]) -> Result<()>;
    /// A vertex was collapsed: its record is no longer needed.
    fn remove_vertex(&mut self, v: u32) -> Result<()>;
    /// A triangle died.
    fn remove_triangle(&mut self, t: u32) -> Result<()>;
    /// A collapse created `node` (its `tri_start` is for the store to fill in); `dying` are the
    /// input corners of the triangles with m(t) = this node, by increasing triangle id.
    fn emit(&mut self, node: &VdtNode, dying: &[[u32; 3]]) -> Result<()>;
}

/// Why [`Region::run`] stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stop {
    /// No pending edge is left, in the region or in the store.
    Exhausted,
    /// The next step needs a vertex loaded and the budget cannot hold it.
    Budget,
}

/// Counters of a region's work (over all batches).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RegionStats {
    pub collapses: u64,
    pub rejections: u64,
    /// Vertices loaded (a vertex loaded in several batches counts each time).
    pub loads: u64,
    /// Connected components of loaded vertices at the end of each spanning phase, summed.
    pub sub_meshes: u64,
}

#[derive(Debug)]
struct VertSlot {
    id: u32,
    loaded: bool,
    state: VertexState,
    /// Live triangles (triangle slots); loaded vertices only.
    tris: Vec<u32>,
}

#[derive(Clone, Copy, Debug)]
struct TriSlot {
    id: u32,
    corners: [u32; 3],
    leaves: [u32; 3],
}

/// Accounting constants, bytes (see [`Region::used_bytes`]).
pub mod cost {
    /// One vertex slot (state, id, flags, triangle-list header) and its free-list entry.
    pub const VERTEX_SLOT: u64 = std::mem::size_of::<super::VertSlot>() as u64 + 4;
    /// One triangle slot and its free-list entry.
    pub const TRIANGLE_SLOT: u64 = std::mem::size_of::<super::TriSlot>() as u64 + 4;
    /// One entry of a `BTreeMap<u32, u32>` (id index, union–find): 8 bytes in nodes of 11 that
    /// are at least 5/11 full, plus the nodes' headers and allocator overhead (about 112 bytes a
    /// node).
    pub const INDEX_ENTRY: u64 = 28;
    /// One entry of the `BTreeSet<u64>` of rejected edges (nodes of about 104 + 16 bytes).
    pub const REJECTED_ENTRY: u64 = 26;
    /// One heap entry (an [`super::EdgeKey`]).
    pub const HEAP_ENTRY: u64 = 16;
    /// What glibc's malloc takes for a triangle list of `cap` ids.
    pub fn list(cap: usize) -> u64 {
        if cap == 0 {
            0
        } else {
            ((cap as u64 * 4 + 8 + 15) & !15).max(32)
        }
    }
    /// Headroom for one collapse's transients (the new triangle list, scratch vectors).
    pub const COLLAPSE_SCRATCH: u64 = 16 << 10;
}

/// A vertex read and sized, ready to be loaded ([`Region::load`]).
struct Prepared {
    v: u32,
    state: VertexState,
    /// Its live triangles: already in the region (slot), or read from the store.
    tris: Vec<PreparedTri>,
    /// Corners to add to the halo, with their states.
    halo: Vec<(u32, VertexState)>,
    cost: u64,
}

enum PreparedTri {
    Here(u32),
    Read(u32, [u32; 3], [u32; 3]),
}

/// A loaded region and the in-memory part of the collapse order (see the module docs).
pub struct Region {
    metric: VdtMetric,
    /// What [`Self::committed_bytes`] may reach.
    budget_bytes: u64,
    verts: Vec<VertSlot>,
    free_verts: Vec<u32>,
    vert_index: BTreeMap<u32, u32>,
    tris: Vec<TriSlot>,
    free_tris: Vec<u32>,
    tri_index: BTreeMap<u32, u32>,
    heap: BinaryHeap<Reverse<EdgeKey>>,
    /// Heap entries whose ends are both alive (the rest are stale, dropped lazily).
    heap_live: usize,
    /// The heap's largest length so far (its buffer never shrinks).
    heap_high_water: usize,
    /// Edges from a loaded vertex to a halo vertex.
    boundary: usize,
    /// Rejected edges with an end in the region, both orientations: `a << 32 | b`.
    rejected: BTreeSet<u64>,
    /// Union–find over loaded vertices joined by edges (parent links; roots map to themselves).
    union_find: BTreeMap<u32, u32>,
    components: u64,
    /// Allocated bytes of the loaded vertices' triangle lists.
    list_bytes: u64,
    loaded: usize,
    next_id: u32,
    peak_bytes: u64,
    stats: RegionStats,
    // Scratch, reused between collapses.
    nbrs: Vec<u32>,
    ring: Vec<u32>,
    others: Vec<u32>,
    /// Dying triangles of a collapse: (slot, id, input corners).
    dying: Vec<(u32, u32, [u32; 3])>,
    dying_leaves: Vec<[u32; 3]>,
}

fn pair(a: u32, b: u32) -> u64 {
    (a as u64) << 32 | b as u64
}

/// `r` as f32, rounded up (radii must not shrink when written).
pub(super) fn f32_up(r: f64) -> f32 {
    let f = r as f32;
    if (f as f64) < r {
        f.next_up()
    } else {
        f
    }
}

fn f32_position(p: [f64; 3]) -> [f64; 3] {
    p.map(|c| c as f32 as f64)
}

impl Region {
    /// An empty region that may commit up to `budget_bytes` ([`Self::committed_bytes`]); new
    /// nodes get ids from `next_id` on. The slabs' capacities are reserved up front (address
    /// space only: pages are touched as slots are used), so growing a slab never copies it;
    /// pass what the budget could hold at most.
    pub fn new(
        metric: VdtMetric,
        budget_bytes: u64,
        next_id: u32,
        max_vertices: usize,
        max_triangles: usize,
        max_heap: usize,
    ) -> Self {
        Region {
            metric,
            budget_bytes,
            verts: Vec::with_capacity(max_vertices),
            free_verts: Vec::with_capacity(max_vertices),
            vert_index: BTreeMap::new(),
            tris: Vec::with_capacity(max_triangles),
            free_tris: Vec::with_capacity(max_triangles),
            tri_index: BTreeMap::new(),
            heap: BinaryHeap::with_capacity(max_heap),
            heap_live: 0,
            heap_high_water: 0,
            boundary: 0,
            rejected: BTreeSet::new(),
            union_find: BTreeMap::new(),
            components: 0,
            list_bytes: 0,
            loaded: 0,
            next_id,
            peak_bytes: 0,
            stats: RegionStats::default(),
            nbrs: Vec::new(),
            ring: Vec::new(),
            others: Vec::new(),
            dying: Vec::new(),
            dying_leaves: Vec::new(),
        }
    }

    /// The id the next collapse gets.
    pub fn next_id(&self) -> u32 {
        self.next_id
    }

    pub fn stats(&self) -> RegionStats {
        self.stats
    }

    /// Loaded vertices.
    pub fn loaded_vertices(&self) -> usize {
        self.loaded
    }

    pub fn is_loaded(&self, v: u32) -> bool {
        self.vert_index.get(&v).is_some_and(|&s| self.verts[s as usize].loaded)
    }

    /// Bytes held now: the slabs and the heap up to their high-water marks (their pages stay
    /// resident), the indices, the union–find, the rejected set and the triangle lists. Each
    /// figure is an upper estimate from the [`cost`] constants.
    pub fn used_bytes(&self) -> u64 {
        self.verts.len() as u64 * cost::VERTEX_SLOT
            + self.tris.len() as u64 * cost::TRIANGLE_SLOT
            + (self.vert_index.len() + self.tri_index.len() + self.union_find.len()) as u64 * cost::INDEX_ENTRY
            + self.rejected.len() as u64 * cost::REJECTED_ENTRY
            + self.heap_high_water as u64 * cost::HEAP_ENTRY
            + self.list_bytes
    }

    /// [`Self::used_bytes`] plus what collapsing may still add without loading: stale heap
    /// entries up to the compaction threshold, a heap entry (and its stale copy) per boundary
    /// edge that a collapse renews, and one collapse's scratch. Loads are refused past
    /// [`Self::new`]'s budget of this, and the collapse phase stops once a step takes it past
    /// the budget: rejected pairs are counted as they are made (in [`Self::used_bytes`]) rather
    /// than reserved for every edge, since about 1% of edges are ever rejected and the
    /// reservation took a third of a region. One step adds far less than the scratch head-room.
    pub fn committed_bytes(&self) -> u64 {
        let heap_cap = (2 * (self.heap_live + self.boundary) + 256).saturating_sub(self.heap_high_water);
        self.used_bytes() + heap_cap as u64 * cost::HEAP_ENTRY + cost::COLLAPSE_SCRATCH
    }

    /// The largest [`Self::used_bytes`] seen at a checkpoint (after each load and collapse).
    pub fn peak_bytes(&self) -> u64 {
        self.peak_bytes
    }

    fn note_peak(&mut self) {
        self.heap_high_water = self.heap_high_water.max(self.heap.len());
        self.peak_bytes = self.peak_bytes.max(self.used_bytes());
    }

    fn slot(&self, v: u32) -> Option<usize> {
        self.vert_index.get(&v).map(|&s| s as usize)
    }

    fn state(&self, v: u32) -> Option<&VertexState> {
        self.slot(v).map(|s| &self.verts[s].state)
    }

    fn new_vert_slot(&mut self, slot: VertSlot) -> usize {
        let id = slot.id;
        let s = match self.free_verts.pop() {
            Some(s) => {
                self.verts[s as usize] = slot;
                s as usize
            }
            None => {
                self.verts.push(slot);
                self.verts.len() - 1
            }
        };
        self.vert_index.insert(id, s as u32);
        s
    }

    fn free_vert_slot(&mut self, s: usize) {
        let slot = &mut self.verts[s];
        self.vert_index.remove(&slot.id);
        self.list_bytes -= cost::list(slot.tris.capacity());
        if slot.loaded {
            self.loaded -= 1;
        }
        *slot = VertSlot { id: NONE, loaded: false, state: VertexState::default(), tris: Vec::new() };
        self.free_verts.push(s as u32);
    }

    /// The key of current edge (a, b) (both must be in the region).
    fn key_of(&self, a: u32, b: u32) -> Result<EdgeKey> {
        let (Some(sa), Some(sb)) = (self.state(a), self.state(b)) else {
            return Err(internal(format!("edge ({a}, {b}) has an end outside the region")));
        };
        Ok(edge_key(collapse_options(self.metric, a, sa, b, sb).0, a, b))
    }

    /// The sorted, distinct other corners of slot `s`'s triangles, into `self.nbrs`.
    fn neighbours(&mut self, s: usize) {
        let id = self.verts[s].id;
        self.nbrs.clear();
        for &t in &self.verts[s].tris {
            self.nbrs.extend(self.tris[t as usize].corners.iter().copied().filter(|&c| c != id));
        }
        self.nbrs.sort_unstable();
        self.nbrs.dedup();
    }

    fn push(&mut self, key: EdgeKey) {
        self.heap.push(Reverse(key));
        self.heap_live += 1;
    }

    /// Reads vertex `v`, its live triangles and the states of their corners that are new to the
    /// region, and sizes what loading it adds to [`Self::committed_bytes`].
    fn prepare(&self, v: u32, store: &mut impl Store) -> Result<Prepared> {
        let (state, ids) = store.vertex(v)?;
        let mut tris = Vec::with_capacity(ids.len());
        let mut corners_seen = Vec::with_capacity(2 * ids.len());
        let mut new_tris = 0u64;
        for t in ids {
            let corners = if let Some(&ts) = self.tri_index.get(&t) {
                tris.push(PreparedTri::Here(ts));
                self.tris[ts as usize].corners
            } else if let Some((corners, leaves)) = store.triangle(t)? {
                if !corners.contains(&v) {
                    return Err(internal(format!("triangle {t} {corners:?} is listed by vertex {v}")));
                }
                tris.push(PreparedTri::Read(t, corners, leaves));
                new_tris += 1;
                corners
            } else {
                continue; // died while v was outside the region
            };
            corners_seen.extend(corners.into_iter().filter(|&c| c != v));
        }
        corners_seen.sort_unstable();
        corners_seen.dedup();
        let k = corners_seen.len() as u64;
        let mut halo = Vec::new();
        for &c in &corners_seen {
            if self.slot(c).is_none() {
                halo.push((c, store.vertex_state(c)?));
            }
        }
        let new_verts = halo.len() as u64 + u64::from(self.slot(v).is_none());
        let cost = new_verts * (cost::VERTEX_SLOT + cost::INDEX_ENTRY)
            + new_tris * (cost::TRIANGLE_SLOT + cost::INDEX_ENTRY)
            + cost::list(tris.len())
            // Per edge: a heap entry with its committed stale copy and rejected pair (as a live
            // or a boundary edge), rejected pairs possibly read from the store, a union–find
            // entry.
            + k * (2 * cost::HEAP_ENTRY + 4 * cost::REJECTED_ENTRY + cost::INDEX_ENTRY)
            + cost::INDEX_ENTRY;
        Ok(Prepared { v, state, tris, halo, cost })
    }

    /// Loads the vertices of `vs` that are not loaded yet (each with its live triangles; the
    /// other corners join the halo), moving their edges to loaded vertices out of the store's
    /// B-tree into the heap and their rejected edges into the region; or, if that would take
    /// [`Self::committed_bytes`] past `limit_bytes`, loads nothing and returns false.
    pub fn load(&mut self, vs: &[u32], limit_bytes: u64, store: &mut impl Store) -> Result<bool> {
        let mut prepared = Vec::with_capacity(vs.len());
        let mut total = 0;
        for &v in vs {
            if !self.is_loaded(v) && !prepared.iter().any(|p: &Prepared| p.v == v) {
                let p = self.prepare(v, store)?;
                total += p.cost;
                prepared.push(p);
            }
        }
        if self.committed_bytes() + total > limit_bytes.min(self.budget_bytes) {
            return Ok(false);
        }
        for p in prepared {
            self.commit_load(p, store)?;
        }
        self.note_peak();
        Ok(true)
    }

    fn commit_load(&mut self, p: Prepared, store: &mut impl Store) -> Result<()> {
        let v = p.v;
        for (c, state) in p.halo {
            if self.slot(c).is_none() {
                self.new_vert_slot(VertSlot { id: c, loaded: false, state, tris: Vec::new() });
            }
        }
        let s = match self.slot(v) {
            Some(s) => s,
            None => self.new_vert_slot(VertSlot { id: v, loaded: false, state: p.state, tris: Vec::new() }),
        };
        let mut list = Vec::with_capacity(p.tris.len());
        for t in p.tris {
            match t {
                PreparedTri::Here(ts) => list.push(ts),
                // Read for v, but loaded meanwhile with the other vertex of the same load.
                PreparedTri::Read(id, ..) if self.tri_index.contains_key(&id) => list.push(self.tri_index[&id]),
                PreparedTri::Read(id, corners, leaves) => {
                    let slot = TriSlot { id, corners, leaves };
                    let ts = match self.free_tris.pop() {
                        Some(ts) => {
                            self.tris[ts as usize] = slot;
                            ts
                        }
                        None => {
                            self.tris.push(slot);
                            (self.tris.len() - 1) as u32
                        }
                    };
                    self.tri_index.insert(id, ts);
                    list.push(ts);
                }
            }
        }
        self.list_bytes += cost::list(list.capacity());
        self.verts[s].tris = list;
        self.verts[s].loaded = true;
        self.loaded += 1;
        self.stats.loads += 1;
        if self.union_find.insert(v, v).is_none() {
            self.components += 1;
        }
        self.neighbours(s);
        let nbrs = std::mem::take(&mut self.nbrs);
        for &c in &nbrs {
            if !self.is_loaded(c) {
                self.boundary += 1; // stays where it is: the B-tree, or the region if rejected
                continue;
            }
            self.boundary = self.boundary.saturating_sub(1); // was c's boundary edge
            self.union(v, c);
            if self.rejected.contains(&pair(v, c)) {
                continue;
            }
            // Pending: in the B-tree if unchanged since c was loaded, else already in the heap
            // (c was renewed or re-examined since).
            let key = self.key_of(v, c)?;
            if store.take_pending(key)? {
                self.push(key);
            }
        }
        self.nbrs = nbrs;
        let mut others = std::mem::take(&mut self.others);
        others.clear();
        store.take_rejected(v, &mut others)?;
        for &d in &others {
            self.rejected.insert(pair(v, d));
            self.rejected.insert(pair(d, v));
        }
        self.others = others;
        Ok(())
    }

    fn find(&mut self, v: u32) -> u32 {
        let mut root = v;
        while let Some(&up) = self.union_find.get(&root).filter(|&&up| up != root) {
            root = up;
        }
        let mut x = v;
        while x != root {
            x = self.union_find.insert(x, root).unwrap_or(root);
        }
        root
    }

    fn union(&mut self, a: u32, b: u32) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            self.union_find.insert(ra.max(rb), ra.min(rb));
            self.components -= 1;
        }
    }

    /// One batch's work, in global shortest-first order (module docs):
    /// 1. Spanning: while [`Self::committed_bytes`] stays within `span_fraction` of the budget,
    ///    take the store's smallest pending edge as a spanning edge and load its ends, growing
    ///    the sub-meshes (connected components of loaded vertices).
    /// 2. Collapsing: take the smallest pending edge overall, from the heap or the B-tree.
    ///    Both ends loaded: collapse it or reject it. Otherwise load the missing ends first (a
    ///    boundary edge whose loaded end moved, or an edge still in the B-tree); if the budget
    ///    cannot hold them, stop with [`Stop::Budget`].
    ///
    /// Returns when no pending edge is left or a needed load does not fit. A fresh region always
    /// makes progress: the store's smallest edge is loaded first (or the budget is too small for
    /// it: an error) and is the first one examined.
    pub fn run(&mut self, span_fraction: f64, store: &mut impl Store) -> Result<Stop> {
        let span_limit = (self.budget_bytes as f64 * span_fraction.clamp(0.0, 1.0)) as u64;
        let fresh = self.loaded == 0;
        let mut spanned = 0u64;
        while let Some(key) = store.pending_min()? {
            let (a, b) = key_ends(key);
            if self.is_loaded(a) && self.is_loaded(b) {
                return Err(internal(format!("edge ({a}, {b}) is in the B-tree with both ends loaded")));
            }
            let limit = if fresh && spanned == 0 { self.budget_bytes } else { span_limit };
            if !self.load(&[a, b], limit, store)? {
                break;
            }
            spanned += 1;
        }
        if fresh && spanned == 0 && store.pending_min()?.is_some() {
            return Err(Error::MemoryBudget {
                budget_bytes: self.budget_bytes,
                problem: "it cannot hold the neighbourhood of the shortest edge".into(),
            });
        }
        self.stats.sub_meshes += self.components;

        // A lower bound of the B-tree's minimum: deletions only raise the true minimum, and
        // insertions (re-examined edges outside the region) lower this one as they happen.
        let mut bound = store.pending_min()?;
        let mut steps = 0u64;
        loop {
            steps += 1;
            if steps.is_multiple_of(4096) {
                crate::sys::cancel::check()?;
            }
            let top = match self.heap.peek() {
                Some(&Reverse(key)) => {
                    let (a, b) = key_ends(key);
                    if self.slot(a).is_none() || self.slot(b).is_none() {
                        self.heap.pop(); // stale: an end was collapsed
                        continue;
                    }
                    Some(key)
                }
                None => None,
            };
            if top.is_none() || bound.is_some_and(|m| top.is_some_and(|k| k > m)) {
                bound = store.pending_min()?;
            }
            let (key, in_heap) = match (top, bound) {
                (None, None) => return Ok(Stop::Exhausted),
                (Some(k), Some(m)) if m < k => (m, false),
                (None, Some(m)) => (m, false),
                (Some(k), _) => (k, true),
            };
            let (a, b) = key_ends(key);
            if !self.is_loaded(a) || !self.is_loaded(b) {
                if !self.load(&[a, b], self.budget_bytes, store)? {
                    return Ok(Stop::Budget);
                }
                continue; // the edge is in the heap now
            }
            if !in_heap {
                return Err(internal(format!("edge ({a}, {b}) is in the B-tree with both ends loaded")));
            }
            self.heap.pop();
            self.heap_live -= 1;
            self.process(a, b, store, &mut bound)?;
            if self.committed_bytes() > self.budget_bytes {
                return Ok(Stop::Budget);
            }
            if self.heap.len() > 2 * self.heap_live + 256 {
                let index = &self.vert_index;
                self.heap.retain(|&Reverse(k)| {
                    let (a, b) = key_ends(k);
                    index.contains_key(&a) && index.contains_key(&b)
                });
            }
            self.note_peak();
        }
    }

    /// Tries both directions of pending edge (a, b); rejects it if both fold over.
    fn process(&mut self, a: u32, b: u32, store: &mut impl Store, bound: &mut Option<EdgeKey>) -> Result<()> {
        let (Some(sa), Some(sb)) = (self.state(a), self.state(b)) else {
            return Err(internal(format!("edge ({a}, {b}) has an end outside the region")));
        };
        let (_, options) = collapse_options(self.metric, a, sa, b, sb);
        for (s, v, value) in options {
            if self.foldover_ok(s, v) {
                return self.collapse(s, v, value, store, bound);
            }
        }
        self.rejected.insert(pair(a, b));
        self.rejected.insert(pair(b, a));
        self.stats.rejections += 1;
        Ok(())
    }

    fn position(&self, v: u32) -> [f64; 3] {
        self.state(v).map(|s| s.position).unwrap_or([f64::NAN; 3])
    }

    /// Whether moving `v` onto `s` keeps every moving triangle's orientation (module docs).
    fn foldover_ok(&self, s: u32, v: u32) -> bool {
        let (Some(ss), Some(vs)) = (self.slot(s), self.slot(v)) else { return false };
        let target = self.verts[ss].state.position;
        self.verts[vs].tris.iter().all(|&t| {
            let corners = self.tris[t as usize].corners;
            if corners.contains(&s) {
                return true; // dies
            }
            let before = corners.map(|c| self.position(c));
            let after = std::array::from_fn(|k| if corners[k] == v { target } else { before[k] });
            triangle_survives(before, after)
        })
    }

    /// Collapses `v` onto `s` into a new node.
    fn collapse(
        &mut self,
        s: u32,
        v: u32,
        value: f64,
        store: &mut impl Store,
        bound: &mut Option<EdgeKey>,
    ) -> Result<()> {
        let (Some(ss), Some(vs)) = (self.slot(s), self.slot(v)) else {
            return Err(internal(format!("collapse ({s}, {v}) outside the region")));
        };
        if self.next_id == NONE {
            return Err(internal("more than 2^32 − 1 nodes".into()));
        }
        let p = self.next_id;
        self.next_id += 1;

        // Retire the edges of s and v (but (s, v) itself, already taken from the heap), and
        // gather the old 1-ring.
        let mut ring = std::mem::take(&mut self.ring);
        ring.clear();
        for (x, xs, other) in [(s, ss, v), (v, vs, s)] {
            self.neighbours(xs);
            let nbrs = std::mem::take(&mut self.nbrs);
            for &c in nbrs.iter().filter(|&&c| c != other) {
                ring.push(c);
                let loaded = self.is_loaded(c);
                if !loaded {
                    self.boundary = self.boundary.saturating_sub(1);
                }
                if self.rejected.remove(&pair(x, c)) {
                    self.rejected.remove(&pair(c, x));
                } else if loaded {
                    self.heap_live -= 1; // internal: its heap entry goes stale
                } else if !store.take_pending(self.key_of(x, c)?)? {
                    self.heap_live -= 1; // a renewed boundary edge, in the heap
                }
            }
            self.nbrs = nbrs;
        }
        ring.sort_unstable();
        ring.dedup();

        // Triangles: those holding both die at p, the others are renamed.
        let mut survivors = Vec::with_capacity(self.verts[ss].tris.len() + self.verts[vs].tris.len());
        let mut dying = std::mem::take(&mut self.dying);
        dying.clear();
        for (xs, x, other) in [(ss, s, v), (vs, v, s)] {
            for k in 0..self.verts[xs].tris.len() {
                let t = self.verts[xs].tris[k];
                let tri = &mut self.tris[t as usize];
                if tri.corners.contains(&other) {
                    if x == s {
                        dying.push((t, tri.id, tri.leaves));
                    }
                } else {
                    for c in tri.corners.iter_mut().filter(|c| **c == x) {
                        *c = p;
                    }
                    survivors.push(t);
                }
            }
        }
        for &(t, _, _) in &dying {
            let tri = self.tris[t as usize];
            if let Some(third) = tri.corners.iter().copied().find(|&c| c != s && c != v) {
                if let Some(cs) = self.slot(third).filter(|&cs| self.verts[cs].loaded) {
                    self.verts[cs].tris.retain(|&x| x != t);
                }
            }
            store.remove_triangle(tri.id)?;
            self.tri_index.remove(&tri.id);
            self.free_tris.push(t);
        }

        // The new node, in s's slot.
        let (st_s, st_v) = (self.verts[ss].state, self.verts[vs].state);
        let at = f32_position(st_s.position);
        let radius = (length(at, f32_position(st_s.position)) + st_s.radius)
            .max(length(at, f32_position(st_v.position)) + st_v.radius);
        let state = VertexState {
            position: st_s.position,
            quadric: add_quadrics(&st_s.quadric, &st_v.quadric),
            switch: value.max(st_s.switch).max(st_v.switch),
            radius: f32_up(radius) as f64,
            leaves: st_s.leaves + st_v.leaves,
        };
        self.free_vert_slot(vs);
        self.free_vert_slot(ss);
        self.list_bytes += cost::list(survivors.capacity());
        let ps = self.new_vert_slot(VertSlot { id: p, loaded: true, state, tris: survivors });
        self.loaded += 1;
        let root = self.find(s); // s and v are in one sub-mesh: their edge joined them
        self.union_find.insert(p, root);
        store.remove_vertex(s)?;
        store.remove_vertex(v)?;

        // p's edges are new; the 1-ring's rejected edges are examined again.
        self.neighbours(ps);
        let nbrs = std::mem::take(&mut self.nbrs);
        for &c in &nbrs {
            if !self.is_loaded(c) {
                self.boundary += 1;
            }
            let key = self.key_of(p, c)?;
            self.push(key);
        }
        self.nbrs = nbrs;
        let mut others = std::mem::take(&mut self.others);
        for &c in &ring {
            others.clear();
            others.extend(self.rejected.range(pair(c, 0)..=pair(c, u32::MAX)).map(|&k| k as u32));
            for &d in &others {
                self.rejected.remove(&pair(c, d));
                self.rejected.remove(&pair(d, c));
                let key = self.key_of(c, d)?;
                self.push(key);
            }
            if !self.is_loaded(c) {
                // c's rejected edges to vertices outside the region are in the store.
                others.clear();
                store.take_rejected(c, &mut others)?;
                for &d in &others {
                    let sd = match self.state(d) {
                        Some(sd) => *sd,
                        None => store.vertex_state(d)?,
                    };
                    let Some(sc) = self.state(c) else { continue };
                    let key = edge_key(collapse_options(self.metric, c, sc, d, &sd).0, c, d);
                    store.put_pending(key)?;
                    *bound = Some(bound.map_or(key, |m| m.min(key)));
                }
            }
        }
        self.others = others;
        self.ring = ring;

        dying.sort_unstable_by_key(|&(_, id, _)| id);
        let mut leaves = std::mem::take(&mut self.dying_leaves);
        leaves.clear();
        leaves.extend(dying.iter().map(|&(_, _, l)| l));
        let node = VdtNode {
            position: state.position.map(|c| c as f32),
            switch: state.switch as f32,
            radius: state.radius as f32,
            children: [s, v],
            parent: NONE,
            leaves: state.leaves,
            tri_start: 0,
            tri_count: leaves.len() as u32,
            reserved: 0,
        };
        store.emit(&node, &leaves)?;
        self.dying_leaves = leaves;
        self.dying = dying;
        self.stats.collapses += 1;
        Ok(())
    }

    /// Puts everything back into the store (pending edges, rejected edges, the loaded vertices'
    /// states and triangle lists, the live triangles) and empties the region, keeping its
    /// allocations for the next load.
    pub fn write_back(&mut self, store: &mut impl Store) -> Result<()> {
        for Reverse(key) in self.heap.drain() {
            let (a, b) = key_ends(key);
            if self.vert_index.contains_key(&a) && self.vert_index.contains_key(&b) {
                store.put_pending(key)?;
            }
        }
        for &k in &self.rejected {
            let (a, b) = ((k >> 32) as u32, k as u32);
            if a < b {
                store.put_rejected(a, b)?;
            }
        }
        let mut ids = Vec::new();
        for slot in self.verts.iter().filter(|s| s.loaded) {
            ids.clear();
            ids.extend(slot.tris.iter().map(|&t| self.tris[t as usize].id));
            store.put_vertex(slot.id, &slot.state, &ids)?;
        }
        for (&id, &t) in &self.tri_index {
            let tri = &self.tris[t as usize];
            store.put_triangle(id, tri.corners, tri.leaves)?;
        }
        self.verts.clear();
        self.free_verts.clear();
        self.vert_index.clear();
        self.tris.clear();
        self.free_tris.clear();
        self.tri_index.clear();
        self.heap_live = 0;
        self.boundary = 0;
        self.rejected.clear();
        self.union_find.clear();
        self.components = 0;
        self.list_bytes = 0;
        self.loaded = 0;
        Ok(())
    }
}

fn internal(problem: String) -> Error {
    Error::Internal { stage: "the VDT build", problem }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_order_by_value_then_ids() {
        let k = |v, a, b| edge_key(v, a, b);
        assert!(k(0.5, 9, 8) < k(1.0, 0, 1));
        assert!(k(1.0, 0, 5) < k(1.0, 1, 2));
        assert!(k(1.0, 1, 2) < k(1.0, 1, 3));
        assert!(k(0.0, 1, 2) > k(-1.0, 1, 2));
        assert!(k(f64::NAN, 1, 2) > k(1e300, 1, 2));
        assert_eq!(key_ends(k(3.0, 7, 4)), (4, 7));
        assert_eq!(key_value(k(3.25, 7, 4)), 3.25);
        assert_eq!(key_value(k(-2.5, 7, 4)), -2.5);
    }

    #[test]
    fn quadric_of_a_plane_measures_squared_distance() {
        let q = plane_quadric([0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]).unwrap();
        assert!((quadric_error(&q, [5.0, -3.0, 4.0]) - 9.0).abs() < 1e-12);
        assert!(plane_quadric([0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]).is_none());
    }

    #[test]
    fn foldover_test_refuses_flips_and_slivers() {
        let tri = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        assert!(triangle_survives(tri, [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.2, 0.9, 0.1]]));
        assert!(!triangle_survives(tri, [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]));
        assert!(!triangle_survives(tri, [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]));
    }
}
