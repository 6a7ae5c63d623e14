//! Affine slippage: the affine motion under which a surface moves least off itself, beside the
//! rigid one of module `slippage`.
//!
//! The rigid measure of Gelfand et al. (module `slippage`) taken over the twelve infinitesimal
//! affine motions u = δA p + δd instead of the six rigid ones. Point-to-plane terms see
//! n · u = r · ξ with ξ = (δA row by row, δd) and r = (n₁ pᵀ, n₂ pᵀ, n₃ pᵀ, nᵀ); the motion's
//! squared displacement is |J ξ|², J = (I ⊗ pᵀ | I). With the same area weights, centroid,
//! unit of length and boundary band as the rigid measure,
//!
//! ```text
//! C = Σ_k (a_k / A) r_k r_kᵀ,        B = Σ_k (a_k / A) J_kᵀ J_k
//! ```
//!
//! and the least eigenvalue of C ξ = λ B ξ is the share of the freest affine motion's
//! displacement that leaves the surface. It is at most the rigid ratio (rigid motions are
//! affine). An ellipsoid of three different axes, which turns about no axis, has three affine
//! motions that keep it on itself (E Ω E⁻¹ for the rotations Ω of the sphere it is the image of,
//! E its axes): 0. So a registration onto or from it can compose its answer with a stretch and
//! shear of the surface along itself and fit exactly as well, and only the regulariser's
//! preference chooses among them. A box or the camel has no such motion.
//!
//! B is singular for a flat surface (δA applied along the normal moves nothing); the measure is
//! taken over the motions that move the surface (B's range).

use super::affine_fit::{affine_row, AffineMap};
use super::extent::finite;
use super::slippage::Samples;
use nalgebra::{SMatrix, Vector3};

type Matrix12 = SMatrix<f64, 12, 12>;

/// Below this share of an affine motion's displacement leaving the surface, the surface slides
/// along itself under a stretch or shear. Measured (NOTES 197): ellipsoids 2–3·10⁻⁷; the
/// targets of stretched tori, cones, cylinders and spheroids 10⁻¹⁵–1.3·10⁻³ (they slide
/// rigidly as well); bumpy blobs from 7.5·10⁻⁴ up (the flattest are nearly ellipsoids); sheets
/// 2.8·10⁻³, boxes 2·10⁻² and the camel 0.094 and over. The rigid measure's limit,
/// [`super::slippage::MAX_SLIPPAGE`].
pub const MAX_AFFINE_SLIPPAGE: f64 = 1e-3;

/// The share of the fit's tolerance (the node spacing) by which an answer may depart from a
/// rigid motion of the source and still count as rigid ([`AffineSlide::is_free`]).
pub const RIGID_SHARE: f64 = 0.1;

/// Both surfaces' affine slippage beside how far a registration's answer is from rigid: where
/// either surface slides under an affine motion and the answer is not rigid, the data cannot
/// tell it from the same answer composed with that motion, and it is not reported registered
/// (`SurfaceVerdict::AffineAmbiguous`). A rigid answer stays: of the answers that fit equally,
/// it is the one that deforms nothing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AffineSlide {
    /// The source's and the target's least affine slippage ratios ([`affine_slippage`]).
    pub ratios: [f64; 2],
    /// The answer's departure from rigid ([`departure_from_rigid`]), in the meshes' unit.
    pub departure: f64,
    /// The departure above which the answer is not rigid: [`RIGID_SHARE`] of the fit's
    /// tolerance.
    pub limit: f64,
}

impl AffineSlide {
    /// Whether either surface slides under an affine motion ([`MAX_AFFINE_SLIPPAGE`]) and the
    /// answer departs from rigid by more than the limit (a departure that could not be measured
    /// counts as more).
    pub fn is_free(&self) -> bool {
        let slides = self.ratios.iter().any(|&r| r < MAX_AFFINE_SLIPPAGE);
        let rigid = self.departure.is_finite() && self.departure <= self.limit;
        slides && !rigid
    }
}

