//! The solver on problems with known answers: synthetic pose graphs, rank deficiency, determinism,
//! user-defined manifolds, automatic and numeric Jacobians, robust kernels.

use dynamap::residuals::pose_graph::synthetic::{self, max_pose_error, SyntheticOptions};
use dynamap::residuals::pose_graph::Pose;
use dynamap::solver::robust::Tukey;
use dynamap::solver::{
    check_jacobians, Algorithm, AutoDiff, CostFunctor, Euclidean, Jacobians, LinearSolverKind,
    Manifold, NumericDiff, Options, Problem, Real, Residual, SolveError, Solver, Termination,
    Timing, UnitQuaternionManifold, Var, SE3, SO3,
};
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use proptest::prelude::*;
use std::collections::BTreeMap;
use std::ops::ControlFlow;

fn small() -> SyntheticOptions {
    SyntheticOptions {
        rings: 8,
        per_ring: 20,
        ..SyntheticOptions::default()
    }
}

fn solve_graph(s: &synthetic::SyntheticGraph, options: Options) -> (BTreeMap<usize, Pose>, f64) {
    let mut pg = s.graph.build_problem(&s.graph.vertices).unwrap();
    let summary = Solver::new(options).solve(&mut pg.problem).unwrap();
    assert!(summary.termination.converged(), "{}", summary.table());
    (pg.poses(), summary.final_cost)
}

#[test]
fn every_algorithm_recovers_the_known_optimum_in_3d_and_2d() {
    for s in [synthetic::sphere(&small()), synthetic::circle(&small())] {
        for algorithm in [
            Algorithm::LevenbergMarquardt,
            Algorithm::GaussNewton,
            Algorithm::Dogleg,
        ] {
            let options = Options {
                algorithm,
                initial_damping_tau: 1e-8,
                ..Options::default()
            };
            let (poses, cost) = solve_graph(&s, options);
            let (dt, dr) = max_pose_error(&poses, &s.truth);
            assert!(
                dt < 1e-7 && dr < 1e-7,
                "{algorithm:?} on {}: {dt:e} m {dr:e} rad",
                s.graph.source
            );
            assert!(cost < 1e-12, "{algorithm:?}: cost {cost}");
        }
    }
}

#[test]
fn dense_and_sparse_solvers_agree() {
    let s = synthetic::circle(&SyntheticOptions {
        rings: 3,
        per_ring: 20,
        ..small()
    });
    let dense = solve_graph(
        &s,
        Options {
            linear_solver: LinearSolverKind::Dense,
            ..Options::default()
        },
    );
    let sparse = solve_graph(
        &s,
        Options {
            linear_solver: LinearSolverKind::Sparse,
            ..Options::default()
        },
    );
    let (dt, dr) = max_pose_error(&dense.0, &sparse.0);
    assert!(dt < 1e-9 && dr < 1e-9);
}

#[test]
fn same_input_gives_the_same_bits() {
    let s = synthetic::sphere(&small());
    let run = || {
        let mut pg = s.graph.build_problem(&s.graph.vertices).unwrap();
        let options = Options {
            max_iterations: 3,
            ..Options::default()
        };
        let summary = Solver::new(options).solve(&mut pg.problem).unwrap();
        let bits: Vec<u64> = pg
            .vars
            .iter()
            .flat_map(|&v| pg.problem.value(v).to_vec())
            .map(f64::to_bits)
            .collect();
        (bits, summary.final_cost.to_bits())
    };
    let first = run();
    for _ in 0..3 {
        assert_eq!(run(), first);
    }
}

#[test]
fn a_graph_without_a_fixed_vertex_reports_its_gauge_freedom() {
    for (s, dim) in [
        (synthetic::sphere(&small()), 6),
        (synthetic::circle(&small()), 3),
    ] {
        let mut pg = s.graph.build_problem(&s.graph.vertices).unwrap();
        pg.problem.set_fixed(pg.vars[0], false).unwrap();
        let err = Solver::new(Options::default())
            .solve(&mut pg.problem)
            .unwrap_err();
        match &err {
            SolveError::RankDeficient { nullity, .. } => assert_eq!(*nullity, dim),
            other => panic!("unexpected {other:?}"),
        }
        let text = err.to_string();
        assert!(
            text.starts_with(&format!(
                "no variable is fixed: the graph has a {dim}-dimensional gauge freedom"
            )),
            "{text}"
        );
    }
}

