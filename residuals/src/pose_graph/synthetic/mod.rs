//! Synthetic pose graphs with known ground truth, for tests, examples and benchmarks.
//!
//! Four families, each generated at any size:
//! - [`sphere`] (SE(3)) and [`circle`] (SE(2)): poses in rings, each tied to the one a ring before
//!   (after sphere2500 of Kaess et al., *iSAM*, 2008); the graph is a mesh, so a direct
//!   factorisation fills in as a planar grid does.
//! - [`city`]: a walk through a grid of streets (after Olson's Manhattan and city10k, *Fast
//!   Iterative Optimization of Pose Graphs with Poor Initial Estimates*, 2006), closing a loop
//!   when it comes back to an intersection; in 3-D the city has floors joined by stairs.
//! - [`corridor`]: passes up and down a long corridor, with loops only at a few doors, so long
//!   chains are held by few closures.
//!
//! Measurements are exact (the ground truth is the optimum, chi2 = 0) or drawn from the edge's
//! Gaussian `Z_ij = (X_i⁻¹ X_j) Exp(δ)`, `δ ~ N(0, Ω⁻¹)` in the solver's tangent order (then the
//! optimum's chi2 is near its expectation, the number of edge residuals minus the number of pose
//! unknowns). The start is the truth with seeded noise on every pose but the anchor, or the
//! odometry chain composed from pose 0, as published graphs give it.

mod city;
mod corridor;
mod outliers;
mod rings;

pub use city::{city, CityOptions};
pub use corridor::{corridor, CorridorOptions};
pub use outliers::{add_false_loops, max_pose_error};
pub use rings::{circle, sphere, SyntheticOptions};

use super::graph::{Dimension, Edge, Measurement, Pose, PoseGraph};
use dynamap_solver::lie::{se2, se3};
use nalgebra::{Matrix3, Matrix6, Vector3, Vector6};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::collections::BTreeMap;

/// A synthetic graph, its ground truth and a start.
pub struct SyntheticGraph {
    /// The graph; its `vertices` hold the start.
    pub graph: PoseGraph,
    /// The ground truth: the optimum when the measurements are exact.
    pub truth: BTreeMap<usize, Pose>,
}

/// Where a generated graph's vertices start.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Start {
    /// The truth with independent noise on every pose but the anchor: a rotation of standard
    /// deviation `rotation` (radians) per axis and a translation of `translation` (metres).
    Perturbed {
        /// Rotation noise (radians).
        rotation: f64,
        /// Translation noise (metres).
        translation: f64,
    },
    /// The measurements composed along the chain 0 → 1 → … from the true pose 0.
    Odometry,
}

/// The measurement model and the start of a generated graph.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Noise {
    /// Standard deviation of each rotation component of a measurement (radians); the edges'
    /// information is `1/σ²` there.
    pub rotation_sigma: f64,
    /// Standard deviation of each translation component (metres).
    pub translation_sigma: f64,
    /// Draw the measurements from their Gaussian (true) or make them exact (false).
    pub noisy: bool,
    /// The start.
    pub start: Start,
    /// Random seed.
    pub seed: u64,
}

impl Default for Noise {
    /// Noisy measurements of σ 0.01 rad and 0.05 m, started from the truth perturbed by 0.05 rad and
    /// 0.2 m.
    fn default() -> Self {
        Self {
            rotation_sigma: 0.01,
            translation_sigma: 0.05,
            noisy: true,
            start: Start::Perturbed {
                rotation: 0.05,
                translation: 0.2,
            },
            seed: 1,
        }
    }
}

/// Salt of the measurement noise's random stream, so that adding it leaves the start's draws as
/// they were.
const MEASUREMENT_STREAM: u64 = 0x6d65_6173_7572_6573;

/// The graph over `truth` (ids 0..n) with an edge per pair, measured and started per `noise`.
/// Pairs must begin with the chain (0, 1), (1, 2), … when the start is [`Start::Odometry`].
fn assemble(
    dimension: Dimension,
    source: &str,
    truth: Vec<Pose>,
    pairs: &[(usize, usize)],
    noise: &Noise,
) -> SyntheticGraph {
    let mut rng = ChaCha8Rng::seed_from_u64(noise.seed ^ MEASUREMENT_STREAM);
    let (nr, nt) = normals(noise.rotation_sigma, noise.translation_sigma);
    let (wr, wt) = (
        noise.rotation_sigma.recip().powi(2),
        noise.translation_sigma.recip().powi(2),
    );
    let mut graph = PoseGraph::new(dimension);
    graph.source = source.into();
    graph.edges = pairs
        .iter()
        .map(|&(a, b)| {
            let z = truth[a].inverse().compose(&truth[b]);
            let measurement = match z {
                Pose::Se2(z) => Measurement::Se2 {
                    z: if noise.noisy {
                        z * se2::exp(&draw2(&mut rng, nr, nt))
                    } else {
                        z
                    },
                    information: Matrix3::from_diagonal(&Vector3::new(wt, wt, wr)),
                },
                Pose::Se3(z) => Measurement::Se3 {
                    z: if noise.noisy {
                        z * se3::exp(&draw3(&mut rng, nr, nt))
                    } else {
                        z
                    },
                    information: Matrix6::from_diagonal(&Vector6::new(wr, wr, wr, wt, wt, wt)),
                },
            };
            Edge {
                from: a,
                to: b,
                measurement,
                line: 0,
            }
        })
        .collect();
    graph.vertices = start(&graph, &truth, noise);
    SyntheticGraph {
        graph,
        truth: truth.into_iter().enumerate().collect(),
    }
}

