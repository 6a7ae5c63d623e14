//! Cholesky factorisation of a symmetric block-sparse matrix plus damping: dense (faer's LLᵀ) for
//! small systems, faer's sparse supernodal or simplicial Cholesky for large ones.
//!
//! The sparse path orders the *block* graph of H (`ordering`): approximate minimum degree
//! (Amestoy, Davis & Duff, 1996), and on graphs of 2,000 blocks or more also METIS's nested
//! dissection, keeping whichever gives the smaller factor. The order is expanded to scalars so each
//! variable's coordinates stay together, and the symbolic factorisation is computed once; every
//! later factorisation with the same structure reuses it.

use crate::block::BlockSparse;
use crate::damping::Damping;
use crate::error::SolveError;
use crate::ordering::{block_amd, block_nested_dissection, Permutation};
use dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::llt::factor::{LltError, LltRegularization};
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky,
    SymmetricOrdering,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, Mat, MatMut, Par, Side};

/// Factor entries above which the sparse factorisation runs on all threads.
const PARALLEL_FACTOR_ENTRIES: usize = 8_000_000;

enum Kind {
    Dense {
        a: Mat<f64>,
    },
    Sparse {
        symbolic: Box<SymbolicCholesky<usize>>,
        /// The scalar row indices of the matrices factorised (their compressed-column pattern).
        row_idx: Vec<usize>,
        l_values: Vec<f64>,
        work: Vec<f64>,
        /// The single-precision factor, its input and a right-hand side, when one is kept
        /// instead of `l_values`.
        single: Option<Single>,
    },
}

/// Buffers of a single-precision sparse factor.
struct Single {
    l_values: Vec<f32>,
    work: Vec<f32>,
    rhs: Vec<f32>,
}

/// The number type of a sparse factorisation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FactorPrecision {
    /// f64: solves are exact up to rounding.
    #[default]
    Double,
    /// f32: about 0.6 times the time of f64 on a 2.2 M-entry factor (faer's SIMD kernels hold
    /// twice the lanes) and half the memory; a solve with it is a preconditioner, not the
    /// solution, and callers iterate on it (`BlockSystem::solve_refined`). Dense factors stay f64.
    Single,
}

/// A Cholesky factorisation of a symmetric block-sparse matrix plus damping, with its workspace
/// kept across iterations.
pub(crate) struct Cholesky {
    kind: Kind,
    mem: MemBuffer,
    par: Par,
    n: usize,
}

impl Cholesky {
    /// Prepares a factorisation of matrices with `a`'s structure: dense, or sparse with the
    /// symbolic analysis done here once.
    pub fn new(a: &BlockSparse, dense: bool) -> Result<Self, SolveError> {
        Self::with_precision(a, dense, FactorPrecision::Double)
    }

