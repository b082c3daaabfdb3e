//! The streamed readers against the readers they replaced ([`super::reference`], kept verbatim):
//! the same mesh (bit for bit), report and one-line message on real meshes in every format,
//! generated meshes in common and odd PLY layouts, malformed files and thousands of mutations of
//! small files, each read whole and in chunks of a few bytes (so that every line, token and
//! record is cut by a chunk's end somewhere); and the scanners against the `str` methods.

use std::io::Write;
use std::path::{Path, PathBuf};

use super::input::{Utf8Check, CHUNK};
use super::text::{parse_f64, parse_i64, parse_u32, parse_usize, Words};
use super::{read_chunked, read_mesh_with_report, reference, write_ply_bytes, Mesh, MeshFormat, PlyEncoding};

fn real_mesh(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/mesh").join(name)
}

/// xorshift64*: reproducible pseudo-random numbers.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

/// A read's outcome: the positions' bits, the triangles and the report, or the message.
type Outcome = Result<(Vec<[u64; 3]>, Vec<[u32; 3]>, String), String>;

/// The outcome of a read as comparable text: the mesh's bits and the report, or the message.
fn outcome(r: crate::error::Result<(Mesh, super::MeshReport)>) -> Outcome {
    match r {
        Ok((m, report)) => {
            let bits = m.positions.iter().map(|p| p.map(f64::to_bits)).collect();
            Ok((bits, m.triangles, format!("{report:?}")))
        }
        Err(e) => Err(e.to_string()),
    }
}

/// Reads `path` with the reference and with the streamed reader in every chunk size given;
/// panics on any difference. Returns the reference's outcome.
fn same(path: &Path, chunks: &[usize]) -> Outcome {
    let want = outcome(reference::read_mesh_with_report(path));
    for &chunk in chunks {
        let got = outcome(read_chunked(path, chunk));
        if got != want {
            let show = |o: &Outcome| match o {
                Ok((p, t, r)) => format!("mesh of {} vertices, {} triangles, {r}", p.len(), t.len()),
                Err(e) => e.clone(),
            };
            panic!("{} (chunk {chunk}):\n  reference: {}\n  streamed:  {}", path.display(), show(&want), show(&got));
        }
    }
    want
}

fn obj_bytes(m: &Mesh) -> Vec<u8> {
    let mut out = b"# obj\n".to_vec();
    for p in &m.positions {
        writeln!(out, "v {} {} {}", p[0], p[1], p[2]).unwrap();
    }
    for t in &m.triangles {
        writeln!(out, "f {} {}/1 {}//2", t[0] + 1, t[1] + 1, t[2] + 1).unwrap();
    }
    out
}

fn off_bytes(m: &Mesh) -> Vec<u8> {
    let mut out = format!("OFF\n# off\n{} {} 0\n", m.positions.len(), m.triangles.len()).into_bytes();
    for p in &m.positions {
        writeln!(out, "{} {} {}", p[0], p[1], p[2]).unwrap();
    }
    for t in &m.triangles {
        writeln!(out, "3 {} {} {}", t[0], t[1], t[2]).unwrap();
    }
    out
}

/// A binary PLY in a layout no fast path takes (the general path reads every record): vertices
/// with a colour between the coordinates and a list, faces with an `ushort`-counted `uint`
/// index list and a second list.
fn odd_ply(m: &Mesh, big: bool) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat binary_{}_endian 1.0\nelement vertex {}\nproperty double x\nproperty double y\n\
         property uchar red\nproperty double z\nproperty list uchar float extra\nelement face {}\n\
         property list ushort uint vertex_indices\nproperty list uchar float weights\nend_header\n",
        if big { "big" } else { "little" },
        m.positions.len(),
        m.triangles.len()
    )
    .into_bytes();
    macro_rules! put {
        ($v:expr) => {
            out.extend_from_slice(&if big { $v.to_be_bytes() } else { $v.to_le_bytes() })
        };
    }
    for p in &m.positions {
        put!(p[0]);
        put!(p[1]);
        out.push(7);
        put!(p[2]);
        out.push(1);
        put!(0.5f32);
    }
    for t in &m.triangles {
        put!(3u16);
        for i in t {
            put!(*i);
        }
        out.push(0);
    }
    out
}

