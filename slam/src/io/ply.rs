//! PLY meshes (Turk, *The PLY Polygon File Format*, 1994): written as binary little-endian with
//! positions, normals, colours and triangles; read from binary little- or big-endian or ASCII,
//! with LF or CR LF header lines.

use super::{write_atomic, IoError};
use crate::mesh::Mesh;
use nalgebra::{Point3, Vector3};
use std::path::Path;

/// Encodes a mesh as binary little-endian PLY.
pub fn encode(mesh: &Mesh) -> Vec<u8> {
    let (has_n, has_c) = (!mesh.normals.is_empty(), !mesh.colors.is_empty());
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment dynamap\nelement vertex {}\n",
        mesh.vertices.len()
    );
    header.push_str("property float x\nproperty float y\nproperty float z\n");
    if has_n {
        header.push_str("property float nx\nproperty float ny\nproperty float nz\n");
    }
    if has_c {
        header.push_str("property uchar red\nproperty uchar green\nproperty uchar blue\n");
    }
    header.push_str(&format!(
        "element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.faces.len()
    ));
    let mut out = header.into_bytes();
    out.reserve(mesh.vertices.len() * 27 + mesh.faces.len() * 13);
    for (i, v) in mesh.vertices.iter().enumerate() {
        for c in v.coords.iter() {
            out.extend_from_slice(&c.to_le_bytes());
        }
        if has_n {
            for c in mesh.normals[i].iter() {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
        if has_c {
            out.extend_from_slice(&mesh.colors[i]);
        }
    }
    for f in &mesh.faces {
        out.push(3);
        for i in f {
            out.extend_from_slice(&(*i as i32).to_le_bytes());
        }
    }
    out
}

/// Writes a mesh as binary PLY through a temporary file.
pub fn write(path: impl AsRef<Path>, mesh: &Mesh) -> Result<(), IoError> {
    let path = path.as_ref();
    mesh.validate().map_err(|m| IoError::file(path, m))?;
    write_atomic(path, &encode(mesh))
}

#[derive(Clone, Copy, PartialEq)]
enum Kind {
    F32,
    F64,
    U8,
    I32,
    U32,
    I16,
    U16,
    I8,
}

impl Kind {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "float" | "float32" => Kind::F32,
            "double" | "float64" => Kind::F64,
            "uchar" | "uint8" => Kind::U8,
            "char" | "int8" => Kind::I8,
            "int" | "int32" => Kind::I32,
            "uint" | "uint32" => Kind::U32,
            "short" | "int16" => Kind::I16,
            "ushort" | "uint16" => Kind::U16,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            Kind::F64 => 8,
            Kind::F32 | Kind::I32 | Kind::U32 => 4,
            Kind::I16 | Kind::U16 => 2,
            Kind::U8 | Kind::I8 => 1,
        }
    }
    /// The value at the start of `b` (at least [`Self::size`] bytes), in the byte order `order`.
    fn read(self, b: &[u8], order: ByteOrder) -> f64 {
        let mut raw = [0u8; 8];
        raw[..self.size()].copy_from_slice(&b[..self.size()]);
        if order == ByteOrder::Big {
            raw[..self.size()].reverse();
        }
        let four = || raw[..4].try_into().unwrap();
        let two = || raw[..2].try_into().unwrap();
        match self {
            Kind::F32 => f32::from_le_bytes(four()) as f64,
            Kind::F64 => f64::from_le_bytes(raw),
            Kind::I32 => i32::from_le_bytes(four()) as f64,
            Kind::U32 => u32::from_le_bytes(four()) as f64,
            Kind::I16 => i16::from_le_bytes(two()) as f64,
            Kind::U16 => u16::from_le_bytes(two()) as f64,
            Kind::U8 => raw[0] as f64,
            Kind::I8 => raw[0] as i8 as f64,
        }
    }
}

/// How a PLY body stores its values.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Encoding {
    Ascii,
    Binary(ByteOrder),
}

/// A binary body's byte order.
#[derive(Clone, Copy, Debug, PartialEq)]
enum ByteOrder {
    Little,
    Big,
}

struct Element {
    name: String,
    count: usize,
    /// (name, type) or, for a list, (name, count type, item type)
    props: Vec<(String, Kind, Option<Kind>)>,
}

