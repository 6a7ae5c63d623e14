//! The reduced system solved by preconditioned conjugate gradients with implicit products
//! `S x = H_cc x − H_ce (H_ee⁻¹ (H_ec x))` and the block-Jacobi preconditioner diag(S)⁻¹
//! (Agarwal et al., *Bundle Adjustment in the Large*, 2010, sec. 4.3); S is never formed.

use super::kernels::{invert_spd, subtract_block, MAX_ELIMINATED, MAX_PRODUCT};
use super::single::SingleJacobians;
use super::{ReducedSolver, Schur, SchurOptions};
use crate::block::BlockSparse;
use crate::coupling::Couplings;
use crate::damping::Damping;
use crate::normal::NormalEquations;
use crate::parallel::{dot, SyncPtr};
use rayon::prelude::*;

/// Buffers of the preconditioned conjugate gradients.
pub(super) struct Pcg {
    /// Inverse diagonal blocks of S, d_c² each, at `s.block_start`-derived offsets.
    preconditioner: Vec<f64>,
    precond_offset: Vec<usize>,
    r: Vec<f64>,
    z: Vec<f64>,
    p: Vec<f64>,
    q: Vec<f64>,
    /// Eliminated-block ranges of about equal neighbour counts, with the total last; one
    /// private copy of the implicit product per range.
    chunk_bounds: Vec<usize>,
    chunk_y: Vec<Vec<f64>>,
    /// One private copy of the preconditioner's blocks per range, while they are formed.
    chunk_p: Vec<Vec<f64>>,
    damping: Damping,
    options: SchurOptions,
    /// The couplings' Jacobians in single precision, for the products.
    pub(super) single: SingleJacobians,
    /// Conjugate-gradient iterations and solves so far.
    pub(super) iterations: usize,
    pub(super) solves: usize,
}

impl Schur {
    /// Copies the H_cc blocks into S's values and inverts the diagonal blocks of S for the
    /// block-Jacobi preconditioner.
    ///
    /// The points' parts −H_je H_ee⁻¹ H_ejᵀ are formed point by point, in the chunks of the
    /// implicit product, into each chunk's private copy of the diagonal blocks (their upper
    /// triangles only), each H_je formed from J on the stack; each camera then sums the copies
    /// onto its damped H_cc block and inverts it.
    pub(super) fn precondition(
        &mut self,
        ne: &NormalEquations,
        damping: Damping,
    ) -> Result<(), usize> {
        let h = ne.h();
        let mut values = std::mem::take(&mut self.s.values);
        for j in 0..self.kept.len() {
            self.copy_direct(h, j, Damping::None, |at, v| values[at] = v);
        }
        self.s.values = values;
        self.copy_damping_scale(h);
        let mut pcg = self.take_pcg();
        pcg.damping = damping;
        let this = &*self;
        let dims =
            |q: usize, n: &super::Neighbour| (this.s.block_dim(n.kept), h.block_dim(this.elim[q]));
        pcg.single.refresh(ne, &this.nbrs, &this.nbr_ptr, dims);
        let (bounds, offsets) = (&pcg.chunk_bounds, &pcg.precond_offset);
        pcg.chunk_p.par_iter_mut().enumerate().for_each(|(c, acc)| {
            acc.fill(0.0);
            for q in bounds[c]..bounds[c + 1] {
                this.add_point_to_preconditioner(ne, q, offsets, acc);
            }
        });
        let out = SyncPtr::new(&mut pcg.preconditioner);
        let copies = &pcg.chunk_p;
        let s = &this.s;
        let result = (0..this.kept.len())
            .into_par_iter()
            .with_min_len(16)
            .try_for_each(|j| {
                let dj = s.block_dim(j);
                // SAFETY: block j owns its preconditioner range.
                let p = unsafe { out.slice(offsets[j], dj * dj) };
                s.damped_diagonal_block(j, damping, p);
                for c in 0..dj {
                    for r in 0..=c {
                        let at = offsets[j] + r + c * dj;
                        let v = p[r + c * dj] + copies.iter().map(|copy| copy[at]).sum::<f64>();
                        p[r + c * dj] = v;
                        p[c + r * dj] = v;
                    }
                }
                invert_spd(p, dj).map_err(|k| h.block_start[this.kept[j]] + k)
            });
        self.reduced = ReducedSolver::Iterative(pcg);
        result
    }

