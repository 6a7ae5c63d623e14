//! Gates on the real public data in `../shared/data` (built only with `--features real-data`; run by
//! `.ci/run`). Each test fails loudly when the data is missing.

use dynamap::slam::eval::{ate, rpe, Alignment, DeltaUnit, MAX_STAMP_DIFFERENCE};
use dynamap::slam::io::folder::FolderSequence;
use dynamap::slam::io::iclnuim::IclNuimSequence;
use dynamap::slam::io::images::{read_color, read_depth};
use dynamap::slam::io::trajectory::Trajectory;
use std::path::PathBuf;

fn data(rel: &str) -> PathBuf {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data")
        .join(rel);
    assert!(
        p.exists(),
        "{} is missing: these gates need ../shared/data",
        p.display()
    );
    p
}

/// evo 1.38.1 on the TUM fr1/xyz ground truth against RGBD-SLAM's estimates, full precision from
/// evo's Python API (the same numbers `evo_ape tum GT EST -a` / `-as` and
/// `evo_rpe tum GT EST -a --delta 1 --delta_unit f [--pose_relation angle_deg]` print rounded):
/// (estimate, APE SE3 rmse/mean/median/max, APE Sim3 rmse/max, RPE trans rmse/mean/median/max,
///  RPE deg rmse/mean/median/max, pairs)
#[allow(clippy::type_complexity)]
const EVO: [(&str, [f64; 4], [f64; 2], [f64; 4], [f64; 4], usize); 2] = [
    (
        "freiburg1_xyz-rgbdslam.txt",
        [
            0.013470088849733695,
            0.012024498709110232,
            0.011183186775061079,
            0.03475954589500904,
        ],
        [0.013389384904168217, 0.03484614485226119],
        [
            0.005764370848928318,
            0.004815609470203963,
            0.0041388577993644255,
            0.020865814532330103,
        ],
        [
            0.3536131610447985,
            0.3003065811400405,
            0.2621389996694454,
            1.6332960623334538,
        ],
        785,
    ),
    (
        "freiburg1_xyz-rgbdslam_drift.txt",
        [
            0.013470118951368277,
            0.01202451606220223,
            0.011183137957357257,
            0.034759897174092724,
        ],
        [0.013389416164851104, 0.034846485997036616],
        [
            0.005764378833030764,
            0.004815612031956734,
            0.004138810593404495,
            0.020865165925125582,
        ],
        [
            0.3536135361731567,
            0.3003084171178446,
            0.2621392221832407,
            1.633283747382841,
        ],
        785,
    ),
];

#[test]
fn ate_and_rpe_agree_with_evo() {
    let dir = data("rgbd/tum_trajectories");
    let gt = Trajectory::read_tum(dir.join("freiburg1_xyz-groundtruth.txt")).unwrap();
    for (name, ape, sim, rpe_t, rpe_r, pairs) in EVO {
        let est = Trajectory::read_tum(dir.join(name)).unwrap();
        let a = ate(&gt, &est, Alignment::Se3, MAX_STAMP_DIFFERENCE).unwrap();
        assert_eq!(a.pairs.len(), pairs, "{name}");
        let got = [a.stats.rmse, a.stats.mean, a.stats.median, a.stats.max];
        for (g, e) in got.iter().zip(ape) {
            assert!((g - e).abs() < 1e-6, "{name} APE {got:?} vs evo {ape:?}");
        }
        let s = ate(&gt, &est, Alignment::Sim3, MAX_STAMP_DIFFERENCE).unwrap();
        assert!(
            (s.stats.rmse - sim[0]).abs() < 1e-6 && (s.stats.max - sim[1]).abs() < 1e-6,
            "{name} Sim3"
        );
        let r = rpe(&gt, &est, 1.0, DeltaUnit::Frames, MAX_STAMP_DIFFERENCE).unwrap();
        let t = [
            r.translation.rmse,
            r.translation.mean,
            r.translation.median,
            r.translation.max,
        ];
        let d = [
            r.rotation_deg.rmse,
            r.rotation_deg.mean,
            r.rotation_deg.median,
            r.rotation_deg.max,
        ];
        for (g, e) in t.iter().zip(rpe_t) {
            assert!(
                (g - e).abs() < 1e-6,
                "{name} RPE translation {t:?} vs evo {rpe_t:?}"
            );
        }
        for (g, e) in d.iter().zip(rpe_r) {
            assert!(
                (g - e).abs() < 1e-6,
                "{name} RPE rotation {d:?} vs evo {rpe_r:?}"
            );
        }
    }
    // The ground truth against itself: zero.
    let z = ate(&gt, &gt, Alignment::Se3, MAX_STAMP_DIFFERENCE).unwrap();
    assert!(z.stats.max < 1e-9);
}

