//! Ray casting a [`Scene`] into depth, colour and normals from a camera pose.

use super::scene::{Hit, Scene};
use super::view_cone::ViewCone;
use crate::camera::Camera;
use crate::image::{ColorImage, DepthImage, Image, NormalMap, INVALID};
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

/// The fixed world light of the shading, so colour does not depend on the view.
fn light() -> Vector3<f64> {
    Vector3::new(0.3, 0.5, 1.0).normalize()
}

/// The colour of a hit in [0, 1]³: albedo × (0.55 + 0.45 |n·l|) for the fixed world light l.
pub(crate) fn shade(hit: &Hit) -> [f64; 3] {
    let shade = 0.55 + 0.45 * hit.normal.dot(&light()).abs();
    hit.albedo.map(|a| a * shade)
}

/// What one view of the scene looks like.
#[derive(Clone, Debug)]
pub struct Rendering {
    /// z-depth in metres (0 where nothing is hit or outside the camera's range).
    pub depth: DepthImage,
    /// Shaded colour: albedo × (0.55 + 0.45 |n·l|) for a fixed world light l.
    pub color: ColorImage,
    /// Camera-frame normals facing the camera (NaN where nothing is hit).
    pub normals: NormalMap,
    /// cos of the angle between the viewing ray and the normal (0 where nothing is hit).
    pub cos_incidence: Image<f32>,
    /// The hit behind each pixel.
    pub hits: Vec<Option<Hit>>,
}

/// Renders `scene` seen by `camera` at `pose` (camera-to-world), one ray through each pixel centre.
pub fn render(scene: &Scene, camera: &Camera, pose: &Isometry3<f64>) -> Rendering {
    let (w, h) = (camera.width, camera.height);
    let origin = Point3::from(pose.translation.vector);
    let prepared = scene.prepare();
    let scene = prepared.within(&ViewCone::of_camera(camera, pose, 0.0));
    let hits: Vec<Option<Hit>> = (0..w * h)
        .into_par_iter()
        .with_min_len(256)
        .map(|i| {
            let (u, v) = ((i % w) as f64, (i / w) as f64);
            let dc = camera.ray(u, v);
            let dir = pose.rotation * dc;
            scene
                .intersect(&origin, &dir)
                .filter(|hit| camera.valid_depth(hit.t * dc.z))
        })
        .collect();
    let mut out = Rendering {
        depth: Image::new(w, h),
        color: Image::filled(w, h, [0, 0, 0]),
        normals: Image::filled(w, h, INVALID),
        cos_incidence: Image::new(w, h),
        hits,
    };
    let inv_rot = pose.rotation.inverse();
    for (i, hit) in out.hits.iter().enumerate() {
        let Some(hit) = hit else { continue };
        let (u, v) = ((i % w) as f64, (i / w) as f64);
        let dc = camera.ray(u, v);
        out.depth.data[i] = (hit.t * dc.z) as f32;
        out.color.data[i] = shade(hit).map(|c| (c * 255.0).round().clamp(0.0, 255.0) as u8);
        let nc = inv_rot * hit.normal;
        out.normals.data[i] = [nc.x as f32, nc.y as f32, nc.z as f32];
        out.cos_incidence.data[i] = (-nc.dot(&dc)) as f32;
    }
    out
}
