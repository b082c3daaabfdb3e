//! `relief mesh`: triangle meshes for the mesh backends, and the meta-node backend.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::bail;
use clap::Subcommand;
use relief::camera::UpAxis;
use relief::flight::frame::StaticMesh;
use relief::format::metanode::MetaNodeFile;
use relief::format::terrain::TerrainFile;
use relief::metanode::blocking::BlockingOptions;
use relief::metanode::build::BuildOptions;
use relief::metanode::navigate::{NavOptions, Navigator, PagedStore, Prefetch};
use relief::metanode::source::NavSource;
use relief::metanode::VdtMetric;
use relief::pager::{Access, MemoryCap};

use super::{
    check_output_file, fmt_bytes, parse_bytes, parse_memory, print_json, progress, up_parser, DeviceArgs, FlyArgs,
};

// One value, parsed once: the variants' size does not matter.
#[allow(clippy::large_enum_variant, reason = "parsed once per run")]
#[derive(Subcommand)]
pub enum Command {
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
        mesh: MeshViewArgs,
        #[command(flatten)]
        fly: FlyArgs,
    },
    /// Fly over a meta-node file (from `relief mesh build`) with view-dependent refinement: in a
    /// window, or headless along a path (`relief path orbit FILE`).
    ///
    /// Each frame the active nodes are split or collapsed against their switch values at the
    /// screen-space tolerance (--tolerance, pixels), respecting the implicit dependencies. With
    /// pool access (ext) meta-nodes come through a buffer pool of --memory bytes with an I/O
    /// thread (a switch whose meta-node is not in memory is a miss: put off, and an urgent
    /// prefetch sent); with map access (virt) straight from the memory-mapped file (the OS pages
    /// it in, the navigation waits); with read access by a positioned read whenever needed.
    /// Per frame: splits + collapses, triangles, misses (% of wanted switches), pages read,
    /// update/render/frame ms.
    Fly {
        /// Meta-node file.
        file: PathBuf,
        /// ext: the buffer pool (--access pool); virt: the memory map (--access map).
        #[arg(long, value_enum, conflicts_with = "access")]
        mode: Option<NavMode>,
        /// How meta-nodes are read: map (virt), read, or pool (ext) [default: pool].
        #[arg(long, value_parser = clap::builder::PossibleValuesParser::new(Access::NAMES))]
        access: Option<String>,
        /// The buffer pool's memory, BYTES (K/M/G suffixes) or a fraction A/B of the tree on disk
        /// (DATA + MNT), e.g. 1/4.
        #[arg(long, value_name = "BYTES|A/B", default_value = "1/4")]
        memory: String,
        /// Limit what the flight allocates and pages in after start-up to BYTES (a cgroup v1
        /// memory limit, any access), so a tree larger than that cannot stay in memory.
        #[arg(long, value_name = "BYTES")]
        cap: Option<String>,
        /// Evict the file from the page cache first and turn off readahead (a cold start).
        #[arg(long)]
        cold: bool,
        /// With --cold: leave the OS's readahead on (a map's fault or a read then brings in the
        /// pages after it too, as the kernel's readahead window allows).
        #[arg(long, requires = "cold")]
        readahead: bool,
        /// Pool: which meta-nodes to prefetch. paper: the parent and all children of every
        /// meta-node in use (El-Sana & Chiang); parent: only the parent; frontier: for every
        /// active node, the blocks its split or its parent's collapse would read.
        #[arg(long, value_enum, default_value = "frontier")]
        prefetch: PrefetchArg,
        /// Pool: I/O threads, each with one read in flight. Match the storage's queue depth (a
        /// disk 1, an SSD or an object store several; with --device-latency, its
        /// --device-queue-depth).
        #[arg(long, value_name = "N", default_value_t = 1)]
        io_threads: usize,
        /// Pool: one read may take the meta-nodes queued beside the one asked for, consecutive in
        /// the file, up to BYTES in all (K/M suffixes; 0: one meta-node a read). A meta-node's
        /// children lie side by side, so on a device where a request costs far more than its
        /// bytes this brings in a switch's whole neighbourhood for one latency.
        #[arg(long, value_name = "BYTES", default_value = "0")]
        coalesce: String,
        #[command(flatten)]
        device: DeviceArgs,
        #[command(flatten)]
        mesh: MeshViewArgs,
        #[command(flatten)]
        fly: FlyArgs,
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
        /// triangle). When it holds the whole build in memory (about 7-9 times the mesh's
        /// size; the report's peak_accounted_bytes) there is no scratch store and one pass;
        /// below that it covers the redb page cache (1/8 of it), the scratch buffers and the
        /// loaded sub-meshes, batch after batch. Either way the output is the same, byte for
        /// byte; reading the input beforehand holds the whole mesh regardless.
        #[arg(long, value_name = "BYTES")]
        memory: String,
        /// Build in batches through the scratch B-tree even when the budget holds the whole
        /// mesh (the same bytes, slower: for measurements).
        #[arg(long)]
        batched: bool,
        /// Collapse metric: edge length, or the square root of the Garland–Heckbert quadric
        /// error (both in mesh units).
        #[arg(long, value_enum, default_value = "length")]
        metric: VdtMetricArg,
        /// Levels of the binary forest per meta-node (for the meta-node step), 1 to 16.
        #[arg(long, value_name = "L", default_value_t = 8)]
        levels_per_node: u32,
        /// Disk page size of the meta-node file, BYTES: a power of two from 512 to 1M (K/M
        /// suffixes allowed).
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

/// What showing a mesh takes besides flying.
#[derive(clap::Args)]
pub struct MeshViewArgs {
    /// Screen-space error tolerance τ handed to the simplification, pixels.
    #[arg(long, value_name = "PX", default_value_t = 1.0, allow_negative_numbers = true)]
    pub tolerance: f64,
    /// The mesh's up axis (sky, sun, the window's horizon) [default: as for `relief path`].
    #[arg(long, value_parser = up_parser())]
    pub up: Option<UpAxis>,
}

/// `--mode` of `relief mesh fly`.
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum NavMode {
    Ext,
    Virt,
}

/// `--metric` of `relief mesh build`.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum VdtMetricArg {
    Length,
    Quadric,
}

