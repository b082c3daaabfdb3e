//! `relief export`'s meshes (relief_core::mesh::export): a real DEM's view as glTF loads back
//! with the gltf reader crate (validated) with exactly the strip's non-degenerate triangles, OBJ
//! and PLY load in relief's own mesh reader, and `--max-error` meshes hold every DEM post within
//! their error, conforming (no T-junction).

use std::collections::{HashMap, HashSet};
use std::process::Command;

use crate::common;

use glam::DVec3;
use relief_core::camera::Camera;
use relief_core::format::terrain::TerrainFile;
use relief_core::layout::LayoutKind;
use relief_core::mesh::export::{gltf_bytes, write_export, ExportFrame, TerrainExport};
use relief_core::mesh::read_mesh;
use relief_core::preprocess::convert::{convert, ConvertOptions};
use relief_core::refine::{RefineOptions, Refiner, Strip};

/// The real lidar DEM cut to 257² posts, so its grid has no padding and the export holds every
/// strip triangle.
fn lidar_257(dir: &std::path::Path) -> Option<TerrainFile> {
    let tif = dir.join("lidar_257.tif");
    let o = Command::new("gdal_translate")
        .args(["-q", "-srcwin", "0", "0", "257", "257"])
        .arg(common::dem("lidar_1m_f32.tif"))
        .arg(&tif)
        .output();
    match o {
        Ok(o) if o.status.success() => {}
        _ => {
            eprintln!("note: gdal_translate (Debian's gdal-bin) not available; export test skipped");
            return None;
        }
    }
    let out = dir.join("lidar_257.relief");
    convert(&tif, &out, &ConvertOptions::new(LayoutKind::Hz)).unwrap();
    Some(TerrainFile::open(&out).unwrap())
}

/// The terrain's (x, y, z) of glTF's y-up (x, y, z) under the node's translation.
fn from_gltf(p: [f32; 3], t: [f32; 3]) -> [f64; 3] {
    let q = [p[0] as f64 + t[0] as f64, p[1] as f64 + t[1] as f64, p[2] as f64 + t[2] as f64];
    [q[0], -q[2], q[1]]
}

/// Positions and triangles read back from glTF bytes with the gltf crate.
fn read_gltf(bytes: &[u8]) -> (Vec<[f64; 3]>, Vec<[u32; 3]>, usize) {
    let g = gltf::Gltf::from_slice(bytes).expect("valid glTF");
    let blob = match &g.blob {
        Some(b) => b.clone(),
        None => {
            use base64::Engine;
            let uri = g.buffers().next().unwrap().source();
            let gltf::buffer::Source::Uri(uri) = uri else { panic!("an embedded buffer") };
            let data = uri.strip_prefix("data:application/octet-stream;base64,").expect("a data URI");
            base64::engine::general_purpose::STANDARD.decode(data).unwrap()
        }
    };
    let node = g.nodes().next().unwrap();
    let t = node.transform().decomposed().0;
    let prim = node.mesh().unwrap().primitives().next().unwrap();
    let reader = prim.reader(|_| Some(&blob[..]));
    let positions: Vec<[f64; 3]> = reader.read_positions().unwrap().map(|p| from_gltf(p, t)).collect();
    let normals = reader.read_normals().unwrap().count();
    let uv: Vec<[f32; 2]> = reader.read_tex_coords(0).unwrap().into_f32().collect();
    assert!(uv.iter().all(|t| (0.0..=1.0).contains(&t[0]) && (0.0..=1.0).contains(&t[1])));
    let idx: Vec<u32> = reader.read_indices().unwrap().into_u32().collect();
    let tris = idx.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    (positions, tris, normals)
}

#[test]
fn a_real_view_exports_to_gltf_ply_and_obj_with_exactly_the_strips_triangles() {
    let dir = tempfile::tempdir().unwrap();
    let Some(t) = lidar_257(dir.path()) else { return };
    let camera =
        Camera::new(DVec3::new(-60.0, -60.0, 470.0), DVec3::new(150.0, 150.0, 385.0), DVec3::Z, 60.0, 1280, 720)
            .unwrap();
    let mut strip = Strip::new();
    Refiner::new(1).unwrap().refine_file(&t, &camera, &RefineOptions::default(), &mut strip).unwrap();
    let want_tris = strip.triangle_counts().0 as usize;
    let want_verts: HashSet<_> = strip.triangles().flatten().collect();
    assert!(want_tris > 1000, "{want_tris}");
    let mesh = TerrainExport::of_strip(&t, &strip, ExportFrame::Local).unwrap();
    assert_eq!((mesh.triangles.len(), mesh.positions.len()), (want_tris, want_verts.len()));
    let h = t.header().clone();
    for glb in [true, false] {
        let bytes = gltf_bytes(&mesh, glb, "test").unwrap();
        let (positions, tris, normals) = read_gltf(&bytes);
        assert_eq!(
            (tris.len(), positions.len(), normals),
            (want_tris, want_verts.len(), want_verts.len()),
            "glb {glb}"
        );
        // Every vertex where its post is (f32 relative to the centre: well under a millimetre).
        for (p, post) in positions.iter().zip(&mesh.posts) {
            let want = [post[0] as f64 * h.spacing_m[0], post[1] as f64 * h.spacing_m[1]];
            assert!((p[0] - want[0]).abs() < 1e-3 && (p[1] - want[1]).abs() < 1e-3, "{p:?} for {post:?}");
            let z = t.height_at(post[0], post[1]).unwrap() as f64;
            assert!((p[2] - z).abs() < 1e-3);
        }
        // Counter-clockwise seen from above, in the terrain's frame.
        for tri in &tris {
            let [a, b, c] = tri.map(|i| positions[i as usize]);
            let cross = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
            assert!(cross > 0.0);
        }
    }
    for ext in ["obj", "ply"] {
        let path = dir.path().join(format!("view.{ext}"));
        write_export(&mesh, &path, "test").unwrap();
        let back = read_mesh(&path).unwrap();
        assert_eq!((back.triangles.len(), back.positions.len()), (want_tris, want_verts.len()), "{ext}");
        for (a, b) in back.positions.iter().zip(&mesh.positions) {
            assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-9), "{ext}: {a:?} {b:?}");
        }
        assert_eq!(back.triangles, mesh.triangles, "{ext}");
    }
}

