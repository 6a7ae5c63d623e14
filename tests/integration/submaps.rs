//! Loop closure with sub-maps (issue 24, points 3 and 4): a camera surveying the room's walls
//! comes back to where it started; tracked against the newest sub-map only, its odometry drifts,
//! the older sub-maps give dense loops, and the frames carried with their keyframes to the
//! graph's solution lie nearer the ground truth than the frames as tracked.

use super::sensor_frame::{sensor_frame, SensorFrame};
use dynamap::residuals::pose_graph::Measurement;
use dynamap::slam::camera::Camera;
use dynamap::slam::eval::{ate, Alignment};
use dynamap::slam::io::trajectory::Trajectory;
use dynamap::slam::mesh::Mesh;
use dynamap::slam::rigid::loops::{KeyframeGraph, LoopCandidate};
use dynamap::slam::rigid::submaps::SubmapParams;
use dynamap::slam::rigid::{RelocaliseParams, RigidSlam, SlamParams};
use dynamap::slam::synthetic::layouts::{self, Layout};
use dynamap::slam::synthetic::motion::{self, Motion};
use dynamap::slam::synthetic::noise::SensorNoise;
use dynamap::slam::synthetic::scene::Scene;
use dynamap::slam::synthetic::surface_error::{surface_error, SurfaceError};
use nalgebra::{Isometry3, Matrix6};
use std::sync::OnceLock;

/// Every `step`-th pose of `frames` survey frames.
fn survey(frames: usize, step: usize) -> Trajectory {
    let all = motion::procedural(Motion::Survey, frames * step, 30.0);
    let mut t = Trajectory::default();
    for k in (0..all.len()).step_by(step) {
        t.push(all.stamps[k], all.poses[k]);
    }
    t
}

/// What a run gives: the trajectories as tracked and as corrected, each loop as (its error
/// against the ground truth's relative pose in metres, its DCS weight), and the map's mesh
/// measured against the scene as fused and with its sub-maps moved by the graph's solution.
struct Run {
    tracked: Trajectory,
    corrected: Trajectory,
    loops: Vec<(f64, f64)>,
    mesh_tracked: SurfaceError,
    mesh_corrected: SurfaceError,
    /// Odometry edges, and those whose information carries the tracking's spread (not the drift
    /// model's diagonal alone).
    odometry: (usize, usize),
    /// The loops in the graph, as found.
    found: Vec<LoopCandidate>,
}

/// How the run hands frames to the pipeline: as soon as the last one is done, or waiting after
/// each for the loop searches under way ([`RigidSlam::finish_graph`]), as if each search ran
/// on the tracking thread.
#[derive(Clone, Copy, PartialEq)]
enum Pace {
    Free,
    WaitForLoops,
}

/// (odometry edges, those whose information is not diagonal) of a keyframe graph.
fn odometry_spread(graph: &KeyframeGraph) -> (usize, usize) {
    let loops: Vec<(usize, usize)> = graph.loops().iter().map(|l| (l.from, l.to)).collect();
    let odometry = graph
        .graph()
        .edges
        .iter()
        .filter(|e| !loops.contains(&(e.from, e.to)));
    let mut counts = (0, 0);
    for e in odometry {
        let Measurement::Se3 { information, .. } = &e.measurement else {
            panic!("a keyframe graph holds SE(3) edges only")
        };
        counts.0 += 1;
        let diagonal = Matrix6::from_diagonal(&information.diagonal());
        counts.1 += usize::from(*information != diagonal);
    }
    counts
}

/// Vertices are measured within 5 cm of the scene along their normals, and lie off it beyond
/// 1 cm (about three times the sensor's depth noise at the room's 1–2 m).
const REACH: f64 = 0.05;
const TOLERANCE: f64 = 0.01;

