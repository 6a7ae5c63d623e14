//! The minimisers: Gauss-Newton, Levenberg-Marquardt and Powell's dogleg over a [`Problem`].
//!
//! Levenberg-Marquardt follows Madsen, Nielsen & Tingleff, *Methods for Non-Linear Least Squares
//! Problems* (2004), alg. 3.16: initial damping μ₀ = τ max diag(JᵀJ) (the thesis' eq. 2.17), gain
//! ratio ρ = (F(x) − F(x+δ)) / (L(0) − L(δ)), and Nielsen's update ([`crate::LevenbergDamping`]).
//! The dogleg follows the same text, alg. 3.21. Each method lives in its own module behind
//! [`method::Method`]; this module holds the loop they share: propose a step, test it for
//! convergence, evaluate the trial point, take or reject it, report the iteration.

mod context;
mod dogleg;
mod gauss_newton;
mod levenberg_marquardt;
mod method;
mod vector;

use crate::bounds::{self, StepBox};
use crate::diagnose;
use crate::error::SolveError;
use crate::linear::LinearSolver;
use crate::normal::NormalEquations;
use crate::options::{Algorithm, DampingKind, Options};
use crate::parallel::dot;
use crate::problem::Problem;
use crate::schur::SchurOptions;
use crate::summary::{IterationSummary, Observer, Summary, Termination, Timing};
use context::{Context, Proposal};
use method::Method;
use std::ops::ControlFlow;
use std::time::Instant;
use vector::{apply_step, free_norm, gradient_norm};

