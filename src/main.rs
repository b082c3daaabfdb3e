//! The `relief` command line: a thin layer over the library. Errors print as one line
//! (`relief: FILE: problem`) with a non-zero exit status.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

use anyhow::{bail, Context};
use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::{Args, Parser, Subcommand};

use glam::DVec3;
use relief::camera::Camera;
use relief::camera::UpAxis;
use relief::dem::DemFormat;
use relief::faults::{run_layouts, terrain_in_layout, LayoutsOptions};
use relief::flight::FlightPath;
use relief::flight::{flyover, flyover_box, orbit, orbit_box, FlyoverOptions, OrbitOptions};
use relief::fly::{bundled_terrain, fly_headless, render_still, save_png, HeadlessOptions};
use relief::format::terrain::TerrainFile;
use relief::layout::LayoutKind;
use relief::mesh_fly::{fly_mesh_headless, MeshFlyOptions, MeshFrameSource, StaticMesh};
use relief::plot::plot_report;
use relief::preprocess::convert::{convert, ConvertOptions};
use relief::preprocess::inspect;
use relief::refine::metric::MetricKind;
use relief::refine::report::{refine_report, ReportOptions};
use relief::refine::RefineOptions;
use relief::render::MeshStyle;
use relief::render::{DrawStyle, Gpu};
use relief::sys::progress::Progress;
use relief::window::{check_display, fly_window, mesh_window, MeshWindowOptions, WindowOptions, WindowSettings};

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

/// A view and how to refine it (shared by `refine` and `render`).
#[derive(Args)]
struct ViewArgs {
    /// Eye position "X,Y,Z", metres.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    eye: String,
    /// Point looked at "X,Y,Z", metres.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    look: String,
    /// Up direction "X,Y,Z".
    #[arg(long, value_name = "X,Y,Z", default_value = "0,0,1", allow_hyphen_values = true)]
    up: String,
    #[command(flatten)]
    image: ImageArgs,
    #[command(flatten)]
    refine: RefineArgs,
}

/// The image a view is refined for (shared by `refine`, `render` and `layouts`).
#[derive(Args)]
struct ImageArgs {
    /// Image width, pixels.
    #[arg(long, value_name = "W", default_value_t = 1920)]
    width: u32,
    /// Image height, pixels.
    #[arg(long, value_name = "H", default_value_t = 1080)]
    height: u32,
    /// Horizontal field of view, degrees.
    #[arg(long, value_name = "DEG", default_value_t = 60.0)]
    fov: f64,
}

/// How to refine (shared by `refine`, `render` and `fly`).
#[derive(Args)]
struct RefineArgs {
    /// Screen-space error tolerance τ, pixels.
    #[arg(long, value_name = "PX", default_value_t = 1.0)]
    tolerance: f64,
    /// Screen-space error metric.
    #[arg(long, value_parser = metric_parser(), default_value = "isotropic")]
    metric: MetricKind,
    /// Do not cull to the view frustum (refine the whole terrain for the eye).
    #[arg(long)]
    no_cull: bool,
    /// Geomorphing: blend vertices in between the distances where their error projects to τ
    /// and to RATIO·τ (RATIO > 1).
    #[arg(long, value_name = "RATIO")]
    geomorph: Option<f64>,
    /// Refinement threads (1: no pool).
    #[arg(long, value_name = "N", default_value_t = 1)]
    threads: usize,
}

impl RefineArgs {
    /// The validated refinement options.
    fn options(&self) -> anyhow::Result<RefineOptions> {
        if !(self.tolerance > 0.0 && self.tolerance.is_finite()) {
            bail!("--tolerance: expected a positive number of pixels, got {}", self.tolerance);
        }
        if let Some(r) = self.geomorph {
            if !(r > 1.0 && r.is_finite()) {
                bail!("--geomorph: expected a ratio greater than 1, got {r}");
            }
        }
        if self.threads == 0 {
            bail!("--threads must be at least 1");
        }
        Ok(RefineOptions {
            tolerance_px: self.tolerance,
            metric: self.metric,
            cull: !self.no_cull,
            morph_ratio: self.geomorph,
        })
    }
}

