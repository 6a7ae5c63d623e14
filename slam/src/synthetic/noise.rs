//! A Kinect-like sensor model (Nguyen, Izadi & Lovell, *Modeling Kinect sensor noise for improved 3D
//! reconstruction and tracking*, 3DIMPVT 2012): axial noise σ(z) = 0.0012 + 0.0019 (z − 0.4)² metres,
//! quantisation to the depth scale, dropouts at grazing angles and random holes; Gaussian colour
//! noise. Seeded per frame, so a sequence is the same on every run.

use crate::image::{ColorImage, DepthImage, Image};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Settings of the sensor model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorNoise {
    /// Apply depth and colour noise (quantisation always applies).
    pub enabled: bool,
    /// Base seed; frame k uses a stream derived from (seed, k).
    pub seed: u64,
    /// Pixels whose viewing ray meets the surface at cos θ below this are dropped (default cos 80°).
    pub grazing_cos: f32,
    /// Fraction of random holes (default 0.5 %).
    pub hole_fraction: f64,
    /// Colour noise standard deviation in 8-bit steps (default 2).
    pub color_sigma: f32,
    /// Amplitude of a drifting auto-exposure gain on the colour: frame k is scaled by
    /// 1 + a sin(2π k / [`GAIN_PERIOD`]) before its noise (default 0: a fixed exposure). 0.15 is
    /// the drift of a consumer sensor's auto-exposure over a few seconds.
    pub gain_drift: f32,
}

/// Frames per period of the exposure drift (5 s at 30 Hz).
pub const GAIN_PERIOD: f64 = 150.0;

impl Default for SensorNoise {
    fn default() -> Self {
        Self {
            enabled: true,
            seed: 0,
            grazing_cos: 80f32.to_radians().cos(),
            hole_fraction: 0.005,
            color_sigma: 2.0,
            gain_drift: 0.0,
        }
    }
}

/// σ(z) of the axial depth noise, metres.
pub fn depth_sigma(z: f64) -> f64 {
    0.0012 + 0.0019 * (z - 0.4) * (z - 0.4)
}

impl SensorNoise {
    /// The exposure gain of frame `frame` (see [`Self::gain_drift`]).
    pub fn gain(&self, frame: u64) -> f64 {
        1.0 + self.gain_drift as f64
            * (2.0 * std::f64::consts::PI * frame as f64 / GAIN_PERIOD).sin()
    }

    /// [`Self::apply`] to a whole rendering: its colour made noisy in place, its raw depth
    /// returned.
    pub fn apply_to(
        &self,
        frame: u64,
        r: &mut super::render::Rendering,
        depth_scale: f64,
    ) -> Image<u16> {
        self.apply(frame, &r.depth, &r.cos_incidence, &mut r.color, depth_scale)
    }

    /// Turns rendered depth (metres) and colour into sensor output: raw 16-bit depth at
    /// `depth_scale` units per metre (0 = missing) and noisy colour.
    pub fn apply(
        &self,
        frame: u64,
        depth: &DepthImage,
        cos_incidence: &Image<f32>,
        color: &mut ColorImage,
        depth_scale: f64,
    ) -> Image<u16> {
        let mut rng =
            ChaCha8Rng::seed_from_u64(self.seed ^ frame.wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let unit = Normal::new(0.0f64, 1.0).expect("unit normal");
        let mut raw = Image::new(depth.width, depth.height);
        for (i, &z) in depth.data.iter().enumerate() {
            if z <= 0.0 {
                continue;
            }
            let mut z = z as f64;
            if self.enabled {
                if cos_incidence.data[i] < self.grazing_cos
                    || rng.random::<f64>() < self.hole_fraction
                {
                    continue;
                }
                z += depth_sigma(z) * unit.sample(&mut rng);
            }
            let q = (z * depth_scale).round();
            if q >= 1.0 && q <= u16::MAX as f64 {
                raw.data[i] = q as u16;
            }
        }
        let gain = self.gain(frame);
        if gain != 1.0 {
            for px in color.data.iter_mut() {
                for c in px.iter_mut() {
                    *c = (*c as f64 * gain).round().clamp(0.0, 255.0) as u8;
                }
            }
        }
        if self.enabled {
            for px in color.data.iter_mut() {
                for c in px.iter_mut() {
                    let v = *c as f64 + self.color_sigma as f64 * unit.sample(&mut rng);
                    *c = v.round().clamp(0.0, 255.0) as u8;
                }
            }
        }
        raw
    }
}
