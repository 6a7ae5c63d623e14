//! The minimisers: Gauss-Newton, Levenberg-Marquardt and Powell's dogleg over a [`Problem`].
//!
//! Levenberg-Marquardt follows Madsen, Nielsen & Tingleff, *Methods for Non-Linear Least Squares
//! Problems* (2004), alg. 3.16: initial damping μ₀ = τ max diag(JᵀJ) (the thesis' eq. 2.17), gain
//! ratio ρ = (F(x) − F(x+δ)) / (L(0) − L(δ)), and Nielsen's update μ ← μ max(1/3, 1 − (2ρ − 1)³) on
//! success, μ ← μν, ν ← 2ν on failure. The dogleg follows the same text, alg. 3.21.

use crate::bounds::{self, StepBox};
use crate::diagnose;
use crate::error::SolveError;
use crate::linear::{Damping, LinearSolver, LinearSolverKind};
use crate::normal::{dot, NormalEquations, SyncPtr};
use crate::problem::{Problem, VarId};
use crate::schur::{self, SchurOptions};
use rayon::prelude::*;
use std::fmt;
use std::ops::ControlFlow;
use std::time::Instant;

/// The minimisation method.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Algorithm {
    /// Plain Gauss-Newton: δ = −H⁻¹g, every step taken.
    GaussNewton,
    /// Levenberg-Marquardt with Nielsen's damping update.
    LevenbergMarquardt,
    /// Powell's dogleg trust region.
    Dogleg,
}

/// How LM's damping term is scaled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DampingKind {
    /// μI.
    Identity,
    /// μ diag(H).
    Diagonal,
}

/// Which variables the Schur-complement solvers eliminate.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum Elimination {
    /// A maximal set of independent variables (no residual ties two of them), chosen greedily by
    /// fewest neighbours, then smallest tangent dimension: the points of bundle adjustment.
    #[default]
    Auto,
    /// These variables (they must be independent; fixed ones are skipped).
    Variables(Vec<VarId>),
}

/// Solver settings. The defaults suit most problems; [`Options::default`] documents each.
#[derive(Clone, Debug)]
pub struct Options {
    /// Minimisation method (default Levenberg-Marquardt).
    pub algorithm: Algorithm,
    /// Largest number of iterations (default 100).
    pub max_iterations: usize,
    /// Wall-clock limit in seconds (default: none).
    pub max_seconds: f64,
    /// Stop when max |gᵢ| ≤ this (default 1e-10).
    pub gradient_tolerance: f64,
    /// Stop when ‖δ‖ ≤ tol (‖x‖ + tol) (default 1e-10).
    pub step_tolerance: f64,
    /// Stop when an accepted step lowers the cost by less than this fraction (default 1e-10).
    pub function_tolerance: f64,
    /// LM: τ in the initial damping, μ₀ = τ max diag(H) for μI damping and μ₀ = τ for
    /// μ diag(H) damping (Ceres' 1 / initial trust-region radius) (default 1e-4).
    pub initial_damping_tau: f64,
    /// LM: damping μI or μ diag(H) (default μI).
    pub damping: DampingKind,
    /// Dogleg: initial trust-region radius (default 1e4).
    pub initial_trust_radius: f64,
    /// Linear solver (default: dense below `dense_threshold` unknowns, sparse above).
    pub linear_solver: LinearSolverKind,
    /// Unknowns up to which [`LinearSolverKind::Auto`] chooses the dense solver (default 200).
    pub dense_threshold: usize,
    /// Check components that touch no fixed variable for a null space before solving (default true).
    pub check_rank: bool,
    /// Variables the Schur solvers eliminate (default [`Elimination::Auto`]).
    pub elimination: Elimination,
    /// Iterative Schur: stop conjugate gradients at ‖S y − b‖ ≤ tol ‖b‖ (default 1e-6).
    pub pcg_tolerance: f64,
    /// Iterative Schur: most conjugate-gradient iterations per step (default 500).
    pub pcg_max_iterations: usize,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            algorithm: Algorithm::LevenbergMarquardt,
            max_iterations: 100,
            max_seconds: f64::INFINITY,
            gradient_tolerance: 1e-10,
            step_tolerance: 1e-10,
            function_tolerance: 1e-10,
            initial_damping_tau: 1e-4,
            damping: DampingKind::Identity,
            initial_trust_radius: 1e4,
            linear_solver: LinearSolverKind::Auto,
            dense_threshold: 200,
            check_rank: true,
            elimination: Elimination::Auto,
            pcg_tolerance: 1e-6,
            pcg_max_iterations: 500,
        }
    }
}

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
    /// Wall-clock seconds of the whole solve.
    pub total_seconds: f64,
    /// Number of unknowns (tangent dimensions of the free variables).
    pub unknowns: usize,
    /// "dense", "sparse", "schur-dense", "schur-sparse" or "schur-iterative".
    pub linear_solver: &'static str,
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

