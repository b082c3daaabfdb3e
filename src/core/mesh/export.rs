//! Terrain meshes out to other tools (`relief export`): the strip refined for a view, or the mesh
//! within a world-space error of the full grid, as triangles with positions, normals and texture
//! coordinates, written as OBJ, PLY or glTF (`.gltf`, `.glb`; written with `gltf-json`).
//!
//! The view-independent mesh follows the way MARTINI is used (Mapbox's RTIN meshes), on the
//! longest-edge bisection of Lindstrom & Pascucci (*Visualization of Large Terrains Made Easy*,
//! 2001): each vertex gets the largest vertical distance of a DEM post in its diamond's two
//! triangles from their planes, nested over its DAG descendants, and a triangle is split while its
//! split vertex's nested distance exceeds the error asked for. Nesting makes the mesh conforming
//! (a vertex is inserted only with both its parents), and every unsplit triangle holds its posts
//! within the error.

use std::path::Path;

use glam::DVec3;

use crate::error::{Error, Result};
use crate::format::terrain::TerrainFile;
use crate::refine::Strip;

/// A mesh of grid posts ready to write: per vertex its post, position, unit normal and texture
/// coordinate; triangles counter-clockwise seen from above (+z).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TerrainExport {
    pub posts: Vec<[u32; 2]>,
    pub positions: Vec<[f64; 3]>,
    pub normals: Vec<[f32; 3]>,
    /// `(u, v)` over the DEM's valid window: u east from its west edge, v south from its north
    /// edge (an image of the DEM, north up, maps onto it as is).
    pub uv: Vec<[f32; 2]>,
    pub triangles: Vec<[u32; 3]>,
    /// An image the texture coordinates map (written into glTF files as the base colour).
    pub texture: Option<Texture>,
}

/// An encoded image (PNG or JPEG bytes, as the file had them) for a mesh's base colour.
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    pub bytes: Vec<u8>,
    /// `image/png` or `image/jpeg`.
    pub mime: String,
    /// Whether u repeats (a world image on a geographic terrain).
    pub wraps: bool,
}

/// Coordinates the positions are given in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ExportFrame {
    /// Local metres from the grid's south-west post (x east, y north, z up), as relief refines.
    #[default]
    Local,
    /// x, y in the terrain's CRS (easting and northing, or longitude and latitude), z metres.
    Crs,
}

/// The DEM's heights, row-major from the south, read once from the records.
struct Heights {
    z: Vec<f32>,
    w: u32,
    h: u32,
}

impl Heights {
    fn read(terrain: &TerrainFile) -> Result<Heights> {
        let hd = terrain.header();
        let [_, _, w, h] = hd.valid_window;
        let mut z = Vec::with_capacity(w as usize * h as usize);
        let posts = (0..h).flat_map(|y| (0..w).map(move |x| (x, y)));
        crate::heightcache::read_heights(terrain, posts, |v| z.push(v))?;
        Ok(Heights { z, w, h })
    }

    /// The height at post `(x, y)`, beyond the DEM its nearest edge post's.
    #[inline]
    fn at(&self, x: i64, y: i64) -> f64 {
        let x = x.clamp(0, self.w as i64 - 1) as usize;
        let y = y.clamp(0, self.h as i64 - 1) as usize;
        self.z[y * self.w as usize + x] as f64
    }
}

/// Whether triangle `t` (grid posts) overlaps the rectangle `[0, w − 1] × [0, h − 1]` with
/// positive area (separating axes: the rectangle's two and the triangle's three edges).
fn overlaps_data(t: [[u32; 2]; 3], w: u32, h: u32) -> bool {
    let p = t.map(|[x, y]| [x as f64, y as f64]);
    let (mx, my) = ((w - 1) as f64, (h - 1) as f64);
    if p.iter().all(|q| q[0] >= mx) || p.iter().all(|q| q[1] >= my) {
        return false;
    }
    let corners = [[0.0, 0.0], [mx, 0.0], [mx, my], [0.0, my]];
    for k in 0..3 {
        let (a, b, c) = (p[k], p[(k + 1) % 3], p[(k + 2) % 3]);
        let side = |q: [f64; 2]| (b[0] - a[0]) * (q[1] - a[1]) - (b[1] - a[1]) * (q[0] - a[0]);
        let inner = side(c).signum();
        if corners.iter().all(|&q| side(q) * inner <= 0.0) {
            return false;
        }
    }
    true
}

