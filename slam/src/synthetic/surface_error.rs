//! How far a reconstructed mesh lies from the scene it was rendered from. A map whose sub-maps
//! did not follow a loop's correction shows a wall twice where the camera came back to it, a few
//! centimetres apart; against the true scene, the second copy's vertices lie off the surface
//! (issue 24, "one wall, not two").
//!
//! Each vertex v with unit normal n is measured along its normal line: a ray from v − r n along
//! n and one from v + r n along −n (r the reach) find the scene's surface at t, and the vertex lies
//! |t − r| from it. Along the normal this is the point-to-plane distance for the walls, floors
//! and tables the scenes are made of.

use super::scene::PreparedScene;
use crate::eval::Stats;
use crate::mesh::Mesh;
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

/// Distances from a mesh's vertices to the scene's surface ([`surface_error`]).
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceError {
    /// The distances of the vertices that found the surface within the reach, metres (`None`
    /// when none did).
    pub distances: Option<Stats>,
    /// Vertices measured (those with a normal).
    pub vertices: usize,
    /// Of them, those that found no surface within the reach along their normal line.
    pub unmatched: usize,
    /// Of them, those farther than the tolerance from the surface, or unmatched.
    pub off: usize,
}

impl SurfaceError {
    /// The share of the measured vertices that lie off the surface (0 for an empty mesh).
    pub fn off_fraction(&self) -> f64 {
        if self.vertices == 0 {
            0.0
        } else {
            self.off as f64 / self.vertices as f64
        }
    }
}

/// The distance from `p` to the scene's surface along the line through `p` with unit direction
/// `n`, when the surface crosses that line within `reach` of `p` (the nearer crossing).
pub(crate) fn distance_along(
    scene: &PreparedScene,
    p: &Point3<f64>,
    n: &Vector3<f64>,
    reach: f64,
) -> Option<f64> {
    let from = |side: f64| {
        let dir = n * side;
        let origin = p - dir * reach;
        let (t, _, _) = scene.surface(&origin, &dir)?;
        let d = (t - reach).abs();
        (d <= reach).then_some(d)
    };
    match (from(1.0), from(-1.0)) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}

/// Measures `mesh` (its vertices moved by `to_scene` into the scene's frame) against `scene`:
/// each vertex's distance to the surface along its normal line (within `reach`), and how many lie
/// farther than `tolerance` or find no surface. Vertex normals are computed from the faces when
/// the mesh has none; vertices without a normal are not measured.
pub fn surface_error(
    mesh: &Mesh,
    scene: &PreparedScene,
    to_scene: &Isometry3<f64>,
    reach: f64,
    tolerance: f64,
) -> SurfaceError {
    let computed;
    let mesh = if mesh.normals.len() == mesh.vertices.len() {
        mesh
    } else {
        let mut m = mesh.clone();
        m.compute_normals();
        computed = m;
        &computed
    };
    let measured: Vec<Option<f64>> = mesh
        .vertices
        .par_iter()
        .zip(&mesh.normals)
        .filter_map(|(v, n)| {
            let n = n.cast::<f64>().try_normalize(1e-12)?;
            let p = to_scene * v.cast::<f64>();
            Some(distance_along(scene, &p, &(to_scene.rotation * n), reach))
        })
        .collect();
    let found: Vec<f64> = measured.iter().flatten().copied().collect();
    let unmatched = measured.len() - found.len();
    SurfaceError {
        distances: (!found.is_empty()).then(|| Stats::of(&found)),
        vertices: measured.len(),
        unmatched,
        off: unmatched + found.iter().filter(|&&d| d > tolerance).count(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::scene::{Scene, Shape};
    use crate::synthetic::texture::Texture;

    /// A floor (the plane z = 0 as a large box's top) and a mesh of two squares: one on the floor
    /// and one 3 cm above it, as a wall fused twice would be.
    #[test]
    fn a_doubled_surface_is_half_off() {
        let mut scene = Scene::default();
        scene.add(
            Shape::Cuboid {
                half: Vector3::new(5.0, 5.0, 0.5),
            },
            Isometry3::translation(0.0, 0.0, -0.5),
            Texture::plain([0.5; 3]),
        );
        let prepared = scene.prepare();
        let mut mesh = Mesh::default();
        for (k, z) in [0.002f32, 0.03].into_iter().enumerate() {
            let base = 4 * k as u32;
            for (x, y) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)] {
                mesh.vertices.push(Point3::new(x, y, z));
            }
            mesh.faces.push([base, base + 1, base + 2]);
            mesh.faces.push([base, base + 2, base + 3]);
        }
        let e = surface_error(&mesh, &prepared, &Isometry3::identity(), 0.05, 0.01);
        assert_eq!((e.vertices, e.unmatched, e.off), (8, 0, 4), "{e:?}");
        let d = e.distances.unwrap();
        assert!(
            (d.min - 0.002).abs() < 1e-6 && (d.max - 0.03).abs() < 1e-6,
            "{d:?}"
        );
        // moved 10 cm up, every vertex is beyond the reach
        let up = Isometry3::translation(0.0, 0.0, 0.1);
        let e = surface_error(&mesh, &prepared, &up, 0.05, 0.01);
        assert_eq!((e.unmatched, e.off), (8, 8), "{e:?}");
        assert_eq!(e.off_fraction(), 1.0);
    }
}
