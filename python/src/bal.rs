//! Bundle adjustment in BAL's form: read, inspect and build from numpy arrays, solve as the
//! `bundle_adjustment` tool does, write back.

use crate::arrays::{self, Matrix};
use crate::errors;
use crate::kernels;
use crate::options::{Options, Summary};
use dynamap_residuals::bal::{self, file, BalProblem as Core, Observation};
use dynamap_solver::{LinearSolverKind, Solver};
use numpy::{PyArray1, PyArray2, PyArrayLike1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use std::path::PathBuf;

/// A bundle-adjustment problem: cameras `[ω, t, f, k₁, k₂]` (n × 9), points (m × 3) and pixel
/// observations (Agarwal et al., *Bundle Adjustment in the Large*, ECCV 2010).
#[pyclass(module = "dynamap")]
pub struct BalProblem {
    core: Core,
}

/// Rows of `K` numbers from an `n × K` array (`what` names it).
fn rows_of<const K: usize>(a: &Matrix<'_>, what: &str) -> PyResult<Vec<[f64; K]>> {
    let v = a.as_array();
    if v.ncols() != K {
        return Err(PyValueError::new_err(format!(
            "{what}: expected n x {K}, got shape {:?}",
            v.shape()
        )));
    }
    Ok(v.rows()
        .into_iter()
        .map(|r| std::array::from_fn(|k| r[k]))
        .collect())
}

/// The observations from parallel arrays, each index checked against its range.
fn observations(
    core: &Core,
    camera_index: &[i64],
    point_index: &[i64],
    uv: Vec<[f64; 2]>,
) -> PyResult<Vec<Observation>> {
    if camera_index.len() != uv.len() || point_index.len() != uv.len() {
        return Err(PyValueError::new_err(format!(
            "observations: {} camera indices, {} point indices and {} pixels differ in number",
            camera_index.len(),
            point_index.len(),
            uv.len()
        )));
    }
    let check = |k: usize, i: i64, n: usize, what: &str| match usize::try_from(i) {
        Ok(i) if i < n => Ok(i),
        _ => Err(PyValueError::new_err(format!(
            "observation {k}: {what} index {i} is outside 0..{n}"
        ))),
    };
    (0..uv.len())
        .map(|k| {
            Ok(Observation {
                camera: check(k, camera_index[k], core.cameras.len(), "camera")?,
                point: check(k, point_index[k], core.points.len(), "point")?,
                uv: uv[k],
            })
        })
        .collect()
}

/// The Schur solver named as `bundle_adjustment --linear-solver` names it.
fn linear_of(name: &str) -> PyResult<LinearSolverKind> {
    Ok(match name {
        "auto" => LinearSolverKind::Schur,
        "schur_dense" => LinearSolverKind::SchurDense,
        "schur_sparse" => LinearSolverKind::SchurSparse,
        "schur_iterative" => LinearSolverKind::SchurIterative,
        "cholesky" => LinearSolverKind::Sparse,
        other => {
            return Err(PyValueError::new_err(format!(
                "linear_solver='{other}': expected auto, schur_dense, schur_sparse, \
                 schur_iterative or cholesky"
            )))
        }
    })
}

#[pymethods]
impl BalProblem {
    /// A problem from arrays: `cameras` n × 9, `points` m × 3, and per observation its camera
    /// index, point index and pixel `uv` (k × 2, from the image centre).
    #[new]
    fn py_new(
        cameras: Matrix<'_>,
        points: Matrix<'_>,
        camera_index: PyArrayLike1<'_, i64>,
        point_index: PyArrayLike1<'_, i64>,
        uv: Matrix<'_>,
    ) -> PyResult<Self> {
        let mut core = Core {
            cameras: rows_of::<9>(&cameras, "cameras")?,
            points: rows_of::<3>(&points, "points")?,
            observations: Vec::new(),
        };
        if let Some(i) = core
            .cameras
            .iter()
            .flatten()
            .chain(core.points.iter().flatten())
            .position(|x| !x.is_finite())
        {
            return Err(PyValueError::new_err(format!(
                "parameter {i} (cameras, then points, row by row) is not finite"
            )));
        }
        let ci: Vec<i64> = camera_index.as_array().iter().copied().collect();
        let pi: Vec<i64> = point_index.as_array().iter().copied().collect();
        core.observations = observations(&core, &ci, &pi, rows_of::<2>(&uv, "uv")?)?;
        Ok(Self { core })
    }

    /// Reads a BAL file; raises `InputError` naming the file and line of a fault.
    #[staticmethod]
    fn read(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let core = py.detach(|| file::read(&path)).map_err(errors::input)?;
        Ok(Self { core })
    }

    /// Writes the problem as a BAL file (through a temporary file renamed into place).
    fn write(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        py.detach(|| file::write(&path, &self.core))
            .map_err(errors::input)
    }

    /// The cameras, n × 9 (a new array).
    #[getter]
    fn cameras<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        arrays::rows(py, self.core.cameras.iter().flatten().copied().collect(), 9)
    }

    /// The points, m × 3 (a new array).
    #[getter]
    fn points<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        arrays::rows(py, self.core.points.iter().flatten().copied().collect(), 3)
    }

    /// The observations as (camera_index, point_index, uv).
    #[allow(clippy::type_complexity)]
    #[getter]
    fn observations<'py>(
        &self,
        py: Python<'py>,
    ) -> (
        Bound<'py, PyArray1<i64>>,
        Bound<'py, PyArray1<i64>>,
        Bound<'py, PyArray2<f64>>,
    ) {
        let o = &self.core.observations;
        let ci: Vec<i64> = o.iter().map(|o| o.camera as i64).collect();
        let pi: Vec<i64> = o.iter().map(|o| o.point as i64).collect();
        let uv = arrays::rows(py, o.iter().flat_map(|o| o.uv).collect(), 2);
        (PyArray1::from_vec(py, ci), PyArray1::from_vec(py, pi), uv)
    }

    /// ½ Σ ‖r‖² in pixels, as BAL's reference values and Ceres report it.
    fn cost(&self) -> f64 {
        self.core.cost()
    }

    /// Bundle adjustment as `bundle_adjustment` runs it (Levenberg-Marquardt with Ceres'
    /// damping, the points eliminated by the Schur complement), updating the cameras and points
    /// in place; returns the `Summary`. `kernel` ("huber:2") is put on every observation;
    /// `linear_solver` is auto, schur_dense, schur_sparse, schur_iterative or cholesky;
    /// `options` replaces the tool's settings whole. With `retriangulate`, a solve that converges
    /// before `max_iterations` re-triangulates the points and resumes while that lowers the cost
    /// (the tool's default; `--no-retriangulate` there is `retriangulate=False` here).
    #[pyo3(signature = (kernel = None, linear_solver = "auto", max_iterations = 50, options = None, retriangulate = true))]
    fn solve(
        &mut self,
        py: Python<'_>,
        kernel: Option<&Bound<'_, PyAny>>,
        linear_solver: &str,
        max_iterations: usize,
        options: Option<Options>,
        retriangulate: bool,
    ) -> PyResult<Summary> {
        let kernel = kernels::optional(kernel)?;
        let options = match options {
            Some(o) => o.core,
            None => bal::options(linear_of(linear_solver)?, max_iterations),
        };
        let mut solve = self.core.build(kernel).map_err(errors::problem)?;
        let mut solver = Solver::new(options);
        let core = &mut self.core;
        let run = py
            .detach(|| {
                if retriangulate {
                    bal::solve_with_restarts(&mut solver, core, &mut solve, kernel, |_| {})
                        .map(|(run, _)| run)
                } else {
                    solver
                        .solve(&mut solve.problem)
                        .map_err(bal::RestartError::Solve)
                }
            })
            .map_err(|e| match e {
                bal::RestartError::Solve(e) => errors::solve(e),
                bal::RestartError::Problem(e) => errors::problem(e),
            })?;
        self.core.update_from(&solve);
        Ok(Summary { run })
    }

    fn __repr__(&self) -> String {
        format!(
            "<dynamap.BalProblem {} cameras, {} points, {} observations>",
            self.core.cameras.len(),
            self.core.points.len(),
            self.core.observations.len()
        )
    }
}

/// Reads a BAL file and solves it as `bundle_adjustment` does: returns `(cameras, points,
/// summary)`.
#[pyfunction]
#[pyo3(signature = (path, kernel = None, linear_solver = "auto", max_iterations = 50))]
#[allow(clippy::type_complexity)]
pub fn solve_bal<'py>(
    py: Python<'py>,
    path: PathBuf,
    kernel: Option<&Bound<'py, PyAny>>,
    linear_solver: &str,
    max_iterations: usize,
) -> PyResult<(
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Summary,
)> {
    let mut p = BalProblem::read(py, path)?;
    let summary = p.solve(py, kernel, linear_solver, max_iterations, None, true)?;
    Ok((p.cameras(py), p.points(py), summary))
}
