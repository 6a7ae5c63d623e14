//! The layout of a Schur elimination, computed once per structure: which blocks are kept and
//! eliminated, each eliminated block's kept neighbours and buffer offsets, the pattern of S, and
//! the index lists the assembly walks.

use super::kernels::{MAX_ELIMINATED, MAX_PRODUCT};
use super::Neighbour;
use crate::block::BlockSparse;
use crate::error::SolveError;
use crate::normal::NormalEquations;

/// Chunks of the point-major assembly: a fixed number, so the sums do not depend on the threads.
const CHUNKS: usize = 4;
/// Largest number of S values for which the point-major assembly keeps its per-chunk copies.
const POINT_MAJOR_VALUES: usize = 1 << 21;

/// The blocks split into eliminated and kept ones, with each block's index in its part.
pub(super) struct Split {
    pub elim: Vec<usize>,
    pub kept: Vec<usize>,
    pub reduced_of: Vec<usize>,
}

impl Split {
    pub fn new(eliminate: &[bool]) -> Self {
        let nb = eliminate.len();
        let elim: Vec<usize> = (0..nb).filter(|&b| eliminate[b]).collect();
        let kept: Vec<usize> = (0..nb).filter(|&b| !eliminate[b]).collect();
        let mut reduced_of = vec![usize::MAX; nb];
        for (k, &b) in kept.iter().enumerate() {
            reduced_of[b] = k;
        }
        Self {
            elim,
            kept,
            reduced_of,
        }
    }
}

/// Each eliminated block's neighbours with their H_ce offsets, and its H_ee⁻¹ offset.
pub(super) struct Neighbours {
    pub nbr_ptr: Vec<usize>,
    pub nbrs: Vec<Neighbour>,
    /// Scalar offset of each eliminated block inside the eliminated part, with the total last.
    pub elim_start: Vec<usize>,
    pub inv_offset: Vec<usize>,
    /// Lengths of the H_ee⁻¹ buffer and of a copy of H_ce.
    pub inv_len: usize,
    pub buf_len: usize,
}

impl Neighbours {
    /// Lays out the kept neighbours of every eliminated block from `ne`'s couplings; an error
    /// for a block too large to eliminate.
    pub fn new(ne: &NormalEquations, split: &Split) -> Result<Self, SolveError> {
        let h = ne.h();
        let dim = |b: usize| h.block_dim(b);
        let couplings = ne.couplings();
        let mut out = Self {
            nbr_ptr: Vec::with_capacity(split.elim.len() + 1),
            nbrs: Vec::with_capacity(couplings.kept.len()),
            elim_start: Vec::with_capacity(split.elim.len() + 1),
            inv_offset: Vec::with_capacity(split.elim.len()),
            inv_len: 0,
            buf_len: 0,
        };
        out.nbr_ptr.push(0);
        out.elim_start.push(0);
        for &e in &split.elim {
            let de = dim(e);
            let list = couplings.of(e);
            let widest = list
                .clone()
                .map(|c| dim(couplings.kept[c]))
                .max()
                .unwrap_or(0);
            if de > MAX_ELIMINATED || de * widest > MAX_PRODUCT {
                return Err(SolveError::LinearSolver(format!(
                    "variable {} ({de} unknowns, next to a variable of {widest}) is too large to \
                     eliminate: the Schur solvers take eliminated variables of at most \
                     {MAX_ELIMINATED} unknowns and products of sizes up to {MAX_PRODUCT}; use \
                     the sparse Cholesky",
                    ne.var_of_block()[e]
                )));
            }
            // the copy of H_ce is laid out like H's block column: column k of every
            // neighbour's block in one run of `rows` values
            let rows: usize = list.clone().map(|c| dim(couplings.kept[c])).sum();
            let mut offset = out.buf_len;
            for c in list {
                let kept = split.reduced_of[couplings.kept[c]];
                out.nbrs.push(Neighbour {
                    kept,
                    coupling: c,
                    offset,
                    step: rows,
                });
                offset += dim(couplings.kept[c]);
            }
            out.buf_len += rows * de;
            out.nbr_ptr.push(out.nbrs.len());
            out.inv_offset.push(out.inv_len);
            out.inv_len += de * de;
            out.elim_start.push(out.elim_start.last().unwrap() + de);
        }
        Ok(out)
    }

    /// The neighbour records of eliminated block q.
    pub fn of(&self, q: usize) -> &[Neighbour] {
        &self.nbrs[self.nbr_ptr[q]..self.nbr_ptr[q + 1]]
    }

    /// For each reduced column, the eliminated blocks next to it as (q, neighbour record).
    pub fn touch_lists(&self, kept: usize) -> Vec<Vec<(usize, usize)>> {
        let mut lists: Vec<Vec<(usize, usize)>> = vec![Vec::new(); kept];
        for q in 0..self.nbr_ptr.len() - 1 {
            for n in self.nbr_ptr[q]..self.nbr_ptr[q + 1] {
                lists[self.nbrs[n].kept].push((q, n));
            }
        }
        lists
    }
}

