//! `relief convert`: a DEM into a terrain file.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::bail;
use relief::dem::DemFormat;
use relief::layout::LayoutKind;
use relief::preprocess::convert::{convert_many, ConvertOptions};

use super::{check_output_file, format_parser, layout_parser, print_json, progress};

#[derive(clap::Args)]
pub struct Args {
    /// DEM to read: GeoTIFF, PNG (16-bit gray, Terrain-RGB, Terrarium), OpenEXR, SRTM .hgt or
    /// ESRI ASCII grid; detected from content and extension unless --format is given. Several
    /// files, or a directory of them, are georeferenced tiles of one terrain (a mosaic): each is
    /// placed by its georeferencing, all in one CRS and posting; posts no tile covers become
    /// nodata; where tiles overlap the first given wins.
    #[arg(required = true, num_args = 1.., value_name = "INPUT")]
    pub inputs: Vec<PathBuf>,
    /// Terrain file to write (replaced atomically if it exists); with --merge also
    /// s3://bucket/key, uploaded in parts to the endpoint of AWS_ENDPOINT_URL_S3 (or AWS itself),
    /// signed with AWS_ACCESS_KEY_ID / AWS_SECRET_ACCESS_KEY where set.
    pub output: PathBuf,
    /// Record order in the file.
    #[arg(long, value_parser = layout_parser(), default_value = "interleaved")]
    pub layout: LayoutKind,
    /// Tile side in posts for --layout tiled (a power of two); default: the largest tile that
    /// fits one 4 KiB page (16 for 12-byte records).
    #[arg(long, value_name = "N")]
    pub tile: Option<u32>,
    /// Post spacing in metres, "S" or "SX,SY"; overrides the file's georeferencing. Needed for
    /// formats that carry none (PNG, EXR); otherwise 1 m is assumed and `info` says so.
    #[arg(long, value_name = "M", allow_hyphen_values = true)]
    pub spacing: Option<String>,
    /// Multiply source values by this to get metres (e.g. 0.3048 for feet, 0.01 for cm; -1 flips
    /// depths into heights).
    #[arg(long, value_name = "S", default_value_t = 1.0, allow_negative_numbers = true)]
    pub z_scale: f64,
    /// Add this many metres after scaling (e.g. -30 for a datum 30 m above the source's zero).
    #[arg(long, value_name = "M", default_value_t = 0.0, allow_negative_numbers = true)]
    pub z_offset: f64,
    /// Force the input format instead of detecting it (`gdal`: any raster GDAL reads, in a
    /// build with the `gdal` feature).
    #[arg(long, value_parser = format_parser())]
    pub format: Option<DemFormat>,
    /// Convert a lossy-compressed DEM (JPEG, lossy WebP, LERC with a maximum error, JPEG 2000)
    /// rather than refuse it: its heights carry the codec's errors.
    #[arg(long)]
    pub allow_lossy: bool,
    /// Directory for the scratch grid (default: the output's directory). Needs about
    /// 12 bytes per post of the padded grid.
    #[arg(long, value_name = "DIR")]
    pub scratch_dir: Option<PathBuf>,
    /// Convert only shard I of N (0 <= I < N) into OUTPUT, a shard file: the blocks of the grid
    /// that shard owns, with the partial bounds its neighbours need. Merge all N with --merge to
    /// get the terrain file a single process writes, byte for byte (see tools/dask_convert.py to
    /// run the shards on a Dask cluster). Needs a DEM without nodata posts.
    #[arg(long, value_name = "I/N", conflicts_with = "merge")]
    pub shard: Option<String>,
    /// The INPUTs are the N shard files of one sharded conversion (any order): merge them into
    /// OUTPUT. A missing, repeated or foreign shard is an error and nothing is written.
    #[arg(long)]
    pub merge: bool,
    /// Worker threads (default: one per core).
    #[arg(long, value_name = "N")]
    pub threads: Option<usize>,
    /// Print the conversion report as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// No progress bars.
    #[arg(long, short)]
    pub quiet: bool,
}

fn parse_spacing(s: &str) -> anyhow::Result<[f64; 2]> {
    let nums: Result<Vec<f64>, _> = s.split(',').map(|p| p.trim().parse::<f64>()).collect();
    match nums.ok().as_deref() {
        Some([v]) if *v > 0.0 && v.is_finite() => Ok([*v, *v]),
        Some([x, y]) if *x > 0.0 && *y > 0.0 && x.is_finite() && y.is_finite() => Ok([*x, *y]),
        _ => bail!("--spacing: expected positive metres as S or SX,SY, got '{s}'"),
    }
}

