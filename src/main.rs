//! The `relief` command line: the commands and their arguments (one module each in `cli/`) over
//! the library. An error prints as one line, its whole chain (`relief: FILE: problem: cause`),
//! and exits 1. Ctrl-C, SIGTERM and SIGHUP stop long work the same way, removing what it was
//! writing.

mod cli;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "relief", version, about = "Terrain files for out-of-core, view-dependent rendering of height fields")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Convert a DEM image into an indexed, memory-mappable terrain file.
    ///
    /// The grid is padded (edge replication, never resampled) to (2^n + 1)² posts; the DEM's own
    /// extent is kept as the valid window. Void/nodata samples are filled from valid neighbours and
    /// counted. Output is written to a temporary file and renamed, so OUTPUT is never half-written.
    Convert(cli::convert::Args),
    /// Describe a terrain file (grid, layout, spacing, extent, height range, waste).
    Info(cli::info::Args),
    /// Check a terrain file: header and payload checksums, and for every vertex the nesting of
    /// errors and bounding spheres. Exits non-zero on any failure.
    Verify(cli::verify::Args),
    /// Refine one view into a single triangle strip and report its size and speed.
    ///
    /// World coordinates are metres with the origin at the grid's south-west corner, x east, y
    /// north, z up (the extent is in `relief info`). A vertex is refined while its nested error
    /// projects to more than --tolerance pixels on a --width-pixel-wide image.
    Refine(cli::refine::Args),
    /// Fly over a terrain: in a window, or headless along a recorded path.
    ///
    /// With no FILE, flies over the bundled terrain (data/zurich_25m_i16.tif, converted on first
    /// use into ~/.cache/relief). In a window: drag to look, W/A/S/D/Q/E to move (Shift ×4), wheel
    /// for speed, F freeze refinement, T wireframe, F12 or P screenshot, R record the path, Esc quit.
    /// With --path: renders each frame of PATH.json ({"eye": [x,y,z], "look": [x,y,z]} per frame,
    /// world metres) offscreen, optionally to PNGs, and reports per-frame figures.
    Fly(cli::fly::Args),
    /// Refine and render one view offscreen (no window needed) to a PNG image.
    ///
    /// Coordinates as for `refine`. Heights are uploaded to the GPU once; the frame then sends
    /// only the strip (8 bytes per vertex, 16 with --geomorph). Without a GPU, Mesa's software
    /// Vulkan (lavapipe) renders it.
    Render(cli::render::Args),
    /// Write a terrain's mesh for other tools: glTF (.glb/.gltf), PLY or OBJ.
    ///
    /// Either the mesh refined for a view (--eye, --look, --tolerance: what `render` draws) or the
    /// view-independent mesh within --max-error metres of every DEM post. Positions in local metres
    /// (or the CRS with --crs), normals, and texture coordinates over the DEM, north up.
    Export(cli::export::Args),
    /// Cut an image once into an imagery tile file that --imagery pages (for images larger than
    /// memory or GPU memory).
    ///
    /// The tile file holds the image's mip levels (each half the size) in tiles of 254² texels
    /// with a one-texel border, 256 KiB each, and the image's placement (its world file or
    /// geotransform). `render`, `fly` and the window then read only the tiles the view wants,
    /// through the pager, and hold them on the GPU within --imagery-gpu-memory.
    Imagery(cli::imagery::Args),
    /// Compare index layouts by page faults along a flight (the terrain paper's experiment).
    ///
    /// INPUT is a DEM (converted once per layout into --cache-dir) or a terrain file (re-laid out
    /// once per layout). For each layout and tolerance the flight in --path is refined frame by
    /// frame and every record read is charged to its page in an LRU model of a page cache of
    /// --memory bytes: faults are that model's misses, identical on every machine. --os also counts
    /// the process's real major faults on a cold, readahead-free mapping.
    Layouts(cli::layouts::Args),
    /// Generate a camera flight path over a terrain or around a mesh and write it as JSON.
    ///
    /// World coordinates are metres with the origin at the grid's south-west corner, x east, y
    /// north, z up (height in metres); a mesh's are its file's. The file is a JSON array with one
    /// frame per line: [{"eye":[X,Y,Z],"look":[X,Y,Z]}, ...]. Prints the frame count, the path's
    /// length and the least clearance of an eye above the terrain (for a mesh: the least distance
    /// to its bounding box).
    Path {
        #[command(subcommand)]
        kind: cli::path::Command,
    },
    /// Triangle meshes for the mesh backends: inspect or show one, build its meta-node trees and
    /// fly over them, or export a terrain as one.
    Mesh {
        #[command(subcommand)]
        kind: cli::mesh::Command,
    },
    /// The disk-page backend (Sajadi et al.): any triangle soup as self-contained fixed-size
    /// pages in a layout order, a k-d tree over the pages' boxes, and a per-frame fetch of whole
    /// pages in sorted order.
    Pages {
        #[command(subcommand)]
        kind: cli::pages::Command,
    },
    /// Serve files over HTTP/1.1 with byte ranges (for reading terrains remotely and benchmarking it).
    ///
    /// Each FILE is served under its file name; the URLs are printed one per line, then requests
    /// are answered until Ctrl-C. GET and HEAD, Range (206, 416), ETag and If-Match; each request
    /// re-reads the file. --latency-ms delays every response to emulate a remote store.
    Serve(cli::serve::Args),
}

fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.command {
        Command::Convert(a) => cli::convert::run(a),
        Command::Info(a) => cli::info::run(a),
        Command::Verify(a) => cli::verify::run(a),
        Command::Refine(a) => cli::refine::run(a),
        Command::Fly(a) => cli::fly::run(a),
        Command::Render(a) => cli::render::run(a),
        Command::Export(a) => cli::export::run(a),
        Command::Imagery(a) => cli::imagery::run(a),
        Command::Layouts(a) => cli::layouts::run(a),
        Command::Path { kind } => cli::path::run(kind),
        Command::Mesh { kind } => cli::mesh::run(kind),
        Command::Pages { kind } => cli::pages::run(kind),
        Command::Serve(a) => cli::serve::run(a),
    }
}

/// The whole chain of causes on one line, `a: b: c`; a cause already said by the message before
/// it (library errors carry their I/O cause in their own text) is not said twice.
fn one_line(e: &anyhow::Error) -> String {
    let mut msg = e.to_string();
    for cause in e.chain().skip(1) {
        let c = cause.to_string();
        if !msg.contains(&c) {
            msg.push_str(": ");
            msg.push_str(&c);
        }
    }
    msg.lines().map(str::trim).collect::<Vec<_>>().join(" ")
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if !matches!(cli.command, Command::Serve(_)) {
        // Output piped into `head` and the like: end quietly when the reader goes, as other
        // command-line tools do, instead of panicking in `println!` (Rust ignores SIGPIPE).
        // Outputs are renamed into place only when complete, so nothing is left half-written.
        // SAFETY: restoring a signal's default disposition at start-up, before any thread runs.
        unsafe {
            libc::signal(libc::SIGPIPE, libc::SIG_DFL);
        }
    }
    // Ctrl-C, SIGTERM (timeout, systemd, docker) and SIGHUP (a closed terminal): ask long loops
    // to stop, so temporary files and scratch directories are removed on the way out.
    let _ = ctrlc::set_handler(relief::sys::cancel::request);
    // A mapped file truncated under us: a one-line error, not a core dump.
    relief::sys::sigbus::install();
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("relief: {}", one_line(&e));
            ExitCode::FAILURE
        }
    }
}
