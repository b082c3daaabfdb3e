//! ASCII OFF: `OFF`, then `vertices faces edges` (on the same line or the next), the vertices
//! (x y z, extra columns such as colours ignored), the faces (`n i0 … i(n−1)`, extra columns
//! ignored). `#` starts a comment anywhere on a line.
//!
//! Streamed line by line. A line is read as `str::lines`, then `split('#')`, `trim` and
//! `split_ascii_whitespace` read it: lines of plain ASCII are cut into words directly, and a line
//! whose words do not parse is read again through those `str` methods (`trim` also removes
//! Unicode and vertical-tab spaces that `split_ascii_whitespace` keeps), so messages are theirs.

use super::input::Input;
use super::text::{before_comment, for_each_line, parse_f64, parse_u32, parse_usize, show, Words};
use super::Builder;

enum State {
    /// Waiting for the `OFF` line.
    Magic,
    /// Waiting for the counts line (line number of `OFF` for nothing).
    Counts,
    Vertices {
        v: usize,
    },
    Faces {
        f: usize,
    },
    Done,
}

struct Off<'b> {
    b: &'b mut Builder,
    state: State,
    vertices: usize,
    faces: usize,
}

/// What a line that failed the fast reading is, read by the `str` methods.
fn exact(line: &[u8]) -> Option<&[u8]> {
    // Invalid UTF-8: the whole input is reported as not text, whatever this says.
    let s = std::str::from_utf8(line).ok()?;
    let s = s.split('#').next().unwrap_or_default().trim();
    Some(s.as_bytes())
}

pub(super) fn parse(input: &mut Input, b: &mut Builder) -> Result<(), String> {
    input.require_utf8("OFF");
    let mut off = Off { b, state: State::Magic, vertices: 0, faces: 0 };
    let mut n = 0usize;
    for_each_line(input, |line, _| {
        n += 1;
        off.line(n, line)
    })?;
    match off.state {
        State::Magic => Err("bad OFF header: no 'OFF' line".into()),
        State::Counts => Err("bad OFF header: missing the vertex and face counts".into()),
        State::Vertices { v } => Err(format!("truncated OFF: {v} of {} vertices", off.vertices)),
        State::Faces { f } => Err(format!("truncated OFF: {f} of {} faces", off.faces)),
        State::Done => Ok(()),
    }
}

/// A vertex line's coordinates, or the message.
#[inline]
fn coordinates(l: &[u8], n: usize, v: usize) -> Result<[f64; 3], String> {
    let mut w = Words::new(l);
    let mut p = [0.0; 3];
    for (k, c) in p.iter_mut().enumerate() {
        let t = w.next().ok_or_else(|| format!("line {n}: vertex {v} has {k} coordinates (3 needed)"))?;
        *c = parse_f64(t).ok_or_else(|| format!("line {n}: vertex {v}: expected a number, found '{}'", show(t)))?;
    }
    Ok(p)
}

/// A face line's corners into `corners`, or the message.
#[inline]
fn corners(l: &[u8], n: usize, f: usize, corners: &mut Vec<u32>) -> Result<(), String> {
    let mut w = Words::new(l);
    let count = w.next().and_then(parse_usize);
    let count = count.ok_or_else(|| format!("line {n}: face {f} does not start with its corner count"))?;
    corners.clear();
    for k in 0..count {
        let t = w.next().ok_or_else(|| format!("line {n}: face {f} has {k} of {count} indices"))?;
        let i = parse_u32(t).ok_or_else(|| format!("line {n}: face {f}: bad vertex index '{}'", show(t)))?;
        corners.push(i);
    }
    Ok(())
}

impl Off<'_> {
    fn line(&mut self, n: usize, raw: &[u8]) -> Result<bool, String> {
        match self.state {
            State::Vertices { v } => {
                let l = before_comment(raw);
                let p = match coordinates(l, n, v) {
                    Ok(p) => p,
                    // An empty line (ASCII spaces only) is empty for `trim` too.
                    Err(_) if Words::new(l).next().is_none() => return Ok(true),
                    Err(first) => match exact(raw) {
                        Some([]) => return Ok(true),
                        Some(l) => coordinates(l, n, v)?,
                        None => return Err(first),
                    },
                };
                self.b.vertex(p)?;
                self.state = if v + 1 < self.vertices { State::Vertices { v: v + 1 } } else { self.after_vertices() };
            }
            State::Faces { f } => {
                let l = before_comment(raw);
                if let Err(first) = corners(l, n, f, &mut self.b.corners) {
                    if Words::new(l).next().is_none() {
                        return Ok(true);
                    }
                    match exact(raw) {
                        Some([]) => return Ok(true),
                        Some(l) => corners(l, n, f, &mut self.b.corners)?,
                        None => return Err(first),
                    }
                }
                self.b.face(self.vertices)?;
                self.state = if f + 1 < self.faces { State::Faces { f: f + 1 } } else { State::Done };
            }
            State::Magic | State::Counts => {
                let Some(l) = exact(raw) else { return Err("OFF is not text".into()) };
                if l.is_empty() {
                    return Ok(true);
                }
                let mut words = l.split(|b| b.is_ascii_whitespace()).filter(|w| !w.is_empty());
                if matches!(self.state, State::Magic) {
                    match words.next() {
                        Some(b"OFF") => {}
                        other => {
                            return Err(format!(
                                "bad OFF header: expected 'OFF', found '{}'",
                                show(other.unwrap_or_default())
                            ))
                        }
                    }
                }
                let counts: Vec<&[u8]> = words.collect();
                if counts.is_empty() {
                    // The counts are on the next non-empty line.
                    self.state = State::Counts;
                    return Ok(true);
                }
                let parse_count = |s: Option<&&[u8]>, what: &str| -> Result<usize, String> {
                    let s = s.ok_or_else(|| format!("bad OFF header (line {n}): missing the {what} count"))?;
                    parse_usize(s)
                        .ok_or_else(|| format!("bad OFF header (line {n}): {what} count '{}' is not a count", show(s)))
                };
                self.vertices = parse_count(counts.first(), "vertex")?;
                self.faces = parse_count(counts.get(1), "face")?;
                self.b.reserve(self.vertices, self.faces);
                self.state = if self.vertices > 0 { State::Vertices { v: 0 } } else { self.after_vertices() };
            }
            State::Done => return Ok(false),
        }
        Ok(!matches!(self.state, State::Done))
    }

    fn after_vertices(&self) -> State {
        if self.faces > 0 {
            State::Faces { f: 0 }
        } else {
            State::Done
        }
    }
}
