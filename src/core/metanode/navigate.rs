//! Run-time navigation of meta-node trees (El-Sana & Chiang 2000, §3.3; implicit dependencies
//! from El-Sana & Varshney 1999): the active nodes (a cut through the forest) and the active
//! triangles, adapted each frame by splits and collapses against the switch values, with the data
//! coming from a [`MetaStore`]: [`PagedStore`], the meta-node file's pager with any access (the
//! plain map, "Virt"; positioned reads; or the buffer pool with its I/O thread, "Ext").
//!
//! - **Active nodes** are kept by their first leaf's DFS number (`dfs_lo`). The cut partitions the
//!   leaves into intervals, so the active node holding leaf d is the one with the greatest key
//!   ≤ d: a triangle's current corner is found from its leaf without touching the tree.
//! - **Active triangles** keep their corner leaves, their current corners and positions; each
//!   active node lists its adjacent triangles. A split renames p's corners to whichever child
//!   covers the corner's leaf and adds the triangles in p's list (m(t) = p); a collapse removes
//!   those and renames back.
//! - **Switching**: node v is wanted split iff its sphere is in the view frustum and
//!   (κ·switch + radius)² > ‖position − eye‖², κ = w / (2 τ tan(φ/2)) as for the terrain. Switch
//!   values and radii are nested, so a parent is wanted whenever a child is.
//! - **Implicit dependencies** (ids grow with each collapse): split p only if p's id exceeds every
//!   neighbour's; collapse (a, b) into p only if every neighbour of a or b has a parent with an id
//!   above p's. Together they keep every pair of adjacent active nodes alive at a common moment of
//!   the construction, so each split or collapse sees the neighbourhood the builder checked.
//! - **Misses**: a split whose children's meta-node, or a collapse whose parent's meta-node, is
//!   not in memory is abandoned for this frame and counted, and an urgent prefetch is sent.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use glam::DVec3;
use serde::Serialize;

use super::NONE;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::format::metanode::{parse_block, BlockView, MetaNodeFile, MnNode, MntEntry};
use crate::format::{self, FileKind};
use crate::lod::metric::Isotropic;
use crate::lod::Lod;
use crate::pager::pool::{Direction, Urgent};

/// Where meta-nodes come from. `with_block` gives `None` when the block is not in memory (a
/// miss for the caller); the counting calls are the buffer pool's protocol and no-ops elsewhere.
pub trait MetaStore {
    fn with_block<R>(&mut self, meta: u32, f: impl FnOnce(BlockView<'_>) -> R) -> Result<Option<R>>;
    /// Makes the block resident before navigation starts (root meta-nodes), waiting if needed,
    /// and raises its usage count by one (the caller drops that hold with `use_block(m, -1)`
    /// once it has pinned what it uses).
    fn load_now(&mut self, meta: u32) -> Result<()>;
    /// Usage count: active nodes in the block. The navigator raises it *before* reading a block
    /// it will activate nodes from, so the block cannot be recycled in between; `false` means
    /// the block is not in memory (nothing changed).
    fn use_block(&mut self, _meta: u32, _delta: i32) -> bool {
        true
    }
    /// Reference count: active parent or child meta-nodes (speculative prefetch).
    fn reference(&mut self, _meta: u32, _delta: i32) {}
    /// An urgent prefetch for a wanted split (`up = false`) or collapse (`up = true`).
    fn request_urgent(&mut self, _meta: u32, _up: bool) {}
    /// Called once at the end of every update.
    fn end_frame(&mut self) {}
    /// Pages read from disk so far.
    fn pages_read(&self) -> u64;
    fn second_chance_hits(&self) -> u64 {
        0
    }
}

/// An inconsistency in a meta-node file's blocks found while navigating, naming the file.
fn corrupt(path: &Path, problem: String) -> Error {
    format::corrupt(path, FileKind::MetaNode, problem)
}

/// Whether `child` records `parent` (at `parent_pos`) as its parent, and the parent sits at the
/// first child's position (`first_pos`): id, switch value, radius and position bit for bit.
fn is_parent_of(parent: &MnNode, parent_pos: [f32; 3], child: &MnNode, first_pos: [f32; 3]) -> bool {
    child.parent_id == parent.id
        && child.parent_switch.to_bits() == parent.switch.to_bits()
        && child.parent_radius.to_bits() == parent.radius.to_bits()
        && parent_pos.map(f32::to_bits) == first_pos.map(f32::to_bits)
}

/// What one frame did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct AdaptStats {
    pub splits: u64,
    pub collapses: u64,
    /// Nodes whose wanted split or collapse was abandoned because the meta-node it needed was
    /// not in memory (once per node and frame).
    pub misses: u64,
    /// Wanted splits or collapses refused by the implicit dependencies (not misses).
    pub blocked: u64,
    pub triangles: u64,
    pub active_nodes: u64,
}

#[derive(Clone, Debug)]
struct Active {
    node: MnNode,
    meta: u32,
    /// Index in its meta-node's block.
    local: u16,
    position: [f32; 3],
    /// Active triangles with this node as a corner (slots).
    adj: Vec<u32>,
}

#[derive(Clone, Copy, Debug)]
struct Tri {
    /// Corner leaves (DFS numbers), fixed.
    leaves: [u32; 3],
    /// Current corners: active nodes' keys.
    corners: [u32; 3],
    positions: [[f32; 3]; 3],
}

/// Which meta-nodes the navigator references (the buffer pool prefetches a referenced block
/// and keeps it off the free list while referenced).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Prefetch {
    /// The paper's (§3.3.3): every meta-node in use references its parent and all its children.
    /// A block of L levels can have up to 2^L child blocks, so with a pool smaller than their
    /// sum the prefetches evict one another (BENCHMARKS.md, "Meta-node trees").
    #[default]
    Paper,
    /// Only the parent of each meta-node in use.
    Parent,
    /// Per active node: the block of its children and the block of its parent when they are not
    /// its own, i.e. exactly the blocks its next split or its parent's collapse would read. At
    /// most two references per active node, so the prefetch grows with the front, not the tree.
    Frontier,
}

/// Navigation options.
#[derive(Clone, Copy, Debug, Default)]
pub struct NavOptions {
    /// Compare the normal of every triangle a split or collapse moves, before and after; flips
    /// are counted in [`Navigator::foldovers`] (costs time; for tests).
    pub check_foldover: bool,
    pub prefetch: Prefetch,
}

