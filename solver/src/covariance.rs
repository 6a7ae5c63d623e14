//! Marginal covariances: blocks of H⁻¹ = (JᵀJ)⁻¹ at the current values.
//!
//! Under Gaussian noise and a whitened cost ½‖r‖², the Laplace approximation of the posterior at
//! the optimum has covariance H⁻¹ in the tangent spaces of the variables (Dellaert & Kaess, *Factor
//! Graphs for Robot Perception*, 2017, sec. 2.4; GTSAM's `Marginals`). The block of one variable
//! is found without forming H⁻¹: H is factorised once (sparse or dense Cholesky) and solved for the
//! unit vectors of that variable's coordinates.

use crate::cholesky::Cholesky;
use crate::damping::Damping;
use crate::diagnose;
use crate::error::SolveError;
use crate::linear::LinearSolver;
use crate::normal::NormalEquations;
use crate::options::Options;
use crate::problem::{Problem, VarId};
use nalgebra::DMatrix;

/// The marginal covariance of each variable in `variables` (tangent_dim × tangent_dim, in the
/// tangent coordinates of its manifold), at the problem's current values.
///
/// Errors: a fixed or unknown variable; a non-finite cost; a gauge freedom or rank deficiency
/// (the error names the unconstrained variables, as a solve would).
pub fn covariance(problem: &Problem, variables: &[VarId]) -> Result<Vec<DMatrix<f64>>, SolveError> {
    let mut ne = NormalEquations::new(problem)?;
    for v in variables {
        match ne.block_of_var().get(v.0) {
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
    let dense = ne.dim() <= Options::default().dense_threshold;
    let mut linear = LinearSolver::direct(Cholesky::new(ne.h(), dense)?);
    if diagnose::has_unanchored_component(problem, &ne) {
        diagnose::check_rank(problem, &ne, &mut linear)?;
    }
    if let Err(pivot) = linear.factor(&ne, Damping::None) {
        diagnose::check_rank(problem, &ne, &mut linear)?;
        let v = ne.var_of_scalar(pivot);
        return Err(SolveError::RankDeficient {
            nullity: 1,
            variables: vec![v],
            message: format!(
                "H is not positive definite at variable {v}: its covariance is unbounded"
            ),
        });
    }
    let n = ne.dim();
    let mut column = vec![0.0; n];
    let mut out = Vec::with_capacity(variables.len());
    for v in variables {
        let b = ne.block_of_var()[v.0];
        let (start, d) = (ne.h().block_start[b], ne.h().block_dim(b));
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