impl TerrainExport {
    /// The mesh of `triangles` (grid posts), dropping those that do not overlap the DEM's valid
    /// window (padding), in `frame`.
    pub fn of_triangles(
        terrain: &TerrainFile,
        triangles: &[[[u32; 2]; 3]],
        frame: ExportFrame,
    ) -> Result<TerrainExport> {
        let hd = terrain.header();
        let [_, _, w, h] = hd.valid_window;
        let georef = match (frame, hd.georef) {
            (ExportFrame::Crs, None) => {
                return Err(Error::InvalidArgument(format!(
                    "{}: --crs needs a coordinate system, and its source was not georeferenced",
                    terrain.path().display()
                )))
            }
            (ExportFrame::Crs, Some(g)) => Some(g),
            (ExportFrame::Local, _) => None,
        };
        let heights = Heights::read(terrain)?;
        let mut out = TerrainExport::default();
        let mut index: std::collections::HashMap<[u32; 2], u32> = std::collections::HashMap::new();
        let [sx, sy] = hd.spacing_m;
        for t in triangles {
            if !overlaps_data(*t, w, h) {
                continue;
            }
            // Counter-clockwise from above.
            let cross = (t[1][0] as i64 - t[0][0] as i64) * (t[2][1] as i64 - t[0][1] as i64)
                - (t[1][1] as i64 - t[0][1] as i64) * (t[2][0] as i64 - t[0][0] as i64);
            if cross == 0 {
                continue;
            }
            let t = if cross > 0 { *t } else { [t[0], t[2], t[1]] };
            let mut tri = [0u32; 3];
            for (k, &[x, y]) in t.iter().enumerate() {
                tri[k] = *index.entry([x, y]).or_insert_with(|| {
                    let z = heights.at(x as i64, y as i64);
                    let (xi, yi) = (x as i64, y as i64);
                    // Central differences (one-sided at the DEM's edge), as the shader's normals.
                    let (x0, x1) = ((xi - 1).max(0), (xi + 1).min(w as i64 - 1).max(xi.min(w as i64 - 1)));
                    let (y0, y1) = ((yi - 1).max(0), (yi + 1).min(h as i64 - 1).max(yi.min(h as i64 - 1)));
                    let dx =
                        if x1 > x0 { (heights.at(x1, yi) - heights.at(x0, yi)) / ((x1 - x0) as f64 * sx) } else { 0.0 };
                    let dy =
                        if y1 > y0 { (heights.at(xi, y1) - heights.at(xi, y0)) / ((y1 - y0) as f64 * sy) } else { 0.0 };
                    let n = DVec3::new(-dx, -dy, 1.0).normalize();
                    let position = match georef {
                        Some(g) => {
                            let [cx, cy] = g.crs_of_post([x as f64, y as f64]);
                            [cx, cy, z]
                        }
                        None => [x as f64 * sx, y as f64 * sy, z],
                    };
                    out.posts.push([x, y]);
                    out.positions.push(position);
                    out.normals.push([n.x as f32, n.y as f32, n.z as f32]);
                    let u = x as f64 / (w.max(2) - 1) as f64;
                    let v = 1.0 - y as f64 / (h.max(2) - 1) as f64;
                    out.uv.push([u as f32, v as f32]);
                    (out.posts.len() - 1) as u32
                });
            }
            out.triangles.push(tri);
        }
        Ok(out)
    }

    /// Textures the mesh with `texture`, placed on the grid by `u = a0 + a1·x`, `v = b0 + b1·y`
    /// (`uv_of_grid = [a0, a1, b0, b1]`, v down the image): the texture coordinates follow it.
    pub fn with_texture(mut self, texture: Texture, uv_of_grid: [f32; 4]) -> TerrainExport {
        let [a0, a1, b0, b1] = uv_of_grid.map(|v| v as f64);
        for (uv, [x, y]) in self.uv.iter_mut().zip(&self.posts) {
            *uv = [(a0 + a1 * *x as f64) as f32, (b0 + b1 * *y as f64) as f32];
        }
        self.texture = Some(texture);
        self
    }

