//! The sensor side end to end on the project's own renderings: normals of rendered primitives,
//! the preprocessing pyramid, and a written TUM sequence read back (with a damaged frame).

use dynamap::slam::camera::Camera;
use dynamap::slam::image::{normal_map, valid, vertex_map, Image};
use dynamap::slam::io::tum::TumSequence;
use dynamap::slam::preprocess::{PreprocessParams, Preprocessor};
use dynamap::slam::synthetic::motion::{self, Motion};
use dynamap::slam::synthetic::noise::SensorNoise;
use dynamap::slam::synthetic::render::render;
use dynamap::slam::synthetic::scene::{Scene, Shape};
use dynamap::slam::synthetic::sequence;
use dynamap::slam::synthetic::texture::Texture;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

/// Angle in degrees between the normals computed from the rendered depth and the true ones, over
/// pixels whose neighbourhood lies on the same object, away from its silhouette and from grazing views.
fn normal_errors(scene: &Scene, cam: &Camera, pose: &Isometry3<f64>) -> Vec<f64> {
    let r = render(scene, cam, pose);
    let (mut v, mut n) = (Image::filled(0, 0, [0.0; 3]), Image::filled(0, 0, [0.0; 3]));
    vertex_map(&r.depth, cam, &mut v);
    normal_map(&v, cam, &mut n);
    let mut out = Vec::new();
    for y in 2..cam.height - 2 {
        for x in 2..cam.width - 2 {
            let i = y * cam.width + x;
            let same = [i, i + 1, i + cam.width, i - 1, i - cam.width]
                .iter()
                .all(|&k| {
                    r.hits[k].map(|h| h.object) == r.hits[i].map(|h| h.object)
                        && r.hits[k].is_some()
                });
            // away from the sphere's rim, where neighbouring depths differ by more than 2 cm
            let smooth = [i + 1, i + cam.width]
                .iter()
                .all(|&k| (r.depth.data[k] - r.depth.data[i]).abs() < 0.02);
            // and not at grazing incidence (beyond 60°), where a pixel spans a long stretch of surface
            let facing = r.cos_incidence.data[i] > 0.5;
            if !same || !smooth || !facing || !valid(&n.data[i]) {
                continue;
            }
            let (a, b) = (
                Vector3::from(n.data[i]).cast::<f64>(),
                Vector3::from(r.normals.data[i]).cast::<f64>(),
            );
            out.push(a.dot(&b).clamp(-1.0, 1.0).acos().to_degrees());
        }
    }
    out
}

#[test]
fn normals_of_a_rendered_plane_and_sphere_are_within_one_degree() {
    let mut scene = Scene::default();
    let tilt = Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 2.0),
        UnitQuaternion::from_scaled_axis(Vector3::new(0.5, 0.3, 0.0)),
    );
    scene.add(
        Shape::Plane { hx: 3.0, hy: 3.0 },
        tilt,
        Texture::random(1, 2.0, 5.0),
    );
    scene.add(
        Shape::Sphere { radius: 0.4 },
        Isometry3::translation(0.2, 0.0, 1.4),
        Texture::random(2, 2.0, 5.0),
    );
    for cam in [
        Camera::tum_default(),
        Camera::new(481.2, -480.0, 319.5, 239.5, 640, 480),
    ] {
        let errors = normal_errors(&scene, &cam, &Isometry3::identity());
        assert!(errors.len() > 200_000, "{} pixels checked", errors.len());
        let worst = errors.iter().cloned().fold(0.0, f64::max);
        assert!(worst < 1.0, "fy = {}: worst normal error {worst}°", cam.fy);
    }
}

#[test]
fn the_pyramid_has_the_scaled_levels_and_filtered_noise() {
    let cam = Camera::new(262.5, 262.5, 159.5, 119.5, 320, 240);
    let pose = motion::procedural(Motion::Orbit, 1, 30.0).poses[0];
    let mut r = render(&Scene::room(1), &cam, &pose);
    let raw = SensorNoise {
        seed: 4,
        ..SensorNoise::default()
    }
    .apply(0, &r.depth, &r.cos_incidence, &mut r.color, cam.depth_scale);
    let mut pre = Preprocessor::new(cam, PreprocessParams::default());
    let levels = pre.process(&raw, Some(&r.color));
    assert_eq!(levels.len(), 3);
    for (l, level) in levels.iter().enumerate() {
        assert_eq!(
            (level.depth.width, level.depth.height),
            (320 >> l, 240 >> l)
        );
        assert_eq!(level.camera, cam.level(l));
        let valid_normals = level.normals.data.iter().filter(|n| valid(n)).count();
        assert!(
            valid_normals > level.depth.data.len() / 2,
            "level {l}: {valid_normals} normals"
        );
        assert_eq!(level.gradient_x.data.len(), level.depth.data.len());
    }
    // Level-0 filtered depth is closer to the truth than the noisy input.
    let (mut before, mut after, mut n) = (0.0, 0.0, 0);
    for i in 0..r.depth.data.len() {
        let (t, noisy, f) = (
            r.depth.data[i] as f64,
            raw.data[i] as f64 / cam.depth_scale,
            levels[0].depth.data[i] as f64,
        );
        if t > 0.0 && noisy > 0.0 && f > 0.0 {
            before += (noisy - t).powi(2);
            after += (f - t).powi(2);
            n += 1;
        }
    }
    assert!(
        n > 50_000 && after < 0.7 * before,
        "rms {} -> {}",
        (before / n as f64).sqrt(),
        (after / n as f64).sqrt()
    );
    // Vertices back-project to the rendered surface.
    let p = levels[0].vertices.at(160, 120);
    let hit = r.hits[120 * 320 + 160].unwrap();
    let world = pose * Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
    assert!((world - hit.point).norm() < 0.05);
}

#[test]
fn a_written_sequence_reads_back_and_a_damaged_frame_is_named() {
    let dir = std::env::temp_dir().join(format!("dynamap-seq-{}", std::process::id()));
    let cam = Camera::new(131.25, 131.25, 79.5, 59.5, 160, 120);
    let traj = motion::procedural(Motion::Shake, 6, 30.0);
    sequence::write_rigid(
        &dir,
        &Scene::room(2),
        &cam,
        &traj,
        &Isometry3::identity(),
        &sequence::Sensor::Ideal(SensorNoise::default()),
        |_| {},
    )
    .unwrap();
    let seq = TumSequence::open(&dir).unwrap();
    assert_eq!(seq.len(), 6);
    assert_eq!(
        (seq.camera.fx, seq.camera.width, seq.camera.depth_scale),
        (131.25, 160, 5000.0)
    );
    let gt = seq.groundtruth.clone().unwrap();
    for (a, b) in gt.poses.iter().zip(&traj.poses) {
        assert!((a.to_homogeneous() - b.to_homogeneous()).abs().max() < 1e-12);
    }
    for i in 0..6 {
        let f = seq.load(i).unwrap();
        assert!(f.depth.data.iter().filter(|&&d| d > 0).count() > 10_000);
    }
    // Damage frame 3's depth: loading it is an error naming the frame and the file; the others load.
    std::fs::write(&seq.frames[3].depth, b"not a png").unwrap();
    let e = seq.load(3).unwrap_err();
    assert!(
        e.message.starts_with("frame 3:") && e.path == seq.frames[3].depth,
        "{e}"
    );
    assert!(seq.load(4).is_ok());
    std::fs::remove_file(&seq.frames[4].rgb).unwrap();
    assert!(seq.load(4).unwrap_err().to_string().contains("frame 4"));
    std::fs::remove_dir_all(&dir).unwrap();
}
