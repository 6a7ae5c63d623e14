//! The damped symmetric matrix `H + μD` of a [`BlockSparse`] copied out as full block rows, for
//! the products of conjugate gradients.
//!
//! [`BlockSparse`] keeps the upper triangle only, so its product scatters every stored block
//! twice: `a_rc x_c` into y_r and `a_rc x_r` into y_c, the second a dot product whose sum runs
//! through one register. Here each block row holds every block of its row, `A_ij` and the
//! mirrored `A_jiᵀ` alike, column-major, with the damping in its diagonal block. A product is then
//! a gather per block row, `y_i = Σ_j A_ij x_j`: columns scaled and added (no horizontal sums), no
//! writes outside the row, so the rows split over threads freely and each y_i is summed in one
//! order whatever the thread count. It takes twice the upper triangle's memory; conjugate
//! gradients, which multiply by one matrix tens of times, fill it once per solve (BSR, the block
//! compressed sparse row format; Saad, *Iterative Methods for Sparse Linear Systems*, 2003,
//! sec. 3.4).

use crate::block::{BlockSparse, SIX};
use crate::damping::Damping;
use crate::parallel::for_parts;
use std::ops::Range;

/// Stored blocks below which a range of rows is filled or multiplied on one thread.
const SERIAL_BLOCKS: usize = 1024;

/// `H + μD` by full block rows, in single precision: the product is limited by reading the
/// matrix, and conjugate gradients stopped at a relative residual of 10⁻³ do not see the
/// rounding (the accumulation is in double precision; the system's preconditioner, right-hand
/// side and model decrease stay in double).
#[derive(Default)]
pub(crate) struct BlockRows {
    /// Scalar offset of each block, with the total at the end (H's).
    block_start: Vec<usize>,
    /// Blocks of row i: `row_ptr[i]..row_ptr[i + 1]`; empty until laid out.
    row_ptr: Vec<usize>,
    /// Each block's column block, ascending within a row.
    cols: Vec<usize>,
    /// Each block's first value (d_i × d_j numbers, column-major), with the total at the end.
    offsets: Vec<usize>,
    /// Each block's position inside H's column block max(i, j) (the stored block's `pos`).
    sources: Vec<usize>,
    values: Vec<f32>,
    /// Whether the structure above is that of the matrix filled from.
    laid_out: bool,
}

impl BlockRows {
    /// Copies `h + damping` into full block rows, reusing this copy's buffers. H's structure is
    /// laid out at the first fill: a [`BlockSparse`]'s structure never changes.
    pub fn fill(&mut self, h: &BlockSparse, damping: Damping) {
        if !self.laid_out {
            self.lay_out(h);
        }
        debug_assert_eq!(self.block_start, h.block_start, "one structure");
        let mut values = std::mem::take(&mut self.values);
        let rows = 0..h.num_blocks();
        self.for_row_parts(
            rows,
            &mut values,
            &|i| self.offsets[self.row_ptr[i]],
            &|rows, part| {
                let base = self.offsets[self.row_ptr[rows.start]];
                for i in rows {
                    for k in self.row_ptr[i]..self.row_ptr[i + 1] {
                        let block = &mut part[self.offsets[k] - base..self.offsets[k + 1] - base];
                        self.copy_block(h, damping, i, k, block);
                    }
                }
            },
        );
        self.values = values;
    }

    /// The structure of the full rows: each stored block (i, j) appears in row i and, mirrored,
    /// in row j; rows are filled in H's storage order, so each row's columns ascend.
    fn lay_out(&mut self, h: &BlockSparse) {
        let nb = h.num_blocks();
        self.block_start.clone_from(&h.block_start);
        self.row_ptr.clear();
        self.row_ptr.resize(nb + 1, 0);
        for j in 0..nb {
            for e in &h.entries[h.entry_ptr[j]..h.entry_ptr[j + 1]] {
                self.row_ptr[e.row_block + 1] += 1;
                if e.row_block != j {
                    self.row_ptr[j + 1] += 1;
                }
            }
        }
        for i in 0..nb {
            self.row_ptr[i + 1] += self.row_ptr[i];
        }
        let len = self.row_ptr[nb];
        self.cols.resize(len, 0);
        self.sources.resize(len, 0);
        let mut cursor = self.row_ptr[..nb].to_vec();
        for j in 0..nb {
            for e in &h.entries[h.entry_ptr[j]..h.entry_ptr[j + 1]] {
                let i = e.row_block;
                for (row, col) in [(i, j), (j, i)].into_iter().take(1 + usize::from(i != j)) {
                    (self.cols[cursor[row]], self.sources[cursor[row]]) = (col, e.pos);
                    cursor[row] += 1;
                }
            }
        }
        self.offsets.clear();
        let mut at = 0;
        for i in 0..nb {
            for k in self.row_ptr[i]..self.row_ptr[i + 1] {
                self.offsets.push(at);
                at += h.block_dim(i) * h.block_dim(self.cols[k]);
            }
        }
        self.offsets.push(at);
        self.values.resize(at, 0.0);
        self.laid_out = true;
    }

