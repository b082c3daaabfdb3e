//! Rendering: WGSL validation, the GPU against the CPU reference of the shading, golden images of
//! real DEMs, and per-frame upload sizes. Runs on any Vulkan adapter; CI uses Mesa's lavapipe
//! (installed by tools/test.sh). Regenerate the golden images with `RELIEF_BLESS=1`.

use crate::common;

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};

use common::{check_golden, compare, dem, gpu};
use glam::DVec3;
use relief::camera::Camera;
use relief::format::terrain::TerrainFile;
use relief::layout::LayoutKind;
use relief::preprocess::convert::{convert, ConvertOptions};
use relief::refine::{RefineOptions, Refiner, Strip};
use relief::render::offscreen::ProbeTargets;
use relief::render::shade::{self, ShadeParams};
use relief::render::terrain::{Probe, FRAME_UNIFORM_BYTES, MORPH_BYTES, VERTEX_BYTES};
use relief::render::{render_still, Look, Ramp, StillReport};
use relief::render::{DrawStyle, FrameView, Gpu, RendererOptions, TerrainRenderer};
use relief::sys::progress::Progress;

/// Converted terrains by DEM name.
type Converted = Vec<(String, Arc<TerrainFile>)>;

/// Real DEMs converted once per test binary.
fn terrain(name: &str) -> Arc<TerrainFile> {
    static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
    static CACHE: OnceLock<Mutex<Converted>> = OnceLock::new();
    let dir = DIR.get_or_init(|| tempfile::tempdir().unwrap());
    let cache = CACHE.get_or_init(|| Mutex::new(Vec::new()));
    let mut cache = cache.lock().unwrap_or_else(|p| p.into_inner());
    if let Some((_, t)) = cache.iter().find(|(n, _)| n == name) {
        return t.clone();
    }
    let out = dir.path().join(format!("{name}.relief"));
    let mut opts = ConvertOptions::new(LayoutKind::Interleaved);
    opts.progress = Progress::hidden();
    if name.starts_with("fuji") {
        // The Terrain-RGB tile carries no georeferencing: 30 m posts give it a plausible shape.
        opts.spacing_m = Some([30.0, 30.0]);
    }
    convert(&dem(name), &out, &opts).unwrap();
    let t = Arc::new(TerrainFile::open(&out).unwrap());
    cache.push((name.to_string(), t.clone()));
    t
}

fn camera(eye: [f64; 3], look: [f64; 3], w: u32, h: u32) -> Camera {
    Camera::new(DVec3::from(eye), DVec3::from(look), DVec3::Z, 60.0, w, h).unwrap()
}

#[test]
fn every_wgsl_file_validates_with_naga() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("shaders");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "wgsl"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no WGSL in {}", dir.display());
    let validate = |src: &str| -> Result<(), String> {
        let module = naga::front::wgsl::parse_str(src).map_err(|e| e.emit_to_string(src))?;
        naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::empty())
            .validate(&module)
            .map_err(|e| format!("{e:?}"))?;
        Ok(())
    };
    for f in &files {
        let src = std::fs::read_to_string(f).unwrap();
        if let Err(e) = validate(&src) {
            panic!("{}: invalid WGSL:\n{e}", f.display());
        }
    }
    // The check itself catches errors: a type error and an undeclared binding.
    assert!(validate("fn f() -> f32 { return 1u; }").is_err());
    assert!(
        validate("@fragment fn f() -> @location(0) vec4<f32> { return textureLoad(t, vec2<u32>(0u), 0); }").is_err()
    );
}

