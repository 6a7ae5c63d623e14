//! A shape's extremities (hooves, head, tail) and their partners on the same shape in another
//! pose, from surface distances and handedness alone.
//!
//! The extremities are the first points of farthest-point sampling along the surface, started
//! from the point farthest from the vertex nearest the centroid: the tips of the limbs. Their
//! mutual surface distances do not change when the limbs bend, so the assignment of the source's
//! extremities to the target's that best keeps those distances is their correspondence, up to
//! the shape's intrinsic symmetry: a left leg and a right leg are as far from everything else.
//! Two cues break that tie. The extremities' surface distances to the core anchors, whose
//! partners the registration of the whole shape gives (the body moves little), tell the
//! body's sides and ends apart. Handedness backs them: a mirror assignment reverses the sign
//! of the triple product `det(a − o, b − o, c − o)` of extremity triples about the centroid o,
//! which a bend of the limbs leaves as it is (an orientation-preserving map, as in Ren et al.,
//! *Continuous and orientation-preserving correspondences via functional maps*, 2018).

use super::extent::centroid;
use nalgebra::{Matrix3, Vector3};

/// Extremities per shape.
pub(crate) const EXTREMITIES: usize = 6;

/// Weight of one reversed triple against the surface distances' disagreement, summed over every
/// ordered pair and divided by the target's bounding-box diagonal.
const HANDEDNESS_WEIGHT: f64 = 0.25;

/// The largest disagreement of the surface distances between assigned extremities, in the
/// source's units ([`intrinsic_scale`]), as a share of their sum ([`assign`]). On the camel's
/// 30 maps 0.02–0.09 (NOTES 104); on a tube, whose farthest points lie anywhere round its rims,
/// 0.17–0.22.
const MAX_MUTUAL: f64 = 0.15;

/// The same for the distances from the extremities to the core anchors: the camel 0.02–0.13, a
/// tube 0.24–0.28.
const MAX_TO_CORE: f64 = 0.2;

/// A shape's extremities and each one's surface distance to every vertex.
pub(crate) struct Extremities {
    /// The extremities' vertices.
    pub vertices: [usize; EXTREMITIES],
    /// Per extremity, its surface distance to every vertex.
    pub columns: Vec<Vec<f64>>,
}

impl Extremities {
    /// The extremities of the mesh whose vertices are `points`, `column(v)` giving every vertex's
    /// surface distance from vertex v, or `None` for a mesh of fewer vertices than extremities.
    pub fn find(column: impl Fn(usize) -> Vec<f64>, points: &[Vector3<f64>]) -> Option<Self> {
        if points.len() < EXTREMITIES {
            return None;
        }
        let centre = nearest(points, &centroid(points))?;
        let mut nearest_extremity = column(centre);
        let mut vertices = [0; EXTREMITIES];
        let mut columns = Vec::with_capacity(EXTREMITIES);
        for v in vertices.iter_mut() {
            *v = farthest(&nearest_extremity);
            let distances = column(*v);
            for (d, c) in nearest_extremity.iter_mut().zip(&distances) {
                *d = d.min(*c);
            }
            // the first sweep measures from the centre, the rest from the extremities found
            if columns.is_empty() {
                nearest_extremity.clone_from(&distances);
            }
            columns.push(distances);
        }
        Some(Self { vertices, columns })
    }

    /// The surface distances between the extremities.
    fn mutual(&self) -> [[f64; EXTREMITIES]; EXTREMITIES] {
        std::array::from_fn(|i| std::array::from_fn(|j| self.columns[i][self.vertices[j]]))
    }

    /// The extremities' positions relative to the centroid o of `points`.
    fn about_centroid(&self, points: &[Vector3<f64>]) -> [Vector3<f64>; EXTREMITIES] {
        let o = centroid(points);
        self.vertices.map(|v| points[v] - o)
    }
}

/// The number of triples a < b < c of extremities.
const TRIPLES: usize = EXTREMITIES * (EXTREMITIES - 1) * (EXTREMITIES - 2) / 6;

