//! The whole-mesh edge collapse: El-Sana & Chiang's spanned sub-mesh simplification (Eurographics
//! 2000, §3.1.2) when the budget holds the whole mesh, so that the one batch needs no disk store.
//! It is the reference order of [`super::simplify`] (shortest pending edge first, both directions'
//! foldover tests, rejected edges re-examined when their 1-ring changes) over dense arrays, and
//! writes the same bytes as the batched build at any budget (tested on the real meshes).
//!
//! Why a second implementation of one order: the batched [`super::simplify::Region`] keeps sparse
//! indices (ordered maps keyed by vertex id) because a batch holds a small, scattered part of the
//! mesh, and every load and write-back goes through the B-tree. With the whole mesh in memory those
//! indices are dense: a vertex's *slot* is the input vertex whose position it has (a half-edge
//! collapse keeps the survivor's position, so the new node takes the survivor's slot), triangle
//! corners are slots, and the priority queue is the initial edges sorted once (in parallel) merged
//! with a heap of the edges that collapses create.
//!
//! Memory: [`needed_bytes`] is what the arrays take at most; the caller compares it with the budget.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use rayon::prelude::*;

use super::simplify::{
    add_quadrics, edge_key, f32_up, key_ends, length, plane_quadric, quadric_error, triangle_survives, EdgeKey,
    Quadric, RegionStats,
};
use super::{VdtNode, VdtTriangle, NONE};
use crate::error::{Error, Result};
use crate::format::vdt::VdtMetric;
use crate::mesh::Mesh;

/// The forest of a whole-mesh build, ready to write as a VDT file.
pub struct Collapsed {
    /// Every node by id (leaves first), parents filled in.
    pub nodes: Vec<VdtNode>,
    /// The triangles that die, grouped by m(t) in increasing node id.
    pub dying: Vec<VdtTriangle>,
    /// The triangles that never die, by input triangle id.
    pub base: Vec<VdtTriangle>,
    pub stats: RegionStats,
}

/// An upper estimate of the memory [`collapse`] holds for a mesh of `vertices` and `triangles`
/// (the mesh itself included), bytes.
pub fn needed_bytes(vertices: u64, triangles: u64, metric: VdtMetric) -> u64 {
    let (n, t) = (vertices, triangles);
    // Edges: at most 3t/2 in a manifold mesh, 3t in any; the sorted array and, at most, as many
    // heap entries.
    let edges = 3 * t;
    let per_vertex = 24 // position (the mesh's)
        + 8 // slot of an id (2n ids), id of a slot
        + 20 // switch, radius, leaves
        + if metric == VdtMetric::Quadric { 80 } else { 0 }
        + 64 // triangle list, in place
        + 2 * 48; // node records (leaves and collapses)
    let per_triangle = 12 // the mesh's
        + 12 // current corners
        + 3 * 4 * 2 // list entries, with the lists' slack
        + 12; // the output record
              // Rejected edges: a map entry and list per rejected end (a few % of edges at most; all of
              // them counted).
    n * per_vertex + t * per_triangle + edges * 2 * 16 + edges * 16
}

/// The per-slot state of a current vertex.
struct Slots {
    id: Vec<u32>,
    switch: Vec<f64>,
    radius: Vec<f64>,
    leaves: Vec<u32>,
    /// Empty for the length metric.
    quadric: Vec<Quadric>,
    /// Live triangles (ids) holding the slot.
    tris: Lists,
    /// Rejected edges by slot: the other ends' slots. Few slots have any (about 1% of edges
    /// are ever rejected), and a dense array of lists cost a cache miss per 1-ring vertex.
    rejected: rustc_hash::FxHashMap<u32, Vec<u32>>,
}

struct Engine<'m> {
    metric: VdtMetric,
    positions: &'m [[f64; 3]],
    input: &'m [[u32; 3]],
    slots: Slots,
    /// The slot of each current vertex id; [`NONE`] once collapsed (or not yet created).
    slot_of: Vec<u32>,
    /// Whether each id is current, one bit each: the queue's staleness test, made for every key
    /// it meets, stays in the cache (`slot_of` does not, on a large mesh).
    alive: Vec<u64>,
    /// Current corners (slots) of each triangle; `[NONE; 3]` once it died.
    corners: Vec<[u32; 3]>,
    queue: Queue,
    next_id: u32,
    nodes: Vec<VdtNode>,
    dying_out: Vec<VdtTriangle>,
    stats: RegionStats,
    // Scratch, reused between collapses.
    nbrs: Vec<u32>,
    ring: Vec<u32>,
    dying: Vec<u32>,
    survivors: Vec<u32>,
    others: Vec<u32>,
}