    /// S's damping scales: those of the kept unknowns of `h`.
    fn copy_damping_scale(&mut self, h: &BlockSparse) {
        self.s.damping_scale.clear();
        if h.damping_scale.is_empty() {
            return;
        }
        for &b in &self.kept {
            let range = h.block_start[b]..h.block_start[b + 1];
            self.s
                .damping_scale
                .extend_from_slice(&h.damping_scale[range]);
        }
    }

    /// acc_j ← acc_j − H_je H_ee⁻¹ H_ejᵀ (upper triangle) for every neighbour j of eliminated
    /// block q, block j at `offsets[j]` (d_j × d_j, column-major), H_je formed from J.
    #[inline]
    fn add_point_to_preconditioner(
        &self,
        ne: &NormalEquations,
        q: usize,
        offsets: &[usize],
        acc: &mut [f64],
    ) {
        let (couplings, jac) = (ne.couplings(), ne.jacobians());
        let de = ne.h().block_dim(self.elim[q]);
        // scratch for one neighbour's H_je and H_ee⁻¹ H_jeᵀ, both overwritten before each read
        let (mut hje, mut u) = ([0.0; MAX_PRODUCT], [0.0; MAX_PRODUCT]);
        let inv = &self.hinv[self.inv_offset[q]..][..de * de];
        for n in &self.nbrs[self.nbr_ptr[q]..self.nbr_ptr[q + 1]] {
            let dj = self.s.block_dim(n.kept);
            let block = &mut acc[offsets[n.kept]..offsets[n.kept] + dj * dj];
            if let [t] = couplings.terms_of(n.coupling) {
                // one residual couples them (a reprojection): J_cᵀ (J_e H_ee⁻¹ J_eᵀ) J_c
                if let (9, 3, 2) = (dj, de, t.m) {
                    subtract_one_term::<9, 3, 2>(&jac[t.jc..], &jac[t.je..], inv, block);
                    continue;
                }
            }
            couplings.block(jac, n.coupling, (dj, de), &mut hje, dj);
            let hj = |k: usize| &hje[k * dj..(k + 1) * dj];
            let u = self.inverse_times_neighbour(q, hj, (de, dj), &mut u);
            subtract_block(block, |c| c * dj, hj, u, (dj, dj, de), true);
        }
    }

    pub(super) fn take_pcg(&mut self) -> Pcg {
        match std::mem::replace(&mut self.reduced, ReducedSolver::Iterative(Pcg::empty())) {
            ReducedSolver::Iterative(pcg) => pcg,
            ReducedSolver::Factored(_) => unreachable!("only the iterative solver has PCG buffers"),
        }
    }

    /// y = S x = (H_cc + damping) x − H_ce (H_ee⁻¹ (H_ec x)), never forming S nor H_ce.
    ///
    /// One pass over the eliminated blocks: each forms t_e = −H_ee⁻¹ H_ec x and adds H_ce t_e
    /// to its chunk's private copy of y while its residuals' Jacobian blocks are still in cache,
    /// so that J is read once per product; the copies are summed at the end.
    pub(super) fn implicit_product(
        &self,
        ne: &NormalEquations,
        pcg: &mut Pcg,
        x: &[f64],
        y: &mut [f64],
    ) {
        let (bounds, single) = (&pcg.chunk_bounds, &pcg.single);
        pcg.chunk_y.par_iter_mut().enumerate().for_each(|(c, acc)| {
            acc.fill(0.0);
            for q in bounds[c]..bounds[c + 1] {
                self.add_eliminated_product(ne, single, q, x, acc);
            }
        });
        self.s.multiply(x, y);
        for (i, (p, (yi, xi))) in self.s.diag_pos().zip(y.iter_mut().zip(x)).enumerate() {
            let v = self.s.values[p];
            *yi += (self.s.damped(pcg.damping, i, v) - v) * xi;
        }
        add_copies(&pcg.chunk_y, y);
    }

