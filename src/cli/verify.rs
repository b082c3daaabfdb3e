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
    let local = !relief::pager::remote::is_remote(&a.file);
    if local && relief::format::sniff(&a.file)? == Some(relief::format::FileKind::Imagery) {
        // An imagery tile file: its payload checksum (a mismatch is the error).
        let f = relief::format::imagery::ImageryFile::open(&a.file, relief::pager::Access::Read)?;
        f.verify()?;
        if a.json {
            print_json(
                &serde_json::json!({ "file": a.file.display().to_string(), "ok": true, "tiles": f.header().tiles }),
            )?;
        } else {
            println!("{}: ok ({} tiles, the payload checksum holds)", a.file.display(), f.header().tiles);
        }
        return Ok(ExitCode::SUCCESS);
    }
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
