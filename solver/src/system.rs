//! A symmetric block-sparse system `(H + μD) δ = −g` that its caller assembles, solved by the
//! Cholesky factorisation behind [`Solver`](crate::Solver)'s sparse path (block AMD ordering, faer's
//! sparse Cholesky, the symbolic analysis done once for the structure).
//!
//! This is the path for problems whose terms share work the [`Residual`](crate::Residual)
//! interface cannot see. The embedded-deformation data term is the example: every Jacobian block
//! of a point factors as `c_k G P_k` through the eight coordinates of one blended dual quaternion,
//! so `H_kl = P_kᵀ (Σ c_k c_l GᵀG) P_l` is summed once per node pair in those eight coordinates and
//! projected once (Sumner et al. 2007; Newcombe et al. 2015 assemble it the same way on the GPU).
//! The caller keeps its own Levenberg-Marquardt loop; the [`Problem`](crate::Problem) API stays the
//! way for everything else.

use crate::block::{block_starts, BlockSparse, SIX};
use crate::block_rows::BlockRows;
use crate::cholesky::{Cholesky, FactorPrecision};
use crate::damping::Damping;
use crate::error::SolveError;
use crate::parallel::{dot, for_parts};
use crate::schur::kernels::invert_spd;
use crate::Options;
use std::sync::atomic::{AtomicUsize, Ordering};

/// H (upper triangle, block-sparse), g, and a factorisation prepared for H's structure.
pub struct BlockSystem {
    h: BlockSparse,
    /// Block column of each entry.
    entry_col: Vec<usize>,
    gradient: Vec<f64>,
    /// The factorisation, its symbolic analysis made at the first [`Self::factorise`]: a system
    /// only ever solved by [`Self::solve_block_jacobi`] never pays for it.
    cholesky: Option<Cholesky>,
    /// The number type the factor is kept in.
    precision: FactorPrecision,
    /// Whether a solve with the factor is exact up to rounding (f64, or dense).
    exact: bool,
    /// Whether `cholesky` holds a factorisation (of an earlier H of this structure).
    factored: bool,
    /// Conjugate-gradient buffers: residual, preconditioned residual, direction, product, and
    /// the product's second half.
    cg: [Vec<f64>; 5],
    /// The inverses of the damped diagonal blocks (d² numbers per block, column-major), for
    /// [`Self::solve_block_jacobi`], and one block's worth of scratch.
    jacobi: Vec<f64>,
    jacobi_scratch: Vec<f64>,
    /// Where each block's inverse starts in `jacobi`, with the total at the end.
    jacobi_at: Vec<usize>,
    /// `H + μD` by full block rows in single precision, the product of
    /// [`Self::solve_block_jacobi`] in a system of [`FactorPrecision::Single`].
    rows: BlockRows,
}

/// Numbers of the diagonal blocks' inverses below which a run of them is inverted on one
/// thread (about 230 blocks of six).
const INVERT_SERIAL: usize = 8192;
/// Stored numbers of H below which [`BlockSystem::set_entries`] sets a run of block columns on
/// one thread.
const SET_SERIAL: usize = 1 << 15;
/// Numbers of a block [`BlockSystem::set_entries`] hands out from the stack (9 × 9: a camera's).
const SMALL_BLOCK: usize = 81;

/// Relative residual to which [`BlockSystem::solve`] iterates on a single-precision factor.
const SINGLE_PRECISION_TOLERANCE: f64 = 1e-12;
/// Conjugate-gradient iterations [`BlockSystem::solve`] allows on a single-precision factor.
const SINGLE_PRECISION_ITERATIONS: usize = 50;

/// What [`BlockSystem::solve_refined`] did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Refined {
    /// Conjugate-gradient iterations (each one product with H and one application of the
    /// preconditioner: a solve with the factor, or the diagonal blocks' inverses).
    pub iterations: usize,
    /// Whether ‖(H + μD) δ + g‖ ≤ tolerance · ‖g‖ was reached.
    pub converged: bool,
}

impl std::fmt::Debug for BlockSystem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BlockSystem")
            .field("blocks", &self.num_blocks())
            .field("entries", &self.num_entries())
            .field("dim", &self.dim())
            .finish()
    }
}

impl BlockSystem {
    /// A system of blocks of sizes `sizes` whose off-diagonal blocks are `pairs` (either order,
    /// repeats allowed; every diagonal block is stored anyway). Values start at zero. The symbolic
    /// factorisation is computed here, once.
    pub fn new(
        sizes: &[usize],
        pairs: impl IntoIterator<Item = (usize, usize)>,
    ) -> Result<Self, SolveError> {
        Self::with_precision(sizes, pairs, FactorPrecision::Double)
    }

    /// [`Self::new`] with a sparse factor kept in `precision`. With
    /// [`FactorPrecision::Single`], [`Self::solve`] iterates on the factor to full precision;
    /// callers content with less use [`Self::factorise`] and [`Self::solve_refined`], or
    /// [`Self::solve_block_jacobi`], whose products are then taken in single precision too. The
    /// symbolic factorisation waits for the first factorisation.
    pub fn with_precision(
        sizes: &[usize],
        pairs: impl IntoIterator<Item = (usize, usize)>,
        precision: FactorPrecision,
    ) -> Result<Self, SolveError> {
        let n = sizes.len();
        let columns = block_columns(n, pairs)?;
        let h = BlockSparse::new(block_starts(sizes), &columns);
        let entry_col = (0..n)
            .flat_map(|j| std::iter::repeat_n(j, h.entry_ptr[j + 1] - h.entry_ptr[j]))
            .collect();
        Ok(Self {
            gradient: vec![0.0; h.dim()],
            exact: is_dense(&h) || precision == FactorPrecision::Double,
            h,
            entry_col,
            cholesky: None,
            precision,
            factored: false,
            cg: Default::default(),
            jacobi: Vec::new(),
            jacobi_scratch: Vec::new(),
            jacobi_at: Vec::new(),
            rows: BlockRows::default(),
        })
    }