    /// [`Self::new`] with the sparse factor kept in `precision`.
    pub fn with_precision(
        a: &BlockSparse,
        dense: bool,
        precision: FactorPrecision,
    ) -> Result<Self, SolveError> {
        let n = a.dim();
        let threads = rayon::current_num_threads();
        if dense {
            let par = if threads > 1 && n >= 1024 {
                Par::rayon(0)
            } else {
                Par::Seq
            };
            let req = faer::linalg::cholesky::llt::factor::cholesky_in_place_scratch::<f64>(
                n,
                par,
                Default::default(),
            )
            .or(faer::linalg::cholesky::llt::solve::solve_in_place_scratch::<f64>(n, 1, par));
            return Ok(Self {
                kind: Kind::Dense {
                    a: Mat::zeros(n, n),
                },
                mem: MemBuffer::new(req),
                par,
                n,
            });
        }
        let row_idx = a.row_indices();
        let symbolic = analyse(a, &row_idx)?;
        // Measured on the pose-graph benchmarks (2 cores): below a few million factor entries the
        // supernodes are too small for threads to pay; sequential was 10-40 % faster.
        let par = if threads > 1 && symbolic.len_val() > PARALLEL_FACTOR_ENTRIES {
            Par::rayon(0)
        } else {
            Par::Seq
        };
        // the scratch of the precision in use only
        let req = match precision {
            FactorPrecision::Double => StackReq::any_of(&[
                symbolic.factorize_numeric_llt_scratch::<f64>(par, Default::default()),
                symbolic.solve_in_place_scratch::<f64>(1, par),
            ]),
            FactorPrecision::Single => StackReq::any_of(&[
                symbolic.factorize_numeric_llt_scratch::<f32>(par, Default::default()),
                symbolic.solve_in_place_scratch::<f32>(1, par),
            ]),
        };
        tracing::debug!(
            scratch_bytes = req.unaligned_bytes_required(),
            "sparse Cholesky scratch"
        );
        let single = (precision == FactorPrecision::Single).then(|| Single {
            l_values: vec![0.0; symbolic.len_val()],
            work: vec![0.0; a.values.len()],
            rhs: vec![0.0; n],
        });
        let l_values = match single {
            Some(_) => Vec::new(),
            None => vec![0.0; symbolic.len_val()],
        };
        Ok(Self {
            kind: Kind::Sparse {
                symbolic: Box::new(symbolic),
                row_idx,
                l_values,
                work: vec![0.0; a.values.len()],
                single,
            },
            mem: MemBuffer::new(req),
            par,
            n,
        })
    }

    /// True for the sparse path.
    pub fn is_sparse(&self) -> bool {
        matches!(self.kind, Kind::Sparse { .. })
    }

    /// Factorises A + μD. On failure returns the (unpermuted) index of a non-positive pivot.
    pub fn factor(&mut self, m: &BlockSparse, damping: Damping) -> Result<(), usize> {
        let stack = MemStack::new(&mut self.mem);
        match &mut self.kind {
            Kind::Dense { a } => {
                a.fill(0.0);
                m.for_each_damped(damping, |r, c, v| {
                    a[(r, c)] = v;
                    a[(c, r)] = v;
                });
                faer::linalg::cholesky::llt::factor::cholesky_in_place(
                    a.as_mut(),
                    LltRegularization::default(),
                    self.par,
                    stack,
                    Default::default(),
                )
                .map(|_| ())
                .map_err(pivot)
            }
            Kind::Sparse {
                symbolic,
                row_idx,
                l_values,
                work,
                single,
            } => {
                work.copy_from_slice(&m.values);
                for &p in &m.diag_pos {
                    work[p] = damping.apply(work[p]);
                }
                let pattern = unsafe {
                    SymbolicSparseColMatRef::new_unchecked(
                        self.n, self.n, &m.col_ptr, None, row_idx,
                    )
                };
                let factored = match single {
                    None => symbolic
                        .factorize_numeric_llt(
                            l_values,
                            SparseColMatRef::new(pattern, work),
                            Side::Upper,
                            LltRegularization::default(),
                            self.par,
                            stack,
                            Default::default(),
                        )
                        .map(|_| ()),
                    Some(single) => {
                        for (o, v) in single.work.iter_mut().zip(work.iter()) {
                            *o = *v as f32;
                        }
                        symbolic
                            .factorize_numeric_llt(
                                &mut single.l_values,
                                SparseColMatRef::new(pattern, &single.work),
                                Side::Upper,
                                LltRegularization::default(),
                                self.par,
                                stack,
                                Default::default(),
                            )
                            .map(|_| ())
                    }
                };
                factored.map_err(|e| {
                    let index = pivot(e);
                    symbolic
                        .perm()
                        .map(|p| p.arrays().0[index])
                        .unwrap_or(index)
                })
            }
        }
    }

