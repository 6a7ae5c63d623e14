//! Forming S = H_cc + damping − Σ_e H_ce H_ee⁻¹ H_ec and the reduced right-hand side
//! b_c − Σ_e H_ce H_ee⁻¹ b_e, point-major into per-chunk copies or column-major, each in a fixed
//! summation order.

use super::kernels::{subtract_block, MAX_ELIMINATED, MAX_PRODUCT};
use super::Schur;
use crate::block::BlockSparse;
use crate::damping::Damping;
use crate::normal::NormalEquations;
use crate::parallel::SyncPtr;
use rayon::prelude::*;

impl Schur {
    /// S = H_cc + damping − Σ_e H_ce H_ee⁻¹ H_ec: point-major into per-chunk copies when S is small,
    /// else in parallel over S's block columns. Both sum in a fixed order.
    pub(super) fn assemble(&mut self, ne: &NormalEquations, damping: Damping) {
        if self.chunk_values.is_empty() {
            self.assemble_by_columns(ne, damping);
        } else {
            self.assemble_by_points(ne, damping);
        }
    }

    /// Each chunk of eliminated blocks subtracts its H_ae H_ee⁻¹ H_beᵀ into its own copy of S's
    /// blocks, streaming through H_ce once (H_ee⁻¹ H_beᵀ formed per block on the fly); the copies
    /// are then summed in chunk order onto H_cc.
    ///
    /// A chunk's copy stores every block whole and contiguous, diagonal blocks with both
    /// triangles: the updates need no masked stores and a block is a few adjacent cache lines.
    pub(super) fn assemble_by_points(&mut self, ne: &NormalEquations, damping: Damping) {
        let h = ne.h();
        let mut chunks = std::mem::take(&mut self.chunk_values);
        let this = &*self;
        let s = &this.s;
        chunks.par_iter_mut().enumerate().for_each(|(k, values)| {
            values.fill(0.0);
            for q in this.chunk_bounds[k]..this.chunk_bounds[k + 1] {
                let de = h.block_dim(this.elim[q]);
                let mut u = [0.0; MAX_PRODUCT];
                let list = &this.nbrs[this.nbr_ptr[q]..this.nbr_ptr[q + 1]];
                let mut entries = this.pair_entry[this.pair_ptr[q]..this.pair_ptr[q + 1]].iter();
                for nb in list {
                    let (j, dj) = (nb.kept, s.block_dim(nb.kept));
                    let hj = |k| this.hce_column(nb, dj, k);
                    let u = this.inverse_times_neighbour(q, hj, (de, dj), &mut u);
                    for na in list {
                        if na.kept > j {
                            break;
                        }
                        let se = *entries.next().expect("one S entry per pair");
                        let di = s.block_dim(na.kept);
                        let hi = |k| this.hce_column(na, di, k);
                        let at = this.block_offset[se];
                        let block = &mut values[at..at + di * dj];
                        subtract_block(block, |c| c * di, hi, u, (di, dj, de), false);
                    }
                }
            }
        });
        let mut values = std::mem::take(&mut self.s.values);
        values.fill(0.0);
        for j in 0..self.kept.len() {
            self.copy_direct(h, j, damping, |at, v| values[at] = v);
        }
        let out = SyncPtr::new(&mut values);
        let (s, block_offset) = (&self.s, &self.block_offset);
        (0..self.kept.len())
            .into_par_iter()
            .with_min_len(4)
            .for_each(|j| {
                let dj = s.block_dim(j);
                let range = s.entry_ptr[j]..s.entry_ptr[j + 1];
                for (se, &offset) in range.clone().zip(&block_offset[range]) {
                    let i = s.entries[se].row_block;
                    let di = s.block_dim(i);
                    for c in 0..dj {
                        let rows = if i == j { c + 1 } else { di };
                        // SAFETY: the column segment belongs to S block column j only.
                        let o = unsafe { out.slice(s.column_start(j, se, c), rows) };
                        let from = offset + c * di;
                        for chunk in &chunks {
                            for (o, v) in o.iter_mut().zip(&chunk[from..from + rows]) {
                                *o += v;
                            }
                        }
                    }
                }
            });
        self.s.values = values;
        self.chunk_values = chunks;
    }

    /// Column-major assembly: each S block column sums its contributions in a fixed order.
    pub(super) fn assemble_by_columns(&mut self, ne: &NormalEquations, damping: Damping) {
        let h = ne.h();
        let values = SyncPtr::new(&mut self.s.values);
        let this = &*self;
        let s = &this.s;
        (0..this.kept.len())
            .into_par_iter()
            .with_min_len(4)
            .for_each(|j| {
                let dj = s.block_dim(j);
                let (c0, c1) = (s.col_ptr[s.block_start[j]], s.col_ptr[s.block_start[j + 1]]);
                // SAFETY: block column j owns values[c0..c1].
                let column = unsafe { values.slice(c0, c1 - c0) };
                column.fill(0.0);
                this.copy_direct(h, j, damping, |at, v| column[at - c0] = v);
                for t in this.touch_ptr[j]..this.touch_ptr[j + 1] {
                    let (q, nj) = this.touch[t];
                    let de = h.block_dim(this.elim[q]);
                    let mut u = [0.0; MAX_PRODUCT];
                    let hj = |k| this.hce_column(&this.nbrs[nj], dj, k);
                    let u = this.inverse_times_neighbour(q, hj, (de, dj), &mut u);
                    let first = this.nbr_ptr[q];
                    for (x, &se) in this.update[this.update_ptr[t]..this.update_ptr[t + 1]]
                        .iter()
                        .enumerate()
                    {
                        let ni = this.nbrs[first + x];
                        let di = s.block_dim(ni.kept);
                        let hi = |k| this.hce_column(&ni, di, k);
                        let diagonal = ni.kept == j;
                        let starts = |c: usize| s.column_start(j, se, c) - c0;
                        subtract_block(column, starts, hi, u, (di, dj, de), diagonal);
                    }
                }
            });
    }

