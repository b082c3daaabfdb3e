//! Refinement over a remote terrain that never waits for the network, and never draws a crack
//! (ARCHITECTURE.md, "Remote terrains").
//!
//! Every frame refines with the records that are *effective*: fetched, and with every DAG parent
//! effective. Any other record reads as never active, so the mesh stays coarser where data is
//! missing. Effectiveness is closed upwards in the DAG, so a vertex the refinement makes active
//! has both its parents active: the nesting that conformity rests on (Lindstrom & Pascucci,
//! *Visualization of Large Terrains Made Easy*, §3) holds for the reduced error field as it does
//! for the file's, and every frame's strip is conforming. The effective set changes only between
//! frames ([`Progressive::refine`] absorbs what arrived before it refines), so a frame never mixes
//! two states; once everything a view needs has arrived, the strip is the local file's.
//!
//! A record that misses marks its block wanted (one atomic bit); the misses of the frame that
//! first marks a block are kept. After the frame they go to a fetcher thread, which asks for
//! their blocks and, as look-ahead, for the blocks of their DAG descendants a few levels down and
//! of those descendants' other parents (what the next frames would miss once the block arrives: a
//! child's error and radius are bounded by the parent's, so an active parent's subtree is where
//! refinement goes), read together by [`Pager::read_blocks`] (for a remote file: coalesced range
//! requests, several in flight; through the pager, so its observer and read counts see them, and a
//! file stored with pages left out is translated where every other read is). A record that
//! is fetched but not effective sends its missing ancestors instead. A wanted block is not asked
//! for again until it arrives.
//!
//! Each arrival carries its causal round: one more than the round of the data of the frame that
//! asked for it (the opening request is round 1). A frame's round is the newest it has absorbed,
//! so the round of the first complete frame is the number of sequential round trips it waited for.

use rustc_hash::FxHashSet;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{channel, Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::format::terrain::{Record, TerrainFile, RECORDS_PER_BLOCK, RECORD_BYTES};
use crate::layout::hierarchy::{Grid, VertexKind};
use crate::layout::{AnyLayout, Layout, LayoutVisitor};
#[cfg(doc)]
use crate::pager::Pager;
use crate::refine::records::RecordSource;
use crate::refine::{Morph, RefineOptions, Refiner, Strip};

const BLOCK_BYTES: u64 = RECORDS_PER_BLOCK * RECORD_BYTES as u64;
const WORDS_PER_BLOCK: usize = (RECORDS_PER_BLOCK as usize).div_ceil(64);

/// How far ahead the fetcher asks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ProgressiveOptions {
    /// Levels of DAG descendants below a missed record whose blocks are fetched with it.
    pub lookahead_levels: u32,
}

impl ProgressiveOptions {
    /// The defaults, with `RELIEF_LOOKAHEAD_LEVELS` from the environment where set.
    pub fn from_env() -> Result<ProgressiveOptions> {
        let mut o = ProgressiveOptions::default();
        if let Some(v) = crate::pager::remote::env_number("RELIEF_LOOKAHEAD_LEVELS")? {
            o.lookahead_levels = v.min(16) as u32;
        }
        Ok(o)
    }
}

impl Default for ProgressiveOptions {
    fn default() -> Self {
        ProgressiveOptions { lookahead_levels: 6 }
    }
}

/// A fetched block of records and which of them are effective (one bit each).
struct Block {
    records: Box<[Record]>,
    effective: [u64; WORDS_PER_BLOCK],
}

/// The record no refinement makes active (NaN error and radius fail the active test).
const MISSING: Record = Record { z: 0.0, error: f32::NAN, radius: f32::NAN };

/// The records of one frame: effective ones as fetched, the rest [`MISSING`], each miss noted.
struct FrameRecords<'a> {
    blocks: &'a [Option<Box<Block>>],
    /// Per block: a miss was noted (a fetch asked for, or its ancestors' sought) and not yet
    /// answered.
    wanted: &'a [AtomicU64],
    /// Per block: first noted by this frame (every miss in it is kept, as look-ahead seeds).
    fresh: &'a [AtomicU64],
    representatives: &'a Mutex<Vec<u64>>,
    missed: AtomicU64,
}

