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
//! - [`dense`]: the dense path for one variable with many scalar terms (trackers), reduced
//!   straight into 6×6 normal equations.
//! - [`lie`]: SO(2), SE(2), SO(3), SE(3) exponentials, logarithms, adjoints and Jacobians.
//!
//! See `Problem`'s example for a complete solve.

#![warn(missing_docs)]

mod autodiff;
mod block;
mod bounds;
mod covariance;
pub mod dense;
mod diagnose;
mod error;
mod jet;
pub mod lie;
mod linear;
mod manifold;
mod minimizer;
mod normal;
mod numeric;
mod problem;
mod real;
mod residual;
pub mod robust;
mod schur;

pub use autodiff::{AutoDiff, CostFunctor};
pub use covariance::covariance;
pub use error::{ProblemError, SolveError};
pub use jet::Jet;
pub use linear::LinearSolverKind;
pub use manifold::{Euclidean, EuclideanDyn, Manifold, UnitQuaternionManifold, SE2, SE3, SO2, SO3};
pub use minimizer::{
    Algorithm, DampingKind, Elimination, IterationSummary, Observer, Options, Solver, Summary,
    Termination,
};
pub use numeric::{check_jacobians, JacobianCheck, NumericDiff, DEFAULT_STEP};
pub use problem::{Problem, ResidualId, VarId};
pub use real::Real;
pub use residual::{Jacobians, Residual, Var};
pub use robust::RobustKernel;
