//! A single-precision copy of the coupling blocks' Jacobians, for the products of conjugate
//! gradients.
//!
//! The implicit product `S x` streams every coupling's Jacobian blocks from memory twice per
//! iteration (`H_ec x`, then `H_ce t`), and on large problems that stream is the product's time.
//! The copy halves it: each term's J_c and J_e are stored as `f32`, one after another in the
//! order the product visits them (point by point, neighbour by neighbour), and read into `f64`
//! arithmetic. Their rounding (a relative 6 × 10⁻⁸) is far below the truncated solve's own
//! tolerance (Nash & Sofer's η = 0.1); the reduced right-hand side, the back-substitution, the
//! preconditioner and the model's decrease keep reading the `f64` Jacobian (mixed precision as in
//! GPU bundle adjusters, e.g. Ren et al., *MegBA*, 2022).

use super::Neighbour;
use crate::coupling::{ce_rows, ce_rows_any, ec_rows, ec_rows_any, Couplings};
use crate::normal::NormalEquations;
use crate::parallel::SyncPtr;
use rayon::prelude::*;

/// The copy and where each neighbour record's terms start in it.
#[derive(Default)]
pub(super) struct SingleJacobians {
    values: Vec<f32>,
    /// Per neighbour record, the start of its terms' blocks in `values`, with the total last.
    start: Vec<usize>,
    /// The Jacobian version copied ([`NormalEquations::jacobian_version`]).
    version: Option<u64>,
}

impl SingleJacobians {
    /// Lays out the copy for the neighbour records `nbrs` of the eliminated blocks `nbr_ptr`
    /// delimits; `dims(q, n)` gives (d_c, d_e) of eliminated block q's neighbour n.
    pub fn new(
        nbrs: &[Neighbour],
        nbr_ptr: &[usize],
        couplings: &Couplings,
        dims: impl Fn(usize, &Neighbour) -> (usize, usize),
    ) -> Self {
        let mut start = Vec::with_capacity(nbrs.len() + 1);
        start.push(0);
        for q in 0..nbr_ptr.len() - 1 {
            for n in &nbrs[nbr_ptr[q]..nbr_ptr[q + 1]] {
                let (dc, de) = dims(q, n);
                let size: usize = couplings
                    .terms_of(n.coupling)
                    .iter()
                    .map(|t| t.m * (dc + de))
                    .sum();
                start.push(start.last().unwrap() + size);
            }
        }
        Self {
            values: vec![0.0; *start.last().unwrap()],
            start,
            version: None,
        }
    }

    /// True when laid out (conjugate gradients with truncated solves).
    pub fn is_active(&self) -> bool {
        !self.start.is_empty()
    }

    /// Copies `ne`'s Jacobian blocks unless this version is already copied; `dims` as for
    /// [`Self::new`].
    pub fn refresh(
        &mut self,
        ne: &NormalEquations,
        nbrs: &[Neighbour],
        nbr_ptr: &[usize],
        dims: impl Fn(usize, &Neighbour) -> (usize, usize) + Sync,
    ) {
        let version = ne.jacobian_version();
        if !self.is_active() || self.version == Some(version) {
            return;
        }
        let (couplings, jac) = (ne.couplings(), ne.jacobians());
        let out = SyncPtr::new(&mut self.values);
        let start = &self.start;
        (0..nbr_ptr.len() - 1)
            .into_par_iter()
            .with_min_len(256)
            .for_each(|q| {
                for i in nbr_ptr[q]..nbr_ptr[q + 1] {
                    let (dc, de) = dims(q, &nbrs[i]);
                    // SAFETY: neighbour record i owns values[start[i]..start[i + 1]].
                    let own = unsafe { out.slice(start[i], start[i + 1] - start[i]) };
                    let mut at = 0;
                    for t in couplings.terms_of(nbrs[i].coupling) {
                        for (from, len) in [(t.jc, t.m * dc), (t.je, t.m * de)] {
                            let to = &mut own[at..at + len];
                            for (o, v) in to.iter_mut().zip(&jac[from..from + len]) {
                                *o = *v as f32;
                            }
                            at += len;
                        }
                    }
                }
            });
        self.version = Some(version);
    }

    /// Calls `f(J_c, J_e, m)` for each term of neighbour record `i` (coupling c, blocks of
    /// d_c and d_e columns), each block at the front of its slice.
    #[inline(always)]
    fn for_terms(
        &self,
        couplings: &Couplings,
        (i, c): (usize, usize),
        (dc, de): (usize, usize),
        mut f: impl FnMut(&[f32], &[f32], usize),
    ) {
        let mut at = self.start[i];
        for term in couplings.terms_of(c) {
            let m = term.m;
            let (a, e) = self.values[at..].split_at(m * dc);
            f(a, e, m);
            at += m * (dc + de);
        }
    }

    /// t += H_ec x for neighbour record `i` (coupling c, x its d_c values, t the d_e ones).
    #[inline(always)]
    pub fn add_ec(&self, couplings: &Couplings, i: usize, c: usize, x: &[f64], t: &mut [f64]) {
        let (dc, de) = (x.len(), t.len());
        self.for_terms(couplings, (i, c), (dc, de), |a, e, m| match (dc, de, m) {
            (9, 3, 2) => ec_rows::<f32, 9, 3, 2>(a, e, fixed(x), fixed_mut(t)),
            (6, 3, 3) => ec_rows::<f32, 6, 3, 3>(a, e, fixed(x), fixed_mut(t)),
            _ => ec_rows_any(a, e, m, x, t),
        });
    }

    /// y += H_ce t for neighbour record `i` (coupling c, t the d_e values, y the d_c ones).
    #[inline(always)]
    pub fn add_ce(&self, couplings: &Couplings, i: usize, c: usize, t: &[f64], y: &mut [f64]) {
        let (dc, de) = (y.len(), t.len());
        self.for_terms(couplings, (i, c), (dc, de), |a, e, m| match (dc, de, m) {
            (9, 3, 2) => ce_rows::<f32, 9, 3, 2>(a, e, fixed(t), fixed_mut(y)),
            (6, 3, 3) => ce_rows::<f32, 6, 3, 3>(a, e, fixed(t), fixed_mut(y)),
            _ => ce_rows_any(a, e, m, t, y),
        });
    }
}

/// A slice of N values as an array (the callers match on the length first).
#[inline(always)]
fn fixed<const N: usize>(v: &[f64]) -> &[f64; N] {
    v.try_into().expect("matched length")
}

/// A mutable slice of N values as an array (the callers match on the length first).
#[inline(always)]
fn fixed_mut<const N: usize>(v: &mut [f64]) -> &mut [f64; N] {
    v.try_into().expect("matched length")
}
