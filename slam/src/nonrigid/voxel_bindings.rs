//! Each canonical voxel's K nearest deformation nodes and their weights, kept across frames for the
//! warped fusion ([`TsdfVolume::integrate_warped`](crate::tsdf::TsdfVolume::integrate_warped)).
//!
//! Nodes never move in the canonical frame and keep their indices as the graph grows, so a voxel's
//! binding changes only when a node is added near it. DynamicFusion (Newcombe et al., CVPR 2015,
//! sec. 3.4) keeps the same K-nearest-node field over its volume for this reason. Here a block's
//! bindings are computed when the block first enters the band the frame updates, and again only
//! when a node has been added within the block's *candidate radius* `d_K + 2h` (d_K: the block
//! centre's K-th nearest node, h: the block's half-diagonal): a node farther than that from the
//! centre is farther from every voxel of the block than the voxel's K-th nearest node, so it cannot
//! enter any voxel's binding. Blocks the band leaves are dropped, so memory follows the band
//! (16 bytes of node indices and 16 of weights per voxel: 16 KiB per 8³ block).

use super::cell_nearest::{candidate_radius, candidates, insert_nearer, Candidates};
use super::graph::{Binding, DeformationGraph};
use crate::tsdf::VoxelWarp;
use dynamap_residuals::deform::{transform_point, MAX_NEIGHBOURS};
use nalgebra::Vector3;
use rayon::prelude::*;
use rustc_hash::FxHashMap;

/// No node.
const NONE: u32 = u32::MAX;

/// One voxel's nodes (unused slots [`NONE`]; all [`NONE`]: out of every node's reach) and their
/// normalised weights.
#[derive(Clone, Copy, Debug, PartialEq)]
struct VoxelBinding {
    nodes: [u32; MAX_NEIGHBOURS],
    weights: [f32; MAX_NEIGHBOURS],
}

const UNBOUND: VoxelBinding = VoxelBinding {
    nodes: [NONE; MAX_NEIGHBOURS],
    weights: [0.0; MAX_NEIGHBOURS],
};

/// The bindings of one block's voxels, in the volume's voxel order (x fastest).
struct BlockBindings {
    /// Nodes in the graph when the bindings were computed.
    nodes_seen: usize,
    /// K when they were computed (less than the graph's setting while it had fewer nodes).
    neighbours: usize,
    /// Block centre and candidate radius `d_K + 2h`.
    centre: Vector3<f64>,
    radius: f64,
    /// The reach ([`reach`]) they were computed with.
    reach: f64,
    /// Empty when no voxel is within reach of a node.
    voxels: Vec<VoxelBinding>,
}

/// The block geometry the cache is laid out for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct BlockGeometry {
    /// Voxel edge, metres.
    pub voxel: f64,
    /// Voxels along a block edge.
    pub block: i32,
}

impl BlockGeometry {
    /// The centre of voxel (0, 0, 0) of block `coord`.
    fn origin(&self, coord: [i32; 3]) -> Vector3<f64> {
        Vector3::new(coord[0] as f64, coord[1] as f64, coord[2] as f64)
            * (self.block as f64 * self.voxel)
    }

    fn centre(&self, coord: [i32; 3]) -> Vector3<f64> {
        self.origin(coord) + Vector3::repeat(0.5 * self.voxel * (self.block - 1) as f64)
    }

    /// The centre of voxel (x, y, z) of the block whose first voxel's centre is `origin`.
    fn voxel_at(&self, origin: &Vector3<f64>, [x, y, z]: [usize; 3]) -> Vector3<f64> {
        origin + Vector3::new(x as f64, y as f64, z as f64) * self.voxel
    }

    fn half_diagonal(&self) -> f64 {
        0.5 * self.voxel * self.block as f64 * 3f64.sqrt()
    }

    fn voxels(&self) -> usize {
        (self.block * self.block * self.block) as usize
    }
}

/// The cache: bindings of the blocks the last frame updated.
#[derive(Default)]
pub(crate) struct VoxelBindings {
    geometry: Option<BlockGeometry>,
    slots: FxHashMap<[i32; 3], usize>,
    blocks: Vec<BlockBindings>,
    /// Blocks whose bindings were (re)computed by the last update.
    pub computed: usize,
}

