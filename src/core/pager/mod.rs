//! The pager: how every backend reads its file. The terrain's vertex records, the meta-node
//! trees' blocks and the disk pages all come through a [`Pager`], which sees a file as numbered
//! blocks (a [`BlockTable`]: a terrain's runs of records, a meta-node, a page) and reads them in
//! one of three ways ([`Access`]):
//!
//! - **map**: a read-only memory map; the OS pages the file in and blocks are borrowed in place.
//!   The terrain paper's choice, and the meta-node paper's "Virt" column.
//! - **read**: a positioned read (`pread`) of each block when it is wanted, with no cache of our
//!   own: the OS page cache is the only one. The disk-page paper's fetch.
//! - **pool**: an explicit buffer pool ([`pool::BufferPool`], El-Sana & Chiang §3.3) of as many
//!   block-sized place holders as a memory budget allows, with an I/O thread, speculative and
//!   urgent prefetch. The meta-node paper's "Ext" column.
//!
//! Bytes come from a [`source::Source`] (a map or a file read with `pread`). An
//! [`observer::PageObserver`] attached to a pager ([`Pager::observe`]) sees every byte range the
//! pager takes from the file: each block borrowed from the map, each positioned read, each load
//! of the pool's. It counts page faults by a model ([`observer::LruTrace`]) or from the OS
//! ([`observer::OsFaults`]). Without one nothing is reported; the terrain's per-record hot path
//! is generic over the observer ([`crate::refine::MappedRecords`]), so the plain path pays
//! nothing for the experiments.

pub mod device;
#[cfg(feature = "device")]
pub mod fuse;
pub mod hosted;
pub mod lru;
pub mod observer;
pub mod os;
pub mod pool;
pub mod remote;
#[cfg(feature = "serve")]
pub mod serve;
pub mod source;
pub mod sparse;
#[cfg(feature = "native")]
pub mod upload;

use std::ops::Deref;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use serde::Serialize;

use crate::error::{Error, Result};
pub use lru::{CacheStats, LruCache};
pub use observer::{Faults, Granules, LruTrace, NoTrace, OsFaults, PageObserver};
pub use os::{drop_from_page_cache, MemoryCap};
pub use pool::PoolIo;
use pool::{holders_for, BlockLoader, BufferPool};
pub use source::RemoteStats;
use source::{Source, SourceKind, PAGE_BYTES};

/// Opens `path` as a source of the given kind. A remote location (`http(s)://`, `s3://`, see
/// [`remote`]) is read with range requests through its local cache, whatever the kind.
pub fn open(path: &std::path::Path, kind: SourceKind) -> Result<Arc<dyn Source>> {
    open_on(path, kind, None)
}

/// [`open`], a local file served through an emulated device when `device` is given (see
/// [`device`]; the `device` feature): mapped or read as asked, from the device's served copy.
pub fn open_on(
    path: &std::path::Path,
    kind: SourceKind,
    device: Option<device::DeviceSpec>,
) -> Result<Arc<dyn Source>> {
    if let Some(spec) = device {
        if remote::is_remote(path) {
            return Err(Error::InvalidArgument(format!(
                "{}: an emulated device is for local files (a remote one has its own latency)",
                path.display()
            )));
        }
        #[cfg(feature = "device")]
        return Ok(Arc::new(fuse::OnDevice::open(path, kind, spec)?));
        #[cfg(not(feature = "device"))]
        return Err(Error::InvalidArgument(format!(
            "{}: an emulated device ({spec}) needs relief built with the `device` feature",
            path.display()
        )));
    }
    #[cfg(not(feature = "native"))]
    return Err(Error::InvalidArgument(format!(
        "{}: files are opened by the host in this build (pager::memory), not by path",
        path.display()
    )));
    #[cfg(feature = "native")]
    if remote::is_remote(path) {
        let location = path.to_string_lossy();
        return Ok(Arc::new(remote::RemoteFile::open(&location, remote::RemoteOptions::from_env()?)?));
    }
    #[cfg(feature = "native")]
    Ok(match kind {
        SourceKind::Map => Arc::new(source::MappedFile::open(path)?),
        SourceKind::Read => Arc::new(source::ReadFile::open(path)?),
    })
}

/// Page size, validated: a power of two.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PageGeometry {
    pub page_bytes: u64,
    shift: u32,
}

impl PageGeometry {
    pub fn new(page_bytes: u64) -> Result<PageGeometry> {
        if page_bytes == 0 || !page_bytes.is_power_of_two() {
            return Err(Error::out_of_range("page size", "a power of two", format!("{page_bytes} bytes")));
        }
        Ok(PageGeometry { page_bytes, shift: page_bytes.trailing_zeros() })
    }

