//! `relief imagery`: an image cut once into the imagery tile file that `--imagery` pages.

use std::path::PathBuf;
use std::process::ExitCode;

use super::{check_output_file, print_json, progress};

#[derive(clap::Args)]
pub struct Args {
    /// The image: PNG or JPEG (with a world file beside it, or spanning the DEM it is draped on),
    /// or, in builds with GDAL, a GeoTIFF or any raster GDAL reads.
    pub image: PathBuf,
    /// The imagery tile file to write (replaced atomically), e.g. ortho.rimg.
    pub out: PathBuf,
    /// Where the coarser levels are built: scratch files of up to a third of the image's
    /// decoded size (4 bytes a texel), deleted as they go [default: OUT's directory].
    #[arg(long, value_name = "DIR")]
    pub scratch_dir: Option<PathBuf>,
    /// Print what was written as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// No progress bars.
    #[arg(long, short)]
    pub quiet: bool,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    check_output_file("OUT", &a.out)?;
    let scratch = match &a.scratch_dir {
        Some(d) => d.clone(),
        None => match a.out.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        },
    };
    let r = relief::render::imagery::make_tiles(&a.image, &a.out, &scratch, progress(a.quiet))?;
    if a.json {
        print_json(&r)?;
    } else {
        println!(
            "{}: {} x {} texels in {} levels, {} tiles of 254² texels (256 KiB each with their border), {} bytes ({:.2} s); drape it with --imagery {}",
            a.out.display(),
            r.width,
            r.height,
            r.levels,
            r.tiles,
            r.file_bytes,
            r.seconds,
            a.out.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}
