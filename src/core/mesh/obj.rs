//! Wavefront OBJ, geometry only: `v x y z [w]` and `f` with `i`, `i/t`, `i//n`, `i/t/n` corners,
//! 1-based or negative (relative to the vertices read so far). Everything else (normals, texture
//! coordinates, groups, materials, lines, points) is skipped.

use super::{parse_f64, Builder};

pub(super) fn parse(bytes: &[u8], b: &mut Builder) -> Result<(), String> {
    let text = std::str::from_utf8(bytes).map_err(|e| format!("OBJ is not text ({e})"))?;
    // A backslash at the end of a line continues the statement; rare, but part of the format.
    let text = text.replace("\\\r\n", " ").replace("\\\n", " ");
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let line = line.split('#').next().unwrap_or_default();
        let mut w = line.split_ascii_whitespace();
        match w.next() {
            Some("v") => {
                let mut p = [0.0; 3];
                for (k, c) in p.iter_mut().enumerate() {
                    let t = w.next().ok_or_else(|| format!("line {n}: 'v' has {k} coordinates (3 needed)"))?;
                    *c = parse_f64(t, || format!("line {n}: 'v'"))?;
                }
                b.vertex(p).map_err(|e| format!("line {n}: {e}"))?;
            }
            Some("f") => {
                let known = b.mesh.positions.len();
                b.corners.clear();
                for corner in w {
                    let t = corner.split('/').next().unwrap_or_default();
                    let i: i64 = t.parse().map_err(|_| format!("line {n}: bad face corner '{corner}'"))?;
                    // 1-based; negative counts back from the latest vertex (−1 is the last).
                    let zero_based = match i {
                        0 => return Err(format!("line {n}: vertex index 0 (OBJ indices start at 1)")),
                        i if i > 0 => i - 1,
                        i => known as i64 + i,
                    };
                    if zero_based < 0 || zero_based >= known as i64 {
                        return Err(format!("line {n}: vertex index {i} out of range ({known} vertices)"));
                    }
                    b.corners.push(zero_based as u32);
                }
                b.face(known).map_err(|e| format!("line {n}: {e}"))?;
            }
            _ => {}
        }
    }
    Ok(())
}
