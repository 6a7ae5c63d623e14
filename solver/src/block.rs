//! A symmetric block-sparse matrix stored as its upper triangle in compressed columns: the layout
//! of the normal equations H and of the Schur complement S, and the one faer's sparse Cholesky
//! reads.
//!
//! Block column j holds the blocks (i, j), i ≤ j, in increasing i; inside every scalar column the
//! rows of one block are contiguous, and the diagonal block keeps only its upper triangle. So the
//! element (r, c) of block (i, j) sits at `values[col_ptr[block_start[j] + c] + pos + r]`, with
//! `pos` the block's offset inside its columns.

use crate::damping::{damping_scale, Damping};

/// Stored elements from which [`BlockSparse::multiply_split`] uses two threads.
const PARALLEL_PRODUCT: usize = 1 << 16;

/// The size of a pose's or a deformation node's block, which products unroll for.
pub(crate) const SIX: usize = 6;

/// The scalar offset of each block of sizes `sizes`, with the total at the end (the layout's
/// `block_start`).
pub(crate) fn block_starts(sizes: &[usize]) -> Vec<usize> {
    let mut start = Vec::with_capacity(sizes.len() + 1);
    start.push(0);
    for s in sizes {
        start.push(start.last().unwrap() + s);
    }
    start
}

/// One block (i, j), i ≤ j, of the upper triangle.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Entry {
    pub row_block: usize,
    /// Offset of the block's first row inside each of its columns.
    pub pos: usize,
}

/// The symmetric matrix: structure and values.
pub(crate) struct BlockSparse {
    /// Scalar offset of each block, with the total at the end.
    pub block_start: Vec<usize>,
    /// Entries of block column j: `entries[entry_ptr[j]..entry_ptr[j + 1]]`.
    pub entry_ptr: Vec<usize>,
    pub entries: Vec<Entry>,
    /// Start of every scalar column in `values` (the scalar row indices are not stored: they
    /// follow from the blocks, and only a sparse factorisation needs them, see
    /// [`Self::row_indices`]; H of a large bundle adjustment saves 8 bytes per element).
    pub col_ptr: Vec<usize>,
    pub values: Vec<f64>,
    /// Each unknown's scale of Marquardt's damping ([`crate::damping::damping_scale`]); empty
    /// for a scale of 1 everywhere.
    pub damping_scale: Vec<f64>,
}

impl BlockSparse {
    /// Lays out a matrix whose block column j has the row blocks `columns[j]` (strictly
    /// increasing, each ≤ j, ending with j itself). Values start at zero.
    pub fn new(block_start: Vec<usize>, columns: &[Vec<usize>]) -> Self {
        let dim = |b: usize| block_start[b + 1] - block_start[b];
        let n = *block_start.last().unwrap_or(&0);
        let mut entry_ptr = Vec::with_capacity(columns.len() + 1);
        entry_ptr.push(0);
        let mut entries = Vec::with_capacity(columns.iter().map(Vec::len).sum());
        let mut col_ptr = Vec::with_capacity(n + 1);
        col_ptr.push(0);
        let mut len = 0;
        for (j, rows) in columns.iter().enumerate() {
            debug_assert_eq!(rows.last(), Some(&j), "block column {j} lacks its diagonal");
            let mut pos = 0;
            for &row in rows {
                entries.push(Entry {
                    row_block: row,
                    pos,
                });
                pos += if row == j { 0 } else { dim(row) };
            }
            entry_ptr.push(entries.len());
            for c in 0..dim(j) {
                // The blocks above the diagonal, then the diagonal block's rows 0..=c.
                len += pos + c + 1;
                col_ptr.push(len);
            }
        }
        Self {
            values: vec![0.0; len],
            block_start,
            entry_ptr,
            entries,
            col_ptr,
            damping_scale: Vec::new(),
        }
    }

