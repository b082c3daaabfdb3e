//! The command line's pieces: one module per command (`convert`, `fly`, …), the argument groups
//! several commands share, and the parsing of values the library takes in other units. Nothing
//! here computes what the library does; a command parses, checks its outputs can be written,
//! calls the library and prints.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::Args;
use glam::DVec3;
use relief::camera::{Camera, UpAxis};
use relief::dem::DemFormat;
use relief::flight::FlightPath;
use relief::format::terrain::TerrainFile;
use relief::layout::LayoutKind;
use relief::pager::Access;
use relief::refine::metric::MetricKind;
use relief::refine::RefineOptions;
use relief::sys::progress::Progress;

pub mod convert;
pub mod export;
pub mod fly;
pub mod imagery;
pub mod info;
pub mod layouts;
pub mod mesh;
pub mod pages;
pub mod path;
pub mod refine;
pub mod render;
pub mod serve;
pub mod show;
pub mod verify;

/// `--layout` values: the library's layout names, listed in `--help`.
pub fn layout_parser() -> impl TypedValueParser<Value = LayoutKind> {
    PossibleValuesParser::new(LayoutKind::ALL.map(LayoutKind::name))
        .map(|name| LayoutKind::from_name(&name).expect("a possible value"))
}

/// `--format` values: the library's DEM format names, listed in `--help`.
pub fn format_parser() -> impl TypedValueParser<Value = DemFormat> {
    PossibleValuesParser::new(DemFormat::ALL.map(DemFormat::name))
        .map(|name| DemFormat::from_name(&name).expect("a possible value"))
}

/// `--metric` values: the library's metric names.
pub fn metric_parser() -> impl TypedValueParser<Value = MetricKind> {
    PossibleValuesParser::new(MetricKind::ALL.map(MetricKind::name))
        .map(|name| MetricKind::from_name(&name).expect("a possible value"))
}

/// `--up` values.
pub fn up_parser() -> impl TypedValueParser<Value = UpAxis> {
    PossibleValuesParser::new(UpAxis::ALL.map(UpAxis::name))
        .map(|name| UpAxis::from_name(&name).expect("a possible value"))
}

/// How a file is read at run time (`--access`, `--memory` for the pool).
#[derive(Args, Clone)]
pub struct AccessArgs {
    /// How the file is read: map (the OS pages a memory map in), read (a positioned read of each
    /// block when it is wanted; only the OS caches) or pool (a buffer pool of --memory bytes with
    /// an I/O thread and prefetch) [default: map; read for page files].
    #[arg(long, value_parser = PossibleValuesParser::new(Access::NAMES))]
    pub access: Option<String>,
    /// The pool's memory: bytes with a binary K/M/G suffix (64M), or a fraction A/B of the file's
    /// data (1/4).
    #[arg(long, value_name = "BYTES|A/B", default_value = "1/4")]
    pub memory: String,
}

impl AccessArgs {
    /// The access asked for (`default` when none); a pool's fraction is of `data_bytes()`.
    pub fn access(&self, default: Access, data_bytes: impl FnOnce() -> relief::Result<u64>) -> anyhow::Result<Access> {
        Ok(match self.access.as_deref() {
            None => default,
            Some("map") => Access::Map,
            Some("read") => Access::Read,
            Some(_) => Access::Pool { bytes: parse_memory("--memory", &self.memory, data_bytes()?)? },
        })
    }
}

/// The image a view is refined or drawn for.
#[derive(Args, Clone, Copy)]
pub struct ImageArgs {
    /// Image width, pixels.
    #[arg(long, value_name = "W", default_value_t = 1920)]
    pub width: u32,
    /// Image height, pixels.
    #[arg(long, value_name = "H", default_value_t = 1080)]
    pub height: u32,
    /// Horizontal field of view, degrees.
    #[arg(long, value_name = "DEG", default_value_t = 60.0, allow_negative_numbers = true)]
    pub fov: f64,
}

/// How to refine a terrain.
#[derive(Args, Clone, Copy)]
pub struct RefineArgs {
    /// Screen-space error tolerance τ, pixels.
    #[arg(long, value_name = "PX", default_value_t = 1.0, allow_negative_numbers = true)]
    pub tolerance: f64,
    /// Screen-space error metric.
    #[arg(long, value_parser = metric_parser(), default_value = "isotropic")]
    pub metric: MetricKind,
    /// Do not cull to the view frustum (refine the whole terrain for the eye).
    #[arg(long)]
    pub no_cull: bool,
    /// Geomorphing: blend vertices in between the distances where their error projects to τ
    /// and to RATIO·τ (RATIO > 1).
    #[arg(long, value_name = "RATIO", allow_negative_numbers = true)]
    pub geomorph: Option<f64>,
    /// Refinement threads (1: no pool).
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub threads: usize,
}

