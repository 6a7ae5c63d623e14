//! Triangle meshes in the text formats shape datasets use, OFF (Princeton shape benchmark) and
//! Wavefront OBJ (vertices, their colours where given, and faces), and [`read_mesh`], which picks the reader (PLY too) by
//! extension. Polygons with more than three corners are fanned into triangles.

use super::{ply, read_text, IoError};
use crate::mesh::{Mesh, Winding};
use dynamap_residuals::text::without_bom;
use nalgebra::Point3;
use std::borrow::Cow;
use std::path::Path;

/// Reads a PLY, OFF or OBJ mesh by its extension; normals are computed from the faces when the file
/// has none, after the triangles wound against their neighbours are turned over
/// ([`Mesh::orient_faces`]; [`read_mesh_oriented`] says how many). A point cloud (no faces)
/// without normals keeps none: it has nothing to compute them from, and a made-up normal would be
/// taken as measured.
pub fn read_mesh(path: impl AsRef<Path>) -> Result<Mesh, IoError> {
    read_mesh_oriented(path).map(|(mesh, _)| mesh)
}

/// [`read_mesh`], with what orienting the faces did when the normals were computed from them
/// (`None` when the file gave normals or has no faces).
pub fn read_mesh_oriented(path: impl AsRef<Path>) -> Result<(Mesh, Option<Winding>), IoError> {
    let path = path.as_ref();
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let mut mesh = match ext.as_str() {
        "ply" => ply::read(path)?,
        "off" => parse_off(&read_text(path)?, path)?,
        "obj" => parse_obj(&read_text(path)?, path)?,
        _ => {
            return Err(IoError::file(
                path,
                "unknown mesh format (expected .ply, .off or .obj)",
            ))
        }
    };
    if mesh.vertices.is_empty() {
        return Err(IoError::file(path, "the mesh has no vertices"));
    }
    let mut winding = None;
    if mesh.normals.len() != mesh.vertices.len() && !mesh.faces.is_empty() {
        winding = Some(mesh.compute_oriented_normals());
    }
    Ok((mesh, winding))
}

/// Parses a finite coordinate.
fn number(s: &str, path: &Path, line: usize) -> Result<f32, IoError> {
    s.parse::<f32>()
        .ok()
        .filter(|v| v.is_finite())
        .ok_or_else(|| IoError::line(path, line, format!("'{s}' is not a finite number")))
}

/// A vertex from its first three fields.
fn point(f: &[&str], path: &Path, line: usize) -> Result<Point3<f32>, IoError> {
    if f.len() < 3 {
        return Err(IoError::line(path, line, "a vertex needs x y z"));
    }
    Ok(Point3::new(
        number(f[0], path, line)?,
        number(f[1], path, line)?,
        number(f[2], path, line)?,
    ))
}

/// Appends a polygon's fan of triangles after checking its indices.
fn push_polygon(
    mesh: &mut Mesh,
    corners: &[u32],
    vertices: usize,
    path: &Path,
    line: usize,
) -> Result<(), IoError> {
    if corners.len() < 3 {
        return Err(IoError::line(path, line, "a face needs at least 3 corners"));
    }
    if let Some(bad) = corners.iter().find(|&&i| i as usize >= vertices) {
        return Err(IoError::line(
            path,
            line,
            format!("vertex index {bad} is past the {vertices} vertices"),
        ));
    }
    for k in 1..corners.len() - 1 {
        mesh.faces.push([corners[0], corners[k], corners[k + 1]]);
    }
    Ok(())
}

