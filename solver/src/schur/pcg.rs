//! The reduced system solved by preconditioned conjugate gradients with implicit products
//! `S x = H_cc x − H_ce (H_ee⁻¹ (H_ec x))` and the block-Jacobi preconditioner diag(S)⁻¹
//! (Agarwal et al., *Bundle Adjustment in the Large*, 2010, sec. 4.3); S is never formed.

use super::kernels::{invert_spd, subtract_block, MAX_PRODUCT};
use super::{ReducedSolver, Schur, SchurOptions};
use crate::block::BlockSparse;
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
    /// H_ee⁻¹ H_ec x for the implicit product, indexed like the eliminated scalars.
    eliminated: Vec<f64>,
    damping: Damping,
    options: SchurOptions,
}

impl Schur {
    /// Copies the H_cc blocks into S's values and inverts the diagonal blocks of S for the
    /// block-Jacobi preconditioner.
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
        let mut pcg = self.take_pcg();
        pcg.damping = damping;
        let out = SyncPtr::new(&mut pcg.preconditioner);
        let offsets = &pcg.precond_offset;
        let this = &*self;
        let s = &this.s;
        let result = (0..this.kept.len())
            .into_par_iter()
            .with_min_len(4)
            .try_for_each(|j| {
                let dj = s.block_dim(j);
                // SAFETY: block j owns its preconditioner range.
                let p = unsafe { out.slice(offsets[j], dj * dj) };
                s.damped_diagonal_block(j, damping, p);
                for t in this.touch_ptr[j]..this.touch_ptr[j + 1] {
                    let (q, nj) = this.touch[t];
                    let de = h.block_dim(this.elim[q]);
                    let mut u = [0.0; MAX_PRODUCT];
                    let u = this.inverse_times_neighbour(q, &this.nbrs[nj], de, dj, &mut u);
                    let hj = &this.hce[this.nbrs[nj].offset..][..dj * de];
                    subtract_block(p, |c| c * dj, hj, u, (dj, dj, de), false);
                }
                invert_spd(p, dj).map_err(|k| h.block_start[this.kept[j]] + k)
            });
        self.reduced = ReducedSolver::Iterative(pcg);
        result
    }

    pub(super) fn take_pcg(&mut self) -> Pcg {
        match std::mem::replace(&mut self.reduced, ReducedSolver::Iterative(Pcg::empty())) {
            ReducedSolver::Iterative(pcg) => pcg,
            ReducedSolver::Factored(_) => unreachable!("only the iterative solver has PCG buffers"),
        }
    }

    /// y = S x = (H_cc + damping) x − H_ce (H_ee⁻¹ (H_ec x)), never forming S.
    pub(super) fn implicit_product(
        &self,
        h: &BlockSparse,
        pcg: &mut Pcg,
        x: &[f64],
        y: &mut [f64],
    ) {
        {
            let tmp = SyncPtr::new(&mut pcg.eliminated);
            (0..self.elim.len())
                .into_par_iter()
                .with_min_len(64)
                .for_each(|q| {
                    let de = h.block_dim(self.elim[q]);
                    // SAFETY: block q owns its range of the eliminated buffer.
                    let out = unsafe { tmp.slice(self.elim_start[q], de) };
                    out.fill(0.0);
                    // tmp_e = −H_ee⁻¹ H_ec x
                    self.eliminated_update(q, de, out, x);
                });
        }
        self.s.multiply(x, y);
        for (&p, (yi, xi)) in self.s.diag_pos.iter().zip(y.iter_mut().zip(x)) {
            let v = self.s.values[p];
            *yi += (pcg.damping.apply(v) - v) * xi;
        }
        let out = SyncPtr::new(y);
        let tmp = &pcg.eliminated;
        (0..self.kept.len())
            .into_par_iter()
            .with_min_len(16)
            .for_each(|j| {
                let (r0, dj) = (self.s.block_start[j], self.s.block_dim(j));
                // SAFETY: block j owns y[r0..r0 + dj].
                let yj = unsafe { out.slice(r0, dj) };
                for &(q, nj) in &self.touch[self.touch_ptr[j]..self.touch_ptr[j + 1]] {
                    let de = h.block_dim(self.elim[q]);
                    let hj = &self.hce[self.nbrs[nj].offset..][..dj * de];
                    for k in 0..de {
                        let t = tmp[self.elim_start[q] + k];
                        for (o, hv) in yj.iter_mut().zip(&hj[k * dj..(k + 1) * dj]) {
                            *o += hv * t;
                        }
                    }
                }
            });
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
        if b_norm > 0.0 {
            self.apply_preconditioner(&pcg, &r, &mut z);
            p.copy_from_slice(&z);
            let mut rz = dot(&r, &z);
            // Q(y) = ½ yᵀS y − bᵀy = −½ yᵀ(b + r) with r = b − S y; Q₀ = 0.
            let mut quadratic = 0.0;
            for iteration in 1..=pcg.options.pcg_max_iterations.max(1) {
                self.implicit_product(ne.h(), &mut pcg, &p, &mut q);
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
    /// Buffers for a reduced system shaped like `s` and `eliminated` eliminated unknowns.
    pub(super) fn new(s: &BlockSparse, eliminated: usize, options: SchurOptions) -> Self {
        let nr = s.dim();
        let mut precond_offset = vec![0];
        for k in 0..s.num_blocks() {
            let d = s.block_dim(k);
            precond_offset.push(precond_offset.last().unwrap() + d * d);
        }
        Self {
            preconditioner: vec![0.0; *precond_offset.last().unwrap()],
            precond_offset,
            r: vec![0.0; nr],
            z: vec![0.0; nr],
            p: vec![0.0; nr],
            q: vec![0.0; nr],
            eliminated: vec![0.0; eliminated],
            damping: Damping::None,
            options,
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
            eliminated: Vec::new(),
            damping: Damping::None,
            options: SchurOptions {
                pcg_tolerance: 0.0,
                pcg_max_iterations: 0,
                pcg_forcing: 0.0,
            },
        }
    }
}
