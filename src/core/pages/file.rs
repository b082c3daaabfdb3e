//! The page file (Sajadi et al. 2009, §3, Figure 2): a triangle soup as a sequence of
//! self-contained fixed-size pages, each holding whole triangles and copies of the vertices they
//! use, with a directory (bounding box and normal cone per page) and the disk-page k-d tree
//! ([`super::kdtree`]) stored before the pages.
//!
//! # Page file (little-endian)
//! ```text
//! offset size  field
//!      0    8  magic "\x89RLFPGS\n"
//!      8    4  version (1)
//!     12    4  header bytes (256)
//!     16    4  page bytes (a power of two, 1 KiB to 1 MiB)
//!     20    4  layout (0 raster, 1 2-factor, 2 Hilbert)
//!     24    8  pages, 32: triangles, 40: vertex copies (Σ over pages), 48: source vertices
//!     56    8  directory offset (256): `pages` × 48-byte entries
//!     64    8  k-d nodes, 72: their offset (40 bytes each)
//!     80    8  k-d page references, 88: their offset (u32 page numbers)
//!     96    8  data offset (a multiple of the page size); the pages run to the end of the file
//!    104   48  bounding box min x, y, z, max x, y, z (f64, of the f32 positions)
//!    152    8  tables checksum: XXH3-64 of the directory, k-d nodes and references
//!    160   88  reserved (0)
//!    248    8  header checksum: XXH3-64 of bytes 0..248
//! ```
//! Directory entry (48 bytes): box min, max (f32 × 3 each), normal-cone axis (f32 × 3),
//! half-angle (f32 radians), triangles, vertices (u32 each).
//!
//! Page (`page bytes`, zero-padded): vertices (u16), triangles (u16), index bytes (u8: 1 when at
//! most 256 vertices, else 2), 3 reserved bytes; then per vertex 22 bytes: position (f32 × 3),
//! normal (i16 × 3, unit × 32767), colour (RGBA8); then per triangle three local indices
//! (u8, or u16 little-endian), counter-clockwise as in the input.
//!
//! Pages are filled greedily in layout order: a triangle goes into the current page when the page
//! still fits it with its new vertices, else the page is closed and a new one begun. Every
//! triangle is thus in exactly one page.

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use memmap2::Mmap;
use serde::Serialize;

use super::hilbert::{hilbert_order, raster_order};
use super::kdtree::{build_kdtree, KdNode, PageBounds, LEAF};
use super::two_factor::{two_factor_order, TwoFactorOptions};
use crate::error::{Error, IoContext, Result};
use crate::format::terrain::{get_u32, get_u64, put_f64, put_u32, put_u64};
use crate::mesh::{Bounds, Mesh};
use crate::sys::progress::Progress;

pub const MAGIC: [u8; 8] = *b"\x89RLFPGS\n";
pub const VERSION: u32 = 1;
pub const HEADER_BYTES: usize = 256;
pub const MIN_PAGE_BYTES: u32 = 1024;
pub const MAX_PAGE_BYTES: u32 = 1 << 20;
pub const PAGE_HEADER_BYTES: usize = 8;
pub const VERTEX_BYTES: usize = 22;
pub const ENTRY_BYTES: usize = 48;
pub const KD_NODE_BYTES: usize = 40;
/// Colour of every vertex: the inputs (OFF, PLY, OBJ, terrains) carry none that we read.
pub const DEFAULT_COLOUR: [u8; 4] = [200, 200, 200, 255];

/// The order triangles are written in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PageLayout {
    /// Input order.
    Raster,
    /// Hierarchical 2-factor order ([`super::two_factor`]).
    #[serde(rename = "2factor")]
    TwoFactor,
    /// 3D Hilbert order of centroids ([`super::hilbert`]).
    Hilbert,
}

impl PageLayout {
    pub const ALL: [PageLayout; 3] = [PageLayout::Raster, PageLayout::TwoFactor, PageLayout::Hilbert];

    pub fn name(self) -> &'static str {
        match self {
            PageLayout::Raster => "raster",
            PageLayout::TwoFactor => "2factor",
            PageLayout::Hilbert => "hilbert",
        }
    }

    pub fn from_name(name: &str) -> Option<PageLayout> {
        PageLayout::ALL.into_iter().find(|l| l.name() == name)
    }

    fn code(self) -> u32 {
        self as u32
    }

    fn from_code(code: u32) -> Option<PageLayout> {
        PageLayout::ALL.get(code as usize).copied()
    }
}

/// How to build a page file.
#[derive(Clone, Debug)]
pub struct PageBuildOptions {
    pub page_bytes: u32,
    pub layout: PageLayout,
    pub two_factor: TwoFactorOptions,
    pub progress: Progress,
}

impl PageBuildOptions {
    pub fn new(page_bytes: u32, layout: PageLayout) -> PageBuildOptions {
        PageBuildOptions { page_bytes, layout, two_factor: TwoFactorOptions::default(), progress: Progress::hidden() }
    }
}

