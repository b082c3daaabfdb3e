//! PLY (Stanford polygon format): ASCII, binary little-endian and binary big-endian bodies.
//!
//! Read: the `vertex` element's `x`, `y`, `z` (any scalar type) and the `face` element's
//! `vertex_indices` (or `vertex_index`) list (any integer count and index types); every other
//! property and element is read past by its declared type, so colours, normals, confidence values
//! or extra elements do not shift the data. Write: `double x, y, z` and `uchar`/`uint` lists.
//!
//! Two ways through a body, one result. The general path reads value by value
//! ([`Body::value`]) and handles every layout. Binary bodies of the common layouts take a fast
//! path first: elements of scalars only (vertices, or skipped elements) are decoded at a fixed
//! stride, and faces whose only list is the index list (`uchar`/`int`/`uint` counts, `int`/`uint`
//! indices) record by record, with no per-value dispatch. A fast path commits only whole records
//! it can read without a problem; at anything else (a record cut by the end of the data, a
//! negative count or index, a very long list) it stops and the general path goes on from that
//! record, so messages are the general path's.

use std::io::Write;
use std::path::Path;

use super::input::Input;
use super::text::{parse_f64, show, Tokens};
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

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
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

    /// Reads the first records of `el` by a fast path, if this body has one for its layout, and
    /// returns how many it read (the general path goes on from there).
    fn fast(&mut self, _el: &Plan, _b: &mut Builder) -> Result<usize, String> {
        Ok(0)
    }
}

struct AsciiBody<'a> {
    tokens: Tokens<'a>,
}

impl Body for AsciiBody<'_> {
    #[inline]
    fn value(&mut self, ty: Scalar) -> Result<f64, BodyError> {
        let t = self.tokens.next_token().ok_or(BodyError::End)?;
        let v = parse_f64(t).ok_or_else(|| BodyError::Bad(format!("expected a number, found '{}'", show(t))))?;
        if ty.is_integer() && !integral(v) {
            return Err(BodyError::Bad(format!("expected an integer, found '{}'", show(t))));
        }
        Ok(v)
    }
}

/// `v.fract() == 0.0` without a call to `trunc` (not inlined without SSE 4.1): every finite
/// double of magnitude 2^52 or more is an integer; NaN and infinities are not.
#[inline]
fn integral(v: f64) -> bool {
    if v.abs() < 4_503_599_627_370_496.0 {
        (v as i64) as f64 == v
    } else {
        v.is_finite()
    }
}

struct BinaryBody<'a, const BIG: bool> {
    input: &'a mut Input,
}

/// A scalar type's bytes as a number.
trait Num: Copy {
    const SIZE: usize;
    fn get<const BIG: bool>(b: &[u8]) -> Self;
    fn to_f64(self) -> f64;
}

macro_rules! num {
    ($($t:ty),*) => {$(
        impl Num for $t {
            const SIZE: usize = std::mem::size_of::<$t>();
            #[inline(always)]
            fn get<const BIG: bool>(b: &[u8]) -> $t {
                let mut a = [0u8; std::mem::size_of::<$t>()];
                a.copy_from_slice(&b[..std::mem::size_of::<$t>()]);
                if BIG { <$t>::from_be_bytes(a) } else { <$t>::from_le_bytes(a) }
            }
            #[inline(always)]
            fn to_f64(self) -> f64 {
                self as f64
            }
        }
    )*};
}
num!(i8, u8, i16, u16, i32, u32, f32, f64);

impl<const BIG: bool> BinaryBody<'_, BIG> {
    #[inline]
    fn take<T: Num>(&mut self) -> Result<f64, BodyError> {
        if !self.input.fill(T::SIZE) {
            return Err(BodyError::End);
        }
        let v = T::get::<BIG>(self.input.window());
        self.input.consume(T::SIZE);
        Ok(v.to_f64())
    }
}

