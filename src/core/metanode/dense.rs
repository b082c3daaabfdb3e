//! The out-of-core build's vertex and triangle records ([`super::build`]), by dense id in three
//! unlinked scratch files read and written with positioned I/O.
//!
//! Vertex and triangle ids are dense (vertices: the n leaves, then one per collapse, below 2n;
//! triangles 0..t) and never reused, so they need no search tree: record `i` sits at byte
//! `i · size`. One `pread` of a record replaces a B-tree descent through pages that at a small
//! budget are rarely in redb's cache (profiled: nearly half of an out-of-core batch went to the
//! vertex and triangle tables). The kernel's page cache holds the files as it holds redb's,
//! outside the build's memory; the edge B-tree, which needs order, stays in redb.
//!
//! - `vertices`: per vertex, its state ([`STATE_BYTES`]), one more than the length of its
//!   triangle list (0: never written, the file's hole; [`DEAD`] once collapsed) and the list's
//!   offset in `lists`.
//! - `lists`: triangle-id lists, appended (a vertex written back gets a new list; the old one
//!   is garbage, a few bytes per load).
//! - `triangles`: per triangle, its current corners then its input corners; current corner 0 is
//!   [`DEAD`] once it died.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

use super::simplify::VertexState;
use crate::error::{Error, IoContext, Result};

/// Bytes of a vertex state record: position, quadric, switch, radius (f64), leaves (u32).
pub const STATE_BYTES: usize = 8 * (3 + 10 + 2) + 4;
/// Bytes of a vertex record: the state, the list's length + 1 (u32) and offset (u64).
const VERTEX_BYTES: usize = STATE_BYTES + 4 + 8;
/// Bytes of a triangle record: current corners, input corners.
const TRIANGLE_BYTES: usize = 24;
/// Marks a collapsed vertex (list length) or a dead triangle (corner 0).
const DEAD: u32 = u32::MAX;
/// Buffer of the sequential passes (ingest, assembly), bytes.
const STREAM_BYTES: usize = 64 << 10;

/// The records of the build ([`super::build`]'s module docs).
pub struct DenseRecords {
    vertices: File,
    lists: File,
    triangles: File,
    dir: PathBuf,
    lists_end: u64,
    /// The input vertices, written by [`Self::ingest`].
    leaves: u32,
    /// Vertex ids are below this.
    vertex_count: u32,
    /// The vertex file's size, bytes.
    vertices_end: u64,
    triangle_count: u32,
    dead_triangles: u64,
    buf: Vec<u8>,
}

fn encode_state(buf: &mut Vec<u8>, state: &VertexState) {
    for c in state.position.iter().chain(&state.quadric).chain([&state.switch, &state.radius]) {
        buf.extend_from_slice(&c.to_le_bytes());
    }
    buf.extend_from_slice(&state.leaves.to_le_bytes());
}

/// A vertex record: the state, one more than the list's length, the list's offset.
fn encode_vertex(buf: &mut Vec<u8>, state: &VertexState, list_len: usize, list_at: u64) {
    buf.clear();
    encode_state(buf, state);
    buf.extend_from_slice(&(list_len as u32 + 1).to_le_bytes());
    buf.extend_from_slice(&list_at.to_le_bytes());
}

fn decode_state(bytes: &[u8; VERTEX_BYTES]) -> VertexState {
    let f = |k: usize| f64::from_le_bytes(bytes[8 * k..8 * k + 8].try_into().unwrap_or_default());
    VertexState {
        position: [f(0), f(1), f(2)],
        quadric: std::array::from_fn(|k| f(3 + k)),
        switch: f(13),
        radius: f(14),
        leaves: u32::from_le_bytes(bytes[120..124].try_into().unwrap_or_default()),
    }
}

fn u32_at(bytes: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap_or_default())
}

impl DenseRecords {
    /// Empty record files in `dir` for a mesh of `vertices` vertices (ids below twice that) and
    /// `triangles` triangles.
    pub fn new(dir: &Path, vertices: u32, triangles: u32) -> Result<DenseRecords> {
        let file = || tempfile::tempfile_in(dir).at(dir);
        Ok(DenseRecords {
            vertices: file()?,
            lists: file()?,
            triangles: file()?,
            dir: dir.to_path_buf(),
            lists_end: 0,
            leaves: vertices,
            vertex_count: vertices.saturating_mul(2),
            vertices_end: 0,
            triangle_count: triangles,
            dead_triangles: 0,
            buf: Vec::new(),
        })
    }