/// A binary PLY in the fast layouts with extra scalars: `float` x, y, z among others, faces with
/// a flag before and after an `int`-counted `int` list; and an extra element.
fn float_ply(m: &Mesh, big: bool) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat binary_{}_endian 1.0\nelement vertex {}\nproperty uchar a\nproperty float x\n\
         property float y\nproperty short b\nproperty float z\nelement face {}\nproperty uchar flag\n\
         property list int int vertex_indices\nproperty ushort flag2\nelement edge 2\nproperty int v1\n\
         property int v2\nend_header\n",
        if big { "big" } else { "little" },
        m.positions.len(),
        m.triangles.len()
    )
    .into_bytes();
    macro_rules! put {
        ($v:expr) => {
            out.extend_from_slice(&if big { $v.to_be_bytes() } else { $v.to_le_bytes() })
        };
    }
    for p in &m.positions {
        out.push(1);
        put!(p[0] as f32);
        put!(p[1] as f32);
        put!(-3i16);
        put!(p[2] as f32);
    }
    for t in &m.triangles {
        out.push(9);
        put!(3i32);
        for i in t {
            put!(*i as i32);
        }
        put!(1u16);
    }
    for v in [0i32, 1, 1, 2] {
        put!(v);
    }
    out
}

/// Every encoding of `m`: (file name, bytes).
fn encodings(m: &Mesh) -> Vec<(&'static str, Vec<u8>)> {
    vec![
        ("le.ply", write_ply_bytes(m, PlyEncoding::BinaryLittleEndian, "t")),
        ("be.ply", write_ply_bytes(m, PlyEncoding::BinaryBigEndian, "t")),
        ("ascii.ply", write_ply_bytes(m, PlyEncoding::Ascii, "t")),
        ("m.obj", obj_bytes(m)),
        ("m.off", off_bytes(m)),
        ("odd_le.ply", odd_ply(m, false)),
        ("odd_be.ply", odd_ply(m, true)),
        ("float_le.ply", float_ply(m, false)),
        ("float_be.ply", float_ply(m, true)),
    ]
}

/// The real meshes in every format, plain and gzip'd: the streamed reader gives the reference's
/// mesh, which is the original mesh (bit-identical), on the fast and the general PLY paths.
#[test]
fn real_meshes_read_identically_in_every_format() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["bunny.off", "armadillo.off", "dragon_202k.ply.gz"] {
        let path = real_mesh(name);
        same(&path, &[CHUNK, 4096]).unwrap();
        let (m, _) = read_mesh_with_report(&path).unwrap();
        for (suffix, bytes) in encodings(&m) {
            for gz in [false, true] {
                let file = dir.path().join(format!("{name}.{suffix}{}", if gz { ".gz" } else { "" }));
                std::fs::write(&file, if gz { gzip(&bytes) } else { bytes.clone() }).unwrap();
                same(&file, &[CHUNK, 4093]).unwrap();
                let (back, report) = read_mesh_with_report(&file).unwrap_or_else(|e| panic!("{e}"));
                assert_eq!(report.gzip, gz);
                assert_eq!(back.triangles, m.triangles, "{}", file.display());
                if suffix.starts_with("float") {
                    let narrowed: Vec<[f64; 3]> = m.positions.iter().map(|p| p.map(|c| c as f32 as f64)).collect();
                    assert_eq!(back.positions, narrowed, "{}", file.display());
                } else {
                    let bits = |v: &[[f64; 3]]| v.iter().map(|p| p.map(f64::to_bits)).collect::<Vec<_>>();
                    assert_eq!(bits(&back.positions), bits(&m.positions), "{}", file.display());
                }
            }
        }
    }
}

/// A small mesh with awkward numbers, a quad and a degenerate face.
fn small_mesh() -> Mesh {
    let mut positions = Vec::new();
    for j in 0..5 {
        for i in 0..6 {
            let (x, y) = (i as f64 * 0.1, j as f64 * -0.37);
            positions.push([x, y, (x * 7.3).sin() * 1e-3 + (y * 1e3).cos() * 1e5]);
        }
    }
    positions.push([1e30, -2.5e-30, 5e-324]);
    let mut triangles = Vec::new();
    for j in 0..4 {
        for i in 0..5 {
            let a = j * 6 + i;
            triangles.push([a, a + 1, a + 7]);
            triangles.push([a, a + 7, a + 6]);
        }
    }
    triangles.push([30, 0, 1]);
    triangles.push([2, 2, 3]);
    Mesh { positions, triangles }
}

