//! Relocalisation from keyframes (issue 24): a camera that returns to a place it has seen, with
//! a gap in the stream on the way back, is found again from the keyframes and reported as
//! relocalised; without the keyframe round it is reported as not tracked, never as tracked
//! somewhere wrong.

use dynamap::slam::camera::Camera;
use dynamap::slam::image::{ColorImage, Image};
use dynamap::slam::io::trajectory::Trajectory;
use dynamap::slam::io::tum::TumSequence;
use dynamap::slam::rigid::{FrameOutcome, FrameStamps, RelocaliseParams, RigidSlam, SlamParams};
use dynamap::slam::synthetic::kinect::KinectModel;
use dynamap::slam::synthetic::layouts::{self, Layout};
use dynamap::slam::synthetic::motion::{self, Motion};
use dynamap::slam::synthetic::noise::SensorNoise;
use dynamap::slam::synthetic::scene::Scene;
use dynamap::slam::synthetic::sequence::{self, Sensor};
use nalgebra::Isometry3;

use super::sensor_frame::sensor_frame;

/// Orbit frames 0..100 and back to 0, with the frames between `gap.0` and `gap.1` (going back)
/// dropped: the stream jumps from frame `gap.0` to frame `gap.1`.
fn there_and_back(gap: (usize, usize)) -> Vec<usize> {
    let out: Vec<usize> = (0..100).collect();
    let back = (0..100).rev().filter(|&k| k >= gap.0 || k <= gap.1);
    out.into_iter().chain(back).collect()
}

/// The sensor's frames (raw depth, colour) along `frames` of the orbit in the room, rendered
/// once for every run.
fn captures(cam: &Camera, gt: &Trajectory, frames: &[usize]) -> Vec<(Image<u16>, ColorImage)> {
    let scene = Scene::room(7);
    let noise = SensorNoise {
        seed: 5,
        ..SensorNoise::default()
    };
    frames
        .iter()
        .enumerate()
        .map(|(n, &k)| sensor_frame(&scene, cam, &gt.poses[k], &noise, n))
        .collect()
}

/// Runs the pipeline along `frames` of the orbit (their `captures`), with stamps at 30 Hz that
/// skip the dropped frames when `skipped` is given as (first frame after the gap, frames
/// dropped), without stamps otherwise; per frame: (orbit frame, outcome, position error m,
/// rotation error deg).
fn run(
    (cam, gt): (&Camera, &Trajectory),
    frames: &[usize],
    captures: &[(Image<u16>, ColorImage)],
    params: SlamParams,
    skipped: Option<(usize, usize)>,
) -> Vec<(usize, FrameOutcome, f64, f64)> {
    let mut slam = RigidSlam::new(*cam, params, gt.poses[0]);
    let mut out = Vec::new();
    for (n, (&k, (raw, color))) in frames.iter().zip(captures).enumerate() {
        let pose: &Isometry3<f64> = &gt.poses[k];
        let report = match skipped {
            Some((after, dropped)) => {
                let t = (n + if n >= after { dropped } else { 0 }) as f64 / 30.0;
                let stamps = FrameStamps { depth: t, color: t };
                slam.process_timed(raw, Some(color), stamps)
            }
            None => slam.process(raw, Some(color)),
        };
        let d = pose.inverse() * report.pose;
        out.push((
            k,
            report.outcome,
            d.translation.vector.norm(),
            d.rotation.angle().to_degrees(),
        ));
    }
    out
}