    /// This copy's buffers for a matrix of another structure: the allocations are kept, the
    /// structure is laid out again at the next fill.
    pub fn recycled(mut self) -> Self {
        self.laid_out = false;
        self
    }

    /// Fills block k, (i, j) of the full matrix, from H: A_ij as stored when i < j, the stored
    /// A_ji transposed when i > j, and both triangles of a diagonal block with the damping.
    fn copy_block(&self, h: &BlockSparse, damping: Damping, i: usize, k: usize, out: &mut [f32]) {
        let (j, pos) = (self.cols[k], self.sources[k]);
        let (di, dj) = (h.block_dim(i), h.block_dim(j));
        // scalar column c of the stored block's column block, from its row `pos`
        let column = |block: usize, c: usize, len: usize| {
            let start = h.col_ptr[h.block_start[block] + c] + pos;
            &h.values[start..start + len]
        };
        if i < j {
            for (c, out) in out.chunks_exact_mut(di).enumerate() {
                for (o, &v) in out.iter_mut().zip(column(j, c, di)) {
                    *o = v as f32;
                }
            }
        } else if i > j {
            for r in 0..di {
                for (c, &v) in column(i, r, dj).iter().enumerate() {
                    out[c * di + r] = v as f32;
                }
            }
        } else {
            for c in 0..di {
                // the column's last c + 1 values are the diagonal block's rows 0..=c
                let end = h.col_ptr[h.block_start[i] + c + 1];
                for (r, &v) in h.values[end - c - 1..end].iter().enumerate() {
                    let v = match r == c {
                        true => h.damped(damping, h.block_start[i] + c, v),
                        false => v,
                    };
                    (out[c * di + r], out[r * di + c]) = (v as f32, v as f32);
                }
            }
        }
    }

    /// y = (H + μD) x, the rows split over threads.
    pub fn multiply(&self, x: &[f64], y: &mut [f64]) {
        let rows = 0..self.row_ptr.len().saturating_sub(1);
        self.for_row_parts(rows, y, &|i| self.block_start[i], &|rows, part| {
            let base = self.block_start[rows.start];
            for i in rows {
                let (start, end) = (self.block_start[i] - base, self.block_start[i + 1] - base);
                self.multiply_row(i, x, &mut part[start..end]);
            }
        });
    }

    /// Runs `f(part of rows, its share of out)` over `rows`, halved by stored blocks (in
    /// parallel, [`for_parts`]) until a part is small enough for one thread; row i's share of
    /// `out` starts at `start(i)`, and the shares of consecutive rows are contiguous.
    fn for_row_parts<T: Send>(
        &self,
        rows: Range<usize>,
        out: &mut [T],
        start: &(impl Fn(usize) -> usize + Sync),
        f: &(impl Fn(Range<usize>, &mut [T]) + Sync),
    ) {
        let weight = |i: usize| self.row_ptr[i];
        for_parts(rows, out, (start, &weight), SERIAL_BLOCKS, f);
    }

    /// Row i of the product: `y_i = Σ_j A_ij x_j`.
    fn multiply_row(&self, i: usize, x: &[f64], y: &mut [f64]) {
        if let Ok(y) = <&mut [f64; SIX]>::try_from(&mut *y) {
            return self.multiply_row_of_six(i, x, y);
        }
        let di = y.len();
        y.fill(0.0);
        for k in self.row_ptr[i]..self.row_ptr[i + 1] {
            let j = self.cols[k];
            let xj = &x[self.block_start[j]..self.block_start[j + 1]];
            let block = &self.values[self.offsets[k]..self.offsets[k + 1]];
            for (column, &xc) in block.chunks_exact(di).zip(xj) {
                for (yr, &v) in y.iter_mut().zip(column) {
                    *yr = f64::from(v).mul_add(xc, *yr);
                }
            }
        }
    }

