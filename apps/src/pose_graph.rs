//! Optimise a g2o pose graph (SE2 or SE3) and print an iteration table and, last, one JSON line.
//!
//! ```text
//! cargo run --release --example pose_graph -- GRAPH.g2o --output OUT.g2o [--init file|odometry|chordal]
//!                                          [--algorithm lm|gn|dogleg]
//! cargo run --release --example pose_graph            # a synthetic graph with a known optimum
//! ```
//!
//! chi2 is Σ eᵀΩe with GTSAM's BetweenFactor error e = Log(Z⁻¹ Xi⁻¹ Xj) (see `../shared/bench/peers/chi2.py`);
//! "seconds" times the optimisation alone, not reading, initialisation or writing. With
//! `--kernel NAME:SCALE` every edge is robust; the JSON line's "cost_final" is then ½ Σ ρ(eᵀΩe),
//! the minimised cost, and "costs" lists it after every iteration (chi2 stays the plain sum).
//! An edge whose information matrix is not positive definite is repaired (the nearest
//! positive-definite matrix), warned of by line and counted in "repaired_edges"; `--strict`
//! refuses the file instead.

use crate::cli;
use crate::iterations;
use crate::preview;
use crate::rerun_log;

use anyhow::{bail, Context, Result};
use clap::{Parser, ValueEnum};
use cli::{InputError, Session};
use dynamap_residuals::pose_graph::{
    self,
    g2o::{self, InformationPolicy},
    init,
    synthetic::{self, SyntheticOptions},
    Dimension, Pose, PoseGraph, PoseGraphProblem,
};
use dynamap_solver::robust::NamedKernel;
use dynamap_solver::{Algorithm, DampingKind, Options, SolveError, Solver};
use iterations::IterationLog;
use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
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
#[command(version, long_about = None)]
struct Args {
    /// The g2o file (VERTEX_SE2/EDGE_SE2 or VERTEX_SE3:QUAT/EDGE_SE3:QUAT, or TORO's planar VERTEX2/EDGE2). Without it, a synthetic
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
    #[arg(long, default_value_t = pose_graph::options().max_iterations)]
    max_iterations: usize,
    /// Stop when an accepted step lowers chi2 by less than this fraction.
    #[arg(long, default_value_t = pose_graph::options().function_tolerance)]
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
    /// A robust kernel on every edge, NAME:SCALE (huber, cauchy, tukey, geman-mcclure, welsch,
    /// fair, dcs), the scale in whitened units (√chi2 of an edge) [default: none].
    #[arg(long, value_name = "NAME:SCALE")]
    kernel: Option<NamedKernel>,
    #[command(flatten)]
    rerun: rerun_log::RerunFlags,
    /// A folder for a plot of chi2 per iteration (cost.png).
    #[arg(long, value_name = "DIR")]
    preview: Option<PathBuf>,
    /// Refuse a graph with an information matrix that is not positive definite. Without it, such
    /// a matrix is replaced by the nearest positive-definite one (eigenvalues raised to 1e-9 of
    /// the largest), each such edge named in a warning and counted in the JSON line
    /// ("repaired_edges").
    #[arg(long)]
    strict: bool,
    /// Marginal covariances of these vertices at the optimum (comma-separated ids), in the JSON
    /// line ("covariance"): 3 × 3 for SE(2) in the tangent order [v_x, v_y, ω], 6 × 6 for SE(3)
    /// in [ω; v], the perturbation X Exp(δ) (GTSAM's Marginals). One factorisation of H serves
    /// all of them; each costs a few solves with it.
    #[arg(long, value_delimiter = ',', value_name = "ID,...")]
    covariance: Vec<usize>,
    #[command(flatten)]
    common: cli::Common,
}

cli::has_common!(Args);

/// The graph's vertex positions (in a plane for SE(2)) and its edges as index pairs.
fn layout(
    graph: &dynamap_residuals::pose_graph::PoseGraph,
    poses: &BTreeMap<usize, Pose>,
) -> (Vec<nalgebra::Point3<f64>>, Vec<(usize, usize)>) {
    let index: BTreeMap<usize, usize> = poses.keys().enumerate().map(|(k, &id)| (id, k)).collect();
    let points = poses
        .values()
        .map(|p| match p {
            Pose::Se2(q) => nalgebra::Point3::new(q.translation.x, q.translation.y, 0.0),
            Pose::Se3(q) => q.translation.vector.into(),
        })
        .collect();
    let edges = graph
        .edges
        .iter()
        .filter_map(|e| Some((*index.get(&e.from)?, *index.get(&e.to)?)))
        .collect();
    (points, edges)
}

/// A graph as loaded: the poses of its known optimum (synthetic graphs), and the number of
/// edges whose information matrix was repaired.
struct Loaded {
    graph: PoseGraph,
    truth: Option<BTreeMap<usize, Pose>>,
    repaired: usize,
    /// The graph's connected pieces ([`PoseGraph::components`]).
    components: usize,
}

