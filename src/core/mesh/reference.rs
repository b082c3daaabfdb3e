//! The readers as they were before streaming (commit 7762b56: the whole input in memory, `str`
//! parsing), kept verbatim as the tests' oracle: the streamed readers must give the same mesh,
//! report and message on every input.
#![allow(clippy::all, reason = "kept verbatim as the oracle of the streamed readers; not restyled")]

use std::io::Read;
use std::path::Path;

use super::{Mesh, MeshFormat, MeshReport};
use crate::error::{Error, IoContext, Result};

/// [`read_mesh`], also returning what was found on the way.
pub(super) fn read_mesh_with_report(path: &Path) -> Result<(Mesh, MeshReport)> {
    let raw = std::fs::read(path).at(path)?;
    if raw.is_empty() {
        return Err(Error::bad_mesh(path, "empty file"));
    }
    let gzip = raw.starts_with(&[0x1f, 0x8b]);
    let bytes = if gzip {
        let mut out = Vec::with_capacity(raw.len() * 4);
        flate2::read::MultiGzDecoder::new(&raw[..])
            .read_to_end(&mut out)
            .map_err(|e| Error::bad_mesh(path, format!("gzip: {e}")))?;
        if out.is_empty() {
            return Err(Error::bad_mesh(path, "empty file (inside gzip)"));
        }
        out
    } else {
        raw
    };
    let bad = |problem: String| Error::bad_mesh(path, problem);
    let mut builder = Builder { input_bytes: bytes.len(), ..Builder::default() };
    let format = if bytes.starts_with(b"ply") {
        ply_parse(&bytes, &mut builder).map_err(bad)?
    } else if first_word(&bytes) == Some(b"OFF".as_slice()) {
        off_parse(&bytes, &mut builder).map_err(bad)?;
        MeshFormat::Off
    } else if is_obj(path, &bytes) {
        obj_parse(&bytes, &mut builder).map_err(bad)?;
        MeshFormat::Obj
    } else {
        let what = if first_word(&bytes).is_some_and(|w| w.starts_with(b"OFF") || w.ends_with(b"OFF")) {
            "unsupported OFF variant (only plain 'OFF' is read)"
        } else {
            "unknown mesh format (expected a 'ply' or 'OFF' header, or an .obj file)"
        };
        return Err(bad(what.to_string()));
    };
    builder.finish(format, gzip).map_err(bad)
}

/// The first whitespace-separated word of the file, skipping `#` comment lines.
fn first_word(bytes: &[u8]) -> Option<&[u8]> {
    bytes
        .split(|&b| b == b'\n')
        .map(|line| line.split(|&b| b == b'#').next().unwrap_or_default())
        .flat_map(|line| line.split(|b| b.is_ascii_whitespace()))
        .find(|w| !w.is_empty())
}

/// OBJ has no magic: trust the extension (under an optional `.gz`), else a leading `v`/`o`/`g`
/// statement.
fn is_obj(path: &Path, bytes: &[u8]) -> bool {
    let name = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    let name = name.strip_suffix(".gz").unwrap_or(&name);
    name.ends_with(".obj") || matches!(first_word(bytes), Some(b"v" | b"o" | b"g" | b"vn" | b"vt" | b"mtllib"))
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

    fn finish(self, format: MeshFormat, gzip: bool) -> Result<(Mesh, MeshReport), String> {
        if self.mesh.triangles.is_empty() {
            let why = if self.faces == 0 { "no faces" } else { "every face is degenerate" };
            return Err(format!("no triangles ({why})"));
        }
        let report = MeshReport { format, gzip, faces: self.faces, degenerate_dropped: self.degenerate_dropped };
        Ok((self.mesh, report))
    }
}

/// Parses a number token, naming what it was for in the error.
fn parse_f64(token: &str, what: impl FnOnce() -> String) -> Result<f64, String> {
    token.parse::<f64>().map_err(|_| format!("{}: expected a number, found '{token}'", what()))
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn from_name(s: &str) -> Option<Scalar> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn is_integer(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }
}

#[derive(Clone, Copy, Debug)]
enum Prop {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<(String, Prop)>,
}

/// Why a body value could not be read.
enum BodyError {
    End,
    Bad(String),
}

