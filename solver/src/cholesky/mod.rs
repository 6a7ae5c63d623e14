//! Cholesky factorisation of a symmetric block-sparse matrix plus damping: dense (faer's LLᵀ) for
//! small systems, faer's sparse supernodal or simplicial Cholesky for large ones.
//!
//! The sparse path orders the *block* graph of H (`ordering`): approximate minimum degree
//! (Amestoy, Davis & Duff, 1996), and on graphs of 2,000 blocks or more also METIS's nested
//! dissection, keeping whichever gives the smaller factor. The order is expanded to scalars so each
//! variable's coordinates stay together, and the symbolic factorisation is computed once; every
//! later factorisation with the same structure reuses it.

mod sparse;

use crate::block::BlockSparse;
use crate::damping::Damping;
use crate::error::SolveError;
use crate::ordering::{block_amd, block_nested_dissection, Permutation};
use dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::{LltError, LltRegularization};
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, SymbolicCholesky, SymbolicCholeskyRaw,
    SymmetricOrdering,
};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::{FaerError, SymbolicSparseColMatRef};
use faer::{Conj, Index, Mat, MatMut, Par, Side};
use sparse::SparseFactor;

/// A sparse factorisation runs on all threads when it takes at least this many floating-point
/// operations and at least [`PARALLEL_FLOPS_PER_ENTRY`] per factor entry (dense supernodes).
const PARALLEL_MIN_FLOPS: f64 = 1e9;
/// See [`PARALLEL_MIN_FLOPS`].
const PARALLEL_FLOPS_PER_ENTRY: f64 = 700.0;

enum Kind {
    Dense {
        a: Mat<f64>,
        mem: MemBuffer,
        par: Par,
    },
    /// 32-bit indices: every factor of fewer than 2³² entries.
    Sparse32(Box<SparseFactor<u32>>),
    Sparse64(Box<SparseFactor<usize>>),
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
    /// `BlockSystem::solve_block_jacobi` then takes its products in f32 as well.
    Single,
}

/// A Cholesky factorisation of a symmetric block-sparse matrix plus damping, with its workspace
/// kept across iterations.
pub(crate) struct Cholesky {
    kind: Kind,
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
            let kind = Kind::Dense {
                a: Mat::zeros(n, n),
                mem: MemBuffer::new(req),
                par,
            };
            return Ok(Self { kind });
        }
        let analysed = Analysed::new(a)?;
        Ok(Self::from_analysis(a, analysed, precision))
    }

    /// A sparse factorisation of matrices with `a`'s structure from its symbolic analysis (the
    /// factor's storage is allocated here, not by the analysis).
    pub fn from_analysis(a: &BlockSparse, analysed: Analysed, precision: FactorPrecision) -> Self {
        // Measured on 2 cores (NOTES 73): faer's parallel supernodal factorisation was 12-77 %
        // slower than the sequential one on pose graphs with 300-500 operations per factor entry
        // (9 M to 32 M entries), 15-31 % faster on those with 1,000-1,300 (127 M and 139 M) and
        // on a bundle adjustment's reduced camera system (1,270 per entry, 17 M entries).
        let flops = analysed.flops();
        let dense_enough = flops >= PARALLEL_MIN_FLOPS
            && flops >= PARALLEL_FLOPS_PER_ENTRY * analysed.len_val() as f64;
        let par = if rayon::current_num_threads() > 1 && dense_enough {
            Par::rayon(0)
        } else {
            Par::Seq
        };
        let single = precision == FactorPrecision::Single;
        let kind = match analysed {
            Analysed::Narrow(s) => Kind::Sparse32(Box::new(SparseFactor::new(a, s, single, par))),
            Analysed::Wide(s) => Kind::Sparse64(Box::new(SparseFactor::new(a, s, single, par))),
        };
        Self { kind }
    }

    /// True for the sparse path.
    pub fn is_sparse(&self) -> bool {
        !matches!(self.kind, Kind::Dense { .. })
    }

    /// Factorises A + μD. On failure returns the (unpermuted) index of a non-positive pivot.
    pub fn factor(&mut self, m: &BlockSparse, damping: Damping) -> Result<(), usize> {
        match &mut self.kind {
            Kind::Dense { a, mem, par } => {
                a.fill(0.0);
                m.for_each_damped(damping, |r, c, v| {
                    a[(r, c)] = v;
                    a[(c, r)] = v;
                });
                faer::linalg::cholesky::llt::factor::cholesky_in_place(
                    a.as_mut(),
                    LltRegularization::default(),
                    *par,
                    MemStack::new(mem),
                    Default::default(),
                )
                .map(|_| ())
                .map_err(|LltError::NonPositivePivot { index }| index)
            }
            Kind::Sparse32(f) => f.factor(m, damping),
            Kind::Sparse64(f) => f.factor(m, damping),
        }
    }

    /// Solves with the last factorisation, overwriting `x` (the right-hand side) with the solution.
    pub fn solve(&mut self, x: &mut [f64]) {
        match &mut self.kind {
            Kind::Dense { a, mem, par } => {
                let n = x.len();
                faer::linalg::cholesky::llt::solve::solve_in_place_with_conj(
                    a.as_ref(),
                    Conj::No,
                    MatMut::from_column_major_slice_mut(x, n, 1),
                    *par,
                    MemStack::new(mem),
                );
            }
            Kind::Sparse32(f) => f.solve(x),
            Kind::Sparse64(f) => f.solve(x),
        }
    }
}