/// The graph of `--graph` (each repaired information matrix warned of, and counted), or the
/// synthetic sphere with its known optimum.
fn load_graph(args: &Args, quiet: bool) -> Result<Loaded> {
    Ok(match &args.graph {
        Some(path) => {
            let policy = match args.strict {
                true => InformationPolicy::Refuse,
                false => InformationPolicy::Repair,
            };
            let (graph, repairs) = g2o::read_with(path, policy).bad_input()?;
            for r in &repairs {
                tracing::warn!("{}: {r}", path.display());
            }
            let components = graph.components();
            if components > 1 {
                tracing::warn!(
                    "{}: no edge joins the graph's {components} pieces; each is held by its \
                     lowest vertex (\"components\" in the JSON)",
                    path.display()
                );
            }
            Loaded {
                graph,
                truth: None,
                repaired: repairs.len(),
                components,
            }
        }
        None => {
            let s = synthetic::sphere(&SyntheticOptions::default());
            if !quiet {
                println!(
                    "synthetic sphere graph: {} poses, {} edges, exact measurements (optimum chi2 = 0)",
                    s.graph.vertices.len(),
                    s.graph.edges.len()
                );
            }
            Loaded {
                components: s.graph.components(),
                graph: s.graph,
                truth: Some(s.truth),
                repaired: 0,
            }
        }
    })
}

/// The solver's options from the command line.
fn solver_options(args: &Args) -> Options {
    Options {
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
        ..pose_graph::options()
    }
}

/// Refuses flags the solver cannot run with (a NaN or negative tolerance, a damping τ that is
/// not positive), named by the flag, and output paths that could not be written, before the
/// graph is read.
fn check_options(args: &Args) -> Result<()> {
    let preview = [("--preview", args.preview.as_deref())];
    cli::check_outputs(&[("--output", args.output.as_deref())], &preview)?;
    match solver_options(args).check() {
        Err(SolveError::InvalidOption { name, value, must }) => {
            let flag = match name {
                "initial_damping_tau" => "--tau",
                "function_tolerance" => "--function-tolerance",
                other => other,
            };
            Err(cli::bad_input(format!("{flag} {must}, not {value}")))
        }
        other => other.map_err(Into::into),
    }
}

/// A solve's error, as bad input when it names vertices of the file.
fn solve_error(e: SolveError, graph: &PoseGraph, pg: &PoseGraphProblem) -> anyhow::Error {
    match pg.describe(&e, &graph.source) {
        Some(message) => cli::bad_input(message),
        None => e.into(),
    }
}

/// `--covariance`: each named vertex's marginal covariance (row-major) and the seconds they took;
/// an id that is not a vertex, or is held fixed, is a clear error.
fn marginals(args: &Args, graph: &PoseGraph, pg: &PoseGraphProblem) -> Result<serde_json::Value> {
    if args.covariance.is_empty() {
        return Ok(serde_json::Value::Null);
    }
    let clock = Instant::now();
    let vars = args
        .covariance
        .iter()
        .map(|id| match pg.ids.binary_search(id) {
            Ok(k) => Ok(pg.vars[k]),
            Err(_) => Err(cli::bad_input(format!(
                "--covariance: {} has no vertex {id}",
                graph.source
            ))),
        })
        .collect::<Result<Vec<_>>>()?;
    let matrices = dynamap_solver::covariance(&pg.problem, &vars)
        .map_err(|e| cli::bad_input(format!("--covariance: {}: {e}", graph.source)))?;
    let blocks: Vec<_> = args
        .covariance
        .iter()
        .zip(&matrices)
        .map(|(id, m)| {
            let rows: Vec<Vec<f64>> = m.row_iter().map(|r| r.iter().copied().collect()).collect();
            serde_json::json!({ "vertex": id, "matrix": rows })
        })
        .collect();
    Ok(serde_json::json!({ "seconds": clock.elapsed().as_secs_f64(), "blocks": blocks }))
}

/// `--preview`: chi2 per iteration.
fn write_preview(dir: &Path, args: &Args, log: &IterationLog) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let chi2: Vec<(usize, f64)> = log.costs().iter().map(|&(i, c)| (i, 2.0 * c)).collect();
    let name = args.graph.as_ref().and_then(|p| p.file_name());
    let title = format!(
        "pose graph: {}",
        name.map_or("synthetic".into(), |f| f.to_string_lossy())
    );
    preview::cost_plot(&dir.join("cost.png"), &title, &[("chi2 = 2 cost", chi2)])?;
    Ok(())
}