/// Buffers kept between solves of problems with the same structure.
struct Workspace {
    key: (u64, u64),
    ne: NormalEquations,
    linear: LinearSolver,
    trial: Vec<f64>,
    step: Vec<f64>,
    scratch: Vec<f64>,
    /// The dogleg's Gauss-Newton step (its buffer, lent to [`Dogleg`] during a solve).
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
        let ne = if self.options.linear_solver.is_schur() {
            // a box-constrained step reads H whole, the coupling blocks included
            let bounded = problem.variables.iter().any(|v| v.bounds.is_some());
            NormalEquations::with_elimination(problem, &self.options.elimination, bounded)?
        } else {
            NormalEquations::new(problem)?
        };
        let linear = LinearSolver::new(
            &ne,
            self.options.linear_solver,
            self.options.dense_threshold,
            SchurOptions {
                pcg_tolerance: self.options.pcg_tolerance,
                pcg_max_iterations: self.options.pcg_max_iterations,
                pcg_forcing: self.options.pcg_forcing,
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
        self.options.check()?;
        let clock = Instant::now();
        let mut ws = self.prepare(problem)?;
        let result = self.run(problem, &mut ws, clock);
        self.workspace = Some(ws);
        result
    }

    /// Runs the minimiser on a prepared workspace (prepared since `clock`): the start point, the
    /// iterations, the summary.
    fn run(
        &mut self,
        problem: &mut Problem,
        ws: &mut Workspace,
        clock: Instant,
    ) -> Result<Summary, SolveError> {
        let opts = self.options.clone();
        let (mut run, mut step_box) = self.start(problem, ws, &opts, clock)?;
        let mut method = Method::new(&opts, run.max_diag, &mut ws.gauss_newton);
        let outcome = self.iterations(problem, ws, &mut method, &mut step_box, &mut run);
        // the dogleg's buffer goes back to the workspace whether or not the loop failed
        if let Some(buffer) = method.finish() {
            ws.gauss_newton = buffer;
        }
        outcome?;
        Ok(run.summary(&ws.ne, &ws.linear))
    }

    /// Iterates until a stopping test, the iteration or time limit, or the observer ends it.
    fn iterations(
        &mut self,
        problem: &mut Problem,
        ws: &mut Workspace,
        method: &mut Method,
        step_box: &mut Option<StepBox>,
        run: &mut Run,
    ) -> Result<(), SolveError> {
        let (max_iterations, max_seconds) = (self.options.max_iterations, self.options.max_seconds);
        let mut iteration = 0;
        while !run.stop
            && run.termination == Termination::MaxIterations
            && iteration < max_iterations
        {
            iteration += 1;
            if run.start.elapsed().as_secs_f64() > max_seconds {
                run.termination = Termination::TimeLimit;
                break;
            }
            if self
                .iterate(problem, ws, method, step_box, run, iteration)?
                .is_break()
            {
                break;
            }
        }
        Ok(())
    }

    /// Evaluates the start point, checks its rank where asked and reports it as iteration 0.
    fn start(
        &mut self,
        problem: &Problem,
        ws: &mut Workspace,
        opts: &Options,
        clock: Instant,
    ) -> Result<(Run, Option<StepBox>), SolveError> {
        let mut timing = Timing {
            setup: clock.elapsed().as_secs_f64(),
            ..Timing::default()
        };
        let Workspace {
            ne, linear, trial, ..
        } = ws;
        trial.copy_from_slice(&problem.values);
        let t0 = Instant::now();
        let cost = ne.evaluate(problem, &problem.values, true);
        if !cost.is_finite() {
            return Err(SolveError::NonFiniteInitialCost(
                ne.first_non_finite().unwrap_or(0),
            ));
        }
        timing.evaluate = t0.elapsed().as_secs_f64();
        ne.assemble();
        let marquardt = opts.algorithm == Algorithm::LevenbergMarquardt
            && opts.damping == DampingKind::Diagonal;
        ne.fix_damping_scale(marquardt);
        let evaluate_seconds = t0.elapsed().as_secs_f64();
        timing.assemble = evaluate_seconds - timing.evaluate;
        let t_rank = Instant::now();
        if opts.check_rank && diagnose::has_unanchored_component(problem, ne) {
            diagnose::check_rank(problem, ne, linear)?;
        }
        // the rank diagnosis (its factorisations and solves included) counts as setup
        timing.setup += t_rank.elapsed().as_secs_f64();
        // The step's box moves with the current point only: rebuilt when a step is accepted.
        let step_box = StepBox::new(problem, ne);
        if step_box.is_some() && opts.algorithm == Algorithm::Dogleg {
            return Err(SolveError::Bounds(
                "the dogleg does not take bounds; use Levenberg-Marquardt or Gauss-Newton".into(),
            ));
        }
        let gnorm = gradient_norm(step_box.as_ref(), ne);
        let max_diag = ne.h().diagonal().fold(0.0f64, f64::max);
        let mut run = Run::new(clock, cost, gnorm, max_diag);
        run.timing = timing;
        run.factor_seconds = linear.factor_seconds();
        let first = run.iteration(0, 0.0, 0.0, 0.0, true, evaluate_seconds, 0.0);
        self.record(&mut run, first);
        run.termination = if run.stop {
            Termination::UserStopped
        } else if gnorm <= opts.gradient_tolerance {
            Termination::GradientTolerance
        } else {
            Termination::MaxIterations
        };
        Ok((run, step_box))
    }

    /// One iteration: a step from the method, the step-size test, the trial point's cost, and
    /// the step taken or rejected. Breaks when the loop must end at once.
    fn iterate(
        &mut self,
        problem: &mut Problem,
        ws: &mut Workspace,
        method: &mut Method,
        step_box: &mut Option<StepBox>,
        run: &mut Run,
        iteration: usize,
    ) -> Result<ControlFlow<()>, SolveError> {
        let opts = &self.options;
        let t_solve = Instant::now();
        let ctx = Context {
            problem,
            ne: &ws.ne,
            linear: &mut ws.linear,
            step_box: step_box.as_ref(),
            step: &mut ws.step,
            scratch: &mut ws.scratch,
            max_diag: run.max_diag,
        };
        let (predicted, damping) = match method.propose(ctx, opts)? {
            Proposal::Step { predicted, damping } => (predicted, damping),
            Proposal::Exhausted { damping } => {
                run.termination = Termination::NoProgress;
                let solve = run.linear_time(t_solve, ws.linear.factor_seconds());
                let it = run.iteration(iteration, 0.0, 0.0, damping, false, 0.0, solve);
                self.record(run, it);
                return Ok(ControlFlow::Continue(()));
            }
        };
        let solve_seconds = run.linear_time(t_solve, ws.linear.factor_seconds());
        let step_norm = dot(&ws.step, &ws.step).sqrt();
        let step_floor = opts.step_tolerance * (free_norm(problem, &ws.ne) + opts.step_tolerance);
        if step_norm <= step_floor {
            run.termination = Termination::StepTolerance;
            let it = run.iteration(
                iteration,
                0.0,
                step_norm,
                damping,
                false,
                0.0,
                solve_seconds,
            );
            self.record(run, it);
            return Ok(ControlFlow::Break(()));
        }
        let t_eval = Instant::now();
        let Workspace {
            ne, step, trial, ..
        } = ws;
        apply_step(problem, ne, step, trial);
        bounds::clamp(problem, trial);
        let new_cost = ne.evaluate(problem, trial, true);
        run.timing.evaluate += t_eval.elapsed().as_secs_f64();
        let actual = run.cost - new_cost;
        let gain = actual / predicted;
        let accept = new_cost.is_finite() && method.takes(gain, predicted);
        run.non_finite.count(new_cost, ne, iteration);
        settle(problem, ne, (trial, new_cost), accept, run, step_box, opts);
        if accept {
            method.taken(gain, step_norm);
        } else if method.rejected(step_floor) {
            run.termination = Termination::NoProgress;
        }
        let change = if accept { actual } else { 0.0 };
        let evaluate_seconds = t_eval.elapsed().as_secs_f64();
        let it = run.iteration(
            iteration,
            change,
            step_norm,
            damping,
            accept,
            evaluate_seconds,
            solve_seconds,
        );
        self.record(run, it);
        Ok(ControlFlow::Continue(()))
    }

    /// Logs an iteration, passes it to the observer and notes whether the observer stops.
    fn record(&mut self, run: &mut Run, it: IterationSummary) {
        tracing::trace!(
            iteration = it.iteration,
            cost = it.cost,
            gradient = it.gradient_norm,
            damping = it.damping,
            accepted = it.accepted,
            "solver iteration"
        );
        let stop = match &mut self.observer {
            Some(o) => o(&it).is_break(),
            None => false,
        };
        run.log.push(it);
        run.stop = stop;
    }
}

/// Trial points whose cost was not finite: in all, in a row, and the last block that gave one.
#[derive(Default)]
struct NonFinite {
    steps: usize,
    run: usize,
    block: Option<usize>,
}

impl NonFinite {
    /// Counts the trial point of cost `cost`.
    fn count(&mut self, cost: f64, ne: &NormalEquations, iteration: usize) {
        if cost.is_finite() {
            self.run = 0;
            return;
        }
        self.steps += 1;
        self.run += 1;
        self.block = ne.first_non_finite();
        tracing::debug!(
            iteration,
            block = self.block,
            "trial point rejected: a residual block is not finite there"
        );
    }
}

/// The shared loop's state.
struct Run {
    start: Instant,
    initial_cost: f64,
    cost: f64,
    gnorm: f64,
    /// max diag H at the start point (the scale of the minimal regularisations).
    max_diag: f64,
    termination: Termination,
    stop: bool,
    log: Vec<IterationSummary>,
    non_finite: NonFinite,
    timing: Timing,
    /// The linear solver's [`LinearSolver::factor_seconds`] at the last reading.
    factor_seconds: f64,
}

impl Run {
    /// Adds a step's linear algebra since `since` (whose factorisations brought the solver's
    /// factorisation clock to `factor_seconds`) to the timing, and returns its seconds.
    fn linear_time(&mut self, since: Instant, factor_seconds: f64) -> f64 {
        let seconds = since.elapsed().as_secs_f64();
        let factorise = factor_seconds - self.factor_seconds;
        self.factor_seconds = factor_seconds;
        self.timing.factorise += factorise;
        self.timing.step += (seconds - factorise).max(0.0);
        seconds
    }

