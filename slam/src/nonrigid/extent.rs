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

/// The finite points' mean, the origin a registration turns the shape about (zero for none). A
/// vertex that is not finite is no part of the surface; in the mean it made every point's
/// place relative to it NaN, and the registration found no point to sample nodes from.
pub fn centroid(points: &[Vector3<f64>]) -> Vector3<f64> {
    let (sum, count) = points
        .iter()
        .filter(|p| finite(p))
        .fold((Vector3::zeros(), 0usize), |(s, n), p| (s + p, n + 1));
    if count == 0 {
        return Vector3::zeros();
    }
    sum / count as f64
}

/// Whether every coordinate of `p` is finite.
pub(crate) fn finite(p: &Vector3<f64>) -> bool {
    p.iter().all(|x| x.is_finite())
}

/// The diagonal of the finite points' bounding box (an infinite vertex made it infinite, and
/// the surface was refused as having no extent).
fn diagonal_of<'a>(points: impl Iterator<Item = &'a Vector3<f64>>) -> f64 {
    let (lo, hi) = points.filter(|p| finite(p)).fold(
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

    /// The corners of a 3-4-5 right triangle.
    fn right_triangle() -> Vec<Vector3<f64>> {
        vec![
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(3.0, 0.0, 0.0),
            Vector3::new(0.0, 4.0, 0.0),
        ]
    }

    #[test]
    fn a_vertex_no_face_uses_does_not_make_a_mesh_larger() {
        let mut points = right_triangle();
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

    #[test]
    fn points_that_are_not_finite_are_no_part_of_the_extent_or_the_centroid() {
        let mut points = right_triangle();
        let (diagonal, centre) = (bounding_diagonal(&points), centroid(&points));
        points.push(Vector3::new(f64::NAN, 1.0, 1.0));
        points.push(Vector3::new(f64::INFINITY, 1.0, 1.0));
        points.push(Vector3::new(0.0, f64::NEG_INFINITY, 1.0));
        assert_eq!(bounding_diagonal(&points), diagonal);
        assert_eq!(surface_diagonal(&points, &[[0, 1, 3], [2, 4, 5]]), diagonal);
        assert_eq!(centroid(&points), centre);
        assert_eq!(centroid(&points[3..]), Vector3::zeros());
    }
}
