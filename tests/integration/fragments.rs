//! A new map after the track is lost for good (issue 24, point 2): a surveying camera whose
//! stream skips 48° of its round, into walls no keyframe saw, cannot be relocalised; with
//! sub-maps it starts a new map fragment within a few frames, and once the camera comes back
//! to where the run began, a loop places the fragment in the map. Until then, or if the camera
//! never comes back, the frames of the smaller fragment have no pose in the map and are said to
//! have none.

use super::sensor_frame::{sensor_frame, SensorFrame};
use dynamap::slam::eval::{ate, Alignment};
use dynamap::slam::io::trajectory::Trajectory;
use dynamap::slam::rigid::{FrameOutcome, FrameStamps, RigidSlam};
use dynamap::slam::synthetic::layouts::{self, Layout};
use dynamap::slam::synthetic::motion::{self, Motion};
use dynamap::slam::synthetic::noise::SensorNoise;
use std::collections::BTreeSet;
use std::ops::Range;
use std::sync::OnceLock;

/// Frames of the survey at 6× speed (a frame every 0.2 s, 2.4° of the round).
const STEP: usize = 6;
/// The longest run's frames.
const FRAMES: usize = 195;

/// Ground truth, and each frame as the sensor gives it (raw depth, colour).
type Survey = (Trajectory, Vec<SensorFrame>);

/// The survey's first [`FRAMES`] frames, rendered once for all the runs of this file.
fn survey() -> &'static Survey {
    static SURVEY: OnceLock<Survey> = OnceLock::new();
    SURVEY.get_or_init(|| {
        let (cam, _) = super::submaps::short_submap_run();
        let all = motion::procedural(Motion::Survey, FRAMES * STEP, 30.0);
        let scene = layouts::build(Layout::Room, 3);
        let noise = SensorNoise {
            seed: 4,
            ..SensorNoise::default()
        };
        let mut truth = Trajectory::default();
        let mut frames = Vec::new();
        for k in 0..FRAMES {
            let (stamp, pose) = (all.stamps[k * STEP], all.poses[k * STEP]);
            truth.push(stamp, pose);
            frames.push(sensor_frame(&scene, &cam, &pose, &noise, k));
        }
        (truth, frames)
    })
}

/// The run: the survey's frames before `end` but those in `dropped`, each frame's outcome,
/// the corrected trajectory of the frames in the map, and the keyframes left outside it.
/// `one_volume`: the map starts as one volume (split when the track is lost for good).
struct Run {
    outcomes: Vec<(usize, FrameOutcome)>,
    /// Each frame's report of whether its pose is in the main map's frame.
    placed: Vec<bool>,
    corrected: Trajectory,
    unplaced: BTreeSet<usize>,
    fragments: usize,
    truth: Trajectory,
}

fn run(end: usize, dropped: Range<usize>, one_volume: bool) -> Run {
    let (cam, mut params) = super::submaps::short_submap_run();
    if one_volume {
        params.submaps = None;
    }
    assert!(end <= FRAMES);
    let (all, frames) = survey();
    let mut slam = RigidSlam::new(cam, params, all.poses[0]);
    let (mut outcomes, mut tracked, mut anchors) = (Vec::new(), Trajectory::default(), Vec::new());
    let mut placed = Vec::new();
    let mut truth = Trajectory::default();
    for k in (0..end).filter(|k| !dropped.contains(k)) {
        let (stamp, pose) = (all.stamps[k], all.poses[k]);
        truth.push(stamp, pose);
        let (raw, color) = &frames[k];
        let stamps = FrameStamps {
            depth: stamp,
            color: stamp,
        };
        let report = slam.process_timed(raw, Some(color), stamps);
        if report.outcome.is_fused() {
            tracked.push(stamp, report.pose);
            anchors.push(report.anchor);
        }
        placed.push(report.placed);
        outcomes.push((k, report.outcome));
    }
    let warm = slam.finish_graph().unwrap().cloned();
    let graph = slam.keyframe_graph();
    let solved = graph.optimise(warm.as_ref()).unwrap();
    assert!(solved.converged);
    let unplaced = graph.unplaced();
    let mut corrected = Trajectory::default();
    for ((stamp, pose), anchor) in tracked.stamps.iter().zip(&tracked.poses).zip(&anchors) {
        let anchor = anchor.expect("every fused frame has a keyframe");
        if !unplaced.contains(&anchor) {
            corrected.push(*stamp, graph.corrected(&solved.poses, anchor, pose));
        }
    }
    Run {
        outcomes,
        placed,
        corrected,
        unplaced,
        fragments: graph.fragment_count(),
        truth,
    }
}

