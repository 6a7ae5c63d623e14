//! Bundle adjustment of a BAL problem with Levenberg-Marquardt and a Schur-complement solver; prints
//! the iteration table and, last, one JSON line.
//!
//! ```text
//! cargo run --release --example bundle_adjustment -- problem.txt [--huber 1.0 | --kernel cauchy:1]
//!        [--linear-solver auto|schur-dense|schur-sparse|schur-iterative|cholesky] [--max-iterations 50]
//!        [--pcg-tolerance 1e-6] [--output solved.txt] [--no-retriangulate]
//! cargo run --release --example bundle_adjustment     # a generated problem with a known optimum
//! ```
//!
//! Costs are ½ Σ ‖r‖² in pixels (with a kernel, ½ Σ ρ(‖r‖²)), as BAL's reference values and Ceres
//! report them; "seconds" times the solve alone, not reading the file. The JSON line's "costs" lists
//! the cost after every iteration, the start first (Ceres' `Summary::iterations`).
//!
//! A solve that converges before the iteration limit re-triangulates the points and resumes while
//! that lowers the cost ([`bal::solve_with_restarts`]); the JSON line says how often
//! ("retriangulations") and how many points moved.

use crate::cli;
use crate::iterations;
use crate::preview;

use anyhow::{bail, Context, Result};
use clap::{Parser, ValueEnum};
use cli::{InputError, Session};
use dynamap_residuals::bal::{
    self,
    synthetic::{self, SyntheticOptions},
    BalProblem, Restarts, Retriangulation,
};
use dynamap_solver::robust::NamedKernel;
use dynamap_solver::{LinearSolverKind, Options, Solver, Summary};
use iterations::IterationLog;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Clone, Copy, Debug, ValueEnum)]
enum LinearKind {
    /// Schur complement, the reduced camera system's solver chosen by its size and sparsity:
    /// dense or sparse Cholesky, or conjugate gradients where a sparse factorisation would cost
    /// more than 100 operations per scalar of H_ce.
    Auto,
    /// Schur complement, reduced camera system by dense Cholesky.
    SchurDense,
    /// Schur complement, reduced camera system by sparse Cholesky.
    SchurSparse,
    /// Schur complement by preconditioned conjugate gradients (block-Jacobi, implicit products).
    SchurIterative,
    /// Sparse Cholesky of the full normal equations (no elimination).
    Cholesky,
}

/// Bundle adjustment of a BAL problem.
#[derive(Parser, Debug)]
#[command(version, long_about = None)]
struct Args {
    /// The BAL file. Without it, a generated problem with a known optimum (cost 0) is solved.
    problem: Option<PathBuf>,
    /// Huber kernel width in pixels (the same as --kernel huber:WIDTH) [default: none, plain least
    /// squares].
    #[arg(long, conflicts_with = "kernel")]
    huber: Option<f64>,
    /// A robust kernel on every observation, NAME:SCALE (huber, cauchy, tukey, geman-mcclure,
    /// welsch, fair, dcs), the scale in pixels [default: none].
    #[arg(long, value_name = "NAME:SCALE")]
    kernel: Option<NamedKernel>,
    /// Linear solver.
    #[arg(long, value_enum, default_value = "auto")]
    linear_solver: LinearKind,
    /// Iteration limit (accepted and rejected steps both count, as in Ceres).
    #[arg(long, default_value_t = 50)]
    max_iterations: usize,
    /// schur-iterative: conjugate gradients stop at this residual relative to the right-hand
    /// side [default: the solver's].
    #[arg(long)]
    pcg_tolerance: Option<f64>,
    /// Worker threads (0: all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// A folder for a plot of the cost per iteration (cost.png).
    #[arg(long, value_name = "DIR")]
    preview: Option<PathBuf>,
    /// Do not restart the points from their rays when the solve converges before the iteration
    /// limit (by default each point is re-triangulated with the cameras held, kept where that
    /// lowers its cost, and the solve resumes while that lowers the total by more than the
    /// function tolerance).
    #[arg(long)]
    no_retriangulate: bool,
    /// Write the solved problem here as a BAL file (the observations as read, the cameras and
    /// points as solved), written to a temporary file and renamed.
    #[arg(long, value_name = "FILE")]
    output: Option<PathBuf>,
    #[command(flatten)]
    common: cli::Common,
}

cli::has_common!(Args);

pub fn main() -> ExitCode {
    cli::run(run)
}

/// The BAL file and its name, or the generated problem with its known optimum.
fn load_problem(path: Option<&Path>) -> Result<(BalProblem, String)> {
    Ok(match path {
        Some(path) => (
            bal::file::read(path).bad_input()?,
            path.display().to_string(),
        ),
        None => (
            synthetic::generate(&SyntheticOptions::default()).start,
            "generated".to_string(),
        ),
    })
}

/// `--preview`: the cost per iteration.
fn write_preview(
    dir: &Path,
    args: &Args,
    name: &str,
    summary: &Summary,
    log: &IterationLog,
) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let file = args.problem.as_ref().and_then(|p| p.file_name());
    let title = format!(
        "bundle adjustment: {}",
        file.map_or(name.to_string(), |f| f.to_string_lossy().into_owned())
    );
    preview::cost_plot(
        &dir.join("cost.png"),
        &title,
        &[(summary.linear_solver, log.costs())],
    )
}