/// `--prefetch` of `relief mesh fly`.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum PrefetchArg {
    Paper,
    Parent,
    Frontier,
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

pub fn run(kind: Command) -> anyhow::Result<ExitCode> {
    match kind {
        Command::View { input, mesh, fly } => {
            // The path first: a bad path file fails before a large mesh is read.
            let flight = fly.check()?;
            let m = relief::mesh::read_mesh(&input)?;
            let mut source = StaticMesh::new(&m)?;
            super::show::mesh(&mut source, &input, flight, mesh.up, mesh.tolerance, &fly)
        }
        Command::Fly {
            file,
            mode,
            access,
            memory,
            cap,
            cold,
            readahead,
            prefetch,
            io_threads,
            coalesce,
            device,
            mesh,
            fly,
        } => {
            let device = device.spec()?;
            if !(1..=256).contains(&io_threads) {
                bail!("--io-threads: expected 1 to 256 I/O threads, got {io_threads}");
            }
            let io =
                relief::pager::PoolIo { threads: io_threads, coalesce_bytes: parse_bytes("--coalesce", &coalesce)? };
            // Map or read access; `None`: the pool, sized once the tree's size is known.
            let unpooled = match (mode, access.as_deref()) {
                (Some(NavMode::Virt), _) | (None, Some("map")) => Some(Access::Map),
                (None, Some("read")) => Some(Access::Read),
                _ => None,
            };
            if unpooled.is_some() && io != relief::pager::PoolIo::default() {
                bail!("--io-threads and --coalesce apply to pool access (--mode ext or --access pool) only");
            }
            let flight = fly.check()?;
            let cap_bytes = cap.as_deref().map(|c| parse_bytes("--cap", c)).transpose()?;
            let access = match unpooled {
                Some(access) => access,
                None => {
                    let tree = MetaNodeFile::open(&file)?.tree_bytes();
                    Access::Pool { bytes: parse_memory("--memory", &memory, tree)? }
                }
            };
            let meta = MetaNodeFile::open_io(&file, access, device, io)?;
            if cold && readahead {
                meta.pager().evict()?;
            } else if cold {
                meta.start_cold()?;
            }
            let prefetch = match prefetch {
                PrefetchArg::Paper => Prefetch::Paper,
                PrefetchArg::Parent => Prefetch::Parent,
                PrefetchArg::Frontier => Prefetch::Frontier,
            };
            let nav = Navigator::new(&meta, PagedStore::new(&meta), NavOptions { prefetch, ..NavOptions::default() })?;
            // The cap covers what the flight does, not start-up (cgroup v1 keeps earlier charges
            // where they were).
            let _cap = cap_bytes.map(MemoryCap::apply).transpose()?;
            let mut source = NavSource::new(nav);
            super::show::mesh(&mut source, &file, flight, mesh.up, mesh.tolerance, &fly)
        }
        Command::Info { file, json } => {
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
                print_json(&info)?;
                return Ok(ExitCode::SUCCESS);
            }
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
            Ok(ExitCode::SUCCESS)
        }
        Command::Build { input, output, vdt, memory, batched, metric, levels_per_node, page_size, json, quiet } => {
            let page_bytes = parse_bytes("--page-size", &page_size)?;
            let blocking = BlockingOptions { levels_per_node, page_bytes: page_bytes.min(u32::MAX as u64) as u32 };
            blocking.validate().map_err(|e| anyhow::anyhow!("--levels-per-node / --page-size: {e}"))?;
            check_output_file("", &output)?;
            if let Some(v) = &vdt {
                check_output_file("--vdt", v)?;
            }
            // The budget may be a fraction of the mesh, so the mesh is read first (the build
            // measures its memory after ingest either way).
            let start = std::time::Instant::now();
            let m = relief::mesh::read_mesh(&input)?;
            let mesh_bytes = m.positions.len() as u64 * 24 + m.triangles.len() as u64 * 12;
            let memory_bytes = parse_memory("--memory", &memory, mesh_bytes)?;
            if memory_bytes == 0 {
                bail!("--memory must be more than 0 bytes");
            }
            // A small mesh's fraction can fall below what any build needs: raise it, and say so.
            let least = relief::metanode::build::least_budget_bytes();
            let memory_bytes = if memory_bytes < least {
                eprintln!(
                    "relief: warning: --memory {memory} is {memory_bytes} bytes, below the least a build needs; \
                     building in {least} bytes ({})",
                    fmt_bytes(least)
                );
                least
            } else {
                memory_bytes
            };
            let metric = match metric {
                VdtMetricArg::Length => VdtMetric::Length,
                VdtMetricArg::Quadric => VdtMetric::Quadric,
            };
            let mut options = BuildOptions::new(memory_bytes, metric);
            options.progress = progress(quiet);
            options.always_batched = batched;
            let read_ms = start.elapsed().as_secs_f64() * 1e3;
            let mut r = relief::metanode::build_tree(m, &output, vdt.as_deref(), &options, blocking)?;
            // Ingest as the user waits for it: reading the file too.
            r.vdt.ingest_ms += read_ms;
            if json {
                print_json(&r)?;
                return Ok(ExitCode::SUCCESS);
            }
            let (meta, report) = (&r.metanode, &r.vdt);
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
            Ok(ExitCode::SUCCESS)
        }
        Command::FromTerrain { terrain, output, step } => {
            if step == 0 {
                bail!("--step must be at least 1");
            }
            check_output_file("", &output)?;
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
    }
}