/// Builds the forest of `mesh` in memory (module docs).
pub fn collapse(mesh: &Mesh, metric: VdtMetric, progress: &crate::sys::progress::Progress) -> Result<Collapsed> {
    let n = mesh.positions.len();
    let t = mesh.triangles.len();
    if n == 0 || n as u64 > (NONE as u64) / 2 || t as u64 >= NONE as u64 {
        return Err(Error::InvalidArgument(format!(
            "a VDT needs 1 to 2^31 vertices and fewer than 2^32 − 1 triangles; this mesh has {n} and {t}"
        )));
    }
    let mut engine = Engine::new(mesh, metric);
    let bar = progress.bar("vdt build", n.saturating_sub(1) as u64, "collapses");
    let mut steps = 0u64;
    while let Some(key) = engine.pop() {
        steps += 1;
        if steps.is_multiple_of(1 << 16) {
            crate::sys::cancel::check()?;
            bar.set_position(engine.stats.collapses);
        }
        engine.process(key)?;
    }
    bar.finish_and_clear();
    let out = engine.finish();
    Ok(out)
}

impl<'m> Engine<'m> {
    fn new(mesh: &'m Mesh, metric: VdtMetric) -> Self {
        let n = mesh.positions.len();
        let positions = &mesh.positions[..];
        let input = &mesh.triangles[..];
        // Vertex → triangle lists.
        let mut counts = vec![0u32; n];
        for tri in input {
            for &c in tri {
                counts[c as usize] += 1;
            }
        }
        let mut tris = Lists::new(n);
        for (v, &k) in counts.iter().enumerate() {
            tris.reserve(v as u32, k as usize);
        }
        drop(counts);
        for (k, tri) in input.iter().enumerate() {
            for &c in tri {
                tris.push(c, k as u32);
            }
        }
        let quadric: Vec<Quadric> = match metric {
            VdtMetric::Length => Vec::new(),
            VdtMetric::Quadric => (0..n as u32)
                .into_par_iter()
                .map(|v| tris.get(v))
                .map(|list| {
                    list.iter().fold([0.0; 10], |q, &k| {
                        let [a, b, c] = input[k as usize].map(|i| positions[i as usize]);
                        plane_quadric(a, b, c).map_or(q, |p| add_quadrics(&q, &p))
                    })
                })
                .collect(),
        };
        let mut engine = Engine {
            metric,
            positions,
            input,
            slots: Slots {
                id: (0..n as u32).collect(),
                switch: vec![0.0; n],
                radius: vec![0.0; n],
                leaves: vec![1; n],
                quadric,
                tris,
                rejected: Default::default(),
            },
            slot_of: Vec::with_capacity(2 * n),
            alive: vec![0; (2 * n).div_ceil(64)],
            corners: input.to_vec(),
            queue: Queue::default(),
            next_id: n as u32,
            nodes: Vec::with_capacity(2 * n),
            dying_out: Vec::with_capacity(input.len()),
            stats: RegionStats::default(),
            nbrs: Vec::new(),
            ring: Vec::new(),
            dying: Vec::new(),
            survivors: Vec::new(),
            others: Vec::new(),
        };
        engine.slot_of.extend(0..n as u32);
        for id in 0..n {
            engine.alive[id / 64] |= 1 << (id % 64);
        }
        // The initial edges (each once, from its smaller end), keyed and sorted in parallel.
        let this = &engine;
        let mut sorted: Vec<EdgeKey> = (0..n as u32)
            .into_par_iter()
            .fold(
                || (Vec::new(), Vec::new()),
                |(mut keys, mut nbrs): (Vec<EdgeKey>, Vec<u32>), v| {
                    this.neighbours_into(v, &mut nbrs);
                    for &c in nbrs.iter().filter(|&&c| c > v) {
                        keys.push(this.key(v, c));
                    }
                    (keys, nbrs)
                },
            )
            .map(|(keys, _)| keys)
            .flatten_iter()
            .collect();
        sorted.par_sort_unstable();
        engine.queue = Queue::new(sorted);
        // What the batched build reports for its one batch: every vertex with an edge is
        // loaded, and the sub-meshes are the components of the edge graph.
        let mut up: Vec<u32> = (0..n as u32).collect();
        fn find(up: &mut [u32], mut x: u32) -> u32 {
            while up[x as usize] != x {
                let g = up[up[x as usize] as usize];
                up[x as usize] = g;
                x = g;
            }
            x
        }
        for tri in input {
            for k in 1..3 {
                let (a, b) = (find(&mut up, tri[0]), find(&mut up, tri[k]));
                if a != b {
                    up[a.max(b) as usize] = a.min(b);
                }
            }
        }
        let with_edges = (0..n as u32).filter(|&v| !engine.slots.tris.get(v).is_empty()).count() as u64;
        let components =
            (0..n as u32).filter(|&v| !engine.slots.tris.get(v).is_empty() && find(&mut up, v) == v).count();
        engine.stats.loads = with_edges;
        engine.stats.sub_meshes = components as u64;
        engine
    }