/// Buffers kept between solves of problems with the same structure.
struct Workspace {
    key: (u64, u64),
    ne: NormalEquations,
    linear: LinearSolver,
    trial: Vec<f64>,
    step: Vec<f64>,
    scratch: Vec<f64>,
    /// The dogleg's Gauss-Newton step, kept while H is unchanged (after a rejected step).
    gauss_newton: Vec<f64>,
}

/// Minimises a [`Problem`]; keeps its symbolic factorisation and buffers for the next solve of a
/// problem with the same structure (the next frame, the next iteration of an outer loop).
pub struct Solver {
    /// The settings.
    pub options: Options,
    observer: Option<Observer>,
    workspace: Option<Workspace>,
}

impl Solver {
    /// A solver with these settings.
    pub fn new(options: Options) -> Self {
        Self {
            options,
            observer: None,
            workspace: None,
        }
    }

    /// Calls `observer` after every iteration (and once at the start point).
    pub fn with_observer(
        mut self,
        observer: impl FnMut(&IterationSummary) -> ControlFlow<()> + Send + 'static,
    ) -> Self {
        self.observer = Some(Box::new(observer));
        self
    }

    fn prepare(&mut self, problem: &Problem) -> Result<Workspace, SolveError> {
        let key = (problem.id, problem.structure_version);
        if let Some(ws) = self.workspace.take() {
            if ws.key == key {
                return Ok(ws);
            }
        }
        let ne = NormalEquations::new(problem)?;
        let eliminate = if self.options.linear_solver.is_schur() {
            schur::elimination_set(problem, &ne, &self.options.elimination)?
        } else {
            Vec::new()
        };
        let linear = LinearSolver::new(
            &ne,
            self.options.linear_solver,
            self.options.dense_threshold,
            &eliminate,
            SchurOptions {
                pcg_tolerance: self.options.pcg_tolerance,
                pcg_max_iterations: self.options.pcg_max_iterations,
            },
        )?;
        let n = ne.dim();
        Ok(Workspace {
            key,
            ne,
            linear,
            trial: problem.values.clone(),
            step: vec![0.0; n],
            scratch: vec![0.0; n],
            gauss_newton: vec![0.0; n],
        })
    }

    /// Minimises `problem` from its current values, which are replaced by the result.
    pub fn solve(&mut self, problem: &mut Problem) -> Result<Summary, SolveError> {
        let mut ws = self.prepare(problem)?;
        let result = self.run(problem, &mut ws);
        self.workspace = Some(ws);
        result
    }

    fn notify(&mut self, it: &IterationSummary, log: &mut Vec<IterationSummary>) -> bool {
        tracing::trace!(
            iteration = it.iteration,
            cost = it.cost,
            gradient = it.gradient_norm,
            damping = it.damping,
            accepted = it.accepted,
            "solver iteration"
        );
        log.push(it.clone());
        match &mut self.observer {
            Some(o) => o(it).is_break(),
            None => false,
        }
    }

