//! Property tests across the solver's layers on random bundle-adjustment structures (issue 25):
//! the assembled H and g equal JᵀJ and Jᵀr formed densely, and every linear solver, the Schur
//! complements among them, solves (H + μI) δ = −g as a dense Cholesky does.

use crate::damping::Damping;
use crate::linear::LinearSolver;
use crate::manifold::Euclidean;
use crate::normal::NormalEquations;
use crate::options::{Elimination, LinearSolverKind};
use crate::problem::{Problem, VarId};
use crate::residual::{Jacobians, Residual, Var};
use crate::schur::SchurOptions;
use nalgebra::{DMatrix, DVector};
use proptest::prelude::*;

/// r = b + Σ_k A_k x_k with fixed A_k (m × d_k, column-major) and b.
struct Affine {
    m: usize,
    a: Vec<Vec<f64>>,
    b: Vec<f64>,
}

impl Residual for Affine {
    fn dim(&self) -> usize {
        self.m
    }
    fn evaluate(&self, vars: &[Var<'_>], r: &mut [f64], jacobians: Option<&mut Jacobians<'_>>) {
        r.copy_from_slice(&self.b);
        for (a, v) in self.a.iter().zip(vars) {
            for (c, x) in v.value.iter().enumerate() {
                for (row, out) in r.iter_mut().enumerate() {
                    *out += a[row + c * self.m] * x;
                }
            }
        }
        if let Some(j) = jacobians {
            for (k, a) in self.a.iter().enumerate() {
                j.block(k).copy_from_slice(a);
            }
        }
    }
}

/// xorshift64*: the structure and values from one proptest seed.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let x = self.0.wrapping_mul(0x2545_f491_4f6c_dd1d);
        (x >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    }
    fn values(&mut self, n: usize) -> Vec<f64> {
        (0..n).map(|_| self.next()).collect()
    }
}

/// Cameras (6 unknowns) and points (3), each point seen by a random non-empty set of cameras
/// through 2-row residuals, and a 3-row prior on every point and a 6-row one on every camera
/// (so that H is positive definite). Returns the problem and the residuals as dense rows.
fn random_problem(seed: u64, cameras: usize, points: usize) -> (Problem, DMatrix<f64>) {
    let mut rng = Rng(seed | 1);
    let mut problem = Problem::new();
    // half the seeds put the points first, so that kept blocks follow eliminated ones
    let points_first = seed & 2 != 0;
    let add_points = |rng: &mut Rng, problem: &mut Problem| -> Vec<VarId> {
        (0..points)
            .map(|_| {
                problem
                    .add_variable(&rng.values(3), Euclidean::<3>)
                    .unwrap()
            })
            .collect()
    };
    let early = if points_first {
        add_points(&mut rng, &mut problem)
    } else {
        Vec::new()
    };
    let cams: Vec<VarId> = (0..cameras)
        .map(|_| {
            problem
                .add_variable(&rng.values(6), Euclidean::<6>)
                .unwrap()
        })
        .collect();
    let pts = if points_first {
        early
    } else {
        add_points(&mut rng, &mut problem)
    };
    let add = |rng: &mut Rng, problem: &mut Problem, vars: &[VarId], dims: &[usize], m| {
        let a = dims.iter().map(|d| rng.values(m * d)).collect();
        let b = rng.values(m);
        problem.add_residual(Affine { m, a, b }, vars).unwrap();
    };
    for &p in &pts {
        let mut seen: Vec<usize> = (0..cameras).filter(|_| rng.next() > 0.0).collect();
        if seen.is_empty() {
            seen.push(((rng.next() + 1.0) * 0.5 * cameras as f64) as usize % cameras);
        }
        for &c in &seen {
            add(&mut rng, &mut problem, &[cams[c], p], &[6, 3], 2);
        }
        // a residual of two cameras and the point (a relative observation)
        if seen.len() >= 2 && rng.next() > 0.3 {
            let vars = [cams[seen[0]], p, cams[seen[1]]];
            add(&mut rng, &mut problem, &vars, &[6, 3, 6], 3);
        }
        add(&mut rng, &mut problem, &[p], &[3], 3);
    }
    for &c in &cams {
        add(&mut rng, &mut problem, &[c], &[6], 6);
    }
    let dense = dense_jacobian(&problem);
    (problem, dense)
}

