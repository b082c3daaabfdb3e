//! The figures of the layout page-fault experiment (`relief layouts`), after Lindstrom &
//! Pascucci: cumulative page faults per frame for each index layout, and total page faults
//! against the screen-space tolerance τ. Drawn with `plotters` into an RGB buffer and written as
//! one PNG, atomically.
//!
//! Text is rendered with `ab_glyph` from a font compiled into the binary (Ubuntu Light, from
//! `epaint_default_fonts`, which egui already uses), so no system font library (fontconfig,
//! freetype) is needed.
//!
//! Both y axes are logarithmic and start at 1: a count of 0, which a log axis cannot show, is
//! drawn at 1.

use std::path::Path;
use std::sync::OnceLock;

use plotters::prelude::*;
use plotters::style::FontStyle;

use crate::Result;

/// The per-frame curve of one layout: `cumulative_faults[k]` is the number of page faults from
/// frame 0 through frame `k` inclusive.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameSeries {
    /// The layout's name as the CLI spells it (`row-major`, `tiled`, `interleaved`, `embedded`,
    /// `hz`); it picks the colour and is shown in the legend.
    pub label: String,
    /// Cumulative page faults, indexed by frame number.
    pub cumulative_faults: Vec<u64>,
}

/// The tolerance sweep of one layout: total page faults of the whole flight per τ.
#[derive(Debug, Clone, PartialEq)]
pub struct ToleranceSeries {
    /// The layout's name (see [`FrameSeries::label`]).
    pub label: String,
    /// `(τ in pixels, total page faults)`, in any order; τ must be finite and positive.
    pub points: Vec<(f64, u64)>,
}

/// Everything drawn in one PNG.
#[derive(Debug, Clone, Copy)]
pub struct Figure<'a> {
    /// The figure's title, drawn across the top (e.g. the terrain and the cache size).
    pub title: &'a str,
    /// The per-frame curves (left panel), one per layout; at least one, each with a frame.
    pub frames: &'a [FrameSeries],
    /// The tolerance sweep (right panel), one per layout. With fewer than two distinct τ values
    /// the right panel is left out.
    pub by_tolerance: &'a [ToleranceSeries],
    /// The τ (pixels) at which the per-frame curves were taken; named in the left panel's
    /// caption.
    pub frames_tolerance_px: f64,
}

/// Size of the PNG with both panels.
pub const TWO_PANEL_SIZE: (u32, u32) = (1600, 700);
/// Size of the PNG with only the per-frame panel (a single-τ run).
pub const ONE_PANEL_SIZE: (u32, u32) = (900, 650);

/// The font family name the plot's text is drawn with (registered from bytes, see the module doc).
const FONT: &str = "sans-serif";

/// Writes one PNG with the two panels side by side ([`TWO_PANEL_SIZE`]), or only the per-frame
/// panel ([`ONE_PANEL_SIZE`]) when `by_tolerance` holds fewer than two distinct τ values. The file
/// is written to a temporary file beside `out` and renamed over it, so `out` is never half
/// written.
///
/// Both y axes are logarithmic starting at 1; zero counts are drawn at 1. Each layout keeps its
/// colour across figures and runs (see [`layout_colour`]).
///
/// Errors: [`crate::AppError::Plot`] when there is nothing to draw (no per-frame series, a series without
/// frames), for a non-finite or non-positive τ, or when drawing fails; [`Error::Io`] when the
/// file cannot be written.
pub fn write_layouts_figure(out: &Path, fig: &Figure) -> Result<()> {
    validate(out, fig)?;
    register_font().map_err(|problem| crate::app_error::plot(out, problem))?;

    let taus = distinct_taus(fig.by_tolerance);
    let two_panels = taus.len() >= 2;
    let (w, h) = if two_panels { TWO_PANEL_SIZE } else { ONE_PANEL_SIZE };
    let mut buf = vec![255u8; w as usize * h as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        let e = |err: &dyn std::fmt::Display| crate::app_error::plot(out, err.to_string());
        root.fill(&WHITE).map_err(|x| e(&x))?;
        let body =
            root.margin(8, 0, 0, 0).titled(fig.title, (FONT, 28).into_font().color(&BLACK)).map_err(|x| e(&x))?;
        if two_panels {
            let (left, right) = body.split_horizontally(w / 2);
            draw_frames_panel(&left, fig).map_err(|x| e(&x))?;
            draw_tolerance_panel(&right, fig.by_tolerance, &taus).map_err(|x| e(&x))?;
        } else {
            draw_frames_panel(&body, fig).map_err(|x| e(&x))?;
        }
        root.present().map_err(|x| e(&x))?;
    }
    let image = image::RgbImage::from_raw(w, h, buf)
        .ok_or_else(|| crate::app_error::plot(out, "the drawing buffer does not match the image size"))?;
    crate::render::save_png(&image, out)
}

