//! The minimiser's settings: the method, its stopping tests, the linear solver and what the Schur
//! solvers eliminate.

use crate::error::SolveError;
use crate::problem::VarId;

/// The minimisation method.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Algorithm {
    /// Plain Gauss-Newton: δ = −H⁻¹g, every step taken.
    GaussNewton,
    /// Levenberg-Marquardt with Nielsen's damping update.
    LevenbergMarquardt,
    /// Powell's dogleg trust region.
    Dogleg,
}

/// How LM's damping term is scaled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DampingKind {
    /// μI.
    Identity,
    /// μ diag(H) (Marquardt), Ceres' damping: each diagonal element clamped to
    /// [1e-6 c, 1e32 c], c = (1 + √v₀)² from its value v₀ at the start of the solve, and
    /// μ ≥ 1e-16 (Ceres' Jacobi scaling, `min_lm_diagonal` and largest trust radius).
    Diagonal,
}

/// Which variables the Schur-complement solvers eliminate.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum Elimination {
    /// A maximal set of independent variables (no residual ties two of them), chosen greedily by
    /// fewest neighbours, then smallest tangent dimension: the points of bundle adjustment.
    #[default]
    Auto,
    /// These variables (they must be independent; fixed ones are skipped).
    Variables(Vec<VarId>),
}

/// Solver settings. The defaults suit most problems; [`Options::default`] documents each.
#[derive(Clone, Debug)]
pub struct Options {
    /// Minimisation method (default Levenberg-Marquardt).
    pub algorithm: Algorithm,
    /// Largest number of iterations (default 100).
    pub max_iterations: usize,
    /// Wall-clock limit in seconds (default: none).
    pub max_seconds: f64,
    /// Stop when max |gᵢ| ≤ this (default 1e-10).
    pub gradient_tolerance: f64,
    /// Stop when ‖δ‖ ≤ tol (‖x‖ + tol) (default 1e-10).
    pub step_tolerance: f64,
    /// Stop when an accepted step lowers the cost by less than this fraction (default 1e-10).
    pub function_tolerance: f64,
    /// LM: τ in the initial damping, μ₀ = τ max diag(H) for μI damping and μ₀ = τ for
    /// μ diag(H) damping (Ceres' 1 / initial trust-region radius) (default 1e-4).
    pub initial_damping_tau: f64,
    /// LM: damping μI or μ diag(H) (default μI).
    pub damping: DampingKind,
    /// Dogleg: initial trust-region radius (default 1e4).
    pub initial_trust_radius: f64,
    /// Linear solver (default: dense below `dense_threshold` unknowns, sparse above).
    pub linear_solver: LinearSolverKind,
    /// Unknowns up to which [`LinearSolverKind::Auto`] chooses the dense solver (default 200).
    pub dense_threshold: usize,
    /// Check components that touch no fixed variable for a null space before solving (default true).
    pub check_rank: bool,
    /// Variables the Schur solvers eliminate (default [`Elimination::Auto`]).
    pub elimination: Elimination,
    /// Iterative Schur: stop conjugate gradients at ‖S y − b‖ ≤ tol ‖b‖ (default 1e-6).
    pub pcg_tolerance: f64,
    /// Iterative Schur: most conjugate-gradient iterations per step (default 500).
    pub pcg_max_iterations: usize,
    /// Iterative Schur: the truncated-Newton forcing η. Conjugate gradients also stop once the
    /// quadratic `Q(y) = ½ yᵀS y − bᵀy` they minimise stalls, `i (Q_i − Q_{i−1}) / Q_i < η` at
    /// iteration i (Nash and Sofer, *Assessing a search direction within a truncated-Newton
    /// method*, Oper. Res. Lett. 9, 1990), as Ceres' ITERATIVE_SCHUR does with its `eta`. The
    /// trust-region step takes the inexact solution's own model decrease. 0 solves to
    /// `pcg_tolerance` alone (default 0.1).
    pub pcg_forcing: f64,
}

