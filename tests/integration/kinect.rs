//! The structured-light sensor model against its own formulas, on planes whose true depth is
//! known: the depth step z²/kq, the depth noise against depth, the projector's and the IR camera's
//! shadow bands beside a near object; and a Kinect sequence written, read back (distortion,
//! separate colour stamps) and tracked.

use dynamap::slam::camera::Camera;
use dynamap::slam::distortion::Distortion;
use dynamap::slam::eval::{ate, Alignment, MAX_STAMP_DIFFERENCE};
use dynamap::slam::io::trajectory::Trajectory;
use dynamap::slam::io::tum::{read_list, TumSequence};
use dynamap::slam::rigid::{RigidSlam, SlamParams};
use dynamap::slam::synthetic::kinect::KinectModel;
use dynamap::slam::synthetic::motion::{self, Motion};
use dynamap::slam::synthetic::scene::{Scene, Shape};
use dynamap::slam::synthetic::sequence::{self, Sensor};
use dynamap::slam::synthetic::texture::Texture;
use nalgebra::{Isometry3, UnitQuaternion, Vector3};

/// The model without distortion (so pixels and rays are the pinhole's) and without random holes.
fn model(seed: u64) -> KinectModel {
    KinectModel {
        seed,
        distortion: Distortion::default(),
        hole_fraction: 0.0,
        ..KinectModel::default()
    }
}

/// A still camera at the origin looking along +z.
fn still(frames: usize) -> Trajectory {
    let mut t = Trajectory::default();
    for k in 0..frames {
        t.push(k as f64 / 30.0, Isometry3::identity());
    }
    t
}

/// A large plane facing the camera at depth `z`, tilted by `tilt` radians about the x axis.
fn wall(z: f64, tilt: f64) -> Scene {
    let mut s = Scene::default();
    s.add(
        Shape::Plane { hx: 20.0, hy: 20.0 },
        Isometry3::from_parts(
            Vector3::new(0.0, 0.0, z).into(),
            UnitQuaternion::from_scaled_axis(Vector3::x() * tilt),
        ),
        Texture::plain([0.5, 0.5, 0.5]),
    );
    s
}

/// The measured depths (metres) of `frames` captures, valid pixels only, with their pixel index.
fn depths(m: &KinectModel, scene: &Scene, cam: &Camera, frames: usize) -> Vec<(usize, f64)> {
    let traj = still(frames);
    let rec = m.recorder(cam);
    (0..frames)
        .flat_map(|k| {
            let d = rec.capture(scene, &traj, k).depth;
            d.data
                .iter()
                .enumerate()
                .filter(|(_, &v)| v > 0)
                .map(|(i, &v)| (i, v as f64 / cam.depth_scale))
                .collect::<Vec<_>>()
        })
        .collect()
}

#[test]
fn the_depth_step_grows_as_z_squared_over_kq() {
    let cam = Camera::tum_default();
    let m = model(1);
    for z0 in [1.0, 2.0] {
        // a tilted plane spans about ±10 cm of depth around z0
        let z: Vec<f64> = depths(&m, &wall(z0, 0.35), &cam, 1)
            .into_iter()
            .map(|(_, z)| z)
            .filter(|z| (z - z0).abs() < 0.05)
            .collect();
        let mut values: Vec<i64> = z.iter().map(|z| (z * 1e4).round() as i64).collect();
        values.sort_unstable();
        values.dedup();
        let mut gaps: Vec<f64> = values
            .windows(2)
            .map(|w| (w[1] - w[0]) as f64 / 1e4)
            .collect();
        gaps.sort_by(f64::total_cmp);
        let median = gaps[gaps.len() / 2];
        let expected = m.depth_step(z0);
        // the millimetre rounding moves a step by at most 1 mm
        assert!(
            (median - expected).abs() <= 0.001 + 0.05 * expected,
            "z {z0}: median step {median} vs z²/kq {expected}"
        );
    }
}

