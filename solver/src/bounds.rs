//! Box constraints on Euclidean variables: the damped step as the solution of a box-constrained
//! quadratic program.
//!
//! With bounds l ≤ x ≤ u on some coordinates, the step δ of Levenberg-Marquardt (or Gauss-Newton)
//! minimises the damped model
//!
//! ```text
//! m(δ) = ½ δᵀ(H + μD)δ + gᵀδ     subject to  l − x ≤ δ ≤ u − x
//! ```
//!
//! (a projected Levenberg-Marquardt step in the sense of Kanzow, Yamashita & Fukushima, *J. Comput.
//! Appl. Math.* 172, 2004). When the unconstrained step already stays inside the box it is the
//! solution; otherwise the QP is handed to Clarabel (Goulart & Chen, 2024), an interior-point
//! solver; its answer is snapped onto the bounds it reaches, the free coordinates are re-solved
//! exactly with that active set (small systems), and every iterate honours the bounds exactly.

use crate::damping::Damping;
use crate::error::SolveError;
use crate::normal::NormalEquations;
use crate::problem::Problem;
use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettingsBuilder, DefaultSolver, IPSolver, NonnegativeConeT, SolverStatus,
};
use nalgebra::{DMatrix, DVector};

/// Distance (relative to 1 + |bound|) within which a QP solution is put on its bound: well above
/// Clarabel's default accuracy (1e-8), well below any step worth taking.
const SNAP: f64 = 1e-7;

/// The box of the step: for every unknown of the system, `[lo, hi]` with infinities where free.
pub(crate) struct StepBox {
    lo: Vec<f64>,
    hi: Vec<f64>,
    /// Unknowns with at least one finite side.
    bounded: Vec<usize>,
}

impl StepBox {
    /// The box at the problem's current values, or None when no free variable is bounded.
    pub fn new(problem: &Problem, ne: &NormalEquations) -> Option<Self> {
        if !ne
            .var_of_block()
            .iter()
            .any(|&v| problem.variables[v].bounds.is_some())
        {
            return None;
        }
        let n = ne.dim();
        let (mut lo, mut hi) = (vec![f64::NEG_INFINITY; n], vec![f64::INFINITY; n]);
        let mut bounded = Vec::new();
        for (b, &v) in ne.var_of_block().iter().enumerate() {
            let var = &problem.variables[v];
            let Some(bounds) = &var.bounds else {
                continue;
            };
            let x = &problem.values[var.offset..];
            for (i, xi) in x.iter().take(bounds.lower.len()).enumerate() {
                let k = ne.h().block_start[b] + i;
                lo[k] = bounds.lower[i] - xi;
                hi[k] = bounds.upper[i] - xi;
                if lo[k].is_finite() || hi[k].is_finite() {
                    bounded.push(k);
                }
            }
        }
        (!bounded.is_empty()).then_some(Self { lo, hi, bounded })
    }

    /// Whether `step` stays inside the box.
    pub fn contains(&self, step: &[f64]) -> bool {
        self.bounded
            .iter()
            .all(|&k| step[k] >= self.lo[k] && step[k] <= self.hi[k])
    }

    /// max |g_i| over the coordinates the box lets move downhill (the projected gradient's norm).
    pub fn projected_gradient_norm(&self, g: &[f64]) -> f64 {
        let mut m = 0.0f64;
        for (k, &gk) in g.iter().enumerate() {
            let blocked = (self.lo[k] >= 0.0 && gk > 0.0) || (self.hi[k] <= 0.0 && gk < 0.0);
            if !blocked {
                m = m.max(gk.abs());
            }
        }
        m
    }

