//! Box constraints and marginal covariances on problems with known answers.

use dynamap::residuals::pose_graph::{Between2, Prior2};
use dynamap::solver::{
    covariance, AutoDiff, CostFunctor, Euclidean, Options, Problem, Real, SolveError, Solver, SE2,
};
use nalgebra::{DMatrix, Isometry2, Matrix3, Vector2};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// y = a + b t at one sample; flags any evaluation with b above `b_max`.
struct Line {
    t: f64,
    y: f64,
    b_max: f64,
    outside: Arc<AtomicBool>,
}
impl CostFunctor for Line {
    fn parameter_sizes(&self) -> &[usize] {
        &[2]
    }
    fn evaluate<T: Real>(&self, p: &[&[T]], r: &mut [T]) {
        if p[0][1].value() > self.b_max {
            self.outside.store(true, Ordering::Relaxed);
        }
        r[0] = p[0][0] + p[0][1] * self.t - self.y;
    }
}

#[test]
fn a_line_fit_whose_slope_is_bounded_reaches_the_closed_form_optimum() {
    // Data of slope 2 with an offset; the bound b ≤ 1.5 is active at the optimum, where
    // b = 1.5 and a = mean(y − 1.5 t) (the least-squares offset for the fixed slope).
    let ts: Vec<f64> = (0..20).map(|i| i as f64 * 0.25).collect();
    let ys: Vec<f64> = ts
        .iter()
        .enumerate()
        .map(|(i, t)| 0.7 + 2.0 * t + 0.05 * ((i * 7 % 5) as f64 - 2.0))
        .collect();
    let b_max = 1.5;
    let outside = Arc::new(AtomicBool::new(false));
    let mut problem = Problem::new();
    let x = problem.add_variable(&[0.0, 0.0], Euclidean::<2>).unwrap();
    problem
        .set_bounds(
            x,
            &[f64::NEG_INFINITY, f64::NEG_INFINITY],
            &[f64::INFINITY, b_max],
        )
        .unwrap();
    for (t, y) in ts.iter().zip(&ys) {
        let f = Line {
            t: *t,
            y: *y,
            b_max,
            outside: outside.clone(),
        };
        problem
            .add_residual(AutoDiff::<_, 1, 2>::new(f), &[x])
            .unwrap();
    }
    let summary = Solver::new(Options::default()).solve(&mut problem).unwrap();
    assert!(summary.termination.converged(), "{}", summary.table());
    let a = ys.iter().zip(&ts).map(|(y, t)| y - b_max * t).sum::<f64>() / ts.len() as f64;
    let v = problem.value(x);
    assert_eq!(v[1], b_max, "the slope sits exactly on its bound");
    assert!((v[0] - a).abs() < 1e-9, "offset {} vs {a}", v[0]);
    assert!(!outside.load(Ordering::Relaxed), "an iterate left the box");
}

/// Rosenbrock's function as least squares: r = (10 (y − x²), 1 − x).
struct Rosenbrock;
impl CostFunctor for Rosenbrock {
    fn parameter_sizes(&self) -> &[usize] {
        &[2]
    }
    fn evaluate<T: Real>(&self, p: &[&[T]], r: &mut [T]) {
        let (x, y) = (p[0][0], p[0][1]);
        r[0] = (y - x * x) * 10.0;
        r[1] = T::from_f64(1.0) - x;
    }
}

#[test]
fn rosenbrock_with_x_bounded_by_a_half_ends_at_the_known_corner() {
    // For x ≤ ½ the cost (1 − x)² + 100 (y − x²)² is least at y = x² and the largest x: (½, ¼).
    let mut problem = Problem::new();
    let p = problem.add_variable(&[-1.2, 1.0], Euclidean::<2>).unwrap();
    problem.set_bounds(p, &[-2.0, -2.0], &[0.5, 2.0]).unwrap();
    problem
        .add_residual(AutoDiff::<_, 2, 2>::new(Rosenbrock), &[p])
        .unwrap();
    let options = Options {
        function_tolerance: 1e-16,
        ..Options::default()
    };
    let summary = Solver::new(options).solve(&mut problem).unwrap();
    let v = problem.value(p);
    assert_eq!(v[0], 0.5, "{}", summary.table());
    assert!((v[1] - 0.25).abs() < 1e-9, "{v:?}\n{}", summary.table());
    assert!((summary.final_cost - 0.125).abs() < 1e-12);
}

#[test]
fn bounds_are_checked_when_set() {
    let mut problem = Problem::new();
    let p = problem.add_variable(&[1.0], Euclidean::<1>).unwrap();
    assert!(problem.set_bounds(p, &[2.0], &[3.0]).is_err());
    assert!(problem.set_bounds(p, &[1.0], &[0.0]).is_err());
    let q = problem.add_variable(&[0.0, 0.0, 0.0], SE2).unwrap();
    assert!(problem.set_bounds(q, &[0.0; 3], &[1.0; 3]).is_err());
    problem.set_bounds(p, &[0.0], &[2.0]).unwrap();
    assert!(problem.set_value(p, &[5.0]).is_err());
}

/// r = y − (a e^{k t} + c): a curve fit with three scalar variables.
struct Exponential {
    t: f64,
    y: f64,
}
impl CostFunctor for Exponential {
    fn parameter_sizes(&self) -> &[usize] {
        &[1, 1, 1]
    }
    fn evaluate<T: Real>(&self, p: &[&[T]], r: &mut [T]) {
        r[0] = (p[0][0] * (p[1][0] * self.t).exp() + p[2][0]) * 2.0 - self.y * 2.0;
    }
}

