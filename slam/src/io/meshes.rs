//! Triangle meshes in the text formats shape datasets use, OFF (Princeton shape benchmark) and
//! Wavefront OBJ (vertices and faces only), and [`read_mesh`], which picks the reader (PLY too) by
//! extension. Polygons with more than three corners are fanned into triangles.

use super::{ply, read_text, IoError};
use crate::mesh::Mesh;
use nalgebra::Point3;
use std::path::Path;

/// Reads a PLY, OFF or OBJ mesh by its extension; normals are computed from the faces when the file
/// has none.
pub fn read_mesh(path: impl AsRef<Path>) -> Result<Mesh, IoError> {
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
    if mesh.normals.len() != mesh.vertices.len() {
        mesh.compute_normals();
    }
    Ok(mesh)
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

/// Parses OFF text: `OFF`, then `nv nf ne`, nv lines `x y z`, nf lines `n i_1 … i_n`.
pub fn parse_off(text: &str, path: &Path) -> Result<Mesh, IoError> {
    // (1-based line number, fields) of the lines that carry data
    let mut lines = text.lines().enumerate().filter_map(|(i, l)| {
        let l = l.split('#').next().unwrap_or("").trim();
        (!l.is_empty()).then(|| (i + 1, l.split_whitespace().collect::<Vec<_>>()))
    });
    let (n0, first) = lines
        .next()
        .ok_or_else(|| IoError::file(path, "empty file"))?;
    // the counts may follow "OFF" on the same line
    let counts = match first.first() {
        Some(&"OFF") if first.len() > 1 => (n0, first[1..].to_vec()),
        Some(&"OFF") => lines
            .next()
            .ok_or_else(|| IoError::file(path, "no counts line after 'OFF'"))?,
        _ => {
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

/// Parses OBJ text: `v x y z` and `f a b c …` lines (indices 1-based, negative ones relative, each
/// possibly `v/vt/vn`); other statements are skipped.
pub fn parse_obj(text: &str, path: &Path) -> Result<Mesh, IoError> {
    let mut mesh = Mesh::default();
    let mut corners = Vec::new();
    for (i, l) in text.lines().enumerate() {
        let line = i + 1;
        let f: Vec<&str> = l.split_whitespace().collect();
        match f.first() {
            Some(&"v") => mesh.vertices.push(point(&f[1..], path, line)?),
            Some(&"f") => {
                corners.clear();
                let nv = mesh.vertices.len() as i64;
                for s in &f[1..] {
                    let idx: i64 = s
                        .split('/')
                        .next()
                        .and_then(|v| v.parse().ok())
                        .ok_or_else(|| {
                            IoError::line(path, line, format!("'{s}' is not a vertex index"))
                        })?;
                    let abs = if idx < 0 { nv + idx } else { idx - 1 };
                    if abs < 0 || idx == 0 {
                        return Err(IoError::line(
                            path,
                            line,
                            format!("vertex index {idx} is out of range"),
                        ));
                    }
                    corners.push(abs as u32);
                }
                push_polygon(&mut mesh, &corners, nv as usize, path, line)?;
            }
            _ => {}
        }
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

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