    /// The page holding byte `offset`.
    #[inline(always)]
    pub fn page_of(&self, offset: u64) -> u64 {
        offset >> self.shift
    }

    /// Pages needed to hold `bytes` (rounded up).
    pub fn pages_for(&self, bytes: u64) -> u64 {
        bytes.div_ceil(self.page_bytes)
    }
}

/// How a pager reads its file's blocks.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase", tag = "mode")]
pub enum Access {
    /// A read-only memory map (the OS pages it in).
    Map,
    /// A positioned read of each block when it is wanted; only the OS caches.
    Read,
    /// A buffer pool of `bytes` of place holders with an I/O thread.
    Pool { bytes: u64 },
}

impl Access {
    /// The names the command line takes.
    pub const NAMES: [&'static str; 3] = ["map", "read", "pool"];

    pub fn name(self) -> &'static str {
        match self {
            Access::Map => "map",
            Access::Read => "read",
            Access::Pool { .. } => "pool",
        }
    }

    /// The source this access reads from.
    pub fn source_kind(self) -> SourceKind {
        match self {
            Access::Map => SourceKind::Map,
            Access::Read | Access::Pool { .. } => SourceKind::Read,
        }
    }
}

/// Where a block lies in its file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Extent {
    pub offset: u64,
    pub bytes: u64,
}

/// A file seen as numbered blocks.
pub trait BlockTable: Send + Sync + 'static {
    /// Blocks `0..blocks()`.
    fn blocks(&self) -> u32;
    /// Block `id`'s bytes in the file (`None` out of range).
    fn extent(&self, id: u32) -> Option<Extent>;
    /// The largest block (a place holder's size).
    fn max_block_bytes(&self) -> u64;
    /// The file's page size: a block of `b` bytes costs ⌈b / page⌉ page reads.
    fn page_bytes(&self) -> u64 {
        4096
    }
}

/// Blocks of `block_bytes` from byte `first` to byte `end` (the last one may be shorter), in a
/// file of `page_bytes` pages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FixedBlocks {
    pub first: u64,
    pub block_bytes: u64,
    pub end: u64,
    pub page_bytes: u64,
}

impl BlockTable for FixedBlocks {
    fn blocks(&self) -> u32 {
        (self.end.saturating_sub(self.first)).div_ceil(self.block_bytes.max(1)).min(u32::MAX as u64) as u32
    }

    fn extent(&self, id: u32) -> Option<Extent> {
        let offset = self.first.checked_add((id as u64).checked_mul(self.block_bytes)?)?;
        (offset < self.end).then(|| Extent { offset, bytes: self.block_bytes.min(self.end - offset) })
    }

    fn max_block_bytes(&self) -> u64 {
        self.block_bytes.min(self.end.saturating_sub(self.first))
    }

    fn page_bytes(&self) -> u64 {
        self.page_bytes
    }
}

/// Blocks listed one by one (the meta-node table), in a file of `page_bytes` pages.
#[derive(Clone, Debug, Default)]
pub struct ExtentTable {
    pub extents: Vec<Extent>,
    pub page_bytes: u64,
}

impl BlockTable for ExtentTable {
    fn blocks(&self) -> u32 {
        self.extents.len().min(u32::MAX as usize) as u32
    }

    fn extent(&self, id: u32) -> Option<Extent> {
        self.extents.get(id as usize).copied()
    }

    fn max_block_bytes(&self) -> u64 {
        self.extents.iter().map(|e| e.bytes).max().unwrap_or(0)
    }

    fn page_bytes(&self) -> u64 {
        self.page_bytes
    }
}

/// Storage for one block, 8-byte aligned so that readers can view records and nodes in place.
#[derive(Clone, Debug, Default)]
pub struct BlockBuf {
    words: Vec<u64>,
    len: usize,
}

impl BlockBuf {
    /// Sets the length to `len` bytes (new bytes are zero).
    pub fn resize(&mut self, len: usize) {
        self.words.resize(len.div_ceil(8), 0);
        self.len = len;
    }

    pub fn bytes(&self) -> &[u8] {
        &bytemuck::cast_slice(&self.words)[..self.len]
    }

    pub fn bytes_mut(&mut self) -> &mut [u8] {
        &mut bytemuck::cast_slice_mut(&mut self.words)[..self.len]
    }
}

