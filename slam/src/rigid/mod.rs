//! Dense rigid RGB-D SLAM (thesis ch. 3; KinectFusion, Newcombe et al. 2011): each frame is tracked
//! against the model raycast at the previous pose ([`tracker`]) and fused into the voxel-hashed TSDF
//! at the new pose ([`pipeline`]); a lost track is found again by [`relocalise`], and every frame
//! ends with a typed [`outcome`].

mod color_timing;
mod conditioning;
pub mod exposure;
mod health;
mod joins;
pub mod keyframes;
mod loop_candidates;
mod loop_search;
pub mod loops;
mod motion_model;
pub mod outcome;
pub mod pipeline;
pub mod relocalise;
mod spread;
pub mod submaps;
pub mod tracker;

pub use outcome::{FrameOutcome, TrackFailure};
pub use pipeline::{FrameReport, FrameStamps, RigidSlam, SlamParams, StageTimes};
pub use relocalise::RelocaliseParams;
pub use tracker::{
    FrameConstraint, ModelPyramid, PhotometricWeight, TrackOutcome, Tracker, TrackerParams,
};
