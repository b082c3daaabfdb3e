//! `relief fly`: a terrain in a window, or headless along a path.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

use relief::camera::UpAxis;
use relief::flight::frame::Presenter;
use relief::flight::terrain::TerrainSource;
use relief::format::terrain::{TerrainFile, RECORD_BYTES};
use relief::pager::Access;
use relief::refine::RefineOptions;
use relief::render::{DrawStyle, Gpu, TerrainPresenter};
use relief::window::{fly_window, WindowOptions};

use super::{progress, AccessArgs, FlyArgs, GpuArgs, RefineArgs};

/// Where refinement runs.
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Refinement {
    /// On its own thread: the render thread draws the newest finished strip and never waits.
    Thread,
    /// Before each frame, on the render thread: each frame is drawn with its own view's strip.
    Sync,
}

#[derive(clap::Args)]
pub struct Args {
    /// Terrain file (default: the bundled terrain).
    pub file: Option<PathBuf>,
    #[command(flatten)]
    pub fly: FlyArgs,
    #[command(flatten)]
    pub refine: RefineArgs,
    /// Where refinement runs [default: thread in a window, sync headless].
    #[arg(long, value_enum)]
    pub refinement: Option<Refinement>,
    /// --path's frames and --eye/--look give X, Y in the terrain's coordinate system (easting and
    /// northing, or longitude and latitude, as `relief info` shows it) and Z in metres, instead of
    /// local metres from the grid's south-west post.
    #[arg(long)]
    pub crs_coords: bool,
    #[command(flatten)]
    pub access: AccessArgs,
    #[command(flatten)]
    pub gpu: GpuArgs,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let refine = a.refine.options()?;
    let renderer = a.gpu.options()?;
    let flight = a.fly.check()?;
    let file = match a.file {
        Some(f) => f,
        None => relief::bundled_terrain(progress(a.fly.quiet))?,
    };
    let access =
        a.access.access(Access::Map, || Ok(TerrainFile::open(&file)?.grid().vertices() * RECORD_BYTES as u64))?;
    let terrain = Arc::new(TerrainFile::open_with(&file, access)?);
    let mut window = a.fly.window()?;
    let mut flight = flight;
    if a.crs_coords {
        let local = super::crs_to_local(&terrain)?;
        if let Some(f) = flight.as_mut() {
            for frame in &mut f.frames {
                frame.eye = local(frame.eye.into()).into();
                frame.look = local(frame.look.into()).into();
            }
        }
        window.start = window.start.map(|(eye, look)| (local(eye), local(look)));
    }
    // Exaggerated: the path and the start view scale with the scene's heights.
    let x = renderer.look.z_exaggeration;
    if x != 1.0 {
        if let Some(f) = flight.as_mut() {
            for frame in &mut f.frames {
                frame.eye[2] *= x;
                frame.look[2] *= x;
            }
        }
        window.start =
            window.start.map(|(eye, look)| (eye * glam::DVec3::new(1.0, 1.0, x), look * glam::DVec3::new(1.0, 1.0, x)));
    }
    let refine = RefineOptions { z_exaggeration: x, ..refine };
    let Some(flight) = flight else {
        let options = WindowOptions {
            window,
            refine,
            wireframe: a.fly.wireframe,
            threads: a.refine.threads,
            sync: a.refinement == Some(Refinement::Sync),
            renderer,
            progress: progress(a.fly.quiet),
        };
        fly_window(terrain, options)?;
        return Ok(ExitCode::SUCCESS);
    };
    let threaded = a.refinement == Some(Refinement::Thread);
    let gpu = if a.fly.no_render { None } else { Some(Gpu::headless()?) };
    let (w, h, style, quiet) = (a.fly.width, a.fly.height, DrawStyle { wireframe: a.fly.wireframe }, a.fly.quiet);
    let presenter = match &gpu {
        Some(gpu) => Some(TerrainPresenter::new(gpu, terrain.clone(), w, h, style, renderer, progress(quiet))?),
        None => None,
    };
    // With the height cache the strip carries its heights, computed on the refinement side.
    let refine = RefineOptions { heights: presenter.as_ref().is_some_and(|p| p.renderer.cached()), ..refine };
    let mut source = TerrainSource::new(terrain, refine, a.refine.threads, threaded)?;
    let presenter = presenter.map(|p| Box::new(p) as Box<dyn Presenter + '_>);
    super::show::headless(&mut source, &file, &flight, (UpAxis::Z, refine.tolerance_px), &a.fly, presenter)
}
