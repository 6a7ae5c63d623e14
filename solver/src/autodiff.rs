//! Exact Jacobians by forward-mode automatic differentiation.
//!
//! The functor is evaluated once on [`Jet`]s seeded with one direction per ambient coordinate,
//! giving ∂r/∂x (ambient); each block is then chained with its manifold's plus Jacobian,
//! ∂r/∂δ = ∂r/∂x · ∂(x ⊞ δ)/∂δ, as Ceres does with its manifolds.

use crate::jet::Jet;
use crate::real::Real;
use crate::residual::{Jacobians, Residual, Var};
use smallvec::SmallVec;

/// A residual function written once, generic over its scalar type.
pub trait CostFunctor: Send + Sync {
    /// Ambient size of each parameter block, in order.
    fn parameter_sizes(&self) -> &[usize];
    /// Writes r(params) into `residual`.
    fn evaluate<T: Real>(&self, params: &[&[T]], residual: &mut [T]);
}

/// Wraps a [`CostFunctor`] with M residual rows and N ambient parameters in all into a
/// [`Residual`] with exact Jacobians.
#[derive(Clone, Debug)]
pub struct AutoDiff<F, const M: usize, const N: usize> {
    functor: F,
}

impl<F: CostFunctor, const M: usize, const N: usize> AutoDiff<F, M, N> {
    /// Wraps `functor`.
    ///
    /// # Panics
    /// If the functor's parameter sizes do not add up to N (a programming error).
    pub fn new(functor: F) -> Self {
        let total: usize = functor.parameter_sizes().iter().sum();
        assert_eq!(
            total, N,
            "AutoDiff: parameter sizes add up to {total}, the type says N = {N}"
        );
        Self { functor }
    }
    /// The wrapped functor.
    pub fn functor(&self) -> &F {
        &self.functor
    }
}

/// Largest ambient × tangent plus-Jacobian held on the stack.
const STACK_PLUS_JACOBIAN: usize = 96;

impl<F: CostFunctor, const M: usize, const N: usize> Residual for AutoDiff<F, M, N> {
    fn dim(&self) -> usize {
        M
    }
    fn arity(&self) -> Option<usize> {
        Some(self.functor.parameter_sizes().len())
    }
    fn evaluate(
        &self,
        vars: &[Var<'_>],
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) {
        let sizes = self.functor.parameter_sizes();
        let Some(jac) = jacobians else {
            let params: SmallVec<[&[f64]; 8]> = vars.iter().map(|v| v.value).collect();
            self.functor.evaluate::<f64>(&params, &mut residual[..M]);
            return;
        };
        let mut x = [Jet::<N>::constant(0.0); N];
        let mut k = 0;
        for (v, &s) in vars.iter().zip(sizes) {
            for &value in &v.value[..s] {
                x[k] = Jet::variable(value, k);
                k += 1;
            }
        }
        let mut params: SmallVec<[&[Jet<N>]; 8]> = SmallVec::new();
        let mut offset = 0;
        for &s in sizes {
            params.push(&x[offset..offset + s]);
            offset += s;
        }
        let mut r = [Jet::<N>::constant(0.0); M];
        self.functor.evaluate(&params, &mut r);
        for (out, j) in residual.iter_mut().zip(&r) {
            *out = j.re;
        }
        let mut offset = 0;
        let mut stack = [0.0; STACK_PLUS_JACOBIAN];
        for (b, (v, &a)) in vars.iter().zip(sizes).enumerate() {
            let t = v.manifold.tangent_dim();
            let block = jac.block(b);
            if v.manifold.is_euclidean() {
                for c in 0..t {
                    for (i, rj) in r.iter().enumerate() {
                        block[c * M + i] = rj.v[offset + c];
                    }
                }
            } else {
                let mut heap = Vec::new();
                let p: &mut [f64] = if a * t <= STACK_PLUS_JACOBIAN {
                    &mut stack[..a * t]
                } else {
                    heap.resize(a * t, 0.0);
                    &mut heap
                };
                v.manifold.plus_jacobian(v.value, p);
                for c in 0..t {
                    for (i, rj) in r.iter().enumerate() {
                        let mut s = 0.0;
                        for q in 0..a {
                            s += rj.v[offset + q] * p[c * a + q];
                        }
                        block[c * M + i] = s;
                    }
                }
            }
            offset += a;
        }
    }
}