    /// Position in `values` of every diagonal element, in the unknowns' order: the last of its
    /// scalar column (not stored: a 1 M-pose graph saves 48 MB).
    pub fn diag_pos(&self) -> impl ExactSizeIterator<Item = usize> + '_ {
        self.col_ptr[1..].iter().map(|&end| end - 1)
    }

    /// The damped value of diagonal element `v` of unknown `i`.
    #[inline]
    pub fn damped(&self, damping: Damping, i: usize, v: f64) -> f64 {
        match self.damping_scale.get(i) {
            Some(&scale) => damping.apply_scaled(v, scale),
            None => damping.apply(v),
        }
    }

    /// Fixes every unknown's damping scale from the current diagonal (at the start of a solve).
    pub fn fix_damping_scale(&mut self) {
        let scales = self.diag_pos().map(|p| damping_scale(self.values[p]));
        self.damping_scale = scales.collect();
    }

    /// The diagonal with each unknown's damping scale, in the unknowns' order.
    pub fn diagonal_and_scale(&self) -> impl Iterator<Item = (f64, f64)> + '_ {
        let scale = |i: usize| self.damping_scale.get(i).copied().unwrap_or(1.0);
        (self.diag_pos().enumerate()).map(move |(i, p)| (self.values[p], scale(i)))
    }

    /// Calls `f(start, row, rows, c)` for every run of stored elements, in storage order: the
    /// `rows` elements of scalar column `c` from `values[start]`, rows `row..row + rows`.
    pub fn for_each_run(&self, mut f: impl FnMut(usize, usize, usize, usize)) {
        for j in 0..self.num_blocks() {
            let entries = &self.entries[self.entry_ptr[j]..self.entry_ptr[j + 1]];
            for dc in 0..self.block_dim(j) {
                let c = self.block_start[j] + dc;
                for e in entries {
                    let rows = if e.row_block == j {
                        dc + 1
                    } else {
                        self.block_dim(e.row_block)
                    };
                    f(
                        self.col_ptr[c] + e.pos,
                        self.block_start[e.row_block],
                        rows,
                        c,
                    );
                }
            }
        }
    }

    /// The scalar row index of every stored element, in storage order (the compressed-column
    /// pattern with [`Self::col_ptr`]), each as `index(row)` (a narrower integer type, say).
    pub fn row_indices<T>(&self, index: impl Fn(usize) -> T) -> Vec<T> {
        let mut rows = Vec::with_capacity(self.values.len());
        self.for_each_run(|_, row, n, _| rows.extend((row..row + n).map(&index)));
        rows
    }

    /// Scalar size.
    pub fn dim(&self) -> usize {
        *self.block_start.last().unwrap_or(&0)
    }

    /// Number of block rows (and columns).
    pub fn num_blocks(&self) -> usize {
        self.block_start.len() - 1
    }

    /// Scalar size of block `b`.
    #[inline]
    pub fn block_dim(&self, b: usize) -> usize {
        self.block_start[b + 1] - self.block_start[b]
    }

    /// Position in `values` of element (0, c) of entry `e` of block column `j`; its rows follow.
    #[inline]
    pub fn column_start(&self, j: usize, e: usize, c: usize) -> usize {
        self.col_ptr[self.block_start[j] + c] + self.entries[e].pos
    }

    /// The entry index of block (i, j), i ≤ j, if it is stored.
    pub fn find(&self, i: usize, j: usize) -> Option<usize> {
        let range = self.entry_ptr[j]..self.entry_ptr[j + 1];
        self.entries[range.clone()]
            .binary_search_by_key(&i, |e| e.row_block)
            .ok()
            .map(|k| range.start + k)
    }

    /// y = A x with A symmetric, stored as its upper triangle.
    pub fn multiply(&self, x: &[f64], y: &mut [f64]) {
        y.fill(0.0);
        self.add_product(0..self.num_blocks(), x, y);
    }

    /// [`Self::multiply`] on two threads when A is large: the block columns are split where
    /// half the stored elements lie, the second half's product summed into `scratch` (resized
    /// to y's length) and added.
    pub fn multiply_split(&self, x: &[f64], y: &mut [f64], scratch: &mut Vec<f64>) {
        if self.values.len() < PARALLEL_PRODUCT {
            return self.multiply(x, y);
        }
        let half = self.values.len() / 2;
        let split = self
            .block_start
            .partition_point(|&s| self.col_ptr[s] < half)
            .min(self.num_blocks());
        scratch.resize(y.len(), 0.0);
        y.fill(0.0);
        scratch.fill(0.0);
        let nb = self.num_blocks();
        rayon::join(
            || self.add_product(0..split, x, y),
            || self.add_product(split..nb, x, scratch),
        );
        for (y, s) in y.iter_mut().zip(scratch.iter()) {
            *y += s;
        }
    }

    /// y += A_J x for the block columns J of the upper triangle and their mirror images: each
    /// stored a_rc (r < c) adds a_rc x_c to y_r and a_rc x_r to y_c, the second summed over the
    /// column in a register and added once.
    fn add_product(&self, columns: std::ops::Range<usize>, x: &[f64], y: &mut [f64]) {
        for j in columns {
            let entries = &self.entries[self.entry_ptr[j]..self.entry_ptr[j + 1]];
            // the diagonal block is the column's last entry
            let above = &entries[..entries.len() - 1];
            match self.block_dim(j) {
                SIX => self.add_column_of_six(j, above, x, y),
                _ => self.add_column(j, above, x, y),
            }
        }
    }

    /// [`Self::add_product`] of block column j, one scalar column at a time.
    fn add_column(&self, j: usize, above: &[Entry], x: &[f64], y: &mut [f64]) {
        let first = self.block_start[j];
        for dc in 0..self.block_dim(j) {
            let c = first + dc;
            let column = &self.values[self.col_ptr[c]..self.col_ptr[c + 1]];
            let xc = x[c];
            let mut sum = 0.0;
            for e in above {
                let (row, pos) = (self.block_start[e.row_block], e.pos);
                sum += match self.block_dim(e.row_block) {
                    // six rows, a length the inlined loop unrolls for
                    SIX => column_rows(
                        &column[pos..pos + SIX],
                        xc,
                        &mut y[row..row + SIX],
                        &x[row..row + SIX],
                    ),
                    d => column_rows(
                        &column[pos..pos + d],
                        xc,
                        &mut y[row..row + d],
                        &x[row..row + d],
                    ),
                };
            }
            self.add_diagonal_column(j, dc, sum, x, y);
        }
    }

    /// [`Self::add_product`] of a block column of six (a pose's or a node's): each 6 × 6 block
    /// above the diagonal at once, its six rows of y and x held in registers across its six
    /// columns. The same sums in the same order as [`Self::add_column`], so the same bits.
    fn add_column_of_six(&self, j: usize, above: &[Entry], x: &[f64], y: &mut [f64]) {
        let first = self.block_start[j];
        let starts: [usize; SIX] = std::array::from_fn(|dc| self.col_ptr[first + dc]);
        let xc: [f64; SIX] = std::array::from_fn(|dc| x[first + dc]);
        let mut sums = [0.0; SIX];
        for e in above {
            let (row, pos) = (self.block_start[e.row_block], e.pos);
            let d = self.block_dim(e.row_block);
            if d != SIX {
                for dc in 0..SIX {
                    let v = &self.values[starts[dc] + pos..starts[dc] + pos + d];
                    sums[dc] += column_rows(v, xc[dc], &mut y[row..row + d], &x[row..row + d]);
                }
                continue;
            }
            let yr: &mut [f64; SIX] = (&mut y[row..row + SIX]).try_into().expect("six rows");
            let xr: &[f64; SIX] = x[row..row + SIX].try_into().expect("six rows");
            let mut acc = *yr;
            for dc in 0..SIX {
                let v: &[f64; SIX] = self.values[starts[dc] + pos..starts[dc] + pos + SIX]
                    .try_into()
                    .expect("six rows");
                let mut sum = 0.0;
                for r in 0..SIX {
                    acc[r] += v[r] * xc[dc];
                    sum += v[r] * xr[r];
                }
                sums[dc] += sum;
            }
            *yr = acc;
        }
        for (dc, &sum) in sums.iter().enumerate() {
            self.add_diagonal_column(j, dc, sum, x, y);
        }
    }

    /// Ends column dc of block column j in [`Self::add_product`]: its rows inside the diagonal
    /// block (0..=dc), then y_c += `sum` (the column's mirror products above) + a_cc x_c.
    #[inline(always)]
    fn add_diagonal_column(&self, j: usize, dc: usize, sum: f64, x: &[f64], y: &mut [f64]) {
        let first = self.block_start[j];
        let c = first + dc;
        let column = &self.values[self.col_ptr[c + 1] - dc - 1..self.col_ptr[c + 1]];
        let (strict, diagonal) = column.split_at(dc);
        let sum = sum + column_rows(strict, x[c], &mut y[first..c], &x[first..c]);
        y[c] += sum + diagonal[0] * x[c];
    }

    /// Calls `f(r, c, v)` for every stored element (r ≤ c) of A + damping.
    pub fn for_each_damped(&self, damping: Damping, mut f: impl FnMut(usize, usize, f64)) {
        self.for_each_run(|start, row, rows, c| {
            let values = &self.values[start..start + rows];
            for (r, &v) in (row..row + rows).zip(values) {
                f(
                    r,
                    c,
                    if r == c {
                        self.damped(damping, r, v)
                    } else {
                        v
                    },
                );
            }
        });
    }

    /// Writes the diagonal block `b` of A + damping, both triangles, into `out` (d × d,
    /// column-major).
    pub fn damped_diagonal_block(&self, b: usize, damping: Damping, out: &mut [f64]) {
        let d = self.block_dim(b);
        let diag = self.entry_ptr[b + 1] - 1;
        for c in 0..d {
            let start = self.column_start(b, diag, c);
            for r in 0..=c {
                let v = self.values[start + r];
                let v = if r == c {
                    self.damped(damping, self.block_start[b] + c, v)
                } else {
                    v
                };
                out[r + c * d] = v;
                out[c + r * d] = v;
            }
        }
    }

    /// The block holding scalar `i`.
    pub fn block_of_scalar(&self, i: usize) -> usize {
        self.block_start
            .partition_point(|&s| s <= i)
            .saturating_sub(1)
    }

    /// The diagonal.
    pub fn diagonal(&self) -> impl Iterator<Item = f64> + '_ {
        self.diag_pos().map(|p| self.values[p])
    }
}

