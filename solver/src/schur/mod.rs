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

mod assembly;
pub(crate) mod kernels;
mod layout;
mod pcg;
mod reach;
mod single;

pub(crate) use kernels::invert_spd;
use kernels::{inverse_times_transpose, MAX_ELIMINATED, MAX_PRODUCT};
use layout::{Neighbours, PointMajor, Split, Touches};
use pcg::Pcg;
use single::SingleJacobians;

use crate::block::BlockSparse;
use crate::cholesky::{Analysed, Cholesky, FactorPrecision};
use crate::damping::Damping;
use crate::error::SolveError;
use crate::normal::NormalEquations;
use crate::options::LinearSolverKind;
use crate::parallel::{dot, SyncPtr};
use rayon::prelude::*;

/// Settings of the iterative Schur solver.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SchurOptions {
    /// Stop when ‖S y − b‖ ≤ tolerance ‖b‖.
    pub pcg_tolerance: f64,
    /// Largest number of conjugate-gradient iterations per solve.
    pub pcg_max_iterations: usize,
    /// Truncated-Newton forcing η (see [`crate::Options::pcg_forcing`]); 0 disables.
    pub pcg_forcing: f64,
}

/// A kept block next to an eliminated one.
#[derive(Clone, Copy, Debug)]
struct Neighbour {
    /// Reduced block index of the kept variable.
    kept: usize,
    /// The coupling block between them in [`NormalEquations::couplings`].
    coupling: usize,
    /// Position of column 0 of H_ce (d_c × d_e) in the exact solvers' copy `Schur::hce`;
    /// column k starts `k step` after it. `step` is the rows of all the eliminated block's
    /// neighbours: their blocks lie one under another, as in H's block column.
    offset: usize,
    step: usize,
}

// One per solver, moved only when the conjugate gradients take their buffers out and back.
#[allow(clippy::large_enum_variant)]
enum ReducedSolver {
    Factored(Cholesky),
    Iterative(Pcg),
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
    /// The exact solvers' copy of the H_ce blocks, formed from J at each factorisation (empty
    /// for conjugate gradients, whose products read J).
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
    reduced: ReducedSolver,
    rhs: Vec<f64>,
    /// For the automatic choice's conjugate gradients: the iterations per solve that cost one
    /// sparse factorisation of S ([`Self::wants_factorisation`]).
    switch_at: Option<f64>,
}

impl Schur {
    /// Lays out the elimination of the blocks `ne` was made to eliminate
    /// ([`NormalEquations::with_elimination`]).
    pub fn new(
        ne: &NormalEquations,
        kind: LinearSolverKind,
        dense_threshold: usize,
        options: SchurOptions,
    ) -> Result<Self, SolveError> {
        let h = ne.h();
        let eliminate = ne.eliminated();
        if eliminate.len() != h.num_blocks() {
            return Err(SolveError::LinearSolver(
                "a Schur solver needs normal equations laid out with an elimination".to_string(),
            ));
        }
        let split = Split::new(eliminate);
        let iterative = kind == LinearSolverKind::SchurIterative;
        let nbrs = Neighbours::new(ne, &split)?;
        let touch_lists = nbrs.touch_lists(split.kept.len());
        let mut s = layout::reduced_pattern(h, eliminate, &split, &nbrs, &touch_lists, iterative);
        let mut switch_at = None;
        let (reduced, kind) = match kind {
            LinearSolverKind::Schur => match choose_reduced(&s, dense_threshold, &nbrs)? {
                Choice::Factor(chosen) => *chosen,
                Choice::Iterate { switch_at: at } => {
                    switch_at = at;
                    // conjugate gradients keep only H_cc's pattern
                    s = layout::reduced_pattern(h, eliminate, &split, &nbrs, &touch_lists, true);
                    let kind = LinearSolverKind::SchurIterative;
                    reduced_solver(&s, kind, &nbrs.nbr_ptr, options)?
                }
            },
            kind => reduced_solver(&s, kind, &nbrs.nbr_ptr, options)?,
        };
        let iterative = kind == LinearSolverKind::SchurIterative;
        let (direct_ptr, direct) = layout::direct_copies(h, eliminate, &split, &s);
        let points = PointMajor::new(&s, &nbrs, split.elim.len(), iterative);
        let touch_lists = if iterative { Vec::new() } else { touch_lists };
        let touches = Touches::new(&touch_lists, &nbrs, &s, !iterative && !points.active());
        let elim_scalars = *nbrs.elim_start.last().unwrap();
        let chunks = points.chunk_bounds.len() - 1;
        let mut reduced = reduced;
        // single precision only for truncated solves, whose steps are inexact by design; a solve
        // asked for to a tight tolerance keeps double precision (NOTES 75)
        if let (ReducedSolver::Iterative(pcg), true) = (&mut reduced, options.pcg_forcing > 0.0) {
            let dims = |q: usize, n: &Neighbour| (s.block_dim(n.kept), h.block_dim(split.elim[q]));
            pcg.single = SingleJacobians::new(&nbrs.nbrs, &nbrs.nbr_ptr, ne.couplings(), dims);
        }
        Ok(Self {
            kind,
            rhs: vec![0.0; s.dim()],
            elim: split.elim,
            kept: split.kept,
            elim_start: nbrs.elim_start,
            nbr_ptr: nbrs.nbr_ptr,
            nbrs: nbrs.nbrs,
            inv_offset: nbrs.inv_offset,
            hinv: vec![0.0; nbrs.inv_len],
            hce: vec![0.0; if iterative { 0 } else { nbrs.buf_len }],
            ze: vec![0.0; if iterative { 0 } else { elim_scalars }],
            direct_ptr,
            direct,
            touch_ptr: touches.touch_ptr,
            touch: touches.touch,
            update_ptr: touches.update_ptr,
            update: touches.update,
            pair_ptr: points.pair_ptr,
            pair_entry: points.pair_entry,
            chunk_values: vec![vec![0.0; *points.block_offset.last().unwrap()]; chunks],
            chunk_rhs: vec![vec![0.0; s.dim()]; chunks],
            block_offset: points.block_offset,
            chunk_bounds: points.chunk_bounds,
            s,
            reduced,
            switch_at,
        })
    }

