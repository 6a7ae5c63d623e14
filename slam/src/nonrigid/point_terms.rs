//! Each data point's share of the warp field's normal equations, kept per point and gathered by
//! the entries and nodes that read it.
//!
//! A point bound to nodes k adds `s_k w_k s_l w_l ρ' GᵀG` to the 8 × 8 sum of each of its pairs
//! (k, l) and `s_k w_k ρ' Gᵀr` to each node's 8-vector (module `system`). The point's matrix
//! `M = ρ' GᵀG` (packed, 36 numbers) and vector `ρ' Gᵀr` are stored once with the pair and node
//! scales; an entry then sums `scale · M` over the points that list it, and a node its
//! `c · Gᵀr`, in the points' order. Nothing is scattered, so no accumulator is zeroed or added
//! up per thread, and the bits do not depend on the thread count (the sums' order is fixed by the
//! index, not by the schedule).

use super::graph::Binding;
use dynamap_residuals::deform::{NodeJacobian, MAX_NEIGHBOURS};
use rayon::prelude::*;

/// Node pairs (k ≤ l) of one binding.
pub(crate) const PAIRS: usize = MAX_NEIGHBOURS * (MAX_NEIGHBOURS + 1) / 2;
/// Entries of a packed symmetric 8 × 8 matrix.
pub(crate) const PACKED: usize = 36;
/// No entry.
pub(crate) const NONE: u32 = u32::MAX;

/// Index of (a, b), a ≤ b < 8, in a packed symmetric 8 × 8 matrix ([`PointTerms::m`]).
#[inline(always)]
pub(crate) const fn packed(a: usize, b: usize) -> usize {
    b * (b + 1) / 2 + a
}

/// Binding slots (a, b), a ≤ b, in the order of a point's ten pair entries.
pub(crate) const SLOT_PAIRS: [(usize, usize); PAIRS] = {
    let mut out = [(0, 0); PAIRS];
    let mut k = 0;
    let mut b = 0;
    while b < MAX_NEIGHBOURS {
        let mut a = 0;
        while a <= b {
            out[k] = (a, b);
            k += 1;
            a += 1;
        }
        b += 1;
    }
    out
};

/// One point's reweighted Gauss-Newton terms in the blend's coordinates.
#[derive(Clone, Copy)]
pub(crate) struct PointTerms {
    /// `Σ ρ' GᵀG` over the point's rows, packed ([`packed`]).
    pub m: [f64; PACKED],
    /// `Σ ρ' Gᵀr` over the point's rows.
    pub g: [f64; 8],
    /// The scale of `m` in each pair's sum ([`SLOT_PAIRS`] order; 0: the pair takes nothing).
    pub scales: [f64; PAIRS],
    /// The scale of `g` in each bound node's sum, `s_k w_k` (0: nothing).
    pub node_scales: [f64; MAX_NEIGHBOURS],
    /// ½ρ of the point's terms.
    pub cost: f64,
}

impl PointTerms {
    /// A point that adds nothing.
    pub const EMPTY: PointTerms = PointTerms {
        m: [0.0; PACKED],
        g: [0.0; 8],
        scales: [0.0; PAIRS],
        node_scales: [0.0; MAX_NEIGHBOURS],
        cost: 0.0,
    };
}

/// Which points add to which entry and node: `entry_terms[entry_ptr[e]..entry_ptr[e + 1]]` lists
/// `PAIRS i + p` for pair p of point i, `node_terms[node_ptr[k]..node_ptr[k + 1]]` lists
/// `MAX_NEIGHBOURS i + a` for binding slot a of point i, each in the points' order.
#[derive(Default)]
pub(crate) struct TermIndex {
    /// The structure's generation and the points' pair entries it was built for. Each node has
    /// its diagonal entry, so the same entries mean the same bound nodes too.
    generation: u64,
    slots: Vec<[u32; PAIRS]>,
    entry_ptr: Vec<u32>,
    entry_terms: Vec<u32>,
    node_ptr: Vec<u32>,
    node_terms: Vec<u32>,
}

impl TermIndex {
    /// Indexes the points' pair entries (`slots`, [`NONE`] for none) and bound nodes, for a system
    /// of `entries` entries and `nodes` nodes, of structure `generation`; kept as it is when
    /// built for the same.
    pub fn build(
        &mut self,
        slots: &[[u32; PAIRS]],
        bindings: &[Binding],
        (entries, nodes): (usize, usize),
        generation: u64,
    ) {
        if self.generation == generation && self.slots == slots && !self.entry_ptr.is_empty() {
            return;
        }
        self.generation = generation;
        self.slots.clear();
        self.slots.extend_from_slice(slots);
        let pairs = slots
            .iter()
            .enumerate()
            .flat_map(|(i, s)| s.iter().enumerate().map(move |(p, &e)| (e, i * PAIRS + p)));
        counting_sort(pairs, entries, &mut self.entry_ptr, &mut self.entry_terms);
        let bound = bindings.iter().enumerate().flat_map(|(i, b)| {
            b.nodes[..b.count]
                .iter()
                .enumerate()
                .map(move |(a, &k)| (k, i * MAX_NEIGHBOURS + a))
        });
        counting_sort(bound, nodes, &mut self.node_ptr, &mut self.node_terms);
    }