    fn new(start: Instant, cost: f64, gnorm: f64, max_diag: f64) -> Self {
        Self {
            start,
            initial_cost: cost,
            cost,
            gnorm,
            max_diag,
            termination: Termination::MaxIterations,
            stop: false,
            log: Vec::new(),
            non_finite: NonFinite::default(),
            timing: Timing::default(),
            factor_seconds: 0.0,
        }
    }

    /// The point moved to cost `cost` with gradient norm `gnorm`: the gradient and relative
    /// decrease tests.
    fn moved(&mut self, cost: f64, gnorm: f64, opts: &Options) {
        let relative = (self.cost - cost) / self.cost.max(f64::MIN_POSITIVE);
        self.cost = cost;
        self.gnorm = gnorm;
        if gnorm <= opts.gradient_tolerance {
            self.termination = Termination::GradientTolerance;
        } else if relative.abs() < opts.function_tolerance {
            self.termination = Termination::FunctionTolerance;
        }
    }

    /// The summary of an iteration ending at the current cost and gradient.
    #[allow(clippy::too_many_arguments)]
    fn iteration(
        &self,
        iteration: usize,
        cost_change: f64,
        step_norm: f64,
        damping: f64,
        accepted: bool,
        evaluate_seconds: f64,
        solve_seconds: f64,
    ) -> IterationSummary {
        IterationSummary {
            iteration,
            cost: self.cost,
            cost_change,
            gradient_norm: self.gnorm,
            step_norm,
            damping,
            accepted,
            evaluate_seconds,
            solve_seconds,
            total_seconds: self.start.elapsed().as_secs_f64(),
        }
    }

