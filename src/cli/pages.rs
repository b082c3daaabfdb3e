//! `relief pages`: the disk-page backend.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::bail;
use clap::builder::PossibleValuesParser;
use clap::Subcommand;
use relief::diskpages::build::{build_page_file, PageBuildOptions};
use relief::diskpages::fetch::{FetchOptions, PageSource};
use relief::format::pagefile::{PageFile, PageLayout};
use relief::format::{sniff, FileKind};
use relief::pager::{Access, MemoryCap};

use super::{check_output_file, fmt_bytes, parse_bytes, print_json, progress, AccessArgs, DeviceArgs, FlyArgs};

// One value, parsed once: the variants' size does not matter.
#[allow(clippy::large_enum_variant, reason = "parsed once per run")]
#[derive(Subcommand)]
pub enum Command {
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
        #[arg(long, value_parser = PossibleValuesParser::new(PageLayout::ALL.map(PageLayout::name)), default_value = "2factor")]
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
    /// leaves collected once each, culled by box and normal cone, sorted, read whole (with read
    /// access, one pread per run of consecutive pages) and all their triangles drawn. Reports
    /// pages requested, bytes read, seek distance (Σ |page − previous page|, in pages, from where
    /// the previous frame's reads ended), fetch and frame times in ms, triangles.
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
        access: AccessArgs,
        #[command(flatten)]
        device: DeviceArgs,
        #[command(flatten)]
        mesh: super::mesh::MeshViewArgs,
        #[command(flatten)]
        fly: FlyArgs,
    },
}

pub fn run(kind: Command) -> anyhow::Result<ExitCode> {
    match kind {
        Command::Build { input, output, page_size, layout, step, json, quiet } => {
            let page_bytes = parse_bytes("--page-size", &page_size)?;
            if step == 0 {
                bail!("--step must be at least 1");
            }
            check_output_file("", &output)?;
            let layout = PageLayout::from_name(&layout).expect("a possible value");
            let mut options = PageBuildOptions::new(page_bytes.min(u32::MAX as u64) as u32, layout);
            options.validate().map_err(|e| anyhow::anyhow!("--page-size: {e}"))?;
            let mesh = if sniff(&input)? == Some(FileKind::Terrain) {
                relief::mesh::terrain_mesh(&relief::format::terrain::TerrainFile::open(&input)?, step)?
            } else {
                relief::mesh::read_mesh(&input)?
            };
            options.progress = progress(quiet);
            let r = build_page_file(&mesh, &output, &options)?;
            if json {
                print_json(&r)?;
                return Ok(ExitCode::SUCCESS);
            }
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
            Ok(ExitCode::SUCCESS)
        }
        Command::Fly { file, cold, cold_frames, cap, no_backface_cull, access, device, mesh, fly } => {
            let device = device.spec()?;
            let cold = cold || cold_frames;
            let cap_bytes = cap.as_deref().map(|c| parse_bytes("--cap", c)).transpose()?;
            let flight = fly.check()?;
            // The paper's fetch reads pages with pread and leaves caching to the OS.
            let access = access.access(Access::Read, || {
                let h = PageFile::open(&file)?.header().clone();
                Ok(h.pages * h.page_bytes as u64)
            })?;
            let pages = PageFile::open_on(&file, access, device)?;
            if cold {
                pages.start_cold()?;
            }
            let mut source = PageSource::new(
                pages,
                FetchOptions { backface_cull: !no_backface_cull, evict_each_frame: cold_frames },
            );
            let _cap = cap_bytes.map(MemoryCap::apply).transpose()?;
            super::show::mesh(&mut source, &file, flight, mesh.up, mesh.tolerance, &fly)
        }
    }
}