/// A symbolic factorisation with the narrowest indices that hold it.
pub(crate) enum Analysed {
    Narrow(SymbolicCholesky<u32>),
    Wide(SymbolicCholesky<usize>),
}

impl Analysed {
    /// The symbolic factorisation of `a`'s pattern under the better of the orderings tried
    /// (see [`analyse`]).
    pub fn new(a: &BlockSparse) -> Result<Self, SolveError> {
        analyse(a, f64::INFINITY, true)
    }

    /// [`Self::new`], but minimum degree's analysis alone when its factorisation would take more
    /// than `enough` operations: for a caller that only factorises below a bound far under
    /// `enough` (nested dissection saved 23 % of the operations on a bundle adjustment's
    /// reduced system, NOTES 74, so it cannot bring such a factor under that bound). The factor's
    /// kind is faer's own choice here, whatever the blocks' width: the caller reads a simplicial
    /// factor as a very sparse system ([`Self::flops`] 0).
    pub fn unless_costlier(a: &BlockSparse, enough: f64) -> Result<Self, SolveError> {
        analyse(a, enough, false)
    }

    fn len_val(&self) -> usize {
        match self {
            Analysed::Narrow(s) => s.len_val(),
            Analysed::Wide(s) => s.len_val(),
        }
    }

    /// The floating-point operations of one numeric factorisation, counted over the supernodes
    /// (c columns and p rows below them: c³/3 + c²p + cp²); 0 for a simplicial factor.
    pub fn flops(&self) -> f64 {
        match self {
            Analysed::Narrow(s) => supernodal_flops(s),
            Analysed::Wide(s) => supernodal_flops(s),
        }
    }
}

fn supernodal_flops<I: Index>(symbolic: &SymbolicCholesky<I>) -> f64 {
    let SymbolicCholeskyRaw::Supernodal(s) = symbolic.raw() else {
        return 0.0;
    };
    let (begin, end) = (s.supernode_begin(), s.supernode_end());
    (0..s.n_supernodes())
        .map(|k| {
            let c = (end[k].zx() - begin[k].zx()) as f64;
            let p = s.supernode(k).pattern().len() as f64;
            c * c * c / 3.0 + c * c * p + c * p * p
        })
        .sum()
}

