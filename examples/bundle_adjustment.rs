//! Bundle adjustment of a BAL problem with Levenberg-Marquardt and a Schur-complement solver; prints
//! the iteration table and, last, one JSON line.
//!
//! ```text
//! cargo run --release --example bundle_adjustment -- problem.txt [--huber 1.0]
//!        [--linear-solver schur-dense|schur-sparse|schur-iterative|cholesky] [--max-iterations 50]
//! cargo run --release --example bundle_adjustment     # a generated problem with a known optimum
//! ```
//!
//! Costs are ½ Σ ‖r‖² in pixels (with --huber, ½ Σ ρ(‖r‖²)), as BAL's reference values and Ceres
//! report them; "seconds" times the solve alone, not reading the file.

use anyhow::{bail, Context, Result};
use clap::{Parser, ValueEnum};
use dynamap::residuals::bal::{
    self,
    synthetic::{self, SyntheticOptions},
};
use dynamap::solver::{IterationSummary, LinearSolverKind, Solver};
use std::ops::ControlFlow;
use std::path::PathBuf;

#[derive(Clone, Copy, Debug, ValueEnum)]
enum LinearKind {
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
#[command(version, about)]
struct Args {
    /// The BAL file. Without it, a generated problem with a known optimum (cost 0) is solved.
    problem: Option<PathBuf>,
    /// Huber kernel width in pixels (default: plain least squares).
    #[arg(long)]
    huber: Option<f64>,
    /// Linear solver.
    #[arg(long, value_enum, default_value = "schur-dense")]
    linear_solver: LinearKind,
    /// Iteration limit (accepted and rejected steps both count, as in Ceres).
    #[arg(long, default_value_t = 50)]
    max_iterations: usize,
    /// Worker threads (0: all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Print only the JSON line.
    #[arg(long)]
    quiet: bool,
}

fn main() -> Result<()> {
    let args = Args::parse();
    if let Some(h) = args.huber {
        if !(h > 0.0 && h.is_finite()) {
            bail!("--huber must be a positive number, got {h}");
        }
    }
    if args.threads > 0 {
        rayon::ThreadPoolBuilder::new()
            .num_threads(args.threads)
            .build_global()
            .context("setting the thread count")?;
    }
    let (mut data, name) = match &args.problem {
        Some(path) => (bal::file::read(path)?, path.display().to_string()),
        None => (
            synthetic::generate(&SyntheticOptions::default()).start,
            "generated".to_string(),
        ),
    };
    let mut solve = data.build(args.huber)?;
    let linear_solver = match args.linear_solver {
        LinearKind::SchurDense => LinearSolverKind::SchurDense,
        LinearKind::SchurSparse => LinearSolverKind::SchurSparse,
        LinearKind::SchurIterative => LinearSolverKind::SchurIterative,
        LinearKind::Cholesky => LinearSolverKind::Sparse,
    };
    let options = bal::options(linear_solver, args.max_iterations);
    let quiet = args.quiet;
    if !quiet {
        println!(
            "{}: {} cameras, {} points, {} observations",
            name,
            data.cameras.len(),
            data.points.len(),
            data.observations.len()
        );
        println!("{}", IterationSummary::HEADER);
    }
    let mut solver = Solver::new(options).with_observer(move |it: &IterationSummary| {
        if !quiet {
            println!("{it}");
        }
        ControlFlow::Continue(())
    });
    let summary = solver
        .solve(&mut solve.problem)
        .with_context(|| format!("{name}: bundle adjustment failed"))?;
    data.update_from(&solve);
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
            "huber": args.huber,
            "cameras": data.cameras.len(),
            "points": data.points.len(),
            "observations": data.observations.len(),
            "cost_initial": summary.initial_cost,
            "cost_final": summary.final_cost,
            "iterations": summary.num_iterations(),
            "seconds": summary.total_seconds,
            "threads": rayon::current_num_threads(),
            "termination": summary.termination.to_string(),
        })
    );
    Ok(())
}
