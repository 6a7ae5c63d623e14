//! Optimise a g2o pose graph (SE2 or SE3) and print an iteration table and, last, one JSON line.
//!
//! ```text
//! cargo run --release --example pose_graph -- GRAPH.g2o --output OUT.g2o [--init file|odometry|chordal]
//!                                          [--algorithm lm|gn|dogleg]
//! cargo run --release --example pose_graph            # a synthetic graph with a known optimum
//! ```
//!
//! chi2 is Σ eᵀΩe with GTSAM's BetweenFactor error e = Log(Z⁻¹ Xi⁻¹ Xj) (see `../shared/bench/peers/chi2.py`);
//! "seconds" times the optimisation alone, not reading, initialisation or writing.

use anyhow::{bail, Context, Result};
use clap::{Parser, ValueEnum};
use dynamap::residuals::pose_graph::{
    g2o, init,
    synthetic::{self, SyntheticOptions},
    Dimension, Pose,
};
use dynamap::solver::{Algorithm, DampingKind, IterationSummary, Options, SolveError, Solver};
use std::collections::BTreeMap;
use std::ops::ControlFlow;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Clone, Copy, Debug, ValueEnum)]
enum InitKind {
    /// The vertices in the file.
    File,
    /// Compose measurements along a spanning tree from the anchor.
    Odometry,
    /// Chordal relaxation of rotations, then translations.
    Chordal,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum AlgorithmKind {
    /// Levenberg-Marquardt.
    Lm,
    /// Gauss-Newton.
    Gn,
    /// Powell's dogleg.
    Dogleg,
}

/// Optimise a pose graph in g2o format.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    /// The g2o file (VERTEX_SE2/EDGE_SE2 or VERTEX_SE3:QUAT/EDGE_SE3:QUAT). Without it, a synthetic
    /// sphere graph with a known optimum is generated and solved.
    graph: Option<PathBuf>,
    /// Where to write the optimised graph (g2o, written through a temporary file).
    #[arg(long)]
    output: Option<PathBuf>,
    /// Initial guess.
    #[arg(long, value_enum, default_value = "file")]
    init: InitKind,
    /// Minimiser (dogleg by default: it reaches every reference optimum from the file start, where
    /// LM with the thesis' damping stalls on M3500 and MIT).
    #[arg(long, value_enum, default_value = "dogleg")]
    algorithm: AlgorithmKind,
    /// Iteration limit.
    #[arg(long, default_value_t = 100)]
    max_iterations: usize,
    /// Stop when an accepted step lowers chi2 by less than this fraction.
    #[arg(long, default_value_t = 1e-9)]
    function_tolerance: f64,
    /// Levenberg-Marquardt: initial damping μ₀ = tau · max diag(JᵀJ) (μ₀ = tau with
    /// --diagonal-damping).
    #[arg(long, default_value_t = Options::default().initial_damping_tau)]
    tau: f64,
    /// Levenberg-Marquardt: damp with μ·diag(JᵀJ) instead of μ·I.
    #[arg(long)]
    diagonal_damping: bool,
    /// Worker threads (0: all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Print only the JSON line.
    #[arg(long)]
    quiet: bool,
}

fn main() -> Result<()> {
    let args = Args::parse();
    if args.threads > 0 {
        rayon::ThreadPoolBuilder::new()
            .num_threads(args.threads)
            .build_global()
            .context("setting up the thread pool")?;
    }
    let (graph, truth) = match &args.graph {
        Some(path) => (g2o::read(path)?, None),
        None => {
            let s = synthetic::sphere(&SyntheticOptions::default());
            if !args.quiet {
                println!(
                    "synthetic sphere graph: {} poses, {} edges, exact measurements (optimum chi2 = 0)",
                    s.graph.vertices.len(),
                    s.graph.edges.len()
                );
            }
            (s.graph, Some(s.truth))
        }
    };
    let t_init = Instant::now();
    let start: BTreeMap<usize, Pose> = match args.init {
        InitKind::File => graph.vertices.clone(),
        InitKind::Odometry => init::odometry(&graph).map_err(anyhow::Error::msg)?,
        InitKind::Chordal => init::chordal(&graph).map_err(anyhow::Error::msg)?,
    };
    let init_seconds = t_init.elapsed().as_secs_f64();
    let mut pg = graph.build_problem(&start).map_err(anyhow::Error::msg)?;
    let chi2_initial = 2.0 * pg.problem.cost();
    let options = Options {
        algorithm: match args.algorithm {
            AlgorithmKind::Lm => Algorithm::LevenbergMarquardt,
            AlgorithmKind::Gn => Algorithm::GaussNewton,
            AlgorithmKind::Dogleg => Algorithm::Dogleg,
        },
        max_iterations: args.max_iterations,
        function_tolerance: args.function_tolerance,
        initial_damping_tau: args.tau,
        damping: if args.diagonal_damping {
            DampingKind::Diagonal
        } else {
            DampingKind::Identity
        },
        ..Options::default()
    };
    let quiet = args.quiet;
    if !quiet {
        println!("{}", IterationSummary::HEADER);
    }
    let mut solver = Solver::new(options).with_observer(move |it: &IterationSummary| {
        if !quiet {
            println!("{it}");
        }
        ControlFlow::Continue(())
    });
    let summary = match solver.solve(&mut pg.problem) {
        Ok(s) => s,
        Err(SolveError::UntouchedVariable(v)) => {
            bail!(
                "{}: vertex {} is touched by no edge",
                graph.source,
                pg.ids[v]
            )
        }
        Err(SolveError::RankDeficient {
            message, variables, ..
        }) => {
            let names: Vec<String> = variables
                .iter()
                .take(12)
                .map(|&v| pg.ids[v].to_string())
                .collect();
            bail!(
                "{}: {message} (vertices {})",
                graph.source,
                names.join(", ")
            )
        }
        Err(e) => return Err(e.into()),
    };
    let poses = pg.poses();
    let chi2_final = graph.chi2(&poses);
    if !quiet {
        println!(
            "stopped: {}; chi2 {:.10e} -> {:.10e}; {} iterations, {:.4} s ({} unknowns, {} Cholesky); init {:.4} s",
            summary.termination,
            chi2_initial,
            chi2_final,
            summary.num_iterations(),
            summary.total_seconds,
            summary.unknowns,
            summary.linear_solver,
            init_seconds
        );
    }
    if let Some(truth) = &truth {
        let (dt, dr) = synthetic::max_pose_error(&poses, truth);
        if !quiet {
            println!("largest error against the known optimum: {dt:.3e} m, {dr:.3e} rad");
        }
        if dt > 1e-6 || dr > 1e-6 {
            bail!("the synthetic graph's optimum was not recovered ({dt:.3e} m, {dr:.3e} rad)");
        }
    }
    if let Some(out) = &args.output {
        g2o::write(out, &graph, &poses)?;
    }
    println!(
        "{}",
        serde_json::json!({
            "solver": "dynamap",
            "graph": args.graph.as_ref().map(|p| p.display().to_string()).unwrap_or_else(|| "synthetic".into()),
            "dimension": match graph.dimension { Dimension::Two => 2, Dimension::Three => 3 },
            "init": format!("{:?}", args.init).to_lowercase(),
            "chi2_initial": chi2_initial,
            "chi2_final": chi2_final,
            "iterations": summary.num_iterations(),
            "seconds": summary.total_seconds,
            "init_seconds": init_seconds,
            "termination": summary.termination.to_string(),
        })
    );
    Ok(())
}