/// What [`build_page_file`] wrote.
#[derive(Clone, Debug, Serialize)]
pub struct PageBuildReport {
    pub output: String,
    pub layout: PageLayout,
    pub page_bytes: u32,
    pub pages: u64,
    pub triangles: u64,
    pub source_vertices: u64,
    /// Σ over pages of the vertices each holds (shared vertices are copied into every page).
    pub vertex_copies: u64,
    pub triangles_per_page_mean: f64,
    /// Mean fraction of a page in use.
    pub fill_mean: f64,
    /// Pages whose triangles use 1-byte local indices.
    pub one_byte_index_pages: u64,
    pub kd_nodes: u64,
    pub kd_refs: u64,
    pub file_bytes: u64,
    /// Computing the layout order, ms.
    pub layout_ms: f64,
    /// Filling the pages, the tree and writing, ms.
    pub write_ms: f64,
}

/// A page's size when it holds `vertices` and `triangles`.
fn page_size(vertices: usize, triangles: usize) -> usize {
    let index = if vertices <= 256 { 1 } else { 2 };
    PAGE_HEADER_BYTES + vertices * VERTEX_BYTES + triangles * 3 * index
}

/// Lays `mesh` out in `options.layout` order and writes it as a page file at `out` (atomically).
pub fn build_page_file(mesh: &Mesh, out: &Path, options: &PageBuildOptions) -> Result<PageBuildReport> {
    let page = options.page_bytes;
    if !page.is_power_of_two() || !(MIN_PAGE_BYTES..=MAX_PAGE_BYTES).contains(&page) {
        return Err(Error::InvalidArgument(format!(
            "page size must be a power of two from {MIN_PAGE_BYTES} to {MAX_PAGE_BYTES} bytes, got {page}"
        )));
    }
    if mesh.triangles.is_empty() {
        return Err(Error::InvalidArgument("the mesh has no triangles to page".into()));
    }
    let nv = mesh.positions.len();
    if let Some((k, t)) = mesh.triangles.iter().enumerate().find(|(_, t)| t.iter().any(|&i| i as usize >= nv)) {
        return Err(Error::InvalidArgument(format!("triangle {k} {t:?}: vertex index out of range ({nv} vertices)")));
    }
    let started = Instant::now();
    // Face normals (unit, zero for degenerate faces), area-weighted vertex normals, centroids.
    let pos = |i: u32| glam::DVec3::from(mesh.positions[i as usize]);
    let mut face_normals = Vec::with_capacity(mesh.triangles.len());
    let mut centroids = Vec::with_capacity(mesh.triangles.len());
    let mut vertex_normals = vec![glam::DVec3::ZERO; nv];
    for t in &mesh.triangles {
        let (a, b, c) = (pos(t[0]), pos(t[1]), pos(t[2]));
        let cross = (b - a).cross(c - a);
        for &i in t {
            vertex_normals[i as usize] += cross;
        }
        face_normals.push(cross.normalize_or_zero().to_array());
        centroids.push(((a + b + c) / 3.0).to_array());
    }
    let order = match options.layout {
        PageLayout::Raster => raster_order(mesh.triangles.len()),
        PageLayout::Hilbert => hilbert_order(&centroids),
        PageLayout::TwoFactor => {
            let bar = options.progress.bar("2-factor layout", mesh.triangles.len() as u64, "triangles");
            let o = two_factor_order(&centroids, &face_normals, &options.two_factor, &|n| bar.set_position(n))?;
            bar.finish_and_clear();
            o
        }
    };
    let layout_ms = started.elapsed().as_secs_f64() * 1e3;
    let started = Instant::now();
    let vertex_normals: Vec<[i16; 3]> =
        vertex_normals.iter().map(|n| n.normalize_or_zero().to_array().map(|c| (c * 32767.0).round() as i16)).collect();
    let positions: Vec<[f32; 3]> = mesh.positions.iter().map(|p| p.map(|c| c as f32)).collect();

    // Greedy fill. `local[v]` is v's index in the page being filled when `stamp[v]` is that
    // page's number (no clearing between pages).
    let source = Source { positions: &positions, vertex_normals: &vertex_normals, face_normals: &face_normals };
    let mut filled = Filled::default();
    let mut stamp = vec![u32::MAX; nv];
    let mut local = vec![0u16; nv];
    let mut open = OpenPage::default();
    for &f in &order {
        let t = mesh.triangles[f as usize];
        let page_no = filled.entries.len() as u32;
        let mut fresh = 0;
        for (k, &v) in t.iter().enumerate() {
            // A vertex repeated within the triangle counts once.
            if stamp[v as usize] != page_no && !t[..k].contains(&v) {
                fresh += 1;
            }
        }
        let (nv_after, nt_after) = (open.vertices.len() + fresh, open.triangles.len() + 1);
        if page_size(nv_after, nt_after) > page as usize || nv_after > u16::MAX as usize || nt_after > u16::MAX as usize
        {
            filled.close(&source, &mut open, page as usize);
        }
        let page_no = filled.entries.len() as u32;
        let mut tri = [0u16; 3];
        for (k, &v) in t.iter().enumerate() {
            if stamp[v as usize] != page_no {
                stamp[v as usize] = page_no;
                local[v as usize] = open.vertices.len() as u16;
                open.vertices.push(v);
            }
            tri[k] = local[v as usize];
        }
        open.triangles.push(tri);
        open.faces.push(f);
    }
    filled.close(&source, &mut open, page as usize);
    let Filled { data, entries, counts, one_byte, vertex_copies } = filled;

    let boxes: Vec<([f32; 3], [f32; 3])> = entries.iter().map(|e| (e.box_min, e.box_max)).collect();
    let (nodes, refs) = build_kdtree(&boxes);
    let pages = entries.len() as u64;
    let mut tables = Vec::with_capacity(entries.len() * ENTRY_BYTES + nodes.len() * KD_NODE_BYTES + refs.len() * 4);
    for (e, &(tris, verts)) in entries.iter().zip(&counts) {
        for v in e.box_min.iter().chain(&e.box_max).chain(&e.cone_axis).chain([&e.cone_half_angle_rad]) {
            tables.extend_from_slice(&v.to_le_bytes());
        }
        tables.extend_from_slice(&tris.to_le_bytes());
        tables.extend_from_slice(&verts.to_le_bytes());
    }
    let kd_offset = (HEADER_BYTES + tables.len()) as u64;
    tables.extend_from_slice(bytemuck::cast_slice(&nodes));
    let refs_offset = (HEADER_BYTES + tables.len()) as u64;
    tables.extend_from_slice(bytemuck::cast_slice(&refs));
    let data_offset = ((HEADER_BYTES + tables.len()) as u64).div_ceil(page as u64) * page as u64;

    let mut bounds = Bounds { min: [f64::INFINITY; 3], max: [f64::NEG_INFINITY; 3] };
    for e in &entries {
        for k in 0..3 {
            bounds.min[k] = bounds.min[k].min(e.box_min[k] as f64);
            bounds.max[k] = bounds.max[k].max(e.box_max[k] as f64);
        }
    }
    let mut header = [0u8; HEADER_BYTES];
    header[0..8].copy_from_slice(&MAGIC);
    put_u32(&mut header, 8, VERSION);
    put_u32(&mut header, 12, HEADER_BYTES as u32);
    put_u32(&mut header, 16, page);
    put_u32(&mut header, 20, options.layout.code());
    put_u64(&mut header, 24, pages);
    put_u64(&mut header, 32, mesh.triangles.len() as u64);
    put_u64(&mut header, 40, vertex_copies);
    put_u64(&mut header, 48, nv as u64);
    put_u64(&mut header, 56, HEADER_BYTES as u64);
    put_u64(&mut header, 64, nodes.len() as u64);
    put_u64(&mut header, 72, kd_offset);
    put_u64(&mut header, 80, refs.len() as u64);
    put_u64(&mut header, 88, refs_offset);
    put_u64(&mut header, 96, data_offset);
    for k in 0..3 {
        put_f64(&mut header, 104 + 8 * k, bounds.min[k]);
        put_f64(&mut header, 128 + 8 * k, bounds.max[k]);
    }
    put_u64(&mut header, 152, xxhash_rust::xxh3::xxh3_64(&tables));
    let sum = xxhash_rust::xxh3::xxh3_64(&header[..248]);
    put_u64(&mut header, 248, sum);
    crate::sys::atomic_file::write(out, |w| {
        w.write_all(&header)?;
        w.write_all(&tables)?;
        w.write_all(&vec![0u8; data_offset as usize - HEADER_BYTES - tables.len()])?;
        w.write_all(&data)
    })?;
    let used: usize = counts.iter().map(|&(t, v)| page_size(v as usize, t as usize)).sum();
    Ok(PageBuildReport {
        output: out.display().to_string(),
        layout: options.layout,
        page_bytes: page,
        pages,
        triangles: mesh.triangles.len() as u64,
        source_vertices: nv as u64,
        vertex_copies,
        triangles_per_page_mean: mesh.triangles.len() as f64 / pages as f64,
        fill_mean: used as f64 / (pages as f64 * page as f64),
        one_byte_index_pages: one_byte,
        kd_nodes: nodes.len() as u64,
        kd_refs: refs.len() as u64,
        file_bytes: data_offset + data.len() as u64,
        layout_ms,
        write_ms: started.elapsed().as_secs_f64() * 1e3,
    })
}

