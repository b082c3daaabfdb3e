//! `relief refine`: refines one view of a terrain file, times it, and optionally proves the mesh
//! conforming ([`crate::refine::check`]) and compares it with the minimal mesh ([`crate::refine::minimal`]).

use std::time::Instant;

use serde::Serialize;

use crate::camera::Camera;
use crate::format::terrain::TerrainFile;
use crate::layout::Layout;
use crate::lod::metric::ErrorMetric;
use crate::refine::check::{check_strip, MeshCheck};
use crate::refine::minimal::minimal_mesh;
use crate::refine::{with_view, RecordSlice, RefineOptions, Refiner, Strip, View, ViewVisitor};

/// What to measure besides the refinement itself.
#[derive(Clone, Copy, Debug)]
pub struct ReportOptions {
    pub threads: usize,
    /// Timed refinements; the median is reported.
    pub repeat: usize,
    pub check: bool,
    pub compare_minimal: bool,
}

/// The figures `relief refine --json` prints.
#[derive(Clone, Debug, Serialize)]
pub struct RefineReport {
    pub file: String,
    pub layout: String,
    pub grid_size: u32,
    pub tolerance_px: f64,
    pub metric: String,
    pub cull: bool,
    pub geomorph: bool,
    pub threads: usize,
    pub repeat: usize,
    /// Non-degenerate triangles.
    pub triangles: u64,
    pub strip_len: u64,
    pub degenerate: u64,
    pub strip_vertices_per_triangle: f64,
    pub visited: u64,
    pub culled: u64,
    /// Median over the repeats, milliseconds.
    pub refine_ms: f64,
    pub refine_ms_min: f64,
    /// Non-degenerate triangles per second of median refinement time, millions.
    pub mtris_per_s: f64,
    /// The mesh check (`--check`): an object of its own, null when not asked for.
    pub check: Option<MeshCheck>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub minimal_triangles: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ratio_to_minimal: Option<f64>,
}

/// Median of a non-empty sample (mean of the middle two for even sizes).
pub fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        values[n / 2]
    } else {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    }
}

/// Refines `terrain` for `camera` `report.repeat` times and measures.
pub fn refine_report(
    terrain: &TerrainFile,
    camera: &Camera,
    options: &RefineOptions,
    report: &ReportOptions,
) -> crate::Result<(RefineReport, Strip)> {
    struct Go<'a> {
        terrain: &'a TerrainFile,
        options: &'a RefineOptions,
        report: &'a ReportOptions,
    }
    impl ViewVisitor for Go<'_> {
        type Output = crate::Result<(RefineReport, Strip)>;
        fn visit<L: Layout, M: ErrorMetric>(self, layout: &L, view: &View<M>) -> Self::Output {
            run(self.terrain, layout, view, self.options, self.report)
        }
    }
    with_view(terrain, camera, options, Go { terrain, options, report })
}

fn run<L: Layout, M: ErrorMetric>(
    terrain: &TerrainFile,
    layout: &L,
    view: &View<M>,
    options: &RefineOptions,
    report: &ReportOptions,
) -> crate::Result<(RefineReport, Strip)> {
    let records = terrain.records()?;
    let records = &*records;
    let slice = RecordSlice::new(records);
    let mut refiner = Refiner::new(report.threads)?;
    let mut strip = Strip::new();
    let mut times_ms = Vec::with_capacity(report.repeat.max(1));
    for _ in 0..report.repeat.max(1) {
        crate::sys::cancel::check()?;
        let t0 = Instant::now();
        match &slice {
            Some(slice) => refiner.refine(layout, slice, view, &mut strip),
            None => refiner.refine(layout, records, view, &mut strip),
        }
        times_ms.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    // The counts come from one more pass, untimed, with the counting loop (the timed loop counts
    // nothing, as in a flight); it makes the same strip.
    let counters = match &slice {
        Some(slice) => refiner.refine_counted(layout, slice, view, &mut strip),
        None => refiner.refine_counted(layout, records, view, &mut strip),
    };
    let refine_ms_min = times_ms.iter().copied().fold(f64::INFINITY, f64::min);
    let refine_ms = median(&mut times_ms);
    let (triangles, degenerate) = strip.triangle_counts();
    let grid = layout.grid();
    let check = report.check.then(|| {
        check_strip(grid, &strip, |x, y| view.is_active(x, y, grid.level(x, y), records[layout.index(x, y) as usize]))
    });
    let minimal =
        report.compare_minimal.then(|| minimal_mesh(layout, &terrain.header().stored(), records, view, &strip));
    Ok((
        RefineReport {
            file: terrain.path().display().to_string(),
            layout: layout.kind().name().to_string(),
            grid_size: grid.size(),
            tolerance_px: options.tolerance_px,
            metric: options.metric.name().to_string(),
            cull: options.cull,
            geomorph: options.morph_ratio.is_some(),
            threads: refiner.threads(),
            repeat: report.repeat.max(1),
            triangles,
            strip_len: strip.len() as u64,
            degenerate,
            strip_vertices_per_triangle: strip.len() as f64 / triangles.max(1) as f64,
            visited: counters.visited,
            culled: counters.culled,
            refine_ms,
            refine_ms_min,
            mtris_per_s: triangles as f64 / (refine_ms * 1e3),
            check,
            minimal_triangles: minimal.map(|m| m.triangles),
            ratio_to_minimal: minimal.map(|m| triangles as f64 / m.triangles as f64),
        },
        strip,
    ))
}
