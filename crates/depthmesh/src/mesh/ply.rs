//! PLY files: ASCII and both binary byte orders, with whatever element and
//! property layout the common tools write.
//!
//! Reading parses the whole file from one byte slice: a PLY body is a flat run
//! of values, so this is both the simplest and the fastest approach.

use crate::atomic::write_atomic;
use crate::error::{Error, Result};
use crate::mesh::Mesh;
use glam::Vec3;
use std::io::Write;
use std::path::Path;

/// How [`write_ply`] encodes the body.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlyFormat {
    /// Compact and fast; what every tool reads.
    BinaryLittleEndian,
    /// Human-readable; for small meshes and debugging.
    Ascii,
}

/// Reads a PLY file.
pub fn read_ply(path: &Path) -> Result<Mesh> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    read_ply_from_bytes(&bytes, path)
}

/// Parses a PLY file held in memory; `path_for_errors` only labels error messages.
///
/// Vertices need `x y z`; `nx ny nz` and `red green blue` (or `diffuse_*`)
/// are kept when all three are present. Faces come from a `vertex_indices`
/// or `vertex_index` list and are fan-triangulated. Everything else is skipped.
pub fn read_ply_from_bytes(bytes: &[u8], path_for_errors: &Path) -> Result<Mesh> {
    let path = path_for_errors;
    let header = parse_header(bytes).map_err(|m| Error::format(path, m))?;
    let body = &bytes[header.body_start..];
    match header.format {
        Format::Ascii => read_body(
            &mut Ascii {
                data: body,
                pos: 0,
                line: header.lines + 1,
            },
            &header,
            path,
        ),
        Format::BinaryLittleEndian => {
            read_body(&mut Binary::<false> { data: body, pos: 0 }, &header, path)
        }
        Format::BinaryBigEndian => {
            read_body(&mut Binary::<true> { data: body, pos: 0 }, &header, path)
        }
    }
}

/// Writes `mesh` to `path` as PLY, atomically (see [`write_atomic`]).
pub fn write_ply(path: &Path, mesh: &Mesh, format: PlyFormat) -> Result<()> {
    mesh.check().map_err(|m| Error::parameter("mesh", m))?;
    write_atomic(path, |w| write_ply_to(w, mesh, format))
}

/// Writes `mesh` as PLY to any writer: `x y z` floats, `nx ny nz` floats if
/// the mesh has normals, `red green blue` uchars if it has colours, and faces
/// as `list uchar int vertex_indices`. An inconsistent mesh is an
/// `InvalidInput` error, since the file would not read back.
pub fn write_ply_to<W: Write>(mut w: W, mesh: &Mesh, format: PlyFormat) -> std::io::Result<()> {
    mesh.check()
        .map_err(|m| std::io::Error::new(std::io::ErrorKind::InvalidInput, m))?;
    let layout = PlyLayout::of(mesh);
    layout.write_header(&mut w, format)?;
    let mut buf = Vec::with_capacity(FLUSH_AT + 256);
    match format {
        PlyFormat::BinaryLittleEndian => {
            layout.write_vertices(&mut w, &mut buf, mesh)?;
            write_faces(&mut w, &mut buf, mesh, 0)?;
        }
        PlyFormat::Ascii => {
            for (i, p) in mesh.positions.iter().enumerate() {
                // `{}` prints the shortest text that parses back to the same
                // f32, so ASCII files round-trip exactly.
                write!(buf, "{} {} {}", p.x, p.y, p.z)?;
                if layout.normals {
                    let n = mesh.normals[i];
                    write!(buf, " {} {} {}", n.x, n.y, n.z)?;
                }
                if layout.colors {
                    let [r, g, b] = mesh.colors[i];
                    write!(buf, " {r} {g} {b}")?;
                }
                buf.push(b'\n');
                flush_full(&mut w, &mut buf)?;
            }
            for [a, b, c] in &mesh.triangles {
                writeln!(buf, "3 {a} {b} {c}")?;
                flush_full(&mut w, &mut buf)?;
            }
        }
    }
    w.write_all(&buf)
}

/// Writes, atomically, one binary PLY holding the meshes `parts` yields,
/// joined in order (vertex indices shifted), without holding them all in
/// memory: `parts` is run twice — once for the vertices, once for the faces
/// — and hands each mesh to the callback it is given. `layout` gives the
/// totals and attributes every non-empty part must have.
pub fn write_ply_joined(
    path: &Path,
    layout: PlyLayout,
    mut parts: impl FnMut(&mut dyn FnMut(&Mesh) -> std::io::Result<()>) -> std::io::Result<()>,
) -> Result<()> {
    write_atomic(path, |w| {
        layout.write_header(w, PlyFormat::BinaryLittleEndian)?;
        let mut buf = Vec::with_capacity(FLUSH_AT + 256);
        let (mut vertices, mut offset, mut triangles) = (0usize, 0usize, 0usize);
        parts(&mut |mesh| {
            layout.check_part(mesh)?;
            layout.write_vertices(w, &mut buf, mesh)?;
            vertices += mesh.vertex_count();
            Ok(())
        })?;
        parts(&mut |mesh| {
            write_faces(w, &mut buf, mesh, offset as u32)?;
            offset += mesh.vertex_count();
            triangles += mesh.triangle_count();
            Ok(())
        })?;
        w.write_all(&buf)?;
        if (vertices, offset, triangles) != (layout.vertices, layout.vertices, layout.triangles) {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!(
                    "the parts hold {vertices} vertices and {triangles} triangles, the header says {} and {}",
                    layout.vertices, layout.triangles
                ),
            ));
        }
        Ok(())
    })
}

