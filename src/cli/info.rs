//! `relief info`: what a terrain file holds.

use std::path::PathBuf;
use std::process::ExitCode;

use relief::format::terrain::TerrainFile;
use relief::preprocess::inspect;

use super::{fmt_bytes, print_json};

#[derive(clap::Args)]
pub struct Args {
    pub file: PathBuf,
    /// Print JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let f = TerrainFile::open(&a.file)?;
    let i = inspect::info(&f);
    if a.json {
        print_json(&i)?;
        return Ok(ExitCode::SUCCESS);
    }
    println!("file          {}", i.file);
    println!("grid          {0} x {0} posts ({1} levels), valid window {2:?}", i.grid_size, i.levels, i.valid_window);
    println!(
        "layout        {}{}",
        i.layout,
        if i.layout == "tiled" { format!(" (tile {})", i.layout_param) } else { String::new() }
    );
    println!("records       {} for {} vertices (waste {:.1}%)", i.records, i.vertices, 100.0 * i.waste_ratio);
    println!(
        "spacing       {} x {} m{}",
        i.spacing_m[0],
        i.spacing_m[1],
        if i.spacing_assumed { " (assumed: the source did not say)" } else { "" }
    );
    if let Some(g) = &i.geographic {
        println!(
            "geographic    source posts {:.6}° x {:.6}°, converted to metres at latitude {:.4}°",
            g.spacing_deg[0], g.spacing_deg[1], g.centre_lat_deg
        );
    }
    println!("extent        {:.1} x {:.1} m (origin south-west corner, z up)", i.extent_m[0], i.extent_m[1]);
    println!("heights       {:.2} .. {:.2} m (source x {} + {})", i.z_min, i.z_max, i.z_scale, i.z_offset);
    println!("nodata filled {}", i.nodata_filled);
    println!("source format {}", i.source_format);
    println!("file          {} ({} bytes), payload xxh3 {}", fmt_bytes(i.file_bytes), i.file_bytes, i.payload_checksum);
    Ok(ExitCode::SUCCESS)
}