/// The pattern of S: the H_cc blocks, and (unless `iterative`) every pair of kept blocks that
/// share an eliminated neighbour.
pub(super) fn reduced_pattern(
    h: &BlockSparse,
    eliminate: &[bool],
    split: &Split,
    nbrs: &Neighbours,
    touch_lists: &[Vec<(usize, usize)>],
    iterative: bool,
) -> BlockSparse {
    let mut columns: Vec<Vec<usize>> = vec![Vec::new(); split.kept.len()];
    for (k, &b) in split.kept.iter().enumerate() {
        for e in h.entry_ptr[b]..h.entry_ptr[b + 1] {
            let i = h.entries[e].row_block;
            if !eliminate[i] {
                columns[k].push(split.reduced_of[i]);
            }
        }
    }
    if !iterative {
        for (j, list) in touch_lists.iter().enumerate() {
            for &(q, n) in list {
                columns[j].extend(nbrs.nbrs[nbrs.nbr_ptr[q]..=n].iter().map(|x| x.kept));
            }
        }
    }
    for c in columns.iter_mut() {
        c.sort_unstable();
        c.dedup();
    }
    let mut reduced_start = vec![0];
    for &b in &split.kept {
        reduced_start.push(reduced_start.last().unwrap() + h.block_dim(b));
    }
    BlockSparse::new(reduced_start, &columns)
}

/// Per reduced column: (S entry, H entry, H column) of the H_cc blocks copied into S.
pub(super) fn direct_copies(
    h: &BlockSparse,
    eliminate: &[bool],
    split: &Split,
    s: &BlockSparse,
) -> (Vec<usize>, Vec<(usize, usize, usize)>) {
    let mut direct_ptr = vec![0];
    let mut direct = Vec::new();
    for (k, &b) in split.kept.iter().enumerate() {
        for e in h.entry_ptr[b]..h.entry_ptr[b + 1] {
            let i = h.entries[e].row_block;
            if !eliminate[i] {
                let se = s
                    .find(split.reduced_of[i], k)
                    .expect("H_cc block in S's pattern");
                direct.push((se, e, b));
            }
        }
        direct_ptr.push(direct.len());
    }
    (direct_ptr, direct)
}

/// The point-major assembly's lists: per eliminated block the S entries of its neighbour pairs,
/// the chunks' boundaries, and each S block's offset in a chunk's copy. Empty (one chunk
/// boundary) when the assembly goes by columns.
pub(super) struct PointMajor {
    pub pair_ptr: Vec<usize>,
    pub pair_entry: Vec<usize>,
    pub chunk_bounds: Vec<usize>,
    pub block_offset: Vec<usize>,
}

impl PointMajor {
    /// The lists when S is small enough for per-chunk copies (and not `iterative`).
    pub fn new(s: &BlockSparse, nbrs: &Neighbours, eliminated: usize, iterative: bool) -> Self {
        let mut out = Self {
            pair_ptr: vec![0],
            pair_entry: Vec::new(),
            chunk_bounds: vec![0],
            block_offset: vec![0],
        };
        if iterative || s.values.len() > POINT_MAJOR_VALUES || eliminated == 0 {
            return out;
        }
        for q in 0..eliminated {
            let list = nbrs.of(q);
            for (b, nb) in list.iter().enumerate() {
                for na in &list[..=b] {
                    out.pair_entry
                        .push(s.find(na.kept, nb.kept).expect("pair block in S's pattern"));
                }
            }
            out.pair_ptr.push(out.pair_entry.len());
        }
        // Chunks of about equal work (pairs), boundaries at block starts.
        let per_chunk = out.pair_entry.len().div_ceil(CHUNKS).max(1);
        for q in 0..eliminated {
            if out.pair_ptr[q + 1] >= per_chunk * out.chunk_bounds.len() && q + 1 < eliminated {
                out.chunk_bounds.push(q + 1);
            }
        }
        out.chunk_bounds.push(eliminated);
        for j in 0..s.num_blocks() {
            for e in &s.entries[s.entry_ptr[j]..s.entry_ptr[j + 1]] {
                let size = s.block_dim(e.row_block) * s.block_dim(j);
                out.block_offset
                    .push(out.block_offset.last().unwrap() + size);
            }
        }
        out
    }

    /// True when the assembly goes point-major.
    pub fn active(&self) -> bool {
        self.chunk_bounds.len() > 1
    }
}

/// Per reduced column j, its touches (q, neighbour record), and per touch the S entries of the
/// blocks (i, j) for q's neighbours i ≤ j (only for the column-major assembly).
pub(super) struct Touches {
    pub touch_ptr: Vec<usize>,
    pub touch: Vec<(usize, usize)>,
    pub update_ptr: Vec<usize>,
    pub update: Vec<usize>,
}

impl Touches {
    pub fn new(
        touch_lists: &[Vec<(usize, usize)>],
        nbrs: &Neighbours,
        s: &BlockSparse,
        with_updates: bool,
    ) -> Self {
        let mut out = Self {
            touch_ptr: vec![0],
            touch: Vec::new(),
            update_ptr: vec![0],
            update: Vec::new(),
        };
        for (j, list) in touch_lists.iter().enumerate() {
            for &(q, n) in list {
                out.touch.push((q, n));
                if with_updates {
                    for x in &nbrs.nbrs[nbrs.nbr_ptr[q]..=n] {
                        out.update
                            .push(s.find(x.kept, j).expect("update block in S's pattern"));
                    }
                }
                out.update_ptr.push(out.update.len());
            }
            out.touch_ptr.push(out.touch.len());
        }
        out
    }
}
