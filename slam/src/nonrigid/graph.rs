//! The deformation graph (thesis 2.4, 4.3; Sumner et al. 2007; DynamicFusion): nodes sampled over the
//! canonical surface, each with a position, a radius of influence and a rigid motion stored as a unit
//! dual quaternion; edges to each node's K nearest nodes; every surface point bound to its K = 4
//! nearest nodes and warped by dual-quaternion blending (eq. 2.23, 4.2-4.3).

use dynamap_residuals::deform::{
    blend, dual_quaternion, rigid_motion, transform_point, transform_vector, MAX_NEIGHBOURS,
};
use kiddo::{ImmutableKdTree, KdTree, SquaredEuclidean};
use nalgebra::{DualQuaternion, Isometry3, Vector3};
use rayon::prelude::*;
use std::num::NonZero;

/// Points per task when the graph looks for surface beyond its nodes.
const NEW_POSITION_CHUNK: usize = 1024;

/// Graph settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GraphParams {
    /// Least distance between nodes, metres (default 0.025).
    pub spacing: f64,
    /// Radius r of a node's influence, in units of the spacing (default 1.0): weights
    /// `exp(−|v − g|² / (2 r²))`.
    pub radius_factor: f64,
    /// Nodes each surface point is bound to (default 4, at most [`MAX_NEIGHBOURS`]).
    pub neighbours: usize,
    /// Regularisation edges per node: its nearest other nodes (default 4).
    pub edges: usize,
}

impl Default for GraphParams {
    fn default() -> Self {
        Self {
            spacing: 0.025,
            radius_factor: 1.0,
            neighbours: MAX_NEIGHBOURS,
            edges: 4,
        }
    }
}

/// One node.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Node {
    /// Position g, canonical frame.
    pub position: Vector3<f64>,
    /// Radius of influence.
    pub radius: f64,
    /// Its rigid motion (canonical to live) as a unit dual quaternion.
    pub motion: DualQuaternion<f64>,
}

/// A surface point's nodes and normalised blending weights.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Binding {
    /// Node indices (the first `count` are used).
    pub nodes: [u32; MAX_NEIGHBOURS],
    /// Normalised weights.
    pub weights: [f64; MAX_NEIGHBOURS],
    /// Nodes used.
    pub count: usize,
}

/// Why a graph cannot be built.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum GraphError {
    /// No finite surface point to sample nodes from.
    #[error("no surface points to sample deformation nodes from")]
    Empty,
    /// A spacing that is not a positive finite length.
    #[error("node spacing must be positive and finite, got {0}")]
    Spacing(f64),
}

/// The deformation graph.
#[derive(Clone, Debug)]
pub struct DeformationGraph {
    /// Settings.
    pub params: GraphParams,
    /// Nodes, in the order they were added.
    pub nodes: Vec<Node>,
    /// Each node's regularisation neighbours (nearest first).
    pub edges: Vec<Vec<u32>>,
    pub(crate) tree: ImmutableKdTree<f64, 3>,
}

impl DeformationGraph {
    /// Samples nodes over `points` (canonical surface) by radius: scanning the points in order, a
    /// point becomes a node when no node lies within the spacing. Every point then has a node within
    /// the spacing, and no two nodes are closer than it. Motions start at the identity.
    pub fn sample(points: &[Vector3<f64>], params: GraphParams) -> Result<Self, GraphError> {
        if !(params.spacing > 0.0 && params.spacing.is_finite()) {
            return Err(GraphError::Spacing(params.spacing));
        }
        let mut graph = Self {
            params,
            nodes: Vec::new(),
            edges: Vec::new(),
            tree: ImmutableKdTree::new_from_slice(&[]),
        };
        let positions = graph.new_positions(points);
        graph.push_nodes(
            &positions,
            vec![DualQuaternion::identity(); positions.len()],
        );
        if graph.nodes.is_empty() {
            return Err(GraphError::Empty);
        }
        graph.rebuild();
        Ok(graph)
    }