/// A block's bytes: borrowed from the map, read into storage of its own, or shared with the pool.
pub enum Block<'a> {
    Mapped(&'a [u8]),
    Read(BlockBuf),
    Pooled(Arc<BlockBuf>),
}

impl Deref for Block<'_> {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            Block::Mapped(b) => b,
            Block::Read(b) => b.bytes(),
            Block::Pooled(b) => b.bytes(),
        }
    }
}

/// Blocks and bytes a pager read from its source (read and pool modes; what a map reads is the
/// OS's page faults).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct ReadStats {
    pub blocks: u64,
    /// Pages of the file the blocks cover (a block costs ⌈bytes / page⌉).
    pub pages: u64,
    pub bytes: u64,
}

#[derive(Debug, Default)]
struct ReadCounter {
    blocks: AtomicU64,
    pages: AtomicU64,
    bytes: AtomicU64,
}

impl ReadCounter {
    fn add(&self, table: &dyn BlockTable, blocks: u64, bytes: u64) {
        self.blocks.fetch_add(blocks, Ordering::Relaxed);
        self.pages.fetch_add(bytes.div_ceil(table.page_bytes().max(1)), Ordering::Relaxed);
        self.bytes.fetch_add(bytes, Ordering::Relaxed);
    }

    fn get(&self) -> ReadStats {
        ReadStats {
            blocks: self.blocks.load(Ordering::Relaxed),
            pages: self.pages.load(Ordering::Relaxed),
            bytes: self.bytes.load(Ordering::Relaxed),
        }
    }
}

/// The observer a pager (and its pool's loader) reports to, set at most once.
type ObserverSlot = Arc<OnceLock<Arc<dyn PageObserver>>>;

fn report(slot: &ObserverSlot, e: Extent) {
    if let Some(o) = slot.get() {
        o.read(e.offset, e.bytes);
    }
}

/// Reads a table's blocks from a source, for the buffer pool.
pub struct SourceLoader {
    source: Arc<dyn Source>,
    table: Arc<dyn BlockTable>,
    reads: ReadCounter,
    observer: ObserverSlot,
}

impl SourceLoader {
    fn read(&self, id: u32, buf: &mut BlockBuf) -> Result<()> {
        let e = extent_of(&*self.source, &*self.table, id)?;
        buf.resize(e.bytes as usize);
        self.source.read_at(e.offset, buf.bytes_mut())?;
        self.reads.add(&*self.table, 1, e.bytes);
        report(&self.observer, e);
        Ok(())
    }
}

impl BlockLoader for SourceLoader {
    type Block = BlockBuf;
    fn load(&self, id: u32, recycled: Option<BlockBuf>) -> Result<BlockBuf> {
        let mut buf = recycled.unwrap_or_default();
        self.read(id, &mut buf)?;
        Ok(buf)
    }

    /// Consecutive blocks lie in file order with at most a page's padding between them (as every
    /// relief file writes them); anything else is not coalesced.
    fn span_bytes(&self, first: u32, last: u32) -> Option<u64> {
        let a = self.table.extent(first)?;
        let b = self.table.extent(last)?;
        if first == last {
            return Some(a.bytes);
        }
        let page = self.table.page_bytes().max(1);
        let (mut end, mut id) = (a.offset + a.bytes, first + 1);
        while id <= last {
            let e = self.table.extent(id)?;
            if e.offset < end || e.offset - end >= page {
                return None;
            }
            end = e.offset + e.bytes;
            id += 1;
        }
        Some(b.offset + b.bytes - a.offset)
    }

    fn load_run(&self, first: u32, count: u32, recycled: &mut Vec<BlockBuf>) -> Result<Vec<BlockBuf>> {
        if count == 0 || self.span_bytes(first, first + (count - 1)).is_none() {
            return (first..first + count).map(|id| self.load(id, recycled.pop())).collect();
        }
        // One request for the whole span, then each block copied out of it.
        let mut span = BlockBuf::default();
        let mut blocks = Vec::with_capacity(count as usize);
        read_span(&*self.source, &*self.table, &self.reads, &self.observer, first, count, &mut span, |_, bytes| {
            let mut buf = recycled.pop().unwrap_or_default();
            buf.resize(bytes.len());
            buf.bytes_mut().copy_from_slice(bytes);
            blocks.push(buf);
            Ok(())
        })?;
        Ok(blocks)
    }
}

