//! Rigid SLAM end to end on the project's own rendered sequences.

use dynamap::slam::camera::Camera;
use dynamap::slam::eval::{ate, Alignment};
use dynamap::slam::image::{ColorImage, DepthImage, Image};
use dynamap::slam::io::trajectory::Trajectory;
use dynamap::slam::rigid::{PhotometricWeight, RigidSlam, SlamParams, TrackFailure};
use dynamap::slam::synthetic::motion::{self, Motion};
use dynamap::slam::synthetic::noise::SensorNoise;
use dynamap::slam::synthetic::render::render;
use dynamap::slam::synthetic::scene::Scene;

/// `frames` frames of `motion` in the room rendered at 320×240 (their hits dropped), so that
/// runs with other settings or sensors reuse one rendering.
struct Views {
    cam: Camera,
    gt: Trajectory,
    /// Per frame: depth (m), cos of incidence, colour.
    frames: Vec<(DepthImage, Image<f32>, ColorImage)>,
}

fn views(m: Motion, frames: usize) -> Views {
    views_by(Camera::new(262.5, 262.5, 159.5, 119.5, 320, 240), m, frames)
}

/// [`views`] through another camera.
fn views_by(cam: Camera, m: Motion, frames: usize) -> Views {
    let gt = motion::procedural(m, frames, 30.0);
    let scene = Scene::room(7);
    let frames = gt
        .poses
        .iter()
        .map(|pose| {
            let r = render(&scene, &cam, pose);
            (r.depth, r.cos_incidence, r.color)
        })
        .collect();
    Views { cam, gt, frames }
}

/// Runs the pipeline on `frames` rendered frames of `motion` with sensor noise; `blank` frames
/// get an empty depth image. Returns (ground truth, estimate, failed frames).
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
    let noise = SensorNoise {
        seed: 3,
        ..SensorNoise::default()
    };
    run_sensor(&views(m, frames), blank, params, noise)
}

/// [`run_with`] on given views through a given sensor model.
fn run_sensor(
    views: &Views,
    blank: std::ops::Range<usize>,
    params: SlamParams,
    noise: SensorNoise,
) -> (Trajectory, Trajectory, Vec<usize>) {
    let (cam, gt) = (views.cam, &views.gt);
    let mut slam = RigidSlam::new(cam, params, gt.poses[0]);
    let mut est = Trajectory::default();
    let mut failed = Vec::new();
    for (k, (depth, cos_incidence, color)) in views.frames.iter().enumerate() {
        let mut color = color.clone();
        let mut raw = noise.apply(k as u64, depth, cos_incidence, &mut color, cam.depth_scale);
        if blank.contains(&k) {
            raw = Image::new(cam.width, cam.height);
        }
        let report = slam.process(&raw, Some(&color));
        if let Some(why) = report.failure() {
            eprintln!("frame {k}: {why}");
            failed.push(k);
        }
        est.push(gt.stamps[k], report.pose);
    }
    (gt.clone(), est, failed)
}

#[test]
fn tracking_a_generated_sequence_stays_within_a_centimetre() {
    let (gt, est, failed) = run(Motion::Orbit, 30, 0..0);
    assert!(failed.is_empty(), "frames {failed:?} failed");
    let a = ate(&gt, &est, Alignment::Se3, 1e-3).unwrap();
    assert!(a.stats.max < 0.01, "ATE {:?}", a.stats);
}

/// A sensor whose image has an odd width and height (cropped or rectified frames) is tracked
/// like any other: every pyramid level of odd size is filtered and halved. Before the
/// depth pyramid's fix, halving an odd width read past the row and panicked.
#[test]
fn a_sensor_of_odd_width_and_height_is_tracked() {
    let cam = Camera::new(262.5, 262.5, 159.0, 118.0, 319, 237);
    let noise = SensorNoise {
        seed: 3,
        ..SensorNoise::default()
    };
    let views = views_by(cam, Motion::Orbit, 20);
    let (gt, est, failed) = run_sensor(&views, 0..0, SlamParams::default(), noise);
    assert!(failed.is_empty(), "frames {failed:?} failed");
    let a = ate(&gt, &est, Alignment::Se3, 1e-3).unwrap();
    assert!(a.stats.max < 0.01, "ATE {:?}", a.stats);
}