impl VoxelBindings {
    /// Forgets every binding (a new graph).
    pub fn clear(&mut self) {
        self.slots.clear();
        self.blocks.clear();
    }

    /// Readies the bindings of the blocks `coords` (each once) for `graph`: kept where no node was
    /// added within a block's candidate radius since they were computed, computed otherwise.
    /// Blocks not in `coords` are dropped.
    pub fn update(&mut self, graph: &DeformationGraph, coords: &[[i32; 3]], geo: BlockGeometry) {
        if self.geometry != Some(geo) {
            self.clear();
            self.geometry = Some(geo);
        }
        let mut old = std::mem::take(&mut self.blocks);
        let mut taken: Vec<Option<BlockBindings>> = coords
            .iter()
            .map(|c| self.slots.get(c).map(|&s| std::mem::take(&mut old[s])))
            .map(|b| b.filter(|b| b.nodes_seen > 0))
            .collect();
        let reach = reach(graph);
        let updated: Vec<(BlockBindings, bool)> = coords
            .par_iter()
            .zip(taken.par_iter_mut())
            .map(|(&c, kept)| match kept.take() {
                Some(b) if still_valid(&b, graph) => (
                    BlockBindings {
                        nodes_seen: graph.nodes.len(),
                        ..b
                    },
                    false,
                ),
                Some(b) if can_rebind(&b, graph, reach) => (rebind_block(graph, geo, c, b), true),
                _ => (bind_block(graph, geo, c, reach), true),
            })
            .collect();
        self.computed = updated.iter().filter(|u| u.1).count();
        self.blocks = updated.into_iter().map(|u| u.0).collect();
        self.slots.clear();
        self.slots
            .extend(coords.iter().enumerate().map(|(s, &c)| (c, s)));
    }
}

impl Default for BlockBindings {
    fn default() -> Self {
        Self {
            nodes_seen: 0,
            neighbours: 0,
            centre: Vector3::zeros(),
            radius: 0.0,
            reach: 0.0,
            voxels: Vec::new(),
        }
    }
}

/// Voxels farther than this from every node are not warped: two node radii.
fn reach(graph: &DeformationGraph) -> f64 {
    2.0 * graph.nodes.iter().map(|n| n.radius).fold(0.0, f64::max)
}

/// Whether `b` still holds for `graph`: K unchanged, no node removed (a graph that shrank is
/// another graph) and no node added within its radius.
fn still_valid(b: &BlockBindings, graph: &DeformationGraph) -> bool {
    let r2 = b.radius * b.radius;
    b.neighbours == graph.neighbours()
        && b.nodes_seen <= graph.nodes.len()
        && graph.nodes[b.nodes_seen..]
            .iter()
            .all(|n| (n.position - b.centre).norm_squared() > r2)
}

/// Computes the bindings of block `coord`: the candidates are the nodes within `d_K + 2h` of its
/// centre, narrowed for each of its sub-blocks ([`SPLIT`] along an edge) to those within
/// `d_K + 2h` of the sub-block's centre, and each voxel takes its K nearest among its sub-block's.
fn bind_block(
    graph: &DeformationGraph,
    geo: BlockGeometry,
    coord: [i32; 3],
    reach: f64,
) -> BlockBindings {
    let centre = geo.centre(coord);
    let k = graph.neighbours();
    let mut out = BlockBindings {
        nodes_seen: graph.nodes.len(),
        neighbours: k,
        centre,
        radius: f64::INFINITY,
        reach,
        voxels: Vec::new(),
    };
    let Some(candidates) = candidates(graph, &centre, geo.half_diagonal()) else {
        return out;
    };
    out.radius = candidates.radius;
    if candidates.nearest > reach + geo.half_diagonal() {
        return out;
    }
    let (origin, b) = (geo.origin(coord), geo.block as usize);
    let s = match b % SPLIT {
        0 => b / SPLIT,
        _ => b,
    };
    // a sub-block's voxel centres lie within half its diagonal less half a voxel's of its centre
    let h = 0.5 * geo.voxel * s.saturating_sub(1) as f64 * 3f64.sqrt();
    let mut sub = Candidates::default();
    out.voxels = vec![UNBOUND; geo.voxels()];
    let at = |x: usize, y: usize, z: usize| geo.voxel_at(&origin, [x, y, z]);
    for (sx, sy, sz) in cube(b / s).map(|(x, y, z)| (x * s, y * s, z * s)) {
        let sub_centre = at(sx, sy, sz) + Vector3::repeat(0.5 * geo.voxel * (s - 1) as f64);
        candidates.narrow(&sub_centre, h, k, &mut sub);
        for (x, y, z) in cube(s).map(|(x, y, z)| (sx + x, sy + y, sz + z)) {
            out.voxels[x + b * (y + b * z)] = bind_voxel(graph, &sub, &at(x, y, z), k, reach);
        }
    }
    out
}

