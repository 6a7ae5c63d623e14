//! A structured-light RGB-D sensor (Kinect v1 / PrimeSense) as the literature describes it, for
//! rendered sequences as hard to track as real ones.
//!
//! - [`depth`]: depth from quantised disparity, z = f_ir b / d with d in 1/8-pixel steps, so the
//!   depth step grows as z² / (8 f_ir b) (Khoshelham & Elberink, *Accuracy and resolution of Kinect
//!   depth data*, Sensors 2012); Gaussian disparity noise, part of it correlated between
//!   neighbours as block matching makes it; a lateral jitter of where each pixel samples the scene
//!   (Handa et al., *A benchmark for RGB-D visual odometry, 3D reconstruction and SLAM*, ICRA 2014,
//!   whose ICL-NUIM noise model jitters pixels the same way), so depth edges come out ragged; holes
//!   where the projector or the IR camera cannot see the point (the projector's shadow beside a
//!   near object, on the side away from the projector), at grazing incidence (Nguyen, Izadi &
//!   Lovell 2012), out of range, in a small random fraction of blobs and in the border the IR
//!   camera's narrower field does not cover; flying pixels of mixed depth at discontinuities.
//! - [`color`]: the colour camera exposes while the camera moves (motion blur), its auto-exposure
//!   gain drifts smoothly by up to [`KinectModel::gain_drift`], the lens darkens the corners
//!   (vignetting), optics blur, shot and read noise, 8 bits.
//! - Colour is captured [`KinectModel::color_delay`] after depth, with its own timestamp, and both
//!   images carry Brown–Conrady distortion.
//!
//! Every random quantity comes from the seed, the frame and the pixel row, so a sequence is the
//! same on every run and thread count.

pub mod color;
pub mod depth;
pub(crate) mod fields;

use super::scene::Scene;
use super::view_cone::ViewCone;
use crate::camera::Camera;
use crate::distortion::{Distortion, TumSensor};
use crate::image::{ColorImage, Image};
use crate::io::trajectory::Trajectory;
use nalgebra::{Isometry3, Vector3};
use rayon::prelude::*;

/// The sensor's settings. Lengths in metres, angles in degrees, image quantities in pixels of a
/// 640-pixel-wide image (scaled to the output width).
#[derive(Clone, Debug, PartialEq)]
pub struct KinectModel {
    /// Base seed of every random quantity.
    pub seed: u64,
    /// Focal length of the IR camera, pixels (580 for a Kinect v1; the depth quantisation is the IR
    /// camera's, whatever the output resolution).
    pub ir_focal: f64,
    /// Distance from the IR camera to the projector (7.5 cm).
    pub baseline: f64,
    /// Where the IR camera sits along the colour camera's x axis (the depth is registered to the
    /// colour camera); the projector is `baseline` further along +x.
    pub ir_offset: f64,
    /// Disparity sub-pixel resolution: steps per pixel (8).
    pub subpixel: f64,
    /// Disparity noise independent per pixel, in steps.
    pub disparity_sigma: f64,
    /// Disparity noise correlated between neighbours, in steps.
    pub disparity_sigma_correlated: f64,
    /// Correlation length of the correlated disparity noise, pixels.
    pub disparity_correlation: f64,
    /// Lateral jitter of each pixel's sample, independent, pixels.
    pub jitter: f64,
    /// Lateral jitter correlated between neighbours, pixels.
    pub jitter_correlated: f64,
    /// Depth range measured reliably, metres: nothing nearer; beyond the far end, holes grow
    /// more likely until none is left at [`Self::range_limit`].
    pub range: (f64, f64),
    /// Depth beyond which nothing is measured, metres.
    pub range_limit: f64,
    /// Incidence angles (degrees) between which holes become certain: none below the first, all
    /// beyond the second.
    pub grazing: (f64, f64),
    /// Fraction of pixels lost in random blobs.
    pub hole_fraction: f64,
    /// Probability that a pixel at a depth discontinuity gets a depth between the two sides.
    /// OpenNI's firmware suppresses most mixed returns: on TUM's and PrimeSense frames a jump
    /// without a hole has an isolated in-between pixel 0–0.16 % of the time (`bench/edge_holes.py`,
    /// NOTES 56), which 0.001 reproduces.
    pub flying_probability: f64,
    /// Holes along a row narrower than this (pixels at 640 wide) are filled with the nearer depth
    /// at their ends: the matching window sees across them (edge fattening).
    pub window_fill: f64,
    /// Columns and rows at the border without depth (left, right, top, bottom), pixels at 640
    /// wide: the IR camera sees a narrower field than the colour camera it is registered to.
    pub dead_border: [f64; 4],
    /// Depth is reported in whole millimetres (OpenNI's unit) before the depth scale.
    pub millimetres: bool,
    /// Delay of the colour exposure after the depth, seconds: a value drawn per sequence in this
    /// range, plus a jitter of ±1 ms per frame.
    pub color_delay: (f64, f64),
    /// Colour exposure time, seconds (the motion blur).
    pub exposure: f64,
    /// Largest relative change of the auto-exposure gain (0.15: ±15 %).
    pub gain_drift: f64,
    /// Relative darkening in the image corners.
    pub vignetting: f64,
    /// Colour noise: variance a + b I in 8-bit levels² for intensity I.
    pub color_noise: (f64, f64),
    /// Standard deviation of the optics' blur, pixels.
    pub optics_blur: f64,
    /// Lens distortion of both images.
    pub distortion: Distortion,
}

