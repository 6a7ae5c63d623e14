//! Dense rigid RGB-D SLAM (thesis ch. 3; KinectFusion, Newcombe et al. 2011): each frame is tracked
//! against the model raycast at the previous pose ([`tracker`]) and fused into the voxel-hashed TSDF
//! at the new pose ([`pipeline`]).

mod color_timing;
mod motion_model;
pub mod pipeline;
pub mod tracker;

pub use pipeline::{FrameReport, FrameStamps, RigidSlam, SlamParams, StageTimes};
pub use tracker::{FrameConstraint, ModelPyramid, TrackOutcome, Tracker, TrackerParams};