    /// Stops [`Self::wants_factorisation`] from asking again.
    pub fn keep_iterating(&mut self) {
        self.switch_at = None;
    }

    /// True when the automatic choice started with conjugate gradients and their iterations so
    /// far exceed what factorising S would have cost in their place, plus
    /// [`SWITCH_MARGIN`] factorisations: the caller then lays the solver out again as
    /// [`LinearSolverKind::SchurSparse`]. A sum, not a recent average: the truncated solves
    /// mostly stop at 2 iterations, with an occasional one of tens or hundreds.
    pub fn wants_factorisation(&self) -> bool {
        match (&self.reduced, self.switch_at) {
            (ReducedSolver::Iterative(pcg), Some(at)) => {
                pcg.iterations as f64 > at * (pcg.solves + SWITCH_MARGIN) as f64
            }
            _ => false,
        }
    }

    /// "schur-dense", "schur-sparse" or "schur-iterative".
    pub fn name(&self) -> &'static str {
        match self.kind {
            LinearSolverKind::SchurIterative => "schur-iterative",
            LinearSolverKind::SchurSparse => "schur-sparse",
            _ => "schur-dense",
        }
    }

    /// Conjugate-gradient iterations so far (0 for the exact solvers).
    pub fn iterations(&self) -> usize {
        match &self.reduced {
            ReducedSolver::Iterative(pcg) => pcg.iterations,
            ReducedSolver::Factored(_) => 0,
        }
    }

    /// True unless the reduced system is solved iteratively.
    pub fn is_exact(&self) -> bool {
        matches!(self.reduced, ReducedSolver::Factored(_))
    }

    /// Inverts the damped H_ee blocks and, for the exact solvers, forms the copy of H_ce from J,
    /// then forms S (or the preconditioner) and factorises it. On failure returns the H scalar
    /// index where definiteness failed.
    pub fn factor(&mut self, ne: &NormalEquations, damping: Damping) -> Result<(), usize> {
        let h = ne.h();
        let (couplings, jac) = (ne.couplings(), ne.jacobians());
        let hinv = SyncPtr::new(&mut self.hinv);
        let hce = SyncPtr::new(&mut self.hce);
        let (elim, nbrs, nbr_ptr, inv_offset, s) = (
            &self.elim,
            &self.nbrs,
            &self.nbr_ptr,
            &self.inv_offset,
            &self.s,
        );
        let copy = self.is_exact();
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
                let list = &nbrs[nbr_ptr[q]..nbr_ptr[q + 1]];
                let Some(first) = list.first().filter(|_| copy) else {
                    return Ok(());
                };
                // SAFETY: block q owns its neighbours' columns in hce, `step × de` values.
                let own = unsafe { hce.slice(first.offset, first.step * de) };
                for n in list {
                    let dc = s.block_dim(n.kept);
                    let at = n.offset - first.offset;
                    couplings.block(jac, n.coupling, (dc, de), &mut own[at..], n.step);
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
            ReducedSolver::Factored(chol) => chol.factor(s, Damping::None).map_err(|i| {
                let k = s.block_of_scalar(i);
                h.block_start[kept[k]] + (i - s.block_start[k])
            }),
            ReducedSolver::Iterative(_) => Ok(()),
        }
    }

    /// Solves the damped system for the right-hand side `x` (H's scalar order), in place.
    pub fn solve(&mut self, ne: &NormalEquations, x: &mut [f64]) {
        let h = ne.h();
        if !self.is_exact() {
            self.reduce_rhs_from_jacobians(ne, x);
        } else if self.chunk_rhs.is_empty() {
            self.reduce_rhs_by_columns(h, x);
        } else {
            self.reduce_rhs_by_points(h, x);
        }
        let mut rhs = std::mem::take(&mut self.rhs);
        match &mut self.reduced {
            ReducedSolver::Factored(chol) => chol.solve(&mut rhs),
            ReducedSolver::Iterative(_) => self.conjugate_gradients(ne, &mut rhs),
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
                    this.eliminated_update(ne, q, de, xe, y);
                });
        }
        for (k, &b) in self.kept.iter().enumerate() {
            let (h0, r0, d) = (h.block_start[b], self.s.block_start[k], self.s.block_dim(k));
            x[h0..h0 + d].copy_from_slice(&rhs[r0..r0 + d]);
        }
        self.rhs = rhs;
    }

    /// Column k (d_c values) of the H_ce block of neighbour `n` in the exact solvers' copy.
    #[inline(always)]
    fn hce_column(&self, n: &Neighbour, dc: usize, k: usize) -> &[f64] {
        &self.hce[n.offset + k * n.step..][..dc]
    }

    /// Column k of all the H_ce blocks of eliminated block q in the exact solvers' copy, one
    /// under another in neighbour order (Σ d_c values).
    #[inline(always)]
    fn hce_run(&self, q: usize, k: usize) -> &[f64] {
        let Some(first) = self.nbrs[self.nbr_ptr[q]..self.nbr_ptr[q + 1]].first() else {
            return &[];
        };
        self.hce_column(first, first.step, k)
    }

    /// u = H_ee⁻¹ H_jeᵀ (d_e × d_j) for eliminated block q and the H_je block whose column k
    /// `hj(k)` gives, written into the front of `scratch`.
    #[inline(always)]
    fn inverse_times_neighbour<'a, 'b>(
        &self,
        q: usize,
        hj: impl Fn(usize) -> &'b [f64],
        (de, dj): (usize, usize),
        scratch: &'a mut [f64; MAX_PRODUCT],
    ) -> &'a [f64] {
        let inv = &self.hinv[self.inv_offset[q]..][..de * de];
        let u = &mut scratch[..de * dj];
        inverse_times_transpose(inv, hj, u, de, dj);
        u
    }

    /// `v ← H_ee⁻¹ (v − H_ec y)` for eliminated block q (d_e unknowns), y in reduced order:
    /// H_ec from the copy for the exact solvers, from J for conjugate gradients.
    fn eliminated_update(
        &self,
        ne: &NormalEquations,
        q: usize,
        de: usize,
        v: &mut [f64],
        y: &[f64],
    ) {
        let mut t = [0.0f64; MAX_ELIMINATED];
        let t = &mut t[..de];
        let nbrs = &self.nbrs[self.nbr_ptr[q]..self.nbr_ptr[q + 1]];
        if self.is_exact() {
            for (k, tk) in t.iter_mut().enumerate() {
                let run = self.hce_run(q, k);
                let mut at = 0;
                for n in nbrs {
                    let (c0, dc) = (self.s.block_start[n.kept], self.s.block_dim(n.kept));
                    *tk += dot(&run[at..at + dc], &y[c0..c0 + dc]);
                    at += dc;
                }
            }
        } else {
            let (couplings, jac) = (ne.couplings(), ne.jacobians());
            for n in nbrs {
                let (c0, dc) = (self.s.block_start[n.kept], self.s.block_dim(n.kept));
                couplings.add_ec(jac, n.coupling, &y[c0..c0 + dc], t);
            }
        }
        for (tk, vk) in t.iter_mut().zip(v.iter()) {
            *tk = vk - *tk;
        }
        let inv = &self.hinv[self.inv_offset[q]..][..de * de];
        for (r, o) in v.iter_mut().enumerate() {
            *o = (0..de).map(|k| inv[r + k * de] * t[k]).sum();
        }
    }
}

