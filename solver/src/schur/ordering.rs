//! Which blocks the Schur solvers eliminate.

use crate::error::SolveError;
use crate::normal::NormalEquations;
use crate::options::Elimination;
use crate::problem::Problem;

/// Marks the H blocks to eliminate: the user's variables, or a greedy maximal independent set of
/// the block graph taken in order of fewest neighbours, then smallest size (Ceres' Schur ordering
/// idea; Li & Saad's independent-set orderings).
pub(crate) fn elimination_set(
    problem: &Problem,
    ne: &NormalEquations,
    elimination: &Elimination,
) -> Result<Vec<bool>, SolveError> {
    let h = ne.h();
    let nb = h.num_blocks();
    let mut eliminate = vec![false; nb];
    match elimination {
        Elimination::Variables(vars) => {
            for v in vars {
                if v.0 >= problem.variables.len() {
                    return Err(SolveError::LinearSolver(format!(
                        "variable {} marked for elimination does not exist",
                        v.0
                    )));
                }
                let b = ne.block_of_var()[v.0];
                if b != usize::MAX {
                    eliminate[b] = true;
                }
            }
        }
        Elimination::Auto => {
            let mut degree = vec![0usize; nb];
            for j in 0..nb {
                for e in &h.entries[h.entry_ptr[j]..h.entry_ptr[j + 1]] {
                    if e.row_block != j {
                        degree[j] += 1;
                        degree[e.row_block] += 1;
                    }
                }
            }
            let mut neighbours: Vec<Vec<usize>> =
                degree.iter().map(|&d| Vec::with_capacity(d)).collect();
            for j in 0..nb {
                for e in &h.entries[h.entry_ptr[j]..h.entry_ptr[j + 1]] {
                    if e.row_block != j {
                        neighbours[j].push(e.row_block);
                        neighbours[e.row_block].push(j);
                    }
                }
            }
            let mut order: Vec<usize> = (0..nb).collect();
            order.sort_by_key(|&b| (degree[b], h.block_dim(b), b));
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
