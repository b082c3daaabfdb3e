//! The per-frame fetch of the disk-page backend (Sajadi et al. 2009, §5) as a
//! [`FrameSource`]: frustum-cull the disk-page k-d tree, collect the page numbers of the
//! surviving leaves (de-duplicated), cull each page by its box and its normal cone, sort, read
//! the pages whole and in order, and draw every triangle in them. There is no cache of our own:
//! like the paper, the OS page cache is the only one, and each frame reads all its pages again.
//!
//! Pages come through the page file's pager: with read access (the default, the paper's) a run
//! of consecutive page numbers is one `pread`; the map and the buffer pool serve the same pages
//! (see [`crate::pager::Access`]); the pager's observer sees every page read. Bytes read are
//! pages × page size. The seek distance of a frame is Σ |p_i − p_{i−1}| over its pages
//! in read order, in pages, where p_0 is the last page the previous frame read (the "head" stays
//! where the last read left it; page 0 before the first frame), so jumping back to the start of
//! the next frame's range is counted too. Consecutive pages cost 1 each.

use std::time::Instant;

use super::kdtree::{back_facing, box_in_frustum, query_frustum};
use crate::camera::Camera;
use crate::error::Result;
use crate::flight::frame::{Frame, FrameSource, FrameStats, PAGE_CHANGES};
use crate::format::pagefile::PageFile;
use crate::mesh::Bounds;
use crate::pager::{BlockBuf, ReadStats};

/// How the fetch culls.
#[derive(Clone, Copy, Debug)]
pub struct FetchOptions {
    /// Skip pages whose normal cone faces away from the eye. The mesh renderer shades back faces
    /// (scans have holes), so turning this on can open holes where a back face was visible.
    pub backface_cull: bool,
    /// Evict the file from the OS page cache before every frame, so every page a frame reads
    /// comes from storage: the fetch with no cache at all (a measurement mode; the paper leaves
    /// caching to the OS, which this switches off).
    pub evict_each_frame: bool,
}

impl Default for FetchOptions {
    fn default() -> Self {
        FetchOptions { backface_cull: true, evict_each_frame: false }
    }
}

/// A page file flown frame by frame.
pub struct PageSource {
    file: PageFile,
    options: FetchOptions,
    triangles: Vec<[f32; 3]>,
    /// This frame's pages (ascending) and the scratch the next frame's are built in.
    pages: Vec<u32>,
    next_pages: Vec<u32>,
    candidates: Vec<u32>,
    stack: Vec<u32>,
    buf: BlockBuf,
    head_page: u64,
    reads: ReadStats,
    device: crate::pager::device::DeviceStats,
    shown: bool,
}

impl PageSource {
    pub fn new(file: PageFile, options: FetchOptions) -> PageSource {
        PageSource {
            reads: file.pager().reads(),
            device: file.pager().device_or_zero(),
            file,
            options,
            triangles: Vec::new(),
            pages: Vec::new(),
            next_pages: Vec::new(),
            candidates: Vec::new(),
            stack: Vec::new(),
            buf: BlockBuf::default(),
            head_page: 0,
            shown: false,
        }
    }

    pub fn file(&self) -> &PageFile {
        &self.file
    }

    /// The triangles the last update fetched, three world positions each.
    pub fn triangles(&self) -> &[[f32; 3]] {
        &self.triangles
    }

    /// The pages the last update read, ascending.
    pub fn pages(&self) -> &[u32] {
        &self.pages
    }

    /// The pages a view needs, ascending, into `out`: the k-d query, then each page's box and
    /// (when on) normal cone.
    fn select(&mut self, camera: &Camera) {
        let eye = camera.eye_in_world;
        let planes = camera.frustum_normals();
        query_frustum(self.file.kd_nodes(), self.file.kd_refs(), eye, &planes, &mut self.candidates, &mut self.stack);
        let dir = self.file.directory();
        self.next_pages.clear();
        self.next_pages.extend(self.candidates.iter().copied().filter(|&p| {
            let e = &dir[p as usize];
            box_in_frustum(e.box_min, e.box_max, eye, &planes) && !(self.options.backface_cull && back_facing(e, eye))
        }));
    }
}

impl FrameSource for PageSource {
    fn update(&mut self, camera: &Camera, _tolerance_px: f64) -> Result<FrameStats> {
        if self.options.evict_each_frame {
            self.file.evict_from_page_cache()?;
        }
        let started = Instant::now();
        self.select(camera);
        self.triangles.clear();
        let mut read_s = 0.0;
        let mut seek = 0u64;
        let mut head = self.head_page;
        let pages = &self.next_pages;
        let mut i = 0;
        while i < pages.len() {
            let mut j = i;
            while j + 1 < pages.len() && pages[j + 1] == pages[j] + 1 {
                j += 1;
            }
            let (file, triangles) = (&self.file, &mut self.triangles);
            let read = file.for_run(pages[i], (j - i + 1) as u32, &mut self.buf, |p, bytes| {
                seek += (p as u64).abs_diff(head);
                head = p as u64;
                file.decode(p, bytes)?.append_triangles(triangles);
                Ok(())
            })?;
            read_s += read.as_secs_f64();
            i = j + 1;
        }
        self.head_page = head;
        // Pages gained and lost (both lists ascending): the loop re-uploads when either is > 0.
        let (mut gained, mut lost) = (0u64, 0u64);
        let (old, new) = (&self.pages, &self.next_pages);
        let (mut a, mut b) = (0, 0);
        while a < old.len() || b < new.len() {
            match (old.get(a), new.get(b)) {
                (Some(x), Some(y)) if x == y => {
                    a += 1;
                    b += 1;
                }
                (Some(x), Some(y)) if x < y => {
                    lost += 1;
                    a += 1;
                }
                (Some(_), None) => {
                    lost += 1;
                    a += 1;
                }
                _ => {
                    gained += 1;
                    b += 1;
                }
            }
        }
        std::mem::swap(&mut self.pages, &mut self.next_pages);
        let (reads, device) = (self.file.pager().reads(), self.file.pager().device_or_zero());
        let served = device.since(self.device);
        let stats = FrameStats {
            update_ms: Some(started.elapsed().as_secs_f64() * 1e3),
            changed: gained + lost > 0 || !self.shown,
            triangles: self.triangles.len() as u64 / 3,
            pages_gained: gained,
            pages_lost: lost,
            pages_read: reads.pages - self.reads.pages,
            bytes_read: reads.bytes - self.reads.bytes,
            pages_candidate: self.candidates.len() as u64,
            pages_requested: self.pages.len() as u64,
            seek_pages: seek,
            read_ms: read_s * 1e3,
            device_requests: served.requests,
            device_ms: served.device_s * 1e3,
            ..FrameStats::default()
        };
        self.reads = reads;
        self.device = device;
        self.shown = true;
        Ok(stats)
    }

    fn frame(&self) -> Frame<'_> {
        Frame::Triangles(&self.triangles)
    }

    fn bounds(&self) -> Bounds {
        self.file.header().bounds
    }

    fn changes(&self) -> &'static str {
        PAGE_CHANGES
    }

    fn describe(&self) -> String {
        let h = self.file.header();
        format!(
            "pages, {} layout, {} pages of {} B, {} access",
            h.layout.name(),
            h.pages,
            h.page_bytes,
            self.file.pager().access().name()
        ) + &crate::pager::device::describe(self.file.pager().device_spec())
    }
}