/// Parses OFF text: `OFF`, then `nv nf ne`, nv lines `x y z`, nf lines `n i_1 … i_n`. The
/// variants of the format that add per-vertex data after the position (`COFF` colours, `NOFF`
/// normals, `STOFF` texture coordinates, and their combinations such as `CNOFF`) are read for
/// their positions; the counts may follow the keyword on its line, even without a space
/// (`OFF490 518 0`, as in some of ModelNet's files); a byte-order mark before it is skipped.
pub fn parse_off(text: &str, path: &Path) -> Result<Mesh, IoError> {
    let text = without_bom(text);
    // (1-based line number, fields) of the lines that carry data
    let mut lines = text.lines().enumerate().filter_map(|(i, l)| {
        let l = l.split('#').next().unwrap_or("").trim();
        (!l.is_empty()).then(|| (i + 1, l.split_whitespace().collect::<Vec<_>>()))
    });
    let (n0, first) = lines
        .next()
        .ok_or_else(|| IoError::file(path, "empty file"))?;
    let counts = match off_keyword(first[0]) {
        Some(Ok(rest)) => {
            let on_line: Vec<&str> = std::iter::once(rest)
                .filter(|r| !r.is_empty())
                .chain(first[1..].iter().copied())
                .collect();
            if on_line.is_empty() {
                lines
                    .next()
                    .ok_or_else(|| IoError::file(path, "no counts line after 'OFF'"))?
            } else {
                (n0, on_line)
            }
        }
        Some(Err(keyword)) => {
            return Err(IoError::line(
                path,
                n0,
                format!("'{keyword}' (a point dimension other than 3) is not supported"),
            ))
        }
        None => {
            return Err(IoError::line(
                path,
                n0,
                "the file does not start with 'OFF'",
            ))
        }
    };
    let count =
        |k: usize| -> Result<usize, IoError> {
            counts.1.get(k).and_then(|s| s.parse().ok()).ok_or_else(|| {
                IoError::line(path, counts.0, "expected 'vertices faces edges' counts")
            })
        };
    let (nv, nf) = (count(0)?, count(1)?);
    let mut mesh = Mesh::default();
    for k in 0..nv {
        let (line, f) = lines.next().ok_or_else(|| {
            IoError::file(path, format!("the file ends after {k} of {nv} vertices"))
        })?;
        mesh.vertices.push(point(&f, path, line)?);
    }
    let mut corners = Vec::new();
    for k in 0..nf {
        let (line, f) = lines
            .next()
            .ok_or_else(|| IoError::file(path, format!("the file ends after {k} of {nf} faces")))?;
        let n: usize = f
            .first()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| IoError::line(path, line, "a face starts with its corner count"))?;
        if f.len() < n + 1 {
            return Err(IoError::line(
                path,
                line,
                format!("expected {n} corner indices"),
            ));
        }
        corners.clear();
        for s in &f[1..=n] {
            corners.push(
                s.parse::<u32>().map_err(|_| {
                    IoError::line(path, line, format!("'{s}' is not a vertex index"))
                })?,
            );
        }
        push_polygon(&mut mesh, &corners, nv, path, line)?;
    }
    Ok(mesh)
}

/// The OFF keyword at the start of `word`: the rest of the word after it (counts written without
/// a space), an error for the n-dimensional and homogeneous variants (`nOFF`, `4OFF`), or `None`
/// when the word is no OFF keyword.
fn off_keyword(word: &str) -> Option<Result<&str, &str>> {
    let at = word.find("OFF")?;
    let prefix = &word[..at];
    let rest = &word[at + 3..];
    let dimension = prefix.ends_with('4') || prefix.ends_with('n');
    let known = prefix
        .trim_end_matches(['4', 'n'])
        .strip_prefix("ST")
        .unwrap_or(prefix.trim_end_matches(['4', 'n']));
    let known = known.strip_prefix('C').unwrap_or(known);
    let known = known.strip_prefix('N').unwrap_or(known);
    let digits = rest.chars().all(|c| c.is_ascii_digit());
    match (known.is_empty() && digits, dimension) {
        (false, _) => None,
        (true, true) => Some(Err(word)),
        (true, false) => Some(Ok(rest)),
    }
}