/// Whether `b`'s bindings can be brought up to `graph` by [`rebind_block`]: the same K and
/// reach, no node removed, and some voxel bound.
fn can_rebind(b: &BlockBindings, graph: &DeformationGraph, reach: f64) -> bool {
    b.neighbours == graph.neighbours()
        && b.nodes_seen <= graph.nodes.len()
        && b.reach == reach
        && !b.voxels.is_empty()
}

/// [`bind_block`] for a block bound before nodes were added: only a node added within the old
/// candidate radius can be nearer a voxel than its K-th nearest, so each bound voxel's new K
/// nearest are its old ones and those nodes merged (the same insertion as
/// [`Candidates::nearest`]), and only voxels whose K nearest changed are weighed again. Unbound
/// voxels search the block's candidates afresh.
fn rebind_block(
    graph: &DeformationGraph,
    geo: BlockGeometry,
    coord: [i32; 3],
    mut b: BlockBindings,
) -> BlockBindings {
    let r2 = b.radius * b.radius;
    let added: Vec<(u32, Vector3<f64>)> = (b.nodes_seen..graph.nodes.len())
        .map(|i| (i as u32, graph.nodes[i].position))
        .filter(|(_, q)| (q - b.centre).norm_squared() <= r2)
        .collect();
    let Some((radius, _)) = candidate_radius(graph, &b.centre, geo.half_diagonal()) else {
        return bind_block(graph, geo, coord, b.reach);
    };
    let (k, n) = (b.neighbours.clamp(1, MAX_NEIGHBOURS), geo.block as usize);
    let origin = geo.origin(coord);
    let reach2 = b.reach * b.reach;
    let mut all: Option<Candidates> = None;
    for (i, v) in b.voxels.iter_mut().enumerate() {
        let p = geo.voxel_at(&origin, [i % n, (i / n) % n, i / (n * n)]);
        if v.nodes[0] == NONE {
            // every old node was beyond the reach: only an added one can bind it
            if added.iter().any(|(_, q)| (q - p).norm_squared() <= reach2) {
                let all = all.get_or_insert_with(|| {
                    candidates(graph, &b.centre, geo.half_diagonal()).expect("a node is near")
                });
                *v = bind_voxel(graph, all, &p, k, b.reach);
            }
            continue;
        }
        let mut best = [(0u32, f64::INFINITY); MAX_NEIGHBOURS];
        for (slot, &node) in best.iter_mut().zip(&v.nodes[..k]) {
            *slot = (
                node,
                (graph.nodes[node as usize].position - p).norm_squared(),
            );
        }
        let mut changed = false;
        for (node, q) in &added {
            changed |= insert_nearer(&mut best[..k], *node, (q - p).norm_squared());
        }
        if changed {
            *v = weighed(graph, &best[..k]);
        }
    }
    b.radius = radius;
    b.nodes_seen = graph.nodes.len();
    b
}

/// Sub-blocks along a block's edge (when it divides the edge), each with its own candidates.
const SPLIT: usize = 2;

