//! # dynamap-residuals
//!
//! Cost terms for the dynamap solver, each a small struct implementing
//! [`Residual`](dynamap_solver::Residual) with exact Jacobians:
//!
//! - [`deform`]: the non-rigid data term under the dual-quaternion-blended warp of K nodes, and the
//!   as-rigid-as-possible regulariser.
//! - [`icp`]: point-to-plane and photometric terms of rigid tracking.
//! - [`pose_graph`]: SE(2) and SE(3) between and prior factors, the g2o file format, and
//!   initialisation (odometry spanning tree, chordal relaxation).

#![warn(missing_docs)]

pub mod deform;
pub mod icp;
pub mod pose_graph;
