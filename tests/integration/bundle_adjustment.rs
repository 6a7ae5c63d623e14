//! Bundle adjustment and the Schur-complement solvers on generated problems with known answers.

use dynamap::residuals::bal::{
    self,
    synthetic::{self, SyntheticOptions},
    BalProblem, SnavelyReprojection,
};
use dynamap::solver::robust::NamedKernel;
use dynamap::solver::{
    AutoDiff, CostFunctor, DampingKind, Elimination, Euclidean, IterationSummary, LinearSolverKind,
    Options, Problem, Real, SolveError, Solver,
};
use std::sync::{Arc, Mutex};

fn options(linear_solver: LinearSolverKind) -> Options {
    Options {
        linear_solver,
        damping: DampingKind::Diagonal,
        check_rank: false,
        max_iterations: 30,
        pcg_tolerance: 1e-10,
        pcg_forcing: 0.0,
        ..Options::default()
    }
}

/// Solves and returns the cost after every iteration.
fn costs(problem: &mut Problem, options: Options) -> (Vec<f64>, &'static str) {
    let log = Arc::new(Mutex::new(Vec::new()));
    let sink = log.clone();
    let summary = Solver::new(options)
        .with_observer(move |it: &IterationSummary| {
            sink.lock().unwrap().push(it.cost);
            std::ops::ControlFlow::Continue(())
        })
        .solve(problem)
        .unwrap();
    let costs = log.lock().unwrap().clone();
    (costs, summary.linear_solver)
}

fn noisy() -> synthetic::Synthetic {
    synthetic::generate(&SyntheticOptions {
        cameras: 6,
        points: 80,
        pixel_noise: 0.5,
        seed: 3,
        ..SyntheticOptions::default()
    })
}

#[test]
fn every_schur_solver_follows_the_full_cholesky_path() {
    let data = noisy().start;
    let (reference, name) = costs(
        &mut data.build(None).unwrap().problem,
        options(LinearSolverKind::Sparse),
    );
    assert_eq!(name, "sparse");
    for (kind, expected, tol) in [
        (LinearSolverKind::SchurDense, "schur-dense", 1e-9),
        (LinearSolverKind::SchurSparse, "schur-sparse", 1e-9),
        (LinearSolverKind::Schur, "schur-dense", 1e-9),
        (LinearSolverKind::SchurIterative, "schur-iterative", 1e-6),
    ] {
        let (path, name) = costs(&mut data.build(None).unwrap().problem, options(kind));
        assert_eq!(name, expected);
        assert_eq!(path.len(), reference.len(), "{kind:?}");
        for (k, (a, b)) in path.iter().zip(&reference).enumerate() {
            assert!(
                (a - b).abs() <= tol * b.abs().max(1e-12),
                "{kind:?} iteration {k}: {a} vs {b}"
            );
        }
    }
    // The noisy problem's optimum: pixel noise of 0.5 leaves about ¼ per observation.
    let last = *reference.last().unwrap();
    let per_obs = 2.0 * last / data.observations.len() as f64;
    assert!(per_obs > 0.05 && per_obs < 0.5, "{per_obs}");
}

#[test]
fn the_generated_problem_reaches_its_known_optimum() {
    let s = synthetic::generate(&SyntheticOptions::default());
    let mut solve = s.start.build(None).unwrap();
    assert!(s.truth.cost() < 1e-20);
    assert!(s.start.cost() > 1e3);
    let summary = Solver::new(options(LinearSolverKind::SchurDense))
        .solve(&mut solve.problem)
        .unwrap();
    // Rounding leaves ~1e-16 of a start cost of ~1e5.
    assert!(summary.final_cost < 1e-14, "{}", summary.table());
    assert!(summary.num_iterations() < 15, "{}", summary.table());
}

/// A camera and a point that no observation names (legal in a BAL file) are held where the file
/// puts them: the rest reaches the optimum as without them, with every Schur solver, where the
/// solve refused the variable no residual touches.
#[test]
fn unobserved_cameras_and_points_are_held_and_the_rest_is_solved() {
    let s = synthetic::generate(&SyntheticOptions::default());
    let mut start = s.start.clone();
    start.cameras.push(s.start.cameras[0]);
    start.points.push([0.5, -0.25, 3.0]);
    let (cameras, points) = (start.cameras.len(), start.points.len());
    assert_eq!(start.unobserved(), (vec![cameras - 1], vec![points - 1]));
    assert_eq!(s.start.unobserved(), (vec![], vec![]));
    for kind in [
        LinearSolverKind::SchurDense,
        LinearSolverKind::SchurSparse,
        LinearSolverKind::SchurIterative,
    ] {
        let mut solve = start.build(None).unwrap();
        let summary = Solver::new(options(kind))
            .solve(&mut solve.problem)
            .unwrap();
        assert!(summary.final_cost < 1e-14, "{kind:?}: {}", summary.table());
        let mut solved = start.clone();
        solved.update_from(&solve);
        assert_eq!(solved.cameras[cameras - 1], start.cameras[cameras - 1]);
        assert_eq!(solved.points[points - 1], start.points[points - 1]);
    }
}