impl RecordSource for FrameRecords<'_> {
    #[inline]
    fn record(&self, index: u64) -> Record {
        let b = (index / RECORDS_PER_BLOCK) as usize;
        let k = (index % RECORDS_PER_BLOCK) as usize;
        if let Some(Some(block)) = self.blocks.get(b) {
            if block.effective[k / 64] >> (k % 64) & 1 == 1 {
                if let Some(r) = block.records.get(k) {
                    return *r;
                }
            }
        }
        self.missed.fetch_add(1, Ordering::Relaxed);
        if let (Some(w), Some(f)) = (self.wanted.get(b / 64), self.fresh.get(b / 64)) {
            let bit = 1u64 << (b % 64);
            let keep = if w.fetch_or(bit, Ordering::Relaxed) & bit == 0 {
                f.fetch_or(bit, Ordering::Relaxed);
                true
            } else {
                f.load(Ordering::Relaxed) & bit != 0
            };
            if keep {
                self.representatives.lock().unwrap_or_else(|p| p.into_inner()).push(index);
            }
        }
        MISSING
    }
}

/// What one progressive frame used and missed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ProgressiveFrame {
    /// Record reads that found no effective record (the strip is coarser there).
    pub missed_records: u64,
    /// The causal round of the newest data the frame used (1: the opening request alone).
    pub round_trips: u64,
    /// Strip vertices whose height was not fetched yet (drawn at the terrain's mid height).
    pub missing_heights: u64,
}

impl ProgressiveFrame {
    /// Whether the frame is the local file's (nothing missed).
    pub fn complete(&self) -> bool {
        self.missed_records == 0 && self.missing_heights == 0
    }
}

/// Work for the fetcher: representatives of missed blocks, and the round they were missed in.
struct Plan {
    round: u64,
    misses: Vec<u64>,
}

enum Arrival {
    /// Fetched blocks, and the records that became effective with them (per block, bits to
    /// set), settled on the fetcher thread so that absorbing costs the refining thread a copy.
    Blocks {
        round: u64,
        blocks: Vec<(u64, Box<[Record]>)>,
        effective: Vec<(u64, [u64; WORDS_PER_BLOCK])>,
    },
    Failed(Error),
}

/// Which records are effective, kept by the fetcher (who knows every block it handed over, in
/// order): a record becomes effective once its block is here and its DAG parents are effective,
/// and then its children are looked at again (each record is settled once, so the work is
/// proportional to what arrived).
struct Settle {
    layout: AnyLayout,
    grid: Grid,
    here: Vec<bool>,
    effective: Vec<Option<Box<[u64; WORDS_PER_BLOCK]>>>,
    /// Blocks whose bits changed in this `add` (reset at its end).
    touched: Vec<bool>,
}

impl Settle {
    fn new(layout: AnyLayout, blocks: usize) -> Settle {
        Settle {
            grid: layout.grid(),
            layout,
            here: vec![false; blocks],
            effective: (0..blocks).map(|_| None).collect(),
            touched: vec![false; blocks],
        }
    }

    fn is_effective(&self, i: u64) -> bool {
        let k = (i % RECORDS_PER_BLOCK) as usize;
        match self.effective.get((i / RECORDS_PER_BLOCK) as usize) {
            Some(Some(w)) => w[k / 64] >> (k % 64) & 1 == 1,
            _ => false,
        }
    }

