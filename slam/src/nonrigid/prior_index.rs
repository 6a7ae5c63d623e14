//! Where the regularisers' blocks go in the warp field's system: each as-rigid-as-possible edge's
//! entries (i, i), (j, j) and (min, max), each stay prior's (k, k), and each entry's blocks in
//! the priors' order.
//!
//! They depend on the edges and the block structure alone, so they are found once and kept
//! while neither changes (a frame's linearisations share them), instead of three binary
//! searches per edge and a counting sort at every linearisation.

use super::point_terms::{counting_sort, NONE};
use dynamap_solver::BlockSystem;
use nalgebra::Vector3;

/// The priors' entries and each entry's blocks, for one structure and one set of priors.
#[derive(Default)]
pub(crate) struct PriorIndex {
    /// What they were found for: the structure's generation, the edges' (i, j) and the number
    /// of stay priors.
    generation: u64,
    pairs: Vec<(u32, u32)>,
    stays: usize,
    /// Entry e's blocks `3 x + s` (block s of prior x): `slots[ptr[e]..ptr[e + 1]]`.
    ptr: Vec<u32>,
    slots: Vec<u32>,
}

impl PriorIndex {
    /// Finds the entries of `edges` (i, j, ·, ·) and of `stays` stay priors on nodes 0.. in
    /// `system` (of structure `generation`), unless they were found for the same ones.
    pub fn refresh(
        &mut self,
        edges: &[(u32, u32, Vector3<f64>, f64)],
        stays: usize,
        system: &BlockSystem,
        generation: u64,
    ) {
        let same = self.generation == generation
            && self.stays == stays
            && self.pairs.len() == edges.len()
            && self.pairs.iter().zip(edges).all(|(p, e)| *p == (e.0, e.1));
        if same && !self.ptr.is_empty() {
            return;
        }
        let entry = |i: usize, j: usize| {
            system
                .entry(i, j)
                .expect("regulariser pairs are in the structure") as u32
        };
        self.generation = generation;
        self.stays = stays;
        self.pairs.clear();
        self.pairs.extend(edges.iter().map(|e| (e.0, e.1)));
        // prior x's entries (unused NONE): an edge's blocks 0, 1, 2, a stay prior's block 0
        let edge_entries = self.pairs.iter().map(|&(i, j)| {
            let (i, j) = (i as usize, j as usize);
            [entry(i, i), entry(j, j), entry(i.min(j), i.max(j))]
        });
        let stay_entries = (0..stays).map(|k| [entry(k, k), NONE, NONE]);
        let entries: Vec<[u32; 3]> = edge_entries.chain(stay_entries).collect();
        let blocks = entries
            .iter()
            .enumerate()
            .flat_map(|(x, es)| es.iter().enumerate().map(move |(s, &e)| (e, 3 * x + s)));
        counting_sort(blocks, system.num_entries(), &mut self.ptr, &mut self.slots);
    }

    /// Entry e's regulariser blocks, each `3 x + s` for block s of prior x, in the priors' order.
    pub fn blocks_of(&self, e: usize) -> &[u32] {
        &self.slots[self.ptr[e] as usize..self.ptr[e + 1] as usize]
    }
}