#[test]
fn truncated_conjugate_gradients_reach_the_optimum_of_a_street_walk_with_fewer_products() {
    // A walk through the streets (the benchmark family's layout) with pixel noise: the exact
    // reduced solve and the truncated one (Nash-Sofer forcing 0.1, Ceres' default) end at the
    // same optimum, and the truncated steps are inexact (the paths differ) yet no slower to
    // converge by more than a few iterations.
    let s = synthetic::generate(&SyntheticOptions {
        layout: synthetic::Layout::Streets,
        cameras: 40,
        points: 1200,
        pixel_noise: 0.5,
        seed: 21,
        ..SyntheticOptions::default()
    });
    let run = |forcing: f64| {
        let mut solve = s.start.build(None).unwrap();
        let summary = Solver::new(Options {
            max_iterations: 200,
            pcg_forcing: forcing,
            ..options(LinearSolverKind::SchurIterative)
        })
        .solve(&mut solve.problem)
        .unwrap();
        assert!(summary.termination.converged(), "{}", summary.table());
        summary
    };
    let exact = run(0.0);
    let truncated = run(0.1);
    let (a, b) = (truncated.final_cost, exact.final_cost);
    assert!((a - b).abs() <= 1e-6 * b, "{a} vs {b}");
    let per_obs = 2.0 * b / s.start.observations.len() as f64;
    assert!(per_obs > 0.1 && per_obs < 0.5, "{per_obs}");
    let differs = truncated
        .iterations
        .iter()
        .zip(&exact.iterations)
        .skip(1)
        .any(|(t, e)| (t.cost - e.cost).abs() > 1e-9 * e.cost);
    assert!(differs, "the truncated steps were exact");
    assert!(
        truncated.num_iterations() <= exact.num_iterations() + 10,
        "{} vs {}",
        truncated.num_iterations(),
        exact.num_iterations()
    );
}

/// A prior tying two cameras' focal lengths: a kept-kept block of H (S gets H_cc off-diagonal).
struct SameFocal;
impl CostFunctor for SameFocal {
    fn parameter_sizes(&self) -> &[usize] {
        &[9, 9]
    }
    fn evaluate<T: Real>(&self, p: &[&[T]], r: &mut [T]) {
        r[0] = (p[0][6] - p[1][6]) * 0.1;
    }
}

#[test]
fn the_automatic_choice_factorises_only_where_conjugate_gradients_take_many_iterations() {
    // A ring with runs of 3-12 neighbouring views makes a banded reduced system: its sparse
    // factor costs about 45 operations per scalar of H_ce, little enough to be tried, and
    // conjugate gradients need tens to hundreds of iterations per step on it, so the automatic
    // choice moves to the factorisation after a few steps. A 200-camera street walk makes a
    // factor of about 220 operations per scalar, where conjugate gradients are kept for good
    // (NOTES 75).
    // A ring of 400 cameras with runs of 3-10 views is 23 blocks of S end to end, more
    // conjugate-gradient iterations than a factorisation's worth (19 per solve): the
    // factorisation from the start (NOTES 118).
    for (layout, views, cameras, points, expected, iterated) in [
        (
            synthetic::Layout::Ring,
            (3, 12),
            200,
            8_000,
            "schur-sparse",
            true,
        ),
        (
            synthetic::Layout::Streets,
            (2, 20),
            200,
            8_000,
            "schur-iterative",
            true,
        ),
        (
            synthetic::Layout::Ring,
            (3, 10),
            400,
            12_000,
            "schur-sparse",
            false,
        ),
    ] {
        let s = synthetic::generate(&SyntheticOptions {
            layout,
            cameras,
            points,
            pixel_noise: 1.0,
            views: Some(views),
            seed: 4,
            ..SyntheticOptions::default()
        });
        let mut solve = s.start.build(None).unwrap();
        let summary = Solver::new(Options {
            max_iterations: 15,
            ..options(LinearSolverKind::Schur)
        })
        .solve(&mut solve.problem)
        .unwrap();
        assert_eq!(summary.linear_solver, expected, "{layout:?} {cameras}");
        // the first two started with conjugate gradients, the long ring did not
        assert_eq!(
            summary.linear_iterations > 0,
            iterated,
            "{layout:?} {cameras}"
        );
        assert!(
            summary.final_cost < 0.5 * summary.initial_cost,
            "{}",
            summary.table()
        );
    }
}