    /// `Σ scale · M` of the points that add to entry `e`, packed.
    pub fn entry_sum(&self, e: usize, points: &[PointTerms]) -> [f64; PACKED] {
        let listed = (&self.entry_ptr[..], &self.entry_terms[..]);
        gather(listed, e, PAIRS, points, |t, p| (t.scales[p], &t.m))
    }

    /// `Σ c · Gᵀr` of the points bound to node `k`.
    pub fn node_sum(&self, k: usize, points: &[PointTerms]) -> [f64; 8] {
        let listed = (&self.node_ptr[..], &self.node_terms[..]);
        gather(listed, k, MAX_NEIGHBOURS, points, |t, a| {
            (t.node_scales[a], &t.g)
        })
    }
}

/// `Σ scale · values` over the points key `k` lists (`terms[ptr[k]..ptr[k + 1]]`, each
/// `per i + s`), `pick` reading point i's scale s and values; a zero scale adds nothing.
fn gather<const N: usize>(
    (ptr, terms): (&[u32], &[u32]),
    k: usize,
    per: usize,
    points: &[PointTerms],
    pick: impl Fn(&PointTerms, usize) -> (f64, &[f64; N]),
) -> [f64; N] {
    let mut sum = [0.0; N];
    for &t in &terms[ptr[k] as usize..ptr[k + 1] as usize] {
        let (scale, values) = pick(&points[t as usize / per], t as usize % per);
        if scale != 0.0 {
            for (o, v) in sum.iter_mut().zip(values) {
                *o += scale * v;
            }
        }
    }
    sum
}

/// `P_iᵀ A P_j` (6 × 6, column-major into `out`) for a symmetric 8 × 8 `A` given packed and node
/// Jacobians of the form `P = [[R, 0], [D, R]]` (R from the real part, D from the dual part, each
/// 4 × 3; [`right_perturbation`](dynamap_residuals::deform::right_perturbation)): with
/// `X = A P_j`, `H = [[R_iᵀX₀ + D_iᵀX₁], [R_iᵀX₁]]` over X's upper and lower four rows, which
/// skips the products with P's zero block (504 multiplications instead of 672).
pub(crate) fn project(pi: &NodeJacobian, a: &[f64; PACKED], pj: &NodeJacobian, out: &mut [f64]) {
    let mut full = [[0.0; 8]; 8];
    for b in 0..8 {
        for x in 0..=b {
            let v = a[packed(x, b)];
            full[x][b] = v;
            full[b][x] = v;
        }
    }
    // X = A P_j: columns 0–2 take R_j through A's left half and D_j through its right, 3–5 R_j
    // through its right
    let mut x = [[0.0; 6]; 8];
    for (row, xr) in full.iter().zip(x.iter_mut()) {
        for c in 0..3 {
            let (mut rot, mut tr) = (0.0, 0.0);
            for k in 0..4 {
                rot += row[k] * pj[(k, c)] + row[4 + k] * pj[(4 + k, c)];
                tr += row[4 + k] * pj[(4 + k, 3 + c)];
            }
            xr[c] = rot;
            xr[3 + c] = tr;
        }
    }
    // H = P_iᵀ X: rows 0–2 R_iᵀX₀ + D_iᵀX₁, rows 3–5 R_iᵀX₁
    for m in 0..6 {
        for c in 0..3 {
            let (mut rot, mut tr) = (0.0, 0.0);
            for k in 0..4 {
                rot += pi[(k, c)] * x[k][m] + pi[(4 + k, c)] * x[4 + k][m];
                tr += pi[(4 + k, 3 + c)] * x[4 + k][m];
            }
            out[m * 6 + c] = rot;
            out[m * 6 + 3 + c] = tr;
        }
    }
}

/// Groups `items` (key, value) by key into `ptr`/`values` (a counting sort; keys of [`NONE`] are
/// left out), values of a key in their order.
pub(crate) fn counting_sort(
    items: impl Iterator<Item = (u32, usize)> + Clone,
    keys: usize,
    ptr: &mut Vec<u32>,
    values: &mut Vec<u32>,
) {
    ptr.clear();
    ptr.resize(keys + 1, 0);
    for (k, _) in items.clone().filter(|&(k, _)| k != NONE) {
        ptr[k as usize + 1] += 1;
    }
    for k in 0..keys {
        ptr[k + 1] += ptr[k];
    }
    values.resize(ptr[keys] as usize, 0);
    // each key's cursor runs from its start; afterwards it stands at the next one's
    for (k, v) in items.filter(|&(k, _)| k != NONE) {
        values[ptr[k as usize] as usize] = v as u32;
        ptr[k as usize] += 1;
    }
    for k in (1..=keys).rev() {
        ptr[k] = ptr[k - 1];
    }
    ptr[0] = 0;
}