/// The colour of a layout's curves: fixed for the five terrain layouts (`row-major`, `tiled`,
/// `interleaved`, `embedded`, `hz`) and the five mesh-backend rows (`meta-node virt|ext`,
/// `pages raster|hilbert|2factor`; case and surrounding blanks ignored), and for any other label
/// one of five further colours chosen by a hash of the label, so it too is the same in every
/// figure.
pub fn layout_colour(label: &str) -> RGBColor {
    // Tableau-10 (matplotlib's default cycle): distinct, and readable on white.
    const KNOWN: [(&str, RGBColor); 10] = [
        ("row-major", RGBColor(31, 119, 180)),      // blue
        ("tiled", RGBColor(255, 127, 14)),          // orange
        ("interleaved", RGBColor(44, 160, 44)),     // green
        ("embedded", RGBColor(214, 39, 40)),        // red
        ("hz", RGBColor(148, 103, 189)),            // purple
        ("meta-node virt", RGBColor(140, 86, 75)),  // brown
        ("meta-node ext", RGBColor(227, 119, 194)), // pink
        ("pages raster", RGBColor(127, 127, 127)),  // grey
        ("pages hilbert", RGBColor(188, 189, 34)),  // olive
        ("pages 2factor", RGBColor(23, 190, 207)),  // cyan
    ];
    const OTHER: [RGBColor; 5] = [
        RGBColor(140, 86, 75),   // brown
        RGBColor(227, 119, 194), // pink
        RGBColor(127, 127, 127), // grey
        RGBColor(188, 189, 34),  // olive
        RGBColor(23, 190, 207),  // cyan
    ];
    let key = label.trim().to_ascii_lowercase();
    if let Some((_, c)) = KNOWN.iter().find(|(name, _)| *name == key) {
        return *c;
    }
    // FNV-1a: stable across runs and Rust versions (unlike std's hasher).
    let hash = key.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3));
    OTHER[(hash % OTHER.len() as u64) as usize]
}

fn validate(out: &Path, fig: &Figure) -> Result<()> {
    if fig.frames.is_empty() {
        return Err(crate::app_error::plot(out, "no per-frame series to plot (no layout was measured)"));
    }
    if let Some(s) = fig.frames.iter().find(|s| s.cumulative_faults.is_empty()) {
        return Err(crate::app_error::plot(out, format!("layout {:?} has no frames", s.label)));
    }
    if !(fig.frames_tolerance_px.is_finite() && fig.frames_tolerance_px > 0.0) {
        return Err(crate::app_error::plot(
            out,
            format!("tolerance τ = {} px is not a positive number", fig.frames_tolerance_px),
        ));
    }
    for s in fig.by_tolerance {
        if let Some(&(tau, _)) = s.points.iter().find(|(tau, _)| !(tau.is_finite() && *tau > 0.0)) {
            return Err(crate::app_error::plot(
                out,
                format!("layout {:?}: tolerance τ = {tau} px is not a positive number", s.label),
            ));
        }
    }
    Ok(())
}