    /// The smallest pending edge whose ends are both alive, taken out of the queue.
    fn pop(&mut self) -> Option<EdgeKey> {
        let alive = &self.alive;
        let key = self.queue.pop(|key| {
            let (x, y) = key_ends(key);
            (alive[x as usize / 64] >> (x % 64)) & (alive[y as usize / 64] >> (y % 64)) & 1 == 1
        })?;
        // The keys to come are known (a run is sorted), and what their collapses read is a
        // chain of dependent loads (slot, its triangle list, the triangles' corners, the
        // corners' positions and lists): each stage is fetched a few keys before the next
        // needs it, so the collapses do not wait on memory.
        let fetch = crate::sys::prefetch::<u8>;
        let slot = |id: u32| self.slot_of.get(id as usize).copied().filter(|&s| s != NONE);
        if let Some(ahead) = self.queue.ahead(16) {
            let (x, y) = key_ends(ahead);
            fetch(self.slot_of.as_ptr().wrapping_add(x as usize).cast());
            fetch(self.slot_of.as_ptr().wrapping_add(y as usize).cast());
        }
        if let Some(ahead) = self.queue.ahead(10) {
            let (x, y) = key_ends(ahead);
            for s in [x, y].into_iter().filter_map(slot) {
                fetch(self.slots.tris.inline.as_ptr().wrapping_add(s as usize).cast());
                fetch(self.slots.id.as_ptr().wrapping_add(s as usize).cast());
            }
        }
        if let Some(ahead) = self.queue.ahead(5) {
            let (x, y) = key_ends(ahead);
            for s in [x, y].into_iter().filter_map(slot) {
                for &t in self.slots.tris.get(s) {
                    fetch(self.corners.as_ptr().wrapping_add(t as usize).cast());
                }
            }
        }
        if let Some(ahead) = self.queue.ahead(2) {
            let (x, y) = key_ends(ahead);
            for s in [x, y].into_iter().filter_map(slot) {
                for &t in self.slots.tris.get(s) {
                    for c in self.corners.get(t as usize).map_or([NONE; 3], |c| *c) {
                        fetch(self.positions.as_ptr().wrapping_add(c as usize).cast());
                        fetch(self.slots.tris.inline.as_ptr().wrapping_add(c as usize).cast());
                        fetch(self.slots.id.as_ptr().wrapping_add(c as usize).cast());
                    }
                }
            }
        }
        Some(key)
    }

    /// The sorted, distinct other corners (slots) of slot `s`'s triangles.
    fn neighbours_into(&self, s: u32, out: &mut Vec<u32>) {
        out.clear();
        for &t in self.slots.tris.get(s) {
            out.extend(self.corners[t as usize].iter().copied().filter(|&c| c != s));
        }
        out.sort_unstable();
        out.dedup();
    }

    /// The key of the current edge between slots `a` and `b`.
    fn key(&self, a: u32, b: u32) -> EdgeKey {
        let (ia, ib) = (self.slots.id[a as usize], self.slots.id[b as usize]);
        edge_key(self.options(a, b).0, ia, ib)
    }

