//! The extent of a point set, the length that registration settings scale with.

use nalgebra::Vector3;

/// The diagonal of the points' axis-aligned bounding box.
pub fn bounding_diagonal(points: &[Vector3<f64>]) -> f64 {
    let (lo, hi) = points.iter().fold(
        (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        ),
        |(lo, hi), p| (lo.inf(p), hi.sup(p)),
    );
    (hi - lo).norm()
}
