//! The `relief` command line: a thin layer over the library. Errors print as one line
//! (`relief: FILE: problem`) with a non-zero exit status.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::bail;
use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::{Parser, Subcommand};

use relief::convert::{convert, ConvertOptions};
use relief::dem::DemFormat;
use relief::format::TerrainFile;
use relief::inspect;
use relief::layout::LayoutKind;
use relief::progress::Progress;

#[derive(Parser)]
#[command(name = "relief", version, about = "Terrain files for out-of-core, view-dependent rendering of height fields")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// `--layout` values: the library's layout names, listed in `--help`.
fn layout_parser() -> impl clap::builder::TypedValueParser<Value = LayoutKind> {
    PossibleValuesParser::new(LayoutKind::ALL.map(LayoutKind::name))
        .map(|name| LayoutKind::from_name(&name).expect("a possible value"))
}

/// `--format` values: the library's DEM format names, listed in `--help`.
fn format_parser() -> impl clap::builder::TypedValueParser<Value = DemFormat> {
    PossibleValuesParser::new(DemFormat::ALL.map(DemFormat::name))
        .map(|name| DemFormat::from_name(&name).expect("a possible value"))
}

#[derive(Subcommand)]
enum Command {
    /// Convert a DEM image into an indexed, memory-mappable terrain file.
    ///
    /// The grid is padded (edge replication, never resampled) to (2^n + 1)² posts; the DEM's own
    /// extent is kept as the valid window. Void/nodata samples are filled from valid neighbours and
    /// counted. Output is written to a temporary file and renamed, so OUTPUT is never half-written.
    Convert {
        /// DEM to read: GeoTIFF, PNG (16-bit gray, Terrain-RGB, Terrarium), OpenEXR, SRTM .hgt or
        /// ESRI ASCII grid; detected from content and extension unless --format is given.
        input: PathBuf,
        /// Terrain file to write (replaced atomically if it exists).
        output: PathBuf,
        /// Record order in the file.
        #[arg(long, value_parser = layout_parser(), default_value = "interleaved")]
        layout: LayoutKind,
        /// Tile side in posts for --layout tiled (a power of two); default: the largest tile that
        /// fits one 4 KiB page (16 for 12-byte records).
        #[arg(long, value_name = "N")]
        tile: Option<u32>,
        /// Post spacing in metres, "S" or "SX,SY"; overrides the file's georeferencing. Needed for
        /// formats that carry none (PNG, EXR); otherwise 1 m is assumed and `info` says so.
        #[arg(long, value_name = "M")]
        spacing: Option<String>,
        /// Multiply source values by this to get metres (e.g. 0.3048 for feet, 0.01 for cm).
        #[arg(long, value_name = "S", default_value_t = 1.0)]
        z_scale: f64,
        /// Add this many metres after scaling.
        #[arg(long, value_name = "M", default_value_t = 0.0)]
        z_offset: f64,
        /// Force the input format instead of detecting it.
        #[arg(long, value_parser = format_parser())]
        format: Option<DemFormat>,
        /// Directory for the scratch grid (default: the output's directory). Needs about
        /// 12 bytes per post of the padded grid.
        #[arg(long, value_name = "DIR")]
        scratch_dir: Option<PathBuf>,
        /// Print the conversion report as JSON on stdout.
        #[arg(long)]
        json: bool,
        /// No progress bars.
        #[arg(long, short)]
        quiet: bool,
    },
    /// Describe a terrain file (grid, layout, spacing, extent, height range, waste).
    Info {
        file: PathBuf,
        /// Print JSON on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Check a terrain file: header and payload checksums, and for every vertex the nesting of
    /// errors and bounding spheres. Exits non-zero on any failure.
    Verify {
        file: PathBuf,
        /// Print JSON on stdout.
        #[arg(long)]
        json: bool,
        /// No progress bars.
        #[arg(long, short)]
        quiet: bool,
    },
}

fn parse_spacing(s: &str) -> anyhow::Result<[f64; 2]> {
    let parts: Vec<&str> = s.split(',').collect();
    let nums: Result<Vec<f64>, _> = parts.iter().map(|p| p.trim().parse::<f64>()).collect();
    match nums.ok().as_deref() {
        Some([v]) if *v > 0.0 && v.is_finite() => Ok([*v, *v]),
        Some([x, y]) if *x > 0.0 && *y > 0.0 && x.is_finite() && y.is_finite() => Ok([*x, *y]),
        _ => bail!("--spacing: expected positive metres as S or SX,SY, got '{s}'"),
    }
}

fn progress(quiet: bool) -> Progress {
    Progress::new(!quiet && std::io::stderr().is_terminal())
}

fn fmt_bytes(b: u64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut v = b as f64;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < UNITS.len() {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{b} B")
    } else {
        format!("{v:.1} {}", UNITS[u])
    }
}

fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.command {
        Command::Convert {
            input,
            output,
            layout,
            tile,
            spacing,
            z_scale,
            z_offset,
            format,
            scratch_dir,
            json,
            quiet,
        } => {
            let mut opts = ConvertOptions::new(layout);
            opts.tile = tile;
            opts.spacing_m = spacing.as_deref().map(parse_spacing).transpose()?;
            opts.z_scale = z_scale;
            opts.z_offset = z_offset;
            opts.format = format;
            opts.scratch_dir = scratch_dir;
            opts.progress = progress(quiet);
            let r = convert(&input, &output, &opts)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&r)?);
            } else {
                if r.spacing_source.starts_with("assumed") {
                    eprintln!("relief: warning: {}: post spacing {}", input.display(), r.spacing_source);
                }
                println!(
                    "{} -> {}: {}x{} {} padded to {}², layout {}, {} records, {:.2} s ({:.1} M vertices/s){}",
                    input.display(),
                    output.display(),
                    r.source_width,
                    r.source_height,
                    r.format,
                    r.grid_size,
                    r.layout,
                    r.records,
                    r.seconds,
                    r.vertices_per_s / 1e6,
                    if r.nodata_filled > 0 {
                        format!(", {} nodata samples filled", r.nodata_filled)
                    } else {
                        String::new()
                    }
                );
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Info { file, json } => {
            let f = TerrainFile::open(&file)?;
            let i = inspect::info(&f);
            if json {
                println!("{}", serde_json::to_string_pretty(&i)?);
                return Ok(ExitCode::SUCCESS);
            }
            println!("file          {}", i.file);
            println!(
                "grid          {0} x {0} posts ({1} levels), valid window {2:?}",
                i.grid_size, i.levels, i.valid_window
            );
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
            println!(
                "file          {} ({} bytes), payload xxh3 {}",
                fmt_bytes(i.file_bytes),
                i.file_bytes,
                i.payload_checksum
            );
            Ok(ExitCode::SUCCESS)
        }
        Command::Verify { file, json, quiet } => {
            let f = TerrainFile::open(&file)?;
            let r = inspect::verify(&f, progress(quiet))?;
            if json {
                println!("{}", serde_json::to_string_pretty(&r)?);
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
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // Ctrl-C: ask long loops to stop, so temporary files are removed on the way out.
    let _ = ctrlc::set_handler(relief::cancel::request);
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            // One line: the library's errors already name the file and the problem.
            let msg = e.to_string().lines().collect::<Vec<_>>().join(" ");
            eprintln!("relief: {msg}");
            ExitCode::FAILURE
        }
    }
}