    /// [`super::simplify::collapse_options`] on slots: the key's value and the two directions
    /// `(survivor slot, victim slot, value)` in the order they are tried.
    fn options(&self, a: u32, b: u32) -> (f64, [(u32, u32, f64); 2]) {
        let (lo, hi) = if self.slots.id[a as usize] < self.slots.id[b as usize] { (a, b) } else { (b, a) };
        let (plo, phi) = (self.positions[lo as usize], self.positions[hi as usize]);
        match self.metric {
            VdtMetric::Length => {
                let len = length(plo, phi);
                (len, [(lo, hi, len), (hi, lo, len)])
            }
            VdtMetric::Quadric => {
                let q = add_quadrics(&self.slots.quadric[lo as usize], &self.slots.quadric[hi as usize]);
                let e_lo = quadric_error(&q, plo).max(0.0).sqrt();
                let e_hi = quadric_error(&q, phi).max(0.0).sqrt();
                if e_hi < e_lo {
                    (e_hi, [(hi, lo, e_hi), (lo, hi, e_lo)])
                } else {
                    (e_lo, [(lo, hi, e_lo), (hi, lo, e_hi)])
                }
            }
        }
    }

    /// Tries both directions of the pending edge `key`; rejects it if both fold over.
    fn process(&mut self, key: EdgeKey) -> Result<()> {
        let (a, b) = key_ends(key);
        let (sa, sb) = (self.slot_of[a as usize], self.slot_of[b as usize]);
        let (_, options) = self.options(sa, sb);
        for (s, v, value) in options {
            if self.foldover_ok(s, v) {
                return self.collapse(s, v, value);
            }
        }
        self.slots.rejected.entry(sa).or_default().push(sb);
        self.slots.rejected.entry(sb).or_default().push(sa);
        self.stats.rejections += 1;
        Ok(())
    }

    /// Whether moving slot `v` onto slot `s` keeps every moving triangle's orientation.
    fn foldover_ok(&self, s: u32, v: u32) -> bool {
        let target = self.positions[s as usize];
        self.slots.tris.get(v).iter().all(|&t| {
            let corners = self.corners[t as usize];
            if corners.contains(&s) {
                return true; // dies
            }
            let before = corners.map(|c| self.positions[c as usize]);
            let after = std::array::from_fn(|k| if corners[k] == v { target } else { before[k] });
            triangle_survives(before, after)
        })
    }

    /// Removes `x` from slot `d`'s rejected list.
    fn unreject(&mut self, d: u32, x: u32) {
        if let Some(list) = self.slots.rejected.get_mut(&d) {
            list.retain(|&y| y != x);
            if list.is_empty() {
                self.slots.rejected.remove(&d);
            }
        }
    }

