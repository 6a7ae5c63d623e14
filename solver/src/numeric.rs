//! Central differences in the tangent space: [`NumericDiff`], an explicit choice of numeric
//! Jacobians, and [`check_jacobians`], which compares any residual's Jacobians with them.
//!
//! `∂r/∂δ_k ≈ (r(x ⊞ h e_k) - r(x ⊞ -h e_k)) / 2h`, error O(h²) + O(ε/h) (Nocedal & Wright,
//! *Numerical Optimization*, 2006, eq. 8.7).

use crate::residual::{Jacobians, Residual, Var};

/// Step used for central differences.
pub const DEFAULT_STEP: f64 = 1e-6;

/// Fills `out` (column-major blocks as in [`Jacobians`]) with central-difference Jacobians of
/// `f(vars) -> r` where `m = r.len()`.
fn central_differences(
    f: &dyn Fn(&[Var<'_>], &mut [f64]),
    m: usize,
    vars: &[Var<'_>],
    h: f64,
    out: &mut Jacobians<'_>,
) {
    let (mut rp, mut rm) = (vec![0.0; m], vec![0.0; m]);
    let mut values: Vec<Vec<f64>> = vars.iter().map(|v| v.value.to_vec()).collect();
    for (b, var) in vars.iter().enumerate() {
        let t = var.manifold.tangent_dim();
        let mut delta = vec![0.0; t];
        for c in 0..t {
            for (sign, r) in [(1.0, &mut rp), (-1.0, &mut rm)] {
                delta.fill(0.0);
                delta[c] = sign * h;
                var.manifold.plus(var.value, &delta, &mut values[b]);
                let moved: Vec<Var<'_>> = vars
                    .iter()
                    .zip(&values)
                    .enumerate()
                    .map(|(i, (v, x))| Var {
                        value: if i == b { x } else { v.value },
                        manifold: v.manifold,
                    })
                    .collect();
                f(&moved, r);
            }
            values[b].copy_from_slice(var.value);
            let block = out.block(b);
            for i in 0..m {
                block[c * m + i] = (rp[i] - rm[i]) / (2.0 * h);
            }
        }
    }
}

/// A residual whose Jacobians are taken by central differences of a plain function.
///
/// Slower and less exact than [`AutoDiff`](crate::AutoDiff) or hand-written Jacobians; choose it
/// knowingly (it allocates on every Jacobian evaluation).
pub struct NumericDiff<F> {
    f: F,
    dim: usize,
    step: f64,
}

impl<F> NumericDiff<F>
where
    F: Fn(&[&[f64]], &mut [f64]) + Send + Sync,
{
    /// A residual with `dim` rows computed by `f(params, residual)`.
    pub fn new(dim: usize, f: F) -> Self {
        Self {
            f,
            dim,
            step: DEFAULT_STEP,
        }
    }
    /// Sets the difference step h.
    pub fn with_step(mut self, step: f64) -> Self {
        self.step = step;
        self
    }
    fn call(&self, vars: &[Var<'_>], r: &mut [f64]) {
        let params: Vec<&[f64]> = vars.iter().map(|v| v.value).collect();
        (self.f)(&params, r);
    }
}

impl<F> Residual for NumericDiff<F>
where
    F: Fn(&[&[f64]], &mut [f64]) + Send + Sync,
{
    fn dim(&self) -> usize {
        self.dim
    }
    fn evaluate(
        &self,
        vars: &[Var<'_>],
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) {
        self.call(vars, residual);
        if let Some(j) = jacobians {
            central_differences(&|v, r| self.call(v, r), self.dim, vars, self.step, j);
        }
    }
}

/// The outcome of [`check_jacobians`]: the worst disagreement between a residual's Jacobians and
/// central differences.
#[derive(Clone, Debug, PartialEq)]
pub struct JacobianCheck {
    /// Largest |analytic - numeric| over all entries.
    pub max_abs_error: f64,
    /// Largest |analytic - numeric| / max(1, |analytic|, |numeric|).
    pub max_rel_error: f64,
    /// Where the largest relative error is: (variable, row, column).
    pub worst_entry: (usize, usize, usize),
    /// The residual's value at the worst entry.
    pub analytic: f64,
    /// Central differences at the worst entry.
    pub numeric: f64,
}

impl JacobianCheck {
    /// True when every entry agrees within `tol` (relative to max(1, |entry|)).
    pub fn passes(&self, tol: f64) -> bool {
        self.max_rel_error <= tol
    }
}

/// Compares the Jacobians a residual reports at `vars` with central differences of its values
/// (step [`DEFAULT_STEP`] in each tangent direction) and reports the worst entry.
pub fn check_jacobians(residual: &dyn Residual, vars: &[Var<'_>]) -> JacobianCheck {
    let m = residual.dim();
    let cols: Vec<usize> = vars.iter().map(|v| v.manifold.tangent_dim()).collect();
    let n: usize = cols.iter().sum();
    let (mut analytic, mut numeric) = (vec![0.0; m * n], vec![0.0; m * n]);
    let mut r = vec![0.0; m];
    residual.evaluate(
        vars,
        &mut r,
        Some(&mut Jacobians::new(&mut analytic, m, &cols)),
    );
    let values = |v: &[Var<'_>], out: &mut [f64]| residual.evaluate(v, out, None);
    central_differences(
        &values,
        m,
        vars,
        DEFAULT_STEP,
        &mut Jacobians::new(&mut numeric, m, &cols),
    );
    let mut out = JacobianCheck {
        max_abs_error: 0.0,
        max_rel_error: 0.0,
        worst_entry: (0, 0, 0),
        analytic: 0.0,
        numeric: 0.0,
    };
    let mut start = 0;
    for (b, &c) in cols.iter().enumerate() {
        for col in 0..c {
            for row in 0..m {
                let i = start + col * m + row;
                let (a, nu) = (analytic[i], numeric[i]);
                let abs = (a - nu).abs();
                let rel = abs / 1f64.max(a.abs()).max(nu.abs());
                // NaN counts as the worst possible disagreement.
                let rel = if rel.is_nan() { f64::INFINITY } else { rel };
                out.max_abs_error =
                    out.max_abs_error
                        .max(if abs.is_nan() { f64::INFINITY } else { abs });
                if rel > out.max_rel_error || (b, row, col) == (0, 0, 0) && rel >= out.max_rel_error
                {
                    out.max_rel_error = rel;
                    out.worst_entry = (b, row, col);
                    out.analytic = a;
                    out.numeric = nu;
                }
            }
        }
        start += m * c;
    }
    out
}
