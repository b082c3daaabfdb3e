//! `relief layouts`: the page-fault experiment (the terrain paper's), for every backend.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::bail;
use relief::faults::{run_layouts, terrain_in_layout, Backend, LayoutsOptions};
use relief::flight::FlightPath;
use relief::format::terrain::{TerrainFile, RECORD_BYTES};
use relief::layout::LayoutKind;
use relief::plot::plot_report;

use super::{check_output_file, fmt_bytes, parse_bytes, parse_memory, print_json, progress, DeviceArgs, ImageArgs};

#[derive(clap::Args)]
pub struct Args {
    pub input: PathBuf,
    /// Flight path JSON (see `relief path`).
    #[arg(long, value_name = "PATH.json")]
    pub path: PathBuf,
    /// Page cache size: bytes with an optional K/M/G suffix (binary), or a fraction such as
    /// 1/16 of the terrain's data (posts × 12 bytes, no index-space waste).
    #[arg(long, value_name = "BYTES|1/N")]
    pub memory: String,
    /// Page size in bytes (a power of two; K/M suffixes allowed).
    #[arg(long, value_name = "BYTES", default_value = "4096")]
    pub page_size: String,
    /// Screen-space tolerances τ in pixels, comma-separated.
    #[arg(long, value_name = "PX[,PX…]", default_value = "1", allow_hyphen_values = true)]
    pub tolerance: String,
    /// The terrain's index layouts to compare, comma-separated.
    #[arg(long, value_name = "a,b,…", default_value = "row-major,tiled,interleaved,embedded,hz")]
    pub layouts: String,
    /// Backends to run, comma-separated: terrain (its index layouts), meta-node (the terrain
    /// exported as a mesh, its meta-node trees read through the map and through a buffer pool of
    /// --memory), pages (the same mesh as disk pages in raster, hilbert and 2factor order), or
    /// all. The mesh backends' files are built once into --cache-dir.
    #[arg(long, value_name = "a,b,…", default_value = "terrain")]
    pub backends: String,
    /// The mesh backends' mesh: every N-th post of the terrain.
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub mesh_step: u32,
    #[command(flatten)]
    pub image: ImageArgs,
    /// Also count real OS page faults (cold mapped runs).
    #[arg(long)]
    pub os: bool,
    /// With --os: run the cold runs under a cgroup v1 memory limit of BYTES (K/M/G) on what
    /// they allocate and page in (needs root and a v1 memory controller; says why not).
    #[arg(long, value_name = "BYTES", requires = "os")]
    pub os_cap: Option<String>,
    /// With --os: the cold runs read each file through an emulated device (its time per frame
    /// is then reported as "os ms/frame").
    #[command(flatten)]
    pub device: DeviceArgs,
    /// Where converted layouts are kept (default ~/.cache/relief/layouts).
    #[arg(long, value_name = "DIR")]
    pub cache_dir: Option<PathBuf>,
    /// Print the results as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// Write the two figures (cumulative faults per frame; faults against τ) to this PNG.
    #[arg(long, value_name = "OUT.png")]
    pub plot: Option<PathBuf>,
    /// No progress bars.
    #[arg(long, short)]
    pub quiet: bool,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    if a.device.device_latency.is_some() && !a.os {
        anyhow::bail!("--device-latency needs --os: only the cold OS runs read their files (the model runs count)");
    }
    let os_cap_bytes = a.os_cap.as_deref().map(|c| parse_bytes("--os-cap", c)).transpose()?;
    let page_bytes = parse_bytes("--page-size", &a.page_size)?;
    let tolerances_px = a
        .tolerance
        .split(',')
        .map(|t| match t.trim().parse::<f64>() {
            Ok(v) if v > 0.0 && v.is_finite() => Ok(v),
            _ => Err(anyhow::anyhow!("--tolerance: expected positive pixels like 1,2,4, got '{}'", a.tolerance)),
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let kinds = a
        .layouts
        .split(',')
        .map(|n| {
            LayoutKind::from_name(n.trim()).ok_or_else(|| {
                anyhow::anyhow!(
                    "--layouts: unknown layout '{}' (choose from {})",
                    n.trim(),
                    LayoutKind::ALL.map(LayoutKind::name).join(", ")
                )
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let backends = if a.backends.trim() == "all" {
        Backend::ALL.to_vec()
    } else {
        a.backends
            .split(',')
            .map(|n| {
                Backend::from_name(n.trim()).ok_or_else(|| {
                    anyhow::anyhow!(
                        "--backends: unknown backend '{}' (choose from terrain, meta-node, pages, all)",
                        n.trim()
                    )
                })
            })
            .collect::<anyhow::Result<Vec<_>>>()?
    };
    if a.mesh_step == 0 {
        bail!("--mesh-step must be at least 1");
    }
    relief::pager::PageGeometry::new(page_bytes).map_err(|e| anyhow::anyhow!("--page-size: {e}"))?;
    if let Some(p) = &a.plot {
        check_output_file("--plot", p)?;
    }
    let flight = FlightPath::load(&a.path)?;
    if !a.input.exists() && !relief::pager::remote::is_remote(&a.input) {
        bail!("{}: no such file", a.input.display());
    }
    let cache_dir = a.cache_dir.unwrap_or_else(|| relief::preprocess::convert::cache_dir().join("layouts"));
    let first = terrain_in_layout(&a.input, kinds[0], &cache_dir, progress(a.quiet))?;
    let memory_bytes = {
        let t = TerrainFile::open(&first)?;
        parse_memory("--memory", &a.memory, t.grid().vertices() * RECORD_BYTES as u64)?
    };
    let ImageArgs { width, height, fov } = a.image;
    let cameras = (0..flight.frames.len())
        .map(|k| {
            flight.camera(k, fov, width, height).map_err(|e| anyhow::anyhow!("{}: frame {k}: {e}", a.path.display()))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let options = LayoutsOptions {
        memory_bytes,
        page_bytes,
        tolerances_px,
        layouts: kinds,
        backends,
        mesh_step: a.mesh_step,
        width_px: width,
        height_px: height,
        fov_x_deg: fov,
        os: a.os,
        os_cap_bytes,
        device: a.device.spec()?,
        progress: progress(a.quiet),
    };
    let report = run_layouts(&a.input, &cameras, &cache_dir, &options)?;
    if let Some(out) = &a.plot {
        plot_report(&report, out)?;
    }
    if a.json {
        print_json(&report)?;
        return Ok(ExitCode::SUCCESS);
    }
    println!(
        "{}: {} frames, {} of memory ({} pages of {} B){}, {}",
        report.input,
        report.frames,
        fmt_bytes(report.memory_bytes),
        report.cache_pages,
        report.page_bytes,
        report.mesh.as_ref().map_or(String::new(), |m| format!(
            ", mesh of every {} post: {} vertices, {} triangles",
            if m.step == 1 { "".to_string() } else { format!("{}th", m.step) },
            m.vertices,
            m.triangles
        )),
        report.os_note.as_deref().unwrap_or("model only")
    );
    println!(
        "{:<10} {:<12} {:<6} {:>6} {:>12} {:>10} {:>9} {:>12} {:>11} {:>8} {:>9} {:>9} {:>10}{}",
        "backend",
        "layout",
        "access",
        "τ px",
        "faults",
        "per frame",
        "max",
        "distinct pg",
        "lower bnd",
        "×bound",
        "×first",
        "ms/frame",
        "tris/frame",
        if a.os { "  os major  os read MiB  os ms/frame" } else { "" }
    );
    for r in &report.runs {
        println!(
            "{:<10} {:<12} {:<6} {:>6} {:>12} {:>10.1} {:>9} {:>12} {:>11} {:>8.2} {:>9} {:>9.2} {:>10.0}{}",
            r.backend.name(),
            r.layout,
            r.access.name(),
            r.tolerance,
            r.faults,
            r.faults_per_frame_mean,
            r.faults_per_frame_max,
            r.distinct_pages,
            r.lower_bound,
            r.ratio_to_lower_bound,
            r.ratio_to_first.map_or("-".into(), |v| format!("{v:.3}")),
            r.update_ms_per_frame,
            r.triangles_per_frame_mean,
            r.os.as_ref().map_or(String::new(), |o| format!(
                "  {:>8} {:>12.1} {:>12.2}",
                o.major,
                o.device.map_or(o.read_bytes, |d| d.bytes) as f64 / 1048576.0,
                o.ms_per_frame_mean
            ))
        );
    }
    Ok(ExitCode::SUCCESS)
}