    /// Writes the initial records: every vertex's state and triangles, then every triangle's
    /// corners (current = input), in id order; before any other call.
    pub fn ingest<'a>(
        &mut self,
        vertices: impl Iterator<Item = (VertexState, &'a [u32])>,
        triangles: impl Iterator<Item = [u32; 3]>,
    ) -> Result<()> {
        let dir = &self.dir;
        let mut vertex_out = BufWriter::with_capacity(STREAM_BYTES, &self.vertices);
        let mut list_out = BufWriter::with_capacity(STREAM_BYTES, &self.lists);
        let mut rec = Vec::with_capacity(VERTEX_BYTES);
        let (mut nv, mut nt, mut end) = (0u64, 0u64, 0u64);
        for (state, tris) in vertices {
            for t in tris {
                list_out.write_all(&t.to_le_bytes()).at(dir)?;
            }
            encode_vertex(&mut rec, &state, tris.len(), end);
            vertex_out.write_all(&rec).at(dir)?;
            end += 4 * tris.len() as u64;
            nv += 1;
        }
        let mut tri_out = BufWriter::with_capacity(STREAM_BYTES, &self.triangles);
        for c in triangles {
            tri_out.write_all(bytemuck::cast_slice(&[c[0], c[1], c[2], c[0], c[1], c[2]])).at(dir)?;
            nt += 1;
        }
        for w in [vertex_out, list_out, tri_out] {
            w.into_inner().map_err(|e| Error::io(dir, e.into_error()))?;
        }
        if nv != self.leaves as u64 || nt != self.triangle_count as u64 {
            return Err(Error::Internal {
                stage: "the VDT build's ingest",
                problem: format!(
                    "{nv} of {} vertices and {nt} of {} triangles written",
                    self.leaves, self.triangle_count
                ),
            });
        }
        self.lists_end = end;
        self.vertices_end = nv * VERTEX_BYTES as u64;
        Ok(())
    }

    fn missing(&self, what: String) -> Error {
        Error::Scratch { path: self.dir.clone(), problem: format!("{what} is missing") }
    }

    fn read_vertex(&self, v: u32) -> Result<[u8; VERTEX_BYTES]> {
        if v >= self.vertex_count {
            return Err(self.missing(format!("vertex {v}")));
        }
        let mut rec = [0u8; VERTEX_BYTES];
        let at = v as u64 * VERTEX_BYTES as u64;
        // A vertex not yet created lies past the file's end or in a hole (zeros).
        if at + VERTEX_BYTES as u64 > self.vertices_end {
            return Err(self.missing(format!("vertex {v}")));
        }
        self.vertices.read_exact_at(&mut rec, at).at(&self.dir)?;
        if matches!(u32_at(&rec, STATE_BYTES), 0 | DEAD) {
            return Err(self.missing(format!("vertex {v}")));
        }
        Ok(rec)
    }

    /// A vertex's state and triangle list.
    pub fn vertex(&mut self, v: u32) -> Result<(VertexState, Vec<u32>)> {
        let rec = self.read_vertex(v)?;
        let len = u32_at(&rec, STATE_BYTES) as usize - 1;
        let at = u64::from_le_bytes(rec[STATE_BYTES + 4..].try_into().unwrap_or_default());
        if at + 4 * len as u64 > self.lists_end {
            return Err(self.missing(format!("the triangle list of vertex {v}")));
        }
        self.buf.resize(4 * len, 0);
        self.lists.read_exact_at(&mut self.buf, at).at(&self.dir)?;
        Ok((decode_state(&rec), self.buf.chunks_exact(4).map(|c| u32_at(c, 0)).collect()))
    }

    /// A vertex's state.
    pub fn vertex_state(&mut self, v: u32) -> Result<VertexState> {
        Ok(decode_state(&self.read_vertex(v)?))
    }

    /// A triangle's current and input corners; `None` once it died.
    pub fn triangle(&mut self, t: u32) -> Result<Option<([u32; 3], [u32; 3])>> {
        if t >= self.triangle_count {
            return Err(self.missing(format!("triangle {t}")));
        }
        let mut rec = [0u8; TRIANGLE_BYTES];
        self.triangles.read_exact_at(&mut rec, t as u64 * TRIANGLE_BYTES as u64).at(&self.dir)?;
        let w: [u32; 6] = std::array::from_fn(|k| u32_at(&rec, 4 * k));
        Ok((w[0] != DEAD).then_some(([w[0], w[1], w[2]], [w[3], w[4], w[5]])))
    }

    /// Stores a vertex's state and its triangle list (appended to `lists`).
    pub fn put_vertex(&mut self, v: u32, state: &VertexState, triangles: &[u32]) -> Result<()> {
        if v >= self.vertex_count {
            return Err(self.missing(format!("room for vertex {v}")));
        }
        self.buf.clear();
        for t in triangles {
            self.buf.extend_from_slice(&t.to_le_bytes());
        }
        self.lists.write_all_at(&self.buf, self.lists_end).at(&self.dir)?;
        let at = self.lists_end;
        self.lists_end += self.buf.len() as u64;
        encode_vertex(&mut self.buf, state, triangles.len(), at);
        let at = v as u64 * VERTEX_BYTES as u64;
        self.vertices.write_all_at(&self.buf, at).at(&self.dir)?;
        self.vertices_end = self.vertices_end.max(at + VERTEX_BYTES as u64);
        Ok(())
    }