    /// acc ← acc − H_ce H_ee⁻¹ H_ec x over eliminated block q's neighbours, from the
    /// single-precision copy of J when there is one, else from J.
    #[inline]
    fn add_eliminated_product(
        &self,
        ne: &NormalEquations,
        single: &SingleJacobians,
        q: usize,
        x: &[f64],
        acc: &mut [f64],
    ) {
        let (couplings, de) = (ne.couplings(), ne.h().block_dim(self.elim[q]));
        if !single.is_active() {
            let mut t = [0.0f64; MAX_ELIMINATED];
            let t = &mut t[..de];
            // t = −H_ee⁻¹ H_ec x
            self.eliminated_update(ne, q, de, t, x);
            self.add_couplings(couplings, ne.jacobians(), q, t, acc);
            return;
        }
        let mut t = [0.0f64; MAX_ELIMINATED];
        let t = &mut t[..de];
        let range = self.nbr_ptr[q]..self.nbr_ptr[q + 1];
        for (i, n) in range.clone().zip(&self.nbrs[range.clone()]) {
            let (c0, dc) = (self.s.block_start[n.kept], self.s.block_dim(n.kept));
            single.add_ec(couplings, i, n.coupling, &x[c0..c0 + dc], t);
        }
        // u = −H_ee⁻¹ H_ec x
        let inv = &self.hinv[self.inv_offset[q]..][..de * de];
        let mut u = [0.0f64; MAX_ELIMINATED];
        for (r, ur) in u[..de].iter_mut().enumerate() {
            *ur = -(0..de).map(|k| inv[r + k * de] * t[k]).sum::<f64>();
        }
        for (i, n) in range.clone().zip(&self.nbrs[range]) {
            let (c0, dc) = (self.s.block_start[n.kept], self.s.block_dim(n.kept));
            single.add_ce(couplings, i, n.coupling, &u[..de], &mut acc[c0..c0 + dc]);
        }
    }

    /// acc_c += H_ce t over eliminated block q's neighbours c, from J.
    #[inline(always)]
    fn add_couplings(
        &self,
        couplings: &Couplings,
        jac: &[f64],
        q: usize,
        t: &[f64],
        acc: &mut [f64],
    ) {
        for n in &self.nbrs[self.nbr_ptr[q]..self.nbr_ptr[q + 1]] {
            let (c0, dc) = (self.s.block_start[n.kept], self.s.block_dim(n.kept));
            couplings.add_ce(jac, n.coupling, t, &mut acc[c0..c0 + dc]);
        }
    }

    /// The reduced right-hand side b_c − Σ_e H_ce H_ee⁻¹ b_e for conjugate gradients, point by
    /// point from J into the chunks' private copies, which are then summed onto b_c.
    pub(super) fn reduce_rhs_from_jacobians(&mut self, ne: &NormalEquations, x: &[f64]) {
        let mut pcg = self.take_pcg();
        let (h, couplings, jac) = (ne.h(), ne.couplings(), ne.jacobians());
        let bounds = &pcg.chunk_bounds;
        let this = &*self;
        pcg.chunk_y.par_iter_mut().enumerate().for_each(|(c, acc)| {
            acc.fill(0.0);
            for q in bounds[c]..bounds[c + 1] {
                let b = this.elim[q];
                let (e0, de) = (h.block_start[b], h.block_dim(b));
                let inv = &this.hinv[this.inv_offset[q]..][..de * de];
                let mut z = [0.0f64; MAX_ELIMINATED];
                for (r, zr) in z[..de].iter_mut().enumerate() {
                    *zr = -(0..de).map(|k| inv[r + k * de] * x[e0 + k]).sum::<f64>();
                }
                this.add_couplings(couplings, jac, q, &z[..de], acc);
            }
        });
        let mut rhs = std::mem::take(&mut self.rhs);
        for (j, &b) in self.kept.iter().enumerate() {
            let (r0, h0, d) = (self.s.block_start[j], h.block_start[b], self.s.block_dim(j));
            rhs[r0..r0 + d].copy_from_slice(&x[h0..h0 + d]);
        }
        add_copies(&pcg.chunk_y, &mut rhs);
        self.rhs = rhs;
        self.reduced = ReducedSolver::Iterative(pcg);
    }

