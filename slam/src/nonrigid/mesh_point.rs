//! A point on a triangle mesh between its vertices: a weighted sum of the corners of one
//! triangle (a vertex, a point on an edge, or inside a face). Two meshes of one surface meshed
//! apart share no vertex, so a correspondence that must land on a vertex is off by up to half the
//! target's spacing; one that lands on a [`MeshPoint`] is not.

use nalgebra::Vector3;

/// A point on a mesh: Σ wₖ vₖ over up to three vertices, the weights non-negative and summing
/// to one (barycentric coordinates).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeshPoint {
    /// The vertices it is made of (repeated where fewer than three carry weight).
    pub vertices: [u32; 3],
    /// Their weights.
    pub weights: [f64; 3],
}

impl MeshPoint {
    /// The vertex `v` itself.
    pub fn vertex(v: u32) -> Self {
        Self {
            vertices: [v; 3],
            weights: [1.0, 0.0, 0.0],
        }
    }

    /// The point a share `t` of the way from vertex `a` to vertex `b`.
    pub fn on_edge(a: u32, b: u32, t: f64) -> Self {
        Self {
            vertices: [a, b, a],
            weights: [1.0 - t, t, 0.0],
        }
    }

    /// The point of triangle `face` at barycentric `(u, v)`: (1 − u − v) f₀ + u f₁ + v f₂.
    pub fn in_face(face: [u32; 3], u: f64, v: f64) -> Self {
        Self {
            vertices: face,
            weights: [1.0 - u - v, u, v],
        }
    }

    /// The weighted sum of `values` (positions, normals, descriptors) at its vertices.
    pub fn blend(&self, values: &[Vector3<f64>]) -> Vector3<f64> {
        self.vertices
            .iter()
            .zip(&self.weights)
            .map(|(&v, &w)| values[v as usize] * w)
            .sum()
    }

    /// The unit normal blended from the vertices' `normals`; the heaviest vertex's where the
    /// blend vanishes (normals that cancel across a crease).
    pub fn normal(&self, normals: &[Vector3<f64>]) -> Vector3<f64> {
        self.blend(normals)
            .try_normalize(1e-12)
            .unwrap_or_else(|| normals[self.heaviest() as usize])
    }

    /// The point of triangle `face` nearest `x`, with `table` the values at the vertices
    /// (positions, descriptors) interpolated linearly over it, and the squared distance
    /// ([`nearest_in_triangle`]).
    pub fn nearest_in_face<const N: usize>(
        face: [u32; 3],
        table: &[[f64; N]],
        x: &[f64; N],
    ) -> (Self, f64) {
        let corners = face.map(|v| &table[v as usize]);
        let (weights, d2) = nearest_in_triangle(corners, x);
        (
            Self {
                vertices: face,
                weights,
            },
            d2,
        )
    }

    /// The vertex of largest weight (the first of equals).
    pub fn heaviest(&self) -> u32 {
        let mut k = 0;
        for j in 1..3 {
            if self.weights[j] > self.weights[k] {
                k = j;
            }
        }
        self.vertices[k]
    }
}