/// The camera and settings of the short sub-map runs (also `fragments`'): 320×240, sub-maps of
/// 60 frames, loops at least 100 frames apart.
pub(crate) fn short_submap_run() -> (Camera, SlamParams) {
    let cam = Camera::new(262.5, 262.5, 159.5, 119.5, 320, 240);
    let mut params = SlamParams {
        submaps: Some(SubmapParams {
            frames: 60,
            overlap: 10,
        }),
        ..SlamParams::default()
    };
    let r: &mut RelocaliseParams = &mut params.relocalise;
    r.loops.min_frames_apart = 100;
    r.keyframes.recent_frames = 100;
    (cam, params)
}

/// A survey in a layout: its ground truth, its scene and each frame as the sensor gives it (raw
/// depth, colour).
struct Survey {
    gt: Trajectory,
    scene: Scene,
    frames: Vec<SensorFrame>,
}

/// `gt` rendered in `layout` (seed 3) by the short runs' camera with sensor noise of seed 9.
fn render(layout: Layout, gt: Trajectory) -> Survey {
    let (cam, _) = short_submap_run();
    let scene = layouts::build(layout, 3);
    let noise = SensorNoise {
        seed: 9,
        ..SensorNoise::default()
    };
    let frames = (gt.poses.iter().enumerate())
        .map(|(k, pose)| sensor_frame(&scene, &cam, pose, &noise, k))
        .collect();
    Survey { gt, scene, frames }
}

/// 1.4 rounds of the room survey at 6× speed (the camera is back where it began after 150
/// frames), rendered once for the tests that run it.
fn room_survey() -> &'static Survey {
    static SURVEY: OnceLock<Survey> = OnceLock::new();
    SURVEY.get_or_init(|| render(Layout::Room, survey(210, 6)))
}

/// The room survey's run with the loop searches off the tracking thread, shared by the tests
/// that read it.
fn room_run() -> &'static Run {
    static RUN: OnceLock<Run> = OnceLock::new();
    RUN.get_or_init(|| run(room_survey(), Pace::Free))
}

/// Runs the pipeline with sub-maps along `survey`.
fn run(survey: &Survey, pace: Pace) -> Run {
    let (cam, params) = short_submap_run();
    let (gt, scene) = (&survey.gt, &survey.scene);
    let mut slam = RigidSlam::new(cam, params, gt.poses[0]);
    let (mut tracked, mut anchors) = (Trajectory::default(), Vec::new());
    for (k, (stamp, (raw, color))) in gt.stamps.iter().zip(&survey.frames).enumerate() {
        let report = slam.process(raw, Some(color));
        assert!(
            report.failure().is_none(),
            "frame {k}: {:?}",
            report.outcome
        );
        tracked.push(*stamp, report.pose);
        anchors.push(report.anchor);
        if pace == Pace::WaitForLoops {
            slam.finish_graph().unwrap();
        }
    }
    let warm = slam.finish_graph().unwrap().cloned();
    let graph = slam.keyframe_graph();
    let solved = graph.optimise(warm.as_ref()).unwrap();
    assert!(solved.converged);
    let mut corrected = tracked.clone();
    for (pose, anchor) in corrected.poses.iter_mut().zip(&anchors) {
        *pose = graph.corrected(&solved.poses, anchor.unwrap(), pose);
    }
    let loops = graph
        .loops()
        .iter()
        .zip(&solved.loop_weights)
        .map(|(l, w)| {
            // keyframes are named by the count of frames processed, from 1
            let truth = gt.poses[l.from - 1].inverse() * gt.poses[l.to - 1];
            let error = (truth.inverse() * l.relative).translation.vector.norm();
            (error, w.2)
        })
        .collect();
    // the pipeline started at the ground truth's first pose: its world is the scene's frame
    let prepared = scene.prepare();
    let measure =
        |mesh: Mesh| surface_error(&mesh, &prepared, &Isometry3::identity(), REACH, TOLERANCE);
    Run {
        tracked,
        corrected,
        loops,
        mesh_tracked: measure(slam.map_mesh(None)),
        mesh_corrected: measure(slam.map_mesh(Some(&solved.poses))),
        odometry: odometry_spread(graph),
        found: graph.loops().to_vec(),
    }
}