/// Block graphs from this many blocks on are also ordered by nested dissection, and the order
/// with the smaller factor is kept. Nested dissection already gave the smaller factor on the
/// generated 10,000-pose graphs (NOTES 72).
const NESTED_DISSECTION_MIN_BLOCKS: usize = 2_000;

/// Smaller graphs are also ordered by nested dissection when minimum degree's factor needs this
/// many operations: its factorisation then takes tens of milliseconds or more per call, against
/// about a millisecond for METIS on a graph of a thousand blocks (the reduced camera system of a
/// bundle adjustment: 23 % fewer operations at 1,000 cameras, NOTES 74). Below both, the small
/// problems (the real pose graphs, deformation graphs, small bundle adjustments) keep minimum
/// degree alone and its cheaper analysis.
const NESTED_DISSECTION_MIN_FLOPS: f64 = 1e9;

/// Blocks at least this wide on average (SE(3) poses, cameras, deformation nodes) get a
/// supernodal factor even where faer's flop heuristic would take a simplicial one (a long
/// corridor's graph): every block's columns share one row structure, so the supernodal factor
/// stores a sixth of the simplicial one's row indices or less (133 MB of 4.7 GB on the 1 M-pose
/// 3-D corridor) at the same speed. SE(2) graphs (blocks of 3) keep faer's choice: forced
/// supernodal, the 100 k-pose 2-D corridor took 20 % longer for 1 % less memory (NOTES 77).
const SUPERNODAL_MIN_BLOCK_WIDTH: usize = 6;

