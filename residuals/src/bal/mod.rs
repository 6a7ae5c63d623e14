//! Bundle adjustment in BAL's form: cameras `[ω, t, f, k₁, k₂]`, 3D points, and pixel
//! observations scored by the [`SnavelyReprojection`] error (Agarwal et al., *Bundle Adjustment in
//! the Large*, ECCV 2010).
//!
//! [`BalProblem::build`] turns a problem into a [`Problem`] with the cameras first and the points
//! after; solve it with one of the Schur-complement linear solvers
//! ([`dynamap_solver::LinearSolverKind::SchurDense`] and friends), which eliminate the points.

pub mod file;
pub mod retriangulate;
mod snavely;
pub mod synthetic;

pub use file::BalError;
pub use retriangulate::{
    retriangulate, solve_with_restarts, RestartError, Restarts, Retriangulation,
};
pub use snavely::{reprojection, rotate, SnavelyReprojection};

use dynamap_solver::robust::NamedKernel;
use dynamap_solver::{
    Algorithm, DampingKind, Euclidean, LinearSolverKind, Options, Problem, ProblemError, VarId,
};
use nalgebra::Vector3;

/// Solver settings for bundle adjustment as Ceres runs it: Levenberg-Marquardt with μ diag(H)
/// damping from μ₀ = 1e-4, tight tolerances, and no rank check (bundle adjustment's 7-dimensional
/// similarity gauge is left to the damping).
pub fn options(linear_solver: LinearSolverKind, max_iterations: usize) -> Options {
    Options {
        algorithm: Algorithm::LevenbergMarquardt,
        damping: DampingKind::Diagonal,
        max_iterations,
        linear_solver,
        function_tolerance: 1e-10,
        gradient_tolerance: 1e-12,
        step_tolerance: 1e-12,
        check_rank: false,
        ..Options::default()
    }
}

/// The centre C = −Rᵀt of a BAL camera `[ω, t, f, k₁, k₂]`, in world coordinates.
pub fn camera_centre(camera: &[f64; 9]) -> Vector3<f64> {
    let w = Vector3::new(-camera[0], -camera[1], -camera[2]);
    -rotate(&w, &Vector3::new(camera[3], camera[4], camera[5]))
}

/// One observation: camera `camera` sees point `point` at pixel `uv`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    /// Camera index.
    pub camera: usize,
    /// Point index.
    pub point: usize,
    /// The measured image point (u, v), pixels from the image centre.
    pub uv: [f64; 2],
}

/// A bundle-adjustment problem: its cameras, points and observations.
#[derive(Clone, Debug, PartialEq)]
pub struct BalProblem {
    /// `[ω (angle-axis), t, f, k₁, k₂]` per camera.
    pub cameras: Vec<[f64; 9]>,
    /// Point coordinates.
    pub points: Vec<[f64; 3]>,
    /// The observations.
    pub observations: Vec<Observation>,
}

/// A [`BalProblem`] as a solver [`Problem`], with the handles of its variables.
pub struct BalSolve {
    /// The problem: one residual block per observation, in the file's order.
    pub problem: Problem,
    /// Handle of each camera.
    pub cameras: Vec<VarId>,
    /// Handle of each point.
    pub points: Vec<VarId>,
}

impl BalProblem {
    /// The reprojection residual of observation `k` at the current parameters.
    pub fn residual(&self, k: usize) -> [f64; 2] {
        let o = &self.observations[k];
        reprojection(&self.cameras[o.camera], &self.points[o.point], o.uv, None)
    }

    /// ½ Σ ‖r_k‖² over the observations where `keep(k)` holds.
    pub fn cost_where(&self, keep: impl Fn(usize) -> bool) -> f64 {
        (0..self.observations.len())
            .filter(|&k| keep(k))
            .map(|k| {
                let r = self.residual(k);
                0.5 * (r[0] * r[0] + r[1] * r[1])
            })
            .sum()
    }

    /// ½ Σ ‖r_k‖², the cost BAL's reference values and Ceres report.
    pub fn cost(&self) -> f64 {
        self.cost_where(|_| true)
    }

    /// The cameras and the points that no observation names, by index. Nothing measures them,
    /// so a solve holds them where they are ([`Self::build`]); a variable that no residual
    /// touches would leave the normal equations singular.
    pub fn unobserved(&self) -> (Vec<usize>, Vec<usize>) {
        let mut seen = (
            vec![false; self.cameras.len()],
            vec![false; self.points.len()],
        );
        for o in &self.observations {
            seen.0[o.camera] = true;
            seen.1[o.point] = true;
        }
        let missing = |seen: Vec<bool>| (0..seen.len()).filter(|&k| !seen[k]).collect();
        (missing(seen.0), missing(seen.1))
    }

    /// A solver problem with the cameras added first, then the points, then one
    /// [`SnavelyReprojection`] per observation, under `kernel` if given (Ceres' `loss_function`).
    /// Cameras and points that no observation names ([`Self::unobserved`]) are held fixed.
    pub fn build(&self, kernel: Option<NamedKernel>) -> Result<BalSolve, ProblemError> {
        let mut problem = Problem::new();
        problem.reserve(
            self.cameras.len() + self.points.len(),
            self.observations.len(),
        );
        let cameras = self
            .cameras
            .iter()
            .map(|c| problem.add_variable(c, Euclidean::<9>))
            .collect::<Result<Vec<_>, _>>()?;
        let points = self
            .points
            .iter()
            .map(|p| problem.add_variable(p, Euclidean::<3>))
            .collect::<Result<Vec<_>, _>>()?;
        for o in &self.observations {
            let r = SnavelyReprojection::new(o.uv[0], o.uv[1]);
            let vars = [cameras[o.camera], points[o.point]];
            match kernel {
                Some(k) => problem.add_robust_residual(r, k, &vars)?,
                None => problem.add_residual(r, &vars)?,
            };
        }
        let (idle_cameras, idle_points) = self.unobserved();
        for c in idle_cameras {
            problem.set_fixed(cameras[c], true)?;
        }
        for p in idle_points {
            problem.set_fixed(points[p], true)?;
        }
        Ok(BalSolve {
            problem,
            cameras,
            points,
        })
    }

    /// Copies the solved values of `solve` back into the cameras and points.
    pub fn update_from(&mut self, solve: &BalSolve) {
        for (c, &v) in self.cameras.iter_mut().zip(&solve.cameras) {
            c.copy_from_slice(solve.problem.value(v));
        }
        for (p, &v) in self.points.iter_mut().zip(&solve.points) {
            p.copy_from_slice(solve.problem.value(v));
        }
    }
}