#[test]
fn an_untouched_variable_is_named() {
    let s = synthetic::circle(&small());
    let mut pg = s.graph.build_problem(&s.graph.vertices).unwrap();
    let extra = pg
        .problem
        .add_variable(&[0.0, 0.0, 0.0], dynamap::solver::SE2)
        .unwrap();
    let err = Solver::new(Options::default())
        .solve(&mut pg.problem)
        .unwrap_err();
    assert_eq!(err, SolveError::UntouchedVariable(extra.index()));
    assert_eq!(
        err.to_string(),
        format!(
            "variable {} is touched by no residual (fix it or remove it)",
            extra.index()
        )
    );
}

/// r = x[0] − target: constrains only the first coordinate of a 2-vector.
struct FirstCoordinate(f64);
impl CostFunctor for FirstCoordinate {
    fn parameter_sizes(&self) -> &[usize] {
        &[2]
    }
    fn evaluate<T: Real>(&self, p: &[&[T]], r: &mut [T]) {
        r[0] = p[0][0] - self.0;
    }
}

/// r = x − target, all coordinates (of a 2-vector, or of S¹ embedded in R²).
struct Anchor([f64; 2]);
impl CostFunctor for Anchor {
    fn parameter_sizes(&self) -> &[usize] {
        &[2]
    }
    fn evaluate<T: Real>(&self, p: &[&[T]], r: &mut [T]) {
        r[0] = p[0][0] - self.0[0];
        r[1] = p[0][1] - self.0[1];
    }
}

#[test]
fn a_partly_constrained_variable_is_named_and_lm_never_produces_nan() {
    let mut problem = Problem::new();
    let a = problem.add_variable(&[1.0, 2.0], Euclidean::<2>).unwrap();
    let b = problem.add_variable(&[3.0, 4.0], Euclidean::<2>).unwrap();
    problem
        .add_residual(AutoDiff::<_, 2, 2>::new(Anchor([0.5, 0.5])), &[a])
        .unwrap();
    problem
        .add_residual(AutoDiff::<_, 1, 2>::new(FirstCoordinate(1.0)), &[b])
        .unwrap();
    let err = Solver::new(Options::default())
        .solve(&mut problem)
        .unwrap_err();
    match err {
        SolveError::RankDeficient {
            nullity,
            variables,
            ref message,
        } => {
            assert_eq!(nullity, 1);
            assert_eq!(variables, vec![b.index()]);
            assert!(
                message.contains("variables 1 are not constrained"),
                "{message}"
            );
        }
        other => panic!("unexpected {other:?}"),
    }
    // Gauss-Newton without the pre-check meets the singular system and reports it too.
    let gn = Options {
        algorithm: Algorithm::GaussNewton,
        check_rank: false,
        ..Options::default()
    };
    assert!(matches!(
        Solver::new(gn).solve(&mut problem),
        Err(SolveError::RankDeficient { .. })
    ));
    // Levenberg-Marquardt without the pre-check damps its way through: finite values, right answer
    // where the problem determines it.
    let lm = Options {
        check_rank: false,
        ..Options::default()
    };
    Solver::new(lm).solve(&mut problem).unwrap();
    assert!(problem
        .value(a)
        .iter()
        .chain(problem.value(b))
        .all(|v| v.is_finite()));
    assert!((problem.value(b)[0] - 1.0).abs() < 1e-8 && (problem.value(a)[1] - 0.5).abs() < 1e-8);
}

