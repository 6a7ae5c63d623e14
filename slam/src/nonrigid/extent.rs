//! The extent of a point set, the length that registration settings scale with.

use nalgebra::Vector3;

/// The diagonal of the points' axis-aligned bounding box.
pub fn bounding_diagonal(points: &[Vector3<f64>]) -> f64 {
    diagonal_of(points.iter())
}

/// A mesh's size: the bounding-box diagonal of the vertices its `faces` use, or of all `points`
/// when it has no faces (a point cloud). OFF and PLY files may hold vertices that no face uses;
/// they are not part of the surface and do not make it larger. Two such vertices 100 m out made
/// a camel's diagonal 190 times its own, its settings as coarse (three nodes, one for the body),
/// and its registration was reported as registered. Face indices past `points` are skipped (the
/// readers refuse them).
pub fn surface_diagonal(points: &[Vector3<f64>], faces: &[[u32; 3]]) -> f64 {
    if faces.is_empty() {
        return bounding_diagonal(points);
    }
    diagonal_of(
        faces
            .iter()
            .flatten()
            .filter_map(|&v| points.get(v as usize)),
    )
}

/// The points' mean, the origin a registration turns the shape about (zero for no points).
pub fn centroid(points: &[Vector3<f64>]) -> Vector3<f64> {
    if points.is_empty() {
        return Vector3::zeros();
    }
    points.iter().sum::<Vector3<f64>>() / points.len() as f64
}

fn diagonal_of<'a>(points: impl Iterator<Item = &'a Vector3<f64>>) -> f64 {
    let (lo, hi) = points.fold(
        (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        ),
        |(lo, hi), p| (lo.inf(p), hi.sup(p)),
    );
    (hi - lo).norm()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_vertex_no_face_uses_does_not_make_a_mesh_larger() {
        let mut points = vec![
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(3.0, 0.0, 0.0),
            Vector3::new(0.0, 4.0, 0.0),
        ];
        let faces = [[0, 1, 2]];
        assert_eq!(surface_diagonal(&points, &faces), 5.0);
        points.push(Vector3::new(100.0, 100.0, 100.0));
        assert_eq!(surface_diagonal(&points, &faces), 5.0);
        assert!(bounding_diagonal(&points) > 170.0);
        // a cloud has no faces: every point counts
        assert_eq!(surface_diagonal(&points, &[]), bounding_diagonal(&points));
        // an index past the points is skipped, not a panic
        assert_eq!(surface_diagonal(&points, &[[0, 1, 2], [0, 1, 9]]), 5.0);
    }
}