/// Every post of the DEM inside each triangle lies within `m` of the triangle's plane, and the
/// mesh is conforming: no mesh vertex inside another triangle's edge.
fn check_within(t: &TerrainFile, mesh: &TerrainExport, m: f64) {
    let [_, _, w, h] = t.header().valid_window;
    let verts: HashSet<[u32; 2]> = mesh.posts.iter().copied().collect();
    let mut edges: HashMap<([u32; 2], [u32; 2]), u32> = HashMap::new();
    let mut worst = 0f64;
    for tri in &mesh.triangles {
        let p = tri.map(|i| mesh.posts[i as usize]);
        for k in 0..3 {
            let (a, b) = (p[k], p[(k + 1) % 3]);
            *edges.entry(if a < b { (a, b) } else { (b, a) }).or_default() += 1;
            // Lattice points strictly inside the edge must not be vertices.
            let (dx, dy) = (b[0] as i64 - a[0] as i64, b[1] as i64 - a[1] as i64);
            let g = gcd(dx.unsigned_abs(), dy.unsigned_abs()) as i64;
            for s in 1..g {
                let q = [(a[0] as i64 + dx / g * s) as u32, (a[1] as i64 + dy / g * s) as u32];
                assert!(!verts.contains(&q), "T-junction: {q:?} on edge {a:?}–{b:?}");
            }
        }
        let z = p.map(|q| t.height_at(q[0], q[1]).unwrap() as f64);
        let det = (p[1][0] as f64 - p[0][0] as f64) * (p[2][1] as f64 - p[0][1] as f64)
            - (p[1][1] as f64 - p[0][1] as f64) * (p[2][0] as f64 - p[0][0] as f64);
        let (x0, x1) = (p.iter().map(|q| q[0]).min().unwrap(), p.iter().map(|q| q[0]).max().unwrap().min(w - 1));
        let (y0, y1) = (p.iter().map(|q| q[1]).min().unwrap(), p.iter().map(|q| q[1]).max().unwrap().min(h - 1));
        for y in y0..=y1 {
            for x in x0..=x1 {
                let (fx, fy) = (x as f64, y as f64);
                let l1 = ((p[1][0] as f64 - fx) * (p[2][1] as f64 - fy)
                    - (p[1][1] as f64 - fy) * (p[2][0] as f64 - fx))
                    / det;
                let l2 = ((p[2][0] as f64 - fx) * (p[0][1] as f64 - fy)
                    - (p[2][1] as f64 - fy) * (p[0][0] as f64 - fx))
                    / det;
                let l3 = 1.0 - l1 - l2;
                if l1 >= -1e-12 && l2 >= -1e-12 && l3 >= -1e-12 {
                    let plane = l1 * z[0] + l2 * z[1] + l3 * z[2];
                    worst = worst.max((t.height_at(x, y).unwrap() as f64 - plane).abs());
                }
            }
        }
    }
    assert!(worst <= m + 1e-3, "a post {worst} m off a triangle, over {m} m");
    assert!(edges.values().all(|&n| n <= 2));
}

fn gcd(a: u64, b: u64) -> u64 {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

#[test]
fn max_error_meshes_hold_every_post_within_their_error() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("zurich.relief");
    // Zürich (real, 399 × 366 in a 513² grid: padding around the data).
    convert(&common::dem("zurich_25m_i16.tif"), &out, &ConvertOptions::new(LayoutKind::Interleaved)).unwrap();
    let t = TerrainFile::open(&out).unwrap();
    let mut last = usize::MAX;
    for m in [1.0, 4.0, 16.0] {
        let mesh = TerrainExport::within_error(&t, m, ExportFrame::Local).unwrap();
        check_within(&t, &mesh, m);
        eprintln!("max error {m} m: {} triangles", mesh.triangles.len());
        // Coarser for a larger error, and far below the grid's 2 × 398 × 365 triangles.
        assert!(mesh.triangles.len() < last && mesh.triangles.len() < 200_000, "{m}: {}", mesh.triangles.len());
        last = mesh.triangles.len();
    }
    assert!(TerrainExport::within_error(&t, -1.0, ExportFrame::Local).is_err());
}
