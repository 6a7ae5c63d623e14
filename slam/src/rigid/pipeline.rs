//! The rigid SLAM loop of one frame: preprocess → track against the model raycast at the previous
//! pose → fuse at the new pose → raycast the model for the next frame. A frame that fails to track
//! is reported and not fused; the next frame starts from the last good pose.

use super::color_timing;
use super::motion_model::MotionModel;
use super::tracker::{FrameConstraint, ModelPyramid, TrackOutcome, Tracker, TrackerParams};
use crate::camera::Camera;
use crate::features::{match_frames, FeatureFrame, FeatureParams};
use crate::image::{ColorImage, DepthImage, Image};
use crate::preprocess::{PreprocessParams, Preprocessor};
use crate::tsdf::{RaycastMaps, TsdfParams, TsdfVolume};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rayon::prelude::*;
use std::time::Instant;

/// How a lost track is found again (see [`RigidSlam::process`]).
#[derive(Clone, Debug, PartialEq)]
pub struct RelocaliseParams {
    /// Try at all (default true).
    pub enabled: bool,
    /// Start poses tried around the last good pose: shifts of these lengths along each world
    /// axis, metres (default 0.15 and 0.3).
    pub shifts: Vec<f64>,
    /// … and turns by this angle about the camera's x and y axes, degrees (default 10).
    pub turn_deg: f64,
    /// A frame relocalised away from the last pose must have at least this fraction of its valid
    /// pixels as inliers (default 0.25, stricter than tracking's, as a false relocalisation
    /// corrupts the map; when the last pose itself wins, tracking's own tests apply).
    pub min_inlier_fraction: f64,
    /// Sparse features matched against the last fused frame give one more start pose.
    pub features: FeatureParams,
}

impl Default for RelocaliseParams {
    fn default() -> Self {
        Self {
            enabled: true,
            shifts: vec![0.15, 0.3],
            turn_deg: 10.0,
            min_inlier_fraction: 0.25,
            features: FeatureParams {
                ransac_iterations: 500,
                ..FeatureParams::default()
            },
        }
    }
}

/// Settings of the whole pipeline.
#[derive(Clone, Debug, PartialEq)]
pub struct SlamParams {
    /// Front end.
    pub preprocess: PreprocessParams,
    /// Tracking.
    pub tracker: TrackerParams,
    /// Map.
    pub tsdf: TsdfParams,
    /// The model is raycast for tracking at the finest sensor pyramid level at most this many
    /// pixels wide (default 160: level 2 of a 640×480 sensor, level 1 of a 320×240 one). A pixel of
    /// a 160-wide raycast spans about one 1 cm voxel at 1.5 m with TUM's intrinsics: finer maps
    /// resample the same voxels. Measured on the rendered sequences of BENCHMARKS.md, a 320-wide
    /// raycast costs 2.4× the time, and the ATE differs by at most 0.05 mm.
    pub raycast_max_width: usize,
    /// Relocalisation after a tracking failure.
    pub relocalise: RelocaliseParams,
    /// Start tracking from the pose extrapolated at constant velocity from the last two tracked
    /// frames, rather than from the last pose.
    pub predict_motion: bool,
    /// Bring colour captured at another instant than depth (stamps given to
    /// [`RigidSlam::process_timed`]) to the depth's instant with the constant-velocity motion.
    pub register_color: bool,
}

impl Default for SlamParams {
    fn default() -> Self {
        Self {
            preprocess: PreprocessParams::default(),
            tracker: TrackerParams::default(),
            tsdf: TsdfParams::default(),
            raycast_max_width: 160,
            relocalise: RelocaliseParams::default(),
            predict_motion: true,
            register_color: true,
        }
    }
}

impl SlamParams {
    /// The sensor pyramid level the model is raycast at (see [`Self::raycast_max_width`]): the
    /// finest at most that wide, else the coarsest, and never level 0 when there are others (the
    /// finest tracking level is strided anyway; on a 160×120 sensor, a full-resolution model whose
    /// coarse levels are subsampled from it tracked 10° steps to 2.3 cm instead of 4 mm).
    pub fn raycast_level(&self, camera: &Camera) -> usize {
        let levels = self.preprocess.levels.max(1);
        (1.min(levels - 1)..levels)
            .find(|&l| camera.level(l).width <= self.raycast_max_width)
            .unwrap_or(levels - 1)
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
    /// The frame was tracked only after relocalisation (tracking from the last pose failed).
    pub relocalised: bool,
    /// λ_min / λ_max of the frame's geometry (see [`TrackerParams::min_conditioning`]; 0 for
    /// the first frame).
    pub conditioning: f64,
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
    /// The last tracked frame failed: the next is relocalised.
    lost: bool,
    /// The last fused frame (filtered depth, colour) for feature relocalisation.
    key_depth: DepthImage,
    key_color: ColorImage,
    /// The frame's colour mapped into the model's exposure before it is fused.
    exposed_color: ColorImage,
    /// The frame's colour brought to its depth's instant with the predicted motion.
    registered_color: ColorImage,
    /// The last tracked poses, for the start of the next track and the colour's instant.
    motion: MotionModel,
}

/// When a frame's two images were captured, seconds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameStamps {
    /// The depth image's instant.
    pub depth: f64,
    /// The colour image's instant.
    pub color: f64,
}

