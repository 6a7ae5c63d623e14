//! Correspondences between two meshes of one shape in different poses, from geodesic descriptors.
//!
//! Closest point cannot tell apart two parts that swing past each other, such as a galloping
//! animal's left and right legs: each is pulled onto the other. Distances along the surface do
//! not change when a limb bends, so a vertex described by its surface distances to a few anchor
//! points keeps its identity across poses (the intrinsic-distance idea of Elad & Kimmel, *On
//! bending invariant signatures for surfaces*, 2003). Anchors off the shape's plane of symmetry
//! also tell its two sides apart.
//!
//! The anchors are spread over the source's core by farthest-point sampling. Their partners must
//! be known: [`descriptor_matches`] takes them from a registration of the whole shape (the core
//! moves little, so closest point is right there). The core alone places the limbs poorly: a
//! hoof is far from every core anchor, and a small error in where those anchors land moves it
//! along its leg. So each descriptor also holds the distances to the shape's extremities, whose
//! partners are found from surface distances and handedness (module `extremities`). Surface
//! distances are shortest paths along the mesh edges (Dijkstra), not along a nearest-neighbour
//! graph, whose edges cut across nearby parts.

use super::extent::{bounding_diagonal, centroid};
use super::extremities::{assign, Extremities, EXTREMITIES};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Vector3;
use petgraph::graph::{NodeIndex, UnGraph};
use rayon::prelude::*;

/// Number of core anchors.
pub(crate) const ANCHORS: usize = 16;

/// The length of a descriptor: the core anchors' distances, then the extremities'.
const DESCRIPTOR: usize = ANCHORS + EXTREMITIES;

/// A mesh's vertices and triangles.
#[derive(Clone, Copy, Debug)]
pub struct MeshRef<'a> {
    /// Vertex positions.
    pub points: &'a [Vector3<f64>],
    /// Triangles as vertex indices.
    pub faces: &'a [[u32; 3]],
}

/// Why descriptors could not be formed.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum DescriptorError {
    /// Fewer vertices than anchors.
    #[error(
        "{0} vertices are too few for {ANCHORS} anchors of the seeded passes (register such a \
         small mesh in one pass: no seeded passes)"
    )]
    TooFewVertices(usize),
    /// A face names a vertex that does not exist.
    #[error("face {face} names vertex {vertex}, but the mesh has {vertices} vertices")]
    BadFace {
        /// Index of the face.
        face: usize,
        /// The vertex it names.
        vertex: u32,
        /// Vertices in the mesh.
        vertices: usize,
    },
    /// A mesh without triangles (a point cloud) has no edges to measure along.
    #[error("a mesh without triangles has no surface distances")]
    NoFaces,
    /// `warped` does not hold one point per source vertex.
    #[error("{warped} warped points for {vertices} source vertices")]
    Mismatch {
        /// Warped points given.
        warped: usize,
        /// Source vertices.
        vertices: usize,
    },
}

/// `count` vertices spread over the `core_fraction` of `points` nearest their centroid, by
/// farthest-point sampling from the core vertex of largest x.
pub(crate) fn core_anchors(
    points: &[Vector3<f64>],
    count: usize,
    core_fraction: f64,
) -> Vec<usize> {
    if points.is_empty() || count == 0 {
        return Vec::new();
    }
    let centre = centroid(points);
    let mut order: Vec<usize> = (0..points.len()).collect();
    order.sort_by(|&a, &b| {
        (points[a] - centre)
            .norm_squared()
            .total_cmp(&(points[b] - centre).norm_squared())
    });
    let keep = ((points.len() as f64 * core_fraction).ceil() as usize)
        .clamp(count.min(points.len()), points.len());
    let core = &order[..keep];
    let first = *core
        .iter()
        .max_by(|&&a, &&b| points[a].x.total_cmp(&points[b].x))
        .expect("the core is not empty");
    let mut anchors = vec![first];
    let mut nearest: Vec<f64> = core
        .iter()
        .map(|&v| (points[v] - points[first]).norm())
        .collect();
    while anchors.len() < count.min(core.len()) {
        let (k, _) = nearest
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .expect("the core is not empty");
        let next = core[k];
        anchors.push(next);
        for (d, &v) in nearest.iter_mut().zip(core) {
            *d = d.min((points[v] - points[next]).norm());
        }
    }
    anchors
}

