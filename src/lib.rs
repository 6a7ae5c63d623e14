//! # dynamap
//!
//! Sparse non-linear least squares on manifolds ([`solver`]), the cost terms built on it
//! ([`residuals`]), and dense RGB-D SLAM ([`slam`]). This crate re-exports the three, holds their
//! integration tests (`tests/`), and runs the applications of `dynamap-apps` (`apps/`) as its
//! examples (`cargo run --release --example rigid_slam`).
//!
//! The layers, bottom up:
//!
//! - [`solver`] knows nothing of cameras: variables on manifolds, residual blocks, robust
//!   kernels, Gauss-Newton / Levenberg-Marquardt / dogleg over block-sparse normal equations.
//!   Its [`guide`](solver::guide) shows how to use it for a problem of your own.
//! - [`residuals`] holds cost terms with exact Jacobians: pose-graph factors and the g2o format,
//!   bundle adjustment and the BAL format, the tracking and non-rigid terms.
//! - [`slam`] is the RGB-D system: sensor pre-processing, the voxel-hashed TSDF, rigid
//!   frame-to-model tracking, non-rigid registration and fusion, datasets and evaluation.
//!
//! A pose graph of three planar poses, solved through the re-exports:
//!
//! ```
//! use dynamap::residuals::pose_graph::{Between2, Prior2};
//! use dynamap::solver::{Options, Problem, Solver, SE2};
//! use nalgebra::{Isometry2, Matrix3, Vector2};
//!
//! let mut problem = Problem::new();
//! let poses: Vec<_> = (0..3)
//!     .map(|_| problem.add_variable(&[0.0, 0.0, 0.0], SE2).unwrap()) // x, y, θ
//!     .collect();
//! let sqrt_info = Matrix3::identity();
//! problem.add_residual(Prior2::new(Isometry2::identity(), sqrt_info), &[poses[0]]).unwrap();
//! // each step: 1 m forward, then a quarter turn to the left
//! let step = Isometry2::new(Vector2::new(1.0, 0.0), std::f64::consts::FRAC_PI_2);
//! for w in poses.windows(2) {
//!     problem.add_residual(Between2::new(step, sqrt_info), &[w[0], w[1]]).unwrap();
//! }
//! let summary = Solver::new(Options::default()).solve(&mut problem).unwrap();
//! assert!(summary.final_cost < 1e-12);
//! let last = problem.value(poses[2]); // at (1, 1), facing back along −x
//! let pi = std::f64::consts::PI;
//! assert!((last[0] - 1.0).abs() < 1e-6 && (last[1] - 1.0).abs() < 1e-6);
//! assert!((last[2].abs() - pi).abs() < 1e-6);
//! ```

pub use dynamap_residuals as residuals;
pub use dynamap_slam as slam;
pub use dynamap_solver as solver;

/// The README's code blocks, compiled and run as doc tests.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
