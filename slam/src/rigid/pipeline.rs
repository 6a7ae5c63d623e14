//! The rigid SLAM loop of one frame, in its steps: preprocess → start the map (first frame) or
//! locate the frame (track against the model raycast at the predicted pose, or relocalise) →
//! fuse at the new pose → raycast the model for the next frame. A frame that is not tracked is
//! reported with a typed reason ([`FrameOutcome::NotTracked`]) and not fused; the next frame
//! starts from the last good pose.

use super::color_timing;
use super::health::{Fit, Health};
use super::keyframes::median_depth;
use super::keyframes::{Candidate, Keyframe, Keyframes};
use super::loop_candidates;
use super::loop_search::{LoopQuery, LoopSearch, LoopTarget, MAX_PENDING};
use super::loops::LoopCandidate;
use super::loops::{find_loop, BackgroundSolver, KeyframeGraph, LoopError, Optimised, Reach};
use super::motion_model::MotionModel;
use super::outcome::{FrameOutcome, TrackFailure};
use super::relocalise::{Floors, LiveFrame, RelocaliseParams, Relocaliser};
use super::spread::OdometrySpread;
use super::submaps::{SubmapParams, Submaps};
use super::tracker::{FrameConstraint, ModelPyramid, TrackOutcome, Tracker, TrackerParams};
use crate::camera::Camera;
use crate::image::{ColorImage, Image};
use crate::mesh::Mesh;
use crate::preprocess::{PreprocessParams, Preprocessor};
use crate::tsdf::{RaycastMaps, TsdfError, TsdfParams, TsdfVolume};
use nalgebra::Isometry3;
use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;

/// How much faster than the fastest motion tracked the camera may have moved while lost.
const REACH_MARGIN: f64 = 1.5;

/// Depth pixels in the fusion range a frame needs to start a map (or a new map fragment).
const MIN_START_DEPTH: usize = 1000;

/// A tracked frame whose texture correlates with the model's below this share of the recent
/// frames' median is not trusted ([`RigidSlam::refused_on_texture`]): half, the plain meaning
/// of "far worse", not a fit. The relocaliser's floor for choosing among its poses is stricter
/// ([`RelocaliseParams::min_fit_ratio`], 0.85).
const TEXTURE_MISMATCH_RATIO: f64 = 0.5;

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
    /// Split the map into sub-maps anchored to keyframes ([`super::submaps`]), tracked against
    /// the newest only, with loops measured densely against the older ones; `None` (the
    /// default) keeps one volume and finds loops by features (written with the graph, but the
    /// volume cannot follow them, so they correct nothing). Needs relocalisation enabled (its
    /// keyframes anchor the sub-maps).
    pub submaps: Option<SubmapParams>,
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
            submaps: None,
        }
    }
}