/// The solver of the reduced system for an explicit `kind`.
fn reduced_solver(
    s: &BlockSparse,
    kind: LinearSolverKind,
    nbr_ptr: &[usize],
    options: SchurOptions,
) -> Result<(ReducedSolver, LinearSolverKind), SolveError> {
    let reduced = match kind {
        LinearSolverKind::SchurIterative => ReducedSolver::Iterative(Pcg::new(s, nbr_ptr, options)),
        kind => ReducedSolver::Factored(Cholesky::new(s, kind == LinearSolverKind::SchurDense)?),
    };
    Ok((reduced, kind))
}

/// Conjugate gradients are chosen for good when one sparse factorisation of S would take more
/// than this many operations per scalar of H_ce. One product with S reads H_ce's share of J
/// twice, and a step took 2-12 products on the street walks (NOTES 75), while a factorisation
/// runs several times faster per operation than the memory-bound products.
const ITERATIVE_FLOPS_PER_HCE_SCALAR: f64 = 100.0;

/// Below that bound conjugate gradients start, and S is factorised instead once their
/// iterations exceed this many per solve per operation per H_ce scalar of the factorisation
/// ([`Schur::wants_factorisation`]): one factorisation with S's assembly took the time of
/// 0.23-0.44 products per operation per scalar on the street walks, rings and Ladybug-49
/// (NOTES 75).
const PRODUCTS_PER_FLOP_PER_HCE_SCALAR: f64 = 0.4;