/// The solver's settings from the flags: the linear solver, the iteration limit and the
/// conjugate gradients' tolerance.
fn solver_options(args: &Args) -> Result<Options> {
    let linear_solver = match args.linear_solver {
        LinearKind::Auto => LinearSolverKind::Schur,
        LinearKind::SchurDense => LinearSolverKind::SchurDense,
        LinearKind::SchurSparse => LinearSolverKind::SchurSparse,
        LinearKind::SchurIterative => LinearSolverKind::SchurIterative,
        LinearKind::Cholesky => LinearSolverKind::Sparse,
    };
    let mut options = bal::options(linear_solver, args.max_iterations);
    if let Some(t) = args.pcg_tolerance {
        if !(t > 0.0 && t < 1.0) {
            return Err(cli::bad_input(format!(
                "--pcg-tolerance must lie in (0, 1), got {t}"
            )));
        }
        options.pcg_tolerance = t;
    }
    Ok(options)
}

fn solve_once(solver: &mut Solver, solve: &mut bal::BalSolve, name: &str) -> Result<Summary> {
    solver
        .solve(&mut solve.problem)
        .with_context(|| format!("{name}: bundle adjustment failed"))
}

/// The solve, with the points re-triangulated and the solve resumed unless `--no-retriangulate`.
fn solve_all(
    args: &Args,
    quiet: bool,
    solver: &mut Solver,
    data: &mut BalProblem,
    solve: &mut bal::BalSolve,
    name: &str,
) -> Result<(Summary, Restarts)> {
    if args.no_retriangulate {
        return Ok((solve_once(solver, solve, name)?, Restarts::default()));
    }
    let report = |r: &Retriangulation| {
        if !quiet {
            println!(
                "re-triangulated {} points: cost {:.10e} -> {:.10e}; resuming",
                r.points_moved, r.cost_before, r.cost_after
            );
        }
    };
    let kernel = args.kernel.or(args.huber.map(NamedKernel::Huber));
    bal::solve_with_restarts(solver, data, solve, kernel, report)
        .with_context(|| format!("{name}: bundle adjustment failed"))
}

/// The numbers of cameras and points that no observation names (held fixed by
/// [`BalProblem::build`]), warned of when there are any.
fn warn_unobserved(data: &BalProblem, name: &str) -> (usize, usize) {
    let (cameras, points) = data.unobserved();
    let counts = (cameras.len(), points.len());
    if counts != (0, 0) {
        tracing::warn!(
            "{name}: {} cameras and {} points have no observation; they are held where the \
             file puts them (\"unobserved_cameras\", \"unobserved_points\" in the JSON)",
            counts.0,
            counts.1
        );
    }
    counts
}

/// Refuses a Huber scale that is not a positive number and output paths that could not be
/// written, before the problem is read.
fn check_flags(args: &Args) -> Result<()> {
    if let Some(h) = args.huber {
        if !(h > 0.0 && h.is_finite()) {
            return Err(cli::bad_input(format!(
                "--huber must be a positive number, got {h}"
            )));
        }
    }
    let preview = [("--preview", args.preview.as_deref())];
    cli::check_outputs(&[("--output", args.output.as_deref())], &preview)
}

fn run(args: Args, session: &Session) -> Result<()> {
    check_flags(&args)?;
    let kernel = args.kernel.or(args.huber.map(NamedKernel::Huber));
    cli::set_threads(args.threads)?;
    let (mut data, name) = load_problem(args.problem.as_deref())?;
    let (idle_cameras, idle_points) = warn_unobserved(&data, &name);
    let mut solve = data.build(kernel).bad_input()?;
    let options = solver_options(&args)?;
    let quiet = session.quiet;
    if !quiet {
        println!(
            "{}: {} cameras, {} points, {} observations",
            name,
            data.cameras.len(),
            data.points.len(),
            data.observations.len()
        );
    }
    let log = IterationLog::new(session, args.max_iterations);
    let mut solver = Solver::new(options).with_observer(log.observer());
    let (summary, restarts) = solve_all(&args, quiet, &mut solver, &mut data, &mut solve, &name)?;
    log.finish();
    data.update_from(&solve);
    if let Some(out) = &args.output {
        bal::file::write(out, &data)?;
    }
    if let Some(dir) = &args.preview {
        write_preview(dir, &args, &name, &summary, &log)?;
    }
    if !quiet {
        println!(
            "stopped after {} iterations: {}; cost {:.10e} -> {:.10e} in {:.3} s ({} unknowns, {})",
            summary.num_iterations(),
            summary.termination,
            summary.initial_cost,
            summary.final_cost,
            summary.total_seconds,
            summary.unknowns,
            summary.linear_solver
        );
    }
    if args.problem.is_none() && summary.final_cost > 1e-12 {
        bail!(
            "the generated problem's optimum (cost 0) was not reached: cost {:.3e}",
            summary.final_cost
        );
    }
    println!(
        "{}",
        serde_json::json!({
            "solver": "dynamap",
            "problem": name,
            "linear_solver": summary.linear_solver,
            "linear_iterations": summary.linear_iterations,
            "huber": args.huber,
            "kernel": kernel.map(|k| k.to_string()),
            "cameras": data.cameras.len(),
            "points": data.points.len(),
            "observations": data.observations.len(),
            "unobserved_cameras": idle_cameras,
            "unobserved_points": idle_points,
            "cost_initial": summary.initial_cost,
            "cost_final": summary.final_cost,
            "iterations": summary.num_iterations(),
            "seconds": summary.total_seconds,
            "timing": crate::iterations::timing_json(&summary.timing),
            "threads": rayon::current_num_threads(),
            "termination": summary.termination.to_string(),
            "converged": summary.termination.converged(),
            "retriangulations": restarts.rounds,
            "points_retriangulated": restarts.points,
            "retriangulation_seconds": restarts.seconds,
            "costs": summary.iterations.iter().map(|it| it.cost).collect::<Vec<_>>(),
            "seconds_at": summary.iterations.iter().map(|it| it.total_seconds).collect::<Vec<_>>(),
        })
    );
    Ok(())
}
