//! Residual blocks: the terms of the cost `½ Σ ρ(‖r_i(x_i1, …, x_ik)‖²)`.

use crate::manifold::Manifold;

/// One variable as a residual sees it: its current value (ambient coordinates) and its manifold.
#[derive(Clone, Copy, Debug)]
pub struct Var<'a> {
    /// Ambient coordinates.
    pub value: &'a [f64],
    /// The manifold the variable lives on.
    pub manifold: &'a dyn Manifold,
}

/// The Jacobian blocks of one residual, one per variable, each `dim × tangent_dim(var)` and
/// column-major (as nalgebra stores matrices), laid end to end.
#[derive(Debug)]
pub struct Jacobians<'a> {
    data: &'a mut [f64],
    rows: usize,
    cols: &'a [usize],
}

impl<'a> Jacobians<'a> {
    /// Wraps a buffer of `rows × Σ cols` numbers.
    pub fn new(data: &'a mut [f64], rows: usize, cols: &'a [usize]) -> Self {
        debug_assert!(data.len() >= rows * cols.iter().sum::<usize>());
        Self { data, rows, cols }
    }
    /// Number of residual rows.
    pub fn rows(&self) -> usize {
        self.rows
    }
    /// Columns (tangent dimension) of block `k`.
    pub fn cols(&self, k: usize) -> usize {
        self.cols[k]
    }
    /// Block `k`: ∂r/∂δ_k, `rows × cols(k)`, column-major.
    pub fn block(&mut self, k: usize) -> &mut [f64] {
        let start = self.rows * self.cols[..k].iter().sum::<usize>();
        &mut self.data[start..start + self.rows * self.cols[k]]
    }
}

/// A residual block: r(x_1, …, x_k) ∈ R^m with its Jacobians with respect to each variable's tangent
/// space, `∂ r(x_1, …, x_j ⊞ δ, …) / ∂δ` at δ = 0.
///
/// Write it by hand for speed, or generically once and wrap it in [`AutoDiff`](crate::AutoDiff);
/// [`NumericDiff`](crate::NumericDiff) is there as an explicit, slower choice. Check any of them with
/// [`check_jacobians`](crate::check_jacobians).
pub trait Residual: Send + Sync {
    /// Number of residual rows m.
    fn dim(&self) -> usize;
    /// Number of variables the residual expects, when fixed (checked when the residual is added).
    fn arity(&self) -> Option<usize> {
        None
    }
    /// The sizes variable `k` must have, (ambient, tangent), when fixed: a residual written for
    /// SE(3) poses reads 7 numbers and writes 6 Jacobian columns per pose, and a variable of
    /// other sizes would be read out of bounds. Checked when the residual is added (see
    /// [`check_sizes`]); `None` (the default) takes any.
    fn variable_size(&self, k: usize) -> Option<(usize, usize)> {
        let _ = k;
        None
    }
    /// Writes r into `residual` (length m) and, when asked, the Jacobian blocks.
    ///
    /// A residual that cannot be evaluated at a point (outside its domain) writes non-finite values;
    /// the minimisers treat that as a rejected step.
    fn evaluate(
        &self,
        vars: &[Var<'_>],
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    );
}

impl<R: Residual + ?Sized> Residual for Box<R> {
    fn dim(&self) -> usize {
        (**self).dim()
    }
    fn arity(&self) -> Option<usize> {
        (**self).arity()
    }
    fn variable_size(&self, k: usize) -> Option<(usize, usize)> {
        (**self).variable_size(k)
    }
    fn evaluate(
        &self,
        vars: &[Var<'_>],
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) {
        (**self).evaluate(vars, residual, jacobians)
    }
}

/// A variable whose sizes differ from those its residual declares ([`Residual::variable_size`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SizeMismatch {
    /// Which of the residual's variables (its position in the residual's list).
    pub argument: usize,
    /// The sizes the residual expects, (ambient, tangent).
    pub expected: (usize, usize),
    /// The variable's, (ambient, tangent).
    pub got: (usize, usize),
}

/// Checks each variable's (ambient, tangent) sizes, `sizes`, against those `residual` declares.
pub fn check_sizes(
    residual: &dyn Residual,
    sizes: impl IntoIterator<Item = (usize, usize)>,
) -> Result<(), SizeMismatch> {
    for (argument, got) in sizes.into_iter().enumerate() {
        match residual.variable_size(argument) {
            Some(expected) if expected != got => {
                return Err(SizeMismatch {
                    argument,
                    expected,
                    got,
                })
            }
            _ => {}
        }
    }
    Ok(())
}