/// [J | r] of `problem` at its values, one row per residual row, columns in variable order.
fn dense_jacobian(problem: &Problem) -> DMatrix<f64> {
    let n: usize = problem
        .variables
        .iter()
        .map(|v| v.manifold.tangent_dim())
        .sum();
    let starts: Vec<usize> = problem
        .variables
        .iter()
        .scan(0, |s, v| {
            let here = *s;
            *s += v.manifold.tangent_dim();
            Some(here)
        })
        .collect();
    let rows: usize = problem.blocks.iter().map(|b| b.residual.dim()).sum();
    let mut out = DMatrix::zeros(rows, n + 1);
    let mut row = 0;
    for block in &problem.blocks {
        let m = block.residual.dim();
        let vars: Vec<Var<'_>> = block
            .vars
            .iter()
            .map(|&v| {
                let var = &problem.variables[v];
                Var {
                    value: &problem.values[var.offset..var.offset + var.manifold.ambient_dim()],
                    manifold: var.manifold.as_ref(),
                }
            })
            .collect();
        let mut r = vec![0.0; m];
        let mut jac = vec![0.0; m * block.cols.iter().sum::<usize>()];
        block.residual.evaluate(
            &vars,
            &mut r,
            Some(&mut Jacobians::new(&mut jac, m, &block.cols)),
        );
        let mut off = 0;
        for (&v, &c) in block.vars.iter().zip(&block.cols) {
            for k in 0..c {
                for i in 0..m {
                    out[(row + i, starts[v] + k)] = jac[off + i + k * m];
                }
            }
            off += m * c;
        }
        for i in 0..m {
            out[(row + i, n)] = r[i];
        }
        row += m;
    }
    out
}