    /// Takes the buffers of `old`, a system this one replaces, so that solving does not allocate
    /// them anew (their capacity only: nothing of `old`'s values or structure is used).
    pub fn reuse_buffers(&mut self, old: BlockSystem) {
        self.cg = old.cg;
        self.jacobi = old.jacobi;
        self.jacobi_scratch = old.jacobi_scratch;
        self.rows = old.rows.recycled();
    }

    /// Scalar size.
    pub fn dim(&self) -> usize {
        self.h.dim()
    }

    /// Number of blocks.
    pub fn num_blocks(&self) -> usize {
        self.h.num_blocks()
    }

    /// Number of stored blocks of the upper triangle (diagonal ones included).
    pub fn num_entries(&self) -> usize {
        self.h.entries.len()
    }

    /// Scalar offset of block `b`.
    pub fn block_start(&self, b: usize) -> usize {
        self.h.block_start[b]
    }

    /// The entry index of block (i, j) (either order: the stored one is (min, max)), if stored.
    pub fn entry(&self, i: usize, j: usize) -> Option<usize> {
        if i.max(j) >= self.num_blocks() {
            return None;
        }
        self.h.find(i.min(j), i.max(j))
    }

    /// The blocks (i, j), i ≤ j, of entry `e`.
    pub fn entry_blocks(&self, e: usize) -> (usize, usize) {
        (self.h.entries[e].row_block, self.entry_col[e])
    }

    /// Sets H and g to zero.
    pub fn clear(&mut self) {
        self.h.values.fill(0.0);
        self.gradient.fill(0.0);
    }

    /// Sets every entry of H: `block(e, i, j, out)` writes entry e = (i, j), i ≤ j, into `out`
    /// (dᵢ × dⱼ, column-major, zeroed before the call; of a diagonal block only the upper
    /// triangle is read). The block columns are set in parallel, so `block` is called from
    /// several threads; the result does not depend on their number. g is left as it is.
    pub fn set_entries(&mut self, block: impl Fn(usize, usize, usize, &mut [f64]) + Sync) {
        // the values leave H while its structure is read beside them
        let mut values = std::mem::take(&mut self.h.values);
        let h = &self.h;
        let start = |j: usize| h.col_ptr[h.block_start[j]];
        for_parts(
            0..h.num_blocks(),
            &mut values,
            (&start, &start),
            SET_SERIAL,
            &|cols, part| {
                let base = start(cols.start);
                // one block's numbers: on the stack when small, as a pose's or a node's are
                let (mut small, mut large) = ([0.0; SMALL_BLOCK], Vec::new());
                for j in cols {
                    let dj = h.block_dim(j);
                    for e in h.entry_ptr[j]..h.entry_ptr[j + 1] {
                        let i = h.entries[e].row_block;
                        let di = h.block_dim(i);
                        let out = match di * dj <= SMALL_BLOCK {
                            true => &mut small[..di * dj],
                            false => {
                                large.resize(di * dj, 0.0);
                                &mut large[..]
                            }
                        };
                        out.fill(0.0);
                        block(e, i, j, out);
                        for c in 0..dj {
                            let rows = if i == j { c + 1 } else { di };
                            let at = h.column_start(j, e, c) - base;
                            part[at..at + rows].copy_from_slice(&out[c * di..c * di + rows]);
                        }
                    }
                }
            },
        );
        self.h.values = values;
    }

    /// Adds `block` (dᵢ × dⱼ, column-major) to entry `e` = (i, j), i ≤ j. Of a diagonal block only
    /// the upper triangle is read. Panics when `block` is not dᵢ × dⱼ long (a caller's bug, not
    /// an input).
    pub fn add_to_entry(&mut self, e: usize, block: &[f64]) {
        let (i, j) = self.entry_blocks(e);
        let (di, dj) = (self.h.block_dim(i), self.h.block_dim(j));
        assert_eq!(block.len(), di * dj, "block of entry {e} is {di} x {dj}");
        for c in 0..dj {
            let rows = if i == j { c + 1 } else { di };
            let start = self.h.column_start(j, e, c);
            for (v, b) in self.h.values[start..start + rows]
                .iter_mut()
                .zip(&block[c * di..])
            {
                *v += b;
            }
        }
    }

    /// The gradient g (one segment per block, at [`Self::block_start`]).
    pub fn gradient(&self) -> &[f64] {
        &self.gradient
    }

    /// The gradient, to add to.
    pub fn gradient_mut(&mut self) -> &mut [f64] {
        &mut self.gradient
    }

    /// Element (r, c) of the symmetric H (either triangle; 0 where no block is stored).
    pub fn get(&self, r: usize, c: usize) -> f64 {
        let (r, c) = (r.min(c), r.max(c));
        let (bi, bj) = (self.h.block_of_scalar(r), self.h.block_of_scalar(c));
        match self.h.find(bi, bj) {
            Some(e) => {
                let start = self.h.column_start(bj, e, c - self.h.block_start[bj]);
                self.h.values[start + r - self.h.block_start[bi]]
            }
            None => 0.0,
        }
    }

    /// The largest diagonal element of H (0 for an empty system).
    pub fn max_diagonal(&self) -> f64 {
        self.h.diagonal().fold(0.0, f64::max)
    }

    /// Writes the step δ solving `(H + μD) δ = −g` into `step` (length [`Self::dim`]). Fails when
    /// the damped matrix is not numerically positive definite (raise the damping and retry), or
    /// when conjugate gradients on a single-precision factor do not reach a relative residual of
    /// 1e-12 in 50 iterations.
    pub fn solve(&mut self, damping: Damping, step: &mut [f64]) -> Result<(), SolveError> {
        assert_eq!(step.len(), self.dim(), "step length");
        self.factorise(damping)?;
        if !self.exact {
            let refined = self.solve_refined(
                damping,
                step,
                SINGLE_PRECISION_TOLERANCE,
                SINGLE_PRECISION_ITERATIONS,
            );
            return match refined.converged {
                true => Ok(()),
                false => Err(SolveError::LinearSolver(format!(
                    "conjugate gradients on the single-precision factor did not converge in {} \
                     iterations",
                    refined.iterations
                ))),
            };
        }
        for (s, g) in step.iter_mut().zip(&self.gradient) {
            *s = -g;
        }
        self.cholesky
            .as_mut()
            .expect("factorised above")
            .solve(step);
        Ok(())
    }