    /// The non-degenerate triangles of a refined strip (those over the DEM).
    pub fn of_strip(terrain: &TerrainFile, strip: &Strip, frame: ExportFrame) -> Result<TerrainExport> {
        let tris: Vec<[[u32; 2]; 3]> = strip.triangles().map(|t| t.map(|v| [v.x, v.y])).collect();
        TerrainExport::of_triangles(terrain, &tris, frame)
    }

    /// The view-independent mesh whose every triangle holds the DEM's posts within `max_error_m`
    /// metres (vertically) of its plane (see the module's note).
    pub fn within_error(terrain: &TerrainFile, max_error_m: f64, frame: ExportFrame) -> Result<TerrainExport> {
        if !(max_error_m.is_finite() && max_error_m >= 0.0) {
            return Err(Error::OutOfRange {
                what: "--max-error",
                allowed: "metres ≥ 0".into(),
                got: max_error_m.to_string(),
            });
        }
        let tris = error_mesh(terrain, max_error_m)?;
        TerrainExport::of_triangles(terrain, &tris, frame)
    }
}

/// The largest vertical distance of a DEM post (of `heights`) inside triangle `t` (inclusive)
/// from the plane through its corners' heights.
fn deviation(heights: &Heights, t: [[i64; 2]; 3]) -> f64 {
    let [a, b, c] = t;
    let det = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    if det == 0 {
        return 0.0;
    }
    let (za, zb, zc) = (heights.at(a[0], a[1]), heights.at(b[0], b[1]), heights.at(c[0], c[1]));
    let x0 = t.iter().map(|p| p[0]).min().unwrap_or(0).max(0);
    let x1 = t.iter().map(|p| p[0]).max().unwrap_or(0).min(heights.w as i64 - 1);
    let y0 = t.iter().map(|p| p[1]).min().unwrap_or(0).max(0);
    let y1 = t.iter().map(|p| p[1]).max().unwrap_or(0).min(heights.h as i64 - 1);
    let mut worst = 0f64;
    for y in y0..=y1 {
        for x in x0..=x1 {
            // Barycentric coordinates × det (exact in integers).
            let wb = (x - a[0]) * (c[1] - a[1]) - (y - a[1]) * (c[0] - a[0]);
            let wc = (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0]);
            let wa = det - wb - wc;
            let inside = if det > 0 { wa >= 0 && wb >= 0 && wc >= 0 } else { wa <= 0 && wb <= 0 && wc <= 0 };
            if inside {
                let plane = (wa as f64 * za + wb as f64 * zb + wc as f64 * zc) / det as f64;
                worst = worst.max((heights.at(x, y) - plane).abs());
            }
        }
    }
    worst
}

/// Whether the hypotenuse `l`–`r` has a grid post at its midpoint (the triangle can be split).
fn has_midpoint(l: [i64; 2], r: [i64; 2]) -> bool {
    l != r && (l[0] - r[0]) % 2 == 0 && (l[1] - r[1]) % 2 == 0
}

