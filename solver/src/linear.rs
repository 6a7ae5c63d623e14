//! Dispatch to the solver of the damped normal equations `(H + μD) δ = −g` that
//! [`LinearSolverKind`] names: a Cholesky of H itself ([`crate::cholesky`]) or the Schur
//! complement ([`crate::schur`]) for problems with many small independent blocks.

use crate::cholesky::Cholesky;
use crate::damping::Damping;
use crate::error::SolveError;
use crate::normal::NormalEquations;
use crate::options::LinearSolverKind;
use crate::schur::{Schur, SchurOptions};
use std::time::Instant;

/// The solver of the damped normal equations chosen by [`LinearSolverKind`], with the time its
/// factorisations took.
pub(crate) struct LinearSolver {
    inner: Inner,
    factor_seconds: f64,
    /// What a Schur solver is laid out again with, when the automatic choice moves from
    /// conjugate gradients to a factorisation.
    dense_threshold: usize,
    schur: SchurOptions,
    /// Conjugate-gradient iterations of a solver replaced that way.
    earlier_iterations: usize,
}

enum Inner {
    /// Cholesky of H itself.
    Direct(Cholesky),
    /// Elimination of independent blocks, then the reduced system.
    Schur(Box<Schur>),
}

impl LinearSolver {
    /// Prepares a solver for `ne`'s structure. The Schur solvers eliminate the blocks `ne` was
    /// made with ([`NormalEquations::with_elimination`]); the direct ones need H whole.
    pub fn new(
        ne: &NormalEquations,
        kind: LinearSolverKind,
        dense_threshold: usize,
        schur: SchurOptions,
    ) -> Result<Self, SolveError> {
        let n = ne.dim();
        if !kind.is_schur() && !ne.couplings().in_h && !ne.couplings().kept.is_empty() {
            return Err(SolveError::LinearSolver(
                "a direct solver needs H whole, but these normal equations leave the blocks \
                 of eliminated variables out"
                    .to_string(),
            ));
        }
        let inner = match kind {
            LinearSolverKind::Dense => Inner::Direct(Cholesky::new(ne.h(), true)?),
            LinearSolverKind::Sparse => Inner::Direct(Cholesky::new(ne.h(), false)?),
            LinearSolverKind::Auto => Inner::Direct(Cholesky::new(ne.h(), n <= dense_threshold)?),
            _ => Inner::Schur(Box::new(Schur::new(ne, kind, dense_threshold, schur)?)),
        };
        Ok(Self {
            inner,
            factor_seconds: 0.0,
            dense_threshold,
            schur,
            earlier_iterations: 0,
        })
    }

    /// A Cholesky of H itself.
    pub fn direct(cholesky: Cholesky) -> Self {
        Self {
            inner: Inner::Direct(cholesky),
            factor_seconds: 0.0,
            dense_threshold: 0,
            schur: SchurOptions {
                pcg_tolerance: 0.0,
                pcg_max_iterations: 0,
                pcg_forcing: 0.0,
            },
            earlier_iterations: 0,
        }
    }

    /// Seconds spent in [`Self::factor`] since this solver was made (for a Schur solver, the
    /// elimination and the reduced system's factorisation).
    pub fn factor_seconds(&self) -> f64 {
        self.factor_seconds
    }

    /// A name for summaries: "dense", "sparse", "schur-dense", "schur-sparse", "schur-iterative".
    pub fn name(&self) -> &'static str {
        match &self.inner {
            Inner::Direct(c) if c.is_sparse() => "sparse",
            Inner::Direct(_) => "dense",
            Inner::Schur(s) => s.name(),
        }
    }

    /// Conjugate-gradient iterations so far (0 for the exact solvers).
    pub fn iterations(&self) -> usize {
        match &self.inner {
            Inner::Direct(_) => 0,
            Inner::Schur(s) => self.earlier_iterations + s.iterations(),
        }
    }

    /// True when [`Self::solve`] is exact up to rounding (false for conjugate gradients).
    pub fn is_exact(&self) -> bool {
        match &self.inner {
            Inner::Direct(_) => true,
            Inner::Schur(s) => s.is_exact(),
        }
    }

    /// Factorises H + μD (or prepares the reduced system). On failure returns the index of an
    /// unknown where positive definiteness failed.
    pub fn factor(&mut self, ne: &NormalEquations, damping: Damping) -> Result<(), usize> {
        let clock = Instant::now();
        let factored = match &mut self.inner {
            Inner::Direct(c) => c.factor(ne.h(), damping),
            Inner::Schur(s) => {
                if s.wants_factorisation() {
                    let kind = LinearSolverKind::SchurSparse;
                    match Schur::new(ne, kind, self.dense_threshold, self.schur) {
                        Ok(sparse) => {
                            tracing::debug!(
                                iterations = s.iterations(),
                                "conjugate gradients replaced by a sparse factorisation of S"
                            );
                            self.earlier_iterations += s.iterations();
                            **s = sparse;
                        }
                        Err(e) => {
                            tracing::warn!("kept conjugate gradients: {e}");
                            s.keep_iterating();
                        }
                    }
                }
                s.factor(ne, damping)
            }
        };
        self.factor_seconds += clock.elapsed().as_secs_f64();
        factored
    }

    /// Solves with the last factorisation, overwriting `x` (the right-hand side) with the solution.
    pub fn solve(&mut self, ne: &NormalEquations, x: &mut [f64]) {
        match &mut self.inner {
            Inner::Direct(c) => c.solve(x),
            Inner::Schur(s) => s.solve(ne, x),
        }
    }
}
