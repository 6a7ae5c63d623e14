//! Triangles wound one way across a mesh: a mesh some of whose triangles are wound against their
//! neighbours (as meshes stitched from parts or written by careless exporters are) has vertex
//! normals that partly cancel and point both ways, and a registration that uses them sees the
//! surface facing two ways at once.
//!
//! Two triangles that share an edge are wound alike when they run along it in opposite
//! directions. A breadth-first walk over each connected piece of the surface (as trimesh's
//! `fix_winding` and Open3D's `orient_triangles` walk theirs) gives each triangle the winding
//! that agrees with the one it was reached from; of that assignment and its reverse, the piece
//! keeps the one that turns the smaller area, so that a consistent mesh is left as it is and a
//! mostly consistent one keeps the way most of it faces. The walk crosses only edges of exactly
//! two triangles (a non-manifold edge says nothing of which way its triangles face), and joins
//! triangles by their corners' positions, so that a triangle soup or a mesh split at its seams
//! is walked as the one surface it describes. On a surface that cannot be oriented (a Möbius
//! strip) some shared edges disagree whatever is done; they are counted.

use super::Mesh;
use nalgebra::Point3;
use rustc_hash::FxHashMap;
use std::collections::VecDeque;

/// What [`Mesh::orient_faces`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Winding {
    /// Triangles turned over (two of their corners swapped).
    pub turned: usize,
    /// Connected pieces of the surface (triangles joined through edges of two triangles).
    pub pieces: usize,
    /// Shared edges whose two triangles still run along them the same way: the surface cannot
    /// be oriented there.
    pub disagreeing: usize,
}

impl Mesh {
    /// Turns over the triangles wound against their neighbours (module docs), and says how many.
    /// Normals already held are left as they are. Like [`Mesh::compute_normals`], it expects
    /// the faces to refer to vertices the mesh has ([`Mesh::validate`]).
    pub fn orient_faces(&mut self) -> Winding {
        let edges = shared_edges(&self.vertices, &self.faces);
        let area: Vec<f64> = (self.faces.iter())
            .map(|f| triangle_area(&self.vertices, f))
            .collect();
        let mut flip: Vec<Option<bool>> = vec![None; self.faces.len()];
        let mut winding = Winding::default();
        let mut queue = VecDeque::new();
        let mut piece = Vec::new();
        for seed in 0..self.faces.len() {
            if flip[seed].is_some() {
                continue;
            }
            winding.pieces += 1;
            flip[seed] = Some(false);
            queue.push_back(seed);
            piece.clear();
            while let Some(f) = queue.pop_front() {
                piece.push(f);
                let turned = flip[f] == Some(true);
                for &(g, same_way) in edges.neighbours(f) {
                    // alike when they run along the edge in opposite directions
                    let wanted = turned ^ same_way;
                    match flip[g] {
                        None => {
                            flip[g] = Some(wanted);
                            queue.push_back(g);
                        }
                        Some(had) if had != wanted && f < g => winding.disagreeing += 1,
                        Some(_) => {}
                    }
                }
            }
            let flipped: f64 = (piece.iter())
                .filter(|&&f| flip[f] == Some(true))
                .map(|&f| area[f])
                .sum();
            let total: f64 = piece.iter().map(|&f| area[f]).sum();
            let reverse = flipped > total - flipped;
            for &f in &piece {
                if (flip[f] == Some(true)) != reverse {
                    self.faces[f].swap(1, 2);
                    winding.turned += 1;
                }
            }
        }
        winding
    }
}

impl Mesh {
    /// Vertex normals from the faces ([`Mesh::compute_normals`]) after the faces are wound
    /// alike ([`Mesh::orient_faces`]): for meshes read or given by a user, whose winding may be
    /// mixed. Marching cubes winds its own triangles alike and calls `compute_normals` alone.
    pub fn compute_oriented_normals(&mut self) -> Winding {
        let winding = self.orient_faces();
        self.compute_normals();
        winding
    }
}

/// Each triangle's neighbours across its edges of exactly two triangles, with whether the two
/// run along the edge the same way.
struct SharedEdges {
    /// Neighbours of triangle f at `links[start[f]..start[f + 1]]`.
    start: Vec<usize>,
    links: Vec<(usize, bool)>,
}

impl SharedEdges {
    fn neighbours(&self, f: usize) -> &[(usize, bool)] {
        &self.links[self.start[f]..self.start[f + 1]]
    }
}