/// A frame whose depth is its own but whose colour is its mirror image (the geometry fits the
/// model, the texture does not, as at a pose tracked wrongly on the same planes) is not tracked
/// and says why (NOTES 124); the frames around it are tracked, and none is off, one given
/// without colour among them (no texture to match is no mismatch, and no intensity is used).
#[test]
fn a_frame_whose_texture_does_not_match_the_model_is_not_tracked() {
    let v = views(Motion::Orbit, 24);
    let cam = v.cam;
    let mut slam = RigidSlam::new(cam, SlamParams::default(), v.gt.poses[0]);
    let noise = SensorNoise {
        seed: 3,
        ..SensorNoise::default()
    };
    let mirrored = 16;
    for (k, (depth, cos_incidence, color)) in v.frames.iter().enumerate() {
        let mut color = color.clone();
        let raw = noise.apply(k as u64, depth, cos_incidence, &mut color, cam.depth_scale);
        if k == mirrored {
            for row in color.data.chunks_mut(cam.width) {
                row.reverse();
            }
        }
        let report = match k == mirrored + 3 {
            true => slam.process(&raw, None),
            false => slam.process(&raw, Some(&color)),
        };
        if k == mirrored {
            let why = report.failure().expect("a mirrored texture was tracked");
            assert!(matches!(why, TrackFailure::TextureMismatch { .. }), "{why}");
            continue;
        }
        assert!(
            report.failure().is_none(),
            "frame {k}: {:?}",
            report.outcome
        );
        // the frame without colour too: its tracking took the last frame's intensity, left in
        // the preprocessor's buffers, as its own, and ended 17 mm off (now 1.7 mm)
        let off = (v.gt.poses[k].inverse() * report.pose)
            .translation
            .vector
            .norm();
        assert!(off < 0.01, "frame {k} is {off} m off");
    }
}