    /// Collapses slot `v` onto slot `s` into a new node, which takes `s`'s slot.
    fn collapse(&mut self, s: u32, v: u32, value: f64) -> Result<()> {
        if self.next_id == NONE {
            return Err(Error::Internal { stage: "the VDT build", problem: "more than 2^32 − 1 nodes".into() });
        }
        let p = self.next_id;
        self.next_id += 1;
        let (su, vu) = (s as usize, v as usize);

        // The old 1-ring; the rejected edges of s and v go (their ends are collapsing).
        let mut ring = std::mem::take(&mut self.ring);
        let mut nbrs = std::mem::take(&mut self.nbrs);
        ring.clear();
        for (x, other) in [(s, v), (v, s)] {
            self.neighbours_into(x, &mut nbrs);
            ring.extend(nbrs.iter().copied().filter(|&c| c != other));
            for c in self.slots.rejected.remove(&x).unwrap_or_default() {
                self.unreject(c, x);
            }
        }
        ring.sort_unstable();
        ring.dedup();

        // Triangles holding both die at p; v's others are renamed to s's slot (p's).
        let mut dying = std::mem::take(&mut self.dying);
        let mut survivors = std::mem::take(&mut self.survivors);
        dying.clear();
        survivors.clear();
        for &t in self.slots.tris.get(s) {
            if self.corners[t as usize].contains(&v) {
                dying.push(t);
            } else {
                survivors.push(t);
            }
        }
        for &t in self.slots.tris.get(v) {
            let corners = &mut self.corners[t as usize];
            if !corners.contains(&s) {
                for c in corners.iter_mut().filter(|c| **c == v) {
                    *c = s;
                }
                survivors.push(t);
            }
        }
        for &t in &dying {
            let corners = self.corners[t as usize];
            if let Some(third) = corners.iter().copied().find(|&c| c != s && c != v) {
                self.slots.tris.remove(third, t);
            }
            self.corners[t as usize] = [NONE; 3];
        }
        self.slots.tris.set(s, &survivors);
        self.slots.tris.set(v, &[]);

        // The new node's state, in s's slot (the same arithmetic as the batched build).
        let f32_at = |p: [f64; 3]| p.map(|c| c as f32 as f64);
        let at = f32_at(self.positions[su]);
        let radius = (length(at, f32_at(self.positions[su])) + self.slots.radius[su])
            .max(length(at, f32_at(self.positions[vu])) + self.slots.radius[vu]);
        let switch = value.max(self.slots.switch[su]).max(self.slots.switch[vu]);
        let leaves = self.slots.leaves[su] + self.slots.leaves[vu];
        let (ids, idv) = (self.slots.id[su], self.slots.id[vu]);
        self.slots.switch[su] = switch;
        self.slots.radius[su] = f32_up(radius) as f64;
        self.slots.leaves[su] = leaves;
        if self.metric == VdtMetric::Quadric {
            self.slots.quadric[su] = add_quadrics(&self.slots.quadric[su], &self.slots.quadric[vu]);
        }
        self.slots.id[su] = p;
        self.slots.id[vu] = NONE;
        self.slot_of[ids as usize] = NONE;
        self.slot_of[idv as usize] = NONE;
        self.slot_of.push(s);
        for (id, on) in [(ids, false), (idv, false), (p, true)] {
            let (word, bit) = (id as usize / 64, 1u64 << (id % 64));
            if on {
                self.alive[word] |= bit;
            } else {
                self.alive[word] &= !bit;
            }
        }

        // p's edges are new; the 1-ring's rejected edges are examined again.
        self.neighbours_into(s, &mut nbrs);
        for &c in &nbrs {
            let key = self.key(s, c);
            self.queue.push(key);
        }
        let mut others = std::mem::take(&mut self.others);
        for &c in &ring {
            let Some(mut list) = self.slots.rejected.remove(&c) else { continue };
            others.clear();
            others.append(&mut list);
            for &d in &others {
                self.unreject(d, c);
                let key = self.key(c, d);
                self.queue.push(key);
            }
        }
        self.others = others;
        self.ring = ring;
        self.nbrs = nbrs;

        dying.sort_unstable();
        let tri_start = self.dying_out.len() as u32;
        self.dying_out.extend(dying.iter().map(|&t| VdtTriangle { corners: self.input[t as usize] }));
        self.nodes.push(VdtNode {
            position: self.positions[su].map(|c| c as f32),
            switch: switch as f32,
            radius: self.slots.radius[su] as f32,
            children: [ids, idv],
            parent: NONE,
            leaves,
            tri_start,
            tri_count: dying.len() as u32,
            reserved: 0,
        });
        self.dying = dying;
        self.survivors = survivors;
        self.stats.collapses += 1;
        Ok(())
    }

    fn finish(self) -> Collapsed {
        let n = self.positions.len();
        let mut nodes: Vec<VdtNode> = Vec::with_capacity(n + self.nodes.len());
        nodes.extend(self.positions.iter().map(|p| VdtNode {
            position: p.map(|c| c as f32),
            children: [NONE, NONE],
            parent: NONE,
            leaves: 1,
            ..VdtNode::default()
        }));
        nodes.extend_from_slice(&self.nodes);
        for id in n..nodes.len() {
            for c in nodes[id].children {
                nodes[c as usize].parent = id as u32;
            }
        }
        let base = self
            .corners
            .iter()
            .zip(self.input)
            .filter(|(c, _)| c[0] != NONE)
            .map(|(_, &corners)| VdtTriangle { corners })
            .collect();
        Collapsed { nodes, dying: self.dying_out, base, stats: self.stats }
    }
}

/// Triangles a slot's list holds in place (one cache line with its length).
const INLINE: usize = 15;

/// The slots' triangle lists: up to [`INLINE`] ids in place, so that reading a list is one
/// cache line and changing it allocates nothing; longer lists (vertices of high valence, few)
/// live in a map.
struct Lists {
    inline: Vec<Inline>,
    long: rustc_hash::FxHashMap<u32, Vec<u32>>,
}

#[derive(Clone, Copy)]
#[repr(C, align(64))]
struct Inline {
    len: u32,
    ids: [u32; INLINE],
}

impl Lists {
    fn new(n: usize) -> Lists {
        Lists { inline: vec![Inline { len: 0, ids: [0; INLINE] }; n], long: Default::default() }
    }