/// What a PLY header declares: element counts and vertex attributes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PlyLayout {
    /// Number of vertices.
    pub vertices: usize,
    /// Number of triangles.
    pub triangles: usize,
    /// Whether vertices carry `nx ny nz`.
    pub normals: bool,
    /// Whether vertices carry `red green blue`.
    pub colors: bool,
}

/// Values go into one reusable buffer handed to the writer in large blocks:
/// a write call per value would dominate the cost.
const FLUSH_AT: usize = 1 << 20;

fn flush_full<W: Write + ?Sized>(w: &mut W, buf: &mut Vec<u8>) -> std::io::Result<()> {
    if buf.len() >= FLUSH_AT {
        w.write_all(buf)?;
        buf.clear();
    }
    Ok(())
}

fn invalid(message: String) -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::InvalidInput, message)
}

impl PlyLayout {
    /// The layout of one whole mesh.
    pub fn of(mesh: &Mesh) -> Self {
        PlyLayout {
            vertices: mesh.vertex_count(),
            triangles: mesh.triangle_count(),
            normals: !mesh.normals.is_empty(),
            colors: !mesh.colors.is_empty(),
        }
    }

    /// Rejects a part whose attributes differ from the header's (an empty
    /// part has none and fits any header).
    fn check_part(&self, mesh: &Mesh) -> std::io::Result<()> {
        mesh.check().map_err(invalid)?;
        let fits = mesh.positions.is_empty()
            || (self.normals != mesh.normals.is_empty() && self.colors != mesh.colors.is_empty());
        if fits {
            Ok(())
        } else {
            Err(invalid(
                "a part's vertex attributes differ from the others'".into(),
            ))
        }
    }

    fn write_header<W: Write + ?Sized>(&self, w: &mut W, format: PlyFormat) -> std::io::Result<()> {
        if self.vertices > i32::MAX as usize {
            return Err(invalid("too many vertices for PLY int indices".into()));
        }
        let mut head = String::from("ply\n");
        head.push_str(match format {
            PlyFormat::BinaryLittleEndian => "format binary_little_endian 1.0\n",
            PlyFormat::Ascii => "format ascii 1.0\n",
        });
        head.push_str("comment written by depthmesh\n");
        head.push_str(&format!("element vertex {}\n", self.vertices));
        head.push_str("property float x\nproperty float y\nproperty float z\n");
        if self.normals {
            head.push_str("property float nx\nproperty float ny\nproperty float nz\n");
        }
        if self.colors {
            head.push_str("property uchar red\nproperty uchar green\nproperty uchar blue\n");
        }
        head.push_str(&format!("element face {}\n", self.triangles));
        head.push_str("property list uchar int vertex_indices\nend_header\n");
        w.write_all(head.as_bytes())
    }

    /// The binary vertex records of `mesh`.
    fn write_vertices<W: Write + ?Sized>(
        &self,
        w: &mut W,
        buf: &mut Vec<u8>,
        mesh: &Mesh,
    ) -> std::io::Result<()> {
        for (i, p) in mesh.positions.iter().enumerate() {
            for v in p.to_array() {
                buf.extend_from_slice(&v.to_le_bytes());
            }
            if self.normals {
                for v in mesh.normals[i].to_array() {
                    buf.extend_from_slice(&v.to_le_bytes());
                }
            }
            if self.colors {
                buf.extend_from_slice(&mesh.colors[i]);
            }
            flush_full(w, buf)?;
        }
        Ok(())
    }
}

/// The binary face records of `mesh`, its indices shifted by `offset`.
fn write_faces<W: Write + ?Sized>(
    w: &mut W,
    buf: &mut Vec<u8>,
    mesh: &Mesh,
    offset: u32,
) -> std::io::Result<()> {
    for t in &mesh.triangles {
        buf.push(3);
        for i in t {
            buf.extend_from_slice(&(i + offset).to_le_bytes());
        }
        flush_full(w, buf)?;
    }
    Ok(())
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Ascii,
    BinaryLittleEndian,
    BinaryBigEndian,
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
    fn parse(name: &str) -> Option<Scalar> {
        Some(match name {
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

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    /// Factor taking a colour channel of this type to 0..=255: floats are
    /// 0..1 by convention, 16-bit channels are 0..65535.
    fn color_scale(self) -> f64 {
        match self {
            Scalar::F32 | Scalar::F64 => 255.0,
            Scalar::U16 => 255.0 / 65535.0,
            _ => 1.0,
        }
    }
}

#[derive(Clone, Copy, Debug)]
enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Debug)]
struct Property {
    name: String,
    kind: Kind,
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
}

impl Element {
    /// Fewest bytes (binary) or tokens (ASCII) one instance can take, so a
    /// lying count in the header cannot make us reserve absurd amounts of memory.
    fn min_size(&self) -> usize {
        self.properties
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(s) => s.size(),
                Kind::List { count, .. } => count.size(),
            })
            .sum()
    }
}

#[derive(Debug)]
struct Header {
    format: Format,
    elements: Vec<Element>,
    /// Offset of the first body byte.
    body_start: usize,
    /// Number of header lines, for ASCII line numbers.
    lines: usize,
}

