//! # dynamap
//!
//! Sparse non-linear least squares on manifolds ([`solver`]), the cost terms built on it
//! ([`residuals`]), and dense RGB-D SLAM ([`slam`]). This crate re-exports the three.

pub use dynamap_residuals as residuals;
pub use dynamap_slam as slam;
pub use dynamap_solver as solver;

/// The README's code blocks, compiled and run as doc tests.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