/// The navigator: active nodes and triangles over a [`MetaStore`].
pub struct Navigator<S: MetaStore> {
    store: S,
    /// The meta-node file, named by errors about its content.
    path: PathBuf,
    mnt: Vec<MntEntry>,
    active: BTreeMap<u32, Active>,
    usage: HashMap<u32, u32>,
    tris: Vec<Tri>,
    live: Vec<bool>,
    free: Vec<u32>,
    /// For each split node (by id), the triangle slots its split created.
    created: HashMap<u32, Vec<u32>>,
    soup: Vec<[f32; 3]>,
    /// Nodes split by force this frame (by id): not collapsed again in the same frame, or a
    /// forced split and the collapse of its unwanted children would alternate.
    forced: std::collections::HashSet<u32>,
    /// Nodes whose wanted switch missed this frame: a miss is counted once per node and frame,
    /// however often the worklist comes back to it.
    missed: std::collections::HashSet<u32>,
    options: NavOptions,
    foldovers: u64,
    worklist: Vec<u32>,
    /// The largest coordinate of the mesh's box, for the rounding slack.
    scale: f64,
}

impl<S: MetaStore> Navigator<S> {
    /// Starts at the coarsest level: every root active, the base triangles over them.
    pub fn new(file: &MetaNodeFile, store: S, options: NavOptions) -> Result<Navigator<S>> {
        let roots = file.header().root_metanodes as u32;
        let mut nav = Navigator {
            store,
            path: file.path().to_path_buf(),
            mnt: file.mnt().to_vec(),
            active: BTreeMap::new(),
            usage: HashMap::new(),
            tris: Vec::new(),
            live: Vec::new(),
            free: Vec::new(),
            created: HashMap::new(),
            soup: Vec::new(),
            forced: std::collections::HashSet::new(),
            missed: std::collections::HashSet::new(),
            options,
            foldovers: 0,
            worklist: Vec::new(),
            scale: {
                let b = file.header().bounds;
                b.min.iter().chain(&b.max).map(|c| c.abs()).filter(|c| c.is_finite()).fold(1.0, f64::max)
            },
        };
        for m in 0..roots {
            // Load and pin each root meta-node before the next load can recycle a holder.
            nav.store.load_now(m)?;
            let root_count =
                nav.store.with_block(m, |view| view.nodes.iter().filter(|v| v.is_root()).count())?.unwrap_or(0);
            for _ in 0..root_count {
                nav.store.use_block(m, 1);
            }
            nav.store.use_block(m, -1); // load_now's hold
            let found = nav.store.with_block(m, |view| {
                view.nodes
                    .iter()
                    .enumerate()
                    .filter(|(_, v)| v.is_root())
                    .map(|(local, v)| (*v, local as u16, view.position(v)))
                    .collect::<Vec<_>>()
            })?;
            let Some(found) = found else {
                return Err(Error::InvalidArgument(format!(
                    "root meta-node {m} could not be loaded: too little memory"
                )));
            };
            for (node, local, position) in found {
                nav.activate(node, m, local, position, Vec::new());
            }
        }
        let leaves = file.header().leaves as u32;
        // The roots' leaf intervals must partition 0..leaves: the cut's keys are looked up by it.
        let mut end = 0u64;
        for (&key, a) in &nav.active {
            if key as u64 != end {
                return Err(corrupt(&nav.path, "the roots do not partition the leaves".into()));
            }
            end += a.node.leaves as u64;
        }
        if end != leaves as u64 || nav.active.len() != nav.usage.values().map(|&u| u as usize).sum::<usize>() {
            return Err(corrupt(file.path(), "the roots do not cover every leaf".into()));
        }
        for t in file.base_triangles() {
            if t.iter().any(|&d| d >= leaves) {
                return Err(corrupt(file.path(), "base triangle corner out of range".into()));
            }
            nav.add_triangle(*t);
        }
        nav.rebuild_soup();
        Ok(nav)
    }

    pub fn store(&self) -> &S {
        &self.store
    }

    pub fn store_mut(&mut self) -> &mut S {
        &mut self.store
    }

    /// The current triangles, three world positions each.
    pub fn triangles(&self) -> &[[f32; 3]] {
        &self.soup
    }

    pub fn triangle_count(&self) -> usize {
        self.soup.len() / 3
    }

    pub fn active_nodes(&self) -> usize {
        self.active.len()
    }

    /// Triangle flips seen by [`NavOptions::check_foldover`].
    pub fn foldovers(&self) -> u64 {
        self.foldovers
    }

    /// Adapts the active nodes to `camera` at `tolerance_px`: every active node is tested, and
    /// new nodes are tested in turn, so with all data in memory one call reaches the cut the
    /// view asks for.
    pub fn update(&mut self, camera: &Camera, tolerance_px: f64) -> Result<AdaptStats> {
        let scale = self.scale.max(camera.eye_in_world.abs().max_element());
        let view = View { lod: Lod::new(camera, tolerance_px, Isotropic), margin: crate::lod::margin_for_scale(scale) };
        let mut stats = AdaptStats::default();
        self.forced.clear();
        self.missed.clear();
        self.worklist.clear();
        self.worklist.extend(self.active.keys().rev());
        while let Some(key) = self.worklist.pop() {
            let Some(a) = self.active.get(&key) else { continue };
            let node = a.node;
            if !node.is_leaf() && view.wants(node.id, a.position, node.switch, node.radius) {
                match self.try_split(key)? {
                    Outcome::Done => {
                        stats.splits += 1;
                        self.push_split(key);
                    }
                    Outcome::Miss => stats.misses += self.missed.insert(key) as u64,
                    Outcome::Blocked(blocker) => {
                        stats.blocked += 1;
                        // Force the older-blocking neighbour to split (it may not want to, e.g.
                        // outside the view), then try again: without this, refinement stalls
                        // wherever a coarse unwanted node borders the wanted region.
                        if let Some(b) = blocker {
                            if self.force_split(b, FORCE_DEPTH, &mut stats)? {
                                self.worklist.push(key);
                            }
                        }
                    }
                }
            } else if !node.is_root() {
                let Some((first, second)) = self.sibling_pair(key) else { continue };
                let position = self.active[&first].position;
                if self.forced.contains(&node.parent_id)
                    || view.wants(node.parent_id, position, node.parent_switch, node.parent_radius)
                {
                    continue;
                }
                match self.try_collapse(first, second)? {
                    Outcome::Done => {
                        stats.collapses += 1;
                        self.push_around(first);
                    }
                    Outcome::Miss => stats.misses += self.missed.insert(first) as u64,
                    Outcome::Blocked(_) => stats.blocked += 1,
                }
            }
        }
        self.store.end_frame();
        self.rebuild_soup();
        stats.triangles = self.triangle_count() as u64;
        stats.active_nodes = self.active.len() as u64;
        Ok(stats)
    }

