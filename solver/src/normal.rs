//! The normal equations `H δ = −g` with `H = JᵀJ` and `g = Jᵀr`, assembled directly in block form.
//!
//! Assembly runs in two parallel passes with a fixed reduction order, so the same input gives the
//! same bits whatever the thread timing:
//! 1. over residual blocks: evaluate r_k and its Jacobian blocks (kernel-corrected) into buffers
//!    laid out once per structure;
//! 2. over block columns of H: each block H_ij = Σ_k J_kiᵀ J_kj and each g_j = Σ_k J_kjᵀ r_k is summed
//!    over its contributing residuals in residual order, written straight into the values of the
//!    upper triangle of H in compressed-column form (the layout faer's sparse Cholesky reads).

use crate::block::BlockSparse;
use crate::coupling::{Couplings, Term};
use crate::elimination::elimination_set;
use crate::error::SolveError;
use crate::options::Elimination;
use crate::parallel::{dot, SyncPtr};
use crate::problem::Problem;
use rayon::prelude::*;

/// A residual's share of an entry: J_aᵀ J_b with `m` rows, Jacobians at these buffer offsets
/// (32-bit: a quarter of the normal equations' index memory in bundle adjustment; buffers are
/// refused beyond `u32::MAX` scalars).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Contribution {
    ja: u32,
    jb: u32,
    m: u32,
}

impl Contribution {
    #[inline(always)]
    pub fn ja(&self) -> usize {
        self.ja as usize
    }
    #[inline(always)]
    pub fn jb(&self) -> usize {
        self.jb as usize
    }
    #[inline(always)]
    pub fn m(&self) -> usize {
        self.m as usize
    }
}

/// A residual's share of a gradient block: J_bᵀ r.
#[derive(Clone, Copy, Debug)]
pub(crate) struct GradientContribution {
    j: u32,
    r: u32,
    m: u32,
}

/// The sparsity structure of the normal equations and the buffers they are assembled into.
pub(crate) struct NormalEquations {
    /// Block (free-variable) index of each variable, `usize::MAX` when fixed.
    block_of_var: Vec<usize>,
    /// Variable of each block.
    var_of_block: Vec<usize>,
    res_offset: Vec<usize>,
    jac_offset: Vec<usize>,
    /// H = JᵀJ, upper triangle; one block row and column per free variable.
    h: BlockSparse,
    contrib_ptr: Vec<usize>,
    contribs: Vec<Contribution>,
    grad_ptr: Vec<usize>,
    grads: Vec<GradientContribution>,
    /// Gradient Jᵀr.
    gradient: Vec<f64>,
    residuals: Vec<f64>,
    jacobians: Vec<f64>,
    costs: Vec<f64>,
    /// Counts the assemblies, so that copies of the Jacobian buffer can tell when they are
    /// stale: between two assemblies the buffer holds the Jacobians of one point whenever a
    /// solve reads it (a rejected trial's are replaced by the current point's again).
    jacobian_version: u64,
    /// The blocks marked for elimination (empty without an elimination).
    eliminate: Vec<bool>,
    /// The blocks between an eliminated and a kept block, applied from J (see [`Couplings`]).
    couplings: Couplings,
}

impl NormalEquations {
    /// H = JᵀJ as assembled: the upper triangle, one block row and column per free variable.
    pub fn h(&self) -> &BlockSparse {
        &self.h
    }

    /// The gradient g = Jᵀr as assembled.
    pub fn gradient(&self) -> &[f64] {
        &self.gradient
    }

    /// The block (free-variable) index of each variable, `usize::MAX` for fixed ones.
    pub fn block_of_var(&self) -> &[usize] {
        &self.block_of_var
    }

    /// The variable of each block.
    pub fn var_of_block(&self) -> &[usize] {
        &self.var_of_block
    }

    /// Lays out the structure of `problem`'s normal equations, every block of H assembled.
    pub fn new(problem: &Problem) -> Result<Self, SolveError> {
        Self::build(problem, None)
    }

