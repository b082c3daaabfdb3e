//! `relief export`: a terrain's mesh out to other tools (glTF, PLY, OBJ).

use std::path::PathBuf;
use std::process::ExitCode;

use relief::camera::Camera;
use relief::format::terrain::TerrainFile;
use relief::mesh::export::{write_export, ExportFormat, ExportFrame, TerrainExport};
use relief::refine::{Refiner, Strip};

use super::{check_output_file, parse_vec3, print_json, ImageArgs, RefineArgs};

#[derive(clap::Args)]
pub struct Args {
    pub file: PathBuf,
    /// Mesh to write: .glb or .gltf (glTF 2.0, y up: terrain z is glTF y), .ply (binary) or .obj;
    /// positions, normals and texture coordinates over the DEM (north up), replaced atomically.
    pub out: PathBuf,
    /// Export the mesh refined for this view: eye "X,Y,Z" in the terrain's metres (with --look,
    /// --tolerance, --width, --fov), as `relief render` would draw it.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, requires = "look", conflicts_with = "max_error")]
    pub eye: Option<String>,
    /// The point looked at "X,Y,Z" (with --eye).
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, requires = "eye")]
    pub look: Option<String>,
    /// Export the view-independent mesh whose every triangle holds the DEM's posts within M
    /// metres (vertically) of its plane (the way MARTINI meshes are made).
    #[arg(long, value_name = "M", allow_negative_numbers = true)]
    pub max_error: Option<f64>,
    /// Positions in the terrain's coordinate system (easting and northing, or longitude and
    /// latitude, and metres up) instead of local metres from the grid's south-west post.
    #[arg(long)]
    pub crs: bool,
    /// Texture the mesh with an image as `render --imagery` drapes it (PNG or JPEG with a world
    /// file, or spanning the DEM): texture coordinates follow the image, and glTF files embed it
    /// as the base colour (OBJ and PLY carry the coordinates only).
    #[arg(long, value_name = "IMAGE")]
    pub imagery: Option<PathBuf>,
    #[command(flatten)]
    pub image: ImageArgs,
    #[command(flatten)]
    pub refine: RefineArgs,
    /// Print what was written as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(serde::Serialize)]
struct Report {
    file: String,
    out: String,
    mode: &'static str,
    vertices: usize,
    triangles: usize,
    bytes: u64,
}

pub fn run(a: Args) -> anyhow::Result<ExitCode> {
    ExportFormat::of_path(&a.out)?;
    check_output_file("OUT", &a.out)?;
    let terrain = TerrainFile::open(&a.file)?;
    let frame = if a.crs { ExportFrame::Crs } else { ExportFrame::Local };
    let (mesh, mode) = match (&a.eye, &a.look, a.max_error) {
        (Some(eye), Some(look), None) => {
            let options = a.refine.options()?;
            let camera = Camera::new(
                parse_vec3("--eye", eye)?,
                parse_vec3("--look", look)?,
                glam::DVec3::Z,
                a.image.fov,
                a.image.width,
                a.image.height,
            )?;
            let mut strip = Strip::new();
            Refiner::new(a.refine.threads)?.refine_file(&terrain, &camera, &options, &mut strip)?;
            (TerrainExport::of_strip(&terrain, &strip, frame)?, "view")
        }
        (None, None, Some(m)) => (TerrainExport::within_error(&terrain, m, frame)?, "max-error"),
        _ => anyhow::bail!("say which mesh: --eye X,Y,Z --look X,Y,Z (refined for a view) or --max-error M"),
    };
    let mesh = match &a.imagery {
        Some(p) => {
            let img = relief::render::imagery::Imagery::open(p)?;
            let (uv, wraps) = img.uv_of_grid(terrain.header())?;
            let bytes = std::fs::read(p).map_err(|e| relief::Error::io(p, e))?;
            let mime = match image::guess_format(&bytes) {
                Ok(image::ImageFormat::Png) => "image/png",
                Ok(image::ImageFormat::Jpeg) => "image/jpeg",
                _ => anyhow::bail!("{}: glTF embeds PNG or JPEG images only", p.display()),
            };
            mesh.with_texture(relief::mesh::export::Texture { bytes, mime: mime.into(), wraps }, uv)
        }
        None => mesh,
    };
    let comment = format!("relief export of {}", a.file.display());
    write_export(&mesh, &a.out, &comment)?;
    let bytes = std::fs::metadata(&a.out).map(|m| m.len()).unwrap_or(0);
    let r = Report {
        file: a.file.display().to_string(),
        out: a.out.display().to_string(),
        mode,
        vertices: mesh.positions.len(),
        triangles: mesh.triangles.len(),
        bytes,
    };
    if a.json {
        print_json(&r)?;
    } else {
        println!("{}: {} vertices, {} triangles ({mode}), {} bytes", r.out, r.vertices, r.triangles, r.bytes);
    }
    Ok(ExitCode::SUCCESS)
}