impl<const BIG: bool> Body for BinaryBody<'_, BIG> {
    fn value(&mut self, ty: Scalar) -> Result<f64, BodyError> {
        match ty {
            Scalar::I8 => self.take::<i8>(),
            Scalar::U8 => self.take::<u8>(),
            Scalar::I16 => self.take::<i16>(),
            Scalar::U16 => self.take::<u16>(),
            Scalar::I32 => self.take::<i32>(),
            Scalar::U32 => self.take::<u32>(),
            Scalar::F32 => self.take::<f32>(),
            Scalar::F64 => self.take::<f64>(),
        }
    }

    fn fast(&mut self, plan: &Plan, b: &mut Builder) -> Result<usize, String> {
        fast_binary::<BIG>(self.input, plan, b)
    }
}

/// Parses a whole PLY file into `b`.
pub(super) fn parse(input: &mut Input, b: &mut Builder) -> Result<MeshFormat, String> {
    let (format, elements) = parse_header(input)?;
    match format {
        MeshFormat::PlyAscii => {
            input.require_utf8("ASCII PLY body");
            read_body(&mut AsciiBody { tokens: Tokens::new(input) }, &elements, b)?
        }
        MeshFormat::PlyBinaryBigEndian => read_body(&mut BinaryBody::<true> { input }, &elements, b)?,
        _ => read_body(&mut BinaryBody::<false> { input }, &elements, b)?,
    }
    Ok(format)
}

fn parse_header(input: &mut Input) -> Result<(MeshFormat, Vec<Element>), String> {
    let bad = |problem: String| format!("bad PLY header: {problem}");
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut line_no = 0;
    let mut ended = false;
    super::text::for_each_line(input, |line, newline| {
        if !newline {
            return Err(bad("no 'end_header' line".into()));
        }
        let line = std::str::from_utf8(line).map_err(|_| bad(format!("line {} is not text", line_no + 1)))?;
        line_no += 1;
        let line = line.trim_end_matches('\r');
        let w: Vec<&str> = line.split_ascii_whitespace().collect();
        if line_no == 1 {
            if line.trim() != "ply" {
                return Err(bad(format!("first line is '{line}', expected 'ply'")));
            }
            return Ok(true);
        }
        match w.as_slice() {
            ["end_header"] => {
                ended = true;
                return Ok(false);
            }
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
        Ok(true)
    })?;
    if !ended {
        return Err(bad("no 'end_header' line".into()));
    }
    let format = format.ok_or_else(|| bad("no 'format' line".into()))?;
    Ok((format, elements))
}

/// How one element is read.
struct Plan<'e> {
    el: &'e Element,
    /// Which of x, y, z each property is (vertex elements).
    axis_of: Vec<Option<usize>>,
    is_vertex: bool,
    /// The index list's position among the properties (face elements).
    indices: Option<usize>,
    /// Vertices the header declares: the range of face indices.
    vertices: usize,
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
        let axis_of = (0..el.props.len()).map(|k| if is_vertex { xyz.iter().position(|&x| x == k) } else { None });
        let plan = Plan { el, axis_of: axis_of.collect(), is_vertex, indices, vertices };
        let done = body.fast(&plan, b)?;
        read_records(body, &plan, done, b)?;
    }
    Ok(())
}

