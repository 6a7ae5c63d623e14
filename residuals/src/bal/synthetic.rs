//! Synthetic bundle-adjustment problems with a known optimum, for tests and the example.
//!
//! Cameras stand on a ring around a cloud of points and look at its centre; every point is seen
//! by a seeded random subset of at least three cameras. With exact observations the ground truth
//! has cost 0 and is an optimum (up to the similarity gauge of bundle adjustment); the start is
//! the truth with seeded noise on every camera and point. Optionally the observations get
//! Gaussian pixel noise and a fraction of them is replaced by gross outliers.

use super::{rotate, BalProblem, Observation};
use dynamap_solver::lie::so3;
use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Settings of [`generate`].
#[derive(Clone, Copy, Debug)]
pub struct SyntheticOptions {
    /// Number of cameras.
    pub cameras: usize,
    /// Number of points.
    pub points: usize,
    /// Standard deviation of the pixel noise on the observations.
    pub pixel_noise: f64,
    /// Fraction of observations replaced by outliers (10 to 60 pixels off, random direction).
    pub outlier_fraction: f64,
    /// Standard deviation of the start's rotation noise (radians).
    pub rotation_noise: f64,
    /// Standard deviation of the start's camera-translation and point noise.
    pub position_noise: f64,
    /// How many cameras see each point. `None`: each camera with probability ½ (at least three),
    /// which suits a dozen cameras. `Some((lo, hi))`: a run of between `lo` and `hi` neighbouring
    /// cameras on the ring, so that each camera sees only the points near its part of the ring,
    /// as in BAL's Venice and Final sets; this scales to thousands of cameras.
    pub views: Option<(usize, usize)>,
    /// Random seed.
    pub seed: u64,
}

impl Default for SyntheticOptions {
    fn default() -> Self {
        Self {
            cameras: 12,
            points: 400,
            pixel_noise: 0.0,
            outlier_fraction: 0.0,
            rotation_noise: 0.01,
            position_noise: 0.05,
            views: None,
            seed: 11,
        }
    }
}

/// A generated problem.
pub struct Synthetic {
    /// The start: the truth's cameras and points with noise, and the observations.
    pub start: BalProblem,
    /// The cameras and points that generated the observations.
    pub truth: BalProblem,
    /// Which observations are outliers.
    pub outlier: Vec<bool>,
}

/// The cameras that see one point, in increasing order.
fn seen_by(o: &SyntheticOptions, rng: &mut ChaCha8Rng) -> Vec<usize> {
    let n = o.cameras;
    let mut seen: Vec<usize> = match o.views {
        None => {
            let mut seen: Vec<usize> = (0..n).filter(|_| rng.random_bool(0.5)).collect();
            while seen.len() < 3.min(n) {
                let c = rng.random_range(0..n);
                if !seen.contains(&c) {
                    seen.push(c);
                }
            }
            seen
        }
        Some((lo, hi)) => {
            let (lo, hi) = (lo.clamp(1, n.max(1)), hi.clamp(1, n.max(1)));
            let k = rng.random_range(lo.min(hi)..=hi.max(lo));
            let first = rng.random_range(0..n.max(1));
            (0..k).map(|i| (first + i) % n).collect()
        }
    };
    seen.sort_unstable();
    seen
}

/// Camera `i` of `n` on the ring, looking at the cloud's centre (BAL's parameters: angle-axis,
/// translation, focal length, two radial distortion coefficients).
fn ring_camera(i: usize, n: usize) -> [f64; 9] {
    let a = 2.0 * std::f64::consts::PI * i as f64 / n.max(1) as f64;
    let centre = Vector3::new(8.0 * a.cos(), 8.0 * a.sin(), 2.0 + (3.0 * a).sin());
    // BAL cameras look down their −z axis.
    let z = centre.normalize();
    let x = Vector3::z().cross(&z).normalize();
    let y = z.cross(&x);
    let r = Rotation3::from_matrix_unchecked(Matrix3::from_rows(&[
        x.transpose(),
        y.transpose(),
        z.transpose(),
    ]));
    let w = so3::log(&UnitQuaternion::from_rotation_matrix(&r));
    let t = -(r * centre);
    let f = 500.0 + 20.0 * i as f64;
    [w.x, w.y, w.z, t.x, t.y, t.z, f, -0.02, 0.001]
}

/// Generates a problem (see the module documentation).
pub fn generate(o: &SyntheticOptions) -> Synthetic {
    let mut rng = ChaCha8Rng::seed_from_u64(o.seed);
    let unit = Normal::new(0.0, 1.0).expect("unit normal");
    let points: Vec<[f64; 3]> = (0..o.points)
        .map(|_| {
            [
                rng.random_range(-2.0..2.0),
                rng.random_range(-2.0..2.0),
                rng.random_range(-1.0..1.0),
            ]
        })
        .collect();
    let cameras: Vec<[f64; 9]> = (0..o.cameras).map(|i| ring_camera(i, o.cameras)).collect();
    let mut observations = Vec::new();
    let mut outlier = Vec::new();
    for (p, point) in points.iter().enumerate() {
        for c in seen_by(o, &mut rng) {
            let cam = &cameras[c];
            let pc = rotate(
                &Vector3::new(cam[0], cam[1], cam[2]),
                &Vector3::from(*point),
            ) + Vector3::new(cam[3], cam[4], cam[5]);
            let (xp, yp) = (-pc.x / pc.z, -pc.y / pc.z);
            let r2 = xp * xp + yp * yp;
            let d = 1.0 + r2 * (cam[7] + cam[8] * r2);
            let mut uv = [
                cam[6] * d * xp + o.pixel_noise * unit.sample(&mut rng),
                cam[6] * d * yp + o.pixel_noise * unit.sample(&mut rng),
            ];
            let bad = rng.random_bool(o.outlier_fraction.clamp(0.0, 1.0));
            if bad {
                let angle = rng.random_range(0.0..2.0 * std::f64::consts::PI);
                let size = rng.random_range(10.0..60.0);
                uv[0] += size * angle.cos();
                uv[1] += size * angle.sin();
            }
            observations.push(Observation {
                camera: c,
                point: p,
                uv,
            });
            outlier.push(bad);
        }
    }
    let truth = BalProblem {
        cameras,
        points,
        observations,
    };
    let mut start = truth.clone();
    for c in &mut start.cameras {
        for x in &mut c[..3] {
            *x += o.rotation_noise * unit.sample(&mut rng);
        }
        for x in &mut c[3..6] {
            *x += o.position_noise * unit.sample(&mut rng);
        }
    }
    for p in &mut start.points {
        for x in p.iter_mut() {
            *x += o.position_noise * unit.sample(&mut rng);
        }
    }
    Synthetic {
        start,
        truth,
        outlier,
    }
}