impl RefineArgs {
    /// The validated refinement options.
    pub fn options(&self) -> anyhow::Result<RefineOptions> {
        check_tolerance(self.tolerance)?;
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
            heights: false,
            z_exaggeration: 1.0,
        })
    }
}

/// One view of a terrain and how to refine it (`refine`, `render`).
#[derive(Args)]
pub struct ViewArgs {
    /// Eye position "X,Y,Z", metres.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    pub eye: String,
    /// Point looked at "X,Y,Z", metres.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    pub look: String,
    /// Up direction "X,Y,Z".
    #[arg(long, value_name = "X,Y,Z", default_value = "0,0,1", allow_hyphen_values = true)]
    pub up: String,
    /// --eye and --look give X, Y in the terrain's coordinate system (easting and northing, or
    /// longitude and latitude, as `relief info` shows it) and Z in metres, instead of local
    /// metres from the grid's south-west post.
    #[arg(long)]
    pub crs_coords: bool,
    #[command(flatten)]
    pub image: ImageArgs,
    #[command(flatten)]
    pub refine: RefineArgs,
}

impl ViewArgs {
    /// The validated camera (in `terrain`'s local metres) and refinement options.
    pub fn resolve(&self, terrain: &TerrainFile) -> anyhow::Result<(Camera, RefineOptions)> {
        let options = self.refine.options()?;
        let (eye, look) = (parse_vec3("--eye", &self.eye)?, parse_vec3("--look", &self.look)?);
        let (eye, look) = if self.crs_coords {
            let local = crs_to_local(terrain)?;
            (local(eye), local(look))
        } else {
            (eye, look)
        };
        let camera =
            Camera::new(eye, look, parse_vec3("--up", &self.up)?, self.image.fov, self.image.width, self.image.height)?;
        Ok((camera, options))
    }
}

/// What `--crs-coords` does: X, Y in `terrain`'s CRS to local metres (Z unchanged); an error
/// naming the file when it has no CRS placement.
pub fn crs_to_local(terrain: &TerrainFile) -> anyhow::Result<impl Fn(DVec3) -> DVec3> {
    let h = terrain.header();
    let Some(g) = h.georef else {
        bail!(
            "--crs-coords: {} has no coordinate system (its source was not georeferenced); give local metres",
            terrain.path().display()
        );
    };
    let spacing_m = h.spacing_m;
    Ok(move |p: DVec3| {
        let [x, y] = g.local_of_crs([p.x, p.y], spacing_m);
        DVec3::new(x, y, p.z)
    })
}