/// What the pages are filled from.
struct Source<'a> {
    positions: &'a [[f32; 3]],
    vertex_normals: &'a [[i16; 3]],
    face_normals: &'a [[f64; 3]],
}

/// The page being filled: source vertices (local index = position), local triangles, faces.
#[derive(Default)]
struct OpenPage {
    vertices: Vec<u32>,
    triangles: Vec<[u16; 3]>,
    faces: Vec<u32>,
}

/// The closed pages.
#[derive(Default)]
struct Filled {
    data: Vec<u8>,
    entries: Vec<PageBounds>,
    counts: Vec<(u32, u32)>,
    one_byte: u64,
    vertex_copies: u64,
}

impl Filled {
    /// Encodes `open` as the next page (its box and normal cone into the directory) and empties it.
    fn close(&mut self, src: &Source<'_>, open: &mut OpenPage, page_bytes: usize) {
        let at = self.data.len();
        self.data.resize(at + page_bytes, 0);
        let p = &mut self.data[at..at + page_bytes];
        p[0..2].copy_from_slice(&(open.vertices.len() as u16).to_le_bytes());
        p[2..4].copy_from_slice(&(open.triangles.len() as u16).to_le_bytes());
        let index_bytes = if open.vertices.len() <= 256 { 1 } else { 2 };
        p[4] = index_bytes as u8;
        let mut o = PAGE_HEADER_BYTES;
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for &v in &open.vertices {
            let q = src.positions[v as usize];
            for k in 0..3 {
                p[o + 4 * k..o + 4 * k + 4].copy_from_slice(&q[k].to_le_bytes());
                p[o + 12 + 2 * k..o + 14 + 2 * k].copy_from_slice(&src.vertex_normals[v as usize][k].to_le_bytes());
                lo[k] = lo[k].min(q[k]);
                hi[k] = hi[k].max(q[k]);
            }
            p[o + 18..o + 22].copy_from_slice(&DEFAULT_COLOUR);
            o += VERTEX_BYTES;
        }
        for t in &open.triangles {
            for &i in t {
                if index_bytes == 1 {
                    p[o] = i as u8;
                } else {
                    p[o..o + 2].copy_from_slice(&i.to_le_bytes());
                }
                o += index_bytes;
            }
        }
        debug_assert!(o <= page_bytes);
        // Normal cone: axis the mean of the unit face normals, half-angle the widest deviation
        // (plus a little for f32 rounding); a degenerate face or no clear mean disables culling.
        let normal = |f: u32| glam::DVec3::from(src.face_normals[f as usize]);
        let degenerate = open.faces.iter().any(|&f| normal(f) == glam::DVec3::ZERO);
        let axis = open.faces.iter().map(|&f| normal(f)).sum::<glam::DVec3>().normalize_or_zero();
        let half_angle = if degenerate || axis == glam::DVec3::ZERO {
            std::f32::consts::PI
        } else {
            let widest = open.faces.iter().map(|&f| normal(f).dot(axis).clamp(-1.0, 1.0).acos()).fold(0.0f64, f64::max);
            (widest + 1e-3) as f32
        };
        self.entries.push(PageBounds {
            box_min: lo,
            box_max: hi,
            cone_axis: axis.as_vec3().to_array(),
            cone_half_angle_rad: half_angle,
        });
        self.counts.push((open.triangles.len() as u32, open.vertices.len() as u32));
        self.one_byte += u64::from(index_bytes == 1);
        self.vertex_copies += open.vertices.len() as u64;
        open.vertices.clear();
        open.triangles.clear();
        open.faces.clear();
    }
}

