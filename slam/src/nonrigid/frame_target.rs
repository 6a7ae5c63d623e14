//! A depth frame as the target of a registration with a large motion: projective association,
//! and where the target's camera sees through the warped point, the nearest of the frame's points
//! in 3-D (ICP's closest point, Besl and McKay, 1992).
//!
//! A point that the warp carried past the target's outline projects onto the background behind it
//! or onto the sensor's shadow beside the object (no depth). Projective association finds it no
//! partner there, so nothing holds it, and the regulariser carries it on with its neighbours: on
//! DeepDeform's shirt the sleeve that folded inwards was left about 5 cm beyond the sleeve. Seen
//! through, the point cannot be where the warp put it; the nearest surface point is where it is
//! pulled back to. Where the target's depth lies in front of the point instead, the point may be
//! hidden and is left to projective association (which rejects the occluder by the gates).

use super::cloud_target::CloudTarget;
use super::photometric::PhotometricTarget;
use super::register::{DepthTarget, Target};
use crate::image::valid;
use nalgebra::{Point3, Vector3};

/// [`DepthTarget`] with a closest-point fallback ([`CloudTarget`]) for points the target sees
/// through.
pub struct SeenThroughTarget<'a> {
    depth: DepthTarget<'a>,
    /// The frame's points that have a normal (none when `within` is 0: no fallback).
    nearest: Option<CloudTarget>,
    /// The target's depth at the point's pixel must lie this far behind it (metres) for the
    /// point to count as seen through.
    behind: f64,
    /// The nearest point is taken only within this distance (metres).
    within: f64,
    /// The chromaticity term, when given.
    chroma: Option<PhotometricTarget<'a>>,
}

impl<'a> SeenThroughTarget<'a> {
    /// The target of `depth`'s maps. A point counts as seen through where its pixel has no depth
    /// or depth more than `behind` beyond it; it then takes the nearest of the frame's points
    /// within `within`, or none.
    pub fn new(depth: DepthTarget<'a>, behind: f64, within: f64) -> Self {
        let vector = |v: &[f32; 3]| Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64);
        let nearest = (within > 0.0).then(|| {
            let points: Vec<_> = depth.vertices.data.iter().map(vector).collect();
            let normals: Vec<_> = depth.normals.data.iter().map(vector).collect();
            // pixels without a vertex or a normal are NaN, which the cloud leaves out
            CloudTarget::new(&points, &normals)
        });
        Self {
            depth,
            nearest,
            behind,
            within,
            chroma: None,
        }
    }

    /// The same target with the chromaticity term `chroma` (module `chroma`).
    pub fn with_chroma(self, chroma: Option<PhotometricTarget<'a>>) -> Self {
        Self { chroma, ..self }
    }

    /// Whether the target's camera sees through `p`: its pixel has no depth, or depth more than
    /// `behind` beyond it. `None` outside the image.
    fn sees_through(&self, p: &Vector3<f64>) -> Option<bool> {
        let (x, y) = self.depth.camera.project_to_pixel(&Point3::from(*p))?;
        let v = self.depth.vertices.data[y * self.depth.vertices.width + x];
        Some(!valid(&v) || v[2] as f64 > p.z + self.behind)
    }
}

impl Target for SeenThroughTarget<'_> {
    fn associate(&self, p: &Vector3<f64>) -> Option<(Vector3<f64>, Vector3<f64>)> {
        if !self.sees_through(p)? {
            return self.depth.associate(p);
        }
        let (q, n) = self.nearest.as_ref()?.associate(p)?;
        ((q - p).norm_squared() <= self.within * self.within).then_some((q, n))
    }

    fn chroma(&self) -> Option<PhotometricTarget<'_>> {
        self.chroma
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use crate::image::{Image, NormalMap, VertexMap, INVALID};

    /// A 40 × 30 camera (f = 100 px: a pixel is 1 cm at 1 m) looking at a plate at 1 m over
    /// columns below 20, a wall at 3 m over columns 22 and beyond, and no depth between (the
    /// sensor's shadow).
    fn scene() -> (Camera, VertexMap, NormalMap) {
        let camera = Camera::new(100.0, 100.0, 20.0, 15.0, 40, 30);
        let mut vertices = Image::filled(40, 30, INVALID);
        let mut normals = Image::filled(40, 30, INVALID);
        for y in 0..30 {
            for x in 0..40 {
                let z = match x {
                    0..20 => 1.0,
                    22.. => 3.0,
                    _ => continue,
                };
                let p = camera.back_project(x as f64, y as f64, z);
                vertices.data[y * 40 + x] = [p.x as f32, p.y as f32, p.z as f32];
                normals.data[y * 40 + x] = [0.0, 0.0, -1.0];
            }
        }
        (camera, vertices, normals)
    }

    #[test]
    fn a_point_seen_through_takes_the_nearest_point_and_a_hidden_one_does_not() {
        let (camera, vertices, normals) = scene();
        let depth = DepthTarget {
            camera: &camera,
            vertices: &vertices,
            normals: &normals,
        };
        let target = SeenThroughTarget::new(depth, 0.1, 0.05);
        let at = |x: f64, z: f64| camera.back_project(x, 15.0, z).coords;
        // on the plate: its own pixel, as projective association gives it
        let on = at(10.0, 1.02);
        assert_eq!(target.associate(&on), depth.associate(&on));
        // 1.6 cm past the plate's edge, over the shadow: the edge's column (19) on that row
        let past = at(20.6, 1.0);
        let (q, n) = target.associate(&past).expect("the edge is within 5 cm");
        assert!((q - at(19.0, 1.0)).norm() < 1e-6 && n == -Vector3::z());
        // over the wall, 2 m in front of it: seen through as well
        let (q, _) = target
            .associate(&at(22.4, 1.0))
            .expect("the edge is 3.4 cm away");
        assert!((q - at(19.0, 1.0)).norm() < 1e-6);
        // 7 cm past the edge: nothing within 5 cm
        assert_eq!(target.associate(&at(26.0, 1.0)), None);
        // behind the plate: possibly hidden, left to projective association and its gates
        let hidden = at(10.0, 1.5);
        assert_eq!(target.associate(&hidden), depth.associate(&hidden));
        // outside the image
        assert_eq!(target.associate(&Vector3::new(5.0, 0.0, 1.0)), None);
    }
}