/// A PLY body: a stream of typed values. Every value fits an `f64` exactly (the widest integer
/// types are 32-bit).
trait Body {
    fn value(&mut self, ty: Scalar) -> Result<f64, BodyError>;
}

struct AsciiBody<'a> {
    tokens: std::str::SplitAsciiWhitespace<'a>,
}

impl Body for AsciiBody<'_> {
    fn value(&mut self, ty: Scalar) -> Result<f64, BodyError> {
        let t = self.tokens.next().ok_or(BodyError::End)?;
        let v: f64 = t.parse().map_err(|_| BodyError::Bad(format!("expected a number, found '{t}'")))?;
        if ty.is_integer() && v.fract() != 0.0 {
            return Err(BodyError::Bad(format!("expected an integer, found '{t}'")));
        }
        Ok(v)
    }
}

struct BinaryBody<'a, const BIG: bool> {
    data: &'a [u8],
    at: usize,
}

impl<const BIG: bool> BinaryBody<'_, BIG> {
    fn take<const N: usize>(&mut self) -> Result<[u8; N], BodyError> {
        let bytes = self.data.get(self.at..self.at + N).ok_or(BodyError::End)?;
        self.at += N;
        let mut a = [0u8; N];
        a.copy_from_slice(bytes);
        Ok(a)
    }
}

macro_rules! decode {
    ($self:ident, $t:ty) => {{
        let a = $self.take::<{ std::mem::size_of::<$t>() }>()?;
        (if BIG { <$t>::from_be_bytes(a) } else { <$t>::from_le_bytes(a) }) as f64
    }};
}

impl<const BIG: bool> Body for BinaryBody<'_, BIG> {
    fn value(&mut self, ty: Scalar) -> Result<f64, BodyError> {
        Ok(match ty {
            Scalar::I8 => decode!(self, i8),
            Scalar::U8 => decode!(self, u8),
            Scalar::I16 => decode!(self, i16),
            Scalar::U16 => decode!(self, u16),
            Scalar::I32 => decode!(self, i32),
            Scalar::U32 => decode!(self, u32),
            Scalar::F32 => decode!(self, f32),
            Scalar::F64 => decode!(self, f64),
        })
    }
}

/// Parses a whole PLY file into `b`.
fn ply_parse(bytes: &[u8], b: &mut Builder) -> Result<MeshFormat, String> {
    let (format, elements, body_at) = parse_header(bytes)?;
    let body = &bytes[body_at..];
    match format {
        MeshFormat::PlyAscii => {
            let text = std::str::from_utf8(body).map_err(|e| format!("ASCII PLY body is not text ({e})"))?;
            read_body(&mut AsciiBody { tokens: text.split_ascii_whitespace() }, &elements, b)?
        }
        MeshFormat::PlyBinaryBigEndian => read_body(&mut BinaryBody::<true> { data: body, at: 0 }, &elements, b)?,
        _ => read_body(&mut BinaryBody::<false> { data: body, at: 0 }, &elements, b)?,
    }
    Ok(format)
}