    /// Preconditioned conjugate gradients on S y = b, overwriting `b` with y (Saad, *Iterative
    /// Methods for Sparse Linear Systems*, 2003, alg. 9.1), starting from y = 0.
    pub(super) fn conjugate_gradients(&mut self, ne: &NormalEquations, b: &mut [f64]) {
        let mut pcg = self.take_pcg();
        let n = b.len();
        let b_norm = dot(b, b).sqrt();
        let mut r = std::mem::take(&mut pcg.r);
        let mut z = std::mem::take(&mut pcg.z);
        let mut p = std::mem::take(&mut pcg.p);
        let mut q = std::mem::take(&mut pcg.q);
        r.copy_from_slice(b);
        b.fill(0.0);
        pcg.solves += 1;
        let before = pcg.iterations;
        if b_norm > 0.0 {
            self.apply_preconditioner(&pcg, &r, &mut z);
            p.copy_from_slice(&z);
            let mut rz = dot(&r, &z);
            // Q(y) = ½ yᵀS y − bᵀy = −½ yᵀ(b + r) with r = b − S y; Q₀ = 0.
            let mut quadratic = 0.0;
            for iteration in 1..=pcg.options.pcg_max_iterations.max(1) {
                pcg.iterations += 1;
                self.implicit_product(ne, &mut pcg, &p, &mut q);
                let pq = dot(&p, &q);
                if pq <= 0.0 || !pq.is_finite() {
                    break;
                }
                let alpha = rz / pq;
                for i in 0..n {
                    b[i] += alpha * p[i];
                    r[i] -= alpha * q[i];
                }
                if dot(&r, &r).sqrt() <= pcg.options.pcg_tolerance * b_norm {
                    break;
                }
                // Q falls by ½ α rᵀz each iteration (Saad, alg. 9.1 with y₀ = 0).
                let next = quadratic - 0.5 * alpha * rz;
                let forcing = pcg.options.pcg_forcing;
                if forcing > 0.0 && iteration as f64 * (next - quadratic) / next < forcing {
                    break;
                }
                quadratic = next;
                self.apply_preconditioner(&pcg, &r, &mut z);
                let rz_next = dot(&r, &z);
                let beta = rz_next / rz;
                rz = rz_next;
                for i in 0..n {
                    p[i] = z[i] + beta * p[i];
                }
            }
        }
        tracing::debug!(
            solve = pcg.solves,
            iterations = pcg.iterations - before,
            "conjugate gradients"
        );
        (pcg.r, pcg.z, pcg.p, pcg.q) = (r, z, p, q);
        self.reduced = ReducedSolver::Iterative(pcg);
    }

    pub(super) fn apply_preconditioner(&self, pcg: &Pcg, r: &[f64], z: &mut [f64]) {
        for j in 0..self.kept.len() {
            let (r0, d) = (self.s.block_start[j], self.s.block_dim(j));
            let m = &pcg.preconditioner[pcg.precond_offset[j]..][..d * d];
            for row in 0..d {
                z[r0 + row] = (0..d).map(|k| m[row + k * d] * r[r0 + k]).sum();
            }
        }
    }
}