/// GPU memory for a terrain's heights (`fly`, `render`).
#[derive(Args)]
pub struct GpuArgs {
    /// GPU memory for heights: bytes with a binary K/M/G suffix (256M). A grid that fits stays
    /// resident whole; a larger one is paged through a height cache of tiles within this budget
    /// (vertices keep their exact heights; shading may use a coarser tile until the fine one
    /// arrives) [default: 2G]
    #[arg(long, value_name = "BYTES")]
    pub gpu_memory: Option<String>,
    /// Height cache: tile bytes sent to the GPU per frame at most (K/M/G suffix) [default: 16M]
    #[arg(long, value_name = "BYTES")]
    pub gpu_upload: Option<String>,
    /// How to draw the DEM's nodata posts (kept by `convert` as a void mask; `info` counts them):
    /// not at all, like the padding around the DEM (void); shaded as calm water at the heights
    /// filled in for the level-of-detail hierarchy (sea-level); or as those filled heights (filled)
    #[arg(long, value_name = "STYLE", value_enum, default_value_t = relief::render::NodataStyle::Void)]
    pub nodata_as: relief::render::NodataStyle,
    /// Draw heights this many times as high (≥ 1; nothing in the file changes). Cameras and
    /// paths scale with the scene: --eye, --look and path heights are the terrain's metres, and
    /// the mesh is refined to stay within --tolerance in the exaggerated scene
    #[arg(long, value_name = "X", default_value_t = 1.0, allow_negative_numbers = true)]
    pub z_exaggeration: f64,
    /// Colour ramp: hypsometric tints (water below 0 m), viridis (perceptually uniform, lowest
    /// to highest point) or a plain grey hillshade
    #[arg(long, value_enum, default_value_t = relief::render::Ramp::Hypsometric)]
    pub ramp: relief::render::Ramp,
    /// Sun direction, degrees clockwise from north (315: the north-west of cartography)
    #[arg(long, value_name = "DEG", default_value_t = 315.0, allow_negative_numbers = true)]
    pub sun_azimuth: f64,
    /// Sun height above the horizon, degrees (0 to 90)
    #[arg(long, value_name = "DEG", default_value_t = 45.0, allow_negative_numbers = true)]
    pub sun_altitude: f64,
    /// Drape an image on the terrain: a north-up PNG or JPEG with a world file (.pgw/.jgw/.wld,
    /// in the terrain's CRS units; a world image wraps on a geographic terrain), or without one
    /// an image of exactly the DEM's extent; held whole on the GPU (down-sampled past the
    /// adapter's texture size). An image larger than that, or than memory: cut it once with
    /// `relief imagery IMAGE OUT.rimg` and drape OUT.rimg, which is paged (only the tiles the
    /// view wants are read and held, within --imagery-gpu-memory)
    #[arg(long, value_name = "IMAGE")]
    pub imagery: Option<std::path::PathBuf>,
    /// How much the hillshade lights the draped image: 0 the image as it is, 1 fully shaded
    #[arg(long, value_name = "0..1", default_value_t = 0.7, requires = "imagery", allow_negative_numbers = true)]
    pub imagery_shade: f32,
    /// Paged imagery (a tile file): GPU memory for its tiles, bytes with a K/M/G suffix; tiles
    /// are sent within --gpu-upload per frame as heights are [default: 256M]
    #[arg(long, value_name = "BYTES", requires = "imagery")]
    pub imagery_gpu_memory: Option<String>,
}

impl GpuArgs {
    pub fn options(&self) -> anyhow::Result<relief::render::RendererOptions> {
        let bytes = |flag: &str, s: &Option<String>| s.as_deref().map(|s| parse_bytes(flag, s)).transpose();
        let look = relief::render::Look {
            ramp: self.ramp,
            sun_azimuth_deg: self.sun_azimuth,
            sun_altitude_deg: self.sun_altitude,
            z_exaggeration: self.z_exaggeration,
        };
        look.validate().map_err(anyhow::Error::msg)?;
        if !(0.0..=1.0).contains(&self.imagery_shade) {
            anyhow::bail!("--imagery-shade must be 0 to 1 (got {})", self.imagery_shade);
        }
        let imagery = match &self.imagery {
            Some(p) => Some((std::sync::Arc::new(relief::render::imagery::Imagery::open(p)?), self.imagery_shade)),
            None => None,
        };
        Ok(relief::render::RendererOptions {
            gpu_memory: bytes("--gpu-memory", &self.gpu_memory)?,
            upload_per_frame: bytes("--gpu-upload", &self.gpu_upload)?,
            imagery_gpu_memory: bytes("--imagery-gpu-memory", &self.imagery_gpu_memory)?,
            nodata: self.nodata_as,
            look,
            imagery,
            ..Default::default()
        })
    }
}

/// An emulated storage device under the file read (see `relief::pager::device`).
#[derive(Args, Clone, Debug)]
pub struct DeviceArgs {
    /// Serve the file through an emulated device taking MS milliseconds a read request (a FUSE
    /// file system of relief's own; needs /dev/fuse and root). Every request the kernel sends is
    /// charged: page faults (map access), preads (read), the pool's loads; what the page cache
    /// holds costs nothing. Published figures: NVMe ~0.02, a cloud block volume ~1, a 7200 rpm
    /// disk ~8 (random 4 KiB), an object store's first byte ~30.
    #[arg(long, value_name = "MS", allow_negative_numbers = true)]
    pub device_latency: Option<f64>,
    /// Requests the emulated device serves at once (1: a disk's single arm; an SSD or an object
    /// store serve many).
    #[arg(long, value_name = "N", default_value_t = 1, requires = "device_latency")]
    pub device_queue_depth: u32,
    /// Cap the emulated device's transfer rate at MB/s (10⁶ bytes a second): a request of B bytes
    /// takes latency + B / rate.
    #[arg(long, value_name = "MB/s", requires = "device_latency")]
    pub device_mb_s: Option<f64>,
}