/// The triangles along one edge: the first two, each with whether it runs from the edge's lower
/// corner to its higher, and how many there are.
#[derive(Default)]
struct EdgeUses {
    by: [(usize, bool); 2],
    count: u32,
}

/// The triangles' shared edges, corners joined by position (±0 alike).
fn shared_edges(vertices: &[Point3<f32>], faces: &[[u32; 3]]) -> SharedEdges {
    let mut id: FxHashMap<[u32; 3], u32> = FxHashMap::default();
    let corner: Vec<u32> = (vertices.iter())
        .map(|p| {
            let next = id.len() as u32;
            *id.entry(p.coords.map(|c| (c + 0.0).to_bits()).into())
                .or_insert(next)
        })
        .collect();
    let mut on_edge: FxHashMap<(u32, u32), EdgeUses> = FxHashMap::default();
    for (f, face) in faces.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (corner[face[k] as usize], corner[face[(k + 1) % 3] as usize]);
            if a != b {
                let uses = on_edge.entry((a.min(b), a.max(b))).or_default();
                if uses.count < 2 {
                    uses.by[uses.count as usize] = (f, a < b);
                }
                uses.count += 1;
            }
        }
    }
    let mut pairs: Vec<(usize, usize, bool)> = (on_edge.values())
        .filter(|e| e.count == 2 && e.by[0].0 != e.by[1].0)
        .map(|e| (e.by[0].0, e.by[1].0, e.by[0].1 == e.by[1].1))
        .collect();
    pairs.sort_unstable();
    let mut count = vec![0usize; faces.len() + 1];
    for &(f, g, _) in &pairs {
        count[f + 1] += 1;
        count[g + 1] += 1;
    }
    for k in 1..count.len() {
        count[k] += count[k - 1];
    }
    let mut links = vec![(0, false); count[faces.len()]];
    let mut fill = count.clone();
    for &(f, g, same) in &pairs {
        links[fill[f]] = (g, same);
        fill[f] += 1;
        links[fill[g]] = (f, same);
        fill[g] += 1;
    }
    SharedEdges {
        start: count,
        links,
    }
}

