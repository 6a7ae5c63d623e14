//! The blocks of H that couple an eliminated variable to a kept one, H_ec = Σ_k J_keᵀ J_kc over
//! the residuals k touching both, kept as those residuals' Jacobian blocks and applied from them
//! instead of being summed into H (the implicit Schur complement of Agarwal et al., *Bundle
//! Adjustment in the Large*, 2010, sec. 4.3, and Ceres' `ImplicitSchurComplement`).
//!
//! Products read J_kc (m × d_c) and J_ke (m × d_e) once each, m rows at a time:
//! `H_ec x = Σ_k J_keᵀ (J_kc x)` and `H_ce t = Σ_k J_kcᵀ (J_ke t)`. In bundle adjustment a
//! reprojection's two Jacobian blocks hold 24 numbers against the 27 of its H_ce block, so the
//! products cost no more than reading H_ce would, and H_ce is never stored.

/// One residual's share of a coupling: its Jacobian blocks of the kept (`jc`) and the eliminated
/// (`je`) variable in the Jacobian buffer, each `m` rows, column-major.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Term {
    pub jc: usize,
    pub je: usize,
    pub m: usize,
}

/// Every coupling block, grouped by eliminated block and ordered by kept block within each.
#[derive(Default)]
pub(crate) struct Couplings {
    /// Per H block b, the couplings `ptr[b]..ptr[b + 1]` (empty unless b is eliminated).
    pub ptr: Vec<usize>,
    /// The kept H block of each coupling.
    pub kept: Vec<usize>,
    /// Per coupling, its terms `term_ptr[c]..term_ptr[c + 1]`, in residual order.
    pub term_ptr: Vec<usize>,
    pub terms: Vec<Term>,
    /// True when the blocks are summed into H as well (for a box-constrained step, which reads
    /// H whole).
    pub in_h: bool,
}

impl Couplings {
    /// The couplings of H block b (a range of coupling indices).
    pub fn of(&self, b: usize) -> std::ops::Range<usize> {
        match self.ptr.get(b + 1) {
            Some(&end) => self.ptr[b]..end,
            None => 0..0,
        }
    }

    /// t += H_ec x for coupling c (x: the kept block's d_c values, t: the eliminated block's d_e).
    #[inline(always)]
    pub fn add_ec(&self, jac: &[f64], c: usize, x: &[f64], t: &mut [f64]) {
        match (x.len(), t.len()) {
            (9, 3) => self.add_ec_fixed::<9, 3>(jac, c, x, t),
            (6, 3) => self.add_ec_fixed::<6, 3>(jac, c, x, t),
            _ => {
                for k in self.terms_of(c) {
                    ec_rows_any(&jac[k.jc..], &jac[k.je..], k.m, x, t);
                }
            }
        }
    }

    /// y += H_ce t for coupling c (t: the eliminated block's d_e values, y: the kept block's d_c).
    #[inline(always)]
    pub fn add_ce(&self, jac: &[f64], c: usize, t: &[f64], y: &mut [f64]) {
        match (y.len(), t.len()) {
            (9, 3) => self.add_ce_fixed::<9, 3>(jac, c, t, y),
            (6, 3) => self.add_ce_fixed::<6, 3>(jac, c, t, y),
            _ => {
                for k in self.terms_of(c) {
                    ce_rows_any(&jac[k.jc..], &jac[k.je..], k.m, t, y);
                }
            }
        }
    }

    /// The block H_ce of coupling c (d_c × d_e, column-major), column k written at
    /// `out[k * stride..k * stride + d_c]`.
    pub fn block(
        &self,
        jac: &[f64],
        c: usize,
        (dc, de): (usize, usize),
        out: &mut [f64],
        stride: usize,
    ) {
        match (dc, de) {
            (9, 3) => return self.block_fixed::<9, 3>(jac, c, out, stride),
            (6, 3) => return self.block_fixed::<6, 3>(jac, c, out, stride),
            _ => {}
        }
        for k in 0..de {
            out[k * stride..k * stride + dc].fill(0.0);
        }
        for t in self.terms_of(c) {
            let m = t.m;
            for k in 0..de {
                let e = &jac[t.je + k * m..t.je + (k + 1) * m];
                let column = &mut out[k * stride..k * stride + dc];
                for (col, o) in column.iter_mut().enumerate() {
                    let a = &jac[t.jc + col * m..t.jc + (col + 1) * m];
                    *o += a.iter().zip(e).map(|(x, y)| x * y).sum::<f64>();
                }
            }
        }
    }