#[test]
fn every_loader_reads_the_real_frames() {
    // ICL-NUIM (negative fy), PNG
    let icl = IclNuimSequence::open(data("rgbd/iclnuim_lr_kt2_5frames")).unwrap();
    assert_eq!(icl.len(), 5);
    for i in 0..5 {
        let f = icl.load(i).unwrap();
        assert_eq!((f.depth.width, f.depth.height), (640, 480));
        assert!(
            f.depth.data.iter().filter(|&&d| d > 0).count() > 200_000,
            "frame {i}"
        );
    }
    // A plain folder with an Open3D camera JSON, JPEG colour, millimetre depth
    let ps = FolderSequence::open(data("rgbd/primesense_5frames"), None).unwrap();
    assert_eq!(
        (ps.len(), ps.camera.fx, ps.camera.depth_scale),
        (5, 525.0, 1000.0)
    );
    for i in 0..5 {
        let f = ps.load(i).unwrap();
        let valid: Vec<f64> = f
            .depth
            .data
            .iter()
            .filter(|&&d| d > 0)
            .map(|&d| d as f64 / 1000.0)
            .collect();
        assert!(valid.len() > 100_000);
        let mean = valid.iter().sum::<f64>() / valid.len() as f64;
        assert!((0.5..5.0).contains(&mean), "frame {i}: mean depth {mean} m");
        assert_eq!(f.color.unwrap().width, 640);
    }
    // Single TUM frames (fr2, fr3), 16-bit depth with scale 5000
    for (d, c) in [
        (
            "rgbd/tum_fr2_2frames/1_depth.png",
            "rgbd/tum_fr2_2frames/1.png",
        ),
        (
            "rgbd/tum_fr3_long_office_1frame/TUM_depth.png",
            "rgbd/tum_fr3_long_office_1frame/TUM_color.png",
        ),
    ] {
        let depth = read_depth(data(d)).unwrap();
        let color = read_color(data(c)).unwrap();
        assert_eq!(
            (depth.width, depth.height, color.width, color.height),
            (640, 480, 640, 480)
        );
        let valid: Vec<f64> = depth
            .data
            .iter()
            .filter(|&&v| v > 0)
            .map(|&v| v as f64 / 5000.0)
            .collect();
        let mean = valid.iter().sum::<f64>() / valid.len() as f64;
        assert!((0.5..6.0).contains(&mean), "{d}: mean depth {mean} m");
    }
    // Wrong kinds of file are errors naming the file, not panics.
    let e = read_depth(data("rgbd/tum_fr2_2frames/1.png")).unwrap_err();
    assert!(
        e.to_string().contains("1.png") && e.to_string().contains("16-bit"),
        "{e}"
    );
}

/// Median |z − D_b| after back-projecting ICL-NUIM frame `a` with `cam` and moving it by `rel` into
/// frame `b` (nearest pixel), over every other pixel.
fn reprojection_median(
    icl: &IclNuimSequence,
    a: usize,
    b: usize,
    cam: &dynamap::slam::Camera,
    rel: &nalgebra::Isometry3<f64>,
) -> (f64, usize) {
    let (fa, fb) = (icl.load(a).unwrap(), icl.load(b).unwrap());
    let mut residuals = Vec::new();
    for v in (0..480).step_by(2) {
        for u in (0..640).step_by(2) {
            let d = fa.depth.at(u, v);
            if d == 0 {
                continue;
            }
            let p = rel * cam.back_project(u as f64, v as f64, d as f64 / cam.depth_scale);
            let Some((ub, vb)) = cam.project_to_pixel(&p) else {
                continue;
            };
            let db = fb.depth.at(ub, vb);
            if db > 0 {
                residuals.push((p.z - db as f64 / cam.depth_scale).abs());
            }
        }
    }
    residuals.sort_by(f64::total_cmp);
    (
        residuals
            .get(residuals.len() / 2)
            .copied()
            .unwrap_or(f64::INFINITY),
        residuals.len(),
    )
}

/// Back-projects ICL-NUIM frame 1 with its ground-truth pose, re-projects it into frame 2 and compares
/// with frame 2's depth, which checks intrinsics (the negative fy), depth scale and pose convention on
/// data the project did not make.
///
/// Measured with the ground-truth poses: 4.2 cm median (1→2) and 3.3 cm (2→1). The issue asked for
/// under 1 cm, which these poses do not allow: the images are rigidly consistent with our conventions,
/// but the poses are not with the images. Registering frame 1 against frame 2 with our own tracker,
/// starting from the ground truth, moves the relative pose by about 0.6° and brings the median to
/// about 2 mm (Open3D's point-to-plane ICP finds 0.59° and 1.8 mm; frames 4→5 need 1.2° and 5 cm, after which
/// the median is 1 mm).
/// The test asserts all of it: with the ground truth under 5 cm, with fy's sign flipped or the poses
/// read as world-to-camera over 20 cm and five times that, and after a correction under 1.5° and 8 cm, under 5 mm.
#[test]
fn iclnuim_frames_reproject_onto_the_same_surface() {
    let icl = IclNuimSequence::open(data("rgbd/iclnuim_lr_kt2_5frames")).unwrap();
    let cam = icl.camera;
    let mut flipped = cam;
    flipped.fy = -cam.fy;
    for (a, b) in [(0, 1), (1, 0), (3, 4)] {
        let rel = icl.poses[b].inverse() * icl.poses[a];
        let (median, n) = reprojection_median(&icl, a, b, &cam, &rel);
        assert!(n > 10_000, "{a}->{b}: only {n} overlapping pixels");
        assert!(median < 0.05, "{a}->{b}: median depth residual {median} m");
        let (wrong_fy, _) = reprojection_median(&icl, a, b, &flipped, &rel);
        let inverted = icl.poses[b] * icl.poses[a].inverse();
        let (wrong_pose, _) = reprojection_median(&icl, a, b, &cam, &inverted);
        assert!(
            wrong_fy.min(wrong_pose) > 0.2f64.max(5.0 * median),
            "{a}->{b}: wrong conventions give {wrong_fy} and {wrong_pose} m"
        );
        let refined = icl.poses[b].inverse() * register_against(&icl, a, b);
        let correction = rel.inverse() * refined;
        let (dt, dr) = (
            correction.translation.vector.norm(),
            correction.rotation.angle().to_degrees(),
        );
        let (median_refined, _) = reprojection_median(&icl, a, b, &cam, &refined);
        eprintln!(
            "ICL-NUIM {}->{}: median {median:.4} m at the ground truth, {median_refined:.4} m after \
             a {dr:.3}° / {dt:.4} m correction",
            a + 1,
            b + 1
        );
        assert!(
            dr < 1.5 && dt < 0.08 && median_refined < 0.005,
            "{a}->{b}: correction {dr}° / {dt} m leaves a median of {median_refined} m"
        );
    }
}

