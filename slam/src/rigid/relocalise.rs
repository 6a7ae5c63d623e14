//! Finding a lost track again, in two rounds:
//! - local: start poses around the last good pose (shifted along each world axis, turned about
//!   the camera's x and y) and the motion that sparse features matched against the last fused
//!   frame give (FAST/BRIEF on an image pyramid, and RANSAC: [`crate::features`]), and after a
//!   break in the stream the last pose carried on at the camera's velocity for the time the
//!   break took ([`RelocaliseParams::coast`]), are each tracked on the coarsest level against
//!   the model raycast at the last pose; the best is refined on all levels;
//! - global (after a gap the camera may be anywhere it has been): the keyframes of the map
//!   fragments joined to the current one ([`super::loops`]) whose fern codes are nearest the
//!   frame's ([`super::keyframes`]) are matched by features, a rigid motion fitted by RANSAC on
//!   the 3-D matches gives a pose (the keyframe's own pose where the features give none), and
//!   the model raycast at that pose verifies it by dense tracking.
//!
//! Both rounds run, and of the poses that pass the one nearest the last pose wins (by the view's
//! shift: the translation over the scene's depth plus the turn): places that look alike fit
//! alike, and only the motion since the last pose tells them apart (NOTES 91). A pose is kept
//! only when it passes the tracker's tests and, away from the last pose, a stricter inlier
//! fraction ([`RelocaliseParams::min_inlier_fraction`]); after a break in the stream also floors
//! on its fit to the model ([`RelocaliseParams::min_fit_ratio`] × the recent frames' fit for the
//! local round, × the keyframe's own agreement for the global one, or the recent frames' floor
//! for a keyframe that started a map and was tracked against nothing). The fit's third number, the
//! correlation of the live texture with the model's, has the recent frames' floor in both rounds:
//! it is what sees a pose slid along a wall, where every pixel still lands on the right plane
//! (NOTES 90). The blind starts (shifts and turns) are tried only where something can tell their
//! results apart: a geometry that fixes every motion, or a correlation floor of at least 0.5 (the
//! recent frames' texture matched the model well). Neither round may take the camera further
//! than it can have gone since the last pose (NOTES 92): in a room with two identical halves, a
//! 3-s gap was relocalised to the other half, 142° round, where the camera turns at most 20°/s.

use super::health::Fit;
use super::keyframes::{Candidate, Keyframe, KeyframeParams, Keyframes};
use super::loops::{LoopParams, Reach};
use super::tracker::{mean_depth, ModelPyramid, TrackOutcome, Tracker, TrackerParams};
use crate::camera::Camera;
use crate::features::{detect, fit_keypoints, FeatureFrame, FeatureParams, Keypoints};
use crate::image::{ColorImage, DepthImage};
use crate::preprocess::Level;
use crate::tsdf::{RaycastMaps, TsdfVolume};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// How a lost track is found again.
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
    /// Sparse features matched against the last fused frame give one more start pose; the
    /// keyframes' and the loops' features are these too (default: six pyramid levels of scale
    /// 1.25, from the full image to a third of it, so that a place seen from up to about three
    /// times nearer or further matches, as after a gap on a walk; NOTES 125).
    pub features: FeatureParams,
    /// After a break in the stream, one more start: the last pose carried on at the velocity
    /// the camera had before the break for the time the break took (default true). A camera
    /// walked along a corridor whose plain walls give the features nothing to match is about
    /// there, further than the blind starts reach.
    pub coast: bool,
    /// Keyframes for the global round.
    pub keyframes: KeyframeParams,
    /// Loops between keyframes ([`super::loops`]).
    pub loops: LoopParams,
    /// Keyframes whose fern codes are nearest the frame's that the global round tries
    /// (default 5).
    pub candidates: usize,
    /// After a break in the stream, and for a track to be kept without facing the
    /// relocaliser, the agreement with the model and the inlier fraction must be at least this
    /// share of the recent frames' medians (default 0.85).
    pub min_fit_ratio: f64,
    /// A track whose texture correlates with the model below this share of the recent frames'
    /// median correlation (where that median can tell poses apart) faces the relocaliser's
    /// starts too, and a start that correlates better replaces it (default 0.9). On a wall
    /// held along itself by a repeating texture alone, a track that slid to the neighbouring
    /// period keeps the geometry's fraction and agreement, and its correlation falls only to
    /// 0.6–0.8 against the recent 0.96: above the half that refuses it outright, then fused,
    /// and the next frames slid further (NOTES 153, 154).
    pub min_correlation_ratio: f64,
    /// Stamps further apart than this many typical frame intervals since the last fused frame
    /// are a break in the stream (default 3).
    pub gap_intervals: f64,
    /// When this many frames in a row were not relocalised, the last of them starts a new map
    /// fragment ([`super::loops`]; default 3, 0 never), as the camera has gone where no
    /// keyframe saw; one volume is then split into sub-maps ([`super::submaps`]), the map so
    /// far being the first. The fragment's frames are placed in the map when a loop joins the
    /// fragment to it, and left out of the trajectory otherwise.
    pub new_map_after: usize,
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
                levels: 6,
                ..FeatureParams::default()
            },
            coast: true,
            keyframes: KeyframeParams::default(),
            loops: LoopParams::default(),
            candidates: 5,
            min_fit_ratio: 0.85,
            min_correlation_ratio: 0.9,
            gap_intervals: 3.0,
            new_map_after: 3,
        }
    }
}

