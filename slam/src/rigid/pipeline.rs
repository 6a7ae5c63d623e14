//! The rigid SLAM loop of one frame: preprocess → track against the model raycast at the previous
//! pose → fuse at the new pose → raycast the model for the next frame. A frame that fails to track
//! is reported and not fused; the next frame starts from the last good pose.

use super::tracker::{ModelPyramid, Tracker, TrackerParams};
use crate::camera::Camera;
use crate::image::{ColorImage, Image};
use crate::preprocess::{PreprocessParams, Preprocessor};
use crate::tsdf::{RaycastMaps, TsdfParams, TsdfVolume};
use nalgebra::Isometry3;
use std::time::Instant;

/// Settings of the whole pipeline.
#[derive(Clone, Debug, PartialEq)]
pub struct SlamParams {
    /// Front end.
    pub preprocess: PreprocessParams,
    /// Tracking.
    pub tracker: TrackerParams,
    /// Map.
    pub tsdf: TsdfParams,
    /// The sensor pyramid level the model is raycast at for tracking (0: full resolution; default 1,
    /// a quarter of the rays: the finest tracking level then associates against a half-resolution
    /// model, as its pixels are strided by 2 anyway).
    pub raycast_level: usize,
}

impl Default for SlamParams {
    fn default() -> Self {
        Self {
            preprocess: PreprocessParams::default(),
            tracker: TrackerParams::default(),
            tsdf: TsdfParams::default(),
            raycast_level: 1,
        }
    }
}

/// Seconds spent in each stage of a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes {
    /// Filtering and pyramids.
    pub preprocess: f64,
    /// Tracking.
    pub track: f64,
    /// TSDF integration.
    pub integrate: f64,
    /// Model raycast.
    pub raycast: f64,
}

impl StageTimes {
    /// Adds another frame's times.
    pub fn add(&mut self, o: &StageTimes) {
        self.preprocess += o.preprocess;
        self.track += o.track;
        self.integrate += o.integrate;
        self.raycast += o.raycast;
    }
}

/// What happened to one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameReport {
    /// The camera-to-world pose (the last good pose if tracking failed).
    pub pose: Isometry3<f64>,
    /// Why the frame was not fused, if it was not.
    pub failure: Option<String>,
    /// Stage times.
    pub times: StageTimes,
    /// Inlier point-to-plane associations at the finest tracking level (0 when not tracked).
    pub inliers: usize,
}

/// Dense rigid SLAM: a TSDF map and a frame-to-model tracker.
pub struct RigidSlam {
    /// Settings.
    pub params: SlamParams,
    camera: Camera,
    pre: Preprocessor,
    tracker: Tracker,
    volume: TsdfVolume,
    raycast: RaycastMaps,
    model: ModelPyramid,
    pose: Isometry3<f64>,
    frames: usize,
    has_model: bool,
}

impl RigidSlam {
    /// A pipeline for images from `camera`, starting at `initial_pose`.
    pub fn new(camera: Camera, params: SlamParams, initial_pose: Isometry3<f64>) -> Self {
        Self {
            pre: Preprocessor::new(camera, params.preprocess),
            tracker: Tracker::new(params.tracker.clone()),
            volume: TsdfVolume::new(params.tsdf),
            raycast: RaycastMaps::new(),
            model: ModelPyramid::new(
                &camera,
                params
                    .preprocess
                    .levels
                    .max(1)
                    .saturating_sub(params.raycast_level)
                    .max(1),
                params
                    .raycast_level
                    .min(params.preprocess.levels.max(1) - 1),
            ),
            params,
            camera,
            pose: initial_pose,
            frames: 0,
            has_model: false,
        }
    }

    /// The sensor's camera.
    pub fn camera(&self) -> Camera {
        self.camera
    }

    /// The current pose.
    pub fn pose(&self) -> Isometry3<f64> {
        self.pose
    }

    /// The map.
    pub fn volume(&self) -> &TsdfVolume {
        &self.volume
    }

    /// The last model raycast (at the current pose).
    pub fn model_maps(&self) -> &RaycastMaps {
        &self.raycast
    }

    /// Processes one frame (raw depth in sensor units, optional colour). Never fails on bad input: a
    /// frame that cannot be tracked or fused is reported in [`FrameReport::failure`].
    pub fn process(&mut self, depth_raw: &Image<u16>, color: Option<&ColorImage>) -> FrameReport {
        let mut times = StageTimes::default();
        if (depth_raw.width, depth_raw.height) != (self.camera.width, self.camera.height)
            || color.is_some_and(|c| (c.width, c.height) != (self.camera.width, self.camera.height))
        {
            return FrameReport {
                pose: self.pose,
                failure: Some(format!(
                    "image size {}x{} does not match the camera's {}x{}",
                    depth_raw.width, depth_raw.height, self.camera.width, self.camera.height
                )),
                times,
                inliers: 0,
            };
        }
        let t = Instant::now();
        self.pre.process(depth_raw, color);
        times.preprocess = t.elapsed().as_secs_f64();
        self.frames += 1;
        let (mut failure, mut inliers) = (None, 0);
        if self.has_model {
            let t = Instant::now();
            let outcome = self
                .tracker
                .track(&self.pre.levels, &self.model, &self.pose);
            times.track = t.elapsed().as_secs_f64();
            failure = outcome.failure;
            inliers = outcome.inliers;
            self.pose = outcome.pose;
        } else {
            let valid = self.pre.levels[0]
                .depth
                .data
                .iter()
                .filter(|d| **d > 0.0)
                .count();
            if valid < 1000 {
                failure = Some(format!("only {valid} valid depth pixels to start the map"));
            }
        }
        if failure.is_none() {
            let t = Instant::now();
            let level = &self.pre.levels[0];
            match self.volume.integrate(
                &level.depth,
                &level.normals,
                color,
                &self.camera,
                &self.pose,
            ) {
                Ok(_) => {}
                Err(e) => failure = Some(e.to_string()),
            }
            times.integrate = t.elapsed().as_secs_f64();
            if failure.is_none() {
                let t = Instant::now();
                let r = self.model.offset;
                let hint = &self.pre.levels[r].depth;
                self.volume.raycast_with_hint(
                    &self.camera.level(r),
                    &self.pose,
                    Some(hint),
                    &mut self.raycast,
                );
                self.model.update(&self.raycast, &self.pose);
                self.has_model = true;
                times.raycast = t.elapsed().as_secs_f64();
            }
        }
        tracing::debug!(
            frame = self.frames,
            inliers,
            preprocess_ms = 1e3 * times.preprocess,
            track_ms = 1e3 * times.track,
            integrate_ms = 1e3 * times.integrate,
            raycast_ms = 1e3 * times.raycast,
            "rigid frame"
        );
        FrameReport {
            pose: self.pose,
            failure,
            times,
            inliers,
        }
    }
}