    /// Adds blocks `new` (their records `count` each); returns the bits of every block whose
    /// bits changed (all of them: setting them again is harmless).
    fn add(&mut self, new: &[(u64, u64)]) -> Vec<(u64, [u64; WORDS_PER_BLOCK])> {
        struct Go<'a> {
            settle: &'a mut Settle,
            new: &'a [(u64, u64)],
        }
        impl LayoutVisitor for Go<'_> {
            type Output = Vec<(u64, [u64; WORDS_PER_BLOCK])>;
            fn visit<L: Layout>(self, layout: &L) -> Self::Output {
                self.settle.add_in(layout, self.new)
            }
        }
        let layout = self.layout.clone();
        layout.visit(Go { settle: self, new })
    }

    /// [`Self::add`] with the layout's type known (settling is index arithmetic on every record
    /// that arrives).
    fn add_in<L: Layout>(&mut self, layout: &L, new: &[(u64, u64)]) -> Vec<(u64, [u64; WORDS_PER_BLOCK])> {
        // Work items carry their record index.
        let mut work: Vec<(u32, u32, u64)> = Vec::new();
        for &(b, count) in new {
            match self.here.get_mut(b as usize) {
                Some(h) if !*h => *h = true,
                _ => continue,
            }
            for k in 0..count {
                let i = b * RECORDS_PER_BLOCK + k;
                if let Some((x, y)) = layout.coords(i) {
                    work.push((x, y, i));
                }
            }
        }
        let mut changed: Vec<u64> = Vec::new();
        while let Some((x, y, i)) = work.pop() {
            let b = i / RECORDS_PER_BLOCK;
            if self.is_effective(i) || !self.here.get(b as usize).copied().unwrap_or(false) {
                continue;
            }
            let (parents, count) = self.grid.dag_parents(x, y);
            if !parents[..count].iter().all(|&(px, py)| self.is_effective(layout.index(px, py))) {
                continue;
            }
            let k = (i % RECORDS_PER_BLOCK) as usize;
            let (word, bit) = (k / 64, 1u64 << (k % 64));
            self.effective[b as usize].get_or_insert_with(|| Box::new([0; WORDS_PER_BLOCK]))[word] |= bit;
            if !std::mem::replace(&mut self.touched[b as usize], true) {
                changed.push(b);
            }
            let (children, count) = self.grid.dag_children(x, y);
            for &(cx, cy) in &children[..count] {
                let ci = layout.index(cx, cy);
                // Only a child that is here can become effective now.
                if self.here.get((ci / RECORDS_PER_BLOCK) as usize).copied().unwrap_or(false) {
                    work.push((cx, cy, ci));
                }
            }
            if count == 0 && matches!(self.grid.kind(x, y), VertexKind::Corner) {
                // The corners are the centre's DAG parents, though not in `dag_children`.
                let (cx, cy) = self.grid.centre();
                work.push((cx, cy, layout.index(cx, cy)));
            }
        }
        changed
            .into_iter()
            .map(|b| {
                self.touched[b as usize] = false;
                (b, self.effective[b as usize].as_deref().copied().unwrap_or([0; WORDS_PER_BLOCK]))
            })
            .collect()
    }
}

/// What the fetcher keeps between plans: which blocks were asked for, which records are
/// effective. It turns misses into blocks to read, and read blocks into an arrival.
struct Planner {
    options: ProgressiveOptions,
    asked: Vec<bool>,
    settle: Settle,
}

impl Planner {
    /// The blocks to read for `misses` (see [`plan_blocks`]), marked asked.
    fn plan(&mut self, misses: &[u64]) -> Vec<u32> {
        struct Go<'a> {
            asked: &'a mut [bool],
            misses: &'a [u64],
            lookahead: u32,
        }
        impl LayoutVisitor for Go<'_> {
            type Output = Vec<u64>;
            fn visit<L: Layout>(self, layout: &L) -> Vec<u64> {
                plan_blocks(layout, self.asked, self.misses, self.lookahead)
            }
        }
        let layout = self.settle.layout.clone();
        let wanted = layout.visit(Go { asked: &mut self.asked, misses, lookahead: self.options.lookahead_levels });
        wanted.iter().filter_map(|&b| u32::try_from(b).ok()).collect()
    }

    /// Reads blocks `ids` through the pager and settles which records they make effective.
    fn read(&mut self, terrain: &TerrainFile, round: u64, ids: &[u32]) -> Arrival {
        let mut staged: Vec<(u64, Box<[Record]>)> = Vec::with_capacity(ids.len());
        let result = terrain.pager().read_blocks(ids, |b, records: Box<[Record]>| {
            staged.push((b as u64, records));
            Ok(())
        });
        match result {
            Ok(()) => {
                let counts: Vec<(u64, u64)> = staged.iter().map(|(b, records)| (*b, records.len() as u64)).collect();
                let effective = self.settle.add(&counts);
                Arrival::Blocks { round, blocks: staged, effective }
            }
            Err(e) => Arrival::Failed(e),
        }
    }
}