/// Registers the embedded font once per process; the outcome is remembered.
fn register_font() -> std::result::Result<(), String> {
    static REGISTERED: OnceLock<std::result::Result<(), String>> = OnceLock::new();
    REGISTERED
        .get_or_init(|| {
            plotters::style::register_font(FONT, FontStyle::Normal, epaint_default_fonts::UBUNTU_LIGHT)
                .map_err(|_| "the embedded font (Ubuntu Light) could not be parsed".to_string())
        })
        .clone()
}

/// The distinct τ values of the sweep, ascending.
fn distinct_taus(series: &[ToleranceSeries]) -> Vec<f64> {
    let mut taus: Vec<f64> = series.iter().flat_map(|s| s.points.iter().map(|p| p.0)).collect();
    taus.sort_by(f64::total_cmp);
    taus.dedup();
    taus
}

/// A count on a log axis: 0 is shown at 1.
fn log_count(v: u64) -> f64 {
    v.max(1) as f64
}

/// The top of a log axis: the power of ten at or above twice the largest value (headroom for the
/// legend), at least 10.
fn log_axis_top(max: u64) -> f64 {
    let m = (2.0 * log_count(max)).max(10.0);
    10f64.powf(m.log10().ceil())
}

/// Tick label for a count: plain below 10,000, else `2e5` style.
fn count_label(v: f64) -> String {
    if v < 1e4 {
        return format!("{v:.0}");
    }
    let e = v.log10().floor();
    let m = v / 10f64.powf(e);
    if (m - m.round()).abs() < 1e-6 {
        format!("{:.0}e{e:.0}", m.round())
    } else {
        format!("{m:.1}e{e:.0}")
    }
}