/// Parses OBJ text: `v x y z` and `f a b c …` lines (indices 1-based, negative ones relative to
/// the vertices read so far, each possibly `v/vt/vn`); other statements are skipped. A face may
/// name a vertex defined further down the file: indices are checked once every vertex is read.
/// A line ending in a backslash goes on on the next (the format's continuation). Vertex colours
/// written after the position (`v x y z r g b`) are read when every vertex has one: in 0–1, as
/// MeshLab and Open3D write them, or in 8-bit levels where any channel of the file exceeds 1.
pub fn parse_obj(text: &str, path: &Path) -> Result<Mesh, IoError> {
    // a byte-order mark would hide the first statement's keyword
    let text = without_bom(text);
    let mut mesh = Mesh::default();
    // every face's corners, flat, and (line, first corner) per face
    let (mut corners, mut faces) = (Vec::new(), Vec::new());
    let mut colors = Vec::new();
    for (line, l) in obj_statements(text) {
        let f: Vec<&str> = l.split_whitespace().collect();
        match f.first() {
            Some(&"v") => {
                mesh.vertices.push(point(&f[1..], path, line)?);
                if let Some(rgb) = f.get(4..7).filter(|_| f.len() == 7) {
                    colors.push(obj_color(rgb, path, line)?);
                }
            }
            Some(&"f") => {
                faces.push((line, corners.len()));
                let so_far = mesh.vertices.len() as i64;
                for s in &f[1..] {
                    corners.push(obj_index(s, so_far, path, line)?);
                }
            }
            _ => {}
        }
    }
    let nv = mesh.vertices.len();
    for (k, &(line, start)) in faces.iter().enumerate() {
        let end = faces.get(k + 1).map_or(corners.len(), |f| f.1);
        push_polygon(&mut mesh, &corners[start..end], nv, path, line)?;
    }
    if colors.len() == nv {
        mesh.colors = obj_levels(&colors);
    }
    Ok(mesh)
}