/// Who reads the blocks that frames missed.
enum Fetch {
    /// A fetcher thread, reading through the pager (which waits on the network there).
    Thread {
        plans: Option<Sender<Plan>>,
        arrivals: Receiver<Arrival>,
        /// Detached when dropped.
        handle: Option<JoinHandle<()>>,
    },
    /// The host fetches the bytes ([`Progressive::take_request`], [`Progressive::deliver`]);
    /// plans wait here until it asks.
    Hosted { planner: Box<Planner>, pending: Vec<Plan> },
}

/// Blocks for the host to fetch (a [`crate::pager::hosted::HostedFile`]'s), with the byte
/// ranges of the file that hold them.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct HostedRequest {
    round: u64,
    plans: u64,
    blocks: Vec<u32>,
    /// `[start, end)` byte ranges of the file as stored: fetch each (one `Range` request, or
    /// several), insert the bytes, then [`Progressive::deliver`] this request.
    pub ranges: Vec<(u64, u64)>,
}

impl HostedRequest {
    /// The causal round its data will carry.
    pub fn round(&self) -> u64 {
        self.round
    }

    /// Bytes its ranges hold.
    pub fn bytes(&self) -> u64 {
        self.ranges.iter().map(|&(a, b)| b - a).sum()
    }
}

/// A remote terrain's records as far as they have arrived, refined without waiting.
pub struct Progressive {
    terrain: Arc<TerrainFile>,
    blocks: Vec<Option<Box<Block>>>,
    wanted: Vec<AtomicU64>,
    fresh: Vec<AtomicU64>,
    representatives: Mutex<Vec<u64>>,
    round: u64,
    fetch: Fetch,
    /// Plans sent and not yet answered.
    outstanding: u64,
}

impl Progressive {
    /// Starts on `terrain` (remote) with the blocks its cache already holds (the opening range,
    /// and what earlier runs fetched), and a fetcher thread.
    pub fn new(terrain: Arc<TerrainFile>, options: ProgressiveOptions) -> Result<Progressive> {
        Progressive::start(terrain, options, false)
    }

    /// [`Self::new`] without a thread: the host fetches what [`Self::take_request`] asks for
    /// (into the terrain's [`crate::pager::hosted::HostedFile`]) and hands it back with
    /// [`Self::deliver`]. For hosts that cannot block (a web page's event loop).
    pub fn hosted(terrain: Arc<TerrainFile>, options: ProgressiveOptions) -> Result<Progressive> {
        Progressive::start(terrain, options, true)
    }

    fn start(terrain: Arc<TerrainFile>, options: ProgressiveOptions, hosted: bool) -> Result<Progressive> {
        if !terrain.is_remote() {
            return Err(Error::InvalidArgument(format!(
                "{}: progressive refinement needs a remote terrain",
                terrain.path().display()
            )));
        }
        let h = terrain.header();
        let n_blocks = h.payload_bytes.div_ceil(BLOCK_BYTES);
        let mut p = Progressive {
            blocks: (0..n_blocks).map(|_| None).collect(),
            wanted: (0..n_blocks.div_ceil(64)).map(|_| AtomicU64::new(0)).collect(),
            fresh: (0..n_blocks.div_ceil(64)).map(|_| AtomicU64::new(0)).collect(),
            representatives: Mutex::new(Vec::new()),
            round: 1,
            // Until the fetcher is started below.
            fetch: Fetch::Thread { plans: None, arrivals: channel().1, handle: None },
            outstanding: 0,
            terrain: terrain.clone(),
        };
        // Blocks the pager has without the network (the opening range, and what earlier runs
        // fetched into the cache) are here from the start.
        let pager = terrain.pager();
        let resident: Vec<u32> = pager
            .resident_blocks()?
            .iter()
            .enumerate()
            .filter(|&(_, &here)| here)
            .map(|(b, _)| b as u32)
            .take(n_blocks as usize)
            .collect();
        let mut have = Vec::with_capacity(resident.len());
        pager.read_blocks(&resident, |b, records: Box<[Record]>| {
            have.push((b as u64, records));
            Ok(())
        })?;
        let mut settle = Settle::new(terrain.layout().clone(), n_blocks as usize);
        let counts: Vec<(u64, u64)> = have.iter().map(|(b, records)| (*b, records.len() as u64)).collect();
        let effective = settle.add(&counts);
        p.insert(have, effective);
        // The fetcher asks for nothing that is here.
        let planner = Planner { options, asked: settle.here.clone(), settle };
        p.fetch = if hosted {
            Fetch::Hosted { planner: Box::new(planner), pending: Vec::new() }
        } else {
            let (plan_tx, plan_rx) = channel::<Plan>();
            let (arrive_tx, arrive_rx) = channel::<Arrival>();
            let t = terrain.clone();
            let handle = std::thread::Builder::new()
                .name("relief-fetch".into())
                .spawn(move || fetcher(t, planner, plan_rx, arrive_tx))
                .map_err(Error::thread("fetch"))?;
            Fetch::Thread { plans: Some(plan_tx), arrivals: arrive_rx, handle: Some(handle) }
        };
        // The corners are strip vertices of every frame (their heights are drawn).
        let grid = h.grid();
        let corners: Vec<u64> = grid.corners().iter().map(|&(x, y)| terrain.layout().index(x, y)).collect();
        let missing: Vec<u64> = corners.into_iter().filter(|&i| !p.present(i)).collect();
        if !missing.is_empty() {
            p.send(Plan { round: 2, misses: missing });
        }
        Ok(p)
    }