/// A walk's graph: odometry along the poses in order, then the loop closures; named
/// "synthetic NAME (2-D)" or "(3-D)".
fn walk(
    dimension: Dimension,
    name: &str,
    truth: Vec<Pose>,
    loops: &[(usize, usize)],
    noise: &Noise,
) -> SyntheticGraph {
    let mut pairs: Vec<(usize, usize)> = (1..truth.len()).map(|i| (i - 1, i)).collect();
    pairs.extend_from_slice(loops);
    let d = match dimension {
        Dimension::Two => 2,
        Dimension::Three => 3,
    };
    let source = format!("synthetic {name} ({d}-D)");
    assemble(dimension, &source, truth, &pairs, noise)
}

/// The start's vertices.
fn start(graph: &PoseGraph, truth: &[Pose], noise: &Noise) -> BTreeMap<usize, Pose> {
    match noise.start {
        Start::Perturbed {
            rotation,
            translation,
        } => {
            let mut rng = ChaCha8Rng::seed_from_u64(noise.seed);
            let (nr, nt) = normals(rotation, translation);
            let mut out = BTreeMap::new();
            for (i, p) in truth.iter().enumerate() {
                let moved = match p {
                    _ if i == 0 => *p,
                    Pose::Se2(x) => Pose::Se2(x * se2::exp(&draw2(&mut rng, nr, nt))),
                    Pose::Se3(x) => Pose::Se3(x * se3::exp(&draw3(&mut rng, nr, nt))),
                };
                out.insert(i, moved);
            }
            out
        }
        Start::Odometry => {
            let mut out = BTreeMap::new();
            let mut here = truth[0];
            out.insert(0, here);
            for (i, e) in graph.edges.iter().take(truth.len() - 1).enumerate() {
                assert!(
                    e.from == i && e.to == i + 1,
                    "the first edges must be the chain"
                );
                here = here.compose(&e.measurement.pose());
                out.insert(i + 1, here);
            }
            out
        }
    }
}

fn normals(rotation: f64, translation: f64) -> (Normal<f64>, Normal<f64>) {
    (
        Normal::new(0.0, rotation).expect("finite rotation sigma"),
        Normal::new(0.0, translation).expect("finite translation sigma"),
    )
}

/// An SE(2) tangent draw `[v_x, v_y, ω]`.
fn draw2(rng: &mut ChaCha8Rng, nr: Normal<f64>, nt: Normal<f64>) -> Vector3<f64> {
    let (x, y) = (nt.sample(rng), nt.sample(rng));
    Vector3::new(x, y, nr.sample(rng))
}

/// An SE(3) tangent draw `[ω; v]`.
fn draw3(rng: &mut ChaCha8Rng, nr: Normal<f64>, nt: Normal<f64>) -> Vector6<f64> {
    Vector6::from_fn(|r, _| {
        if r < 3 {
            nr.sample(rng)
        } else {
            nt.sample(rng)
        }
    })
}

/// Checks the settings every family shares: finite positive sigmas and at least `least` poses.
fn check(poses: usize, least: usize, noise: &Noise) -> Result<(), SyntheticError> {
    let positive = |s: f64| s.is_finite() && s > 0.0;
    let start_ok = match noise.start {
        Start::Perturbed {
            rotation,
            translation,
        } => {
            rotation.is_finite() && rotation >= 0.0 && translation.is_finite() && translation >= 0.0
        }
        Start::Odometry => true,
    };
    if poses < least {
        return Err(SyntheticError::TooSmall { poses, least });
    }
    if !(positive(noise.rotation_sigma) && positive(noise.translation_sigma) && start_ok) {
        return Err(SyntheticError::Noise);
    }
    Ok(())
}

/// Settings a family cannot generate from.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SyntheticError {
    /// Too few poses for the layout.
    #[error("{poses} poses: this layout needs at least {least}")]
    TooSmall {
        /// Poses asked for.
        poses: usize,
        /// The least the layout takes.
        least: usize,
    },
    /// A sigma that is not finite and positive (start noise may be zero).
    #[error("measurement sigmas must be finite and positive, start noise finite and non-negative")]
    Noise,
    /// A layout's setting out of its range.
    #[error("{0}")]
    Setting(&'static str),
}
