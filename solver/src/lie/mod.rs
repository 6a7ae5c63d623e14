//! Lie groups SO(2), SE(2), SO(3), SE(3) on nalgebra types: exponential and logarithm maps, adjoints
//! and Jacobians.
//!
//! Conventions (Solà, Deray & Atchuthan, *A micro Lie theory for state estimation in robotics*, 2018):
//! perturbations are on the right, `X ⊞ δ = X · Exp(δ)`. Tangent orders follow GTSAM so that
//! information matrices map one to one: SE(2) is `[v_x, v_y, ω]`, SE(3) is `[ω; v]` (rotation first).

pub mod se2;
pub mod se3;
pub mod so2;
pub mod so3;