    fn present(&self, index: u64) -> bool {
        matches!(self.blocks.get((index / RECORDS_PER_BLOCK) as usize), Some(Some(_)))
    }

    fn send(&mut self, plan: Plan) {
        match &mut self.fetch {
            Fetch::Thread { plans: Some(tx), .. } => {
                if tx.send(plan).is_ok() {
                    self.outstanding += 1;
                }
            }
            Fetch::Thread { plans: None, .. } => {}
            Fetch::Hosted { pending, .. } => {
                pending.push(plan);
                self.outstanding += 1;
            }
        }
    }

    /// What the host should fetch next (every plan since the last call, as one round), or
    /// `None` when there is nothing to fetch. Only for [`Self::hosted`]; the ranges are bytes
    /// of the file as stored.
    pub fn take_request(&mut self) -> Result<Option<HostedRequest>> {
        let Fetch::Hosted { planner, pending } = &mut self.fetch else { return Ok(None) };
        if pending.is_empty() {
            return Ok(None);
        }
        let plans = pending.len() as u64;
        let round = pending.iter().map(|p| p.round).max().unwrap_or(1);
        let misses: Vec<u64> = pending.drain(..).flat_map(|p| p.misses).collect();
        let blocks = planner.plan(&misses);
        if blocks.is_empty() {
            // Everything asked for is here or on its way: these plans are answered.
            self.outstanding = self.outstanding.saturating_sub(plans);
            return Ok(None);
        }
        let ranges = self.terrain.pager().stored_ranges(&blocks)?;
        Ok(Some(HostedRequest { round, plans, blocks, ranges }))
    }

    /// Takes the blocks of `request` once the host has inserted every one of its ranges: read
    /// through the pager (counted and observed there), settled, effective from the next frame.
    pub fn deliver(&mut self, request: HostedRequest) -> Result<()> {
        let Fetch::Hosted { planner, .. } = &mut self.fetch else {
            return Err(Error::InvalidArgument("a request delivered to a terrain with its own fetcher".into()));
        };
        let arrival = planner.read(&self.terrain, request.round, &request.blocks);
        // Every merged plan is answered (`arrived` counts the one carrying the blocks).
        self.outstanding = self.outstanding.saturating_sub(request.plans.saturating_sub(1));
        self.arrived(arrival)
    }

    /// Plans sent and not yet answered (for a host: fetches still to make or in flight).
    pub fn outstanding(&self) -> u64 {
        self.outstanding
    }