impl DeviceArgs {
    /// The device asked for, checked; `None` without --device-latency.
    pub fn spec(&self) -> anyhow::Result<Option<relief::pager::device::DeviceSpec>> {
        self.device_latency
            .map(|ms| relief::pager::device::DeviceSpec::new(ms, self.device_queue_depth, self.device_mb_s))
            .transpose()
            .map_err(|e| anyhow::anyhow!("--device-latency: {e}"))
    }
}

/// Flying in a window or headless along a path: what every `fly` and `view` command shares.
#[derive(Args)]
pub struct FlyArgs {
    /// Fly headless along this path (see `relief path`) instead of opening a window.
    #[arg(long, value_name = "PATH.json")]
    pub path: Option<PathBuf>,
    /// Headless: write each frame as DIR/frame_00000.png, ...
    #[arg(long, value_name = "DIR", requires = "path")]
    pub frames_out: Option<PathBuf>,
    /// Headless: write the per-frame figures and the summary as JSON ({"frames":[…],"summary":{…}}).
    #[arg(long, value_name = "OUT.json", requires = "path")]
    pub stats: Option<PathBuf>,
    /// Headless: print the per-frame figures and the summary as JSON on stdout.
    #[arg(long, requires = "path")]
    pub json: bool,
    /// Image or window width, pixels.
    #[arg(long, value_name = "W", default_value_t = 1280)]
    pub width: u32,
    /// Image or window height, pixels.
    #[arg(long, value_name = "H", default_value_t = 720)]
    pub height: u32,
    /// Horizontal field of view, degrees.
    #[arg(long, value_name = "DEG", default_value_t = 60.0, allow_negative_numbers = true)]
    pub fov: f64,
    /// Draw the triangles' edges.
    #[arg(long)]
    pub wireframe: bool,
    /// Directory for screenshots and recorded paths (window).
    #[arg(long, value_name = "DIR", default_value = ".")]
    pub output_dir: PathBuf,
    /// Window: start at this eye position "X,Y,Z" (with --look), world units.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, requires = "look", conflicts_with = "path")]
    pub eye: Option<String>,
    /// Window: start looking at this point "X,Y,Z" (with --eye).
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, requires = "eye")]
    pub look: Option<String>,
    /// Window: close after this many frames (scripted runs).
    #[arg(long, value_name = "N", conflicts_with = "path")]
    pub exit_after_frames: Option<u64>,
    /// Window: record the flight path from the first frame (R stops and saves it; closing the
    /// window saves it too).
    #[arg(long, conflicts_with = "path")]
    pub record: bool,
    /// Headless: update only, no rendering (times the refinement, adaptation or fetch alone).
    #[arg(long, requires = "path")]
    pub no_render: bool,
    /// Headless: start frames at least MS milliseconds apart, like a display (with --no-render,
    /// the time a renderer would take, during which prefetching goes on); not counted in frame_ms.
    #[arg(long, value_name = "MS", default_value_t = 0.0, requires = "path", allow_negative_numbers = true)]
    pub pace: f64,
    /// Headless: before frame 0, update the first view until it is complete (nothing it needs is
    /// missing, and an update changes nothing) for at most SECONDS, timed and reported apart from
    /// the frames ("converge" in the report: updates, ms, and what was left if time ran out), so
    /// the flight starts from the mesh a still camera would reach; the same before any frame that
    /// jumps (the eye moves more than half its distance to the look-at point, or the view turns
    /// more than 30°: "jumps"). `mesh fly` does this by default for 2 s; elsewhere (and with
    /// --no-converge) frame 0 is the first update.
    #[arg(long, value_name = "SECONDS", num_args = 0..=1, default_missing_value = "120", requires = "path")]
    pub converge: Option<f64>,
    /// Headless: do not converge the first view (nor jumps): frame 0 is the first update, as a
    /// window's is (for measuring how navigation catches up).
    #[arg(long, conflicts_with = "converge")]
    pub no_converge: bool,
    /// No progress bars.
    #[arg(long, short)]
    pub quiet: bool,
}

