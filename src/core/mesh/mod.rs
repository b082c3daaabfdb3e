//! Triangle meshes for the mesh backends: reading OFF, PLY (ASCII, binary little and big endian)
//! and OBJ, each optionally gzip-compressed, and exporting a terrain's valid window as a mesh.
//!
//! Parsers: all three are our own (`off`, `ply`, `obj`), each a few hundred lines at most.
//! - PLY: the Rust crates are not sound enough to build on. `ply-rs` has had no release since
//!   2018 and is unmaintained; its fork `ply-rs-bw` is kept alive but still decodes every element
//!   into a `HashMap<String, Property>` per vertex/face (slow and memory-hungry on large meshes),
//!   and neither reports which element a truncated body broke in. The part we need (x, y, z and
//!   a face index list, everything else skipped by type) is small.
//! - OBJ: `tobj` is maintained and sound, but it splits the file into one model per `o`/`g` and
//!   re-indexes each model's positions, so vertices shared between groups are duplicated and the
//!   file's vertex numbering is lost; the mesh backends need one connected, globally indexed mesh.
//!   We only need `v` and `f` (with `v/vt/vn` forms and negative indices), so we parse them.
//!
//! Whole files are read into memory (decompressed if gzip'd): the inputs of the mesh backends are
//! first converted by them, so only the conversion holds the mesh in memory.
//!
//! Faces with more than three corners are fan-triangulated. Triangles that repeat a vertex index
//! are dropped and counted ([`MeshReport::degenerate_dropped`]); every other problem (bad header,
//! truncated data, index out of range, non-finite coordinate, no triangles) is an [`Error::BadMesh`]
//! naming the file.

pub mod export;
mod input;
mod obj;
mod off;
mod ply;
#[cfg(test)]
mod reference;
mod terrain;
#[cfg(test)]
mod tests;
mod text;

use std::path::Path;

use serde::Serialize;

use crate::error::{Error, IoContext, Result};
use input::{Input, StreamError};

pub use crate::format::Bounds;
pub use ply::{write_ply_binary, write_ply_bytes, PlyEncoding};
pub use terrain::terrain_mesh;

/// An indexed triangle mesh. Units are those of the file (metres for terrains).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<[f64; 3]>,
    /// Counter-clockwise (as stored in the file), every index `< positions.len()`.
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    /// The bounding box of all positions (also unreferenced ones); `None` if there are none.
    pub fn bounds(&self) -> Option<Bounds> {
        let first = *self.positions.first()?;
        let mut b = Bounds { min: first, max: first };
        for p in &self.positions {
            for (k, &c) in p.iter().enumerate() {
                b.min[k] = b.min[k].min(c);
                b.max[k] = b.max[k].max(c);
            }
        }
        Some(b)
    }
}

/// The container and encoding a mesh was read from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MeshFormat {
    Off,
    PlyAscii,
    PlyBinaryLittleEndian,
    PlyBinaryBigEndian,
    Obj,
}

impl MeshFormat {
    pub fn name(self) -> &'static str {
        match self {
            MeshFormat::Off => "OFF",
            MeshFormat::PlyAscii => "PLY (ASCII)",
            MeshFormat::PlyBinaryLittleEndian => "PLY (binary little-endian)",
            MeshFormat::PlyBinaryBigEndian => "PLY (binary big-endian)",
            MeshFormat::Obj => "OBJ",
        }
    }
}

/// What reading a mesh found besides the mesh itself.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MeshReport {
    pub format: MeshFormat,
    pub gzip: bool,
    /// Faces as stored (before fan triangulation and dropping degenerates).
    pub faces: u64,
    /// Triangles dropped because they repeat a vertex index.
    pub degenerate_dropped: u64,
}

/// Reads a mesh, detecting the format from the content (gzip magic, `ply`/`OFF` headers) and
/// falling back to the extension (`.obj`, after an optional `.gz`).
pub fn read_mesh(path: &Path) -> Result<Mesh> {
    read_mesh_with_report(path).map(|(mesh, _)| mesh)
}

/// [`read_mesh`], also returning what was found on the way.
pub fn read_mesh_with_report(path: &Path) -> Result<(Mesh, MeshReport)> {
    read_chunked(path, input::CHUNK)
}

/// [`read_mesh_with_report`], reading `chunk` bytes at a time.
fn read_chunked(path: &Path, chunk: usize) -> Result<(Mesh, MeshReport)> {
    let Some(mut input) = Input::open(path, chunk).at(path)? else {
        return Err(Error::bad_mesh(path, "empty file"));
    };
    let parsed = parse(path, &mut input);
    // Whatever the parser found, a read error, a corrupt gzip stream or text that is not UTF-8
    // anywhere in the input comes first (as when the input was read whole before parsing).
    match input.finish() {
        Some(StreamError::Io(e)) => Err(Error::io(path, e)),
        Some(StreamError::Gzip(e)) => Err(Error::bad_mesh(path, format!("gzip: {e}"))),
        Some(StreamError::NotText(e)) => Err(Error::bad_mesh(path, e)),
        None => parsed.map_err(|e| Error::bad_mesh(path, e)),
    }
}