    /// Splits the node at `key` whether or not the view wants it, first forcing the neighbours
    /// that block it (up to `depth` deep). Whether it split.
    fn force_split(&mut self, key: u32, depth: u32, stats: &mut AdaptStats) -> Result<bool> {
        if self.active.get(&key).is_none_or(|a| a.node.is_leaf()) {
            return Ok(false);
        }
        for _ in 0..4 {
            let id = self.active[&key].node.id;
            match self.try_split(key)? {
                Outcome::Done => {
                    stats.splits += 1;
                    self.forced.insert(id);
                    self.push_split(key);
                    return Ok(true);
                }
                Outcome::Miss => {
                    stats.misses += self.missed.insert(key) as u64;
                    return Ok(false);
                }
                Outcome::Blocked(Some(b)) if depth > 0 => {
                    stats.blocked += 1;
                    if !self.force_split(b, depth - 1, stats)? {
                        return Ok(false);
                    }
                }
                Outcome::Blocked(_) => {
                    stats.blocked += 1;
                    return Ok(false);
                }
            }
        }
        Ok(false)
    }

    /// After the split of the node at `key`: queues both children, and the neighbours a
    /// dependency may have held back.
    fn push_split(&mut self, key: u32) {
        let second = key + self.active[&key].node.leaves;
        self.push_around(key);
        self.push_around(second);
    }

    /// Queues the node at `key` and its neighbours for another test.
    fn push_around(&mut self, key: u32) {
        self.worklist.push(key);
        let a = &self.active[&key];
        for &t in &a.adj {
            for &c in &self.tris[t as usize].corners {
                if c != key {
                    self.worklist.push(c);
                }
            }
        }
    }

    /// The keys of `key`'s node and its sibling, first child first, if both are active.
    fn sibling_pair(&self, key: u32) -> Option<(u32, u32)> {
        let a = &self.active[&key];
        let parent = a.node.parent_id;
        if let Some(b) = self.active.get(&(key + a.node.leaves)) {
            if b.node.parent_id == parent {
                return Some((key, key + a.node.leaves));
            }
        }
        let (&k, b) = self.active.range(..key).next_back()?;
        (b.node.parent_id == parent && k + b.node.leaves == key).then_some((k, key))
    }

    fn try_split(&mut self, key: u32) -> Result<Outcome> {
        let p = &self.active[&key];
        let (pnode, pmeta, plocal, ppos) = (p.node, p.meta, p.local as usize, p.position);
        // Implicit dependency: every neighbour is older than p.
        for &t in &p.adj {
            for &c in &self.tris[t as usize].corners {
                if c != key && self.active[&c].node.id > pnode.id {
                    return Ok(Outcome::Blocked(Some(c)));
                }
            }
        }
        // Pin the children's blocks first (their usage counts), then read them.
        for k in 0..2 {
            if !self.store.use_block(pnode.child_meta[k], 1) {
                if k == 1 {
                    self.store.use_block(pnode.child_meta[0], -1);
                }
                self.store.request_urgent(pnode.child_meta[k], false);
                return Ok(Outcome::Miss);
            }
        }
        let mut children = [(MnNode::default(), [0f32; 3]); 2];
        for (k, child) in children.iter_mut().enumerate() {
            let (m, local) = (pnode.child_meta[k], pnode.child_local[k] as usize);
            let got = self.store.with_block(m, |view| view.nodes.get(local).map(|c| (*c, view.position(c))))?;
            match got {
                Some(Some(c)) => *child = c,
                _ => {
                    return Err(Error::Internal {
                        stage: "meta-node navigation",
                        problem: format!("meta-node {m}: child {local} of node {} missing", pnode.id),
                    })
                }
            }
        }
        let created =
            self.store.with_block(pmeta, |view| view.nodes.get(plocal).map(|v| view.triangles_of(v).to_vec()))?;
        let Some(Some(created)) = created else {
            return Err(Error::Internal {
                stage: "meta-node navigation",
                problem: format!("meta-node {pmeta} of active node {} is not in memory", pnode.id),
            });
        };
        let [(a, a_pos), (b, b_pos)] = children;
        if a.dfs_lo != pnode.dfs_lo
            || b.dfs_lo as u64 != pnode.dfs_lo as u64 + a.leaves as u64
            || a.leaves as u64 + b.leaves as u64 != pnode.leaves as u64
        {
            return Err(corrupt(&self.path, format!("node {}: children do not split its leaves", pnode.id)));
        }
        // The children's copies of the parent (collapse decides on them) must be the parent's own
        // values, or a split and the collapse undoing it could both be wanted and alternate forever.
        if !is_parent_of(&pnode, ppos, &a, a_pos) || !is_parent_of(&pnode, ppos, &b, a_pos) {
            return Err(corrupt(&self.path, format!("node {}: its children's copies of it differ from it", pnode.id)));
        }
        // The triangles the split creates bring a third corner that need not be p's neighbour
        // yet: it too must be older than p. (Also asking it to be younger than p's children's
        // parents would keep the invariant checked in `check` by construction, but deadlocks:
        // two such nodes can each wait for the other.)
        for leaves in &created {
            for &d in leaves {
                if pnode.covers(d) {
                    continue;
                }
                let Some((&xkey, x)) = self.active.range(..=d).next_back() else { continue };
                if x.node.id > pnode.id {
                    self.store.use_block(pnode.child_meta[0], -1);
                    self.store.use_block(pnode.child_meta[1], -1);
                    return Ok(Outcome::Blocked(Some(xkey)));
                }
            }
        }
        let p = self.deactivate(key);
        let key_b = key + a.leaves;
        let mut adj_a = Vec::with_capacity(p.adj.len());
        let mut adj_b = Vec::with_capacity(p.adj.len());
        for &t in &p.adj {
            let before = self.tris[t as usize].positions;
            let tri = &mut self.tris[t as usize];
            for k in 0..3 {
                if tri.corners[k] == key {
                    if a.covers(tri.leaves[k]) {
                        tri.positions[k] = a_pos;
                        adj_a.push(t);
                    } else {
                        tri.corners[k] = key_b;
                        tri.positions[k] = b_pos;
                        adj_b.push(t);
                    }
                }
            }
            if self.options.check_foldover && flipped(&before, &self.tris[t as usize].positions) {
                self.foldovers += 1;
            }
        }
        self.activate(a, pnode.child_meta[0], pnode.child_local[0], a_pos, adj_a);
        self.activate(b, pnode.child_meta[1], pnode.child_local[1], b_pos, adj_b);
        let mut slots = Vec::with_capacity(created.len());
        for leaves in created {
            if let Some(s) = self.add_triangle(leaves) {
                slots.push(s);
            }
        }
        self.created.insert(pnode.id, slots);
        Ok(Outcome::Done)
    }