    /// Makes fetched blocks resident and sets the bits of the records that became effective.
    fn insert(&mut self, arrived: Vec<(u64, Box<[Record]>)>, effective: Vec<(u64, [u64; WORDS_PER_BLOCK])>) {
        for (b, records) in arrived {
            let Some(slot) = self.blocks.get_mut(b as usize) else { continue };
            if slot.is_some() {
                continue;
            }
            *slot = Some(Box::new(Block { records, effective: [0; WORDS_PER_BLOCK] }));
            if let Some(w) = self.wanted.get(b as usize / 64) {
                w.fetch_and(!(1u64 << (b % 64)), Ordering::Relaxed);
            }
        }
        for (b, words) in effective {
            if let Some(Some(block)) = self.blocks.get_mut(b as usize) {
                for (w, new) in block.effective.iter_mut().zip(words) {
                    *w |= new;
                }
            }
        }
    }

    /// Takes what has arrived (never waits); a failed fetch is the error.
    pub fn absorb(&mut self) -> Result<()> {
        loop {
            let Fetch::Thread { arrivals, .. } = &self.fetch else { return Ok(()) };
            let Ok(a) = arrivals.try_recv() else { return Ok(()) };
            self.arrived(a)?;
        }
    }

    fn arrived(&mut self, a: Arrival) -> Result<()> {
        self.outstanding = self.outstanding.saturating_sub(1);
        match a {
            Arrival::Blocks { round, blocks, effective } => {
                // An answer that brought nothing (all asked already) is no round trip.
                if !blocks.is_empty() {
                    self.round = self.round.max(round);
                }
                self.insert(blocks, effective);
                Ok(())
            }
            Arrival::Failed(e) => Err(e),
        }
    }

    /// Waits up to `timeout` for an arrival and takes it; `false` when none came (or nothing is
    /// outstanding).
    pub fn wait_arrival(&mut self, timeout: Duration) -> Result<bool> {
        let Fetch::Thread { arrivals, .. } = &self.fetch else { return Ok(false) };
        if self.outstanding == 0 {
            return Ok(false);
        }
        match arrivals.recv_timeout(timeout) {
            Ok(a) => {
                self.arrived(a)?;
                self.absorb()?;
                Ok(true)
            }
            Err(RecvTimeoutError::Timeout | RecvTimeoutError::Disconnected) => Ok(false),
        }
    }

    /// Refines `camera`'s view with what is here (after absorbing what arrived), asks for what
    /// was missed, and fills the strip's heights (`options.heights`) from the fetched records.
    pub fn refine(
        &mut self,
        refiner: &mut Refiner,
        camera: &Camera,
        options: &RefineOptions,
        strip: &mut Strip,
    ) -> Result<ProgressiveFrame> {
        self.absorb()?;
        let terrain = self.terrain.clone();
        let records = FrameRecords {
            blocks: &self.blocks,
            wanted: &self.wanted,
            fresh: &self.fresh,
            representatives: &self.representatives,
            missed: AtomicU64::new(0),
        };
        refiner.refine_source(&terrain, &records, camera, options, strip);
        let missed_records = records.missed.into_inner();
        let mut missing_heights = 0;
        if options.heights && options.morph_ratio.is_none() {
            let h = terrain.header();
            let mid = (0.5 * (h.z_min + h.z_max)) as f32;
            let layout = terrain.layout();
            strip.morph.clear();
            for v in &strip.vertices {
                let i = layout.index(v.x, v.y);
                let k = (i % RECORDS_PER_BLOCK) as usize;
                let z_m = match self.blocks.get((i / RECORDS_PER_BLOCK) as usize) {
                    Some(Some(b)) => b.records.get(k).map_or(mid, |r| r.z),
                    _ => {
                        missing_heights += 1;
                        mid
                    }
                };
                strip.morph.push(Morph { blend: 1.0, z_m });
            }
        }
        let misses = std::mem::take(&mut *self.representatives.lock().unwrap_or_else(|p| p.into_inner()));
        // A block that is here stays noted only for this frame: its records wait for ancestors,
        // which the next frame may find missing by another of its records.
        for &i in &misses {
            let b = i / RECORDS_PER_BLOCK;
            if let Some(f) = self.fresh.get(b as usize / 64) {
                f.fetch_and(!(1u64 << (b % 64)), Ordering::Relaxed);
            }
            if self.present(i) {
                if let Some(w) = self.wanted.get(b as usize / 64) {
                    w.fetch_and(!(1u64 << (b % 64)), Ordering::Relaxed);
                }
            }
        }
        if !misses.is_empty() {
            let round = self.round + 1;
            self.send(Plan { round, misses });
        }
        Ok(ProgressiveFrame { missed_records, round_trips: self.round, missing_heights })
    }
}

