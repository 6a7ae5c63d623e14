//! A triangle mesh as a registration target: each point is associated with the nearest point of
//! the surface, not of the vertices. Closest point to a vertex pulls every point towards the
//! target's vertices along the surface; where the two meshes were meshed apart that pull is up
//! to half the target's spacing, and the point-to-point term follows it.

use super::mesh_point::{faces_around, MeshPoint};
use super::register::{Samples, Target};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Vector3;

/// How many times the search for the nearest point moves on to the triangles around another
/// vertex (see [`MeshTarget::nearest`]).
const WALK: usize = 3;

/// A mesh with vertex normals, associated by the nearest point of its triangles (normal blended
/// from the corners'), searched from the vertex nearest the point.
pub struct MeshTarget {
    points: Vec<Vector3<f64>>,
    /// The same as arrays, for the nearest point of a triangle.
    coords: Vec<[f64; 3]>,
    normals: Vec<Vector3<f64>>,
    faces: Vec<[u32; 3]>,
    /// The faces around each vertex.
    faces_of: Vec<Vec<u32>>,
    /// Finite vertices, by their index in `points`.
    tree: ImmutableKdTree<f64, 3>,
    kept: Vec<u32>,
}

impl MeshTarget {
    /// A target from a mesh's vertices, unit normals and triangles. Non-finite vertices and the
    /// triangles that use them are left out, as are triangles naming a vertex it does not have.
    pub fn new(points: &[Vector3<f64>], normals: &[Vector3<f64>], faces: &[[u32; 3]]) -> Self {
        let n = points.len().min(normals.len());
        let finite = |v: usize| {
            v < n
                && points[v]
                    .iter()
                    .chain(normals[v].iter())
                    .all(|x| x.is_finite())
        };
        let kept: Vec<u32> = (0..n).filter(|&v| finite(v)).map(|v| v as u32).collect();
        let faces: Vec<[u32; 3]> = faces
            .iter()
            .filter(|f| f.iter().all(|&v| finite(v as usize)))
            .copied()
            .collect();
        let faces_of = faces_around(&faces, n);
        let coords: Vec<[f64; 3]> = points[..n].iter().map(|&p| p.into()).collect();
        let finite_coords: Vec<[f64; 3]> = kept.iter().map(|&v| coords[v as usize]).collect();
        Self {
            tree: ImmutableKdTree::new_from_slice(&finite_coords),
            kept,
            coords,
            points: points[..n].to_vec(),
            normals: normals[..n].to_vec(),
            faces,
            faces_of,
        }
    }

    /// The nearest point of the surface to `p`, or `None` for a target with no finite vertex:
    /// searched over the triangles around the nearest vertex, then around the vertices of the
    /// best point so far while it lies on the rim of the triangles searched (three times at
    /// most), so that a point nearest a triangle that does not touch the nearest vertex finds it.
    pub fn nearest(&self, p: &Vector3<f64>) -> Option<MeshPoint> {
        if self.kept.is_empty() {
            return None;
        }
        let x: [f64; 3] = (*p).into();
        let near = self.tree.nearest_one::<SquaredEuclidean>(&x);
        let mut centre = self.kept[near.item as usize];
        let mut best = (MeshPoint::vertex(centre), near.distance);
        for _ in 0..WALK {
            for &f in &self.faces_of[centre as usize] {
                let fit = MeshPoint::nearest_in_face(self.faces[f as usize], &self.coords, &x);
                if fit.1 < best.1 {
                    best = fit;
                }
            }
            // inside the searched triangles where it still weighs on the centre
            let m = best.0;
            if (0..3).any(|k| m.vertices[k] == centre && m.weights[k] > 0.0) {
                break;
            }
            centre = m.heaviest();
        }
        Some(best.0)
    }
}

impl Target for MeshTarget {
    fn associate(&self, p: &Vector3<f64>) -> Option<(Vector3<f64>, Vector3<f64>)> {
        let m = self.nearest(p)?;
        Some((m.blend(&self.points), m.normal(&self.normals)))
    }

    fn samples(&self) -> Option<Samples<'_>> {
        Some((&self.points, &self.normals))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    type Square = (Vec<Vector3<f64>>, Vec<Vector3<f64>>, Vec<[u32; 3]>);

    /// A flat square of 2 × 2 cells, spacing 1, normals +z.
    fn square() -> Square {
        let points: Vec<Vector3<f64>> = (0..9)
            .map(|k| Vector3::new((k % 3) as f64, (k / 3) as f64, 0.0))
            .collect();
        let mut faces = Vec::new();
        for j in 0..2u32 {
            for i in 0..2u32 {
                let v = j * 3 + i;
                faces.push([v, v + 1, v + 4]);
                faces.push([v, v + 4, v + 3]);
            }
        }
        (points, vec![Vector3::z(); 9], faces)
    }

    #[test]
    fn a_point_is_associated_with_the_surface_below_it_not_a_vertex() {
        let (points, normals, faces) = square();
        let target = MeshTarget::new(&points, &normals, &faces);
        let (q, n) = target.associate(&Vector3::new(0.7, 1.2, 0.4)).unwrap();
        assert!((q - Vector3::new(0.7, 1.2, 0.0)).norm() < 1e-12, "{q}");
        assert_eq!(n, Vector3::z());
        // off the side: the nearest point of the rim
        let (q, _) = target.associate(&Vector3::new(2.5, 0.5, 0.0)).unwrap();
        assert!((q - Vector3::new(2.0, 0.5, 0.0)).norm() < 1e-12, "{q}");
    }

    #[test]
    fn non_finite_vertices_and_their_triangles_are_left_out() {
        let (mut points, normals, faces) = square();
        points[4] = Vector3::new(f64::NAN, 0.0, 0.0);
        let target = MeshTarget::new(&points, &normals, &faces);
        let (q, _) = target.associate(&Vector3::new(1.0, 1.0, 1.0)).unwrap();
        assert!(q.iter().all(|x| x.is_finite()));
        assert!((q - Vector3::new(1.0, 1.0, 0.0)).norm() > 0.4, "{q}");
        let empty = MeshTarget::new(&[], &[], &[]);
        assert!(empty.associate(&Vector3::zeros()).is_none());
        // a face naming a vertex that is not there is dropped
        let target = MeshTarget::new(&points[..3], &normals[..3], &[[0, 1, 7]]);
        assert!(target.associate(&Vector3::zeros()).is_some());
    }
}
