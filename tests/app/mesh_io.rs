//! Mesh input (`relief::mesh`): the real meshes in ../shared/data/mesh, every format round trip,
//! terrain export, and the one-line errors for malformed files.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use relief::format::terrain::TerrainFile;
use relief::layout::LayoutKind;
use relief::mesh::{read_mesh, read_mesh_with_report, terrain_mesh, write_ply_bytes, Mesh, MeshFormat, PlyEncoding};
use relief::preprocess::convert::{convert, ConvertOptions};

fn real_mesh(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/mesh").join(name)
}

fn check_sane(name: &str, m: &Mesh) {
    let b = m.bounds().expect("bounds");
    for k in 0..3 {
        assert!(b.min[k].is_finite() && b.max[k].is_finite(), "{name}: bounds {b:?}");
        assert!(b.max[k] > b.min[k], "{name}: empty extent on axis {k}: {b:?}");
    }
    let n = m.positions.len() as u32;
    assert!(m.triangles.iter().flatten().all(|&i| i < n), "{name}: index out of range");
    assert!(m.triangles.iter().all(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2]), "{name}: degenerate kept");
}

/// The documented counts (../shared/data/data_README.md) equal the file headers' face counts; all
/// faces of these meshes are triangles with distinct corners, so nothing is dropped.
#[test]
fn real_meshes_match_their_documented_counts() {
    for (name, format, gzip, vertices, triangles) in [
        ("bunny.off", MeshFormat::Off, false, 37_706, 75_408),
        ("armadillo.off", MeshFormat::Off, false, 26_002, 52_000),
        ("dragon_202k.ply.gz", MeshFormat::PlyAscii, true, 100_250, 202_520),
    ] {
        let start = Instant::now();
        let (m, r) = read_mesh_with_report(&real_mesh(name)).unwrap_or_else(|e| panic!("{e}"));
        eprintln!("{name}: read in {:.1} ms", start.elapsed().as_secs_f64() * 1e3);
        assert_eq!((r.format, r.gzip), (format, gzip), "{name}");
        assert_eq!(m.positions.len(), vertices, "{name}");
        assert_eq!(m.triangles.len(), triangles, "{name}");
        assert_eq!(r.faces, triangles as u64, "{name}");
        assert_eq!(r.degenerate_dropped, 0, "{name}");
        check_sane(name, &m);
    }
}

/// A small mesh with a quad (fan-triangulated) and a degenerate triangle, in every format.
/// Vertices: a unit square and an apex; faces: quad 0 1 2 3, triangles 0 1 4, 1 1 2 (degenerate).
const POS: [[f64; 3]; 5] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0], [0.5, 0.5, 0.75]];
const EXPECTED: [[u32; 3]; 3] = [[0, 1, 2], [0, 2, 3], [0, 1, 4]];

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

/// A binary PLY written by hand: float x, y, z between skipped properties of other types, a
/// `uchar`-counted `int` index list after an `ushort` property, and an extra element.
fn binary_ply(big: bool) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat binary_{}_endian 1.0\ncomment by hand\nelement vertex 5\nproperty uchar red\nproperty float x\n\
         property double nx\nproperty float y\nproperty float z\nproperty list uchar short extra\n\
         element face 3\nproperty ushort flags\nproperty list uchar int vertex_indices\n\
         element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n",
        if big { "big" } else { "little" }
    )
    .into_bytes();
    macro_rules! put {
        ($v:expr) => {
            out.extend_from_slice(&if big { $v.to_be_bytes() } else { $v.to_le_bytes() })
        };
    }
    for p in POS {
        out.push(200);
        put!(p[0] as f32);
        put!(-1.0f64);
        put!(p[1] as f32);
        put!(p[2] as f32);
        out.push(2);
        put!(7i16);
        put!(-7i16);
    }
    for face in [&[0i32, 1, 2, 3][..], &[0, 1, 4], &[1, 1, 2]] {
        put!(0xbeefu16);
        out.push(face.len() as u8);
        for &i in face {
            put!(i);
        }
    }
    put!(0i32);
    put!(1i32);
    out
}

fn all_formats(dir: &Path) -> Vec<(PathBuf, MeshFormat)> {
    let off = "OFF\n# a comment\n5 3 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n0.5 0.5 0.75 # apex\n4 0 1 2 3\n3 0 1 4\n3 1 1 2\n";
    let ply_ascii = "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\n\
                     property uchar alpha\nelement face 3\nproperty list uchar uint vertex_index\nend_header\n\
                     0 0 0 9\n1 0 0 9\n1 1 0 9\n0 1 0 9\n0.5 0.5 0.75 9\n4 0 1 2 3\n3 0 1 4\n3 1 1 2\n";
    // Corner forms v, v/vt, v//vn, v/vt/vn and negative indices; a group in between.
    let obj = "# cube\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\ng one\nf 1/1 2//1 3/1/1 -1\n\
               g two\nv 0.5 0.5 0.75\nf 1 2 -1\nf 2 2 3\n";
    vec![
        (write(dir, "m.off", off.as_bytes()), MeshFormat::Off),
        (write(dir, "m_ascii.ply", ply_ascii.as_bytes()), MeshFormat::PlyAscii),
        (write(dir, "m_le.ply", &binary_ply(false)), MeshFormat::PlyBinaryLittleEndian),
        (write(dir, "m_be.ply", &binary_ply(true)), MeshFormat::PlyBinaryBigEndian),
        (write(dir, "m.obj", obj.as_bytes()), MeshFormat::Obj),
        (write(dir, "m.off.gz", &gzip(off.as_bytes())), MeshFormat::Off),
        (write(dir, "m.ply.gz", &gzip(&binary_ply(true))), MeshFormat::PlyBinaryBigEndian),
        (write(dir, "m.obj.gz", &gzip(obj.as_bytes())), MeshFormat::Obj),
        // Content wins over the extension.
        (write(dir, "misnamed.obj", off.as_bytes()), MeshFormat::Off),
    ]
}

