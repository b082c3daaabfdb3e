//! Flying any source headless along a path (the one loop, `flight::frame::fly`), or a mesh
//! source in a window; and the one line a flight's summary prints as.

use std::path::Path;
use std::process::ExitCode;

use relief::camera::{Camera, UpAxis};
use relief::flight::frame::{
    fly, ConvergeEnd, Convergence, FlightOptions, FlightReport, FlightSummary, FrameSource, Presenter,
    DEFAULT_CONVERGE_TIMEOUT, NODE_CHANGES, PAGE_CHANGES, STRIP_CHANGES,
};
use relief::flight::FlightPath;
use relief::render::Gpu;
use relief::window::{mesh_window, MeshWindowOptions};

use super::{fmt_bytes, progress, FlyArgs};

/// The camera of every frame of a flight path, with `up` up (errors name the file and the frame).
pub fn cameras(flight: &FlightPath, file: &Path, up: UpAxis, fly: &FlyArgs) -> anyhow::Result<Vec<Camera>> {
    (0..flight.frames.len())
        .map(|k| {
            flight
                .camera_with_up(k, up, fly.fov, fly.width, fly.height)
                .map_err(|e| anyhow::anyhow!("{}: frame {k}: {e}", file.display()))
        })
        .collect()
}

/// Flies `source` along `flight` headless, drawing with what `presenter` makes (none with
/// `--no-render`), and prints the report as the flags ask.
/// `presenter` draws the frames; none with `--no-render` (the update alone is timed).
pub fn headless(
    source: &mut dyn FrameSource,
    file: &Path,
    flight: &FlightPath,
    (up, tolerance_px): (UpAxis, f64),
    fly_args: &FlyArgs,
    mut presenter: Option<Box<dyn Presenter + '_>>,
) -> anyhow::Result<ExitCode> {
    let path = fly_args.path.as_deref().unwrap_or(Path::new("path"));
    let cameras = cameras(flight, path, up, fly_args)?;
    let mut options = FlightOptions::new(fly_args.width, fly_args.height, tolerance_px);
    options.pace_ms = fly_args.pace;
    options.converge_timeout = match (fly_args.converge, fly_args.no_converge) {
        (_, true) => None,
        (Some(s), false) => Some(std::time::Duration::from_secs_f64(s)),
        (None, false) => source.converges_by_default().then_some(DEFAULT_CONVERGE_TIMEOUT),
    };
    options.frames_out = fly_args.frames_out.clone();
    options.stats_out = fly_args.stats.clone();
    options.progress = progress(fly_args.quiet);
    let report = fly(source, &cameras, presenter.as_deref_mut(), &options)?;
    if fly_args.json {
        super::print_json(&report)?;
    } else {
        print_summary(file, &report);
    }
    Ok(ExitCode::SUCCESS)
}

/// What a flight's source changed per frame, in its own counters ([`FrameSource::changes`]).
fn changes_per_frame(s: &FlightSummary) -> String {
    match s.changes {
        NODE_CHANGES => format!(
            "{:.1} splits + collapses per frame ({:.1} + {:.1}, means), {:.2}% misses",
            s.splits.mean + s.collapses.mean,
            s.splits.mean,
            s.collapses.mean,
            s.miss_pct
        ),
        PAGE_CHANGES => format!(
            "{:.1} pages gained + lost per frame ({:.1} gained, {:.1} lost, means)",
            s.pages_gained.mean + s.pages_lost.mean,
            s.pages_gained.mean,
            s.pages_lost.mean
        ),
        STRIP_CHANGES if s.misses.total > 0.0 => {
            format!(
                "{:.0} strip vertices per frame (mean), {:.1} blocks missed per frame",
                s.strip_len.mean, s.misses.mean
            )
        }
        STRIP_CHANGES => format!("{:.0} strip vertices per frame (mean)", s.strip_len.mean),
        other => format!("changes: {other}"),
    }
}

/// How converging stopped, for the summary line: nothing when complete, else why and what was
/// left.
fn convergence_end(c: &Convergence) -> String {
    let left =
        format!("; left: {} switches missing their meta-nodes, {} still changing", c.misses_left, c.changes_left);
    match c.end {
        ConvergeEnd::Complete => String::new(),
        ConvergeEnd::Timeout => format!(" (incomplete: the time allowed ran out{left})"),
        ConvergeEnd::Stalled => {
            format!(" (incomplete: stopped making progress, the view's front does not fit the memory given{left})")
        }
    }
}