    /// Lays out the normal equations of a Schur solve: the blocks `elimination` marks, and the
    /// blocks that couple them to kept ones left out of H (unless `couplings_in_h`) and applied
    /// from J ([`Self::couplings`]). An error when two eliminated blocks share a residual.
    pub fn with_elimination(
        problem: &Problem,
        elimination: &Elimination,
        couplings_in_h: bool,
    ) -> Result<Self, SolveError> {
        Self::build(problem, Some((elimination, couplings_in_h)))
    }

    fn build(
        problem: &Problem,
        elimination: Option<(&Elimination, bool)>,
    ) -> Result<Self, SolveError> {
        let (block_of_var, var_of_block, block_start) = free_blocks(problem);
        let nb = var_of_block.len();
        let layout = ResidualLayout::new(problem, &block_of_var, nb);
        if let Some(b) = layout.touched.iter().position(|t| !t) {
            return Err(SolveError::UntouchedVariable(var_of_block[b]));
        }
        let ResidualLayout {
            res_offset,
            jac_offset,
            mut pairs,
            mut grad_list,
            ..
        } = layout;
        let scalars = jac_offset.last().copied().unwrap_or(0);
        if scalars > u32::MAX as usize {
            return Err(SolveError::LinearSolver(format!(
                "the Jacobian has {scalars} scalars, more than the 2³² the normal equations index"
            )));
        }
        pairs.sort_unstable_by_key(|p| (p.0, p.1, p.2));
        grad_list.sort_unstable_by_key(|g| (g.0, g.1));
        let (mut columns, mut contrib_ptr, mut contribs) = hessian_contributions(&pairs, nb);
        // The lists are the largest temporaries (48 and 40 bytes per pair and gradient entry):
        // freed before H and the Jacobian buffer are allocated, they do not add to the peak.
        drop(pairs);
        let (grad_ptr, grads) = gradient_contributions(&grad_list, nb);
        drop(grad_list);
        let (eliminate, couplings) = match elimination {
            Some((elimination, in_h)) => {
                let dim = |b: usize| block_start[b + 1] - block_start[b];
                let eliminate = elimination_set(&block_of_var, &columns, dim, elimination)?;
                let lists = (&mut columns, &mut contrib_ptr, &mut contribs);
                let couplings = split_couplings(lists, &eliminate, in_h, &var_of_block)?;
                (eliminate, couplings)
            }
            None => (Vec::new(), Couplings::default()),
        };
        let h = BlockSparse::new(block_start, &columns);
        drop(columns);
        Ok(Self {
            gradient: vec![0.0; h.dim()],
            residuals: vec![0.0; *res_offset.last().unwrap()],
            jacobians: vec![0.0; *jac_offset.last().unwrap()],
            costs: vec![0.0; problem.blocks.len()],
            jacobian_version: 0,
            block_of_var,
            var_of_block,
            res_offset,
            jac_offset,
            h,
            contrib_ptr,
            contribs,
            grad_ptr,
            grads,
            eliminate,
            couplings,
        })
    }

    /// The blocks marked for elimination (empty unless made by [`Self::with_elimination`]).
    pub fn eliminated(&self) -> &[bool] {
        &self.eliminate
    }

    /// The blocks coupling eliminated to kept blocks, applied from [`Self::jacobians`].
    pub fn couplings(&self) -> &Couplings {
        &self.couplings
    }

    /// True when solves read the Jacobian buffer (the couplings are applied from it), so that it
    /// must hold the Jacobians of the point H was assembled at.
    pub fn reads_jacobians(&self) -> bool {
        !self.couplings.in_h && !self.couplings.kept.is_empty()
    }

    /// Changes whenever [`Self::assemble`] forms H from a new Jacobian.
    pub fn jacobian_version(&self) -> u64 {
        self.jacobian_version
    }

    /// The kernel-corrected Jacobian blocks as evaluated, each m × d column-major.
    pub fn jacobians(&self) -> &[f64] {
        &self.jacobians
    }