impl Drop for Progressive {
    fn drop(&mut self) {
        // Closing the plan channel ends the fetcher after its current fetch. It is not waited
        // for: a fetch from a server that stopped answering can take its whole timeout and
        // retries, and closing a window must not. What it still fetches goes to the cache only.
        if let Fetch::Thread { plans, handle, .. } = &mut self.fetch {
            *plans = None;
            drop(handle.take());
        }
    }
}

/// The fetcher thread: turns plans into blocks (the missed ones, their look-ahead, or the
/// missing ancestors of records that are here but not effective), reads them, hands them over.
fn fetcher(terrain: Arc<TerrainFile>, mut planner: Planner, plans: Receiver<Plan>, arrivals: Sender<Arrival>) {
    while let Ok(first) = plans.recv() {
        // Plans queued behind a fetch are served together: one round of requests.
        let mut plan_count = 1u64;
        let mut round = first.round;
        let mut misses = first.misses;
        while let Ok(more) = plans.try_recv() {
            plan_count += 1;
            round = round.max(more.round);
            misses.extend(more.misses);
        }
        let ids = planner.plan(&misses);
        let arrival = planner.read(&terrain, round, &ids);
        let failed = matches!(arrival, Arrival::Failed(_));
        if arrivals.send(arrival).is_err() {
            return;
        }
        // Every merged plan is answered (the first carried the blocks).
        for _ in 1..plan_count {
            if arrivals.send(Arrival::Blocks { round, blocks: Vec::new(), effective: Vec::new() }).is_err() {
                return;
            }
        }
        if failed {
            return;
        }
    }
}