/// The general path: records `from..` of an element, value by value.
fn read_records<B: Body>(body: &mut B, plan: &Plan, from: usize, b: &mut Builder) -> Result<(), String> {
    let Plan { el, ref axis_of, is_vertex, indices, vertices } = *plan;
    for i in from..el.count {
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
                    if let Some(axis) = axis_of[k] {
                        p[axis] = v;
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
                            if !(v >= 0.0 && v <= u32::MAX as f64 && integral(v)) {
                                return Err(format!("face {i}: vertex index {v} out of range ({vertices} vertices)"));
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
    Ok(())
}

/// The longest face record the fast path reads whole (longer ones go value by value).
const LONGEST_FAST_FACE: usize = 1 << 16;

/// The binary fast paths: records of `plan` read while their layout is a common one.
fn fast_binary<const BIG: bool>(input: &mut Input, plan: &Plan, b: &mut Builder) -> Result<usize, String> {
    let el = plan.el;
    let scalars: Option<Vec<Scalar>> =
        el.props.iter().map(|(_, p)| if let Prop::Scalar(t) = p { Some(*t) } else { None }).collect();
    if let Some(types) = scalars {
        let stride: usize = types.iter().map(|t| t.size()).sum();
        if stride == 0 {
            return Ok(0);
        }
        if !plan.is_vertex {
            return skip_fixed(input, stride, el.count);
        }
        // Offset and type of x, y, z (an axis whose property is missing stays 0, as in the
        // general path).
        let mut axes = [None; 3];
        let mut at = 0;
        for (k, t) in types.iter().enumerate() {
            if let Some(axis) = plan.axis_of[k] {
                axes[axis] = Some((at, *t));
            }
            at += t.size();
        }
        return match axes {
            [Some((x, Scalar::F32)), Some((y, Scalar::F32)), Some((z, Scalar::F32))] => {
                vertices_fixed::<f32, BIG>(input, stride, [x, y, z], el.count, b)
            }
            [Some((x, Scalar::F64)), Some((y, Scalar::F64)), Some((z, Scalar::F64))] => {
                vertices_fixed::<f64, BIG>(input, stride, [x, y, z], el.count, b)
            }
            _ => vertices_mixed::<BIG>(input, stride, axes, el.count, b),
        };
    }
    // Faces: scalars around the one list, the index list.
    let Some(k) = plan.indices else { return Ok(0) };
    let lists = el.props.iter().filter(|(_, p)| matches!(p, Prop::List { .. })).count();
    let Prop::List { count, item } = el.props[k].1 else { return Ok(0) };
    if lists != 1 {
        return Ok(0);
    }
    let size = |props: &[(String, Prop)]| -> usize {
        props.iter().map(|(_, p)| if let Prop::Scalar(t) = p { t.size() } else { 0 }).sum()
    };
    let (pre, post) = (size(&el.props[..k]), size(&el.props[k + 1..]));
    let f = Faces { pre, post, count: el.count, vertices: plan.vertices };
    match (count, item) {
        (Scalar::U8, Scalar::I32) => faces::<u8, i32, BIG>(input, f, b),
        (Scalar::U8, Scalar::U32) => faces::<u8, u32, BIG>(input, f, b),
        (Scalar::I32, Scalar::I32) => faces::<i32, i32, BIG>(input, f, b),
        (Scalar::I32, Scalar::U32) => faces::<i32, u32, BIG>(input, f, b),
        (Scalar::U32, Scalar::I32) => faces::<u32, i32, BIG>(input, f, b),
        (Scalar::U32, Scalar::U32) => faces::<u32, u32, BIG>(input, f, b),
        _ => Ok(0),
    }
}

/// Records of a skipped element of scalars: whole ones are passed over.
fn skip_fixed(input: &mut Input, stride: usize, count: usize) -> Result<usize, String> {
    let mut i = 0;
    while i < count {
        if !input.fill(stride) {
            break;
        }
        let k = (input.window().len() / stride).min(count - i);
        input.consume(k * stride);
        i += k;
    }
    Ok(i)
}

fn vertices_fixed<T: Num, const BIG: bool>(
    input: &mut Input,
    stride: usize,
    [x, y, z]: [usize; 3],
    count: usize,
    b: &mut Builder,
) -> Result<usize, String> {
    let mut i = 0;
    while i < count {
        if !input.fill(stride) {
            break;
        }
        let w = input.window();
        let k = (w.len() / stride).min(count - i);
        for r in w[..k * stride].chunks_exact(stride) {
            let p = [T::get::<BIG>(&r[x..]).to_f64(), T::get::<BIG>(&r[y..]).to_f64(), T::get::<BIG>(&r[z..]).to_f64()];
            b.vertex(p)?;
        }
        input.consume(k * stride);
        i += k;
    }
    Ok(i)
}

#[inline]
fn get_f64<const BIG: bool>(r: &[u8], ty: Scalar) -> f64 {
    match ty {
        Scalar::I8 => i8::get::<BIG>(r).to_f64(),
        Scalar::U8 => u8::get::<BIG>(r).to_f64(),
        Scalar::I16 => i16::get::<BIG>(r).to_f64(),
        Scalar::U16 => u16::get::<BIG>(r).to_f64(),
        Scalar::I32 => i32::get::<BIG>(r).to_f64(),
        Scalar::U32 => u32::get::<BIG>(r).to_f64(),
        Scalar::F32 => f32::get::<BIG>(r).to_f64(),
        Scalar::F64 => f64::get::<BIG>(r).to_f64(),
    }
}

/// Vertices whose axes differ in type (or are missing): fixed stride, a match per axis.
fn vertices_mixed<const BIG: bool>(
    input: &mut Input,
    stride: usize,
    axes: [Option<(usize, Scalar)>; 3],
    count: usize,
    b: &mut Builder,
) -> Result<usize, String> {
    let mut i = 0;
    while i < count {
        if !input.fill(stride) {
            break;
        }
        let w = input.window();
        let k = (w.len() / stride).min(count - i);
        for r in w[..k * stride].chunks_exact(stride) {
            let p = axes.map(|a| a.map_or(0.0, |(at, ty)| get_f64::<BIG>(&r[at..], ty)));
            b.vertex(p)?;
        }
        input.consume(k * stride);
        i += k;
    }
    Ok(i)
}

#[derive(Clone, Copy)]
struct Faces {
    /// Bytes of the scalars before and after the index list.
    pre: usize,
    post: usize,
    count: usize,
    vertices: usize,
}

/// An index list's count or item as an integer.
trait Int: Num {
    fn int(self) -> i64;
}

impl Int for u8 {
    #[inline(always)]
    fn int(self) -> i64 {
        i64::from(self)
    }
}

impl Int for i32 {
    #[inline(always)]
    fn int(self) -> i64 {
        i64::from(self)
    }
}

impl Int for u32 {
    #[inline(always)]
    fn int(self) -> i64 {
        i64::from(self)
    }
}

fn faces<C: Int, I: Int, const BIG: bool>(input: &mut Input, f: Faces, b: &mut Builder) -> Result<usize, String> {
    let head = f.pre + C::SIZE;
    let mut i = 0;
    while i < f.count {
        if !input.fill(head) {
            break;
        }
        let w = input.window();
        let mut used = 0;
        // Stop at this record (the general path reads it); read more first (bytes needed).
        let mut stop = false;
        let mut need = 0;
        while i < f.count {
            let r = &w[used..];
            if r.len() < head {
                break;
            }
            let n = C::get::<BIG>(&r[f.pre..]).int();
            if n < 0 {
                stop = true;
                break;
            }
            let len = head + n as usize * I::SIZE + f.post;
            if r.len() < len {
                stop = len > LONGEST_FAST_FACE;
                need = len;
                break;
            }
            let items = &r[head..head + n as usize * I::SIZE];
            if n == 3 {
                let t = [0, 1, 2].map(|k| I::get::<BIG>(&items[k * I::SIZE..]).int());
                if t.iter().any(|&v| !(0..=i64::from(u32::MAX)).contains(&v)) {
                    stop = true;
                    break;
                }
                b.triangle(t.map(|v| v as u32), f.vertices)?;
            } else {
                b.corners.clear();
                if items.chunks_exact(I::SIZE).any(|c| !(0..=i64::from(u32::MAX)).contains(&I::get::<BIG>(c).int())) {
                    stop = true;
                    break;
                }
                b.corners.extend(items.chunks_exact(I::SIZE).map(|c| I::get::<BIG>(c).int() as u32));
                b.face(f.vertices)?;
            }
            used += len;
            i += 1;
        }
        input.consume(used);
        if stop || (need > 0 && !input.fill(need)) {
            break;
        }
    }
    Ok(i)
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
