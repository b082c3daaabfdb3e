//! Writing a page file (Sajadi et al. 2009, §3): a triangle soup laid out in a layout order and
//! filled greedily into self-contained fixed-size pages; the format is [`crate::format::pagefile`].
//!
//! Pages are filled greedily in layout order: a triangle goes into the current page when the page
//! still fits it with its new vertices, else the page is closed and a new one begun. Every
//! triangle is thus in exactly one page.

use std::io::Write;
use std::path::Path;
use std::time::Instant;

use serde::Serialize;

use super::hilbert::{hilbert_order, raster_order};
use super::kdtree::{build_kdtree, PageBounds};
use super::two_factor::{two_factor_order, TwoFactorOptions};
use crate::error::{Error, Result};
use crate::format::pagefile::{
    page_size, PageHeader, PageLayout, DEFAULT_COLOUR, ENTRY_BYTES, HEADER_BYTES, KD_NODE_BYTES, MAX_PAGE_BYTES,
    MIN_PAGE_BYTES, PAGE_HEADER_BYTES, VERTEX_BYTES,
};
use crate::format::Format;
use crate::mesh::{Bounds, Mesh};
use crate::sys::progress::Progress;

/// How to build a page file.
#[derive(Clone, Debug)]
pub struct PageBuildOptions {
    pub page_bytes: u32,
    pub layout: PageLayout,
    pub two_factor: TwoFactorOptions,
    pub progress: Progress,
}

impl PageBuildOptions {
    /// Checks the page size: a power of two from 1 KiB to 1 MiB.
    pub fn validate(&self) -> Result<()> {
        let page = self.page_bytes;
        if !page.is_power_of_two() || !(MIN_PAGE_BYTES..=MAX_PAGE_BYTES).contains(&page) {
            return Err(Error::out_of_range("page size", "a power of two from 1K to 1M bytes", page));
        }
        Ok(())
    }

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

/// Lays `mesh` out in `options.layout` order and writes it as a page file at `out` (atomically).
pub fn build_page_file(mesh: &Mesh, out: &Path, options: &PageBuildOptions) -> Result<PageBuildReport> {
    options.validate()?;
    let page = options.page_bytes;
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
    let header = PageHeader {
        page_bytes: page,
        layout: options.layout,
        pages,
        triangles: mesh.triangles.len() as u64,
        vertex_copies,
        source_vertices: nv as u64,
        kd_nodes: nodes.len() as u64,
        kd_offset,
        kd_refs: refs.len() as u64,
        refs_offset,
        data_offset,
        bounds,
        tables_checksum: xxhash_rust::xxh3::xxh3_64(&tables),
    }
    .encode()
    .0;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::pagefile::PageFile;
    use crate::pager::Access;

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

    /// Every page's triangles, read with positioned reads and checked against the map.
    fn decode_all(f: &PageFile) -> Vec<[[f32; 3]; 3]> {
        let read = PageFile::open_with(f.path(), Access::Read).unwrap();
        let mut tris = Vec::new();
        for p in 0..f.header().pages as u32 {
            let page = read.page(p).unwrap();
            let mut out = Vec::new();
            read.decode(p, &page).unwrap().append_triangles(&mut out);
            assert_eq!(&*f.page(p).unwrap(), &*page);
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
            for (p, e) in f.directory().iter().enumerate() {
                let page = f.page(p as u32).unwrap();
                let v = f.decode(p as u32, &page).unwrap();
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
        assert_eq!(f.decode(0, &f.page(0).unwrap()).unwrap().index_bytes(), 2);
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
        let mut page = f.page(0).unwrap().to_vec();
        page[4] = 2;
        assert!(f.decode(0, &page).unwrap_err().to_string().contains("page 0"));
        let mut page = f.page(0).unwrap().to_vec();
        let (tris, verts) = f.counts()[0];
        let first_index = PAGE_HEADER_BYTES + verts as usize * VERTEX_BYTES;
        page[first_index] = 255;
        assert!(tris > 0 && f.decode(0, &page).is_err());
        assert!(build_page_file(&grid_mesh(), &out, &PageBuildOptions::new(512, PageLayout::Raster)).is_err());
        assert!(build_page_file(&grid_mesh(), &out, &PageBuildOptions::new(3000, PageLayout::Raster)).is_err());
        assert!(build_page_file(&Mesh::default(), &out, &PageBuildOptions::new(4096, PageLayout::Raster)).is_err());
    }
}