/// The signs of `det(a − o, b − o, c − o)` over every triple a < b < c of the extremities
/// `at` (relative to the centroid o, [`Extremities::about_centroid`]) taken in `order`.
fn handedness(at: &[Vector3<f64>; EXTREMITIES], order: &[usize; EXTREMITIES]) -> [bool; TRIPLES] {
    let mut signs = [false; TRIPLES];
    for (sign, (a, b, c)) in signs.iter_mut().zip(triples()) {
        let columns = [at[order[a]], at[order[b]], at[order[c]]];
        *sign = Matrix3::from_columns(&columns).determinant() > 0.0;
    }
    signs
}

/// One shape's side of an assignment: its extremities, its vertices and each vertex's surface
/// distances to the core anchors (whose partners are known).
pub(crate) type ExtremitySide<'a, const N: usize> =
    (&'a Extremities, &'a [Vector3<f64>], &'a [[f64; N]]);

/// The target's intrinsic size over the source's: the sum of the surface distances between its
/// extremities over the source's (a sum over every pair, the same in any order). A bend of the
/// limbs leaves it at 1; a shape that is larger along its surface, or stretched, scales it. The
/// camel's poses differ by up to 10 % (pose 1, whose legs are stretched the furthest; NOTES 104).
/// `None` when either sum is 0 or not finite.
fn intrinsic_scale(source: &Extremities, target: &Extremities) -> Option<f64> {
    let sum = |e: &Extremities| e.mutual().iter().flatten().sum::<f64>();
    let scale = sum(target) / sum(source);
    (scale.is_finite() && scale > 0.0).then_some(scale)
}

/// An assignment of the target's extremities to the source's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Assignment {
    /// For each source extremity, the index of its partner among the target's.
    pub perm: [usize; EXTREMITIES],
    /// The target's surface distances over the source's ([`intrinsic_scale`]).
    pub scale: f64,
}

/// For each source extremity, the index of its partner among the target's: the assignment
/// that keeps the surface distances best, between extremities and from each extremity to the
/// core anchors (the core places the body, which tells a left leg from a right one and the
/// head from the tail), with each reversed triple ([`handedness`]) counted
/// [`HANDEDNESS_WEIGHT`] times the target's diagonal. `None` when even that assignment leaves
/// the distances between the extremities off by more than [`MAX_MUTUAL`] of their sum, or those
/// to the core by more than [`MAX_TO_CORE`]: the points found on the two shapes are not the same
/// ones (a symmetric shape, a tube's rim, has no distinct tips). The target's distances are
/// compared in the source's units (over [`intrinsic_scale`], returned with the assignment), so
/// that a shape larger along its surface is assigned as one of the same size.
pub(crate) fn assign<const N: usize>(
    source: ExtremitySide<'_, N>,
    target: ExtremitySide<'_, N>,
    diagonal: f64,
) -> Option<Assignment> {
    let scale = intrinsic_scale(source.0, target.0)?;
    let (ds, mut dt) = (source.0.mutual(), target.0.mutual());
    let core = |side: &ExtremitySide<'_, N>| -> Vec<[f64; N]> {
        side.0.vertices.iter().map(|&v| side.2[v]).collect()
    };
    let (cs, mut ct) = (core(&source), core(&target));
    dt.iter_mut().flatten().for_each(|d| *d /= scale);
    ct.iter_mut().flatten().for_each(|d| *d /= scale);
    let identity: [usize; EXTREMITIES] = std::array::from_fn(|k| k);
    let hands = handedness(&source.0.about_centroid(source.1), &identity);
    let target_at = target.0.about_centroid(target.1);
    let mut best = (f64::INFINITY, identity, [f64::INFINITY; 2]);
    for_each_permutation(|perm| {
        let mutual: f64 = (0..EXTREMITIES)
            .flat_map(|i| (0..EXTREMITIES).map(move |j| (i, j)))
            .map(|(i, j)| (ds[i][j] - dt[perm[i]][perm[j]]).abs())
            .sum();
        let to_core: f64 = (0..EXTREMITIES)
            .flat_map(|i| cs[i].iter().zip(&ct[perm[i]]))
            .map(|(a, b)| (a - b).abs())
            .sum();
        let spread = mutual + to_core;
        let reversed = handedness(&target_at, perm)
            .iter()
            .zip(&hands)
            .filter(|(a, b)| a != b)
            .count();
        let score = spread / diagonal + HANDEDNESS_WEIGHT * reversed as f64;
        if score < best.0 {
            best = (score, *perm, [mutual, to_core]);
        }
    });
    let total: f64 = ds.iter().flatten().sum();
    let core_total: f64 = cs.iter().flatten().sum();
    let [mutual, to_core] = best.2;
    (mutual <= MAX_MUTUAL * total && to_core <= MAX_TO_CORE * core_total).then_some(Assignment {
        perm: best.1,
        scale,
    })
}