#[test]
fn the_observer_sees_every_iteration_and_can_stop() {
    let s = synthetic::sphere(&small());
    let mut pg = s.graph.build_problem(&s.graph.vertices).unwrap();
    let seen = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let log = seen.clone();
    let mut solver = Solver::new(Options::default()).with_observer(move |it| {
        log.lock().unwrap().push(it.iteration);
        if it.iteration == 2 {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    });
    let summary = solver.solve(&mut pg.problem).unwrap();
    assert_eq!(summary.termination, Termination::UserStopped);
    assert_eq!(*seen.lock().unwrap(), vec![0, 1, 2]);
    assert_eq!(summary.iterations.len(), 3);
    assert!(summary
        .iterations
        .windows(2)
        .all(|w| w[1].cost <= w[0].cost));
    // The iteration limit is a stopping reason of its own.
    let mut pg = s.graph.build_problem(&s.graph.vertices).unwrap();
    let summary = Solver::new(Options {
        max_iterations: 1,
        ..Options::default()
    })
    .solve(&mut pg.problem)
    .unwrap();
    assert_eq!(summary.termination, Termination::MaxIterations);
}

#[test]
fn a_solver_reuses_its_structure_and_restarts_cleanly() {
    let s = synthetic::circle(&small());
    let mut solver = Solver::new(Options::default());
    let mut pg = s.graph.build_problem(&s.graph.vertices).unwrap();
    solver.solve(&mut pg.problem).unwrap();
    // Perturb and solve again with the cached symbolic factorisation.
    for &v in &pg.vars[1..] {
        let mut x = pg.problem.value(v).to_vec();
        x[0] += 0.3;
        pg.problem.set_value(v, &x).unwrap();
    }
    solver.solve(&mut pg.problem).unwrap();
    let (dt, _) = max_pose_error(&pg.poses(), &s.truth);
    assert!(dt < 1e-7);
    // A different problem through the same solver.
    let other = synthetic::sphere(&small());
    let mut pg2 = other.graph.build_problem(&other.graph.vertices).unwrap();
    solver.solve(&mut pg2.problem).unwrap();
    assert!(max_pose_error(&pg2.poses(), &other.truth).0 < 1e-7);
}

/// The time report: every part measured, the parts within the total, and a solve that reuses its
/// structure spends (almost) nothing on setup.
#[test]
fn the_time_report_divides_the_total_and_a_reused_structure_needs_no_setup() {
    let s = synthetic::sphere(&small());
    let options = Options {
        linear_solver: LinearSolverKind::Sparse,
        ..Options::default()
    };
    let mut solver = Solver::new(options);
    let mut pg = s.graph.build_problem(&s.graph.vertices).unwrap();
    let first = solver.solve(&mut pg.problem).unwrap();
    let parts = |t: &Timing| [t.setup, t.evaluate, t.assemble, t.factorise, t.step];
    let t = first.timing;
    assert!(parts(&t).iter().all(|&p| p > 0.0), "{t:?}");
    let sum: f64 = parts(&t).iter().sum();
    assert!(
        sum <= first.total_seconds * (1.0 + 1e-9) + 1e-9,
        "{t:?} {}",
        first.total_seconds
    );
    for &v in &pg.vars[1..] {
        let mut x = pg.problem.value(v).to_vec();
        x[0] += 0.1;
        pg.problem.set_value(v, &x).unwrap();
    }
    let second = solver.solve(&mut pg.problem).unwrap();
    assert!(second.timing.setup < t.setup, "{:?} {t:?}", second.timing);
    assert!(second.timing.factorise > 0.0);
}

/// A user-defined manifold: the unit circle S¹ embedded in R², stored as (cos θ, sin θ).
#[derive(Debug)]
struct Circle;
impl Manifold for Circle {
    fn ambient_dim(&self) -> usize {
        2
    }
    fn tangent_dim(&self) -> usize {
        1
    }
    fn plus(&self, x: &[f64], d: &[f64], out: &mut [f64]) {
        let (s, c) = d[0].sin_cos();
        out[0] = x[0] * c - x[1] * s;
        out[1] = x[0] * s + x[1] * c;
    }
    fn minus(&self, y: &[f64], x: &[f64], out: &mut [f64]) {
        out[0] = (x[0] * y[1] - x[1] * y[0]).atan2(x[0] * y[0] + x[1] * y[1]);
    }
    fn plus_jacobian(&self, x: &[f64], out: &mut [f64]) {
        out[0] = -x[1];
        out[1] = x[0];
    }
}

#[test]
fn a_user_defined_manifold_works_with_autodiff() {
    let target = [0.6f64.cos(), 0.6f64.sin()];
    let mut problem = Problem::new();
    let x = problem.add_variable(&[1.0, 0.0], Circle).unwrap();
    problem
        .add_residual(AutoDiff::<_, 2, 2>::new(Anchor(target)), &[x])
        .unwrap();
    let v = [0.3f64.cos(), 0.3f64.sin()];
    let check = check_jacobians(
        &AutoDiff::<_, 2, 2>::new(Anchor(target)),
        &[Var {
            value: &v,
            manifold: &Circle,
        }],
    );
    assert!(check.passes(1e-8), "{check:?}");
    Solver::new(Options::default()).solve(&mut problem).unwrap();
    let got = problem.value(x);
    assert!((got[1].atan2(got[0]) - 0.6).abs() < 1e-8, "{got:?}");
}

/// r = R(q) p − y, written generically (rotation of a point by a quaternion [x, y, z, w]).
struct Rotate {
    p: [f64; 3],
    y: [f64; 3],
}
impl CostFunctor for Rotate {
    fn parameter_sizes(&self) -> &[usize] {
        &[4]
    }
    fn evaluate<T: Real>(&self, q: &[&[T]], r: &mut [T]) {
        let (x, y, z, w) = (q[0][0], q[0][1], q[0][2], q[0][3]);
        let p = [
            T::from_f64(self.p[0]),
            T::from_f64(self.p[1]),
            T::from_f64(self.p[2]),
        ];
        // t = 2 q_v × p; p' = p + w t + q_v × t
        let t = [
            (y * p[2] - z * p[1]) * 2.0,
            (z * p[0] - x * p[2]) * 2.0,
            (x * p[1] - y * p[0]) * 2.0,
        ];
        let c = [
            y * t[2] - z * t[1],
            z * t[0] - x * t[2],
            x * t[1] - y * t[0],
        ];
        for i in 0..3 {
            r[i] = p[i] + w * t[i] + c[i] - self.y[i];
        }
    }
}

/// The same residual on SO(3) stored as a matrix, with a hand-written Jacobian: ∂(R Exp(δ) p)/∂δ = −R [p]×.
struct RotateMatrix {
    p: Vector3<f64>,
    y: Vector3<f64>,
}
impl Residual for RotateMatrix {
    fn dim(&self) -> usize {
        3
    }
    fn evaluate(&self, vars: &[Var<'_>], r: &mut [f64], jac: Option<&mut Jacobians<'_>>) {
        let rot = Matrix3::from_column_slice(vars[0].value);
        r.copy_from_slice((rot * self.p - self.y).as_slice());
        if let Some(j) = jac {
            let d = -rot * dynamap::solver::lie::so3::hat(&self.p);
            j.block(0).copy_from_slice(d.as_slice());
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn autodiff_chains_through_the_quaternion_manifold(a in prop::array::uniform3(-2.0f64..2.0), p in prop::array::uniform3(-1.0f64..1.0)) {
        let q = UnitQuaternion::from_scaled_axis(Vector3::from(a));
        let value = [q.i, q.j, q.k, q.w];
        let r = AutoDiff::<_, 3, 4>::new(Rotate { p, y: [0.1, 0.2, 0.3] });
        let check = check_jacobians(&r, &[Var { value: &value, manifold: &UnitQuaternionManifold }]);
        prop_assert!(check.passes(1e-7), "{check:?}");
        let m = q.to_rotation_matrix().into_inner();
        let hand = RotateMatrix { p: Vector3::from(p), y: Vector3::new(0.1, 0.2, 0.3) };
        let check = check_jacobians(&hand, &[Var { value: m.as_slice(), manifold: &SO3 }]);
        prop_assert!(check.passes(1e-7), "{check:?}");
        let numeric = NumericDiff::new(3, |x: &[&[f64]], out: &mut [f64]| {
            AutoDiff::<_, 3, 4>::new(Rotate { p, y: [0.1, 0.2, 0.3] }).functor().evaluate::<f64>(x, out)
        });
        let check = check_jacobians(&numeric, &[Var { value: &value, manifold: &UnitQuaternionManifold }]);
        prop_assert!(check.passes(1e-6), "{check:?}");
    }
}

#[test]
fn check_jacobians_catches_a_wrong_jacobian() {
    let hand = RotateMatrix {
        p: Vector3::new(1.0, 2.0, 3.0),
        y: Vector3::zeros(),
    };
    let m = Matrix3::<f64>::identity();
    // A sign error in one entry.
    struct Flipped(RotateMatrix);
    impl Residual for Flipped {
        fn dim(&self) -> usize {
            3
        }
        fn evaluate(&self, vars: &[Var<'_>], r: &mut [f64], jac: Option<&mut Jacobians<'_>>) {
            match jac {
                Some(j) => {
                    self.0.evaluate(vars, r, Some(&mut *j));
                    j.block(0)[5] *= -1.0;
                }
                None => self.0.evaluate(vars, r, None),
            }
        }
    }
    let good = check_jacobians(
        &hand,
        &[Var {
            value: m.as_slice(),
            manifold: &SO3,
        }],
    );
    assert!(good.passes(1e-8));
    let bad = check_jacobians(
        &Flipped(RotateMatrix {
            p: Vector3::new(1.0, 2.0, 3.0),
            y: Vector3::zeros(),
        }),
        &[Var {
            value: m.as_slice(),
            manifold: &SO3,
        }],
    );
    assert!(!bad.passes(1e-3), "{bad:?}");
    assert_eq!((bad.worst_entry.1, bad.worst_entry.2), (2, 1));
}

#[test]
fn a_pose_from_point_pairs_with_outliers_on_se3_with_tukey() {
    // Recover a pose from 60 point pairs, 10 of them gross outliers: Tukey's kernel ignores them
    // entirely (exact recovery) once started inside its basin; plain least squares does not.
    struct Transfer {
        p: Vector3<f64>,
        q: Vector3<f64>,
    }
    impl Residual for Transfer {
        fn dim(&self) -> usize {
            3
        }
        fn evaluate(&self, vars: &[Var<'_>], r: &mut [f64], jac: Option<&mut Jacobians<'_>>) {
            let t = dynamap::solver::lie::se3::from_slice(vars[0].value);
            let rot = t.rotation.to_rotation_matrix().into_inner();
            r.copy_from_slice(
                (t * nalgebra::Point3::from(self.p) - nalgebra::Point3::from(self.q)).as_slice(),
            );
            if let Some(j) = jac {
                // ∂(R Exp(ω) (p) + t + R v)/∂[ω; v] = [−R [p]×, R]
                let b = j.block(0);
                b[..9].copy_from_slice((-rot * dynamap::solver::lie::so3::hat(&self.p)).as_slice());
                b[9..].copy_from_slice(rot.as_slice());
            }
        }
    }
    let truth =
        dynamap::solver::lie::se3::exp(&nalgebra::Vector6::new(0.3, -0.2, 0.5, 1.0, 2.0, -0.5));
    let start = truth
        * dynamap::solver::lie::se3::exp(&nalgebra::Vector6::new(
            0.05, -0.03, 0.02, 0.1, -0.1, 0.05,
        ));
    let mut s = [0.0; 7];
    dynamap::solver::lie::se3::to_slice(&start, &mut s);
    let mut problem = Problem::new();
    let mut plain = Problem::new();
    let x = problem.add_variable(&s, SE3).unwrap();
    let y = plain.add_variable(&s, SE3).unwrap();
    for i in 0..60 {
        let f = i as f64;
        let p = Vector3::new(
            (f * 0.37).sin() * 2.0,
            (f * 0.71).cos() * 2.0,
            (f * 0.13).sin(),
        );
        let mut q = (truth * nalgebra::Point3::from(p)).coords;
        if i % 6 == 0 {
            q += Vector3::new(3.0, -2.0, 4.0);
        }
        let r = Transfer { p, q };
        let value = [0.1, 0.2, 0.3, 0.1, 0.2, 0.3, 0.927];
        let norm: f64 = value[3..].iter().map(|v| v * v).sum::<f64>().sqrt();
        let mut v = value;
        v[3..].iter_mut().for_each(|a| *a /= norm);
        if i == 0 {
            let c = check_jacobians(
                &r,
                &[Var {
                    value: &v,
                    manifold: &SE3,
                }],
            );
            assert!(c.passes(1e-7), "{c:?}");
        }
        plain
            .add_residual(Transfer { p: r.p, q: r.q }, &[y])
            .unwrap();
        problem.add_robust_residual(r, Tukey(1.0), &[x]).unwrap();
    }
    Solver::new(Options::default()).solve(&mut problem).unwrap();
    Solver::new(Options::default()).solve(&mut plain).unwrap();
    let error = |v: &[f64]| {
        let got = dynamap::solver::lie::se3::from_slice(v);
        dynamap::solver::lie::se3::log(&(truth.inverse() * got)).norm()
    };
    assert!(
        error(problem.value(x)) < 1e-8,
        "robust pose error {}",
        error(problem.value(x))
    );
    assert!(
        error(plain.value(y)) > 0.1,
        "plain least squares should be pulled away by the outliers"
    );
}

/// r = x − c on a scalar variable.
struct Offset(f64);
impl Residual for Offset {
    fn dim(&self) -> usize {
        1
    }
    fn evaluate(&self, vars: &[Var<'_>], r: &mut [f64], jac: Option<&mut Jacobians<'_>>) {
        r[0] = vars[0].value[0] - self.0;
        if let Some(j) = jac {
            j.block(0)[0] = 1.0;
        }
    }
}

#[test]
fn replaced_residuals_keep_the_structure_and_move_the_optimum() {
    let mut problem = Problem::new();
    let x = problem.add_variable(&[0.0], Euclidean::<1>).unwrap();
    let a = problem.add_residual(Offset(1.0), &[x]).unwrap();
    let b = problem.add_residual(Offset(3.0), &[x]).unwrap();
    let mut solver = Solver::new(Options {
        algorithm: Algorithm::GaussNewton,
        ..Options::default()
    });
    let s = solver.solve(&mut problem).unwrap();
    assert!(
        (problem.value(x)[0] - 2.0).abs() < 1e-9,
        "{} {:?}",
        problem.value(x)[0],
        s.termination
    );
    problem.replace_residual(a, Box::new(Offset(5.0))).unwrap();
    problem.replace_residual(b, Box::new(Offset(7.0))).unwrap();
    solver.solve(&mut problem).unwrap();
    assert!((problem.value(x)[0] - 6.0).abs() < 1e-9);
    // a replacement must fit the block
    let wide = AutoDiff::<_, 2, 1>::new(TwoRows);
    assert!(problem.replace_residual(a, Box::new(wide)).is_err());
    // an id this problem never handed out (the third block of another problem)
    let mut other = Problem::new();
    let y = other.add_variable(&[0.0], Euclidean::<1>).unwrap();
    let foreign = (0..3)
        .map(|_| other.add_residual(Offset(0.0), &[y]).unwrap())
        .last()
        .unwrap();
    assert!(problem
        .replace_residual(foreign, Box::new(Offset(0.0)))
        .is_err());
}

/// Two rows on one scalar, to be refused as a replacement for a one-row block.
struct TwoRows;
impl CostFunctor for TwoRows {
    fn parameter_sizes(&self) -> &[usize] {
        &[1]
    }
    fn evaluate<T: Real>(&self, p: &[&[T]], r: &mut [T]) {
        r[0] = p[0][0];
        r[1] = p[0][0];
    }
}

/// r(x) = √x − 0.1 (closure tests below): NaN for x < 0, an infinite slope at 0.
struct SquareRoot;

impl Residual for SquareRoot {
    fn dim(&self) -> usize {
        1
    }
    fn evaluate(&self, vars: &[Var<'_>], r: &mut [f64], jac: Option<&mut Jacobians<'_>>) {
        let x = vars[0].value[0];
        r[0] = x.sqrt() - 0.1;
        if let Some(j) = jac {
            j.block(0)[0] = 0.5 / x.sqrt();
        }
    }
}

/// A residual that is finite only at the start point x = 0.5 (a broken user residual).
struct FiniteOnlyAtStart;

impl Residual for FiniteOnlyAtStart {
    fn dim(&self) -> usize {
        1
    }
    fn evaluate(&self, vars: &[Var<'_>], r: &mut [f64], jac: Option<&mut Jacobians<'_>>) {
        let x = vars[0].value[0];
        r[0] = if x == 0.5 { 0.0 } else { f64::NAN };
        if let Some(j) = jac {
            j.block(0)[0] = if x == 0.5 { 0.0 } else { f64::INFINITY };
        }
    }
}

/// A Gauss-Newton step from x = 4 on √x − 0.1 lands at x < 0, where the residual is NaN: the step
/// is rejected, the damping raised, and the solve still reaches x = 0.01.
#[test]
fn steps_into_nan_are_rejected_and_the_solve_goes_on() {
    let mut problem = Problem::new();
    let x = problem.add_variable(&[4.0], Euclidean::<1>).unwrap();
    problem.add_residual(SquareRoot, &[x]).unwrap();
    let summary = Solver::new(Options {
        initial_damping_tau: 1e-8,
        max_iterations: 100,
        ..Options::default()
    })
    .solve(&mut problem)
    .unwrap();
    assert!(summary.non_finite_steps > 0, "{}", summary.table());
    assert_eq!(summary.non_finite_block, None);
    assert!(summary.termination.converged(), "{}", summary.table());
    assert!(
        (problem.value(x)[0] - 0.01).abs() < 1e-8,
        "{:?}",
        problem.value(x)
    );
}

/// A residual block that is NaN (or has an infinite Jacobian) everywhere but the start: every
/// step is rejected until the damping runs out; the summary names the block, and the values are
/// the last finite point, not NaN.
#[test]
fn a_persistently_non_finite_block_is_named_and_the_values_stay_finite() {
    for algorithm in [
        Algorithm::LevenbergMarquardt,
        Algorithm::Dogleg,
        Algorithm::GaussNewton,
    ] {
        let mut problem = Problem::new();
        let x = problem.add_variable(&[0.5], Euclidean::<1>).unwrap();
        problem.add_residual(Offset(3.0), &[x]).unwrap();
        problem.add_residual(Offset(3.0), &[x]).unwrap();
        problem.add_residual(FiniteOnlyAtStart, &[x]).unwrap();
        let summary = Solver::new(Options {
            algorithm,
            max_iterations: 500,
            ..Options::default()
        })
        .solve(&mut problem)
        .unwrap();
        assert_eq!(
            summary.non_finite_block,
            Some(2),
            "{algorithm:?}: {}",
            summary.table()
        );
        assert!(summary.table().contains("residual block 2"));
        assert_eq!(problem.value(x), &[0.5], "{algorithm:?}");
        assert!(summary.final_cost.is_finite());
        assert!(!summary.termination.converged(), "{algorithm:?}");
    }
}

/// A residual written for SE(3) poses, given a variable of other sizes, is refused when it is
/// added or swapped in (NOTES 170): before, the problem took it, and the solve read the vector as
/// a 7-number pose and wrote 6 Jacobian columns into its 3 (a panic, through Python too).
#[test]
fn a_variable_of_other_sizes_than_its_residual_reads_is_refused() {
    use dynamap::residuals::pose_graph::{Between3, Prior3};
    use dynamap::solver::ProblemError;
    use nalgebra::{Isometry3, Matrix6};
    let between = || Between3::new(Isometry3::identity(), Matrix6::identity());
    let mut p = Problem::new();
    let identity = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
    let a = p.add_variable(&identity, SE3).unwrap();
    let b = p.add_variable(&identity, SE3).unwrap();
    let v = p.add_variable(&[0.0; 3], Euclidean::<3>).unwrap();
    let seven = p.add_variable(&identity, Euclidean::<7>).unwrap();
    let err = p.add_residual(between(), &[a, v]).unwrap_err();
    assert_eq!(
        err,
        ProblemError::VariableSize {
            variable: v.index(),
            argument: 1,
            expected: (7, 6),
            got: (3, 3),
        }
    );
    assert!(err.to_string().contains("expects 7 and 6"), "{err}");
    // the right number of coordinates on the wrong manifold is refused too
    assert!(matches!(
        p.add_residual(
            Prior3::new(Isometry3::identity(), Matrix6::identity()),
            &[seven]
        ),
        Err(ProblemError::VariableSize { argument: 0, .. })
    ));
    let id = p.add_residual(between(), &[a, b]).unwrap();
    p.set_fixed(a, true).unwrap();
    p.set_fixed(seven, true).unwrap();
    p.set_fixed(v, true).unwrap();
    assert!(Solver::new(Options::default()).solve(&mut p).is_ok());
    // a replacement over the same variables is checked against them as well
    p.replace_residual(id, Box::new(between())).unwrap();
    let loose = p.add_residual(SixZeros, &[seven, v]).unwrap();
    assert!(matches!(
        p.replace_residual(loose, Box::new(between())),
        Err(ProblemError::VariableSize { argument: 0, .. })
    ));
}

/// Six rows of zeros over any variables, declaring no sizes.
struct SixZeros;
impl Residual for SixZeros {
    fn dim(&self) -> usize {
        6
    }
    fn evaluate(&self, vars: &[Var<'_>], r: &mut [f64], j: Option<&mut Jacobians<'_>>) {
        r.fill(0.0);
        if let Some(j) = j {
            for k in 0..vars.len() {
                j.block(k).fill(0.0);
            }
        }
    }
}