impl Options {
    /// Refuses options no solve can run with: a NaN or negative tolerance or time limit, a
    /// damping or trust radius that is not positive (as Ceres' `Solver::Options::IsValid`). An
    /// infinite time limit is none; a tolerance of 0 never stops a solve by itself.
    pub fn check(&self) -> Result<(), SolveError> {
        let at_least_zero = [
            ("max_seconds", self.max_seconds),
            ("gradient_tolerance", self.gradient_tolerance),
            ("step_tolerance", self.step_tolerance),
            ("function_tolerance", self.function_tolerance),
            ("pcg_tolerance", self.pcg_tolerance),
            ("pcg_forcing", self.pcg_forcing),
        ];
        for (name, value) in at_least_zero {
            if value.is_nan() || value < 0.0 {
                let must = "must be 0 or more";
                return Err(SolveError::InvalidOption { name, value, must });
            }
        }
        let positive = [
            ("initial_damping_tau", self.initial_damping_tau),
            ("initial_trust_radius", self.initial_trust_radius),
        ];
        for (name, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                let must = "must be a positive number";
                return Err(SolveError::InvalidOption { name, value, must });
            }
        }
        Ok(())
    }
}

impl Default for Options {
    fn default() -> Self {
        Self {
            algorithm: Algorithm::LevenbergMarquardt,
            max_iterations: 100,
            max_seconds: f64::INFINITY,
            gradient_tolerance: 1e-10,
            step_tolerance: 1e-10,
            function_tolerance: 1e-10,
            initial_damping_tau: 1e-4,
            damping: DampingKind::Identity,
            initial_trust_radius: 1e4,
            linear_solver: LinearSolverKind::Auto,
            dense_threshold: 200,
            check_rank: true,
            elimination: Elimination::Auto,
            pcg_tolerance: 1e-6,
            pcg_max_iterations: 500,
            pcg_forcing: 0.1,
        }
    }
}

/// Which linear solver to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinearSolverKind {
    /// Dense below [`crate::Options::dense_threshold`] unknowns, sparse above.
    Auto,
    /// Dense Cholesky of the full matrix.
    Dense,
    /// Sparse Cholesky with AMD ordering.
    Sparse,
    /// Schur complement: eliminate independent variables (see [`crate::Elimination`]), solve the
    /// reduced system by dense Cholesky below [`crate::Options::dense_threshold`] unknowns and
    /// sparse Cholesky above, or by conjugate gradients ([`Self::SchurIterative`]) when the
    /// sparse factorisation would cost more than 100 operations per scalar of the eliminated
    /// blocks' coupling H_ce (large bundle adjustments; NOTES 74).
    Schur,
    /// Schur complement with a dense Cholesky of the reduced system.
    SchurDense,
    /// Schur complement with a sparse Cholesky of the reduced system.
    SchurSparse,
    /// Schur complement solved by preconditioned conjugate gradients with implicit products and a
    /// block-Jacobi preconditioner (the reduced system is never formed).
    SchurIterative,
}

impl LinearSolverKind {
    /// True for the Schur-complement solvers.
    pub fn is_schur(self) -> bool {
        matches!(
            self,
            Self::Schur | Self::SchurDense | Self::SchurSparse | Self::SchurIterative
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn options_no_solve_can_run_with_are_named() {
        assert_eq!(Options::default().check(), Ok(()));
        let unlimited = Options {
            max_seconds: f64::INFINITY,
            function_tolerance: 0.0,
            ..Options::default()
        };
        assert_eq!(unlimited.check(), Ok(()));
        let cases = [
            (
                "function_tolerance",
                Options {
                    function_tolerance: f64::NAN,
                    ..Options::default()
                },
            ),
            (
                "step_tolerance",
                Options {
                    step_tolerance: -1e-9,
                    ..Options::default()
                },
            ),
            (
                "initial_damping_tau",
                Options {
                    initial_damping_tau: 0.0,
                    ..Options::default()
                },
            ),
            (
                "initial_trust_radius",
                Options {
                    initial_trust_radius: f64::INFINITY,
                    ..Options::default()
                },
            ),
        ];
        for (field, options) in cases {
            match options.check() {
                Err(SolveError::InvalidOption { name, .. }) => assert_eq!(name, field),
                other => panic!("{field}: {other:?}"),
            }
        }
    }
}
