//! `relief path`: camera paths over a terrain or around a mesh.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Subcommand};
use relief::camera::UpAxis;
use relief::flight::{FlyoverOptions, OrbitOptions, PathSubject};

use super::{check_output_file, up_parser};

#[derive(Subcommand)]
pub enum Command {
    /// A low-altitude straight fly-over along the DEM's diagonal, south-west to north-east (5%
    /// inside the corners), climbing over the highest terrain within 3% of the diagonal around the
    /// eye, looking ahead 15° below the horizon. For a mesh: across its bounding box along the
    /// horizontal diagonal, at a constant height above the box's top.
    Flyover {
        #[command(flatten)]
        common: PathArgs,
        /// Least height of the eye above the highest terrain around it, metres [default: 2% of
        /// the DEM's diagonal].
        #[arg(long, value_name = "M", allow_negative_numbers = true)]
        clearance: Option<f64>,
    },
    /// A circle around the DEM's centre at constant altitude, one full turn counter-clockwise from
    /// due east, looking at the centre (at the terrain's height there). For a mesh: about the up
    /// axis through its bounding box's centre [radius 1.2 × the box's diagonal, height 0.4 ×
    /// the diagonal above the centre], looking at the centre.
    Orbit {
        #[command(flatten)]
        common: PathArgs,
        /// Horizontal distance of the eye from the centre, metres [default: 0.6 × half the DEM's
        /// diagonal].
        #[arg(long, value_name = "M", allow_negative_numbers = true)]
        radius: Option<f64>,
        /// Eye height (world z), metres [default: highest terrain + 0.3 × half the DEM's diagonal].
        #[arg(long, value_name = "M", allow_negative_numbers = true)]
        altitude: Option<f64>,
    },
}

/// What every `relief path` generator takes.
#[derive(Args)]
pub struct PathArgs {
    /// Terrain file (.relief), or a mesh (OFF, PLY, OBJ, optionally gzip'd), a meta-node file or
    /// a page file: then the path is about the mesh's bounding box, in the file's units.
    pub file: PathBuf,
    /// A mesh's up axis [default: the axis of the box's smallest side when it is at most half the
    /// next (a terrain), else y (scanned objects, OBJ)]. Terrains are always z up.
    #[arg(long, value_parser = up_parser())]
    pub up: Option<UpAxis>,
    /// Number of frames (at least 1; an orbit spaces them evenly over the turn).
    #[arg(long, value_name = "N")]
    pub frames: usize,
    /// Flight-path file to write (replaced atomically if it exists).
    #[arg(long, value_name = "PATH.json")]
    pub out: PathBuf,
    /// Print the summary as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

pub fn run(kind: Command) -> anyhow::Result<ExitCode> {
    let common = match &kind {
        Command::Flyover { common, .. } | Command::Orbit { common, .. } => common,
    };
    check_output_file("--out", &common.out)?;
    let subject = PathSubject::open(&common.file, common.up)?;
    let path = match &kind {
        Command::Flyover { common, clearance } => {
            subject.flyover(&FlyoverOptions { frames: common.frames, clearance_m: *clearance })?
        }
        Command::Orbit { common, radius, altitude } => {
            subject.orbit(&OrbitOptions { frames: common.frames, radius_m: *radius, altitude_m: *altitude })?
        }
    };
    path.save(&common.out)?;
    let s = subject.summary(&path)?;
    // Terrains are in metres; a mesh in its file's units, shown to about 1/1000 of its size.
    let (clearance_what, unit, decimals) = match &subject {
        PathSubject::Terrain(_) => ("min clearance above terrain", " m", 1),
        PathSubject::Box(b, _) => {
            ("min distance to the mesh's box", "", (3.0 - b.diagonal().log10().floor()).clamp(0.0, 9.0) as usize)
        }
    };
    let up = subject.up();
    if common.json {
        let j = serde_json::json!({
            "frames": s.frames,
            "length_m": s.length_m,
            "min_clearance_m": s.min_clearance_m,
            "up": up,
            "out": common.out.display().to_string(),
        });
        super::print_json(&j)?;
    } else {
        let clearance = match s.min_clearance_m {
            Some(c) => format!("{c:.decimals$}{unit}"),
            None => "n/a (no eye over the grid)".to_string(),
        };
        println!(
            "{}: {} frames, length {:.decimals$}{unit}, {clearance_what} {clearance}, {} up",
            common.out.display(),
            s.frames,
            s.length_m,
            up.name()
        );
    }
    Ok(ExitCode::SUCCESS)
}