/// Camera-to-world pose of ICL-NUIM frame `a` registered by the rigid tracker against a model fused
/// from frame `b` alone at its ground-truth pose, starting from `a`'s ground truth.
fn register_against(icl: &IclNuimSequence, a: usize, b: usize) -> nalgebra::Isometry3<f64> {
    use dynamap::slam::preprocess::{PreprocessParams, Preprocessor};
    use dynamap::slam::rigid::tracker::{ModelPyramid, Tracker, TrackerParams};
    use dynamap::slam::tsdf::RaycastMaps;
    let cam = icl.camera;
    let vol = fuse_iclnuim_at_ground_truth(icl, &[b]);
    let mut maps = RaycastMaps::new();
    vol.raycast(&cam, &icl.poses[b], &mut maps);
    let mut model = ModelPyramid::new(&cam, 3, 0);
    model.update(&maps, &icl.poses[b]);
    let fa = icl.load(a).unwrap();
    let mut pre = Preprocessor::new(cam, PreprocessParams::default());
    let live = pre.process(&fa.depth, fa.color.as_ref());
    let mut tracker = Tracker::new(TrackerParams {
        iterations: vec![20, 20, 20],
        strides: vec![1, 1, 1],
        ..TrackerParams::default()
    });
    let out = tracker.track(live, &model, &icl.poses[a]);
    assert!(out.failure.is_none(), "{a} against {b}: {:?}", out.failure);
    out.pose
}