    fn run(&mut self, problem: &mut Problem, ws: &mut Workspace) -> Result<Summary, SolveError> {
        let opts = self.options.clone();
        let start = Instant::now();
        let Workspace {
            ne,
            linear,
            trial,
            step,
            scratch,
            gauss_newton,
            ..
        } = ws;
        let mut gn_valid = false;
        trial.copy_from_slice(&problem.values);
        let t0 = Instant::now();
        let mut cost = ne.evaluate(problem, &problem.values, true);
        if !cost.is_finite() {
            return Err(SolveError::NonFiniteInitialCost(
                ne.first_non_finite().unwrap_or(0),
            ));
        }
        ne.assemble();
        let mut evaluate_seconds = t0.elapsed().as_secs_f64();
        if opts.check_rank && diagnose::has_unanchored_component(problem, ne) {
            diagnose::check_rank(problem, ne, linear)?;
        }
        let initial_cost = cost;
        let mut log = Vec::new();
        // The step's box moves with the current point only: rebuilt when a step is accepted.
        let mut step_box = StepBox::new(problem, ne);
        if step_box.is_some() && opts.algorithm == Algorithm::Dogleg {
            return Err(SolveError::Bounds(
                "the dogleg does not take bounds; use Levenberg-Marquardt or Gauss-Newton".into(),
            ));
        }
        let mut gnorm = gradient_norm(step_box.as_ref(), ne);
        let mut stop = self.notify(
            &IterationSummary {
                iteration: 0,
                cost,
                cost_change: 0.0,
                gradient_norm: gnorm,
                step_norm: 0.0,
                damping: 0.0,
                accepted: true,
                evaluate_seconds,
                solve_seconds: 0.0,
                total_seconds: start.elapsed().as_secs_f64(),
            },
            &mut log,
        );
        let max_diag = ne.h.diagonal().fold(0.0f64, f64::max);
        let mut mu = match opts.damping {
            DampingKind::Identity => opts.initial_damping_tau * max_diag.max(f64::MIN_POSITIVE),
            DampingKind::Diagonal => opts.initial_damping_tau,
        };
        let mut nu = 2.0;
        let mut radius = opts.initial_trust_radius;
        let mut termination = if stop {
            Termination::UserStopped
        } else if gnorm <= opts.gradient_tolerance {
            Termination::GradientTolerance
        } else {
            Termination::MaxIterations
        };
        let mut iteration = 0;
        // non-finite trial points: in all, in a row, and the last block that gave one
        let (mut non_finite_steps, mut non_finite_run, mut non_finite_block) =
            (0usize, 0usize, None);
        // LM: factorisations of H + μD that failed and were retried with more damping
        let mut factor_retries = 0usize;
        while !stop && termination == Termination::MaxIterations && iteration < opts.max_iterations
        {
            iteration += 1;
            if start.elapsed().as_secs_f64() > opts.max_seconds {
                termination = Termination::TimeLimit;
                break;
            }
            let t_solve = Instant::now();
            // Choose a step δ and its predicted decrease L(0) − L(δ).
            let (predicted, damping_used) = match opts.algorithm {
                Algorithm::GaussNewton => {
                    if let Err(_pivot) = linear.factor(ne, Damping::None) {
                        diagnose::check_rank(problem, ne, linear)?;
                        // Full rank but not numerically positive definite: damp minimally.
                        let tiny = 1e-12 * max_diag;
                        linear.factor(ne, Damping::Identity(tiny)).map_err(|p| {
                            SolveError::RankDeficient {
                                nullity: 1,
                                variables: vec![ne.var_of_scalar(p)],
                                message: format!(
                                    "the normal equations are singular at variable {}",
                                    ne.var_of_scalar(p)
                                ),
                            }
                        })?;
                    }
                    negate_into(&ne.gradient, step);
                    linear.solve(ne, step);
                    let pred = if constrain_step(step_box.as_ref(), ne, Damping::None, step)? {
                        model_decrease(ne, step, scratch)
                    } else {
                        -dot(&ne.gradient, step) * 0.5
                    };
                    (pred, 0.0)
                }
                Algorithm::LevenbergMarquardt => {
                    // H + μD that is not numerically positive definite (a gauge direction under
                    // tiny damping) yields no step to try: raise μ as a rejection would, within
                    // this iteration, since nothing was evaluated (NOTES 49).
                    let (d, factored) = loop {
                        let d = match opts.damping {
                            DampingKind::Identity => Damping::Identity(mu),
                            DampingKind::Diagonal => Damping::Diagonal(mu),
                        };
                        if linear.factor(ne, d).is_ok() {
                            break (d, true);
                        }
                        if !mu.is_finite() || mu > 1e300 {
                            break (d, false);
                        }
                        factor_retries += 1;
                        mu *= nu;
                        nu *= 2.0;
                    };
                    if !factored {
                        termination = Termination::NoProgress;
                        stop = self.notify(
                            &rejected(iteration, cost, gnorm, mu, t_solve, start),
                            &mut log,
                        );
                        continue;
                    }
                    negate_into(&ne.gradient, step);
                    linear.solve(ne, step);
                    let boxed = constrain_step(step_box.as_ref(), ne, d, step)?;
                    if boxed || !linear.is_exact() {
                        (model_decrease(ne, step, scratch), mu)
                    } else {
                        // For the exact solution of (H + μD)δ = −g: L(0) − L(δ) = ½ δᵀ(μDδ − g)
                        let damp_term: f64 = match opts.damping {
                            DampingKind::Identity => mu * dot(step, step),
                            DampingKind::Diagonal => {
                                ne.h.diag_pos
                                    .iter()
                                    .zip(step.iter())
                                    .map(|(&p, s)| mu * ne.h.values[p].clamp(1e-6, 1e32) * s * s)
                                    .sum()
                            }
                        };
                        (0.5 * (damp_term - dot(step, &ne.gradient)), mu)
                    }
                }
                Algorithm::Dogleg => {
                    if !gn_valid {
                        gauss_newton_step(ne, linear, max_diag, gauss_newton);
                        gn_valid = true;
                    }
                    let pred = dogleg_step(ne, gauss_newton, radius, step, scratch);
                    (pred, radius)
                }
            };
            let solve_seconds = t_solve.elapsed().as_secs_f64();
            let step_norm = dot(step, step).sqrt();
            let x_norm = free_norm(problem, ne);
            if step_norm <= opts.step_tolerance * (x_norm + opts.step_tolerance) {
                termination = Termination::StepTolerance;
                stop = self.notify(
                    &IterationSummary {
                        iteration,
                        cost,
                        cost_change: 0.0,
                        gradient_norm: gnorm,
                        step_norm,
                        damping: damping_used,
                        accepted: false,
                        evaluate_seconds: 0.0,
                        solve_seconds,
                        total_seconds: start.elapsed().as_secs_f64(),
                    },
                    &mut log,
                );
                break;
            }
            let t_eval = Instant::now();
            apply_step(problem, ne, step, trial);
            bounds::clamp(problem, trial);
            let new_cost = ne.evaluate(problem, trial, true);
            let actual = cost - new_cost;
            let gain = actual / predicted;
            let accept = new_cost.is_finite()
                && match opts.algorithm {
                    Algorithm::GaussNewton => true,
                    _ => gain > 0.0 && predicted > 0.0,
                };
            if new_cost.is_finite() {
                non_finite_run = 0;
            } else {
                non_finite_steps += 1;
                non_finite_run += 1;
                non_finite_block = ne.first_non_finite();
                tracing::debug!(
                    iteration,
                    block = non_finite_block,
                    "trial point rejected: a residual block is not finite there"
                );
            }
            if accept {
                gn_valid = false;
                problem.values.copy_from_slice(trial);
                ne.assemble();
                step_box = StepBox::new(problem, ne);
                gnorm = gradient_norm(step_box.as_ref(), ne);
                let relative = actual / cost.max(f64::MIN_POSITIVE);
                cost = new_cost;
                match opts.algorithm {
                    Algorithm::LevenbergMarquardt => {
                        mu *= (1.0f64 / 3.0).max(1.0 - (2.0 * gain - 1.0).powi(3));
                        nu = 2.0;
                    }
                    Algorithm::Dogleg => {
                        if gain > 0.75 {
                            radius = radius.max(3.0 * step_norm);
                        } else if gain < 0.25 {
                            radius *= 0.5;
                        }
                    }
                    Algorithm::GaussNewton => {}
                }
                if gnorm <= opts.gradient_tolerance {
                    termination = Termination::GradientTolerance;
                } else if relative.abs() < opts.function_tolerance {
                    termination = Termination::FunctionTolerance;
                }
            } else {
                match opts.algorithm {
                    Algorithm::LevenbergMarquardt => {
                        mu *= nu;
                        nu *= 2.0;
                        if !mu.is_finite() || mu > 1e300 {
                            termination = Termination::NoProgress;
                        }
                    }
                    Algorithm::Dogleg => {
                        radius *= 0.5;
                        if radius < 1e-300
                            || radius <= opts.step_tolerance * (x_norm + opts.step_tolerance)
                        {
                            termination = Termination::NoProgress;
                        }
                    }
                    Algorithm::GaussNewton => {
                        // A non-finite cost after a Gauss-Newton step: keep the last good point.
                        termination = Termination::NoProgress;
                    }
                }
            }
            evaluate_seconds = t_eval.elapsed().as_secs_f64();
            stop = self.notify(
                &IterationSummary {
                    iteration,
                    cost,
                    cost_change: if accept { actual } else { 0.0 },
                    gradient_norm: gnorm,
                    step_norm,
                    damping: damping_used,
                    accepted: accept,
                    evaluate_seconds,
                    solve_seconds,
                    total_seconds: start.elapsed().as_secs_f64(),
                },
                &mut log,
            );
        }
        if stop && termination == Termination::MaxIterations {
            termination = Termination::UserStopped;
        }
        if factor_retries > 0 {
            tracing::debug!(
                factor_retries,
                "damped normal equations not positive definite; retried with more damping"
            );
        }
        if non_finite_run > 0 && termination.converged() {
            // the step shrank only because every trial point was non-finite: not a convergence
            termination = Termination::NoProgress;
        }
        Ok(Summary {
            initial_cost,
            final_cost: cost,
            iterations: log,
            termination,
            total_seconds: start.elapsed().as_secs_f64(),
            unknowns: ne.dim(),
            linear_solver: linear.name(),
            non_finite_steps,
            non_finite_block: if non_finite_run > 0 {
                non_finite_block
            } else {
                None
            },
        })
    }
}

