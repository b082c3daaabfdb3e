//! `relief info` and `relief verify`: what a terrain file holds, and whether it is intact.

use rayon::prelude::*;
use serde::Serialize;

use crate::dem::DemFormat;
use crate::error::Result;
use crate::format::terrain::{Record, TerrainFile, FLAG_GEOGRAPHIC, FLAG_SPACING_ASSUMED};
use crate::georef::{unit, CrsKind, Georef};
use crate::layout::Layout;
use crate::preprocess::nesting_violation;
use crate::sys::cancel;
use crate::sys::progress::Progress;

/// Everything `info` reports (JSON keys are part of the interface).
#[derive(Clone, Debug, Serialize)]
pub struct Info {
    pub file: String,
    pub version: u32,
    pub grid_size: u32,
    pub levels: u32,
    pub layout: String,
    pub layout_param: u32,
    pub records: u64,
    pub vertices: u64,
    pub waste_ratio: f64,
    pub record_bytes: u32,
    pub spacing_m: [f64; 2],
    pub spacing_assumed: bool,
    /// Posts of the data (the valid window), east and north.
    pub data_posts: [u32; 2],
    /// Extent of the data, metres, from its first post to its last (posts span posts − 1
    /// spacings).
    pub data_extent_m: [f64; 2],
    /// Local metres of the data's south-west post (the grid's south-west corner is 0, 0).
    pub data_origin_m: [f64; 2],
    /// Extent of the whole grid, padding included, metres.
    pub extent_m: [f64; 2],
    pub z_min: f64,
    pub z_max: f64,
    pub z_scale: f64,
    pub z_offset: f64,
    pub valid_window: [u32; 4],
    pub nodata_filled: u64,
    /// Whether the file keeps which posts were nodata (a void mask, drawn as no data).
    pub void_mask: bool,
    pub source_format: String,
    /// Present when the source grid was geographic: its posts in degrees and the latitude at which
    /// they were converted to metres.
    pub geographic: Option<Geographic>,
    /// The source's CRS and the data's place in it, where the source said.
    pub crs: Option<CrsInfo>,
    pub file_bytes: u64,
    /// Vertices with a record (the data posts and their ancestors; the rest of the grid is
    /// padding that is not stored).
    pub stored_vertices: u64,
    /// Payload pages (4 KiB) in the file, and of the payload as read; equal where every page is
    /// stored (files before version 3).
    pub stored_pages: u64,
    pub payload_pages: u64,
    pub payload_checksum: String,
}

#[derive(Clone, Debug, Serialize)]
pub struct Geographic {
    pub spacing_deg: [f64; 2],
    pub centre_lat_deg: f64,
}

/// The CRS of a terrain's source and where its data lies in it (see [`crate::georef`]).
#[derive(Clone, Debug, Serialize)]
pub struct CrsInfo {
    /// `EPSG:n`, or what is known without a code.
    pub name: String,
    pub kind: CrsKind,
    pub epsg: Option<u32>,
    /// Unit of the coordinates, e.g. "metre", "degree"; `None` when not stated.
    pub unit: Option<String>,
    pub unit_code: Option<u16>,
    pub vertical_epsg: Option<u32>,
    /// Unit of the source's heights (converted to metres in the file); `None` when not stated.
    pub vertical_unit: Option<String>,
    pub vertical_unit_code: Option<u16>,
    /// CRS coordinates of the data's south-west post.
    pub origin: [f64; 2],
    /// CRS units between posts, east and north.
    pub step: [f64; 2],
    /// The data's posts in CRS coordinates: `[x_min, y_min, x_max, y_max]`.
    pub extent: [f64; 4],
    /// CRS coordinates of the grid's post (0, 0) (local metres 0, 0).
    pub grid_origin: [f64; 2],
}

impl CrsInfo {
    fn new(g: &Georef, valid_window: [u32; 4]) -> CrsInfo {
        let [x0, y0, x1, y1] = valid_window.map(f64::from);
        let sw = g.crs_of_post([x0, y0]);
        let ne = g.crs_of_post([x1 - 1.0, y1 - 1.0]);
        let code = |c: u32| (c != 0).then_some(c);
        let unit_of = |c: u16| (c != 0).then(|| unit::name(c).map_or(format!("EPSG unit {c}"), String::from));
        CrsInfo {
            name: g.crs_label(),
            kind: g.kind,
            epsg: code(g.epsg),
            unit: unit_of(g.unit),
            unit_code: (g.unit != 0).then_some(g.unit),
            vertical_epsg: code(g.vertical_epsg),
            vertical_unit: unit_of(g.vertical_unit),
            vertical_unit_code: (g.vertical_unit != 0).then_some(g.vertical_unit),
            origin: sw,
            step: g.step,
            extent: [sw[0], sw[1], ne[0], ne[1]],
            grid_origin: g.origin,
        }
    }
}