/// The probe pass writes what `fs_terrain` computes; the CPU reference (`render::shade`) must
/// agree at every covered pixel. Small tiles (64 posts, 81 layers) make the shader cross tile
/// borders everywhere, and the default single-layer tiling must give the same bits.
#[test]
fn gpu_shading_matches_the_cpu_reference_across_tiles() {
    let gpu = gpu();
    let t = terrain("zurich_25m_i16.tif");
    let plain = camera([2000.0, -1500.0, 1500.0], [5000.0, 4500.0, 500.0], 256, 160);
    // The default look, then render-time looks: the perceptually uniform ramp on a scene three
    // times as high under a low south-east sun, and the grey hillshade at 1.5 times.
    let looks = [
        Look::DEFAULT,
        Look { ramp: Ramp::Viridis, z_exaggeration: 3.0, sun_azimuth_deg: 135.0, sun_altitude_deg: 20.0 },
        Look { ramp: Ramp::Grey, z_exaggeration: 1.5, ..Look::DEFAULT },
    ];
    for (k, look) in looks.iter().enumerate() {
        let cam = look.scene_camera(&plain);
        let x = look.z_exaggeration;
        let mut strip = Strip::new();
        let refine = RefineOptions { tolerance_px: 2.0, z_exaggeration: x, ..Default::default() };
        Refiner::new(1).unwrap().refine_file(&t, &cam, &refine, &mut strip).unwrap();
        let probe = |tile_posts: Option<u32>, what: Probe| {
            let mut r = TerrainRenderer::new(
                &gpu,
                &t,
                relief::render::offscreen::OFFSCREEN_FORMAT,
                RendererOptions { tile_posts, look: *look, ..Default::default() },
                Progress::hidden(),
            )
            .unwrap();
            r.upload_strip(&gpu, &strip).unwrap();
            let targets = ProbeTargets::new(&gpu, cam.width_px, cam.height_px);
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            r.encode_probe(
                &gpu,
                &mut enc,
                [&targets.views[0], &targets.views[1]],
                &targets.depth_view,
                &FrameView::new(&t, cam, x),
                what,
            );
            gpu.queue.submit([enc.finish()]);
            (r.tiling(), targets.read(&gpu, 0).unwrap(), targets.read(&gpu, 1).unwrap())
        };
        let (tiling, pos, normal) = probe(Some(64), Probe::Normal);
        assert_eq!((tiling.tile_posts, tiling.layers()), (64, 81));
        let (_, pos2, colour) = probe(Some(64), Probe::Colour);
        let (one, pos1, normal1) = probe(None, Probe::Normal);
        assert_eq!(one.layers(), 1);
        assert_eq!(pos, pos1, "tiling changed the surface");
        assert_eq!(normal, normal1, "tiling changed the normals");
        assert_eq!(pos, pos2);

        let h = t.header();
        let params = ShadeParams::for_terrain(h.spacing_m, t.grid().size(), h.z_min, h.z_max).with_look(look);
        let last = t.grid().max_coord() as i32;
        let height = |x: i32, y: i32| t.height_at(x.clamp(0, last) as u32, y.clamp(0, last) as u32).unwrap() as f64;
        let (mut covered, mut worst_h, mut worst_n, mut worst_c) = (0, 0f64, 0f64, 0f64);
        for k in 0..pos.len() {
            if normal[k][3] != 1.0 {
                continue; // sky, or padding outside the DEM
            }
            covered += 1;
            let [gx, gy, h_gpu, mesh_z] = pos[k].map(|v| v as f64);
            let s = shade::surface_at(&params, &height, [gx, gy]);
            worst_h = worst_h.max((s.height_m - h_gpu).abs());
            let n_gpu = DVec3::new(normal[k][0] as f64, normal[k][1] as f64, normal[k][2] as f64);
            worst_n = worst_n.max((s.normal - n_gpu).length());
            let rel = DVec3::new(gx * h.spacing_m[0], gy * h.spacing_m[1], mesh_z) - cam.eye_in_world;
            let c = shade::shade(&params, s, rel);
            let c_gpu = DVec3::new(colour[k][0] as f64, colour[k][1] as f64, colour[k][2] as f64);
            worst_c = worst_c.max((c - c_gpu).abs().max_element());
        }
        assert!(covered > pos.len() / 3, "look {k}: terrain covers only {covered} of {} pixels", pos.len());
        // f32 on the GPU against f64 here: heights of ~900 m interpolated in f32 are good to ~1e-4
        // relative; normals and colours to a few 1e-4.
        assert!(worst_h < 0.02, "look {k}: height differs by {worst_h} m");
        assert!(worst_n < 2e-3, "look {k}: normal differs by {worst_n}");
        assert!(worst_c < 2e-3, "look {k}: colour differs by {worst_c}");
    }
}

