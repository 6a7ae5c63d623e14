//! A point set's principal axes (the eigenvectors of its covariance), and the starts they give
//! for laying one whole shape onto another: the four proper rotations that put the source's axes
//! onto the target's, and the same with each axis stretched by the ratio of the two spreads
//! along it (matching the second moments, as moment-based registration does: an affine map A
//! carries the covariance Σ to A Σ Aᵀ, so a stretch along the principal axes is recovered
//! exactly, up to the axes' signs); and, for flat sheets, the maps that match the second moments
//! at sampled turns of the whitened plane, among which lies a stretch along any direction.

use super::affine_fit::AffineMap;
use super::extent::{centroid, finite};
use nalgebra::{Isometry3, Matrix3, Rotation3, UnitQuaternion, Vector3};

/// The sign changes of the axes that keep a right-handed frame right-handed: the identity and
/// the half turns about each axis.
const PROPER_FLIPS: [[f64; 3]; 4] = [
    [1.0, 1.0, 1.0],
    [1.0, -1.0, -1.0],
    [-1.0, 1.0, -1.0],
    [-1.0, -1.0, 1.0],
];

/// A spread below this share of the largest one is taken for none: a flat sheet's spread along
/// its normal is rounding, and its ratio to another sheet's says nothing.
const FLAT_SHARE: f64 = 1e-3;

/// The centroid, principal axes and spreads of a point set.
#[derive(Clone, Copy, Debug)]
struct PrincipalFrame {
    centre: Vector3<f64>,
    /// The axes as columns, by decreasing variance, made right-handed.
    axes: Matrix3<f64>,
    /// The standard deviation along each axis.
    spreads: Vector3<f64>,
}

impl PrincipalFrame {
    /// The frame of the finite ones of `points`; `None` with fewer than three.
    fn of(points: &[Vector3<f64>]) -> Option<Self> {
        let points: Vec<Vector3<f64>> = points.iter().filter(|p| finite(p)).copied().collect();
        if points.len() < 3 {
            return None;
        }
        let centre = centroid(&points);
        let covariance = points
            .iter()
            .map(|p| (p - centre) * (p - centre).transpose())
            .sum::<Matrix3<f64>>()
            / points.len() as f64;
        let eig = covariance.symmetric_eigen();
        let mut order = [0, 1, 2];
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
        let mut axes =
            Matrix3::from_columns(&order.map(|k| eig.eigenvectors.column(k).into_owned()));
        if axes.determinant() < 0.0 {
            axes.column_mut(2).neg_mut();
        }
        let spreads = Vector3::from(order.map(|k| eig.eigenvalues[k].max(0.0).sqrt()));
        Some(Self {
            centre,
            axes,
            spreads,
        })
    }
}

/// The frames of `source` and `target`, where both have three finite points.
fn frames(
    source: &[Vector3<f64>],
    target: &[Vector3<f64>],
) -> Option<(PrincipalFrame, PrincipalFrame)> {
    Some((PrincipalFrame::of(source)?, PrincipalFrame::of(target)?))
}

/// `linear` taken about the source's centroid and carrying it to the target's.
fn about(linear: Matrix3<f64>, s: &PrincipalFrame, t: &PrincipalFrame) -> AffineMap {
    AffineMap {
        linear,
        centre: s.centre,
        moved_centre: t.centre,
    }
}

/// Starting motions for registering one whole shape onto another: the identity, and the four
/// proper rotations that put the source's principal axes onto the target's, each moving centroid
/// onto centroid; over the finite points alone (one that is not would leave the covariance
/// without a number), the identity alone with fewer than three.
pub fn principal_axes_guesses(
    source: &[Vector3<f64>],
    target: &[Vector3<f64>],
) -> Vec<Isometry3<f64>> {
    let mut out = vec![Isometry3::identity()];
    let Some((s, t)) = frames(source, target) else {
        return out;
    };
    for flip in PROPER_FLIPS {
        let r = t.axes * Matrix3::from_diagonal(&Vector3::from(flip)) * s.axes.transpose();
        // a product of orthonormal matrices: orthonormal already
        let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
        let translation = t.centre - rotation * s.centre;
        out.push(Isometry3::from_parts(translation.into(), rotation));
    }
    out
}

