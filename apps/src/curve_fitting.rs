//! Fit y = exp(m x + c) to data with 20 % gross outliers, once with plain least squares and once
//! with a Cauchy kernel: the solver serves problems other than SLAM.
//!
//! ```text
//! cargo run --release --example curve_fitting [-- --points 200 --outliers 0.2 --seed 1]
//! cargo run --release --example curve_fitting -- --data points.txt     # "x y" a line
//! ```
//! Prints both estimates against the true (m, c) and, last, one JSON line with each fit's
//! estimate, iterations, final cost and solve seconds.

use crate::cli;
use crate::iterations;
use crate::preview;

use anyhow::{Context, Result};
use clap::Parser;
use cli::Session;
use dynamap_residuals::text::without_bom;
use dynamap_solver::robust::Cauchy;
use dynamap_solver::{AutoDiff, CostFunctor, Euclidean, Options, Problem, Real, Solver};
use iterations::IterationLog;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::path::PathBuf;
use std::process::ExitCode;

/// r = y − exp(m x + c) for one observation.
struct Exponential {
    x: f64,
    y: f64,
}

impl CostFunctor for Exponential {
    fn parameter_sizes(&self) -> &[usize] {
        &[2]
    }
    fn evaluate<T: Real>(&self, p: &[&[T]], r: &mut [T]) {
        r[0] = -(p[0][0] * self.x + p[0][1]).exp() + self.y;
    }
}

/// Robust curve fitting demo.
#[derive(Parser, Debug)]
#[command(long_about = None)]
struct Args {
    /// Number of observations.
    #[arg(long, default_value_t = 200)]
    points: usize,
    /// Fraction of gross outliers.
    #[arg(long, default_value_t = 0.2)]
    outliers: f64,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Fit these observations instead of generated ones: "x y" a line, '#' starts a comment
    /// (--points, --outliers and --seed are then unused).
    #[arg(long, value_name = "FILE")]
    data: Option<PathBuf>,
    /// A folder for a plot of both fits' cost per iteration (cost.png).
    #[arg(long, value_name = "DIR")]
    preview: Option<PathBuf>,
    #[command(flatten)]
    common: cli::Common,
}

cli::has_common!(Args);

/// A fit: the estimate (m, c), the iterations taken, the cost per iteration, the final cost and
/// the solve's seconds.
struct Fit {
    estimate: [f64; 2],
    iterations: usize,
    costs: Vec<(usize, f64)>,
    cost: f64,
    seconds: f64,
}

/// Fits (m, c), with or without the Cauchy kernel.
fn fit(data: &[(f64, f64)], robust: bool, session: &Session) -> Result<Fit> {
    let mut problem = Problem::new();
    let mc = problem.add_variable(&[0.0, 0.0], Euclidean::<2>)?;
    for &(x, y) in data {
        let r = AutoDiff::<_, 1, 2>::new(Exponential { x, y });
        if robust {
            problem.add_robust_residual(r, Cauchy(0.1), &[mc])?;
        } else {
            problem.add_residual(r, &[mc])?;
        }
    }
    let options = Options::default();
    let log = IterationLog::new(session, options.max_iterations);
    let summary = Solver::new(options)
        .with_observer(log.observer())
        .solve(&mut problem)?;
    log.finish();
    let v = problem.value(mc);
    Ok(Fit {
        estimate: [v[0], v[1]],
        iterations: summary.num_iterations(),
        costs: log.costs(),
        cost: summary.final_cost,
        seconds: summary.total_seconds,
    })
}

/// Observations from a file of "x y" lines; a line that is not two finite numbers is an error
/// naming the file and line.
fn read_data(path: &std::path::Path) -> Result<Vec<(f64, f64)>> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| cli::bad_input(format!("{}: cannot read: {e}", path.display())))?;
    let mut data = Vec::new();
    for (k, line) in without_bom(&text).lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let v: Result<Vec<f64>, _> = line.split_whitespace().map(str::parse).collect();
        match v.as_deref() {
            Ok(&[x, y]) if x.is_finite() && y.is_finite() => data.push((x, y)),
            _ => {
                return Err(cli::bad_input(format!(
                    "{}:{}: expected two finite numbers, x and y",
                    path.display(),
                    k + 1
                )))
            }
        }
    }
    if data.len() < 2 {
        return Err(cli::bad_input(format!(
            "{}: at least two observations are needed",
            path.display()
        )));
    }
    Ok(data)
}

/// `--points` observations of exp(m x + c) on [0, 5) with noise σ = 0.02, a fraction
/// `--outliers` of them replaced by uniform values in [0, 8).
fn generate(args: &Args, m: f64, c: f64) -> Result<Vec<(f64, f64)>> {
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let noise = Normal::new(0.0, 0.02)?;
    Ok((0..args.points)
        .map(|i| {
            let x = 5.0 * i as f64 / args.points as f64;
            let y = if rng.random::<f64>() < args.outliers {
                rng.random::<f64>() * 8.0
            } else {
                (m * x + c).exp() + noise.sample(&mut rng)
            };
            (x, y)
        })
        .collect())
}

/// The most observations `--points` generates: a residual block each, a few hundred bytes; 10⁹
/// of them were killed for memory.
const MAX_POINTS: usize = 10_000_000;

pub fn main() -> ExitCode {
    cli::run(run)
}

fn run(args: Args, session: &Session) -> Result<()> {
    if !(0.0..1.0).contains(&args.outliers) || !(2..=MAX_POINTS).contains(&args.points) {
        return Err(cli::bad_input(format!(
            "--outliers must be in [0, 1) and --points between 2 and {MAX_POINTS}"
        )));
    }
    let (m, c) = (0.3, 0.1);
    let data = match &args.data {
        Some(path) => read_data(path)?,
        None => generate(&args, m, c)?,
    };
    let plain_fit = fit(&data, false, session)?;
    let robust_fit = fit(&data, true, session)?;
    let (plain, it_plain) = (plain_fit.estimate, plain_fit.iterations);
    let (robust, it_robust) = (robust_fit.estimate, robust_fit.iterations);
    if !session.quiet {
        println!("true           m = {m:.5}  c = {c:.5}");
        println!(
            "least squares  m = {:.5}  c = {:.5}  ({it_plain} iterations)",
            plain[0], plain[1]
        );
        println!(
            "Cauchy(0.1)    m = {:.5}  c = {:.5}  ({it_robust} iterations)",
            robust[0], robust[1]
        );
    }
    if let Some(dir) = &args.preview {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let series = [
            ("least squares", plain_fit.costs.clone()),
            ("Cauchy(0.1)", robust_fit.costs.clone()),
        ];
        preview::cost_plot(
            &dir.join("cost.png"),
            "curve fitting: y = exp(m x + c)",
            &series,
        )?;
    }
    let err = |p: [f64; 2]| ((p[0] - m).powi(2) + (p[1] - c).powi(2)).sqrt();
    println!(
        "{}",
        serde_json::json!({"points": data.len(), "outliers": args.outliers,
            "data": args.data.as_ref().map(|p| p.display().to_string()),
            "plain": plain, "robust": robust, "plain_error": err(plain), "robust_error": err(robust),
            "plain_iterations": it_plain, "robust_iterations": it_robust,
            "plain_cost": plain_fit.cost, "robust_cost": robust_fit.cost,
            "plain_seconds": plain_fit.seconds, "robust_seconds": robust_fit.seconds})
    );
    Ok(())
}