/// The live frame as the relocaliser sees it.
pub(crate) struct LiveFrame<'a> {
    /// The live pyramid.
    pub levels: &'a [Level],
    /// Its colour, if any.
    pub color: Option<&'a ColorImage>,
    /// The sensor.
    pub camera: &'a Camera,
    /// A model pyramid of the pipeline's shape, copied once for raycasts at candidate poses.
    pub model_template: &'a ModelPyramid,
}

/// What a relocalised pose must reach, beyond the tracker's tests.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Floors {
    /// For a pose near the last one (the local round): its proximity to the model (the
    /// agreement without the normal test, which a far surface's depth steps fail at the right
    /// pose too: NOTES 158) and its correlation, and also its inlier fraction unless the sparse
    /// features' motion led to it or the correlation is telling ([`Fit::telling`]). The
    /// correlation's floor holds for a pose found from a keyframe too.
    pub local: Fit,
    /// For a pose found from a keyframe: this share of the agreement the keyframe was tracked
    /// with (the same view should match about as well as it did then); a keyframe that started
    /// a map has none, and `local`'s agreement stands in.
    pub keyframe_ratio: f64,
}

/// Buffers for tracking the live frame against a map raycast at a candidate pose: the
/// raycast and a model pyramid of the pipeline's shape (copied from the first live frame's
/// template).
#[derive(Debug, Default)]
pub(crate) struct Verifier {
    maps: RaycastMaps,
    model: Option<ModelPyramid>,
}

impl Verifier {
    /// Tracks the live frame from `start` against `volume` raycast at `start`.
    pub fn verify(
        &mut self,
        tracker: &mut Tracker,
        volume: &TsdfVolume,
        live: &LiveFrame<'_>,
        start: &Isometry3<f64>,
    ) -> TrackOutcome {
        let model = self
            .model
            .get_or_insert_with(|| live.model_template.clone());
        let r = model.offset;
        volume.raycast_with_hint(
            &live.camera.level(r),
            start,
            Some(&live.levels[r].depth),
            &mut self.maps,
        );
        model.update(&self.maps, start);
        tracker.probe(live.levels, model, start)
    }
}

/// The relocaliser's memory: the last fused frame, the keyframes, and buffers for raycasting
/// the model at a candidate pose.
#[derive(Debug)]
pub(crate) struct Relocaliser {
    key_depth: DepthImage,
    key_color: ColorImage,
    /// The last fused frame's keypoints, detected at the first relocalisation that needs them
    /// and kept while that frame stays the last (frames lost in a row match against it).
    key_keypoints: Option<Keypoints>,
    keyframes: Keyframes,
    verifier: Verifier,
    /// The first frame of the current map fragment.
    since: usize,
}

impl Relocaliser {
    /// A relocaliser that has seen no frame yet.
    pub fn new(params: &RelocaliseParams) -> Self {
        Self {
            key_depth: DepthImage::new(0, 0),
            key_color: ColorImage::new(0, 0),
            key_keypoints: None,
            keyframes: Keyframes::new(params.keyframes.clone()),
            verifier: Verifier::default(),
            since: 0,
        }
    }