/// Hand-written files with comments, quads, continuation lines, CRLF, odd spaces and tokens.
fn handmade() -> Vec<(&'static str, Vec<u8>)> {
    let v = vec![
        ("a.off", &b"OFF\n# a comment\n5 3 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n0.5 0.5 0.75 # apex\n4 0 1 2 3\n3 0 1 4\n3 1 1 2\n"[..]),
        ("b.off", b"  # lead\r\n\r\nOFF 4 2 0\r\n0 0 0 255 0 0\r\n\x0b1 0 0\r\n  1 1 0 \x0b\r\n0 1 0\r\n\r\n3 0 1 2 9\r\n3 0 2 3"),
        ("c.off", "OFF\n3 1 0\n\u{3000}\n0 0 0\n1e0 +0 -0\n.5 5. 0\n3 0 +1 2\n".as_bytes()),
        ("d.off", b"OFF\n\n3 1\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"),
        ("e.obj", b"# cube\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\ng one\nf 1/1 2//1 3/1/1 -1\ng two\nv 0.5 0.5 0.75\nf 1 2 -1\nf 2 2 3\n"),
        ("f.obj", b"v 0 0 0\r\nv 1 \\\r\n 0 0\r\nv 0 1 0 1\\\nf 1 2 \\\n3\nf +1 2 3 # c\nf -3 -2 -1\\\n"),
        ("g.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\\\n"),
        ("h.ply", b"ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\nproperty uchar alpha\nelement face 3\nproperty list uchar uint vertex_index\nend_header\n0 0 0 9\n1 0 0 9\n1 1 0 9\n0 1 0 9\n0.5 0.5 0.75 9\n4 0 1 2 3\n3 0 1 4\n3 1 1 2\n"),
        ("i.ply", b"ply\r\nformat ascii 1.0\r\ncomment x\r\nelement vertex 3\r\nproperty double x\r\nproperty double y\r\nproperty double z\r\nelement face 1\r\nproperty list int int vertex_indices\r\nend_header\r\n  0\t0 0\r\n1e0 0 0 0 1.0\n0\r\n3.0 0 1 2e0\r\n trailing"),
    ];
    v.into_iter().map(|(n, b)| (n, b.to_vec())).collect()
}

/// The malformed inputs of the app's mesh_io test, with their messages, and more.
#[test]
fn malformed_inputs_give_the_same_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let le = float_ply(&small_mesh(), false);
    let ascii = write_ply_bytes(&small_mesh(), PlyEncoding::Ascii, "t");
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("empty.ply", vec![], "empty file"),
        ("truncated.ply", le[..le.len() - 10].to_vec(), "truncated PLY data: element 'edge' 0 of 2"),
        ("truncated_faces.ply", le[..le.len() - 30].to_vec(), "truncated PLY data: element 'face' 41 of 42"),
        ("truncated_vertices.ply", le[..400].to_vec(), "truncated PLY data: element 'vertex' 7 of 31"),
        ("truncated_ascii.ply", ascii[..ascii.len() - 9].to_vec(), "truncated PLY data: element 'face' 41 of 42"),
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
            "range.ply",
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
              element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 -1\n"
                .to_vec(),
            "face 0: vertex index -1 out of range (3 vertices)",
        ),
        ("noend.ply", b"ply\nformat ascii 1.0\nelement vertex 3\n".to_vec(), "bad PLY header: no 'end_header' line"),
        (
            "range.obj",
            b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n".to_vec(),
            "line 4: vertex index 4 out of range (3 vertices)",
        ),
        ("nan.obj", b"v 0 0 0\nv NaN 0 0\n".to_vec(), "line 2: vertex 1: non-finite coordinate NaN"),
        ("bad.gz", vec![0x1f, 0x8b, 8, 0, 0, 0], "gzip: unexpected end of file"),
        (
            "text.obj",
            b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n# \xff\n".to_vec(),
            "OBJ is not text (invalid utf-8 sequence of 1 bytes from index 34)",
        ),
        (
            "text.off",
            b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 9\n\xe2\x82".to_vec(),
            "OFF is not text (incomplete utf-8 byte sequence from index 36)",
        ),
    ];
    let mut failures = Vec::new();
    for (name, bytes, want) in cases {
        for gz in [false, true] {
            if gz && (bytes.is_empty() || name.ends_with(".gz")) {
                continue;
            }
            let p = dir.path().join(if gz { format!("{name}.gz") } else { name.to_string() });
            std::fs::write(&p, if gz { gzip(&bytes) } else { bytes.clone() }).unwrap();
            let got = same(&p, &[CHUNK, 1, 5]).expect_err(name);
            let got = got.strip_prefix(&format!("{}: ", p.display())).unwrap_or(&got).to_string();
            let want = if gz && want == "empty file" { "empty file (inside gzip)" } else { want };
            if got != want {
                failures.push(format!("{name} (gzip {gz}): got '{got}', want '{want}'"));
            }
        }
    }
    assert!(failures.is_empty(), "\n{}", failures.join("\n"));
}

