//! Rigid SLAM end to end on the project's own rendered sequences.

use dynamap::slam::camera::Camera;
use dynamap::slam::eval::{ate, Alignment};
use dynamap::slam::image::Image;
use dynamap::slam::io::trajectory::Trajectory;
use dynamap::slam::rigid::{RigidSlam, SlamParams};
use dynamap::slam::synthetic::motion::{self, Motion};
use dynamap::slam::synthetic::noise::SensorNoise;
use dynamap::slam::synthetic::render::render;
use dynamap::slam::synthetic::scene::Scene;

/// Runs the pipeline on `frames` rendered frames of `motion` at 320×240 with sensor noise;
/// `blank` frames get an empty depth image. Returns (ground truth, estimate, failed frames).
fn run(
    m: Motion,
    frames: usize,
    blank: std::ops::Range<usize>,
) -> (Trajectory, Trajectory, Vec<usize>) {
    run_with(m, frames, blank, SlamParams::default())
}

/// [`run`] with other settings.
fn run_with(
    m: Motion,
    frames: usize,
    blank: std::ops::Range<usize>,
    params: SlamParams,
) -> (Trajectory, Trajectory, Vec<usize>) {
    let cam = Camera::new(262.5, 262.5, 159.5, 119.5, 320, 240);
    let gt = motion::procedural(m, frames, 30.0);
    let scene = Scene::room(7);
    let noise = SensorNoise {
        seed: 3,
        ..SensorNoise::default()
    };
    let mut slam = RigidSlam::new(cam, params, gt.poses[0]);
    let mut est = Trajectory::default();
    let mut failed = Vec::new();
    for (k, pose) in gt.poses.iter().enumerate() {
        let mut r = render(&scene, &cam, pose);
        let mut raw = noise.apply(
            k as u64,
            &r.depth,
            &r.cos_incidence,
            &mut r.color,
            cam.depth_scale,
        );
        if blank.contains(&k) {
            raw = Image::new(cam.width, cam.height);
        }
        let report = slam.process(&raw, Some(&r.color));
        if let Some(why) = &report.failure {
            eprintln!("frame {k}: {why}");
            failed.push(k);
        }
        est.push(gt.stamps[k], report.pose);
    }
    (gt, est, failed)
}

#[test]
fn tracking_a_generated_sequence_stays_within_a_centimetre() {
    let (gt, est, failed) = run(Motion::Orbit, 30, 0..0);
    assert!(failed.is_empty(), "frames {failed:?} failed");
    let a = ate(&gt, &est, Alignment::Se3, 1e-3).unwrap();
    assert!(a.stats.max < 0.01, "ATE {:?}", a.stats);
}

/// With the finest level switched off (0 iterations), inliers are counted on the finest level that
/// runs, so tracking neither fails for "too few inliers" nor drifts.
#[test]
fn tracking_without_the_finest_level_counts_inliers_where_it_runs() {
    let mut params = SlamParams::default();
    params.tracker.iterations = vec![0, 5, 10];
    let (gt, est, failed) = run_with(Motion::Orbit, 15, 0..0, params);
    assert!(failed.is_empty(), "frames {failed:?} failed");
    let a = ate(&gt, &est, Alignment::Se3, 1e-3).unwrap();
    assert!(a.stats.max < 0.01, "ATE {:?}", a.stats);
}

#[test]
fn blank_depth_frames_are_skipped_and_tracking_recovers() {
    let (gt, est, failed) = run(Motion::Shake, 30, 12..17);
    assert_eq!(
        failed,
        vec![12, 13, 14, 15, 16],
        "exactly the blank frames fail"
    );
    // Blank frames keep the last good pose; every tracked frame, after the gap too, is within 1 cm.
    let tracked: Trajectory = {
        let mut t = Trajectory::default();
        for k in (0..30).filter(|k| !failed.contains(k)) {
            t.push(est.stamps[k], est.poses[k]);
        }
        t
    };
    let a = ate(&gt, &tracked, Alignment::None, 1e-3).unwrap();
    assert_eq!(a.pairs.len(), 25);
    assert!(a.stats.max < 0.01, "ATE after the gap {:?}", a.stats);
}