/// The four affine maps `x ↦ A (x − c_source) + c_target` that put the source's
/// principal axes onto the target's (a proper sign change of them, as in
/// [`principal_axes_guesses`]) and stretch each by the target's spread over the source's along
/// it; an axis along which either spread is below a thousandth of its largest (a flat sheet's
/// normal) is not stretched. Empty with fewer than three finite points on either side.
pub fn moment_stretches(source: &[Vector3<f64>], target: &[Vector3<f64>]) -> Vec<AffineMap> {
    let Some((s, t)) = frames(source, target) else {
        return Vec::new();
    };
    let (s_max, t_max) = (s.spreads.max(), t.spreads.max());
    let ratio = Vector3::from_fn(|k, _| {
        let (a, b) = (s.spreads[k], t.spreads[k]);
        match a > FLAT_SHARE * s_max && b > FLAT_SHARE * t_max {
            true => b / a,
            false => 1.0,
        }
    });
    (PROPER_FLIPS.iter())
        .map(|flip| {
            let scaled = Vector3::from(*flip).component_mul(&ratio);
            let linear = t.axes * Matrix3::from_diagonal(&scaled) * s.axes.transpose();
            about(linear, &s, &t)
        })
        .collect()
}

/// For two flat point sets (each one's least spread under a thousandth of its largest), the
/// affine maps (about the centroids, as [`moment_stretches`] gives them) that carry the source's
/// second moments onto the target's in the plane, at `steps` turns evenly round it, each also
/// with the sheet turned over: an affine map A of the plane carries the covariance Σ to
/// A Σ Aᵀ, so A = L_t Q L_s⁻¹ for the whitening L = (axes) · diag(spreads) of each and some
/// orthogonal Q, which the turns sample. A stretch along any direction of the sheet lies among
/// them to within half a step. Empty where either set is not flat or has fewer than three
/// finite points.
pub fn whitened_turns(
    source: &[Vector3<f64>],
    target: &[Vector3<f64>],
    steps: usize,
) -> Vec<AffineMap> {
    let Some((s, t)) = frames(source, target) else {
        return Vec::new();
    };
    let flat = |f: &PrincipalFrame| f.spreads[2] <= FLAT_SHARE * f.spreads.max();
    if !flat(&s) || !flat(&t) || s.spreads[1] <= 0.0 {
        return Vec::new();
    }
    let spreads = |f: &PrincipalFrame| Vector3::new(f.spreads[0], f.spreads[1], 1.0);
    let unwhiten = t.axes * Matrix3::from_diagonal(&spreads(&t));
    let whiten = Matrix3::from_diagonal(&spreads(&s).map(|v| 1.0 / v)) * s.axes.transpose();
    let over = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0));
    (0..steps.max(1))
        .flat_map(|k| {
            let angle = std::f64::consts::TAU * k as f64 / steps.max(1) as f64;
            let turn = *Rotation3::from_axis_angle(&Vector3::z_axis(), angle).matrix();
            [turn, turn * over]
        })
        .map(|q| about(unwhiten * q * whiten, &s, &t))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Unit;

    /// A flat lattice sheet 2 × 1 on 21 × 11 points in the plane z = 0.
    fn sheet() -> Vec<Vector3<f64>> {
        (0..11)
            .flat_map(|j| (0..21).map(move |i| Vector3::new(0.1 * i as f64, 0.1 * j as f64, 0.0)))
            .collect()
    }

    /// A flat sheet stretched by 1.3 along its length, then turned 150° and moved: one of the
    /// four moment stretches is the map itself, and each of the four lays the sheet's points on
    /// the target's (the sheet's symmetries), none stretching its normal.
    #[test]
    fn a_stretched_sheet_is_laid_back_by_one_of_its_moment_stretches() {
        let source = sheet();
        let axis = Unit::new_normalize(Vector3::new(0.2, -0.7, 0.4));
        let turn = *Rotation3::from_axis_angle(&axis, 150f64.to_radians()).matrix();
        let linear = turn * Matrix3::from_diagonal(&Vector3::new(1.3, 1.0, 1.0));
        let shift = Vector3::new(0.3, -1.0, 2.0);
        let target: Vec<Vector3<f64>> = source.iter().map(|p| linear * p + shift).collect();
        let stretches = moment_stretches(&source, &target);
        assert_eq!(stretches.len(), 4);
        let carried = |m: &AffineMap| source.iter().map(|p| m.apply(p)).collect::<Vec<_>>();
        let exact = stretches.iter().filter(|s| {
            let moved = carried(s);
            (moved.iter().zip(&target)).all(|(m, t)| (m - t).norm() < 1e-9)
        });
        assert_eq!(exact.count(), 1);
        for s in &stretches {
            let moved = carried(s);
            let farthest = moved
                .iter()
                .map(|m| {
                    target
                        .iter()
                        .map(|t| (m - t).norm())
                        .fold(f64::MAX, f64::min)
                })
                .fold(0.0, f64::max);
            assert!(farthest < 1e-9, "{farthest}");
            let singular = s.linear.singular_values();
            assert!(
                singular.iter().all(|&v| (0.99..=1.31).contains(&v)),
                "{singular}"
            );
        }
    }

    /// The sheet stretched by 1.3 along a direction 30° off its length (a shear of its axes),
    /// turned 150° and moved: no moment stretch lays it back, but one of the 144 whitened turns
    /// carries every point within a twentieth of the sheet's length of its image; a ball is not
    /// flat and gives none.
    #[test]
    fn a_sheet_stretched_off_its_axes_is_near_one_of_its_whitened_turns() {
        let source = sheet();
        let along = Vector3::new(30f64.to_radians().cos(), 30f64.to_radians().sin(), 0.0);
        let axis = Unit::new_normalize(Vector3::new(0.2, -0.7, 0.4));
        let turn = *Rotation3::from_axis_angle(&axis, 150f64.to_radians()).matrix();
        let linear = turn * (Matrix3::identity() + 0.3 * along * along.transpose());
        let target: Vec<Vector3<f64>> = source.iter().map(|p| linear * p).collect();
        let farthest = |m: &AffineMap| {
            (source.iter().zip(&target))
                .map(|(p, t)| (m.apply(p) - t).norm())
                .fold(0.0, f64::max)
        };
        let nearest = |maps: Vec<_>| maps.iter().map(farthest).fold(f64::MAX, f64::min);
        assert!(nearest(moment_stretches(&source, &target)) > 0.1);
        let turns = whitened_turns(&source, &target, 72);
        assert_eq!(turns.len(), 144);
        assert!(
            nearest(turns) < 0.1,
            "{}",
            nearest(whitened_turns(&source, &target, 72))
        );
        let ball: Vec<Vector3<f64>> = (0..200)
            .map(|k| {
                let (a, b) = (0.1 * k as f64, 0.37 * k as f64);
                Vector3::new(a.sin() * b.cos(), a.sin() * b.sin(), a.cos())
            })
            .collect();
        assert!(whitened_turns(&ball, &ball, 72).is_empty());
    }

    /// Two points give no frame: no guesses but the identity and no stretches.
    #[test]
    fn too_few_points_give_no_frame() {
        let two = [Vector3::zeros(), Vector3::x()];
        assert_eq!(principal_axes_guesses(&two, &sheet()).len(), 1);
        assert!(moment_stretches(&sheet(), &two).is_empty());
    }
}