    /// Adds nodes where `points` (canonical) lie farther than the spacing from every node: new
    /// surface. A new node takes the current warp at its position (the blend of its nearest existing
    /// nodes), as DynamicFusion does. Returns the number of nodes added.
    pub fn extend(&mut self, points: &[Vector3<f64>]) -> usize {
        let positions = self.new_positions(points);
        if positions.is_empty() {
            return 0;
        }
        let motions = positions
            .par_iter()
            .map(|g| normalised(&self.blend(&self.bind(g))))
            .collect();
        self.push_nodes(&positions, motions);
        self.rebuild();
        positions.len()
    }

    /// The greedy radius sampling shared by [`Self::sample`] and [`Self::extend`]: the points,
    /// in order, that lie at least the spacing from every node and every point taken before them.
    fn new_positions(&self, points: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        let r2 = self.params.spacing * self.params.spacing;
        // points within the spacing of an existing node are never taken: dropped in parallel
        let candidates: Vec<&Vector3<f64>> = points
            .par_chunks(NEW_POSITION_CHUNK)
            .flat_map_iter(|chunk| self.beyond_every_node(chunk, r2))
            .collect();
        // the candidates are beyond every existing node, so only those taken are checked again
        let mut taken: KdTree<f64, 3> = KdTree::with_capacity(64);
        let mut added = Vec::new();
        for p in candidates {
            let q: [f64; 3] = (*p).into();
            if !added.is_empty() && taken.nearest_one::<SquaredEuclidean>(&q).distance < r2 {
                continue;
            }
            taken.add(&q, added.len() as u64);
            added.push(*p);
        }
        added
    }

