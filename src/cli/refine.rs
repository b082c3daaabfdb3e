//! `relief refine`: one view refined into a strip, its size, speed and checks.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::bail;
use relief::format::terrain::TerrainFile;
use relief::refine::report::{refine_report, ReportOptions};

use super::{print_json, ViewArgs};

#[derive(clap::Args)]
pub struct Args {
    pub file: PathBuf,
    #[command(flatten)]
    pub view: ViewArgs,
    /// Prove the mesh conforming: edges, areas, windings, T-junctions.
    #[arg(long)]
    pub check: bool,
    /// Compare with the minimal mesh for the same view and tolerance.
    #[arg(long)]
    pub compare_minimal: bool,
    /// Refine this many times and report the median time.
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub repeat: usize,
    /// Print JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    if a.repeat == 0 {
        bail!("--repeat must be at least 1");
    }
    let f = TerrainFile::open(&a.file)?;
    let (camera, options) = a.view.resolve(&f)?;
    let report = ReportOptions {
        threads: a.view.refine.threads,
        repeat: a.repeat,
        check: a.check,
        compare_minimal: a.compare_minimal,
    };
    let (r, _) = refine_report(&f, &camera, &options, &report)?;
    if a.json {
        print_json(&r)?;
    } else {
        println!(
            "{}: {} triangles, strip {} ({} degenerate, {:.3} vertices/triangle), visited {}, culled {}",
            r.file, r.triangles, r.strip_len, r.degenerate, r.strip_vertices_per_triangle, r.visited, r.culled
        );
        println!(
            "refine {:.3} ms median of {} ({:.3} ms min), {:.1} M triangles/s, {} thread(s), layout {}",
            r.refine_ms, r.repeat, r.refine_ms_min, r.mtris_per_s, r.threads, r.layout
        );
        if let Some(c) = &r.check {
            println!(
                "check: {} ({} edge errors, {} winding errors, area {}, {} inactive vertices)",
                if c.crack_free { "crack-free" } else { "CRACKS" },
                c.edge_errors,
                c.winding_errors,
                if c.area_ok { "ok" } else { "wrong" },
                c.inactive_vertices
            );
        }
        if let (Some(m), Some(ratio)) = (r.minimal_triangles, r.ratio_to_minimal) {
            println!("minimal mesh: {m} triangles, ratio {ratio:.4}");
        }
    }
    let failed = r.check.as_ref().is_some_and(|c| !c.crack_free || c.inactive_vertices > 0);
    Ok(if failed { ExitCode::FAILURE } else { ExitCode::SUCCESS })
}