#[test]
fn every_format_reads_back_to_the_same_triangles() {
    let dir = tempfile::tempdir().unwrap();
    for (path, format) in all_formats(dir.path()) {
        let (m, r) = read_mesh_with_report(&path).unwrap_or_else(|e| panic!("{e}"));
        let name = path.display().to_string();
        assert_eq!(r.format, format, "{name}");
        assert_eq!(r.gzip, name.ends_with(".gz"), "{name}");
        assert_eq!(m.positions, POS.to_vec(), "{name}");
        assert_eq!(m.triangles, EXPECTED.to_vec(), "{name}");
        assert_eq!((r.faces, r.degenerate_dropped), (3, 1), "{name}");
    }
}

#[test]
fn written_ply_reads_back_identically_in_every_encoding() {
    let dir = tempfile::tempdir().unwrap();
    // Values that are not exact in f32, to catch any narrowing.
    let mesh = Mesh {
        positions: vec![[0.1, -2.5e-7, 1e300], [std::f64::consts::PI, 2.0, -3.0], [4.0, 5.0, 6.000000000001]],
        triangles: vec![[0, 1, 2], [2, 1, 0]],
    };
    for (enc, format) in [
        (PlyEncoding::Ascii, MeshFormat::PlyAscii),
        (PlyEncoding::BinaryLittleEndian, MeshFormat::PlyBinaryLittleEndian),
        (PlyEncoding::BinaryBigEndian, MeshFormat::PlyBinaryBigEndian),
    ] {
        let p = write(dir.path(), "w.ply", &write_ply_bytes(&mesh, enc, "test"));
        let (back, r) = read_mesh_with_report(&p).unwrap();
        assert_eq!(r.format, format);
        assert_eq!(back, mesh, "{enc:?}");
    }
}

/// A 7 x 5 ESRI ASCII grid converted to a terrain file (padded to 9 x 9; valid window 7 x 5).
fn small_terrain(dir: &Path) -> PathBuf {
    let mut asc = String::from("ncols 7\nnrows 5\nxllcorner 0\nyllcorner 0\ncellsize 10\nNODATA_value -9999\n");
    for r in 0..5 {
        let row: Vec<String> = (0..7).map(|c| format!("{}", 100 + 3 * r + c * c)).collect();
        asc += &(row.join(" ") + "\n");
    }
    let dem = write(dir, "small.asc", asc.as_bytes());
    let out = dir.join("small.relief");
    convert(&dem, &out, &ConvertOptions::new(LayoutKind::Hz)).unwrap();
    out
}

#[test]
fn from_terrain_round_trips_through_binary_ply() {
    let dir = tempfile::tempdir().unwrap();
    let terrain = small_terrain(dir.path());
    let f = TerrainFile::open(&terrain).unwrap();
    let [x0, y0, x1, y1] = f.header().valid_window;
    let (w, h) = ((x1 - x0) as usize, (y1 - y0) as usize);
    assert_eq!((w, h), (7, 5));
    let [sx, sy] = f.header().spacing_m;

    let mesh = terrain_mesh(&f, 1).unwrap();
    assert_eq!(mesh.positions.len(), w * h);
    assert_eq!(mesh.triangles.len(), 2 * (w - 1) * (h - 1));
    check_sane("terrain", &mesh);
    // World metres: corner posts and heights.
    assert_eq!(mesh.positions[0], [x0 as f64 * sx, y0 as f64 * sy, f.record_at(x0, y0).unwrap().z as f64]);
    let last = (x1 - 1, y1 - 1);
    assert_eq!(
        mesh.positions[w * h - 1],
        [last.0 as f64 * sx, last.1 as f64 * sy, f.record_at(last.0, last.1).unwrap().z as f64]
    );

    // Through the CLI: binary little-endian PLY, read back identically.
    let ply = dir.path().join("small.ply");
    let out = Command::new(env!("CARGO_BIN_EXE_relief"))
        .args(["mesh".as_ref(), "from-terrain".as_ref(), terrain.as_os_str(), ply.as_os_str()])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let (back, r) = read_mesh_with_report(&ply).unwrap();
    assert_eq!(r.format, MeshFormat::PlyBinaryLittleEndian);
    assert_eq!(back, mesh);
    // No temporary file left beside it.
    let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(names.len(), 3, "{names:?}");

    // Every N-th post, the last row and column kept: 7 x 5 posts → 4 x 3 (step 2), 3 x 2 (step 4).
    for (step, pw, ph) in [(2, 4, 3), (4, 3, 2), (100, 2, 2)] {
        let m = terrain_mesh(&f, step).unwrap();
        assert_eq!(m.positions.len(), pw * ph, "step {step}");
        assert_eq!(m.triangles.len(), 2 * (pw - 1) * (ph - 1), "step {step}");
        // Same x, y extent as the full mesh: the window's edges are kept.
        let (b, full) = (m.bounds().unwrap(), mesh.bounds().unwrap());
        assert_eq!((&b.min[..2], &b.max[..2]), (&full.min[..2], &full.max[..2]), "step {step}");
    }
}

