//! What a solve reports: each iteration, why it stopped, and the whole solve's figures.

use std::fmt;
use std::ops::ControlFlow;

/// What happened in one iteration.
#[derive(Clone, Debug, PartialEq)]
pub struct IterationSummary {
    /// Iteration number; 0 is the start point.
    pub iteration: usize,
    /// Cost ½Σρ after the iteration.
    pub cost: f64,
    /// Cost decrease of this iteration (0 when the step was rejected).
    pub cost_change: f64,
    /// max |gᵢ| at the current point.
    pub gradient_norm: f64,
    /// ‖δ‖ of the step tried.
    pub step_norm: f64,
    /// LM's μ, or the dogleg's trust radius, used for the step.
    pub damping: f64,
    /// Whether the step was taken.
    pub accepted: bool,
    /// Seconds spent evaluating residuals and Jacobians and assembling H.
    pub evaluate_seconds: f64,
    /// Seconds spent factorising and solving.
    pub solve_seconds: f64,
    /// Seconds since the solve started.
    pub total_seconds: f64,
}

/// Why the minimiser stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Termination {
    /// The gradient is below `gradient_tolerance`.
    GradientTolerance,
    /// The step is below `step_tolerance`.
    StepTolerance,
    /// The relative cost decrease is below `function_tolerance`.
    FunctionTolerance,
    /// `max_iterations` reached.
    MaxIterations,
    /// `max_seconds` reached.
    TimeLimit,
    /// The observer asked to stop.
    UserStopped,
    /// LM's damping (or the dogleg's radius) ran out of range without finding a better point.
    NoProgress,
}

impl Termination {
    /// True for the convergence criteria (gradient, step or function tolerance).
    pub fn converged(self) -> bool {
        matches!(
            self,
            Self::GradientTolerance | Self::StepTolerance | Self::FunctionTolerance
        )
    }
}

impl fmt::Display for Termination {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::GradientTolerance => "gradient below tolerance",
            Self::StepTolerance => "step below tolerance",
            Self::FunctionTolerance => "relative cost change below tolerance",
            Self::MaxIterations => "iteration limit reached",
            Self::TimeLimit => "time limit reached",
            Self::UserStopped => "stopped by the observer",
            Self::NoProgress => "no further decrease found (damping exhausted)",
        })
    }
}

/// Where a solve's time went, in wall-clock seconds (after the time report of Ceres'
/// `Solver::Summary::FullReport`). The parts add up to [`Summary::total_seconds`] but for the
/// minimiser's own bookkeeping (convergence tests, step updates, the observer).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Timing {
    /// The normal equations' layout, the fill-reducing ordering and the symbolic factorisation
    /// (0 when the solver reused them from a solve of the same structure).
    pub setup: f64,
    /// Residuals and Jacobians, at the start and at every trial point.
    pub evaluate: f64,
    /// H = JᵀJ and g = Jᵀr from them.
    pub assemble: f64,
    /// Numeric factorisations of H + μD (with a Schur solver, the elimination and the reduced
    /// system's factorisation or preconditioner).
    pub factorise: f64,
    /// The rest of each step's linear algebra: triangular solves, conjugate gradients, the
    /// dogleg's Cauchy point and predicted decrease.
    pub step: f64,
}

impl Timing {
    /// Adds another solve's times to these.
    pub fn add(&mut self, other: &Timing) {
        self.setup += other.setup;
        self.evaluate += other.evaluate;
        self.assemble += other.assemble;
        self.factorise += other.factorise;
        self.step += other.step;
    }
}

/// The outcome of a solve.
#[derive(Clone, Debug)]
pub struct Summary {
    /// Cost at the start.
    pub initial_cost: f64,
    /// Cost at the end.
    pub final_cost: f64,
    /// Every iteration, starting with iteration 0 (the start point).
    pub iterations: Vec<IterationSummary>,
    /// Why it stopped.
    pub termination: Termination,
    /// Wall-clock seconds of the whole solve, the setup ([`Timing::setup`]) included.
    pub total_seconds: f64,
    /// How [`Self::total_seconds`] divides.
    pub timing: Timing,
    /// Number of unknowns (tangent dimensions of the free variables).
    pub unknowns: usize,
    /// "dense", "sparse", "schur-dense", "schur-sparse" or "schur-iterative" (the solver in use
    /// at the end, when the automatic choice changed it during the solve).
    pub linear_solver: &'static str,
    /// Conjugate-gradient iterations over the whole solve (each one product with the reduced
    /// system); 0 for the exact solvers.
    pub linear_iterations: usize,
    /// Steps rejected because a residual block returned NaN or an infinity (in its residual or
    /// its Jacobian) at the trial point; the damping was raised after each.
    pub non_finite_steps: usize,
    /// The residual block (its [`crate::ResidualId`] index) that returned a non-finite value at
    /// the last such rejected step, when the solve ended on it: without progress, or with every
    /// step of its last iterations rejected that way. The values are those of the last finite
    /// point, never NaN.
    pub non_finite_block: Option<usize>,
}

impl Summary {
    /// Number of iterations performed (excluding the start point).
    pub fn num_iterations(&self) -> usize {
        self.iterations.len().saturating_sub(1)
    }

