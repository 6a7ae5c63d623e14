//! # dynamap-slam
//!
//! Dense RGB-D SLAM on the dynamap solver. The sensor side:
//!
//! - [`camera`]: the pinhole model, pyramid intrinsics.
//! - [`image`]: bilateral filter, Gaussian pyramid, vertex and normal maps, intensity and gradients;
//!   [`preprocess`] ties them into a per-frame pyramid.
//! - [`io`]: TUM RGB-D, ICL-NUIM and folder datasets, PNG images, TUM trajectories, PLY meshes,
//!   DeepDeform flow files.
//! - [`mesh`]: triangle meshes.
//! - [`rigid`]: frame-to-model tracking and the rigid SLAM pipeline.
//! - [`nonrigid`]: the deformation graph, dual-quaternion warp and warp-field optimiser.
//! - [`tsdf`]: the voxel-hashed TSDF map: integration, raycasting, marching cubes.
//! - [`synthetic`]: the project's own rendered RGB-D sequences (rigid and deforming) with ground truth.
//! - [`eval`]: ATE and RPE (as evo computes them), scene-flow EPE, mesh distances.
//! - [`features`]: FAST/BRIEF colour matches between frames and a RANSAC rigid fit to them.

#![warn(missing_docs)]

pub mod camera;
pub mod eval;
pub mod features;
pub mod image;
pub mod io;
pub mod mesh;
pub mod nonrigid;
pub mod preprocess;
pub mod rigid;
pub mod synthetic;
pub mod tsdf;

pub use camera::Camera;
