//! Synthetic bundle-adjustment problems with a known optimum, for tests, benchmarks and the
//! example.
//!
//! Two layouts ([`Layout`]): cameras on a ring around a cloud of points ([`ring`]), which suits a
//! dozen cameras, and a walk through a grid of streets photographing the façades ([`streets`]),
//! whose city grows with the number of cameras so that every camera sees a similar number of
//! points and the walk returns to streets it has seen, as in BAL's Venice and Final sets. With
//! exact observations the ground truth has cost 0 and is an optimum (up to the similarity gauge
//! of bundle adjustment); the start is the truth with seeded noise on every camera (turned about
//! its own centre, then moved) and point.
//! Optionally the observations get Gaussian pixel noise and a fraction of them is replaced by
//! gross outliers.

pub mod ring;
pub mod streets;

use super::{camera_centre, rotate, BalProblem, Observation};
use dynamap_solver::lie::so3;
use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Where the cameras stand and what they see.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Layout {
    /// A ring of cameras around a cloud of points ([`ring`]).
    #[default]
    Ring,
    /// A walk through a grid of streets, looking at the façades ([`streets`]).
    Streets,
}

/// Settings of [`generate`].
#[derive(Clone, Copy, Debug)]
pub struct SyntheticOptions {
    /// Where the cameras stand.
    pub layout: Layout,
    /// Number of cameras.
    pub cameras: usize,
    /// Number of points (the streets layout may make fewer if too few façades are in view; see
    /// [`streets`]).
    pub points: usize,
    /// Standard deviation of the pixel noise on the observations.
    pub pixel_noise: f64,
    /// Fraction of observations replaced by outliers (10 to 60 pixels off, random direction).
    pub outlier_fraction: f64,
    /// Standard deviation of the start's rotation noise (radians).
    pub rotation_noise: f64,
    /// Standard deviation of the start's camera-translation and point noise.
    pub position_noise: f64,
    /// How many cameras see each point. Ring: `None` is each camera with probability ½ (at least
    /// three), `Some((lo, hi))` a run of between `lo` and `hi` neighbouring cameras on the ring.
    /// Streets: between `lo` and `hi` of the cameras that have the point in view (`None`: 2 to
    /// 20).
    pub views: Option<(usize, usize)>,
    /// Random seed.
    pub seed: u64,
}

impl Default for SyntheticOptions {
    fn default() -> Self {
        Self {
            layout: Layout::Ring,
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

/// The cameras and points of a layout, and for every point the cameras that see it (increasing).
pub(crate) struct Scene {
    pub cameras: Vec<[f64; 9]>,
    pub points: Vec<[f64; 3]>,
    pub seen_by: Vec<Vec<usize>>,
}

/// BAL's parameters `[ω, t, f, k₁, k₂]` of a camera at `centre` whose optical axis is `forward`
/// with `up` roughly upwards in the image (BAL cameras look down their −z axis).
pub(crate) fn look_camera(
    centre: Vector3<f64>,
    forward: Vector3<f64>,
    up: Vector3<f64>,
    focal: f64,
) -> [f64; 9] {
    let z = -forward.normalize();
    let x = up.cross(&z).normalize();
    let y = z.cross(&x);
    let r = Rotation3::from_matrix_unchecked(Matrix3::from_rows(&[
        x.transpose(),
        y.transpose(),
        z.transpose(),
    ]));
    let w = so3::log(&UnitQuaternion::from_rotation_matrix(&r));
    let t = -(r * centre);
    [w.x, w.y, w.z, t.x, t.y, t.z, focal, -0.02, 0.001]
}

/// A point in the frame of BAL camera `cam`.
pub(crate) fn in_camera(cam: &[f64; 9], point: &[f64; 3]) -> Vector3<f64> {
    rotate(
        &Vector3::new(cam[0], cam[1], cam[2]),
        &Vector3::from(*point),
    ) + Vector3::new(cam[3], cam[4], cam[5])
}

/// The exact image of `point` in `cam` (BAL's projection with radial distortion).
pub(crate) fn project(cam: &[f64; 9], point: &[f64; 3]) -> [f64; 2] {
    let pc = in_camera(cam, point);
    let (xp, yp) = (-pc.x / pc.z, -pc.y / pc.z);
    let r2 = xp * xp + yp * yp;
    let d = 1.0 + r2 * (cam[7] + cam[8] * r2);
    [cam[6] * d * xp, cam[6] * d * yp]
}

/// Generates a problem (see the module documentation).
pub fn generate(o: &SyntheticOptions) -> Synthetic {
    let mut rng = ChaCha8Rng::seed_from_u64(o.seed);
    let scene = match o.layout {
        Layout::Ring => ring::scene(o, &mut rng),
        Layout::Streets => streets::scene(o, &mut rng),
    };
    let (observations, outlier) = observe(&scene, o, &mut rng);
    let truth = BalProblem {
        cameras: scene.cameras,
        points: scene.points,
        observations,
    };
    let start = perturbed(&truth, o, &mut rng);
    Synthetic {
        start,
        truth,
        outlier,
    }
}

/// Every point's observations, point by point as BAL files list them, with pixel noise and
/// outliers; and which are outliers.
fn observe(
    scene: &Scene,
    o: &SyntheticOptions,
    rng: &mut ChaCha8Rng,
) -> (Vec<Observation>, Vec<bool>) {
    let unit = Normal::new(0.0, 1.0).expect("unit normal");
    let mut observations = Vec::new();
    let mut outlier = Vec::new();
    for (p, (point, cams)) in scene.points.iter().zip(&scene.seen_by).enumerate() {
        for &c in cams {
            let exact = project(&scene.cameras[c], point);
            let mut uv = [
                exact[0] + o.pixel_noise * unit.sample(rng),
                exact[1] + o.pixel_noise * unit.sample(rng),
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
    (observations, outlier)
}

/// The truth with seeded noise on every camera's rotation and translation and every point.
fn perturbed(truth: &BalProblem, o: &SyntheticOptions, rng: &mut ChaCha8Rng) -> BalProblem {
    let unit = Normal::new(0.0, 1.0).expect("unit normal");
    let mut start = truth.clone();
    for c in &mut start.cameras {
        // The rotation turns the camera about its own centre (t = −R c), so that the start's
        // error does not grow with the camera's distance from the world's origin.
        let centre = camera_centre(c);
        for x in &mut c[..3] {
            *x += o.rotation_noise * unit.sample(rng);
        }
        let t = -rotate(&Vector3::new(c[0], c[1], c[2]), &centre);
        for (k, x) in c[3..6].iter_mut().enumerate() {
            *x = t[k] + o.position_noise * unit.sample(rng);
        }
    }
    for p in &mut start.points {
        for x in p.iter_mut() {
            *x += o.position_noise * unit.sample(rng);
        }
    }
    start
}