impl Default for KinectModel {
    fn default() -> Self {
        Self {
            seed: 0,
            ir_focal: 580.0,
            baseline: 0.075,
            ir_offset: -0.025,
            subpixel: 8.0,
            disparity_sigma: 0.05,
            disparity_sigma_correlated: 0.3,
            disparity_correlation: 1.5,
            jitter: 0.1,
            jitter_correlated: 0.4,
            range: (0.5, 4.5),
            range_limit: 8.0,
            grazing: (70.0, 82.0),
            hole_fraction: 0.01,
            flying_probability: 0.001,
            window_fill: 4.0,
            dead_border: [10.0, 24.0, 10.0, 10.0],
            millimetres: true,
            color_delay: (0.010, 0.020),
            exposure: 0.02,
            gain_drift: 0.15,
            vignetting: 0.3,
            color_noise: (0.8, 0.012),
            optics_blur: 0.5,
            distortion: TumSensor::Freiburg1.calibration().1,
        }
    }
}

/// One captured frame.
#[derive(Clone, Debug)]
pub struct KinectFrame {
    /// Raw depth at the camera's depth scale (0 = no measurement), at the depth stamp.
    pub depth: Image<u16>,
    /// Colour, at `color_stamp`.
    pub color: ColorImage,
    /// When the colour was exposed (the middle of its exposure), seconds.
    pub color_stamp: f64,
}

impl KinectModel {
    /// The depth quantisation constant 8 f_ir b (metres × steps): z = kq / (steps).
    pub fn kq(&self) -> f64 {
        self.subpixel * self.ir_focal * self.baseline
    }

    /// The depth step at depth z: z² / kq (before the millimetre rounding).
    pub fn depth_step(&self, z: f64) -> f64 {
        z * z / self.kq()
    }

    /// The standard deviation of the depth noise at z from the disparity noise alone:
    /// σ_z = z² / kq · √(σ_i² + σ_c²) (the quantisation adds a uniform error of one step on top).
    pub fn depth_sigma(&self, z: f64) -> f64 {
        self.depth_step(z) * self.disparity_sigma.hypot(self.disparity_sigma_correlated)
    }

    /// The colour delay of frame `frame` (see [`Self::color_delay`]).
    pub fn delay(&self, frame: usize) -> f64 {
        let (lo, hi) = self.color_delay;
        let unit = |x: u64| (fields::mix(x) >> 11) as f64 / (1u64 << 53) as f64;
        let base = lo + (hi - lo) * unit(self.seed ^ 0xDE1A);
        let jitter = 0.001 * (2.0 * unit(self.seed ^ fields::mix(frame as u64 + 1)) - 1.0);
        (base + jitter).clamp(lo.min(hi), hi.max(lo))
    }