/// A mesh's graph of shortest paths, built once and asked from many sets of anchors.
pub(crate) struct SurfacePaths {
    vertices: usize,
    graph: UnGraph<(), f64>,
}

impl SurfacePaths {
    /// Paths along the mesh's edges.
    pub(crate) fn along_edges(mesh: MeshRef<'_>) -> Result<Self, DescriptorError> {
        Ok(Self::over(mesh, &mesh_edges(mesh)?))
    }

    /// Paths that may also cut straight from a vertex to any vertex of its second ring. A grid's
    /// triangles have their diagonals one way only, so paths along the edges alone overestimate
    /// distances across the other diagonal by up to 41 %, and differently on two meshes of one
    /// surface; with the second ring the worst direction is 2.7 % long on a square grid.
    pub(crate) fn two_ring(mesh: MeshRef<'_>) -> Result<Self, DescriptorError> {
        let edges = mesh_edges(mesh)?;
        let mut ring: Vec<Vec<u32>> = vec![Vec::new(); mesh.points.len()];
        for &(a, b) in &edges {
            ring[a as usize].push(b);
            ring[b as usize].push(a);
        }
        let mut wide = edges.clone();
        for (v, near) in ring.iter().enumerate() {
            for &u in near {
                wide.extend(
                    ring[u as usize]
                        .iter()
                        .filter(|&&w| w as usize > v)
                        .map(|&w| (v as u32, w)),
                );
            }
        }
        wide.sort_unstable();
        wide.dedup();
        Ok(Self::over(mesh, &wide))
    }

    /// The graph of `edges`, each as long as the straight line between its ends.
    fn over(mesh: MeshRef<'_>, edges: &[(u32, u32)]) -> Self {
        let n = mesh.points.len();
        let mut graph = UnGraph::<(), f64>::from_edges(edges.iter().map(|&(a, b)| {
            let length = (mesh.points[a as usize] - mesh.points[b as usize]).norm();
            (a, b, length)
        }));
        while graph.node_count() < n {
            graph.add_node(());
        }
        Self { vertices: n, graph }
    }

    /// Each vertex's shortest-path distances to the `ANCHORS` anchors. A vertex the anchor
    /// cannot reach (another component) gets twice the largest distance found, so that it stays
    /// far from every reachable one.
    pub(crate) fn descriptors(&self, anchors: &[usize; ANCHORS]) -> Vec<[f64; ANCHORS]> {
        let columns: Vec<Vec<f64>> = anchors
            .par_iter()
            .map(|&a| self.distances_from(&self.graph, NodeIndex::new(a)))
            .collect();
        self.rows(&columns)
    }

    /// [`Self::descriptors`] to anchors that may lie between vertices: anchor k is reached
    /// from each vertex `v` of `starts[k]` through `d`, that anchor's distance to `v` (a point
    /// on an edge, from its two ends along the edge). Such a start joins the graph as a node of
    /// its own; it shortens no path between vertices as long as each `d` is at least the
    /// anchor's straight distance to `v`.
    pub(crate) fn descriptors_from(
        &self,
        starts: &[Vec<(u32, f64)>; ANCHORS],
    ) -> Vec<[f64; ANCHORS]> {
        let columns: Vec<Vec<f64>> = starts
            .par_iter()
            .map(|start| {
                let mut graph = self.graph.clone();
                let s = graph.add_node(());
                for &(v, d) in start {
                    graph.add_edge(s, NodeIndex::new(v as usize), d);
                }
                self.distances_from(&graph, s)
            })
            .collect();
        self.rows(&columns)
    }

    /// Every vertex's shortest-path distance from vertex `v`.
    pub(crate) fn column(&self, v: usize) -> Vec<f64> {
        self.distances_from(&self.graph, NodeIndex::new(v))
    }

    /// Every vertex's shortest-path distance from `start` in `graph`.
    fn distances_from(&self, graph: &UnGraph<(), f64>, start: NodeIndex) -> Vec<f64> {
        let reached = petgraph::algo::dijkstra(graph, start, None, |e| *e.weight());
        let far = 2.0 * reached.values().copied().fold(0.0, f64::max);
        (0..self.vertices)
            .map(|v| reached.get(&NodeIndex::new(v)).copied().unwrap_or(far))
            .collect()
    }

