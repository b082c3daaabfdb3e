//! PLY (Stanford polygon format): ASCII, binary little-endian and binary big-endian bodies.
//!
//! Read: the `vertex` element's `x`, `y`, `z` (any scalar type) and the `face` element's
//! `vertex_indices` (or `vertex_index`) list (any integer count and index types); every other
//! property and element is read past by its declared type, so colours, normals, confidence values
//! or extra elements do not shift the data. Write: `double x, y, z` and `uchar`/`uint` lists.

use std::io::Write;
use std::path::Path;

use super::{Builder, Mesh, MeshFormat};
use crate::error::Result;

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
pub(super) fn parse(bytes: &[u8], b: &mut Builder) -> Result<MeshFormat, String> {
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

/// PLY body encodings for writing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlyEncoding {
    Ascii,
    BinaryLittleEndian,
    BinaryBigEndian,
}

/// Encodes a mesh as PLY: `double` x, y, z (lossless) and `uchar`-counted `uint` index lists.
pub fn write_ply_bytes(mesh: &Mesh, encoding: PlyEncoding, comment: &str) -> Vec<u8> {
    let name = match encoding {
        PlyEncoding::Ascii => "ascii",
        PlyEncoding::BinaryLittleEndian => "binary_little_endian",
        PlyEncoding::BinaryBigEndian => "binary_big_endian",
    };
    let mut out = Vec::with_capacity(256 + mesh.positions.len() * 24 + mesh.triangles.len() * 13);
    let comment = comment.replace(['\n', '\r'], " ");
    let header = format!(
        "ply\nformat {name} 1.0\ncomment {comment}\nelement vertex {}\nproperty double x\nproperty double y\n\
         property double z\nelement face {}\nproperty list uchar uint vertex_indices\nend_header\n",
        mesh.positions.len(),
        mesh.triangles.len()
    );
    out.extend_from_slice(header.as_bytes());
    let big = encoding == PlyEncoding::BinaryBigEndian;
    match encoding {
        PlyEncoding::Ascii => {
            // `{}` prints the shortest representation that parses back to the same f64.
            for p in &mesh.positions {
                out.extend_from_slice(format!("{} {} {}\n", p[0], p[1], p[2]).as_bytes());
            }
            for t in &mesh.triangles {
                out.extend_from_slice(format!("3 {} {} {}\n", t[0], t[1], t[2]).as_bytes());
            }
        }
        _ => {
            for p in &mesh.positions {
                for c in p {
                    out.extend_from_slice(&if big { c.to_be_bytes() } else { c.to_le_bytes() });
                }
            }
            for t in &mesh.triangles {
                out.push(3);
                for i in t {
                    out.extend_from_slice(&if big { i.to_be_bytes() } else { i.to_le_bytes() });
                }
            }
        }
    }
    out
}

/// Writes a mesh as binary little-endian PLY through a temporary file beside `path`, renamed into
/// place, so a reader never sees a half-written mesh.
pub fn write_ply_binary(mesh: &Mesh, path: &Path, comment: &str) -> Result<()> {
    let bytes = write_ply_bytes(mesh, PlyEncoding::BinaryLittleEndian, comment);
    crate::sys::atomic_file::write(path, |w| w.write_all(&bytes))
}