/// The symbolic Cholesky factorisation of `a`'s pattern under the ordering with the fewer
/// factor entries: block AMD, or METIS nested dissection on large graphs or costly factors.
/// Supernodal wherever the blocks are wide, when `wide_supernodal`
/// ([`SUPERNODAL_MIN_BLOCK_WIDTH`]); otherwise as faer's flop heuristic chooses.
fn analyse(a: &BlockSparse, enough: f64, wide_supernodal: bool) -> Result<Analysed, SolveError> {
    let mut params = CholeskySymbolicParams::default();
    if wide_supernodal && a.dim() >= SUPERNODAL_MIN_BLOCK_WIDTH * a.num_blocks() {
        params.supernodal_flop_ratio_threshold = SupernodalThreshold::FORCE_SUPERNODAL;
    }
    let clock = std::time::Instant::now();
    let amd = symbolic(a, &block_amd(a)?, params)?;
    let amd_s = clock.elapsed().as_secs_f64();
    let mut chosen = amd;
    let mut nested = None;
    let amd_flops = chosen.flops();
    if (a.num_blocks() >= NESTED_DISSECTION_MIN_BLOCKS || amd_flops >= NESTED_DISSECTION_MIN_FLOPS)
        && amd_flops <= enough
    {
        // an ordering only changes the speed: if METIS fails, AMD's factor is used, and said so
        match block_nested_dissection(a).and_then(|p| symbolic(a, &p, params)) {
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
        unknowns = a.dim(),
        entries_h = a.values.len(),
        entries_l = chosen.len_val(),
        entries_l_nested_dissection = nested,
        flops = chosen.flops(),
        index_bits = if matches!(chosen, Analysed::Narrow(_)) {
            32
        } else {
            64
        },
        amd_s,
        nested_dissection_s = clock.elapsed().as_secs_f64() - amd_s,
        "sparse Cholesky analysed"
    );
    Ok(chosen)
}

/// The symbolic factorisation of `a` under `perm`, with 32-bit indices unless the factor
/// needs more.
fn symbolic(
    a: &BlockSparse,
    perm: &Permutation,
    params: CholeskySymbolicParams,
) -> Result<Analysed, SolveError> {
    if a.values.len() < u32::MAX as usize {
        match symbolic_of::<u32>(a, perm, params) {
            Err(FaerError::IndexOverflow) => {}
            other => return other.map(Analysed::Narrow).map_err(faer_error),
        }
    }
    symbolic_of::<usize>(a, perm, params)
        .map(Analysed::Wide)
        .map_err(faer_error)
}

fn faer_error(e: FaerError) -> SolveError {
    SolveError::LinearSolver(format!("sparse Cholesky analysis failed: {e:?}"))
}

/// faer's symbolic factorisation of `a`'s pattern (upper triangle) in index type `I`.
fn symbolic_of<I: Index>(
    a: &BlockSparse,
    (fwd, inv): &Permutation,
    params: CholeskySymbolicParams,
) -> Result<SymbolicCholesky<I>, FaerError> {
    let n = a.dim();
    let narrow = |v: &[usize]| v.iter().map(|&x| I::truncate(x)).collect::<Vec<I>>();
    let row_idx = a.row_indices(I::truncate);
    let col_ptr = narrow(&a.col_ptr);
    let (fwd, inv) = (narrow(fwd), narrow(inv));
    let pattern = SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &row_idx);
    let perm = faer::perm::PermRef::new_checked(&fwd, &inv, n);
    factorize_symbolic_cholesky(
        pattern,
        Side::Upper,
        SymmetricOrdering::Custom(perm),
        params,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A diagonally dominant block matrix of 40 blocks of sizes 1 to 3 coupled at random
    /// (a deterministic linear congruential generator), with `negative` diagonal element made
    /// negative when given.
    fn random_matrix(seed: u64, negative: Option<usize>) -> BlockSparse {
        let mut state = seed;
        let mut next = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) as f64 / (1u64 << 31) as f64
        };
        let nb = 40;
        let mut block_start = vec![0];
        for _ in 0..nb {
            block_start.push(block_start.last().unwrap() + 1 + (next() * 3.0) as usize);
        }
        let columns: Vec<Vec<usize>> = (0..nb)
            .map(|j| {
                let mut rows: Vec<usize> = (0..j).filter(|_| next() < 0.15).collect();
                rows.push(j);
                rows
            })
            .collect();
        let mut m = BlockSparse::new(block_start, &columns);
        let mut row_sum = vec![0.0; m.dim()];
        let runs = {
            let mut runs = Vec::new();
            m.for_each_run(|start, row, rows, c| runs.push((start, row, rows, c)));
            runs
        };
        for (start, row, rows, c) in runs {
            for k in 0..rows {
                if row + k != c {
                    let v = next() * 2.0 - 1.0;
                    m.values[start + k] = v;
                    row_sum[row + k] += v.abs();
                    row_sum[c] += v.abs();
                }
            }
        }
        let diag: Vec<usize> = m.diag_pos().collect();
        for (i, &p) in diag.iter().enumerate() {
            m.values[p] = row_sum[i] + 1.0;
        }
        if let Some(i) = negative {
            m.values[diag[i]] = -1.0;
        }
        m
    }

    fn sparse_factor<I: Index>(
        m: &BlockSparse,
        threshold: SupernodalThreshold,
        single: bool,
    ) -> SparseFactor<I> {
        let params = CholeskySymbolicParams {
            supernodal_flop_ratio_threshold: threshold,
            ..Default::default()
        };
        let symbolic = symbolic_of::<I>(m, &block_amd(m).unwrap(), params).unwrap();
        SparseFactor::new(m, symbolic, single, Par::Seq)
    }

    /// The largest difference between the solutions of the sparse factor and the dense one.
    fn error_against_dense<I: Index>(
        m: &BlockSparse,
        damping: Damping,
        threshold: SupernodalThreshold,
        single: bool,
    ) -> f64 {
        let rhs: Vec<f64> = (0..m.dim()).map(|i| (i as f64 * 0.7).sin()).collect();
        let mut dense = Cholesky::new(m, true).unwrap();
        dense.factor(m, damping).unwrap();
        let mut expected = rhs.clone();
        dense.solve(&mut expected);
        let mut sparse = sparse_factor::<I>(m, threshold, single);
        // twice, as an iteration would: the scatter must start afresh every time
        for _ in 0..2 {
            sparse.factor(m, damping).unwrap();
        }
        let mut got = rhs;
        sparse.solve(&mut got);
        got.iter()
            .zip(&expected)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max)
    }

    /// A corridor: `nb` blocks of `width` unknowns, each coupled to the next, with a few
    /// loop closures two blocks back.
    fn chain(nb: usize, width: usize) -> BlockSparse {
        let block_start = (0..=nb).map(|b| b * width).collect();
        let columns: Vec<Vec<usize>> = (0..nb)
            .map(|j| match j {
                0 => vec![0],
                _ if j % 7 == 0 => vec![j - 2, j - 1, j],
                _ => vec![j - 1, j],
            })
            .collect();
        BlockSparse::new(block_start, &columns)
    }

    #[test]
    fn wide_blocks_get_a_supernodal_factor_where_faer_would_take_a_simplicial_one() {
        let simplicial = |a: &Analysed| a.flops() == 0.0;
        // a sparse chain: faer's flop heuristic takes a simplicial factor at either width
        assert!(simplicial(&Analysed::new(&chain(300, 3)).unwrap()));
        assert!(simplicial(
            &Analysed::unless_costlier(&chain(300, 6), f64::INFINITY).unwrap()
        ));
        // blocks of six: supernodal, with a sixth of the row indices or fewer
        let wide = Analysed::new(&chain(300, 6)).unwrap();
        assert!(!simplicial(&wide));
        let Analysed::Narrow(s) = &wide else {
            panic!("a small factor needs no 64-bit indices")
        };
        let SymbolicCholeskyRaw::Supernodal(sn) = s.raw() else {
            unreachable!()
        };
        let indices: usize = (0..sn.n_supernodes())
            .map(|k| sn.supernode(k).pattern().len())
            .sum();
        assert!(6 * indices <= s.len_val(), "{indices} of {}", s.len_val());
    }

    #[test]
    fn sparse_factors_of_either_index_width_and_kind_solve_the_damped_system() {
        let kinds = [
            SupernodalThreshold::FORCE_SIMPLICIAL,
            SupernodalThreshold::FORCE_SUPERNODAL,
        ];
        for seed in 1..4 {
            let mut m = random_matrix(seed, None);
            if seed == 3 {
                // damping scales that raise some diagonals' floor above them (a collapsed
                // curvature): the sparse scatter must find each unknown's scale through the
                // permutation
                let n = m.dim();
                m.damping_scale = (0..n).map(|i| 10f64.powi((i * 7 % 9) as i32)).collect();
            }
            for damping in [
                Damping::None,
                Damping::Identity(0.5),
                Damping::Diagonal(0.1),
            ] {
                for threshold in kinds {
                    let e32 = error_against_dense::<u32>(&m, damping, threshold, false);
                    let e64 = error_against_dense::<usize>(&m, damping, threshold, false);
                    let single = error_against_dense::<u32>(&m, damping, threshold, true);
                    assert!(
                        e32 < 1e-12 && e64 < 1e-12,
                        "{seed} {damping:?}: {e32} {e64}"
                    );
                    assert!(single < 1e-5, "{seed} {damping:?}: single {single}");
                }
            }
        }
    }

    #[test]
    fn a_non_positive_pivot_is_reported_at_its_unpermuted_index() {
        for negative in [0, 17, 45] {
            let m = random_matrix(7, Some(negative));
            for threshold in [
                SupernodalThreshold::FORCE_SIMPLICIAL,
                SupernodalThreshold::FORCE_SUPERNODAL,
            ] {
                let mut f = sparse_factor::<u32>(&m, threshold, false);
                assert_eq!(f.factor(&m, Damping::None), Err(negative), "{threshold:?}");
                // enough damping makes it positive definite again
                assert_eq!(f.factor(&m, Damping::Identity(2.0)), Ok(()));
            }
        }
    }
}