    /// y = H x, the coupling blocks included.
    pub fn multiply(&self, x: &[f64], y: &mut [f64]) {
        self.h.multiply(x, y);
        if self.couplings.in_h {
            return;
        }
        let (h, cp, jac) = (&self.h, &self.couplings, &self.jacobians);
        for e in 0..h.num_blocks() {
            let (e0, de) = (h.block_start[e], h.block_dim(e));
            for c in cp.of(e) {
                let k = cp.kept[c];
                let (c0, dc) = (h.block_start[k], h.block_dim(k));
                cp.add_ec(jac, c, &x[c0..c0 + dc], &mut y[e0..e0 + de]);
                cp.add_ce(jac, c, &x[e0..e0 + de], &mut y[c0..c0 + dc]);
            }
        }
    }

    /// xᵀ H x, the coupling blocks included; `scratch` (the system's size) is overwritten.
    pub fn quadratic(&self, x: &[f64], scratch: &mut [f64]) -> f64 {
        self.h.multiply(x, scratch);
        let explicit = dot(x, scratch);
        if self.couplings.in_h || self.couplings.kept.is_empty() {
            return explicit;
        }
        // 2 Σ x_eᵀ H_ec x_c, summed over fixed ranges of blocks so that the bits do not depend
        // on the threads.
        let (h, cp, jac) = (&self.h, &self.couplings, &self.jacobians);
        let nb = h.num_blocks();
        let partial: Vec<f64> = (0..nb.div_ceil(QUADRATIC_RANGE))
            .into_par_iter()
            .map(|r| {
                let mut sum = 0.0;
                for e in r * QUADRATIC_RANGE..((r + 1) * QUADRATIC_RANGE).min(nb) {
                    let (e0, de) = (h.block_start[e], h.block_dim(e));
                    let (mut stack, mut heap) = ([0.0f64; 16], Vec::new());
                    let t: &mut [f64] = if de <= 16 {
                        &mut stack[..de]
                    } else {
                        heap.resize(de, 0.0);
                        &mut heap
                    };
                    for c in cp.of(e) {
                        let k = cp.kept[c];
                        let (c0, dc) = (h.block_start[k], h.block_dim(k));
                        cp.add_ec(jac, c, &x[c0..c0 + dc], t);
                    }
                    sum += dot(t, &x[e0..e0 + de]);
                }
                sum
            })
            .collect();
        explicit + 2.0 * partial.iter().sum::<f64>()
    }

    /// Scalar size of the system.
    pub fn dim(&self) -> usize {
        self.h.dim()
    }

    /// The variable owning unknown `i` of the system.
    pub fn var_of_scalar(&self, i: usize) -> usize {
        self.var_of_block[self
            .h
            .block_of_scalar(i)
            .min(self.var_of_block.len().saturating_sub(1))]
    }

    /// Number of blocks (free variables).
    pub fn num_blocks(&self) -> usize {
        self.var_of_block.len()
    }

    /// Evaluates every residual block at `values` in parallel and returns the cost ½Σρ, summed in
    /// block order. With `jacobians`, also fills the Jacobian buffer (kernel-corrected).
    pub fn evaluate(&mut self, problem: &Problem, values: &[f64], jacobians: bool) -> f64 {
        let r = SyncPtr::new(&mut self.residuals);
        let j = SyncPtr::new(&mut self.jacobians);
        let (ro, jo) = (&self.res_offset, &self.jac_offset);
        self.costs
            .par_iter_mut()
            .enumerate()
            .with_min_len(64)
            .for_each(|(k, cost)| {
                // SAFETY: block k owns residuals[ro[k]..ro[k+1]] and jacobians[jo[k]..jo[k+1]].
                let rk = unsafe { r.slice(ro[k], ro[k + 1] - ro[k]) };
                let jk = jacobians.then(|| unsafe { j.slice(jo[k], jo[k + 1] - jo[k]) });
                *cost = problem.evaluate_block(k, values, rk, jk);
            });
        self.costs.iter().sum()
    }

    /// Index of the first residual block with a non-finite cost.
    pub fn first_non_finite(&self) -> Option<usize> {
        self.costs.iter().position(|c| !c.is_finite())
    }

    /// Fixes each unknown's scale of Marquardt's damping from H's current diagonal when `fix`
    /// (at the start of a solve, as Ceres fixes its Jacobi scaling), else drops the scales.
    pub fn fix_damping_scale(&mut self, fix: bool) {
        if fix {
            self.h.fix_damping_scale();
        } else {
            self.h.damping_scale.clear();
        }
    }

