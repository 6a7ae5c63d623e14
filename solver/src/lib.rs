//! # dynamap-solver
//!
//! Sparse non-linear least squares on manifolds:
//!
//! ```text
//! min_x  ½ Σ_i ρ_i(‖r_i(x_i1, …, x_ik)‖²)      x_j on manifolds, x_j ⊞ δ = x_j Exp(δ)
//! ```
//!
//! - [`Problem`]: variables ([`Manifold`]s: [`Euclidean`], [`EuclideanDyn`], [`SO2`], [`SE2`], [`SO3`],
//!   [`SE3`], [`UnitQuaternionManifold`], or your own) and [`Residual`] blocks with optional
//!   [`RobustKernel`]s. Variables can be held fixed.
//! - Jacobians three ways: hand-written, [`AutoDiff`] (const-generic dual numbers, [`Jet`]), or
//!   [`NumericDiff`] (central differences, an explicit choice). [`check_jacobians`] compares any
//!   residual with central differences.
//! - [`Solver`]: Gauss-Newton, Levenberg-Marquardt and Powell's dogleg over normal equations
//!   assembled in block form in parallel, solved by dense Cholesky or faer's sparse Cholesky with a
//!   symbolic factorisation reused across iterations and solves.
//! - [`Elimination`] and the Schur-complement [`LinearSolverKind`]s: eliminate many small
//!   independent variables (the points of bundle adjustment) and solve the reduced system by dense
//!   or sparse Cholesky, or by conjugate gradients with implicit products.
//! - [`Problem::set_bounds`]: box constraints on Euclidean variables, honoured at every iterate.
//! - [`covariance()`]: marginal covariances, blocks of H⁻¹ at the solution.
//! - [`linearize()`]: the kernel-corrected H and g the solver steps from, written out densely.
//! - [`BlockSystem`]: block-sparse normal equations the caller assembles itself (terms that share
//!   work the residual interface cannot see), solved by the sparse path's Cholesky.
//! - [`dense`]: the dense path for one variable with many scalar terms (trackers), reduced
//!   straight into 6×6 normal equations.
//! - [`lie`]: SO(2), SE(2), SO(3), SE(3) exponentials, logarithms, adjoints and Jacobians.
//!
//! ## The model
//!
//! A [`Problem`] holds *variables*, each a point `x_j` of a [`Manifold`] stored in ambient
//! coordinates (a unit quaternion stores 4 numbers, has 3 degrees of freedom), and *residual
//! blocks*, each a function `r_i` of a few variables with an optional robust kernel `ρ_i`. The
//! solver linearises every block in the tangent spaces, `r_i(x ⊞ δ) ≈ r_i + J_i δ`, and solves the
//! (damped) normal equations `(JᵀJ + μD) δ = −Jᵀr` block-sparse: each variable is one block row and
//! column of `H = JᵀJ`, and each residual block adds to the blocks of the variables it touches.
//! Robust kernels enter by Triggs' correction where ρ'' > 0 and as weights ρ' where ρ'' ≤ 0 (as
//! Ceres' `Corrector`), so `H` stays positive semi-definite and `g` is the gradient of ½Σρ.
//! Gauss-Newton takes the step; Levenberg-Marquardt and dogleg accept it only when the cost
//! falls as the model predicts.
//!
//! ## A first solve
//!
//! Three noisy measurements of a point in the plane, one of them an outlier tamed by a Cauchy
//! kernel:
//!
//! ```
//! use dynamap_solver::{robust::Cauchy, AutoDiff, CostFunctor, Euclidean, Options, Problem, Real, Solver};
//!
//! /// r = x − z for a measurement z of the point x.
//! struct Measured([f64; 2]);
//! impl CostFunctor for Measured {
//!     fn parameter_sizes(&self) -> &[usize] {
//!         &[2]
//!     }
//!     fn evaluate<T: Real>(&self, p: &[&[T]], r: &mut [T]) {
//!         r[0] = p[0][0] - self.0[0];
//!         r[1] = p[0][1] - self.0[1];
//!     }
//! }
//!
//! let mut problem = Problem::new();
//! let x = problem.add_variable(&[0.0, 0.0], Euclidean::<2>).unwrap();
//! for z in [[1.0, 2.0], [1.02, 1.98], [9.0, -4.0]] {
//!     let r = AutoDiff::<_, 2, 2>::new(Measured(z));
//!     problem.add_robust_residual(r, Cauchy(0.1), &[x]).unwrap();
//! }
//! let summary = Solver::new(Options::default()).solve(&mut problem).unwrap();
//! assert!(summary.termination.converged());
//! let v = problem.value(x);
//! assert!((v[0] - 1.01).abs() < 0.02 && (v[1] - 1.99).abs() < 0.02, "{v:?}");
//! ```
//!
//! The [`guide`] walks through a custom residual, a custom manifold, a property test of the
//! Jacobians and the [`Summary`].
//!
//! ## Where things are (for contributors)
//!
//! The modules form layers; each uses only those before it (`tests/integration/structure.rs`
//! checks that no module imports one that imports it):
//!
//! 1. `error`, `parallel` (a pointer for disjoint writes, the one dot product), `damping`
//!    ([`Damping`], [`LevenbergDamping`]), `summary` ([`Summary`]);
//! 2. [`lie`], `manifold`, `residual`, `real`, `jet`, `autodiff`, `numeric`, [`robust`],
//!    `problem`, `options` ([`Options`] and its enums);
//! 3. `block` (the block-sparse matrix), `normal` (H and g assembled from the residuals),
//!    `cholesky` (dense and sparse, with the block AMD ordering);
//! 4. `schur/` (`ordering`, `layout`, `assembly`, `pcg`, `kernels`), then `linear`, which only
//!    dispatches between Cholesky and Schur;
//! 5. `diagnose` (rank and null space), `bounds` (the box-constrained step);
//! 6. `minimizer/`: `method` says what differs between Gauss-Newton (`gauss_newton`),
//!    Levenberg-Marquardt (`levenberg_marquardt`) and the dogleg (`dogleg`); `mod` is the loop
//!    they share; then `covariance`, `linearize`, `system`, [`dense`].

