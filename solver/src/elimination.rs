//! Which blocks the Schur solvers eliminate.

use crate::error::SolveError;
use crate::options::Elimination;

/// Marks the blocks to eliminate: the user's variables (`block_of_var` maps them to blocks,
/// `usize::MAX` for fixed ones, which are skipped), or a greedy maximal independent set of the
/// block graph taken in order of fewest neighbours, then smallest size (Ceres' Schur ordering
/// idea; Li & Saad's independent-set orderings). `columns[j]` lists the row blocks i ≤ j of H's
/// upper triangle in block column j; `dim(b)` is block b's size.
pub(crate) fn elimination_set(
    block_of_var: &[usize],
    columns: &[Vec<usize>],
    dim: impl Fn(usize) -> usize,
    elimination: &Elimination,
) -> Result<Vec<bool>, SolveError> {
    let nb = columns.len();
    let mut eliminate = vec![false; nb];
    match elimination {
        Elimination::Variables(vars) => {
            for v in vars {
                let Some(&b) = block_of_var.get(v.0) else {
                    return Err(SolveError::LinearSolver(format!(
                        "variable {} marked for elimination does not exist",
                        v.0
                    )));
                };
                if b != usize::MAX {
                    eliminate[b] = true;
                }
            }
        }
        Elimination::Auto => {
            let mut degree = vec![0usize; nb];
            for (j, rows) in columns.iter().enumerate() {
                for &i in rows.iter().filter(|&&i| i != j) {
                    degree[j] += 1;
                    degree[i] += 1;
                }
            }
            let mut neighbours: Vec<Vec<usize>> =
                degree.iter().map(|&d| Vec::with_capacity(d)).collect();
            for (j, rows) in columns.iter().enumerate() {
                for &i in rows.iter().filter(|&&i| i != j) {
                    neighbours[j].push(i);
                    neighbours[i].push(j);
                }
            }
            let mut order: Vec<usize> = (0..nb).collect();
            order.sort_by_key(|&b| (degree[b], dim(b), b));
            let mut blocked = vec![false; nb];
            for b in order {
                if !blocked[b] {
                    eliminate[b] = true;
                    for &n in &neighbours[b] {
                        blocked[n] = true;
                    }
                }
            }
        }
    }
    Ok(eliminate)
}