    /// One descriptor per vertex from one column of distances per anchor.
    fn rows(&self, columns: &[Vec<f64>]) -> Vec<[f64; ANCHORS]> {
        (0..self.vertices)
            .map(|v| std::array::from_fn(|k| columns[k][v]))
            .collect()
    }
}

/// The mesh's edges, each once as (smaller, larger) vertex index.
fn mesh_edges(mesh: MeshRef<'_>) -> Result<Vec<(u32, u32)>, DescriptorError> {
    let n = mesh.points.len();
    let mut edges = Vec::with_capacity(mesh.faces.len() * 3);
    for (face, f) in mesh.faces.iter().enumerate() {
        if let Some(&vertex) = f.iter().find(|&&v| v as usize >= n) {
            return Err(DescriptorError::BadFace {
                face,
                vertex,
                vertices: n,
            });
        }
        for (a, b) in [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])] {
            edges.push((a.min(b), a.max(b)));
        }
    }
    // an edge between two triangles is listed by both
    edges.sort_unstable();
    edges.dedup();
    Ok(edges)
}

/// For every source vertex, the target vertex whose geodesic descriptor is nearest its own.
/// The anchors are the core anchors of the source (the `core_fraction` nearest its centroid);
/// each anchor's partner is the target vertex nearest its position in `warped`, the source
/// registered onto the target as a whole. (For several `warped` of one pair,
/// [`DescriptorPair`] does the work that does not depend on them once.)
pub fn descriptor_matches(
    source: MeshRef<'_>,
    warped: &[Vector3<f64>],
    target: MeshRef<'_>,
    core_fraction: f64,
) -> Result<Vec<usize>, DescriptorError> {
    check_warped(source, warped)?;
    DescriptorPair::new(source, target, core_fraction)?.matches(warped)
}

/// `warped` must hold one point per source vertex.
fn check_warped(source: MeshRef<'_>, warped: &[Vector3<f64>]) -> Result<(), DescriptorError> {
    if warped.len() == source.points.len() {
        Ok(())
    } else {
        Err(DescriptorError::Mismatch {
            warped: warped.len(),
            vertices: source.points.len(),
        })
    }
}

/// What [`descriptor_matches`] needs of a pair of meshes that does not depend on where the
/// source was registered: the source's core anchors and its descriptors to them, the target's
/// surface paths, and both meshes' extremities (module `extremities`).
pub struct DescriptorPair<'a> {
    source: MeshRef<'a>,
    target: MeshRef<'a>,
    anchors: [usize; ANCHORS],
    from: Vec<[f64; ANCHORS]>,
    target_paths: SurfacePaths,
    target_tree: ImmutableKdTree<f64, 3>,
    /// The target's bounding-box diagonal, the unit of the extremities' handedness term.
    target_diagonal: f64,
    extremities: Option<(Extremities, Extremities)>,
}

impl<'a> DescriptorPair<'a> {
    /// The pair, with the core anchors over the `core_fraction` of the source nearest its
    /// centroid; meshes smaller than the anchors, without triangles or with a face naming a
    /// missing vertex are errors.
    pub fn new(
        source: MeshRef<'a>,
        target: MeshRef<'a>,
        core_fraction: f64,
    ) -> Result<Self, DescriptorError> {
        for mesh in [source, target] {
            if mesh.points.len() < ANCHORS {
                return Err(DescriptorError::TooFewVertices(mesh.points.len()));
            }
            if mesh.faces.is_empty() {
                return Err(DescriptorError::NoFaces);
            }
        }
        let anchors: [usize; ANCHORS] = core_anchors(source.points, ANCHORS, core_fraction)
            .try_into()
            .map_err(|_| DescriptorError::TooFewVertices(source.points.len()))?;
        let (source_paths, target_paths) = (
            SurfacePaths::along_edges(source)?,
            SurfacePaths::along_edges(target)?,
        );
        let extremities = Extremities::find(|v| source_paths.column(v), source.points)
            .zip(Extremities::find(|v| target_paths.column(v), target.points));
        let coords: Vec<[f64; 3]> = target.points.iter().map(|p| (*p).into()).collect();
        Ok(Self {
            from: source_paths.descriptors(&anchors),
            source,
            target,
            anchors,
            target_paths,
            target_tree: ImmutableKdTree::new_from_slice(&coords),
            target_diagonal: bounding_diagonal(target.points),
            extremities,
        })
    }