/// Factorisations' worth of conjugate-gradient iterations allowed beyond the factorisations'
/// cost before the automatic choice switches (a hysteresis against the first, costlier solves).
const SWITCH_MARGIN: usize = 3;

/// The automatic choice's outcome.
enum Choice {
    /// A factorisation of S.
    Factor(Box<(ReducedSolver, LinearSolverKind)>),
    /// Conjugate gradients, to be replaced by a sparse factorisation when their iterations
    /// exceed `switch_at` per solve (beyond [`SWITCH_MARGIN`]).
    Iterate { switch_at: Option<f64> },
}

/// The automatic choice ([`LinearSolverKind::Schur`]) for the reduced pattern `s`: dense
/// Cholesky up to `dense_threshold` unknowns; above, sparse Cholesky when its symbolic analysis
/// finds a simplicial factor (a very sparse S); conjugate gradients for good when the
/// factorisation would cost more than [`ITERATIVE_FLOPS_PER_HCE_SCALAR`] per scalar of H_ce;
/// sparse Cholesky from the start when S's graph is so long ([`reach::diameter_bound`]) that a
/// converged solve needs more conjugate-gradient iterations than a factorisation's worth
/// ([`PRODUCTS_PER_FLOP_PER_HCE_SCALAR`]): a ring or a long corridor of cameras, not a city;
/// otherwise conjugate gradients until their iterations show a factorisation to be cheaper.
fn choose_reduced(
    s: &BlockSparse,
    dense_threshold: usize,
    nbrs: &Neighbours,
) -> Result<Choice, SolveError> {
    if s.dim() <= dense_threshold {
        let chol = Cholesky::new(s, true)?;
        let chosen = (ReducedSolver::Factored(chol), LinearSolverKind::SchurDense);
        return Ok(Choice::Factor(Box::new(chosen)));
    }
    let hce_scalars = (0..nbrs.nbr_ptr.len() - 1)
        .map(|q| {
            let cameras = &nbrs.nbrs[nbrs.nbr_ptr[q]..nbrs.nbr_ptr[q + 1]];
            let de = nbrs.elim_start[q + 1] - nbrs.elim_start[q];
            de * cameras.iter().map(|n| s.block_dim(n.kept)).sum::<usize>()
        })
        .sum::<usize>()
        .max(1) as f64;
    let bound = ITERATIVE_FLOPS_PER_HCE_SCALAR * hce_scalars;
    let analysed = Analysed::unless_costlier(s, 4.0 * bound)?;
    let flops = analysed.flops();
    let per_scalar = flops / hce_scalars;
    tracing::debug!(
        flops,
        hce_scalars,
        per_scalar,
        "reduced camera system: sparse factorisation's cost per scalar of H_ce"
    );
    if flops > bound {
        return Ok(Choice::Iterate { switch_at: None });
    }
    if flops == 0.0 {
        let chol = Cholesky::from_analysis(s, analysed, FactorPrecision::Double);
        let chosen = (ReducedSolver::Factored(chol), LinearSolverKind::SchurSparse);
        return Ok(Choice::Factor(Box::new(chosen)));
    }
    let switch_at = PRODUCTS_PER_FLOP_PER_HCE_SCALAR * per_scalar;
    let diameter = reach::diameter_bound(s);
    tracing::debug!(
        diameter,
        switch_at,
        "reduced camera system: iterations per solve at which a factorisation pays, and the \
         fewest a converged solve takes"
    );
    if diameter as f64 > switch_at {
        let chol = Cholesky::from_analysis(s, analysed, FactorPrecision::Double);
        let chosen = (ReducedSolver::Factored(chol), LinearSolverKind::SchurSparse);
        return Ok(Choice::Factor(Box::new(chosen)));
    }
    Ok(Choice::Iterate {
        switch_at: Some(switch_at),
    })
}