    /// The auto-exposure gain at time t: 1 + drift · s(t), s a sum of three slow sinusoids
    /// (0.03–0.25 Hz, phases and frequencies from the seed) normalised to |s| ≤ 1.
    pub fn gain(&self, t: f64) -> f64 {
        let unit = |x: u64| (fields::mix(self.seed ^ x) >> 11) as f64 / (1u64 << 53) as f64;
        let mut s = 0.0;
        for i in 0..3u64 {
            let f = 0.03 + 0.22 * unit(0x6A11 + i);
            let phase = std::f64::consts::TAU * unit(0x9A5E + i);
            s += (std::f64::consts::TAU * f * t + phase).sin();
        }
        1.0 + self.gain_drift * s / 3.0
    }

    /// Scales the image-space settings of a 640-wide image to `width`.
    pub(crate) fn pixel_scale(width: usize) -> f64 {
        width as f64 / 640.0
    }

    /// The sensor with `camera`'s intrinsics, ready to capture frames (its rays computed once).
    pub fn recorder(&self, camera: &Camera) -> Recorder<'_> {
        Recorder {
            model: self,
            camera: *camera,
            rays: Rays::new(camera, &self.distortion),
        }
    }
}

/// A [`KinectModel`] on a camera.
#[derive(Clone, Debug)]
pub struct Recorder<'a> {
    /// The sensor.
    pub model: &'a KinectModel,
    /// Its intrinsics.
    pub camera: Camera,
    rays: Rays,
}

impl Recorder<'_> {
    /// Captures frame `frame` (depth at `trajectory.stamps[frame]`, colour after its delay) of
    /// `scene` seen by the camera moving along `trajectory` (camera-to-scene poses).
    pub fn capture(&self, scene: &Scene, trajectory: &Trajectory, frame: usize) -> KinectFrame {
        let scene = &scene.prepare();
        let t = trajectory.stamps[frame];
        let depth = depth::capture(self, scene, &trajectory.poses[frame], frame);
        let color_stamp = t + self.model.delay(frame);
        let color = color::capture(self, scene, trajectory, color_stamp, frame);
        KinectFrame {
            depth,
            color,
            color_stamp,
        }
    }
}

/// The camera-frame rays (z = 1) through every recorded pixel centre of a distorted camera,
/// undistorted once; rays between centres are interpolated.
#[derive(Clone, Debug)]
pub(crate) struct Rays {
    width: usize,
    height: usize,
    xy: Vec<[f64; 2]>,
    /// The largest |(x, y)| of a ray: every ray, interpolated or not, lies within it.
    widest: f64,
}

impl Rays {
    fn new(camera: &Camera, distortion: &Distortion) -> Self {
        let (w, h) = (camera.width, camera.height);
        let xy: Vec<[f64; 2]> = (0..w * h)
            .into_par_iter()
            .map(|i| {
                let (xd, yd) = (
                    ((i % w) as f64 - camera.cx) / camera.fx,
                    ((i / w) as f64 - camera.cy) / camera.fy,
                );
                if distortion.is_zero() {
                    return [xd, yd];
                }
                distortion
                    .undistort(xd, yd)
                    .map_or([f64::NAN; 2], |(x, y)| [x, y])
            })
            .collect();
        let widest = (xy.iter())
            .map(|[x, y]: &[f64; 2]| x.hypot(*y))
            .filter(|r| r.is_finite())
            .fold(0.0, f64::max);
        Self {
            width: w,
            height: h,
            xy,
            widest,
        }
    }

    /// The cone of every ray from a camera at `pose` (camera-to-world), with shadow rays to eyes
    /// within `reach` of its centre.
    pub(crate) fn cone(&self, pose: &Isometry3<f64>, reach: f64) -> ViewCone {
        ViewCone::new(pose, self.widest, reach)
    }

    /// The ray through pixel centre `i`.
    #[inline]
    pub(crate) fn at_pixel(&self, i: usize) -> Option<Vector3<f64>> {
        let [x, y] = self.xy[i];
        x.is_finite().then(|| Vector3::new(x, y, 1.0))
    }