fn parse_header(bytes: &[u8]) -> Result<Header, String> {
    let mut pos = 0;
    let mut line_no = 0;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    loop {
        let Some(len) = bytes[pos..].iter().position(|&b| b == b'\n') else {
            return Err(if line_no == 0 {
                "not a PLY file (no 'ply' magic line)".to_string()
            } else {
                "header has no end_header line".to_string()
            });
        };
        let raw = &bytes[pos..pos + len];
        pos += len + 1;
        line_no += 1;
        let line = String::from_utf8_lossy(raw);
        let mut words = line.split_ascii_whitespace();
        let keyword = words.next();
        if line_no == 1 {
            if keyword != Some("ply") || words.next().is_some() {
                return Err("not a PLY file (no 'ply' magic line)".to_string());
            }
            continue;
        }
        let bad = || format!("header line {line_no}: cannot parse '{}'", line.trim());
        match keyword {
            None | Some("comment") | Some("obj_info") => {}
            Some("format") => {
                format = Some(match words.next() {
                    Some("ascii") => Format::Ascii,
                    Some("binary_little_endian") => Format::BinaryLittleEndian,
                    Some("binary_big_endian") => Format::BinaryBigEndian,
                    other => {
                        return Err(format!(
                            "header line {line_no}: unknown format '{}' (expected ascii, \
                             binary_little_endian or binary_big_endian)",
                            other.unwrap_or("")
                        ))
                    }
                })
            }
            Some("element") => {
                let (Some(name), Some(count), None) = (words.next(), words.next(), words.next())
                else {
                    return Err(bad());
                };
                let count = count.parse().map_err(|_| bad())?;
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    properties: Vec::new(),
                });
            }
            Some("property") => {
                let Some(element) = elements.last_mut() else {
                    return Err(format!(
                        "header line {line_no}: property before any element"
                    ));
                };
                let scalar = |name: Option<&str>| {
                    let name = name.unwrap_or("");
                    Scalar::parse(name).ok_or_else(|| {
                        format!("header line {line_no}: unknown property type '{name}'")
                    })
                };
                let first = words.next();
                let kind = if first == Some("list") {
                    Kind::List {
                        count: scalar(words.next())?,
                        item: scalar(words.next())?,
                    }
                } else {
                    Kind::Scalar(scalar(first)?)
                };
                let (Some(name), None) = (words.next(), words.next()) else {
                    return Err(bad());
                };
                element.properties.push(Property {
                    name: name.to_string(),
                    kind,
                });
            }
            Some("end_header") => break,
            Some(_) => return Err(bad()),
        }
    }
    let format = format.ok_or("header has no format line")?;
    Ok(Header {
        format,
        elements,
        body_start: pos,
        lines: line_no,
    })
}

/// Why a value could not be read from the body.
enum Stop {
    /// The data ended early.
    End,
    /// An ASCII token that is not a number.
    BadToken { line: usize, token: String },
}

/// Where a kept vertex property sits in a fixed-size binary record.
#[derive(Clone, Copy, Debug)]
struct Field {
    offset: usize,
    ty: Scalar,
    slot: usize,
}

/// Number of per-vertex values we keep: position, normal, colour.
const SLOTS: usize = 9;

/// A source of body values, so one element walker serves all three encodings
/// (monomorphised, hence no dispatch cost per value).
trait Values {
    /// The next value of type `ty`, widened to f64 (exact for every PLY type).
    fn value(&mut self, ty: Scalar) -> Result<f64, Stop>;
    /// Skips `n` values of type `ty`.
    fn skip(&mut self, ty: Scalar, n: usize) -> Result<(), Stop>;
    /// Bytes (binary) or bytes of text (ASCII) not yet read.
    fn remaining(&self) -> usize;
    /// Current line, for ASCII error messages.
    fn line(&self) -> Option<usize>;

    /// Fast path for elements of fixed-size binary records: decodes `fields`
    /// of `count` records of `stride` bytes and hands each record's slots to
    /// `each`. `None` means not handled (ASCII, or too little data) and
    /// nothing was consumed; the caller then reads value by value, which also
    /// pinpoints where the data ends.
    fn records<F>(
        &mut self,
        _stride: usize,
        _count: usize,
        _fields: &[Field],
        _each: F,
    ) -> Option<Result<()>>
    where
        F: FnMut(usize, &[f64; SLOTS]) -> Result<()>,
    {
        None
    }

    /// Fast path for the overwhelmingly common binary face `3 i j k` with a
    /// one-byte count and 32-bit `item` indices. `None` means the next face
    /// is something else (or this is ASCII) and nothing was consumed.
    fn triangle(&mut self, _item: Scalar) -> Option<[f64; 3]> {
        None
    }
}

struct Binary<'a, const BIG_ENDIAN: bool> {
    data: &'a [u8],
    pos: usize,
}

/// Decodes a value of type `ty` from the start of `bytes`, `None` if too short.
#[inline(always)]
fn decode<const BIG_ENDIAN: bool>(bytes: &[u8], ty: Scalar) -> Option<f64> {
    macro_rules! read {
        ($t:ty) => {{
            let b = *bytes.first_chunk()?;
            (if BIG_ENDIAN {
                <$t>::from_be_bytes(b)
            } else {
                <$t>::from_le_bytes(b)
            }) as f64
        }};
    }
    Some(match ty {
        Scalar::I8 => read!(i8),
        Scalar::U8 => read!(u8),
        Scalar::I16 => read!(i16),
        Scalar::U16 => read!(u16),
        Scalar::I32 => read!(i32),
        Scalar::U32 => read!(u32),
        Scalar::F32 => read!(f32),
        Scalar::F64 => read!(f64),
    })
}