    /// Solves with the last factorisation, overwriting `x` (the right-hand side) with the solution.
    pub fn solve(&mut self, x: &mut [f64]) {
        let stack = MemStack::new(&mut self.mem);
        let n = self.n;
        match &mut self.kind {
            Kind::Dense { a } => {
                faer::linalg::cholesky::llt::solve::solve_in_place_with_conj(
                    a.as_ref(),
                    Conj::No,
                    MatMut::from_column_major_slice_mut(x, n, 1),
                    self.par,
                    stack,
                );
            }
            Kind::Sparse {
                symbolic,
                l_values,
                single: None,
                ..
            } => {
                LltRef::new(symbolic, l_values).solve_in_place_with_conj(
                    Conj::No,
                    MatMut::from_column_major_slice_mut(x, n, 1),
                    self.par,
                    stack,
                );
            }
            Kind::Sparse {
                symbolic,
                single: Some(single),
                ..
            } => {
                let Single { l_values, rhs, .. } = single;
                for (o, v) in rhs.iter_mut().zip(x.iter()) {
                    *o = *v as f32;
                }
                LltRef::new(symbolic, l_values).solve_in_place_with_conj(
                    Conj::No,
                    MatMut::from_column_major_slice_mut(rhs, n, 1),
                    self.par,
                    stack,
                );
                for (o, v) in x.iter_mut().zip(rhs.iter()) {
                    *o = *v as f64;
                }
            }
        }
    }
}

/// The index of the pivot at which faer's LLᵀ found the matrix not positive definite.
fn pivot(e: LltError) -> usize {
    match e {
        LltError::NonPositivePivot { index } => index,
    }
}

/// Block graphs from this many blocks on are also ordered by nested dissection, and the order
/// with the smaller factor is kept; below it minimum degree alone, so that the small problems
/// (the real pose graphs, bundle adjustments' reduced systems, deformation graphs) keep the
/// path their benchmarks measured. Nested dissection already gave the smaller factor on the
/// generated 10,000-pose graphs (NOTES 72).
const NESTED_DISSECTION_MIN_BLOCKS: usize = 2_000;

/// The symbolic Cholesky factorisation of `a`'s pattern (scalar row indices `row_idx`) under the
/// ordering with the fewer factor entries: block AMD, or METIS nested dissection on large graphs.
fn analyse(a: &BlockSparse, row_idx: &[usize]) -> Result<SymbolicCholesky<usize>, SolveError> {
    let n = a.dim();
    let clock = std::time::Instant::now();
    let symbolic_of = |(fwd, inv): Permutation| {
        let pattern = SymbolicSparseColMatRef::new_checked(n, n, &a.col_ptr, None, row_idx);
        let perm_ref = faer::perm::PermRef::new_checked(&fwd, &inv, n);
        factorize_symbolic_cholesky(
            pattern,
            Side::Upper,
            SymmetricOrdering::Custom(perm_ref),
            CholeskySymbolicParams::default(),
        )
        .map_err(|e| SolveError::LinearSolver(format!("{e:?}")))
    };
    let amd = symbolic_of(block_amd(a)?)?;
    let amd_s = clock.elapsed().as_secs_f64();
    let mut chosen = amd;
    let mut nested = None;
    if a.num_blocks() >= NESTED_DISSECTION_MIN_BLOCKS {
        // an ordering only changes the speed: if METIS fails, AMD's factor is used, and said so
        match block_nested_dissection(a).and_then(symbolic_of) {
            Ok(nd) => {
                nested = Some(nd.len_val());
                if nd.len_val() < chosen.len_val() {
                    chosen = nd;
                }
            }
            Err(e) => tracing::warn!("nested dissection skipped, minimum degree kept: {e}"),
        }
    }
    tracing::debug!(
        unknowns = n,
        entries_h = row_idx.len(),
        entries_l = chosen.len_val(),
        entries_l_nested_dissection = nested,
        amd_s,
        nested_dissection_s = clock.elapsed().as_secs_f64() - amd_s,
        "sparse Cholesky analysed"
    );
    Ok(chosen)
}