/// Reads blocks `first..first + count` (`count ≥ 1`, in file order) in one request, from the
/// first block's start to the last one's end, into `span`; counts the span's bytes in `reads`,
/// reports each block to the observer and hands it to `f`. Returns the time the read took
/// (not counting `f`).
#[allow(clippy::too_many_arguments, reason = "internal; each argument is a distinct input")]
fn read_span(
    source: &dyn Source,
    table: &dyn BlockTable,
    reads: &ReadCounter,
    observer: &ObserverSlot,
    first: u32,
    count: u32,
    span: &mut BlockBuf,
    mut f: impl FnMut(u32, &[u8]) -> Result<()>,
) -> Result<Duration> {
    let started = Instant::now();
    let start = extent_of(source, table, first)?;
    let last = extent_of(source, table, first + (count - 1))?;
    let end = last.offset + last.bytes;
    span.resize((end - start.offset) as usize);
    source.read_at(start.offset, span.bytes_mut())?;
    let read = started.elapsed();
    reads.add(table, count as u64, end - start.offset);
    for id in first..first + count {
        let e = extent_of(source, table, id)?;
        report(observer, e);
        let at = (e.offset - start.offset) as usize;
        f(id, &span.bytes()[at..at + e.bytes as usize])?;
    }
    Ok(read)
}

/// The pages `[p, q)` an extent lies on.
fn pages_of(e: Extent) -> (u64, u64) {
    (e.offset / PAGE_BYTES, (e.offset + e.bytes).div_ceil(PAGE_BYTES))
}

/// Runs `[p, q)` sorted, and merged where they touch or overlap.
fn merge_runs(mut runs: Vec<(u64, u64)>) -> Vec<(u64, u64)> {
    runs.sort_unstable();
    let mut out: Vec<(u64, u64)> = Vec::with_capacity(runs.len());
    for (p, q) in runs {
        match out.last_mut() {
            Some(last) if last.1 >= p => last.1 = last.1.max(q),
            _ => out.push((p, q)),
        }
    }
    out
}

fn extent_of(source: &dyn Source, table: &dyn BlockTable, id: u32) -> Result<Extent> {
    table.extent(id).ok_or_else(|| Error::BlockOutOfRange {
        path: source.path().to_path_buf(),
        block: id,
        blocks: table.blocks(),
    })
}

enum Mode {
    Map,
    Read(ReadCounter),
    Pool(BufferPool<SourceLoader>),
}

/// A file's blocks, read one of the three ways.
pub struct Pager {
    source: Arc<dyn Source>,
    table: Arc<dyn BlockTable>,
    access: Access,
    mode: Mode,
    observer: ObserverSlot,
}

impl Pager {
    /// A pager over `source`'s blocks as `table` numbers them. `Map` needs a mapped source, except
    /// a remote file, which is read instead (every file kind opens remote locations alike); a
    /// pool gets as many place holders as `bytes` allows for the table's largest block.
    pub fn new(source: Arc<dyn Source>, table: Arc<dyn BlockTable>, access: Access) -> Result<Pager> {
        Pager::with_io(source, table, access, PoolIo::default())
    }

    /// [`Self::new`], a pool's I/O issued as `io` says (threads, coalesced requests). The memory
    /// budget covers the I/O threads' requests in flight too: each may hold two copies of a
    /// coalesced span (the read and the blocks cut from it) on top of the holders.
    pub fn with_io(source: Arc<dyn Source>, table: Arc<dyn BlockTable>, access: Access, io: PoolIo) -> Result<Pager> {
        let observer = ObserverSlot::default();
        let access = if access == Access::Map && source.network().is_some() { Access::Read } else { access };
        let mode = match access {
            Access::Map => {
                if source.mapped().is_none() {
                    return Err(Error::InvalidArgument(format!(
                        "{}: mapped access needs a mapped source",
                        source.path().display()
                    )));
                }
                Mode::Map
            }
            Access::Read => Mode::Read(ReadCounter::default()),
            Access::Pool { bytes } => {
                let block = table.max_block_bytes().max(1);
                // One block of staging per thread, or two spans when coalescing; holders_for keeps
                // one block back itself.
                let per_thread = block.max(2 * io.coalesce_bytes.div_ceil(block) * block);
                let reserve = (per_thread * io.threads as u64).saturating_sub(block);
                let holders = holders_for(bytes.saturating_sub(reserve), block).map_err(|e| match e {
                    Error::InvalidArgument(m) if reserve > 0 => Error::InvalidArgument(format!(
                        "{m}, after {reserve} bytes for {} I/O thread(s) and their coalesced reads",
                        io.threads
                    )),
                    e => e,
                })?;
                let loader = SourceLoader {
                    source: Arc::clone(&source),
                    table: Arc::clone(&table),
                    reads: ReadCounter::default(),
                    observer: Arc::clone(&observer),
                };
                Mode::Pool(BufferPool::with_io(loader, holders, io)?)
            }
        };
        Ok(Pager { source, table, access, mode, observer })
    }