    /// Sets each unknown's scale of Marquardt's damping (tests).
    #[cfg(test)]
    pub(crate) fn set_damping_scale(&mut self, scale: Vec<f64>) {
        self.h.damping_scale = scale;
    }

    /// Forms H and g from the Jacobian and residual buffers filled by [`Self::evaluate`].
    pub fn assemble(&mut self) {
        self.jacobian_version += 1;
        let h = SyncPtr::new(&mut self.h.values);
        let g = SyncPtr::new(&mut self.gradient);
        let this = &*self;
        (0..this.num_blocks())
            .into_par_iter()
            .with_min_len(16)
            .for_each(|jb| this.assemble_column(jb, h, g));
    }

    /// Entry `e` (a DI × DJ block of block column `jb`) as Σ J_aᵀ J_b over its contributions,
    /// accumulated in registers one residual row at a time. Returns true (it always handles the
    /// entry; the bool lets the caller dispatch on sizes in one match).
    #[inline(always)]
    fn fixed_block<const DI: usize, const DJ: usize>(
        &self,
        e: usize,
        jb: usize,
        h: SyncPtr,
    ) -> bool {
        let (jac, hm) = (&self.jacobians, &self.h);
        let entry = hm.entries[e];
        let diagonal = entry.row_block == jb;
        let c0 = hm.block_start[jb];
        let mut acc = [[0.0f64; DI]; DJ];
        let contribs = &self.contribs[self.contrib_ptr[e]..self.contrib_ptr[e + 1]];
        for (x, k) in contribs.iter().enumerate() {
            // A camera's residuals lie far apart in the Jacobian buffer (BAL lists observations
            // point by point), so the hardware cannot guess the next one: ask for it early.
            if let Some(ahead) = contribs.get(x + PREFETCH_AHEAD) {
                prefetch(jac, ahead.ja(), DI * ahead.m());
                if ahead.jb != ahead.ja {
                    prefetch(jac, ahead.jb(), DJ * ahead.m());
                }
            }
            let (m, ja, jb) = (k.m(), k.ja(), k.jb());
            let (a, b) = (&jac[ja..ja + DI * m], &jac[jb..jb + DJ * m]);
            // Residuals of one to three rows (reprojections, point-to-plane, 3D points) get
            // their row count as a constant, so that every load below is at a fixed offset.
            match m {
                1 => add_rows::<DI, DJ, 1>(a, b, &mut acc),
                2 => add_rows::<DI, DJ, 2>(a, b, &mut acc),
                3 => add_rows::<DI, DJ, 3>(a, b, &mut acc),
                _ => {
                    for i in 0..m {
                        let ar: [f64; DI] = std::array::from_fn(|r| a[r * m + i]);
                        let bc: [f64; DJ] = std::array::from_fn(|c| b[c * m + i]);
                        add_outer(&ar, &bc, &mut acc);
                    }
                }
            }
        }
        for (c, column) in acc.iter().enumerate() {
            let rows = if diagonal { c + 1 } else { DI };
            // SAFETY: column c0 + c belongs to block column jb only.
            let col = unsafe { h.slice(hm.col_ptr[c0 + c] + entry.pos, rows) };
            col.copy_from_slice(&column[..rows]);
        }
        true
    }