    /// Stores a live triangle's current and input corners.
    pub fn put_triangle(&mut self, t: u32, corners: [u32; 3], leaves: [u32; 3]) -> Result<()> {
        let words = [corners[0], corners[1], corners[2], leaves[0], leaves[1], leaves[2]];
        self.triangles.write_all_at(bytemuck::cast_slice(&words), t as u64 * TRIANGLE_BYTES as u64).at(&self.dir)
    }

    /// A vertex was collapsed.
    pub fn remove_vertex(&mut self, v: u32) -> Result<()> {
        self.vertices
            .write_all_at(&DEAD.to_le_bytes(), v as u64 * VERTEX_BYTES as u64 + STATE_BYTES as u64)
            .at(&self.dir)
    }

    /// A triangle died.
    pub fn remove_triangle(&mut self, t: u32) -> Result<()> {
        self.dead_triangles += 1;
        self.triangles.write_all_at(&DEAD.to_le_bytes(), t as u64 * TRIANGLE_BYTES as u64).at(&self.dir)
    }

    /// How many triangles are alive.
    pub fn live_triangles(&self) -> u64 {
        self.triangle_count as u64 - self.dead_triangles
    }

    /// Writes the input corners of the live triangles, by increasing id, to `w`; returns how many.
    pub fn write_live_triangles(&self, w: &mut impl Write) -> std::io::Result<u64> {
        let mut chunk = vec![0u8; STREAM_BYTES / TRIANGLE_BYTES * TRIANGLE_BYTES];
        let total = self.triangle_count as u64 * TRIANGLE_BYTES as u64;
        let (mut at, mut live) = (0u64, 0u64);
        while at < total {
            let len = (total - at).min(chunk.len() as u64) as usize;
            let part = &mut chunk[..len];
            self.triangles.read_exact_at(part, at)?;
            for rec in part.chunks_exact(TRIANGLE_BYTES) {
                if u32_at(rec, 0) != DEAD {
                    w.write_all(&rec[12..])?;
                    live += 1;
                }
            }
            at += part.len() as u64;
        }
        Ok(live)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(x: f64) -> VertexState {
        VertexState { position: [x, 2.0 * x, 3.0 * x], quadric: [x; 10], switch: x, radius: 0.5 * x, leaves: 1 }
    }

    #[test]
    fn records_read_back_as_written_and_dead_or_unwritten_ones_are_missing() {
        let dir = tempfile::tempdir().unwrap();
        let mut r = DenseRecords::new(dir.path(), 3, 2).unwrap();
        let lists: [&[u32]; 3] = [&[0], &[0, 1], &[1]];
        r.ingest((0..3).map(|v| (state(v as f64), lists[v])), [[0, 1, 2], [2, 1, 0]].into_iter()).unwrap();
        assert_eq!(r.vertex(1).unwrap(), (state(1.0), vec![0, 1]));
        assert_eq!(r.vertex_state(2).unwrap(), state(2.0));
        assert_eq!(r.triangle(1).unwrap(), Some(([2, 1, 0], [2, 1, 0])));
        // A collapse: vertex 3 is new, 0 and 1 go, triangle 0 dies, 1 is renamed.
        r.put_vertex(3, &state(7.0), &[1]).unwrap();
        r.put_triangle(1, [2, 3, 3], [2, 1, 0]).unwrap();
        r.remove_vertex(0).unwrap();
        r.remove_triangle(0).unwrap();
        assert_eq!(r.vertex(3).unwrap(), (state(7.0), vec![1]));
        assert_eq!(r.triangle(0).unwrap(), None);
        assert_eq!(r.triangle(1).unwrap(), Some(([2, 3, 3], [2, 1, 0])));
        assert!(r.vertex(0).unwrap_err().to_string().contains("vertex 0 is missing"));
        // Vertex 4 is past the file's end; once 5 is written, 4 is a hole: missing either way.
        assert!(r.vertex_state(4).unwrap_err().to_string().contains("vertex 4 is missing"));
        r.put_vertex(5, &state(9.0), &[]).unwrap();
        assert!(r.vertex_state(4).unwrap_err().to_string().contains("vertex 4 is missing"));
        assert_eq!(r.vertex(5).unwrap(), (state(9.0), vec![]));
        // Ids stop below twice the leaves.
        assert!(r.put_vertex(6, &state(1.0), &[]).is_err());
        assert!(r.triangle(2).unwrap_err().to_string().contains("triangle 2 is missing"));
        assert_eq!(r.live_triangles(), 1);
        let mut out = Vec::new();
        assert_eq!(r.write_live_triangles(&mut out).unwrap(), 1);
        assert_eq!(out, bytemuck::cast_slice::<u32, u8>(&[2, 1, 0]));
    }
}