#![warn(missing_docs)]

mod autodiff;
mod block;
mod block_rows;
mod bounds;
mod cholesky;
mod coupling;
mod covariance;
mod damping;
pub mod dense;
mod diagnose;
mod elimination;
mod error;
mod jet;
pub mod lie;
mod linear;
mod linearize;
mod manifold;
mod minimizer;
mod normal;
mod numeric;
mod options;
mod ordering;
mod parallel;
mod problem;
#[cfg(test)]
mod properties;
mod real;
mod residual;
pub mod robust;
mod schur;
mod summary;
mod system;

pub use autodiff::{AutoDiff, CostFunctor};
pub use cholesky::FactorPrecision;
pub use covariance::covariance;
pub use damping::{Damping, LevenbergDamping};
pub use error::{ProblemError, SolveError};
pub use jet::Jet;
pub use linearize::{linearize, Linearization};
pub use manifold::{Euclidean, EuclideanDyn, Manifold, UnitQuaternionManifold, SE2, SE3, SO2, SO3};
pub use minimizer::Solver;
pub use numeric::{check_jacobians, JacobianCheck, NumericDiff, DEFAULT_STEP};
pub use options::{Algorithm, DampingKind, Elimination, LinearSolverKind, Options};
pub use problem::{Problem, ResidualId, VarId};
pub use real::Real;
pub use residual::{check_sizes, Jacobians, Residual, SizeMismatch, Var};
pub use robust::RobustKernel;
pub use summary::{IterationSummary, Observer, Summary, Termination, Timing};
pub use system::{BlockSystem, CgStart, Refined};

#[doc = include_str!("../../docs/solver_guide.md")]
pub mod guide {
    // in scope for the guide's links
    #[allow(unused_imports)]
    use crate::*;
}