    /// Factorises `H + μD` (for [`Self::solve_refined`], or inside [`Self::solve`]). Fails when
    /// it is not numerically positive definite.
    pub fn factorise(&mut self, damping: Damping) -> Result<(), SolveError> {
        self.factored = false;
        let cholesky = match &mut self.cholesky {
            Some(c) => c,
            none => none.insert(Cholesky::with_precision(
                &self.h,
                is_dense(&self.h),
                self.precision,
            )?),
        };
        cholesky
            .factor(&self.h, damping)
            .map_err(|pivot| SolveError::RankDeficient {
                nullity: 1,
                variables: vec![self.h.block_of_scalar(pivot)],
                message: format!(
                    "the damped system is not positive definite at block {}",
                    self.h.block_of_scalar(pivot)
                ),
            })?;
        self.factored = true;
        Ok(())
    }

    /// Whether a factorisation from an earlier [`Self::solve`] or [`Self::factorise`] is held
    /// (for [`Self::solve_refined`]).
    pub fn has_factorisation(&self) -> bool {
        self.factored
    }

    /// Solves `(H + μD) δ = −g` by conjugate gradients preconditioned with the factorisation of
    /// the last [`Self::solve`] or [`Self::factorise`], whose matrix (an earlier H of the same structure, its damping)
    /// need not be the current one: a factorisation of a nearby matrix is a preconditioner that
    /// leaves few distinct eigenvalues, so a few iterations replace a new factorisation
    /// (Hestenes & Stiefel 1952; Saad, *Iterative Methods for Sparse Linear Systems*, 2003,
    /// alg. 9.1). Stops at `‖r‖ ≤ tolerance ‖g‖` or after `max_iterations`; the step is the last
    /// iterate either way, and [`Refined::converged`] says which. Without a factorisation held,
    /// nothing is solved and `step` is zero with `converged` false.
    pub fn solve_refined(
        &mut self,
        damping: Damping,
        step: &mut [f64],
        tolerance: f64,
        max_iterations: usize,
    ) -> Refined {
        assert_eq!(step.len(), self.dim(), "step length");
        let cholesky = match (&mut self.cholesky, self.factored) {
            (Some(c), true) => c,
            _ => {
                step.fill(0.0);
                return Refined {
                    iterations: 0,
                    converged: false,
                };
            }
        };
        let h = &self.h;
        let cg = CgSystem {
            product: |x: &[f64], y: &mut [f64], half: &mut Vec<f64>| {
                multiply_damped(h, damping, x, y, half)
            },
            gradient: &self.gradient,
        };
        cg.solve(
            &mut self.cg,
            step,
            tolerance,
            max_iterations,
            |z| cholesky.solve(z),
            CgStart::Zero,
        )
    }

    /// Solves `(H + μD) δ = −g` by conjugate gradients preconditioned with the inverses of the
    /// damped diagonal blocks (block Jacobi; Saad 2003, sec. 10.2), as real-time non-rigid
    /// trackers solve their warp fields (Newcombe, Fox & Seitz, *DynamicFusion*, CVPR 2015;
    /// Innmann et al., *VolumeDeform*, ECCV 2016). Nothing is factorised: each iteration costs
    /// one product with `H + μD`. In a system of [`FactorPrecision::Single`] the product is
    /// taken on a single-precision copy of `H + μD` by full block rows (module `block_rows`:
    /// the product is bound by reading the matrix, and the copy reads half as much), so the
    /// step solves the copy's system, whose entries are H's rounded to 24 bits (6·10⁻⁸
    /// relative); in one of [`FactorPrecision::Double`] on H itself. Stops at
    /// `‖r‖ ≤ tolerance ‖g‖` or after `max_iterations`; each iterate lowers the quadratic model it
    /// solves below its value at δ = 0, so `−gᵀδ > 0` and a truncated solve is still a descent
    /// direction ([`Self::model_decrease`] gives its decrease on H). `start` says whether to
    /// begin at 0 or at the guess `step` holds ([`CgStart`]). Fails when a damped diagonal block
    /// is not positive definite.
    pub fn solve_block_jacobi(
        &mut self,
        damping: Damping,
        step: &mut [f64],
        tolerance: f64,
        max_iterations: usize,
        start: CgStart,
    ) -> Result<Refined, SolveError> {
        assert_eq!(step.len(), self.dim(), "step length");
        self.invert_diagonal_blocks(damping)?;
        let single = self.precision == FactorPrecision::Single;
        if single {
            self.rows.fill(&self.h, damping);
        }
        let (h, jacobi, scratch) = (&self.h, &self.jacobi, &mut self.jacobi_scratch);
        let rows = &self.rows;
        let cg = CgSystem {
            product: |x: &[f64], y: &mut [f64], half: &mut Vec<f64>| match single {
                true => rows.multiply(x, y),
                false => multiply_damped(h, damping, x, y, half),
            },
            gradient: &self.gradient,
        };
        let precondition = |z: &mut [f64]| apply_block_inverses(h, jacobi, z, scratch);
        Ok(cg.solve(
            &mut self.cg,
            step,
            tolerance,
            max_iterations,
            precondition,
            start,
        ))
    }

    /// Fills [`Self::jacobi`] with the inverse of each damped diagonal block, runs of blocks
    /// in parallel. Fails naming the first block that is not positive definite.
    fn invert_diagonal_blocks(&mut self, damping: Damping) -> Result<(), SolveError> {
        let h = &self.h;
        let nb = h.num_blocks();
        // block b's inverse is jacobi[at[b]..at[b + 1]]
        let at = &mut self.jacobi_at;
        at.clear();
        at.push(0);
        for b in 0..nb {
            at.push(at[b] + h.block_dim(b).pow(2));
        }
        let at = &self.jacobi_at;
        self.jacobi.resize(at[nb], 0.0);
        let failed = AtomicUsize::new(usize::MAX);
        let start = |b: usize| at[b];
        for_parts(
            0..nb,
            &mut self.jacobi,
            (&start, &start),
            INVERT_SERIAL,
            &|blocks, part| {
                let base = at[blocks.start];
                for b in blocks {
                    let block = &mut part[at[b] - base..at[b + 1] - base];
                    h.damped_diagonal_block(b, damping, block);
                    if invert_spd(block, h.block_dim(b)).is_err() {
                        failed.fetch_min(b, Ordering::Relaxed);
                    }
                }
            },
        );
        match failed.into_inner() {
            usize::MAX => Ok(()),
            b => Err(SolveError::RankDeficient {
                nullity: 1,
                variables: vec![b],
                message: format!("the damped diagonal block {b} is not positive definite"),
            }),
        }
    }

