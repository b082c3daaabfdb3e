//! `relief verify`: checksums and the nesting invariants of a terrain file.

use std::path::PathBuf;
use std::process::ExitCode;

use relief::format::terrain::TerrainFile;
use relief::preprocess::inspect;

use super::{print_json, progress};

#[derive(clap::Args)]
pub struct Args {
    pub file: PathBuf,
    /// Print JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// No progress bars.
    #[arg(long, short)]
    pub quiet: bool,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let f = TerrainFile::open(&a.file)?;
    let r = inspect::verify(&f, progress(a.quiet))?;
    if a.json {
        print_json(&r)?;
    } else if r.ok {
        println!("{}: ok ({} vertices, checksums and nesting invariants hold)", r.file, r.vertices_checked);
    } else {
        println!(
            "{}: FAILED: payload checksum {}, {} nesting violations, {} heights out of range, {} dirty unused slots",
            r.file,
            if r.payload_checksum_ok { "ok" } else { "bad" },
            r.nesting_violations,
            r.out_of_range,
            r.dirty_unused_slots
        );
        for p in &r.problems {
            println!("  {p}");
        }
    }
    Ok(if r.ok { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}
