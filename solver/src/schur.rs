//! The Schur complement: eliminate many small independent blocks, solve for the rest.
//!
//! Split the unknowns into eliminated blocks e (no residual ties two of them, so H_ee is block
//! diagonal; the 3D points of bundle adjustment) and kept blocks c (the cameras). The damped
//! normal equations
//!
//! ```text
//! [ H_cc  H_ce ] [δ_c]   [b_c]
//! [ H_ec  H_ee ] [δ_e] = [b_e]
//! ```
//!
//! reduce to `S δ_c = b_c − H_ce H_ee⁻¹ b_e` with `S = H_cc − H_ce H_ee⁻¹ H_ec`, after which
//! `δ_e = H_ee⁻¹ (b_e − H_ec δ_c)` block by block (Triggs et al., *Bundle Adjustment — A Modern
//! Synthesis*, 2000, sec. 6.1; Agarwal et al., *Bundle Adjustment in the Large*, 2010).
//!
//! S is assembled in parallel over its block columns, each summing its contributions in a fixed
//! order, and factorised by dense or sparse Cholesky (the sparse symbolic analysis done once), or
//! never formed: conjugate gradients with implicit products `S x = H_cc x − H_ce (H_ee⁻¹ (H_ec x))`
//! and the block-Jacobi preconditioner diag(S)⁻¹ (Agarwal et al. 2010, sec. 4.3).

use crate::block::BlockSparse;
use crate::error::SolveError;
use crate::linear::{Cholesky, Damping, LinearSolverKind};
use crate::minimizer::Elimination;
use crate::normal::{dot, NormalEquations, SyncPtr};
use crate::problem::Problem;
use rayon::prelude::*;

/// Marks the H blocks to eliminate: the user's variables, or a greedy maximal independent set of
/// the block graph taken in order of fewest neighbours, then smallest size (Ceres' Schur ordering
/// idea; Li & Saad's independent-set orderings).
pub(crate) fn elimination_set(
    problem: &Problem,
    ne: &NormalEquations,
    elimination: &Elimination,
) -> Result<Vec<bool>, SolveError> {
    let h = &ne.h;
    let nb = h.num_blocks();
    let mut eliminate = vec![false; nb];
    match elimination {
        Elimination::Variables(vars) => {
            for v in vars {
                if v.0 >= problem.variables.len() {
                    return Err(SolveError::LinearSolver(format!(
                        "variable {} marked for elimination does not exist",
                        v.0
                    )));
                }
                let b = ne.block_of_var[v.0];
                if b != usize::MAX {
                    eliminate[b] = true;
                }
            }
        }
        Elimination::Auto => {
            let mut degree = vec![0usize; nb];
            for j in 0..nb {
                for e in &h.entries[h.entry_ptr[j]..h.entry_ptr[j + 1]] {
                    if e.row_block != j {
                        degree[j] += 1;
                        degree[e.row_block] += 1;
                    }
                }
            }
            let mut neighbours: Vec<Vec<usize>> =
                degree.iter().map(|&d| Vec::with_capacity(d)).collect();
            for j in 0..nb {
                for e in &h.entries[h.entry_ptr[j]..h.entry_ptr[j + 1]] {
                    if e.row_block != j {
                        neighbours[j].push(e.row_block);
                        neighbours[e.row_block].push(j);
                    }
                }
            }
            let mut order: Vec<usize> = (0..nb).collect();
            order.sort_by_key(|&b| (degree[b], h.block_dim(b), b));
            let mut blocked = vec![false; nb];
            for b in order {
                if !blocked[b] {
                    eliminate[b] = true;
                    for &n in &neighbours[b] {
                        blocked[n] = true;
                    }
                }
            }
        }
    }
    Ok(eliminate)
}

/// Settings of the iterative Schur solver.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SchurOptions {
    /// Stop when ‖S y − b‖ ≤ tolerance ‖b‖.
    pub pcg_tolerance: f64,
    /// Largest number of conjugate-gradient iterations per solve.
    pub pcg_max_iterations: usize,
}