    /// The decrease `−gᵀδ − ½ δᵀHδ` the undamped quadratic model predicts for any step δ (for an
    /// exact solution of the damped system it equals [`Damping::predicted_decrease`]).
    pub fn model_decrease(&mut self, step: &[f64]) -> f64 {
        let [.., q, half] = &mut self.cg;
        q.resize(self.h.dim(), 0.0);
        self.h.multiply_split(step, q, half);
        -dot(&self.gradient, step) - 0.5 * dot(step, q)
    }
}

/// Each block column's row blocks, ascending and without repeats, its diagonal included, from
/// `pairs` (either order, repeats allowed): counted, placed in one array, then each column's
/// repeats dropped and the rest sorted, so that no column grows one push at a time (a warp
/// field's system is rebuilt from ~50,000 pairs, most of them repeats, whenever its graph
/// grows).
fn block_columns(
    n: usize,
    pairs: impl IntoIterator<Item = (usize, usize)>,
) -> Result<Vec<Vec<usize>>, SolveError> {
    let pairs: Vec<(usize, usize)> = pairs.into_iter().collect();
    if let Some(&(i, j)) = pairs.iter().find(|&&(i, j)| i >= n || j >= n) {
        return Err(SolveError::LinearSolver(format!(
            "block pair ({i}, {j}) outside a system of {n} blocks"
        )));
    }
    // column j's rows go to rows[ptr[j]..ptr[j + 1]], the diagonal first
    let mut ptr = vec![1usize; n + 1];
    ptr[n] = 0;
    for &(i, j) in &pairs {
        ptr[i.max(j)] += 1;
    }
    let mut total = 0;
    for p in &mut ptr {
        (*p, total) = (total, total + *p);
    }
    let mut rows = vec![0usize; total];
    let mut cursor = ptr.clone();
    for j in 0..n {
        rows[cursor[j]] = j;
        cursor[j] += 1;
    }
    for &(i, j) in &pairs {
        let c = i.max(j);
        rows[cursor[c]] = i.min(j);
        cursor[c] += 1;
    }
    // repeats dropped before sorting: `seen[i] == j` once row i is in column j
    let mut seen = vec![usize::MAX; n];
    Ok((0..n)
        .map(|j| {
            let mut out: Vec<usize> = rows[ptr[j]..ptr[j + 1]]
                .iter()
                .filter(|&&i| std::mem::replace(&mut seen[i], j) != j)
                .copied()
                .collect();
            out.sort_unstable();
            out
        })
        .collect())
}

/// Whether H is small enough to factorise densely (the solver's default threshold, as on its
/// own sparse path).
fn is_dense(h: &BlockSparse) -> bool {
    h.dim() <= Options::default().dense_threshold
}

/// Where conjugate gradients start.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CgStart {
    /// From δ = 0: every iterate lowers the quadratic model below its value at 0, so even a
    /// truncated solve is a descent direction.
    Zero,
    /// From the δ the step buffer holds (a nearby system's solution: the last frame's step of
    /// a tracker), when the quadratic model is lower there than at 0, which keeps every iterate
    /// a descent direction; from 0 otherwise. It costs one more product.
    Guess,
}

/// The damped system a conjugate-gradient solve works on: its product `y = (H + μD) x` (given
/// a scratch vector) and g.
struct CgSystem<'a, P> {
    product: P,
    gradient: &'a [f64],
}

impl<P: Fn(&[f64], &mut [f64], &mut Vec<f64>)> CgSystem<'_, P> {
    /// Whether conjugate gradients may start at the guess `x`: the quadratic model
    /// `m(x) = gᵀx + ½ xᵀ(H + μD)x` is below m(0) = 0 there, i.e. x lies nearer the solution
    /// than 0 does in the energy norm (`m(x) = ½‖x − δ*‖² − ½‖δ*‖²`). Leaves the residual
    /// `r = −g − (H + μD)x` in `r` (`q` and `half` are scratch).
    fn start_at_guess(&self, x: &[f64], r: &mut [f64], q: &mut [f64], half: &mut Vec<f64>) -> bool {
        (self.product)(x, q, half);
        let model = dot(self.gradient, x) + 0.5 * dot(x, q);
        for ((r, g), q) in r.iter_mut().zip(self.gradient).zip(&*q) {
            *r = -g - q;
        }
        model < 0.0
    }

    /// Preconditioned conjugate gradients on `(H + μD) δ = −g` from δ = 0 or a guess
    /// ([`CgStart`]) (Hestenes & Stiefel 1952; Saad 2003, alg. 9.1), `precondition` replacing
    /// r by M⁻¹ r in place; `buffers` are the residual, preconditioned residual, direction,
    /// product and the product's second half. Stops at `‖r‖ ≤ tolerance ‖g‖` wherever it began.
    fn solve(
        &self,
        buffers: &mut [Vec<f64>; 5],
        step: &mut [f64],
        tolerance: f64,
        max_iterations: usize,
        mut precondition: impl FnMut(&mut [f64]),
        start: CgStart,
    ) -> Refined {
        let n = step.len();
        let [r, z, p, q, half] = buffers;
        for v in [&mut *r, &mut *z, &mut *p, &mut *q] {
            v.resize(n, 0.0);
        }
        let mut out = Refined {
            iterations: 0,
            converged: false,
        };
        let bound = tolerance * dot(self.gradient, self.gradient).sqrt();
        if bound == 0.0 {
            step.fill(0.0);
            out.converged = true;
            return out;
        }
        if !(start == CgStart::Guess && self.start_at_guess(step, r, q, half)) {
            step.fill(0.0);
            for (r, g) in r.iter_mut().zip(self.gradient) {
                *r = -g;
            }
        }
        if dot(r, r).sqrt() <= bound {
            out.converged = true;
            return out;
        }
        z.copy_from_slice(r);
        precondition(z);
        p.copy_from_slice(z);
        let mut rz = dot(r, z);
        while out.iterations < max_iterations {
            out.iterations += 1;
            (self.product)(p, q, half);
            let pq = dot(p, q);
            if !(pq > 0.0 && rz.is_finite()) {
                break;
            }
            let alpha = rz / pq;
            // ‖r‖² summed in index order as `dot` sums it, in the update's pass
            let mut rr = 0.0;
            for (((x, r), p), q) in step.iter_mut().zip(r.iter_mut()).zip(&*p).zip(&*q) {
                *x += alpha * p;
                *r -= alpha * q;
                rr += *r * *r;
            }
            if rr.sqrt() <= bound {
                out.converged = true;
                break;
            }
            z.copy_from_slice(r);
            precondition(z);
            let rz_next = dot(r, z);
            let beta = rz_next / rz;
            rz = rz_next;
            for (p, z) in p.iter_mut().zip(&*z) {
                *p = z + beta * *p;
            }
        }
        out
    }
}