/// Small files in every format, then thousands of mutations of them (cut short, a byte replaced
/// by one that matters to some parser, bytes inserted), plain and gzip'd: the reference's outcome
/// every time, read whole and in chunks of 1, 2, 7 and 64 bytes.
#[test]
fn mutated_files_read_as_the_reference_reads_them() {
    let dir = tempfile::tempdir().unwrap();
    let mut bases = encodings(&small_mesh());
    bases.extend(handmade());
    let special = b"0123456789 \t\r\n\x0b\x0c#\\/-+.eExnaif\x00\x80\xc3\xff";
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let (mut ok, mut failed) = (0, 0);
    for (name, base) in &bases {
        let chunks: &[usize] = &[CHUNK, 1, 2, 7, 64];
        let p = dir.path().join(name);
        std::fs::write(&p, base).unwrap();
        same(&p, chunks).unwrap_or_else(|e| panic!("{name}: {e}"));
        for k in 0..250 {
            let mut bytes = base.clone();
            match k % 4 {
                0 => bytes.truncate(rng.below(bytes.len() + 1)),
                1 | 2 => {
                    let at = rng.below(bytes.len());
                    bytes[at] = special[rng.below(special.len())];
                }
                _ => {
                    let at = rng.below(bytes.len() + 1);
                    let n = 1 + rng.below(3);
                    let ins: Vec<u8> = (0..n).map(|_| special[rng.below(special.len())]).collect();
                    bytes.splice(at..at, ins);
                }
            }
            let gz = k % 5 == 4;
            let file = dir.path().join(format!("m{k}_{name}{}", if gz { ".gz" } else { "" }));
            std::fs::write(&file, if gz { gzip(&bytes) } else { bytes }).unwrap();
            match same(&file, if gz { &chunks[..3] } else { chunks }) {
                Ok(_) => ok += 1,
                Err(_) => failed += 1,
            }
            std::fs::remove_file(&file).unwrap();
        }
    }
    // Both kinds of outcome were exercised.
    assert!(ok > 500 && failed > 500, "{ok} read, {failed} failed");
}

/// Corrupt gzip streams: cut or with a byte changed, anywhere (the header, the deflate data,
/// the trailer's checksum and length).
#[test]
fn corrupt_gzip_streams_fail_as_before() {
    let dir = tempfile::tempdir().unwrap();
    let base = gzip(&write_ply_bytes(&small_mesh(), PlyEncoding::BinaryBigEndian, "gz"));
    let mut rng = Rng(7);
    for k in 0..200 {
        let mut bytes = base.clone();
        if k % 2 == 0 {
            bytes.truncate(2 + rng.below(bytes.len() - 2));
        } else {
            let at = 2 + rng.below(bytes.len() - 2);
            bytes[at] ^= 1 << rng.below(8);
        }
        let file = dir.path().join(format!("c{k}.ply.gz"));
        std::fs::write(&file, &bytes).unwrap();
        let _ = same(&file, &[CHUNK, 3]);
    }
    // Two members read as one stream.
    let mut two = gzip(b"OFF\n3 1 0\n0 0 0\n");
    two.extend(gzip(b"1 0 0\n0 1 0\n3 0 1 2\n"));
    let file = dir.path().join("two.off.gz");
    std::fs::write(&file, two).unwrap();
    assert!(same(&file, &[CHUNK, 1]).is_ok());
}