#[test]
fn covariance_blocks_equal_the_dense_inverse() {
    let mut problem = Problem::new();
    let vars: Vec<_> = [1.0, 0.3, 0.1]
        .iter()
        .map(|v| problem.add_variable(&[*v], Euclidean::<1>).unwrap())
        .collect();
    let samples: Vec<(f64, f64)> = (0..15)
        .map(|i| {
            let t = i as f64 * 0.2;
            (t, 1.3 * (0.4 * t).exp() - 0.2 + 0.01 * (i % 3) as f64)
        })
        .collect();
    for &(t, y) in &samples {
        problem
            .add_residual(AutoDiff::<_, 1, 3>::new(Exponential { t, y }), &vars)
            .unwrap();
    }
    Solver::new(Options::default()).solve(&mut problem).unwrap();
    // Dense H = JᵀJ from the analytic Jacobian rows at the optimum.
    let (a, k) = (problem.value(vars[0])[0], problem.value(vars[1])[0]);
    let mut j = DMatrix::zeros(samples.len(), 3);
    for (i, &(t, _)) in samples.iter().enumerate() {
        j[(i, 0)] = 2.0 * (k * t).exp();
        j[(i, 1)] = 2.0 * a * t * (k * t).exp();
        j[(i, 2)] = 2.0;
    }
    let dense = (j.transpose() * &j).try_inverse().unwrap();
    let blocks = covariance(&problem, &vars).unwrap();
    for (i, b) in blocks.iter().enumerate() {
        let expected = dense[(i, i)];
        assert!(
            (b[(0, 0)] - expected).abs() < 1e-9 * expected,
            "variable {i}: {} vs {expected}",
            b[(0, 0)]
        );
    }
}

fn pose(x: f64, y: f64, theta: f64) -> Isometry2<f64> {
    Isometry2::new(Vector2::new(x, y), theta)
}

fn sqrt_info(sigmas: [f64; 3]) -> Matrix3<f64> {
    Matrix3::from_diagonal(&nalgebra::Vector3::from(sigmas.map(|s| 1.0 / s)))
}

/// GTSAM's Pose2 SLAM example (a prior on pose 1, four odometry edges and a loop closure 5 → 2).
fn gtsam_example(with_prior: bool) -> (Problem, Vec<dynamap::solver::VarId>) {
    use std::f64::consts::FRAC_PI_2;
    let mut problem = Problem::new();
    let starts = [
        [0.5, 0.0, 0.2],
        [2.3, 0.1, -0.2],
        [4.1, 0.1, FRAC_PI_2],
        [4.0, 2.0, std::f64::consts::PI],
        [2.1, 2.1, -FRAC_PI_2],
    ];
    let ids: Vec<_> = starts
        .iter()
        .map(|s| problem.add_variable(s, SE2).unwrap())
        .collect();
    if with_prior {
        problem
            .add_residual(
                Prior2::new(pose(0.0, 0.0, 0.0), sqrt_info([0.3, 0.3, 0.1])),
                &[ids[0]],
            )
            .unwrap();
    }
    let odo = sqrt_info([0.2, 0.2, 0.1]);
    let edges = [
        (0, 1, pose(2.0, 0.0, 0.0)),
        (1, 2, pose(2.0, 0.0, FRAC_PI_2)),
        (2, 3, pose(2.0, 0.0, FRAC_PI_2)),
        (3, 4, pose(2.0, 0.0, FRAC_PI_2)),
        (4, 1, pose(2.0, 0.0, FRAC_PI_2)),
    ];
    for (i, j, z) in edges {
        problem
            .add_residual(Between2::new(z, odo), &[ids[i], ids[j]])
            .unwrap();
    }
    (problem, ids)
}

#[test]
fn pose_graph_marginals_match_gtsam() {
    // GTSAM 4 (python), LevenbergMarquardtOptimizer then Marginals(graph, result)
    // .marginalCovariance(k) for poses 1, 3 and 5 of the same graph (rounded to 12 digits; the
    // values are 0.09, 0.362, ... up to rounding in GTSAM's elimination).
    #[rustfmt::skip]
    let gtsam: [[f64; 9]; 3] = [
        [0.09, 0.0, 0.0, 0.0, 0.09, 0.0, 0.0, 0.0, 0.01],
        [0.362, 0.0, 0.062, 0.0, 0.162, -0.002, 0.062, -0.002, 0.0265],
        [0.202, 0.036, -0.018, 0.036, 0.26, -0.051, -0.018, -0.051, 0.0265],
    ];
    let (mut problem, ids) = gtsam_example(true);
    Solver::new(Options::default()).solve(&mut problem).unwrap();
    let blocks = covariance(&problem, &[ids[0], ids[2], ids[4]]).unwrap();
    for (b, g) in blocks.iter().zip(&gtsam) {
        let expected = DMatrix::from_row_slice(3, 3, g);
        assert!(
            (b - &expected).abs().max() < 1e-9,
            "ours {b} GTSAM {expected}"
        );
    }
}

#[test]
fn covariance_of_a_graph_without_anchor_names_the_gauge_freedom() {
    let (mut problem, ids) = gtsam_example(false);
    problem.set_fixed(ids[0], true).unwrap();
    Solver::new(Options::default()).solve(&mut problem).unwrap();
    problem.set_fixed(ids[0], false).unwrap();
    match covariance(&problem, &[ids[2]]) {
        Err(SolveError::RankDeficient { message, .. }) => {
            assert!(message.contains("gauge"), "{message}")
        }
        other => panic!("expected a gauge freedom, got {other:?}"),
    }
    problem.set_fixed(ids[0], true).unwrap();
    assert!(matches!(
        covariance(&problem, &[ids[0]]),
        Err(SolveError::Covariance(_))
    ));
    assert!(covariance(&problem, &[ids[2]]).is_ok());
}