#[test]
fn a_gap_on_the_way_back_is_relocalised_from_a_keyframe_or_reported() {
    // 30 orbit frames (24°, 75 cm) are skipped on the way back
    let frames = there_and_back((70, 40));
    let after = frames.iter().rposition(|&k| k == 40).unwrap();
    // without keyframes and without new maps (tests/integration/fragments.rs has those: a new
    // map's poses are in its own frame until a loop places it): the local round alone, whose
    // features on an image pyramid bridge the gap, and with them on one image size, which do not
    // (without the coasting start: the orbit's steady pace carries the last pose there too)
    let local_round = |levels: usize, coast: bool| {
        let mut relocalise = RelocaliseParams {
            candidates: 0,
            new_map_after: 0,
            coast,
            ..RelocaliseParams::default()
        };
        relocalise.features.levels = levels;
        SlamParams {
            relocalise,
            ..SlamParams::default()
        }
    };
    let stamps = Some((after, 29));
    let cam = Camera::new(262.5, 262.5, 159.5, 119.5, 320, 240);
    let gt = motion::procedural(Motion::Orbit, 100, 30.0);
    let captures = captures(&cam, &gt, &frames);
    for (what, params, skipped) in [
        ("keyframes, stamps", SlamParams::default(), stamps),
        ("keyframes, no stamps", SlamParams::default(), None),
        (
            "pyramid features, no keyframes, stamps",
            local_round(6, false),
            stamps,
        ),
        (
            "one-level features, no keyframes, stamps",
            local_round(1, false),
            stamps,
        ),
        (
            "coasting, one-level features, no keyframes, stamps",
            local_round(1, true),
            stamps,
        ),
    ] {
        let run = run((&cam, &gt), &frames, &captures, params, skipped);
        for (n, (k, outcome, t, r)) in run.iter().enumerate() {
            assert!(
                !outcome.is_fused() || (*t < 0.1 && *r < 5.0),
                "{what}: step {n} (orbit frame {k}): {outcome:?} but {t:.3} m, {r:.1}° off"
            );
            if n < after {
                assert!(
                    outcome.is_fused(),
                    "{what}: step {n}: {outcome:?} before the gap"
                );
            }
        }
        let (_, outcome, t, r) = &run[after];
        if !what.starts_with("one-level") {
            assert_eq!(*outcome, FrameOutcome::Relocalised, "{what}: after the gap");
            assert!(
                *t < 0.03 && *r < 2.0,
                "{what}: relocalised {t:.3} m, {r:.2}° off"
            );
            let fused = run[after..].iter().filter(|x| x.1.is_fused()).count();
            assert!(
                fused + 2 >= run.len() - after,
                "{what}: {fused} fused after the gap"
            );
        } else {
            assert!(
                outcome.failure().is_some(),
                "{what}: {outcome:?} after the gap"
            );
        }
    }
}

/// Frames `frames` of the 15 Hz survey in `layout` (layout and Kinect model of `seed`, 320×240),
/// written to `dir`.
fn survey(
    dir: &std::path::Path,
    (layout, seed): (Layout, u64),
    frames: std::ops::Range<usize>,
) -> TumSequence {
    let full = motion::procedural(Motion::Survey, frames.end, 15.0);
    let part = Trajectory {
        stamps: full.stamps[frames.clone()].to_vec(),
        poses: full.poses[frames].to_vec(),
    };
    let model = KinectModel {
        seed,
        gain_drift: 0.15,
        ..KinectModel::default()
    };
    sequence::write_rigid(
        dir,
        &layouts::build(layout, seed),
        &Camera::scaled_default(320, 240),
        &part,
        &Isometry3::identity(),
        &Sensor::Kinect(Box::new(model)),
        |_| {},
    )
    .unwrap();
    TumSequence::open(dir).unwrap()
}