#[test]
fn number_parsing_matches_str_parse() {
    let mut tokens: Vec<String> = [
        "0",
        "-0",
        "+0",
        "00",
        "1",
        "+1",
        "-1",
        "1.",
        ".5",
        "-.5",
        "+.5",
        ".",
        "-",
        "+",
        "",
        "e",
        "1e",
        "1e+",
        "1e-",
        "1e5",
        "1E-5",
        "1e+05",
        "1.5e3",
        "-1.5E-3x",
        "1.2.3",
        "1_0",
        "0x10",
        "inf",
        "-inf",
        "+inf",
        "Inf",
        "INFINITY",
        "infinity",
        "infinit",
        "nan",
        "NaN",
        "-nan",
        "+NaN",
        "nan(1)",
        "1e400",
        "-1e400",
        "1e-400",
        "4.9e-324",
        "2.4703282292062327e-324",
        "2.4703282292062328e-324",
        "1.7976931348623157e308",
        "1.7976931348623159e308",
        "9007199254740993",
        "9007199254740992",
        "18446744073709551616",
        "4294967295",
        "4294967296",
        "999999999",
        "9999999999",
        "123456789012345678",
        "1234567890123456789",
        "-9223372036854775808",
        "9223372036854775808",
        "0.30000000000000004",
        "3.141592653589793238462643383279",
        "1\u{b}",
        "\u{3000}1",
        "１",
        "1 ",
        " 1",
        "--1",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let mut rng = Rng(42);
    let alphabet = b"0123456789.eE+-";
    for _ in 0..20_000 {
        let n = 1 + rng.below(24);
        let t: String = (0..n)
            .map(|i| {
                let c = if i > 0 && rng.below(3) > 0 { b'0' + rng.below(10) as u8 } else { alphabet[rng.below(15)] };
                c as char
            })
            .collect();
        tokens.push(t);
        let v = f64::from_bits(rng.next());
        tokens.push(format!("{v}"));
        tokens.push(format!("{v:e}"));
        tokens.push(format!("{}", rng.next() >> rng.below(64)));
    }
    for t in &tokens {
        let b = t.as_bytes();
        let std_f64 = t.parse::<f64>().ok();
        assert_eq!(parse_f64(b).map(f64::to_bits), std_f64.map(f64::to_bits), "f64 '{t}'");
        assert_eq!(parse_u32(b), t.parse::<u32>().ok(), "u32 '{t}'");
        assert_eq!(parse_usize(b), t.parse::<usize>().ok(), "usize '{t}'");
        assert_eq!(parse_i64(b), t.parse::<i64>().ok(), "i64 '{t}'");
    }
    assert_eq!(parse_f64(b"\xff"), None);
}

#[test]
fn words_match_split_ascii_whitespace() {
    let mut rng = Rng(3);
    let alphabet = b"ab \t\r\n\x0b\x0c#";
    for _ in 0..5000 {
        let s: String = (0..rng.below(20)).map(|_| alphabet[rng.below(alphabet.len())] as char).collect();
        let want: Vec<&str> = s.split_ascii_whitespace().collect();
        let got: Vec<&str> = Words::new(s.as_bytes()).map(|w| std::str::from_utf8(w).unwrap()).collect();
        assert_eq!(got, want, "{s:?}");
    }
}

/// The incremental check finds `std::str::from_utf8`'s first error, however the text is cut.
#[test]
fn utf8_check_matches_from_utf8_across_pieces() {
    let mut rng = Rng(11);
    let pieces = ["a", "é", "€", "𝄞", "\u{7f}"];
    for _ in 0..5000 {
        let mut text: Vec<u8> = Vec::new();
        for _ in 0..rng.below(12) {
            match rng.below(4) {
                0 => text.push(0x80 + rng.below(0x80) as u8),
                _ => text.extend_from_slice(pieces[rng.below(pieces.len())].as_bytes()),
            }
        }
        if rng.below(3) == 0 && !text.is_empty() {
            let n = rng.below(text.len());
            text.truncate(n);
        }
        let want = std::str::from_utf8(&text).err().map(|e| e.to_string());
        let mut check = Utf8Check::default();
        let (mut at, offset) = (0, 1000 + rng.below(50) as u64);
        while at < text.len() {
            let n = (1 + rng.below(4)).min(text.len() - at);
            check.feed(&text[at..at + n], offset + at as u64);
            at += n;
        }
        if text.is_empty() {
            check.feed(&[], offset);
        }
        assert_eq!(check.end(), want, "{text:x?}");
    }
}

/// Formats detected as before, also when the first word lies past the first chunk.
#[test]
fn formats_are_detected_past_long_comments() {
    let dir = tempfile::tempdir().unwrap();
    let mut off = Vec::new();
    for _ in 0..100 {
        off.extend_from_slice(b"# a comment line that is long enough to span chunks\n");
    }
    off.extend_from_slice(b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
    let p = dir.path().join("long.mesh");
    std::fs::write(&p, &off).unwrap();
    let (_, _, report) = same(&p, &[CHUNK, 1, 16]).unwrap();
    assert!(report.contains(&format!("{:?}", MeshFormat::Off)), "{report}");
}
