//! Fill-reducing orderings of a block-sparse matrix's block graph, expanded to scalars so that
//! each variable's coordinates stay together.
//!
//! - [`block_amd`]: approximate minimum degree (Amestoy, Davis & Duff, 1996), through faer.
//! - [`block_nested_dissection`]: METIS's multilevel nested dissection (Karypis & Kumar, 1998),
//!   after George's nested dissection of grids (1973). On graphs that look like a planar mesh (a
//!   city walk, a sphere of rings) the factor of a nested-dissection order grows as n log n where
//!   minimum degree's grows faster.

use crate::block::BlockSparse;
use crate::error::SolveError;
use dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::amd;
use faer::sparse::SymbolicSparseColMatRef;

/// A scalar permutation: new → old and its inverse.
pub(crate) type Permutation = (Vec<usize>, Vec<usize>);

/// AMD on the block graph of `a`.
pub(crate) fn block_amd(a: &BlockSparse) -> Result<Permutation, SolveError> {
    let nb = a.num_blocks();
    let mut col_ptr = Vec::with_capacity(nb + 1);
    let mut row_idx = Vec::with_capacity(a.entries.len());
    col_ptr.push(0usize);
    for j in 0..nb {
        for e in &a.entries[a.entry_ptr[j]..a.entry_ptr[j + 1]] {
            row_idx.push(e.row_block);
        }
        col_ptr.push(row_idx.len());
    }
    let (mut bp, mut bi) = (vec![0usize; nb], vec![0usize; nb]);
    if nb > 0 {
        let graph = SymbolicSparseColMatRef::new_checked(nb, nb, &col_ptr, None, &row_idx);
        let mut mem = MemBuffer::new(amd::order_scratch::<usize>(nb, row_idx.len()));
        amd::order(
            &mut bp,
            &mut bi,
            graph,
            amd::Control::default(),
            MemStack::new(&mut mem),
        )
        .map_err(|e| SolveError::LinearSolver(format!("AMD ordering failed: {e:?}")))?;
    }
    Ok(expand(a, &bp))
}

/// METIS nested dissection on the block graph of `a`, each block weighted by its size.
pub(crate) fn block_nested_dissection(a: &BlockSparse) -> Result<Permutation, SolveError> {
    let nb = a.num_blocks();
    let too_large = || SolveError::LinearSolver("block graph too large for METIS".into());
    let (xadj, adjncy) = symmetric_adjacency::<i32>(a).ok_or_else(too_large)?;
    let mut weights: Vec<i32> = (0..nb)
        .map(|b| (a.block_start[b + 1] - a.block_start[b]) as i32)
        .collect();
    let mut nvtxs = i32::try_from(nb).map_err(|_| too_large())?;
    let (mut perm, mut iperm) = (vec![0i32; nb], vec![0i32; nb]);
    let (mut xadj, mut adjncy) = (xadj, adjncy);
    if nb > 0 {
        // SAFETY: xadj has nb + 1 offsets into adjncy, which holds each vertex's neighbours
        // (none itself); weights, perm and iperm have nb entries; a null options pointer takes
        // METIS's defaults. METIS reads the graph and writes perm and iperm only.
        let status = unsafe {
            metis_sys::METIS_NodeND(
                &mut nvtxs,
                xadj.as_mut_ptr(),
                adjncy.as_mut_ptr(),
                weights.as_mut_ptr(),
                std::ptr::null_mut(),
                perm.as_mut_ptr(),
                iperm.as_mut_ptr(),
            )
        };
        if status != metis_sys::rstatus_et_METIS_OK {
            return Err(SolveError::LinearSolver(format!(
                "METIS nested dissection failed (status {status})"
            )));
        }
    }
    // METIS's perm maps new → old, as faer's forward permutation does
    let order: Vec<usize> = perm.iter().map(|&b| b as usize).collect();
    Ok(expand(a, &order))
}

/// The block graph of `a` in compressed rows, each block's neighbours in both directions and no
/// self-loops, with indices of type `I` (`i32` for METIS). `None` when they do not fit `I`.
pub(crate) fn symmetric_adjacency<I: TryFrom<usize> + Copy + Default>(
    a: &BlockSparse,
) -> Option<(Vec<I>, Vec<I>)> {
    let nb = a.num_blocks();
    let mut degree = vec![0usize; nb + 1];
    let off_diagonal = |j: usize| {
        a.entries[a.entry_ptr[j]..a.entry_ptr[j + 1]]
            .iter()
            .map(|e| e.row_block)
            .filter(move |&i| i != j)
    };
    for j in 0..nb {
        for i in off_diagonal(j) {
            degree[i + 1] += 1;
            degree[j + 1] += 1;
        }
    }
    for b in 0..nb {
        degree[b + 1] += degree[b];
    }
    let index = |v: usize| I::try_from(v).ok();
    index(degree[nb])?;
    index(nb)?;
    let mut next = degree.clone();
    let mut adjncy = vec![I::default(); degree[nb]];
    for j in 0..nb {
        for i in off_diagonal(j) {
            adjncy[next[i]] = index(j)?;
            next[i] += 1;
            adjncy[next[j]] = index(i)?;
            next[j] += 1;
        }
    }
    let xadj = degree
        .iter()
        .map(|&d| index(d))
        .collect::<Option<Vec<I>>>()?;
    Some((xadj, adjncy))
}

/// The scalar permutation of a block order (new → old).
fn expand(a: &BlockSparse, blocks: &[usize]) -> Permutation {
    let n = a.dim();
    let mut fwd = Vec::with_capacity(n);
    for &b in blocks {
        fwd.extend(a.block_start[b]..a.block_start[b + 1]);
    }
    let mut inv = vec![0; n];
    for (new, &old) in fwd.iter().enumerate() {
        inv[old] = new;
    }
    (fwd, inv)
}
