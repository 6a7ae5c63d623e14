//! # dynamap-residuals
//!
//! Cost terms for the dynamap solver, each a small struct implementing
//! [`Residual`](dynamap_solver::Residual) with exact Jacobians:
//!
//! - [`bal`]: bundle adjustment: the Snavely reprojection error, the BAL file format and
//!   synthetic problems.
//! - [`deform`]: the non-rigid data term under the dual-quaternion-blended warp of K nodes, and the
//!   as-rigid-as-possible regulariser.
//! - [`icp`]: point-to-plane and photometric terms of rigid tracking.
//! - [`pose_graph`]: SE(2) and SE(3) between and prior factors, the g2o file format, and
//!   initialisation (odometry spanning tree, chordal relaxation).
//!
//! ## The model
//!
//! A term here is a value type holding its measurement (a relative pose, an image observation,
//! a point and its model normal) and implementing [`Residual`](dynamap_solver::Residual): given
//! its variables' current values it writes its residual vector and, when asked, one Jacobian
//! block per variable in that variable's tangent space. Information matrices enter as square
//! roots (`r = U e` with `UᵀU = Ω`), so `½‖r‖²` is the Mahalanobis cost. Each term's Jacobians are
//! property-tested against central differences (`check_jacobians`) in its module's tests. The file
//! formats (g2o, BAL) build whole problems from these terms.
//!
//! ## Example: a bundle-adjustment problem with a known optimum
//!
//! ```
//! use dynamap_residuals::bal::{self, synthetic::{generate, SyntheticOptions}};
//! use dynamap_solver::{LinearSolverKind, Solver};
//!
//! let options = SyntheticOptions { cameras: 3, points: 40, ..SyntheticOptions::default() };
//! let mut data = generate(&options).start;
//! let mut solve = data.build(None).unwrap(); // one Snavely reprojection term per observation
//! let summary = Solver::new(bal::options(LinearSolverKind::SchurDense, 50))
//!     .solve(&mut solve.problem)
//!     .unwrap();
//! assert!(summary.final_cost < 1e-10 * summary.initial_cost);
//! data.update_from(&solve);
//! ```

#![warn(missing_docs)]

pub mod atomic;
pub mod bal;
pub mod deform;
pub mod icp;
pub mod pose_graph;
pub mod text;

use dynamap_solver::Jacobians;

/// Writes `scale · r` and `scale · J_b` (one column-major block per variable) into a
/// [`Residual`](dynamap_solver::Residual)'s outputs.
pub(crate) fn write_scaled<const M: usize>(
    scale: f64,
    r: &[f64],
    blocks: &[[f64; M]],
    residual: &mut [f64],
    jacobians: Option<&mut Jacobians<'_>>,
) {
    for (o, x) in residual.iter_mut().zip(r) {
        *o = scale * x;
    }
    if let Some(j) = jacobians {
        for (b, jb) in blocks.iter().enumerate() {
            for (o, x) in j.block(b).iter_mut().zip(jb) {
                *o = scale * x;
            }
        }
    }
}
