//! Vertices at one position joined into one: the connectivity of a mesh stored as a triangle soup.
//!
//! STL exports and many OBJ and PLY writers store each triangle with its own three vertices, so
//! that the surface's triangles share positions but no vertex. The geodesic descriptors and the
//! rim walk need the triangles' shared edges; on such a soup every triangle is a surface of its
//! own. Welding (as Open3D's `merge_close_vertices` or trimesh's `merge_vertices` do, here for
//! positions equal to the bit) gives back the surface the file describes.

use nalgebra::Vector3;
use rustc_hash::FxHashMap;

/// A mesh whose vertices at one position are one vertex.
#[derive(Clone, Debug)]
pub(crate) struct Welded {
    /// One point per distinct position, in the order of first appearance.
    pub points: Vec<Vector3<f64>>,
    /// Per point, the normalised sum of the normals of the vertices joined in it (the first
    /// one's where they cancel).
    pub normals: Vec<Vector3<f64>>,
    /// The triangles on the joined vertices.
    pub faces: Vec<[u32; 3]>,
}

/// The mesh with its vertices at equal positions (±0 alike) joined, or `None` when no two
/// vertices share a position. Face indices past `points` are kept as they are (the readers
/// refuse them).
pub(crate) fn weld(
    points: &[Vector3<f64>],
    normals: &[Vector3<f64>],
    faces: &[[u32; 3]],
) -> Option<Welded> {
    let key = |p: &Vector3<f64>| p.map(|c| (c + 0.0).to_bits());
    let mut first: FxHashMap<Vector3<u64>, u32> = FxHashMap::default();
    // each vertex's joined vertex, and each joined vertex's first vertex
    let (mut of, mut firsts) = (Vec::with_capacity(points.len()), Vec::new());
    let mut welded = Welded {
        points: Vec::new(),
        normals: Vec::new(),
        faces: Vec::new(),
    };
    for (k, p) in points.iter().enumerate() {
        let next = welded.points.len() as u32;
        let at = *first.entry(key(p)).or_insert(next);
        if at == next {
            firsts.push(k);
            welded.points.push(*p);
            welded.normals.push(Vector3::zeros());
        }
        if let Some(n) = normals.get(k) {
            welded.normals[at as usize] += n;
        }
        of.push(at);
    }
    if welded.points.len() == points.len() {
        return None;
    }
    for (n, &k) in welded.normals.iter_mut().zip(&firsts) {
        *n = n
            .try_normalize(1e-12)
            .unwrap_or_else(|| normals.get(k).copied().unwrap_or_else(Vector3::z));
    }
    welded.faces = faces
        .iter()
        .map(|f| f.map(|v| of.get(v as usize).copied().unwrap_or(v)))
        .collect();
    Some(welded)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two triangles of a square stored apart (six vertices) share their diagonal once welded;
    /// a mesh with no shared position is left alone.
    #[test]
    fn a_triangle_soup_is_welded_into_shared_vertices() {
        let corner = |x: f64, y: f64| Vector3::new(x, y, 0.0);
        let points = [
            corner(0.0, 0.0),
            corner(1.0, 0.0),
            corner(1.0, 1.0),
            corner(-0.0, 0.0),
            corner(1.0, 1.0),
            corner(0.0, 1.0),
        ];
        let tilted = Vector3::new(0.0, 0.6, 0.8);
        let normals = [
            Vector3::z(),
            Vector3::z(),
            Vector3::z(),
            tilted,
            tilted,
            tilted,
        ];
        let faces = [[0, 1, 2], [3, 4, 5]];
        let w = weld(&points, &normals, &faces).expect("two positions are shared");
        assert_eq!(w.points.len(), 4);
        assert_eq!(w.faces, vec![[0, 1, 2], [0, 2, 3]]);
        let shared = (Vector3::z() + tilted).normalize();
        assert!((w.normals[0] - shared).norm() < 1e-12, "{:?}", w.normals[0]);
        assert!((w.normals[1] - Vector3::z()).norm() < 1e-12);
        assert!((w.normals[3] - tilted).norm() < 1e-12);
        assert!(weld(&points[..3], &normals[..3], &faces[..1]).is_none());
    }
}
