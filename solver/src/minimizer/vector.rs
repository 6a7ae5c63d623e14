//! Vector helpers of the minimisers: norms, the model's decrease and the step applied on the
//! variables' manifolds.

use crate::bounds::StepBox;
use crate::damping::Damping;
use crate::error::SolveError;
use crate::normal::NormalEquations;
use crate::parallel::{dot, SyncPtr};
use crate::problem::Problem;
use rayon::prelude::*;

/// max |g_i|, projected onto the bounds where there are any.
pub(super) fn gradient_norm(step_box: Option<&StepBox>, ne: &NormalEquations) -> f64 {
    match step_box {
        Some(b) => b.projected_gradient_norm(ne.gradient()),
        None => max_abs(ne.gradient()),
    }
}

/// Keeps `step` inside the bounds of the current point (see [`crate::bounds`]); true when it had
/// to be replaced by the box-constrained minimiser.
pub(super) fn constrain_step(
    step_box: Option<&StepBox>,
    ne: &NormalEquations,
    damping: Damping,
    step: &mut [f64],
) -> Result<bool, SolveError> {
    match step_box {
        Some(b) if !b.contains(step) => b.constrain(ne, damping, step).map(|_| true),
        _ => Ok(false),
    }
}

/// The decrease of the undamped model, L(0) − L(δ) = −gᵀδ − ½ δᵀHδ, for any δ.
pub(super) fn model_decrease(ne: &NormalEquations, step: &[f64], scratch: &mut [f64]) -> f64 {
    -dot(ne.gradient(), step) - 0.5 * ne.quadratic(step, scratch)
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0f64, |m, x| m.max(x.abs()))
}

/// dst = −src.
pub(super) fn negate_into(src: &[f64], dst: &mut [f64]) {
    for (d, s) in dst.iter_mut().zip(src) {
        *d = -s;
    }
}

/// ‖x‖ over the free variables' ambient coordinates.
pub(super) fn free_norm(problem: &Problem, ne: &NormalEquations) -> f64 {
    ne.var_of_block()
        .iter()
        .map(|&v| {
            let var = &problem.variables[v];
            problem.values[var.offset..var.offset + var.manifold.ambient_dim()]
                .iter()
                .map(|x| x * x)
                .sum::<f64>()
        })
        .sum::<f64>()
        .sqrt()
}

/// trial = values ⊞ step for every free variable (fixed ones copied), in parallel.
pub(super) fn apply_step(problem: &Problem, ne: &NormalEquations, step: &[f64], trial: &mut [f64]) {
    let out = SyncPtr::new(trial);
    ne.var_of_block()
        .par_iter()
        .enumerate()
        .with_min_len(256)
        .for_each(|(b, &v)| {
            let var = &problem.variables[v];
            let a = var.manifold.ambient_dim();
            let x = &problem.values[var.offset..var.offset + a];
            // SAFETY: each variable owns its ambient range of `trial`.
            let o = unsafe { out.slice(var.offset, a) };
            var.manifold.plus(
                x,
                &step[ne.h().block_start[b]..ne.h().block_start[b + 1]],
                o,
            );
        });
}