/// A kept block next to an eliminated one.
#[derive(Clone, Copy, Debug)]
struct Neighbour {
    /// Reduced block index of the kept variable.
    kept: usize,
    /// Offset of H_ce (d_c × d_e, column-major) in its buffer.
    offset: usize,
    /// H entry holding the block, and whether it is stored as H_ec (the kept block comes later).
    h_entry: usize,
    h_column: usize,
    transposed: bool,
}

enum Reduced {
    Factored(Cholesky),
    Iterative(Pcg),
}

/// Buffers of the preconditioned conjugate gradients.
struct Pcg {
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

/// The Schur-complement solver for one structure of the normal equations.
pub(crate) struct Schur {
    kind: LinearSolverKind,
    /// H blocks eliminated, ascending.
    elim: Vec<usize>,
    /// H blocks kept, ascending: reduced block k is H block `kept[k]`.
    kept: Vec<usize>,
    /// Scalar offset of each eliminated block inside the eliminated part, with the total last.
    elim_start: Vec<usize>,
    nbr_ptr: Vec<usize>,
    nbrs: Vec<Neighbour>,
    /// Offset of each eliminated block's H_ee⁻¹ in `hinv`.
    inv_offset: Vec<usize>,
    hinv: Vec<f64>,
    hce: Vec<f64>,
    /// H_ee⁻¹ b_e during a solve, indexed like the eliminated scalars.
    ze: Vec<f64>,
    /// The reduced system (for the iterative solver only its H_cc part).
    s: BlockSparse,
    /// Per reduced column j: (S entry, H entry, H column) of the H_cc blocks copied into S.
    direct_ptr: Vec<usize>,
    direct: Vec<(usize, usize, usize)>,
    /// Per reduced column j: the eliminated blocks next to it, as (eliminated index, index of j's
    /// neighbour record).
    touch_ptr: Vec<usize>,
    touch: Vec<(usize, usize)>,
    /// Per touch (j, q): the S entries of the blocks (i, j) for q's neighbours i ≤ j, in order.
    update_ptr: Vec<usize>,
    update: Vec<usize>,
    /// Point-major assembly (when S is small enough to keep one copy per chunk): per eliminated
    /// block q, the S entries of the blocks (a, b), a ≤ b over q's neighbours, b-major.
    pair_ptr: Vec<usize>,
    pair_entry: Vec<usize>,
    /// Offset of each S entry's block in a chunk's copy, where every block is stored whole and
    /// contiguous (d_i × d_j, column-major), with the total last.
    block_offset: Vec<usize>,
    /// Eliminated-block ranges of the chunks, and one private copy of S's blocks per chunk.
    chunk_bounds: Vec<usize>,
    chunk_values: Vec<Vec<f64>>,
    /// One private reduced right-hand side per chunk.
    chunk_rhs: Vec<Vec<f64>>,
    reduced: Reduced,
    rhs: Vec<f64>,
}

/// Chunks of the point-major assembly: a fixed number, so the sums do not depend on the threads.
const CHUNKS: usize = 4;
/// Largest number of S values for which the point-major assembly keeps its per-chunk copies.
const POINT_MAJOR_VALUES: usize = 1 << 21;

impl Schur {
    /// Lays out the elimination of the H blocks marked in `eliminate` from `ne`'s structure.
    pub fn new(
        ne: &NormalEquations,
        eliminate: &[bool],
        kind: LinearSolverKind,
        dense_threshold: usize,
        options: SchurOptions,
    ) -> Result<Self, SolveError> {
        let h = &ne.h;
        let nb = h.num_blocks();
        debug_assert_eq!(eliminate.len(), nb);
        let elim: Vec<usize> = (0..nb).filter(|&b| eliminate[b]).collect();
        let kept: Vec<usize> = (0..nb).filter(|&b| !eliminate[b]).collect();
        let mut reduced_of = vec![usize::MAX; nb];
        let mut elim_of = vec![usize::MAX; nb];
        for (k, &b) in kept.iter().enumerate() {
            reduced_of[b] = k;
        }
        for (q, &b) in elim.iter().enumerate() {
            elim_of[b] = q;
        }
        // Neighbours of the eliminated blocks, from both halves of the symmetric pattern.
        let mut adjacency: Vec<Vec<(usize, usize, usize, bool)>> = vec![Vec::new(); elim.len()];
        for j in 0..nb {
            for e in h.entry_ptr[j]..h.entry_ptr[j + 1] {
                let i = h.entries[e].row_block;
                if i == j {
                    continue;
                }
                match (eliminate[i], eliminate[j]) {
                    (true, true) => {
                        return Err(SolveError::LinearSolver(format!(
                            "variables {} and {} are both marked for elimination but share a \
                             residual: eliminated variables must be independent",
                            ne.var_of_block[i], ne.var_of_block[j]
                        )))
                    }
                    // H_ij with i eliminated, j kept: stored as H_ec.
                    (true, false) => adjacency[elim_of[i]].push((reduced_of[j], e, j, true)),
                    (false, true) => adjacency[elim_of[j]].push((reduced_of[i], e, j, false)),
                    (false, false) => {}
                }
            }
        }
        let dim = |b: usize| h.block_dim(b);
        let mut nbr_ptr = vec![0];
        let mut nbrs = Vec::new();
        let mut elim_start = vec![0];
        let mut inv_offset = Vec::with_capacity(elim.len());
        let (mut inv_len, mut buf_len) = (0, 0);
        for (q, list) in adjacency.iter_mut().enumerate() {
            list.sort_unstable_by_key(|n| n.0);
            let de = dim(elim[q]);
            let widest = list.iter().map(|n| dim(kept[n.0])).max().unwrap_or(0);
            if de > MAX_ELIMINATED || de * widest > MAX_PRODUCT {
                return Err(SolveError::LinearSolver(format!(
                    "variable {} ({de} unknowns, next to a variable of {widest}) is too large to \
                     eliminate: the Schur solvers take eliminated variables of at most \
                     {MAX_ELIMINATED} unknowns and products of sizes up to {MAX_PRODUCT}; use \
                     the sparse Cholesky",
                    ne.var_of_block[elim[q]]
                )));
            }
            for &(k, h_entry, h_column, transposed) in list.iter() {
                nbrs.push(Neighbour {
                    kept: k,
                    offset: buf_len,
                    h_entry,
                    h_column,
                    transposed,
                });
                buf_len += dim(kept[k]) * de;
            }
            nbr_ptr.push(nbrs.len());
            inv_offset.push(inv_len);
            inv_len += de * de;
            elim_start.push(elim_start.last().unwrap() + de);
        }
        // Which eliminated blocks touch each reduced column.
        let mut touch_lists: Vec<Vec<(usize, usize)>> = vec![Vec::new(); kept.len()];
        for q in 0..elim.len() {
            for n in nbr_ptr[q]..nbr_ptr[q + 1] {
                touch_lists[nbrs[n].kept].push((q, n));
            }
        }
        let iterative = kind == LinearSolverKind::SchurIterative;
        // Pattern of S: the H_cc blocks, and (unless iterative) every pair of kept blocks that
        // share an eliminated neighbour.
        let mut columns: Vec<Vec<usize>> = vec![Vec::new(); kept.len()];
        for (k, &b) in kept.iter().enumerate() {
            for e in h.entry_ptr[b]..h.entry_ptr[b + 1] {
                let i = h.entries[e].row_block;
                if !eliminate[i] {
                    columns[k].push(reduced_of[i]);
                }
            }
        }
        if !iterative {
            for (j, list) in touch_lists.iter().enumerate() {
                for &(q, n) in list {
                    columns[j].extend(nbrs[nbr_ptr[q]..=n].iter().map(|x| x.kept));
                }
            }
        }
        for c in columns.iter_mut() {
            c.sort_unstable();
            c.dedup();
        }
        let mut reduced_start = vec![0];
        for &b in &kept {
            reduced_start.push(reduced_start.last().unwrap() + dim(b));
        }
        let s = BlockSparse::new(reduced_start, &columns);
        let mut direct_ptr = vec![0];
        let mut direct = Vec::new();
        for (k, &b) in kept.iter().enumerate() {
            for e in h.entry_ptr[b]..h.entry_ptr[b + 1] {
                let i = h.entries[e].row_block;
                if !eliminate[i] {
                    let se = s.find(reduced_of[i], k).expect("H_cc block in S's pattern");
                    direct.push((se, e, b));
                }
            }
            direct_ptr.push(direct.len());
        }
        let point_major = !iterative && s.values.len() <= POINT_MAJOR_VALUES && !elim.is_empty();
        let mut pair_ptr = vec![0];
        let mut pair_entry = Vec::new();
        let mut chunk_bounds = vec![0];
        if point_major {
            for q in 0..elim.len() {
                let list = &nbrs[nbr_ptr[q]..nbr_ptr[q + 1]];
                for (b, nb) in list.iter().enumerate() {
                    for na in &list[..=b] {
                        pair_entry
                            .push(s.find(na.kept, nb.kept).expect("pair block in S's pattern"));
                    }
                }
                pair_ptr.push(pair_entry.len());
            }
            // Chunks of about equal work (pairs), boundaries at block starts.
            let per_chunk = pair_entry.len().div_ceil(CHUNKS).max(1);
            for q in 0..elim.len() {
                if pair_ptr[q + 1] >= per_chunk * chunk_bounds.len() && q + 1 < elim.len() {
                    chunk_bounds.push(q + 1);
                }
            }
            chunk_bounds.push(elim.len());
        }
        let mut block_offset = vec![0];
        if point_major {
            for j in 0..kept.len() {
                for e in &s.entries[s.entry_ptr[j]..s.entry_ptr[j + 1]] {
                    let size = s.block_dim(e.row_block) * s.block_dim(j);
                    block_offset.push(block_offset.last().unwrap() + size);
                }
            }
        }
        let chunk_values = vec![vec![0.0; *block_offset.last().unwrap()]; chunk_bounds.len() - 1];
        let chunk_rhs = vec![vec![0.0; s.dim()]; chunk_bounds.len() - 1];
        let mut touch_ptr = vec![0];
        let mut touch = Vec::new();
        let mut update_ptr = vec![0];
        let mut update = Vec::new();
        for (j, list) in touch_lists.iter().enumerate() {
            for &(q, n) in list {
                touch.push((q, n));
                if !iterative && !point_major {
                    for x in &nbrs[nbr_ptr[q]..=n] {
                        update.push(s.find(x.kept, j).expect("update block in S's pattern"));
                    }
                }
                update_ptr.push(update.len());
            }
            touch_ptr.push(touch.len());
        }
        let reduced = if iterative {
            let nr = s.dim();
            let mut precond_offset = vec![0];
            for k in 0..kept.len() {
                let d = s.block_dim(k);
                precond_offset.push(precond_offset.last().unwrap() + d * d);
            }
            Reduced::Iterative(Pcg {
                preconditioner: vec![0.0; *precond_offset.last().unwrap()],
                precond_offset,
                r: vec![0.0; nr],
                z: vec![0.0; nr],
                p: vec![0.0; nr],
                q: vec![0.0; nr],
                eliminated: vec![0.0; *elim_start.last().unwrap()],
                damping: Damping::None,
                options,
            })
        } else {
            let dense = match kind {
                LinearSolverKind::SchurDense => true,
                LinearSolverKind::SchurSparse => false,
                _ => s.dim() <= dense_threshold,
            };
            Reduced::Factored(Cholesky::new(&s, dense)?)
        };
        let kind = match (&reduced, kind) {
            (Reduced::Factored(c), LinearSolverKind::Schur) => {
                if c.is_sparse() {
                    LinearSolverKind::SchurSparse
                } else {
                    LinearSolverKind::SchurDense
                }
            }
            (_, k) => k,
        };
        let elim_scalars = *elim_start.last().unwrap();
        Ok(Self {
            kind,
            rhs: vec![0.0; s.dim()],
            elim,
            kept,
            elim_start,
            nbr_ptr,
            nbrs,
            inv_offset,
            hinv: vec![0.0; inv_len],
            hce: vec![0.0; buf_len],
            ze: vec![0.0; elim_scalars],
            s,
            direct_ptr,
            direct,
            touch_ptr,
            touch,
            update_ptr,
            update,
            pair_ptr,
            pair_entry,
            block_offset,
            chunk_bounds,
            chunk_values,
            chunk_rhs,
            reduced,
        })
    }

