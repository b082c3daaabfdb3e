//! `relief render`: one view of a terrain drawn offscreen to a PNG.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

use relief::format::terrain::TerrainFile;
use relief::render::{render_still, save_png, DrawStyle, Gpu, StillOptions};

use super::{check_output_file, fmt_bytes, print_json, progress, GpuArgs, ViewArgs};

#[derive(clap::Args)]
pub struct Args {
    pub file: PathBuf,
    #[command(flatten)]
    pub view: ViewArgs,
    /// PNG image to write (replaced atomically).
    #[arg(long, value_name = "IMAGE.png")]
    pub out: PathBuf,
    /// Overlay the mesh edges (shows the level of detail).
    #[arg(long)]
    pub wireframe: bool,
    /// Print the frame's figures as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// No progress bars.
    #[arg(long, short)]
    pub quiet: bool,
    #[command(flatten)]
    pub gpu: GpuArgs,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    let renderer = a.gpu.options()?;
    check_output_file("--out", &a.out)?;
    let f = Arc::new(TerrainFile::open(&a.file)?);
    let (camera, options) = a.view.resolve(&f)?;
    // Refined and drawn in the exaggerated scene.
    let camera = renderer.look.scene_camera(&camera);
    let options = relief::refine::RefineOptions { z_exaggeration: renderer.look.z_exaggeration, ..options };
    let gpu = Gpu::headless()?;
    let style = DrawStyle { wireframe: a.wireframe };
    let (image, r) = render_still(
        &gpu,
        f,
        &camera,
        &options,
        StillOptions { style, renderer, threads: a.view.refine.threads },
        progress(a.quiet),
    )?;
    save_png(&image, &a.out)?;
    if a.json {
        print_json(&r)?;
    } else {
        println!(
            "{}: {} x {} px, {} triangles (strip {}), refine {:.2} ms, render {:.2} ms, {} uploaded this frame, heights {} on the GPU{}{} ({})",
            a.out.display(),
            r.width,
            r.height,
            r.triangles,
            r.strip_len,
            r.refine_ms,
            r.render_ms,
            fmt_bytes(r.upload_bytes),
            fmt_bytes(r.heights_gpu_bytes),
            if r.height_cache { " (height cache)" } else { "" },
            match (r.imagery_gpu_bytes, r.imagery_tiles_resident) {
                (0, _) => String::new(),
                (b, 0) => format!(", imagery {}", fmt_bytes(b)),
                (b, t) => format!(", imagery {} ({t} tiles resident)", fmt_bytes(b)),
            },
            r.adapter
        );
    }
    Ok(ExitCode::SUCCESS)
}