impl SlamParams {
    /// The sensor pyramid level the model is raycast at (see [`Self::raycast_max_width`]): the
    /// finest at most that wide, else the coarsest, and never level 0 when there are others (the
    /// finest tracking level is strided anyway; on a 160×120 sensor, a full-resolution model whose
    /// coarse levels are subsampled from it tracked 10° steps to 2.3 cm instead of 4 mm).
    pub(crate) fn raycast_level(&self, camera: &Camera) -> usize {
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
    /// Whether the frame was fused, and how its pose was found or why it was not.
    pub outcome: FrameOutcome,
    /// Stage times.
    pub times: StageTimes,
    /// Inlier point-to-plane associations at the finest tracking level (0 when not tracked).
    pub inliers: usize,
    /// … as a fraction of the valid pixels on that level's tracking grid.
    pub inlier_fraction: f64,
    /// Of those pixels that land on the model, the share that agree with it (see
    /// [`TrackOutcome::agreement`]).
    pub agreement: f64,
    /// … and the share near it whatever the normals' angle ([`TrackOutcome::proximity`]).
    pub proximity: f64,
    /// Over the agreeing points, the correlation of the live intensities with the model's
    /// ([`TrackOutcome::correlation`]).
    pub correlation: f64,
    /// λ_min / λ_max of the frame's geometry (see [`TrackerParams::min_conditioning`]; 0 for
    /// the first frame).
    pub conditioning: f64,
    /// The keyframe (its frame index in the [`KeyframeGraph`]) whose pose this frame's hangs
    /// from: the newest one when the frame was fused. [`KeyframeGraph::corrected`] carries the
    /// pose along when a loop moves the keyframe. `None` before the first keyframe.
    pub anchor: Option<usize>,
    /// Whether the frame's map fragment lies in the main map: false for a frame of a new map
    /// fragment that no loop has joined to it yet ([`KeyframeGraph::is_placed`]), whose pose
    /// says nothing of where it lies in the map. The pose stays in its fragment's tracking
    /// frame either way: [`KeyframeGraph::between_fragments`] (from `anchor` to the first
    /// keyframe) takes it into the main map's, and [`KeyframeGraph::corrected`] with the
    /// graph's solution into the corrected map, as `rigid_slam`'s trajectory does.
    pub placed: bool,
    /// The exposure gain a the frame was tracked with: the model's intensity is about a I for
    /// the live intensity I (NOTES 60; 1 when not fitted or not tracked). The colour is fused
    /// as recorded.
    pub gain: f64,
    /// The live frame's vignetting v relative to the model's that the frame was tracked with:
    /// the live intensity l enters as a l / (1 − v ρ²) (NOTES 87; 0 when not fitted or not
    /// tracked).
    pub vignetting: f64,
}

impl FrameReport {
    /// Why the frame was not tracked, if it was not.
    pub fn failure(&self) -> Option<&TrackFailure> {
        self.outcome.failure()
    }
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
    /// Finds a lost track again.
    relocaliser: Relocaliser,
    /// The keyframes' pose graph with the loops found.
    loops: KeyframeGraph,
    /// Solves the graph off the tracking thread whenever a loop is added.
    graph_solver: BackgroundSolver,
    /// Searches the sub-maps for a new keyframe's loop off the tracking thread.
    loop_search: LoopSearch,
    /// The recent frames' agreements with the model and stamps.
    health: Health,
    /// Frames given to [`Self::process`] and [`Self::process_timed`].
    calls: usize,
    /// The frame's colour brought to its depth's instant with the predicted motion.
    registered_color: ColorImage,
    /// The last tracked poses, for the start of the next track and the colour's instant.
    motion: MotionModel,
    /// The newest keyframe in the graph.
    anchor: Option<usize>,
    /// The older sub-maps, when the map is split ([`SlamParams::submaps`]).
    submaps: Option<Submaps>,
    /// Depth samples for a loop's median depth.
    samples: Vec<f32>,
    /// The tracking's spread since the newest keyframe, for the next odometry edge.
    spread: OdometrySpread,
    /// Frames in a row the relocaliser did not find.
    unrelocalised: usize,
    /// The frame being fused starts a new map fragment.
    starting_map: bool,
    /// The stamps of the frame being processed and of the newest keyframe.
    stamp: f64,
    keyframe_stamp: f64,
    /// The frame's stamps are the sensor's ([`Self::process_timed`]), not frame counts.
    timed: bool,
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
    pub fn new(camera: Camera, mut params: SlamParams, initial_pose: Isometry3<f64>) -> Self {
        let raycast_level = params.raycast_level(&camera);
        let r = &mut params.relocalise;
        if params.submaps.is_some() && r.keyframes.recent_frames == usize::MAX {
            r.keyframes.recent_frames = r.loops.min_frames_apart;
        }
        let relocaliser = Relocaliser::new(&params.relocalise);
        let loops = KeyframeGraph::new(params.relocalise.loops.clone());
        let params_submaps = params.submaps;
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
            loops,
            graph_solver: BackgroundSolver::new(),
            loop_search: LoopSearch::default(),
            relocaliser,
            health: Health::default(),
            calls: 0,
            registered_color: ColorImage::new(0, 0),
            motion: MotionModel::default(),
            anchor: None,
            submaps: params_submaps.map(Submaps::new),
            samples: Vec::new(),
            spread: OdometrySpread::default(),
            unrelocalised: 0,
            starting_map: false,
            stamp: 0.0,
            keyframe_stamp: 0.0,
            timed: false,
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

    /// Frames counted so far: those given that had the configured size. Keyframes and the
    /// log name a frame by this count (from 1).
    pub fn frames_counted(&self) -> usize {
        self.frames
    }

    /// The keyframes' pose graph: odometry between consecutive keyframes and the loops found
    /// ([`super::loops`]); [`KeyframeGraph::optimise`] solves it.
    pub fn keyframe_graph(&self) -> &KeyframeGraph {
        &self.loops
    }

    /// The newest solution of the keyframe graph that the background solver has finished,
    /// without waiting for one under way (`None` before the first loop is solved).
    pub fn graph_solution(&mut self) -> Result<Option<&Optimised>, LoopError> {
        self.graph_solver.poll()
    }

    /// Waits for the loop searches under way to add their loops to the graph and for the
    /// background solver to finish the graphs handed to it; the newest solution (`None` when
    /// no loop was found).
    pub fn finish_graph(&mut self) -> Result<Option<&Optimised>, LoopError> {
        self.finish_loops();
        self.graph_solver.finish()
    }

    /// Waits for the loop searches under way (with sub-maps they run off the tracking thread)
    /// and adds their loops to the graph.
    pub fn finish_loops(&mut self) {
        self.take_loops(1);
    }

    /// The older sub-maps, when the map is split ([`SlamParams::submaps`]).
    pub fn submaps(&self) -> Option<&Submaps> {
        self.submaps.as_ref()
    }

    /// The map's surface in the frame of the graph's `solution` (when there is one): with
    /// sub-maps, each moved with its anchor keyframe ([`Submaps::mesh`]); a single volume
    /// cannot follow and is meshed as fused.
    pub fn map_mesh(&self, solution: Option<&BTreeMap<usize, Isometry3<f64>>>) -> Mesh {
        let Some(s) = &self.submaps else {
            return self.volume.extract_mesh();
        };
        let unplaced = self.loops.unplaced();
        let identity = Isometry3::identity();
        s.mesh(&self.volume, |a| {
            let c = solution.map_or(identity, |x| self.loops.corrected(x, a, &identity));
            (!unplaced.contains(&a)).then_some(c)
        })
    }

    /// The keyframes kept for relocalisation.
    pub fn keyframes(&self) -> &Keyframes {
        self.relocaliser.keyframes()
    }

    /// The last model raycast (at the current pose).
    pub fn model_maps(&self) -> &RaycastMaps {
        &self.raycast
    }

    /// Processes one frame (raw depth in sensor units, optional colour) whose images were taken
    /// at the same instant, one frame interval after the last. Never fails on bad input: a frame
    /// that cannot be tracked or fused is reported in [`FrameReport::outcome`]. Without stamps
    /// the time a dropped stretch took is unknown, so a relocalised pose is not held to the
    /// camera's reach (see [`Self::process_timed`]).
    pub fn process(&mut self, depth_raw: &Image<u16>, color: Option<&ColorImage>) -> FrameReport {
        let t = self.calls as f64;
        self.process_at(depth_raw, color, FrameStamps { depth: t, color: t }, false)
    }

    /// [`Self::process`] for images taken at the given instants: the motion is extrapolated by
    /// time, colour taken at another instant than depth is brought to the depth's
    /// ([`SlamParams::register_color`]), and a relocalised pose must lie within the camera's
    /// reach of the last one for the time elapsed (NOTES 92).
    pub fn process_timed(
        &mut self,
        depth_raw: &Image<u16>,
        color: Option<&ColorImage>,
        stamps: FrameStamps,
    ) -> FrameReport {
        self.process_at(depth_raw, color, stamps, true)
    }

    /// [`Self::process_timed`], the stamps being the sensor's (`timed`) or frame counts.
    fn process_at(
        &mut self,
        depth_raw: &Image<u16>,
        color: Option<&ColorImage>,
        stamps: FrameStamps,
        timed: bool,
    ) -> FrameReport {
        self.calls += 1;
        self.timed = timed;
        let step = |tau: f64| self.motion.step(tau);
        let start = match self.motion.last_time() {
            Some(last) if self.params.predict_motion => {
                step(stamps.depth - last).map_or(self.pose, |s| self.pose * s)
            }
            _ => self.pose,
        };
        let delay = stamps.color - stamps.depth;
        let sized = |c: &ColorImage| (c.width, c.height) == (depth_raw.width, depth_raw.height);
        let shift = self
            .motion
            .colour_step(delay)
            .filter(|_| self.params.register_color && delay.abs() > 1e-6);
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
        let mut report = self.process_frame(depth_raw, color, start, stamps.depth);
        // the colour's registration is part of the frame's preprocessing
        report.times.preprocess += register_seconds;
        self.registered_color = registered;
        // a relocalised pose starts a new motion: the jump to it is no velocity
        let jumped = matches!(
            report.outcome,
            FrameOutcome::Relocalised | FrameOutcome::NewMap
        );
        if !report.outcome.is_fused() || jumped {
            self.motion.reset();
        }
        if report.outcome.is_fused() {
            self.motion.push(stamps.depth, report.pose);
        }
        report
    }

    /// One frame's steps from the predicted pose `start`: preprocess, start the map or locate
    /// the frame, fuse, raycast.
    fn process_frame(
        &mut self,
        depth_raw: &Image<u16>,
        color: Option<&ColorImage>,
        start: Isometry3<f64>,
        stamp: f64,
    ) -> FrameReport {
        let mut report = FrameReport {
            pose: self.pose,
            outcome: if self.has_model {
                FrameOutcome::Tracked
            } else {
                FrameOutcome::Started
            },
            times: StageTimes::default(),
            inliers: 0,
            inlier_fraction: 0.0,
            agreement: 0.0,
            proximity: 0.0,
            correlation: 0.0,
            conditioning: 0.0,
            anchor: None,
            placed: true,
            gain: 1.0,
            vignetting: 0.0,
        };
        if let Err(why) = self.check_size(depth_raw, color) {
            report.outcome = FrameOutcome::NotTracked(why);
            return report;
        }
        self.stamp = stamp;
        let t = Instant::now();
        self.pre.process(depth_raw, color);
        report.times.preprocess = t.elapsed().as_secs_f64();
        self.frames += 1;
        let located = if self.has_model {
            let t = Instant::now();
            let located = self.locate(color, start, stamp, &mut report);
            let located = self.new_map_if_lost(located, color.is_some(), &mut report);
            report.times.track = t.elapsed().as_secs_f64();
            located
        } else {
            self.can_start().map(|()| 1.0)
        };
        let untracked = matches!(report.outcome, FrameOutcome::Started | FrameOutcome::NewMap);
        let fit = (!untracked).then_some(Fit {
            fraction: report.inlier_fraction,
            agreement: report.agreement,
            proximity: report.proximity,
            correlation: report.correlation,
        });
        let agreement = fit.map(|f| f.agreement);
        let fused = located.and_then(|gain| {
            report.gain = gain;
            let t = Instant::now();
            let fused = self.fuse(color, agreement);
            report.times.integrate = t.elapsed().as_secs_f64();
            fused.map_err(TrackFailure::from)
        });
        match fused {
            Ok(()) => {
                self.health.push(stamp, fit);
                if let (FrameOutcome::Relocalised, Some(fit)) = (&report.outcome, fit) {
                    self.health.restart(fit);
                }
                let t = Instant::now();
                self.raycast();
                report.times.raycast = t.elapsed().as_secs_f64();
            }
            Err(why) => report.outcome = FrameOutcome::NotTracked(why),
        }
        self.take_loops(usize::MAX);
        report.pose = self.pose;
        report.anchor = self.anchor;
        report.placed = self.anchor.is_none_or(|a| self.loops.is_placed(a));
        self.log(&report);
        report
    }

    /// The frame's images must be the camera's size.
    fn check_size(
        &self,
        depth_raw: &Image<u16>,
        color: Option<&ColorImage>,
    ) -> Result<(), TrackFailure> {
        let (width, height) = (self.camera.width, self.camera.height);
        let wrong = |w: usize, h: usize| (w, h) != (width, height);
        let (got_width, got_height) = match color {
            _ if wrong(depth_raw.width, depth_raw.height) => (depth_raw.width, depth_raw.height),
            Some(c) if wrong(c.width, c.height) => (c.width, c.height),
            _ => return Ok(()),
        };
        Err(TrackFailure::ImageSize {
            got_width,
            got_height,
            width,
            height,
        })
    }

    /// Counts the frames in a row that were not relocalised; once there are
    /// [`RelocaliseParams::new_map_after`], the frame (if it has colour for a keyframe and
    /// depth to start a map) starts a new map fragment at the last good pose: the active
    /// sub-map is frozen (one volume becomes the first sub-map), an empty one takes over, and
    /// the frame becomes the fragment's first keyframe when fused ([`super::loops`] places the
    /// fragment once a loop joins it).
    fn new_map_if_lost(
        &mut self,
        located: Result<f64, TrackFailure>,
        has_color: bool,
        report: &mut FrameReport,
    ) -> Result<f64, TrackFailure> {
        if !matches!(located, Err(TrackFailure::NotRelocalised)) {
            if located.is_ok() {
                self.unrelocalised = 0;
            }
            return located;
        }
        self.unrelocalised += 1;
        let after = self.params.relocalise.new_map_after;
        let due = after > 0 && self.unrelocalised >= after && has_color;
        let tsdf = self.params.tsdf;
        if !due || self.can_start().is_err() {
            return located;
        }
        if !self.split_volume() {
            return located;
        }
        if let Some(s) = self.submaps.as_mut() {
            s.restart(self.frames, tsdf, &mut self.volume);
        }
        self.unrelocalised = 0;
        self.lost = false;
        self.starting_map = true;
        self.health.forget_fits();
        self.spread = OdometrySpread::default();
        report.outcome = FrameOutcome::NewMap;
        tracing::info!(
            frame = self.frames,
            "lost for good: a new map fragment starts"
        );
        Ok(1.0)
    }

    /// Whether the map is in sub-maps: with one volume, that volume becomes the one sub-map
    /// so far, anchored at the first keyframe (not before there is one) and never split by its
    /// frame count.
    fn split_volume(&mut self) -> bool {
        if self.submaps.is_some() {
            return true;
        }
        let Some(&anchor) = self.loops.graph().vertices.keys().next() else {
            return false;
        };
        let params = SubmapParams {
            frames: usize::MAX,
            ..SubmapParams::default()
        };
        let last = self.frames.saturating_sub(1);
        self.submaps = Some(Submaps::single(params, anchor, 1, last));
        // as `new` sets it for sub-maps
        let r = &self.params.relocalise;
        if r.keyframes.recent_frames == usize::MAX {
            self.relocaliser
                .keep_away_from_recent(r.loops.min_frames_apart);
        }
        true
    }

    /// The first frame starts the map if enough of its depth lies in the fusion range.
    fn can_start(&self) -> Result<(), TrackFailure> {
        let max_depth = self.params.tsdf.max_depth;
        let depth = &self.pre.levels[0].depth.data;
        let valid = depth
            .iter()
            .filter(|d| **d > 0.0 && **d <= max_depth)
            .count();
        if valid < MIN_START_DEPTH {
            return Err(TrackFailure::TooLittleDepthToStart { valid, max_depth });
        }
        Ok(())
    }

    /// Finds the frame's pose. After a break in the stream (the track was lost, or the stamps
    /// skip more than [`RelocaliseParams::gap_intervals`] frame intervals) every start of the
    /// relocaliser competes and the winner must look like the recent frames (the floors of
    /// [`RelocaliseParams::min_fit_ratio`] × their fit); otherwise the frame is tracked from
    /// `start`, and a track that fails or falls below either floor faces the relocaliser, the
    /// higher inlier fraction kept. Sets the pose, the report's outcome, inliers and
    /// conditioning; on success, the exposure gain the frame was tracked with.
    fn locate(
        &mut self,
        color: Option<&ColorImage>,
        start: Isometry3<f64>,
        stamp: f64,
        report: &mut FrameReport,
    ) -> Result<f64, TrackFailure> {
        // degeneracy does not depend on the pose: checked once, before any start is tried
        let constraint = FrameConstraint::of(&self.pre.levels);
        report.conditioning = constraint.conditioning;
        let p = &self.params.relocalise;
        let enabled = p.enabled;
        let expected = self
            .health
            .expected()
            .map_or(Fit::default(), |e| e.scaled(p.min_fit_ratio));
        let broken = self.lost || self.health.is_gap(stamp, p.gap_intervals);
        let floors = Floors {
            local: expected,
            keyframe_ratio: p.min_fit_ratio,
        };
        let (outcome, relocalised) = if let Some(why) = constraint.degeneracy(&self.tracker.params)
        {
            (TrackOutcome::failed(self.pose, why), false)
        } else if broken && enabled {
            match self.relocalise(color, floors, constraint.conditioning, true) {
                Some(found) => (found, true),
                None => (
                    TrackOutcome::failed(self.pose, TrackFailure::NotRelocalised),
                    false,
                ),
            }
        } else {
            self.track_from(color, start, expected, constraint.conditioning)
        };
        let outcome = match color {
            Some(_) => self.refused_on_texture(outcome),
            // a frame without colour has no texture to match
            None => outcome,
        };
        self.lost = outcome.failure.is_some();
        self.pose = outcome.pose;
        if let Some(c) = &outcome.covariance {
            self.spread.push(&self.pose, c);
        }
        report.inliers = outcome.inliers;
        report.inlier_fraction = outcome.inlier_fraction();
        report.agreement = outcome.agreement;
        report.proximity = outcome.proximity;
        report.correlation = outcome.correlation;
        if outcome.failure.is_none() {
            report.vignetting = outcome.vignetting;
        }
        if relocalised {
            report.outcome = FrameOutcome::Relocalised;
        }
        match outcome.failure {
            Some(why) => Err(why),
            None => Ok(outcome.gain),
        }
    }

    /// The frame tracked from `start`; a track that fails, falls below the `expected` fit or
    /// whose texture is in doubt ([`Self::texture_doubt`]) faces the relocaliser, whose pose
    /// replaces it when the track failed, or has a higher inlier fraction, or (in doubt over
    /// the texture) correlates better. Whether the pose is the relocaliser's.
    fn track_from(
        &mut self,
        color: Option<&ColorImage>,
        start: Isometry3<f64>,
        expected: Fit,
        conditioning: f64,
    ) -> (TrackOutcome, bool) {
        let tracked = self.tracker.track(&self.pre.levels, &self.model, &start);
        let fraction = tracked.inlier_fraction();
        let texture_doubt = color.is_some() && self.texture_doubt(tracked.correlation);
        let doubtful = tracked.failure.is_some()
            || texture_doubt
            || tracked.agreement < expected.agreement
            || fraction < expected.fraction;
        let retry = doubtful && self.params.relocalise.enabled && tracked.valid_pixels > 0;
        // a pose that replaces the track needs only a better fraction, but its texture must
        // match the model as the recent frames' did
        let floors = Floors {
            local: Fit {
                correlation: expected.correlation,
                ..Fit::default()
            },
            keyframe_ratio: 0.0,
        };
        match retry
            .then(|| self.relocalise(color, floors, conditioning, false))
            .flatten()
        {
            Some(found)
                if tracked.failure.is_some()
                    || found.inlier_fraction() > fraction
                    || (texture_doubt && found.correlation > tracked.correlation) =>
            {
                (found, true)
            }
            _ => (tracked, false),
        }
    }

    /// Whether a track's `correlation` with the model falls below
    /// [`RelocaliseParams::min_correlation_ratio`] of the recent frames' median, where that
    /// median can tell poses apart ([`Fit::telling`]).
    fn texture_doubt(&self, correlation: f64) -> bool {
        let ratio = self.params.relocalise.min_correlation_ratio;
        self.health
            .expected()
            .is_some_and(|recent| recent.telling() && correlation < ratio * recent.correlation)
    }

    /// `outcome`, or a failure at the last good pose when its texture matches the model far
    /// worse than the recent frames' did ([`TEXTURE_MISMATCH_RATIO`] of their median
    /// correlation, where that median can tell poses apart, [`Fit::telling`]). The fraction
    /// and the agreement are geometry's; a track that ends at a wrong pose on the same planes
    /// keeps them, and only the texture gives it away. A camera that began to whip at 360°/s
    /// was tracked 25 cm off with a correlation of 0.33, against 0.97 over the frames before
    /// (NOTES 124). A relocalised pose has passed a stricter floor already.
    fn refused_on_texture(&self, mut outcome: TrackOutcome) -> TrackOutcome {
        let Some(recent) = self.health.expected() else {
            return outcome;
        };
        let floor = TEXTURE_MISMATCH_RATIO * recent.correlation;
        if outcome.failure.is_none() && recent.telling() && outcome.correlation < floor {
            outcome.failure = Some(TrackFailure::TextureMismatch {
                correlation: outcome.correlation,
                floor,
            });
            outcome.pose = self.pose;
            outcome.covariance = None;
        }
        outcome
    }

    /// The relocaliser's pose for the live frame (whose geometry's conditioning is
    /// `conditioning`), if it finds one; after a break in the stream (`broken`) it also starts
    /// from where the camera's last velocity carries it ([`RelocaliseParams::coast`]).
    fn relocalise(
        &mut self,
        color: Option<&ColorImage>,
        floors: Floors,
        conditioning: f64,
        broken: bool,
    ) -> Option<TrackOutcome> {
        // the time since the last fused frame
        let elapsed = self.stamp - self.health.last_stamp().unwrap_or(self.stamp);
        // where the camera got to had it gone on as it was going (RelocaliseParams::coast)
        let coast = (broken && self.params.relocalise.coast)
            .then(|| self.motion.coast(elapsed))
            .flatten()
            .map(|m| self.pose * m);
        let reach = if self.timed {
            self.reach_after(elapsed)
        } else {
            Reach::UNBOUNDED
        };
        let live = LiveFrame {
            levels: &self.pre.levels,
            color,
            camera: &self.camera,
            model_template: &self.model,
        };
        let (loops, current) = (&self.loops, self.anchor.unwrap_or(0));
        let place = |f: usize| loops.between_fragments(f, current);
        let found = self.relocaliser.relocalise(
            &self.params.relocalise,
            &mut self.tracker,
            (&self.volume, &self.model),
            &live,
            (self.pose, coast, reach, conditioning),
            floors,
            (self.frames, &place),
        );
        if found.is_some() {
            tracing::debug!(frame = self.frames, "relocalised");
        }
        found
    }

    /// Fuses the frame at the current pose, its colour as recorded; the relocaliser keeps it
    /// (with the agreement it was tracked with). The exposure fit is tracking's alone: colour
    /// fused through it fed the fit back into the model, and where the sensor darkens the
    /// image's corners (vignetting), surfaces first seen at the border made the model darker
    /// than the view's centre, the next fit lower, and so on, down to half the exposure within
    /// 200 frames of a survey (NOTES 60).
    fn fuse(
        &mut self,
        color: Option<&ColorImage>,
        agreement: Option<f64>,
    ) -> Result<(), TsdfError> {
        let level = &self.pre.levels[0];
        let view = (&self.camera, &self.pose);
        integrate(&mut self.volume, level, color, view)?;
        if let Some(next) = self.submaps.as_mut().and_then(Submaps::next_volume) {
            integrate(next, level, color, view)?;
        }
        if let Some(s) = self.submaps.as_mut() {
            s.fused(self.frames, &mut self.volume);
        }
        if self.params.relocalise.enabled {
            let frame = Candidate {
                frame: self.frames,
                pose: self.pose,
                agreement,
                color,
                depth: &level.depth,
                camera: &self.camera,
            };
            let max_depth = self.params.tsdf.max_depth;
            let p = &self.params.relocalise;
            let new_map = std::mem::take(&mut self.starting_map);
            if self.relocaliser.remember(&frame, p, max_depth, new_map) {
                self.keyframe_added(color, new_map);
            }
        }
        Ok(())
    }

    /// The frame just became a keyframe: it joins the graph (as the first of a new map
    /// fragment when `new_map`), may anchor a sub-map, and is matched against the older
    /// keyframes for a loop (densely against the older sub-maps off the tracking thread when
    /// the map is split, by features otherwise); a loop found sends the graph to the solver.
    fn keyframe_added(&mut self, color: Option<&ColorImage>, new_map: bool) {
        let spread = self.spread.take(&self.pose);
        if new_map {
            self.loops.start_fragment(
                self.frames,
                self.pose,
                self.reach_after(self.stamp - self.keyframe_stamp),
            );
        } else {
            self.loops
                .add_tracked_keyframe(self.frames, self.pose, spread.as_ref());
        }
        self.anchor = Some(self.frames);
        self.keyframe_stamp = self.stamp;
        let tsdf = self.params.tsdf;
        if let Some(s) = self.submaps.as_mut().filter(|s| s.wants_anchor()) {
            s.anchor(self.frames, tsdf);
            if let Some(next) = s.next_volume() {
                // the anchor's own frame starts the new sub-map; an error is the memory
                // budget's, met again (and reported) when the next frame is fused into it
                let view = (&self.camera, &self.pose);
                if let Err(why) = integrate(next, &self.pre.levels[0], color, view) {
                    tracing::warn!(frame = self.frames, %why, "the new sub-map's first frame was not fused");
                }
            }
        }
        if new_map {
            return;
        }
        if self.submaps.is_some() {
            // searched off the tracking thread; its loop reaches the graph in a later frame
            if let Some(query) = self.loop_query(color) {
                self.take_loops(MAX_PENDING);
                self.loop_search.submit(query);
            }
            return;
        }
        let p = &self.params.relocalise;
        if let Some(l) = find_loop(
            self.relocaliser.keyframes(),
            &self.loops.params,
            &p.features,
        ) {
            self.add_loop(&l);
        }
    }

    /// How far the camera can have gone `elapsed` after a pose: half as fast again as the
    /// fastest it moved between two tracked frames, for that time.
    fn reach_after(&self, elapsed: f64) -> Reach {
        let elapsed = elapsed.max(0.0);
        let (v, w) = self.motion.fastest();
        Reach {
            translation: REACH_MARGIN * v * elapsed,
            rotation: REACH_MARGIN * w * elapsed,
        }
    }

    /// The dense loop search of the new keyframe (the current frame), for the worker
    /// ([`super::loop_search`]): older keyframes in frozen sub-maps at least
    /// [`super::loops::LoopParams::min_frames_apart`] frames back (keyframes of older map
    /// fragments however recent, as no odometry joins them), the nearest by fern code and those
    /// of the current map fragment whose tracked poses lie near the new one's
    /// ([`loop_candidates::nearby`]). `None` when there is nothing to try or the recent frames
    /// do not yet say what a good fit is.
    fn loop_query(&mut self, color: Option<&ColorImage>) -> Option<Box<LoopQuery>> {
        let submaps = self.submaps.as_ref()?;
        let until = submaps.frozen_until()?;
        let p = &self.params.relocalise;
        let apart = self.loops.params.min_frames_apart.max(1);
        let since = self.relocaliser.fragment_start();
        let floor = self.health.expected()?.scaled(p.min_fit_ratio);
        let depth = median_depth(&self.pre.levels[0].depth, &mut self.samples);
        let keys = self.relocaliser.keyframes().frames();
        let targets: Vec<LoopTarget> = self
            .loop_candidates(since, until, apart, depth)
            .into_iter()
            .filter_map(|(k, frame, pose)| {
                let map = submaps.containing(frame)?;
                Some(LoopTarget {
                    index: k,
                    frame,
                    pose,
                    map: Arc::clone(&map.volume),
                    keyframe: (frame < since).then(|| keys[k].clone()),
                })
            })
            .collect();
        if targets.is_empty() {
            return None;
        }
        Some(Box::new(LoopQuery {
            frame: self.frames,
            pose: self.pose,
            since,
            depth,
            floor,
            targets,
            poses: keys.iter().map(|k| k.pose).collect(),
            newest: keys.last()?.clone(),
            levels: self.pre.levels.clone(),
            color: color.cloned(),
            camera: self.camera,
            model_template: self.model.clone(),
            tracker: self.tracker.clone(),
            params: p.clone(),
        }))
    }

    /// Adds the loops the worker has found since the last call to the graph, in the order
    /// their keyframes were taken, after waiting until fewer than `below` searches are
    /// pending; a loop added sends the graph to the solver.
    fn take_loops(&mut self, below: usize) {
        for l in self.loop_search.finished(below) {
            self.add_loop(&l);
        }
    }

    /// Adds a verified loop to the keyframe graph and, if the graph keeps it, has the graph
    /// solved.
    fn add_loop(&mut self, l: &LoopCandidate) {
        tracing::debug!(from = l.from, to = l.to, inliers = l.inliers, "loop");
        if self.loops.add_loop(l) {
            self.graph_solver.submit(&self.loops);
        }
    }

    /// The keyframes a dense loop from the newest keyframe tries, as (index, frame, pose):
    /// those taken by frame `until` (in frozen sub-maps) and either before `since` (older map
    /// fragments) or `apart` frames back; the nearest by fern code first, then those near the
    /// newest one's tracked pose in the current fragment (scene median depth `depth`).
    fn loop_candidates(
        &self,
        since: usize,
        until: usize,
        apart: usize,
        depth: f64,
    ) -> Vec<(usize, usize, Isometry3<f64>)> {
        let keys = self.relocaliser.keyframes();
        let frames = keys.frames();
        let Some(newest) = frames.last() else {
            return Vec::new();
        };
        let old = |f: &Keyframe| f.frame < since || f.frame + apart <= self.frames;
        let limit = frames.partition_point(|f| old(f) && f.frame <= until);
        let count = self.loops.params.candidates;
        let mut picked = keys.nearest_code(&newest.code, 0..limit, count);
        for k in loop_candidates::nearby(frames, limit, since, &self.pose, depth, count) {
            if !picked.contains(&k) {
                picked.push(k);
            }
        }
        picked
            .into_iter()
            .map(|k| (k, frames[k].frame, frames[k].pose))
            .collect()
    }

    /// Raycasts the model at the current pose for the next frame's tracking.
    fn raycast(&mut self) {
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
    }

    /// Logs the frame's report at debug level.
    fn log(&self, report: &FrameReport) {
        let times = &report.times;
        tracing::debug!(
            frame = self.frames,
            outcome = ?report.outcome,
            inliers = report.inliers,
            fraction = report.inlier_fraction,
            agreement = report.agreement,
            proximity = report.proximity,
            correlation = report.correlation,
            conditioning = report.conditioning,
            gain = report.gain,
            vignetting = report.vignetting,
            preprocess_ms = 1e3 * times.preprocess,
            track_ms = 1e3 * times.track,
            integrate_ms = 1e3 * times.integrate,
            raycast_ms = 1e3 * times.raycast,
            "rigid frame"
        );
    }
}

/// Fuses a pyramid level's depth and normals (and the colour) seen from `camera` at `pose`.
fn integrate(
    volume: &mut TsdfVolume,
    level: &crate::preprocess::Level,
    color: Option<&ColorImage>,
    (camera, pose): (&Camera, &Isometry3<f64>),
) -> Result<(), TsdfError> {
    volume
        .integrate(&level.depth, &level.normals, color, camera, pose)
        .map(|_| ())
}
