//! One frame of the simulated sensor, for the tests that run the pipeline on rendered scenes.

use dynamap::slam::camera::Camera;
use dynamap::slam::image::{ColorImage, Image};
use dynamap::slam::synthetic::noise::SensorNoise;
use dynamap::slam::synthetic::render::render;
use dynamap::slam::synthetic::scene::Scene;
use nalgebra::Isometry3;

/// A frame as the sensor gives it: the raw depth at the camera's depth scale and the colour.
pub(crate) type SensorFrame = (Image<u16>, ColorImage);

/// `scene` seen by `cam` at `pose` (camera-to-world) through `noise` as its frame `k`: the raw
/// depth at the camera's depth scale and the colour.
pub(crate) fn sensor_frame(
    scene: &Scene,
    cam: &Camera,
    pose: &Isometry3<f64>,
    noise: &SensorNoise,
    k: usize,
) -> SensorFrame {
    let mut r = render(scene, cam, pose);
    let raw = noise.apply_to(k as u64, &mut r, cam.depth_scale);
    (raw, r.color)
}