/// The area of triangle `f`.
fn triangle_area(vertices: &[Point3<f32>], f: &[u32; 3]) -> f64 {
    let [a, b, c] = f.map(|v| vertices[v as usize].cast::<f64>());
    (b - a).cross(&(c - a)).norm() / 2.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nonrigid::orientation::tests::sphere;
    use nalgebra::Vector3;

    /// A UV sphere as a mesh, wound outward.
    fn ball(centre: Vector3<f64>) -> Mesh {
        let (points, faces) = sphere(0.4, centre, 10);
        Mesh {
            vertices: points.iter().map(|p| p.cast::<f32>().into()).collect(),
            faces,
            ..Mesh::default()
        }
    }

    fn reversed(faces: &[[u32; 3]]) -> Vec<[u32; 3]> {
        faces.iter().map(|&[a, b, c]| [a, c, b]).collect()
    }

    /// The mesh with every face `k` for which `pick(k)` holds turned over.
    fn mixed(mesh: &Mesh, pick: impl Fn(usize) -> bool) -> Mesh {
        let mut m = mesh.clone();
        for (k, f) in m.faces.iter_mut().enumerate() {
            if pick(k) {
                f.swap(1, 2);
            }
        }
        m
    }

    /// The same triangles as `m`, each with its own three vertices.
    fn soup(m: &Mesh) -> Mesh {
        Mesh {
            vertices: m
                .faces
                .iter()
                .flatten()
                .map(|&v| m.vertices[v as usize])
                .collect(),
            faces: (0..m.faces.len() as u32)
                .map(|k| [3 * k, 3 * k + 1, 3 * k + 2])
                .collect(),
            ..Mesh::default()
        }
    }

    /// Each triangle's corners, in its order.
    fn corners(m: &Mesh) -> Vec<[Point3<f32>; 3]> {
        m.faces
            .iter()
            .map(|f| f.map(|v| m.vertices[v as usize]))
            .collect()
    }

    /// A mesh wound alike throughout, either way, is left as it is.
    #[test]
    fn a_consistent_mesh_is_left_as_it_is() {
        let out = ball(Vector3::zeros());
        let mut m = out.clone();
        let w = m.orient_faces();
        assert_eq!(m, out);
        assert_eq!((w.turned, w.pieces, w.disagreeing), (0, 1, 0));
        let inward = Mesh {
            faces: reversed(&out.faces),
            ..out.clone()
        };
        let mut m = inward.clone();
        assert_eq!(m.orient_faces().turned, 0);
        assert_eq!(m, inward);
    }

    /// Three faces in ten turned over are turned back, so that the normals computed after are
    /// the consistent mesh's; seven in ten turned, the mesh is wound the way most of it is
    /// (every face reversed). As a triangle soup the same faces are turned.
    #[test]
    fn faces_wound_against_their_neighbours_are_turned_to_the_majority() {
        let out = ball(Vector3::new(3.0, -1.0, 20.0));
        let some = |k: usize| k % 10 < 3;
        let mut m = mixed(&out, some);
        let w = m.orient_faces();
        assert_eq!(m.faces, out.faces);
        let picked = (0..out.faces.len()).filter(|&k| some(k)).count();
        assert_eq!((w.turned, w.pieces, w.disagreeing), (picked, 1, 0));
        let (mut fixed, mut truth, mut raw) = (m.clone(), out.clone(), mixed(&out, some));
        fixed.compute_normals();
        truth.compute_normals();
        raw.compute_normals();
        assert_eq!(fixed.normals, truth.normals);
        // without the turn, the normals point both ways
        let against = (raw.normals.iter().zip(&truth.normals)).filter(|(a, b)| a.dot(b) < 0.5);
        assert!(against.count() > out.vertices.len() / 20);

        let most = |k: usize| k % 10 >= 3;
        let mut m = mixed(&out, most);
        m.orient_faces();
        assert_eq!(m.faces, reversed(&out.faces));

        let mut s = soup(&mixed(&out, some));
        let w = s.orient_faces();
        assert_eq!(corners(&s), corners(&out));
        assert_eq!((w.turned, w.pieces), (picked, 1));
    }

    /// Two separate surfaces are oriented each by its own majority.
    #[test]
    fn separate_pieces_are_oriented_each_by_itself() {
        let (a, b) = (ball(Vector3::zeros()), ball(Vector3::new(5.0, 0.0, 0.0)));
        let n = a.vertices.len() as u32;
        let mut both = Mesh {
            vertices: [a.vertices.clone(), b.vertices.clone()].concat(),
            faces: (a.faces.iter().copied())
                .chain(reversed(&b.faces).iter().map(|f| f.map(|v| v + n)))
                .collect(),
            ..Mesh::default()
        };
        let expected = both.faces.clone();
        let half = both.faces.len() / 2;
        both = mixed(&both, |k| k % 7 == 0 || (k >= half && k % 5 == 0));
        let w = both.orient_faces();
        assert_eq!(both.faces, expected);
        assert_eq!((w.pieces, w.disagreeing), (2, 0));
    }

    /// A Möbius strip cannot be oriented: an edge disagrees whatever is done, and is counted.
    /// Three triangles on one edge are not walked across.
    #[test]
    fn a_surface_that_cannot_be_oriented_is_counted_and_a_non_manifold_edge_is_not_crossed() {
        let (n, mut vertices, mut faces) = (24u32, Vec::new(), Vec::new());
        for k in 0..n {
            let t = std::f32::consts::TAU * k as f32 / n as f32;
            let (c, s) = (t.cos(), t.sin());
            for w in [-0.2f32, 0.2] {
                let r = 1.0 + w * (t / 2.0).cos();
                vertices.push(Point3::new(r * c, r * s, w * (t / 2.0).sin()));
            }
        }
        for k in 0..n {
            let (a, b) = (2 * k, 2 * k + 1);
            // the last quad joins the strip's ends with its edges swapped
            let (c, d) = if k + 1 == n { (1, 0) } else { (a + 2, b + 2) };
            faces.push([a, c, b]);
            faces.push([b, c, d]);
        }
        let mut strip = Mesh {
            vertices,
            faces,
            ..Mesh::default()
        };
        let w = strip.orient_faces();
        assert_eq!(w.pieces, 1);
        assert!(w.disagreeing >= 1, "{w:?}");

        let fin = |p: [f32; 3]| Point3::new(p[0], p[1], p[2]);
        let mut fins = Mesh {
            vertices: vec![
                fin([0.0, 0.0, 0.0]),
                fin([0.0, 0.0, 1.0]),
                fin([1.0, 0.0, 0.5]),
                fin([-1.0, 0.0, 0.5]),
                fin([0.0, 1.0, 0.5]),
            ],
            faces: vec![[0, 1, 2], [0, 1, 3], [1, 0, 4]],
            ..Mesh::default()
        };
        let w = fins.orient_faces();
        assert_eq!((w.turned, w.pieces, w.disagreeing), (0, 3, 0));
    }
}