/// One line of what a flight did (with a second for the disk-page fetch).
pub fn print_summary(file: &Path, report: &FlightReport) {
    let s = &report.summary;
    println!(
        "{} ({}): {} frames at {} x {}, {:.1} fps, frame {:.2} ms, update {:.2} ms, render {:.2} ms (medians), {:.0} triangles per frame (mean), {}, {} pages read, {} major / {} minor page faults, {} uploaded ({})",
        file.display(),
        s.source,
        s.frames,
        s.width,
        s.height,
        s.fps,
        s.frame_ms.median,
        s.update_ms.median,
        s.render_ms.median,
        s.triangles.mean,
        changes_per_frame(s),
        s.pages_read.total,
        s.major_faults.total,
        s.minor_faults.total,
        fmt_bytes(s.upload_bytes.total as u64),
        s.adapter
    );
    if let Some(c) = &s.converge {
        println!(
            "  first view converged before frame 0: {} updates, {:.1} ms, {} pages read, {} major faults, {} device requests, {} triangles{}",
            c.updates,
            c.ms,
            c.pages_read,
            c.major_faults,
            c.device_requests,
            c.triangles,
            convergence_end(c)
        );
    }
    if !s.jumps.is_empty() {
        let ms: f64 = s.jumps.iter().map(|j| j.convergence.ms).sum();
        let complete = s.jumps.iter().filter(|j| j.convergence.complete).count();
        println!(
            "  {} jumps converged before their frames ({} complete), {:.1} ms in all, first at frame {}",
            s.jumps.len(),
            complete,
            ms,
            s.jumps[0].frame
        );
    }
    if s.pages_requested.total > 0.0 {
        println!(
            "  pages: {:.1} requested per frame (of {:.1} named by the k-d tree), seek {:.1} pages, fetch {:.2} ms (reads {:.2} ms) per frame (means)",
            s.pages_requested.mean, s.pages_candidate.mean, s.seek_pages.mean, s.update_ms.mean, s.read_ms.mean
        );
    }
    if s.requests > 0 || s.settle_updates.is_some() {
        let first = match (s.first_complete_frame, s.first_complete_round_trips, s.first_complete_s) {
            (Some(f), Some(r), Some(t)) => format!("frame {f} after {r} round trips ({t:.2} s)"),
            _ => "none during the flight".into(),
        };
        println!(
            "  network: {} requests, {} received; {} of {} frames coarser than wanted (data missing); first complete {first}; final strip {} triangles, digest {} (after {} more updates)",
            s.requests,
            fmt_bytes(s.net_bytes),
            s.coarse_frames,
            s.frames,
            s.final_triangles,
            s.final_digest,
            s.settle_updates.unwrap_or(0)
        );
    } else {
        println!("  final strip {} triangles, digest {}", s.final_triangles, s.final_digest);
    }
}

/// Shows a mesh source as `fly` asks: headless along `flight` when given, else in a window.
pub fn mesh(
    source: &mut dyn FrameSource,
    file: &Path,
    flight: Option<FlightPath>,
    up: Option<UpAxis>,
    tolerance_px: f64,
    fly_args: &FlyArgs,
) -> anyhow::Result<ExitCode> {
    super::check_tolerance(tolerance_px)?;
    let up = up.unwrap_or_else(|| UpAxis::guess(source.bounds().extent()));
    let Some(flight) = flight else {
        let options = MeshWindowOptions {
            window: fly_args.window()?,
            tolerance_px,
            wireframe: fly_args.wireframe,
            up,
            source_name: source.describe(),
        };
        mesh_window(source, &file.display().to_string(), options)?;
        return Ok(ExitCode::SUCCESS);
    };
    let gpu = if fly_args.no_render { None } else { Some(Gpu::headless()?) };
    let bounds = source.bounds();
    let (w, h, style) = (fly_args.width, fly_args.height, relief::render::MeshStyle { wireframe: fly_args.wireframe });
    let presenter: Option<Box<dyn Presenter + '_>> = match &gpu {
        Some(gpu) => Some(Box::new(relief::render::MeshPresenter::new(gpu, bounds, up, w, h, style)?)),
        None => None,
    };
    headless(source, file, &flight, (up, tolerance_px), fly_args, presenter)
}