#[test]
fn points_before_cameras_and_coupled_cameras_are_eliminated_correctly() {
    let data = noisy().start;
    // Points first, so every H_ce block is stored transposed; cameras 0 and 1 share a residual.
    let build = || {
        let mut problem = Problem::new();
        let points: Vec<_> = data
            .points
            .iter()
            .map(|p| problem.add_variable(p, Euclidean::<3>).unwrap())
            .collect();
        let cameras: Vec<_> = data
            .cameras
            .iter()
            .map(|c| problem.add_variable(c, Euclidean::<9>).unwrap())
            .collect();
        for o in &data.observations {
            problem
                .add_residual(
                    SnavelyReprojection::new(o.uv[0], o.uv[1]),
                    &[cameras[o.camera], points[o.point]],
                )
                .unwrap();
        }
        problem
            .add_residual(
                AutoDiff::<_, 1, 18>::new(SameFocal),
                &[cameras[0], cameras[1]],
            )
            .unwrap();
        (problem, points)
    };
    let (mut p, _) = build();
    let (reference, _) = costs(&mut p, options(LinearSolverKind::Dense));
    for kind in [
        LinearSolverKind::SchurDense,
        LinearSolverKind::SchurSparse,
        LinearSolverKind::SchurIterative,
    ] {
        let (mut p, points) = build();
        let o = Options {
            elimination: Elimination::Variables(points),
            ..options(kind)
        };
        let (path, _) = costs(&mut p, o);
        let (a, b) = (path.last().unwrap(), reference.last().unwrap());
        assert!((a - b).abs() <= 1e-7 * b, "{kind:?}: {a} vs {b}");
    }
}

#[test]
fn an_elimination_set_with_coupled_variables_is_refused() {
    let data = noisy().start;
    let solve = data.build(None).unwrap();
    let mut problem = solve.problem;
    let o = Options {
        elimination: Elimination::Variables(vec![
            solve.cameras[data.observations[0].camera],
            solve.points[data.observations[0].point],
        ]),
        ..options(LinearSolverKind::SchurDense)
    };
    match Solver::new(o).solve(&mut problem) {
        Err(SolveError::LinearSolver(m)) => assert!(m.contains("share a residual"), "{m}"),
        other => panic!("expected a refusal, got {other:?}"),
    }
}

#[test]
fn huber_lowers_the_inlier_cost_when_a_tenth_of_the_observations_are_corrupt() {
    let s = synthetic::generate(&SyntheticOptions {
        cameras: 8,
        points: 200,
        pixel_noise: 0.5,
        outlier_fraction: 0.1,
        seed: 5,
        ..SyntheticOptions::default()
    });
    let outliers = s.outlier.iter().filter(|&&b| b).count();
    assert!(outliers > s.outlier.len() / 20, "{outliers} outliers");
    let solve_with = |kernel: Option<NamedKernel>| -> BalProblem {
        let mut data = s.start.clone();
        let mut solve = data.build(kernel).unwrap();
        // Reweighted least squares converges linearly once the outliers are down-weighted
        // (NOTES 49): this one takes 110 iterations to a relative change of 1e-10.
        let summary = Solver::new(Options {
            max_iterations: 400,
            ..options(LinearSolverKind::SchurDense)
        })
        .solve(&mut solve.problem)
        .unwrap();
        assert!(summary.termination.converged(), "{}", summary.table());
        data.update_from(&solve);
        data
    };
    let inlier_cost = |d: &BalProblem| d.cost_where(|k| !s.outlier[k]);
    let plain = inlier_cost(&solve_with(None));
    let robust = inlier_cost(&solve_with(Some(NamedKernel::Huber(1.0))));
    let truth = inlier_cost(&s.truth);
    assert!(
        robust < 0.8 * plain,
        "inlier cost with Huber {robust}, without {plain} (at the truth {truth})"
    );
}