/// The real nodata DEM (hugo, 27% void): its void posts are not drawn by default, drawn as water
/// at their filled heights with `sea-level`, and drawn as their filled heights with `filled`. Which post owns a
/// fragment is the nearest one, as in the shader.
#[test]
fn nodata_posts_are_drawn_as_asked() {
    use relief::render::NodataStyle;
    let gpu = gpu();
    let t = terrain("hugo_site_nodata.asc");
    let mask = t.void_mask().unwrap().expect("hugo has nodata, so a void mask");
    assert_eq!(mask.count(), t.header().nodata_filled);
    let cam = camera([-60.0, -160.0, 1860.0], [380.0, 300.0, 1660.0], 256, 160);
    let mut strip = Strip::new();
    Refiner::new(1)
        .unwrap()
        .refine_file(&t, &cam, &RefineOptions { tolerance_px: 1.0, ..Default::default() }, &mut strip)
        .unwrap();
    let probe = |nodata: NodataStyle| {
        let opts = RendererOptions { nodata, ..Default::default() };
        let mut r =
            TerrainRenderer::new(&gpu, &t, relief::render::offscreen::OFFSCREEN_FORMAT, opts, Progress::hidden())
                .unwrap();
        r.upload_strip(&gpu, &strip).unwrap();
        let targets = ProbeTargets::new(&gpu, cam.width_px, cam.height_px);
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        let views = [&targets.views[0], &targets.views[1]];
        r.encode_probe(&gpu, &mut enc, views, &targets.depth_view, &FrameView::new(&t, cam, 1.0), Probe::Normal);
        gpu.queue.submit([enc.finish()]);
        (targets.read(&gpu, 0).unwrap(), targets.read(&gpu, 1).unwrap())
    };
    // (covered pixels, of which on void posts), and the void pixels' surface heights.
    let census = |(pos, normal): &(Vec<[f32; 4]>, Vec<[f32; 4]>)| {
        let (mut covered, mut void, mut void_heights) = (0usize, 0usize, Vec::new());
        for (p, n) in pos.iter().zip(normal) {
            if n[3] != 1.0 {
                continue;
            }
            covered += 1;
            let post = [(p[0] + 0.5).floor() as u32, (p[1] + 0.5).floor() as u32];
            if mask.is_void(post[0], post[1]) {
                void += 1;
                void_heights.push(p[2]);
            }
        }
        (covered, void, void_heights)
    };
    let (filled_covered, filled_void, _) = census(&probe(NodataStyle::Filled));
    let (void_covered, void_void, _) = census(&probe(NodataStyle::Void));
    let (sea_covered, sea_void, sea_heights) = census(&probe(NodataStyle::SeaLevel));
    assert!(filled_void > filled_covered / 10, "the view shows the void: {filled_void} of {filled_covered} pixels");
    assert_eq!(void_void, 0, "a void post was drawn");
    assert!(void_covered > 2_000 && void_covered < filled_covered - filled_void / 2, "{void_covered}");
    // Water is drawn where the filled heights would be: the same pixels, shaded as water.
    assert_eq!((sea_covered, sea_void), (filled_covered, filled_void), "water covers the void");
    eprintln!(
        "filled {filled_covered} ({filled_void} void), void {void_covered}, sea {sea_covered} ({sea_void} water)"
    );
    assert!(sea_heights.iter().all(|&z| z == -0.5), "water is drawn as water");
}

/// A golden view: DEM, camera (in the terrain's metres; it scales with an exaggerated scene),
/// tolerance, style, look.
struct Golden {
    name: &'static str,
    dem: &'static str,
    eye: [f64; 3],
    look: [f64; 3],
    tolerance_px: f64,
    wireframe: bool,
    geomorph: Option<f64>,
    looks: Look,
    /// An image draped on it (in the checkout's data/).
    imagery: Option<&'static str>,
}

const PLAIN: Look =
    Look { ramp: Ramp::Hypsometric, sun_azimuth_deg: 315.0, sun_altitude_deg: 45.0, z_exaggeration: 1.0 };