/// The point of the triangle with `corners` nearest `x`, in any dimension (positions, or
/// descriptors interpolated linearly over the triangle): its barycentric weights and squared
/// distance. The least-squares weights (1 − u − v, u, v) where they fall inside the triangle,
/// else the nearest point of its nearest edge; a degenerate triangle is taken by its edges.
pub fn nearest_in_triangle<const N: usize>(
    corners: [&[f64; N]; 3],
    x: &[f64; N],
) -> ([f64; 3], f64) {
    let [c0, c1, c2] = corners;
    // residual r(u, v) = a + u e1 + v e2
    let a: [f64; N] = std::array::from_fn(|k| c0[k] - x[k]);
    let e1: [f64; N] = std::array::from_fn(|k| c1[k] - c0[k]);
    let e2: [f64; N] = std::array::from_fn(|k| c2[k] - c0[k]);
    let (g11, g12, g22) = (dot(&e1, &e1), dot(&e1, &e2), dot(&e2, &e2));
    let (b1, b2) = (-dot(&a, &e1), -dot(&a, &e2));
    let det = g11 * g22 - g12 * g12;
    if det > 1e-12 * g11 * g22 {
        let (u, v) = ((b1 * g22 - b2 * g12) / det, (g11 * b2 - g12 * b1) / det);
        if u >= 0.0 && v >= 0.0 && u + v <= 1.0 {
            let cost = dot(&a, &a) - u * b1 - v * b2;
            return ([1.0 - u - v, u, v], cost.max(0.0));
        }
    }
    [(0, 1), (0, 2), (1, 2)]
        .into_iter()
        .map(|(i, j)| {
            let (p, q) = (corners[i], corners[j]);
            let from: [f64; N] = std::array::from_fn(|k| p[k] - x[k]);
            let along: [f64; N] = std::array::from_fn(|k| q[k] - p[k]);
            let length = dot(&along, &along);
            let t = if length > 0.0 {
                (-dot(&from, &along) / length).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let r: [f64; N] = std::array::from_fn(|k| from[k] + t * along[k]);
            let mut w = [0.0; 3];
            w[i] = 1.0 - t;
            w[j] = t;
            (w, dot(&r, &r))
        })
        .min_by(|x, y| x.1.total_cmp(&y.1))
        .expect("a triangle has three edges")
}

/// The triangles around each of `vertices` vertices, by their index in `faces` (whose vertices
/// must all be below `vertices`).
pub(crate) fn faces_around(faces: &[[u32; 3]], vertices: usize) -> Vec<Vec<u32>> {
    let mut out = vec![Vec::new(); vertices];
    for (f, face) in faces.iter().enumerate() {
        for &v in face {
            out[v as usize].push(f as u32);
        }
    }
    out
}

fn dot<const N: usize>(a: &[f64; N], b: &[f64; N]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_blends_its_corners_by_their_weights() {
        let p = [Vector3::zeros(), Vector3::x(), Vector3::y()];
        let inside = MeshPoint::in_face([0, 1, 2], 0.25, 0.5);
        assert!((inside.blend(&p) - Vector3::new(0.25, 0.5, 0.0)).norm() < 1e-15);
        assert_eq!(inside.heaviest(), 2);
        let edge = MeshPoint::on_edge(1, 2, 0.75);
        assert!((edge.blend(&p) - Vector3::new(0.25, 0.75, 0.0)).norm() < 1e-15);
        assert_eq!(MeshPoint::vertex(1).blend(&p), Vector3::x());
        // opposite normals cancel halfway: the first vertex's is taken
        let n = [Vector3::z(), -Vector3::z(), Vector3::z()];
        assert_eq!(MeshPoint::on_edge(0, 1, 0.5).normal(&n), Vector3::z());
        assert_eq!(MeshPoint::on_edge(0, 1, 0.75).normal(&n), -Vector3::z());
    }

    #[test]
    fn the_nearest_point_of_a_triangle_is_inside_on_an_edge_or_a_corner() {
        let (a, b, c) = ([0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0]);
        let near = |x: [f64; 3]| nearest_in_triangle([&a, &b, &c], &x);
        // above the inside: the foot of the perpendicular
        let (w, d2) = near([0.5, 0.5, 3.0]);
        assert!(
            (w[0] - 0.5).abs() < 1e-12 && (w[1] - 0.25).abs() < 1e-12,
            "{w:?}"
        );
        assert!((d2 - 9.0).abs() < 1e-12);
        // beyond the hypotenuse: its midpoint
        let (w, d2) = near([2.0, 2.0, 0.0]);
        assert!(
            (w[1] - 0.5).abs() < 1e-12 && (w[2] - 0.5).abs() < 1e-12,
            "{w:?}"
        );
        assert!((d2 - 2.0).abs() < 1e-12);
        // beyond a corner: the corner
        let (w, d2) = near([-1.0, -1.0, 0.0]);
        assert_eq!(w, [1.0, 0.0, 0.0]);
        assert!((d2 - 2.0).abs() < 1e-12);
        // a triangle collapsed onto a segment is taken by its edges
        let (w, d2) = nearest_in_triangle([&a, &b, &b], &[1.0, 1.0, 0.0]);
        assert!(
            (w[0] - 0.5).abs() < 1e-12 && (d2 - 1.0).abs() < 1e-12,
            "{w:?}"
        );
    }
}