pub fn info(file: &TerrainFile) -> Info {
    let h = file.header();
    let [x0, y0, x1, y1] = h.valid_window;
    let geographic = (h.flags & FLAG_GEOGRAPHIC != 0)
        .then_some(Geographic { spacing_deg: h.source_spacing_deg, centre_lat_deg: h.source_centre_lat_deg });
    Info {
        file: file.path().display().to_string(),
        version: h.version,
        grid_size: h.grid().size(),
        levels: h.grid().levels(),
        layout: h.layout.name().into(),
        layout_param: h.layout_param,
        records: h.records,
        vertices: h.vertices(),
        waste_ratio: file.layout().waste_ratio(),
        record_bytes: h.record_bytes,
        spacing_m: h.spacing_m,
        spacing_assumed: h.flags & FLAG_SPACING_ASSUMED != 0,
        data_posts: [x1 - x0, y1 - y0],
        data_extent_m: [f64::from(x1 - x0 - 1) * h.spacing_m[0], f64::from(y1 - y0 - 1) * h.spacing_m[1]],
        data_origin_m: [f64::from(x0) * h.spacing_m[0], f64::from(y0) * h.spacing_m[1]],
        extent_m: h.extent_m(),
        z_min: h.z_min,
        z_max: h.z_max,
        z_scale: h.z_scale,
        z_offset: h.z_offset,
        valid_window: h.valid_window,
        nodata_filled: h.nodata_filled,
        void_mask: h.void_mask_offset != 0,
        source_format: DemFormat::ALL.get(h.source_format as usize).map(|f| f.name()).unwrap_or("unknown").into(),
        geographic,
        crs: h.georef.as_ref().map(|g| CrsInfo::new(g, h.valid_window)),
        file_bytes: file.stored_bytes(),
        stored_vertices: h.stored().count(),
        payload_pages: h.payload_bytes.div_ceil(4096),
        stored_pages: file.page_map().map_or(h.payload_bytes.div_ceil(4096), |m| {
            // Less the header page and the void mask's pages.
            let mask = if h.void_mask_offset == 0 { 0 } else { (8 + h.void_mask_bits_bytes()).div_ceil(4096) };
            m.stored_pages() - 1 - mask
        }),
        payload_checksum: format!("{:016x}", h.payload_checksum),
    }
}

/// The outcome of `verify`.
#[derive(Clone, Debug, Serialize)]
pub struct VerifyReport {
    pub file: String,
    pub ok: bool,
    pub header_checksum_ok: bool,
    pub payload_checksum_ok: bool,
    pub vertices_checked: u64,
    /// Vertices whose height, error or radius break the nesting invariants.
    pub nesting_violations: u64,
    /// Heights outside the header's [z_min, z_max].
    pub out_of_range: u64,
    /// Unused index slots that are not all zero.
    pub dirty_unused_slots: u64,
    /// Up to ten descriptions of failures.
    pub problems: Vec<String>,
}

/// Checks the payload checksum and, for every vertex, the nesting invariants (error ≥ raw error,
/// error ≥ children's, sphere ⊇ children's spheres), heights within the header's range, and that
/// unused slots are zero. The header checksum was already checked by [`TerrainFile::open`].
pub fn verify(file: &TerrainFile, progress: Progress) -> Result<VerifyReport> {
    let h = file.header();
    let grid = h.grid();
    let layout = file.layout();
    let records = file.records()?;
    let records = &*records;
    let mut problems = Vec::new();
    let payload_checksum_ok = match file.verify_payload() {
        Ok(()) => true,
        Err(e) => {
            problems.push(e.to_string());
            false
        }
    };
    let side = grid.size();
    let stored = h.stored();
    let get = |x: u32, y: u32| records[layout.index(x, y) as usize];
    let (z_lo, z_hi) = (h.z_min as f32, h.z_max as f32);
    let bar = progress.bar("verify", grid.vertices(), "vertices");
    let per_row: Vec<(u64, u64, Option<String>)> = (0..side)
        .into_par_iter()
        .map(|y| -> Result<(u64, u64, Option<String>)> {
            cancel::check()?;
            let (mut bad, mut range, mut first) = (0u64, 0u64, None);
            for x in 0..side {
                if let Some(p) = nesting_violation(grid, &stored, h.spacing_m, get, x, y) {
                    bad += 1;
                    first.get_or_insert(p);
                }
                if !stored.contains(x, y) {
                    continue;
                }
                let z = get(x, y).z;
                if !(z >= z_lo && z <= z_hi) {
                    range += 1;
                    first.get_or_insert(format!("({x}, {y}): height {z} outside {}..{}", h.z_min, h.z_max));
                }
            }
            bar.inc(side as u64);
            Ok((bad, range, first))
        })
        .collect::<Result<_>>()?;
    bar.finish_and_clear();
    let nesting_violations = per_row.iter().map(|r| r.0).sum();
    let out_of_range = per_row.iter().map(|r| r.1).sum();
    problems.extend(per_row.into_iter().filter_map(|r| r.2).take(10));

    let zero = Record::default();
    let dirty_unused_slots = if h.records > grid.vertices() {
        records.par_iter().enumerate().filter(|(i, r)| **r != zero && layout.coords(*i as u64).is_none()).count() as u64
    } else {
        0
    };
    if dirty_unused_slots > 0 {
        problems.push(format!("{dirty_unused_slots} unused index slots are not zero"));
    }
    problems.truncate(10);
    let ok = payload_checksum_ok && nesting_violations == 0 && out_of_range == 0 && dirty_unused_slots == 0;
    Ok(VerifyReport {
        file: file.path().display().to_string(),
        ok,
        header_checksum_ok: true,
        payload_checksum_ok,
        vertices_checked: grid.vertices(),
        nesting_violations,
        out_of_range,
        dirty_unused_slots,
        problems,
    })
}