/// z ← M⁻¹ z for the block-diagonal M whose blocks' inverses `inverses` holds (d² numbers per
/// block, column-major); `x` is scratch.
fn apply_block_inverses(h: &BlockSparse, inverses: &[f64], z: &mut [f64], x: &mut Vec<f64>) {
    let mut at = 0;
    for b in 0..h.num_blocks() {
        let (start, d) = (h.block_start[b], h.block_dim(b));
        let inverse = &inverses[at..at + d * d];
        if let Ok(z) = <&mut [f64; SIX]>::try_from(&mut z[start..start + d]) {
            // a pose's or a node's block: its columns scaled and added, unrolled
            let r = *z;
            *z = [0.0; SIX];
            for (column, &rc) in inverse.chunks_exact(SIX).zip(&r) {
                for (o, &v) in z.iter_mut().zip(column) {
                    *o = v.mul_add(rc, *o);
                }
            }
            at += d * d;
            continue;
        }
        x.clear();
        x.extend_from_slice(&z[start..start + d]);
        for (r, out) in z[start..start + d].iter_mut().enumerate() {
            *out = x
                .iter()
                .enumerate()
                .map(|(c, v)| inverse[r + c * d] * v)
                .sum();
        }
        at += d * d;
    }
}

/// y = (H + μD) x, on two threads for a large H (`scratch` for the second's half).
fn multiply_damped(
    h: &BlockSparse,
    damping: Damping,
    x: &[f64],
    y: &mut [f64],
    scratch: &mut Vec<f64>,
) {
    h.multiply_split(x, y, scratch);
    for (i, at) in h.diag_pos().enumerate() {
        let v = h.values[at];
        y[i] += (h.damped(damping, i, v) - v) * x[i];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Block-Jacobi conjugate gradients from 0 at damping 0.25.
    fn solve_cold(
        s: &mut BlockSystem,
        step: &mut [f64],
        tolerance: f64,
        cap: usize,
    ) -> Result<Refined, SolveError> {
        s.solve_block_jacobi(Damping::Identity(0.25), step, tolerance, cap, CgStart::Zero)
    }

    /// Pairs in either order and repeated make one entry each, beside every diagonal; a pair
    /// outside the system is an error naming it.
    #[test]
    fn block_columns_are_sorted_without_repeats_and_keep_the_diagonal() {
        let pairs = [(1, 0), (0, 1), (3, 1), (1, 3), (1, 3), (0, 3), (2, 2)];
        let columns = block_columns(4, pairs).unwrap();
        assert_eq!(columns, vec![vec![0], vec![0, 1], vec![2], vec![0, 1, 3]]);
        let err = block_columns(3, [(0, 1), (3, 0)]).unwrap_err();
        assert!(err.to_string().contains("(3, 0)"), "{err}");
    }

    /// A 3-block system (sizes 2, 1, 2) coupling blocks 0-2 and 1-2, filled from a dense SPD
    /// matrix with that pattern: the solve must match the dense solution, with and without damping.
    #[test]
    fn assembled_blocks_solve_like_the_dense_matrix() {
        let mut s = BlockSystem::new(&[2, 1, 2], [(2, 0), (1, 2), (0, 2)]).unwrap();
        assert_eq!(s.num_entries(), 5);
        assert_eq!(s.entry(1, 0), None);
        let dense = nalgebra::DMatrix::from_row_slice(
            5,
            5,
            &[
                4.0, 1.0, 0.0, 0.5, 0.2, //
                1.0, 3.0, 0.0, 0.1, 0.3, //
                0.0, 0.0, 2.0, 0.4, -0.2, //
                0.5, 0.1, 0.4, 5.0, 1.0, //
                0.2, 0.3, -0.2, 1.0, 6.0,
            ],
        );
        let g = nalgebra::DVector::from_column_slice(&[1.0, -2.0, 0.5, 3.0, -1.0]);
        for e in 0..s.num_entries() {
            let (i, j) = s.entry_blocks(e);
            let (ri, cj) = (s.block_start(i), s.block_start(j));
            let (di, dj) = (s.block_start(i + 1) - ri, s.block_start(j + 1) - cj);
            let block: Vec<f64> = (0..dj)
                .flat_map(|c| (0..di).map(move |r| (r, c)))
                .map(|(r, c)| dense[(ri + r, cj + c)])
                .collect();
            // in two halves, to exercise accumulation
            let half: Vec<f64> = block.iter().map(|v| v * 0.5).collect();
            s.add_to_entry(e, &half);
            s.add_to_entry(e, &half);
        }
        s.gradient_mut().copy_from_slice(g.as_slice());
        for r in 0..5 {
            for c in 0..5 {
                assert_eq!(s.get(r, c), dense[(r, c)], "({r}, {c})");
            }
        }
        assert_eq!(s.max_diagonal(), 6.0);
        for mu in [0.0, 0.7] {
            let mut step = vec![0.0; 5];
            s.solve(Damping::Identity(mu), &mut step).unwrap();
            let a = &dense + nalgebra::DMatrix::identity(5, 5) * mu;
            let expect = a.cholesky().unwrap().solve(&(-&g));
            for (x, y) in step.iter().zip(expect.iter()) {
                assert!((x - y).abs() < 1e-12, "{step:?} {expect}");
            }
        }
        s.clear();
        assert_eq!(s.get(3, 4), 0.0);
        assert!(s.solve(Damping::None, &mut [0.0; 5]).is_err());
    }

    /// A pseudo-random number generator in [-0.5, 0.5).
    fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut seed = seed;
        move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        }
    }

    /// `JᵀJ + I` of a random banded J over a chain of `nb` blocks of 6, and a random g.
    fn chain_matrix(nb: usize, seed: u64) -> (nalgebra::DMatrix<f64>, nalgebra::DVector<f64>) {
        let n = nb * 6;
        let mut next = uniform(seed);
        let mut j = nalgebra::DMatrix::<f64>::zeros(n, n);
        for r in 0..n {
            for c in r.saturating_sub(12)..(r + 1) {
                j[(r, c)] = next();
            }
        }
        let g = nalgebra::DVector::from_fn(n, |_, _| next());
        (j.transpose() * &j + nalgebra::DMatrix::identity(n, n), g)
    }

    /// The structure of a chain of `nb` blocks of 6, each coupled to the two before it.
    fn chain_structure(nb: usize, precision: FactorPrecision) -> BlockSystem {
        let pairs = (0..nb).flat_map(|b| (b.saturating_sub(2)..b).map(move |a| (a, b)));
        BlockSystem::with_precision(&vec![6; nb], pairs, precision).unwrap()
    }

    /// The chain's system (`s`, or a new one of f64) holding `dense` and `g`.
    fn chain_system(
        s: Option<BlockSystem>,
        dense: &nalgebra::DMatrix<f64>,
        g: &nalgebra::DVector<f64>,
    ) -> BlockSystem {
        let nb = dense.nrows() / 6;
        let mut s = s.unwrap_or_else(|| chain_structure(nb, FactorPrecision::Double));
        s.clear();
        for e in 0..s.num_entries() {
            let (bi, bj) = s.entry_blocks(e);
            let block: Vec<f64> = (0..6)
                .flat_map(|c| (0..6).map(move |r| (r, c)))
                .map(|(r, c)| dense[(bi * 6 + r, bj * 6 + c)])
                .collect();
            s.add_to_entry(e, &block);
        }
        s.gradient_mut().copy_from_slice(g.as_slice());
        s
    }

    /// The dense solution of `(A + μI) δ = −g`.
    fn dense_step(
        a: &nalgebra::DMatrix<f64>,
        g: &nalgebra::DVector<f64>,
        mu: f64,
    ) -> nalgebra::DVector<f64> {
        let n = a.nrows();
        (a + nalgebra::DMatrix::identity(n, n) * mu)
            .cholesky()
            .unwrap()
            .solve(&(-g))
    }

    /// A chain of 60 blocks of 6 (360 unknowns: the sparse path) filled from `JᵀJ + I` of a random
    /// banded J, against nalgebra's dense Cholesky.
    #[test]
    fn a_large_chain_solves_on_the_sparse_path() {
        let (dense, g) = chain_matrix(60, 7);
        let mut s = chain_system(None, &dense, &g);
        let mut step = vec![0.0; dense.nrows()];
        s.solve(Damping::Identity(0.25), &mut step).unwrap();
        let expect = dense_step(&dense, &g, 0.25);
        let err = (nalgebra::DVector::from_vec(step) - &expect).amax();
        assert!(err < 1e-10 * (1.0 + expect.amax()), "{err}");
    }

    /// Conjugate gradients preconditioned by the factorisation of another matrix of the same
    /// structure (another J, another damping) reach the new system's solution in far fewer
    /// iterations than unknowns; the model decrease of an exact step is the damped formula's; an
    /// iteration cap short of the tolerance is reported; without a factorisation nothing is solved.
    #[test]
    fn refined_solves_reach_a_changed_system_on_an_earlier_factorisation() {
        let (first, g) = chain_matrix(60, 7);
        let mut s = chain_system(None, &first, &g);
        let n = first.nrows();
        let mut step = vec![1.0; n];
        let none = s.solve_refined(Damping::Identity(0.5), &mut step, 1e-6, 10);
        assert_eq!((none.iterations, none.converged), (0, false));
        assert!(step.iter().all(|v| *v == 0.0));
        s.solve(Damping::Identity(0.25), &mut step).unwrap();
        // the next iteration's matrix: J moved by a tenth of its size
        let (other, g2) = chain_matrix(60, 8);
        let second = &first * 0.9 + &other * 0.1;
        let mut s = chain_system(Some(s), &second, &g2);
        let refined = s.solve_refined(Damping::Identity(0.5), &mut step, 1e-12, 100);
        assert!(refined.converged, "{refined:?}");
        assert!(refined.iterations < 30, "{refined:?}");
        let expect = dense_step(&second, &g2, 0.5);
        let err = (nalgebra::DVector::from_column_slice(&step) - &expect).amax();
        assert!(err < 1e-9 * (1.0 + expect.amax()), "{err}");
        let exact =
            Damping::Identity(0.5).predicted_decrease(&step, g2.as_slice(), std::iter::empty());
        let model = s.model_decrease(&step);
        assert!(
            (model - exact).abs() < 1e-9 * exact.abs(),
            "{model} {exact}"
        );
        let capped = s.solve_refined(Damping::Identity(0.5), &mut step, 1e-12, 1);
        assert_eq!((capped.iterations, capped.converged), (1, false));
        assert!(step.iter().any(|v| *v != 0.0));
    }

    /// With a single-precision factor, `solve` still gives the f64 solution (it iterates on the
    /// factor), and a refined solve on a fresh single factor reaches a loose tolerance in a few
    /// iterations.
    #[test]
    fn a_single_precision_factor_solves_to_double_precision() {
        let (dense, g) = chain_matrix(60, 9);
        let single = chain_structure(dense.nrows() / 6, FactorPrecision::Single);
        let mut s = chain_system(Some(single), &dense, &g);
        let mut step = vec![0.0; dense.nrows()];
        s.solve(Damping::Identity(0.25), &mut step).unwrap();
        let expect = dense_step(&dense, &g, 0.25);
        let err = (nalgebra::DVector::from_column_slice(&step) - &expect).amax();
        assert!(err < 1e-9 * (1.0 + expect.amax()), "{err}");
        s.factorise(Damping::Identity(0.25)).unwrap();
        let refined = s.solve_refined(Damping::Identity(0.25), &mut step, 1e-3, 4);
        assert!(refined.converged && refined.iterations <= 2, "{refined:?}");
    }

    /// Entries set in parallel hold what entries added one by one hold, to the bit, over values
    /// left from before: on a chain large enough to be split over threads, and with blocks of
    /// mixed sizes (a diagonal block's lower triangle is not read).
    #[test]
    fn entries_set_in_parallel_are_the_entries_added() {
        let value = |e: usize, k: usize| ((e * 31 + k * 7) % 113) as f64 / 9.0 - 6.0;
        let check = |sizes: &[usize], pairs: &[(usize, usize)]| {
            let mut added = BlockSystem::new(sizes, pairs.iter().copied()).unwrap();
            let mut set = BlockSystem::new(sizes, pairs.iter().copied()).unwrap();
            set.h.values.fill(7.0);
            let blocks: Vec<(usize, usize)> = (0..set.num_entries())
                .map(|e| set.entry_blocks(e))
                .collect();
            set.set_entries(|e, i, j, out| {
                assert_eq!(blocks[e], (i, j));
                for (k, o) in out.iter_mut().enumerate() {
                    *o = value(e, k);
                }
            });
            for (e, &(i, j)) in blocks.iter().enumerate() {
                let len = added.h.block_dim(i) * added.h.block_dim(j);
                let block: Vec<f64> = (0..len).map(|k| value(e, k)).collect();
                added.add_to_entry(e, &block);
            }
            assert_eq!(set.h.values, added.h.values);
            set.h.values.len()
        };
        let chain: Vec<(usize, usize)> = (1..1000usize)
            .flat_map(|j| [(j - 1, j), (j.saturating_sub(2), j)])
            .collect();
        assert!(
            check(&[6; 1000], &chain) > 2 * SET_SERIAL,
            "split over threads"
        );
        check(&[2, 1, 3, 12], &[(0, 2), (1, 2), (0, 3), (2, 3)]);
    }

    /// In a single-precision system, block-Jacobi steps take their products on an f32 copy:
    /// the converged step is the dense solution to single precision, truncated steps still
    /// descend on H itself, and a system of another structure reusing the buffers solves its
    /// own.
    #[test]
    fn single_precision_block_jacobi_steps_solve_to_single_precision_and_descend() {
        let (dense, g) = chain_matrix(60, 11);
        let single = chain_structure(dense.nrows() / 6, FactorPrecision::Single);
        let mut s = chain_system(Some(single), &dense, &g);
        let mut step = vec![0.0; dense.nrows()];
        let solved = solve_cold(&mut s, &mut step, 1e-9, 1000).unwrap();
        assert!(solved.converged, "{solved:?}");
        let expect = dense_step(&dense, &g, 0.25);
        let err = (nalgebra::DVector::from_column_slice(&step) - &expect).amax();
        assert!(err < 1e-5 * (1.0 + expect.amax()), "{err}");
        assert!(err > 0.0, "the copy is rounded");
        let mut last = 0.0;
        for cap in 1..6 {
            solve_cold(&mut s, &mut step, 1e-12, cap).unwrap();
            let decrease = s.model_decrease(&step);
            assert!(decrease > last, "{cap}: {decrease} {last}");
            last = decrease;
        }
        // a smaller chain (another structure) on the first one's buffers
        let (dense2, g2) = chain_matrix(20, 3);
        let mut other = chain_structure(dense2.nrows() / 6, FactorPrecision::Single);
        other.reuse_buffers(s);
        let mut other = chain_system(Some(other), &dense2, &g2);
        let mut step2 = vec![0.0; dense2.nrows()];
        solve_cold(&mut other, &mut step2, 1e-9, 1000).unwrap();
        let expect2 = dense_step(&dense2, &g2, 0.25);
        let err2 = (nalgebra::DVector::from_column_slice(&step2) - &expect2).amax();
        assert!(err2 < 1e-5 * (1.0 + expect2.amax()), "{err2}");
    }

    /// Conjugate gradients on the diagonal blocks' inverses reach the dense solution without
    /// any factorisation; each iteration of a truncated solve lowers the quadratic model
    /// further, short of the exact step's decrease; a damped diagonal block that is not positive
    /// definite is an error naming it.
    #[test]
    fn block_jacobi_steps_reach_the_solution_and_truncated_ones_descend() {
        let (dense, g) = chain_matrix(60, 11);
        let mut s = chain_system(None, &dense, &g);
        let mut step = vec![0.0; dense.nrows()];
        let solved = solve_cold(&mut s, &mut step, 1e-12, 1000).unwrap();
        assert!(solved.converged && solved.iterations < 200, "{solved:?}");
        assert!(!s.has_factorisation() && s.cholesky.is_none());
        let expect = dense_step(&dense, &g, 0.25);
        let err = (nalgebra::DVector::from_column_slice(&step) - &expect).amax();
        assert!(err < 1e-9 * (1.0 + expect.amax()), "{err}");
        let exact = s.model_decrease(&step);
        let mut last = 0.0;
        for cap in 1..6 {
            let truncated = solve_cold(&mut s, &mut step, 1e-12, cap).unwrap();
            assert_eq!((truncated.iterations, truncated.converged), (cap, false));
            let decrease = s.model_decrease(&step);
            assert!(
                decrease > last && decrease < exact,
                "{cap}: {decrease} {last} {exact}"
            );
            last = decrease;
        }
        // block 3's first unknown made negative beyond what the damping restores
        let at = s.h.diag_pos().nth(18).unwrap();
        s.h.values[at] = -10.0;
        match solve_cold(&mut s, &mut step, 1e-12, 10) {
            Err(SolveError::RankDeficient { variables, .. }) => assert_eq!(variables, [3]),
            other => panic!("{other:?}"),
        }
    }

    /// Started at a guess, block-Jacobi steps reach the same solution: at the solution itself
    /// at once, from a nearby one in fewer iterations than from 0, truncated still descending;
    /// a guess the quadratic model rates worse than 0 (the solution reversed, or not finite)
    /// is not used, and the solve is the one from 0, iteration for iteration.
    #[test]
    fn block_jacobi_steps_started_at_a_guess_reach_the_solution_or_start_from_zero() {
        let (dense, g) = chain_matrix(60, 11);
        let mut s = chain_system(None, &dense, &g);
        let damping = Damping::Identity(0.25);
        let expect = dense_step(&dense, &g, 0.25);
        let mut solve = |guess: &[f64], tolerance: f64, cap: usize| {
            let mut step = guess.to_vec();
            let solved = s
                .solve_block_jacobi(damping, &mut step, tolerance, cap, CgStart::Guess)
                .unwrap();
            let decrease = s.model_decrease(&step);
            (step, solved, decrease)
        };
        let zero = vec![0.0; dense.nrows()];
        let (_, cold, _) = solve(&zero, 1e-10, 1000);
        let (_, at, _) = solve(expect.as_slice(), 1e-6, 1000);
        assert!(at.converged && at.iterations == 0, "{at:?}");
        let near: Vec<f64> = expect.iter().map(|x| 0.9 * x + 1e-3).collect();
        let (step, warm, _) = solve(&near, 1e-10, 1000);
        let err = (nalgebra::DVector::from_column_slice(&step) - &expect).amax();
        assert!(
            warm.converged && err < 1e-7 * (1.0 + expect.amax()),
            "{err}"
        );
        assert!(warm.iterations < cold.iterations, "{warm:?} {cold:?}");
        for cap in 1..4 {
            let (_, _, decrease) = solve(&near, 1e-12, cap);
            assert!(decrease > 0.0, "{cap}: {decrease}");
        }
        let reversed: Vec<f64> = expect.iter().map(|x| -x).collect();
        let mut nan = near.clone();
        nan[7] = f64::NAN;
        for bad in [&reversed, &nan] {
            let (step, solved, _) = solve(bad, 1e-10, 1000);
            assert_eq!(solved.iterations, cold.iterations);
            assert!(step.iter().all(|x| x.is_finite()));
        }
    }

    /// On a chain long enough for the diagonal blocks to be inverted in parallel runs, every
    /// inverse is right (H = 2I: the step is −g / (2 + μ)), and of two blocks that are not
    /// positive definite the error names the first, whichever run meets it first.
    #[test]
    fn diagonal_blocks_inverted_in_parallel_solve_and_name_the_first_bad_one() {
        let nb = 1000;
        let mut s = chain_structure(nb, FactorPrecision::Double);
        let mut two = [0.0; 36];
        (0..6).for_each(|k| two[7 * k] = 2.0);
        for b in 0..nb {
            let e = s.entry(b, b).unwrap();
            s.add_to_entry(e, &two);
        }
        s.gradient_mut()
            .iter_mut()
            .enumerate()
            .for_each(|(i, g)| *g = (i % 7) as f64 - 3.0);
        let mut step = vec![0.0; 6 * nb];
        let solved = s
            .solve_block_jacobi(Damping::Identity(0.5), &mut step, 1e-12, 5, CgStart::Zero)
            .unwrap();
        assert!(solved.converged, "{solved:?}");
        for (i, d) in step.iter().enumerate() {
            assert!((d + ((i % 7) as f64 - 3.0) / 2.5).abs() < 1e-12, "{i}: {d}");
        }
        for b in [700, 300] {
            let at = s.h.diag_pos().nth(6 * b + 2).unwrap();
            s.h.values[at] = -10.0;
        }
        match s.solve_block_jacobi(Damping::Identity(0.5), &mut step, 1e-12, 5, CgStart::Zero) {
            Err(SolveError::RankDeficient { variables, .. }) => assert_eq!(variables, [300]),
            other => panic!("{other:?}"),
        }
    }

    /// The product with H, on one thread and split over two, is the sum over the stored blocks
    /// and their mirror images, with blocks of sizes 2, 1 and 2, and on a chain large enough to
    /// be split.
    #[test]
    fn products_with_h_are_the_sums_over_its_blocks() {
        let chain = (0..1500).flat_map(|b: usize| (b.saturating_sub(2)..b).map(move |a| (a, b)));
        let mut next = uniform(3);
        for mut s in [
            BlockSystem::new(&[2, 1, 2], [(0, 2), (1, 2)]).unwrap(),
            BlockSystem::new(&[6; 1500], chain).unwrap(),
        ] {
            for e in 0..s.num_entries() {
                let (i, j) = s.entry_blocks(e);
                let len = s.h.block_dim(i) * s.h.block_dim(j);
                let block: Vec<f64> = (0..len).map(|_| next()).collect();
                s.add_to_entry(e, &block);
            }
            let n = s.dim();
            let x: Vec<f64> = (0..n).map(|_| next()).collect();
            let mut expect = vec![0.0; n];
            for e in 0..s.num_entries() {
                let (i, j) = s.entry_blocks(e);
                for r in s.block_start(i)..s.block_start(i) + s.h.block_dim(i) {
                    for c in s.block_start(j)..s.block_start(j) + s.h.block_dim(j) {
                        expect[r] += s.get(r, c) * x[c];
                        if i != j {
                            expect[c] += s.get(r, c) * x[r];
                        }
                    }
                }
            }
            let (mut y, mut split, mut scratch) = (vec![0.0; n], vec![0.0; n], Vec::new());
            s.h.multiply(&x, &mut y);
            s.h.multiply_split(&x, &mut split, &mut scratch);
            assert_eq!(scratch.is_empty(), n < 100, "split only the large one");
            for ((a, b), e) in y.iter().zip(&split).zip(&expect) {
                assert!((a - e).abs() < 1e-12 * (1.0 + e.abs()), "{a} {e}");
                assert!((b - e).abs() < 1e-12 * (1.0 + e.abs()), "{b} {e}");
            }
        }
    }

    #[test]
    fn pairs_outside_the_system_are_an_error() {
        assert!(BlockSystem::new(&[6, 6], [(0, 2)]).is_err());
    }
}