impl<const BIG_ENDIAN: bool> Values for Binary<'_, BIG_ENDIAN> {
    #[inline(always)]
    fn value(&mut self, ty: Scalar) -> Result<f64, Stop> {
        let v = decode::<BIG_ENDIAN>(&self.data[self.pos..], ty).ok_or(Stop::End)?;
        self.pos += ty.size();
        Ok(v)
    }

    fn skip(&mut self, ty: Scalar, n: usize) -> Result<(), Stop> {
        let len = n.checked_mul(ty.size()).ok_or(Stop::End)?;
        if len > self.remaining() {
            return Err(Stop::End);
        }
        self.pos += len;
        Ok(())
    }

    fn remaining(&self) -> usize {
        self.data.len() - self.pos
    }

    fn line(&self) -> Option<usize> {
        None
    }

    fn records<F>(
        &mut self,
        stride: usize,
        count: usize,
        fields: &[Field],
        mut each: F,
    ) -> Option<Result<()>>
    where
        F: FnMut(usize, &[f64; SLOTS]) -> Result<()>,
    {
        let len = stride.checked_mul(count)?;
        let block = self.data.get(self.pos..self.pos.checked_add(len)?)?;
        self.pos += len;
        for (i, record) in block.chunks_exact(stride).enumerate() {
            let mut v = [0.0; SLOTS];
            for f in fields {
                // Fields lie inside the record by construction, so this
                // always decodes; `get` just makes that a checked fact
                // instead of a place that could panic.
                if let Some(x) = record
                    .get(f.offset..)
                    .and_then(|b| decode::<BIG_ENDIAN>(b, f.ty))
                {
                    v[f.slot] = x;
                }
            }
            if let Err(e) = each(i, &v) {
                return Some(Err(e));
            }
        }
        Some(Ok(()))
    }

    #[inline(always)]
    fn triangle(&mut self, item: Scalar) -> Option<[f64; 3]> {
        let [count, rest @ ..] = self.data[self.pos..].first_chunk::<13>()?;
        if *count != 3 || item.size() != 4 {
            return None;
        }
        let mut corners = [0.0; 3];
        for (corner, bytes) in corners.iter_mut().zip(rest.chunks_exact(4)) {
            *corner = decode::<BIG_ENDIAN>(bytes, item)?;
        }
        self.pos += 13;
        Some(corners)
    }
}

struct Ascii<'a> {
    data: &'a [u8],
    pos: usize,
    line: usize,
}

impl<'a> Ascii<'a> {
    fn token(&mut self) -> Result<&'a [u8], Stop> {
        while let Some(&b) = self.data.get(self.pos) {
            if !b.is_ascii_whitespace() {
                break;
            }
            if b == b'\n' {
                self.line += 1;
            }
            self.pos += 1;
        }
        let start = self.pos;
        while self
            .data
            .get(self.pos)
            .is_some_and(|b| !b.is_ascii_whitespace())
        {
            self.pos += 1;
        }
        if start == self.pos {
            Err(Stop::End)
        } else {
            Ok(&self.data[start..self.pos])
        }
    }
}

impl Values for Ascii<'_> {
    fn value(&mut self, ty: Scalar) -> Result<f64, Stop> {
        let token = self.token()?;
        std::str::from_utf8(token)
            .ok()
            .and_then(|s| {
                // Parsing a float property straight to f32 avoids the rare
                // double rounding of text -> f64 -> f32, keeping round trips exact.
                if ty == Scalar::F32 {
                    s.parse::<f32>().ok().map(f64::from)
                } else {
                    s.parse().ok()
                }
            })
            .ok_or_else(|| Stop::BadToken {
                line: self.line,
                token: String::from_utf8_lossy(&token[..token.len().min(40)]).into_owned(),
            })
    }

    fn skip(&mut self, ty: Scalar, n: usize) -> Result<(), Stop> {
        for _ in 0..n {
            self.value(ty)?;
        }
        Ok(())
    }

    fn remaining(&self) -> usize {
        self.data.len() - self.pos
    }

    fn line(&self) -> Option<usize> {
        Some(self.line)
    }
}

/// Slots of the per-vertex values we keep.
const X: usize = 0;
const NX: usize = 3;
const RED: usize = 6;

fn vertex_slot(name: &str) -> Option<usize> {
    Some(match name {
        "x" => X,
        "y" => X + 1,
        "z" => X + 2,
        "nx" => NX,
        "ny" => NX + 1,
        "nz" => NX + 2,
        "red" | "diffuse_red" => RED,
        "green" | "diffuse_green" => RED + 1,
        "blue" | "diffuse_blue" => RED + 2,
        _ => return None,
    })
}

/// Walks every element of the body in header order.
fn read_body<V: Values>(src: &mut V, header: &Header, path: &Path) -> Result<Mesh> {
    let vertex_count = header
        .elements
        .iter()
        .find(|e| e.name == "vertex")
        .map(|e| e.count)
        .ok_or_else(|| Error::format(path, "no vertex element"))?;
    let mut mesh = Mesh::default();
    let mut seen_vertex = false;
    let mut seen_face = false;
    for element in &header.elements {
        match element.name.as_str() {
            "vertex" if !seen_vertex => {
                seen_vertex = true;
                read_vertices(src, element, &mut mesh, path)?;
            }
            "face" if !seen_face => {
                seen_face = true;
                read_faces(src, element, vertex_count, &mut mesh, path)?;
            }
            _ => skip_element(src, element, path)?,
        }
    }
    Ok(mesh)
}

fn stop_error(stop: Stop, path: &Path, element: &Element, index: usize) -> Error {
    let what = format!("{} {index} (of {})", element.name, element.count);
    match stop {
        Stop::End => Error::format(path, format!("data ends inside {what}")),
        Stop::BadToken { line, token } => Error::format(
            path,
            format!("line {line}: '{token}' is not a number (in {what})"),
        ),
    }
}

/// A list length as an exact non-negative integer.
#[inline(always)]
fn list_len(v: f64) -> Option<usize> {
    let n = v as u32;
    (n as f64 == v).then_some(n as usize)
}

fn bad_list(src: &impl Values, path: &Path, element: &Element, index: usize, v: f64) -> Error {
    let at = src
        .line()
        .map(|l| format!("line {l}: "))
        .unwrap_or_default();
    Error::format(
        path,
        format!("{at}bad list length {v} in {} {index}", element.name),
    )
}

