//! Rank diagnosis: which variables the residuals leave unconstrained.
//!
//! A component of the variable graph that touches no fixed variable may have a gauge freedom (a
//! pose graph with relative measurements only can be moved as a whole). The numerical null space
//! of H is found by subspace inverse iteration on H + εI followed by a Rayleigh-Ritz projection
//! (Saad, *Numerical Methods for Large Eigenvalue Problems*, 2011, sec. 4.3 and 5.1), and the
//! variables carrying it are named.

use crate::damping::Damping;
use crate::error::SolveError;
use crate::linear::LinearSolver;
use crate::normal::NormalEquations;
use crate::parallel::dot;
use crate::problem::Problem;
use nalgebra::{DMatrix, SymmetricEigen};

/// True when some connected component of free variables touches no fixed variable, so that its
/// rank depends on what the residuals measure.
pub(crate) fn has_unanchored_component(problem: &Problem, ne: &NormalEquations) -> bool {
    let nb = ne.num_blocks();
    let mut parent: Vec<usize> = (0..nb).collect();
    fn find(p: &mut [usize], mut i: usize) -> usize {
        while p[i] != i {
            p[i] = p[p[i]];
            i = p[i];
        }
        i
    }
    let mut anchored = vec![false; nb];
    let mut anchored_roots = Vec::new();
    for block in &problem.blocks {
        let mut first = None;
        let mut touches_fixed = false;
        for &v in &block.vars {
            let b = ne.block_of_var()[v];
            if b == usize::MAX {
                touches_fixed = true;
                continue;
            }
            match first {
                None => first = Some(b),
                Some(a) => {
                    let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
                    parent[ra] = rb;
                }
            }
        }
        if let (Some(b), true) = (first, touches_fixed) {
            anchored_roots.push(b);
        }
    }
    for b in anchored_roots {
        let r = find(&mut parent, b);
        anchored[r] = true;
    }
    (0..nb).any(|b| {
        let r = find(&mut parent, b);
        !anchored[r]
    })
}

/// Deterministic pseudo-random numbers in [-1, 1) (a 64-bit LCG; quality is irrelevant here).
fn lcg(state: &mut u64) -> f64 {
    *state = state
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    ((*state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
}

/// Looks for a numerical null space of H; returns `Err(RankDeficient)` naming its variables.
pub(crate) fn check_rank(
    problem: &Problem,
    ne: &NormalEquations,
    solver: &mut LinearSolver,
) -> Result<(), SolveError> {
    let n = ne.dim();
    if n == 0 {
        return Ok(());
    }
    let max_diag = ne
        .h()
        .diagonal()
        .fold(0.0f64, f64::max)
        .max(f64::MIN_POSITIVE);
    let mut eps = 1e-10 * max_diag;
    let mut factored = false;
    for _ in 0..4 {
        if solver.factor(ne, Damping::Identity(eps)).is_ok() {
            factored = true;
            break;
        }
        eps *= 100.0;
    }
    if !factored {
        return Err(deficiency(problem, ne, n, (0..ne.num_blocks()).collect()));
    }
    let k = n.min(8);
    let mut seed = 0x5eed_u64;
    let mut basis: Vec<Vec<f64>> = (0..k)
        .map(|_| (0..n).map(|_| lcg(&mut seed)).collect())
        .collect();
    for _ in 0..3 {
        for v in basis.iter_mut() {
            solver.solve(ne, v);
        }
        orthonormalise(&mut basis);
    }
    let mut hv = vec![0.0; n];
    let mut t = DMatrix::zeros(k, k);
    for j in 0..k {
        ne.multiply(&basis[j], &mut hv);
        for i in 0..k {
            t[(i, j)] = dot(&basis[i], &hv);
        }
    }
    let t = (&t + t.transpose()) * 0.5;
    let eig = SymmetricEigen::new(t);
    let tol = 1e-8 * max_diag;
    let mut mass = vec![0.0; ne.num_blocks()];
    let mut nullity = 0;
    for (e, &lambda) in eig.eigenvalues.iter().enumerate() {
        if lambda < tol {
            nullity += 1;
            let y = eig.eigenvectors.column(e);
            for (b, m) in mass.iter_mut().enumerate() {
                for i in ne.h().block_start[b]..ne.h().block_start[b + 1] {
                    let u: f64 = basis.iter().zip(y.iter()).map(|(v, yj)| v[i] * yj).sum();
                    *m += u * u;
                }
            }
        }
    }
    if nullity == 0 {
        return Ok(());
    }
    let mut order: Vec<usize> = (0..mass.len()).collect();
    order.sort_by(|a, b| mass[*b].total_cmp(&mass[*a]));
    let threshold = 0.01 * mass[order[0]];
    let blocks: Vec<usize> = order
        .into_iter()
        .take_while(|&b| mass[b] >= threshold)
        .collect();
    Err(deficiency(problem, ne, nullity, blocks))
}

fn deficiency(
    problem: &Problem,
    ne: &NormalEquations,
    nullity: usize,
    blocks: Vec<usize>,
) -> SolveError {
    let mut variables: Vec<usize> = blocks.iter().map(|&b| ne.var_of_block()[b]).collect();
    let any_fixed = problem.variables.iter().any(|v| v.fixed);
    // A null space over every free variable of a problem with nothing fixed is a gauge freedom.
    let message = if !any_fixed && variables.len() == ne.num_blocks() && ne.num_blocks() > 1 {
        format!(
            "no variable is fixed: the graph has a {nullity}-dimensional gauge freedom \
             (fix one variable, e.g. variable {}, or add a prior)",
            ne.var_of_block()[0]
        )
    } else {
        let mut shown: Vec<usize> = variables.clone();
        shown.sort_unstable();
        let list = shown
            .iter()
            .take(12)
            .map(|v| v.to_string())
            .collect::<Vec<_>>()
            .join(", ");
        let more = if shown.len() > 12 {
            format!(" and {} more", shown.len() - 12)
        } else {
            String::new()
        };
        format!(
            "the normal equations are rank-deficient ({nullity} null directions): variables {list}{more} \
             are not constrained by the residuals (fix them or add priors)"
        )
    };
    variables.truncate(64);
    SolveError::RankDeficient {
        nullity,
        variables,
        message,
    }
}

fn orthonormalise(basis: &mut [Vec<f64>]) {
    for i in 0..basis.len() {
        for j in 0..i {
            let (a, b) = basis.split_at_mut(i);
            let d = dot(&a[j], &b[0]);
            for (x, y) in b[0].iter_mut().zip(&a[j]) {
                *x -= d * y;
            }
        }
        let n = dot(&basis[i], &basis[i]).sqrt();
        if n > 0.0 {
            for x in basis[i].iter_mut() {
                *x /= n;
            }
        }
    }
}