impl RigidSlam {
    /// A pipeline for images from `camera`, starting at `initial_pose`.
    pub fn new(camera: Camera, params: SlamParams, initial_pose: Isometry3<f64>) -> Self {
        let raycast_level = params.raycast_level(&camera);
        Self {
            pre: Preprocessor::new(camera, params.preprocess),
            tracker: Tracker::new(params.tracker.clone()),
            volume: TsdfVolume::new(params.tsdf),
            raycast: RaycastMaps::new(),
            model: ModelPyramid::new(
                &camera,
                params.preprocess.levels.max(1) - raycast_level,
                raycast_level,
            ),
            params,
            camera,
            pose: initial_pose,
            frames: 0,
            has_model: false,
            lost: false,
            key_depth: DepthImage::new(0, 0),
            key_color: ColorImage::new(0, 0),
            exposed_color: ColorImage::new(0, 0),
            registered_color: ColorImage::new(0, 0),
            motion: MotionModel::default(),
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

    /// Processes one frame (raw depth in sensor units, optional colour) whose images were taken
    /// at the same instant, one frame interval after the last. Never fails on bad input: a frame
    /// that cannot be tracked or fused is reported in [`FrameReport::failure`].
    pub fn process(&mut self, depth_raw: &Image<u16>, color: Option<&ColorImage>) -> FrameReport {
        let t = self.motion.last_time().map_or(0.0, |t| t + 1.0);
        self.process_timed(depth_raw, color, FrameStamps { depth: t, color: t })
    }

    /// [`Self::process`] for images taken at the given instants: the motion is extrapolated by
    /// time, and colour taken at another instant than depth is brought to the depth's
    /// ([`SlamParams::register_color`]).
    pub fn process_timed(
        &mut self,
        depth_raw: &Image<u16>,
        color: Option<&ColorImage>,
        stamps: FrameStamps,
    ) -> FrameReport {
        let step = |tau: f64| self.motion.step(tau);
        let start = match self.motion.last_time() {
            Some(last) if self.params.predict_motion => {
                step(stamps.depth - last).map_or(self.pose, |s| self.pose * s)
            }
            _ => self.pose,
        };
        let delay = stamps.color - stamps.depth;
        let sized = |c: &ColorImage| (c.width, c.height) == (depth_raw.width, depth_raw.height);
        let shift = step(delay).filter(|_| self.params.register_color && delay.abs() > 1e-6);
        let mut registered = std::mem::replace(&mut self.registered_color, ColorImage::new(0, 0));
        let t_register = Instant::now();
        let color = match (color, shift) {
            (Some(c), Some(s))
                if sized(c) && (c.width, c.height) == (self.camera.width, self.camera.height) =>
            {
                color_timing::register(depth_raw, c, &self.camera, &s, &mut registered);
                Some(&registered)
            }
            (c, _) => c,
        };
        let register_seconds = t_register.elapsed().as_secs_f64();
        let mut report = self.process_frame(depth_raw, color, start);
        // the colour's registration is part of the frame's preprocessing
        report.times.preprocess += register_seconds;
        self.registered_color = registered;
        if report.failure.is_none() {
            self.motion.push(stamps.depth, report.pose);
        } else {
            self.motion.reset();
        }
        report
    }

    /// Tracks from `start` and fuses.
    fn process_frame(
        &mut self,
        depth_raw: &Image<u16>,
        color: Option<&ColorImage>,
        start: Isometry3<f64>,
    ) -> FrameReport {
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
                relocalised: false,
                conditioning: 0.0,
            };
        }
        let t = Instant::now();
        self.pre.process(depth_raw, color);
        times.preprocess = t.elapsed().as_secs_f64();
        self.frames += 1;
        let (mut failure, mut inliers, mut relocalised) = (None, 0, false);
        let (mut conditioning, mut texture) = (0.0, 0.0);
        let mut brightness = (1.0, 0.0);
        if self.has_model {
            let t = Instant::now();
            // degeneracy does not depend on the pose: checked once, before any start is tried
            let constraint = FrameConstraint::of(&self.pre.levels);
            (conditioning, texture) = (constraint.conditioning, constraint.texture);
            let enabled = self.params.relocalise.enabled;
            let outcome = if let Some(why) = constraint.degeneracy(&self.tracker.params) {
                TrackOutcome::failed(self.pose, why)
            } else if self.lost && enabled {
                // after a failure the last pose is only one start among the relocaliser's: a
                // track that converges from it is not trusted over a better one
                let found = self.relocalise(color);
                relocalised = found.is_some();
                found.unwrap_or_else(|| {
                    TrackOutcome::failed(
                        self.pose,
                        "lost, and no start pose relocalised the frame".into(),
                    )
                })
            } else {
                let tracked = self.tracker.track(&self.pre.levels, &self.model, &start);
                let retry = tracked.failure.is_some() && enabled && tracked.valid_pixels > 0;
                let found = if retry { self.relocalise(color) } else { None };
                relocalised = found.is_some();
                found.unwrap_or(tracked)
            };
            if relocalised {
                tracing::debug!(frame = self.frames, "relocalised");
            }
            times.track = t.elapsed().as_secs_f64();
            self.lost = outcome.failure.is_some();
            failure = outcome.failure;
            inliers = outcome.inliers;
            brightness = outcome.brightness;
            self.pose = outcome.pose;
        } else {
            let max = self.params.tsdf.max_depth;
            let valid = self.pre.levels[0]
                .depth
                .data
                .iter()
                .filter(|d| **d > 0.0 && **d <= max)
                .count();
            if valid < 1000 {
                failure = Some(format!(
                    "only {valid} depth pixels within the fusion range (0, {max} m] to start the map"
                ));
            }
        }
        // fuse the colour in the model's exposure, so that the model stays one brightness
        let color = match color {
            Some(c) if failure.is_none() && brightness != (1.0, 0.0) => {
                expose(c, brightness, &mut self.exposed_color);
                Some(&self.exposed_color)
            }
            other => other,
        };
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
            if failure.is_none() && self.params.relocalise.enabled {
                self.key_depth.clone_from(&level.depth);
                if let Some(c) = color {
                    self.key_color.clone_from(c);
                }
            }
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
            conditioning,
            texture,
            relocalised,
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
            relocalised,
            conditioning,
        }
    }

    /// Tries to find the live frame's pose after tracking from the last pose failed: start poses
    /// around the last good pose (shifted along each axis, turned about the camera's x and y), and
    /// the motion that sparse features matched against the last fused frame give, are each tracked
    /// on the coarsest level; the best is refined on all levels and kept when it passes the
    /// tracker's tests with [`RelocaliseParams::min_inlier_fraction`] inliers.
    fn relocalise(&mut self, color: Option<&ColorImage>) -> Option<TrackOutcome> {
        let p = &self.params.relocalise;
        let last = self.pose;
        let mut starts = vec![last];
        if let Some(c) = color.filter(|_| !self.key_color.data.is_empty()) {
            let live = FeatureFrame {
                color: c,
                depth: &self.pre.levels[0].depth,
                camera: &self.camera,
                mask: None,
            };
            let key = FeatureFrame {
                color: &self.key_color,
                depth: &self.key_depth,
                camera: &self.camera,
                mask: None,
            };
            if let Some(m) = match_frames(&live, &key, &p.features) {
                // live points map into the key frame: T_live = T_key · M
                starts.push(last * m.motion);
            }
        }
        for &d in &p.shifts {
            for axis in 0..3 {
                for sign in [-1.0, 1.0] {
                    let mut t = Vector3::zeros();
                    t[axis] = sign * d;
                    starts.push(Translation3::from(t) * last);
                }
            }
        }
        for axis in [Vector3::x(), Vector3::y()] {
            for sign in [-1.0, 1.0] {
                let turn = UnitQuaternion::from_scaled_axis(axis * sign * p.turn_deg.to_radians());
                starts.push(last * turn);
            }
        }
        // screen on the coarsest level only
        let full = std::mem::take(&mut self.tracker.params.iterations);
        let coarse = full.len().saturating_sub(1);
        self.tracker.params.iterations = (0..full.len())
            .map(|l| if l == coarse { full[l].max(4) } else { 0 })
            .collect();
        let mut best: Option<(f64, usize)> = None;
        for (k, start) in starts.iter().enumerate() {
            let o = self.tracker.track(&self.pre.levels, &self.model, start);
            let fraction = o.inliers as f64 / o.valid_pixels.max(1) as f64;
            if o.failure.is_none() && best.is_none_or(|b| fraction > b.0) {
                best = Some((fraction, k));
            }
        }
        self.tracker.params.iterations = full;
        let (screened, k) = best?;
        let o = self
            .tracker
            .track(&self.pre.levels, &self.model, &starts[k]);
        let fraction = o.inliers as f64 / o.valid_pixels.max(1) as f64;
        tracing::debug!(
            frame = self.frames,
            candidates = starts.len(),
            best = k,
            screened,
            fraction,
            failure = o.failure.as_deref().unwrap_or_default(),
            "relocalisation"
        );
        // the last pose winning is ordinary tracking, held to its tests; a jump elsewhere must
        // also have the stricter inlier fraction
        let strict = if k == 0 {
            0.0
        } else {
            self.params.relocalise.min_inlier_fraction
        };
        (o.failure.is_none() && fraction >= strict).then_some(o)
    }
}

/// `out` = a c + 255 b per channel of `c`, rounded and clamped to 8 bits: a colour image mapped
/// by the exposure fit (a, b) of intensities in [0, 1].
fn expose(c: &ColorImage, (a, b): (f64, f64), out: &mut ColorImage) {
    out.reset(c.width, c.height, [0; 3]);
    let (a, b) = (a as f32, 255.0 * b as f32);
    out.data.par_iter_mut().zip(&c.data).for_each(|(o, p)| {
        for (oc, &pc) in o.iter_mut().zip(p) {
            *oc = (a * pc as f32 + b).round().clamp(0.0, 255.0) as u8;
        }
    });
}