/// A 15 % auto-exposure drift (issue 23): with the exposure (gain) fit the ATE stays within
/// 10 % (and 0.1 mm) of the same sequence at a fixed exposure, on two motions; without the fit
/// it is worse on at least one (since residuals are weighed by depth noise, NOTES 54, the shake
/// is held by its geometry and the drift no longer moves its ATE either way).
#[test]
fn an_exposure_drift_costs_no_accuracy() {
    let frames = 75; // the gain climbs to 1.15 at frame 37 and is back to 1 at 75
    let mut fit_mattered = false;
    for m in [Motion::Orbit, Motion::Shake] {
        let views = views(m, frames);
        let ate_of = |gain_drift: f32, fit: bool| {
            let mut params = SlamParams::default();
            params.tracker.fit_gain = fit;
            let noise = SensorNoise {
                seed: 3,
                gain_drift,
                ..SensorNoise::default()
            };
            let (gt, est, failed) = run_sensor(&views, 0..0, params, noise);
            assert!(failed.is_empty(), "{m:?}: frames {failed:?} failed");
            ate(&gt, &est, Alignment::Se3, 1e-3).unwrap().stats.rmse
        };
        let fixed = ate_of(0.0, true);
        let drifting = ate_of(0.15, true);
        let uncompensated = ate_of(0.15, false);
        eprintln!(
            "{m:?}: ATE fixed exposure {fixed:.6} m, drifting {drifting:.6}, drifting without the fit {uncompensated:.6}"
        );
        // 10 % and 0.1 mm: one 75-frame realisation's sub-millimetre ATE moves by a few
        // hundredths of a millimetre with the raycast's sample positions alone (NOTES 113)
        assert!(
            drifting <= 1.1 * fixed + 1e-4,
            "{m:?}: ATE {drifting} with the drift, {fixed} without"
        );
        fit_mattered |= uncompensated > 1.1 * drifting;
    }
    assert!(
        fit_mattered,
        "the exposure fit made no difference on either motion"
    );
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

/// A camera sliding along a wall: without texture the wall leaves three motions unobservable and
/// the frame fails as degenerate (not fused); with texture the photometric term pins them and the
/// slide is tracked. The same at 320×240 and at 640×480: the texture is measured per radian of
/// view, not per pixel (NOTES 109).
#[test]
fn a_plain_wall_is_degenerate_and_a_textured_one_is_tracked() {
    for cam in [
        Camera::new(262.5, 262.5, 159.5, 119.5, 320, 240),
        Camera::new(525.0, 525.0, 319.5, 239.5, 640, 480),
    ] {
        wall_slide(cam);
    }
}

/// The texture that decides a degenerate frame is a property of the view, not of the
/// resolution: one textured wall measures the same at 320×240 and at 640×480 (per pixel, the
/// finer frame's coarsest level would read half).
#[test]
fn a_walls_texture_measures_the_same_at_any_resolution() {
    use dynamap::slam::preprocess::{PreprocessParams, Preprocessor};
    use dynamap::slam::rigid::FrameConstraint;
    use dynamap::slam::synthetic::motion::look_at;
    use dynamap::slam::synthetic::scene::Shape;
    use dynamap::slam::synthetic::texture::Texture;
    use nalgebra::{Isometry3, Point3, Vector3};

    let mut scene = Scene::default();
    scene.add(
        Shape::Plane { hx: 3.0, hy: 3.0 },
        Isometry3::translation(0.0, 0.0, 1.5),
        Texture::random(4, 3.0, 12.0),
    );
    let pose = look_at(
        &Point3::origin(),
        &Point3::new(0.0, 0.0, 1.0),
        &-Vector3::y(),
    );
    let measure = |cam: Camera| {
        let r = render(&scene, &cam, &pose);
        let mut pre = Preprocessor::new(cam, PreprocessParams::default());
        FrameConstraint::of(pre.process_metres(&r.depth, Some(&r.color))).texture
    };
    let coarse = measure(Camera::new(262.5, 262.5, 159.5, 119.5, 320, 240));
    let fine = measure(Camera::new(525.0, 525.0, 319.5, 239.5, 640, 480));
    assert!(coarse > 0.0, "no texture measured");
    assert!(
        (fine / coarse - 1.0).abs() < 0.2,
        "texture {coarse:.3} per radian at 320×240, {fine:.3} at 640×480"
    );
}

/// A textured wall `z` ahead of the camera at the origin and a textured floor 1 m below it (the
/// camera's up is -y).
fn wall_over_floor(z: f64) -> Scene {
    use dynamap::slam::synthetic::scene::Shape;
    use dynamap::slam::synthetic::texture::Texture;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
    let mut wall = Scene::default();
    wall.add(
        Shape::Plane { hx: 6.0, hy: 4.5 },
        Isometry3::translation(0.0, 0.0, z),
        Texture::random(5, 3.0, 12.0),
    );
    wall.add(
        Shape::Plane { hx: 6.0, hy: 6.0 },
        Isometry3::from_parts(
            Translation3::new(0.0, 1.0, 1.0),
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_2),
        ),
        Texture::random(6, 3.0, 12.0),
    );
    wall
}