    fn try_collapse(&mut self, first: u32, second: u32) -> Result<Outcome> {
        let (a, b) = (&self.active[&first], &self.active[&second]);
        let parent_id = a.node.parent_id;
        // Implicit dependency: every neighbour's parent is younger than the new node.
        for x in [a, b] {
            for &t in &x.adj {
                for &c in &self.tris[t as usize].corners {
                    if c != first && c != second && self.active[&c].node.parent_id <= parent_id {
                        return Ok(Outcome::Blocked(None));
                    }
                }
            }
        }
        let (pm, pl) = (a.node.parent_meta, a.node.parent_local as usize);
        if !self.store.use_block(pm, 1) {
            self.store.request_urgent(pm, true);
            return Ok(Outcome::Miss);
        }
        let got = self.store.with_block(pm, |view| view.nodes.get(pl).map(|p| (*p, view.position(p))))?;
        let Some(Some((p, p_pos))) = got else {
            return Err(Error::Internal {
                stage: "meta-node navigation",
                problem: format!("meta-node {pm}: parent {pl} missing"),
            });
        };
        let a_pos = self.active[&first].position;
        let a_leaves = self.active[&first].node.leaves as u64 + self.active[&second].node.leaves as u64;
        let copies = [&self.active[&first].node, &self.active[&second].node];
        if p.id != parent_id
            || p.dfs_lo != first
            || p.leaves as u64 != a_leaves
            || !copies.iter().all(|c| is_parent_of(&p, p_pos, c, a_pos))
        {
            return Err(corrupt(&self.path, format!("node {parent_id}: parent record does not match its children")));
        }
        for t in self.created.remove(&p.id).unwrap_or_default() {
            self.remove_triangle(t);
        }
        let a = self.deactivate(first);
        let b = self.deactivate(second);
        let mut adj = a.adj;
        adj.extend_from_slice(&b.adj);
        for &t in &adj {
            let before = self.tris[t as usize].positions;
            let tri = &mut self.tris[t as usize];
            for k in 0..3 {
                if tri.corners[k] == first || tri.corners[k] == second {
                    tri.corners[k] = first;
                    tri.positions[k] = p_pos;
                }
            }
            if self.options.check_foldover && flipped(&before, &self.tris[t as usize].positions) {
                self.foldovers += 1;
            }
        }
        self.activate(p, pm, pl as u16, p_pos, adj);
        Ok(Outcome::Done)
    }

    /// Makes a node active; its block's usage count was already raised by the caller.
    fn activate(&mut self, node: MnNode, meta: u32, local: u16, position: [f32; 3], adj: Vec<u32>) {
        self.active.insert(node.dfs_lo, Active { node, meta, local, position, adj });
        let usage = self.usage.entry(meta).or_insert(0);
        *usage += 1;
        if *usage == 1 {
            self.reference_around(meta, 1);
        }
        self.reference_frontier(&node, meta, 1);
    }

    fn deactivate(&mut self, key: u32) -> Active {
        let a = self.active.remove(&key).expect("deactivating an active node");
        let usage = self.usage.get_mut(&a.meta).expect("usage of an active node's meta-node");
        *usage -= 1;
        let last = *usage == 0;
        if last {
            self.usage.remove(&a.meta);
        }
        self.store.use_block(a.meta, -1);
        if last {
            self.reference_around(a.meta, -1);
        }
        self.reference_frontier(&a.node, a.meta, -1);
        a
    }

    /// [`Prefetch::Paper`] and [`Prefetch::Parent`]: a meta-node in use references its parent
    /// (and its children).
    fn reference_around(&mut self, meta: u32, delta: i32) {
        let children = match self.options.prefetch {
            Prefetch::Paper => true,
            Prefetch::Parent => false,
            Prefetch::Frontier => return,
        };
        let e = self.mnt[meta as usize];
        if e.parent != NONE {
            self.store.reference(e.parent, delta);
        }
        if children {
            for c in e.first_child..e.first_child + e.child_count {
                self.store.reference(c, delta);
            }
        }
    }

    /// [`Prefetch::Frontier`]: an active node references the blocks of its children and of its
    /// parent that are not its own block.
    fn reference_frontier(&mut self, node: &MnNode, meta: u32, delta: i32) {
        if self.options.prefetch != Prefetch::Frontier {
            return;
        }
        for other in [node.child_meta[0], node.child_meta[1], node.parent_meta] {
            if other != NONE && other != meta {
                self.store.reference(other, delta);
            }
        }
    }

    /// Adds the triangle with corner leaves `leaves` over the current cut; `None` if two corners
    /// share an active node (cannot happen for a well-formed forest).
    fn add_triangle(&mut self, leaves: [u32; 3]) -> Option<u32> {
        let mut corners = [0u32; 3];
        let mut positions = [[0f32; 3]; 3];
        for k in 0..3 {
            let (&key, a) = self.active.range(..=leaves[k]).next_back()?;
            corners[k] = key;
            positions[k] = a.position;
        }
        if corners[0] == corners[1] || corners[1] == corners[2] || corners[0] == corners[2] {
            return None;
        }
        let tri = Tri { leaves, corners, positions };
        let slot = match self.free.pop() {
            Some(s) => {
                self.tris[s as usize] = tri;
                self.live[s as usize] = true;
                s
            }
            None => {
                self.tris.push(tri);
                self.live.push(true);
                (self.tris.len() - 1) as u32
            }
        };
        for c in corners {
            if let Some(a) = self.active.get_mut(&c) {
                a.adj.push(slot);
            }
        }
        Some(slot)
    }