/// One run of stored rows of a column in [`BlockSparse::add_product`] (`values`, `y` and `x`
/// of equal length): y_r += v_r x_c for each, and Σ v_r x_r returned, summed in row order.
#[inline(always)]
fn column_rows(values: &[f64], xc: f64, y: &mut [f64], x: &[f64]) -> f64 {
    let mut sum = 0.0;
    for ((v, yr), xr) in values.iter().zip(y.iter_mut()).zip(x) {
        *yr += v * xc;
        sum += v * xr;
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn marquardt_damping_is_that_of_the_columns_scaled_at_the_start() {
        // Ceres scales J's column i by s = 1 / (1 + √v₀) once, v₀ the diagonal at the start,
        // and damps the scaled system by μ clamp(s² v, 1e-6, 1e32); unscaled, that is
        // μ clamp(s² v, 1e-6, 1e32) / s² on the diagonal v.
        let mut m = BlockSparse::new(vec![0, 2, 4], &[vec![0], vec![1]]);
        let start = [4.0e6, 9.0, 0.0, 1e-12];
        let now = [4.0e-3, 90.0, 0.0, 5.0];
        let set = |m: &mut BlockSparse, v: &[f64]| {
            for (i, p) in m.diag_pos().collect::<Vec<_>>().into_iter().enumerate() {
                m.values[p] = v[i];
            }
        };
        set(&mut m, &start);
        m.fix_damping_scale();
        set(&mut m, &now);
        let mu = 0.01;
        for (i, (&v0, &v)) in start.iter().zip(&now).enumerate() {
            let s2 = (1.0 / (1.0 + v0.sqrt())).powi(2);
            let ceres = v + mu * (s2 * v).clamp(1e-6, 1e32) / s2;
            let ours = m.damped(Damping::Diagonal(mu), i, v);
            assert!(
                (ours - ceres).abs() <= 1e-12 * ceres,
                "{i}: {ours} against {ceres}"
            );
        }
        // the unknown whose curvature fell by 1e9 keeps a floor of 1e-6 of its start
        let collapsed = m.damped(Damping::Diagonal(mu), 0, now[0]) - now[0];
        assert!((collapsed - mu * 1e-6 * (1.0 + 2e3f64).powi(2)).abs() < 1e-12);
        let d: Vec<(f64, f64)> = m.diagonal_and_scale().collect();
        assert_eq!(d[0], (now[0], (1.0 + 2e3f64).powi(2)));
        // without scales, the floor is 1e-6 itself
        m.damping_scale.clear();
        assert_eq!(
            m.damped(Damping::Diagonal(mu), 0, now[0]),
            now[0] + mu * now[0]
        );
    }

    #[test]
    fn layout_places_every_block_element_once() {
        // blocks of sizes 2, 1, 3; column 2 holds blocks (0, 2) and (2, 2), column 1 only (1, 1)
        let m = BlockSparse::new(vec![0, 2, 3, 6], &[vec![0], vec![1], vec![0, 2]]);
        assert_eq!(m.dim(), 6);
        assert_eq!(m.find(0, 2), Some(2));
        assert_eq!(m.find(1, 2), None);
        // column of scalar 4 (block 2, c = 1): rows 0, 1 of block 0, then rows 3, 4 of block 2
        let rows = m.row_indices(|r| r);
        assert_eq!(rows.len(), m.values.len());
        let p = m.col_ptr[4];
        assert_eq!(&rows[p..m.col_ptr[5]], &[0, 1, 3, 4]);
        assert_eq!(m.column_start(2, 3, 1), p + 2);
        assert_eq!(rows[m.diag_pos().nth(4).unwrap()], 4);
        assert_eq!(m.values.len(), 3 + 1 + 2 * 3 + 6);
    }

    /// Columns of six blocks multiplied a block at a time give the bits of the column-by-column
    /// product, beside rows of three and one, and a column of another size; and the product is
    /// that of the dense symmetric matrix.
    #[test]
    fn a_product_by_blocks_of_six_is_the_product_by_columns() {
        let sizes = [6, 3, 6, 1, 6, 2, 6];
        let columns: Vec<Vec<usize>> = vec![
            vec![0],
            vec![0, 1],
            vec![0, 1, 2],
            vec![2, 3],
            vec![0, 1, 3, 4],
            vec![2, 4, 5],
            vec![1, 3, 4, 5, 6],
        ];
        let mut m = BlockSparse::new(block_starts(&sizes), &columns);
        for (k, v) in m.values.iter_mut().enumerate() {
            *v = ((k * 7919) % 1009) as f64 / 97.0 - 5.0;
        }
        let n = m.dim();
        let x: Vec<f64> = (0..n).map(|i| (i as f64 * 1.3).sin() * 1e3).collect();
        let mut by_blocks = vec![0.0; n];
        m.multiply(&x, &mut by_blocks);
        let mut by_columns = vec![0.0; n];
        for j in 0..m.num_blocks() {
            let entries = &m.entries[m.entry_ptr[j]..m.entry_ptr[j + 1]];
            m.add_column(j, &entries[..entries.len() - 1], &x, &mut by_columns);
        }
        assert_eq!(by_blocks, by_columns);
        let mut dense = nalgebra::DMatrix::<f64>::zeros(n, n);
        m.for_each_damped(Damping::None, |r, c, v| {
            dense[(r, c)] = v;
            dense[(c, r)] = v;
        });
        let expected = dense * nalgebra::DVector::from_vec(x);
        for (a, b) in by_blocks.iter().zip(expected.iter()) {
            assert!((a - b).abs() <= 1e-9 * (1.0 + b.abs()), "{a} against {b}");
        }
    }
}