    /// Reports every byte range this pager takes from the file from now on to `observer`: blocks
    /// borrowed from the map, positioned reads, the pool's loads (not its hits: those cost no
    /// I/O). One observer per pager; a second is refused.
    pub fn observe(&self, observer: Arc<dyn PageObserver>) -> Result<()> {
        self.observer.set(observer).map_err(|_| {
            Error::InvalidArgument(format!("{}: the pager already has an observer", self.source.path().display()))
        })
    }

    /// The attached observer, if any.
    pub fn observer(&self) -> Option<&dyn PageObserver> {
        self.observer.get().map(|o| &**o)
    }

    pub fn access(&self) -> Access {
        self.access
    }

    pub fn source(&self) -> &dyn Source {
        &*self.source
    }

    pub fn table(&self) -> &dyn BlockTable {
        &*self.table
    }

    /// The whole file in memory (map access only).
    pub fn mapped(&self) -> Option<&[u8]> {
        match self.mode {
            Mode::Map => self.source.mapped(),
            _ => None,
        }
    }

    /// The buffer pool (pool access only), for the meta-node navigator's protocol (usage and
    /// reference counts, urgent prefetch).
    pub fn pool(&self) -> Option<&BufferPool<SourceLoader>> {
        match &self.mode {
            Mode::Pool(p) => Some(p),
            _ => None,
        }
    }

    /// Where block `id` lies in the file.
    pub fn extent(&self, id: u32) -> Result<Extent> {
        extent_of(&*self.source, &*self.table, id)
    }