    /// "schur-dense", "schur-sparse" or "schur-iterative".
    pub fn name(&self) -> &'static str {
        match self.kind {
            LinearSolverKind::SchurIterative => "schur-iterative",
            LinearSolverKind::SchurSparse => "schur-sparse",
            _ => "schur-dense",
        }
    }

    /// True unless the reduced system is solved iteratively.
    pub fn is_exact(&self) -> bool {
        matches!(self.reduced, Reduced::Factored(_))
    }

    /// Inverts the damped H_ee blocks and gathers the H_ce blocks, then forms S (or the
    /// preconditioner) and factorises it. On failure returns the H scalar index where definiteness failed.
    pub fn factor(&mut self, ne: &NormalEquations, damping: Damping) -> Result<(), usize> {
        let h = &ne.h;
        let hinv = SyncPtr::new(&mut self.hinv);
        let hce = SyncPtr::new(&mut self.hce);
        let (elim, nbrs, nbr_ptr, inv_offset, kept) = (
            &self.elim,
            &self.nbrs,
            &self.nbr_ptr,
            &self.inv_offset,
            &self.kept,
        );
        (0..elim.len())
            .into_par_iter()
            .with_min_len(64)
            .try_for_each(|q| {
                let b = elim[q];
                let de = h.block_dim(b);
                // SAFETY: block q owns its ranges of hinv and hce.
                let inv = unsafe { hinv.slice(inv_offset[q], de * de) };
                h.damped_diagonal_block(b, damping, inv);
                if let Err(k) = invert_spd(inv, de) {
                    return Err(h.block_start[b] + k);
                }
                for n in &nbrs[nbr_ptr[q]..nbr_ptr[q + 1]] {
                    let dc = h.block_dim(kept[n.kept]);
                    let block = unsafe { hce.slice(n.offset, dc * de) };
                    if n.transposed {
                        for r in 0..dc {
                            let from = h.column_start(n.h_column, n.h_entry, r);
                            for k in 0..de {
                                block[r + k * dc] = h.values[from + k];
                            }
                        }
                    } else {
                        for k in 0..de {
                            let from = h.column_start(n.h_column, n.h_entry, k);
                            block[k * dc..(k + 1) * dc].copy_from_slice(&h.values[from..from + dc]);
                        }
                    }
                }
                Ok(())
            })?;
        if self.is_exact() {
            self.assemble(ne, damping);
        } else {
            self.precondition(ne, damping)?;
        }
        let (s, kept) = (&self.s, &self.kept);
        match &mut self.reduced {
            Reduced::Factored(chol) => chol.factor(s, Damping::None).map_err(|i| {
                let k = s.block_of_scalar(i);
                h.block_start[kept[k]] + (i - s.block_start[k])
            }),
            Reduced::Iterative(_) => Ok(()),
        }
    }

