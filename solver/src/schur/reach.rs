//! How far apart the reduced system's unknowns lie in its graph: a lower bound on the diameter
//! of the graph whose nodes are S's block columns and whose edges are its off-diagonal blocks.
//!
//! A conjugate-gradient iteration multiplies by S once, so after k iterations a correction has
//! travelled at most k blocks through that graph (the Krylov space K_k(S, r) of a vector r is
//! made of S's first k powers). A solve that must make the ends of the graph agree, as the
//! camera system's long-wavelength bending does once the damping has fallen, takes at least the
//! graph's diameter in iterations (Saad, *Iterative Methods for Sparse Linear Systems*, 2nd ed.,
//! §6.1). The bound is the double sweep: the farthest node from node 0 by breadth-first search,
//! then the largest distance from that node (exact on trees and cycles, a lower bound elsewhere;
//! Magnien, Latapy & Habib, *Fast computation of empirically tight bounds for the diameter of
//! massive graphs*, 2009).

use crate::block::BlockSparse;
use crate::ordering::symmetric_adjacency;
use std::collections::VecDeque;

/// The double-sweep lower bound on the diameter of S's block graph (0 for a single block; the
/// component of block 0 when the graph is not connected).
pub(super) fn diameter_bound(s: &BlockSparse) -> usize {
    // usize indices always fit
    let Some((ptr, adj)) = symmetric_adjacency::<usize>(s) else {
        return 0;
    };
    let n = ptr.len() - 1;
    if n < 2 {
        return 0;
    }
    let mut dist = vec![usize::MAX; n];
    let mut queue = VecDeque::with_capacity(n);
    let (far, _) = sweep(&ptr, &adj, 0, &mut dist, &mut queue);
    dist.fill(usize::MAX);
    sweep(&ptr, &adj, far, &mut dist, &mut queue).1
}

/// Breadth-first search from `start`: the last node reached and its distance.
fn sweep(
    ptr: &[usize],
    adj: &[usize],
    start: usize,
    dist: &mut [usize],
    queue: &mut VecDeque<usize>,
) -> (usize, usize) {
    queue.clear();
    dist[start] = 0;
    queue.push_back(start);
    let mut last = start;
    while let Some(u) = queue.pop_front() {
        last = u;
        for &v in &adj[ptr[u]..ptr[u + 1]] {
            if dist[v] == usize::MAX {
                dist[v] = dist[u] + 1;
                queue.push_back(v);
            }
        }
    }
    (last, dist[last])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A matrix of 1 × 1 blocks whose upper triangle holds the pairs `edges` (i < j).
    fn pattern(n: usize, edges: &[(usize, usize)]) -> BlockSparse {
        let columns: Vec<Vec<usize>> = (0..n)
            .map(|j| {
                let mut rows: Vec<usize> = edges.iter().filter(|e| e.1 == j).map(|e| e.0).collect();
                rows.sort_unstable();
                rows.push(j);
                rows
            })
            .collect();
        BlockSparse::new((0..=n).collect(), &columns)
    }

    #[test]
    fn the_bound_is_exact_on_paths_cycles_and_stars() {
        let path: Vec<(usize, usize)> = (0..9).map(|i| (i, i + 1)).collect();
        assert_eq!(diameter_bound(&pattern(10, &path)), 9);
        let mut cycle = path.clone();
        cycle.push((0, 9));
        assert_eq!(diameter_bound(&pattern(10, &cycle)), 5);
        let star: Vec<(usize, usize)> = (1..10).map(|i| (0, i)).collect();
        assert_eq!(diameter_bound(&pattern(10, &star)), 2);
        assert_eq!(diameter_bound(&pattern(1, &[])), 0);
    }

    #[test]
    fn a_band_of_width_w_has_diameter_n_over_w() {
        // each node joined to the next 4: 40 nodes are 39 / 4 → 10 hops end to end
        let band: Vec<(usize, usize)> = (0..40)
            .flat_map(|i| (1..=4).map(move |k| (i, i + k)))
            .filter(|e| e.1 < 40)
            .collect();
        assert_eq!(diameter_bound(&pattern(40, &band)), 10);
    }
}