/// A sequence rendered along the real fr1/xyz trajectory reads back through the TUM reader with its
/// ground truth intact: ATE of the written ground truth against the file's is zero, and every frame
/// loads with the written intrinsics.
#[test]
fn a_sequence_rendered_along_fr1_xyz_keeps_its_ground_truth() {
    use dynamap::slam::io::tum::TumSequence;
    use dynamap::slam::synthetic::{motion, noise::SensorNoise, scene::Scene, sequence};
    let gt =
        Trajectory::read_tum(data("rgbd/tum_trajectories/freiburg1_xyz-groundtruth.txt")).unwrap();
    let dir = std::env::temp_dir().join(format!("dynamap-fr1-{}", std::process::id()));
    let cam = dynamap::slam::Camera::new(131.25, 131.25, 79.5, 59.5, 160, 120);
    let traj = motion::resample(&gt, 20, 30.0);
    sequence::write_rigid(
        &dir,
        &Scene::room(3),
        &cam,
        &traj,
        &motion::world_to_room(&gt),
        &sequence::Sensor::Ideal(SensorNoise::default()),
        |_| {},
    )
    .unwrap();
    let seq = TumSequence::open(&dir).unwrap();
    assert_eq!(seq.len(), 20);
    let written = seq.groundtruth.clone().unwrap();
    let a = ate(&gt, &written, Alignment::None, MAX_STAMP_DIFFERENCE).unwrap();
    assert_eq!(a.pairs.len(), 20);
    assert!(
        a.stats.max < 1e-9,
        "ATE of the ground truth against itself: {:?}",
        a.stats
    );
    for i in 0..seq.len() {
        let f = seq.load(i).unwrap();
        assert!((f.timestamp - written.stamps[i]).abs() < 1e-6);
        assert!(
            f.depth.data.iter().filter(|&&d| d > 0).count() > 10_000,
            "frame {i} sees the room"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Reads an Open3D `.log` trajectory: per frame a line of three ids, then a 4×4 matrix.
fn read_open3d_log(path: &std::path::Path) -> Vec<nalgebra::Matrix4<f64>> {
    let text = std::fs::read_to_string(path).unwrap();
    let rows: Vec<Vec<f64>> = text
        .lines()
        .map(|l| l.split_whitespace().map(|t| t.parse().unwrap()).collect())
        .collect();
    rows.chunks(5)
        .map(|c| nalgebra::Matrix4::from_fn(|i, j| c[1 + i][j]))
        .collect()
}

/// The 5 consecutive PrimeSense frames tracked by our pipeline: relative poses within 5 mm and 0.3°
/// of Open3D's estimates (its trajectory.log, a peer's estimate rather than ground truth).
#[test]
fn primesense_frames_track_like_open3d() {
    use dynamap::slam::rigid::{RigidSlam, SlamParams};
    let dir = data("rgbd/primesense_5frames");
    let seq = FolderSequence::open(&dir, None).unwrap();
    let theirs = read_open3d_log(&dir.join("trajectory.log"));
    let mut slam = RigidSlam::new(
        seq.camera,
        SlamParams::default(),
        nalgebra::Isometry3::identity(),
    );
    let mut ours = Vec::new();
    for i in 0..seq.len() {
        let f = seq.load(i).unwrap();
        let r = slam.process(&f.depth, f.color.as_ref());
        assert!(r.failure().is_none(), "frame {i}: {:?}", r.outcome);
        ours.push(r.pose.to_homogeneous());
    }
    for i in 0..seq.len() - 1 {
        let a = ours[i].try_inverse().unwrap() * ours[i + 1];
        let b = theirs[i].try_inverse().unwrap() * theirs[i + 1];
        let d = a.try_inverse().unwrap() * b;
        let dt = d.fixed_view::<3, 1>(0, 3).norm();
        let dr = ((d.fixed_view::<3, 3>(0, 0).trace() - 1.0) / 2.0)
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees();
        eprintln!(
            "PrimeSense frames {i}->{}: {dt:.4} m, {dr:.3}° from Open3D",
            i + 1
        );
        assert!(
            dt < 0.005 && dr < 0.3,
            "frames {i}->{}: {dt:.4} m, {dr:.3}° from Open3D",
            i + 1
        );
    }
}

/// ICL-NUIM frames `which` preprocessed and fused at their ground-truth poses (depth up to 6 m).
fn fuse_iclnuim_at_ground_truth(
    icl: &IclNuimSequence,
    which: &[usize],
) -> dynamap::slam::tsdf::TsdfVolume {
    use dynamap::slam::preprocess::{PreprocessParams, Preprocessor};
    use dynamap::slam::tsdf::{TsdfParams, TsdfVolume};
    let mut pre = Preprocessor::new(icl.camera, PreprocessParams::default());
    let mut vol = TsdfVolume::new(TsdfParams {
        max_depth: 6.0,
        ..TsdfParams::default()
    });
    for &i in which {
        let f = icl.load(i).unwrap();
        let levels = pre.process(&f.depth, f.color.as_ref());
        vol.integrate(
            &levels[0].depth,
            &levels[0].normals,
            f.color.as_ref(),
            &icl.camera,
            &icl.poses[i],
        )
        .unwrap();
    }
    vol
}

/// The 5 ICL-NUIM frames fused at their ground-truth poses: each frame's depth against the model
/// raycast at its pose.
#[test]
fn iclnuim_frames_fuse_at_their_ground_truth_poses() {
    use dynamap::slam::tsdf::RaycastMaps;
    let icl = IclNuimSequence::open(data("rgbd/iclnuim_lr_kt2_5frames")).unwrap();
    let cam = icl.camera;
    let all: Vec<usize> = (0..icl.len()).collect();
    let vol = fuse_iclnuim_at_ground_truth(&icl, &all);
    let frames: Vec<_> = all.iter().map(|&i| icl.load(i).unwrap()).collect();
    let mut maps = RaycastMaps::new();
    for (i, (f, pose)) in frames.iter().zip(&icl.poses).enumerate() {
        vol.raycast(&cam, pose, &mut maps);
        let mut r: Vec<f64> = f
            .depth
            .data
            .iter()
            .zip(&maps.depth.data)
            .filter(|(d, m)| **d > 0 && **m > 0.0)
            .map(|(d, m)| (*d as f64 / cam.depth_scale - *m as f64).abs())
            .collect();
        r.sort_by(f64::total_cmp);
        let median = r[r.len() / 2];
        eprintln!(
            "ICL-NUIM frame {}: median |depth − model| {median:.4} m over {} pixels",
            i + 1,
            r.len()
        );
        assert!(
            r.len() > 100_000 && median < 0.01,
            "frame {}: median {median} m",
            i + 1
        );
    }
}

/// The two TUM fr2 frames (fr2 intrinsics) track without failure.
#[test]
fn tum_fr2_frames_track() {
    use dynamap::slam::rigid::{RigidSlam, SlamParams};
    let cam = dynamap::slam::Camera::new(520.9, 521.0, 325.1, 249.7, 640, 480);
    let mut slam = RigidSlam::new(cam, SlamParams::default(), nalgebra::Isometry3::identity());
    for k in [1, 2] {
        let d = read_depth(data(&format!("rgbd/tum_fr2_2frames/{k}_depth.png"))).unwrap();
        let c = read_color(data(&format!("rgbd/tum_fr2_2frames/{k}.png"))).unwrap();
        let r = slam.process(&d, Some(&c));
        assert!(r.failure().is_none(), "frame {k}: {:?}", r.outcome);
        eprintln!("fr2 frame {k}: pose {:?}", r.pose.translation.vector);
    }
}

/// DeepDeform's camera (its pairs' intrinsics.txt; depth in millimetres).
fn deepdeform_camera() -> dynamap::slam::camera::Camera {
    let mut camera =
        dynamap::slam::camera::Camera::new(575.548, 577.46, 323.172, 236.417, 640, 480);
    camera.depth_scale = 1000.0;
    camera
}

/// A DeepDeform pair's depth frame `name` (in `dir/depth`), metres.
fn deepdeform_depth(
    dir: &std::path::Path,
    name: &str,
    camera: &dynamap::slam::camera::Camera,
) -> dynamap::slam::image::DepthImage {
    let raw = read_depth(dir.join("depth").join(name)).unwrap();
    let mut out = dynamap::slam::image::Image::new(0, 0);
    dynamap::slam::image::depth_to_metres(&raw, camera, &mut out);
    out
}

/// DeepDeform seq258 (a shirt moved about 23 cm between frames 0 and 110): the scene flow of the
/// masked shirt's pixels against the ground truth, EPE 3D under issue 26's 1.5 cm (1.12 cm seen
/// on 2026-12-04; 1.82 before NOTES 95; zero flow scores 23 cm), and 97 % of the pixels within
/// 5 cm. Without colour features the outline search starts it, under 2 cm (1.41 cm seen).
#[test]
fn deepdeform_shirt_scene_flow_is_within_one_and_a_half_centimetres() {
    use dynamap::slam::eval::epe3d;
    use dynamap::slam::image::Image;
    use dynamap::slam::io::flow::read_flow;
    use dynamap::slam::io::images::read_mask;
    use dynamap::slam::nonrigid::{register_frames, FrameSettings, FrameVerdict, FrameView};
    use nalgebra::Vector3;

    let dir = data("nonrigid/deepdeform_2pairs/train/seq258");
    let camera = deepdeform_camera();
    let metres = |name: &str| deepdeform_depth(&dir, name, &camera);
    let (d0, d1) = (metres("000000.png"), metres("000110.png"));
    let (c0, c1) = (
        read_color(dir.join("color/000000.jpg")).unwrap(),
        read_color(dir.join("color/000110.jpg")).unwrap(),
    );
    let mask = read_mask(dir.join("mask/000000_shirt.png")).unwrap();
    let gt: Image<[f32; 3]> = read_flow(dir.join("scene_flow/shirt_000000_000110.sflow")).unwrap();
    // the default (colour features start it), then without features: the outline search
    // starts it, a check of the search on real data it was not shaped on (NOTES 147: 1.41 cm)
    let plain = FrameSettings {
        features: None,
        ..FrameSettings::default()
    };
    for (settings, bound) in [(&FrameSettings::default(), 0.015), (&plain, 0.02)] {
        let reg = register_frames(
            &FrameView::new(&camera, &d0, Some(&c0), Some(&mask)),
            &FrameView::new(&camera, &d1, Some(&c1), None),
            settings,
        )
        .unwrap();
        let flow = reg.scene_flow(d0.width, d0.height);
        let v = |p: &[f32; 3]| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        let (mut ours, mut truth) = (Vec::new(), Vec::new());
        for (i, g) in gt.data.iter().enumerate() {
            if mask.data[i] && g.iter().all(|c| c.is_finite()) && flow.data[i][0].is_finite() {
                ours.push(v(&flow.data[i]));
                truth.push(v(g));
            }
        }
        assert!(ours.len() > 50_000, "{} scored pixels", ours.len());
        lies_as_close_as_the_ground_truth(&reg, &gt, &FrameView::new(&camera, &d1, None, None));
        let zero = epe3d(&vec![Vector3::zeros(); truth.len()], &truth, None);
        let epe = epe3d(&ours, &truth, None);
        let start = reg.start.name();
        println!(
            "{start}: EPE {} m (zero flow {} m)",
            epe.stats.mean, zero.stats.mean
        );
        assert!(zero.stats.mean > 0.2, "zero flow {}", zero.stats.mean);
        assert!(
            epe.stats.mean < bound && epe.within_5cm > 0.97,
            "{start}: EPE {} m, {} within 5 cm",
            epe.stats.mean,
            epe.within_5cm
        );
        assert_eq!(reg.verdict(), FrameVerdict::Registered);
        let expected = if settings.features.is_some() {
            "features"
        } else {
            "outline"
        };
        assert_eq!(start, expected);
    }
}

/// The registered shirt lies on the target's surface (median distance to its nearest point) no
/// farther than the source moved by DeepDeform's ground-truth flow does, with a tenth of a
/// millimetre to spare for rounding: the data's own answer is the floor that depth noise leaves
/// (2.53 mm seen, ours 2.39 mm), and it is why issue 26's 1 mm is out of reach on this pair.
fn lies_as_close_as_the_ground_truth(
    reg: &dynamap::slam::nonrigid::FrameRegistration,
    gt: &dynamap::slam::image::Image<[f32; 3]>,
    target: &dynamap::slam::nonrigid::FrameView<'_>,
) {
    use dynamap::slam::nonrigid::{frame_points, median_distance};
    let truth = reg.points_moved_by(gt);
    let surface = frame_points(target);
    let ours = median_distance(&reg.warped, &surface).unwrap();
    let floor = median_distance(&truth, &surface).unwrap();
    println!("median distance to the target: {ours} m (ground truth {floor} m)");
    assert!(
        ours <= floor + 1e-4,
        "{ours} m against the ground truth's {floor} m"
    );
}

/// DeepDeform's test pair seq017 (300 → 600; a plain shirt lifted about 45 cm, no mask, the
/// source's graph nodes given): the object taken from the nodes is the shirt's size; no colour
/// feature match agrees, the outline search starts it (NOTES 147), and it is registered with a
/// median distance to the target's surface under 1 cm (4.0 mm seen, 224 mm before). Without
/// the search it is not registered, and says so (the verdict agrees with the distance).
#[test]
fn deepdeform_seq017_is_started_by_its_outline_and_registered() {
    use dynamap::slam::io::deepdeform::read_graph_nodes;
    use dynamap::slam::nonrigid::{
        frame_points, mask_near_nodes, median_distance, register_frames, FrameSettings, FrameStart,
        FrameVerdict, FrameView,
    };

    let dir = data("nonrigid/deepdeform_2pairs/test/seq017");
    let camera = deepdeform_camera();
    let metres = |name: &str| deepdeform_depth(&dir, name, &camera);
    let (d0, d1) = (metres("000300.png"), metres("000600.png"));
    let nodes = read_graph_nodes(
        dir.join("graph_nodes/5dbd7c9104df0300f329f294_shirt_000300_000600_geodesic_0.05.bin"),
    )
    .unwrap();
    assert_eq!(nodes.len(), 109);
    let settings = FrameSettings::default();
    let mask = mask_near_nodes(&camera, &d0, &nodes, settings.graph.spacing);
    let pixels = mask.data.iter().filter(|&&m| m).count();
    // the shirt covers about a tenth of the frame
    assert!((15_000..60_000).contains(&pixels), "{pixels} object pixels");
    let (c0, c1) = (
        read_color(dir.join("color/000300.jpg")).unwrap(),
        read_color(dir.join("color/000600.jpg")).unwrap(),
    );
    let target = FrameView::new(&camera, &d1, Some(&c1), None);
    let source = FrameView::new(&camera, &d0, Some(&c0), Some(&mask));
    let surface = frame_points(&target);
    let local = FrameSettings {
        outline_start: false,
        ..FrameSettings::default()
    };
    for settings in [&settings, &local] {
        let reg = register_frames(&source, &target, settings).unwrap();
        let after = median_distance(&reg.warped, &surface).unwrap();
        let before = median_distance(&reg.points, &surface).unwrap();
        println!(
            "seq017 ({}): {:?}, median distance {before} m -> {after} m",
            reg.start.name(),
            reg.verdict()
        );
        match reg.verdict() {
            FrameVerdict::Registered => assert!(after < 0.01, "registered at {after} m"),
            FrameVerdict::NotRegistered { .. } => {
                assert!(after >= 0.01, "not registered at {after} m")
            }
            // on a surface, flush in it or slid along it: the distance says nothing
            FrameVerdict::LiesFlush(_) | FrameVerdict::ColourDisagrees(_) => {}
        }
        if settings.outline_start {
            assert!(
                matches!(reg.start, FrameStart::Outline(_)),
                "{:?}",
                reg.start
            );
            assert_eq!(reg.verdict(), FrameVerdict::Registered);
            assert!(before > 0.1, "{before} m before");
        }
    }
}

/// The camel's pose `i` registered onto pose `j` by `register_mesh_pair`, both meshes, and the
/// mean error against the map `i_to_j` (a share of the target's diagonal).
fn camel_pair(
    i: usize,
    j: usize,
) -> (
    dynamap::slam::nonrigid::SurfaceRegistration,
    dynamap::slam::mesh::Mesh,
    dynamap::slam::mesh::Mesh,
    f64,
) {
    use dynamap::slam::eval::VertexMap;
    use dynamap::slam::io::meshes::read_mesh;
    use dynamap::slam::nonrigid::{bounding_diagonal, mesh_points, register_mesh_pair, Seeding};

    let dir = data("nonrigid/camel_gallop");
    let mesh = |k: usize| read_mesh(dir.join(format!("camel-gallop-{k:02}.off"))).unwrap();
    let (source, target) = (mesh(i), mesh(j));
    let reg = register_mesh_pair(&source, &target, &Seeding::default()).unwrap();
    let (sp, tp) = (mesh_points(&source).0, mesh_points(&target).0);
    let map = VertexMap::read(dir.join(format!("maps/{i}_to_{j}")), sp.len(), tp.len()).unwrap();
    let error = map.error(&reg.points, &tp, bounding_diagonal(&tp)).mean;
    (reg, source, target, error)
}

/// The camel's pose 1 onto pose 3 registers, and its error against the given vertex map is that
/// of BENCHMARKS.md's table (0.75 % of the target's diagonal); onto the half of pose 3 on one
/// side, it lies on the half but carries twice its area, and is not registered.
#[test]
fn camel_meshes_register_onto_another_pose_and_not_onto_half_of_it() {
    use dynamap::slam::mesh::Mesh;
    use dynamap::slam::nonrigid::{mesh_points, register_mesh_pair, Seeding, SurfaceVerdict};

    let (reg, source, target, error) = camel_pair(1, 3);
    let tp = mesh_points(&target).0;
    println!("1 -> 3: {:?}, mean error {error}", reg.fit);
    assert_eq!(reg.verdict(), SurfaceVerdict::Registered);
    assert!(error < 0.01, "{error}");
    // the vertices on the low side of the longest axis' median, and the triangles among them
    let axis = (0..3)
        .max_by(|&a, &b| {
            let extent = |k: usize| {
                tp.iter().map(|p| p[k]).fold(f64::NEG_INFINITY, f64::max)
                    - tp.iter().map(|p| p[k]).fold(f64::INFINITY, f64::min)
            };
            extent(a).total_cmp(&extent(b))
        })
        .unwrap();
    let mut along: Vec<f64> = tp.iter().map(|p| p[axis]).collect();
    let mid = along.len() / 2;
    let cut = *along.select_nth_unstable_by(mid, f64::total_cmp).1;
    let kept: Vec<bool> = tp.iter().map(|p| p[axis] <= cut).collect();
    let mut index = vec![u32::MAX; tp.len()];
    let mut half = Mesh::default();
    for (k, v) in target.vertices.iter().enumerate().filter(|(k, _)| kept[*k]) {
        index[k] = half.vertices.len() as u32;
        half.vertices.push(*v);
    }
    half.faces = target
        .faces
        .iter()
        .filter(|f| f.iter().all(|&v| kept[v as usize]))
        .map(|f| f.map(|v| index[v as usize]))
        .collect();
    let reg = register_mesh_pair(&source, &half, &Seeding::default()).unwrap();
    println!("1 -> half of 3: {:?}", reg.fit);
    assert!(reg.fit.on_target > 0.9, "{:?}", reg.fit);
    assert!(
        matches!(reg.verdict(), SurfaceVerdict::NotRegistered(_)),
        "{:?}",
        reg.fit
    );
}

/// The camel map 7 → 1, the worst one way (2.64 % mean error): the way back, 1 onto 7, lies
/// closer to its target, and where it places the source the error is under 1 % (NOTES 189).
#[test]
fn camel_map_7_to_1_takes_the_way_back_and_lands_within_one_percent() {
    use dynamap::slam::nonrigid::SurfaceVerdict;

    let (reg, _, _, error) = camel_pair(7, 1);
    println!(
        "7 -> 1: mean error {error}, placed back {}",
        reg.placed_back
    );
    assert_eq!(reg.verdict(), SurfaceVerdict::Registered);
    assert!(reg.placed_back);
    assert!(error < 0.01, "{error}");
}

/// The camel onto a copy of itself whose vertices are moved at random by up to 0.87 % of its
/// diagonal along each axis (0.5 % standard deviation): a right registration moves its points
/// by about the noise, and the way back adds as much again, so the round trip comes back more
/// than its displacement off. The noise floor (twice the fit's median distance, module
/// `round_trip`) is what keeps it registered: with the spacing's floor alone it is refused
/// (NOTES 188).
#[test]
fn camel_meshes_register_onto_a_noisy_copy_of_themselves() {
    use dynamap::slam::io::meshes::read_mesh;
    use dynamap::slam::nonrigid::{
        bounding_diagonal, mesh_points, register_mesh_pair, Seeding, SurfaceVerdict,
    };

    let source = read_mesh(data("nonrigid/camel_gallop").join("camel-gallop-03.off")).unwrap();
    let d = bounding_diagonal(&mesh_points(&source).0) as f32;
    let mut state = 0x9e37_79b9_7f4a_7c15_u64;
    let mut uniform = || {
        // splitmix64, mapped to [-1, 1)
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f32 / (1u64 << 52) as f32 - 1.0
    };
    let mut noisy = source.clone();
    noisy.normals.clear();
    for v in &mut noisy.vertices {
        for k in 0..3 {
            v[k] += 0.005 * 3f32.sqrt() * d * uniform();
        }
    }
    let reg = register_mesh_pair(&source, &noisy, &Seeding::default()).unwrap();
    let trip = reg.round_trip.expect("a round trip");
    println!("3 -> noisy 3: {:?}, {trip:?}", reg.fit);
    assert_eq!(reg.verdict(), SurfaceVerdict::Registered);
    assert!(
        trip.ratio() > 0.35 && trip.mean > 0.05 * reg.fit.tolerance,
        "{trip:?}"
    );
}

/// The dense Schur solver with `bal::options`, as the example runs it with
/// `--linear-solver schur-dense`.
fn solve_bal(
    data: &dynamap::residuals::bal::BalProblem,
    max_iterations: usize,
) -> dynamap::solver::Summary {
    use dynamap::solver::{LinearSolverKind, Solver};
    let mut solve = data.build(None).unwrap();
    Solver::new(dynamap::residuals::bal::options(
        LinearSolverKind::SchurDense,
        max_iterations,
    ))
    .solve(&mut solve.problem)
    .unwrap()
}

/// BAL's ladybug problem 49-7776: the initial cost matches the reference to 9 digits (SOURCE.txt:
/// 8.50912460680839605629e+05) and 50 Levenberg-Marquardt iterations with the dense Schur solver
/// reach Ceres 2.1's DENSE_SCHUR cost after 50 (13344.254795935909 here; ours, with Ceres'
/// damping since NOTES 76, 13344.254795962903) to 1e-6 relative, or lower.
#[test]
fn bal_ladybug_reaches_the_reference_cost_in_50_iterations() {
    use dynamap::residuals::bal;
    let data = bal::file::read(data("bal/problem-49-7776-pre.txt")).unwrap();
    assert_eq!(
        (data.cameras.len(), data.points.len()),
        (49, 7776),
        "ladybug's size"
    );
    let reference = 850_912.460_680_839_6;
    assert!(
        (data.cost() - reference).abs() < 1e-9 * reference,
        "initial cost {}",
        data.cost()
    );
    let summary = solve_bal(&data, 50);
    assert!((summary.initial_cost - reference).abs() < 1e-9 * reference);
    assert!(summary.num_iterations() <= 50);
    let ceres = 13_344.254_795_935_909;
    assert!(
        summary.final_cost <= ceres * (1.0 + 1e-6),
        "final cost {}",
        summary.final_cost
    );
}

/// dubrovnik-3-7 (3 cameras, 7 points, 19 observations: fewer residuals than unknowns) is solved
/// exactly: its initial cost matches SOURCE.txt and LM drives the cost below 1e-12.
#[test]
fn bal_dubrovnik_converges_to_zero_cost() {
    use dynamap::residuals::bal;
    let data = bal::file::read(data("bal/dubrovnik-3-7-pre.txt")).unwrap();
    assert!((data.cost() - 2764.219984422157).abs() < 1e-9 * 2764.22);
    let summary = solve_bal(&data, 100);
    assert!(summary.final_cost < 1e-12, "{}", summary.table());
}

/// Issue 26, point 3: a pair that barely moves must not get worse. DeepDeform seq258's masked
/// shirt registered onto its own frame, and onto that frame with every depth 2 mm farther: the
/// warped shirt ends no farther from the target's surface than it started (within 0.5 mm; the
/// depth's quantisation at 1 m is 1 mm), within 1 mm of it and, moved, at most half as far as
/// before; its motion is the 0 or 2 mm to within 1 mm, and the verdict says registered (seen:
/// 0 → 0.07 mm and 2.03 → 0.07 mm).
#[test]
fn deepdeform_a_pair_that_barely_moves_does_not_get_worse() {
    use dynamap::slam::io::images::read_mask;
    use dynamap::slam::nonrigid::{
        frame_points, median_distance, register_frames, FrameSettings, FrameVerdict, FrameView,
    };

    let dir = data("nonrigid/deepdeform_2pairs/train/seq258");
    let camera = deepdeform_camera();
    let d0 = deepdeform_depth(&dir, "000000.png", &camera);
    let c0 = read_color(dir.join("color/000000.jpg")).unwrap();
    let mask = read_mask(dir.join("mask/000000_shirt.png")).unwrap();
    let mut farther = d0.clone();
    farther
        .data
        .iter_mut()
        .filter(|z| **z > 0.0)
        .for_each(|z| *z += 0.002);
    for (name, target_depth, shift) in [("itself", &d0, 0.0), ("2 mm farther", &farther, 0.002)] {
        let target = FrameView::new(&camera, target_depth, Some(&c0), None);
        let reg = register_frames(
            &FrameView::new(&camera, &d0, Some(&c0), Some(&mask)),
            &target,
            &FrameSettings::default(),
        )
        .unwrap();
        let surface = frame_points(&target);
        let after = median_distance(&reg.warped, &surface).unwrap();
        let before = median_distance(&reg.points, &surface).unwrap();
        let mut moved: Vec<f64> = reg
            .points
            .iter()
            .zip(&reg.warped)
            .map(|(p, w)| (w - p).norm())
            .collect();
        moved.sort_by(f64::total_cmp);
        let median_moved = moved[moved.len() / 2];
        println!(
            "onto {name}: median distance {before} m -> {after} m, median motion {median_moved} m"
        );
        assert_eq!(reg.verdict(), FrameVerdict::Registered, "onto {name}");
        assert!(
            after <= before + 0.0005,
            "onto {name}: {before} m -> {after} m"
        );
        // issue 26's target for masked real pairs: at most 1 mm, and at most half of before
        assert!(
            after <= 0.001 && (shift == 0.0 || after <= 0.5 * before),
            "onto {name}: {before} m -> {after} m"
        );
        assert!(
            (median_moved - shift).abs() < 0.001,
            "onto {name}: median motion {median_moved} m"
        );
    }
}

/// Every real frame here (ICL-NUIM's living room, Open3D's PrimeSense frames, TUM fr2 and fr3)
/// has the geometry to fix its pose: its conditioning (planes fitted to patches, NOTES 156, 157)
/// is above the degeneracy floor by a margin, so a floor chosen on rendered far walls does not
/// call a real room degenerate. The weakest, ICL-NUIM 1 (a wall with slivers of the ceiling and
/// a side wall, and a television), reads 4.4·10⁻³, 1.5× the floor; the rest 6.7·10⁻³ and more.
#[test]
fn real_frames_are_well_conditioned() {
    use dynamap::slam::preprocess::{PreprocessParams, Preprocessor};
    use dynamap::slam::rigid::{FrameConstraint, TrackerParams};
    use dynamap::slam::Camera;
    let floor = TrackerParams::default().min_conditioning;
    let mut frames = Vec::new();
    let icl = IclNuimSequence::open(data("rgbd/iclnuim_lr_kt2_5frames")).unwrap();
    for i in 0..icl.len() {
        let f = icl.load(i).unwrap();
        frames.push((format!("ICL-NUIM {i}"), icl.camera, f.depth, f.color));
    }
    let ps = FolderSequence::open(data("rgbd/primesense_5frames"), None).unwrap();
    for i in 0..ps.len() {
        let f = ps.load(i).unwrap();
        frames.push((format!("PrimeSense {i}"), ps.camera, f.depth, f.color));
    }
    let fr2 = Camera::new(520.9, 521.0, 325.1, 249.7, 640, 480);
    let fr3 = Camera::new(535.4, 539.2, 320.1, 247.6, 640, 480);
    for (name, cam, d, c) in [
        (
            "TUM fr2 1",
            fr2,
            "rgbd/tum_fr2_2frames/1_depth.png",
            "rgbd/tum_fr2_2frames/1.png",
        ),
        (
            "TUM fr2 2",
            fr2,
            "rgbd/tum_fr2_2frames/2_depth.png",
            "rgbd/tum_fr2_2frames/2.png",
        ),
        (
            "TUM fr3",
            fr3,
            "rgbd/tum_fr3_long_office_1frame/TUM_depth.png",
            "rgbd/tum_fr3_long_office_1frame/TUM_color.png",
        ),
    ] {
        let depth = read_depth(data(d)).unwrap();
        let color = read_color(data(c)).unwrap();
        frames.push((name.to_string(), cam, depth, Some(color)));
    }
    let mut weak = Vec::new();
    for (name, cam, depth, color) in &frames {
        let mut pre = Preprocessor::new(*cam, PreprocessParams::default());
        let k = FrameConstraint::of(pre.process(depth, color.as_ref()));
        eprintln!(
            "{name}: conditioning {:.2e}, texture {:.2}",
            k.conditioning, k.texture
        );
        if k.conditioning < 1.25 * floor {
            weak.push(format!("{name} {:.2e}", k.conditioning));
        }
    }
    assert!(
        weak.is_empty(),
        "near or below the floor {floor:.1e}: {weak:?}"
    );
}
