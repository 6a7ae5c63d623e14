//! The frame the photometric term's reference intensities come from (module `photometric`):
//! a tracked frame's intensity ratios, vertex and normal maps, and the node motions it was
//! tracked with, kept for a few frames.

use super::graph::{Binding, DeformationGraph};
use super::photometric::RatioImage;
use super::register::{DepthTarget, Target};
use crate::camera::Camera;
use crate::image::{NormalMap, VertexMap};
use dynamap_residuals::deform::{blend, transform_point, transform_vector, MAX_NEIGHBOURS};
use nalgebra::{DualQuaternion, Vector3};
use rayon::prelude::*;

/// The frame the reference intensities are taken from: its ratio image, vertex and normal maps,
/// and the node motions it was tracked with. Data points re-sampled since are carried into it by those
/// motions, so every point bound to nodes that existed then has a reference.
#[derive(Default)]
pub struct ReferenceFrame {
    ratio: RatioImage,
    vertices: VertexMap,
    normals: NormalMap,
    camera: Option<Camera>,
    motions: Vec<DualQuaternion<f64>>,
    /// Frames tracked since it was taken.
    pub age: usize,
}

impl ReferenceFrame {
    /// Takes the frame just tracked (its ratio image, vertices, normals and intrinsics, at the
    /// data level) with the graph's current motions.
    pub fn take(
        &mut self,
        ratio: &RatioImage,
        (vertices, normals): (&VertexMap, &NormalMap),
        camera: &Camera,
        graph: &DeformationGraph,
    ) {
        self.ratio.clone_from(ratio);
        self.vertices.clone_from(vertices);
        self.normals.clone_from(normals);
        self.camera = Some(*camera);
        self.motions.clear();
        self.motions.extend(graph.nodes.iter().map(|n| n.motion));
        self.age = 0;
    }

    /// Forgets the frame: no point has a reference until the next is taken.
    pub fn clear(&mut self) {
        self.camera = None;
    }

    /// Each point's ratio in this frame, where it was seen there: bound only to nodes that
    /// existed, facing the camera, and the frame's depth at its pixel within `gate` of it. NaN
    /// elsewhere.
    pub fn intensities(
        &self,
        points: &[Vector3<f64>],
        normals: &[Vector3<f64>],
        bindings: &[Binding],
        gate: f64,
        out: &mut Vec<f32>,
    ) {
        out.clear();
        let Some(camera) = &self.camera else {
            out.resize(points.len(), f32::NAN);
            return;
        };
        let live = self.ratio.live(camera);
        let depth = DepthTarget {
            camera,
            vertices: &self.vertices,
            normals: &self.normals,
        };
        out.par_extend(
            points
                .par_iter()
                .zip(normals)
                .zip(bindings)
                .map(|((v, n), b)| {
                    let nodes = &b.nodes[..b.count];
                    if nodes.iter().any(|&k| k as usize >= self.motions.len()) {
                        return f32::NAN;
                    }
                    let mut dqs = [DualQuaternion::identity(); MAX_NEIGHBOURS];
                    for (o, &k) in dqs.iter_mut().zip(nodes) {
                        *o = self.motions[k as usize];
                    }
                    let (q, _) = blend(&dqs[..b.count], &b.weights[..b.count]);
                    let (p, n) = (transform_point(&q, v), transform_vector(&q, n));
                    let seen = n.dot(&p) < 0.0
                        && depth
                            .associate(&p)
                            .is_some_and(|(x, _)| (x - p).norm_squared() <= gate * gate);
                    match seen.then(|| live.sample(&p)).flatten() {
                        Some((value, _)) => value as f32,
                        None => f32::NAN,
                    }
                }),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nonrigid::photometric::tests::image;

    /// A reference frame of a textured wall 1 m ahead, taken with a graph over a patch of it:
    /// a point on the wall gets the frame's ratio where it projects; one facing away, one off
    /// the wall's depth, and one bound to a node added after the frame get none.
    #[test]
    fn references_are_taken_where_the_frame_saw_the_point() {
        use crate::nonrigid::graph::GraphParams;
        let camera = Camera::tum_default().level(1);
        let gray = image(camera.width, camera.height);
        let mut ratio = RatioImage::default();
        ratio.compute(&gray, 4);
        let (mut vertices, normals) = (
            VertexMap::filled(camera.width, camera.height, [0.0; 3]),
            NormalMap::filled(camera.width, camera.height, [0.0, 0.0, -1.0]),
        );
        for y in 0..camera.height {
            for x in 0..camera.width {
                let p = camera.back_project(x as f64, y as f64, 1.0);
                vertices.set(x, y, [p.x as f32, p.y as f32, p.z as f32]);
            }
        }
        let patch: Vec<Vector3<f64>> = (0..100)
            .map(|i| Vector3::new((i % 10) as f64 * 0.02, (i / 10) as f64 * 0.02, 1.0))
            .collect();
        let params = GraphParams {
            spacing: 0.05,
            ..GraphParams::default()
        };
        let mut graph = DeformationGraph::sample(&patch, params).unwrap();
        let mut frame = ReferenceFrame::default();
        frame.take(&ratio, (&vertices, &normals), &camera, &graph);
        // a node far off the patch, added after the frame was taken
        let away = Vector3::new(0.5, 0.5, 1.0);
        assert_eq!(graph.extend(&[away]), 1);
        let toward = -Vector3::z();
        let points = [
            patch[55],
            patch[55],
            patch[55] + Vector3::new(0.0, 0.0, 0.2),
            away,
        ];
        let normals_in = [toward, -toward, toward, toward];
        let bindings = graph.bind_all(&points);
        let mut out = Vec::new();
        frame.intensities(&points, &normals_in, &bindings, 0.04, &mut out);
        let (expect, _) = ratio.live(&camera).sample(&patch[55]).unwrap();
        assert!(
            (out[0] as f64 - expect).abs() < 1e-6,
            "{} against {expect}",
            out[0]
        );
        assert!(
            out[1].is_nan() && out[2].is_nan() && out[3].is_nan(),
            "{out:?}"
        );
        // forgotten, nothing has a reference
        frame.clear();
        frame.intensities(&points, &normals_in, &bindings, 0.04, &mut out);
        assert!(out.iter().all(|r| r.is_nan()));
    }
}
