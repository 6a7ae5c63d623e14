//! The library's own residuals, made from numpy arrays: pose-graph between and prior factors in
//! 2-D and 3-D, BAL's reprojection error and ICP's point-to-plane distance. Each is a `Residual`
//! object that `Problem.add_residual` takes in place of a Python callable.

use crate::arrays::{to_fixed, to_square, Matrix, Vector};
use dynamap_residuals::bal::SnavelyReprojection;
use dynamap_residuals::icp::PointToPlane;
use dynamap_residuals::pose_graph::{sqrt_information, Between2, Between3, Prior2, Prior3};
use dynamap_solver::lie::{se2, se3};
use dynamap_solver::{Jacobians, Manifold, Residual as Core, Var, SE2, SE3};
use nalgebra::{SMatrix, Vector3};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use std::sync::Arc;

/// A built-in residual block, ready for `Problem.add_residual`.
#[pyclass(module = "dynamap", frozen)]
pub struct Residual {
    pub(crate) inner: Arc<dyn Core>,
    what: String,
    arity: usize,
}

#[pymethods]
impl Residual {
    /// Number of residual rows.
    #[getter]
    fn dim(&self) -> usize {
        self.inner.dim()
    }
    /// Number of variables it takes.
    #[getter]
    fn arity(&self) -> usize {
        self.arity
    }
    fn __repr__(&self) -> String {
        format!(
            "<dynamap.Residual {} ({} rows)>",
            self.what,
            self.inner.dim()
        )
    }
}

impl Residual {
    fn new(inner: impl Core + 'static, what: &str, arity: usize) -> Self {
        Self {
            inner: Arc::new(inner),
            what: what.into(),
            arity,
        }
    }
}

/// A shared built-in residual as a block of a problem (one object may serve many blocks).
pub struct Shared(pub Arc<dyn Core>);

impl Core for Shared {
    fn dim(&self) -> usize {
        self.0.dim()
    }
    fn arity(&self) -> Option<usize> {
        self.0.arity()
    }
    fn variable_size(&self, k: usize) -> Option<(usize, usize)> {
        self.0.variable_size(k)
    }
    fn evaluate(&self, vars: &[Var<'_>], r: &mut [f64], j: Option<&mut Jacobians<'_>>) {
        self.0.evaluate(vars, r, j)
    }
}

/// U with UᵀU = Ω, or a clear error when Ω is not symmetric positive definite.
fn sqrt_info<const N: usize>(information: &Matrix<'_>) -> PyResult<SMatrix<f64, N, N>> {
    let omega = to_square::<N>(information, "information")?;
    sqrt_information(&omega).ok_or_else(|| {
        PyValueError::new_err("information: the matrix is not symmetric positive definite")
    })
}

/// SE(2) between factor `r = U Log(Z⁻¹ X_i⁻¹ X_j)` on two SE(2) variables, with UᵀU = Ω.
///
/// `measurement` is Z as `[x, y, θ]`; `information` is Ω, 3 × 3 in the tangent order
/// `[v_x, v_y, ω]` (g2o's EDGE_SE2 order).
#[pyfunction]
pub fn between_se2(measurement: Vector<'_>, information: Matrix<'_>) -> PyResult<Residual> {
    let z = se2::from_coordinates(&measurement_on::<3>(&SE2, &measurement)?);
    let u = sqrt_info::<3>(&information)?;
    Ok(Residual::new(Between2::new(z, u), "between_se2", 2))
}

/// SE(3) between factor `r = U Log(Z⁻¹ X_i⁻¹ X_j)` on two SE(3) variables, with UᵀU = Ω.
///
/// `measurement` is Z as `[tx, ty, tz, qx, qy, qz, qw]`; `information` is Ω, 6 × 6 in the
/// tangent order `[ω; v]` (GTSAM's Pose3 order; g2o files list translation first).
#[pyfunction]
pub fn between_se3(measurement: Vector<'_>, information: Matrix<'_>) -> PyResult<Residual> {
    let z = se3::from_slice(&measurement_on::<7>(&SE3, &measurement)?);
    let u = sqrt_info::<6>(&information)?;
    Ok(Residual::new(Between3::new(z, u), "between_se3", 2))
}

/// SE(2) prior `r = U Log(Z⁻¹ X)` on one SE(2) variable (measurement and Ω as in
/// `between_se2`).
#[pyfunction]
pub fn prior_se2(measurement: Vector<'_>, information: Matrix<'_>) -> PyResult<Residual> {
    let z = se2::from_coordinates(&measurement_on::<3>(&SE2, &measurement)?);
    let u = sqrt_info::<3>(&information)?;
    Ok(Residual::new(Prior2::new(z, u), "prior_se2", 1))
}

/// SE(3) prior `r = U Log(Z⁻¹ X)` on one SE(3) variable (measurement and Ω as in
/// `between_se3`).
#[pyfunction]
pub fn prior_se3(measurement: Vector<'_>, information: Matrix<'_>) -> PyResult<Residual> {
    let z = se3::from_slice(&measurement_on::<7>(&SE3, &measurement)?);
    let u = sqrt_info::<6>(&information)?;
    Ok(Residual::new(Prior3::new(z, u), "prior_se3", 1))
}

/// BAL's reprojection error of an observation at pixel `(u, v)` (from the image centre) on a
/// camera `[ω, t, f, k₁, k₂]` (R⁹) and a point (R³) (Agarwal et al., *Bundle Adjustment in the
/// Large*, ECCV 2010).
#[pyfunction]
pub fn bal_reprojection(u: f64, v: f64) -> PyResult<Residual> {
    if !(u.is_finite() && v.is_finite()) {
        return Err(PyValueError::new_err(format!(
            "bal_reprojection: the pixel ({u}, {v}) is not finite"
        )));
    }
    Ok(Residual::new(
        SnavelyReprojection::new(u, v),
        "bal_reprojection",
        2,
    ))
}

/// A measurement that is a point of `manifold` (finite, an SE(3) quaternion of non-zero norm,
/// normalised as the variables' values are), or ValueError naming it.
fn measurement_on<const N: usize>(manifold: &dyn Manifold, a: &Vector<'_>) -> PyResult<[f64; N]> {
    let v = to_fixed::<N>(a, "measurement")?;
    let valid = manifold
        .validate(&v)
        .map_err(|e| PyValueError::new_err(format!("measurement: {e}")))?;
    Ok(valid.as_slice().try_into().unwrap_or(v))
}

/// Point-to-plane distance `r = nᵀ(T p − q)` on one SE(3) variable T (camera to world): `source`
/// p in the camera frame, `target` q and its unit `normal` n in the world frame.
#[pyfunction]
pub fn point_to_plane(
    source: Vector<'_>,
    target: Vector<'_>,
    normal: Vector<'_>,
) -> PyResult<Residual> {
    let [p, q, n] = [("source", source), ("target", target), ("normal", normal)]
        .map(|(what, a)| to_fixed::<3>(&a, what).map(Vector3::from));
    let (p, q, n) = (p?, q?, n?);
    if !(p.iter().chain(q.iter()).all(|x| x.is_finite())) {
        return Err(PyValueError::new_err(
            "point_to_plane: the source and target points must be finite",
        ));
    }
    let norm = n.norm();
    if !norm.is_finite() || (norm - 1.0).abs() > 1e-6 {
        return Err(PyValueError::new_err(format!(
            "point_to_plane: the normal must have unit length, it has {norm}"
        )));
    }
    let r = PointToPlane {
        source: p,
        target: q,
        normal: n,
    };
    Ok(Residual::new(r, "point_to_plane", 1))
}