    /// S = H_cc + damping − Σ_e H_ce H_ee⁻¹ H_ec: point-major into per-chunk copies when S is small,
    /// else in parallel over S's block columns. Both sum in a fixed order.
    fn assemble(&mut self, ne: &NormalEquations, damping: Damping) {
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
    fn assemble_by_points(&mut self, ne: &NormalEquations, damping: Damping) {
        let h = &ne.h;
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
                    let u = this.inverse_times_neighbour(q, nb, de, dj, &mut u);
                    for na in list {
                        if na.kept > j {
                            break;
                        }
                        let se = *entries.next().expect("one S entry per pair");
                        let di = s.block_dim(na.kept);
                        let hi = &this.hce[na.offset..][..di * de];
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
    fn assemble_by_columns(&mut self, ne: &NormalEquations, damping: Damping) {
        let h = &ne.h;
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
                    let u = this.inverse_times_neighbour(q, &this.nbrs[nj], de, dj, &mut u);
                    let first = this.nbr_ptr[q];
                    for (x, &se) in this.update[this.update_ptr[t]..this.update_ptr[t + 1]]
                        .iter()
                        .enumerate()
                    {
                        let ni = this.nbrs[first + x];
                        let di = s.block_dim(ni.kept);
                        let hi = &this.hce[ni.offset..][..di * de];
                        let diagonal = ni.kept == j;
                        let starts = |c: usize| s.column_start(j, se, c) - c0;
                        subtract_block(column, starts, hi, u, (di, dj, de), diagonal);
                    }
                }
            });
    }