/// OBJ's statements with the line each starts on: a line ending in `\` is joined to the next
/// (only such statements are copied; the others borrow their line).
fn obj_statements(text: &str) -> Vec<(usize, Cow<'_, str>)> {
    let mut out: Vec<(usize, Cow<'_, str>)> = Vec::new();
    let mut open = false;
    for (i, l) in text.lines().enumerate() {
        let (body, goes_on) = match l.trim_end().strip_suffix('\\') {
            Some(b) => (b, true),
            None => (l, false),
        };
        match out.last_mut().filter(|_| open) {
            Some((_, s)) => {
                let s = s.to_mut();
                s.push(' ');
                s.push_str(body);
            }
            None => out.push((i + 1, Cow::Borrowed(body))),
        }
        open = goes_on;
    }
    out
}

/// A vertex colour of OBJ's `v x y z r g b`, as written.
fn obj_color(rgb: &[&str], path: &Path, line: usize) -> Result<[f32; 3], IoError> {
    let mut c = [0.0; 3];
    for (c, s) in c.iter_mut().zip(rgb) {
        *c = number(s, path, line)?;
    }
    Ok(c)
}

/// OBJ vertex colours as 8-bit levels: the file's channels are fractions of 1 unless one of them
/// exceeds 1, when they are levels of 255 (some writers give those); clamped to the range.
fn obj_levels(colors: &[[f32; 3]]) -> Vec<[u8; 3]> {
    let levels = colors.iter().flatten().any(|&c| c > 1.0);
    let scale = if levels { 1.0 } else { 255.0 };
    let level = |c: f32| (c * scale).round().clamp(0.0, 255.0) as u8;
    colors.iter().map(|c| c.map(level)).collect()
}

/// A face corner's 0-based vertex index from `v`, `v/vt`, `v//vn` or `v/vt/vn` (`so_far`
/// vertices read before it, which a negative index counts back from).
fn obj_index(s: &str, so_far: i64, path: &Path, line: usize) -> Result<u32, IoError> {
    let idx: i64 = s
        .split('/')
        .next()
        .and_then(|v| v.parse().ok())
        .ok_or_else(|| IoError::line(path, line, format!("'{s}' is not a vertex index")))?;
    let abs = if idx < 0 { so_far + idx } else { idx - 1 };
    u32::try_from(abs)
        .ok()
        .filter(|_| idx != 0)
        .ok_or_else(|| IoError::line(path, line, format!("vertex index {idx} is out of range")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn off_and_obj_give_the_same_square() {
        let p = Path::new("square");
        let off = parse_off(
            "OFF\n# a square\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n",
            p,
        )
        .unwrap();
        let obj = parse_obj(
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nf 1/1 2 3 -1\n",
            p,
        )
        .unwrap();
        assert_eq!(off.faces, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(off, obj);
        // a face continued on the next line by a backslash is the same face
        let continued = parse_obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 \\\n 3 4\n", p);
        assert_eq!(continued.unwrap(), off);
    }

    /// `v x y z r g b` gives every vertex its colour (0–1 to 8 bits, or 8-bit levels where a
    /// channel exceeds 1; clamped either way); a file where only some
    /// vertices have one keeps none, and a colour that is no number is named by line.
    #[test]
    fn obj_vertex_colours_are_read_when_every_vertex_has_one() {
        let p = Path::new("c.obj");
        let mesh = parse_obj(
            "v 0 0 0 1 0 0\nv 1 0 0 0 0.5 0\nv 1 1 0 0 -0.5 1\nf 1 2 3\n",
            p,
        );
        assert_eq!(
            mesh.unwrap().colors,
            [[255, 0, 0], [0, 128, 0], [0, 0, 255]]
        );
        // a writer's 8-bit levels are read as levels, not clamped to white
        let levels = parse_obj("v 0 0 0 255 0 0\nv 1 0 0 0 128 1\nv 1 1 0 0 0 300\n", p);
        assert_eq!(
            levels.unwrap().colors,
            [[255, 0, 0], [0, 128, 1], [0, 0, 255]]
        );
        let some = parse_obj("v 0 0 0 1 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n", p).unwrap();
        assert!(some.colors.is_empty() && some.faces.len() == 1);
        let bad = parse_obj("v 0 0 0\nv 1 0 0 x 0 0\n", p).unwrap_err();
        assert_eq!(bad.to_string(), "c.obj:2: 'x' is not a finite number");
    }

    /// The unit square of `off_and_obj_give_the_same_square`, as two triangles.
    fn square() -> Mesh {
        let p = Path::new("square");
        parse_off("OFF\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n", p).unwrap()
    }

    #[test]
    fn off_variants_and_odd_headers_are_read_for_their_positions() {
        let p = Path::new("odd.off");
        let body = "0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n";
        let coloured = "0 0 0 255 0 0 255\n1 0 0 0 255 0 255\n1 1 0 0 0 255 255\n\
                        0 1 0 9 9 9 255\n4 0 1 2 3 128 128 128\n";
        let normals = "0 0 0 0 0 1\n1 0 0 0 0 1\n1 1 0 0 0 1\n0 1 0 0 0 1\n4 0 1 2 3\n";
        for text in [
            format!("OFF 4 1 0\n{body}"),
            format!("OFF4 1 0\n{body}"),
            format!("\u{feff}OFF\r\n4 1 0\r\n{}", body.replace('\n', "\r\n")),
            format!("COFF\n4 1 0\n{coloured}"),
            format!("NOFF\n4 1 0\n{normals}"),
            format!("CNOFF\n4 1 0\n{coloured}"),
            format!("STOFF\n# texture coordinates after each position\n4 1 0\n{normals}"),
        ] {
            let mesh = parse_off(&text, p).unwrap_or_else(|e| panic!("{text:?}: {e}"));
            assert_eq!(mesh, square(), "{text:?}");
        }
        for (text, says) in [
            (format!("4OFF\n4 1 0\n{body}"), "dimension"),
            (format!("nOFF\n3\n4 1 0\n{body}"), "dimension"),
            (
                format!("OFFICE\n4 1 0\n{body}"),
                "does not start with 'OFF'",
            ),
            ("COFF four 1 0\n".to_string(), "counts"),
        ] {
            let e = parse_off(&text, p).unwrap_err();
            assert!(e.message.contains(says) && e.line == 1, "{text:?}: {e}");
        }
    }

    /// Normals are computed from the faces where a file gives none; a point cloud without
    /// normals has nothing to compute them from and is read without.
    #[test]
    fn normals_are_computed_from_faces_and_not_made_up_for_a_cloud() {
        let dir = std::env::temp_dir().join(format!("dynamap_meshes_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (mesh, cloud) = (dir.join("square.off"), dir.join("cloud.off"));
        std::fs::write(&mesh, "OFF\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n").unwrap();
        std::fs::write(&cloud, "OFF\n4 0 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n").unwrap();
        let square = read_mesh(&mesh).unwrap();
        assert!(square
            .normals
            .iter()
            .all(|n| (n - Vector3::z()).norm() < 1e-6));
        assert_eq!(square.normals.len(), 4);
        let cloud = read_mesh(&cloud).unwrap();
        assert_eq!((cloud.vertices.len(), cloud.normals.len()), (4, 0));
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A grid whose triangles are wound some up, some down, is read with one normal direction
    /// (the majority's), and the read says how many were turned; a file with normals is left be.
    #[test]
    fn triangles_wound_against_their_neighbours_are_turned_before_normals_are_made() {
        let n = 5;
        let counts = format!("{} {} 0\n", (n + 1) * (n + 1), 2 * n * n);
        let corners = |normal: &str| {
            let rows = (0..=n).flat_map(|j| (0..=n).map(move |i| (i, j)));
            rows.map(|(i, j)| format!("{i} {j} 0{normal}\n"))
                .collect::<String>()
        };
        let mut faces = String::new();
        let at = |i: usize, j: usize| j * (n + 1) + i;
        for (k, (i, j)) in (0..n).flat_map(|j| (0..n).map(move |i| (i, j))).enumerate() {
            let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
            // every third square is wound downwards, the corner (0, 0) among them
            let (b, d) = if k % 3 == 0 { (d, b) } else { (b, d) };
            faces += &format!("3 {a} {b} {c}\n3 {a} {c} {d}\n");
        }
        let dir = std::env::temp_dir().join(format!("dynamap_winding_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("grid.off");
        std::fs::write(&file, format!("OFF\n{counts}{}{faces}", corners(""))).unwrap();
        let (mesh, winding) = read_mesh_oriented(&file).unwrap();
        let winding = winding.expect("normals were computed from the faces");
        assert_eq!((winding.turned, winding.pieces), (18, 1));
        assert_eq!(winding.disagreeing, 0);
        for (v, normal) in mesh.normals.iter().enumerate() {
            assert!(
                (normal - Vector3::z()).norm() < 1e-6,
                "vertex {v}: {normal:?}"
            );
        }
        let ply = dir.join("grid.ply");
        let head = format!(
            "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\n\
             property float z\nproperty float nx\nproperty float ny\nproperty float nz\n\
             element face {}\nproperty list uchar int vertex_indices\nend_header\n",
            (n + 1) * (n + 1),
            2 * n * n
        );
        std::fs::write(&ply, format!("{head}{}{faces}", corners(" 0 0 1"))).unwrap();
        let (given, winding) = read_mesh_oriented(&ply).unwrap();
        assert_eq!((given.normals.len(), winding), ((n + 1) * (n + 1), None));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn obj_faces_may_name_vertices_further_down_the_file() {
        let p = Path::new("late.obj");
        let late = parse_obj("f 1 2 3 4\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n", p).unwrap();
        assert_eq!(late, square());
        let marked = "\u{feff}v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n";
        assert_eq!(parse_obj(marked, p).unwrap(), square());
        let e = parse_obj("v 0 0 0\nf 1 2 5\nv 1 0 0\nv 1 1 0\n", p).unwrap_err();
        assert_eq!(e.line, 2, "{e}");
        // a negative index counts back from the vertices read before the face
        let e = parse_obj("v 0 0 0\nf -1 -2 -3\nv 1 0 0\nv 1 1 0\n", p).unwrap_err();
        assert!(e.line == 2 && e.message.contains("-2"), "{e}");
    }

    #[test]
    fn malformed_files_name_the_line() {
        let p = Path::new("bad.off");
        let e = parse_off("OFF\n2 1 0\n0 0 0\n1 x 0\n3 0 1 2\n", p).unwrap_err();
        assert_eq!((e.line, e.message.contains("'x'")), (4, true), "{e}");
        let e = parse_off("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n", p).unwrap_err();
        assert_eq!(e.line, 6, "{e}");
        let e = parse_off("OFF\n3 1 0\n0 0 0\n", p).unwrap_err();
        assert!(e.message.contains("1 of 3 vertices"), "{e}");
        let e = parse_obj("v 0 0 0\nf 1 2 3\n", Path::new("bad.obj")).unwrap_err();
        assert_eq!(e.line, 2, "{e}");
        assert!(read_mesh("mesh.stl").is_err());
    }
}
