//! Between and prior factors on SE(2) and SE(3) with analytic Jacobians.
//!
//! For `e = Log(E)`, `E = Z⁻¹ X_i⁻¹ X_j`, right perturbations give (Solà et al. 2018, sec. 4):
//! `∂e/∂δ_j = Jr⁻¹(e)` and `∂e/∂δ_i = −Jr⁻¹(e) Ad((X_i⁻¹ X_j)⁻¹)`; the residual is `r = U e` with
//! `UᵀU = Ω`.

use dynamap_solver::lie::{se2, se3};
use dynamap_solver::{Jacobians, Residual, Var, SE2, SE3};
use nalgebra::{Isometry2, Isometry3, Matrix3, Matrix6, SMatrix, SVector, Vector6};

/// The upper-triangular U with UᵀU = Ω, or `None` when Ω is not symmetric positive definite.
pub fn sqrt_information<const N: usize>(info: &SMatrix<f64, N, N>) -> Option<SMatrix<f64, N, N>> {
    if (info - info.transpose()).abs().max() > 1e-9 * info.abs().max() {
        return None;
    }
    nalgebra::Cholesky::new(*info).map(|c| c.l().transpose())
}

/// An upper-triangular 6 × 6 matrix U stored by its 21 entries row by row (U_ij, j ≥ i): the
/// square-root information of an SE(3) factor in 168 bytes instead of 288, which a 1 M-edge
/// graph feels (120 MB), and products that skip the zeros.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Upper6([f64; 21]);

impl Upper6 {
    /// The upper triangle of `u` (its strictly lower part is ignored).
    fn new(u: &Matrix6<f64>) -> Self {
        let mut packed = [0.0; 21];
        let mut k = 0;
        for i in 0..6 {
            for j in i..6 {
                packed[k] = u[(i, j)];
                k += 1;
            }
        }
        Self(packed)
    }

    /// Row i's entries U_ij, j = i..6.
    fn row(&self, i: usize) -> &[f64] {
        const START: [usize; 6] = [0, 6, 11, 15, 18, 20];
        &self.0[START[i]..START[i] + 6 - i]
    }

    /// U e.
    fn mul_vector(&self, e: &Vector6<f64>) -> Vector6<f64> {
        Vector6::from_fn(|i, _| {
            (self.row(i).iter().enumerate())
                .map(|(k, u)| u * e[i + k])
                .sum()
        })
    }

    /// U M.
    fn mul_matrix(&self, m: &Matrix6<f64>) -> Matrix6<f64> {
        Matrix6::from_fn(|i, c| {
            (self.row(i).iter().enumerate())
                .map(|(k, u)| u * m[(i + k, c)])
                .sum()
        })
    }
}

fn write_block<const N: usize>(jac: &mut Jacobians<'_>, k: usize, m: &SMatrix<f64, N, N>) {
    jac.block(k).copy_from_slice(m.as_slice());
}

fn whiten<const N: usize>(u: &SMatrix<f64, N, N>, e: &SVector<f64, N>, out: &mut [f64]) {
    out[..N].copy_from_slice((u * e).as_slice());
}

/// SE(2) between factor: `r = U Log(Z⁻¹ X_i⁻¹ X_j)`, variables X_i, X_j on [`dynamap_solver::SE2`].
#[derive(Clone, Debug)]
pub struct Between2 {
    z_inv: Isometry2<f64>,
    sqrt_info: Matrix3<f64>,
}

impl Between2 {
    /// A factor with measurement `z` and square-root information `sqrt_info` (UᵀU = Ω).
    pub fn new(z: Isometry2<f64>, sqrt_info: Matrix3<f64>) -> Self {
        Self {
            z_inv: z.inverse(),
            sqrt_info,
        }
    }
}

