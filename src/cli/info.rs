//! `relief info`: what a terrain file holds.

use std::path::PathBuf;
use std::process::ExitCode;

use relief::format::terrain::TerrainFile;
use relief::georef::CrsKind;
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
    let local = !relief::pager::remote::is_remote(&a.file);
    if local && relief::format::sniff(&a.file)? == Some(relief::format::FileKind::Imagery) {
        return imagery_info(&a);
    }
    let f = TerrainFile::open(&a.file)?;
    let i = inspect::info(&f);
    if a.json {
        print_json(&i)?;
        return Ok(ExitCode::SUCCESS);
    }
    println!("file          {}", i.file);
    println!(
        "data          {} x {} posts, {:.1} x {:.1} m (valid window x {}..{}, y {}..{} of the grid)",
        i.data_posts[0],
        i.data_posts[1],
        i.data_extent_m[0],
        i.data_extent_m[1],
        i.valid_window[0],
        i.valid_window[2],
        i.valid_window[1],
        i.valid_window[3]
    );
    println!(
        "spacing       {} x {} m{}",
        i.spacing_m[0],
        i.spacing_m[1],
        if i.spacing_assumed { " (assumed: the source did not say)" } else { "" }
    );
    match &i.crs {
        Some(c) => {
            let unit = c.unit.as_deref().unwrap_or("unit not stated");
            match c.kind {
                CrsKind::Unknown => println!("crs           not stated by the source (placed in its own units below)"),
                kind => println!("crs           {} ({}, {unit})", c.name, kind.name()),
            }
            let vertical = match (c.vertical_epsg, c.vertical_unit.as_deref()) {
                (Some(code), Some(u)) => format!("EPSG:{code}, source heights in {u}"),
                (Some(code), None) => format!("EPSG:{code}, source unit not stated (taken as metres)"),
                (None, Some(u)) => format!("CRS not stated, source heights in {u}"),
                (None, None) => "not stated (source heights taken as metres)".into(),
            };
            println!("vertical      {vertical}");
            // Millimetres for linear units, about a centimetre on the ground for degrees.
            let p = if c.kind == CrsKind::Geographic { 7 } else { 3 };
            println!(
                "placement     south-west post at {:.p$}, {:.p$}; posts {} x {} apart (CRS units)",
                c.origin[0], c.origin[1], c.step[0], c.step[1]
            );
            println!(
                "crs extent    x {:.p$} .. {:.p$}, y {:.p$} .. {:.p$} (first post to last)",
                c.extent[0], c.extent[2], c.extent[1], c.extent[3]
            );
        }
        None => println!("crs           none (the source was not georeferenced; local metres only)"),
    }
    if let Some(g) = &i.geographic {
        println!(
            "geographic    source posts {:.6}° x {:.6}°, converted to metres at latitude {:.4}°",
            g.spacing_deg[0], g.spacing_deg[1], g.centre_lat_deg
        );
    }
    println!(
        "grid          {0} x {0} posts ({1} levels), {2:.1} x {3:.1} m with padding (origin its south-west post, z up)",
        i.grid_size, i.levels, i.extent_m[0], i.extent_m[1]
    );
    println!(
        "layout        {}{}",
        i.layout,
        if i.layout == "tiled" { format!(" (tile {})", i.layout_param) } else { String::new() }
    );
    println!("records       {} for {} vertices (waste {:.1}%)", i.records, i.vertices, 100.0 * i.waste_ratio);
    if i.stored_pages < i.payload_pages || i.stored_vertices < i.vertices {
        println!(
            "stored        {} vertices (the data and their ancestors), {} of {} payload pages; the padding is not stored",
            i.stored_vertices, i.stored_pages, i.payload_pages
        );
    }
    println!("heights       {:.2} .. {:.2} m (source x {} + {})", i.z_min, i.z_max, i.z_scale, i.z_offset);
    match (i.nodata_filled, i.void_mask) {
        (0, _) => println!("nodata        none"),
        (n, true) => {
            println!("nodata        {n} posts, filled for the hierarchy, kept as a void mask (drawn as no data)")
        }
        (n, false) => println!("nodata        {n} posts filled (no void mask: converted by an older relief)"),
    }
    println!("source format {}", i.source_format);
    println!("file          {} ({} bytes), payload xxh3 {}", fmt_bytes(i.file_bytes), i.file_bytes, i.payload_checksum);
    Ok(ExitCode::SUCCESS)
}

/// `relief info` of an imagery tile file (`relief imagery`): its size, levels, tiles, placement.
fn imagery_info(a: &Args) -> anyhow::Result<ExitCode> {
    let f = relief::format::imagery::ImageryFile::open(&a.file, relief::pager::Access::Read)?;
    let h = f.header();
    if a.json {
        #[derive(serde::Serialize)]
        struct Info<'a> {
            file: String,
            kind: &'static str,
            #[serde(flatten)]
            header: &'a relief::format::imagery::ImageryHeader,
            file_bytes: u64,
        }
        print_json(&Info { file: a.file.display().to_string(), kind: "imagery", header: h, file_bytes: h.file_len() })?;
        return Ok(ExitCode::SUCCESS);
    }
    println!("file          {} (imagery tile file)", a.file.display());
    println!(
        "image         {} x {} texels, {} mip levels, {} tiles of {}² texels with a 1-texel border",
        h.width, h.height, h.levels, h.tiles, h.tile
    );
    match h.placement {
        Some([x0, dx, y0, dy]) => println!(
            "placement     upper-left texel centre ({x0}, {y0}), texels {dx} x {dy} in the terrain's CRS units"
        ),
        None => println!("placement     none: stretched over the DEM it is draped on"),
    }
    println!("size          {}", fmt_bytes(h.file_len()));
    Ok(ExitCode::SUCCESS)
}
