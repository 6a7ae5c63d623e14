//! Gauss-Newton: δ = −H⁻¹g, taken whenever the cost there is finite.

use super::context::{Context, Proposal};
use super::vector::{constrain_step, model_decrease, negate_into};
use crate::damping::Damping;
use crate::diagnose;
use crate::error::SolveError;
use crate::linear::LinearSolver;
use crate::normal::NormalEquations;
use crate::parallel::dot;

/// The Gauss-Newton step; a singular H is diagnosed, and one that is of full rank but not
/// numerically positive definite is damped minimally.
pub(super) fn propose(ctx: Context<'_>) -> Result<Proposal, SolveError> {
    let Context {
        problem,
        ne,
        linear,
        step_box,
        step,
        scratch,
        max_diag,
    } = ctx;
    if let Err(_pivot) = linear.factor(ne, Damping::None) {
        diagnose::check_rank(problem, ne, linear)?;
        // Full rank but not numerically positive definite: damp minimally.
        let tiny = 1e-12 * max_diag;
        linear
            .factor(ne, Damping::Identity(tiny))
            .map_err(|p| SolveError::RankDeficient {
                nullity: 1,
                variables: vec![ne.var_of_scalar(p)],
                message: format!(
                    "the normal equations are singular at variable {}",
                    ne.var_of_scalar(p)
                ),
            })?;
    }
    negate_into(ne.gradient(), step);
    linear.solve(ne, step);
    let predicted = if constrain_step(step_box, ne, Damping::None, step)? {
        model_decrease(ne, step, scratch)
    } else {
        -dot(ne.gradient(), step) * 0.5
    };
    Ok(Proposal::Step {
        predicted,
        damping: 0.0,
    })
}

/// The Gauss-Newton step −H⁻¹g into `out`, minimally regularised where H is singular (the
/// dogleg's; it does not diagnose).
pub(super) fn regularised_step(
    ne: &NormalEquations,
    linear: &mut LinearSolver,
    max_diag: f64,
    out: &mut [f64],
) {
    let mut tiny = 0.0;
    while linear
        .factor(
            ne,
            if tiny == 0.0 {
                Damping::None
            } else {
                Damping::Identity(tiny)
            },
        )
        .is_err()
    {
        tiny = if tiny == 0.0 {
            1e-12 * max_diag.max(f64::MIN_POSITIVE)
        } else {
            tiny * 100.0
        };
    }
    negate_into(ne.gradient(), out);
    linear.solve(ne, out);
}