    /// Block `id`, now: borrowed from the map, read from the file, or from the pool (read on the
    /// calling thread when no holder has it).
    pub fn block(&self, id: u32) -> Result<Block<'_>> {
        match &self.mode {
            Mode::Map => {
                let e = self.extent(id)?;
                let map = self.source.mapped().expect("map access has a mapped source");
                report(&self.observer, e);
                Ok(Block::Mapped(&map[e.offset as usize..(e.offset + e.bytes) as usize]))
            }
            Mode::Read(reads) => {
                let e = self.extent(id)?;
                let mut buf = BlockBuf::default();
                buf.resize(e.bytes as usize);
                self.source.read_at(e.offset, buf.bytes_mut())?;
                reads.add(&*self.table, 1, e.bytes);
                report(&self.observer, e);
                Ok(Block::Read(buf))
            }
            Mode::Pool(pool) => Ok(Block::Pooled(pool.get_or_load(id)?)),
        }
    }

    /// Block `id` if it can be had without waiting: always with map and read access; from the
    /// pool only when a holder has it (otherwise an urgent load is queued and `None` returned).
    pub fn try_block(&self, id: u32) -> Result<Option<Block<'_>>> {
        match &self.mode {
            Mode::Pool(pool) => match pool.get(id) {
                Some(b) => Ok(Some(Block::Pooled(b))),
                None => {
                    pool.request_urgent(id, pool::Direction::Up);
                    Ok(None)
                }
            },
            _ => self.block(id).map(Some),
        }
    }

    /// Calls `f` with blocks `first .. first + count` in order. Read access reads the run with
    /// one `pread` into `buf` (the blocks must be contiguous in the file, as pages are); map
    /// access borrows each block; the pool hands over each block as [`block`](Self::block) does.
    ///
    /// Returns the time spent getting the bytes, not counting `f`: the `pread` with read
    /// access, the lookups and waits with pool access, zero with map access (its page faults
    /// happen where `f` touches the bytes and cannot be told apart).
    pub fn for_run(
        &self,
        first: u32,
        count: u32,
        buf: &mut BlockBuf,
        mut f: impl FnMut(u32, &[u8]) -> Result<()>,
    ) -> Result<Duration> {
        if count == 0 {
            return Ok(Duration::ZERO);
        }
        match &self.mode {
            Mode::Read(reads) => read_span(&*self.source, &*self.table, reads, &self.observer, first, count, buf, f),
            Mode::Map => {
                for id in first..first + count {
                    let b = self.block(id)?;
                    f(id, &b)?;
                }
                Ok(Duration::ZERO)
            }
            Mode::Pool(_) => {
                let mut read = Duration::ZERO;
                for id in first..first + count {
                    let t = Instant::now();
                    let b = self.block(id)?;
                    read += t.elapsed();
                    f(id, &b)?;
                }
                Ok(read)
            }
        }
    }

    /// What this pager has read from its source so far (map access: nothing it can count).
    pub fn reads(&self) -> ReadStats {
        self.read_counter().map(ReadCounter::get).unwrap_or_default()
    }

    /// Where this pager counts its reads (map access: nowhere, the OS pages the file in).
    fn read_counter(&self) -> Option<&ReadCounter> {
        match &self.mode {
            Mode::Map => None,
            Mode::Read(r) => Some(r),
            Mode::Pool(p) => Some(&p.loader().reads),
        }
    }

    /// What the emulated device under this pager's file has served, if it is on one.
    pub fn device(&self) -> Option<device::DeviceStats> {
        self.source.device_stats()
    }

    /// [`Self::device`], zero without a device (for per-frame differences).
    pub fn device_or_zero(&self) -> device::DeviceStats {
        self.device().unwrap_or_default()
    }

    /// The emulated device under this pager's file, if it is on one.
    pub fn device_spec(&self) -> Option<device::DeviceSpec> {
        self.source.device_spec()
    }

    /// What reading this pager's file has cost over the network, where it is remote.
    pub fn network(&self) -> Option<RemoteStats> {
        self.source.network()
    }

    /// Whether the file is read over a network (every read may wait on it).
    pub fn is_remote(&self) -> bool {
        self.source.network().is_some()
    }

    /// Which blocks `0..blocks()` can be had now without waiting on a network: all of a local
    /// file's; of a remote file's, those whose pages are in its local cache.
    pub fn resident_blocks(&self) -> Result<Vec<bool>> {
        let n = self.table.blocks();
        let pages = self.source.len().div_ceil(PAGE_BYTES);
        let resident = self.source.resident_pages(0, pages)?;
        (0..n)
            .map(|id| {
                let (p, q) = pages_of(self.extent(id)?);
                Ok(resident.get(p as usize..q as usize).is_some_and(|r| r.iter().all(|&x| x)))
            })
            .collect()
    }

    /// Reads blocks `ids` in as few requests as the source can make (a remote file: coalesced
    /// range requests, several in flight; pages in its cache without any) and calls `f` with
    /// each, in ascending order of id, as records of `T` (a block must hold whole records), so
    /// that the bytes are copied once, from the source into the records. Counted in
    /// [`Self::reads`] (read and pool access) and reported to the observer as any other read. For
    /// look-ahead: many blocks asked for at once cost one round trip, where [`Self::block`] costs
    /// one each.
    pub fn read_blocks<T: bytemuck::Pod>(
        &self,
        ids: &[u32],
        mut f: impl FnMut(u32, Box<[T]>) -> Result<()>,
    ) -> Result<()> {
        let mut ids = ids.to_vec();
        ids.sort_unstable();
        ids.dedup();
        let extents = ids.iter().map(|&id| self.extent(id)).collect::<Result<Vec<Extent>>>()?;
        // Blocks of one table ascend in the file with their ids (every relief table does).
        let ordered = extents.windows(2).all(|w| w[0].offset + w[0].bytes <= w[1].offset);
        if !ordered {
            return Err(Error::InvalidArgument(format!(
                "{}: blocks to read together overlap or are out of file order",
                self.source.path().display()
            )));
        }
        let record = std::mem::size_of::<T>().max(1) as u64;
        if let Some(e) = extents.iter().find(|e| e.bytes % record != 0) {
            return Err(Error::InvalidArgument(format!(
                "{}: a block of {} bytes at {} is not whole {record}-byte records",
                self.source.path().display(),
                e.bytes,
                e.offset
            )));
        }
        let mut blocks: Vec<Box<[T]>> =
            extents.iter().map(|e| bytemuck::zeroed_slice_box((e.bytes / record) as usize)).collect();
        // Page runs covering the blocks, merged where they touch.
        let runs = merge_runs(extents.iter().map(|&e| pages_of(e)).collect());
        self.source.read_page_runs(&runs, &mut |page, bytes| {
            let (lo, hi) = (page * PAGE_BYTES, page * PAGE_BYTES + bytes.len() as u64);
            // The first block ending after `lo`, then every block starting before `hi`.
            let first = extents.partition_point(|e| e.offset + e.bytes <= lo);
            for (e, block) in extents[first..].iter().zip(&mut blocks[first..]) {
                if e.offset >= hi {
                    break;
                }
                let (s, t) = (e.offset.max(lo), (e.offset + e.bytes).min(hi));
                if s < t {
                    bytemuck::cast_slice_mut::<T, u8>(block)[(s - e.offset) as usize..(t - e.offset) as usize]
                        .copy_from_slice(&bytes[(s - lo) as usize..(t - lo) as usize]);
                }
            }
            Ok(())
        })?;
        let counter = self.read_counter();
        for ((&id, e), block) in ids.iter().zip(&extents).zip(blocks) {
            if let Some(c) = counter {
                c.add(&*self.table, 1, e.bytes);
            }
            report(&self.observer, *e);
            f(id, block)?;
        }
        Ok(())
    }

    /// The byte ranges `[start, end)` of the file as stored that [`Self::read_blocks`] of `ids`
    /// reads: what a host that supplies the bytes ([`hosted`]) fetches first. Ascending, pages
    /// that touch merged, whole pages (the last may end at the file's end).
    pub fn stored_ranges(&self, ids: &[u32]) -> Result<Vec<(u64, u64)>> {
        let runs = merge_runs(ids.iter().map(|&id| self.extent(id).map(pages_of)).collect::<Result<_>>()?);
        let out = merge_runs(self.source.stored_runs(&runs));
        let len = self.source.len();
        Ok(out.into_iter().map(|(p, q)| (p * PAGE_BYTES, (q * PAGE_BYTES).min(len))).filter(|r| r.0 < r.1).collect())
    }

    /// No readahead (see [`Source::advise_random`]).
    pub fn advise_random(&self) -> Result<()> {
        self.source.advise_random()
    }

    /// Drops the file from the OS page cache (see [`Source::evict`]); the pool keeps its blocks.
    pub fn evict(&self) -> Result<()> {
        self.source.evict()
    }

    /// Bytes outside the block table (a file's trailing sections, a checksum pass) read from the
    /// source and reported to the observer as a read of that range; not counted in [`Self::reads`],
    /// which counts blocks.
    pub fn read_range(&self, offset: u64, buf: &mut [u8]) -> Result<()> {
        self.source.read_at(offset, buf)?;
        report(&self.observer, Extent { offset, bytes: buf.len() as u64 });
        Ok(())
    }

    /// A cold start for measurements: readahead off, then the file dropped from the OS page
    /// cache. Called after the open: reading the header through a fresh map faults in a whole
    /// readahead window (`read_ahead_kb`, 8 MiB on some virtual disks), which would otherwise
    /// leave a small file resident before the first counted frame.
    pub fn start_cold(&self) -> Result<()> {
        self.source.advise_random()?;
        self.source.evict()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file_of(len: usize) -> (tempfile::TempDir, std::path::PathBuf, Vec<u8>) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("blocks.bin");
        let bytes: Vec<u8> = (0..len).map(|i| (i * 31 % 253) as u8).collect();
        std::fs::write(&path, &bytes).unwrap();
        (dir, path, bytes)
    }

    #[test]
    fn fixed_blocks_cover_the_range_and_the_last_is_short() {
        let t = FixedBlocks { first: 100, block_bytes: 64, end: 300, page_bytes: 64 };
        assert_eq!(t.blocks(), 4);
        assert_eq!(t.extent(0), Some(Extent { offset: 100, bytes: 64 }));
        assert_eq!(t.extent(3), Some(Extent { offset: 292, bytes: 8 }));
        assert_eq!(t.extent(4), None);
        assert_eq!(t.extent(u32::MAX), None);
    }

    #[test]
    fn every_access_gives_the_same_bytes() {
        let (_dir, path, bytes) = file_of(40_000);
        let table: Arc<dyn BlockTable> =
            Arc::new(FixedBlocks { first: 96, block_bytes: 4096, end: 40_000, page_bytes: 4096 });
        for access in [Access::Map, Access::Read, Access::Pool { bytes: 6 * 4096 }] {
            let pager = Pager::new(open(&path, access.source_kind()).unwrap(), table.clone(), access).unwrap();
            for id in [0u32, 9, 3, 0, 9] {
                let e = pager.extent(id).unwrap();
                let want = &bytes[e.offset as usize..(e.offset + e.bytes) as usize];
                assert_eq!(&*pager.block(id).unwrap(), want, "{access:?} block {id}");
            }
            let mut seen = Vec::new();
            let mut buf = BlockBuf::default();
            pager
                .for_run(2, 5, &mut buf, |id, b| {
                    let e = pager.extent(id).unwrap();
                    assert_eq!(b, &bytes[e.offset as usize..(e.offset + e.bytes) as usize]);
                    seen.push(id);
                    Ok(())
                })
                .unwrap();
            assert_eq!(seen, [2, 3, 4, 5, 6]);
            assert!(pager.block(10).is_err());
            match access {
                Access::Map => assert_eq!(pager.reads(), ReadStats::default()),
                Access::Read => assert_eq!(pager.reads().blocks, 5 + 5),
                // Blocks 0, 9, 3 read once each; the run reads 2, 4, 5, 6 (3 is held).
                Access::Pool { .. } => assert_eq!(pager.reads().blocks, 3 + 4),
            }
        }
    }

    #[test]
    fn the_observer_sees_what_each_access_takes_from_the_file() {
        let (_dir, path, _) = file_of(16 * 1024);
        let table: Arc<dyn BlockTable> =
            Arc::new(FixedBlocks { first: 0, block_bytes: 1024, end: 16 * 1024, page_bytes: 1024 });
        for access in [Access::Map, Access::Read, Access::Pool { bytes: 8 * 1024 }] {
            let pager = Pager::new(open(&path, access.source_kind()).unwrap(), table.clone(), access).unwrap();
            let trace = Arc::new(LruTrace::new(LruCache::with_pages(64), PageGeometry::new(1024).unwrap()));
            pager.observe(trace.clone()).unwrap();
            assert!(pager.observe(trace.clone()).is_err(), "one observer per pager");
            for id in [1u32, 2, 1, 1, 5] {
                pager.block(id).unwrap();
            }
            let mut buf = BlockBuf::default();
            pager.for_run(6, 3, &mut buf, |_, _| Ok(())).unwrap();
            // Map and read see every access (a repeat of the page just read is not a touch);
            // the pool only its loads (1, 2 and 5 once each).
            let stats = trace.stats();
            let touches = stats.hits + stats.misses;
            match access {
                Access::Map | Access::Read => assert_eq!(touches, 4 + 3, "{access:?}"),
                Access::Pool { .. } => assert_eq!(touches, 3 + 3, "{access:?}"),
            }
            assert_eq!(stats.distinct_pages, 6, "{access:?}");
        }
    }

    #[test]
    fn the_pool_can_be_asked_without_waiting() {
        let (_dir, path, _) = file_of(10 * 1024);
        let table: Arc<dyn BlockTable> =
            Arc::new(FixedBlocks { first: 0, block_bytes: 1024, end: 10 * 1024, page_bytes: 1024 });
        let access = Access::Pool { bytes: 8 * 1024 };
        let pager = Pager::new(open(&path, access.source_kind()).unwrap(), table, access).unwrap();
        assert!(pager.try_block(4).unwrap().is_none(), "not resident: an urgent load is queued");
        pager.pool().unwrap().drain().unwrap();
        assert!(pager.try_block(4).unwrap().is_some());
        let e = Pager::new(
            open(&path, SourceKind::Read).unwrap(),
            Arc::new(FixedBlocks { first: 0, block_bytes: 1024, end: 10 * 1024, page_bytes: 1024 }),
            Access::Map,
        )
        .err()
        .unwrap();
        assert!(e.to_string().contains("mapped source"), "{e}");
    }

    #[test]
    fn a_coalesced_pool_read_is_one_request_over_consecutive_blocks() {
        let (_dir, path, bytes) = file_of(16 * 1024);
        let table: Arc<dyn BlockTable> =
            Arc::new(FixedBlocks { first: 0, block_bytes: 1024, end: 16 * 1024, page_bytes: 1024 });
        let access = Access::Pool { bytes: 16 * 1024 };
        let io = PoolIo { threads: 1, coalesce_bytes: 4 * 1024 };
        let pager = Pager::with_io(open(&path, access.source_kind()).unwrap(), table, access, io).unwrap();
        let pool = pager.pool().unwrap();
        pool.hold(true);
        // 0, 2, 3 in one request (1 read between them and dropped); 9 alone.
        for id in [0, 2, 3, 9] {
            assert!(pool.reference(id, 1));
        }
        pool.drain().unwrap();
        let s = pool.stats();
        assert_eq!((s.read_requests, s.disk_reads, s.gap_blocks), (2, 5, 1), "{s:?}");
        assert_eq!(pager.reads().blocks, 5);
        for id in [0u32, 2, 3, 9] {
            let e = pager.extent(id).unwrap();
            let held = pool.get(id).unwrap_or_else(|| panic!("block {id} not loaded"));
            assert_eq!(held.bytes(), &bytes[e.offset as usize..(e.offset + e.bytes) as usize], "block {id}");
        }
        assert!(pool.get(1).is_none(), "a gap block is not installed");
    }
}
