//! Fit y = exp(m x + c) to data with 20 % gross outliers, once with plain least squares and once
//! with a Cauchy kernel: the solver serves problems other than SLAM.
//!
//! ```text
//! cargo run --release --example curve_fitting [-- --points 200 --outliers 0.2 --seed 1]
//! ```
//! Prints both estimates against the true (m, c) and, last, one JSON line.

use anyhow::{ensure, Result};
use clap::Parser;
use dynamap::solver::robust::Cauchy;
use dynamap::solver::{AutoDiff, CostFunctor, Euclidean, Options, Problem, Real, Solver};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

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
#[command(about)]
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
}

fn fit(data: &[(f64, f64)], robust: bool) -> Result<([f64; 2], usize)> {
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
    let summary = Solver::new(Options::default()).solve(&mut problem)?;
    let v = problem.value(mc);
    Ok(([v[0], v[1]], summary.num_iterations()))
}

fn main() -> Result<()> {
    let args = Args::parse();
    ensure!(
        (0.0..1.0).contains(&args.outliers),
        "--outliers must be in [0, 1)"
    );
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
    let (plain, it_plain) = fit(&data, false)?;
    let (robust, it_robust) = fit(&data, true)?;
    println!("true           m = {m:.5}  c = {c:.5}");
    println!(
        "least squares  m = {:.5}  c = {:.5}  ({it_plain} iterations)",
        plain[0], plain[1]
    );
    println!(
        "Cauchy(0.1)    m = {:.5}  c = {:.5}  ({it_robust} iterations)",
        robust[0], robust[1]
    );
    let err = |p: [f64; 2]| ((p[0] - m).powi(2) + (p[1] - c).powi(2)).sqrt();
    println!(
        "{}",
        serde_json::json!({"points": args.points, "outliers": args.outliers,
            "plain": plain, "robust": robust, "plain_error": err(plain), "robust_error": err(robust)})
    );
    Ok(())
}