fn skip_element(src: &mut impl Values, element: &Element, path: &Path) -> Result<()> {
    if element.properties.is_empty() {
        // Zero-size instances: nothing to skip, however large the count.
        return Ok(());
    }
    for i in 0..element.count {
        for p in &element.properties {
            let r = match p.kind {
                Kind::Scalar(ty) => src.skip(ty, 1),
                Kind::List { count, item } => {
                    let v = src
                        .value(count)
                        .map_err(|s| stop_error(s, path, element, i))?;
                    let n = list_len(v).ok_or_else(|| bad_list(src, path, element, i, v))?;
                    src.skip(item, n)
                }
            };
            r.map_err(|s| stop_error(s, path, element, i))?;
        }
    }
    Ok(())
}

fn read_vertices(
    src: &mut impl Values,
    element: &Element,
    mesh: &mut Mesh,
    path: &Path,
) -> Result<()> {
    let mut slots = Vec::with_capacity(element.properties.len());
    let mut fields = Vec::new();
    let mut fixed_size = Some(0);
    let mut found = [false; SLOTS];
    let mut color_scale = [1.0; 3];
    for p in &element.properties {
        let slot = match p.kind {
            Kind::Scalar(ty) => {
                let slot = vertex_slot(&p.name);
                if let Some(s) = slot {
                    found[s] = true;
                    if s >= RED {
                        color_scale[s - RED] = ty.color_scale();
                    }
                    if let Some(offset) = fixed_size {
                        fields.push(Field {
                            offset,
                            ty,
                            slot: s,
                        });
                    }
                }
                fixed_size = fixed_size.map(|size| size + ty.size());
                slot
            }
            Kind::List { .. } => {
                fixed_size = None;
                None
            }
        };
        slots.push(slot);
    }
    for (s, axis) in ["x", "y", "z"].iter().enumerate() {
        if !found[X + s] {
            return Err(Error::format(
                path,
                format!("vertex element has no scalar '{axis}' property"),
            ));
        }
    }
    let has_normals = found[NX..NX + 3].iter().all(|&f| f);
    let has_colors = found[RED..RED + 3].iter().all(|&f| f);

    let capacity = element
        .count
        .min(src.remaining() / element.min_size().max(1));
    mesh.positions.reserve(capacity);
    if has_normals {
        mesh.normals.reserve(capacity);
    }
    if has_colors {
        mesh.colors.reserve(capacity);
    }
    let mut push = |i: usize, v: &[f64; SLOTS]| {
        let p = Vec3::new(v[X] as f32, v[X + 1] as f32, v[X + 2] as f32);
        if !p.is_finite() {
            return Err(Error::format(
                path,
                format!("vertex {i} has a non-finite coordinate {p}"),
            ));
        }
        mesh.positions.push(p);
        if has_normals {
            mesh.normals
                .push(Vec3::new(v[NX] as f32, v[NX + 1] as f32, v[NX + 2] as f32));
        }
        if has_colors {
            // `as u8` saturates (and maps NaN to 0), so out-of-range input clamps.
            mesh.colors.push(std::array::from_fn(|c| {
                (v[RED + c] * color_scale[c] + 0.5) as u8
            }));
        }
        Ok(())
    };
    if let Some(stride) = fixed_size.filter(|&size| size > 0) {
        if let Some(result) = src.records(stride, element.count, &fields, &mut push) {
            return result;
        }
    }
    for i in 0..element.count {
        let mut v = [0.0f64; SLOTS];
        for (p, slot) in element.properties.iter().zip(&slots) {
            let r = match (p.kind, *slot) {
                (Kind::Scalar(ty), Some(s)) => src.value(ty).map(|x| v[s] = x),
                (Kind::Scalar(ty), None) => src.skip(ty, 1),
                (Kind::List { count, item }, _) => {
                    let c = src
                        .value(count)
                        .map_err(|s| stop_error(s, path, element, i))?;
                    let n = list_len(c).ok_or_else(|| bad_list(src, path, element, i, c))?;
                    src.skip(item, n)
                }
            };
            r.map_err(|s| stop_error(s, path, element, i))?;
        }
        push(i, &v)?;
    }
    Ok(())
}