#[test]
fn a_short_looping_survey_closes_its_loop_and_lowers_the_trajectory_error() {
    let (gt, r) = (&room_survey().gt, room_run());
    let error = |t: &Trajectory| ate(gt, t, Alignment::Se3, 1e-3).unwrap().stats.rmse;
    let (before, after) = (error(&r.tracked), error(&r.corrected));
    let kept = r.loops.iter().filter(|l| l.1 > 0.5).count();
    assert!(
        r.loops.len() >= 2 && kept >= 1,
        "loops (error m, weight): {:?}",
        r.loops
    );
    assert!(
        after < 0.8 * before,
        "ATE {:.1} mm corrected against {:.1} mm tracked",
        1e3 * after,
        1e3 * before
    );
    // every loop that reaches the graph measures where its keyframes truly are: within two of
    // its deviations (1.5 cm at the room's 1.5 m), not short of the place as a track can stop
    // along a motion the view barely fixes (NOTES 116)
    assert!(
        r.loops.iter().all(|l| l.0 < 0.03),
        "loops (error m, weight): {:?}",
        r.loops
    );
    // every odometry edge carries the tracking's spread (NOTES 80)
    let (edges, spread) = r.odometry;
    assert!(
        edges >= 2 && spread == edges,
        "{spread} of {edges} odometry edges"
    );
    let (m0, m1) = (&r.mesh_tracked, &r.mesh_corrected);
    eprintln!("mesh against the scene, as fused: {m0:?}\nwith the sub-maps moved: {m1:?}");
    // one wall where the camera came back, not two: a copy a few millimetres off is mostly
    // within the tolerance, so the share off the surface must fall by half at least (at the
    // time of writing 3.9 % as fused, 0.7 % moved)
    assert!(
        m1.off_fraction() < 0.5 * m0.off_fraction(),
        "vertices off the surface: {:.2} % with the sub-maps moved, {:.2} % as fused",
        100.0 * m1.off_fraction(),
        100.0 * m0.off_fraction()
    );
}

#[test]
fn identical_places_half_a_round_apart_do_not_bend_the_trajectory() {
    // in the twin room the place half a round away looks the same as this one: loops to it are
    // false, and they must be rejected or switched off
    let twins = render(Layout::Twins, survey(300, 6));
    let r = run(&twins, Pace::Free);
    let error = |t: &Trajectory| ate(&twins.gt, t, Alignment::Se3, 1e-3).unwrap().stats.rmse;
    let (before, after) = (error(&r.tracked), error(&r.corrected));
    let report = format!(
        "ATE {:.1} mm corrected against {:.1} mm tracked; loops (error m, weight): {:?}",
        1e3 * after,
        1e3 * before,
        r.loops
    );
    eprintln!("{report}");
    // the look-alike must not crowd out the true place when the camera comes back to it: a
    // loop that agrees with the track is preferred (NOTES 89). Here a true place always fits
    // when the twin does, so no false loop is even added (before NOTES 89 three were, each
    // 1.6-2 m off, and DCS switched them off), and the true ones lower the error
    let false_added = r.loops.iter().filter(|l| l.0 > 0.1).count();
    let true_kept = r.loops.iter().filter(|l| l.0 < 0.05 && l.1 > 0.5).count();
    assert!(
        false_added == 0 && true_kept >= 1 && after < 0.8 * before,
        "{report}"
    );
}

#[test]
fn the_loop_search_off_the_tracking_thread_finds_what_a_waited_for_search_finds() {
    // the search reads only what its keyframe captured, so however far tracking runs ahead of
    // it, the same loops reach the graph in the same order, and tracking is not disturbed
    let free = room_run();
    let waited = run(room_survey(), Pace::WaitForLoops);
    assert!(free.found.len() >= 2, "{} loops", free.found.len());
    assert_eq!(free.found, waited.found);
    assert_eq!(free.tracked.poses, waited.tracked.poses);
}
