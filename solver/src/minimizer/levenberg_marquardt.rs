//! Levenberg-Marquardt (Madsen, Nielsen & Tingleff 2004, alg. 3.16): solve (H + μD) δ = −g, with
//! μ raised until H + μD is numerically positive definite.

use super::context::{Context, Proposal};
use super::vector::{constrain_step, model_decrease, negate_into};
use crate::damping::{Damping, LevenbergDamping};
use crate::error::SolveError;
use crate::options::{DampingKind, Options};

/// The damped step. H + μD that is not numerically positive definite (a gauge direction under
/// tiny damping) yields no step to try: μ is raised as a rejection would, within this
/// iteration, since nothing was evaluated (NOTES 49); `retries` counts those.
pub(super) fn propose(
    ctx: Context<'_>,
    opts: &Options,
    lm: &mut LevenbergDamping,
    retries: &mut usize,
) -> Result<Proposal, SolveError> {
    let Context {
        ne,
        linear,
        step_box,
        step,
        scratch,
        ..
    } = ctx;
    let d = loop {
        let d = match opts.damping {
            DampingKind::Identity => Damping::Identity(lm.mu()),
            DampingKind::Diagonal => Damping::Diagonal(lm.mu()),
        };
        if linear.factor(ne, d).is_ok() {
            break d;
        }
        if !lm.usable() {
            return Ok(Proposal::Exhausted { damping: lm.mu() });
        }
        *retries += 1;
        lm.rejected();
    };
    negate_into(ne.gradient(), step);
    linear.solve(ne, step);
    let boxed = constrain_step(step_box, ne, d, step)?;
    let predicted = if boxed || !linear.is_exact() {
        model_decrease(ne, step, scratch)
    } else {
        d.predicted_decrease(step, ne.gradient(), ne.h().diagonal_and_scale())
    };
    Ok(Proposal::Step {
        predicted,
        damping: lm.mu(),
    })
}