    /// Calls `put(position in S's values, value)` for every element of the (damped) H_cc blocks
    /// of reduced column j.
    fn copy_direct(
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
                            damping.apply(v)
                        } else {
                            v
                        },
                    );
                }
            }
        }
    }

    /// Copies the H_cc blocks into S's values and inverts the diagonal blocks of S for the
    /// block-Jacobi preconditioner.
    fn precondition(&mut self, ne: &NormalEquations, damping: Damping) -> Result<(), usize> {
        let h = &ne.h;
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
        self.reduced = Reduced::Iterative(pcg);
        result
    }

    fn take_pcg(&mut self) -> Pcg {
        match std::mem::replace(&mut self.reduced, Reduced::Iterative(Pcg::empty())) {
            Reduced::Iterative(pcg) => pcg,
            Reduced::Factored(_) => unreachable!("only the iterative solver has PCG buffers"),
        }
    }

    /// Solves the damped system for the right-hand side `x` (H's scalar order), in place.
    pub fn solve(&mut self, ne: &NormalEquations, x: &mut [f64]) {
        let h = &ne.h;
        if self.chunk_rhs.is_empty() {
            self.reduce_rhs_by_columns(h, x);
        } else {
            self.reduce_rhs_by_points(h, x);
        }
        let mut rhs = std::mem::take(&mut self.rhs);
        match &mut self.reduced {
            Reduced::Factored(chol) => chol.solve(&mut rhs),
            Reduced::Iterative(_) => self.conjugate_gradients(ne, &mut rhs),
        }
        // δ_e = H_ee⁻¹ (b_e − H_ec δ_c), then δ_c into place.
        {
            let out = SyncPtr::new(x);
            let this = &*self;
            let y = &rhs;
            (0..this.elim.len())
                .into_par_iter()
                .with_min_len(64)
                .for_each(|q| {
                    let b = this.elim[q];
                    let (e0, de) = (h.block_start[b], h.block_dim(b));
                    // SAFETY: eliminated block q owns x[e0..e0 + de]; kept ranges are not read.
                    let xe = unsafe { out.slice(e0, de) };
                    this.eliminated_update(q, de, xe, y);
                });
        }
        for (k, &b) in self.kept.iter().enumerate() {
            let (h0, r0, d) = (h.block_start[b], self.s.block_start[k], self.s.block_dim(k));
            x[h0..h0 + d].copy_from_slice(&rhs[r0..r0 + d]);
        }
        self.rhs = rhs;
    }

    /// b_c − Σ_e H_ce H_ee⁻¹ b_e point-major: each chunk streams through its eliminated blocks and
    /// subtracts into its own copy; the copies are summed in chunk order.
    fn reduce_rhs_by_points(&mut self, h: &BlockSparse, x: &[f64]) {
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
                    let hb = &this.hce[n.offset..][..dc * de];
                    let o = &mut out[c0..c0 + dc];
                    for (k, zk) in z[..de].iter().enumerate() {
                        for (ov, hv) in o.iter_mut().zip(&hb[k * dc..(k + 1) * dc]) {
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
    fn reduce_rhs_by_columns(&mut self, h: &BlockSparse, x: &[f64]) {
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
                    let hj = &this.hce[this.nbrs[nj].offset..][..dj * de];
                    let z = &this.ze[this.elim_start[q]..][..de];
                    for (k, zk) in z.iter().enumerate() {
                        for (o, hv) in out.iter_mut().zip(&hj[k * dj..(k + 1) * dj]) {
                            *o -= hv * zk;
                        }
                    }
                }
            });
        }
    }

    /// u = H_ee⁻¹ H_jeᵀ (d_e × d_j) for eliminated block q and its neighbour j, written into the
    /// front of `scratch`.
    #[inline(always)]
    fn inverse_times_neighbour<'a>(
        &'a self,
        q: usize,
        n: &Neighbour,
        de: usize,
        dj: usize,
        scratch: &'a mut [f64; MAX_PRODUCT],
    ) -> &'a [f64] {
        let hj = &self.hce[n.offset..][..dj * de];
        let inv = &self.hinv[self.inv_offset[q]..][..de * de];
        let u = &mut scratch[..de * dj];
        inverse_times_transpose(inv, hj, u, de, dj);
        u
    }

    /// `v ← H_ee⁻¹ (v − H_ec y)` for eliminated block q (d_e unknowns), y in reduced order.
    fn eliminated_update(&self, q: usize, de: usize, v: &mut [f64], y: &[f64]) {
        let mut t = [0.0f64; MAX_ELIMINATED];
        let t = &mut t[..de];
        t.copy_from_slice(v);
        for n in &self.nbrs[self.nbr_ptr[q]..self.nbr_ptr[q + 1]] {
            let (c0, dc) = (self.s.block_start[n.kept], self.s.block_dim(n.kept));
            let hb = &self.hce[n.offset..][..dc * de];
            for (k, tk) in t.iter_mut().enumerate() {
                *tk -= dot(&hb[k * dc..(k + 1) * dc], &y[c0..c0 + dc]);
            }
        }
        let inv = &self.hinv[self.inv_offset[q]..][..de * de];
        for (r, o) in v.iter_mut().enumerate() {
            *o = (0..de).map(|k| inv[r + k * de] * t[k]).sum();
        }
    }

    /// y = S x = (H_cc + damping) x − H_ce (H_ee⁻¹ (H_ec x)), never forming S.
    fn implicit_product(&self, h: &BlockSparse, pcg: &mut Pcg, x: &[f64], y: &mut [f64]) {
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
    fn conjugate_gradients(&mut self, ne: &NormalEquations, b: &mut [f64]) {
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
            for _ in 0..pcg.options.pcg_max_iterations.max(1) {
                self.implicit_product(&ne.h, &mut pcg, &p, &mut q);
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
        self.reduced = Reduced::Iterative(pcg);
    }

    fn apply_preconditioner(&self, pcg: &Pcg, r: &[f64], z: &mut [f64]) {
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
            },
        }
    }
}

