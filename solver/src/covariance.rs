//! Marginal covariances: blocks of H⁻¹ = (JᵀJ)⁻¹ at the current values.
//!
//! Under Gaussian noise and a whitened cost ½‖r‖², the Laplace approximation of the posterior at
//! the optimum has covariance H⁻¹ in the tangent spaces of the variables (Dellaert & Kaess, *Factor
//! Graphs for Robot Perception*, 2017, sec. 2.4; GTSAM's `Marginals`). The block of one variable
//! is found without forming H⁻¹: H is factorised once (sparse or dense Cholesky) and solved for the
//! unit vectors of that variable's coordinates.

use crate::diagnose;
use crate::error::SolveError;
use crate::linear::{Damping, LinearSolver, LinearSolverKind};
use crate::normal::NormalEquations;
use crate::problem::{Problem, VarId};
use crate::schur::SchurOptions;
use nalgebra::DMatrix;

/// The marginal covariance of each variable in `variables` (tangent_dim × tangent_dim, in the
/// tangent coordinates of its manifold), at the problem's current values.
///
/// Errors: a fixed or unknown variable; a non-finite cost; a gauge freedom or rank deficiency
/// (the error names the unconstrained variables, as a solve would).
pub fn covariance(problem: &Problem, variables: &[VarId]) -> Result<Vec<DMatrix<f64>>, SolveError> {
    let mut ne = NormalEquations::new(problem)?;
    for v in variables {
        match ne.block_of_var.get(v.0) {
            None => {
                return Err(SolveError::Covariance(format!(
                    "variable {} does not exist",
                    v.0
                )))
            }
            Some(&usize::MAX) => {
                return Err(SolveError::Covariance(format!(
                    "variable {} is fixed: it has no covariance",
                    v.0
                )))
            }
            Some(_) => {}
        }
    }
    let cost = ne.evaluate(problem, &problem.values, true);
    if !cost.is_finite() {
        return Err(SolveError::NonFiniteInitialCost(
            ne.first_non_finite().unwrap_or(0),
        ));
    }
    ne.assemble();
    let mut linear = LinearSolver::new(
        &ne,
        LinearSolverKind::Auto,
        200,
        &[],
        SchurOptions {
            pcg_tolerance: 0.0,
            pcg_max_iterations: 0,
        },
    )?;
    if diagnose::has_unanchored_component(problem, &ne) {
        diagnose::check_rank(problem, &ne, &mut linear)?;
    }
    if let Err(pivot) = linear.factor(&ne, Damping::None) {
        diagnose::check_rank(problem, &ne, &mut linear)?;
        let b = ne.h.block_start.partition_point(|&s| s <= pivot) - 1;
        return Err(SolveError::RankDeficient {
            nullity: 1,
            variables: vec![ne.var_of_block[b]],
            message: format!(
                "H is not positive definite at variable {}: its covariance is unbounded",
                ne.var_of_block[b]
            ),
        });
    }
    let n = ne.dim();
    let mut column = vec![0.0; n];
    let mut out = Vec::with_capacity(variables.len());
    for v in variables {
        let b = ne.block_of_var[v.0];
        let (start, d) = (ne.h.block_start[b], ne.h.block_dim(b));
        let mut m = DMatrix::zeros(d, d);
        for c in 0..d {
            column.fill(0.0);
            column[start + c] = 1.0;
            linear.solve(&ne, &mut column);
            for r in 0..d {
                m[(r, c)] = column[start + r];
            }
        }
        out.push((&m + m.transpose()) * 0.5);
    }
    Ok(out)
}