    fn remove_triangle(&mut self, slot: u32) {
        for c in self.tris[slot as usize].corners {
            if let Some(a) = self.active.get_mut(&c) {
                if let Some(i) = a.adj.iter().position(|&t| t == slot) {
                    a.adj.swap_remove(i);
                }
            }
        }
        self.live[slot as usize] = false;
        self.free.push(slot);
    }

    fn rebuild_soup(&mut self) {
        self.soup.clear();
        for (tri, &live) in self.tris.iter().zip(&self.live) {
            if live {
                self.soup.extend_from_slice(&tri.positions);
            }
        }
    }

    /// Pairs of adjacent active nodes that never coexisted during the construction (one is not
    /// older than the other's parent). The El-Sana–Varshney argument keeps this at 0 when every
    /// neighbour, including the third corners of the triangles a split creates, is checked on
    /// both sides; relief checks the third corners only for age, because the two-sided test can
    /// deadlock (two nodes each waiting for the other; seen on the dragon). What matters, no
    /// foldover, is checked per switch by [`NavOptions::check_foldover`]. For tests; O(triangles).
    pub fn coexistence_violations(&self) -> u64 {
        let mut count = 0;
        for (t, &l) in self.tris.iter().zip(&self.live) {
            if !l {
                continue;
            }
            for k in 0..3 {
                let (u, v) = (&self.active[&t.corners[k]].node, &self.active[&t.corners[(k + 1) % 3]].node);
                count += (u.id >= v.parent_id || v.id >= u.parent_id) as u64;
            }
        }
        count
    }

    /// The active triangles by corner leaves (for tests: compare with the forest's m(t)).
    pub fn triangle_leaves(&self) -> Vec<[u32; 3]> {
        self.tris.iter().zip(&self.live).filter(|(_, &l)| l).map(|(t, _)| t.leaves).collect()
    }

    /// The active nodes' ids.
    pub fn active_ids(&self) -> Vec<u32> {
        self.active.values().map(|a| a.node.id).collect()
    }

    /// Checks the bookkeeping: every active triangle's corners are active nodes covering its
    /// leaves, adjacency lists match, the cut covers the leaves without overlap, usage counts
    /// match. For tests; O(active).
    pub fn check(&self) -> std::result::Result<(), String> {
        let mut next = 0u32;
        for (&k, a) in &self.active {
            if k != next || a.node.dfs_lo != k {
                return Err(format!("cut gap or overlap at leaf {next} (node {} at {k})", a.node.id));
            }
            next = k + a.node.leaves;
            for &t in &a.adj {
                if !self.live[t as usize] || !self.tris[t as usize].corners.contains(&k) {
                    return Err(format!("node {}: stale adjacency {t}", a.node.id));
                }
            }
        }
        for (s, (t, &l)) in self.tris.iter().zip(&self.live).enumerate() {
            if !l {
                continue;
            }
            for k in 0..3 {
                let a = self.active.get(&t.corners[k]).ok_or(format!("triangle {s}: corner not active"))?;
                if !a.node.covers(t.leaves[k]) || a.position != t.positions[k] || !a.adj.contains(&(s as u32)) {
                    return Err(format!("triangle {s}: corner {k} inconsistent"));
                }
            }
        }
        let mut usage: HashMap<u32, u32> = HashMap::new();
        for a in self.active.values() {
            *usage.entry(a.meta).or_default() += 1;
        }
        if usage != self.usage {
            return Err("usage counts differ from the active nodes".into());
        }
        Ok(())
    }
}

enum Outcome {
    Done,
    Miss,
    /// Refused by a dependency; for a split, the neighbour that must split first.
    Blocked(Option<u32>),
}

/// How far a forced split may recurse through blocking neighbours in one go.
const FORCE_DEPTH: u32 = 32;

/// One frame's test: the shared one ([`crate::lod`]), with a slack per node id (a parent's id
/// exceeds its children's, so the parent always gets more) against rounding.
struct View {
    lod: Lod<Isotropic>,
    margin: f64,
}

impl View {
    /// Whether node `id` at `position` with `switch` and `radius` should be split.
    #[inline]
    fn wants(&self, id: u32, position: [f32; 3], switch: f32, radius: f32) -> bool {
        let p = DVec3::new(position[0] as f64, position[1] as f64, position[2] as f64);
        self.lod.wants(p, switch as f64, radius as f64 + self.margin * id as f64)
    }
}

/// Whether a triangle's orientation flipped between two corner positions.
fn flipped(before: &[[f32; 3]; 3], after: &[[f32; 3]; 3]) -> bool {
    let normal = |p: &[[f32; 3]; 3]| {
        let v = |k: usize| DVec3::new(p[k][0] as f64, p[k][1] as f64, p[k][2] as f64);
        (v(1) - v(0)).cross(v(2) - v(0))
    };
    let (n0, n1) = (normal(before), normal(after));
    n0.length_squared() > 0.0 && n1.length_squared() > 0.0 && n0.dot(n1) <= 0.0
}

/// The meta-node store: blocks through the file's [`crate::pager::Pager`], whatever its access.
/// With the map or positioned reads every block is there when asked for (the OS pages it in,
/// the navigation waits: the paper's "Virt"). With the buffer pool ("Ext") a block no holder has
/// is a miss, and the store speaks the pool's protocol: usage counts for the blocks of active
/// nodes, references for prefetch, urgent prefetch for missed switches. The pager's observer
/// sees what is read either way.
pub struct PagedStore<'a> {
    file: &'a MetaNodeFile,
    /// Blocks asked for urgently, held by a reference until a node in them is activated (or for
    /// [`URGENT_HOLD_FRAMES`]): an urgently loaded block nobody references yet would sit first on
    /// the free list, and the next load would take its holder before the navigator gets to it.
    urgent: HashMap<u32, u64>,
    frame: u64,
    faults_at_start: u64,
}

/// How long an urgent load is held for the switch that asked for it.
const URGENT_HOLD_FRAMES: u64 = 4;

