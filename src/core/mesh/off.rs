//! ASCII OFF: `OFF`, then `vertices faces edges` (on the same line or the next), the vertices
//! (x y z, extra columns such as colours ignored), the faces (`n i0 … i(n−1)`, extra columns
//! ignored). `#` starts a comment anywhere on a line.

use super::{parse_f64, Builder};

pub(super) fn parse(bytes: &[u8], b: &mut Builder) -> Result<(), String> {
    let text = std::str::from_utf8(bytes).map_err(|e| format!("OFF is not text ({e})"))?;
    // Non-empty lines without comments, with their 1-based line numbers for messages.
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.split('#').next().unwrap_or_default().trim()))
        .filter(|(_, l)| !l.is_empty());

    let (first_line, first) = lines.next().ok_or("bad OFF header: no 'OFF' line")?;
    let mut words = first.split_ascii_whitespace();
    match words.next() {
        Some("OFF") => {}
        other => return Err(format!("bad OFF header: expected 'OFF', found '{}'", other.unwrap_or_default())),
    }
    let mut counts: Vec<&str> = words.collect();
    let mut counts_line = first_line;
    if counts.is_empty() {
        let (n, l) = lines.next().ok_or("bad OFF header: missing the vertex and face counts")?;
        counts = l.split_ascii_whitespace().collect();
        counts_line = n;
    }
    let parse_count = |s: Option<&&str>, what: &str| -> Result<usize, String> {
        let s = s.ok_or_else(|| format!("bad OFF header (line {counts_line}): missing the {what} count"))?;
        s.parse::<usize>()
            .map_err(|_| format!("bad OFF header (line {counts_line}): {what} count '{s}' is not a count"))
    };
    let vertices = parse_count(counts.first(), "vertex")?;
    let faces = parse_count(counts.get(1), "face")?;
    b.reserve(vertices, faces);

    for v in 0..vertices {
        let (n, l) = lines.next().ok_or_else(|| format!("truncated OFF: {v} of {vertices} vertices"))?;
        let mut w = l.split_ascii_whitespace();
        let mut p = [0.0; 3];
        for (k, c) in p.iter_mut().enumerate() {
            let t = w.next().ok_or_else(|| format!("line {n}: vertex {v} has {k} coordinates (3 needed)"))?;
            *c = parse_f64(t, || format!("line {n}: vertex {v}"))?;
        }
        b.vertex(p)?;
    }
    for f in 0..faces {
        let (n, l) = lines.next().ok_or_else(|| format!("truncated OFF: {f} of {faces} faces"))?;
        let mut w = l.split_ascii_whitespace();
        let corners = w.next().and_then(|t| t.parse::<usize>().ok());
        let corners = corners.ok_or_else(|| format!("line {n}: face {f} does not start with its corner count"))?;
        b.corners.clear();
        for k in 0..corners {
            let t = w.next().ok_or_else(|| format!("line {n}: face {f} has {k} of {corners} indices"))?;
            let i = t.parse::<u32>().map_err(|_| format!("line {n}: face {f}: bad vertex index '{t}'"))?;
            b.corners.push(i);
        }
        b.face(vertices)?;
    }
    Ok(())
}