/// Reads a PLY mesh (binary of either byte order, or ASCII; vertices with optional normals and
/// colours, polygon faces fanned into triangles).
pub fn read(path: impl AsRef<Path>) -> Result<Mesh, IoError> {
    let path = path.as_ref();
    let bytes =
        std::fs::read(path).map_err(|e| IoError::file(path, format!("cannot read: {e}")))?;
    decode(&bytes, path)
}

/// Decodes PLY bytes; `path` names them in errors.
pub fn decode(bytes: &[u8], path: &Path) -> Result<Mesh, IoError> {
    let (header, body) = split_header(bytes, path)?;
    let (elements, encoding) = parse_header(header, path)?;
    check_counts(&elements, body.len(), path)?;
    let mut values = match encoding {
        Encoding::Ascii => {
            let text = std::str::from_utf8(body)
                .map_err(|_| IoError::file(path, "ASCII body is not text"))?;
            Values::Ascii(text.split_whitespace())
        }
        Encoding::Binary(order) => Values::Binary(body, order),
    };
    let mut mesh = Mesh::default();
    for el in elements.iter().filter(|e| !e.props.is_empty()) {
        for _ in 0..el.count {
            read_entry(el, &mut values, &mut mesh, path)?;
        }
    }
    mesh.validate().map_err(|m| IoError::file(path, m))?;
    Ok(mesh)
}

/// The header's text (up to its `end_header` line, which may end in CR LF as files written on
/// Windows do) and the body after it.
fn split_header<'a>(bytes: &'a [u8], path: &Path) -> Result<(&'a str, &'a [u8]), IoError> {
    let tag = b"end_header";
    let end = bytes
        .windows(tag.len())
        .enumerate()
        .filter(|(_, w)| w == tag)
        .map(|(i, _)| i)
        .find(|&i| {
            (i == 0 || bytes[i - 1] == b'\n')
                && matches!(&bytes[i + tag.len()..], [b'\n', ..] | [b'\r', b'\n', ..])
        })
        .ok_or_else(|| IoError::file(path, "no 'end_header' line"))?;
    let header = std::str::from_utf8(&bytes[..end])
        .map_err(|_| IoError::file(path, "header is not text"))?;
    let newline = if bytes[end + tag.len()] == b'\r' {
        2
    } else {
        1
    };
    Ok((header, &bytes[end + tag.len() + newline..]))
}