impl FlyArgs {
    /// Rejects numbers no flight can use and output paths that cannot be written, before
    /// anything is read; opens the path file.
    pub fn check(&self) -> anyhow::Result<Option<FlightPath>> {
        if self.width == 0 || self.height == 0 {
            bail!("--width and --height must be at least 1 pixel");
        }
        if !(self.pace >= 0.0 && self.pace.is_finite()) {
            bail!("--pace: expected milliseconds ≥ 0, got {}", self.pace);
        }
        if let Some(s) = self.converge {
            if !(s > 0.0 && s <= 86_400.0) {
                bail!("--converge: expected seconds in (0, 86400], got {s}");
            }
        }
        if !(self.fov > 0.0 && self.fov < 180.0) {
            bail!("--fov: expected degrees between 0 and 180, got {}", self.fov);
        }
        if let Some(s) = &self.stats {
            check_output_file("--stats", s)?;
        }
        let flight = match &self.path {
            Some(p) => Some(FlightPath::load(p)?),
            None => {
                relief::window::check_display()?;
                None
            }
        };
        if let Some(d) = &self.frames_out {
            // Made when the first frame is drawn; here only whether it can be.
            if d.exists() && !d.is_dir() {
                bail!("--frames-out: {} is not a directory", d.display());
            }
            if !d.exists() {
                check_output_file("--frames-out", d)?;
            }
        }
        Ok(flight)
    }

    /// A window's start from `--eye` and `--look`.
    pub fn start(&self) -> anyhow::Result<Option<(DVec3, DVec3)>> {
        Ok(match (&self.eye, &self.look) {
            (Some(e), Some(l)) => Some((parse_vec3("--eye", e)?, parse_vec3("--look", l)?)),
            _ => None,
        })
    }

    /// The window settings.
    pub fn window(&self) -> anyhow::Result<relief::window::WindowSettings> {
        Ok(relief::window::WindowSettings {
            width_px: self.width,
            height_px: self.height,
            fov_x_deg: self.fov,
            output_dir: self.output_dir.clone(),
            start: self.start()?,
            exit_after_frames: self.exit_after_frames,
            record: self.record,
        })
    }
}

pub fn check_tolerance(tolerance_px: f64) -> anyhow::Result<()> {
    if !(tolerance_px > 0.0 && tolerance_px.is_finite()) {
        bail!("--tolerance: expected a positive number of pixels, got {tolerance_px}");
    }
    Ok(())
}

/// Fails unless `path` can be created or replaced: its directory exists and is writable, and it
/// is not itself a directory. Run before the work, so a long job never ends on a typo. `flag`
/// names the option the path came from (empty for an operand).
pub fn check_output_file(flag: &str, path: &Path) -> anyhow::Result<()> {
    let what = if flag.is_empty() { path.display().to_string() } else { format!("{flag}: {}", path.display()) };
    if path.is_dir() {
        bail!("{what}: is a directory");
    }
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        bail!("{what}: the directory {} does not exist", dir.display());
    }
    // Writability as the output will be written: a temporary file beside it.
    tempfile::Builder::new()
        .prefix(".relief-check.")
        .tempfile_in(dir)
        .with_context(|| format!("{what}: cannot write in {}", dir.display()))?;
    Ok(())
}

pub fn parse_vec3(flag: &str, s: &str) -> anyhow::Result<DVec3> {
    let nums: Result<Vec<f64>, _> = s.split(',').map(|p| p.trim().parse::<f64>()).collect();
    match nums.ok().as_deref() {
        Some(&[x, y, z]) if x.is_finite() && y.is_finite() && z.is_finite() => Ok(DVec3::new(x, y, z)),
        _ => bail!("{flag}: expected three finite numbers X,Y,Z, got '{s}'"),
    }
}

/// Bytes with an optional binary K/M/G suffix ("4096", "64K", "1.5G").
pub fn parse_bytes(flag: &str, s: &str) -> anyhow::Result<u64> {
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

/// Bytes, or "A/B" of `data_bytes` (the input's data: a terrain's records, a mesh, a tree).
pub fn parse_memory(flag: &str, s: &str, data_bytes: u64) -> anyhow::Result<u64> {
    if let Some((a, b)) = s.split_once('/') {
        match (a.trim().parse::<f64>(), b.trim().parse::<f64>()) {
            (Ok(a), Ok(b)) if a > 0.0 && b > 0.0 && a.is_finite() && b.is_finite() => {
                return Ok((data_bytes as f64 * a / b) as u64)
            }
            _ => bail!("{flag}: expected bytes (64M) or a fraction of the input's data (1/16), got '{s}'"),
        }
    }
    parse_bytes(flag, s)
}

/// Progress bars on stderr where it is a terminal, unless `quiet`.
pub fn progress(quiet: bool) -> Progress {
    Progress::new(!quiet && std::io::stderr().is_terminal())
}

pub fn fmt_bytes(b: u64) -> String {
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

/// Prints `value` as pretty JSON on stdout.
pub fn print_json(value: &impl serde::Serialize) -> anyhow::Result<()> {
    println!("{}", serde_json::to_string_pretty(value)?);
    Ok(())
}