fn parse_header(bytes: &[u8]) -> Result<(MeshFormat, Vec<Element>, usize), String> {
    let bad = |problem: String| format!("bad PLY header: {problem}");
    let mut at = 0;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut line_no = 0;
    loop {
        let rest = &bytes[at..];
        let end = rest.iter().position(|&c| c == b'\n').ok_or_else(|| bad("no 'end_header' line".into()))?;
        let line = std::str::from_utf8(&rest[..end]).map_err(|_| bad(format!("line {} is not text", line_no + 1)))?;
        at += end + 1;
        line_no += 1;
        let line = line.trim_end_matches('\r');
        let w: Vec<&str> = line.split_ascii_whitespace().collect();
        if line_no == 1 {
            if line.trim() != "ply" {
                return Err(bad(format!("first line is '{line}', expected 'ply'")));
            }
            continue;
        }
        match w.as_slice() {
            ["end_header"] => break,
            ["comment" | "obj_info", ..] | [] => {}
            ["format", kind, _version] => {
                format = Some(match *kind {
                    "ascii" => MeshFormat::PlyAscii,
                    "binary_little_endian" => MeshFormat::PlyBinaryLittleEndian,
                    "binary_big_endian" => MeshFormat::PlyBinaryBigEndian,
                    other => return Err(bad(format!("unknown format '{other}'"))),
                })
            }
            ["element", name, count] => {
                let count =
                    count.parse().map_err(|_| bad(format!("element '{name}' count '{count}' is not a count")))?;
                elements.push(Element { name: name.to_string(), count, props: Vec::new() });
            }
            ["property", "list", count, item, name] => {
                let el = elements.last_mut().ok_or_else(|| bad(format!("property '{name}' before any element")))?;
                let ty = |s: &str| Scalar::from_name(s).ok_or_else(|| bad(format!("unknown type '{s}' of '{name}'")));
                let (count, item) = (ty(count)?, ty(item)?);
                if !count.is_integer() {
                    return Err(bad(format!("list '{name}' has a non-integer count type")));
                }
                el.props.push((name.to_string(), Prop::List { count, item }));
            }
            ["property", ty, name] => {
                let el = elements.last_mut().ok_or_else(|| bad(format!("property '{name}' before any element")))?;
                let ty = Scalar::from_name(ty).ok_or_else(|| bad(format!("unknown type '{ty}' of '{name}'")))?;
                el.props.push((name.to_string(), Prop::Scalar(ty)));
            }
            _ => return Err(bad(format!("line {line_no}: cannot read '{line}'"))),
        }
    }
    let format = format.ok_or_else(|| bad("no 'format' line".into()))?;
    Ok((format, elements, at))
}

fn read_body<B: Body>(body: &mut B, elements: &[Element], b: &mut Builder) -> Result<(), String> {
    let vertex = elements.iter().find(|e| e.name == "vertex").ok_or("bad PLY header: no 'vertex' element")?;
    let mut xyz = [usize::MAX; 3];
    for (k, axis) in ["x", "y", "z"].iter().enumerate() {
        match vertex.props.iter().position(|(n, _)| n == axis) {
            Some(i) if matches!(vertex.props[i].1, Prop::Scalar(_)) => xyz[k] = i,
            _ => return Err(format!("bad PLY header: the vertex element has no scalar property '{axis}'")),
        }
    }
    let vertices = vertex.count;
    let face_count = elements.iter().find(|e| e.name == "face").map_or(0, |e| e.count);
    b.reserve(vertices, face_count);

    for el in elements {
        let indices = if el.name == "face" {
            let i = el
                .props
                .iter()
                .position(|(n, p)| (n == "vertex_indices" || n == "vertex_index") && matches!(p, Prop::List { .. }));
            Some(i.ok_or("bad PLY header: the face element has no 'vertex_indices' list")?)
        } else {
            None
        };
        let is_vertex = el.name == "vertex";
        for i in 0..el.count {
            let at = |e: BodyError| match e {
                BodyError::End => format!("truncated PLY data: element '{}' {i} of {}", el.name, el.count),
                BodyError::Bad(why) => format!("PLY element '{}' {i}: {why}", el.name),
            };
            let mut p = [0.0; 3];
            b.corners.clear();
            for (k, (_, prop)) in el.props.iter().enumerate() {
                match *prop {
                    Prop::Scalar(ty) => {
                        let v = body.value(ty).map_err(at)?;
                        if is_vertex {
                            if let Some(axis) = xyz.iter().position(|&x| x == k) {
                                p[axis] = v;
                            }
                        }
                    }
                    Prop::List { count, item } => {
                        let n = body.value(count).map_err(at)?;
                        if n < 0.0 {
                            return Err(format!("PLY element '{}' {i}: negative list length {n}", el.name));
                        }
                        let keep = indices == Some(k);
                        for _ in 0..n as usize {
                            let v = body.value(item).map_err(at)?;
                            if keep {
                                if !(v >= 0.0 && v <= u32::MAX as f64 && v.fract() == 0.0) {
                                    return Err(format!(
                                        "face {i}: vertex index {v} out of range ({vertices} vertices)"
                                    ));
                                }
                                b.corners.push(v as u32);
                            }
                        }
                    }
                }
            }
            if is_vertex {
                b.vertex(p)?;
            } else if indices.is_some() {
                b.face(vertices)?;
            }
        }
    }
    Ok(())
}

fn obj_parse(bytes: &[u8], b: &mut Builder) -> Result<(), String> {
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

fn off_parse(bytes: &[u8], b: &mut Builder) -> Result<(), String> {
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
