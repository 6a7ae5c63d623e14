//! faer's sparse Cholesky (supernodal or simplicial) of H + μD under a fill-reducing order.
//!
//! H is kept by its assembler as the upper triangle in the unknowns' order ([`BlockSparse`]).
//! Each factorisation scatters it, damped, into the permuted triangle faer's numeric
//! factorisation reads (the lower one for a supernodal factor, the upper one for a simplicial
//! one), whose pattern was laid out once at analysis. faer's own entry point would copy H twice
//! per factorisation (a damped copy, then its permutation in scratch memory) and keep a
//! second row-index array; here one permuted copy is kept, and the indices are 32-bit whenever
//! the factor fits them (faer's `Index`), which halves every index array of a large problem.

use crate::block::BlockSparse;
use crate::damping::Damping;
use dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::llt::factor::{LltError, LltRegularization};
use faer::sparse::linalg::cholesky::{
    simplicial, supernodal, LltRef, SymbolicCholesky, SymbolicCholeskyRaw,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::traits::ComplexField;
use faer::{Conj, Index, MatMut, Par};

/// The values of the permuted triangle and of the factor, in the precision kept.
enum Values {
    Double {
        a: Vec<f64>,
        l: Vec<f64>,
    },
    /// Single precision, with a right-hand side to solve in it.
    Single {
        a: Vec<f32>,
        l: Vec<f32>,
        rhs: Vec<f32>,
    },
}

/// A sparse Cholesky factorisation with its permuted copy of H and its workspace.
pub(super) struct SparseFactor<I: Index> {
    symbolic: SymbolicCholesky<I>,
    /// Column starts and row indices of the permuted triangle (rows unsorted inside a column,
    /// as faer's numeric factorisations allow).
    col_ptr: Vec<I>,
    row_idx: Vec<I>,
    /// Write cursor of every column during a scatter.
    next: Vec<I>,
    /// The new position of every scalar.
    inv: Vec<I>,
    values: Values,
    mem: MemBuffer,
    par: Par,
}

impl<I: Index> SparseFactor<I> {
    /// Lays out the permuted triangle of `a`'s pattern under `symbolic`'s order and reserves
    /// the factor and the workspace in `single` or double precision.
    pub fn new(a: &BlockSparse, symbolic: SymbolicCholesky<I>, single: bool, par: Par) -> Self {
        let n = a.dim();
        let lower = is_lower(&symbolic);
        let inv = inverse(&symbolic, n);
        let mut col_ptr = vec![I::truncate(0); n + 1];
        for_each_placed(a, &inv, lower, |_, col, _, _| {
            col_ptr[col + 1] = I::truncate(col_ptr[col + 1].zx() + 1)
        });
        for c in 0..n {
            col_ptr[c + 1] = I::truncate(col_ptr[c + 1].zx() + col_ptr[c].zx());
        }
        let mut next = col_ptr[..n].to_vec();
        let mut row_idx = vec![I::truncate(0); a.values.len()];
        for_each_placed(a, &inv, lower, |_, col, row, _| {
            row_idx[advance(&mut next[col])] = I::truncate(row)
        });
        // checks the pattern once; every factorisation reuses it unchecked
        SymbolicSparseColMatRef::new_unsorted_checked(n, n, &col_ptr, None, &row_idx);
        let nnz = a.values.len();
        let (values, req) = if single {
            let values = Values::Single {
                a: vec![0.0; nnz],
                l: vec![0.0; symbolic.len_val()],
                rhs: vec![0.0; n],
            };
            (values, scratch::<I, f32>(&symbolic, par))
        } else {
            let values = Values::Double {
                a: vec![0.0; nnz],
                l: vec![0.0; symbolic.len_val()],
            };
            (values, scratch::<I, f64>(&symbolic, par))
        };
        tracing::debug!(
            scratch_bytes = req.unaligned_bytes_required(),
            index_bytes = std::mem::size_of::<I>(),
            "sparse Cholesky scratch"
        );
        Self {
            symbolic,
            col_ptr,
            row_idx,
            next,
            inv,
            values,
            mem: MemBuffer::new(req),
            par,
        }
    }

    /// Factorises `m` + damping (`m` of the pattern given to [`Self::new`]). On failure returns
    /// the unpermuted index of a non-positive pivot.
    pub fn factor(&mut self, m: &BlockSparse, damping: Damping) -> Result<(), usize> {
        let n = self.inv.len();
        debug_assert_eq!(m.dim(), n, "a matrix of another structure");
        self.next.copy_from_slice(&self.col_ptr[..n]);
        // SAFETY: the pattern was checked when it was laid out (`new`) and has not changed.
        let pattern = unsafe {
            SymbolicSparseColMatRef::new_unchecked(n, n, &self.col_ptr, None, &self.row_idx)
        };
        let (inv, lower, next) = (&self.inv, is_lower(&self.symbolic), &mut self.next);
        let symbolic = &self.symbolic;
        let stack = MemStack::new(&mut self.mem);
        let factored = match &mut self.values {
            Values::Double { a, l } => {
                scatter(m, damping, inv, lower, next, a, |v| v);
                numeric(
                    symbolic,
                    SparseColMatRef::new(pattern, a),
                    l,
                    self.par,
                    stack,
                )
            }
            Values::Single { a, l, .. } => {
                scatter(m, damping, inv, lower, next, a, |v| v as f32);
                numeric(
                    symbolic,
                    SparseColMatRef::new(pattern, a),
                    l,
                    self.par,
                    stack,
                )
            }
        };
        factored.map_err(|LltError::NonPositivePivot { index }| {
            // faer's simplicial factorisation counts pivots from 1, the supernodal one from 0
            let index = match symbolic.raw() {
                SymbolicCholeskyRaw::Simplicial(_) => index.saturating_sub(1),
                SymbolicCholeskyRaw::Supernodal(_) => index,
            };
            match symbolic.perm() {
                Some(p) => p.arrays().0[index].zx(),
                None => index,
            }
        })
    }

    /// Solves with the last factorisation, overwriting `x` with the solution.
    pub fn solve(&mut self, x: &mut [f64]) {
        let n = x.len();
        let stack = MemStack::new(&mut self.mem);
        match &mut self.values {
            Values::Double { l, .. } => LltRef::new(&self.symbolic, l).solve_in_place_with_conj(
                Conj::No,
                MatMut::from_column_major_slice_mut(x, n, 1),
                self.par,
                stack,
            ),
            Values::Single { l, rhs, .. } => {
                for (o, v) in rhs.iter_mut().zip(x.iter()) {
                    *o = *v as f32;
                }
                LltRef::new(&self.symbolic, l).solve_in_place_with_conj(
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

/// Whether faer's numeric factorisation of `symbolic` reads the lower triangle (supernodal) or
/// the upper one (simplicial).
fn is_lower<I: Index>(symbolic: &SymbolicCholesky<I>) -> bool {
    matches!(symbolic.raw(), SymbolicCholeskyRaw::Supernodal(_))
}

/// The new position of every scalar under `symbolic`'s order.
fn inverse<I: Index>(symbolic: &SymbolicCholesky<I>, n: usize) -> Vec<I> {
    match symbolic.perm() {
        Some(p) => p.arrays().1.to_vec(),
        None => (0..n).map(I::truncate).collect(),
    }
}

/// Returns the cursor's position and moves it on by one.
#[inline]
fn advance<I: Index>(cursor: &mut I) -> usize {
    let at = cursor.zx();
    *cursor = I::truncate(at + 1);
    at
}

/// Calls `f(source, column, row, r)` for every stored element of `m`: its position in
/// `m.values`, its place in the permuted triangle (the lower one if `lower`, else the upper
/// one) and its row r in `m`, in
/// the same order every time. A block order keeps each block's coordinates together and in
/// order, so a run of rows of one block stays a run after the permutation.
#[inline]
fn for_each_placed<I: Index>(
    m: &BlockSparse,
    inv: &[I],
    lower: bool,
    mut f: impl FnMut(usize, usize, usize, usize),
) {
    m.for_each_run(|start, row, rows, c| {
        let (r0, cn) = (inv[row].zx(), inv[c].zx());
        debug_assert!(rows == 0 || inv[row + rows - 1].zx() == r0 + rows - 1);
        for k in 0..rows {
            let r = r0 + k;
            let (col, placed) = if (r > cn) == lower { (cn, r) } else { (r, cn) };
            f(start + k, col, placed, row + k);
        }
    });
}

/// Writes `m` + damping into the permuted triangle's values `a`, cast by `cast`.
fn scatter<I: Index, T>(
    m: &BlockSparse,
    damping: Damping,
    inv: &[I],
    lower: bool,
    next: &mut [I],
    a: &mut [T],
    cast: impl Fn(f64) -> T,
) {
    for_each_placed(m, inv, lower, |src, col, row, unpermuted| {
        let v = m.values[src];
        let v = if row == col {
            m.damped(damping, unpermuted, v)
        } else {
            v
        };
        a[advance(&mut next[col])] = cast(v);
    });
}

/// faer's numeric LLᵀ of the permuted triangle `a` into `l`.
fn numeric<I: Index, T: ComplexField>(
    symbolic: &SymbolicCholesky<I>,
    a: SparseColMatRef<'_, I, T>,
    l: &mut [T],
    par: Par,
    stack: &mut MemStack,
) -> Result<(), LltError> {
    let regularization = LltRegularization::<T::Real>::default();
    match symbolic.raw() {
        SymbolicCholeskyRaw::Simplicial(s) => {
            simplicial::factorize_simplicial_numeric_llt(l, a, regularization, s, stack).map(|_| ())
        }
        SymbolicCholeskyRaw::Supernodal(s) => supernodal::factorize_supernodal_numeric_llt(
            l,
            a,
            regularization,
            s,
            par,
            stack,
            Default::default(),
        )
        .map(|_| ()),
    }
}

/// The workspace of a numeric factorisation and of a solve in `T`.
fn scratch<I: Index, T: ComplexField>(symbolic: &SymbolicCholesky<I>, par: Par) -> StackReq {
    let factor = match symbolic.raw() {
        SymbolicCholeskyRaw::Simplicial(_) => {
            simplicial::factorize_simplicial_numeric_llt_scratch::<I, T>(symbolic.nrows())
        }
        SymbolicCholeskyRaw::Supernodal(s) => {
            supernodal::factorize_supernodal_numeric_llt_scratch::<I, T>(s, par, Default::default())
        }
    };
    StackReq::any_of(&[factor, symbolic.solve_in_place_scratch::<T>(1, par)])
}