impl Residual for Between2 {
    fn dim(&self) -> usize {
        3
    }
    fn arity(&self) -> Option<usize> {
        Some(2)
    }
    fn variable_size(&self, _k: usize) -> Option<(usize, usize)> {
        Some(SE2::SIZE)
    }
    fn evaluate(
        &self,
        vars: &[Var<'_>],
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) {
        let xi = se2::from_coordinates(vars[0].value);
        let xj = se2::from_coordinates(vars[1].value);
        let xij = xi.inverse() * xj;
        let e = se2::log(&(self.z_inv * xij));
        whiten(&self.sqrt_info, &e, residual);
        if let Some(jac) = jacobians {
            let jj = self.sqrt_info * se2::right_jacobian_inv(&e);
            let ji = -jj * se2::adjoint(&xij.inverse());
            write_block(jac, 0, &ji);
            write_block(jac, 1, &jj);
        }
    }
}

/// SE(3) between factor: `r = U Log(Z⁻¹ X_i⁻¹ X_j)`, variables on [`dynamap_solver::SE3`].
#[derive(Clone, Debug)]
pub struct Between3 {
    z_inv: Isometry3<f64>,
    sqrt_info: Upper6,
}

impl Between3 {
    /// A factor with measurement `z` and square-root information `sqrt_info` (UᵀU = Ω, `[ω; v]`
    /// order; upper triangular, its strictly lower part is not read).
    pub fn new(z: Isometry3<f64>, sqrt_info: Matrix6<f64>) -> Self {
        Self {
            z_inv: z.inverse(),
            sqrt_info: Upper6::new(&sqrt_info),
        }
    }
}

impl Residual for Between3 {
    fn dim(&self) -> usize {
        6
    }
    fn arity(&self) -> Option<usize> {
        Some(2)
    }
    fn variable_size(&self, _k: usize) -> Option<(usize, usize)> {
        Some(SE3::SIZE)
    }
    fn evaluate(
        &self,
        vars: &[Var<'_>],
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) {
        let xi = se3::from_slice(vars[0].value);
        let xj = se3::from_slice(vars[1].value);
        let xij = xi.inverse() * xj;
        let e = se3::log(&(self.z_inv * xij));
        residual[..6].copy_from_slice(self.sqrt_info.mul_vector(&e).as_slice());
        if let Some(jac) = jacobians {
            let jj = self.sqrt_info.mul_matrix(&se3::right_jacobian_inv(&e));
            let ji = -jj * se3::adjoint(&xij.inverse());
            write_block(jac, 0, &ji);
            write_block(jac, 1, &jj);
        }
    }
}

/// SE(2) prior: `r = U Log(Z⁻¹ X)`.
#[derive(Clone, Debug)]
pub struct Prior2 {
    z_inv: Isometry2<f64>,
    sqrt_info: Matrix3<f64>,
}

impl Prior2 {
    /// A prior at `z` with square-root information `sqrt_info`.
    pub fn new(z: Isometry2<f64>, sqrt_info: Matrix3<f64>) -> Self {
        Self {
            z_inv: z.inverse(),
            sqrt_info,
        }
    }
}

impl Residual for Prior2 {
    fn dim(&self) -> usize {
        3
    }
    fn arity(&self) -> Option<usize> {
        Some(1)
    }
    fn variable_size(&self, _k: usize) -> Option<(usize, usize)> {
        Some(SE2::SIZE)
    }
    fn evaluate(
        &self,
        vars: &[Var<'_>],
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) {
        let e = se2::log(&(self.z_inv * se2::from_coordinates(vars[0].value)));
        whiten(&self.sqrt_info, &e, residual);
        if let Some(jac) = jacobians {
            write_block(jac, 0, &(self.sqrt_info * se2::right_jacobian_inv(&e)));
        }
    }
}

/// SE(3) prior: `r = U Log(Z⁻¹ X)`.
#[derive(Clone, Debug)]
pub struct Prior3 {
    z_inv: Isometry3<f64>,
    sqrt_info: Upper6,
}

impl Prior3 {
    /// A prior at `z` with square-root information `sqrt_info` (`[ω; v]` order; upper
    /// triangular, its strictly lower part is not read).
    pub fn new(z: Isometry3<f64>, sqrt_info: Matrix6<f64>) -> Self {
        Self {
            z_inv: z.inverse(),
            sqrt_info: Upper6::new(&sqrt_info),
        }
    }
}

impl Residual for Prior3 {
    fn dim(&self) -> usize {
        6
    }
    fn arity(&self) -> Option<usize> {
        Some(1)
    }
    fn variable_size(&self, _k: usize) -> Option<(usize, usize)> {
        Some(SE3::SIZE)
    }
    fn evaluate(
        &self,
        vars: &[Var<'_>],
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) {
        let e = se3::log(&(self.z_inv * se3::from_slice(vars[0].value)));
        residual[..6].copy_from_slice(self.sqrt_info.mul_vector(&e).as_slice());
        if let Some(jac) = jacobians {
            write_block(
                jac,
                0,
                &self.sqrt_info.mul_matrix(&se3::right_jacobian_inv(&e)),
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynamap_solver::{check_jacobians, Manifold, SE2, SE3};
    use nalgebra::Vector3;
    use proptest::prelude::*;

    fn pose3(a: &[f64]) -> Isometry3<f64> {
        se3::exp(&Vector6::new(
            a[0] * 2.0,
            a[1] * 2.0,
            a[2] * 2.0,
            a[3] * 5.0,
            a[4] * 5.0,
            a[5] * 5.0,
        ))
    }
    fn pose2(a: &[f64]) -> Isometry2<f64> {
        se2::exp(&Vector3::new(a[0] * 5.0, a[1] * 5.0, a[2] * 3.0))
    }
    fn spd<const N: usize>(a: &[f64]) -> SMatrix<f64, N, N> {
        let m = SMatrix::<f64, N, N>::from_fn(|i, j| a[(i * N + j) % a.len()]);
        m * m.transpose() + SMatrix::<f64, N, N>::identity() * 0.5
    }
    fn slice3(t: &Isometry3<f64>) -> [f64; 7] {
        let mut s = [0.0; 7];
        se3::to_slice(t, &mut s);
        s
    }
    fn slice2(t: &Isometry2<f64>) -> [f64; 3] {
        let c = se2::coordinates(t);
        [c.x, c.y, c.z]
    }

    proptest! {
        #[test]
        fn se3_factor_jacobians_match_central_differences(a in prop::collection::vec(-1.0f64..1.0, 24)) {
            let (xi, xj, z) = (pose3(&a[0..6]), pose3(&a[6..12]), pose3(&a[12..18]));
            let u = sqrt_information(&spd::<6>(&a[18..24])).unwrap();
            let (si, sj) = (slice3(&xi), slice3(&xj));
            let vars = [Var { value: &si, manifold: &SE3 as &dyn Manifold }, Var { value: &sj, manifold: &SE3 }];
            // Log is discontinuous where the error rotation reaches π, and central differences lose
            // their accuracy just before it (a case at 179.993° missed 1e-6 by 2×).
            prop_assume!((z.inverse() * xi.inverse() * xj).rotation.angle() < 3.0);
            let between = check_jacobians(&Between3::new(z, u), &vars);
            prop_assert!(between.passes(1e-6), "{between:?}");
            prop_assume!((z.inverse() * xi).rotation.angle() < 3.0);
            let prior = check_jacobians(&Prior3::new(z, u), &vars[..1]);
            prop_assert!(prior.passes(1e-6), "{prior:?}");
        }

        #[test]
        fn se2_factor_jacobians_match_central_differences(a in prop::collection::vec(-1.0f64..1.0, 18)) {
            let (xi, xj, z) = (pose2(&a[0..3]), pose2(&a[3..6]), pose2(&a[6..9]));
            let u = sqrt_information(&spd::<3>(&a[9..18])).unwrap();
            let (si, sj) = (slice2(&xi), slice2(&xj));
            let vars = [Var { value: &si, manifold: &SE2 as &dyn Manifold }, Var { value: &sj, manifold: &SE2 }];
            // Log is discontinuous where the relative rotation crosses ±π.
            let e = se2::log(&(z.inverse() * xi.inverse() * xj));
            prop_assume!(e.z.abs() < 3.0);
            let between = check_jacobians(&Between2::new(z, u), &vars);
            prop_assert!(between.passes(1e-6), "{between:?}");
            let ep = se2::log(&(z.inverse() * xi));
            prop_assume!(ep.z.abs() < 3.0);
            let prior = check_jacobians(&Prior2::new(z, u), &vars[..1]);
            prop_assert!(prior.passes(1e-6), "{prior:?}");
        }
    }

    #[test]
    fn the_packed_square_root_information_multiplies_as_the_dense_triangle() {
        let a: Vec<f64> = (0..36).map(|k| (k as f64 * 0.77).sin()).collect();
        let u = sqrt_information(&spd::<6>(&a)).unwrap();
        let packed = Upper6::new(&u);
        let e = Vector6::from_fn(|i, _| (i as f64 * 1.3).cos());
        let m = Matrix6::from_fn(|i, j| ((i * 6 + j) as f64 * 0.41).sin());
        assert!((packed.mul_vector(&e) - u * e).amax() < 1e-14);
        assert!((packed.mul_matrix(&m) - u * m).amax() < 1e-14);
        // a full matrix: only its upper triangle is kept
        let full = Matrix6::from_fn(|i, j| 1.0 + (i + 2 * j) as f64);
        assert_eq!(Upper6::new(&full).mul_vector(&e), full.upper_triangle() * e);
    }

    #[test]
    fn zero_error_at_the_measurement() {
        let xi = pose3(&[0.1, 0.2, -0.3, 0.4, 0.5, 0.6]);
        let z = pose3(&[0.3, -0.1, 0.2, -0.4, 0.1, 0.2]);
        let xj = xi * z;
        let (si, sj) = (slice3(&xi), slice3(&xj));
        let vars = [
            Var {
                value: &si,
                manifold: &SE3 as &dyn Manifold,
            },
            Var {
                value: &sj,
                manifold: &SE3,
            },
        ];
        let mut r = [1.0; 6];
        Between3::new(z, Matrix6::identity()).evaluate(&vars, &mut r, None);
        assert!(r.iter().all(|v| v.abs() < 1e-12), "{r:?}");
    }

    #[test]
    fn non_spd_information_is_refused() {
        assert!(
            sqrt_information(&Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0)).is_none()
        );
        assert!(
            sqrt_information(&Matrix3::new(1.0, 2.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)).is_none()
        );
    }
}