impl Pcg {
    /// Buffers for a reduced system shaped like `s`, whose eliminated blocks have the
    /// neighbour lists delimited by `nbr_ptr`.
    pub(super) fn new(s: &BlockSparse, nbr_ptr: &[usize], options: SchurOptions) -> Self {
        let chunk_bounds = chunk_bounds(nbr_ptr, PRODUCT_CHUNKS * rayon::current_num_threads());
        let nr = s.dim();
        let mut precond_offset = vec![0];
        for k in 0..s.num_blocks() {
            let d = s.block_dim(k);
            precond_offset.push(precond_offset.last().unwrap() + d * d);
        }
        let blocks = *precond_offset.last().unwrap();
        Self {
            preconditioner: vec![0.0; blocks],
            precond_offset,
            r: vec![0.0; nr],
            z: vec![0.0; nr],
            p: vec![0.0; nr],
            q: vec![0.0; nr],
            chunk_y: vec![vec![0.0; nr]; chunk_bounds.len() - 1],
            chunk_p: vec![vec![0.0; blocks]; chunk_bounds.len() - 1],
            chunk_bounds,
            damping: Damping::None,
            options,
            iterations: 0,
            solves: 0,
            single: SingleJacobians::default(),
        }
    }

    fn empty() -> Self {
        Self {
            preconditioner: Vec::new(),
            precond_offset: Vec::new(),
            r: Vec::new(),
            z: Vec::new(),
            p: Vec::new(),
            q: Vec::new(),
            chunk_bounds: vec![0],
            chunk_y: Vec::new(),
            chunk_p: Vec::new(),
            damping: Damping::None,
            options: SchurOptions {
                pcg_tolerance: 0.0,
                pcg_max_iterations: 0,
                pcg_forcing: 0.0,
            },
            iterations: 0,
            solves: 0,
            single: SingleJacobians::default(),
        }
    }
}

/// Chunks of the implicit product per worker thread (for balance).
const PRODUCT_CHUNKS: usize = 2;

/// Scalars of y summed per task when the chunks' products are added.
const SUM_RANGE: usize = 4096;

/// block −= J_cᵀ W J_c (upper triangle, DC × DC column-major) with W = J_e H_ee⁻¹ J_eᵀ (M × M),
/// for a coupling of one residual of M rows: H_je H_ee⁻¹ H_jeᵀ with H_je = J_cᵀ J_e, in about
/// 150 operations for a reprojection against 380 through H_je.
#[inline(always)]
fn subtract_one_term<const DC: usize, const DE: usize, const M: usize>(
    a: &[f64],
    e: &[f64],
    inv: &[f64],
    block: &mut [f64],
) {
    let (a, e, inv) = (&a[..DC * M], &e[..DE * M], &inv[..DE * DE]);
    // p = J_e H_ee⁻¹ (M × DE), w = p J_eᵀ (M × M)
    let mut p = [[0.0f64; DE]; M];
    for (i, row) in p.iter_mut().enumerate() {
        for (k, v) in row.iter_mut().enumerate() {
            *v = (0..DE).map(|l| e[l * M + i] * inv[l + k * DE]).sum();
        }
    }
    let mut w = [[0.0f64; M]; M];
    for (i, row) in w.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..DE).map(|k| p[i][k] * e[k * M + j]).sum();
        }
    }
    // v = W J_c (M × DC), then the upper triangle of J_cᵀ v
    let mut v = [[0.0f64; DC]; M];
    for (i, row) in v.iter_mut().enumerate() {
        for (col, x) in row.iter_mut().enumerate() {
            *x = (0..M).map(|j| w[i][j] * a[col * M + j]).sum();
        }
    }
    for c in 0..DC {
        for r in 0..=c {
            block[r + c * DC] -= (0..M).map(|i| a[r * M + i] * v[i][c]).sum::<f64>();
        }
    }
}

/// y += Σ copies, in parallel over ranges of y, the copies in order.
fn add_copies(copies: &[Vec<f64>], y: &mut [f64]) {
    y.par_chunks_mut(SUM_RANGE)
        .enumerate()
        .for_each(|(i, part)| {
            let r0 = i * SUM_RANGE;
            for copy in copies {
                for (o, a) in part.iter_mut().zip(&copy[r0..]) {
                    *o += a;
                }
            }
        });
}