/// τ as a short label: `0.5`, `2`, `1.25`.
fn tau_label(v: f64) -> String {
    let s = format!("{v:.3}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

type Area<'b> = DrawingArea<BitMapBackend<'b>, plotters::coord::Shift>;
type DrawResult = std::result::Result<(), DrawingAreaErrorKind<<BitMapBackend<'static> as DrawingBackend>::ErrorType>>;

fn draw_frames_panel(area: &Area<'_>, fig: &Figure) -> DrawResult {
    let frames = fig.frames.iter().map(|s| s.cumulative_faults.len()).max().unwrap_or(1);
    let last_frame = (frames as u64).saturating_sub(1).max(1);
    let max = fig.frames.iter().flat_map(|s| s.cumulative_faults.iter().copied()).max().unwrap_or(1);
    let caption = format!("cumulative page faults per frame, τ = {} px", tau_label(fig.frames_tolerance_px));
    let mut chart = ChartBuilder::on(area)
        .caption(caption, (FONT, 22))
        .margin(12)
        .x_label_area_size(50)
        .y_label_area_size(80)
        .build_cartesian_2d(0u64..last_frame, (1f64..log_axis_top(max)).log_scale())?;
    chart
        .configure_mesh()
        .x_desc("frame")
        .y_desc("cumulative page faults (log)")
        .x_label_formatter(&|v| v.to_string())
        .y_label_formatter(&|v| count_label(*v))
        .label_style((FONT, 15))
        .axis_desc_style((FONT, 18))
        .light_line_style(RGBColor(235, 235, 235))
        .bold_line_style(RGBColor(210, 210, 210))
        .draw()?;
    for s in fig.frames {
        let colour = layout_colour(&s.label);
        let points = s.cumulative_faults.iter().enumerate().map(|(k, &v)| (k as u64, log_count(v)));
        chart
            .draw_series(LineSeries::new(points, colour.stroke_width(2)))?
            .label(s.label.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], colour.stroke_width(3)));
        if s.cumulative_faults.len() == 1 {
            // A single frame makes no line: show the point.
            chart.draw_series(std::iter::once(Circle::new(
                (0, log_count(s.cumulative_faults[0])),
                4,
                colour.filled(),
            )))?;
        }
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .margin(12)
        .label_font((FONT, 16))
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

fn draw_tolerance_panel(area: &Area<'_>, series: &[ToleranceSeries], taus: &[f64]) -> DrawResult {
    let lo = taus.first().copied().unwrap_or(1.0);
    let hi = taus.last().copied().unwrap_or(2.0);
    // A little room left and right so the end markers are not on the frame.
    let pad = (hi / lo).powf(0.06);
    let max = series.iter().flat_map(|s| s.points.iter().map(|p| p.1)).max().unwrap_or(1);
    let mut chart = ChartBuilder::on(area)
        .caption("total page faults vs screen-space tolerance", (FONT, 22))
        .margin(12)
        .x_label_area_size(50)
        .y_label_area_size(80)
        .build_cartesian_2d(
            ((lo / pad)..(hi * pad)).log_scale().with_key_points(taus.to_vec()),
            (1f64..log_axis_top(max)).log_scale(),
        )?;
    chart
        .configure_mesh()
        .x_desc("screen-space tolerance τ (px)")
        .y_desc("page faults (log)")
        .x_label_formatter(&|v| tau_label(*v))
        .y_label_formatter(&|v| count_label(*v))
        .label_style((FONT, 15))
        .axis_desc_style((FONT, 18))
        .light_line_style(RGBColor(235, 235, 235))
        .bold_line_style(RGBColor(210, 210, 210))
        .draw()?;
    for s in series.iter().filter(|s| !s.points.is_empty()) {
        let colour = layout_colour(&s.label);
        let mut points: Vec<(f64, f64)> = s.points.iter().map(|&(t, v)| (t, log_count(v))).collect();
        points.sort_by(|a, b| a.0.total_cmp(&b.0));
        chart
            .draw_series(LineSeries::new(points.iter().copied(), colour.stroke_width(2)))?
            .label(s.label.clone())
            .legend(move |(x, y)| {
                EmptyElement::at((x, y))
                    + PathElement::new(vec![(0, 0), (24, 0)], colour.stroke_width(3))
                    + Circle::new((12, 0), 4, colour.filled())
            });
        chart.draw_series(points.iter().map(|&p| Circle::new(p, 5, colour.filled())))?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .margin(12)
        .label_font((FONT, 16))
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

/// The label of a run in the figures: the terrain's layout name (which picks its fixed colour), or
/// the backend and its layout or access.
fn run_label(r: &crate::faults::FaultRun) -> String {
    match r.backend {
        crate::faults::Backend::Terrain => r.layout.clone(),
        b => format!("{} {}", b.name(), r.layout),
    }
}

/// Draws the paper's two figures for `report` into `out` (PNG): cumulative faults per frame at the
/// smallest τ, and total faults against τ, one line per backend and layout.
pub fn plot_report(report: &crate::faults::LayoutsReport, out: &Path) -> Result<()> {
    let first_tau = report.runs.iter().map(|r| r.tolerance).fold(f64::INFINITY, f64::min);
    let mut labels: Vec<String> = Vec::new();
    for r in &report.runs {
        if !labels.contains(&run_label(r)) {
            labels.push(run_label(r));
        }
    }
    let frames: Vec<FrameSeries> = labels
        .iter()
        .filter_map(|l| report.runs.iter().find(|r| run_label(r) == *l && r.tolerance == first_tau))
        .map(|r| FrameSeries {
            label: run_label(r),
            cumulative_faults: r
                .faults_per_frame
                .iter()
                .scan(0u64, |sum, f| {
                    *sum += f;
                    Some(*sum)
                })
                .collect(),
        })
        .collect();
    let by_tolerance: Vec<ToleranceSeries> = labels
        .iter()
        .map(|l| ToleranceSeries {
            label: l.clone(),
            points: report.runs.iter().filter(|r| run_label(r) == *l).map(|r| (r.tolerance, r.faults)).collect(),
        })
        .collect();
    let name = Path::new(&report.input).file_name().map_or(report.input.clone(), |n| n.to_string_lossy().into_owned());
    let title = format!(
        "{name}: {} frames, LRU cache {:.1} MiB of {} B pages",
        report.frames,
        report.memory_bytes as f64 / 1048576.0,
        report.page_bytes
    );
    write_layouts_figure(
        out,
        &Figure { title: &title, frames: &frames, by_tolerance: &by_tolerance, frames_tolerance_px: first_tau },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    const LAYOUTS: [&str; 5] = ["row-major", "tiled", "interleaved", "embedded", "hz"];

    /// Synthetic numbers: layout `i` faults about 2^(4-i) times as much as `hz`.
    fn frames(n: usize) -> Vec<FrameSeries> {
        LAYOUTS
            .iter()
            .enumerate()
            .map(|(i, l)| {
                let per = 1u64 << (4 - i);
                let cumulative_faults = (0..n as u64).map(|k| 5000 * per + k * k * per).collect();
                FrameSeries { label: l.to_string(), cumulative_faults }
            })
            .collect()
    }

    fn sweep(taus: &[f64]) -> Vec<ToleranceSeries> {
        LAYOUTS
            .iter()
            .enumerate()
            .map(|(i, l)| ToleranceSeries {
                label: l.to_string(),
                points: taus.iter().map(|&t| (t, ((2e6 * (5 - i) as f64) / (t * t)) as u64)).collect(),
            })
            .collect()
    }

    fn count_colour(img: &image::RgbImage, x: std::ops::Range<u32>, c: RGBColor) -> usize {
        img.enumerate_pixels().filter(|(px, _, p)| x.contains(px) && p.0 == [c.0, c.1, c.2]).count()
    }

    fn distinct_colours(img: &image::RgbImage) -> usize {
        img.pixels().map(|p| p.0).collect::<std::collections::HashSet<_>>().len()
    }

    #[test]
    fn two_panels_with_every_layout_drawn() {
        let dir = tempfile::tempdir().expect("temp dir");
        let out = dir.path().join("layouts.png");
        let f = frames(300);
        let t = sweep(&[0.5, 1.0, 2.0, 4.0, 8.0]);
        let fig = Figure {
            title: "synthetic: 5 layouts, LRU 64 pages",
            frames: &f,
            by_tolerance: &t,
            frames_tolerance_px: 2.0,
        };
        write_layouts_figure(&out, &fig).expect("figure written");
        let img = image::open(&out).expect("decodes").to_rgb8();
        assert_eq!(img.dimensions(), TWO_PANEL_SIZE);
        // Text (anti-aliased) and five line colours: far more than a blank or flat image.
        assert!(distinct_colours(&img) > 50, "{} colours", distinct_colours(&img));
        let (w, _) = img.dimensions();
        for l in LAYOUTS {
            let c = layout_colour(l);
            // Far more pixels than the legend's swatch (about 24 × 3): the curves are drawn, in
            // both panels.
            let left = count_colour(&img, 0..w / 2, c);
            let right = count_colour(&img, w / 2..w, c);
            assert!(left > 300, "{l}: {left} pixels of its colour in the left panel");
            assert!(right > 300, "{l}: {right} pixels of its colour in the right panel");
        }
        // No temporary file is left beside the output.
        let names: Vec<_> =
            std::fs::read_dir(dir.path()).expect("list").map(|e| e.expect("entry").file_name()).collect();
        assert_eq!(names, vec![std::ffi::OsString::from("layouts.png")]);
    }

    #[test]
    fn one_tolerance_draws_only_the_frame_panel() {
        let dir = tempfile::tempdir().expect("temp dir");
        let out = dir.path().join("one.png");
        let f = frames(120);
        let t = sweep(&[2.0]);
        let fig = Figure { title: "single τ", frames: &f, by_tolerance: &t, frames_tolerance_px: 2.0 };
        write_layouts_figure(&out, &fig).expect("figure written");
        let img = image::open(&out).expect("decodes").to_rgb8();
        assert_eq!(img.dimensions(), ONE_PANEL_SIZE);
        assert!(distinct_colours(&img) > 50);
        for l in LAYOUTS {
            assert!(count_colour(&img, 0..ONE_PANEL_SIZE.0, layout_colour(l)) > 300, "{l}");
        }
        // No sweep at all: the same.
        let fig = Figure { by_tolerance: &[], ..fig };
        write_layouts_figure(&out, &fig).expect("figure written");
        assert_eq!(image::open(&out).expect("decodes").to_rgb8().dimensions(), ONE_PANEL_SIZE);
    }

    #[test]
    fn zeros_draw_without_error() {
        let dir = tempfile::tempdir().expect("temp dir");
        let out = dir.path().join("zeros.png");
        let f = vec![
            FrameSeries { label: "hz".into(), cumulative_faults: vec![0, 0, 0, 3, 3, 10] },
            FrameSeries { label: "tiled".into(), cumulative_faults: vec![0; 6] },
            FrameSeries { label: "single".into(), cumulative_faults: vec![0] },
        ];
        let t = vec![
            ToleranceSeries { label: "hz".into(), points: vec![(1.0, 0), (4.0, 0), (2.0, 5)] },
            ToleranceSeries { label: "tiled".into(), points: vec![] },
        ];
        let fig = Figure { title: "zeros", frames: &f, by_tolerance: &t, frames_tolerance_px: 1.0 };
        write_layouts_figure(&out, &fig).expect("figure written");
        assert_eq!(image::open(&out).expect("decodes").to_rgb8().dimensions(), TWO_PANEL_SIZE);
    }

    #[test]
    fn empty_input_is_an_error() {
        let dir = tempfile::tempdir().expect("temp dir");
        let out = dir.path().join("empty.png");
        let fig = Figure { title: "empty", frames: &[], by_tolerance: &[], frames_tolerance_px: 1.0 };
        let err = write_layouts_figure(&out, &fig).expect_err("nothing to draw");
        assert!(matches!(crate::AppError::of(&err), Some(crate::AppError::Plot { .. })), "{err}");
        assert!(err.to_string().contains("no per-frame series"), "{err}");

        let f = vec![FrameSeries { label: "hz".into(), cumulative_faults: vec![] }];
        let err = write_layouts_figure(&out, &Figure { frames: &f, ..fig }).expect_err("no frames");
        assert!(err.to_string().contains("\"hz\" has no frames"), "{err}");

        let f = frames(3);
        let t = vec![ToleranceSeries { label: "hz".into(), points: vec![(0.0, 1), (1.0, 1)] }];
        let err = write_layouts_figure(&out, &Figure { frames: &f, by_tolerance: &t, ..fig }).expect_err("τ = 0");
        assert!(matches!(crate::AppError::of(&err), Some(crate::AppError::Plot { .. })), "{err}");
        assert!(!out.exists(), "nothing written on error");
    }

    #[test]
    fn colours_are_stable_and_distinct() {
        let known: Vec<RGBColor> = LAYOUTS.iter().map(|l| layout_colour(l)).collect();
        for (i, a) in known.iter().enumerate() {
            for b in &known[i + 1..] {
                assert_ne!(a, b);
            }
        }
        assert_eq!(layout_colour(" Row-Major "), known[0]);
        assert_eq!(layout_colour("morton-3d"), layout_colour("morton-3d"));
        assert!(!known.contains(&layout_colour("morton-3d")));
    }

    #[test]
    fn labels() {
        assert_eq!(tau_label(0.5), "0.5");
        assert_eq!(tau_label(2.0), "2");
        assert_eq!(tau_label(1.25), "1.25");
        assert_eq!(count_label(1.0), "1");
        assert_eq!(count_label(5000.0), "5000");
        assert_eq!(count_label(100000.0), "1e5");
        assert_eq!(count_label(250000.0), "2.5e5");
        assert_eq!(log_axis_top(0), 10.0);
        assert_eq!(log_axis_top(400), 1000.0);
        assert_eq!(log_axis_top(600), 10000.0);
    }
}