    /// Replaces `step` by the minimiser of the damped model inside the box.
    pub fn constrain(
        &self,
        ne: &NormalEquations,
        damping: Damping,
        step: &mut [f64],
    ) -> Result<(), SolveError> {
        let n = ne.dim();
        let h = ne.h();
        let mut values = h.values.clone();
        for (i, p) in h.diag_pos().enumerate() {
            values[p] = h.damped(damping, i, values[p]);
        }
        let p = CscMatrix::new(n, n, h.col_ptr.clone(), h.row_indices(|r| r), values);
        // A δ + s = b, s ≥ 0: rows δ_k ≤ hi_k and −δ_k ≤ −lo_k for the finite sides.
        let mut col_ptr = vec![0];
        let (mut rows, mut vals, mut b) = (Vec::new(), Vec::new(), Vec::new());
        let mut is_bounded = vec![false; n];
        for &k in &self.bounded {
            is_bounded[k] = true;
        }
        for (k, &bounded) in is_bounded.iter().enumerate() {
            if bounded {
                if self.hi[k].is_finite() {
                    rows.push(b.len());
                    vals.push(1.0);
                    b.push(self.hi[k]);
                }
                if self.lo[k].is_finite() {
                    rows.push(b.len());
                    vals.push(-1.0);
                    b.push(-self.lo[k]);
                }
            }
            col_ptr.push(rows.len());
        }
        let a = CscMatrix::new(b.len(), n, col_ptr, rows, vals);
        let cones = [NonnegativeConeT(b.len())];
        let settings = DefaultSettingsBuilder::default()
            .verbose(false)
            .build()
            .map_err(|e| SolveError::Bounds(format!("settings: {e:?}")))?;
        let mut qp = DefaultSolver::new(&p, ne.gradient(), &a, &b, &cones, settings)
            .map_err(|e| SolveError::Bounds(format!("the step's QP was refused: {e:?}")))?;
        qp.solve();
        match qp.solution.status {
            SolverStatus::Solved | SolverStatus::AlmostSolved => {}
            status => {
                return Err(SolveError::Bounds(format!(
                    "the box-constrained step was not found ({status:?})"
                )))
            }
        }
        // The interior-point answer approaches an active bound from inside; snap it on.
        for (k, (s, x)) in step.iter_mut().zip(&qp.solution.x).enumerate() {
            let (lo, hi) = (self.lo[k], self.hi[k]);
            *s = if hi.is_finite() && *x >= hi - SNAP * (1.0 + hi.abs()) {
                hi
            } else if lo.is_finite() && *x <= lo + SNAP * (1.0 + lo.abs()) {
                lo
            } else {
                *x
            };
        }
        if n <= POLISH_LIMIT {
            polish(ne, damping, &self.lo, &self.hi, step);
        }
        Ok(())
    }
}

/// Systems up to this size get the active-set polish after the interior-point solve.
const POLISH_LIMIT: usize = 2000;

/// With the active set fixed (coordinates on a bound stay there), solves the damped model exactly
/// for the free coordinates: (H + μD)_FF δ_F = −g_F − (H + μD)_FA δ_A. The interior-point answer
/// is accurate to about 1e-8; this makes the step exact, so iterates settle on the constrained
/// optimum. A polished step that would leave the box is discarded (the QP answer stays).
fn polish(ne: &NormalEquations, damping: Damping, lo: &[f64], hi: &[f64], step: &mut [f64]) {
    let n = ne.dim();
    let free: Vec<usize> = (0..n)
        .filter(|&k| step[k] != lo[k] && step[k] != hi[k])
        .collect();
    if free.len() == n || free.is_empty() {
        return;
    }
    let h = ne.h();
    let mut dense = DMatrix::<f64>::zeros(n, n);
    h.for_each_damped(damping, |r, c, v| {
        dense[(r, c)] = v;
        dense[(c, r)] = v;
    });
    let mut a = DMatrix::<f64>::zeros(free.len(), free.len());
    let mut b = DVector::<f64>::zeros(free.len());
    for (i, &fi) in free.iter().enumerate() {
        b[i] = -ne.gradient()[fi];
        for k in 0..n {
            if step[k] == lo[k] || step[k] == hi[k] {
                b[i] -= dense[(fi, k)] * step[k];
            }
        }
        for (j, &fj) in free.iter().enumerate() {
            a[(i, j)] = dense[(fi, fj)];
        }
    }
    if let Some(chol) = a.cholesky() {
        let x = chol.solve(&b);
        if free
            .iter()
            .zip(x.iter())
            .all(|(&k, v)| *v >= lo[k] && *v <= hi[k])
        {
            for (&k, v) in free.iter().zip(x.iter()) {
                step[k] = *v;
            }
        }
    }
}

/// Clamps the bounded variables of `values` onto their boxes (after x ⊞ δ, rounding may leave a
/// coordinate an ulp outside).
pub(crate) fn clamp(problem: &Problem, values: &mut [f64]) {
    for var in &problem.variables {
        let Some(b) = &var.bounds else { continue };
        for (i, (l, u)) in b.lower.iter().zip(&b.upper).enumerate() {
            let x = &mut values[var.offset + i];
            *x = x.clamp(*l, *u);
        }
    }
}