    /// The finite `points` farther than `√r2` from every node, in order. Neighbouring points
    /// (a mesh's, block by block) mostly share a node within reach, so the node that held the
    /// last point, then its regularisation neighbours, are tried before the tree is searched.
    fn beyond_every_node<'a>(
        &'a self,
        points: &'a [Vector3<f64>],
        r2: f64,
    ) -> impl Iterator<Item = &'a Vector3<f64>> + 'a {
        let mut last: Option<usize> = None;
        points
            .iter()
            .filter(|p| p.iter().all(|v| v.is_finite()))
            .filter(move |p| {
                if self.nodes.is_empty() {
                    return true;
                }
                let holds = |k: usize| (self.nodes[k].position - **p).norm_squared() < r2;
                if let Some(k) = last {
                    // the last holder, else its regularisation neighbours, before the tree
                    let near = std::iter::once(k)
                        .chain(self.edges[k].iter().map(|&j| j as usize))
                        .find(|&j| holds(j));
                    if near.is_some() {
                        last = near;
                        return false;
                    }
                }
                let nearest = self.tree.nearest_one::<SquaredEuclidean>(&(**p).into());
                let within = nearest.distance < r2;
                last = within.then_some(nearest.item as usize);
                !within
            })
    }

    /// Appends nodes at `positions` with `motions` and the configured radius.
    fn push_nodes(&mut self, positions: &[Vector3<f64>], motions: Vec<DualQuaternion<f64>>) {
        let radius = self.params.spacing * self.params.radius_factor;
        self.nodes
            .extend(positions.iter().zip(motions).map(|(p, motion)| Node {
                position: *p,
                radius,
                motion,
            }));
    }

    /// Rebuilds the node tree after nodes moved (the edges kept).
    fn rebuild_tree(&mut self) {
        let positions: Vec<[f64; 3]> = self.nodes.iter().map(|n| n.position.into()).collect();
        self.tree = ImmutableKdTree::new_from_slice(&positions);
    }

    /// Rebuilds the node tree and the edges after nodes were added.
    fn rebuild(&mut self) {
        let positions: Vec<[f64; 3]> = self.nodes.iter().map(|n| n.position.into()).collect();
        self.tree = ImmutableKdTree::new_from_slice(&positions);
        let k = (self.params.edges + 1).min(self.nodes.len());
        self.edges = positions
            .par_iter()
            .enumerate()
            .map(|(i, q)| match NonZero::new(k) {
                Some(k) => self
                    .tree
                    .nearest_n::<SquaredEuclidean>(q, k)
                    .iter()
                    .map(|n| n.item as u32)
                    .filter(|&j| j as usize != i)
                    .take(self.params.edges)
                    .collect(),
                None => Vec::new(),
            })
            .collect();
    }

    /// Binds a canonical point to its K nearest nodes with weights `exp(−|v − g_k|² / (2 r_k²))`,
    /// normalised (see [`Self::binding`]).
    pub fn bind(&self, p: &Vector3<f64>) -> Binding {
        self.bind_in(&self.tree, p)
    }

    /// [`Self::bind`] with the nearest nodes looked up in `tree`, a tree over the nodes in their
    /// order at other positions (e.g. warped into the live frame).
    pub(crate) fn bind_in(&self, tree: &ImmutableKdTree<f64, 3>, p: &Vector3<f64>) -> Binding {
        let mut found = [(0u32, 0.0); MAX_NEIGHBOURS];
        let Some(k) = NonZero::new(self.neighbours()) else {
            return self.binding(&[]);
        };
        let nearest = tree.nearest_n::<SquaredEuclidean>(&(*p).into(), k);
        for (o, n) in found.iter_mut().zip(&nearest) {
            *o = (n.item as u32, n.distance);
        }
        self.binding(&found[..nearest.len()])
    }

    /// The number of nodes a point is bound to: K, at most [`MAX_NEIGHBOURS`] and the node count.
    pub fn neighbours(&self) -> usize {
        self.params
            .neighbours
            .clamp(1, MAX_NEIGHBOURS)
            .min(self.nodes.len())
    }

    /// The binding to `nearest` (node, squared distance) pairs, at most [`MAX_NEIGHBOURS`]: weights
    /// `exp(−d² / (2 r_k²))`, normalised. The exponents are shifted by their largest before
    /// exponentiating, which the normalisation cancels, so a point far from every node still gets
    /// finite weights.
    pub fn binding(&self, nearest: &[(u32, f64)]) -> Binding {
        let mut b = Binding {
            nodes: [0; MAX_NEIGHBOURS],
            weights: [0.0; MAX_NEIGHBOURS],
            count: nearest.len().min(MAX_NEIGHBOURS),
        };
        let mut exponents = [0.0; MAX_NEIGHBOURS];
        for (i, &(k, d2)) in nearest.iter().take(MAX_NEIGHBOURS).enumerate() {
            let r = self.nodes[k as usize].radius;
            b.nodes[i] = k;
            exponents[i] = -d2 / (2.0 * r * r);
        }
        let top = exponents[..b.count]
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        let mut sum = 0.0;
        for (w, e) in b.weights.iter_mut().zip(&exponents[..b.count]) {
            *w = (e - top).exp();
            sum += *w;
        }
        for w in &mut b.weights[..b.count] {
            *w /= sum;
        }
        b
    }

    /// [`Self::bind`] for many points, in parallel.
    pub fn bind_all(&self, points: &[Vector3<f64>]) -> Vec<Binding> {
        points.par_iter().map(|p| self.bind(p)).collect()
    }

    /// The blended (unnormalised) dual quaternion of a binding.
    pub fn blend(&self, b: &Binding) -> DualQuaternion<f64> {
        let mut nodes = [DualQuaternion::identity(); MAX_NEIGHBOURS];
        for (o, &k) in nodes.iter_mut().zip(&b.nodes[..b.count]) {
            *o = self.nodes[k as usize].motion;
        }
        blend(&nodes[..b.count], &b.weights[..b.count]).0
    }

    /// Warps a point and its normal by its binding.
    pub fn warp(
        &self,
        b: &Binding,
        p: &Vector3<f64>,
        n: &Vector3<f64>,
    ) -> (Vector3<f64>, Vector3<f64>) {
        let q = self.blend(b);
        (transform_point(&q, p), transform_vector(&q, n))
    }

    /// Warps many points and normals, in parallel, into `out_points` and `out_normals`.
    pub fn warp_all(
        &self,
        bindings: &[Binding],
        points: &[Vector3<f64>],
        normals: &[Vector3<f64>],
        out_points: &mut Vec<Vector3<f64>>,
        out_normals: &mut Vec<Vector3<f64>>,
    ) {
        out_points.resize(points.len(), Vector3::zeros());
        out_normals.resize(points.len(), Vector3::zeros());
        out_points
            .par_iter_mut()
            .zip(out_normals.par_iter_mut())
            .enumerate()
            .for_each(|(i, (op, on))| {
                (*op, *on) = self.warp(&bindings[i], &points[i], &normals[i]);
            });
    }

    /// The same graph with every length multiplied by `k` (positions, radii, the spacing and the
    /// motions' translations): the warp of points scaled by `k` is the warp scaled by `k`.
    pub fn scale(&mut self, k: f64) {
        self.params.spacing *= k;
        for n in &mut self.nodes {
            n.position *= k;
            n.radius *= k;
            let mut m = rigid_motion(&n.motion);
            m.translation.vector *= k;
            n.motion = dual_quaternion(&m);
        }
        self.rebuild_tree();
    }

    /// The same graph for points moved by `o`: positions move by `o` and every motion A_k
    /// becomes T_o A_k T_o⁻¹ (its rotation kept, its translation t + o − R o), so that the warp
    /// of points moved by `o` is the warp moved by `o`.
    pub fn shift(&mut self, o: &Vector3<f64>) {
        for n in &mut self.nodes {
            n.position += o;
            let mut m = rigid_motion(&n.motion);
            m.translation.vector += o - m.rotation * o;
            n.motion = dual_quaternion(&m);
        }
        self.rebuild_tree();
    }

    /// Applies a rigid motion after the warp: every node's motion becomes `T A_k`. Blending is
    /// linear in the nodes, so the warp becomes exactly `T ∘ W`.
    pub fn premultiply(&mut self, t: &Isometry3<f64>) {
        let q = dual_quaternion(t);
        for n in &mut self.nodes {
            n.motion = q * n.motion;
        }
    }
}