fn rejected(
    iteration: usize,
    cost: f64,
    gnorm: f64,
    damping: f64,
    t_solve: Instant,
    start: Instant,
) -> IterationSummary {
    IterationSummary {
        iteration,
        cost,
        cost_change: 0.0,
        gradient_norm: gnorm,
        step_norm: 0.0,
        damping,
        accepted: false,
        evaluate_seconds: 0.0,
        solve_seconds: t_solve.elapsed().as_secs_f64(),
        total_seconds: start.elapsed().as_secs_f64(),
    }
}

/// max |g_i|, projected onto the bounds where there are any.
fn gradient_norm(step_box: Option<&StepBox>, ne: &NormalEquations) -> f64 {
    match step_box {
        Some(b) => b.projected_gradient_norm(&ne.gradient),
        None => max_abs(&ne.gradient),
    }
}

/// Keeps `step` inside the bounds of the current point (see [`crate::bounds`]); true when it had
/// to be replaced by the box-constrained minimiser.
fn constrain_step(
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
fn model_decrease(ne: &NormalEquations, step: &[f64], scratch: &mut [f64]) -> f64 {
    ne.h.multiply(step, scratch);
    -dot(&ne.gradient, step) - 0.5 * dot(step, scratch)
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0f64, |m, x| m.max(x.abs()))
}

