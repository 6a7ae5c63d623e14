//! Robust kernels in the solver: on random small problems, the gradient the solver steps from is
//! the gradient of ½ Σ ρ(‖rᵢ‖²), and a Gauss-Newton step of the kernel-corrected system lowers
//! that cost near a minimum.

use dynamap::residuals::pose_graph::Between2;
use dynamap::solver::robust::{Barron, NamedKernel};
use dynamap::solver::{lie::se2, linearize, Options, Problem, RobustKernel, Solver, VarId, SE2};
use nalgebra::{Isometry2, Matrix3, Vector2, Vector3};
use proptest::prelude::*;

/// Every built-in kernel, at scale `c`, and Barron's with α = 4 (the one with ρ'' > 0, where the
/// full second-order correction applies).
fn kernel(which: usize, c: f64) -> Box<dyn RobustKernel> {
    match which {
        0 => Box::new(NamedKernel::Huber(c)),
        1 => Box::new(NamedKernel::Cauchy(c)),
        2 => Box::new(NamedKernel::Tukey(3.0 * c)),
        3 => Box::new(NamedKernel::GemanMcClure(c)),
        4 => Box::new(NamedKernel::Welsch(2.0 * c)),
        5 => Box::new(NamedKernel::Fair(c)),
        6 => Box::new(NamedKernel::Dcs(c)),
        _ => Box::new(Barron {
            alpha: 4.0,
            scale: c,
        }),
    }
}

/// A random problem: `n` SE(2) poses (the first fixed) joined by between factors of every pair,
/// each under one of the kernels; one in four measurements is a gross outlier.
#[derive(Clone, Debug)]
struct Case {
    poses: Vec<[f64; 3]>,
    edges: Vec<(usize, usize, [f64; 3], usize, f64)>,
}

fn case() -> impl Strategy<Value = Case> {
    (3usize..6)
        .prop_flat_map(|n| {
            let poses = prop::collection::vec(
                (-2.0f64..2.0, -2.0f64..2.0, -1.5f64..1.5).prop_map(|(x, y, t)| [x, y, t]),
                n,
            );
            let pairs: Vec<(usize, usize)> = (0..n)
                .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
                .collect();
            let m = pairs.len();
            let edges = prop::collection::vec(
                (
                    (-0.05f64..0.05, -0.05f64..0.05, -0.03f64..0.03),
                    prop::bool::weighted(0.25),
                    0usize..8,
                    0.3f64..2.0,
                ),
                m,
            )
            .prop_map(move |noise| {
                noise
                    .into_iter()
                    .zip(&pairs)
                    .map(|(((dx, dy, dt), outlier, k, c), &(i, j))| {
                        let s = if outlier { 40.0 } else { 1.0 };
                        (i, j, [s * dx, s * dy, s * dt], k, c)
                    })
                    .collect()
            });
            (poses, edges)
        })
        .prop_map(|(poses, edges)| Case { poses, edges })
}

fn pose(p: &[f64; 3]) -> Isometry2<f64> {
    se2::from_coordinates(p)
}

/// The problem of `case`, its poses at `start` (the truth perturbed by `start_noise`).
fn build(case: &Case, start_noise: f64) -> (Problem, Vec<VarId>) {
    let mut problem = Problem::new();
    let vars: Vec<VarId> = case
        .poses
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let wiggle = start_noise * ((k as f64 * 1.7).sin());
            let q = [p[0] + wiggle, p[1] - wiggle, p[2] + 0.5 * wiggle];
            problem.add_variable(&q, SE2).unwrap()
        })
        .collect();
    problem.set_fixed(vars[0], true).unwrap();
    for &(i, j, noise, k, c) in &case.edges {
        let z = pose(&case.poses[i]).inverse() * pose(&case.poses[j]) * se2::exp(&noise.into());
        let u = Matrix3::from_diagonal(&Vector3::new(10.0, 10.0, 20.0));
        problem
            .add_block(
                Box::new(Between2::new(z, u)),
                Some(kernel(k, c)),
                &[vars[i], vars[j]],
            )
            .unwrap();
    }
    (problem, vars)
}

/// Moves the free variables of `problem` by `delta` (tangent coordinates in `order`).
fn retract(problem: &mut Problem, order: &[VarId], delta: &[f64]) {
    for (b, &v) in order.iter().enumerate() {
        let x = problem.value(v).to_vec();
        let mut out = vec![0.0; x.len()];
        problem
            .manifold(v)
            .plus(&x, &delta[3 * b..3 * b + 3], &mut out);
        problem.set_value(v, &out).unwrap();
    }
}