fn read_faces(
    src: &mut impl Values,
    element: &Element,
    vertex_count: usize,
    mesh: &mut Mesh,
    path: &Path,
) -> Result<()> {
    let indices = element
        .properties
        .iter()
        .position(|p| {
            matches!(p.kind, Kind::List { .. })
                && (p.name == "vertex_indices" || p.name == "vertex_index")
        })
        .ok_or_else(|| {
            Error::format(
                path,
                "face element has no vertex_indices (or vertex_index) list",
            )
        })?;
    // Faces that are nothing but a list with a one-byte count can take the
    // binary triangle fast path.
    let fast_item = match element.properties.as_slice() {
        [Property {
            kind:
                Kind::List {
                    count: Scalar::U8,
                    item,
                },
            ..
        }] => Some(*item),
        _ => None,
    };
    let capacity = element
        .count
        .min(src.remaining() / element.min_size().max(1));
    mesh.triangles.reserve(capacity);
    let index = |v: f64, f: usize| {
        let i = v as u32;
        if i as f64 == v && (i as usize) < vertex_count {
            Ok(i)
        } else {
            Err(Error::format(
                path,
                format!("face {f}: vertex index {v} out of range ({vertex_count} vertices)"),
            ))
        }
    };
    for f in 0..element.count {
        if let Some(corners) = fast_item.and_then(|item| src.triangle(item)) {
            let [a, b, c] = corners;
            mesh.triangles
                .push([index(a, f)?, index(b, f)?, index(c, f)?]);
            continue;
        }
        for (j, p) in element.properties.iter().enumerate() {
            match p.kind {
                Kind::Scalar(ty) => src
                    .skip(ty, 1)
                    .map_err(|s| stop_error(s, path, element, f))?,
                Kind::List { count, item } => {
                    let c = src
                        .value(count)
                        .map_err(|s| stop_error(s, path, element, f))?;
                    let n = list_len(c).ok_or_else(|| bad_list(src, path, element, f, c))?;
                    if j != indices || n < 3 {
                        src.skip(item, n)
                            .map_err(|s| stop_error(s, path, element, f))?;
                        continue;
                    }
                    let mut next = || -> Result<u32> {
                        let v = src
                            .value(item)
                            .map_err(|s| stop_error(s, path, element, f))?;
                        index(v, f)
                    };
                    let a = next()?;
                    let mut b = next()?;
                    for _ in 2..n {
                        let c = next()?;
                        mesh.triangles.push([a, b, c]);
                        b = c;
                    }
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atomic::scratch::ScratchDir;

    fn sample(normals: bool, colors: bool) -> Mesh {
        let positions = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.5, -2.25, 3.125),
            Vec3::new(0.1, 0.2, 0.3),
            Vec3::new(-1e-7, 12345.678, f32::MAX),
        ];
        Mesh {
            normals: if normals {
                vec![Vec3::X, Vec3::Y, Vec3::new(0.6, 0.0, 0.8), Vec3::NEG_Z]
            } else {
                Vec::new()
            },
            colors: if colors {
                vec![[0, 0, 0], [255, 128, 1], [7, 200, 99], [255, 255, 255]]
            } else {
                Vec::new()
            },
            positions,
            triangles: vec![[0, 1, 2], [2, 1, 3], [3, 0, 2]],
        }
    }

    fn to_bytes(mesh: &Mesh, format: PlyFormat) -> Vec<u8> {
        let mut out = Vec::new();
        write_ply_to(&mut out, mesh, format).unwrap();
        out
    }

    fn parse(bytes: &[u8]) -> Result<Mesh> {
        read_ply_from_bytes(bytes, Path::new("test.ply"))
    }

    fn err(bytes: &[u8]) -> String {
        let e = parse(bytes).unwrap_err();
        let message = e.to_string();
        assert!(matches!(e, Error::Format { .. }), "{message}");
        assert!(message.contains("test.ply"), "{message}");
        message
    }

    /// Builds a binary PLY from a header and body assembled by the caller.
    fn binary(header: &str, body: &[u8]) -> Vec<u8> {
        let mut out = header.as_bytes().to_vec();
        out.extend_from_slice(body);
        out
    }

    #[test]
    fn binary_round_trip_is_exact() {
        for (normals, colors) in [(false, false), (true, false), (false, true), (true, true)] {
            let mesh = sample(normals, colors);
            let back = parse(&to_bytes(&mesh, PlyFormat::BinaryLittleEndian)).unwrap();
            assert_eq!(back, mesh);
        }
    }

    #[test]
    fn ascii_round_trip_is_exact() {
        for (normals, colors) in [(false, false), (true, true)] {
            let mesh = sample(normals, colors);
            let bytes = to_bytes(&mesh, PlyFormat::Ascii);
            assert!(bytes.starts_with(b"ply\nformat ascii 1.0\n"));
            assert_eq!(parse(&bytes).unwrap(), mesh);
        }
    }

    #[test]
    fn big_endian_is_read() {
        let mesh = sample(true, true);
        let mut body = Vec::new();
        for i in 0..mesh.positions.len() {
            for v in mesh.positions[i].to_array() {
                body.extend_from_slice(&v.to_be_bytes());
            }
            for v in mesh.normals[i].to_array() {
                body.extend_from_slice(&v.to_be_bytes());
            }
            body.extend_from_slice(&mesh.colors[i]);
        }
        for t in &mesh.triangles {
            body.push(3);
            for i in t {
                body.extend_from_slice(&i.to_be_bytes());
            }
        }
        let header = "ply\nformat binary_big_endian 1.0\nelement vertex 4\n\
            property float x\nproperty float y\nproperty float z\n\
            property float nx\nproperty float ny\nproperty float nz\n\
            property uchar red\nproperty uchar green\nproperty uchar blue\n\
            element face 3\nproperty list uchar uint vertex_indices\nend_header\n";
        assert_eq!(parse(&binary(header, &body)).unwrap(), mesh);
    }

    #[test]
    fn file_round_trip() {
        let dir = ScratchDir::new("ply-file");
        let path = dir.path().join("mesh.ply");
        let mesh = sample(true, true);
        for format in [PlyFormat::BinaryLittleEndian, PlyFormat::Ascii] {
            write_ply(&path, &mesh, format).unwrap();
            assert_eq!(read_ply(&path).unwrap(), mesh);
        }
        assert_eq!(dir.entries(), vec!["mesh.ply".to_string()]);
    }

    #[test]
    fn invalid_mesh_is_not_written() {
        let dir = ScratchDir::new("ply-invalid");
        let path = dir.path().join("mesh.ply");
        let mut mesh = sample(false, false);
        mesh.triangles.push([0, 1, 9]);
        assert!(matches!(
            write_ply(&path, &mesh, PlyFormat::BinaryLittleEndian),
            Err(Error::Parameter { .. })
        ));
        assert!(dir.entries().is_empty());
    }

    #[test]
    fn meshlab_layout_with_alpha_and_quality() {
        let header = "ply\r\nformat binary_little_endian 1.0\r\ncomment VCGLIB generated\r\n\
            element vertex 3\r\nproperty float x\r\nproperty float y\r\nproperty float z\r\n\
            property float nx\r\nproperty float ny\r\nproperty float nz\r\n\
            property uchar red\r\nproperty uchar green\r\nproperty uchar blue\r\n\
            property uchar alpha\r\nproperty float quality\r\n\
            element face 1\r\nproperty list uchar int vertex_indices\r\nend_header\r\n";
        let mut body = Vec::new();
        for i in 0..3 {
            let f = i as f32;
            for v in [f, f + 0.5, -f, 0.0, 0.0, 1.0] {
                body.extend_from_slice(&v.to_le_bytes());
            }
            body.extend_from_slice(&[10 * i as u8, 20, 30, 255]);
            body.extend_from_slice(&0.75f32.to_le_bytes());
        }
        body.push(3);
        for i in [2i32, 1, 0] {
            body.extend_from_slice(&i.to_le_bytes());
        }
        let mesh = parse(&binary(header, &body)).unwrap();
        assert_eq!(mesh.positions[2], Vec3::new(2.0, 2.5, -2.0));
        assert_eq!(mesh.normals, vec![Vec3::Z; 3]);
        assert_eq!(mesh.colors, vec![[0, 20, 30], [10, 20, 30], [20, 20, 30]]);
        assert_eq!(mesh.triangles, vec![[2, 1, 0]]);
    }

    #[test]
    fn open3d_trimesh_layout_with_double_coordinates() {
        // vertex_index with uint counts, double coordinates, float colours,
        // an extra list property on vertices and an edge element to skip.
        let header = "ply\nformat binary_little_endian 1.0\nobj_info made by hand\n\
            element vertex 4\nproperty double x\nproperty double y\nproperty double z\n\
            property list uint8 int32 extra\n\
            property float32 diffuse_red\nproperty float32 diffuse_green\n\
            property float32 diffuse_blue\n\
            element face 2\nproperty list uint uint32 vertex_index\nproperty int16 flags\n\
            element edge 1\nproperty int vertex1\nproperty int vertex2\n\
            end_header\n";
        let mut body = Vec::new();
        for i in 0..4 {
            for v in [i as f64 * 0.1, 1e-3, 1e5 + i as f64] {
                body.extend_from_slice(&v.to_le_bytes());
            }
            body.push(2);
            body.extend_from_slice(&[0u8; 8]);
            for c in [0.0f32, 0.5, 1.0] {
                body.extend_from_slice(&c.to_le_bytes());
            }
        }
        for face in [[0u32, 1, 2], [0, 2, 3]] {
            body.extend_from_slice(&3u32.to_le_bytes());
            for i in face {
                body.extend_from_slice(&i.to_le_bytes());
            }
            body.extend_from_slice(&7i16.to_le_bytes());
        }
        body.extend_from_slice(&[0u8; 8]);
        let mesh = parse(&binary(header, &body)).unwrap();
        assert_eq!(mesh.positions.len(), 4);
        assert_eq!(mesh.positions[3], Vec3::new(0.3, 1e-3, 100003.0));
        assert!(mesh.normals.is_empty());
        assert_eq!(mesh.colors, vec![[0, 128, 255]; 4]);
        assert_eq!(mesh.triangles, vec![[0, 1, 2], [0, 2, 3]]);
    }

    #[test]
    fn polygons_are_fanned_and_degenerate_faces_skipped() {
        let text = "ply\nformat ascii 1.0\ncomment quad, pentagon, a line and a point\n\
            element vertex 5\nproperty float x\nproperty float y\nproperty float z\n\
            element face 4\nproperty list uchar int vertex_indices\nend_header\n\
            0 0 0\n1 0 0\n1 1 0\n0 1 0\n0.5 2 0\n\
            4 0 1 2 3\n5 0 1 2 4 3\n2 0 1\n1 4\n";
        let mesh = parse(text.as_bytes()).unwrap();
        assert_eq!(
            mesh.triangles,
            vec![[0, 1, 2], [0, 2, 3], [0, 1, 2], [0, 2, 4], [0, 4, 3]]
        );
    }

    #[test]
    fn point_cloud_without_faces() {
        let text = "ply\nformat ascii 1.0\nelement vertex 2\nproperty int x\n\
            property short y\nproperty uchar z\nend_header\n1 -2 3\n4 5 6\n";
        let mesh = parse(text.as_bytes()).unwrap();
        assert_eq!(
            mesh.positions,
            vec![Vec3::new(1.0, -2.0, 3.0), Vec3::new(4.0, 5.0, 6.0)]
        );
        assert!(mesh.triangles.is_empty());
    }

    #[test]
    fn header_errors() {
        assert!(err(b"").contains("not a PLY file"));
        assert!(err(b"plx\nformat ascii 1.0\nend_header\n").contains("not a PLY file"));
        assert!(err(b"ply\nformat binary_middle_endian 1.0\nend_header\n")
            .contains("unknown format 'binary_middle_endian'"));
        assert!(err(b"ply\nelement vertex 0\nend_header\n").contains("no format"));
        assert!(err(b"ply\nformat ascii 1.0\nelement vertex 1\n").contains("end_header"));
        assert!(
            err(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty quad x\nend_header\n")
                .contains("unknown property type 'quad'")
        );
        assert!(
            err(b"ply\nformat ascii 1.0\nproperty float x\nend_header\n")
                .contains("before any element")
        );
        assert!(
            err(b"ply\nformat ascii 1.0\nelement vertex many\nend_header\n")
                .contains("header line 3")
        );
        assert!(err(b"ply\nformat ascii 1.0\nend_header\n").contains("no vertex element"));
        let no_z = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n\
            property float y\nend_header\n1 2\n";
        assert!(err(no_z.as_bytes()).contains("'z'"));
        let no_indices = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n\
            property float y\nproperty float z\nelement face 1\nproperty list uchar int \
            corners\nend_header\n1 2 3\n3 0 0 0\n";
        assert!(err(no_indices.as_bytes()).contains("vertex_indices"));
    }

    #[test]
    fn truncated_binary_names_element_and_index() {
        let bytes = to_bytes(&sample(true, true), PlyFormat::BinaryLittleEndian);
        assert!(err(&bytes[..bytes.len() - 1]).contains("face 2 (of 3)"));
        let vertex_end = bytes.len() - 3 * 13;
        assert!(err(&bytes[..vertex_end - 5]).contains("vertex 3 (of 4)"));
    }

    #[test]
    fn every_truncation_fails_cleanly() {
        for format in [PlyFormat::BinaryLittleEndian, PlyFormat::Ascii] {
            let bytes = to_bytes(&sample(true, true), format);
            // Only ASCII's final newline may go and leave a valid file.
            for len in 0..bytes.len() - 1 {
                err(&bytes[..len]);
            }
        }
    }

    #[test]
    fn corrupted_bytes_never_panic() {
        let clean = to_bytes(&sample(true, true), PlyFormat::BinaryLittleEndian);
        for bytes in crate::mesh::corrupted_copies(&clean, 0x9e37_79b9_7f4a_7c15, 2000) {
            if parse(&bytes).is_err() {
                err(&bytes);
            }
        }
    }

    #[test]
    fn out_of_range_index_names_face() {
        let text = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n\
            property float y\nproperty float z\nelement face 2\n\
            property list uchar int vertex_indices\nend_header\n\
            0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 1 3\n";
        let message = err(text.as_bytes());
        assert!(
            message.contains("face 1: vertex index 3 out of range"),
            "{message}"
        );
        let negative = text.replace("3 0 1 3", "3 0 -1 2");
        assert!(err(negative.as_bytes()).contains("vertex index -1"));
    }

    #[test]
    fn binary_quads_and_out_of_range_indices() {
        let header = "ply\nformat binary_little_endian 1.0\nelement vertex 4\n\
            property float x\nproperty float y\nproperty float z\nelement face 3\n\
            property list uchar int vertex_indices\nend_header\n";
        let mut body = vec![0u8; 48];
        for face in [&[0i32, 1, 2][..], &[0, 1, 2, 3], &[3, 2, 1]] {
            body.push(face.len() as u8);
            for i in face {
                body.extend_from_slice(&i.to_le_bytes());
            }
        }
        let mesh = parse(&binary(header, &body)).unwrap();
        assert_eq!(
            mesh.triangles,
            vec![[0, 1, 2], [0, 1, 2], [0, 2, 3], [3, 2, 1]]
        );
        // Index 3 of the last face (a plain triangle) becomes 4, then -1.
        let at = body.len() - 12;
        body[at..at + 4].copy_from_slice(&4i32.to_le_bytes());
        let message = err(&binary(header, &body));
        assert!(
            message.contains("face 2: vertex index 4 out of range"),
            "{message}"
        );
        body[at..at + 4].copy_from_slice(&(-1i32).to_le_bytes());
        assert!(err(&binary(header, &body)).contains("face 2: vertex index -1"));
        // The same in the quad, which takes the general path.
        body[48 + 13 + 1..48 + 13 + 5].copy_from_slice(&9i32.to_le_bytes());
        assert!(err(&binary(header, &body)).contains("face 1: vertex index 9"));
    }

    #[test]
    fn garbage_ascii_names_line() {
        let text = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\n\
            property float y\nproperty float z\nend_header\n0 0 0\n1 zero 0\n";
        let message = err(text.as_bytes());
        assert!(
            message.contains("line 9: 'zero' is not a number"),
            "{message}"
        );
        assert!(message.contains("vertex 1"), "{message}");
        let short = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\n\
            property float y\nproperty float z\nend_header\n0 0 0\n1 0\n";
        assert!(err(short.as_bytes()).contains("data ends inside vertex 1 (of 2)"));
        let bad_count = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n\
            property float y\nproperty float z\nelement face 1\n\
            property list uchar int vertex_indices\nend_header\n0 0 0\n2.5 0 0 0\n";
        assert!(err(bad_count.as_bytes()).contains("line 11: bad list length 2.5"));
    }

    #[test]
    fn non_finite_coordinates_are_rejected() {
        let text = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\n\
            property float y\nproperty float z\nend_header\n0 0 0\n1 nan 0\n";
        assert!(err(text.as_bytes()).contains("vertex 1 has a non-finite"));
        let header = "ply\nformat binary_little_endian 1.0\nelement vertex 1\n\
            property double x\nproperty double y\nproperty double z\nend_header\n";
        let mut body = Vec::new();
        for v in [0.0, 1e300, 0.0f64] {
            body.extend_from_slice(&v.to_le_bytes());
        }
        assert!(err(&binary(header, &body)).contains("non-finite"));
    }

    #[test]
    fn huge_counts_do_not_allocate_or_hang() {
        let header = "ply\nformat binary_little_endian 1.0\n\
            element vertex 18446744073709551615\nproperty float x\nproperty float y\n\
            property float z\nend_header\n";
        assert!(err(&binary(header, &[0; 24])).contains("data ends inside vertex 2"));
        let empty = "ply\nformat binary_little_endian 1.0\nelement nothing 18446744073709551615\n\
            element vertex 0\nproperty float x\nproperty float y\nproperty float z\n\
            end_header\n";
        assert!(parse(empty.as_bytes()).unwrap().positions.is_empty());
        let long_list = "ply\nformat binary_little_endian 1.0\nelement vertex 1\n\
            property float x\nproperty float y\nproperty float z\nelement face 1\n\
            property list uint int vertex_indices\nend_header\n";
        let mut body = vec![0u8; 12];
        body.extend_from_slice(&u32::MAX.to_le_bytes());
        assert!(err(&binary(long_list, &body)).contains("face 0"));
    }
}
