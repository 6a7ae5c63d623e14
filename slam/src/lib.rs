//! # dynamap-slam
//!
//! Dense RGB-D SLAM on the dynamap solver. The sensor side:
//!
//! - [`camera`]: the pinhole model, pyramid intrinsics.
//! - [`distortion`]: Brown–Conrady lens distortion, undone by a precomputed remap; TUM's published
//!   calibrations.
//! - [`image`]: bilateral filter, Gaussian pyramid, vertex and normal maps, intensity and gradients;
//!   [`preprocess`] ties them into a per-frame pyramid.
//! - [`io`]: one interface over TUM RGB-D, ICL-NUIM and plain folders (`io::sequence::Sequence`),
//!   PNG images, TUM trajectories, PLY, OFF and OBJ meshes, DeepDeform flow files.
//! - [`mesh`]: triangle meshes.
//! - [`rigid`]: frame-to-model tracking and the rigid SLAM pipeline: typed frame outcomes,
//!   keyframes and relocalisation, loop closure on a keyframe pose graph, sub-maps.
//! - [`nonrigid`]: the deformation graph, dual-quaternion warp and warp-field optimiser.
//! - [`tsdf`]: the voxel-hashed TSDF map: integration, raycasting, marching cubes.
//! - [`synthetic`]: the project's own rendered RGB-D sequences (rigid and deforming) with ground truth.
//! - [`eval`]: ATE and RPE (as evo computes them), scene-flow EPE, mesh distances.
//! - [`features`]: FAST/BRIEF colour matches between frames and a RANSAC rigid fit to them.
//! - [`correlation`]: Pearson's correlation from running sums (the tracker's and the colour
//!   check's texture tests).
//!
//! ## The model
//!
//! Rigid SLAM (after KinectFusion and voxel hashing): each depth frame is filtered and turned into
//! a three-level pyramid of vertex and normal maps; the camera pose is found by registering that
//! pyramid against the map raycast from the previous pose (point-to-plane ICP plus a photometric
//! term, coarse to fine, on the solver's dense 6-DoF path); the frame is then fused into a
//! truncated signed distance field stored in 8³-voxel blocks allocated only near observed surface.
//! Poses are camera-to-world isometries; depth is in metres once read (raw sensor units divided by
//! [`Camera::depth_scale`]).
//!
//! Non-rigid fusion (after DynamicFusion) keeps the TSDF in a canonical frame and a deformation
//! graph of nodes, each with a rigid motion; a point moves by the dual-quaternion blend of its
//! nearest nodes' motions, and each frame's motions are found by a sparse Levenberg-Marquardt
//! solve of a point-to-plane data term and an as-rigid-as-possible regulariser.
//!
//! ## Example: track a rendered room
//!
//! ```
//! use dynamap_slam::rigid::{RigidSlam, SlamParams};
//! use dynamap_slam::synthetic::{motion, noise::SensorNoise, render::render, scene::Scene};
//! use dynamap_slam::Camera;
//!
//! let camera = Camera::tum_default().level(2); // 160 × 120
//! let scene = Scene::room(1);
//! let truth = motion::procedural(motion::Motion::Orbit, 4, 30.0);
//! let mut slam = RigidSlam::new(camera, SlamParams::default(), truth.poses[0]);
//! for (k, pose) in truth.poses.iter().enumerate() {
//!     let mut frame = render(&scene, &camera, pose);
//!     let noise = SensorNoise { enabled: false, ..SensorNoise::default() };
//!     let depth = noise.apply(k as u64, &frame.depth, &frame.cos_incidence, &mut frame.color, camera.depth_scale);
//!     let report = slam.process(&depth, Some(&frame.color));
//!     assert!(report.failure().is_none(), "frame {k}: {:?}", report.outcome);
//! }
//! let error = (slam.pose().translation.vector - truth.poses[3].translation.vector).norm();
//! assert!(error < 0.01, "{error} m");
//! ```

#![warn(missing_docs)]

pub mod camera;
pub mod correlation;
pub mod distortion;
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