/// Fills `out` with every point's terms, computed by `term` in parallel.
pub(crate) fn fill_terms(
    out: &mut Vec<PointTerms>,
    n: usize,
    term: impl Fn(usize, &mut PointTerms) + Sync,
) {
    out.resize(n, PointTerms::EMPTY);
    out.par_iter_mut()
        .enumerate()
        .with_min_len(256)
        .for_each(|(i, t)| term(i, t));
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynamap_residuals::deform::{dual_quaternion, right_perturbation};
    use nalgebra::{Isometry3, SMatrix, Vector3};

    #[test]
    fn a_pair_projected_past_the_zero_block_is_the_full_product() {
        let jac = |t: [f64; 3], r: [f64; 3]| {
            let m = Isometry3::new(Vector3::from(t), Vector3::from(r));
            right_perturbation(&dual_quaternion(&m))
        };
        let (pi, pj) = (
            jac([0.3, -1.2, 0.5], [0.4, 0.1, -0.9]),
            jac([-2.0, 0.7, 0.1], [-1.1, 0.6, 0.2]),
        );
        let mut packed = [0.0; PACKED];
        for (k, v) in packed.iter_mut().enumerate() {
            *v = ((k * 37) % 11) as f64 - 4.5;
        }
        let mut a = SMatrix::<f64, 8, 8>::zeros();
        for b in 0..8 {
            for x in 0..=b {
                a[(x, b)] = packed[super::packed(x, b)];
                a[(b, x)] = packed[super::packed(x, b)];
            }
        }
        // the zero block the projection skips
        assert_eq!(pi.fixed_view::<4, 3>(0, 3).norm(), 0.0);
        let want = pi.transpose() * a * pj;
        let mut got = [0.0; 36];
        project(&pi, &packed, &pj, &mut got);
        for (g, w) in got.iter().zip(want.as_slice()) {
            assert!((g - w).abs() <= 1e-12 * want.norm(), "{g} against {w}");
        }
    }

    fn binding(nodes: &[u32]) -> Binding {
        let mut b = Binding {
            nodes: [0; MAX_NEIGHBOURS],
            weights: [0.0; MAX_NEIGHBOURS],
            count: nodes.len(),
        };
        b.nodes[..nodes.len()].copy_from_slice(nodes);
        b
    }

    #[test]
    fn gathered_sums_are_the_scattered_sums() {
        // three points over four nodes, the entries numbered by hand; a scatter in point order
        // gives the reference
        let bindings = [binding(&[0, 1]), binding(&[1, 2, 3]), binding(&[3])];
        let entries = 10;
        let entry_of = |k: u32, l: u32| k.min(l) * 4 + k.max(l) - k.min(l) * (k.min(l) + 1) / 2;
        let slots: Vec<[u32; PAIRS]> = bindings
            .iter()
            .map(|b| {
                let mut s = [NONE; PAIRS];
                for (slot, &(x, y)) in s.iter_mut().zip(&SLOT_PAIRS) {
                    if y < b.count {
                        *slot = entry_of(b.nodes[x], b.nodes[y]);
                    }
                }
                s
            })
            .collect();
        let mut points = Vec::new();
        fill_terms(&mut points, 3, |i, t| {
            *t = PointTerms::EMPTY;
            for (x, m) in t.m.iter_mut().enumerate() {
                *m = (i * 100 + x) as f64;
            }
            for (x, g) in t.g.iter_mut().enumerate() {
                *g = (i * 10 + x) as f64 + 0.5;
            }
            for (p, s) in t.scales.iter_mut().enumerate() {
                *s = if slots[i][p] == NONE {
                    0.0
                } else {
                    1.0 + p as f64
                };
            }
            for a in 0..bindings[i].count {
                t.node_scales[a] = 0.25 * (a + 1) as f64;
            }
        });
        let mut index = TermIndex::default();
        index.build(&slots, &bindings, (entries, 4), 1);
        let mut scattered = vec![[0.0; PACKED]; entries];
        let mut nodes = vec![[0.0; 8]; 4];
        for (i, t) in points.iter().enumerate() {
            for (p, &e) in slots[i].iter().enumerate().filter(|(_, &e)| e != NONE) {
                for (o, v) in scattered[e as usize].iter_mut().zip(&t.m) {
                    *o += t.scales[p] * v;
                }
            }
            for (a, &k) in bindings[i].nodes[..bindings[i].count].iter().enumerate() {
                for (o, v) in nodes[k as usize].iter_mut().zip(&t.g) {
                    *o += t.node_scales[a] * v;
                }
            }
        }
        for (e, want) in scattered.iter().enumerate() {
            assert_eq!(&index.entry_sum(e, &points), want, "entry {e}");
        }
        for (k, want) in nodes.iter().enumerate() {
            assert_eq!(&index.node_sum(k, &points), want, "node {k}");
        }
        // entry (1, 1) takes from points 0 (m₀ = 0) and 1 (m₀ = 100, scale 1); (0, 3) from none
        assert_eq!(index.entry_sum(entry_of(1, 1) as usize, &points)[0], 100.0);
        assert_eq!(
            index.entry_sum(entry_of(0, 3) as usize, &points),
            [0.0; PACKED]
        );
    }
}
