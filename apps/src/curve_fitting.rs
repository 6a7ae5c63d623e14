//! Fit y = exp(m x + c) to data with 20 % gross outliers, once with plain least squares and once
//! with a Cauchy kernel: the solver serves problems other than SLAM.
//!
//! ```text
//! cargo run --release --example curve_fitting [-- --points 200 --outliers 0.2 --seed 1]
//! ```
//! Prints both estimates against the true (m, c) and, last, one JSON line.

use crate::cli;
use crate::iterations;
use crate::preview;

use anyhow::{Context, Result};
use clap::Parser;
use cli::Session;
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
    /// A folder for a plot of both fits' cost per iteration (cost.png).
    #[arg(long, value_name = "DIR")]
    preview: Option<PathBuf>,
    #[command(flatten)]
    common: cli::Common,
}

cli::has_common!(Args);

/// A fit: the estimate (m, c), the iterations taken and the cost per iteration.
type Fit = ([f64; 2], usize, Vec<(usize, f64)>);

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
    Ok(([v[0], v[1]], summary.num_iterations(), log.costs()))
}

pub fn main() -> ExitCode {
    cli::run(run)
}

fn run(args: Args, session: &Session) -> Result<()> {
    if !(0.0..1.0).contains(&args.outliers) || args.points < 2 {
        return Err(cli::bad_input(
            "--outliers must be in [0, 1) and --points at least 2",
        ));
    }
    let (m, c) = (0.3, 0.1);
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let noise = Normal::new(0.0, 0.02)?;
    let data: Vec<(f64, f64)> = (0..args.points)
        .map(|i| {
            let x = 5.0 * i as f64 / args.points as f64;
            let y = if rng.random::<f64>() < args.outliers {
                rng.random::<f64>() * 8.0
            } else {
                (m * x + c).exp() + noise.sample(&mut rng)
            };
            (x, y)
        })
        .collect();
    let (plain, it_plain, cost_plain) = fit(&data, false, session)?;
    let (robust, it_robust, cost_robust) = fit(&data, true, session)?;
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
        let series = [("least squares", cost_plain), ("Cauchy(0.1)", cost_robust)];
        preview::cost_plot(
            &dir.join("cost.png"),
            "curve fitting: y = exp(m x + c)",
            &series,
        )?;
    }
    let err = |p: [f64; 2]| ((p[0] - m).powi(2) + (p[1] - c).powi(2)).sqrt();
    println!(
        "{}",
        serde_json::json!({"points": args.points, "outliers": args.outliers,
            "plain": plain, "robust": robust, "plain_error": err(plain), "robust_error": err(robust)})
    );
    Ok(())
}