/// Every triple a < b < c of extremity indices.
fn triples() -> impl Iterator<Item = (usize, usize, usize)> {
    (0..EXTREMITIES).flat_map(|a| {
        (a + 1..EXTREMITIES).flat_map(move |b| (b + 1..EXTREMITIES).map(move |c| (a, b, c)))
    })
}

/// Calls `f` with every permutation of 0..EXTREMITIES (Heap's algorithm, iterative).
fn for_each_permutation(mut f: impl FnMut(&[usize; EXTREMITIES])) {
    let mut perm: [usize; EXTREMITIES] = std::array::from_fn(|k| k);
    let mut counters = [0usize; EXTREMITIES];
    f(&perm);
    let mut i = 1;
    while i < EXTREMITIES {
        if counters[i] < i {
            let j = if i % 2 == 0 { 0 } else { counters[i] };
            perm.swap(j, i);
            f(&perm);
            counters[i] += 1;
            i = 1;
        } else {
            counters[i] = 0;
            i += 1;
        }
    }
}

/// The vertex nearest `p`.
fn nearest(points: &[Vector3<f64>], p: &Vector3<f64>) -> Option<usize> {
    (0..points.len()).min_by(|&a, &b| {
        (points[a] - p)
            .norm_squared()
            .total_cmp(&(points[b] - p).norm_squared())
    })
}