const GOLDEN: [Golden; 9] = [
    Golden {
        name: "zurich",
        dem: "zurich_25m_i16.tif",
        eye: [2000.0, -1500.0, 1500.0],
        look: [5000.0, 4500.0, 500.0],
        tolerance_px: 1.0,
        wireframe: false,
        geomorph: None,
        looks: PLAIN,
        imagery: None,
    },
    Golden {
        name: "zurich_wire_geomorph",
        dem: "zurich_25m_i16.tif",
        eye: [2000.0, -1500.0, 1500.0],
        look: [5000.0, 4500.0, 500.0],
        tolerance_px: 4.0,
        wireframe: true,
        geomorph: Some(2.0),
        looks: PLAIN,
        imagery: None,
    },
    Golden {
        name: "fuji",
        dem: "fuji_terrain_rgb.png",
        eye: [7680.0, -6000.0, 3000.0],
        look: [7680.0, 7680.0, 2000.0],
        tolerance_px: 1.0,
        wireframe: false,
        geomorph: None,
        looks: PLAIN,
        imagery: None,
    },
    Golden {
        name: "lidar",
        dem: "lidar_1m_f32.tif",
        eye: [-60.0, -60.0, 470.0],
        look: [250.0, 250.0, 385.0],
        tolerance_px: 1.0,
        wireframe: false,
        geomorph: None,
        looks: PLAIN,
        imagery: None,
    },
    Golden {
        name: "etopo_bathymetry",
        dem: "etopo20_world.tif",
        eye: [12.0e6, -2.0e6, 4.0e6],
        look: [12.0e6, 9.0e6, -3.0e6],
        tolerance_px: 1.0,
        wireframe: false,
        geomorph: None,
        looks: PLAIN,
        imagery: None,
    },
    // Render-time looks: exaggeration with the perceptually uniform ramp, a continental DEM
    // exaggerated 40 times, and the grey hillshade under a low south-east sun.
    Golden {
        name: "zurich_x3_viridis",
        dem: "zurich_25m_i16.tif",
        eye: [2000.0, -1500.0, 1500.0],
        look: [5000.0, 4500.0, 500.0],
        tolerance_px: 1.0,
        wireframe: false,
        geomorph: None,
        looks: Look { ramp: Ramp::Viridis, z_exaggeration: 3.0, ..PLAIN },
        imagery: None,
    },
    Golden {
        name: "etopo_x40",
        dem: "etopo20_world.tif",
        eye: [12.0e6, -2.0e6, 1.0e5],
        look: [12.0e6, 9.0e6, -7.5e4],
        tolerance_px: 1.0,
        wireframe: false,
        geomorph: None,
        looks: Look { z_exaggeration: 40.0, ..PLAIN },
        imagery: None,
    },
    Golden {
        name: "lidar_grey_low_sun",
        dem: "lidar_1m_f32.tif",
        eye: [-60.0, -60.0, 470.0],
        look: [250.0, 250.0, 385.0],
        tolerance_px: 1.0,
        wireframe: false,
        geomorph: None,
        looks: Look { ramp: Ramp::Grey, sun_azimuth_deg: 135.0, sun_altitude_deg: 20.0, ..PLAIN },
        imagery: None,
    },
    // Real imagery of the same place: NASA's world image on ETOPO20, exaggerated.
    Golden {
        name: "etopo_draped_x40",
        dem: "etopo20_world.tif",
        eye: [12.0e6, -2.0e6, 1.0e5],
        look: [12.0e6, 9.0e6, -7.5e4],
        tolerance_px: 1.0,
        wireframe: false,
        geomorph: None,
        looks: Look { z_exaggeration: 40.0, ..PLAIN },
        imagery: Some("data/imagery/earth_2048.jpg"),
    },
];

fn render_golden(g: &Golden, gpu: &Gpu) -> (image::RgbaImage, StillReport) {
    let t = terrain(g.dem);
    let cam = g.looks.scene_camera(&camera(g.eye, g.look, 320, 200));
    let options = RefineOptions {
        tolerance_px: g.tolerance_px,
        morph_ratio: g.geomorph,
        z_exaggeration: g.looks.z_exaggeration,
        ..Default::default()
    };
    let imagery = g.imagery.map(|p| {
        let img = relief::render::imagery::Imagery::open(&Path::new(env!("CARGO_MANIFEST_DIR")).join(p)).unwrap();
        (Arc::new(img), 0.7)
    });
    let renderer = RendererOptions { look: g.looks, imagery, ..Default::default() };
    render_still(
        gpu,
        t,
        &cam,
        &options,
        relief::render::StillOptions { style: DrawStyle { wireframe: g.wireframe }, renderer, ..Default::default() },
        Progress::hidden(),
    )
    .unwrap()
}

#[test]
fn golden_images_of_real_dems() {
    let gpu = gpu();
    let mut failures = Vec::new();
    for g in &GOLDEN {
        let (got, report) = render_golden(g, &gpu);
        assert!(report.triangles > 0, "{}: nothing drawn", g.name);
        if let Err(e) = check_golden(g.name, &got) {
            failures.push(e);
        }
    }
    assert!(failures.is_empty(), "golden images differ:\n{}", failures.join("\n"));
}