impl<'a> PagedStore<'a> {
    pub fn new(file: &'a MetaNodeFile) -> PagedStore<'a> {
        PagedStore { file, urgent: HashMap::new(), frame: 0, faults_at_start: crate::sys::mem::page_faults().0 }
    }

    pub fn file(&self) -> &'a MetaNodeFile {
        self.file
    }
}

impl MetaStore for PagedStore<'_> {
    fn with_block<R>(&mut self, meta: u32, f: impl FnOnce(BlockView<'_>) -> R) -> Result<Option<R>> {
        let block = match self.file.pager().pool() {
            Some(pool) => match pool.get(meta) {
                Some(b) => crate::pager::Block::Pooled(b),
                None => return Ok(None),
            },
            None => self.file.block(meta)?,
        };
        let view = parse_block(self.file, meta, &block)?;
        Ok(Some(f(view)))
    }

    fn load_now(&mut self, meta: u32) -> Result<()> {
        let Some(pool) = self.file.pager().pool() else { return Ok(()) };
        // A reference keeps the block off the free list once loaded, so the prefetches queued
        // behind the urgent load cannot take its holder before the usage count pins it.
        pool.reference(meta, 1);
        pool.request_urgent(meta, Direction::Up);
        pool.drain()?;
        let pinned = pool.use_block(meta, 1);
        pool.reference(meta, -1);
        if !pinned {
            return Err(Error::InvalidArgument(format!(
                "the buffer pool's {} place holders cannot hold the root meta-nodes; give it more memory",
                pool.holders()
            )));
        }
        Ok(())
    }

    fn use_block(&mut self, meta: u32, delta: i32) -> bool {
        let Some(pool) = self.file.pager().pool() else { return true };
        let ok = pool.use_block(meta, delta);
        if ok && delta > 0 && self.urgent.remove(&meta).is_some() {
            pool.reference(meta, -1); // the usage count holds it now
        }
        ok
    }

    fn reference(&mut self, meta: u32, delta: i32) {
        if let Some(pool) = self.file.pager().pool() {
            pool.reference(meta, delta);
        }
    }

    fn request_urgent(&mut self, meta: u32, up: bool) {
        let Some(pool) = self.file.pager().pool() else { return };
        let asked = pool.request_urgent(meta, if up { Direction::Up } else { Direction::Down });
        if asked != Urgent::Refused && !self.urgent.contains_key(&meta) {
            pool.reference(meta, 1);
            self.urgent.insert(meta, self.frame);
        }
    }

    fn end_frame(&mut self) {
        self.frame += 1;
        let Some(pool) = self.file.pager().pool() else { return };
        let frame = self.frame;
        self.urgent.retain(|&meta, &mut asked| {
            let keep = frame - asked < URGENT_HOLD_FRAMES;
            if !keep {
                pool.reference(meta, -1);
            }
            keep
        });
    }

    /// Pages read from the file: the pool's and the positioned reads'; with the map, the
    /// process's major faults since the store was made.
    fn pages_read(&self) -> u64 {
        match self.file.pager().access() {
            crate::pager::Access::Map => crate::sys::mem::page_faults().0 - self.faults_at_start,
            _ => self.file.pager().reads().pages,
        }
    }

    fn second_chance_hits(&self) -> u64 {
        self.file.pager().pool().map_or(0, |p| p.stats().second_chance_hits)
    }
}

#[cfg(test)]
mod tests {
    //! Navigation over a small forest built here by a naive shortest-first collapse of a bumpy
    //! grid (the real builder has its own tests); the point is the bookkeeping.
    use super::*;
    use crate::mesh::Bounds;
    use crate::metanode::blocking::{write_metanode_file, BlockingOptions, Forest};
    use crate::metanode::{VdtNode, VdtTriangle};

