//! A terrain file's valid window as a regular triangle mesh (`relief mesh from-terrain`), so the
//! mesh backends can be compared with the terrain path on the same surface.

use super::Mesh;
use crate::error::{Error, Result};
use crate::format::terrain::TerrainFile;

/// The posts `x0, x0 + step, …` of `[x0, x1)`, plus the last post `x1 − 1` when the step does not
/// land on it, so the mesh always covers the whole window (its last row/column of cells may be
/// narrower).
fn posts(x0: u32, x1: u32, step: u32) -> Vec<u32> {
    let mut v: Vec<u32> = (x0..x1).step_by(step as usize).collect();
    if v.last() != Some(&(x1 - 1)) {
        v.push(x1 - 1);
    }
    v
}

/// The valid window's posts (every `step`-th, see [`posts`]) in world metres (x = gx · spacing x,
/// y = gy · spacing y, z = height, the terrain path's own frame), two counter-clockwise (seen
/// from +z) triangles per cell. Vertices are row-major, x fastest.
pub fn terrain_mesh(file: &TerrainFile, step: u32) -> Result<Mesh> {
    if step == 0 {
        return Err(Error::OutOfRange { what: "the step", allowed: "at least 1 post".into(), got: step.to_string() });
    }
    let h = file.header();
    let [x0, y0, x1, y1] = h.valid_window;
    let (xs, ys) = (posts(x0, x1, step), posts(y0, y1, step));
    let (w, ht) = (xs.len(), ys.len());
    if w < 2 || ht < 2 {
        return Err(Error::bad_mesh(file.path(), format!("valid window {w} x {ht} posts has no cell to triangulate")));
    }
    if (w as u64) * (ht as u64) > u32::MAX as u64 {
        return Err(Error::bad_mesh(
            file.path(),
            format!("{w} x {ht} posts exceed 32-bit indices; take fewer (a larger step)"),
        ));
    }
    let [sx, sy] = h.spacing_m;
    let mut mesh =
        Mesh { positions: Vec::with_capacity(w * ht), triangles: Vec::with_capacity(2 * (w - 1) * (ht - 1)) };
    for &gy in &ys {
        for &gx in &xs {
            mesh.positions.push([gx as f64 * sx, gy as f64 * sy, file.height_at(gx, gy)? as f64]);
        }
    }
    let w32 = w as u32;
    for j in 0..ht as u32 - 1 {
        for i in 0..w32 - 1 {
            let a = j * w32 + i;
            let (b, c, d) = (a + 1, a + w32, a + w32 + 1);
            mesh.triangles.push([a, b, d]);
            mesh.triangles.push([a, d, c]);
        }
    }
    Ok(mesh)
}