/// A dual quaternion scaled to a unit real part, with the dual part made orthogonal to it.
fn normalised(b: &DualQuaternion<f64>) -> DualQuaternion<f64> {
    dual_quaternion(&rigid_motion(b))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    /// A graph shifted by `o` with its points warps them (bound as before) to its warp shifted
    /// by `o`, normals unchanged.
    #[test]
    fn a_shifted_graph_warps_shifted_points_to_the_shifted_warp() {
        let points: Vec<Vector3<f64>> = (0..400)
            .map(|k| {
                let (a, b) = ((k % 20) as f64, (k / 20) as f64);
                Vector3::new(0.01 * a, 0.01 * b, 0.002 * ((a * b) % 7.0))
            })
            .collect();
        let normals = vec![Vector3::z(); points.len()];
        let params = GraphParams {
            spacing: 0.04,
            ..GraphParams::default()
        };
        let mut graph = DeformationGraph::sample(&points, params).unwrap();
        for (k, n) in graph.nodes.iter_mut().enumerate() {
            let k = k as f64;
            n.motion = dual_quaternion(&Isometry3::from_parts(
                Translation3::new(0.01 * k, -0.02, 0.005),
                UnitQuaternion::from_euler_angles(0.1 * k, -0.2, 0.05),
            ));
        }
        let bindings = graph.bind_all(&points);
        let warp = |graph: &DeformationGraph, points: &[Vector3<f64>]| {
            let (mut p, mut n) = (Vec::new(), Vec::new());
            graph.warp_all(&bindings, points, &normals, &mut p, &mut n);
            (p, n)
        };
        let (before, before_n) = warp(&graph, &points);
        let o = Vector3::new(30.0, -20.0, 50.0);
        graph.shift(&o);
        let moved: Vec<_> = points.iter().map(|p| p + o).collect();
        let (after, after_n) = warp(&graph, &moved);
        assert!(graph.nodes.len() > 10, "{}", graph.nodes.len());
        for (k, ((a, b), (na, nb))) in after
            .iter()
            .zip(&before)
            .zip(after_n.iter().zip(&before_n))
            .enumerate()
        {
            assert!(
                (a - (b + o)).norm() < 1e-9,
                "point {k}: {a:?} against {:?}",
                b + o
            );
            assert!((na - nb).norm() < 1e-12, "normal {k}");
        }
    }
}