    fn assemble_column(&self, jb: usize, h: SyncPtr, g: SyncPtr) {
        let (jac, res) = (&self.jacobians, &self.residuals);
        let hm = &self.h;
        let c0 = hm.block_start[jb];
        let dj = hm.block_dim(jb);
        for e in hm.entry_ptr[jb]..hm.entry_ptr[jb + 1] {
            let entry = hm.entries[e];
            let diagonal = entry.row_block == jb;
            let di = hm.block_dim(entry.row_block);
            // The common block sizes (SE(3) poses, BAL cameras and points) run through a
            // fixed-size kernel the compiler unrolls; other sizes through the loop below.
            let fixed = match (di, dj) {
                (6, 6) => self.fixed_block::<6, 6>(e, jb, h),
                (9, 9) => self.fixed_block::<9, 9>(e, jb, h),
                (3, 3) => self.fixed_block::<3, 3>(e, jb, h),
                (9, 3) => self.fixed_block::<9, 3>(e, jb, h),
                (3, 9) => self.fixed_block::<3, 9>(e, jb, h),
                (6, 3) => self.fixed_block::<6, 3>(e, jb, h),
                (3, 6) => self.fixed_block::<3, 6>(e, jb, h),
                _ => false,
            };
            if fixed {
                continue;
            }
            for c in 0..dj {
                let rows = if diagonal { c + 1 } else { di };
                // SAFETY: column c0 + c belongs to block column jb only.
                let col = unsafe { h.slice(hm.col_ptr[c0 + c] + entry.pos, rows) };
                col.fill(0.0);
                for k in &self.contribs[self.contrib_ptr[e]..self.contrib_ptr[e + 1]] {
                    let (m, ja, jb) = (k.m(), k.ja(), k.jb());
                    let b = &jac[jb + c * m..jb + (c + 1) * m];
                    for (r, out) in col.iter_mut().enumerate() {
                        let a = &jac[ja + r * m..ja + (r + 1) * m];
                        *out += dot(a, b);
                    }
                }
            }
        }
        // SAFETY: the gradient segment of block jb is written by this task only.
        let gj = unsafe { g.slice(c0, dj) };
        gj.fill(0.0);
        for k in &self.grads[self.grad_ptr[jb]..self.grad_ptr[jb + 1]] {
            let (j, m) = (k.j as usize, k.m as usize);
            let r = &res[k.r as usize..k.r as usize + m];
            for (c, out) in gj.iter_mut().enumerate() {
                *out += dot(&jac[j + c * m..j + (c + 1) * m], r);
            }
        }
    }
}

/// Blocks per task of [`NormalEquations::quadratic`]'s coupling sum.
const QUADRATIC_RANGE: usize = 4096;

/// H's block columns, entry pointers and contributions as laid out by [`hessian_contributions`].
type HessianLists<'a> = (
    &'a mut Vec<Vec<usize>>,
    &'a mut Vec<usize>,
    &'a mut Vec<Contribution>,
);

/// Takes the blocks between an eliminated and a kept block out of the lists (unless `in_h`)
/// and returns them as [`Couplings`], grouped by eliminated block; an error when two eliminated
/// blocks share a residual.
fn split_couplings(
    (columns, contrib_ptr, contribs): HessianLists,
    eliminate: &[bool],
    in_h: bool,
    var_of_block: &[usize],
) -> Result<Couplings, SolveError> {
    let nb = columns.len();
    // (eliminated block, kept block, entry), in the entries' order: per eliminated block this
    // lists its kept neighbours ascending (those before it from its own column, then the later
    // columns in order).
    let mut found = Vec::new();
    let mut entry = 0;
    for (j, rows) in columns.iter().enumerate() {
        for &i in rows {
            if i != j && eliminate[i] && eliminate[j] {
                return Err(SolveError::LinearSolver(format!(
                    "variables {} and {} are both marked for elimination but share a residual: \
                     eliminated variables must be independent",
                    var_of_block[i], var_of_block[j]
                )));
            }
            if eliminate[i] != eliminate[j] {
                let (e, c) = if eliminate[j] { (j, i) } else { (i, j) };
                found.push((e, c, entry));
            }
            entry += 1;
        }
    }
    found.sort_by_key(|&(e, _, _)| e);
    let mut out = Couplings {
        ptr: vec![0; nb + 1],
        kept: Vec::with_capacity(found.len()),
        term_ptr: Vec::with_capacity(found.len() + 1),
        terms: Vec::new(),
        in_h,
    };
    out.term_ptr.push(0);
    let terms: usize = found
        .iter()
        .map(|&(_, _, x)| contrib_ptr[x + 1] - contrib_ptr[x])
        .sum();
    out.terms.reserve_exact(terms);
    for &(e, c, x) in &found {
        out.ptr[e + 1] += 1;
        out.kept.push(c);
        for k in &contribs[contrib_ptr[x]..contrib_ptr[x + 1]] {
            // the contribution's `ja` is the row block's Jacobian, `jb` the column block's
            let (jc, je) = if e > c { (k.ja, k.jb) } else { (k.jb, k.ja) };
            out.terms.push(Term {
                jc: jc as usize,
                je: je as usize,
                m: k.m(),
            });
        }
        out.term_ptr.push(out.terms.len());
    }
    for b in 0..nb {
        out.ptr[b + 1] += out.ptr[b];
    }
    if !in_h {
        remove_entries(columns, contrib_ptr, contribs, |j, i| {
            eliminate[i] != eliminate[j]
        });
    }
    Ok(out)
}