    /// Calls `put(position in S's values, value)` for every element of the (damped) H_cc blocks
    /// of reduced column j.
    pub(super) fn copy_direct(
        &self,
        h: &BlockSparse,
        j: usize,
        damping: Damping,
        mut put: impl FnMut(usize, f64),
    ) {
        let s = &self.s;
        let dj = s.block_dim(j);
        for &(se, he, hc) in &self.direct[self.direct_ptr[j]..self.direct_ptr[j + 1]] {
            let diagonal = s.entries[se].row_block == j;
            let di = s.block_dim(s.entries[se].row_block);
            for c in 0..dj {
                let rows = if diagonal { c + 1 } else { di };
                let (from, to) = (h.column_start(hc, he, c), s.column_start(j, se, c));
                for r in 0..rows {
                    let v = h.values[from + r];
                    put(
                        to + r,
                        if diagonal && r == c {
                            h.damped(damping, h.block_start[hc] + c, v)
                        } else {
                            v
                        },
                    );
                }
            }
        }
    }

    /// b_c − Σ_e H_ce H_ee⁻¹ b_e point-major: each chunk streams through its eliminated blocks and
    /// subtracts into its own copy; the copies are summed in chunk order.
    pub(super) fn reduce_rhs_by_points(&mut self, h: &BlockSparse, x: &[f64]) {
        let mut chunks = std::mem::take(&mut self.chunk_rhs);
        let this = &*self;
        chunks.par_iter_mut().enumerate().for_each(|(k, out)| {
            out.fill(0.0);
            for q in this.chunk_bounds[k]..this.chunk_bounds[k + 1] {
                let b = this.elim[q];
                let (e0, de) = (h.block_start[b], h.block_dim(b));
                let inv = &this.hinv[this.inv_offset[q]..][..de * de];
                let mut z = [0.0f64; MAX_ELIMINATED];
                for (r, zr) in z[..de].iter_mut().enumerate() {
                    *zr = (0..de).map(|k| inv[r + k * de] * x[e0 + k]).sum();
                }
                for n in &this.nbrs[this.nbr_ptr[q]..this.nbr_ptr[q + 1]] {
                    let (c0, dc) = (this.s.block_start[n.kept], this.s.block_dim(n.kept));
                    let o = &mut out[c0..c0 + dc];
                    for (k, zk) in z[..de].iter().enumerate() {
                        for (ov, hv) in o.iter_mut().zip(this.hce_column(n, dc, k)) {
                            *ov += hv * zk;
                        }
                    }
                }
            }
        });
        for (j, &b) in self.kept.iter().enumerate() {
            let (r0, h0, d) = (self.s.block_start[j], h.block_start[b], self.s.block_dim(j));
            for i in 0..d {
                let mut v = x[h0 + i];
                for chunk in &chunks {
                    v -= chunk[r0 + i];
                }
                self.rhs[r0 + i] = v;
            }
        }
        self.chunk_rhs = chunks;
    }

    /// b_c − Σ_e H_ce H_ee⁻¹ b_e in parallel over the kept blocks.
    pub(super) fn reduce_rhs_by_columns(&mut self, h: &BlockSparse, x: &[f64]) {
        {
            let ze = SyncPtr::new(&mut self.ze);
            let this = &*self;
            let xs = x;
            (0..this.elim.len())
                .into_par_iter()
                .with_min_len(256)
                .for_each(|q| {
                    let b = this.elim[q];
                    let (e0, de) = (h.block_start[b], h.block_dim(b));
                    // SAFETY: block q owns its range of ze.
                    let out = unsafe { ze.slice(this.elim_start[q], de) };
                    let inv = &this.hinv[this.inv_offset[q]..][..de * de];
                    for (r, o) in out.iter_mut().enumerate() {
                        *o = (0..de).map(|k| inv[r + k * de] * xs[e0 + k]).sum();
                    }
                });
        }
        {
            let rhs = SyncPtr::new(&mut self.rhs);
            let this = &*self;
            let xs = x;
            (0..this.kept.len()).into_par_iter().for_each(|j| {
                let (r0, dj) = (this.s.block_start[j], this.s.block_dim(j));
                // SAFETY: block j owns rhs[r0..r0 + dj].
                let out = unsafe { rhs.slice(r0, dj) };
                let h0 = h.block_start[this.kept[j]];
                out.copy_from_slice(&xs[h0..h0 + dj]);
                for &(q, nj) in &this.touch[this.touch_ptr[j]..this.touch_ptr[j + 1]] {
                    let de = h.block_dim(this.elim[q]);
                    let n = &this.nbrs[nj];
                    let z = &this.ze[this.elim_start[q]..][..de];
                    for (k, zk) in z.iter().enumerate() {
                        for (o, hv) in out.iter_mut().zip(this.hce_column(n, dj, k)) {
                            *o -= hv * zk;
                        }
                    }
                }
            });
        }
    }
}