    /// [`Self::multiply_row`] for a row of six: six-row columns, the even and odd ones into two
    /// accumulators so that the additions overlap.
    fn multiply_row_of_six(&self, i: usize, x: &[f64], y: &mut [f64; SIX]) {
        let (mut even, mut odd) = ([0.0; SIX], [0.0; SIX]);
        for k in self.row_ptr[i]..self.row_ptr[i + 1] {
            let j = self.cols[k];
            let xj = &x[self.block_start[j]..self.block_start[j + 1]];
            let block = &self.values[self.offsets[k]..self.offsets[k + 1]];
            let mut columns = block.chunks_exact(2 * SIX).zip(xj.chunks_exact(2));
            for (pair, xc) in &mut columns {
                let (a, b) = pair.split_at(SIX);
                for r in 0..SIX {
                    even[r] = f64::from(a[r]).mul_add(xc[0], even[r]);
                    odd[r] = f64::from(b[r]).mul_add(xc[1], odd[r]);
                }
            }
            if xj.len() % 2 == 1 {
                let column = &block[block.len() - SIX..];
                let xc = xj[xj.len() - 1];
                for r in 0..SIX {
                    even[r] = f64::from(column[r]).mul_add(xc, even[r]);
                }
            }
        }
        for r in 0..SIX {
            y[r] = even[r] + odd[r];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::block::block_starts;

    /// Blocks of sizes 6, 3, 6, 1, 6, 6 coupled irregularly, filled with distinct values: the
    /// full rows' product must equal the upper triangle's product plus the damping, for each
    /// kind of damping.
    #[test]
    fn full_rows_multiply_like_the_upper_triangle_with_damping() {
        let sizes = [6, 3, 6, 1, 6, 6];
        let columns: Vec<Vec<usize>> = vec![
            vec![0],
            vec![0, 1],
            vec![1, 2],
            vec![0, 2, 3],
            vec![3, 4],
            vec![0, 1, 4, 5],
        ];
        let mut h = BlockSparse::new(block_starts(&sizes), &columns);
        for (k, v) in h.values.iter_mut().enumerate() {
            // sixteenths: exact in single precision, so the copy's rounding does not enter
            *v = ((k * 37) % 101) as f64 / 16.0 - 2.0;
        }
        let n = h.dim();
        let x: Vec<f64> = (0..n).map(|i| (i as f64 * 0.7).sin()).collect();
        for damping in [
            Damping::None,
            Damping::Identity(2.5),
            Damping::Diagonal(0.5),
        ] {
            let mut expected = vec![0.0; n];
            h.multiply(&x, &mut expected);
            for (i, at) in h.diag_pos().enumerate() {
                // the damped diagonal as the copy keeps it, in single precision
                let damped = f64::from(h.damped(damping, i, h.values[at]) as f32);
                expected[i] += (damped - h.values[at]) * x[i];
            }
            let mut rows = BlockRows::default();
            rows.fill(&h, damping);
            let mut y = vec![f64::NAN; n];
            rows.multiply(&x, &mut y);
            for (a, b) in y.iter().zip(&expected) {
                assert!((a - b).abs() <= 1e-12 * (1.0 + b.abs()), "{a} against {b}");
            }
            // every stored number twice, the diagonal blocks' once: both triangles, full
            let diagonal: usize = sizes.iter().map(|d| d * d).sum();
            let stored_off: usize =
                h.values.len() - sizes.iter().map(|d| d * (d + 1) / 2).sum::<usize>();
            assert_eq!(rows.values.len(), diagonal + 2 * stored_off);
        }
    }

    /// A chain of 600 blocks of six, each coupled to the next three: more stored blocks than one
    /// thread takes, so the rows are split; the product must not depend on the split.
    #[test]
    fn a_product_split_over_threads_is_the_product_on_one() {
        let nb = 600;
        let columns: Vec<Vec<usize>> = (0..nb)
            .map(|j: usize| (j.saturating_sub(3)..=j).collect())
            .collect();
        let block_start: Vec<usize> = (0..=nb).map(|b| 6 * b).collect();
        let mut h = BlockSparse::new(block_start, &columns);
        for (k, v) in h.values.iter_mut().enumerate() {
            *v = ((k * 53) % 97) as f64 / 16.0 - 3.0;
        }
        let x: Vec<f64> = (0..h.dim()).map(|i| (i as f64 * 0.31).cos()).collect();
        let mut rows = BlockRows::default();
        rows.fill(&h, Damping::Identity(1.0));
        assert!(rows.cols.len() > 2 * SERIAL_BLOCKS);
        let mut split = vec![0.0; h.dim()];
        rows.multiply(&x, &mut split);
        let mut serial = vec![0.0; h.dim()];
        for i in 0..nb {
            rows.multiply_row(i, &x, &mut serial[6 * i..6 * i + 6]);
        }
        assert_eq!(split, serial);
        let mut expected = vec![0.0; h.dim()];
        h.multiply(&x, &mut expected);
        for (i, e) in expected.iter_mut().enumerate() {
            *e += x[i];
        }
        for (a, b) in split.iter().zip(&expected) {
            assert!((a - b).abs() <= 1e-12 * (1.0 + b.abs()), "{a} against {b}");
        }
    }
}