/// H = JᵀJ and g = Jᵀr formed densely.
fn dense_normal(jr: &DMatrix<f64>) -> (DMatrix<f64>, DVector<f64>) {
    let n = jr.ncols() - 1;
    let j = jr.columns(0, n);
    let r = jr.column(n);
    (j.transpose() * j, j.transpose() * r)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn assembled_h_and_g_equal_the_dense_products(
        seed in any::<u64>(), cameras in 1usize..5, points in 1usize..14,
    ) {
        let (problem, jr) = random_problem(seed, cameras, points);
        let (h, g) = dense_normal(&jr);
        let mut ne = NormalEquations::new(&problem).unwrap();
        ne.evaluate(&problem, &problem.values, true);
        ne.assemble();
        let n = h.nrows();
        let mut assembled = DMatrix::zeros(n, n);
        ne.h().for_each_damped(Damping::None, |r, c, v| {
            assembled[(r, c)] = v;
            assembled[(c, r)] = v;
        });
        let scale = 1.0 + h.amax();
        prop_assert!((&assembled - &h).amax() <= 1e-12 * scale, "H differs");
        let gs = DVector::from_column_slice(ne.gradient());
        prop_assert!((&gs - &g).amax() <= 1e-12 * (1.0 + g.amax()), "g differs");
    }

    #[test]
    fn every_linear_solver_solves_the_damped_system_as_dense_cholesky_does(
        seed in any::<u64>(), cameras in 1usize..5, points in 1usize..14, mu in 1e-3f64..1.0,
    ) {
        let (problem, jr) = random_problem(seed, cameras, points);
        let (h, g) = dense_normal(&jr);
        let n = h.nrows();
        // Marquardt's damping with scales that lift some diagonals to their floor
        let scale: Vec<f64> = (0..n).map(|i| 10f64.powi((i * 7 % 13) as i32)).collect();
        let marquardt = DMatrix::from_fn(n, n, |r, c| {
            if r == c { mu * h[(r, r)].clamp(1e-6 * scale[r], 1e32 * scale[r]) } else { 0.0 }
        });
        let mut whole = NormalEquations::new(&problem).unwrap();
        // the Schur solvers' normal equations leave the coupling blocks out of H (or, with
        // bounds, keep them in too)
        let mut split = NormalEquations::with_elimination(&problem, &Elimination::Auto, false).unwrap();
        let mut both = NormalEquations::with_elimination(&problem, &Elimination::Auto, true).unwrap();
        for ne in [&mut whole, &mut split, &mut both] {
            ne.evaluate(&problem, &problem.values, true);
            ne.assemble();
            ne.set_damping_scale(scale.clone());
        }
        prop_assert!(split.eliminated().iter().any(|&e| e), "something is eliminated");
        let schur = SchurOptions {
            pcg_tolerance: 1e-12,
            pcg_max_iterations: 1000,
            pcg_forcing: 0.0,
        };
        let identity = DMatrix::<f64>::identity(n, n) * mu;
        for (damping, added) in [(Damping::Identity(mu), identity), (Damping::Diagonal(mu), marquardt)] {
            let expected = (&h + added).cholesky().unwrap().solve(&(-&g));
            for (kind, tolerance) in [
                (LinearSolverKind::Dense, 1e-9),
                (LinearSolverKind::Sparse, 1e-9),
                (LinearSolverKind::SchurDense, 1e-9),
                (LinearSolverKind::SchurSparse, 1e-9),
                (LinearSolverKind::SchurIterative, 1e-6),
            ] {
                let systems = if kind.is_schur() { vec![&split, &both] } else { vec![&whole] };
                for ne in systems {
                    let mut solver = LinearSolver::new(ne, kind, 200, schur).unwrap();
                    solver.factor(ne, damping).unwrap();
                    let mut x: Vec<f64> = ne.gradient().iter().map(|v| -v).collect();
                    solver.solve(ne, &mut x);
                    let err = (DVector::from_column_slice(&x) - &expected).amax();
                    prop_assert!(
                        err <= tolerance * (1.0 + expected.amax()),
                        "{kind:?} {damping:?}: off by {err:e}"
                    );
                }
            }
        }
        // H x and xᵀ H x with the couplings applied from J equal the dense products
        let x: Vec<f64> = (0..n).map(|i| ((i * 7 + 3) % 11) as f64 - 5.0).collect();
        let xv = DVector::from_column_slice(&x);
        let hx = &h * &xv;
        for ne in [&whole, &split, &both] {
            let mut y = vec![0.0; n];
            ne.multiply(&x, &mut y);
            let scale = 1.0 + hx.amax();
            prop_assert!((DVector::from_column_slice(&y) - &hx).amax() <= 1e-12 * scale, "H x");
            let q = ne.quadratic(&x, &mut y);
            prop_assert!((q - xv.dot(&hx)).abs() <= 1e-12 * (1.0 + xv.dot(&hx).abs()) * scale, "xᵀ H x");
        }
    }
}

/// A kernel swapped in place ([`Problem::set_kernel`]) changes the cost as a problem built with
/// that kernel has it, and leaves the structure (so a solver's symbolic factorisation) alone.
#[test]
fn a_kernel_swapped_in_place_changes_the_cost_not_the_structure() {
    use crate::problem::ResidualId;
    use crate::robust::NamedKernel;
    let mut p = Problem::new();
    let x = p.add_variable(&[0.5, -1.0], Euclidean::<2>).unwrap();
    let affine = || Affine {
        m: 2,
        a: vec![vec![1.0, 0.0, 0.0, 1.0]],
        b: vec![2.0, 1.0],
    };
    let r = p
        .add_robust_residual(affine(), NamedKernel::Huber(0.1), &[x])
        .unwrap();
    let version = p.structure_version;
    let huber = p.cost();
    p.set_kernel(r, None).unwrap();
    let plain = p.cost();
    // r = (2.5, 0): ½‖r‖² = 3.125; Huber with c = 0.1: ½(2c‖r‖ − c²) = 0.245
    assert!((plain - 3.125).abs() < 1e-12, "{plain}");
    assert!((huber - 0.245).abs() < 1e-12, "{huber}");
    p.set_kernel(r, Some(Box::new(NamedKernel::Huber(0.1))))
        .unwrap();
    assert_eq!(p.cost(), huber);
    assert_eq!(p.structure_version, version);
    assert!(p.set_kernel(ResidualId(1), None).is_err());
}