    #[inline(always)]
    fn block_fixed<const DC: usize, const DE: usize>(
        &self,
        jac: &[f64],
        c: usize,
        out: &mut [f64],
        stride: usize,
    ) {
        let mut acc = [[0.0f64; DC]; DE];
        for t in self.terms_of(c) {
            let m = t.m;
            let (a, e) = (&jac[t.jc..t.jc + DC * m], &jac[t.je..t.je + DE * m]);
            for i in 0..m {
                for (k, column) in acc.iter_mut().enumerate() {
                    let ek = e[k * m + i];
                    for (col, o) in column.iter_mut().enumerate() {
                        *o += a[col * m + i] * ek;
                    }
                }
            }
        }
        for (k, column) in acc.iter().enumerate() {
            out[k * stride..k * stride + DC].copy_from_slice(column);
        }
    }

    #[inline(always)]
    pub fn terms_of(&self, c: usize) -> &[Term] {
        &self.terms[self.term_ptr[c]..self.term_ptr[c + 1]]
    }

    #[inline(always)]
    fn add_ec_fixed<const DC: usize, const DE: usize>(
        &self,
        jac: &[f64],
        c: usize,
        x: &[f64],
        t: &mut [f64],
    ) {
        let x: &[f64; DC] = x.try_into().expect("DC values");
        let mut acc = [0.0f64; DE];
        for k in self.terms_of(c) {
            let (a, e) = (&jac[k.jc..], &jac[k.je..]);
            // reprojections (2 rows) and 3D residuals get their row count as a constant
            match k.m {
                2 => ec_rows::<f64, DC, DE, 2>(a, e, x, &mut acc),
                3 => ec_rows::<f64, DC, DE, 3>(a, e, x, &mut acc),
                m => ec_rows_any(a, e, m, x, &mut acc),
            }
        }
        for (o, a) in t.iter_mut().zip(acc) {
            *o += a;
        }
    }

    #[inline(always)]
    fn add_ce_fixed<const DC: usize, const DE: usize>(
        &self,
        jac: &[f64],
        c: usize,
        t: &[f64],
        y: &mut [f64],
    ) {
        let t: &[f64; DE] = t.try_into().expect("DE values");
        let mut acc = [0.0f64; DC];
        for k in self.terms_of(c) {
            let (a, e) = (&jac[k.jc..], &jac[k.je..]);
            match k.m {
                2 => ce_rows::<f64, DC, DE, 2>(a, e, t, &mut acc),
                3 => ce_rows::<f64, DC, DE, 3>(a, e, t, &mut acc),
                m => ce_rows_any(a, e, m, t, &mut acc),
            }
        }
        for (o, a) in y.iter_mut().zip(acc) {
            *o += a;
        }
    }
}

/// acc += J_eᵀ (J_c x) for one residual of M rows (J_c M × DC and J_e M × DE, column-major, at
/// the fronts of `a` and `e`).
#[inline(always)]
pub(crate) fn ec_rows<T: Copy + Into<f64>, const DC: usize, const DE: usize, const M: usize>(
    a: &[T],
    e: &[T],
    x: &[f64; DC],
    acc: &mut [f64; DE],
) {
    let (a, e) = (&a[..DC * M], &e[..DE * M]);
    for i in 0..M {
        let mut v = 0.0;
        for col in 0..DC {
            v += a[col * M + i].into() * x[col];
        }
        for r in 0..DE {
            acc[r] += e[r * M + i].into() * v;
        }
    }
}

/// acc += J_eᵀ (J_c x) for one residual of `m` rows, the sizes read from `x` (d_c) and `acc`
/// (d_e): [`ec_rows`] for sizes that are not constants.
#[inline(always)]
pub(crate) fn ec_rows_any<T: Copy + Into<f64>>(
    a: &[T],
    e: &[T],
    m: usize,
    x: &[f64],
    acc: &mut [f64],
) {
    for i in 0..m {
        let mut v = 0.0;
        for (col, xc) in x.iter().enumerate() {
            v += a[col * m + i].into() * xc;
        }
        for (r, ar) in acc.iter_mut().enumerate() {
            *ar += e[r * m + i].into() * v;
        }
    }
}

/// acc += J_cᵀ (J_e t) for one residual of `m` rows, the sizes read from `t` (d_e) and `acc`
/// (d_c): [`ec_rows_any`] with the blocks' roles exchanged.
#[inline(always)]
pub(crate) fn ce_rows_any<T: Copy + Into<f64>>(
    a: &[T],
    e: &[T],
    m: usize,
    t: &[f64],
    acc: &mut [f64],
) {
    ec_rows_any(e, a, m, t, acc)
}

/// acc += J_cᵀ (J_e t) for one residual of M rows: [`ec_rows`] with the blocks' roles
/// exchanged (the same operations in the same order).
#[inline(always)]
pub(crate) fn ce_rows<T: Copy + Into<f64>, const DC: usize, const DE: usize, const M: usize>(
    a: &[T],
    e: &[T],
    t: &[f64; DE],
    acc: &mut [f64; DC],
) {
    ec_rows::<T, DE, DC, M>(e, a, t, acc)
}