    /// A grid of `side`² vertices with pseudo-random heights, collapsed shortest edge first
    /// (half-edge collapse into the lower id, skipping collapses that flip a triangle).
    fn naive_forest(side: u32) -> (Vec<VdtNode>, Vec<VdtTriangle>, usize, Bounds) {
        let mut pos = Vec::new();
        let mut seed = 12345u64;
        for y in 0..side {
            for x in 0..side {
                seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                let z = ((seed >> 33) % 1000) as f32 / 1000.0 * 0.3;
                pos.push([x as f32, y as f32, z]);
            }
        }
        let mut tris = Vec::new();
        for y in 0..side - 1 {
            for x in 0..side - 1 {
                let v = y * side + x;
                tris.push([v, v + 1, v + side + 1]);
                tris.push([v, v + side + 1, v + side]);
            }
        }
        let leaves = pos.len() as u32;
        let mut nodes: Vec<VdtNode> = pos
            .iter()
            .map(|&p| VdtNode { position: p, children: [NONE; 2], parent: NONE, leaves: 1, ..Default::default() })
            .collect();
        let mut current: Vec<[u32; 3]> = tris.clone(); // corners as current node ids
        let mut alive = vec![true; tris.len()];
        let mut died: Vec<Vec<u32>> = vec![Vec::new(); leaves as usize];
        let len =
            |a: [f32; 3], b: [f32; 3]| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
        let normal = |p: [[f32; 3]; 3]| {
            let u = [p[1][0] - p[0][0], p[1][1] - p[0][1], p[1][2] - p[0][2]];
            let v = [p[2][0] - p[0][0], p[2][1] - p[0][1], p[2][2] - p[0][2]];
            [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
        };
        loop {
            let mut best: Option<(f32, u32, u32)> = None;
            for (t, c) in current.iter().enumerate() {
                if !alive[t] {
                    continue;
                }
                for k in 0..3 {
                    let (a, b) = (c[k].min(c[(k + 1) % 3]), c[k].max(c[(k + 1) % 3]));
                    let l = len(nodes[a as usize].position, nodes[b as usize].position);
                    // Keep a into which b collapses; reject flips.
                    let ok = current.iter().enumerate().all(|(s, d)| {
                        if !alive[s] || !d.contains(&b) || d.contains(&a) {
                            return true;
                        }
                        let p0 = d.map(|v| nodes[v as usize].position);
                        let p1 = d.map(|v| nodes[if v == b { a } else { v } as usize].position);
                        let (n0, n1) = (normal(p0), normal(p1));
                        n0[0] * n1[0] + n0[1] * n1[1] + n0[2] * n1[2] > 0.0
                    });
                    if ok && best.is_none_or(|(bl, ba, bb)| (l, a, b) < (bl, ba, bb)) {
                        best = Some((l, a, b));
                    }
                }
            }
            let Some((l, a, b)) = best else { break };
            let p = nodes.len() as u32;
            let (na, nb) = (nodes[a as usize], nodes[b as usize]);
            let pp = na.position;
            let r = (na.radius).max(len(pp, nb.position) + nb.radius);
            nodes.push(VdtNode {
                position: pp,
                switch: l.max(na.switch).max(nb.switch),
                radius: r,
                children: [a, b],
                parent: NONE,
                leaves: na.leaves + nb.leaves,
                ..Default::default()
            });
            died.push(Vec::new());
            nodes[a as usize].parent = p;
            nodes[b as usize].parent = p;
            for (t, c) in current.iter_mut().enumerate() {
                if !alive[t] {
                    continue;
                }
                for v in c.iter_mut() {
                    if *v == a || *v == b {
                        *v = p;
                    }
                }
                if c[0] == c[1] || c[1] == c[2] || c[0] == c[2] {
                    alive[t] = false;
                    died[p as usize].push(t as u32);
                }
            }
        }
        let mut out = Vec::new();
        for (id, list) in died.iter().enumerate() {
            nodes[id].tri_start = out.len() as u32;
            nodes[id].tri_count = list.len() as u32;
            out.extend(list.iter().map(|&t| VdtTriangle { corners: tris[t as usize] }));
        }
        let base: Vec<_> = (0..tris.len()).filter(|&t| alive[t]).map(|t| VdtTriangle { corners: tris[t] }).collect();
        let nbase = base.len();
        out.extend(base);
        let bounds = Bounds { min: [0.0, 0.0, 0.0], max: [side as f64 - 1.0, side as f64 - 1.0, 0.3] };
        (nodes, out, nbase, bounds)
    }

    fn file(side: u32, options: BlockingOptions) -> (tempfile::TempDir, MetaNodeFile, Vec<VdtNode>, Vec<VdtTriangle>) {
        let (nodes, tris, base, bounds) = naive_forest(side);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("grid.rmn");
        let forest =
            Forest { nodes: &nodes, triangles: &tris, base_triangles: base, leaves: side * side, metric: 0, bounds };
        write_metanode_file(&forest, options, &path).unwrap();
        let f = MetaNodeFile::open(&path).unwrap();
        (dir, f, nodes, tris)
    }

    fn camera(eye: [f64; 3], look: [f64; 3]) -> Camera {
        Camera::new(DVec3::from(eye), DVec3::from(look), DVec3::Z, 60.0, 320, 200).unwrap()
    }

    #[test]
    fn coarsest_and_finest_cuts_match_the_forest() {
        let (_d, f, nodes, tris) = file(12, BlockingOptions { levels_per_node: 3, page_bytes: 512 });
        assert!(f.header().metanodes > 10, "small pages give many meta-nodes");
        let mut nav =
            Navigator::new(&f, PagedStore::new(&f), NavOptions { check_foldover: true, ..NavOptions::default() })
                .unwrap();
        let roots = nodes.iter().filter(|v| v.parent == NONE).count();
        assert_eq!(nav.active_nodes(), roots);
        nav.check().unwrap();
        // Close up with a tiny tolerance: every node splits, the full grid comes back.
        let s = nav.update(&camera([5.5, -30.0, 40.0], [5.5, 5.5, 0.0]), 1e-4).unwrap();
        nav.check().unwrap();
        assert_eq!(nav.active_nodes(), 144);
        assert_eq!(nav.triangle_count(), 2 * 11 * 11);
        assert_eq!(s.splits as usize, nodes.len() - 144, "one split per internal node");
        let mut got: Vec<[u32; 3]> = nav.triangle_leaves();
        got.sort();
        assert_eq!(got.len(), tris.len());
        // Far away: everything collapses back to the roots.
        let s = nav.update(&camera([5.5, -3e6, 4e6], [5.5, 5.5, 0.0]), 1.0).unwrap();
        nav.check().unwrap();
        assert_eq!(nav.active_nodes(), roots);
        assert_eq!(s.collapses as usize, nodes.len() - 144, "one collapse per internal node");
        assert_eq!(nav.foldovers(), 0);
    }

    /// The triangles the forest says a cut shows: base ones, and those whose m(t) is split.
    fn expected(nodes: &[VdtNode], tris: &[VdtTriangle], base: usize, active: &[u32]) -> Vec<[u32; 3]> {
        let mut split = vec![false; nodes.len()];
        for &a in active {
            let mut v = nodes[a as usize].parent;
            while v != NONE && !split[v as usize] {
                split[v as usize] = true;
                v = nodes[v as usize].parent;
            }
        }
        // Leaf DFS numbers as the meta-node file assigns them.
        let mut dfs = vec![0u32; nodes.len()];
        let mut next = 0;
        for r in (0..nodes.len()).filter(|&v| nodes[v].parent == NONE) {
            let mut stack = vec![r as u32];
            while let Some(v) = stack.pop() {
                let n = &nodes[v as usize];
                if n.children[0] == NONE {
                    dfs[v as usize] = next;
                    next += 1;
                } else {
                    stack.push(n.children[1]);
                    stack.push(n.children[0]);
                }
            }
        }
        let mut out = Vec::new();
        for (id, n) in nodes.iter().enumerate() {
            if split[id] {
                for t in &tris[n.tri_start as usize..(n.tri_start + n.tri_count) as usize] {
                    out.push(t.corners.map(|c| dfs[c as usize]));
                }
            }
        }
        out.extend(tris[tris.len() - base..].iter().map(|t| t.corners.map(|c| dfs[c as usize])));
        out.sort();
        out
    }

    #[test]
    fn random_views_keep_the_cut_consistent_without_foldovers() {
        let side = 14;
        let (nodes, tris, base, _) = naive_forest(side);
        let (_d, f, _, _) = file(side, BlockingOptions { levels_per_node: 2, page_bytes: 512 });
        let mut nav =
            Navigator::new(&f, PagedStore::new(&f), NavOptions { check_foldover: true, ..NavOptions::default() })
                .unwrap();
        let mut seed = 7u64;
        let mut rnd = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut splits, mut collapses, mut blocked) = (0, 0, 0);
        for _ in 0..300 {
            let eye = [rnd() * 20.0 - 3.0, rnd() * 20.0 - 3.0, 0.5 + rnd() * 6.0];
            let look = [rnd() * 13.0, rnd() * 13.0, 0.0];
            let tolerance = [0.5, 2.0, 8.0, 40.0][(rnd() * 4.0) as usize];
            let s = nav.update(&camera(eye, look), tolerance).unwrap();
            nav.check().unwrap();
            let mut got = nav.triangle_leaves();
            got.sort();
            assert_eq!(got, expected(&nodes, &tris, base, &nav.active_ids()));
            splits += s.splits;
            collapses += s.collapses;
            blocked += s.blocked;
        }
        assert_eq!(nav.foldovers(), 0);
        assert!(splits > 1000 && collapses > 1000, "{splits} splits, {collapses} collapses");
        eprintln!("{splits} splits, {collapses} collapses, {blocked} blocked");
    }