/// The header's elements with their properties, and how the body is encoded.
fn parse_header(header: &str, path: &Path) -> Result<(Vec<Element>, Encoding), IoError> {
    let mut elements: Vec<Element> = Vec::new();
    let mut encoding = None;
    for (i, line) in header.lines().enumerate() {
        let f: Vec<&str> = line.split_whitespace().collect();
        let err = |m: &str| IoError::line(path, i + 1, m.to_string());
        match f.first().copied() {
            Some("ply") | Some("comment") | Some("obj_info") | None => {}
            Some("format") => match f.get(1).copied() {
                Some("binary_little_endian") => {
                    encoding = Some(Encoding::Binary(ByteOrder::Little))
                }
                Some("binary_big_endian") => encoding = Some(Encoding::Binary(ByteOrder::Big)),
                Some("ascii") => encoding = Some(Encoding::Ascii),
                other => return Err(err(&format!("unsupported format {other:?}"))),
            },
            Some("element") => {
                let count = f
                    .get(2)
                    .and_then(|c| c.parse().ok())
                    .ok_or_else(|| err("element needs a name and a count"))?;
                elements.push(Element {
                    name: f.get(1).unwrap_or(&"").to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            Some("property") => {
                let el = elements
                    .last_mut()
                    .ok_or_else(|| err("property before any element"))?;
                el.props.push(parse_property(&f).map_err(err)?);
            }
            Some(other) => return Err(err(&format!("unknown header keyword '{other}'"))),
        }
    }
    let encoding =
        encoding.ok_or_else(|| IoError::file(path, "the header has no 'format' line"))?;
    Ok((elements, encoding))
}

/// A `property` line's (name, type, list item type), split into words.
fn parse_property(f: &[&str]) -> Result<(String, Kind, Option<Kind>), &'static str> {
    if f.get(1) == Some(&"list") {
        let (c, t) = (
            f.get(2).and_then(|s| Kind::parse(s)),
            f.get(3).and_then(|s| Kind::parse(s)),
        );
        match (c, t, f.get(4)) {
            (Some(c), Some(t), Some(n)) => Ok((n.to_string(), c, Some(t))),
            _ => Err("malformed list property"),
        }
    } else {
        match (f.get(1).and_then(|s| Kind::parse(s)), f.get(2)) {
            (Some(k), Some(n)) => Ok((n.to_string(), k, None)),
            _ => Err("malformed property"),
        }
    }
}

/// Every property takes at least a byte (two in ASCII): a count beyond the body is a lie, and
/// looping over it would take forever (an element without properties is read as nothing).
fn check_counts(elements: &[Element], body: usize, path: &Path) -> Result<(), IoError> {
    match elements
        .iter()
        .find(|e| !e.props.is_empty() && e.count > body)
    {
        Some(el) => Err(IoError::file(
            path,
            format!(
                "element '{}' declares {} entries, more than the {} bytes after the header hold",
                el.name, el.count, body
            ),
        )),
        None => Ok(()),
    }
}

/// The body's values in order: words of an ASCII body, or binary in a byte order.
enum Values<'a> {
    Ascii(std::str::SplitWhitespace<'a>),
    Binary(&'a [u8], ByteOrder),
}

impl Values<'_> {
    /// The next value, of type `k`.
    fn next(&mut self, k: Kind, path: &Path) -> Result<f64, IoError> {
        match self {
            Values::Ascii(t) => t
                .next()
                .and_then(|s| s.parse::<f64>().ok())
                .ok_or_else(|| IoError::file(path, "ASCII body ends early or has a non-number")),
            Values::Binary(body, order) => {
                if body.len() < k.size() {
                    return Err(IoError::file(path, "binary body ends early"));
                }
                let v = k.read(body, *order);
                *body = &body[k.size()..];
                Ok(v)
            }
        }
    }
}

/// Reads one entry of `el` and adds it to `mesh`: a vertex (with its normal and colour when it
/// has them), or a face (polygons fan-triangulated); entries of other elements are skipped.
fn read_entry(
    el: &Element,
    values: &mut Values,
    mesh: &mut Mesh,
    path: &Path,
) -> Result<(), IoError> {
    let mut vals: Vec<(usize, f64)> = Vec::with_capacity(el.props.len());
    let mut face = Vec::new();
    for (pi, (name, k, list)) in el.props.iter().enumerate() {
        match list {
            Some(t) => {
                let n = values.next(*k, path)? as usize;
                for _ in 0..n {
                    let v = values.next(*t, path)?;
                    if name == "vertex_indices" || name == "vertex_index" {
                        face.push(v);
                    }
                }
            }
            None => vals.push((pi, values.next(*k, path)?)),
        }
    }
    let get = |n: &str| {
        el.props
            .iter()
            .position(|p| p.0 == n)
            .and_then(|i| vals.iter().find(|v| v.0 == i))
            .map(|v| v.1)
    };
    if el.name == "vertex" {
        let (x, y, z) = (get("x"), get("y"), get("z"));
        let (Some(x), Some(y), Some(z)) = (x, y, z) else {
            return Err(IoError::file(path, "vertex element lacks x, y or z"));
        };
        mesh.vertices
            .push(Point3::new(x as f32, y as f32, z as f32));
        if let (Some(a), Some(b), Some(c)) = (get("nx"), get("ny"), get("nz")) {
            mesh.normals
                .push(Vector3::new(a as f32, b as f32, c as f32));
        }
        if let (Some(r), Some(g), Some(b)) = (get("red"), get("green"), get("blue")) {
            mesh.colors.push([r as u8, g as u8, b as u8]);
        }
    } else if el.name == "face" {
        if face.len() < 3 {
            return Err(IoError::file(
                path,
                format!("face {} has {} vertices", mesh.faces.len(), face.len()),
            ));
        }
        if let Some(bad) = face
            .iter()
            .find(|&&v| v < 0.0 || v.fract() != 0.0 || v > u32::MAX as f64)
        {
            return Err(IoError::file(
                path,
                format!("face {} has vertex index {bad}", mesh.faces.len()),
            ));
        }
        for k in 1..face.len() - 1 {
            mesh.faces
                .push([face[0] as u32, face[k] as u32, face[k + 1] as u32]);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetrahedron() -> Mesh {
        let mut m = Mesh {
            vertices: vec![
                Point3::new(0.0, 0.0, 0.0),
                Point3::new(1.0, 0.0, 0.0),
                Point3::new(0.0, 1.0, 0.0),
                Point3::new(0.0, 0.0, 1.0),
            ],
            normals: vec![],
            colors: vec![[255, 0, 0], [0, 255, 0], [0, 0, 255], [7, 8, 9]],
            faces: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        };
        m.compute_normals();
        m
    }

    #[test]
    fn binary_round_trip() {
        let m = tetrahedron();
        let back = decode(&encode(&m), Path::new("t.ply")).unwrap();
        assert_eq!(back, m);
    }

    #[test]
    fn ascii_and_errors() {
        let text = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
        let m = decode(text, Path::new("a.ply")).unwrap();
        assert_eq!((m.vertices.len(), m.faces.len()), (3, 1));
        let bad = decode(&text[..text.len() - 4], Path::new("a.ply")).unwrap_err();
        assert!(
            bad.to_string().starts_with("a.ply: ASCII body ends early"),
            "{bad}"
        );
        let mut broken = encode(&tetrahedron());
        broken.truncate(broken.len() - 3);
        assert!(decode(&broken, Path::new("b.ply"))
            .unwrap_err()
            .to_string()
            .contains("binary body ends early"));
        let out_of_range = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n3 0 1 2\n";
        assert!(decode(out_of_range, Path::new("c.ply"))
            .unwrap_err()
            .to_string()
            .contains("face 0"));
    }

    /// `mesh` (no normals or colours) as binary big-endian PLY with double coordinates.
    fn big_endian(mesh: &Mesh) -> Vec<u8> {
        let mut out = format!(
            "ply\r\nformat binary_big_endian 1.0\r\nelement vertex {}\r\n\
             property double x\r\nproperty double y\r\nproperty double z\r\n\
             element face {}\r\nproperty list uchar uint vertex_indices\r\nend_header\r\n",
            mesh.vertices.len(),
            mesh.faces.len()
        )
        .into_bytes();
        for v in &mesh.vertices {
            for c in v.coords.iter() {
                out.extend_from_slice(&(*c as f64).to_be_bytes());
            }
        }
        for f in &mesh.faces {
            out.push(3);
            for i in f {
                out.extend_from_slice(&i.to_be_bytes());
            }
        }
        out
    }

    #[test]
    fn big_endian_files_with_windows_line_ends_are_read() {
        let mut m = tetrahedron();
        m.colors.clear();
        m.normals.clear();
        let back = decode(&big_endian(&m), Path::new("big.ply")).unwrap();
        assert_eq!(back, m);
    }

    #[test]
    fn face_indices_must_be_whole_and_not_negative_and_the_format_stated() {
        let head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                    property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
                    end_header\n0 0 0\n1 0 0\n0 1 0\n";
        for (face, says) in [("3 0 -1 2\n", "-1"), ("3 0 1.5 2\n", "1.5")] {
            let e = decode(format!("{head}{face}").as_bytes(), Path::new("f.ply")).unwrap_err();
            assert!(e.to_string().contains(says), "{e}");
        }
        let no_format = head.replace("format ascii 1.0\n", "");
        let e = decode(
            format!("{no_format}3 0 1 2\n").as_bytes(),
            Path::new("g.ply"),
        );
        assert!(e.unwrap_err().to_string().contains("'format'"));
    }

    proptest::proptest! {
        #[test]
        fn any_mesh_round_trips_through_binary_ply(
            points in proptest::collection::vec(
                (proptest::num::f32::NORMAL, proptest::num::f32::NORMAL, proptest::num::f32::NORMAL),
                1..40,
            ),
            faces in proptest::collection::vec((0u32..40, 0u32..40, 0u32..40), 0..30),
            normals: bool, colors: bool, seed in 0u8..255,
        ) {
            let n = points.len() as u32;
            let mesh = Mesh {
                vertices: points.iter().map(|&(x, y, z)| nalgebra::Point3::new(x, y, z)).collect(),
                normals: if normals {
                    points.iter().map(|&(x, y, z)| nalgebra::Vector3::new(z, x, y)).collect()
                } else {
                    Vec::new()
                },
                colors: if colors {
                    (0..n).map(|i| [i as u8, seed, (i as u8).wrapping_mul(seed)]).collect()
                } else {
                    Vec::new()
                },
                faces: faces.iter().map(|&(a, b, c)| [a % n, b % n, c % n]).collect(),
            };
            let back = decode(&encode(&mesh), Path::new("m.ply")).unwrap();
            proptest::prop_assert_eq!(back, mesh);
        }
    }
}