    /// Appends a solve that resumed from this one's end (after the caller changed some values):
    /// its iterations numbered on from this one's last (its start point left out) and timed from
    /// this one's start, its times and counts added, its final cost and termination taken.
    pub fn resume(&mut self, next: Summary) {
        let (offset, before) = (self.num_iterations(), self.total_seconds);
        self.iterations
            .extend(next.iterations.into_iter().skip(1).map(|mut it| {
                it.iteration += offset;
                it.total_seconds += before;
                it
            }));
        self.final_cost = next.final_cost;
        self.termination = next.termination;
        self.total_seconds += next.total_seconds;
        self.timing.add(&next.timing);
        self.linear_solver = next.linear_solver;
        self.linear_iterations += next.linear_iterations;
        self.non_finite_steps += next.non_finite_steps;
        self.non_finite_block = next.non_finite_block;
    }

    /// A table with one line per iteration, for printing.
    pub fn table(&self) -> String {
        let mut s = String::from(IterationSummary::HEADER);
        s.push('\n');
        for it in &self.iterations {
            s.push_str(&it.to_string());
            s.push('\n');
        }
        s.push_str(&format!(
            "stopped after {} iterations: {}; cost {:.10e} -> {:.10e} in {:.4} s ({} unknowns, {} Cholesky)",
            self.num_iterations(),
            self.termination,
            self.initial_cost,
            self.final_cost,
            self.total_seconds,
            self.unknowns,
            self.linear_solver
        ));
        let t = &self.timing;
        s.push_str(&format!(
            "\ntime: setup {:.4} s, evaluate {:.4} s, assemble {:.4} s, factorise {:.4} s, step {:.4} s",
            t.setup, t.evaluate, t.assemble, t.factorise, t.step
        ));
        if let Some(block) = self.non_finite_block {
            s.push_str(&format!(
                "\nresidual block {block} returned NaN or infinity at the last trial points ({} non-finite trial points in all); the result is the last finite point",
                self.non_finite_steps
            ));
        } else if self.non_finite_steps > 0 {
            s.push_str(&format!(
                "\n{} trial steps were rejected for non-finite residuals, and the solve went on",
                self.non_finite_steps
            ));
        }
        s
    }
}

impl IterationSummary {
    /// Column titles matching the `Display` form.
    pub const HEADER: &'static str =
        " iter          cost      cost_change    |gradient|        |step|       damping  ok  eval_s   solve_s   total_s";
}

impl fmt::Display for IterationSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{:5} {:13.6e} {:16.6e} {:13.6e} {:13.6e} {:13.6e} {:>3} {:7.4} {:9.4} {:9.4}",
            self.iteration,
            self.cost,
            self.cost_change,
            self.gradient_norm,
            self.step_norm,
            self.damping,
            if self.accepted { "y" } else { "n" },
            self.evaluate_seconds,
            self.solve_seconds,
            self.total_seconds
        )
    }
}

/// An observer sees every iteration and may stop the solve by returning `ControlFlow::Break`.
pub type Observer = Box<dyn FnMut(&IterationSummary) -> ControlFlow<()> + Send>;

#[cfg(test)]
mod tests {
    use super::*;

    fn iteration(iteration: usize, cost: f64, total_seconds: f64) -> IterationSummary {
        IterationSummary {
            iteration,
            cost,
            cost_change: 0.0,
            gradient_norm: 0.0,
            step_norm: 0.0,
            damping: 0.0,
            accepted: true,
            evaluate_seconds: 0.0,
            solve_seconds: 0.0,
            total_seconds,
        }
    }

    fn summary(costs: &[f64], seconds: f64, termination: Termination) -> Summary {
        let n = costs.len();
        Summary {
            initial_cost: costs[0],
            final_cost: costs[n - 1],
            iterations: (0..n)
                .map(|i| iteration(i, costs[i], seconds * i as f64 / (n - 1) as f64))
                .collect(),
            termination,
            total_seconds: seconds,
            timing: Timing {
                evaluate: seconds / 2.0,
                ..Timing::default()
            },
            unknowns: 3,
            linear_solver: "schur-iterative",
            linear_iterations: 10,
            non_finite_steps: 1,
            non_finite_block: None,
        }
    }

    #[test]
    fn a_resumed_solve_numbers_and_times_its_iterations_on() {
        let mut first = summary(&[10.0, 5.0, 4.0], 2.0, Termination::FunctionTolerance);
        // the caller lowered the cost to 3 between the solves; the resumed start is left out
        first.resume(summary(
            &[3.0, 2.0, 1.5, 1.4],
            3.0,
            Termination::MaxIterations,
        ));
        let numbers: Vec<usize> = first.iterations.iter().map(|i| i.iteration).collect();
        assert_eq!(numbers, [0, 1, 2, 3, 4, 5]);
        let costs: Vec<f64> = first.iterations.iter().map(|i| i.cost).collect();
        assert_eq!(costs, [10.0, 5.0, 4.0, 2.0, 1.5, 1.4]);
        assert_eq!(first.iterations[3].total_seconds, 3.0);
        assert_eq!(first.iterations[5].total_seconds, 5.0);
        assert_eq!(first.num_iterations(), 5);
        assert_eq!((first.initial_cost, first.final_cost), (10.0, 1.4));
        assert_eq!(first.termination, Termination::MaxIterations);
        assert_eq!(first.total_seconds, 5.0);
        assert_eq!(first.timing.evaluate, 2.5);
        assert_eq!((first.linear_iterations, first.non_finite_steps), (20, 2));
    }
}