/// The header of a page file.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PageHeader {
    pub page_bytes: u32,
    pub layout: PageLayout,
    pub pages: u64,
    pub triangles: u64,
    pub vertex_copies: u64,
    pub source_vertices: u64,
    pub kd_nodes: u64,
    pub kd_offset: u64,
    pub kd_refs: u64,
    pub refs_offset: u64,
    pub data_offset: u64,
    pub bounds: Bounds,
    pub tables_checksum: u64,
}

/// One page as stored: its vertex table and triangles, validated ([`PageView::parse`]).
#[derive(Clone, Copy, Debug)]
pub struct PageView<'a> {
    bytes: &'a [u8],
    vertices: usize,
    triangles: usize,
    index_bytes: usize,
}

impl<'a> PageView<'a> {
    /// Checks the counts against the page's size and every index against the vertex count.
    pub fn parse(bytes: &'a [u8]) -> std::result::Result<PageView<'a>, String> {
        if bytes.len() < PAGE_HEADER_BYTES {
            return Err(format!("page of {} bytes is shorter than its header", bytes.len()));
        }
        let vertices = u16::from_le_bytes([bytes[0], bytes[1]]) as usize;
        let triangles = u16::from_le_bytes([bytes[2], bytes[3]]) as usize;
        let index_bytes = bytes[4] as usize;
        let want = if vertices <= 256 { 1 } else { 2 };
        if index_bytes != want {
            return Err(format!("{index_bytes}-byte indices for {vertices} vertices"));
        }
        if triangles == 0 || page_size(vertices, triangles) > bytes.len() {
            return Err(format!("{vertices} vertices and {triangles} triangles do not fit {} bytes", bytes.len()));
        }
        let view = PageView { bytes, vertices, triangles, index_bytes };
        for t in 0..triangles {
            if let Some(&i) = view.triangle(t).iter().find(|&&i| i as usize >= vertices) {
                return Err(format!("triangle {t} uses vertex {i} of {vertices}"));
            }
        }
        Ok(view)
    }

    pub fn vertices(&self) -> usize {
        self.vertices
    }

    pub fn triangles(&self) -> usize {
        self.triangles
    }

    pub fn index_bytes(&self) -> usize {
        self.index_bytes
    }

    fn f32_at(&self, at: usize) -> f32 {
        f32::from_le_bytes(self.bytes[at..at + 4].try_into().expect("4 bytes"))
    }

    /// Position of local vertex `i` (f32, as the input rounded).
    pub fn position(&self, i: usize) -> [f32; 3] {
        let at = PAGE_HEADER_BYTES + i * VERTEX_BYTES;
        [self.f32_at(at), self.f32_at(at + 4), self.f32_at(at + 8)]
    }

    /// Unit normal of local vertex `i` (from its i16 encoding).
    pub fn normal(&self, i: usize) -> [f32; 3] {
        let at = PAGE_HEADER_BYTES + i * VERTEX_BYTES + 12;
        [0, 1, 2].map(|k| i16::from_le_bytes([self.bytes[at + 2 * k], self.bytes[at + 2 * k + 1]]) as f32 / 32767.0)
    }

    /// RGBA colour of local vertex `i`.
    pub fn colour(&self, i: usize) -> [u8; 4] {
        let at = PAGE_HEADER_BYTES + i * VERTEX_BYTES + 18;
        [self.bytes[at], self.bytes[at + 1], self.bytes[at + 2], self.bytes[at + 3]]
    }

    /// Local vertex indices of triangle `t`.
    pub fn triangle(&self, t: usize) -> [u16; 3] {
        let at = PAGE_HEADER_BYTES + self.vertices * VERTEX_BYTES + t * 3 * self.index_bytes;
        if self.index_bytes == 1 {
            [0, 1, 2].map(|k| self.bytes[at + k] as u16)
        } else {
            [0, 1, 2].map(|k| u16::from_le_bytes([self.bytes[at + 2 * k], self.bytes[at + 2 * k + 1]]))
        }
    }

    /// Appends the page's triangles as 3 positions each.
    pub fn append_triangles(&self, out: &mut Vec<[f32; 3]>) {
        out.reserve(3 * self.triangles);
        for t in 0..self.triangles {
            for i in self.triangle(t) {
                out.push(self.position(i as usize));
            }
        }
    }
}

/// An open page file: header, directory and k-d tree in memory (validated), the pages mapped.
pub struct PageFile {
    path: PathBuf,
    file: File,
    map: Mmap,
    header: PageHeader,
    directory: Vec<PageBounds>,
    counts: Vec<(u32, u32)>,
    nodes: Vec<KdNode>,
    refs: Vec<u32>,
}

impl PageFile {
    /// Opens and validates a page file: magic, version, header checksum, section sizes against
    /// the file's length, the tables' checksum, every directory entry and k-d node. Pages are
    /// validated when decoded ([`PageView::parse`]).
    pub fn open(path: &Path) -> Result<PageFile> {
        let file = File::open(path).at(path)?;
        let len = file.metadata().at(path)?.len();
        let map = crate::pager::source::map_read_only(path, &file, len)?;
        let header = decode_header(path, &map, len)?;
        let bad = |problem: String| Error::bad_pages(path, problem);
        let tables = &map[HEADER_BYTES..header.refs_offset as usize + header.kd_refs as usize * 4];
        let computed = xxhash_rust::xxh3::xxh3_64(tables);
        if computed != header.tables_checksum {
            return Err(Error::Checksum {
                path: path.into(),
                which: "tables",
                stored: header.tables_checksum,
                computed,
            });
        }
        let f = |at: usize| f32::from_le_bytes(map[at..at + 4].try_into().expect("4 bytes"));
        let mut directory = Vec::with_capacity(header.pages as usize);
        let mut counts = Vec::with_capacity(header.pages as usize);
        let mut triangles = 0u64;
        for p in 0..header.pages as usize {
            let at = HEADER_BYTES + p * ENTRY_BYTES;
            let e = PageBounds {
                box_min: [f(at), f(at + 4), f(at + 8)],
                box_max: [f(at + 12), f(at + 16), f(at + 20)],
                cone_axis: [f(at + 24), f(at + 28), f(at + 32)],
                cone_half_angle_rad: f(at + 36),
            };
            let (tris, verts) = (get_u32(&map, at + 40), get_u32(&map, at + 44));
            let ok = (0..3)
                .all(|k| e.box_min[k].is_finite() && e.box_max[k].is_finite() && e.box_min[k] <= e.box_max[k])
                && e.cone_axis.iter().all(|c| c.is_finite())
                && (0.0..=4.0).contains(&e.cone_half_angle_rad)
                && tris > 0
                && page_size(verts as usize, tris as usize) <= header.page_bytes as usize;
            if !ok {
                return Err(bad(format!("directory entry {p} is inconsistent")));
            }
            triangles += tris as u64;
            directory.push(e);
            counts.push((tris, verts));
        }
        if triangles != header.triangles {
            return Err(bad(format!("the directory holds {triangles} triangles, the header {}", header.triangles)));
        }
        let kd_at = header.kd_offset as usize;
        let nodes: Vec<KdNode> = map[kd_at..kd_at + header.kd_nodes as usize * KD_NODE_BYTES]
            .chunks_exact(KD_NODE_BYTES)
            .map(bytemuck::pod_read_unaligned)
            .collect();
        let refs_at = header.refs_offset as usize;
        let refs: Vec<u32> = map[refs_at..refs_at + header.kd_refs as usize * 4]
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes(c.try_into().expect("4 bytes")))
            .collect();
        if let Some(r) = refs.iter().find(|&&r| r as u64 >= header.pages) {
            return Err(bad(format!("the k-d tree names page {r} of {}", header.pages)));
        }
        for (i, n) in nodes.iter().enumerate() {
            let ok = match n.axis {
                LEAF => n.a as u64 + n.b as u64 <= refs.len() as u64,
                0..=2 => {
                    (n.a as usize) > i
                        && (n.b as usize) > i
                        && (n.a as usize) < nodes.len()
                        && (n.b as usize) < nodes.len()
                }
                _ => false,
            };
            if !ok {
                return Err(bad(format!("k-d node {i} is inconsistent")));
            }
        }
        Ok(PageFile { path: path.to_path_buf(), file, map, header, directory, counts, nodes, refs })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn header(&self) -> &PageHeader {
        &self.header
    }