/// Frames `frames` of a survey (see [`survey`]) run from the first ground-truth pose with the
/// frames stamped within `gap` dropped: asserts that no frame is fused in the map more than 10 cm
/// or 5° from the truth, and that one of the first five frames after the gap is fused; returns
/// whether each frame after the gap was fused in the map (placed in it, for a new map fragment).
fn survey_with_gap(
    scene: (Layout, u64),
    frames: std::ops::Range<usize>,
    gap: (f64, f64),
) -> Vec<bool> {
    let dir = std::env::temp_dir().join(format!(
        "dynamap-gap-{:?}-{}-{}",
        scene.0,
        frames.start,
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    let seq = survey(&dir, scene, frames);
    let after = run_with_gap(&seq, gap);
    let _ = std::fs::remove_dir_all(&dir);
    assert!(
        after.iter().take(5).any(|&(fused, _)| fused),
        "nothing fused within 5 frames after the gap: {after:?}"
    );
    after
        .into_iter()
        .map(|(fused, placed)| fused && placed)
        .collect()
}

/// Runs `seq` from its first ground-truth pose with the frames stamped within `gap` dropped;
/// asserts that no frame is fused in the map more than 10 cm or 5° from the truth, and returns
/// whether each frame after the gap was fused, and placed in the map.
fn run_with_gap(seq: &TumSequence, gap: (f64, f64)) -> Vec<(bool, bool)> {
    let gt = seq.groundtruth.clone().unwrap();
    let truth = |stamp: f64| gt.poses[gt.stamps.iter().position(|&s| s == stamp).unwrap()];
    let first = seq.load(0).unwrap();
    let mut slam = RigidSlam::new(seq.camera, SlamParams::default(), truth(first.timestamp));
    let (mut after, mut first_anchor) = (Vec::new(), None);
    for i in 0..seq.len() {
        let frame = seq.load(i).unwrap();
        if (gap.0..gap.1).contains(&frame.timestamp) {
            continue;
        }
        let stamps = FrameStamps {
            depth: frame.timestamp,
            color: frame.color_timestamp,
        };
        let report = slam.process_timed(&frame.depth, frame.color.as_ref(), stamps);
        // a new map fragment's frames are in a frame of their own; once a loop places the
        // fragment, that placement takes them into the main map's (the first keyframe's)
        if first_anchor.is_none() {
            first_anchor = report.anchor;
        }
        let graph = slam.keyframe_graph();
        let into_main = report
            .anchor
            .zip(first_anchor)
            .and_then(|(a, m)| graph.between_fragments(a, m))
            .unwrap_or(Isometry3::identity());
        let d = truth(frame.timestamp).inverse() * into_main * report.pose;
        let (t, r) = (d.translation.vector.norm(), d.rotation.angle().to_degrees());
        let outcome = &report.outcome;
        assert!(
            !(outcome.is_fused() && report.placed) || (t < 0.1 && r < 5.0),
            "{:.3} s: {outcome:?} but {t:.3} m, {r:.1}° off",
            frame.timestamp
        );
        if frame.timestamp >= gap.1 {
            after.push((outcome.is_fused(), report.placed));
        }
    }
    after
}

/// Before the correlation's test, the relocaliser's blind search slid this frame 0.64 m along
/// the wall with an inlier fraction of 0.97 (the whole view lies on the two planes) and it was
/// reported relocalised, and every later frame with it (NOTES 90). From 49 s to 54 s of the
/// survey the camera walks beside a wall and the floor, whose geometry leaves a slide along the
/// wall free and whose texture is smooth; 0.6 s is dropped.
#[test]
fn after_a_gap_beside_a_wall_no_frame_is_fused_slid_along_it() {
    survey_with_gap((Layout::Room, 61), 735..810, (51.42, 52.01));
}

/// In the room of two identical halves, after a 3-s gap the camera looks at a part of its half
/// that no keyframe saw closer than 0.65 m and 38°; the twin half's keyframe verified (fraction
/// 0.88, correlation 0.99) and the frame was reported relocalised 1.6 m and 180° off, every later
/// frame with it. Reaching the twin meant turning 142° in 3.1 s, where the camera had turned at
/// most 20°/s (NOTES 92): the frames are now not tracked, then start a new map fragment.
#[test]
fn after_a_gap_in_the_twin_room_no_frame_is_placed_in_the_other_half() {
    survey_with_gap((Layout::Twins, 63), 0..375, (20.45, 23.5));
}

/// After a 1-s gap in the room survey (seed 51) the camera had moved 25 cm and turned 15°,
/// beyond the local round, and no keyframe verified: a new map fragment starts. Its dense loops
/// to the main map matched the texture (correlation 0.98–0.99), but a loop between fragments
/// also needed 12 sparse-feature inliers, which these renders never give, so the fragment was
/// never placed (NOTES 94). Now the texture places it, and the frames since are in the map.
#[test]
fn a_new_map_after_a_gap_is_placed_by_a_loop_whose_texture_matches() {
    let placed = survey_with_gap((Layout::Room, 51), 0..525, (20.7, 21.8));
    assert!(
        placed.iter().rev().take(30).all(|&p| p),
        "the last frames are not placed in the map: {placed:?}"
    );
}

/// The wall 1.5 m ahead and the floor 0.4 m below of a camera that slides along x: the depth
/// of pixel row `v` in the camera's frame, which a slide does not change.
fn wall_over_floor(cam: &Camera, v: usize) -> f64 {
    let y = (v as f64 - cam.cy) / cam.fy;
    if y > 0.4 / 1.5 {
        0.4 / y
    } else {
        1.5
    }
}

/// The frame of a camera at `x` along the wall and floor of [`wall_over_floor`], painted with
/// stripes across x that repeat every 20 cm, beaten by a fainter wave of 54 cm.
fn striped_frame(cam: &Camera, x: f64) -> (Image<u16>, ColorImage) {
    let (w, h) = (cam.width, cam.height);
    let mut depth = Image::filled(w, h, 0u16);
    let mut color = ColorImage::filled(w, h, [0; 3]);
    let tau = std::f64::consts::TAU;
    for v in 0..h {
        for u in 0..w {
            let d = wall_over_floor(cam, v);
            let along = x + cam.back_project(u as f64, v as f64, d).x;
            let grey = 128.0 + 50.0 * (tau * along / 0.2).sin() + 20.0 * (tau * along / 0.54).sin();
            depth.data[v * w + u] = (d * cam.depth_scale).round() as u16;
            color.data[v * w + u] = [grey as u8; 3];
        }
    }
    (depth, color)
}

/// A camera that slides along a striped wall, speeding up by 3 cm a frame to 12 cm a frame,
/// and stops dead: the constant-velocity start lies 12 cm ahead, 0.6 of the stripes' period,
/// and the track settled on the next stripe, 20 cm ahead, with a correlation of about 0.8
/// against the recent 0.99: above the half that refuses a frame, and the geometry (both
/// planes hold the x axis) cannot tell. Such a track now faces the relocaliser's starts, and
/// the last pose's correlates better (NOTES 154). No frame may be reported more than 3 cm off.
#[test]
fn a_track_one_stripe_ahead_on_a_repeating_wall_is_not_kept() {
    let cam = Camera::scaled_default(320, 240);
    let steps = [
        0.0, 0.0, 0.0, 0.03, 0.06, 0.09, 0.12, 0.12, 0.12, 0.0, 0.0, 0.0,
    ];
    let mut slam = RigidSlam::new(cam, SlamParams::default(), Isometry3::identity());
    let mut x = 0.0;
    for (k, step) in steps.iter().enumerate() {
        x += step;
        let (depth, color) = striped_frame(&cam, x);
        let stamp = k as f64 / 30.0;
        let stamps = FrameStamps {
            depth: stamp,
            color: stamp,
        };
        let report = slam.process_timed(&depth, Some(&color), stamps);
        assert!(report.outcome.is_fused(), "frame {k}: {:?}", report.outcome);
        let off = (report.pose.translation.vector - nalgebra::Vector3::new(x, 0.0, 0.0)).norm();
        assert!(
            off < 0.03,
            "frame {k} ({:?}) is {off:.3} m off",
            report.outcome
        );
    }
}

/// Where, along x, the wall of [`wall_over_floor`] bulges out by [`bulged_wall`]'s hills:
/// spaced unevenly so that no two stretches of the wall look alike.
const HILLS: [f64; 8] = [-0.8, -0.1, 0.35, 0.9, 1.25, 1.9, 2.6, 2.95];

/// The depth along the ray of pixel row and column slopes (`dx`, `dy`) of a camera at `x`
/// before the floor of [`wall_over_floor`] and a wall 1.5 m ahead with 12-cm hills 12 cm wide
/// at [`HILLS`]: solved for the wall by fixed-point iteration (each shrinks the error to at
/// most 0.55 of it: the hills' slopes are under 0.9 and the rays' under 0.61).
fn bulged_wall(x: f64, dx: f64, dy: f64) -> f64 {
    let wall = |along: f64| {
        let hill = |c: &f64| 0.12 * (-((along - c) / 0.12).powi(2)).exp();
        1.5 - HILLS.iter().map(hill).sum::<f64>()
    };
    let mut z = 1.5;
    for _ in 0..12 {
        z = wall(x + z * dx);
    }
    if dy > 0.0 {
        z.min(0.4 / dy)
    } else {
        z
    }
}

/// The depth and colour of a camera at `x` before [`bulged_wall`], whose hills fix the slide
/// along it. A `textured` wall is shaded by two slow waves along it (70 and 113 cm): a texture
/// the model's can be correlated with, but without a corner for the features; the other is
/// plain grey.
fn bulged_frame(cam: &Camera, x: f64, textured: bool) -> (Image<u16>, ColorImage) {
    let (w, h) = (cam.width, cam.height);
    let mut depth = Image::filled(w, h, 0u16);
    let mut color = ColorImage::filled(w, h, [128; 3]);
    let tau = std::f64::consts::TAU;
    for v in 0..h {
        let dy = (v as f64 - cam.cy) / cam.fy;
        for u in 0..w {
            let dx = (u as f64 - cam.cx) / cam.fx;
            let d = bulged_wall(x, dx, dy);
            depth.data[v * w + u] = (d * cam.depth_scale).round() as u16;
            if textured {
                let along = x + d * dx;
                let wave = 40.0 * (tau * along / 0.7).sin() + 30.0 * (tau * along / 1.13).sin();
                color.data[v * w + u] = [(128.0 + wave) as u8; 3];
            }
        }
    }
    (depth, color)
}

/// A camera walking along [`bulged_wall`] at 0.5 m/s for 1 s, whose stream then skips 1.5 s, and
/// 10 frames after the gap, run with and without [`RelocaliseParams::coast`]: each run's
/// outcomes after the gap and whether each was fused in the map. Asserts that every frame before
/// the gap is fused and that none is fused more than 5 cm off (the track drifts 2 cm over the
/// 30 frames before the gap).
fn walk_past_hills(textured: bool) -> [Vec<(FrameOutcome, bool)>; 2] {
    let cam = Camera::scaled_default(320, 240);
    let speed = 0.5;
    let frames: Vec<_> = (0..30)
        .chain(75..85)
        .map(|k| (k, bulged_frame(&cam, speed * k as f64 / 30.0, textured)))
        .collect();
    let run = |coast: bool| {
        let mut params = SlamParams::default();
        params.relocalise.coast = coast;
        let mut slam = RigidSlam::new(cam, params, Isometry3::identity());
        let mut after = Vec::new();
        for (k, (depth, color)) in &frames {
            let stamp = *k as f64 / 30.0;
            let stamps = FrameStamps {
                depth: stamp,
                color: stamp,
            };
            let report = slam.process_timed(depth, Some(color), stamps);
            let fused = report.outcome.is_fused() && report.placed;
            let truth = nalgebra::Vector3::new(speed * stamp, 0.0, 0.0);
            let off = (report.pose.translation.vector - truth).norm();
            assert!(
                !fused || off < 0.05,
                "coast {coast}: frame {k} ({:?}) is {off:.3} m off",
                report.outcome
            );
            assert!(
                *k >= 30 || fused,
                "frame {k} before the gap: {:?}",
                report.outcome
            );
            if *k >= 75 {
                after.push((report.outcome, fused));
            }
        }
        after
    };
    [run(true), run(false)]
}

/// After the gap in [`walk_past_hills`] the camera is 0.75 m further on, beyond the local
/// round's starts (0.3 m) and one track (0.3 m), and the wall's slow shading gives the features
/// nothing to match. Carried on at its pace from before the gap
/// ([`RelocaliseParams::coast`]), the last pose lands where the hills hold the track and the
/// shading correlates: the first frame after the gap is relocalised; without that start none
/// of the five after it is fused in the map.
#[test]
fn a_walk_that_skipped_a_stretch_is_found_where_its_pace_carried_it() {
    let [coasting, not] = walk_past_hills(true);
    assert_eq!(
        coasting[0],
        (FrameOutcome::Relocalised, true),
        "{coasting:?}"
    );
    assert!(not.iter().take(5).all(|&(_, f)| !f), "{not:?}");
}

/// On the plain wall of [`walk_past_hills`] nothing tells the pose after the gap but the
/// geometry, and the view there overlaps what was seen by half. The map's first keyframe,
/// tracked against nothing, had no agreement of its own, and the global round held a pose
/// found from it to none: the first frame after the gap was relocalised from it 1.05 m off
/// with an agreement of 0.36 (fraction 0.40). Such a keyframe is now held to the recent
/// frames' floor, and no frame is fused off the truth (asserted by `walk_past_hills`).
#[test]
fn a_keyframe_that_started_the_map_holds_its_poses_to_the_recent_fit() {
    let [coasting, not] = walk_past_hills(false);
    for after in [coasting, not] {
        assert!(after.iter().any(|(o, _)| o.is_fused()), "{after:?}");
    }
}