    /// The ray through (u, v), interpolated between the four centres around it (clamped to the
    /// image).
    #[inline]
    pub(crate) fn at(&self, u: f64, v: f64) -> Option<Vector3<f64>> {
        let (w, h) = (self.width, self.height);
        let u = u.clamp(0.0, (w - 1) as f64);
        let v = v.clamp(0.0, (h - 1) as f64);
        let (x0, y0) = (u.floor() as usize, v.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let (fx, fy) = (u - x0 as f64, v - y0 as f64);
        let p = |x: usize, y: usize| self.xy[y * w + x];
        let mut out = [0.0; 2];
        for (c, o) in out.iter_mut().enumerate() {
            let top = p(x0, y0)[c] * (1.0 - fx) + p(x1, y0)[c] * fx;
            let bottom = p(x0, y1)[c] * (1.0 - fx) + p(x1, y1)[c] * fx;
            *o = top * (1.0 - fy) + bottom * fy;
        }
        out[0]
            .is_finite()
            .then(|| Vector3::new(out[0], out[1], 1.0))
    }
}

/// Where the camera-frame point p is recorded (distorted pixel), if in front of the camera.
#[inline]
pub(crate) fn project(
    camera: &Camera,
    distortion: &Distortion,
    p: &Vector3<f64>,
) -> Option<(f64, f64)> {
    if p.z <= 1e-9 {
        return None;
    }
    let (x, y) = distortion.distort(p.x / p.z, p.y / p.z);
    Some((camera.fx * x + camera.cx, camera.fy * y + camera.cy))
}

/// The pose at time `t` on a trajectory: interpolated between the stamps around it (the rotation
/// by slerp, the translation linearly), extrapolated from the nearest pair beyond either end.
pub(crate) fn pose_at(trajectory: &Trajectory, t: f64) -> Isometry3<f64> {
    let s = &trajectory.stamps;
    let p = &trajectory.poses;
    if s.len() < 2 {
        return p.first().copied().unwrap_or_else(Isometry3::identity);
    }
    let i = s.partition_point(|&x| x <= t).clamp(1, s.len() - 1) - 1;
    let span = s[i + 1] - s[i];
    let a = if span > 0.0 { (t - s[i]) / span } else { 0.0 };
    let rel = p[i].inverse() * p[i + 1];
    let step = Isometry3::from_parts((rel.translation.vector * a).into(), rel.rotation.powf(a));
    p[i] * step
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poses_are_interpolated_between_stamps_and_extrapolated_beyond() {
        let mut t = Trajectory::default();
        for k in 0..3 {
            let f = k as f64;
            t.push(
                f * 0.1,
                Isometry3::new(Vector3::new(f, 0.0, 0.0), Vector3::new(0.0, 0.0, 0.1 * f)),
            );
        }
        let mid = pose_at(&t, 0.05);
        assert!((mid.translation.x - 0.5).abs() < 1e-9);
        assert!((mid.rotation.angle() - 0.05).abs() < 1e-9);
        let beyond = pose_at(&t, 0.25);
        assert!((beyond.translation.x - 2.5).abs() < 1e-9);
        assert!((beyond.rotation.angle() - 0.25).abs() < 1e-9);
        let at = pose_at(&t, 0.1);
        assert!((at.translation.vector - t.poses[1].translation.vector).norm() < 1e-12);
        assert!(at.rotation.angle_to(&t.poses[1].rotation) < 1e-12);
    }

    #[test]
    fn the_colour_delay_and_the_gain_stay_in_their_ranges() {
        let m = KinectModel::default();
        for k in 0..200 {
            let d = m.delay(k);
            assert!((0.010..=0.020).contains(&d), "{d}");
            let g = m.gain(k as f64 / 30.0);
            assert!((0.85..=1.15).contains(&g), "{g}");
        }
        // it drifts: over 20 s the gain moves by more than 3 %
        let g: Vec<f64> = (0..600).map(|k| m.gain(k as f64 / 30.0)).collect();
        let span =
            g.iter().cloned().fold(f64::MIN, f64::max) - g.iter().cloned().fold(f64::MAX, f64::min);
        assert!(span > 0.03, "{span}");
    }
}