    fn get(&self, s: u32) -> &[u32] {
        let l = &self.inline[s as usize];
        if l.len as usize <= INLINE {
            &l.ids[..l.len as usize]
        } else {
            self.long.get(&s).map_or(&[], |v| v.as_slice())
        }
    }

    /// Makes room for `k` ids in an empty list.
    fn reserve(&mut self, s: u32, k: usize) {
        if k > INLINE {
            self.long.insert(s, Vec::with_capacity(k));
        }
    }

    fn push(&mut self, s: u32, t: u32) {
        let l = &mut self.inline[s as usize];
        let len = l.len as usize;
        if len < INLINE && !self.long.contains_key(&s) {
            l.ids[len] = t;
            l.len += 1;
            return;
        }
        let long = self.long.entry(s).or_default();
        if len == INLINE && long.is_empty() {
            long.extend_from_slice(&l.ids);
        }
        long.push(t);
        l.len = long.len() as u32;
    }

    fn set(&mut self, s: u32, ids: &[u32]) {
        let l = &mut self.inline[s as usize];
        if ids.len() <= INLINE {
            l.ids[..ids.len()].copy_from_slice(ids);
            if l.len as usize > INLINE {
                self.long.remove(&s);
            }
        } else {
            let long = self.long.entry(s).or_default();
            long.clear();
            long.extend_from_slice(ids);
        }
        l.len = ids.len() as u32;
    }

    /// Removes `t` from slot `s`'s list (keeping the order of the others).
    fn remove(&mut self, s: u32, t: u32) {
        let mut ids: [u32; INLINE + 1] = [0; INLINE + 1];
        let list = self.get(s);
        if list.len() <= INLINE + 1 {
            let mut k = 0;
            for &x in list.iter().filter(|&&x| x != t) {
                ids[k] = x;
                k += 1;
            }
            self.set(s, &ids[..k]);
        } else if let Some(long) = self.long.get_mut(&s) {
            long.retain(|&x| x != t);
            self.inline[s as usize].len = long.len() as u32;
        }
    }
}

/// Keys a run holds ahead of its cursor below the queue's limit (see [`Queue`]).
const WINDOW: usize = 1 << 18;
/// Sorted runs kept before the two shortest are merged.
const MAX_RUNS: usize = 8;

/// The pending edges in key order, for a front that mostly moves up: the collapses' new edges
/// are mostly longer than the edge just taken. A binary heap of every pending edge (tens of
/// millions) spends its time in cache misses; here keys at most `limit` go to a small heap
/// (`near`), larger ones are appended to `fresh`, which is sorted into a new run only when the
/// front reaches `limit`. The smallest key is the least of `near`'s top and the runs' heads, and
/// it is taken only while no fresh key can be smaller (it is at most `limit`, or `fresh` is
/// empty), so the order is exact whatever `limit` is; `limit` only trades heap size against
/// sorting. Stale keys (an end collapsed) are dropped when met and before each sort.
#[derive(Default)]
struct Queue {
    runs: Vec<Run>,
    /// The run the last key came from (None: `near`).
    last: Option<usize>,
    near: BinaryHeap<Reverse<EdgeKey>>,
    fresh: Vec<EdgeKey>,
    limit: EdgeKey,
}

#[derive(Default)]
struct Run {
    keys: Vec<EdgeKey>,
    at: usize,
}

impl Run {
    fn head(&self) -> Option<EdgeKey> {
        self.keys.get(self.at).copied()
    }
}

impl Queue {
    fn new(sorted: Vec<EdgeKey>) -> Queue {
        let mut q = Queue { runs: vec![Run { keys: sorted, at: 0 }], ..Queue::default() };
        q.set_limit();
        q
    }

    fn push(&mut self, key: EdgeKey) {
        if key <= self.limit {
            self.near.push(Reverse(key));
        } else {
            self.fresh.push(key);
        }
    }