#[test]
fn the_golden_comparison_catches_real_changes() {
    let gpu = gpu();
    let (img, _) = render_golden(&GOLDEN[0], &gpu);
    assert!(compare(&img, &img).is_ok());
    // The same view at another tolerance, and shifted by a few pixels, must both fail.
    let coarse = Golden { tolerance_px: 64.0, ..GOLDEN[0] };
    let (other, _) = render_golden(&coarse, &gpu);
    assert!(compare(&other, &img).is_err(), "τ = 64 px looked the same as τ = 1 px");
    let moved = Golden { eye: [2060.0, -1500.0, 1500.0], ..GOLDEN[0] };
    let (shifted, _) = render_golden(&moved, &gpu);
    assert!(compare(&shifted, &img).is_err(), "a moved eye looked the same");
}

/// Per-frame uploads are the strip (8 bytes a vertex, 16 with geomorphing) plus the frame
/// uniform, whatever the terrain's size.
#[test]
fn a_frame_uploads_the_strip_not_the_terrain() {
    let gpu = gpu();
    for g in [&GOLDEN[0], &GOLDEN[1], &GOLDEN[4]] {
        let (_, r) = render_golden(g, &gpu);
        let per_vertex = VERTEX_BYTES + if g.geomorph.is_some() { MORPH_BYTES } else { 0 };
        assert_eq!(r.upload_bytes, r.strip_len * per_vertex + FRAME_UNIFORM_BYTES, "{}", g.name);
        let t = terrain(g.dem);
        let terrain_bytes = t.grid().vertices() * 4;
        assert_eq!(r.heights_gpu_bytes, t.grid().size() as u64 * t.grid().size() as u64 * 4);
        assert!(r.upload_bytes * 10 < terrain_bytes, "{}: {} bytes per frame", g.name, r.upload_bytes);
    }
}

/// Imagery is placed by its world file in the terrain's CRS: NASA's world image on ETOPO20
/// (EPSG:4326, its first post at 20.17° E, 89.83° S) wraps in longitude; a bad world file is one
/// line naming it.
#[test]
fn imagery_is_placed_by_its_world_file() {
    use relief::render::imagery::Imagery;
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let img = Imagery::open(&root.join("data/imagery/earth_2048.jpg")).unwrap();
    assert_eq!(img.image().unwrap().dimensions(), (2048, 1024));
    let t = terrain("etopo20_world.tif");
    let (uv, wraps) = img.uv_of_grid(t.header()).unwrap();
    assert!(wraps);
    let g = t.header().georef.unwrap();
    let (lon, lat) = (g.origin[0], g.origin[1]);
    assert!((uv[0] as f64 - (lon + 180.0) / 360.0).abs() < 1e-6, "{uv:?}");
    assert!((uv[2] as f64 - (90.0 - lat) / 180.0).abs() < 1e-6, "{uv:?}");
    // One post east is a third of a degree; one north moves up the image.
    assert!((uv[1] as f64 - (1.0 / 3.0) / 360.0).abs() < 1e-9 && uv[3] < 0.0);
    let dir = tempfile::tempdir().unwrap();
    let copy = dir.path().join("earth.jpg");
    std::fs::copy(root.join("data/imagery/earth_2048.jpg"), &copy).unwrap();
    let wf = dir.path().join("earth.jgw");
    for (text, want) in [("1 0.1 0 -1 0 0", "rotated"), ("1 0 0 -1 0", "six numbers"), ("1 0 0 1 0 0", "north up")] {
        std::fs::write(&wf, text).unwrap();
        let e = Imagery::open(&copy).unwrap_err().to_string();
        assert!(e.starts_with(&wf.display().to_string()) && e.contains(want) && !e.contains('\n'), "{e}");
    }
    // Without a world file the image spans the DEM.
    std::fs::remove_file(&wf).unwrap();
    let plain = Imagery::open(&copy).unwrap();
    assert_eq!(plain.uv_of_grid(t.header()).unwrap(), ([0.0, 1.0 / 1080.0, 1.0, -1.0 / 539.0], false));
}