/// The cost at the free variables moved by `delta`; the values are restored after.
fn cost_at(problem: &mut Problem, order: &[VarId], delta: &[f64]) -> f64 {
    let saved: Vec<Vec<f64>> = order.iter().map(|&v| problem.value(v).to_vec()).collect();
    retract(problem, order, delta);
    let cost = problem.cost();
    for (&v, x) in order.iter().zip(&saved) {
        problem.set_value(v, x).unwrap();
    }
    cost
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn the_solver_gradient_is_the_robust_cost_gradient(c in case(), noise in 0.0f64..0.3) {
        let (mut problem, _) = build(&c, noise);
        let lin = linearize(&problem).unwrap();
        prop_assert!((lin.cost - problem.cost()).abs() <= 1e-12 * (1.0 + lin.cost));
        let n = lin.gradient.len();
        let h = 1e-6;
        for i in 0..n {
            let mut e = vec![0.0; n];
            e[i] = h;
            let plus = cost_at(&mut problem, &lin.variables, &e);
            e[i] = -h;
            let minus = cost_at(&mut problem, &lin.variables, &e);
            let numeric = (plus - minus) / (2.0 * h);
            let g = lin.gradient[i];
            // truncation O(h²) and rounding of the two costs, eps·cost/h
            let tolerance = 1e-6 * (1.0 + g.abs()) + 1e-9 * lin.cost;
            prop_assert!(
                (g - numeric).abs() <= tolerance,
                "coordinate {i}: solver {g}, central difference {numeric}"
            );
        }
    }

    #[test]
    fn a_gauss_newton_step_of_the_corrected_system_lowers_the_cost_near_a_minimum(
        c in case(), direction in prop::collection::vec(-1.0f64..1.0, 15)
    ) {
        let (mut problem, _) = build(&c, 0.02);
        let summary = Solver::new(Options { max_iterations: 200, ..Options::default() })
            .solve(&mut problem)
            .unwrap();
        prop_assume!(summary.termination.converged());
        let lin = linearize(&problem).unwrap();
        // a small displacement from the minimum, then one Gauss-Newton step back
        let n = lin.gradient.len();
        let scale = 1e-3 / (direction[..n].iter().map(|d| d * d).sum::<f64>().sqrt() + 1e-12);
        let d: Vec<f64> = direction[..n].iter().map(|x| x * scale).collect();
        retract(&mut problem, &lin.variables, &d);
        let displaced = linearize(&problem).unwrap();
        let Some(chol) = displaced.hessian.clone().cholesky() else {
            // a Tukey or Welsch that zeroed a pose's every term leaves H singular: no step to test
            return Err(TestCaseError::reject("H is singular at this point"));
        };
        let step = -chol.solve(&displaced.gradient);
        let before = problem.cost();
        retract(&mut problem, &displaced.variables, step.as_slice());
        let after = problem.cost();
        prop_assert!(
            after <= before + 1e-12 * before.abs().max(1.0),
            "cost {before} -> {after} after a Gauss-Newton step (gradient {:.3e})",
            displaced.gradient.norm()
        );
    }
}

#[test]
fn huber_outliers_keep_their_curvature() {
    // One variable, one inlier and one outlier far beyond Huber's kink: the reweighted
    // Hessian must keep ρ' JᵀJ of the outlier (the exact Gauss-Newton term would be 0).
    let mut problem = Problem::new();
    let x = problem.add_variable(&[0.0, 0.0, 0.0], SE2).unwrap();
    let anchor = problem.add_variable(&[0.0, 0.0, 0.0], SE2).unwrap();
    problem.set_fixed(anchor, true).unwrap();
    let u = Matrix3::identity();
    for (dx, k) in [(0.1, 1.0), (50.0, 1.0)] {
        let z = Isometry2::new(Vector2::new(dx, 0.0), 0.0);
        problem
            .add_robust_residual(Between2::new(z, u), NamedKernel::Huber(k), &[anchor, x])
            .unwrap();
    }
    let lin = linearize(&problem).unwrap();
    // inlier weight 1, outlier ρ' = c/‖r‖ = 1/50 along x
    let expected = 1.0 + 1.0 / 50.0;
    assert!(
        (lin.hessian[(0, 0)] - expected).abs() < 1e-9,
        "H_xx = {}, expected {expected}",
        lin.hessian[(0, 0)]
    );
}