/// The blocks to fetch for `misses`, in ascending order, marking them `asked` (leaving out those
/// asked already): each miss's own block, or, when that is here (the record is not effective),
/// the blocks of its missing ancestors; and the blocks of its DAG descendants down `lookahead`
/// levels and of their parents.
fn plan_blocks<L: Layout>(layout: &L, asked: &mut [bool], misses: &[u64], lookahead: u32) -> Vec<u64> {
    let grid = layout.grid();
    let mut out: Vec<u64> = Vec::new();
    fn want(asked: &mut [bool], i: u64, out: &mut Vec<u64>) {
        let b = i / RECORDS_PER_BLOCK;
        if let Some(a) = asked.get_mut(b as usize) {
            if !*a {
                *a = true;
                out.push(b);
            }
        }
    }
    // Whether each miss's block was asked for before this plan (then the record is here, or on
    // its way, and not effective: an ancestor is missing).
    let climb: Vec<bool> =
        misses.iter().map(|&i| asked.get((i / RECORDS_PER_BLOCK) as usize).copied().unwrap_or(false)).collect();
    // Shared by every miss of the plan: a vertex is descended from once, climbed from once.
    let (mut seen, mut climbed): (FxHashSet<u64>, FxHashSet<u64>) = Default::default();
    let mut level: Vec<(u32, u32)> = Vec::new();
    let mut next: Vec<(u32, u32)> = Vec::new();
    for (&i, &climb) in misses.iter().zip(&climb) {
        let Some((x, y)) = layout.coords(i) else { continue };
        if climb {
            let mut up = vec![(x, y)];
            while let Some((ux, uy)) = up.pop() {
                let (parents, count) = grid.dag_parents(ux, uy);
                for &(px, py) in &parents[..count] {
                    let pi = layout.index(px, py);
                    if climbed.insert(pi) {
                        want(asked, pi, &mut out);
                        up.push((px, py));
                    }
                }
            }
            continue;
        }
        want(asked, i, &mut out);
        if !seen.insert(i) {
            continue;
        }
        level.clear();
        level.push((x, y));
        for _ in 0..lookahead {
            next.clear();
            for &(vx, vy) in &level {
                let (children, count) = grid.dag_children(vx, vy);
                for &c in &children[..count] {
                    let ci = layout.index(c.0, c.1);
                    if seen.insert(ci) {
                        want(asked, ci, &mut out);
                        // A descendant is effective only with both its parents: the one off
                        // this descent lies beside it.
                        let (parents, pc) = grid.dag_parents(c.0, c.1);
                        for &(px, py) in &parents[..pc] {
                            want(asked, layout.index(px, py), &mut out);
                        }
                        next.push(c);
                    }
                }
            }
            std::mem::swap(&mut level, &mut next);
            if level.is_empty() {
                break;
            }
        }
    }
    out.sort_unstable();
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::LayoutKind;

    /// Every effective record has effective DAG parents, and every record that is here with
    /// effective parents is effective: the closure is exact whatever order blocks arrive in.
    #[test]
    fn settling_is_the_upward_closed_set_of_what_arrived_in_any_order() {
        for kind in [LayoutKind::Interleaved, LayoutKind::RowMajor, LayoutKind::Hz] {
            let grid = Grid::new(7).unwrap();
            let layout = AnyLayout::new(kind, grid, 0, RECORD_BYTES).unwrap();
            let blocks = layout.records().div_ceil(RECORDS_PER_BLOCK);
            let count = |b: u64| (layout.records() - b * RECORDS_PER_BLOCK).min(RECORDS_PER_BLOCK);
            let mut settle = Settle::new(layout.clone(), blocks as usize);
            // Finest blocks first (the worst order for a hierarchical layout), one at a time.
            let mut bits: Vec<[u64; WORDS_PER_BLOCK]> = vec![[0; WORDS_PER_BLOCK]; blocks as usize];
            for b in (0..blocks).rev() {
                for (c, words) in settle.add(&[(b, count(b))]) {
                    for (w, n) in bits[c as usize].iter_mut().zip(words) {
                        *w |= n;
                    }
                }
                let on = |i: u64| {
                    let k = (i % RECORDS_PER_BLOCK) as usize;
                    bits[(i / RECORDS_PER_BLOCK) as usize][k / 64] >> (k % 64) & 1 == 1
                };
                for i in 0..layout.records() {
                    let Some((x, y)) = layout.coords(i) else { continue };
                    let (parents, n) = grid.dag_parents(x, y);
                    let parents_on = parents[..n].iter().all(|&(px, py)| on(layout.index(px, py)));
                    let here = i / RECORDS_PER_BLOCK >= b;
                    assert_eq!(on(i), here && parents_on, "{kind}: record {i} at ({x}, {y}) after block {b}");
                }
            }
            assert!(
                (0..layout.records()).all(|i| layout.coords(i).is_none() || settle.is_effective(i)),
                "{kind}: everything arrived, everything effective"
            );
        }
    }

    /// A plan asks for the missed record's block and its descendants', each block once.
    #[test]
    fn a_plan_asks_for_the_miss_and_its_descendants_once() {
        let grid = Grid::new(9).unwrap();
        let layout = AnyLayout::new(LayoutKind::Interleaved, grid, 0, RECORD_BYTES).unwrap();
        let blocks = layout.records().div_ceil(RECORDS_PER_BLOCK) as usize;
        let mut asked = vec![false; blocks];
        asked[0] = true;
        let (cx, cy) = (128, 128);
        let miss = layout.index(cx, cy);
        let plan = plan_blocks(&layout, &mut asked, &[miss], 6);
        assert!(plan.contains(&(miss / RECORDS_PER_BLOCK)) || miss / RECORDS_PER_BLOCK == 0);
        let (children, n) = grid.dag_children(cx, cy);
        for &(x, y) in &children[..n] {
            let b = layout.index(x, y) / RECORDS_PER_BLOCK;
            assert!(b == 0 || plan.contains(&b), "child ({x}, {y}) in block {b}: {plan:?}");
        }
        assert!(plan.windows(2).all(|w| w[0] < w[1]), "ascending, no repeats");
        assert!(plan.iter().all(|&b| asked[b as usize]));
        assert!(plan_blocks(&layout, &mut asked, &[miss], 6).is_empty(), "nothing is asked twice");
    }
}