/// `relief export --imagery` textures the mesh as `render --imagery` drapes it: the .glb embeds
/// the image's own bytes as the base colour (read back with the gltf crate), with a sampler that
/// wraps in longitude, and the texture coordinates follow the world file.
#[test]
fn export_embeds_the_imagery_as_a_gltf_texture() {
    let dir = tempfile::tempdir().unwrap();
    let t = terrain("etopo20_world.tif");
    let image = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/imagery/earth_2048.jpg");
    let out = dir.path().join("world.glb");
    let o = common::relief()
        .arg("export")
        .arg(t.path())
        .arg(&out)
        .args(["--max-error", "500", "--imagery"])
        .arg(&image)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", common::stderr_of(&o));
    let bytes = std::fs::read(&out).unwrap();
    let g = gltf::Gltf::from_slice(&bytes).expect("valid glTF");
    let blob = g.blob.as_ref().unwrap();
    let prim = g.meshes().next().unwrap().primitives().next().unwrap();
    let info = prim.material().pbr_metallic_roughness().base_color_texture().expect("a base colour texture");
    let tex = info.texture();
    assert_eq!(tex.sampler().wrap_s(), gltf::texture::WrappingMode::Repeat);
    let gltf::image::Source::View { view, mime_type } = tex.source().source() else { panic!("an embedded image") };
    assert_eq!(mime_type, "image/jpeg");
    assert!(blob[view.offset()..view.offset() + view.length()] == std::fs::read(&image).unwrap()[..]);
    // The first post (20.17° E, 89.83° S) at its place in the world image.
    let reader = prim.reader(|_| Some(&blob[..]));
    let uv: Vec<[f32; 2]> = reader.read_tex_coords(0).unwrap().into_f32().collect();
    let g0 = t.header().georef.unwrap();
    let want = [((g0.origin[0] + 180.0) / 360.0) as f32, ((90.0 - g0.origin[1]) / 180.0) as f32];
    assert!(uv.iter().any(|u| (u[0] - want[0]).abs() < 1e-5 && (u[1] - want[1]).abs() < 1e-5), "{want:?}");
    // Not an image: one line naming it, nothing written.
    let bad = dir.path().join("bad.png");
    std::fs::write(&bad, b"not a png").unwrap();
    let out2 = dir.path().join("bad.glb");
    let o = common::relief()
        .arg("export")
        .arg(t.path())
        .arg(&out2)
        .args(["--max-error", "500", "--imagery"])
        .arg(&bad)
        .output()
        .unwrap();
    let e = common::stderr_of(&o);
    assert!(!o.status.success() && e.trim_end().lines().count() == 1 && e.contains(&bad.display().to_string()), "{e}");
    assert!(!out2.exists());
}