    /// Bounding box and normal cone of every page.
    pub fn directory(&self) -> &[PageBounds] {
        &self.directory
    }

    /// (triangles, vertices) of every page.
    pub fn counts(&self) -> &[(u32, u32)] {
        &self.counts
    }

    pub fn kd_nodes(&self) -> &[KdNode] {
        &self.nodes
    }

    pub fn kd_refs(&self) -> &[u32] {
        &self.refs
    }

    pub fn page_bytes(&self) -> usize {
        self.header.page_bytes as usize
    }

    /// Page `p` through the map.
    pub fn mapped_page(&self, p: u32) -> &[u8] {
        let at = self.header.data_offset as usize + p as usize * self.page_bytes();
        &self.map[at..at + self.page_bytes()]
    }

    /// Reads pages `first .. first + count` with one `pread` into `buf` (resized).
    pub fn read_pages(&self, first: u32, count: u32, buf: &mut Vec<u8>) -> Result<()> {
        use std::os::unix::fs::FileExt;
        if first as u64 + count as u64 > self.header.pages {
            return Err(Error::InvalidArgument(format!("pages {first}+{count} of {}", self.header.pages)));
        }
        buf.resize(count as usize * self.page_bytes(), 0);
        let at = self.header.data_offset + first as u64 * self.page_bytes() as u64;
        self.file.read_exact_at(buf, at).at(&self.path)
    }

