//! The K nearest deformation nodes of points grouped in cubes: one tree search per cube finds the
//! nodes any of its points can be bound to, and each point takes its K nearest among them. A node
//! farther than `d_K + 2h` from a cube's centre (d_K: the centre's K-th nearest node, h: the
//! cube's half-diagonal) is farther from every point of the cube than the point's K-th nearest
//! node, so the result is the exact K nearest. DynamicFusion (Newcombe et al., CVPR 2015, sec.
//! 3.4) binds its volume's voxels by such a precomputed field for the same reason.

use super::graph::{Binding, DeformationGraph};
use dynamap_residuals::deform::MAX_NEIGHBOURS;
use kiddo::SquaredEuclidean;
use nalgebra::Vector3;
use rayon::prelude::*;
use std::num::NonZero;

/// The nodes that can be among the K nearest of a point within `h` of a cube's centre.
#[derive(Default)]
pub(crate) struct Candidates {
    /// Node indices.
    pub nodes: Vec<u32>,
    /// Their positions, side by side for the scans.
    positions: Vec<Vector3<f64>>,
    /// `d_K + 2h`: a node added farther than this from the centre changes no point's binding.
    pub radius: f64,
    /// The centre's nearest node's distance.
    pub nearest: f64,
}

/// The candidates of the cube with `centre` and half-diagonal `h`, or `None` for a graph with no
/// node (or K = 0).
pub(crate) fn candidates(
    graph: &DeformationGraph,
    centre: &Vector3<f64>,
    h: f64,
) -> Option<Candidates> {
    let (radius, nearest) = candidate_radius(graph, centre, h)?;
    let q: [f64; 3] = (*centre).into();
    let nodes: Vec<u32> = graph
        .tree
        .within_unsorted::<SquaredEuclidean>(&q, radius * radius)
        .iter()
        .map(|n| n.item as u32)
        .collect();
    let positions = nodes
        .iter()
        .map(|&n| graph.nodes[n as usize].position)
        .collect();
    Some(Candidates {
        nodes,
        positions,
        radius,
        nearest,
    })
}

/// The candidate radius `d_K + 2h` of the cube with `centre` and half-diagonal `h`, and the
/// centre's nearest node's distance, or `None` for a graph with no node (or K = 0).
pub(crate) fn candidate_radius(
    graph: &DeformationGraph,
    centre: &Vector3<f64>,
    h: f64,
) -> Option<(f64, f64)> {
    let k = NonZero::new(graph.neighbours())?;
    let q: [f64; 3] = (*centre).into();
    let nearest = graph.tree.nearest_n::<SquaredEuclidean>(&q, k);
    let (first, last) = (nearest.first()?, nearest.last()?);
    Some((last.distance.sqrt() + 2.0 * h, first.distance.sqrt()))
}

/// Inserts `(node, d2)` into `best` (sorted nearest first, as long as K) if it is nearer than
/// the last; of equidistant nodes the one inserted first stays first. Whether it went in.
#[inline]
pub(crate) fn insert_nearer(best: &mut [(u32, f64)], node: u32, d2: f64) -> bool {
    let Some(last) = best.len().checked_sub(1) else {
        return false;
    };
    if d2 >= best[last].1 {
        return false;
    }
    let mut i = last;
    while i > 0 && best[i - 1].1 > d2 {
        best[i] = best[i - 1];
        i -= 1;
    }
    best[i] = (node, d2);
    true
}

impl Candidates {
    /// The `k` nearest candidates to `p`, nearest first, as (node, squared distance) pairs (the
    /// first `k` used): an insertion into a short sorted list. Of equidistant nodes the one
    /// listed first comes first.
    pub fn nearest(&self, p: &Vector3<f64>, k: usize) -> [(u32, f64); MAX_NEIGHBOURS] {
        let mut best = [(0u32, f64::INFINITY); MAX_NEIGHBOURS];
        let k = k.clamp(1, MAX_NEIGHBOURS);
        for (&c, position) in self.nodes.iter().zip(&self.positions) {
            insert_nearer(&mut best[..k], c, (position - p).norm_squared());
        }
        best
    }