/// A GeoTIFF orthophoto (here NASA's world image made a GeoTIFF with gdal_translate) is read
/// through GDAL and placed by its geotransform: the same placement as the JPEG's world file, the
/// same pixels within JPEG decoders' rounding.
#[cfg(feature = "gdal")]
#[test]
fn geotiff_imagery_is_placed_by_its_geotransform() {
    use relief::render::imagery::Imagery;
    let dir = tempfile::tempdir().unwrap();
    let jpg = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/imagery/earth_2048.jpg");
    let tif = dir.path().join("earth.tif");
    let o = std::process::Command::new("gdal_translate")
        .args(["-q", "-a_srs", "EPSG:4326", "-a_ullr", "-180", "90", "180", "-90"])
        .arg(&jpg)
        .arg(&tif)
        .output()
        .expect("gdal_translate (Debian's gdal-bin)");
    assert!(o.status.success(), "{}", common::stderr_of(&o));
    let (a, b) = (Imagery::open(&jpg).unwrap(), Imagery::open(&tif).unwrap());
    let (pa, pb) = (a.placement.unwrap(), b.placement.unwrap());
    assert!((0..4).all(|k| (pa[k] - pb[k]).abs() < 1e-9), "{pa:?} {pb:?}");
    let (a_px, b_px) = (a.image().unwrap(), b.image().unwrap());
    assert_eq!(a_px.dimensions(), b_px.dimensions());
    let diff: f64 = a_px.as_raw().iter().zip(b_px.as_raw()).map(|(x, y)| (*x as f64 - *y as f64).abs()).sum::<f64>()
        / a_px.as_raw().len() as f64;
    assert!(diff < 2.0, "mean difference {diff} levels");
    let t = terrain("etopo20_world.tif");
    assert_eq!(a.uv_of_grid(t.header()).unwrap(), b.uv_of_grid(t.header()).unwrap());
    // Tiled through GDAL, 256 rows at a time: the JPEG's tile file, placed alike, every tile
    // within the decoders' rounding.
    let (from_jpg, from_tif) = (dir.path().join("j.rimg"), dir.path().join("t.rimg"));
    let make = |src: &Path, out: &Path| {
        relief::render::imagery::make_tiles(src, out, dir.path(), Progress::hidden()).unwrap();
        relief::format::imagery::ImageryFile::open(out, relief::pager::Access::Map).unwrap()
    };
    let (tj, tt) = (make(&jpg, &from_jpg), make(&tif, &from_tif));
    let (hj, ht) = (tj.header(), tt.header());
    assert_eq!((hj.width, hj.height, hj.tiles), (ht.width, ht.height, ht.tiles));
    let (pj, pt) = (hj.placement.unwrap(), ht.placement.unwrap());
    assert!((0..4).all(|k| (pj[k] - pt[k]).abs() < 1e-9), "{pj:?} {pt:?}");
    let side = tj.grid().slot_side() as usize;
    let (mut x, mut y) = (vec![0u32; side * side], vec![0u32; side * side]);
    for key in 0..tj.grid().tiles() {
        tj.read_tile(key, &mut x).unwrap();
        tt.read_tile(key, &mut y).unwrap();
        let sum: f64 = x
            .iter()
            .zip(&y)
            .flat_map(|(p, q)| (0..4).map(move |c| ((p >> (8 * c)) & 255) as f64 - ((q >> (8 * c)) & 255) as f64))
            .map(f64::abs)
            .sum();
        let mean = sum / (4 * side * side) as f64;
        assert!(mean < 2.0, "tile {key}: mean difference {mean} levels");
    }
}

/// Paged imagery: the draped golden view drawn from an imagery tile file of the same JPEG
/// (`relief imagery`) matches the golden image within its tolerance, both with room for every
/// tile and through a pool of 24 slots (of the file's 69 tiles) that holds only what the view
/// wants; the pool stays within its budget.
#[test]
fn paged_imagery_draws_the_draped_golden_view() {
    let gpu = gpu();
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let tiles = dir.path().join("earth.rimg");
    let r = relief::render::imagery::make_tiles(
        &root.join("data/imagery/earth_2048.jpg"),
        &tiles,
        dir.path(),
        Progress::hidden(),
    )
    .unwrap();
    assert_eq!((r.width, r.height, r.levels, r.tiles), (2048, 1024, 5, 69));
    let g = GOLDEN.iter().find(|g| g.name == "etopo_draped_x40").unwrap();
    let t = terrain(g.dem);
    let cam = g.looks.scene_camera(&camera(g.eye, g.look, 320, 200));
    let options = RefineOptions { tolerance_px: 1.0, z_exaggeration: g.looks.z_exaggeration, ..Default::default() };
    let img = Arc::new(relief::render::imagery::Imagery::open(&tiles).unwrap());
    let slot = 256 * 256 * 4;
    let table = 4 * (32 + 69);
    for (slots, budget) in [(69u64, None), (24, Some(24 * slot + table))] {
        let renderer = RendererOptions {
            look: g.looks,
            imagery: Some((img.clone(), 0.7)),
            imagery_gpu_memory: budget,
            ..Default::default()
        };
        let still = relief::render::StillOptions { renderer, ..Default::default() };
        let (got, report) = render_still(&gpu, t.clone(), &cam, &options, still, Progress::hidden()).unwrap();
        assert_eq!(report.imagery_gpu_bytes, slots * slot + table, "{slots} slots");
        assert!(report.imagery_tiles_resident >= 5 && report.imagery_tiles_resident <= slots, "{report:?}");
        if let Err(e) = check_golden(g.name, &got) {
            panic!("paged through {slots} slots: {e}");
        }
    }
    // A budget below two tiles is refused in one line.
    let renderer = RendererOptions { imagery: Some((img, 0.7)), imagery_gpu_memory: Some(slot), ..Default::default() };
    let still = relief::render::StillOptions { renderer, ..Default::default() };
    let e = render_still(&gpu, t, &cam, &options, still, Progress::hidden()).err().unwrap().to_string();
    assert!(e.contains("a GPU imagery budget of 262144 bytes is too small"), "{e}");
}