#[test]
fn bounds_set_after_a_schur_solve_give_the_steps_of_a_fresh_solver() {
    // Without bounds the Schur solvers leave the camera-point blocks out of H; the
    // box-constrained step reads H whole, so a solver reused after bounds are set must lay H
    // out again, and then takes the steps a fresh solver takes.
    let data = noisy().start;
    let opts = Options {
        max_iterations: 8,
        ..options(LinearSolverKind::SchurSparse)
    };
    let mut reused = data.build(None).unwrap();
    let mut solver = Solver::new(opts.clone());
    solver.solve(&mut reused.problem).unwrap();
    // a second problem at the first one's solution
    let mut fresh = data.build(None).unwrap();
    let pairs = [
        (&reused.cameras, &fresh.cameras),
        (&reused.points, &fresh.points),
    ];
    for (from, to) in pairs {
        for (&a, &b) in from.iter().zip(to.iter()) {
            let x = reused.problem.value(a).to_vec();
            fresh.problem.set_value(b, &x).unwrap();
        }
    }
    // both moved off the solution alike, every focal length held within 10⁻³ of its value
    for solve in [&mut reused, &mut fresh] {
        for (k, &p) in solve.points.iter().enumerate() {
            let mut x = solve.problem.value(p).to_vec();
            x[k % 3] += 0.05;
            solve.problem.set_value(p, &x).unwrap();
        }
        for &c in &solve.cameras {
            let f = solve.problem.value(c)[6];
            let (mut lower, mut upper) = ([f64::NEG_INFINITY; 9], [f64::INFINITY; 9]);
            (lower[6], upper[6]) = (f - 1e-3, f + 1e-3);
            solve.problem.set_bounds(c, &lower, &upper).unwrap();
        }
    }
    let a = solver.solve(&mut reused.problem).unwrap();
    let b = Solver::new(opts).solve(&mut fresh.problem).unwrap();
    assert_eq!(a.iterations.len(), b.iterations.len());
    for (x, y) in a.iterations.iter().zip(&b.iterations) {
        assert!(
            (x.cost - y.cost).abs() <= 1e-9 * y.cost,
            "{} vs {}",
            x.cost,
            y.cost
        );
    }
}

/// The truth of a generated problem with one point carried 40 times farther out along the ray of
/// one camera that sees it: that observation stays exact, the others are hundreds of pixels off.
fn one_point_out_along_its_ray() -> (BalProblem, BalProblem) {
    let truth = synthetic::generate(&SyntheticOptions {
        cameras: 8,
        points: 120,
        seed: 5,
        ..SyntheticOptions::default()
    })
    .truth;
    let mut start = truth.clone();
    let o = start.observations[0];
    let centre = bal::camera_centre(&start.cameras[o.camera]);
    let x = nalgebra::Vector3::from(start.points[o.point]);
    let far = centre + (x - centre) * 40.0;
    start.points[o.point] = [far.x, far.y, far.z];
    (start, truth)
}

#[test]
fn a_point_left_out_along_its_ray_is_restarted_and_the_solve_resumes() {
    let kernel = Some(NamedKernel::Cauchy(1.0));
    let solve_from = |restart: bool| {
        let (mut data, truth) = one_point_out_along_its_ray();
        let mut solve = data.build(kernel).unwrap();
        // a tolerance at which the point's slow flight outwards counts as converged
        let mut solver = Solver::new(Options {
            function_tolerance: 1e-6,
            ..bal::options(LinearSolverKind::SchurSparse, 200)
        });
        let (summary, restarts) = if restart {
            let mut heard = Vec::new();
            let out = bal::solve_with_restarts(&mut solver, &mut data, &mut solve, kernel, |r| {
                heard.push(*r)
            })
            .unwrap();
            assert_eq!(heard.len(), out.1.rounds);
            (out.0, out.1)
        } else {
            (
                solver.solve(&mut solve.problem).unwrap(),
                bal::Restarts::default(),
            )
        };
        data.update_from(&solve);
        // the costs reported go down, one per iteration, the start first
        assert_eq!(summary.iterations.len(), summary.num_iterations() + 1);
        for w in summary.iterations.windows(2) {
            assert!(w[1].cost <= w[0].cost, "{} after {}", w[1].cost, w[0].cost);
            assert_eq!(w[1].iteration, w[0].iteration + 1);
        }
        assert!(summary.num_iterations() <= 200);
        let worst = data
            .points
            .iter()
            .zip(&truth.points)
            .map(|(p, q)| (nalgebra::Vector3::from(*p) - nalgebra::Vector3::from(*q)).norm())
            .fold(0.0, f64::max);
        (summary, restarts, worst)
    };
    // without the restart the solve converges with the point still out there
    let (stuck, none, far) = solve_from(false);
    assert!(stuck.termination.converged(), "{:?}", stuck.termination);
    assert!(stuck.final_cost > 1.0, "{}", stuck.final_cost);
    assert!(far > 1.0, "{far}");
    assert_eq!(none.rounds, 0);
    // with it, the point comes back and the problem reaches its optimum (cost 0); compared by
    // cost, not position, as the similarity gauge drifted while the point flew out
    let (solved, restarts, _) = solve_from(true);
    assert!(restarts.rounds >= 1 && restarts.points >= 1, "{restarts:?}");
    assert!(solved.final_cost < 1e-10, "{}", solved.final_cost);
    assert!(solved.termination.converged(), "{:?}", solved.termination);
}