impl ViewArgs {
    /// The validated camera and refinement options.
    fn resolve(&self) -> anyhow::Result<(Camera, RefineOptions)> {
        let options = self.refine.options()?;
        let camera = Camera::new(
            parse_vec3("--eye", &self.eye)?,
            parse_vec3("--look", &self.look)?,
            parse_vec3("--up", &self.up)?,
            self.image.fov,
            self.image.width,
            self.image.height,
        )?;
        Ok((camera, options))
    }
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
    /// Refine one view into a single triangle strip and report its size and speed.
    ///
    /// World coordinates are metres with the origin at the grid's south-west corner, x east, y
    /// north, z up (the extent is in `relief info`). A vertex is refined while its nested error
    /// projects to more than --tolerance pixels on a --width-pixel-wide image.
    Refine {
        file: PathBuf,
        #[command(flatten)]
        view: ViewArgs,
        /// Prove the mesh conforming: edges, areas, windings, T-junctions.
        #[arg(long)]
        check: bool,
        /// Compare with the minimal mesh for the same view and tolerance.
        #[arg(long)]
        compare_minimal: bool,
        /// Refine this many times and report the median time.
        #[arg(long, value_name = "N", default_value_t = 1)]
        repeat: usize,
        /// Print JSON on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Fly over a terrain: in a window, or headless along a recorded path.
    ///
    /// With no FILE, flies over the bundled terrain (data/zurich_25m_i16.tif, converted on first
    /// use into ~/.cache/relief). In a window: drag to look, W/A/S/D/Q/E to move (Shift ×4), wheel
    /// for speed, F freeze refinement, T wireframe, F12 or P screenshot, R record the path, Esc quit.
    /// With --path: renders each frame of PATH.json ({"eye": [x,y,z], "look": [x,y,z]} per frame,
    /// world metres) offscreen, optionally to PNGs, and reports per-frame figures.
    Fly {
        /// Terrain file (default: the bundled terrain).
        file: Option<PathBuf>,
        /// Fly headless along this path (see `relief path`) instead of opening a window.
        #[arg(long, value_name = "PATH.json")]
        path: Option<PathBuf>,
        /// Headless: write each frame as DIR/frame_00000.png, ...
        #[arg(long, value_name = "DIR", requires = "path")]
        frames_out: Option<PathBuf>,
        /// Headless: write per-frame figures (refine ms, render ms, triangles, bytes, faults) as JSON.
        #[arg(long, value_name = "OUT.json", requires = "path")]
        stats: Option<PathBuf>,
        /// Headless: print the summary as JSON on stdout.
        #[arg(long, requires = "path")]
        json: bool,
        /// Where refinement runs: on its own thread (the render thread draws the newest finished
        /// strip and never waits) or synchronously before each frame. Default: thread in a
        /// window, sync headless (each frame drawn with its own view's strip).
        #[arg(long, value_parser = ["thread", "sync"])]
        refinement: Option<String>,
        /// Image or window width, pixels.
        #[arg(long, value_name = "W", default_value_t = 1280)]
        width: u32,
        /// Image or window height, pixels.
        #[arg(long, value_name = "H", default_value_t = 720)]
        height: u32,
        /// Horizontal field of view, degrees.
        #[arg(long, value_name = "DEG", default_value_t = 60.0)]
        fov: f64,
        #[command(flatten)]
        refine: RefineArgs,
        /// Start with the wireframe overlay on.
        #[arg(long)]
        wireframe: bool,
        /// Directory for screenshots and recorded paths (window).
        #[arg(long, value_name = "DIR", default_value = ".")]
        output_dir: PathBuf,
        /// Window: start at this eye position "X,Y,Z", metres (with --look).
        #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, requires = "look", conflicts_with = "path")]
        eye: Option<String>,
        /// Window: start looking at this point "X,Y,Z", metres (with --eye).
        #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, requires = "eye")]
        look: Option<String>,
        /// Window: close after this many frames (scripted runs).
        #[arg(long, value_name = "N", conflicts_with = "path")]
        exit_after_frames: Option<u64>,
        /// No progress bars.
        #[arg(long, short)]
        quiet: bool,
    },
    /// Refine and render one view offscreen (no window needed) to a PNG image.
    ///
    /// Coordinates as for `refine`. Heights are uploaded to the GPU once; the frame then sends
    /// only the strip (8 bytes per vertex, 16 with --geomorph). Without a GPU, Mesa's software
    /// Vulkan (lavapipe) renders it.
    Render {
        file: PathBuf,
        #[command(flatten)]
        view: ViewArgs,
        /// PNG image to write (replaced atomically).
        #[arg(long, value_name = "IMAGE.png")]
        out: PathBuf,
        /// Overlay the mesh edges (shows the level of detail).
        #[arg(long)]
        wireframe: bool,
        /// Print the frame's figures as JSON on stdout.
        #[arg(long)]
        json: bool,
        /// No progress bars.
        #[arg(long, short)]
        quiet: bool,
    },
    /// Compare index layouts by page faults along a flight (the terrain paper's experiment).
    ///
    /// INPUT is a DEM (converted once per layout into --cache-dir) or a terrain file (re-laid out
    /// once per layout). For each layout and tolerance the flight in --path is refined frame by
    /// frame and every record read is charged to its page in an LRU model of a page cache of
    /// --memory bytes: faults are that model's misses, identical on every machine. --os also counts
    /// the process's real major faults on a cold, readahead-free mapping.
    Layouts {
        input: PathBuf,
        /// Flight path JSON (see `relief path`).
        #[arg(long, value_name = "PATH.json")]
        path: PathBuf,
        /// Page cache size: bytes with an optional K/M/G suffix (binary), or a fraction such as
        /// 1/16 of the terrain's data (posts × 12 bytes, no index-space waste).
        #[arg(long, value_name = "BYTES|1/N")]
        memory: String,
        /// Page size in bytes (a power of two; K/M suffixes allowed).
        #[arg(long, value_name = "BYTES", default_value = "4096")]
        page_size: String,
        /// Screen-space tolerances τ in pixels, comma-separated.
        #[arg(long, value_name = "PX[,PX…]", default_value = "1")]
        tolerance: String,
        /// Layouts to compare, comma-separated.
        #[arg(long, value_name = "a,b,…", default_value = "row-major,tiled,interleaved,embedded,hz")]
        layouts: String,
        #[command(flatten)]
        image: ImageArgs,
        /// Also count real OS page faults (cold mapped runs).
        #[arg(long)]
        os: bool,
        /// With --os: run the cold runs under a cgroup v1 memory limit of BYTES (K/M/G) on what
        /// they allocate and page in (needs root and a v1 memory controller; says why not).
        #[arg(long, value_name = "BYTES", requires = "os")]
        os_cap: Option<String>,
        /// Where converted layouts are kept (default ~/.cache/relief/layouts).
        #[arg(long, value_name = "DIR")]
        cache_dir: Option<PathBuf>,
        /// Print the results as JSON on stdout.
        #[arg(long)]
        json: bool,
        /// Write the two figures (cumulative faults per frame; faults against τ) to this PNG.
        #[arg(long, value_name = "OUT.png")]
        plot: Option<PathBuf>,
        /// No progress bars.
        #[arg(long, short)]
        quiet: bool,
    },
    /// Generate a camera flight path over a terrain or around a mesh and write it as JSON.
    ///
    /// World coordinates are metres with the origin at the grid's south-west corner, x east, y
    /// north, z up (height in metres); a mesh's are its file's. The file is a JSON array with one
    /// frame per line: [{"eye":[X,Y,Z],"look":[X,Y,Z]}, ...]. Prints the frame count, the path's
    /// length and the least clearance of an eye above the terrain (for a mesh: the least distance
    /// to its bounding box).
    Path {
        #[command(subcommand)]
        kind: PathCommand,
    },
    /// Triangle meshes for the mesh backends: inspect or show one, build its meta-node trees and
    /// fly over them, or export a terrain as one.
    Mesh {
        #[command(subcommand)]
        kind: MeshCommand,
    },
    /// The disk-page backend (Sajadi et al.): any triangle soup as self-contained fixed-size
    /// pages in a layout order, a k-d tree over the pages' boxes, and a per-frame fetch of whole
    /// pages in sorted order.
    Pages {
        #[command(subcommand)]
        kind: PagesCommand,
    },
}

#[derive(Subcommand)]
enum PagesCommand {
    /// Write a mesh (OFF, PLY, OBJ, optionally gzip'd) or a terrain file (.relief, as the mesh of
    /// `relief mesh from-terrain`) as a page file (replaced atomically): pages of whole triangles
    /// with copies of the vertices they use (position, normal, colour; 1-byte local indices when a
    /// page holds at most 256 vertices, else 2), each triangle in exactly one page; a directory
    /// with each page's bounding box and normal cone; the k-d tree over the boxes.
    Build {
        /// Mesh or terrain file.
        input: PathBuf,
        /// Page file to write.
        output: PathBuf,
        /// Page size, BYTES: a power of two from 1K to 1M (K/M suffixes allowed).
        #[arg(long, value_name = "BYTES", default_value = "4096")]
        page_size: String,
        /// Triangle order: raster (the input's), 2factor (hierarchical minimum-weight 2-factor:
        /// distance, then normal deviation within clusters of at most 12), hilbert (3D Hilbert
        /// curve through the centroids).
        #[arg(long, value_parser = PossibleValuesParser::new(["raster", "2factor", "hilbert"]), default_value = "2factor")]
        layout: String,
        /// Terrain input: take every N-th post.
        #[arg(long, value_name = "N", default_value_t = 1)]
        step: u32,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
        /// No progress bar.
        #[arg(long)]
        quiet: bool,
    },
    /// Fly over a page file: in a window, or headless along a path (`relief path orbit FILE`).
    ///
    /// Per frame: the k-d tree is culled against the view frustum, the pages of the surviving
    /// leaves collected once each, culled by box and normal cone, sorted, read whole with pread
    /// (one call per run of consecutive pages) and all their triangles drawn. Reports pages
    /// requested, bytes read, seek distance (Σ |page − previous page|, in pages, from where the
    /// previous frame's reads ended), fetch and frame times in ms, triangles.
    Fly {
        /// Page file (from `relief pages build`).
        file: PathBuf,
        /// Evict the file from the page cache first and turn off readahead (a cold start).
        #[arg(long)]
        cold: bool,
        /// Evict the file from the page cache before every frame (implies --cold): every page
        /// is read from storage, the fetch with no cache (a measurement mode).
        #[arg(long)]
        cold_frames: bool,
        /// Limit what the flight allocates and pages in after start-up to BYTES (a cgroup v1
        /// memory limit): the OS page cache then holds at most about that much of the file, as
        /// in the paper's walkthrough (264 MB left for caching pages).
        #[arg(long, value_name = "BYTES")]
        cap: Option<String>,
        /// Keep pages whose normal cone faces away from the eye (back faces are shaded, so
        /// culling can open holes in open scans).
        #[arg(long)]
        no_backface_cull: bool,
        #[command(flatten)]
        show: MeshShowArgs,
    },
}

#[derive(Subcommand)]
enum MeshCommand {
    /// Show a whole mesh (OFF, PLY, OBJ, optionally gzip'd; no simplification): in a window, or
    /// headless along a flight path (see `relief path orbit MESH`).
    ///
    /// In a window: drag to look, W/A/S/D/Q/E to move (Shift ×4), wheel for speed, T wireframe,
    /// F freeze, F12 or P screenshot, R record the path, Esc quit. With --path: renders each frame
    /// offscreen, optionally to PNGs, and reports per-frame figures.
    View {
        /// Mesh file.
        input: PathBuf,
        #[command(flatten)]
        show: MeshShowArgs,
    },
    /// Fly over a meta-node file (from `relief mesh build`) with view-dependent refinement: in a
    /// window, or headless along a path (`relief path orbit FILE`).
    ///
    /// Each frame the active nodes are split or collapsed against their switch values at the
    /// screen-space tolerance (--tolerance, pixels), respecting the implicit dependencies. In ext
    /// mode meta-nodes come through a buffer pool of --memory bytes with an I/O thread (a switch
    /// whose meta-node is not in memory is a miss: put off, and an urgent prefetch sent); in virt
    /// mode straight from the memory-mapped file (the OS pages it in, the navigation waits).
    /// Per frame: splits + collapses (adapt), triangles, misses (% of wanted switches), pages read,
    /// adapt/render/frame ms.
    Fly {
        /// Meta-node file.
        file: PathBuf,
        /// ext: buffer pool + I/O thread; virt: the plain memory map.
        #[arg(long, value_enum, default_value = "ext")]
        mode: NavMode,
        /// ext: the buffer pool's memory, BYTES (K/M/G suffixes) or a fraction A/B of the tree on
        /// disk (DATA + MNT), e.g. 1/4.
        #[arg(long, value_name = "BYTES", default_value = "1/4")]
        memory: String,
        /// Limit what the flight allocates and pages in after start-up to BYTES (a cgroup v1
        /// memory limit, both modes), so a tree larger than that cannot stay in memory.
        #[arg(long, value_name = "BYTES")]
        cap: Option<String>,
        /// Evict the file from the page cache first and turn off readahead (a cold start).
        #[arg(long)]
        cold: bool,
        /// ext: which meta-nodes to prefetch. paper: the parent and all children of every
        /// meta-node in use (El-Sana & Chiang); parent: only the parent; frontier: for every
        /// active node, the blocks its split or its parent's collapse would read.
        #[arg(long, value_enum, default_value = "frontier")]
        prefetch: PrefetchArg,
        #[command(flatten)]
        show: MeshShowArgs,
    },
    /// Read a mesh (OFF, PLY ASCII/binary, OBJ; optionally gzip'd) and print its vertices,
    /// triangles, bounds and the degenerate triangles dropped.
    Info {
        /// Mesh file.
        file: PathBuf,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Build the view-dependence forest of a mesh out of core (El-Sana & Chiang's spanned
    /// sub-mesh simplification): shortest-first edge collapses in exactly the order of an
    /// in-memory build, within a memory budget; then blocked into page-sized meta-nodes and
    /// written as a meta-node file (replaced atomically). Scratch files (the edge B-tree, the
    /// VDT forest unless --vdt keeps it) go beside OUTPUT and are removed afterwards.
    Build {
        /// Mesh file (OFF, PLY, OBJ; optionally gzip'd).
        input: PathBuf,
        /// Meta-node file to write (the DATA blocks and the MNT table in one file).
        output: PathBuf,
        /// Also keep the intermediate view-dependence forest (VDT file) here [default: a
        /// temporary file beside OUTPUT, removed].
        #[arg(long, value_name = "VDT")]
        vdt: Option<PathBuf>,
        /// Memory budget of the build phase: BYTES with an optional binary K/M/G suffix (64M,
        /// 1.5G), or a fraction "A/B" of the mesh's size in memory (24 bytes a vertex plus 12 a
        /// triangle). It covers the redb page cache (1/8 of it), the scratch buffers and the
        /// loaded sub-meshes; reading the input beforehand holds the whole mesh regardless.
        #[arg(long, value_name = "BYTES")]
        memory: String,
        /// Collapse metric: edge length, or the square root of the Garland–Heckbert quadric
        /// error (both in mesh units).
        #[arg(long, value_enum, default_value = "length")]
        metric: VdtMetricArg,
        /// Levels of the binary forest per meta-node (for the meta-node step).
        #[arg(long, value_name = "L", default_value_t = 8)]
        levels_per_node: u32,
        /// Disk page size of the meta-node file, BYTES (K/M/G suffixes allowed).
        #[arg(long, value_name = "BYTES", default_value = "4096")]
        page_size: String,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
        /// No progress bar.
        #[arg(long)]
        quiet: bool,
    },
    /// Write a terrain's valid window as a regular triangle mesh in world metres (x = gx·spacing,
    /// y = gy·spacing, z = height; two triangles per cell), binary little-endian PLY, replaced
    /// atomically.
    FromTerrain {
        /// Terrain file (.relief).
        terrain: PathBuf,
        /// Output mesh (.ply).
        output: PathBuf,
        /// Take every N-th post (the window's last row and column are always kept).
        #[arg(long, value_name = "N", default_value_t = 1)]
        step: u32,
    },
}

/// How to show a mesh source: in a window, or headless along a path (shared by `mesh view` and the
/// mesh backends).
#[derive(Args)]
struct MeshShowArgs {
    /// Fly headless along this path (see `relief path orbit MESH`) instead of opening a window.
    #[arg(long, value_name = "PATH.json")]
    path: Option<PathBuf>,
    /// Headless: write each frame as DIR/frame_00000.png, ...
    #[arg(long, value_name = "DIR", requires = "path")]
    frames_out: Option<PathBuf>,
    /// Headless: write the per-frame figures and the summary as JSON ({"frames":[…],"summary":{…}}).
    #[arg(long, value_name = "OUT.json", requires = "path")]
    stats: Option<PathBuf>,
    /// Headless: print the per-frame figures and the summary as JSON on stdout.
    #[arg(long, requires = "path")]
    json: bool,
    /// Image or window width, pixels.
    #[arg(long, value_name = "W", default_value_t = 1280)]
    width: u32,
    /// Image or window height, pixels.
    #[arg(long, value_name = "H", default_value_t = 720)]
    height: u32,
    /// Horizontal field of view, degrees.
    #[arg(long, value_name = "DEG", default_value_t = 60.0)]
    fov: f64,
    /// Screen-space error tolerance τ handed to the simplification, pixels.
    #[arg(long, value_name = "PX", default_value_t = 1.0)]
    tolerance: f64,
    /// The mesh's up axis (sky, sun, the window's horizon) [default: as for `relief path`].
    #[arg(long, value_parser = up_parser())]
    up: Option<UpAxis>,
    /// Draw the triangles' edges.
    #[arg(long)]
    wireframe: bool,
    /// Directory for screenshots and recorded paths (window).
    #[arg(long, value_name = "DIR", default_value = ".")]
    output_dir: PathBuf,
    /// Window: start at this eye position "X,Y,Z" (with --look).
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, requires = "look", conflicts_with = "path")]
    eye: Option<String>,
    /// Window: start looking at this point "X,Y,Z" (with --eye).
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, requires = "eye")]
    look: Option<String>,
    /// Window: close after this many frames (scripted runs).
    #[arg(long, value_name = "N", conflicts_with = "path")]
    exit_after_frames: Option<u64>,
    /// Headless: adapt only, no rendering (times the simplification and its I/O alone).
    #[arg(long, requires = "path")]
    no_render: bool,
    /// Headless: start frames at least MS milliseconds apart, like a display (with --no-render,
    /// the time a renderer would take, during which prefetching goes on); not counted in frame_ms.
    #[arg(long, value_name = "MS", default_value_t = 0.0, requires = "path")]
    pace: f64,
    /// No progress bars.
    #[arg(long, short)]
    quiet: bool,
}