/// Largest d_e × d_c product of an eliminated and a kept block's sizes (the scratch of one
/// H_ee⁻¹ H_ecᵀ block lives on the stack).
pub(crate) const MAX_PRODUCT: usize = 256;
/// Largest size of an eliminated block (its scratch vectors live on the stack).
pub(crate) const MAX_ELIMINATED: usize = 16;

/// u = H_ee⁻¹ H_jᵀ (d_e × d_j) from the symmetric inverse (d_e × d_e) and H_j (d_j × d_e), all
/// column-major.
#[inline(always)]
fn inverse_times_transpose(inv: &[f64], hj: &[f64], u: &mut [f64], de: usize, dj: usize) {
    match (de, dj) {
        (3, 9) => inverse_times_transpose_fixed::<3, 9>(inv, hj, u),
        (3, 6) => inverse_times_transpose_fixed::<3, 6>(inv, hj, u),
        _ => inverse_times_transpose_any(inv, hj, u, de, dj),
    }
}

#[inline(always)]
fn inverse_times_transpose_fixed<const DE: usize, const DJ: usize>(
    inv: &[f64],
    hj: &[f64],
    u: &mut [f64],
) {
    let (inv, hj, u) = (&inv[..DE * DE], &hj[..DJ * DE], &mut u[..DE * DJ]);
    for c in 0..DJ {
        let mut acc = [0.0f64; DE];
        for k in 0..DE {
            let h = hj[c + k * DJ];
            for (a, iv) in acc.iter_mut().zip(&inv[k * DE..(k + 1) * DE]) {
                *a += iv * h;
            }
        }
        u[c * DE..(c + 1) * DE].copy_from_slice(&acc);
    }
}