/// The points (x, y, z) of an n × n × n grid, x fastest.
fn cube(n: usize) -> impl Iterator<Item = (usize, usize, usize)> {
    (0..n * n * n).map(move |i| (i % n, (i / n) % n, i / (n * n)))
}

/// The K nearest of `candidates` to `p`, by insertion into a short sorted list, as a binding;
/// [`UNBOUND`] when the nearest is beyond `reach`.
fn bind_voxel(
    graph: &DeformationGraph,
    candidates: &Candidates,
    p: &Vector3<f64>,
    k: usize,
    reach: f64,
) -> VoxelBinding {
    let best = candidates.nearest(p, k);
    if best[0].1.sqrt() > reach {
        return UNBOUND;
    }
    weighed(graph, &best[..k.clamp(1, MAX_NEIGHBOURS)])
}

/// The binding of a voxel whose K nearest nodes are `nearest` (node, squared distance).
fn weighed(graph: &DeformationGraph, nearest: &[(u32, f64)]) -> VoxelBinding {
    let b = graph.binding(nearest);
    let mut out = UNBOUND;
    for s in 0..b.count {
        out.nodes[s] = b.nodes[s];
        out.weights[s] = b.weights[s] as f32;
    }
    out
}

/// The graph's warp through the cached bindings, as a [`VoxelWarp`]. The scratch is the block's
/// slot in the cache.
pub(crate) struct CachedWarp<'a> {
    pub graph: &'a DeformationGraph,
    pub bindings: &'a VoxelBindings,
}

