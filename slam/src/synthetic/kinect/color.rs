//! The colour image of the sensor: a moving exposure, auto-exposure gain, vignetting, optics blur,
//! noise and 8-bit quantisation.
//!
//! Motion blur is the mean of the sharp image along each pixel's motion during the exposure: with
//! X the point seen at pixel x at the middle of the exposure and x₀, x₁ where it projects at its
//! start and end, the recorded value is the mean of the sharp image at x − (x₁ − x₀) s for s evenly
//! spaced in [−½, ½] (one sample per pixel of motion, up to nine): the first-order, depth-aware
//! blur of a camera moving during its exposure.
//!
//! The intensity I (8-bit levels) then becomes g(t) (1 − v r²/r_c²) I + n, with g the drifting gain,
//! v the vignetting at the corners (r the distance from the principal point, r_c that of the
//! farthest corner) and n Gaussian with variance a + b I (read noise and shot noise).

use super::fields::{blur, mix, row_rng};
use super::{pose_at, project, KinectModel, Recorder};
use crate::camera::Camera;
use crate::image::{ColorImage, Image};
use crate::io::trajectory::Trajectory;
use crate::synthetic::render::shade;
use crate::synthetic::scene::PreparedScene;
use nalgebra::{Isometry3, Point3, Vector3};
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

/// Most samples along a pixel's motion.
const MAX_BLUR_SAMPLES: usize = 9;

/// A sharp rendering as three planes of 8-bit levels, with each pixel's camera-frame point.
struct Sharp {
    planes: [Vec<f32>; 3],
    points: Vec<Option<Vector3<f64>>>,
}

/// Captures the colour of `scene` exposed around time `t` (the camera moving along `trajectory`).
pub fn capture(
    rec: &Recorder,
    scene: &PreparedScene,
    trajectory: &Trajectory,
    t: f64,
    frame: usize,
) -> ColorImage {
    let (model, camera) = (rec.model, &rec.camera);
    let (w, h) = (camera.width, camera.height);
    let pose = pose_at(trajectory, t);
    let sharp = render_sharp(rec, scene, &pose);
    let half = 0.5 * model.exposure;
    let start = pose_at(trajectory, t - half).inverse() * pose;
    let end = pose_at(trajectory, t + half).inverse() * pose;
    let mut planes = motion_blur(model, camera, &sharp, &start, &end);
    let sigma = model.optics_blur * KinectModel::pixel_scale(w);
    for p in planes.iter_mut() {
        blur(p, w, h, sigma);
    }
    expose(
        model,
        camera,
        &planes,
        model.gain(t),
        mix(model.seed ^ mix(frame as u64 ^ 0xC0)),
    )
}

/// The scene through the distorted lens at `pose`, one ray per pixel centre.
fn render_sharp(rec: &Recorder, scene: &PreparedScene, pose: &Isometry3<f64>) -> Sharp {
    let (w, h) = (rec.camera.width, rec.camera.height);
    let origin = Point3::from(pose.translation.vector);
    let scene = &scene.within(&rec.rays.cone(pose, 0.0));
    let px: Vec<([f32; 3], Option<Vector3<f64>>)> = (0..w * h)
        .into_par_iter()
        .with_min_len(256)
        .map(|i| {
            let Some(ray) = rec.rays.at_pixel(i) else {
                return ([0.0; 3], None);
            };
            let dir = pose.rotation * ray.normalize();
            match scene.intersect(&origin, &dir) {
                Some(hit) => {
                    let z = (pose.inverse() * hit.point).z;
                    (shade(&hit).map(|c| (c * 255.0) as f32), Some(ray * z))
                }
                None => ([0.0; 3], None),
            }
        })
        .collect();
    let planes = [0, 1, 2].map(|c| px.iter().map(|p| p.0[c]).collect());
    Sharp {
        planes,
        points: px.into_iter().map(|p| p.1).collect(),
    }
}