/// Detects the format and parses the input (read up to where the parser stopped).
fn parse(path: &Path, input: &mut Input) -> Result<(Mesh, MeshReport), String> {
    let gzip = input.is_gzip();
    if !input.more() && input.window().is_empty() {
        // Nothing decompressed: a gzip error, if any, is reported by `finish`.
        return Err("empty file (inside gzip)".into());
    }
    let mut builder = Builder { input_bytes: input.size_hint(), ..Builder::default() };
    input.fill(3);
    let format = if input.window().starts_with(b"ply") {
        ply::parse(input, &mut builder)?
    } else {
        let word = first_word_of(input);
        let word = word.as_deref();
        if word == Some(b"OFF".as_slice()) {
            off::parse(input, &mut builder)?;
            MeshFormat::Off
        } else if is_obj(path, word) {
            obj::parse(input, &mut builder)?;
            MeshFormat::Obj
        } else {
            let what = if word.is_some_and(|w| w.starts_with(b"OFF") || w.ends_with(b"OFF")) {
                "unsupported OFF variant (only plain 'OFF' is read)"
            } else {
                "unknown mesh format (expected a 'ply' or 'OFF' header, or an .obj file)"
            };
            return Err(what.to_string());
        }
    };
    builder.finish(format, gzip)
}

/// The first whitespace-separated word of the file, skipping `#` comment lines.
fn first_word(bytes: &[u8]) -> Option<&[u8]> {
    bytes
        .split(|&b| b == b'\n')
        .map(|line| line.split(|&b| b == b'#').next().unwrap_or_default())
        .flat_map(|line| line.split(|b| b.is_ascii_whitespace()))
        .find(|w| !w.is_empty())
}

/// [`first_word`] of the whole input, reading ahead (nothing consumed) until the word is known.
fn first_word_of(input: &mut Input) -> Option<Vec<u8>> {
    // Lines before `scanned` hold no word.
    let mut scanned = 0;
    loop {
        let w = input.window();
        let complete = match memchr::memrchr(b'\n', &w[scanned..]) {
            Some(i) => scanned + i + 1,
            None => scanned,
        };
        if let Some(word) = first_word(&w[scanned..complete]) {
            return Some(word.to_vec());
        }
        scanned = complete;
        if input.at_end() || !input.more() {
            return first_word(&input.window()[scanned..]).map(<[u8]>::to_vec);
        }
    }
}

/// OBJ has no magic: trust the extension (under an optional `.gz`), else a leading `v`/`o`/`g`
/// statement.
fn is_obj(path: &Path, first_word: Option<&[u8]>) -> bool {
    let name = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    let name = name.strip_suffix(".gz").unwrap_or(&name);
    name.ends_with(".obj") || matches!(first_word, Some(b"v" | b"o" | b"g" | b"vn" | b"vt" | b"mtllib"))
}

/// Collects vertices and faces for every parser, so validation and triangulation are written
/// once.
#[derive(Default)]
struct Builder {
    mesh: Mesh,
    faces: u64,
    degenerate_dropped: u64,
    /// Corners of the face being added (reused).
    corners: Vec<u32>,
    /// Length of the (decompressed) input, which bounds how many elements it can hold.
    input_bytes: usize,
}

impl Builder {
    fn reserve(&mut self, vertices: usize, faces: usize) {
        // Counts come from headers: cap them by what the input can hold (every format spends at
        // least 3 bytes on a vertex or a face), so a small file with a corrupt header cannot ask
        // for gigabytes; the vectors still grow as needed.
        let most = (self.input_bytes / 3).min(1 << 24);
        self.mesh.positions.reserve(vertices.min(most));
        self.mesh.triangles.reserve(faces.min(most));
    }

    #[inline]
    fn vertex(&mut self, p: [f64; 3]) -> Result<(), String> {
        if let Some(bad) = p.iter().find(|c| !c.is_finite()) {
            return Err(format!("vertex {}: non-finite coordinate {bad}", self.mesh.positions.len()));
        }
        self.mesh.positions.push(p);
        Ok(())
    }

    /// Adds the face whose corners were pushed into `corners` (indices already resolved to
    /// 0-based), checking them against the vertices known so far.
    fn face(&mut self, vertex_count: usize) -> Result<(), String> {
        let face = self.faces;
        self.faces += 1;
        if self.corners.len() < 3 {
            return Err(format!("face {face}: {} corners (at least 3 needed)", self.corners.len()));
        }
        if let Some(&i) = self.corners.iter().find(|&&i| i as usize >= vertex_count) {
            return Err(format!("face {face}: vertex index {i} out of range ({vertex_count} vertices)"));
        }
        let c = &self.corners;
        for k in 1..c.len() - 1 {
            let t = [c[0], c[k], c[k + 1]];
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                self.degenerate_dropped += 1;
            } else {
                self.mesh.triangles.push(t);
            }
        }
        Ok(())
    }

    /// [`Builder::face`] of a triangle (the fast paths' common case).
    #[inline]
    fn triangle(&mut self, t: [u32; 3], vertex_count: usize) -> Result<(), String> {
        let face = self.faces;
        self.faces += 1;
        if let Some(&i) = t.iter().find(|&&i| i as usize >= vertex_count) {
            return Err(format!("face {face}: vertex index {i} out of range ({vertex_count} vertices)"));
        }
        if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
            self.degenerate_dropped += 1;
        } else {
            self.mesh.triangles.push(t);
        }
        Ok(())
    }

    fn finish(self, format: MeshFormat, gzip: bool) -> Result<(Mesh, MeshReport), String> {
        if self.mesh.triangles.is_empty() {
            let why = if self.faces == 0 { "no faces" } else { "every face is degenerate" };
            return Err(format!("no triangles ({why})"));
        }
        let report = MeshReport { format, gzip, faces: self.faces, degenerate_dropped: self.degenerate_dropped };
        Ok((self.mesh, report))
    }
}