impl VoxelWarp for CachedWarp<'_> {
    type Scratch = usize;

    fn prepare(&self, block: [i32; 3], slot: &mut usize) -> bool {
        match self.bindings.slots.get(&block) {
            Some(&s) if !self.bindings.blocks[s].voxels.is_empty() => {
                *slot = s;
                true
            }
            _ => false,
        }
    }

    fn warp(&self, voxel: usize, p: &Vector3<f64>, slot: &usize) -> Option<Vector3<f64>> {
        let v = &self.bindings.blocks[*slot].voxels[voxel];
        if v.nodes[0] == NONE {
            return None;
        }
        let mut b = Binding {
            nodes: [0; MAX_NEIGHBOURS],
            weights: [0.0; MAX_NEIGHBOURS],
            count: 0,
        };
        for (s, (&n, &w)) in v.nodes.iter().zip(&v.weights).enumerate() {
            if n == NONE {
                break;
            }
            b.nodes[s] = n;
            b.weights[s] = w as f64;
            b.count = s + 1;
        }
        Some(transform_point(&self.graph.blend(&b), p))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nonrigid::GraphParams;

    /// A 1 cm grid over the square [x0, x1] × [0, 0.4] of the plane z = 0.3, each point moved by
    /// up to 1 mm (so that no two nodes are equally far from a voxel).
    fn plane(x0: f64, x1: f64) -> Vec<Vector3<f64>> {
        let steps = ((x1 - x0) / 0.01).round() as usize;
        (0..=steps)
            .flat_map(|i| (0..=40).map(move |j| (i, j)))
            .map(|(i, j)| {
                let (a, b) = (i as f64 * 0.01 + x0, j as f64 * 0.01);
                let jitter = Vector3::new((37.0 * a + 11.0 * b).sin(), (53.0 * b).cos(), 0.0);
                Vector3::new(a, b, 0.3) + 1e-3 * jitter
            })
            .collect()
    }

    /// Every cached voxel of `cache` is bound as [`DeformationGraph::bind`] binds it, or unbound
    /// exactly when its nearest node is beyond the reach.
    fn assert_matches_fresh_bindings(cache: &VoxelBindings, graph: &DeformationGraph) {
        let geo = cache.geometry.unwrap();
        let reach = reach(graph);
        let mut bound = 0;
        for (&coord, &slot) in &cache.slots {
            let block = &cache.blocks[slot];
            for (i, v) in block.voxels.iter().enumerate() {
                let b = geo.block as usize;
                let (x, y, z) = (i % b, (i / b) % b, i / (b * b));
                let p = geo.origin(coord) + Vector3::new(x as f64, y as f64, z as f64) * geo.voxel;
                let fresh = graph.bind(&p);
                let nearest = (graph.nodes[fresh.nodes[0] as usize].position - p).norm();
                if nearest > reach {
                    assert_eq!(v.nodes[0], NONE, "{coord:?} voxel {i}");
                    continue;
                }
                bound += 1;
                for s in 0..fresh.count {
                    assert_eq!(v.nodes[s], fresh.nodes[s], "{coord:?} voxel {i}");
                    assert!((v.weights[s] as f64 - fresh.weights[s]).abs() < 1e-6);
                }
            }
        }
        assert!(bound > 1000, "{bound} voxels bound");
    }

    /// A graph over the plane of [`plane`] from x = 0 to 0.4 (nodes 5 cm apart) and 8³ blocks of
    /// 1 cm voxels.
    fn plane_graph() -> (DeformationGraph, BlockGeometry) {
        let params = GraphParams {
            spacing: 0.05,
            ..GraphParams::default()
        };
        let graph = DeformationGraph::sample(&plane(0.0, 0.4), params).unwrap();
        let geo = BlockGeometry {
            voxel: 0.01,
            block: 8,
        };
        (graph, geo)
    }

    /// The cache holds the bindings a fresh K-nearest search gives, keeps them while no node is
    /// added, recomputes only the blocks a new node can reach, and drops blocks the band left.
    #[test]
    fn cached_bindings_are_the_fresh_ones_across_graph_growth() {
        let (mut graph, geo) = plane_graph();
        let coords: Vec<[i32; 3]> = (0..5)
            .flat_map(|x| (0..5).map(move |y| [x, y, 3]))
            .collect();
        let mut cache = VoxelBindings::default();
        cache.update(&graph, &coords, geo);
        assert_eq!(cache.computed, coords.len());
        assert_matches_fresh_bindings(&cache, &graph);
        cache.update(&graph, &coords, geo);
        assert_eq!(cache.computed, 0);
        // new surface beyond x = 0.4: nodes there reach the blocks at x = 4 (and 3), not x = 0
        assert!(graph.extend(&plane(0.4, 0.6)) > 0);
        let grown: Vec<[i32; 3]> = coords.iter().copied().chain([[6, 2, 3]]).collect();
        cache.update(&graph, &grown, geo);
        assert!(
            cache.computed > 1 && cache.computed < 15,
            "{}",
            cache.computed
        );
        assert_matches_fresh_bindings(&cache, &graph);
        cache.update(&graph, &grown[..3], geo);
        assert_eq!((cache.computed, cache.blocks.len()), (0, 3));
    }

    /// A block bound before nodes were added, brought up to the grown graph by merging the
    /// added nodes, holds the bindings a fresh binding of the block gives, bit for bit, the
    /// voxels that only an added node reaches included.
    #[test]
    fn a_block_rebound_after_growth_is_the_block_bound_afresh() {
        let (mut graph, geo) = plane_graph();
        let coords = [[4, 2, 3], [5, 2, 3], [3, 1, 3]];
        let before: Vec<BlockBindings> = coords
            .iter()
            .map(|&c| bind_block(&graph, geo, c, reach(&graph)))
            .collect();
        let unbound = |b: &BlockBindings| b.voxels.iter().filter(|v| v.nodes[0] == NONE).count();
        assert!(before.iter().any(|b| unbound(b) > 0));
        assert!(graph.extend(&plane(0.4, 0.6)) > 0);
        let mut rebound = 0;
        for (&c, b) in coords.iter().zip(before) {
            let fresh = bind_block(&graph, geo, c, reach(&graph));
            let was_unbound = unbound(&b);
            assert!(can_rebind(&b, &graph, reach(&graph)));
            let merged = rebind_block(&graph, geo, c, b);
            assert_eq!(merged.voxels, fresh.voxels, "block {c:?}");
            assert_eq!(
                (merged.radius, merged.nodes_seen),
                (fresh.radius, fresh.nodes_seen)
            );
            rebound += usize::from(unbound(&merged) < was_unbound);
        }
        assert!(rebound > 0, "no voxel was bound by an added node");
    }
}