/// A textured wall 2.7–5 m away over a floor, as a Kinect records it: the sensor's noise tilts
/// each coarse normal at random, and per-pixel normals read those tilts as constraint along the
/// slide the two planes leave free (conditioning 3·10⁻³–2·10⁻², above the floor of then, 10⁻³:
/// with λ = 0 all 300 frames of such a render were reported tracked, ATE 651 mm; NOTES 156). The
/// planes fitted to patches see two planes, degenerate without the texture, from the wall's
/// middle, nearer the floor and turned along the wall, up to 5 m where the sensor's depth steps
/// are 72 mm (with 16 patches across, which fit the steps, a view 5 m away read 4.5·10⁻³; NOTES
/// 157). A room with its table, recorded the same way, reads over four times the floor.
#[test]
fn a_far_wall_over_a_floor_is_degenerate_without_its_texture_despite_the_noise() {
    use dynamap::slam::preprocess::{PreprocessParams, Preprocessor};
    use dynamap::slam::rigid::{FrameConstraint, TrackerParams};
    use dynamap::slam::synthetic::kinect::KinectModel;
    use dynamap::slam::synthetic::layouts::{self, Layout};
    use dynamap::slam::synthetic::motion::look_at;
    use nalgebra::{Isometry3, Point3, Vector3};

    let cam = Camera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
    let room = layouts::build(Layout::Room, 7);
    let orbit = motion::procedural(Motion::Orbit, 1, 30.0);
    let p = TrackerParams::default();
    let geometry_only = TrackerParams {
        photometric_weight: PhotometricWeight::Fixed(0.0),
        ..p.clone()
    };
    for seed in [3, 4] {
        let model = KinectModel {
            seed,
            ..KinectModel::default()
        };
        let measure = |scene: &Scene, pose: Isometry3<f64>| {
            let mut one = Trajectory::default();
            one.push(0.0, pose);
            let f = model.recorder(&cam).capture(scene, &one, 0);
            let mut pre = Preprocessor::new(cam, PreprocessParams::default());
            FrameConstraint::of(pre.process(&f.depth, Some(&f.color)))
        };
        for z in [2.7, 4.0, 5.0] {
            let wall = wall_over_floor(z);
            // looking at the wall's middle, lower (more floor), and turned along the wall
            for (across, down) in [(0.0, 0.0), (0.0, 0.3), (0.0, 0.6), (0.3, 0.0), (0.3, 0.6)] {
                let view = look_at(
                    &Point3::origin(),
                    &Point3::new(across * z, down, z),
                    &-Vector3::y(),
                );
                let w = measure(&wall, view);
                eprintln!(
                    "seed {seed}, wall {z} m, view ({across}, {down}): conditioning {:.1e}",
                    w.conditioning
                );
                assert!(
                    matches!(
                        w.degeneracy(&geometry_only),
                        Some(TrackFailure::Degenerate { .. })
                    ),
                    "seed {seed}: the wall {z} m away seen at ({across}, {down}) with λ = 0 is not \
                     degenerate: conditioning {:.1e}",
                    w.conditioning
                );
                assert_eq!(
                    w.degeneracy(&p),
                    None,
                    "the textured wall is held by its texture"
                );
            }
        }
        let r = measure(&room, orbit.poses[0]);
        eprintln!("seed {seed}: room {:.1e}", r.conditioning);
        assert!(
            r.conditioning > 4.0 * p.min_conditioning,
            "the room's conditioning {:.1e}",
            r.conditioning
        );
    }
}