/// The triangles (grid posts) of the mesh within `max_error_m` of the DEM.
fn error_mesh(terrain: &TerrainFile, max_error_m: f64) -> Result<Vec<[[u32; 2]; 3]>> {
    let grid = terrain.grid();
    let heights = Heights::read(terrain)?;
    let side = grid.size() as usize;
    if side.checked_mul(side).is_none_or(|n| n > 1 << 31) {
        return Err(Error::InvalidArgument(format!(
            "{}: a {side}² grid is too large for --max-error here; export a view instead",
            terrain.path().display()
        )));
    }
    // Own distances per vertex: each bisection triangle's posts against its plane, charged to the
    // triangle's split vertex (the midpoint of its hypotenuse).
    let mut own = vec![0f32; side * side];
    let m = grid.max_coord() as i64;
    let c = m / 2;
    let roots: [[[i64; 2]; 3]; 4] =
        [[[0, 0], [c, c], [m, 0]], [[m, 0], [c, c], [m, m]], [[m, m], [c, c], [0, m]], [[0, m], [c, c], [0, 0]]];
    // (left end of the hypotenuse, apex, right end).
    let mut stack: Vec<[[i64; 2]; 3]> = roots.to_vec();
    while let Some([l, a, r]) = stack.pop() {
        let mid = [(l[0] + r[0]) / 2, (l[1] + r[1]) / 2];
        if !has_midpoint(l, r) {
            continue; // no post inside
        }
        let d = deviation(&heights, [l, a, r]) as f32;
        let k = mid[1] as usize * side + mid[0] as usize;
        own[k] = own[k].max(d);
        stack.push([a, mid, l]);
        stack.push([r, mid, a]);
    }
    // Nested over the DAG descendants, finest level first.
    let mut nested = own;
    for level in 1..=grid.levels() {
        let step = 1u32 << ((level - 1) / 2);
        for y in (0..=m as u32).step_by(step as usize) {
            for x in (0..=m as u32).step_by(step as usize) {
                if grid.level(x, y) != level {
                    continue;
                }
                let (children, count) = grid.dag_children(x, y);
                let k = y as usize * side + x as usize;
                for &(cx, cy) in &children[..count] {
                    nested[k] = nested[k].max(nested[cy as usize * side + cx as usize]);
                }
            }
        }
    }
    // Top down: split while the split vertex's nested distance exceeds the error.
    let mut out = Vec::new();
    let mut stack: Vec<[[i64; 2]; 3]> = roots.to_vec();
    while let Some([l, a, r]) = stack.pop() {
        let mid = [(l[0] + r[0]) / 2, (l[1] + r[1]) / 2];
        let split = has_midpoint(l, r) && nested[mid[1] as usize * side + mid[0] as usize] as f64 > max_error_m;
        if split {
            stack.push([a, mid, l]);
            stack.push([r, mid, a]);
        } else {
            out.push([l, a, r].map(|p| [p[0] as u32, p[1] as u32]));
        }
    }
    Ok(out)
}

/// Output formats, by file extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportFormat {
    Obj,
    Ply,
    Gltf,
    Glb,
}

impl ExportFormat {
    /// The format of `path` by its extension.
    pub fn of_path(path: &Path) -> Result<ExportFormat> {
        let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
        Ok(match ext.as_deref() {
            Some("obj") => ExportFormat::Obj,
            Some("ply") => ExportFormat::Ply,
            Some("gltf") => ExportFormat::Gltf,
            Some("glb") => ExportFormat::Glb,
            _ => {
                return Err(Error::InvalidArgument(format!(
                    "{}: unknown mesh format (give OUT a .glb, .gltf, .ply or .obj extension)",
                    path.display()
                )))
            }
        })
    }
}

/// The mesh as OBJ text: `v`, `vt`, `vn` per vertex and `f a/a/a b/b/b c/c/c`.
pub fn obj_bytes(mesh: &TerrainExport, comment: &str) -> Vec<u8> {
    use std::fmt::Write;
    let mut s = String::with_capacity(64 * mesh.positions.len() + 32 * mesh.triangles.len());
    let _ = writeln!(s, "# {comment}");
    for p in &mesh.positions {
        let _ = writeln!(s, "v {} {} {}", p[0], p[1], p[2]);
    }
    for t in &mesh.uv {
        let _ = writeln!(s, "vt {} {}", t[0], t[1]);
    }
    for n in &mesh.normals {
        let _ = writeln!(s, "vn {} {} {}", n[0], n[1], n[2]);
    }
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| i + 1);
        let _ = writeln!(s, "f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}");
    }
    s.into_bytes()
}

/// The mesh as binary little-endian PLY: `double` x, y, z, `float` nx, ny, nz, s, t, and
/// `uchar`-counted `uint` faces.
pub fn ply_bytes(mesh: &TerrainExport, comment: &str) -> Vec<u8> {
    let mut b = format!(
        "ply\nformat binary_little_endian 1.0\ncomment {comment}\nelement vertex {}\nproperty double x\n\
         property double y\nproperty double z\nproperty float nx\nproperty float ny\nproperty float nz\n\
         property float s\nproperty float t\nelement face {}\nproperty list uchar uint vertex_indices\nend_header\n",
        mesh.positions.len(),
        mesh.triangles.len()
    )
    .into_bytes();
    for k in 0..mesh.positions.len() {
        for v in mesh.positions[k] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        for v in mesh.normals[k].iter().chain(&mesh.uv[k]) {
            b.extend_from_slice(&v.to_le_bytes());
        }
    }
    for t in &mesh.triangles {
        b.push(3);
        for i in t {
            b.extend_from_slice(&i.to_le_bytes());
        }
    }
    b
}