/// The index of the largest distance.
fn farthest(distances: &[f64]) -> usize {
    (0..distances.len())
        .max_by(|&a, &b| distances[a].total_cmp(&distances[b]))
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nonrigid::descriptors::{tube, MeshRef, SurfacePaths};
    use nalgebra::Rotation3;

    const ANCHORS: usize = 3;

    /// A four-legged shape's extremities (head, tail, four hooves; left and right mirror
    /// images) and three core points off its plane of symmetry, as vertices 0–5 and 6–8.
    fn animal() -> Vec<Vector3<f64>> {
        vec![
            Vector3::new(0.0, 0.2, 2.0),
            Vector3::new(0.0, 0.0, -2.0),
            Vector3::new(0.5, -1.0, 1.0),
            Vector3::new(-0.5, -1.0, 1.0),
            Vector3::new(0.5, -1.0, -1.0),
            Vector3::new(-0.5, -1.0, -1.0),
            Vector3::new(0.3, 0.0, 0.5),
            Vector3::new(-0.2, 0.3, -0.4),
            Vector3::new(0.1, -0.2, 0.0),
        ]
    }

    /// The extremities at `order` among `points`, with straight-line distances for surface
    /// ones, and each vertex's distances to the core points `core` (the rest of a descriptor 0).
    fn side(
        points: &[Vector3<f64>],
        order: [usize; EXTREMITIES],
        core: &[usize],
    ) -> (Extremities, Vec<[f64; ANCHORS]>) {
        let distances = |v: usize| points.iter().map(|p| (p - points[v]).norm()).collect();
        let columns = order.iter().map(|&v| distances(v)).collect();
        let descriptors = points
            .iter()
            .map(|p| std::array::from_fn(|k| core.get(k).map_or(0.0, |&c| (p - points[c]).norm())))
            .collect();
        (
            Extremities {
                vertices: order,
                columns,
            },
            descriptors,
        )
    }

    #[test]
    fn extremities_are_assigned_by_distances_and_handedness() {
        let source = animal();
        // the target: the same shape turned and moved, its extremities found in another order
        let turn = Rotation3::from_euler_angles(0.3, -1.1, 0.7);
        let target: Vec<Vector3<f64>> = source
            .iter()
            .map(|p| turn * p + Vector3::new(1.0, 2.0, 3.0))
            .collect();
        let found = [4, 0, 5, 2, 1, 3];
        let (es, cs) = side(&source, [0, 1, 2, 3, 4, 5], &[6, 7, 8]);
        let (et, ct) = side(&target, found, &[6, 7, 8]);
        let perm = assign((&es, &source, &cs), (&et, &target, &ct), 4.0)
            .unwrap()
            .perm;
        for k in 0..EXTREMITIES {
            assert_eq!(found[perm[k]], k, "extremity {k}: {perm:?}");
        }
        // without the core, the left and right hooves are as far from everything else either
        // way round; handedness still tells them apart
        // (in either order of finding, so that neither wins a tie by coming first)
        let (es, cs) = side(&source, [0, 1, 2, 3, 4, 5], &[]);
        for found in [[4, 0, 5, 2, 1, 3], [5, 0, 4, 3, 1, 2]] {
            let (et, ct) = side(&target, found, &[]);
            let perm = assign((&es, &source, &cs), (&et, &target, &ct), 4.0)
                .unwrap()
                .perm;
            for k in 0..EXTREMITIES {
                assert_eq!(found[perm[k]], k, "by handedness, extremity {k}: {perm:?}");
            }
        }
        // a copy 1.3 times as large along its surface is assigned the same way, and says so
        let larger: Vec<Vector3<f64>> = target.iter().map(|p| p * 1.3).collect();
        let (es, cs) = side(&source, [0, 1, 2, 3, 4, 5], &[6, 7, 8]);
        let (el, cl) = side(&larger, found, &[6, 7, 8]);
        let got = assign((&es, &source, &cs), (&el, &larger, &cl), 4.0).unwrap();
        assert!((got.scale - 1.3).abs() < 1e-12, "{got:?}");
        assert!((0..EXTREMITIES).all(|k| found[got.perm[k]] == k), "{got:?}");
        // points that are not the same ones on the two shapes are not assigned
        let mut other = target.clone();
        other[2] += Vector3::new(0.0, 1.5, -1.0);
        other[5] -= Vector3::new(1.0, 0.0, 0.5);
        let (eo, co) = side(&other, found, &[6, 7, 8]);
        let (es, cs) = side(&source, [0, 1, 2, 3, 4, 5], &[6, 7, 8]);
        assert_eq!(assign((&es, &source, &cs), (&eo, &other, &co), 4.0), None);
    }

    #[test]
    fn a_bent_tubes_first_extremities_are_its_two_ends() {
        let (points, faces) = tube(24, 16, 0.8);
        let mesh = MeshRef {
            points: &points,
            faces: &faces,
        };
        let paths = SurfacePaths::along_edges(mesh).unwrap();
        let found = Extremities::find(|v| paths.column(v), &points).unwrap();
        let ring = |v: usize| v / 16;
        let ends = [ring(found.vertices[0]), ring(found.vertices[1])];
        assert!(
            ends.contains(&0) && ends.contains(&23),
            "{:?}",
            found.vertices
        );
        assert_eq!(found.columns.len(), EXTREMITIES);
        assert_eq!(found.columns[0][found.vertices[0]], 0.0);
        assert!(Extremities::find(|v| paths.column(v), &points[..5]).is_none());
    }

    #[test]
    fn heaps_algorithm_visits_every_permutation_once() {
        let mut seen = std::collections::HashSet::new();
        for_each_permutation(|p| {
            assert!(seen.insert(*p), "{p:?} twice");
        });
        assert_eq!(seen.len(), 720);
        assert_eq!(triples().count(), TRIPLES);
    }
}