/// The root mean square distance of `placed` (an answer, in the source's order) from `source`
/// carried by the rigid motion that fits them best ([`AffineMap::nearest_rigid`]), over the
/// pairs where both are finite; `None` where that motion is `None`.
pub fn departure_from_rigid(source: &[Vector3<f64>], placed: &[Vector3<f64>]) -> Option<f64> {
    let motion = AffineMap::nearest_rigid(source, placed)?;
    let (sum, count) = (source.iter().zip(placed))
        .filter(|(p, q)| finite(p) && finite(q))
        .fold((0.0, 0usize), |(sum, count), (p, q)| {
            (sum + (motion.apply(p) - q).norm_squared(), count + 1)
        });
    Some((sum / count as f64).sqrt())
}

/// The least share of an affine motion's mean squared displacement that leaves the mesh
/// `faces` over `points` with the vertex `normals`, its boundary counted as a band `band` wide
/// (module docs); `None` where the mesh has no area or its points span no motion.
pub fn affine_slippage(
    points: &[Vector3<f64>],
    normals: &[Vector3<f64>],
    faces: &[[u32; 3]],
    band: f64,
) -> Option<f64> {
    let (c, b) = Samples::new(points, normals, faces, band)?.sums(constraint, displacement);
    least_ratio(&c, &b)
}

/// r rᵀ, r = (n₁ pᵀ, n₂ pᵀ, n₃ pᵀ, nᵀ) ([`affine_row`]): what a point-to-plane term at p with
/// normal n measures of an affine motion, squared.
fn constraint(p: &Vector3<f64>, n: &Vector3<f64>) -> Matrix12 {
    let r = affine_row(p, n);
    r * r.transpose()
}

/// Jᵀ J, J = (I ⊗ pᵀ | I): an affine motion's squared displacement of p.
fn displacement(p: &Vector3<f64>) -> Matrix12 {
    let mut j = SMatrix::<f64, 3, 12>::zeros();
    for i in 0..3 {
        j.fixed_view_mut::<1, 3>(i, 3 * i).copy_from(&p.transpose());
        j[(i, 9 + i)] = 1.0;
    }
    j.transpose() * j
}