fn inverse_times_transpose_any(inv: &[f64], hj: &[f64], u: &mut [f64], de: usize, dj: usize) {
    for c in 0..dj {
        for r in 0..de {
            u[r + c * de] = (0..de).map(|k| inv[r + k * de] * hj[c + k * dj]).sum();
        }
    }
}

/// S_ij −= H_i u for one block, with H_i d_i × d_e and u = H_ee⁻¹ H_jᵀ d_e × d_j (column-major);
/// column c of the block starts at `out[starts(c)]` (only rows ≤ c on the diagonal). The common
/// sizes run through a fixed-size kernel.
#[inline(always)]
fn subtract_block(
    out: &mut [f64],
    starts: impl Fn(usize) -> usize,
    hi: &[f64],
    u: &[f64],
    (di, dj, de): (usize, usize, usize),
    diagonal: bool,
) {
    match (di, dj, de) {
        (9, 9, 3) => subtract_fixed::<9, 9, 3>(out, starts, hi, u, diagonal),
        (6, 6, 3) => subtract_fixed::<6, 6, 3>(out, starts, hi, u, diagonal),
        _ => {
            for c in 0..dj {
                let start = starts(c);
                let rows = if diagonal { c + 1 } else { di };
                let o = &mut out[start..start + rows];
                for k in 0..de {
                    let uv = u[k + c * de];
                    for (ov, hv) in o.iter_mut().zip(&hi[k * di..k * di + rows]) {
                        *ov -= hv * uv;
                    }
                }
            }
        }
    }
}

