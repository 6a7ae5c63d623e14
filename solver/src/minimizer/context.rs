//! What a minimiser is given to choose a step, and what it answers.

use crate::bounds::StepBox;
use crate::linear::LinearSolver;
use crate::normal::NormalEquations;
use crate::problem::Problem;

/// What a method needs to choose a step at the current point.
pub(super) struct Context<'a> {
    pub problem: &'a Problem,
    pub ne: &'a NormalEquations,
    pub linear: &'a mut LinearSolver,
    pub step_box: Option<&'a StepBox>,
    /// The step chosen, written by the method.
    pub step: &'a mut [f64],
    pub scratch: &'a mut [f64],
    /// max diag H at the start point.
    pub max_diag: f64,
}

/// A method's answer at the current point.
pub(super) enum Proposal {
    /// A step (in [`Context::step`]) with the model's predicted decrease L(0) − L(δ) and the
    /// damping (μ or trust radius) reported for it.
    Step { predicted: f64, damping: f64 },
    /// No damping yields a step to try: the solve ends without progress.
    Exhausted { damping: f64 },
}