/// Removes the entries (row i, column j) for which `drop(j, i)` holds, with their contributions,
/// in place.
fn remove_entries(
    columns: &mut [Vec<usize>],
    contrib_ptr: &mut Vec<usize>,
    contribs: &mut Vec<Contribution>,
    drop: impl Fn(usize, usize) -> bool,
) {
    let (mut entry, mut write) = (0, 0);
    let mut ptr = vec![0];
    for (j, rows) in columns.iter_mut().enumerate() {
        rows.retain(|&i| {
            let keep = !drop(j, i);
            if keep {
                for x in contrib_ptr[entry]..contrib_ptr[entry + 1] {
                    contribs[write] = contribs[x];
                    write += 1;
                }
                ptr.push(write);
            }
            entry += 1;
            keep
        });
    }
    contribs.truncate(write);
    contribs.shrink_to_fit();
    *contrib_ptr = ptr;
}

/// How many contributions ahead [`NormalEquations::assemble`] prefetches Jacobians.
const PREFETCH_AHEAD: usize = 6;

/// Hints the cache to load `data[start..start + len]` (a no-op off x86-64).
#[inline(always)]
fn prefetch(data: &[f64], start: usize, len: usize) {
    #[cfg(target_arch = "x86_64")]
    {
        let end = (start + len).min(data.len());
        if start >= end {
            return;
        }
        // One address per 64-byte line: every eighth element, and the last one.
        for i in (start..end).step_by(8).chain([end - 1]) {
            // SAFETY: the address lies inside `data`; a prefetch never faults or writes.
            unsafe {
                std::arch::x86_64::_mm_prefetch(
                    data.as_ptr().add(i) as *const i8,
                    std::arch::x86_64::_MM_HINT_T0,
                )
            };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (data, start, len);
}

/// acc += aᵀ b for column-major Jacobian blocks a (M × DI) and b (M × DJ), one row at a time.
#[inline(always)]
fn add_rows<const DI: usize, const DJ: usize, const M: usize>(
    a: &[f64],
    b: &[f64],
    acc: &mut [[f64; DI]; DJ],
) {
    let (a, b) = (&a[..DI * M], &b[..DJ * M]);
    for i in 0..M {
        let ar: [f64; DI] = std::array::from_fn(|r| a[r * M + i]);
        let bc: [f64; DJ] = std::array::from_fn(|c| b[c * M + i]);
        add_outer(&ar, &bc, acc);
    }
}

/// acc += a bᵀ (acc column-major, DI × DJ).
#[inline(always)]
fn add_outer<const DI: usize, const DJ: usize>(
    a: &[f64; DI],
    b: &[f64; DJ],
    acc: &mut [[f64; DI]; DJ],
) {
    for (column, &bv) in acc.iter_mut().zip(b) {
        for (o, &av) in column.iter_mut().zip(a) {
            *o += av * bv;
        }
    }
}

/// Each free variable's block index (usize::MAX for fixed ones), each block's variable, and the
/// blocks' scalar starts.
fn free_blocks(problem: &Problem) -> (Vec<usize>, Vec<usize>, Vec<usize>) {
    let mut block_of_var = vec![usize::MAX; problem.variables.len()];
    let mut var_of_block = Vec::new();
    let mut block_start = vec![0];
    for (v, var) in problem.variables.iter().enumerate() {
        if !var.fixed {
            block_of_var[v] = var_of_block.len();
            var_of_block.push(v);
            block_start.push(block_start.last().unwrap() + var.manifold.tangent_dim());
        }
    }
    (block_of_var, var_of_block, block_start)
}

/// (col block, row block, residual, Jacobian offset of the row block, of the column block, rows)
type Pair = (usize, usize, usize, usize, usize, usize);
/// (block, residual, Jacobian offset, residual offset, rows)
type GradientEntry = (usize, usize, usize, usize, usize);

/// Where each residual's values and Jacobian blocks live, and what each contributes to H and g.
struct ResidualLayout {
    res_offset: Vec<usize>,
    jac_offset: Vec<usize>,
    pairs: Vec<Pair>,
    grad_list: Vec<GradientEntry>,
    /// Whether some residual touches each block.
    touched: Vec<bool>,
}

impl ResidualLayout {
    fn new(problem: &Problem, block_of_var: &[usize], nb: usize) -> Self {
        // Sized exactly: grown by doubling, the lists of a large problem kept up to twice their
        // size.
        let (mut num_pairs, mut num_grads) = (0, 0);
        for block in &problem.blocks {
            let free = block
                .vars
                .iter()
                .filter(|&&v| block_of_var[v] != usize::MAX)
                .count();
            num_pairs += free * (free + 1) / 2;
            num_grads += free;
        }
        let mut out = Self {
            res_offset: Vec::with_capacity(problem.blocks.len() + 1),
            jac_offset: Vec::with_capacity(problem.blocks.len() + 1),
            pairs: Vec::with_capacity(num_pairs),
            grad_list: Vec::with_capacity(num_grads),
            touched: vec![false; nb],
        };
        out.res_offset.push(0);
        out.jac_offset.push(0);
        for (k, block) in problem.blocks.iter().enumerate() {
            let m = block.residual.dim();
            let (r0, j0) = (
                *out.res_offset.last().unwrap(),
                *out.jac_offset.last().unwrap(),
            );
            let mut local = Vec::with_capacity(block.vars.len());
            let mut off = j0;
            for (&v, &c) in block.vars.iter().zip(&block.cols) {
                let b = block_of_var[v];
                if b != usize::MAX {
                    local.push((b, off));
                    out.touched[b] = true;
                    out.grad_list.push((b, k, off, r0, m));
                }
                off += m * c;
            }
            for &(ba, ja) in &local {
                for &(bb, jb) in &local {
                    if ba <= bb {
                        out.pairs.push((bb, ba, k, ja, jb, m));
                    }
                }
            }
            out.res_offset.push(r0 + m);
            out.jac_offset.push(off);
        }
        out
    }
}

/// From the sorted pairs: each block column's row blocks, and each entry's contributions.
fn hessian_contributions(
    pairs: &[Pair],
    nb: usize,
) -> (Vec<Vec<usize>>, Vec<usize>, Vec<Contribution>) {
    let mut columns: Vec<Vec<usize>> = vec![Vec::new(); nb];
    let mut contrib_ptr = vec![0];
    let mut contribs = Vec::with_capacity(pairs.len());
    let mut i = 0;
    while i < pairs.len() {
        let (col, row) = (pairs[i].0, pairs[i].1);
        columns[col].push(row);
        while i < pairs.len() && pairs[i].0 == col && pairs[i].1 == row {
            let p = pairs[i];
            // offsets below 2³², checked by `NormalEquations::build`
            contribs.push(Contribution {
                ja: p.3 as u32,
                jb: p.4 as u32,
                m: p.5 as u32,
            });
            i += 1;
        }
        contrib_ptr.push(contribs.len());
    }
    (columns, contrib_ptr, contribs)
}

/// From the sorted gradient entries: each block's contributions to g.
fn gradient_contributions(
    grad_list: &[GradientEntry],
    nb: usize,
) -> (Vec<usize>, Vec<GradientContribution>) {
    let mut grad_ptr = vec![0; nb + 1];
    let mut grads = Vec::with_capacity(grad_list.len());
    for g in grad_list {
        grad_ptr[g.0 + 1] += 1;
        grads.push(GradientContribution {
            j: g.2 as u32,
            r: g.3 as u32,
            m: g.4 as u32,
        });
    }
    for b in 0..nb {
        grad_ptr[b + 1] += grad_ptr[b];
    }
    (grad_ptr, grads)
}