/// The new map's first frame says its pose is not in the main map (the older fragment is
/// larger then), and the last frame says its pose is.
fn assert_placed_as_reported(r: &Run) {
    let new_map = r.outcomes.iter().position(|o| o.1 == FrameOutcome::NewMap);
    let new_map = new_map.expect("a new map was started");
    assert!(
        !r.placed[new_map],
        "the new map's first frame reported placed"
    );
    assert!(
        r.placed.last() == Some(&true),
        "the last frame reported unplaced"
    );
}

/// The outcome of each of the first `n` frames after the gap.
fn after_gap(r: &Run, gap_end: usize, n: usize) -> Vec<&FrameOutcome> {
    r.outcomes
        .iter()
        .filter(|(k, _)| *k >= gap_end)
        .take(n)
        .map(|(_, o)| o)
        .collect()
}

/// 1.3 rounds; frames 40..60 (48° of the round, 4 s) are dropped in the first: the frames
/// after the gap start a new map, which the loops at the end of the round place.
fn new_map_placed(one_volume: bool) {
    let gap = 40..60;
    let r = run(195, gap.clone(), one_volume);
    let first = after_gap(&r, gap.end, 5);
    assert!(
        first.contains(&&FrameOutcome::NewMap),
        "after the gap: {first:?}"
    );
    assert_eq!(r.fragments, 2);
    assert!(r.unplaced.is_empty(), "unplaced: {:?}", r.unplaced);
    assert_placed_as_reported(&r);
    let placed = ate(&r.truth, &r.corrected, Alignment::Se3, 1e-3).unwrap();
    let fused = r.outcomes.iter().filter(|o| o.1.is_fused()).count();
    assert_eq!(r.corrected.len(), fused, "every fused frame is in the map");
    assert!(
        placed.stats.max < 0.05,
        "ATE {:.1} mm, worst frame {:.1} mm",
        1e3 * placed.stats.rmse,
        1e3 * placed.stats.max
    );
}

#[test]
fn a_gap_into_unseen_walls_starts_a_new_map_that_a_loop_places() {
    new_map_placed(false);
}

#[test]
fn one_volume_is_split_when_the_track_is_lost_for_good() {
    new_map_placed(true);
}

#[test]
fn a_new_map_that_no_loop_places_is_left_out() {
    // the same gap, but the run stops before the camera comes back
    let gap = 40..60;
    let r = run(110, gap.clone(), false);
    assert!(after_gap(&r, gap.end, 5).contains(&&FrameOutcome::NewMap));
    assert_eq!(r.fragments, 2);
    // the fragment before the gap is the smaller one: its keyframes (named by the count of
    // frames processed, from 1) are outside the map, and the map's frames all lie after it
    assert!(!r.unplaced.is_empty());
    assert_placed_as_reported(&r);
    assert!(
        r.unplaced.iter().all(|&id| id <= gap.start),
        "unplaced: {:?}",
        r.unplaced
    );
    let placed = ate(&r.truth, &r.corrected, Alignment::Se3, 1e-3).unwrap();
    assert!(r.corrected.stamps[0] >= r.truth.stamps[gap.start]);
    assert!(placed.stats.max < 0.05, "worst {:.3} m", placed.stats.max);
}