    /// Decodes a page's bytes (from [`PageFile::read_pages`] or the map); a damaged page is an
    /// error naming the file and the page.
    pub fn decode<'a>(&self, p: u32, bytes: &'a [u8]) -> Result<PageView<'a>> {
        let view = PageView::parse(bytes).map_err(|e| Error::bad_pages(&self.path, format!("page {p}: {e}")))?;
        let (tris, verts) = self.counts.get(p as usize).copied().unwrap_or_default();
        if (view.triangles() as u32, view.vertices() as u32) != (tris, verts) {
            return Err(Error::bad_pages(&self.path, format!("page {p}: counts differ from the directory")));
        }
        Ok(view)
    }

    /// Drops the file's pages from the OS page cache (those not mapped by a process).
    pub fn evict_from_page_cache(&self) -> Result<()> {
        use std::os::fd::AsRawFd;
        // SAFETY: posix_fadvise only reads the descriptor, which `self.file` keeps open.
        let rc = unsafe { libc::posix_fadvise(self.file.as_raw_fd(), 0, 0, libc::POSIX_FADV_DONTNEED) };
        if rc != 0 {
            return Err(Error::io(&self.path, std::io::Error::from_raw_os_error(rc)));
        }
        Ok(())
    }

    /// No readahead for the map and for `pread` (a cold flight reads exactly its pages).
    pub fn advise_random(&self) -> Result<()> {
        use std::os::fd::AsRawFd;
        self.map.advise(memmap2::Advice::Random).at(&self.path)?;
        // SAFETY: posix_fadvise only reads the descriptor, which `self.file` keeps open.
        let rc = unsafe { libc::posix_fadvise(self.file.as_raw_fd(), 0, 0, libc::POSIX_FADV_RANDOM) };
        if rc != 0 {
            return Err(Error::io(&self.path, std::io::Error::from_raw_os_error(rc)));
        }
        Ok(())
    }
}