    /// [`descriptor_matches`] with the source registered onto the target at `warped`.
    pub fn matches(&self, warped: &[Vector3<f64>]) -> Result<Vec<usize>, DescriptorError> {
        check_warped(self.source, warped)?;
        let partners: [usize; ANCHORS] = std::array::from_fn(|k| {
            self.target_tree
                .nearest_one::<SquaredEuclidean>(&warped[self.anchors[k]].into())
                .item as usize
        });
        let to = self.target_paths.descriptors(&partners);
        let (from, to) = self.with_extremities(&to);
        let tree: ImmutableKdTree<f64, DESCRIPTOR> = ImmutableKdTree::new_from_slice(&to);
        Ok(from
            .par_iter()
            .map(|d| tree.nearest_one::<SquaredEuclidean>(d).item as usize)
            .collect())
    }

    /// The core descriptors of both meshes (`to` the target's), each extended by the vertex's
    /// surface distances to the mesh's extremities, the target's in the order of their assigned
    /// source partners: the core anchors place the body, the extremities the limbs along their
    /// length. Where the extremities are not found on both or not assigned (a mesh too small,
    /// a shape without distinct tips), both get zeros there, which change no distance.
    fn with_extremities(
        &self,
        to: &[[f64; ANCHORS]],
    ) -> (Vec<[f64; DESCRIPTOR]>, Vec<[f64; DESCRIPTOR]>) {
        let extended = |core: &[[f64; ANCHORS]], columns: Option<Vec<&[f64]>>| {
            core.iter()
                .enumerate()
                .map(|(v, d)| {
                    std::array::from_fn(|k| match (k.checked_sub(ANCHORS), &columns) {
                        (None, _) => d[k],
                        (Some(e), Some(c)) => c[e][v],
                        (Some(_), None) => 0.0,
                    })
                })
                .collect::<Vec<[f64; DESCRIPTOR]>>()
        };
        let (source, target) = (self.source.points, self.target.points);
        let assigned = self.extremities.as_ref().and_then(|(es, et)| {
            let side = (es, source, self.from.as_slice());
            let found = assign(side, (et, target, to), self.target_diagonal)?;
            Some((es, et, found))
        });
        let Some((es, et, found)) = assigned else {
            return (extended(&self.from, None), extended(to, None));
        };
        let source_columns = es.columns.iter().map(Vec::as_slice).collect();
        let target_columns = found
            .perm
            .iter()
            .map(|&k| et.columns[k].as_slice())
            .collect();
        let mut target = extended(to, Some(target_columns));
        // in the source's units: a target larger along its surface would otherwise match each
        // limb's points to points farther out along the limb (NOTES 104)
        target.iter_mut().flatten().for_each(|d| *d /= found.scale);
        (extended(&self.from, Some(source_columns)), target)
    }
}

