//! Dispatch to the solver of the damped normal equations `(H + μD) δ = −g` that
//! [`LinearSolverKind`] names: a Cholesky of H itself ([`crate::cholesky`]) or the Schur
//! complement ([`crate::schur`]) for problems with many small independent blocks.

use crate::cholesky::Cholesky;
use crate::damping::Damping;
use crate::error::SolveError;
use crate::normal::NormalEquations;
use crate::options::LinearSolverKind;
use crate::schur::{Schur, SchurOptions};

/// The solver of the damped normal equations chosen by [`LinearSolverKind`].
pub(crate) enum LinearSolver {
    /// Cholesky of H itself.
    Direct(Cholesky),
    /// Elimination of independent blocks, then the reduced system.
    Schur(Box<Schur>),
}

impl LinearSolver {
    /// Prepares a solver for `ne`'s structure. `eliminate` marks the H blocks the Schur solvers
    /// eliminate (ignored by the direct ones).
    pub fn new(
        ne: &NormalEquations,
        kind: LinearSolverKind,
        dense_threshold: usize,
        eliminate: &[bool],
        schur: SchurOptions,
    ) -> Result<Self, SolveError> {
        let n = ne.dim();
        Ok(match kind {
            LinearSolverKind::Dense => Self::Direct(Cholesky::new(ne.h(), true)?),
            LinearSolverKind::Sparse => Self::Direct(Cholesky::new(ne.h(), false)?),
            LinearSolverKind::Auto => Self::Direct(Cholesky::new(ne.h(), n <= dense_threshold)?),
            _ => Self::Schur(Box::new(Schur::new(
                ne,
                eliminate,
                kind,
                dense_threshold,
                schur,
            )?)),
        })
    }

    /// A name for summaries: "dense", "sparse", "schur-dense", "schur-sparse", "schur-iterative".
    pub fn name(&self) -> &'static str {
        match self {
            Self::Direct(c) if c.is_sparse() => "sparse",
            Self::Direct(_) => "dense",
            Self::Schur(s) => s.name(),
        }
    }

    /// True when [`Self::solve`] is exact up to rounding (false for conjugate gradients).
    pub fn is_exact(&self) -> bool {
        match self {
            Self::Direct(_) => true,
            Self::Schur(s) => s.is_exact(),
        }
    }

    /// Factorises H + μD (or prepares the reduced system). On failure returns the index of an
    /// unknown where positive definiteness failed.
    pub fn factor(&mut self, ne: &NormalEquations, damping: Damping) -> Result<(), usize> {
        match self {
            Self::Direct(c) => c.factor(ne.h(), damping),
            Self::Schur(s) => s.factor(ne, damping),
        }
    }

    /// Solves with the last factorisation, overwriting `x` (the right-hand side) with the solution.
    pub fn solve(&mut self, ne: &NormalEquations, x: &mut [f64]) {
        match self {
            Self::Direct(c) => c.solve(x),
            Self::Schur(s) => s.solve(ne, x),
        }
    }
}