    /// The keyframes kept so far.
    pub fn keyframes(&self) -> &Keyframes {
        &self.keyframes
    }

    /// The first frame of the current map fragment.
    pub fn fragment_start(&self) -> usize {
        self.since
    }

    /// Keyframes are kept away from those of the last `frames` frames only (sub-maps'
    /// setting: an older place seen again gets keyframes of its own, for loops).
    pub fn keep_away_from_recent(&mut self, frames: usize) {
        self.keyframes.params.recent_frames = frames;
    }

    /// Keeps a fused frame (filtered depth, colour) as the one the features match against (none
    /// when it has no colour), and offers it as a keyframe; whether it became one. The first
    /// frame of a new map fragment (`new_map`) is kept as a keyframe wherever it lies.
    pub(crate) fn remember(
        &mut self,
        frame: &Candidate<'_>,
        params: &RelocaliseParams,
        max_depth: f32,
        new_map: bool,
    ) -> bool {
        self.key_depth.clone_from(frame.depth);
        self.key_keypoints = None;
        match frame.color {
            Some(c) => self.key_color.clone_from(c),
            // no colour to match against: an older frame's would pair with this depth
            None => self.key_color.reset(0, 0, [0; 3]),
        }
        if !new_map {
            return self.keyframes.offer(frame, &params.features, max_depth);
        }
        self.since = frame.frame;
        self.keyframes.insert(frame, &params.features, max_depth)
    }

    /// The live frame's pose: the better of the local and the global rounds' results that pass
    /// the tests (see the module's documentation) and reach the `floors`; `frame` only labels
    /// the log. `place` takes a keyframe's frame index to the motion from its map fragment's
    /// frame into the current one's, `None` for fragments not joined to it. A pose further from
    /// the last one than `reach` (how far the camera can have gone since, never less than the
    /// local round's own reach: [`local_extent`]) is refused, whatever its fit: where two places
    /// look alike, the one the camera could not have reached is the wrong one (NOTES 92).
    /// `conditioning` is the live frame's ([`super::tracker::FrameConstraint`], measured once by
    /// the pipeline); `coast`, if given, is one more start for the local round (where the
    /// camera's velocity carried the last pose: [`RelocaliseParams::coast`]).
    #[allow(clippy::too_many_arguments)]
    pub fn relocalise(
        &mut self,
        params: &RelocaliseParams,
        tracker: &mut Tracker,
        map: (&TsdfVolume, &ModelPyramid),
        live: &LiveFrame<'_>,
        (last, coast, reach, conditioning): (Isometry3<f64>, Option<Isometry3<f64>>, Reach, f64),
        floors: Floors,
        (frame, place): (usize, &dyn Fn(usize) -> Option<Isometry3<f64>>),
    ) -> Option<TrackOutcome> {
        let reach = reach.at_least(local_extent(params, &tracker.params));
        // the live frame's keypoints, detected once for both rounds
        let keypoints = live.color.map(|color| {
            let now = FeatureFrame {
                color,
                depth: &live.levels[0].depth,
                camera: live.camera,
                mask: None,
            };
            detect(&now, &params.features)
        });
        let keypoints = keypoints.as_ref();
        let local = self.local(
            params,
            tracker,
            map,
            (live, keypoints),
            (last, coast, reach, conditioning),
            floors.local,
            frame,
        );
        // the scene's depth, against which a translation is weighed
        let scale = mean_depth(&live.levels[live.levels.len() - 1]);
        let global = self.global(
            params,
            tracker,
            map.0,
            (live, keypoints),
            (&last, scale, reach),
            floors,
            (frame, place),
        );
        // as between keyframes: of two poses that pass, the nearer the last one
        match (local, global) {
            (Some(a), Some(b)) => {
                let nearer = view_shift(&last, &b.pose, scale) < view_shift(&last, &a.pose, scale);
                Some(if nearer { b } else { a })
            }
            (a, b) => a.or(b),
        }
    }