/// Averages the sharp image along each pixel's motion between the exposure's start and end
/// (`start`, `end`: from the middle camera frame to the start and end ones).
fn motion_blur(
    model: &KinectModel,
    camera: &Camera,
    sharp: &Sharp,
    start: &Isometry3<f64>,
    end: &Isometry3<f64>,
) -> [Vec<f32>; 3] {
    let (w, h) = (camera.width, camera.height);
    let samples: Vec<[f32; 3]> = (0..w * h)
        .into_par_iter()
        .with_min_len(256)
        .map(|i| {
            let here = [0, 1, 2].map(|c| sharp.planes[c][i]);
            let Some(p) = sharp.points[i] else {
                return here;
            };
            let a = project(camera, &model.distortion, &(start * Point3::from(p)).coords);
            let b = project(camera, &model.distortion, &(end * Point3::from(p)).coords);
            let (Some(a), Some(b)) = (a, b) else {
                return here;
            };
            let m = (b.0 - a.0, b.1 - a.1);
            let len = m.0.hypot(m.1);
            let n = ((len.ceil() as usize) + 1).min(MAX_BLUR_SAMPLES);
            if n < 2 {
                return here;
            }
            let (u, v) = ((i % w) as f64, (i / w) as f64);
            let mut acc = [0f32; 3];
            for j in 0..n {
                let s = j as f64 / (n - 1) as f64 - 0.5;
                let at = Bilinear::new(w, h, u - m.0 * s, v - m.1 * s);
                for (a, plane) in acc.iter_mut().zip(&sharp.planes) {
                    *a += at.sample(plane);
                }
            }
            acc.map(|a| a / n as f32)
        })
        .collect();
    [0, 1, 2].map(|c| samples.iter().map(|s| s[c]).collect())
}

/// Where a bilinear lookup at (x, y), clamped to the image, reads a plane: the four pixels and
/// the weights, found once and used for each colour plane.
struct Bilinear {
    top: (usize, usize),
    bottom: (usize, usize),
    fx: f32,
    fy: f32,
}

impl Bilinear {
    fn new(w: usize, h: usize, x: f64, y: f64) -> Self {
        let x = x.clamp(0.0, (w - 1) as f64);
        let y = y.clamp(0.0, (h - 1) as f64);
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        Self {
            top: (y0 * w + x0, y0 * w + x1),
            bottom: (y1 * w + x0, y1 * w + x1),
            fx: (x - x0 as f64) as f32,
            fy: (y - y0 as f64) as f32,
        }
    }

    /// The plane's value there.
    fn sample(&self, plane: &[f32]) -> f32 {
        let (fx, fy) = (self.fx, self.fy);
        let top = plane[self.top.0] * (1.0 - fx) + plane[self.top.1] * fx;
        let bottom = plane[self.bottom.0] * (1.0 - fx) + plane[self.bottom.1] * fx;
        top * (1.0 - fy) + bottom * fy
    }
}

/// Gain, vignetting, noise and 8-bit quantisation.
fn expose(
    model: &KinectModel,
    camera: &Camera,
    planes: &[Vec<f32>; 3],
    gain: f64,
    seed: u64,
) -> ColorImage {
    let (w, h) = (camera.width, camera.height);
    let corner2 = [
        (0.0, 0.0),
        (w as f64, 0.0),
        (0.0, h as f64),
        (w as f64, h as f64),
    ]
    .iter()
    .map(|&(x, y)| (x - camera.cx).powi(2) + (y - camera.cy).powi(2))
    .fold(0.0, f64::max);
    let (a, b) = model.color_noise;
    let mut out: ColorImage = Image::filled(w, h, [0, 0, 0]);
    out.data.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
        let mut rng = row_rng(seed, 1, v);
        for (u, px) in row.iter_mut().enumerate() {
            let (du, dv) = (u as f64 - camera.cx, v as f64 - camera.cy);
            let scale = gain * (1.0 - model.vignetting * (du * du + dv * dv) / corner2);
            for (c, out) in px.iter_mut().enumerate() {
                let i = planes[c][v * w + u] as f64 * scale;
                let n: f64 = StandardNormal.sample(&mut rng);
                let noisy = i + (a + b * i.max(0.0)).sqrt() * n;
                *out = noisy.round().clamp(0.0, 255.0) as u8;
            }
        }
    });
    out
}