/// Opens the recording of `--rerun` (if any) and logs the graph at the start to it.
fn log_before(
    args: &Args,
    graph: &PoseGraph,
    start: &BTreeMap<usize, Pose>,
) -> Result<rerun_log::Recorder> {
    let rec = rerun_log::Recorder::open(&args.rerun, "dynamap pose_graph")?;
    if rec.enabled() {
        let (points, edges) = layout(graph, start);
        rec.at("iteration", 0);
        rec.graph("world/before", &points, &edges)?;
    }
    Ok(rec)
}

/// Logs chi2 per iteration and the graph after the solve to the recording.
fn log_after(
    rec: &rerun_log::Recorder,
    log: &IterationLog,
    graph: &PoseGraph,
    poses: &BTreeMap<usize, Pose>,
) -> Result<()> {
    for (i, cost) in log.costs() {
        rec.at("iteration", i);
        rec.scalar("solver/chi2", 2.0 * cost)?;
    }
    let (points, edges) = layout(graph, poses);
    rec.graph("world/after", &points, &edges)?;
    rec.flush()
}

/// The poses the solve starts from: the file's (not copied), or by odometry or chordal
/// relaxation.
fn initial_poses(graph: &PoseGraph, init_kind: InitKind) -> Result<Cow<'_, BTreeMap<usize, Pose>>> {
    let from = match init_kind {
        InitKind::File => init::Start::File,
        InitKind::Odometry => init::Start::Odometry,
        InitKind::Chordal => init::Start::Chordal,
    };
    init::start(graph, from)
        .map_err(anyhow::Error::msg)
        .bad_input()
}

/// The synthetic graph's solution against its known optimum: an error when it was not recovered.
fn check_optimum(
    poses: &BTreeMap<usize, Pose>,
    truth: &BTreeMap<usize, Pose>,
    quiet: bool,
) -> Result<()> {
    let (dt, dr) = synthetic::max_pose_error(poses, truth);
    if !quiet {
        println!("largest error against the known optimum: {dt:.3e} m, {dr:.3e} rad");
    }
    if dt > 1e-6 || dr > 1e-6 {
        bail!("the synthetic graph's optimum was not recovered ({dt:.3e} m, {dr:.3e} rad)");
    }
    Ok(())
}

pub fn main() -> ExitCode {
    cli::run(run)
}

fn run(args: Args, session: &Session) -> Result<()> {
    let quiet = session.quiet;
    cli::set_threads(args.threads)?;
    check_options(&args)?;
    let Loaded {
        graph,
        truth,
        repaired,
        components,
    } = load_graph(&args, quiet)?;
    let t_init = Instant::now();
    let start = initial_poses(&graph, args.init)?;
    let init_seconds = t_init.elapsed().as_secs_f64();
    let mut pg = graph
        .build_robust_problem(&start, args.kernel)
        .map_err(anyhow::Error::msg)
        .bad_input()?;
    // with a kernel the problem's cost is no longer ½ chi2
    let chi2_initial = match args.kernel {
        None => 2.0 * pg.problem.cost(),
        Some(_) => graph.chi2(&start),
    };
    let options = solver_options(&args);
    let rec = log_before(&args, &graph, &start)?;
    let log = IterationLog::new(session, args.max_iterations);
    let mut solver = Solver::new(options).with_observer(log.observer());
    let solved = solver.solve(&mut pg.problem);
    log.finish();
    // its factorisation and buffers are not needed for what follows (and would add to the peak)
    drop(solver);
    let summary = solved.map_err(|e| solve_error(e, &graph, &pg))?;
    let poses = pg.poses();
    let chi2_final = graph.chi2(&poses);
    if rec.enabled() {
        log_after(&rec, &log, &graph, &poses)?;
    }
    if let Some(dir) = &args.preview {
        write_preview(dir, &args, &log)?;
    }
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
        check_optimum(&poses, truth, quiet)?;
    }
    if let Some(out) = &args.output {
        g2o::write(out, &graph, &poses)?;
    }
    let covariance = marginals(&args, &graph, &pg)?;
    println!(
        "{}",
        serde_json::json!({
            "solver": "dynamap",
            "graph": args.graph.as_ref().map(|p| p.display().to_string()).unwrap_or_else(|| "synthetic".into()),
            "dimension": match graph.dimension { Dimension::Two => 2, Dimension::Three => 3 },
            "init": format!("{:?}", args.init).to_lowercase(),
            "chi2_initial": chi2_initial,
            "chi2_final": chi2_final,
            "kernel": args.kernel.map(|k| k.to_string()),
            "cost_initial": summary.initial_cost,
            "cost_final": summary.final_cost,
            "converged": summary.termination.converged(),
            "costs": summary.iterations.iter().map(|it| it.cost).collect::<Vec<_>>(),
            "iterations": summary.num_iterations(),
            "seconds": summary.total_seconds,
            "timing": iterations::timing_json(&summary.timing),
            "init_seconds": init_seconds,
            "termination": summary.termination.to_string(),
            "repaired_edges": repaired,
            "components": components,
            "covariance": covariance,
        })
    );
    Ok(())
}