/// Bounds of at most `chunks` ranges of eliminated blocks with about equal numbers of
/// neighbours (the product's work), the total last.
fn chunk_bounds(nbr_ptr: &[usize], chunks: usize) -> Vec<usize> {
    let eliminated = nbr_ptr.len() - 1;
    let per_chunk = nbr_ptr[eliminated].div_ceil(chunks.max(1)).max(1);
    let mut bounds = vec![0];
    for (q, &before) in nbr_ptr.iter().enumerate().take(eliminated).skip(1) {
        if before >= per_chunk * bounds.len() {
            bounds.push(q);
        }
    }
    bounds.push(eliminated);
    bounds
}

#[cfg(test)]
mod tests {
    use super::super::kernels::{inverse_times_transpose, subtract_block};
    use super::{chunk_bounds, subtract_one_term};

    #[test]
    fn one_residuals_preconditioner_term_equals_the_product_through_h_je() {
        // J_c 2 × 9, J_e 2 × 3 (column-major), H_ee⁻¹ symmetric positive definite
        let value = |k: usize| ((k * 37 + 11) % 23) as f64 / 7.0 - 1.5;
        let a: Vec<f64> = (0..18).map(value).collect();
        let e: Vec<f64> = (0..6).map(|k| value(k + 40)).collect();
        let inv = [2.0, 0.3, -0.1, 0.3, 1.5, 0.2, -0.1, 0.2, 1.2];
        let mut fast = vec![0.5; 81];
        subtract_one_term::<9, 3, 2>(&a, &e, &inv, &mut fast);
        // H_je = J_cᵀ J_e (9 × 3), u = H_ee⁻¹ H_jeᵀ, block −= H_je u
        let mut hje = [0.0; 27];
        for k in 0..3 {
            for r in 0..9 {
                hje[r + 9 * k] = (0..2).map(|i| a[r * 2 + i] * e[k * 2 + i]).sum();
            }
        }
        let hj = |k: usize| &hje[k * 9..(k + 1) * 9];
        let mut u = [0.0; 27];
        inverse_times_transpose(&inv, hj, &mut u, 3, 9);
        let mut slow = vec![0.5; 81];
        subtract_block(&mut slow, |c| c * 9, hj, &u, (9, 9, 3), true);
        for c in 0..9 {
            for r in 0..=c {
                let (f, s) = (fast[r + 9 * c], slow[r + 9 * c]);
                assert!(
                    (f - s).abs() <= 1e-12 * (1.0 + s.abs()),
                    "({r}, {c}): {f} vs {s}"
                );
            }
        }
        assert!((fast[4 * 9 + 2] - 0.5).abs() > 1e-3, "the block changed");
    }

    #[test]
    fn the_product_chunks_cover_every_eliminated_block_once_with_about_equal_work() {
        // 100 blocks of 1..=10 neighbours
        let mut nbr_ptr = vec![0];
        for q in 0..100 {
            nbr_ptr.push(nbr_ptr[q] + 1 + q % 10);
        }
        for chunks in [1, 2, 4, 7] {
            let bounds = chunk_bounds(&nbr_ptr, chunks);
            assert_eq!((bounds[0], *bounds.last().unwrap()), (0, 100));
            assert!(bounds.windows(2).all(|w| w[0] < w[1]));
            assert!(bounds.len() - 1 <= chunks);
            let work: Vec<usize> = bounds
                .windows(2)
                .map(|w| nbr_ptr[w[1]] - nbr_ptr[w[0]])
                .collect();
            let ideal = nbr_ptr[100].div_ceil(chunks);
            assert!(work.iter().all(|&w| w <= ideal + 10), "{chunks}: {work:?}");
        }
        assert_eq!(chunk_bounds(&[0], 4), vec![0, 0]);
    }
}