/// A textured wall 2.7 and 4 m away over a floor, recorded by the Kinect model as the camera
/// steps 1 cm a frame along it: every frame is tracked and lies near the model (its proximity,
/// the share of its points within the noise model's distance of the model on its side, over
/// 0.9). The sensor's depth steps (21 and 46 mm there) tilt the per-pixel normals beyond the
/// association's 20° on many points: the agreement, which asks for that angle too, read 0.41 at
/// 2.7 m, and after a gap on a walk its floor refused the right pose (NOTES 158).
#[test]
fn a_far_wall_lies_near_its_model_despite_the_depth_steps() {
    use dynamap::slam::synthetic::kinect::KinectModel;
    use dynamap::slam::synthetic::motion::look_at;
    use nalgebra::{Point3, Vector3};

    let cam = Camera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
    let model = KinectModel {
        seed: 8,
        ..KinectModel::default()
    };
    let recorder = model.recorder(&cam);
    for z in [2.7, 4.0] {
        let wall = wall_over_floor(z);
        let mut steps = Trajectory::default();
        for k in 0..8 {
            let x = 0.01 * k as f64;
            let eye = Point3::new(x, 0.0, 0.0);
            let view = look_at(&eye, &Point3::new(x, 0.3, z), &-Vector3::y());
            steps.push(k as f64 / 30.0, view);
        }
        let mut slam = RigidSlam::new(cam, SlamParams::default(), steps.poses[0]);
        let mut lowest = f64::INFINITY;
        for k in 0..steps.poses.len() {
            let f = recorder.capture(&wall, &steps, k);
            let report = slam.process(&f.depth, Some(&f.color));
            if k == 0 {
                continue;
            }
            assert!(
                report.failure().is_none(),
                "{z} m, frame {k}: {:?}",
                report.outcome
            );
            let off = (report.pose.translation.vector - steps.poses[k].translation.vector).norm();
            assert!(off < 0.02, "{z} m, frame {k}: {off:.3} m off");
            lowest = lowest.min(report.proximity);
        }
        eprintln!("wall {z} m: lowest proximity {lowest:.3}");
        assert!(lowest > 0.9, "wall {z} m: proximity {lowest:.3}");
    }
}

/// [`a_plain_wall_is_degenerate_and_a_textured_one_is_tracked`] with one camera.
fn wall_slide(cam: Camera) {
    use dynamap::slam::synthetic::motion::look_at;
    use dynamap::slam::synthetic::scene::Shape;
    use dynamap::slam::synthetic::texture::Texture;
    use nalgebra::{Isometry3, Point3, Vector3};

    let at = |x: f64| {
        look_at(
            &Point3::new(x, 0.0, 0.0),
            &Point3::new(x, 0.0, 1.0),
            &-Vector3::y(),
        )
    };
    // the texture holds the slide only where the photometric term is on: with λ = 0 the
    // textured wall is as free as the plain one
    let textured = || Texture::random(4, 10.0, 40.0);
    for (texture, photometric, degenerate) in [
        (Texture::plain([0.6, 0.6, 0.6]), true, true),
        (textured(), true, false),
        (textured(), false, true),
    ] {
        let mut scene = Scene::default();
        scene.add(
            Shape::Plane { hx: 3.0, hy: 3.0 },
            Isometry3::translation(0.0, 0.0, 1.0),
            texture,
        );
        let mut params = SlamParams::default();
        if !photometric {
            params.tracker.photometric_weight = PhotometricWeight::Fixed(0.0);
        }
        let mut slam = RigidSlam::new(cam, params, at(0.0));
        let frame = |x: f64| {
            let mut r = render(&scene, &cam, &at(x));
            let raw = SensorNoise::default().apply_to(0, &mut r, cam.depth_scale);
            (raw, r.color)
        };
        let (d0, c0) = frame(0.0);
        assert!(slam.process(&d0, Some(&c0)).failure().is_none());
        // the first slide is weighed before any frame has measured the residuals' scales, the
        // next ones with the scales of the frame before (NOTES 115)
        for slide in [0.02, 0.04, 0.06] {
            let (d1, c1) = frame(slide);
            let report = slam.process(&d1, Some(&c1));
            if degenerate {
                let why = report.failure().expect("a plain wall was tracked");
                assert!(matches!(why, TrackFailure::Degenerate { .. }), "{why}");
                break;
            }
            assert!(report.failure().is_none(), "{:?}", report.outcome);
            let x = report.pose.translation.vector.x;
            assert!((x - slide).abs() < 0.005, "slid {x:.4} m of {slide}");
        }
    }
}