    /// Removes and returns the smallest key for which `live` holds.
    fn pop(&mut self, live: impl Fn(EdgeKey) -> bool) -> Option<EdgeKey> {
        loop {
            // The least head: `near` (None) or a run's index.
            let mut best: Option<(EdgeKey, Option<usize>)> = self.near.peek().map(|r| (r.0, None));
            for (k, run) in self.runs.iter().enumerate() {
                if let Some(h) = run.head() {
                    if best.is_none_or(|(b, _)| h < b) {
                        best = Some((h, Some(k)));
                    }
                }
            }
            let key = match best {
                Some((key, _)) if key > self.limit && !self.fresh.is_empty() => None,
                None if !self.fresh.is_empty() => None,
                None => return None,
                Some((key, _)) => Some(key),
            };
            let Some(key) = key else {
                self.flush(&live);
                continue;
            };
            self.last = best.and_then(|(_, from)| from);
            match self.last {
                Some(k) => self.runs[k].at += 1,
                None => {
                    self.near.pop();
                }
            }
            if live(key) {
                return Some(key);
            }
        }
    }

    /// The key `d` places after the last one taken in its run, if it came from a run.
    fn ahead(&self, d: usize) -> Option<EdgeKey> {
        let run = self.runs.get(self.last?)?;
        run.keys.get(run.at + d - 1).copied()
    }

    /// Sorts `fresh` into a run, drops spent runs, merges the two shortest while there are too
    /// many, and moves `limit` ahead.
    fn flush(&mut self, live: &impl Fn(EdgeKey) -> bool) {
        let mut fresh = std::mem::take(&mut self.fresh);
        fresh.retain(|&k| live(k));
        if fresh.len() > 1 << 16 {
            fresh.par_sort_unstable();
        } else {
            fresh.sort_unstable();
        }
        if !fresh.is_empty() {
            self.runs.push(Run { keys: fresh, at: 0 });
        }
        self.runs.retain(|r| r.at < r.keys.len());
        self.last = None;
        while self.runs.len() > MAX_RUNS {
            self.runs.sort_by_key(|r| Reverse(r.keys.len() - r.at));
            let (Some(a), Some(b)) = (self.runs.pop(), self.runs.pop()) else { break };
            self.runs.push(merge(&a.keys[a.at..], &b.keys[b.at..], live));
        }
        self.set_limit();
    }

    /// The least of the runs' keys `WINDOW` ahead of their cursors (or their last keys).
    fn set_limit(&mut self) {
        self.limit = self
            .runs
            .iter()
            .filter_map(|r| r.keys.get((r.at + WINDOW).min(r.keys.len().saturating_sub(1))).copied())
            .min()
            .unwrap_or(EdgeKey::MAX);
    }
}

/// The live keys of two sorted runs, merged.
fn merge(a: &[EdgeKey], b: &[EdgeKey], live: &impl Fn(EdgeKey) -> bool) -> Run {
    let mut keys = Vec::with_capacity(a.len() + b.len());
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        let k = if a[i] < b[j] {
            i += 1;
            a[i - 1]
        } else {
            j += 1;
            b[j - 1]
        };
        if live(k) {
            keys.push(k);
        }
    }
    keys.extend(a[i..].iter().chain(&b[j..]).copied().filter(|&k| live(k)));
    Run { keys, at: 0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The queue pops exactly what a binary heap pops, under pushes below, inside and above
    /// its window, with stale keys dropped.
    #[test]
    fn queue_pops_in_the_order_of_a_heap() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut rand = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let dead = |k: EdgeKey| k % 7 == 3;
        let mut initial: Vec<EdgeKey> =
            (0..3 * WINDOW as u64).map(|_| (rand() % 1_000_000) as EdgeKey * 1000).collect();
        initial.sort_unstable();
        initial.dedup();
        let mut reference: BinaryHeap<Reverse<EdgeKey>> = initial.iter().map(|&k| Reverse(k)).collect();
        let mut q = Queue::new(initial);
        let mut popped = 0u64;
        let mut next_unique = 1u128;
        loop {
            let want = loop {
                match reference.pop() {
                    Some(Reverse(k)) if dead(k) => continue,
                    other => break other.map(|r| r.0),
                }
            };
            let got = q.pop(|k| !dead(k));
            assert_eq!(got, want, "pop {popped}");
            let Some(k) = got else { break };
            popped += 1;
            // New keys around the front: mostly above, some below it, unique.
            for _ in 0..(rand() % 4) {
                let spread = (rand() % 2_000_000) as i128 - 200_000;
                let base = (k as i128 / 1000 + spread).max(0) as u128;
                let key = base * 1000 + next_unique % 1000;
                next_unique += 1;
                if popped < 2_000_000 {
                    q.push(key);
                    reference.push(Reverse(key));
                }
            }
        }
        assert!(popped > 3 * WINDOW as u64);
    }
}