#[test]
fn the_depth_noise_follows_the_disparity_model() {
    let cam = Camera::new(525.0, 525.0, 159.5, 119.5, 320, 240);
    let m = model(2);
    let mut sigmas = Vec::new();
    // a slight tilt spreads the true disparity over many steps, so its rounding is uniform
    let tilt = 0.15f64;
    let normal = UnitQuaternion::from_scaled_axis(Vector3::x() * tilt) * Vector3::z();
    for z0 in [1.0, 2.0, 3.0] {
        let z = depths(&m, &wall(z0, tilt), &cam, 3);
        let truth = |i: usize| {
            let (u, v) = ((i % cam.width) as f64, (i / cam.width) as f64);
            let ray = Vector3::new((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0);
            z0 * normal.z / normal.dot(&ray)
        };
        let n = z.len() as f64;
        let rms = (z.iter().map(|&(i, z)| (z - truth(i)).powi(2)).sum::<f64>() / n).sqrt();
        // disparity noise and the uniform quantisation of one step, then of the millimetre (the
        // lateral jitter on the slight tilt adds well under 5 %)
        let step = m.depth_step(z0);
        let expected = (m.depth_sigma(z0).powi(2) + step * step / 12.0 + 1e-6 / 12.0).sqrt();
        assert!(
            (rms / expected - 1.0).abs() < 0.2,
            "z {z0}: rms {rms} vs model {expected}"
        );
        sigmas.push(rms);
    }
    let ratio = sigmas[1] / sigmas[0];
    assert!(
        (3.0..5.0).contains(&ratio),
        "noise at 2 m / 1 m = {ratio}, z² gives 4"
    );
}

#[test]
fn shadows_lie_beside_a_near_object_as_wide_as_the_baselines_make_them() {
    let cam = Camera::tum_default();
    let m = model(3);
    let (near, far) = (1.0, 2.0);
    let mut scene = wall(far, 0.0);
    scene.add(
        Shape::Plane { hx: 0.15, hy: 0.15 },
        Isometry3::translation(0.0, 0.0, near),
        Texture::plain([0.8, 0.8, 0.8]),
    );
    let depth = m.recorder(&cam).capture(&scene, &still(2), 0).depth;
    // the object spans u = cx ± f·0.15/near; measure the holes beside it on the middle rows
    let (lo, hi) = (cam.cx - cam.fx * 0.15 / near, cam.cx + cam.fx * 0.15 / near);
    let mut left = Vec::new();
    let mut right = Vec::new();
    for v in 200..280 {
        let row = &depth.data[v * cam.width..(v + 1) * cam.width];
        let hole_run = |range: &mut dyn Iterator<Item = usize>| {
            range
                .skip_while(|&u| row[u] > 0 && row[u] < 8000)
                .take_while(|&u| row[u] == 0)
                .count()
        };
        // leftwards from inside the object, rightwards likewise
        left.push(hole_run(&mut (0..lo as usize + 3).rev()) as f64);
        right.push(hole_run(&mut (hi as usize - 3..cam.width)) as f64);
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let gap = 1.0 / near - 1.0 / far;
    // the projector (ir_offset + baseline along +x) shades the far side to the object's left, the
    // IR camera (ir_offset) cannot see the wall just right of it
    let projector = cam.fx * (m.ir_offset + m.baseline) * gap;
    let ir = cam.fx * -m.ir_offset * gap;
    let (l, r) = (median(&mut left), median(&mut right));
    assert!(
        (l - projector).abs() <= 2.0,
        "left band {l} px, projector shadow {projector}"
    );
    assert!(
        (r - ir).abs() <= 2.0,
        "right band {r} px, IR occlusion {ir}"
    );
}

#[test]
fn a_steep_surface_is_lost_in_patches_at_the_rate_of_its_incidence() {
    let cam = Camera::tum_default();
    let m = model(4);
    let (g0, g1) = m.grazing;
    // a wall turned about the y axis so that the central column's incidence is mid-band
    let mid = (0.5 * (g0 + g1)).to_radians();
    let mut scene = Scene::default();
    scene.add(
        Shape::Plane { hx: 20.0, hy: 20.0 },
        Isometry3::from_parts(
            Vector3::new(0.0, 0.0, 1.5).into(),
            UnitQuaternion::from_scaled_axis(Vector3::y() * mid),
        ),
        Texture::plain([0.5, 0.5, 0.5]),
    );
    let depth = m.recorder(&cam).capture(&scene, &still(1), 0).depth;
    // columns near the centre, whose incidence is within ±1.5° of mid-band
    let (u0, u1) = (cam.cx as usize - 6, cam.cx as usize + 6);
    let (mut holes, mut valid, mut isolated) = (0usize, 0usize, 0usize);
    for v in 60..420 {
        let row = &depth.data[v * cam.width..(v + 1) * cam.width];
        for u in u0..u1 {
            if row[u] == 0 {
                holes += 1;
                continue;
            }
            valid += 1;
            if row[u - 1] == 0 && row[u + 1] == 0 {
                isolated += 1;
            }
        }
    }
    let rate = holes as f64 / (holes + valid) as f64;
    // the marginal rate is (angle − g0) / (g1 − g0) = 1/2
    assert!((0.3..0.7).contains(&rate), "hole rate {rate}, model 0.5");
    // independent per-pixel losses would leave (1 − rate)² ≈ 1/4 of the valid pixels isolated
    let speckle = isolated as f64 / valid as f64;
    assert!(speckle < 0.05, "isolated valid pixels {speckle}");
}

#[test]
fn a_kinect_sequence_reads_back_with_its_own_stamps_and_is_tracked() {
    let dir = std::env::temp_dir().join(format!("dynamap-kinect-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let cam = Camera::scaled_default(320, 240);
    let traj = motion::procedural(Motion::Orbit, 40, 30.0);
    let model = KinectModel {
        seed: 5,
        ..KinectModel::default()
    };
    sequence::write_rigid(
        &dir,
        &Scene::room(5),
        &cam,
        &traj,
        &Isometry3::identity(),
        &Sensor::Kinect(Box::new(model.clone())),
        |_| {},
    )
    .unwrap();
    // colour stamps lie 10-20 ms after the depth ones, in their own list
    let rgb = read_list(&dir.join("rgb.txt")).unwrap();
    let depth = read_list(&dir.join("depth.txt")).unwrap();
    for (c, d) in rgb.iter().zip(&depth) {
        let delay = c.0 - d.0;
        assert!(
            (0.0099..=0.0201).contains(&delay),
            "colour {} depth {}",
            c.0,
            d.0
        );
    }
    // the distortion is written with the intrinsics and the frames come back undistorted
    let intr = std::fs::read_to_string(dir.join("intrinsics.txt")).unwrap();
    assert_eq!(intr.split_whitespace().count(), 10, "{intr}");
    let seq = TumSequence::open(&dir).unwrap();
    assert!(seq.len() >= 36, "{} frames associated", seq.len());
    let gt = seq.groundtruth.clone().unwrap();
    let first = seq.load(0).unwrap();
    let start = gt.poses[gt
        .stamps
        .iter()
        .position(|&s| s == first.timestamp)
        .unwrap()];
    let mut slam = RigidSlam::new(seq.camera, SlamParams::default(), start);
    let mut est = Trajectory::default();
    for i in 0..seq.len() {
        let frame = seq.load(i).unwrap();
        let report = slam.process(&frame.depth, frame.color.as_ref());
        assert!(
            report.failure().is_none(),
            "frame {i}: {:?}",
            report.outcome
        );
        est.push(frame.timestamp, report.pose);
    }
    let e = ate(&gt, &est, Alignment::Se3, MAX_STAMP_DIFFERENCE).unwrap();
    assert!(e.stats.rmse < 0.01, "ATE {:?}", e.stats);
    let _ = std::fs::remove_dir_all(&dir);
}