/// The mesh as glTF 2.0: a JSON document (`glb`: false, the buffer embedded as a base64 data
/// URI) or a binary `.glb`. glTF is y-up: terrain (x, y, z) is written as (x, z, −y). Positions
/// are f32 relative to the mesh's centre, which the node's translation restores (f32 keeps
/// millimetres over kilometres that way, not over the terrain's CRS coordinates).
pub fn gltf_bytes(mesh: &TerrainExport, glb: bool, generator: &str) -> Result<Vec<u8>> {
    use gltf_json as json;
    use json::validation::{Checked::Valid, USize64};
    let n = mesh.positions.len();
    let to_gltf = |p: [f64; 3]| [p[0], p[2], -p[1]];
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for p in &mesh.positions {
        let q = to_gltf(*p);
        for k in 0..3 {
            lo[k] = lo[k].min(q[k]);
            hi[k] = hi[k].max(q[k]);
        }
    }
    let centre: [f64; 3] = std::array::from_fn(|k| if n == 0 { 0.0 } else { 0.5 * (lo[k] + hi[k]) });
    // One buffer: positions, normals, texture coordinates, indices (each 4-byte aligned).
    let mut bin: Vec<u8> = Vec::with_capacity(n * 32 + mesh.triangles.len() * 12);
    let (mut pmin, mut pmax) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for p in &mesh.positions {
        let q = to_gltf(*p);
        for k in 0..3 {
            let v = (q[k] - centre[k]) as f32;
            pmin[k] = pmin[k].min(v);
            pmax[k] = pmax[k].max(v);
            bin.extend_from_slice(&v.to_le_bytes());
        }
    }
    let normals_at = bin.len();
    for nrm in &mesh.normals {
        for v in [nrm[0], nrm[2], -nrm[1]] {
            bin.extend_from_slice(&v.to_le_bytes());
        }
    }
    let uv_at = bin.len();
    for t in &mesh.uv {
        // glTF's texture origin is the image's top-left, as `uv`'s is.
        for v in t {
            bin.extend_from_slice(&v.to_le_bytes());
        }
    }
    let index_at = bin.len();
    for t in &mesh.triangles {
        for i in t {
            bin.extend_from_slice(&i.to_le_bytes());
        }
    }
    let image_at = bin.len();
    if let Some(t) = &mesh.texture {
        bin.extend_from_slice(&t.bytes);
    }
    let mut root = json::Root {
        asset: json::Asset { generator: Some(generator.into()), ..Default::default() },
        ..Default::default()
    };
    let uri = (!glb).then(|| {
        use base64::Engine;
        format!("data:application/octet-stream;base64,{}", base64::engine::general_purpose::STANDARD.encode(&bin))
    });
    let buffer = root.push(json::Buffer {
        byte_length: USize64(bin.len() as u64),
        uri,
        extensions: None,
        extras: Default::default(),
    });
    let view = |offset: usize, len: usize, target: json::buffer::Target| json::buffer::View {
        buffer,
        byte_length: USize64(len as u64),
        byte_offset: Some(USize64(offset as u64)),
        byte_stride: None,
        target: Some(Valid(target)),
        extensions: None,
        extras: Default::default(),
    };
    use json::buffer::Target::{ArrayBuffer, ElementArrayBuffer};
    let views = [
        view(0, normals_at, ArrayBuffer),
        view(normals_at, uv_at - normals_at, ArrayBuffer),
        view(uv_at, index_at - uv_at, ArrayBuffer),
        view(index_at, image_at - index_at, ElementArrayBuffer),
    ];
    let views: Vec<_> = views.into_iter().map(|v| root.push(v)).collect();
    let material = mesh.texture.as_ref().map(|t| {
        let image_view = root.push(json::buffer::View { target: None, ..view(image_at, t.bytes.len(), ArrayBuffer) });
        let image = root.push(json::Image {
            buffer_view: Some(image_view),
            mime_type: Some(json::image::MimeType(t.mime.clone())),
            uri: None,
            extensions: None,
            extras: Default::default(),
        });
        use json::texture::{MagFilter, MinFilter, WrappingMode};
        let wrap_s = if t.wraps { WrappingMode::Repeat } else { WrappingMode::ClampToEdge };
        let sampler = root.push(json::texture::Sampler {
            mag_filter: Some(Valid(MagFilter::Linear)),
            min_filter: Some(Valid(MinFilter::LinearMipmapLinear)),
            wrap_s: Valid(wrap_s),
            wrap_t: Valid(WrappingMode::ClampToEdge),
            extensions: None,
            extras: Default::default(),
        });
        let texture = root.push(json::Texture {
            sampler: Some(sampler),
            source: image,
            extensions: None,
            extras: Default::default(),
        });
        root.push(json::Material {
            pbr_metallic_roughness: json::material::PbrMetallicRoughness {
                base_color_texture: Some(json::texture::Info {
                    index: texture,
                    tex_coord: 0,
                    extensions: None,
                    extras: Default::default(),
                }),
                metallic_factor: json::material::StrengthFactor(0.0),
                roughness_factor: json::material::StrengthFactor(1.0),
                ..Default::default()
            },
            ..Default::default()
        })
    });
    let accessor = |view, count: usize, component, kind, bounds: Option<([f32; 3], [f32; 3])>| json::Accessor {
        buffer_view: Some(view),
        byte_offset: None,
        count: USize64(count as u64),
        component_type: Valid(json::accessor::GenericComponentType(component)),
        extensions: None,
        extras: Default::default(),
        type_: Valid(kind),
        min: bounds.map(|b| serde_json::json!(b.0)),
        max: bounds.map(|b| serde_json::json!(b.1)),
        normalized: false,
        sparse: None,
    };
    use json::accessor::{ComponentType, Type};
    let positions = root.push(accessor(views[0], n, ComponentType::F32, Type::Vec3, Some((pmin, pmax))));
    let normals = root.push(accessor(views[1], n, ComponentType::F32, Type::Vec3, None));
    let uv = root.push(accessor(views[2], n, ComponentType::F32, Type::Vec2, None));
    let indices = root.push(accessor(views[3], mesh.triangles.len() * 3, ComponentType::U32, Type::Scalar, None));
    let primitive = json::mesh::Primitive {
        attributes: [
            (Valid(json::mesh::Semantic::Positions), positions),
            (Valid(json::mesh::Semantic::Normals), normals),
            (Valid(json::mesh::Semantic::TexCoords(0)), uv),
        ]
        .into_iter()
        .collect(),
        extensions: None,
        extras: Default::default(),
        indices: Some(indices),
        material,
        mode: Valid(json::mesh::Mode::Triangles),
        targets: None,
    };
    let m = root.push(json::Mesh {
        extensions: None,
        extras: Default::default(),
        primitives: vec![primitive],
        weights: None,
    });
    let node =
        root.push(json::Node { mesh: Some(m), translation: Some(centre.map(|c| c as f32)), ..Default::default() });
    let scene = root.push(json::Scene { extensions: None, extras: Default::default(), nodes: vec![node] });
    root.scene = Some(scene);
    let text = root.to_vec().map_err(|e| Error::InvalidArgument(format!("glTF: {e}")))?;
    if !glb {
        return Ok(text);
    }
    // GLB: header, JSON chunk padded with spaces, BIN chunk padded with zeros (4-byte aligned).
    let mut json_chunk = text;
    json_chunk.resize(json_chunk.len().next_multiple_of(4), b' ');
    bin.resize(bin.len().next_multiple_of(4), 0);
    let total = 12 + 8 + json_chunk.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json_chunk.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json_chunk);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    Ok(out)
}

/// Writes `mesh` to `path` in the format of its extension, atomically (a temporary file renamed
/// into place).
pub fn write_export(mesh: &TerrainExport, path: &Path, comment: &str) -> Result<()> {
    let bytes = match ExportFormat::of_path(path)? {
        ExportFormat::Obj => obj_bytes(mesh, comment),
        ExportFormat::Ply => ply_bytes(mesh, comment),
        ExportFormat::Gltf => gltf_bytes(mesh, false, comment)?,
        ExportFormat::Glb => gltf_bytes(mesh, true, comment)?,
    };
    crate::sys::atomic_file::write(path, |w| std::io::Write::write_all(w, &bytes))
}