impl MeshShowArgs {
    /// Rejects numbers no flight can use, before anything is read.
    fn check(&self) -> anyhow::Result<()> {
        if !(self.tolerance > 0.0 && self.tolerance.is_finite()) {
            bail!("--tolerance: expected a positive number of pixels, got {}", self.tolerance);
        }
        if self.width == 0 || self.height == 0 {
            bail!("--width and --height must be at least 1 pixel");
        }
        Ok(())
    }
}

/// Shows `source` (read from `file`, adapted by `source_name`) as `show` asks: headless along
/// `flight` when given, else in a window. The one call a mesh backend's command makes.
fn show_mesh(
    source: &mut dyn MeshFrameSource,
    file: &std::path::Path,
    source_name: &str,
    flight: Option<FlightPath>,
    show: MeshShowArgs,
) -> anyhow::Result<ExitCode> {
    show.check()?;
    let up = show.up.unwrap_or_else(|| UpAxis::guess(source.bounds().extent()));
    let (Some(flight), Some(path)) = (flight, show.path.as_deref()) else {
        let options = MeshWindowOptions {
            window: WindowSettings {
                width_px: show.width,
                height_px: show.height,
                fov_x_deg: show.fov,
                output_dir: show.output_dir,
                start: parse_start(show.eye.as_deref(), show.look.as_deref())?,
                exit_after_frames: show.exit_after_frames,
            },
            tolerance_px: show.tolerance,
            wireframe: show.wireframe,
            up,
            source_name: source_name.to_string(),
        };
        mesh_window(source, &file.display().to_string(), options)?;
        return Ok(ExitCode::SUCCESS);
    };
    let cameras = (0..flight.frames.len())
        .map(|k| {
            flight
                .camera_with_up(k, up, show.fov, show.width, show.height)
                .map_err(|e| anyhow::anyhow!("{}: frame {k}: {e}", path.display()))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    if !(show.pace >= 0.0 && show.pace.is_finite()) {
        bail!("--pace: expected milliseconds ≥ 0, got {}", show.pace);
    }
    let options = MeshFlyOptions {
        pace_ms: show.pace,
        width_px: show.width,
        height_px: show.height,
        tolerance_px: show.tolerance,
        style: MeshStyle { wireframe: show.wireframe },
        up,
        frames_out: show.frames_out,
        stats_out: show.stats,
        progress: progress(show.quiet),
    };
    let gpu = if show.no_render { None } else { Some(Gpu::headless()?) };
    let report = fly_mesh_headless(gpu.as_ref(), source, &cameras, &options)?;
    let s = &report.summary;
    if show.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "{} ({source_name}): {} frames at {} x {}, frame {:.2} ms, render {:.2} ms (means), {:.0} triangles and {:.1} splits + collapses per frame (mean), {:.2}% misses, {} pages read, {} uploaded ({})",
            file.display(),
            s.frames,
            s.width,
            s.height,
            s.frame_ms_mean,
            s.render_ms_mean,
            s.triangles_mean,
            s.adapt_mean,
            s.miss_pct,
            s.pages_read,
            fmt_bytes(s.upload_bytes),
            s.adapter
        );
        if let Some(p) = &s.fetch {
            println!(
                "  pages: {:.1} requested per frame (of {:.1} named by the k-d tree), {} read, seek {:.1} pages, fetch {:.2} ms (reads {:.2} ms) per frame (means)",
                p.pages_mean,
                p.pages_candidate_mean,
                fmt_bytes(p.bytes_read),
                p.seek_pages_mean,
                p.fetch_ms_mean,
                p.read_ms_mean
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// `--mode` of `relief mesh fly`.
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum NavMode {
    Ext,
    Virt,
}

/// `--metric` of `relief mesh build`.
#[derive(Clone, Copy, clap::ValueEnum)]
enum VdtMetricArg {
    Length,
    Quadric,
}

impl From<VdtMetricArg> for relief::metanode::VdtMetric {
    fn from(m: VdtMetricArg) -> Self {
        match m {
            VdtMetricArg::Length => relief::metanode::VdtMetric::Length,
            VdtMetricArg::Quadric => relief::metanode::VdtMetric::Quadric,
        }
    }
}

/// `--prefetch` of `relief mesh fly`.
#[derive(Clone, Copy, clap::ValueEnum)]
enum PrefetchArg {
    Paper,
    Parent,
    Frontier,
}

impl From<PrefetchArg> for relief::metanode::navigate::Prefetch {
    fn from(p: PrefetchArg) -> Self {
        use relief::metanode::navigate::Prefetch;
        match p {
            PrefetchArg::Paper => Prefetch::Paper,
            PrefetchArg::Parent => Prefetch::Parent,
            PrefetchArg::Frontier => Prefetch::Frontier,
        }
    }
}

/// `relief mesh info` as printed with `--json`.
#[derive(serde::Serialize)]
struct MeshInfo {
    file: String,
    format: relief::mesh::MeshFormat,
    gzip: bool,
    vertices: usize,
    triangles: usize,
    faces: u64,
    degenerate_dropped: u64,
    bounds: Option<relief::mesh::Bounds>,
    read_ms: f64,
}

#[derive(Subcommand)]
enum PathCommand {
    /// A low-altitude straight fly-over along the DEM's diagonal, south-west to north-east (5%
    /// inside the corners), climbing over the highest terrain within 3% of the diagonal around the
    /// eye, looking ahead 15° below the horizon. For a mesh: across its bounding box along the
    /// horizontal diagonal, at a constant height above the box's top.
    Flyover {
        #[command(flatten)]
        common: PathArgs,
        /// Least height of the eye above the highest terrain around it, metres [default: 2% of
        /// the DEM's diagonal].
        #[arg(long, value_name = "M")]
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
        #[arg(long, value_name = "M")]
        radius: Option<f64>,
        /// Eye height (world z), metres [default: highest terrain + 0.3 × half the DEM's diagonal].
        #[arg(long, value_name = "M", allow_hyphen_values = true)]
        altitude: Option<f64>,
    },
}

/// What `relief path` flies over or around.
enum PathSubject {
    Terrain(TerrainFile),
    /// A mesh's bounding box and up axis.
    Mesh(relief::mesh::Bounds, UpAxis),
}

/// What every `relief path` generator takes.
#[derive(Args)]
struct PathArgs {
    /// Terrain file (.relief), or a mesh (OFF, PLY, OBJ, optionally gzip'd), a meta-node file or
    /// a page file: then the path is about the mesh's bounding box, in the file's units.
    file: PathBuf,
    /// A mesh's up axis [default: the axis of the box's smallest side when it is at most half the
    /// next (a terrain), else y (scanned objects, OBJ)]. Terrains are always z up.
    #[arg(long, value_parser = up_parser())]
    up: Option<UpAxis>,
    /// Number of frames (at least 1; an orbit spaces them evenly over the turn).
    #[arg(long, value_name = "N")]
    frames: usize,
    /// Flight-path file to write (replaced atomically if it exists).
    #[arg(long, value_name = "PATH.json")]
    out: PathBuf,
    /// Print the summary as JSON on stdout.
    #[arg(long)]
    json: bool,
}

/// `--up` values.
fn up_parser() -> impl clap::builder::TypedValueParser<Value = UpAxis> {
    PossibleValuesParser::new(UpAxis::ALL.map(UpAxis::name))
        .map(|name| UpAxis::from_name(&name).expect("a possible value"))
}

/// Whether `path` starts with the terrain file magic (a mesh otherwise; unreadable files are left
/// to the mesh reader to report).
fn is_terrain_file(path: &std::path::Path) -> bool {
    has_magic(path, relief::format::FileKind::Terrain)
}

/// Whether the file starts with the magic of `kind`.
fn has_magic(path: &std::path::Path, kind: relief::format::FileKind) -> bool {
    matches!(relief::format::sniff(path), Ok(Some(k)) if k == kind)
}

/// A window's start from `--eye` and `--look` (clap makes them come together).
fn parse_start(eye: Option<&str>, look: Option<&str>) -> anyhow::Result<Option<(DVec3, DVec3)>> {
    Ok(match (eye, look) {
        (Some(e), Some(l)) => Some((parse_vec3("--eye", e)?, parse_vec3("--look", l)?)),
        _ => None,
    })
}

/// `--metric` values: the library's metric names.
fn metric_parser() -> impl clap::builder::TypedValueParser<Value = MetricKind> {
    PossibleValuesParser::new(MetricKind::ALL.map(MetricKind::name))
        .map(|name| MetricKind::from_name(&name).expect("a possible value"))
}

fn parse_vec3(flag: &str, s: &str) -> anyhow::Result<DVec3> {
    let nums: Result<Vec<f64>, _> = s.split(',').map(|p| p.trim().parse::<f64>()).collect();
    match nums.ok().as_deref() {
        Some(&[x, y, z]) if x.is_finite() && y.is_finite() && z.is_finite() => Ok(DVec3::new(x, y, z)),
        _ => bail!("{flag}: expected three finite numbers X,Y,Z, got '{s}'"),
    }
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

/// Bytes with an optional binary K/M/G suffix ("4096", "64K", "1.5G").
fn parse_bytes(flag: &str, s: &str) -> anyhow::Result<u64> {
    let t = s.trim();
    let (num, mult) = match t.char_indices().last() {
        Some((i, 'K' | 'k')) => (&t[..i], 1u64 << 10),
        Some((i, 'M' | 'm')) => (&t[..i], 1 << 20),
        Some((i, 'G' | 'g')) => (&t[..i], 1 << 30),
        _ => (t, 1),
    };
    match num.parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 && v * (mult as f64) < u64::MAX as f64 => Ok((v * mult as f64) as u64),
        _ => bail!("{flag}: expected bytes such as 4096, 64K or 1G, got '{s}'"),
    }
}

/// The camera of every frame of a flight path (errors name the file and the frame).
fn path_cameras(flight: &FlightPath, path: &std::path::Path, fov: f64, w: u32, h: u32) -> anyhow::Result<Vec<Camera>> {
    (0..flight.frames.len())
        .map(|k| flight.camera(k, fov, w, h).map_err(|e| anyhow::anyhow!("{}: frame {k}: {e}", path.display())))
        .collect()
}

/// `--memory`: bytes, or "A/B" of `data_bytes` (the input's data: a terrain's records, a mesh).
fn parse_memory(s: &str, data_bytes: u64) -> anyhow::Result<u64> {
    if let Some((a, b)) = s.split_once('/') {
        match (a.trim().parse::<f64>(), b.trim().parse::<f64>()) {
            (Ok(a), Ok(b)) if a > 0.0 && b > 0.0 && a.is_finite() && b.is_finite() => {
                return Ok((data_bytes as f64 * a / b) as u64)
            }
            _ => bail!("--memory: expected bytes (64M) or a fraction of the input's data (1/16), got '{s}'"),
        }
    }
    parse_bytes("--memory", s)
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
        Command::Refine { file, view, check, compare_minimal, repeat, json } => {
            let (camera, options) = view.resolve()?;
            if repeat == 0 {
                bail!("--repeat must be at least 1");
            }
            let threads = view.refine.threads;
            let f = TerrainFile::open(&file)?;
            let report = ReportOptions { threads, repeat, check, compare_minimal };
            let (r, _) = refine_report(&f, &camera, &options, &report)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&r)?);
            } else {
                println!(
                    "{}: {} triangles, strip {} ({} degenerate, {:.3} vertices/triangle), visited {}, culled {}",
                    r.file, r.triangles, r.strip_len, r.degenerate, r.strip_vertices_per_triangle, r.visited, r.culled
                );
                println!(
                    "refine {:.3} ms median of {} ({:.3} ms min), {:.1} M triangles/s, {} thread(s), layout {}",
                    r.refine_ms, r.repeat, r.refine_ms_min, r.mtris_per_s, r.threads, r.layout
                );
                if let Some(c) = &r.check {
                    println!(
                        "check: {} ({} edge errors, {} winding errors, area {}, {} inactive vertices)",
                        if c.crack_free { "crack-free" } else { "CRACKS" },
                        c.edge_errors,
                        c.winding_errors,
                        if c.area_ok { "ok" } else { "wrong" },
                        c.inactive_vertices
                    );
                }
                if let (Some(m), Some(ratio)) = (r.minimal_triangles, r.ratio_to_minimal) {
                    println!("minimal mesh: {m} triangles, ratio {ratio:.4}");
                }
            }
            let failed = r.check.as_ref().is_some_and(|c| !c.crack_free || c.inactive_vertices > 0);
            Ok(if failed { ExitCode::FAILURE } else { ExitCode::SUCCESS })
        }
        Command::Fly {
            file,
            path,
            frames_out,
            stats,
            json,
            refinement,
            width,
            height,
            fov,
            refine,
            wireframe,
            output_dir,
            eye,
            look,
            exit_after_frames,
            quiet,
        } => {
            let threads = refine.threads;
            let refine = refine.options()?;
            if width == 0 || height == 0 {
                bail!("--width and --height must be at least 1 pixel");
            }
            if path.is_none() {
                check_display()?;
            }
            let file = match file {
                Some(f) => f,
                None => bundled_terrain(progress(quiet))?,
            };
            let terrain = Arc::new(TerrainFile::open(&file)?);
            let Some(path) = path else {
                let options = WindowOptions {
                    window: WindowSettings {
                        width_px: width,
                        height_px: height,
                        fov_x_deg: fov,
                        output_dir,
                        start: parse_start(eye.as_deref(), look.as_deref())?,
                        exit_after_frames,
                    },
                    refine,
                    wireframe,
                    threads,
                    sync: refinement.as_deref() == Some("sync"),
                    progress: progress(quiet),
                };
                fly_window(terrain, options)?;
                return Ok(ExitCode::SUCCESS);
            };
            let flight = FlightPath::load(&path)?;
            let cameras = path_cameras(&flight, &path, fov, width, height)?;
            let options = HeadlessOptions {
                width_px: width,
                height_px: height,
                fov_x_deg: fov,
                refine,
                style: DrawStyle { wireframe },
                threads,
                refine_thread: refinement.as_deref() == Some("thread"),
                frames_out,
                progress: progress(quiet),
            };
            let report = fly_headless(terrain, &cameras, &options)?;
            if let Some(out) = &stats {
                let text = serde_json::to_string_pretty(&report)?;
                relief::sys::atomic_file::write(out, |w| std::io::Write::write_all(w, text.as_bytes()))?;
            }
            let s = &report.summary;
            if json {
                println!("{}", serde_json::to_string_pretty(s)?);
            } else {
                println!(
                    "{}: {} frames at {} x {}, {:.1} fps, frame {:.2} ms, refine {:.2} ms, render {:.2} ms (medians), {:.0} triangles and {:.0} bytes uploaded per frame (mean), {} major / {} minor page faults ({})",
                    file.display(),
                    s.frames,
                    s.width,
                    s.height,
                    s.fps,
                    s.frame_ms_median,
                    s.refine_ms_median,
                    s.render_ms_median,
                    s.triangles_mean,
                    s.upload_bytes_mean,
                    s.major_faults,
                    s.minor_faults,
                    s.adapter
                );
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Render { file, view, out, wireframe, json, quiet } => {
            let (camera, options) = view.resolve()?;
            let f = TerrainFile::open(&file)?;
            let gpu = Gpu::headless()?;
            let style = DrawStyle { wireframe };
            let (image, r) = render_still(&gpu, &f, &camera, &options, style, view.refine.threads, progress(quiet))?;
            save_png(&image, &out)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&r)?);
            } else {
                println!(
                    "{}: {} x {} px, {} triangles (strip {}), refine {:.2} ms, render {:.2} ms, {} uploaded this frame, heights {} on the GPU ({})",
                    out.display(),
                    r.width,
                    r.height,
                    r.triangles,
                    r.strip_len,
                    r.refine_ms,
                    r.render_ms,
                    fmt_bytes(r.upload_bytes),
                    fmt_bytes(r.heights_gpu_bytes),
                    r.adapter
                );
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Layouts {
            input,
            path,
            memory,
            page_size,
            tolerance,
            layouts,
            image: ImageArgs { width, height, fov },
            os,
            os_cap,
            cache_dir,
            json,
            plot,
            quiet,
        } => {
            let os_cap_bytes = os_cap.as_deref().map(|c| parse_bytes("--os-cap", c)).transpose()?;
            let page_bytes = parse_bytes("--page-size", &page_size)?;
            let tolerances_px = tolerance
                .split(',')
                .map(|t| match t.trim().parse::<f64>() {
                    Ok(v) if v > 0.0 && v.is_finite() => Ok(v),
                    _ => Err(anyhow::anyhow!("--tolerance: expected positive pixels like 1,2,4, got '{tolerance}'")),
                })
                .collect::<anyhow::Result<Vec<_>>>()?;
            let kinds = layouts
                .split(',')
                .map(|n| {
                    LayoutKind::from_name(n.trim()).ok_or_else(|| {
                        anyhow::anyhow!(
                            "--layouts: unknown layout '{}' (choose from {})",
                            n.trim(),
                            LayoutKind::ALL.map(LayoutKind::name).join(", ")
                        )
                    })
                })
                .collect::<anyhow::Result<Vec<_>>>()?;
            relief::pager::PageGeometry::new(page_bytes)?;
            let flight = FlightPath::load(&path)?;
            if !input.exists() {
                bail!("{}: no such file", input.display());
            }
            let cache_dir = cache_dir.unwrap_or_else(|| relief::preprocess::convert::cache_dir().join("layouts"));
            let first = terrain_in_layout(&input, kinds[0], &cache_dir, progress(quiet))?;
            let memory_bytes = {
                let t = TerrainFile::open(&first)?;
                parse_memory(&memory, t.grid().vertices() * relief::format::terrain::RECORD_BYTES as u64)?
            };
            let cameras = path_cameras(&flight, &path, fov, width, height)?;
            let options = LayoutsOptions {
                memory_bytes,
                page_bytes,
                tolerances_px,
                layouts: kinds,
                width_px: width,
                height_px: height,
                fov_x_deg: fov,
                os,
                os_cap_bytes,
                progress: progress(quiet),
            };
            let report = run_layouts(&input, &cameras, &cache_dir, &options)?;
            if let Some(out) = &plot {
                plot_report(&report, out)?;
            }
            if json {
                println!("{}", serde_json::to_string_pretty(&report)?);
            } else {
                println!(
                    "{}: {} frames, LRU cache of {} pages of {} B ({}), {}",
                    report.input,
                    report.frames,
                    report.cache_pages,
                    report.page_bytes,
                    fmt_bytes(report.memory_bytes),
                    report.os_note.as_deref().unwrap_or("model only")
                );
                println!(
                    "{:<12} {:>6} {:>12} {:>10} {:>9} {:>12} {:>11} {:>8} {:>10} {:>9}{}",
                    "layout",
                    "τ px",
                    "faults",
                    "per frame",
                    "max",
                    "distinct pg",
                    "lower bnd",
                    "×bound",
                    "×row-major",
                    "ms/frame",
                    if os { "  os major" } else { "" }
                );
                for r in &report.layouts {
                    println!(
                        "{:<12} {:>6} {:>12} {:>10.1} {:>9} {:>12} {:>11} {:>8.2} {:>10} {:>9.2}{}",
                        r.layout,
                        r.tolerance,
                        r.faults,
                        r.faults_per_frame_mean,
                        r.faults_per_frame_max,
                        r.distinct_pages,
                        r.lower_bound,
                        r.ratio_to_lower_bound,
                        r.ratio_to_row_major.map_or("-".into(), |v| format!("{v:.3}")),
                        r.refine_ms_per_frame,
                        r.os.as_ref().map_or(String::new(), |o| format!("  {:>8}", o.major))
                    );
                }
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Path { kind } => {
            let common = match &kind {
                PathCommand::Flyover { common, .. } | PathCommand::Orbit { common, .. } => common,
            };
            let (file, out, json) = (&common.file, &common.out, common.json);
            // A terrain file by its magic; anything else must be a mesh read_mesh reads.
            let subject = if is_terrain_file(file) {
                if common.up.is_some_and(|u| u != UpAxis::Z) {
                    bail!("--up: a terrain's up axis is z");
                }
                PathSubject::Terrain(TerrainFile::open(file)?)
            } else if has_magic(file, relief::format::FileKind::Pages) {
                let bounds = relief::format::pages::PageFile::open(file)?.header().bounds;
                PathSubject::Mesh(bounds, common.up.unwrap_or_else(|| UpAxis::guess(bounds.extent())))
            } else if has_magic(file, relief::format::FileKind::MetaNode) {
                let bounds = relief::format::metanode::MetaNodeFile::open(file)?.header().bounds;
                PathSubject::Mesh(bounds, common.up.unwrap_or_else(|| UpAxis::guess(bounds.extent())))
            } else {
                let mesh = relief::mesh::read_mesh(file)?;
                let bounds = mesh.bounds().ok_or_else(|| anyhow::anyhow!("{}: no vertices", file.display()))?;
                PathSubject::Mesh(bounds, common.up.unwrap_or_else(|| UpAxis::guess(bounds.extent())))
            };
            let path = match &kind {
                PathCommand::Flyover { common, clearance } => {
                    let opts = FlyoverOptions { frames: common.frames, clearance_m: *clearance };
                    match &subject {
                        PathSubject::Terrain(t) => flyover(t, &opts)?,
                        PathSubject::Mesh(b, up) => flyover_box(b, *up, &opts)?,
                    }
                }
                PathCommand::Orbit { common, radius, altitude } => {
                    let opts = OrbitOptions { frames: common.frames, radius_m: *radius, altitude_m: *altitude };
                    match &subject {
                        PathSubject::Terrain(t) => orbit(t, &opts)?,
                        PathSubject::Mesh(b, up) => orbit_box(b, *up, &opts)?,
                    }
                }
            };
            path.save(out)?;
            // Terrains are in metres; a mesh in its file's units, shown to about 1/1000 of its size.
            let (s, clearance_what, unit, decimals, up) = match &subject {
                PathSubject::Terrain(t) => (path.summary(t)?, "min clearance above terrain", " m", 1, UpAxis::Z),
                PathSubject::Mesh(b, up) => {
                    let decimals = (3.0 - b.diagonal().log10().floor()).clamp(0.0, 9.0) as usize;
                    (path.summary_box(b), "min distance to the mesh's box", "", decimals, *up)
                }
            };
            if json {
                let j = serde_json::json!({
                    "frames": s.frames,
                    "length_m": s.length_m,
                    "min_clearance_m": s.min_clearance_m,
                    "up": up,
                    "out": out.display().to_string(),
                });
                println!("{}", serde_json::to_string_pretty(&j)?);
            } else {
                let clearance = match s.min_clearance_m {
                    Some(c) => format!("{c:.decimals$}{unit}"),
                    None => "n/a (no eye over the grid)".to_string(),
                };
                println!(
                    "{}: {} frames, length {:.decimals$}{unit}, {clearance_what} {clearance}, {} up",
                    out.display(),
                    s.frames,
                    s.length_m,
                    up.name()
                );
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Mesh { kind: MeshCommand::View { input, show } } => {
            show.check()?;
            // The path first: a bad path file fails before a large mesh is read.
            let flight = show.path.as_deref().map(FlightPath::load).transpose()?;
            if flight.is_none() {
                check_display()?;
            }
            let mesh = relief::mesh::read_mesh(&input)?;
            let mut source = StaticMesh::new(&mesh)?;
            show_mesh(&mut source, &input, "static", flight, show)
        }
        Command::Mesh { kind: MeshCommand::Fly { file, mode, memory, cap, cold, prefetch, show } } => {
            use relief::format::metanode::MetaNodeFile;
            use relief::metanode::navigate::{NavOptions, Navigator, PagedStore};
            use relief::metanode::source::NavSource;
            show.check()?;
            let flight = show.path.as_deref().map(FlightPath::load).transpose()?;
            if flight.is_none() {
                check_display()?;
            }
            let cap_bytes = cap.as_deref().map(|c| parse_bytes("--cap", c)).transpose()?;
            if cold {
                relief::pager::drop_from_page_cache(&file)?;
            }
            let meta = MetaNodeFile::open(&file)?;
            if cold {
                meta.advise_random()?;
            }
            let memory_bytes = parse_memory(&memory, meta.tree_bytes())?;
            let bounds = meta.header().bounds;
            let pooled = match mode {
                NavMode::Ext => {
                    let f = MetaNodeFile::open_with(&file, relief::pager::Access::Pool { bytes: memory_bytes })?;
                    if cold {
                        f.advise_random()?;
                    }
                    Some(f)
                }
                NavMode::Virt => None,
            };
            // The cap covers what the flight does, not start-up (cgroup v1 keeps earlier charges
            // where they were).
            let apply_cap = || cap_bytes.map(relief::pager::MemoryCap::apply).transpose();
            match mode {
                NavMode::Virt => {
                    let nav = Navigator::new(&meta, PagedStore::new(&meta), NavOptions::default())?;
                    let _cap = apply_cap()?;
                    let mut source = NavSource::new(nav, bounds);
                    show_mesh(&mut source, &file, "meta-node trees, virt", flight, show)
                }
                NavMode::Ext => {
                    let pooled = pooled.as_ref().expect("opened with a pool above");
                    let holders = pooled.pager().pool().map_or(0, |p| p.holders());
                    let nav = Navigator::new(
                        pooled,
                        PagedStore::new(pooled),
                        NavOptions { prefetch: prefetch.into(), ..NavOptions::default() },
                    )?;
                    let _cap = apply_cap()?;
                    let mut source = NavSource::new(nav, bounds);
                    let name = format!("meta-node trees, ext, {holders} holders of {} B", meta.header().holder_bytes);
                    show_mesh(&mut source, &file, &name, flight, show)
                }
            }
        }
        Command::Mesh { kind: MeshCommand::Info { file, json } } => {
            let start = std::time::Instant::now();
            let (mesh, report) = relief::mesh::read_mesh_with_report(&file)?;
            let info = MeshInfo {
                file: file.display().to_string(),
                format: report.format,
                gzip: report.gzip,
                vertices: mesh.positions.len(),
                triangles: mesh.triangles.len(),
                faces: report.faces,
                degenerate_dropped: report.degenerate_dropped,
                bounds: mesh.bounds(),
                read_ms: start.elapsed().as_secs_f64() * 1e3,
            };
            if json {
                println!("{}", serde_json::to_string_pretty(&info)?);
            } else {
                println!(
                    "{}: {}{}, {} vertices, {} triangles ({} faces, {} degenerate dropped), read in {:.1} ms",
                    info.file,
                    info.format.name(),
                    if info.gzip { ", gzip" } else { "" },
                    info.vertices,
                    info.triangles,
                    info.faces,
                    info.degenerate_dropped,
                    info.read_ms
                );
                if let Some(b) = info.bounds {
                    println!("  bounds: min {:?} max {:?}", b.min, b.max);
                }
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Mesh {
            kind: MeshCommand::Build { input, output, vdt, memory, metric, levels_per_node, page_size, json, quiet },
        } => {
            if levels_per_node == 0 {
                bail!("--levels-per-node must be at least 1");
            }
            let page_bytes = parse_bytes("--page-size", &page_size)?;
            if page_bytes == 0 {
                bail!("--page-size must be at least 1 byte");
            }
            // The budget may be a fraction of the mesh, so the mesh is read first (the build
            // measures its memory after ingest either way).
            let start = std::time::Instant::now();
            let mesh = relief::mesh::read_mesh(&input)?;
            let mesh_bytes = mesh.positions.len() as u64 * 24 + mesh.triangles.len() as u64 * 12;
            let memory_bytes = parse_memory(&memory, mesh_bytes)?;
            if memory_bytes == 0 {
                bail!("--memory must be more than 0 bytes");
            }
            let mut options = relief::metanode::build::BuildOptions::new(memory_bytes, metric.into());
            options.progress = progress(quiet);
            if !page_bytes.is_power_of_two() || !(512..=1 << 20).contains(&page_bytes) {
                bail!("--page-size must be a power of two from 512 bytes to 1M, got {page_bytes}");
            }
            let blocking =
                relief::metanode::blocking::BlockingOptions { levels_per_node, page_bytes: page_bytes as u32 };
            // The forest goes to a temporary file beside the output unless --vdt keeps it.
            let dir = match output.parent() {
                Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
                _ => PathBuf::from("."),
            };
            let scratch = tempfile::Builder::new()
                .prefix(".relief-vdt.")
                .tempdir_in(&dir)
                .with_context(|| format!("{}: cannot create a scratch directory", dir.display()))?;
            let vdt_path = vdt.clone().unwrap_or_else(|| scratch.path().join("forest.vdt"));
            let mut report = relief::metanode::build::build_vdt_from_mesh(mesh, &vdt_path, &options)?;
            // Ingest as the user waits for it: reading the file too.
            report.ingest_ms = start.elapsed().as_secs_f64() * 1e3 - report.build_ms;
            let forest_file = relief::metanode::VdtFile::open(&vdt_path)?;
            let forest = relief::metanode::blocking::Forest {
                nodes: forest_file.nodes(),
                triangles: forest_file.triangles(),
                base_triangles: forest_file.base_triangles().len(),
                leaves: forest_file.leaves() as u32,
                metric: forest_file.metric() as u32,
                bounds: forest_file.bounds(),
            };
            let meta = relief::metanode::blocking::write_metanode_file(&forest, blocking, &output)?;
            drop(forest_file);
            #[derive(serde::Serialize)]
            struct MeshBuild<'a> {
                #[serde(flatten)]
                vdt: &'a relief::metanode::build::BuildReport,
                metanode: &'a relief::metanode::blocking::MetaNodeReport,
                levels_per_node: u32,
                page_bytes: u64,
            }
            if json {
                let both = MeshBuild { vdt: &report, metanode: &meta, levels_per_node, page_bytes };
                println!("{}", serde_json::to_string_pretty(&both)?);
            } else {
                println!(
                    "{}: {} meta-nodes ({} roots, {:.1} nodes and {:.0}% of a {}-byte page each on average), DATA {}, MNT {}, {:.0} ms",
                    output.display(),
                    meta.metanodes,
                    meta.root_metanodes,
                    meta.nodes_per_metanode_mean,
                    meta.fill_mean * 100.0,
                    page_bytes,
                    fmt_bytes(meta.data_bytes),
                    fmt_bytes(meta.mnt_bytes),
                    meta.build_ms
                );
                println!(
                    "{}: {} leaves, {} nodes, {} roots, {} triangles ({} base); {} batches, {:.0} ms build (+{:.0} ms ingest), peak {} accounted, {} anon RSS above the start of the build phase, budget {}",
                    vdt.as_deref().unwrap_or(std::path::Path::new("forest")).display(),
                    report.leaves,
                    report.nodes,
                    report.roots,
                    report.triangles,
                    report.base_triangles,
                    report.batches,
                    report.build_ms,
                    report.ingest_ms,
                    fmt_bytes(report.peak_accounted_bytes),
                    fmt_bytes(report.peak_rss_anon_bytes.saturating_sub(report.rss_anon_baseline_bytes)),
                    fmt_bytes(report.memory_budget_bytes)
                );
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Mesh { kind: MeshCommand::FromTerrain { terrain, output, step } } => {
            if step == 0 {
                bail!("--step must be at least 1");
            }
            let f = TerrainFile::open(&terrain)?;
            let mesh = relief::mesh::terrain_mesh(&f, step)?;
            let comment = format!("relief mesh from-terrain {} --step {step}", terrain.display());
            relief::mesh::write_ply_binary(&mesh, &output, &comment)?;
            println!(
                "{}: {} vertices, {} triangles (binary little-endian PLY)",
                output.display(),
                mesh.positions.len(),
                mesh.triangles.len()
            );
            Ok(ExitCode::SUCCESS)
        }
        Command::Pages { kind: PagesCommand::Build { input, output, page_size, layout, step, json, quiet } } => {
            use relief::format::pages::PageLayout;
            use relief::pages::build::{build_page_file, PageBuildOptions};
            let page_bytes = parse_bytes("--page-size", &page_size)?;
            if !page_bytes.is_power_of_two() || !(1024..=1 << 20).contains(&page_bytes) {
                bail!("--page-size must be a power of two from 1K to 1M bytes, got {page_bytes}");
            }
            if step == 0 {
                bail!("--step must be at least 1");
            }
            let layout = PageLayout::from_name(&layout).expect("a possible value");
            let mesh = if is_terrain_file(&input) {
                relief::mesh::terrain_mesh(&TerrainFile::open(&input)?, step)?
            } else {
                relief::mesh::read_mesh(&input)?
            };
            let mut options = PageBuildOptions::new(page_bytes as u32, layout);
            options.progress = progress(quiet);
            let r = build_page_file(&mesh, &output, &options)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&r)?);
            } else {
                println!(
                    "{}: {} pages of {} B ({} layout), {} triangles ({:.1} a page, {:.0}% full), {} vertex copies of {} vertices, {} pages with 1-byte indices, k-d tree {} nodes / {} references, {}; layout {:.0} ms, pages {:.0} ms",
                    r.output,
                    r.pages,
                    r.page_bytes,
                    layout.name(),
                    r.triangles,
                    r.triangles_per_page_mean,
                    r.fill_mean * 100.0,
                    r.vertex_copies,
                    r.source_vertices,
                    r.one_byte_index_pages,
                    r.kd_nodes,
                    r.kd_refs,
                    fmt_bytes(r.file_bytes),
                    r.layout_ms,
                    r.write_ms
                );
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Pages { kind: PagesCommand::Fly { file, cold, cold_frames, cap, no_backface_cull, show } } => {
            use relief::format::pages::PageFile;
            use relief::pages::fetch::{FetchOptions, PageSource};
            let cold = cold || cold_frames;
            let cap_bytes = cap.as_deref().map(|c| parse_bytes("--cap", c)).transpose()?;
            show.check()?;
            let flight = show.path.as_deref().map(FlightPath::load).transpose()?;
            if flight.is_none() {
                check_display()?;
            }
            if cold {
                relief::pager::drop_from_page_cache(&file)?;
            }
            let pages = PageFile::open_with(&file, relief::pager::Access::Read)?;
            if cold {
                pages.advise_random()?;
            }
            let name = format!(
                "pages, {} layout, {} pages of {} B",
                pages.header().layout.name(),
                pages.header().pages,
                pages.header().page_bytes
            );
            let mut source = PageSource::new(
                pages,
                FetchOptions { backface_cull: !no_backface_cull, evict_each_frame: cold_frames },
            );
            let _cap = cap_bytes.map(relief::pager::MemoryCap::apply).transpose()?;
            show_mesh(&mut source, &file, &name, flight, show)
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
    let _ = ctrlc::set_handler(relief::sys::cancel::request);
    // A mapped file truncated under us: a one-line error, not a core dump.
    relief::sys::sigbus::install();
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
