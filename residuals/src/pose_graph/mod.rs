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