    /// The local round (see the module's documentation): the best start, screened against the
    /// model at the last pose, is tracked against the model raycast at its screened pose.
    #[allow(clippy::too_many_arguments)]
    fn local(
        &mut self,
        params: &RelocaliseParams,
        tracker: &mut Tracker,
        (volume, model): (&TsdfVolume, &ModelPyramid),
        (live, keypoints): (&LiveFrame<'_>, Option<&Keypoints>),
        (last, coast, reach, conditioning): (Isometry3<f64>, Option<Isometry3<f64>>, Reach, f64),
        floor: Fit,
        frame: usize,
    ) -> Option<TrackOutcome> {
        // a blind search is only as good as the power to tell its results apart: where the
        // geometry leaves a motion free, the fraction and the agreement cannot see a slide along
        // it, and only a texture the recent frames matched well can
        let telling = floor.telling();
        let blind = telling || conditioning >= tracker.params.min_conditioning;
        let (mut starts, from_features) = self.starts(params, live.camera, keypoints, last, blind);
        starts.extend(coast);
        let (screened, k, pose) = screen(tracker, model, live.levels, &starts, floor.correlation)?;
        let o = self.verifier.verify(tracker, volume, live, &pose);
        let fraction = o.inlier_fraction();
        let reachable = reach.admits(&last, &o.pose);
        tracing::debug!(
            frame,
            candidates = starts.len(),
            best = k,
            screened,
            fraction,
            agreement = o.agreement,
            proximity = o.proximity,
            correlation = o.correlation,
            reachable,
            floor = ?floor,
            failure = o.failure.as_ref().map(ToString::to_string),
            "local relocalisation"
        );
        // the last pose winning is ordinary tracking, held to its tests; a jump elsewhere must
        // also have the stricter inlier fraction
        let strict = if k == 0 {
            0.0
        } else {
            params.min_inlier_fraction
        };
        // a dense pose the sparse features led to, or whose texture matches the model as the
        // recent frames' did, has a second kind of support; any other must also see as much of
        // the model as the recent frames did (where the camera moved on to what the model has
        // not seen, the fraction falls at the right pose too)
        let supported = from_features == Some(k) || telling;
        let fits = o.proximity >= floor.proximity
            && o.correlation >= floor.correlation
            && (supported || fraction >= floor.fraction);
        (o.failure.is_none() && fraction >= strict && fits && reachable).then_some(o)
    }

    /// The global round (see the module's documentation): of the keyframe poses that verify, the
    /// one nearest the last pose ([`view_shift`] with the scene's depth `scale`). Each keyframe's
    /// start is the features' motion from it or, when they give none, its own pose (the frame
    /// looks like the keyframe, so the camera is near where it was: ElasticFusion's fern
    /// relocalisation, Whelan et al. 2016). Nearest, not best fitting: two places that look alike
    /// fit alike (a twin room), and only the motion since the last pose tells them apart.
    #[allow(clippy::too_many_arguments)]
    fn global(
        &mut self,
        params: &RelocaliseParams,
        tracker: &mut Tracker,
        volume: &TsdfVolume,
        (live, keypoints): (&LiveFrame<'_>, Option<&Keypoints>),
        (last, scale, reach): (&Isometry3<f64>, f64, Reach),
        floors: Floors,
        (frame, place): (usize, &dyn Fn(usize) -> Option<Isometry3<f64>>),
    ) -> Option<TrackOutcome> {
        let (color, keypoints) = live.color.zip(keypoints)?;
        let depth = &live.levels[0].depth;
        let joined = |k: &Keyframe| place(k.frame).is_some();
        let nearest = self
            .keyframes
            .nearest_where(Some(color), depth, params.candidates, joined);
        let mut best: Option<(f64, TrackOutcome)> = None;
        for k in nearest {
            let key = &self.keyframes.frames()[k];
            // live points map into the keyframe: T_live = T_key · M, in the current fragment's
            // frame
            let Some(into) = place(key.frame) else {
                continue;
            };
            let m = fit_keypoints(keypoints, &key.keypoints, &params.features);
            let motion = m.as_ref().map_or(Isometry3::identity(), |m| m.fit.motion);
            let start = into * key.pose * motion;
            // a track moves at most one track's motion from its start, so a start further than
            // that beyond the reach cannot end within it: not worth a raycast and a track
            if !reach.plus(one_track(&tracker.params)).admits(last, &start) {
                tracing::debug!(frame, keyframe = key.frame, "keyframe start out of reach");
                continue;
            }
            // a keyframe that started a map was tracked against nothing: the recent frames'
            // floor stands in for its own
            let floor = key
                .agreement
                .map_or(floors.local.agreement, |a| floors.keyframe_ratio * a);
            let keyframe = key.frame;
            let o = self.verifier.verify(tracker, volume, live, &start);
            let (fraction, shift) = (o.inlier_fraction(), view_shift(last, &o.pose, scale));
            let reachable = reach.admits(last, &o.pose);
            tracing::debug!(
                frame,
                keyframe,
                inliers = m.as_ref().map(|m| m.fit.inlier_count()),
                fraction,
                agreement = o.agreement,
                correlation = o.correlation,
                shift,
                reachable,
                floor,
                failure = o.failure.as_ref().map(ToString::to_string),
                "global relocalisation candidate"
            );
            let passes = o.failure.is_none()
                && fraction >= params.min_inlier_fraction
                && o.agreement >= floor
                && o.correlation >= floors.local.correlation
                && reachable;
            if passes && best.as_ref().is_none_or(|b| shift < b.0) {
                best = Some((shift, o));
            }
        }
        best.map(|b| b.1)
    }

    /// The start poses: the last pose first, the features' motion, then (if `blind`) the shifts
    /// and turns; and the index of the features' start, if they gave one.
    fn starts(
        &mut self,
        p: &RelocaliseParams,
        camera: &Camera,
        keypoints: Option<&Keypoints>,
        last: Isometry3<f64>,
        blind: bool,
    ) -> (Vec<Isometry3<f64>>, Option<usize>) {
        let mut starts = vec![last];
        let mut from_features = None;
        if let Some(now) = keypoints.filter(|_| !self.key_color.data.is_empty()) {
            let (color, depth) = (&self.key_color, &self.key_depth);
            let key = self.key_keypoints.get_or_insert_with(|| {
                let key = FeatureFrame {
                    color,
                    depth,
                    camera,
                    mask: None,
                };
                detect(&key, &p.features)
            });
            if let Some(m) = fit_keypoints(now, key, &p.features) {
                // live points map into the key frame: T_live = T_key · M
                from_features = Some(starts.len());
                starts.push(last * m.fit.motion);
            }
        }
        if blind {
            push_blind_starts(p, last, &mut starts);
        }
        (starts, from_features)
    }
}

/// Appends the blind search's starts around `last` to `starts`: shifts along each world axis,
/// then turns about the camera's x and y axes.
fn push_blind_starts(p: &RelocaliseParams, last: Isometry3<f64>, starts: &mut Vec<Isometry3<f64>>) {
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
}

/// The most one track may move a pose from its start ([`super::TrackerParams::max_translation`]
/// and [`super::TrackerParams::max_rotation_deg`]; beyond, it fails as an implausible motion).
fn one_track(tracker: &TrackerParams) -> Reach {
    Reach {
        translation: tracker.max_translation,
        rotation: tracker.max_rotation_deg.to_radians(),
    }
}

/// How far the local round can carry a pose from the last one: its longest shift or its turn,
/// and beyond that [`one_track`].
fn local_extent(p: &RelocaliseParams, tracker: &TrackerParams) -> Reach {
    let longest = p.shifts.iter().copied().fold(0.0, f64::max);
    let starts = Reach {
        translation: longest,
        rotation: p.turn_deg.to_radians(),
    };
    starts.plus(one_track(tracker))
}

/// How far `pose` lies from `last` as the view sees it: the translation over the scene's depth
/// `depth` plus the turn in radians (each about the share of the view that moves).
fn view_shift(last: &Isometry3<f64>, pose: &Isometry3<f64>, depth: f64) -> f64 {
    let d = last.inverse() * pose;
    d.translation.vector.norm() / depth.max(0.1) + d.rotation.angle()
}

/// Tracks every start on the coarsest level only; the best inlier fraction among the tracks that
/// pass and correlate with the model's texture at least `min_correlation`, its start's index and
/// the pose it reached.
fn screen(
    tracker: &mut Tracker,
    model: &ModelPyramid,
    levels: &[Level],
    starts: &[Isometry3<f64>],
    min_correlation: f64,
) -> Option<(f64, usize, Isometry3<f64>)> {
    let full = std::mem::take(&mut tracker.params.iterations);
    let coarse = full.len().saturating_sub(1);
    tracker.params.iterations = (0..full.len())
        .map(|l| if l == coarse { full[l].max(4) } else { 0 })
        .collect();
    let mut best: Option<(f64, usize, Isometry3<f64>)> = None;
    for (k, start) in starts.iter().enumerate() {
        let o = tracker.probe(levels, model, start);
        let fraction = o.inlier_fraction();
        tracing::trace!(
            start = k,
            fraction,
            agreement = o.agreement,
            correlation = o.correlation,
            moved = (o.pose.translation.vector - starts[0].translation.vector).norm(),
            failure = o.failure.as_ref().map(ToString::to_string),
            "relocalisation start screened"
        );
        let passes = o.failure.is_none() && o.correlation >= min_correlation;
        if passes && best.is_none_or(|b| fraction > b.0) {
            best = Some((fraction, k, o.pose));
        }
    }
    tracker.params.iterations = full;
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The local round's own reach is its longest shift or its turn plus what one track
    /// accepts: 0.3 + 0.3 m and 10 + 30° by default.
    #[test]
    fn the_local_round_reaches_its_longest_start_plus_one_track() {
        let e = local_extent(&RelocaliseParams::default(), &TrackerParams::default());
        assert!((e.translation - 0.6).abs() < 1e-12, "{e:?}");
        assert!((e.rotation - 40f64.to_radians()).abs() < 1e-12, "{e:?}");
    }

    /// The view's shift weighs a translation by the scene's depth and adds the turn: a twin
    /// place half a turn away is far however near its position, and the same step counts less
    /// before a far scene.
    #[test]
    fn the_view_shift_is_the_translation_over_the_depth_plus_the_turn() {
        let last = Isometry3::from_parts(
            Translation3::new(0.4, -0.2, 1.3),
            UnitQuaternion::from_euler_angles(0.1, 0.3, -0.2),
        );
        let step = last * Translation3::new(0.3, 0.0, 0.4);
        assert!((view_shift(&last, &step, 2.0) - 0.25).abs() < 1e-12);
        assert!((view_shift(&last, &step, 1.0) - 0.5).abs() < 1e-12);
        let about = UnitQuaternion::from_scaled_axis(Vector3::y() * std::f64::consts::PI);
        let twin = last * Translation3::new(0.1, 0.0, 0.0) * about;
        let shift = view_shift(&last, &twin, 2.0);
        assert!(
            (shift - (0.05 + std::f64::consts::PI)).abs() < 1e-9,
            "{shift}"
        );
        assert!(shift > view_shift(&last, &step, 1.0));
        // a too small depth is taken as 0.1 m
        assert!((view_shift(&last, &step, 0.0) - 5.0).abs() < 1e-12);
    }

    /// After a fused frame without colour, the local round has no features to match: before,
    /// it matched the older frame's colour, paired with the newer frame's depth.
    #[test]
    fn a_frame_without_colour_leaves_the_local_round_no_features() {
        let cam = Camera::new(262.5, 262.5, 159.5, 119.5, 320, 240);
        let mut color = ColorImage::new(320, 240);
        for (i, c) in color.data.iter_mut().enumerate() {
            let (u, v) = (i % 320, i / 320);
            let on = ((u / 7) ^ (v / 5) ^ (u * v / 97)) & 1 == 1;
            *c = if on { [230, 200, 40] } else { [20, 30, 90] };
        }
        let depth = DepthImage::filled(320, 240, 1.5);
        let p = RelocaliseParams::default();
        let mut r = Relocaliser::new(&p);
        let fused = |frame, color| Candidate {
            frame,
            pose: Isometry3::identity(),
            agreement: None,
            color,
            depth: &depth,
            camera: &cam,
        };
        let live = FeatureFrame {
            color: &color,
            depth: &depth,
            camera: &cam,
            mask: None,
        };
        let now = detect(&live, &p.features);
        let last = Isometry3::identity();
        r.remember(&fused(1, Some(&color)), &p, 5.0, false);
        let (_, from_features) = r.starts(&p, &cam, Some(&now), last, false);
        assert_eq!(from_features, Some(1), "the same view matches itself");
        r.remember(&fused(2, None), &p, 5.0, false);
        let (starts, from_features) = r.starts(&p, &cam, Some(&now), last, false);
        assert_eq!((starts.len(), from_features), (1, None));
    }
}