    /// Into `out`, the candidates of a smaller cube (centre `centre`, half-diagonal `h`) that lies
    /// inside this one's: those within `d_K + 2h` of its centre, in this list's order, so that
    /// every point of the smaller cube finds the same K nearest, ties included, among fewer.
    pub fn narrow(&self, centre: &Vector3<f64>, h: f64, k: usize, out: &mut Candidates) {
        let best = self.nearest(centre, k);
        let k = k.clamp(1, MAX_NEIGHBOURS);
        out.radius = best[k - 1].1.sqrt() + 2.0 * h;
        out.nearest = best[0].1.sqrt();
        let r2 = out.radius * out.radius;
        out.nodes.clear();
        out.positions.clear();
        for (&c, position) in self.nodes.iter().zip(&self.positions) {
            if (position - centre).norm_squared() <= r2 {
                out.nodes.push(c);
                out.positions.push(*position);
            }
        }
    }
}

/// A point's cube (none for a point that is not finite) and its index.
type Keyed = (Option<[i64; 3]>, u32);

/// [`DeformationGraph::bind`] of every point, found cube by cube (cubes of edge `cell`, in
/// parallel). The same bindings up to the order of equidistant nodes; a point that is not finite
/// is bound as `bind` binds it.
pub(crate) fn bind_in_cells(
    graph: &DeformationGraph,
    points: &[Vector3<f64>],
    cell: f64,
) -> Vec<Binding> {
    let k = graph.neighbours();
    let cell = cell.max(1e-9);
    // each point's cube, once (none for a point that is not finite), sorted so cubes run together
    let mut keyed: Vec<Keyed> = points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let cube = p
                .iter()
                .all(|v| v.is_finite())
                .then(|| p.map(|v| (v / cell).floor() as i64).into());
            (cube, i as u32)
        })
        .collect();
    keyed.par_sort_unstable_by_key(|&(cube, i)| (cube.is_none(), cube, i));
    let runs: Vec<&[Keyed]> = keyed.chunk_by(|a, b| a.0.is_some() && a.0 == b.0).collect();
    let bound: Vec<(u32, Binding)> = runs
        .par_iter()
        .flat_map_iter(|run| {
            let nodes = run[0].0.and_then(|c| {
                let centre = (Vector3::from(c).cast::<f64>() + Vector3::repeat(0.5)) * cell;
                candidates(graph, &centre, 0.5 * cell * 3f64.sqrt())
            });
            run.iter().map(move |&(_, i)| {
                let p = &points[i as usize];
                let b = match &nodes {
                    Some(c) => graph.binding(&c.nearest(p, k)[..k]),
                    None => graph.bind(p),
                };
                (i, b)
            })
        })
        .collect();
    let mut out = vec![graph.binding(&[]); points.len()];
    for (i, b) in bound {
        out[i as usize] = b;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nonrigid::graph::GraphParams;

    /// Points on a curved sheet, bound cube by cube at several cube sizes, get the bindings
    /// `bind` gives them; a point that is not finite is bound as `bind` binds it.
    #[test]
    fn bindings_in_cells_are_the_k_nearest_nodes() {
        let surface = |u: f64, v: f64| Vector3::new(u, v, 0.3 * (3.0 * u).sin() * v.cos());
        let mut points = Vec::new();
        for i in 0..60 {
            for j in 0..50 {
                // irrational steps: no two nodes equidistant from a point
                points.push(surface(i as f64 * 0.0173 - 0.5, j as f64 * 0.0191 - 0.45));
            }
        }
        let nodes: Vec<Vector3<f64>> = points.iter().step_by(7).copied().collect();
        let graph = DeformationGraph::sample(
            &nodes,
            GraphParams {
                spacing: 0.06,
                ..GraphParams::default()
            },
        )
        .unwrap();
        points.push(Vector3::new(f64::NAN, 0.0, 0.0));
        let exact: Vec<Binding> = points.iter().map(|p| graph.bind(p)).collect();
        for cell in [0.02, 0.06, 0.2] {
            let cells = bind_in_cells(&graph, &points, cell);
            for (i, (a, b)) in cells.iter().zip(&exact).enumerate() {
                assert_eq!(a.count, b.count);
                assert_eq!(
                    a.nodes[..a.count],
                    b.nodes[..b.count],
                    "point {i}, cell {cell}"
                );
                for (x, y) in a.weights[..a.count].iter().zip(&b.weights[..b.count]) {
                    assert!(
                        (x - y).abs() < 1e-12 || (x.is_nan() && y.is_nan()),
                        "point {i}"
                    );
                }
            }
        }
    }
}