fn decode_header(path: &Path, b: &[u8], len: u64) -> Result<PageHeader> {
    let bad = |problem: String| Error::BadHeader { path: path.to_path_buf(), problem };
    if b.len() < 8 || b[0..8] != MAGIC {
        return Err(Error::BadMagic { path: path.to_path_buf() });
    }
    if b.len() < HEADER_BYTES {
        return Err(Error::Truncated { path: path.into(), expected: HEADER_BYTES as u64, found: len });
    }
    let version = get_u32(b, 8);
    if version != VERSION {
        return Err(Error::BadVersion { path: path.into(), found: version, supported: VERSION });
    }
    let stored = get_u64(b, 248);
    let computed = xxhash_rust::xxh3::xxh3_64(&b[..248]);
    if stored != computed {
        return Err(Error::Checksum { path: path.into(), which: "header", stored, computed });
    }
    let f = |at| f64::from_bits(get_u64(b, at));
    let layout =
        PageLayout::from_code(get_u32(b, 20)).ok_or_else(|| bad(format!("unknown layout {}", get_u32(b, 20))))?;
    let h = PageHeader {
        page_bytes: get_u32(b, 16),
        layout,
        pages: get_u64(b, 24),
        triangles: get_u64(b, 32),
        vertex_copies: get_u64(b, 40),
        source_vertices: get_u64(b, 48),
        kd_nodes: get_u64(b, 64),
        kd_offset: get_u64(b, 72),
        kd_refs: get_u64(b, 80),
        refs_offset: get_u64(b, 88),
        data_offset: get_u64(b, 96),
        bounds: Bounds { min: [f(104), f(112), f(120)], max: [f(128), f(136), f(144)] },
        tables_checksum: get_u64(b, 152),
    };
    if get_u32(b, 12) != HEADER_BYTES as u32 || get_u64(b, 56) != HEADER_BYTES as u64 {
        return Err(bad("header size or directory offset is not 256".into()));
    }
    if !h.page_bytes.is_power_of_two() || !(MIN_PAGE_BYTES..=MAX_PAGE_BYTES).contains(&h.page_bytes) {
        return Err(bad(format!("page size {} is not a power of two from 1 KiB to 1 MiB", h.page_bytes)));
    }
    if h.pages == 0 || h.pages >= u32::MAX as u64 || h.triangles < h.pages || h.kd_nodes == 0 || h.kd_refs < h.pages {
        return Err(bad(format!(
            "{} pages, {} triangles, {} k-d nodes, {} references",
            h.pages, h.triangles, h.kd_nodes, h.kd_refs
        )));
    }
    let kd_at = (HEADER_BYTES as u64)
        .checked_add(h.pages.checked_mul(ENTRY_BYTES as u64).ok_or_else(|| bad("sizes overflow".into()))?);
    let refs_at = h.kd_nodes.checked_mul(KD_NODE_BYTES as u64).and_then(|x| x.checked_add(h.kd_offset));
    let tables_end = h.kd_refs.checked_mul(4).and_then(|x| x.checked_add(h.refs_offset));
    let data_end = h.pages.checked_mul(h.page_bytes as u64).and_then(|x| x.checked_add(h.data_offset));
    let ordered = kd_at == Some(h.kd_offset)
        && refs_at == Some(h.refs_offset)
        && tables_end.is_some_and(|e| e <= h.data_offset)
        && h.data_offset.is_multiple_of(h.page_bytes as u64);
    if !ordered {
        return Err(bad("section offsets are inconsistent".into()));
    }
    match data_end {
        Some(end) if end == len => {}
        Some(end) => return Err(Error::Truncated { path: path.into(), expected: end, found: len }),
        None => return Err(bad("page data size overflows".into())),
    }
    if !(0..3).all(|k| h.bounds.min[k].is_finite() && h.bounds.max[k].is_finite() && h.bounds.min[k] <= h.bounds.max[k])
    {
        return Err(bad("bounding box is not finite and ordered".into()));
    }
    Ok(h)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 40 × 40 grid of quads (3,200 triangles) on a wavy surface.
    fn grid_mesh() -> Mesh {
        let n = 41u32;
        let positions = (0..n * n)
            .map(|i| {
                let (x, y) = ((i % n) as f64, (i / n) as f64);
                [x, y, (x * 0.3).sin() * 2.0 + (y * 0.2).cos()]
            })
            .collect();
        let mut triangles = Vec::new();
        for y in 0..n - 1 {
            for x in 0..n - 1 {
                let v = y * n + x;
                triangles.push([v, v + 1, v + n + 1]);
                triangles.push([v, v + n + 1, v + n]);
            }
        }
        Mesh { positions, triangles }
    }

    fn decode_all(f: &PageFile) -> Vec<[[f32; 3]; 3]> {
        let mut tris = Vec::new();
        let mut buf = Vec::new();
        for p in 0..f.header().pages as u32 {
            f.read_pages(p, 1, &mut buf).unwrap();
            let mut out = Vec::new();
            f.decode(p, &buf).unwrap().append_triangles(&mut out);
            assert_eq!(f.mapped_page(p), &buf[..]);
            tris.extend(out.chunks_exact(3).map(|c| [c[0], c[1], c[2]]));
        }
        tris
    }

    #[test]
    fn pages_hold_every_triangle_once_in_every_layout() {
        let mesh = grid_mesh();
        let dir = tempfile::tempdir().unwrap();
        let mut want: Vec<[[u32; 3]; 3]> = mesh
            .triangles
            .iter()
            .map(|t| t.map(|i| mesh.positions[i as usize].map(|c| (c as f32).to_bits())))
            .collect();
        want.sort_unstable();
        for layout in PageLayout::ALL {
            let out = dir.path().join(format!("{}.pages", layout.name()));
            let r = build_page_file(&mesh, &out, &PageBuildOptions::new(1024, layout)).unwrap();
            let f = PageFile::open(&out).unwrap();
            assert_eq!(f.header().layout, layout);
            assert_eq!(r.pages, f.header().pages);
            assert!(r.pages > 30, "{} pages", r.pages);
            let mut got: Vec<[[u32; 3]; 3]> = decode_all(&f).iter().map(|t| t.map(|p| p.map(f32::to_bits))).collect();
            got.sort_unstable();
            assert_eq!(got, want, "{}", layout.name());
            // Boxes hold their pages' vertices; cones hold their faces' normals.
            let mut buf = Vec::new();
            for (p, e) in f.directory().iter().enumerate() {
                f.read_pages(p as u32, 1, &mut buf).unwrap();
                let v = f.decode(p as u32, &buf).unwrap();
                for i in 0..v.vertices() {
                    let q = v.position(i);
                    assert!((0..3).all(|k| e.box_min[k] <= q[k] && q[k] <= e.box_max[k]));
                    let n = v.normal(i);
                    assert!((n[0] * n[0] + n[1] * n[1] + n[2] * n[2] - 1.0).abs() < 1e-3);
                    assert_eq!(v.colour(i), DEFAULT_COLOUR);
                }
                assert!(e.cone_half_angle_rad < 1.5, "a smooth surface has narrow cones");
            }
        }
    }

    #[test]
    fn two_byte_indices_when_a_page_holds_more_than_256_vertices() {
        // Disconnected triangles: 3 vertices each, so a 64 KiB page holds far more than 256.
        let mut mesh = Mesh::default();
        for k in 0..2000u32 {
            let x = k as f64;
            mesh.positions.extend([[x, 0.0, 0.0], [x + 0.5, 1.0, 0.0], [x, 0.0, 1.0]]);
            mesh.triangles.push([3 * k, 3 * k + 1, 3 * k + 2]);
        }
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("soup.pages");
        let r = build_page_file(&mesh, &out, &PageBuildOptions::new(65536, PageLayout::Raster)).unwrap();
        assert!(r.one_byte_index_pages < r.pages);
        let f = PageFile::open(&out).unwrap();
        assert_eq!(decode_all(&f).len(), 2000);
        let mut buf = Vec::new();
        f.read_pages(0, 1, &mut buf).unwrap();
        assert_eq!(f.decode(0, &buf).unwrap().index_bytes(), 2);
    }

    #[test]
    fn damaged_files_are_one_line_errors() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("g.pages");
        build_page_file(&grid_mesh(), &out, &PageBuildOptions::new(2048, PageLayout::Hilbert)).unwrap();
        let good = std::fs::read(&out).unwrap();
        let try_bytes = |bytes: &[u8]| {
            let p = dir.path().join("bad.pages");
            std::fs::write(&p, bytes).unwrap();
            PageFile::open(&p).map(|_| ()).unwrap_err().to_string()
        };
        let mut b = good.clone();
        b[0] = b'X';
        assert!(try_bytes(&b).contains("bad magic"));
        let mut b = good.clone();
        b[30] ^= 1;
        assert!(try_bytes(&b).contains("header checksum"));
        let mut b = good.clone();
        b[HEADER_BYTES + 3] ^= 0x40;
        assert!(try_bytes(&b).contains("tables checksum"));
        assert!(try_bytes(&good[..good.len() - 1]).contains("truncated"));
        assert!(try_bytes(&good[..100]).contains("truncated"));
        for e in [try_bytes(&b), try_bytes(&good[..7])] {
            assert_eq!(e.lines().count(), 1, "{e}");
        }
        // A damaged page decodes to an error naming the page.
        let f = PageFile::open(&out).unwrap();
        let mut page = f.mapped_page(0).to_vec();
        page[4] = 2;
        assert!(f.decode(0, &page).unwrap_err().to_string().contains("page 0"));
        let mut page = f.mapped_page(0).to_vec();
        let (tris, verts) = f.counts()[0];
        let first_index = PAGE_HEADER_BYTES + verts as usize * VERTEX_BYTES;
        page[first_index] = 255;
        assert!(tris > 0 && f.decode(0, &page).is_err());
        assert!(build_page_file(&grid_mesh(), &out, &PageBuildOptions::new(512, PageLayout::Raster)).is_err());
        assert!(build_page_file(&grid_mesh(), &out, &PageBuildOptions::new(3000, PageLayout::Raster)).is_err());
        assert!(build_page_file(&Mesh::default(), &out, &PageBuildOptions::new(4096, PageLayout::Raster)).is_err());
    }
}