    /// The solve's summary; a stop by the observer and a convergence reached only through
    /// non-finite trial points are named as such.
    fn summary(mut self, ne: &NormalEquations, linear: &LinearSolver) -> Summary {
        if self.stop && self.termination == Termination::MaxIterations {
            self.termination = Termination::UserStopped;
        }
        let stuck = self.non_finite.run > 0;
        if stuck && self.termination.converged() {
            // the step shrank only because every trial point was non-finite: not a convergence
            self.termination = Termination::NoProgress;
        }
        Summary {
            initial_cost: self.initial_cost,
            final_cost: self.cost,
            iterations: self.log,
            termination: self.termination,
            total_seconds: self.start.elapsed().as_secs_f64(),
            timing: self.timing,
            unknowns: ne.dim(),
            linear_solver: linear.name(),
            linear_iterations: linear.iterations(),
            non_finite_steps: self.non_finite.steps,
            non_finite_block: if stuck { self.non_finite.block } else { None },
        }
    }
}

/// Moves to the trial point (`trial` values at cost `cost`) and assembles there when `accept`;
/// otherwise, where solves read the Jacobian buffer, restores the current point's Jacobians,
/// which the trial's evaluation replaced.
fn settle(
    problem: &mut Problem,
    ne: &mut NormalEquations,
    (trial, cost): (&[f64], f64),
    accept: bool,
    run: &mut Run,
    step_box: &mut Option<StepBox>,
    opts: &Options,
) {
    if accept {
        problem.values.copy_from_slice(trial);
        let t_assemble = Instant::now();
        ne.assemble();
        run.timing.assemble += t_assemble.elapsed().as_secs_f64();
        *step_box = StepBox::new(problem, ne);
        run.moved(cost, gradient_norm(step_box.as_ref(), ne), opts);
    } else if ne.reads_jacobians() {
        ne.evaluate(problem, &problem.values, true);
    }
}
