//! Mesh ingest (`mesh::read_mesh`): bytes of (decompressed) input per second for every format, on
//! a SYNTHETIC grid mesh (a height field of sines as an indexed triangle mesh, generated in
//! memory; not real data).
//!
//! Three modes, one binary:
//! - plain `cargo bench -p relief-core --bench mesh_ingest`: criterion, a 257² grid (66 k vertices,
//!   131 k triangles: 3–8 MB per format) written to a temporary directory and read back
//!   (Throughput::Bytes of the decompressed file);
//! - `RELIEF_INGEST_WRITE=DIR [RELIEF_INGEST_SIDE=2049]`: writes the large SYNTHETIC inputs
//!   (`synthetic_{binary.ply, ascii.ply, obj.obj, off.off, binary.ply.gz}`) into DIR;
//! - `RELIEF_INGEST_FILES=DIR`: reads every `synthetic_*` file of DIR three times and prints the
//!   median MB/s (10^6 bytes of decompressed input per second) as a Markdown table row.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

use criterion::{BenchmarkId, Criterion, Throughput};
use relief_core::mesh::{read_mesh_with_report, write_ply_bytes, Mesh, PlyEncoding};

/// A SYNTHETIC `side`² grid mesh: x and y on a 0.05 spacing, z a sum of sines (full-precision
/// doubles, so ASCII files carry up to 17 significant digits).
fn synthetic(side: u32) -> Mesh {
    let mut positions = Vec::with_capacity((side * side) as usize);
    for j in 0..side {
        for i in 0..side {
            let (x, y) = (i as f64 * 0.05, j as f64 * 0.05);
            positions.push([x, y, 3.0 * (x * 0.37).sin() * (y * 0.23).cos() + 0.1 * (x * 2.1).sin()]);
        }
    }
    let mut triangles = Vec::with_capacity(2 * ((side - 1) * (side - 1)) as usize);
    for j in 0..side - 1 {
        for i in 0..side - 1 {
            let a = j * side + i;
            triangles.push([a, a + 1, a + side + 1]);
            triangles.push([a, a + side + 1, a + side]);
        }
    }
    Mesh { positions, triangles }
}

fn obj_bytes(m: &Mesh) -> Vec<u8> {
    let mut out = Vec::with_capacity(m.positions.len() * 40 + m.triangles.len() * 30);
    writeln!(out, "# SYNTHETIC grid mesh").unwrap();
    for p in &m.positions {
        writeln!(out, "v {} {} {}", p[0], p[1], p[2]).unwrap();
    }
    for t in &m.triangles {
        writeln!(out, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1).unwrap();
    }
    out
}

fn off_bytes(m: &Mesh) -> Vec<u8> {
    let mut out = Vec::with_capacity(m.positions.len() * 40 + m.triangles.len() * 30);
    writeln!(out, "OFF\n# SYNTHETIC grid mesh\n{} {} 0", m.positions.len(), m.triangles.len()).unwrap();
    for p in &m.positions {
        writeln!(out, "{} {} {}", p[0], p[1], p[2]).unwrap();
    }
    for t in &m.triangles {
        writeln!(out, "3 {} {} {}", t[0], t[1], t[2]).unwrap();
    }
    out
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

/// Every SYNTHETIC input: file name and content.
fn inputs(m: &Mesh) -> Vec<(&'static str, Vec<u8>)> {
    let binary = write_ply_bytes(m, PlyEncoding::BinaryLittleEndian, "SYNTHETIC grid mesh");
    let gz = gzip(&binary);
    vec![
        ("synthetic_binary.ply", binary),
        ("synthetic_ascii.ply", write_ply_bytes(m, PlyEncoding::Ascii, "SYNTHETIC grid mesh")),
        ("synthetic_obj.obj", obj_bytes(m)),
        ("synthetic_off.off", off_bytes(m)),
        ("synthetic_binary.ply.gz", gz),
    ]
}

/// Bytes of input the parser sees: the file, decompressed if gzip'd.
fn decompressed_len(path: &Path) -> u64 {
    let raw = std::fs::read(path).unwrap();
    if raw.starts_with(&[0x1f, 0x8b]) {
        let mut n = 0u64;
        let mut d = flate2::read::MultiGzDecoder::new(&raw[..]);
        let mut buf = vec![0u8; 1 << 20];
        loop {
            match d.read(&mut buf).unwrap() {
                0 => break n,
                k => n += k as u64,
            }
        }
    } else {
        raw.len() as u64
    }
}

fn write_inputs(dir: &Path) {
    let side = std::env::var("RELIEF_INGEST_SIDE").map_or(2049, |s| s.parse().expect("RELIEF_INGEST_SIDE"));
    std::fs::create_dir_all(dir).unwrap();
    let m = synthetic(side);
    for (name, bytes) in inputs(&m) {
        std::fs::write(dir.join(name), &bytes).unwrap();
        println!("{name}: {} bytes", bytes.len());
    }
}

fn time_files(dir: &Path) {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.file_name().unwrap().to_string_lossy().starts_with("synthetic_"))
        .collect();
    files.sort();
    println!("| input | bytes (decompressed) | vertices | triangles | run 1 s | run 2 s | run 3 s | median MB/s |");
    println!("|---|---|---|---|---|---|---|---|");
    for path in files {
        let bytes = decompressed_len(&path);
        let mut runs = Vec::new();
        let mut counts = (0, 0);
        for _ in 0..3 {
            let start = Instant::now();
            let (m, _) = read_mesh_with_report(&path).unwrap_or_else(|e| panic!("{e}"));
            runs.push(start.elapsed().as_secs_f64());
            counts = (m.positions.len(), m.triangles.len());
            drop(m);
        }
        let mut sorted = runs.clone();
        sorted.sort_by(f64::total_cmp);
        println!(
            "| {} | {bytes} | {} | {} | {:.3} | {:.3} | {:.3} | {:.0} |",
            path.file_name().unwrap().to_string_lossy(),
            counts.0,
            counts.1,
            runs[0],
            runs[1],
            runs[2],
            bytes as f64 / sorted[1] / 1e6
        );
    }
}

fn bench(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let m = synthetic(257);
    let mut g = c.benchmark_group("mesh_ingest");
    g.sample_size(10);
    for (name, bytes) in inputs(&m) {
        let path = dir.path().join(name);
        std::fs::write(&path, &bytes).unwrap();
        g.throughput(Throughput::Bytes(decompressed_len(&path)));
        g.bench_function(BenchmarkId::new("read_mesh", name), |b| {
            b.iter(|| read_mesh_with_report(std::hint::black_box(&path)).unwrap())
        });
    }
    g.finish();
}

fn main() {
    if let Some(dir) = std::env::var_os("RELIEF_INGEST_WRITE") {
        return write_inputs(Path::new(&dir));
    }
    if let Some(dir) = std::env::var_os("RELIEF_INGEST_FILES") {
        return time_files(Path::new(&dir));
    }
    let mut c = Criterion::default().configure_from_args();
    bench(&mut c);
    c.final_summary();
}
