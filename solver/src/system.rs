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

use crate::block::BlockSparse;
use crate::cholesky::Cholesky;
use crate::damping::Damping;
use crate::error::SolveError;
use crate::Options;

/// H (upper triangle, block-sparse), g, and a factorisation prepared for H's structure.
pub struct BlockSystem {
    h: BlockSparse,
    /// Block column of each entry.
    entry_col: Vec<usize>,
    gradient: Vec<f64>,
    cholesky: Cholesky,
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
        let n = sizes.len();
        let mut columns: Vec<Vec<usize>> = (0..n).map(|j| vec![j]).collect();
        for (i, j) in pairs {
            if i >= n || j >= n {
                return Err(SolveError::LinearSolver(format!(
                    "block pair ({i}, {j}) outside a system of {n} blocks"
                )));
            }
            columns[i.max(j)].push(i.min(j));
        }
        for c in &mut columns {
            c.sort_unstable();
            c.dedup();
        }
        let mut block_start = Vec::with_capacity(n + 1);
        block_start.push(0);
        for s in sizes {
            block_start.push(block_start.last().unwrap() + s);
        }
        let h = BlockSparse::new(block_start, &columns);
        let entry_col = (0..n)
            .flat_map(|j| std::iter::repeat_n(j, h.entry_ptr[j + 1] - h.entry_ptr[j]))
            .collect();
        // dense up to the solver's default threshold, as on its own sparse path
        let cholesky = Cholesky::new(&h, h.dim() <= Options::default().dense_threshold)?;
        Ok(Self {
            gradient: vec![0.0; h.dim()],
            h,
            entry_col,
            cholesky,
        })
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
    /// the damped matrix is not numerically positive definite (raise the damping and retry).
    pub fn solve(&mut self, damping: Damping, step: &mut [f64]) -> Result<(), SolveError> {
        assert_eq!(step.len(), self.dim(), "step length");
        self.cholesky
            .factor(&self.h, damping)
            .map_err(|pivot| SolveError::RankDeficient {
                nullity: 1,
                variables: vec![self.h.block_of_scalar(pivot)],
                message: format!(
                    "the damped system is not positive definite at block {}",
                    self.h.block_of_scalar(pivot)
                ),
            })?;
        for (s, g) in step.iter_mut().zip(&self.gradient) {
            *s = -g;
        }
        self.cholesky.solve(step);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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

    /// A chain of 60 blocks of 6 (360 unknowns: the sparse path) filled from `JᵀJ + I` of a random
    /// banded J, against nalgebra's dense Cholesky.
    #[test]
    fn a_large_chain_solves_on_the_sparse_path() {
        let (nb, d) = (60, 6);
        let n = nb * d;
        let mut seed = 7u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut j = nalgebra::DMatrix::<f64>::zeros(n, n);
        for r in 0..n {
            for c in r.saturating_sub(2 * d)..(r + 1) {
                j[(r, c)] = next();
            }
        }
        let dense = j.transpose() * &j + nalgebra::DMatrix::identity(n, n);
        let pairs = (0..nb).flat_map(|b| (b.saturating_sub(2)..b).map(move |a| (a, b)));
        let mut s = BlockSystem::new(&vec![d; nb], pairs).unwrap();
        for e in 0..s.num_entries() {
            let (bi, bj) = s.entry_blocks(e);
            let block: Vec<f64> = (0..d)
                .flat_map(|c| (0..d).map(move |r| (r, c)))
                .map(|(r, c)| dense[(bi * d + r, bj * d + c)])
                .collect();
            s.add_to_entry(e, &block);
        }
        let g = nalgebra::DVector::from_fn(n, |_, _| next());
        s.gradient_mut().copy_from_slice(g.as_slice());
        let mut step = vec![0.0; n];
        s.solve(Damping::Identity(0.25), &mut step).unwrap();
        let a = &dense + nalgebra::DMatrix::identity(n, n) * 0.25;
        let expect = a.cholesky().unwrap().solve(&(-&g));
        let err = (nalgebra::DVector::from_vec(step) - &expect).amax();
        assert!(err < 1e-10 * (1.0 + expect.amax()), "{err}");
    }

    #[test]
    fn pairs_outside_the_system_are_an_error() {
        assert!(BlockSystem::new(&[6, 6], [(0, 2)]).is_err());
    }
}
