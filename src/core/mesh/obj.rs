//! Wavefront OBJ, geometry only: `v x y z [w]` and `f` with `i`, `i/t`, `i//n`, `i/t/n` corners,
//! 1-based or negative (relative to the vertices read so far). Everything else (normals, texture
//! coordinates, groups, materials, lines, points) is skipped.
//!
//! Streamed line by line; a backslash at the end of a line joins it to the next with a space
//! (line numbers in messages count joined lines as one, as before).

use super::input::Input;
use super::text::{before_comment, for_each_line, parse_f64, parse_i64, show, strip_cr, Words};
use super::Builder;

pub(super) fn parse(input: &mut Input, b: &mut Builder) -> Result<(), String> {
    input.require_utf8("OBJ");
    let mut n = 0usize;
    // The statement continued from earlier lines (`\` before the newline), if any.
    let mut joined: Vec<u8> = Vec::new();
    for_each_line(input, |raw, newline| {
        if newline {
            let cut = if raw.ends_with(b"\\\r") {
                2
            } else if raw.ends_with(b"\\") {
                1
            } else {
                0
            };
            if cut > 0 {
                joined.extend_from_slice(&raw[..raw.len() - cut]);
                joined.push(b' ');
                return Ok(true);
            }
        }
        n += 1;
        let line = strip_cr(raw, newline);
        if joined.is_empty() {
            statement(line, n, b)?;
        } else {
            joined.extend_from_slice(line);
            let r = statement(&joined, n, b);
            joined.clear();
            r?;
        }
        Ok(true)
    })?;
    if !joined.is_empty() {
        // The text ended right after a continued line's newline.
        n += 1;
        statement(&joined, n, b)?;
    }
    Ok(())
}

#[inline]
fn statement(line: &[u8], n: usize, b: &mut Builder) -> Result<(), String> {
    let mut w = Words::new(before_comment(line));
    match w.next() {
        Some(b"v") => {
            let mut p = [0.0; 3];
            for (k, c) in p.iter_mut().enumerate() {
                let t = w.next().ok_or_else(|| format!("line {n}: 'v' has {k} coordinates (3 needed)"))?;
                *c = parse_f64(t).ok_or_else(|| format!("line {n}: 'v': expected a number, found '{}'", show(t)))?;
            }
            b.vertex(p).map_err(|e| format!("line {n}: {e}"))?;
        }
        Some(b"f") => {
            let known = b.mesh.positions.len();
            b.corners.clear();
            for corner in w {
                let t = match memchr::memchr(b'/', corner) {
                    Some(i) => &corner[..i],
                    None => corner,
                };
                let i = parse_i64(t).ok_or_else(|| format!("line {n}: bad face corner '{}'", show(corner)))?;
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
    Ok(())
}