fn parse_shard(s: &str) -> anyhow::Result<(u32, u32)> {
    let parsed =
        s.split_once('/').and_then(|(i, n)| Some((i.trim().parse::<u32>().ok()?, n.trim().parse::<u32>().ok()?)));
    match parsed {
        Some((i, n)) if n >= 1 && i < n => Ok((i, n)),
        _ => bail!("--shard: expected I/N with 0 <= I < N (e.g. 3/16), got '{s}'"),
    }
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    match a.threads {
        Some(0) => bail!("--threads: expected at least 1"),
        Some(t) => {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(t).build()?;
            pool.install(|| run_in_pool(a))
        }
        None => run_in_pool(a),
    }
}

fn run_in_pool(a: Args) -> anyhow::Result<ExitCode> {
    let to_bucket = a.merge && a.output.to_str().is_some_and(|o| o.starts_with("s3://"));
    if !to_bucket {
        check_output_file("", &a.output)?;
    }
    if a.merge {
        let s3 = relief::pager::remote::S3Config::from_env()?;
        let output = a.output.to_string_lossy();
        let r = relief::preprocess::shard::merge(&a.inputs, &output, &s3, &progress(a.quiet))?;
        if a.json {
            print_json(&r)?;
        } else {
            println!(
                "{} shards -> {}: {} records, {} coarse, {} seam bounds, {:.1} MiB, {:.2} s",
                r.shards,
                r.output,
                r.records,
                r.coarse_vertices,
                r.seam_bounds,
                r.file_bytes as f64 / (1u64 << 20) as f64,
                r.seconds
            );
        }
        return Ok(ExitCode::SUCCESS);
    }
    if let Some(d) = &a.scratch_dir {
        if !d.is_dir() {
            bail!("--scratch-dir: {}: no such directory", d.display());
        }
    }
    if !(a.z_scale.is_finite() && a.z_scale != 0.0) {
        bail!("--z-scale: expected a finite, non-zero factor, got {}", a.z_scale);
    }
    if !a.z_offset.is_finite() {
        bail!("--z-offset: expected finite metres, got {}", a.z_offset);
    }
    let mut opts = ConvertOptions::new(a.layout);
    opts.tile = a.tile;
    opts.spacing_m = a.spacing.as_deref().map(parse_spacing).transpose()?;
    opts.z_scale = a.z_scale;
    opts.z_offset = a.z_offset;
    opts.format = a.format;
    opts.allow_lossy = a.allow_lossy;
    opts.scratch_dir = a.scratch_dir;
    opts.progress = progress(a.quiet);
    let input = &a.inputs[0];
    if let Some(spec) = &a.shard {
        let which = parse_shard(spec)?;
        // Test hook: RELIEF_TEST_KILL_SHARD_AFTER=K aborts the process once K blocks are written
        // (a shard killed mid-way, for the rerun tests).
        let kill_after: Option<u32> = std::env::var("RELIEF_TEST_KILL_SHARD_AFTER").ok().and_then(|v| v.parse().ok());
        let after = |done: u32| {
            if kill_after.is_some_and(|k| done >= k) {
                std::process::abort();
            }
        };
        let r = relief::preprocess::shard::convert_shard(&a.inputs, &a.output, &opts, which, &after)?;
        if a.json {
            print_json(&r)?;
        } else {
            println!(
                "shard {}/{} -> {}: {} blocks of {}², {} vertices, {} seam bounds, {:.1} MiB, {:.2} s ({:.1} M vertices/s)",
                r.shard,
                r.shards,
                r.output.display(),
                r.blocks,
                r.block_side,
                r.vertices,
                r.foreign,
                r.file_bytes as f64 / (1u64 << 20) as f64,
                r.seconds,
                r.vertices_per_s / 1e6
            );
        }
        return Ok(ExitCode::SUCCESS);
    }
    let r = convert_many(&a.inputs, &a.output, &opts).map_err(|e| match e {
        relief::Error::UnknownFormat { .. } => anyhow::anyhow!("{e} (--format)"),
        e => e.into(),
    })?;
    if a.json {
        print_json(&r)?;
        return Ok(ExitCode::SUCCESS);
    }
    if r.spacing_source.starts_with("assumed") {
        eprintln!("relief: warning: {}: post spacing {} (--spacing)", input.display(), r.spacing_source);
    }
    println!(
        "{}{} -> {}: {}x{} {} in a {}² grid, layout {}, {} vertices stored ({:.1} MiB, {:.2}x the posts' 12 bytes), {:.2} s ({:.1} M vertices/s){}",
        input.display(),
        if a.inputs.len() > 1 { format!(" (and {} more)", a.inputs.len() - 1) } else { String::new() },
        a.output.display(),
        r.source_width,
        r.source_height,
        r.format,
        r.grid_size,
        r.layout,
        r.stored_vertices,
        r.file_bytes as f64 / (1u64 << 20) as f64,
        r.file_bytes as f64 / (r.source_width as f64 * r.source_height as f64 * 12.0),
        r.seconds,
        r.vertices_per_s / 1e6,
        if r.nodata_filled > 0 { format!(", {} nodata samples filled", r.nodata_filled) } else { String::new() }
    );
    Ok(ExitCode::SUCCESS)
}