/// A test surface (also used by `surface`'s tests): an open tube of `rings` × `around` vertices, radius 0.2 and length 2 along z, whose
/// centre line is bent into a circular arc through `bend` radians (0: straight).
#[cfg(test)]
pub(crate) fn tube(rings: usize, around: usize, bend: f64) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
    let mut points = Vec::new();
    for r in 0..rings {
        let s = 2.0 * r as f64 / (rings - 1) as f64;
        let (turn, centre) = if bend == 0.0 {
            (nalgebra::Rotation3::identity(), Vector3::new(0.0, 0.0, s))
        } else {
            let (radius, angle) = (2.0 / bend, bend * s / 2.0);
            (
                nalgebra::Rotation3::from_axis_angle(&Vector3::x_axis(), -angle),
                Vector3::new(0.0, radius * (1.0 - angle.cos()), radius * angle.sin()),
            )
        };
        for a in 0..around {
            let t = std::f64::consts::TAU * a as f64 / around as f64;
            points.push(centre + turn * Vector3::new(0.2 * t.cos(), 0.2 * t.sin(), 0.0));
        }
    }
    let mut faces = Vec::new();
    for r in 0..rings - 1 {
        for a in 0..around {
            let (i, j) = (
                (r * around + a) as u32,
                (r * around + (a + 1) % around) as u32,
            );
            let (k, l) = (i + around as u32, j + around as u32);
            faces.push([i, j, k]);
            faces.push([j, l, k]);
        }
    }
    (points, faces)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector3};

    /// Each vertex's shortest-path distances along the mesh edges to the `ANCHORS` anchors.
    fn geodesic_descriptors(
        mesh: MeshRef<'_>,
        anchors: &[usize; ANCHORS],
    ) -> Result<Vec<[f64; ANCHORS]>, DescriptorError> {
        Ok(SurfacePaths::along_edges(mesh)?.descriptors(anchors))
    }

    /// Matches of the straight tube onto a copy bent by `bend` radians, moved rigidly and
    /// renumbered. Returns how many vertices found their own copy, the largest distance (on the
    /// straight tube) between a vertex and the vertex whose copy it found, and the count.
    fn match_bent_copy(bend: f64) -> (usize, f64, usize) {
        let (points, faces) = tube(24, 16, 0.0);
        let (bent, bent_faces) = tube(24, 16, bend);
        let n = bent.len();
        let new_of = |v: usize| (v * 7 + 3) % n; // 7 is prime to n = 384
        let motion = Rotation3::from_euler_angles(0.3, -0.2, 0.5);
        let moved: Vec<Vector3<f64>> = bent
            .iter()
            .map(|p| motion * p + Vector3::new(1.0, -2.0, 0.5))
            .collect();
        let mut target = vec![Vector3::zeros(); n];
        let mut old_of = vec![0; n];
        for (v, p) in moved.iter().enumerate() {
            target[new_of(v)] = *p;
            old_of[new_of(v)] = v;
        }
        let target_faces: Vec<[u32; 3]> = bent_faces
            .iter()
            .map(|f| f.map(|v| new_of(v as usize) as u32))
            .collect();
        // the whole-shape registration that places the anchors: the moved bent tube itself
        let matches = descriptor_matches(
            MeshRef {
                points: &points,
                faces: &faces,
            },
            &moved,
            MeshRef {
                points: &target,
                faces: &target_faces,
            },
            0.5,
        )
        .unwrap();
        let right = (0..n).filter(|&v| matches[v] == new_of(v)).count();
        let worst = (0..n)
            .map(|v| (points[old_of[matches[v]]] - points[v]).norm())
            .fold(0.0, f64::max);
        (right, worst, n)
    }

    #[test]
    fn a_moved_and_renumbered_copy_is_matched_vertex_for_vertex() {
        let (right, _, n) = match_bent_copy(0.0);
        assert_eq!(
            right, n,
            "{right} of {n} vertices matched to their own copy"
        );
    }

    /// A six-armed star: a hub of 12 vertices round a centre, and arms of 8 rows of two
    /// vertices and a tip, 0.8–1.8 long, on a saddle `z = 0.15 x y` (so that no triple of tips
    /// is coplanar).
    fn star() -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
        let (hub, width, rows): (f64, f64, usize) = (0.3, 0.2, 8);
        let on_saddle = |x: f64, y: f64| Vector3::new(x, y, 0.15 * x * y);
        let mut points = vec![on_saddle(0.0, 0.0)];
        let mut faces = Vec::new();
        let half = (0.5 * width / hub).atan();
        for k in 0..6 {
            let angle = std::f64::consts::TAU * k as f64 / 6.0;
            for side in [-half, half] {
                points.push(on_saddle(
                    hub * (angle + side).cos(),
                    hub * (angle + side).sin(),
                ));
            }
        }
        for k in 0..12u32 {
            faces.push([0, 1 + k, 1 + (k + 1) % 12]);
        }
        for k in 0..6 {
            let angle = std::f64::consts::TAU * k as f64 / 6.0;
            let (along, across) = (
                Vector3::new(angle.cos(), angle.sin(), 0.0),
                Vector3::new(-angle.sin(), angle.cos(), 0.0),
            );
            let length = 0.8 + 0.2 * k as f64;
            let mut last = [1 + 2 * k as u32, 2 + 2 * k as u32];
            for r in 1..=rows {
                let c = along * (hub + length * r as f64 / rows as f64);
                let row = [points.len() as u32, points.len() as u32 + 1];
                for s in [-0.5, 0.5] {
                    let p = c + across * (s * width);
                    points.push(on_saddle(p.x, p.y));
                }
                faces.push([last[0], row[0], row[1]]);
                faces.push([last[0], row[1], last[1]]);
                last = row;
            }
            let tip = along * (hub + length + 0.1);
            faces.push([last[0], points.len() as u32, last[1]]);
            points.push(on_saddle(tip.x, tip.y));
        }
        (points, faces)
    }

    #[test]
    fn a_copy_larger_along_its_surface_is_matched_vertex_for_vertex() {
        // every surface distance of the target is 1.3 times the source's: the extremities'
        // distances say so, and the target's descriptors are taken in the source's units
        let (points, faces) = star();
        let n = points.len();
        let new_of = |v: usize| (v * 11 + 5) % n;
        let renumbered: std::collections::HashSet<usize> = (0..n).map(new_of).collect();
        assert_eq!(renumbered.len(), n, "a renumbering");
        let motion = Rotation3::from_euler_angles(-0.4, 0.2, 1.1);
        let mut target = vec![Vector3::zeros(); n];
        for (v, p) in points.iter().enumerate() {
            target[new_of(v)] = motion * (p * 1.3) + Vector3::new(0.5, 1.0, -2.0);
        }
        let target_faces: Vec<[u32; 3]> = faces
            .iter()
            .map(|f| f.map(|v| new_of(v as usize) as u32))
            .collect();
        let registered: Vec<Vector3<f64>> = (0..n).map(|v| target[new_of(v)]).collect();
        let source = MeshRef {
            points: &points,
            faces: &faces,
        };
        let pair = DescriptorPair::new(
            source,
            MeshRef {
                points: &target,
                faces: &target_faces,
            },
            0.5,
        )
        .unwrap();
        let matches = pair.matches(&registered).unwrap();
        let right = (0..n).filter(|&v| matches[v] == new_of(v)).count();
        assert_eq!(
            right, n,
            "{right} of {n} vertices matched to their own copy"
        );
    }

    #[test]
    fn a_bent_copy_is_matched_within_a_ring() {
        // bending through 0.6 rad stretches the outer side's edges by 6 %, so a few vertices
        // slip to a neighbour, but none farther than the ring spacing (2 / 23)
        let (right, worst, n) = match_bent_copy(0.6);
        assert!(right * 10 >= n * 9, "{right} of {n} exact");
        assert!(worst <= 2.0 / 23.0 + 1e-9, "worst slip {worst}");
    }

    #[test]
    fn shortest_paths_follow_the_edges() {
        let (points, faces) = tube(5, 8, 0.0);
        let anchors = [0; ANCHORS];
        let d = geodesic_descriptors(
            MeshRef {
                points: &points,
                faces: &faces,
            },
            &anchors,
        )
        .unwrap();
        // straight up the tube: four ring spacings of 0.5
        assert!((d[4 * 8][0] - 2.0).abs() < 1e-12, "{}", d[4 * 8][0]);
        // half way round a ring: four chords of the octagon
        let chord = 2.0 * 0.2 * (std::f64::consts::PI / 8.0).sin();
        assert!((d[4][0] - 4.0 * chord).abs() < 1e-12);
    }

    #[test]
    fn bad_faces_and_short_inputs_are_errors() {
        let (points, mut faces) = tube(5, 8, 0.0);
        faces.push([0, 1, 99]);
        let mesh = MeshRef {
            points: &points,
            faces: &faces,
        };
        assert!(matches!(
            geodesic_descriptors(mesh, &[0; ANCHORS]),
            Err(DescriptorError::BadFace { vertex: 99, .. })
        ));
        let cloud = MeshRef {
            points: &points,
            faces: &[],
        };
        assert_eq!(
            descriptor_matches(cloud, &points, cloud, 0.5),
            Err(DescriptorError::NoFaces)
        );
        let few = &points[..4];
        let small = MeshRef {
            points: few,
            faces: &[],
        };
        assert_eq!(
            descriptor_matches(small, few, small, 0.5),
            Err(DescriptorError::TooFewVertices(4))
        );
        assert!(matches!(
            descriptor_matches(mesh, &points[..3], mesh, 0.5),
            Err(DescriptorError::Mismatch { .. })
        ));
    }
}