    #[test]
    fn ext_matches_virt_with_room_and_stays_consistent_with_a_tiny_pool() {
        let side = 14;
        let (nodes, tris, base, _) = naive_forest(side);
        let (_d, f, _, _) = file(side, BlockingOptions { levels_per_node: 2, page_bytes: 512 });
        let metas = f.header().metanodes as usize;
        // A pool of `holders` place holders (and the staging buffer) over the same file.
        let pooled = |holders: usize| {
            let bytes = (holders as u64 + 1) * f.header().holder_bytes;
            MetaNodeFile::open_with(f.path(), crate::pager::Access::Pool { bytes }).unwrap()
        };
        let pool_of = |nav: &Navigator<PagedStore<'_>>| nav.store().file().pager().pool().unwrap().stats();
        let views: Vec<(Camera, f64)> = {
            let mut seed = 99u64;
            let mut rnd = || {
                seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                (seed >> 11) as f64 / (1u64 << 53) as f64
            };
            (0..150)
                .map(|_| {
                    let eye = [rnd() * 20.0 - 3.0, rnd() * 20.0 - 3.0, 0.5 + rnd() * 6.0];
                    let look = [rnd() * 13.0, rnd() * 13.0, 0.0];
                    (camera(eye, look), [0.5, 2.0, 8.0][(rnd() * 3.0) as usize])
                })
                .collect()
        };
        // Room for every block, and the I/O thread drained before each frame: no misses, the same
        // cuts as the map.
        let mut virt = Navigator::new(&f, PagedStore::new(&f), NavOptions::default()).unwrap();
        let roomy = pooled(metas + 4);
        let mut ext = Navigator::new(&roomy, PagedStore::new(&roomy), NavOptions::default()).unwrap();
        for (cam, tol) in &views {
            // Converge: a frame that misses retries once its urgent loads are in.
            virt.update(cam, *tol).unwrap();
            for _ in 0..64 {
                roomy.pager().pool().unwrap().drain().unwrap();
                if ext.update(cam, *tol).unwrap().misses == 0 {
                    break;
                }
            }
            assert_eq!(ext.active_ids(), virt.active_ids());
        }
        // A tiny pool: misses happen, the bookkeeping stays right, nothing in use is evicted,
        // whichever blocks are prefetched.
        for prefetch in [Prefetch::Paper, Prefetch::Parent, Prefetch::Frontier] {
            let small = pooled(16);
            let mut tiny =
                Navigator::new(&small, PagedStore::new(&small), NavOptions { check_foldover: true, prefetch }).unwrap();
            let mut misses = 0;
            for (k, (cam, tol)) in views.iter().enumerate() {
                let s = tiny.update(cam, *tol).unwrap();
                misses += s.misses;
                tiny.check().unwrap();
                small.pager().pool().unwrap().check_invariants().unwrap();
                let mut got = tiny.triangle_leaves();
                got.sort();
                assert_eq!(got, expected(&nodes, &tris, base, &tiny.active_ids()));
                if k % 3 == 0 {
                    small.pager().pool().unwrap().drain().unwrap();
                }
            }
            assert!(misses > 0, "16 holders for {metas} meta-nodes must miss");
            assert_eq!(tiny.foldovers(), 0);
            let stats = pool_of(&tiny);
            // Whether a released block is asked for again before it is recycled (a second-chance
            // hit) depends on how far the I/O thread got with the prefetches: not asserted here
            // (the pool's own tests check second chance deterministically).
            assert!(stats.disk_reads > 8 && stats.evictions > 0, "{prefetch:?}: {stats:?}");
        }
    }

    /// Fuzzing (tools/fuzz.sh, target `navigate`): a child whose copy of its parent's switch
    /// value differs from the parent's made a split and the collapse undoing it both wanted, and
    /// `update` alternated between them forever. Now the split is refused with one line naming
    /// the file.
    #[test]
    fn a_child_whose_copy_of_its_parent_differs_is_refused_not_looped_on() {
        let (dir, f, _, _) = file(12, BlockingOptions { levels_per_node: 3, page_bytes: 512 });
        let mut bytes = std::fs::read(f.path()).unwrap();
        // Every non-root node's copy of its parent's switch value becomes 0 (never wanted).
        let at = std::mem::offset_of!(MnNode, parent_switch);
        let mut patched = 0;
        for (m, e) in f.mnt().iter().enumerate() {
            let bytes_of_block = f.block(m as u32).unwrap();
            let block = BlockView::parse(&bytes_of_block, f.header().metanodes as u32).unwrap();
            for (k, v) in block.nodes.iter().enumerate() {
                if !v.is_root() {
                    let o = e.offset as usize
                        + crate::format::metanode::BLOCK_HEADER_BYTES
                        + k * std::mem::size_of::<MnNode>()
                        + at;
                    bytes[o..o + 4].copy_from_slice(&0f32.to_le_bytes());
                    patched += 1;
                }
            }
        }
        assert!(patched > 100);
        let path = dir.path().join("bad-copies.rmn");
        std::fs::write(&path, &bytes).unwrap();
        let bad = MetaNodeFile::open(&path).unwrap();
        let mut nav = Navigator::new(&bad, PagedStore::new(&bad), NavOptions::default()).unwrap();
        let e = nav.update(&camera([5.5, -30.0, 40.0], [5.5, 5.5, 0.0]), 1e-4).expect_err("an error").to_string();
        assert!(e.contains("bad-copies.rmn") && e.contains("copies of it differ") && !e.contains('\n'), "{e}");
    }
}
