//! Pose-graph optimisation: poses X_i linked by relative measurements Z_ij.
//!
//! The error of an edge is GTSAM's BetweenFactor error `e = Log(Z_ij⁻¹ X_i⁻¹ X_j)` in the tangent
//! orders of [`dynamap_solver::lie`] (`[v_x, v_y, ω]` for SE(2), `[ω; v]` for SE(3)), and
//! `chi2 = Σ eᵀ Ω e` with Ω the edge's information matrix in that order (Grisetti et al., *A
//! Tutorial on Graph-Based SLAM*, 2010; Dellaert & Kaess, *Factor Graphs for Robot Perception*, 2017).

mod factors;
pub mod g2o;
mod graph;
pub mod information;
pub mod init;
pub mod synthetic;

pub use factors::{sqrt_information, Between2, Between3, Prior2, Prior3};
pub use graph::{Dimension, Edge, Measurement, Pose, PoseGraph, PoseGraphProblem};

use dynamap_solver::{Algorithm, Options};

/// The settings `pose_graph` solves with unless told otherwise: Powell's dogleg (it reaches every
/// reference optimum of `../shared/data/posegraph` from the file's start, where
/// Levenberg-Marquardt with μI damping stalls on M3500 and MIT), at most 100 iterations, and a
/// stop when an accepted step lowers chi2 by less than 1e-9 of it.
pub fn options() -> Options {
    Options {
        algorithm: Algorithm::Dogleg,
        max_iterations: 100,
        function_tolerance: 1e-9,
        ..Options::default()
    }
}