/// [`subtract_block`] for fixed sizes, each column formed in registers first.
#[inline(always)]
fn subtract_fixed<const DI: usize, const DJ: usize, const DE: usize>(
    out: &mut [f64],
    starts: impl Fn(usize) -> usize,
    hi: &[f64],
    u: &[f64],
    diagonal: bool,
) {
    let (hi, u) = (&hi[..DI * DE], &u[..DE * DJ]);
    for c in 0..DJ {
        let mut acc = [0.0f64; DI];
        for k in 0..DE {
            let uv = u[k + c * DE];
            for (a, hv) in acc.iter_mut().zip(&hi[k * DI..(k + 1) * DI]) {
                *a += hv * uv;
            }
        }
        let start = starts(c);
        if diagonal {
            for (o, a) in out[start..start + c + 1].iter_mut().zip(&acc) {
                *o -= a;
            }
        } else {
            let o: &mut [f64; DI] = (&mut out[start..start + DI]).try_into().expect("DI rows");
            for (o, a) in o.iter_mut().zip(&acc) {
                *o -= a;
            }
        }
    }
}

/// Inverts a symmetric positive definite `d × d` matrix in place by Gauss-Jordan elimination
/// (no pivoting is needed for such matrices: every pivot is a Schur complement's diagonal).
/// On a pivot that is not clearly positive returns its index.
pub(crate) fn invert_spd(a: &mut [f64], d: usize) -> Result<(), usize> {
    let scale = (0..d).map(|i| a[i + i * d].abs()).fold(0.0f64, f64::max);
    for k in 0..d {
        let pivot = a[k + k * d];
        if pivot.is_nan() || pivot <= 1e-13 * scale || !pivot.is_finite() {
            return Err(k);
        }
        let inv = 1.0 / pivot;
        a[k + k * d] = 1.0;
        for j in 0..d {
            a[k + j * d] *= inv;
        }
        for i in 0..d {
            if i == k {
                continue;
            }
            let f = a[i + k * d];
            if f == 0.0 {
                continue;
            }
            a[i + k * d] = 0.0;
            for j in 0..d {
                a[i + j * d] -= f * a[k + j * d];
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gauss_jordan_inverts_a_positive_definite_matrix() {
        let m = [4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 2.0];
        let mut inv = m;
        invert_spd(&mut inv, 3).unwrap();
        for r in 0..3 {
            for c in 0..3 {
                let v: f64 = (0..3).map(|k| m[r + k * 3] * inv[k + c * 3]).sum();
                assert!((v - if r == c { 1.0 } else { 0.0 }).abs() < 1e-14);
            }
        }
        let mut singular = [1.0, 1.0, 1.0, 1.0];
        assert_eq!(invert_spd(&mut singular, 2), Err(1));
    }
}