/// The full one-line message (`FILE: problem`) of reading `bytes` as `name`.
fn error_of(dir: &Path, name: &str, bytes: &[u8]) -> String {
    let p = write(dir, name, bytes);
    let e = read_mesh(&p).expect_err(name).to_string();
    assert!(!e.contains('\n'), "{e}");
    let prefix = format!("{}: ", p.display());
    e.strip_prefix(&prefix).unwrap_or_else(|| panic!("'{e}' does not name the file")).to_string()
}

#[test]
fn malformed_inputs_give_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let le = binary_ply(false);
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("empty.ply", vec![], "empty file"),
        ("truncated.ply", le[..le.len() - 10].to_vec(), "truncated PLY data: element 'face' 2 of 3"),
        ("truncated_vertices.ply", le[..le.len() - 77].to_vec(), "truncated PLY data: element 'vertex' 4 of 5"),
        ("bad_header.off", b"OFF\n5 three 0\n".to_vec(), "bad OFF header (line 2): face count 'three' is not a count"),
        (
            "bad_magic.off",
            b"# c\nOFX\n1 1 0\n".to_vec(),
            "unknown mesh format (expected a 'ply' or 'OFF' header, or an .obj file)",
        ),
        ("coff.off", b"COFF\n1 1 0\n".to_vec(), "unsupported OFF variant (only plain 'OFF' is read)"),
        (
            "range.off",
            b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n".to_vec(),
            "face 0: vertex index 3 out of range (3 vertices)",
        ),
        ("nan.off", b"OFF\n3 1 0\n0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n".to_vec(), "vertex 1: non-finite coordinate NaN"),
        ("short.off", b"OFF\n3 1 0\n0 0 0\n1 0 0\n".to_vec(), "truncated OFF: 2 of 3 vertices"),
        ("none.off", b"OFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n".to_vec(), "no triangles (no faces)"),
        (
            "degenerate.off",
            b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 1\n".to_vec(),
            "no triangles (every face is degenerate)",
        ),
        (
            "range.ply",
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
              element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 -1\n"
                .to_vec(),
            "face 0: vertex index -1 out of range (3 vertices)",
        ),
        (
            "inf.ply",
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
              element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 inf 0\n0 1 0\n3 0 1 2\n"
                .to_vec(),
            "vertex 1: non-finite coordinate inf",
        ),
        ("noend.ply", b"ply\nformat ascii 1.0\nelement vertex 3\n".to_vec(), "bad PLY header: no 'end_header' line"),
        (
            "noxyz.ply",
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n0 0\n".to_vec(),
            "bad PLY header: the vertex element has no scalar property 'z'",
        ),
        (
            "range.obj",
            b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n".to_vec(),
            "line 4: vertex index 4 out of range (3 vertices)",
        ),
        ("nan.obj", b"v 0 0 0\nv NaN 0 0\n".to_vec(), "line 2: vertex 1: non-finite coordinate NaN"),
        ("bad.gz", vec![0x1f, 0x8b, 8, 0, 0, 0], "gzip: unexpected end of file"),
    ];
    let mut failures = Vec::new();
    for (name, bytes, want) in cases {
        let got = error_of(d, name, &bytes);
        if got != want {
            failures.push(format!("{name}: got '{got}', want '{want}'"));
        }
    }
    assert!(failures.is_empty(), "\n{}", failures.join("\n"));

    // The CLI prints the same as one line, prefixed with `relief: `.
    let p = d.join("range.off");
    let out = Command::new(env!("CARGO_BIN_EXE_relief"))
        .args(["mesh".as_ref(), "info".as_ref(), p.as_os_str()])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(stderr.trim_end(), format!("relief: {}: face 0: vertex index 3 out of range (3 vertices)", p.display()));
}

#[test]
fn mesh_info_cli_reports_counts_as_json() {
    let out = Command::new(env!("CARGO_BIN_EXE_relief"))
        .args(["mesh".as_ref(), "info".as_ref(), real_mesh("bunny.off").as_os_str(), "--json".as_ref()])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["vertices"], 37_706);
    assert_eq!(v["triangles"], 75_408);
    assert_eq!(v["degenerate_dropped"], 0);
    assert_eq!(v["format"], "off");
}