/// The least eigenvalue of C ξ = λ B ξ over B's range: B = V Λ Vᵀ, the directions of Λ above a
/// 10⁻⁹ share of its largest kept, W = V_k Λ_k^−½, and the least eigenvalue of Wᵀ C W.
fn least_ratio(c: &Matrix12, b: &Matrix12) -> Option<f64> {
    let eigen = b.symmetric_eigen();
    let largest = eigen.eigenvalues.max();
    if largest.is_nan() || largest <= 0.0 {
        return None;
    }
    let kept: Vec<usize> = (0..12)
        .filter(|&k| eigen.eigenvalues[k] > 1e-9 * largest)
        .collect();
    let w = nalgebra::DMatrix::from_fn(12, kept.len(), |i, j| {
        let k = kept[j];
        eigen.eigenvectors[(i, k)] / eigen.eigenvalues[k].sqrt()
    });
    let m = w.transpose() * c * &w;
    let m = 0.5 * (&m + m.transpose());
    let least = m.symmetric_eigenvalues().min();
    least.is_finite().then(|| least.max(0.0))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nonrigid::orientation::tests::{bumps, sphere};
    use crate::nonrigid::slippage::slippage;
    use crate::nonrigid::slippage::tests::normals;

    /// The sphere mesh of `sphere` with its points moved by `f`.
    fn shaped(f: impl Fn(&Vector3<f64>) -> Vector3<f64>) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
        let (p, faces) = sphere(1.0, Vector3::zeros(), 24);
        (p.iter().map(f).collect(), faces)
    }

    fn both(mesh: &(Vec<Vector3<f64>>, Vec<[u32; 3]>), band: f64) -> (f64, f64) {
        let n = normals(&mesh.0, &mesh.1);
        let rigid = slippage(&mesh.0, &n, &mesh.1, band).expect("area").ratio;
        let affine = affine_slippage(&mesh.0, &n, &mesh.1, band).expect("area");
        (rigid, affine)
    }

    #[test]
    fn an_ellipsoid_slides_under_an_affine_motion_and_a_bumpy_or_boxy_shape_does_not() {
        let axes = Vector3::new(1.0, 0.6, 0.35);
        let (rigid, affine) = both(&shaped(|p| p.component_mul(&axes)), 0.0);
        // it turns about no axis, yet stretches along itself
        assert!(rigid > 0.01 && affine < 1e-4, "{rigid} {affine}");
        // bumps of a fifth of the radius pin it
        let bumpy = |p: &Vector3<f64>| (bumps(p) * p).component_mul(&axes);
        let (_, pinned) = both(&shaped(bumpy), 0.0);
        assert!(pinned > MAX_AFFINE_SLIPPAGE, "{pinned}");
        // a rounded cube (a sphere pushed out to the sup-norm ball, halfway)
        let boxy = |p: &Vector3<f64>| 0.5 * (p + p / p.amax());
        let (_, cube) = both(&shaped(boxy), 0.0);
        assert!(cube > MAX_AFFINE_SLIPPAGE, "{cube}");
        // never above the rigid ratio
        let (rigid, affine) = both(&shaped(bumpy), 0.0);
        assert!(affine <= rigid + 1e-12, "{rigid} {affine}");
    }

    #[test]
    fn a_rigid_answer_does_not_depart_and_a_stretched_one_does() {
        let (points, _) = shaped(|p| p.component_mul(&Vector3::new(1.0, 0.6, 0.35)));
        let turn = nalgebra::Rotation3::from_euler_angles(0.2, -0.9, 1.4);
        let moved: Vec<Vector3<f64>> = points
            .iter()
            .map(|p| turn * p + Vector3::new(3.0, -2.0, 0.5))
            .collect();
        assert!(departure_from_rigid(&points, &moved).unwrap() < 1e-9);
        let stretched: Vec<Vector3<f64>> =
            moved.iter().map(|p| p + 0.2 * p.x * Vector3::x()).collect();
        let d = departure_from_rigid(&points, &stretched).unwrap();
        assert!(d > 0.05, "{d}");
        let slide = |ratios, departure| AffineSlide {
            ratios,
            departure,
            limit: 0.01,
        };
        assert!(slide([1e-6, 0.2], d).is_free());
        assert!(!slide([0.2, 0.2], d).is_free());
        assert!(!slide([1e-6, 1e-6], 1e-3).is_free());
        assert!(slide([1e-6, 0.2], f64::NAN).is_free());
        // a lost point is left out; too few points fix nothing
        let mut holed = moved.clone();
        holed[3] = Vector3::repeat(f64::NAN);
        assert!(departure_from_rigid(&points, &holed).unwrap() < 1e-9);
        assert_eq!(departure_from_rigid(&points[..2], &moved[..2]), None);
    }

    #[test]
    fn the_measure_is_unit_free_and_a_flat_sheet_is_measured_within_its_plane() {
        let ellipsoid = |s: f64| shaped(move |p| s * p.component_mul(&Vector3::new(1.0, 0.7, 0.4)));
        let turn = nalgebra::Rotation3::from_euler_angles(0.4, 0.1, -0.7);
        let lumpy = |s: f64| shaped(move |p| s * (turn * p) * (1.0 + 0.1 * (3.0 * p.x).sin()));
        let (a, b) = (both(&lumpy(0.01), 0.0).1, both(&lumpy(100.0), 0.0).1);
        assert!((a - b).abs() <= 1e-6 * a, "{a} {b}");
        assert!(both(&ellipsoid(0.01), 0.0).1 < 1e-4);
        // a flat grid: B is singular along the normal, and the band holds the rest
        let n = 12;
        let points: Vec<Vector3<f64>> = (0..n * n)
            .map(|k| Vector3::new((k % n) as f64 * 0.1, (k / n) as f64 * 0.05, 0.0))
            .collect();
        let faces: Vec<[u32; 3]> = (0..n - 1)
            .flat_map(|j| (0..n - 1).map(move |i| (j * n + i) as u32))
            .flat_map(|a| {
                let n = n as u32;
                [[a, a + 1, a + n + 1], [a, a + n + 1, a + n]]
            })
            .collect();
        let normals = vec![Vector3::z(); points.len()];
        let held = affine_slippage(&points, &normals, &faces, 0.1).expect("area");
        let loose = affine_slippage(&points, &normals, &faces, 0.0).expect("area");
        assert!(held > MAX_AFFINE_SLIPPAGE && loose < 1e-9, "{held} {loose}");
        // no area
        let line = [Vector3::zeros(), Vector3::x(), 2.0 * Vector3::x()];
        assert_eq!(
            affine_slippage(&line, &normals[..3], &[[0, 1, 2]], 0.1),
            None
        );
    }
}