fn negate_into(src: &[f64], dst: &mut [f64]) {
    for (d, s) in dst.iter_mut().zip(src) {
        *d = -s;
    }
}

/// ‖x‖ over the free variables' ambient coordinates.
fn free_norm(problem: &Problem, ne: &NormalEquations) -> f64 {
    ne.var_of_block
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
fn apply_step(problem: &Problem, ne: &NormalEquations, step: &[f64], trial: &mut [f64]) {
    let out = SyncPtr::new(trial);
    ne.var_of_block
        .par_iter()
        .enumerate()
        .with_min_len(256)
        .for_each(|(b, &v)| {
            let var = &problem.variables[v];
            let a = var.manifold.ambient_dim();
            let x = &problem.values[var.offset..var.offset + a];
            // SAFETY: each variable owns its ambient range of `trial`.
            let o = unsafe { out.slice(var.offset, a) };
            var.manifold
                .plus(x, &step[ne.h.block_start[b]..ne.h.block_start[b + 1]], o);
        });
}

/// The Gauss-Newton step −H⁻¹g, minimally regularised where H is singular.
fn gauss_newton_step(
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
    negate_into(&ne.gradient, out);
    linear.solve(ne, out);
}

/// Powell's dogleg step inside `radius` (Madsen et al. 2004, alg. 3.21) from the Gauss-Newton step
/// `gn`; returns the predicted decrease L(0) − L(δ).
fn dogleg_step(
    ne: &NormalEquations,
    gn: &[f64],
    radius: f64,
    step: &mut [f64],
    hg: &mut [f64],
) -> f64 {
    let g = &ne.gradient;
    let g2 = dot(g, g);
    let gn_norm = dot(gn, gn).sqrt();
    if gn_norm <= radius {
        step.copy_from_slice(gn);
    } else {
        ne.h.multiply(g, hg);
        let ghg = dot(g, hg);
        // Cauchy point: −α g with α = ‖g‖² / gᵀHg.
        let alpha = if ghg > 0.0 {
            g2 / ghg
        } else {
            radius / g2.sqrt()
        };
        let sd_norm = alpha * g2.sqrt();
        if sd_norm >= radius {
            let s = radius / g2.sqrt();
            for (d, gi) in step.iter_mut().zip(g) {
                *d = -s * gi;
            }
        } else {
            // δ = a + β(b − a), a = −αg, b = δ_gn, ‖δ‖ = radius
            let (mut ab, mut bb) = (0.0, 0.0);
            for (b, gi) in gn.iter().zip(g) {
                let a = -alpha * gi;
                ab += a * (b - a);
                bb += (b - a) * (b - a);
            }
            let c = alpha * alpha * g2 - radius * radius;
            let root = (ab * ab - bb * c).max(0.0).sqrt();
            let beta = if ab <= 0.0 {
                (-ab + root) / bb
            } else {
                -c / (ab + root)
            };
            for ((d, b), gi) in step.iter_mut().zip(gn).zip(g) {
                let a = -alpha * gi;
                *d = a + beta * (b - a);
            }
        }
    }
    ne.h.multiply(step, hg);
    -dot(g, step) - 0.5 * dot(step, hg)
}
