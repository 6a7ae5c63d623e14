//! Non-rigid registration: the thesis' grid experiment (Table 4.1) beaten tenfold, and the
//! deformation graph growing only over new surface.

use super::sensor_frame::SensorFrame;
use dynamap::residuals::deform::rigid_motion;
use dynamap::slam::nonrigid::{mesh_points, register_surfaces, DeformationGraph, GraphParams};
use dynamap::slam::synthetic::plate::{flat_grid, registration_settings, PlateDeformation};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

/// The thesis reports maxima of 4e-3 to 2.4e-2 after registration (Table 4.1); we ask every case
/// to be ten times below the smallest of them.
const BOUND: f64 = 4e-4;

#[test]
fn grid_registrations_are_ten_times_below_the_thesis() {
    let source = flat_grid();
    assert_eq!((source.vertices.len(), source.faces.len()), (273, 480));
    let (sp, sn) = mesh_points(&source);
    let (graph, params) = registration_settings();
    for def in PlateDeformation::ALL {
        let (tp, tn) = mesh_points(&def.deformed(&source));
        let before = sp
            .iter()
            .zip(&tp)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        let reg = register_surfaces((&sp, &sn), (&tp, &tn), graph, params.clone(), true).unwrap();
        let after = reg
            .points
            .iter()
            .zip(&tp)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        eprintln!("{}: max {before:.2e} -> {after:.2e}", def.name());
        assert!(
            before > 0.04,
            "{}: the target is hardly deformed",
            def.name()
        );
        assert!(after < BOUND, "{}: max distance {after:.2e}", def.name());
    }
}

#[test]
fn the_graph_grows_only_over_new_surface() {
    let (points, _) = mesh_points(&flat_grid());
    let left: Vec<Vector3<f64>> = points.iter().filter(|p| p.x < 0.0).copied().collect();
    let params = GraphParams {
        spacing: 0.1,
        ..GraphParams::default()
    };
    let mut graph = DeformationGraph::sample(&left, params).unwrap();
    let before = graph.nodes.len();
    // move everything rigidly: new nodes must take the current warp
    let t = Isometry3::from_parts(
        Translation3::new(0.1, 0.2, -0.3),
        UnitQuaternion::from_euler_angles(0.2, -0.1, 0.4),
    );
    graph.premultiply(&t);
    assert_eq!(graph.extend(&left), 0, "the old surface is covered");
    let added = graph.extend(&points);
    assert!(added > 0);
    let (old, new) = graph.nodes.split_at(before);
    for node in new {
        // on the new half, and beyond the reach of every old node
        assert!(
            node.position.x >= 0.0,
            "node at {} is not on new surface",
            node.position
        );
        let nearest = old
            .iter()
            .map(|o| (o.position - node.position).norm())
            .fold(f64::INFINITY, f64::min);
        assert!(nearest >= params.spacing - 1e-9, "{nearest}");
        let m = rigid_motion(&node.motion);
        assert!((m.to_homogeneous() - t.to_homogeneous()).norm() < 1e-9);
    }
    // every point now has a node within the spacing, and the edges reach the new nodes
    for p in &points {
        let b = graph.bind(p);
        let g = graph.nodes[b.nodes[0] as usize].position;
        assert!((g - p).norm() <= params.spacing + 1e-9);
    }
    assert_eq!(graph.edges.len(), graph.nodes.len());
    // a point bound to nodes that all carry the same motion moves rigidly
    let p = Vector3::new(0.13, -0.07, 0.0);
    let (w, _) = graph.warp(&graph.bind(&p), &p, &Vector3::z());
    assert!((w - (t * Point3::from(p)).coords).norm() < 1e-9);
}

/// Growing a graph takes, in order, each point farther than the spacing from every node and
/// every point taken before it: the same nodes as a greedy pass over all of them, on a mesh's
/// points in their order (neighbours in a row) and scattered, with a point that is not finite.
#[test]
fn growing_a_graph_takes_the_points_a_greedy_pass_would() {
    let (points, _) = mesh_points(&flat_grid());
    let params = GraphParams {
        spacing: 0.07,
        ..GraphParams::default()
    };
    let left: Vec<Vector3<f64>> = points.iter().filter(|p| p.x < -0.1).copied().collect();
    // every 97th point round the list (97 is prime, and no factor of 273): neighbours apart
    let n = points.len();
    assert_ne!(n % 97, 0);
    let mut shuffled: Vec<Vector3<f64>> = (0..n).map(|i| points[i * 97 % n]).collect();
    shuffled.insert(17, Vector3::new(f64::NAN, 0.0, 0.0));
    for order in [points.clone(), shuffled] {
        let mut graph = DeformationGraph::sample(&left, params).unwrap();
        let mut greedy: Vec<Vector3<f64>> = graph.nodes.iter().map(|n| n.position).collect();
        let before = greedy.len();
        for p in order.iter().filter(|p| p.iter().all(|v| v.is_finite())) {
            if greedy
                .iter()
                .all(|g| (g - p).norm_squared() >= params.spacing * params.spacing)
            {
                greedy.push(*p);
            }
        }
        let added = graph.extend(&order);
        assert!(added >= 5, "{added}");
        assert_eq!(added, greedy.len() - before);
        let grown: Vec<Vector3<f64>> = graph.nodes[before..].iter().map(|n| n.position).collect();
        assert_eq!(grown, greedy[before..]);
    }
}

/// The colour terms' weights of a tracking test: the photometric and the chromaticity weight,
/// each the default where `None`.
type ColourWeights = (Option<f64>, Option<f64>);

/// Non-rigid fusion's failure paths, each typed, none fusing: a blank first frame does not start
/// the model, an image of the wrong size is refused, and after a good start a blank frame and
/// a frame of the plate 1.5 m further away are lost, leaving the field as it was; the next good
/// frame is tracked again.
#[test]
fn nonrigid_fusion_reports_each_failure_and_keeps_its_field() {
    use dynamap::slam::camera::Camera;
    use dynamap::slam::image::Image;
    use dynamap::slam::nonrigid::{FusionFailure, FusionParams, NonRigidFusion};
    use dynamap::slam::synthetic::deform::{surface, DeformingScene, Field, SurfaceKind};
    use dynamap::slam::synthetic::noise::SensorNoise;

    let scene = DeformingScene::new(surface(SurfaceKind::Plane, 60), Field::Bend, 3);
    let camera = Camera::tum_default().level(1);
    let mut slam = NonRigidFusion::new(camera, FusionParams::default());
    let noise = SensorNoise::default();
    let frame = |k, pose: &Isometry3<f64>| scene.sensor_frame(&camera, pose, k, &noise);
    let (depth, color) = frame(0, &Isometry3::identity());
    let blank = Image::filled(depth.width, depth.height, 0u16);
    let failure = slam.process(&blank, Some(&color), None).failure;
    assert_eq!(failure, Some(FusionFailure::TooLittleDepth { pixels: 0 }));
    assert!(slam.graph().is_none(), "a blank frame starts nothing");
    let small = Image::filled(depth.width / 2, depth.height, 1000u16);
    let failure = slam.process(&small, None, None).failure;
    assert!(
        matches!(failure, Some(FusionFailure::ImageSize { .. })),
        "{failure:?}"
    );
    assert_eq!(slam.process(&depth, Some(&color), None).failure, None);
    let (depth, color) = frame(1, &Isometry3::identity());
    assert_eq!(slam.process(&depth, Some(&color), None).failure, None);
    let field = |slam: &NonRigidFusion| slam.warp_points(slam.data_points());
    let before = field(&slam);
    let failure = slam.process(&blank, Some(&color), None).failure;
    assert!(
        matches!(failure, Some(FusionFailure::Lost { matched: 0, .. })),
        "{failure:?}"
    );
    let away = Isometry3::translation(0.0, 0.0, -1.5);
    let (far, far_color) = frame(2, &away);
    let failure = slam.process(&far, Some(&far_color), None).failure;
    assert!(
        matches!(
            failure,
            Some(FusionFailure::Lost { .. } | FusionFailure::Register(_))
        ),
        "{failure:?}"
    );
    assert_eq!(
        field(&slam),
        before,
        "a frame not tracked leaves the field as it was"
    );
    let (depth, color) = frame(2, &Isometry3::identity());
    assert_eq!(slam.process(&depth, Some(&color), None).failure, None);
}

/// Tracks the rendered plate's frames with these colour weights; see [`track_surface`]. Every
/// frame must be fused.
fn track_plate(plate: &Rendered, weights: ColourWeights) -> Tracked {
    let tracked = track_surface(plate, tracking_params(weights));
    tracked.assert_all_fused();
    tracked
}

/// The tracking tests' settings: the data term at full resolution (the frames are 320 × 240)
/// and, where given, these colour weights.
fn tracking_params(
    (photometric_weight, chroma_weight): ColourWeights,
) -> dynamap::slam::nonrigid::FusionParams {
    let mut params = dynamap::slam::nonrigid::FusionParams {
        data_level: 0,
        ..Default::default()
    };
    if let Some(w) = photometric_weight {
        params.register.photometric_weight = w;
    }
    if let Some(w) = chroma_weight {
        params.register.chroma_weight = w;
    }
    params
}

/// What [`track_surface`] saw: each frame's mean tracking error (m) and failure, and the node
/// counts after the first frame and at the end.
struct Tracked {
    errors: Vec<f64>,
    failures: Vec<Option<dynamap::slam::nonrigid::FusionFailure>>,
    first_nodes: usize,
    nodes: usize,
}

impl Tracked {
    fn assert_all_fused(&self) {
        for (k, f) in self.failures.iter().enumerate() {
            assert_eq!(f, &None, "frame {k}");
        }
    }
}

/// A generated surface and its frames, rendered once for every run over them.
struct Rendered {
    scene: dynamap::slam::synthetic::deform::DeformingScene,
    frames: Vec<SensorFrame>,
}

/// The first `frames` frames of a generated surface under `field` (texture `seed`), rendered
/// with sensor noise at 320 × 240.
fn render_surface(
    kind: dynamap::slam::synthetic::deform::SurfaceKind,
    field: dynamap::slam::synthetic::deform::Field,
    seed: u64,
    frames: usize,
) -> Rendered {
    use dynamap::slam::synthetic::deform::{surface, DeformingScene};
    use dynamap::slam::synthetic::noise::SensorNoise;

    let scene = DeformingScene::new(surface(kind, 60), field, seed);
    let camera = tracking_camera();
    let noise = SensorNoise::default();
    let frames = (0..frames)
        .map(|k| scene.sensor_frame(&camera, &Isometry3::identity(), k, &noise))
        .collect();
    Rendered { scene, frames }
}

/// The camera of [`render_surface`]'s frames (320 × 240).
fn tracking_camera() -> dynamap::slam::camera::Camera {
    dynamap::slam::camera::Camera::tum_default().level(1)
}

/// Tracks the rendered surface's frames with `params`.
fn track_surface(rendered: &Rendered, params: dynamap::slam::nonrigid::FusionParams) -> Tracked {
    use dynamap::slam::nonrigid::NonRigidFusion;
    let slam = NonRigidFusion::new(tracking_camera(), params);
    track_frames(&rendered.scene, slam, rendered.frames.len(), |k| {
        &rendered.frames[k]
    })
}

/// Runs `slam` over the first `frames` frames of `scene`, frame k's depth and colour being
/// `frame(k)`.
fn track_frames<F>(
    scene: &dynamap::slam::synthetic::deform::DeformingScene,
    mut slam: dynamap::slam::nonrigid::NonRigidFusion,
    frames: usize,
    frame: impl Fn(usize) -> F,
) -> Tracked
where
    F: std::borrow::Borrow<SensorFrame>,
{
    use dynamap::slam::eval::Stats;
    let mut tracked = Tracked {
        errors: Vec::new(),
        failures: Vec::new(),
        first_nodes: 0,
        nodes: 0,
    };
    for k in 0..frames {
        let f = frame(k);
        let (depth, color) = f.borrow();
        let report = slam.process(depth, Some(color), None);
        tracked.failures.push(report.failure);
        if k == 0 {
            tracked.first_nodes = report.nodes;
        }
        let points = slam.data_points();
        let errors = scene.tracking_errors(points, &slam.warp_points(points), k);
        tracked.errors.push(Stats::of(&errors).mean);
    }
    tracked.nodes = slam.graph().unwrap().nodes.len();
    tracked
}

/// DynamicFusion-style tracking of a plate bending to a 0.67 m radius and back over 30 frames:
/// every frame's warped canonical samples lie within 5 mm of their material points on average,
/// no frame fails, and the graph grows only a little (the surface seen at the start is all
/// there is, bar the edges that turn into view).
#[test]
fn a_bending_plate_is_tracked_within_five_millimetres() {
    use dynamap::slam::synthetic::deform::{Field, SurfaceKind};
    let Tracked {
        errors,
        first_nodes,
        nodes,
        ..
    } = track_plate(
        &render_surface(SurfaceKind::Plane, Field::Bend, 3, 30),
        (None, None),
    );
    let worst = errors.iter().fold(0.0f64, |a, &e| a.max(e));
    assert!(worst < 5e-3, "worst frame's mean error {worst} m");
    assert!(
        first_nodes > 100 && nodes < first_nodes + first_nodes / 5,
        "{first_nodes} nodes at the start, {nodes} at the end"
    );
}

/// A wave travelling along a plate moves its material only across the plate, while the shape
/// runs along it: depth alone fits the shape and lets the material slide with the wave. The
/// colour terms hold it: over 40 frames the error stays under 1 cm, and without them (same
/// frames) it is more than twice as large. The intensity ratio alone holds it too.
#[test]
fn a_travelling_wave_is_held_by_the_photometric_term() {
    use dynamap::slam::synthetic::deform::{Field, SurfaceKind};
    let wave = render_surface(SurfaceKind::Plane, Field::Wave, 5, 40);
    let last = |w| *track_plate(&wave, w).errors.last().unwrap();
    let (held, ratio, slid) = (
        last((None, None)),
        last((None, Some(0.0))),
        last((Some(0.0), Some(0.0))),
    );
    assert!(held < 0.01, "with the colour terms: {held} m");
    assert!(ratio < 0.01, "with the intensity ratio alone: {ratio} m");
    assert!(slid > 2.0 * held, "without them: {slid} m against {held} m");
}

/// A tube twisting about its own axis leaves its depth as it was, and the intensity ratio, a
/// high-pass of the texture referenced to a recent frame, lets the material walk. The
/// chromaticity, kept from the frame each point was first seen in, holds it: over 15 frames
/// of the twist the mean error falls by more than 30 %. (It does not hold it all: the tube stays
/// centimetres off, BENCHMARKS.)
#[test]
fn a_twisting_tube_is_held_by_the_chromaticity() {
    use dynamap::slam::nonrigid::FusionParams;
    use dynamap::slam::synthetic::deform::{Field, SurfaceKind};
    let tube = render_surface(SurfaceKind::Cylinder, Field::Twist, 3, 15);
    let mean = |w| {
        // the term's hold is measured with every frame fused: no colour drift judged
        let params = FusionParams {
            colour_drift_ratio: 0.0,
            ..tracking_params(w)
        };
        let tracked = track_surface(&tube, params);
        tracked.assert_all_fused();
        tracked.errors.iter().sum::<f64>() / tracked.errors.len() as f64
    };
    let (held, walked) = (mean((None, None)), mean((None, Some(0.0))));
    // over these 15 frames: 1.5 against 3.8 cm (2.1 against 3.9 at λ = 100; BENCHMARKS "The
    // chromaticity term")
    assert!(
        held < 0.03 && held < 0.7 * walked,
        "with the chromaticity: {held} m, without: {walked} m"
    );
}

/// A tube twisting about its axis, recorded through the Kinect model at 640 × 480 as
/// `nonrigid_slam --sensor kinect` records it: its material slides along the surface, which
/// depth does not see and the warp does not follow all of (BENCHMARKS: centimetres off). The
/// chromaticity residual against its floor says so (module `colour_drift`): frames are reported
/// as drifted, each of them more than 5 mm off, while the bending plate recorded the same way
/// has no such report. (Not every drifted frame is caught: BENCHMARKS.)
#[test]
fn a_tube_whose_material_slides_is_reported_as_not_fused() {
    use dynamap::slam::synthetic::deform::{Field, SurfaceKind};
    let tube = track_recorded_surface(SurfaceKind::Cylinder, Field::Twist, 20);
    let drifted: Vec<(usize, f64)> = (0..tube.errors.len())
        .filter(|&k| tube.failures[k].is_some())
        .map(|k| (k, tube.errors[k]))
        .collect();
    assert!(!drifted.is_empty(), "no frame reported as drifted");
    for (k, e) in &drifted {
        assert!(*e > 0.005, "frame {k} reported drifted at {e} m");
    }
    let plate = track_recorded_surface(SurfaceKind::Plane, Field::Bend, 20);
    plate.assert_all_fused();
    let worst = plate.errors.iter().fold(0.0f64, |a, &e| a.max(e));
    assert!(worst < 0.005, "the plate's worst frame {worst} m");
}

/// A plate twisting by up to ±43° at its ends (1.5 rad/m), recorded through the Kinect model:
/// its corners swing up to 4 cm a frame towards or away from the camera. Over the first 40 frames
/// (past the first peak of the twist, into the second) every frame stays within 1 cm on average.
/// With Tukey's c at 2 cm inside the 5 cm gate (before NOTES 133) the corners fell more than c
/// behind, their matches got no weight, and frame 33 was already 1.02 cm off.
#[test]
fn a_twisting_plate_keeps_its_corners() {
    use dynamap::slam::synthetic::deform::{Field, SurfaceKind};
    let plate = track_recorded_surface(SurfaceKind::Plane, Field::Twist, 40);
    for (k, e) in plate.errors.iter().enumerate() {
        assert!(*e < 0.01, "frame {k}: {e} m");
    }
}

/// Tracks `frames` frames of a generated surface under `field` (texture 7) as the Kinect model
/// records them at 640 × 480, with the default settings; any failure but a colour drift fails.
fn track_recorded_surface(
    kind: dynamap::slam::synthetic::deform::SurfaceKind,
    field: dynamap::slam::synthetic::deform::Field,
    frames: usize,
) -> Tracked {
    use dynamap::slam::camera::Camera;
    use dynamap::slam::distortion::Distortion;
    use dynamap::slam::nonrigid::{FusionFailure, FusionParams, NonRigidFusion};
    use dynamap::slam::synthetic::deform::{surface, DeformingScene};
    use dynamap::slam::synthetic::kinect::KinectModel;
    use dynamap::slam::synthetic::sequence::static_camera;

    let scene = DeformingScene::new(surface(kind, 60), field, 7);
    let camera = Camera::tum_default();
    let model = KinectModel {
        seed: 7,
        distortion: Distortion::default(),
        ..KinectModel::default()
    };
    let stamps = static_camera(frames, 30.0);
    let slam = NonRigidFusion::new(camera, FusionParams::default());
    let tracked = track_frames(&scene, slam, frames, |k| {
        let f = model
            .recorder(&camera)
            .capture(&scene.scene_at(k), &stamps, k);
        (f.depth, f.color)
    });
    for (k, failure) in tracked.failures.iter().enumerate() {
        assert!(
            matches!(failure, None | Some(FusionFailure::ColourDrift(_))),
            "frame {k}: {failure:?}"
        );
    }
    tracked
}

/// `source` onto `target` moved half a metre back, with the registration's search for a start
/// by the outline switched off: nothing lies within the gates, so the registration is reported
/// as not registered, not as a result. With the search on, onto a target that no longer shows
/// the object (a plain wall behind where everything was): the search must not lay the object on
/// the wall (NOTES 68's failure), and it is not registered either.
fn assert_out_of_reach_is_not_registered(
    camera: &dynamap::slam::camera::Camera,
    source: &dynamap::slam::image::DepthImage,
    target: &dynamap::slam::image::DepthImage,
) {
    use dynamap::slam::nonrigid::{register_frames, FrameSettings, FrameVerdict, FrameView};
    let mut far = target.clone();
    far.data
        .iter_mut()
        .filter(|z| **z > 0.0)
        .for_each(|z| *z += 0.5);
    let deepest = target.data.iter().copied().fold(0.0f32, f32::max);
    let mut wall = target.clone();
    wall.data.iter_mut().for_each(|z| *z = deepest + 0.8);
    let local = FrameSettings {
        outline_start: false,
        ..FrameSettings::default()
    };
    for (moved, settings, what) in [
        (&far, &local, "half a metre back, no search"),
        (&wall, &FrameSettings::default(), "only a wall"),
    ] {
        let lost = register_frames(
            &FrameView::new(camera, source, None, None),
            &FrameView::new(camera, moved, None, None),
            settings,
        )
        .unwrap();
        assert!(
            matches!(lost.verdict(), FrameVerdict::NotRegistered { matched, data_points }
                if matched < data_points / 2),
            "{what}: {:?}",
            lost.verdict()
        );
    }
}

/// A generated frame pair registered with `settings` (the source masked to the surface): the
/// registration and its EPE against the truth, with zero flow's. A bent pair also checks that
/// the same pair pushed out of reach is reported as not registered.
fn frame_pair(
    case: &dynamap::slam::synthetic::frame_pair::FramePairCase,
    settings: &dynamap::slam::nonrigid::FrameSettings,
) -> (
    dynamap::slam::nonrigid::FrameRegistration,
    dynamap::slam::eval::EpeResult,
    dynamap::slam::eval::EpeResult,
) {
    use dynamap::slam::nonrigid::{register_frames, FrameView};
    use dynamap::slam::synthetic::deform::Field;

    let pair = case.render();
    let ((d0, c0), (d1, c1)) = (&pair.source, &pair.target);
    let reg = register_frames(
        &FrameView::new(&pair.camera, d0, Some(c0), Some(&pair.mask)),
        &FrameView::new(&pair.camera, d1, Some(c1), None),
        settings,
    )
    .unwrap();
    if case.field == Field::Bend {
        assert_out_of_reach_is_not_registered(&pair.camera, d0, d1);
    }
    let (epe, zero) = pair.score(&reg.points, &reg.warped);
    (reg, epe, zero)
}

/// Two frames of a bending, textured plate seen from cameras 12 cm and 6° apart (DeepDeform's
/// setting, generated): the feature-matched rigid start and the dense non-rigid refinement give a
/// scene flow within 1.5 cm of the truth on average (0.8 cm seen), where zero flow is off by
/// over 10 cm.
#[test]
fn a_frame_pair_with_a_large_motion_gets_its_scene_flow() {
    use dynamap::slam::nonrigid::{FrameSettings, FrameVerdict};
    use dynamap::slam::synthetic::deform::{Field, SurfaceKind};
    use dynamap::slam::synthetic::frame_pair::FramePairCase;
    let case = FramePairCase {
        kind: SurfaceKind::Plane,
        field: Field::Bend,
        seed: 5,
        moved: Isometry3::from_parts(
            Translation3::new(0.12, 0.0, 0.0),
            UnitQuaternion::from_scaled_axis(Vector3::y() * 6f64.to_radians()),
        ),
        frame: 8,
        wall: false,
    };
    let (reg, epe, zero) = frame_pair(&case, &FrameSettings::default());
    assert_eq!(reg.verdict(), FrameVerdict::Registered);
    let matches = reg
        .matches
        .as_ref()
        .expect("features agree on a rigid start");
    assert!(
        matches.source.len() >= 30,
        "{} inlier matches",
        matches.source.len()
    );
    assert!(
        zero.stats.mean > 0.1,
        "zero flow scores {}",
        zero.stats.mean
    );
    assert!(
        epe.stats.mean < 0.015 && epe.within_5cm > 0.97,
        "EPE {} m, {} within 5 cm",
        epe.stats.mean,
        epe.within_5cm
    );
    // the registration's own flow moves its points to where it warped them; pixels without a
    // finite flow are left out (the ground-truth floor of `nonrigid_register frames`)
    let camera = case.render().camera;
    let mut flow = reg.scene_flow(camera.width, camera.height);
    let moved = reg.points_moved_by(&flow);
    assert_eq!(moved.len(), reg.warped.len());
    for (m, q) in moved.iter().zip(&reg.warped) {
        assert!((m - q).norm() < 1e-5, "{m} against {q}");
    }
    flow.data[reg.pixels[0]][1] = f32::NAN;
    assert_eq!(reg.points_moved_by(&flow).len(), reg.warped.len() - 1);
}

/// A rippling ball before a wall, seen from cameras 9 cm and 8° apart: its outline moves over
/// the wall between the frames. Points the target sees through are held by the nearest surface
/// point, and the feature matches hold theirs (NOTES 95): EPE 0.35 cm, against 0.88 cm with
/// projective association alone and the matches as the rigid start only.
#[test]
fn a_ball_whose_outline_moves_is_held_where_the_target_sees_through_it() {
    use dynamap::slam::nonrigid::{FrameSettings, FrameVerdict};
    use dynamap::slam::synthetic::deform::{Field, SurfaceKind};
    use dynamap::slam::synthetic::frame_pair::FramePairCase;
    let case = FramePairCase {
        kind: SurfaceKind::Sphere,
        field: Field::Wave,
        seed: 11,
        moved: Isometry3::from_parts(
            Translation3::new(0.09, 0.02, 0.0),
            UnitQuaternion::from_scaled_axis(Vector3::y() * 8f64.to_radians()),
        ),
        frame: 8,
        wall: true,
    };
    let (reg, epe, zero) = frame_pair(&case, &FrameSettings::default());
    eprintln!(
        "ball: EPE {:.4} m (zero flow {:.4})",
        epe.stats.mean, zero.stats.mean
    );
    assert_eq!(reg.verdict(), FrameVerdict::Registered);
    assert!(
        zero.stats.mean > 0.1,
        "zero flow scores {}",
        zero.stats.mean
    );
    assert!(
        epe.stats.mean < 0.006 && epe.within_5cm > 0.99,
        "EPE {} m, {} within 5 cm",
        epe.stats.mean,
        epe.within_5cm
    );
}

/// A cylinder twisted end against end, seen from cameras 9 cm and 8° apart: its motion is mostly
/// along its own surface, which depth does not see. The rigid fit keeps the matches of the
/// middle; grown by local agreement and fitted before the depth (NOTES 95) they carry the ends:
/// EPE 2.8 cm, 93 % within 5 cm, against 5.6 cm and 46 % with the matches as the rigid start only
/// (both without the chromaticity term, which would hide what the matches do). 2.8 cm is on the
/// surface but slid along it, and the colour check says so.
#[test]
fn a_twisted_cylinder_is_carried_by_its_matches_grown_from_the_middle() {
    use dynamap::slam::nonrigid::{FrameSettings, FrameVerdict};
    use dynamap::slam::synthetic::deform::{Field, SurfaceKind};
    use dynamap::slam::synthetic::frame_pair::FramePairCase;
    let case = FramePairCase {
        kind: SurfaceKind::Cylinder,
        field: Field::Twist,
        seed: 11,
        moved: Isometry3::from_parts(
            Translation3::new(0.09, 0.02, 0.0),
            UnitQuaternion::from_scaled_axis(Vector3::y() * 8f64.to_radians()),
        ),
        frame: 8,
        wall: false,
    };
    let mut settings = FrameSettings::default();
    settings.register.chroma_weight = 0.0;
    let (reg, epe, _) = frame_pair(&case, &settings);
    assert!(
        matches!(reg.verdict(), FrameVerdict::ColourDisagrees(_)),
        "{:?}",
        reg.verdict()
    );
    assert!(
        epe.stats.mean < 0.035 && epe.within_5cm > 0.85,
        "EPE {} m, {} within 5 cm",
        epe.stats.mean,
        epe.within_5cm
    );
}

/// A cylinder bent about its middle, seen from cameras 9 cm and 6° apart (the first seed's bent
/// cylinder of `nonrigid_register pairs`, which NOTES 96 was chosen on): the ends slide along the
/// surface, where the grown matches are too few to hold them. The chromaticity of the source's
/// own pixels, compared where the warp carries them, holds them: 0.17 cm against 3.7 cm.
#[test]
fn a_bent_cylinder_is_held_by_the_chromaticity_of_its_pixels() {
    use dynamap::slam::nonrigid::{FrameSettings, FrameVerdict};
    use dynamap::slam::synthetic::deform::{Field, SurfaceKind};
    use dynamap::slam::synthetic::frame_pair::FramePairCase;
    let case = FramePairCase::set(1, 1, false)
        .into_iter()
        .find(|c| c.kind == SurfaceKind::Cylinder && c.field == Field::Bend)
        .expect("the set has a bent cylinder");
    let (reg, held, _) = frame_pair(&case, &FrameSettings::default());
    let mut settings = FrameSettings::default();
    settings.register.chroma_weight = 0.0;
    let (slid_reg, slid, _) = frame_pair(&case, &settings);
    assert_eq!(reg.verdict(), FrameVerdict::Registered);
    assert!(
        held.stats.mean < 0.01 && slid.stats.mean > 3.0 * held.stats.mean,
        "EPE {} m with the chromaticity, {} m without",
        held.stats.mean,
        slid.stats.mean
    );
    // left slid, the depth is met but the colour check is not
    assert!(
        matches!(slid_reg.verdict(), FrameVerdict::ColourDisagrees(_)),
        "{:?} at {} m",
        slid_reg.verdict(),
        slid.stats.mean
    );
}

/// A pair the registration leaves slid along the surface (the twisting tube of seed 2, 4.1 cm
/// EPE, on the depth within its gates) is not registered: the colour disagrees on more than a
/// fifth of its textured patches (module `colour_check`). Its neighbour of seed 1, registered
/// to 0.3 cm, is.
#[test]
fn a_pair_left_slid_along_the_surface_is_not_registered() {
    use dynamap::slam::nonrigid::{FrameSettings, FrameVerdict};
    use dynamap::slam::synthetic::deform::{Field, SurfaceKind};
    use dynamap::slam::synthetic::frame_pair::FramePairCase;
    let cases = FramePairCase::set(1, 2, false);
    let twist = |seed| {
        cases
            .iter()
            .find(|c| c.kind == SurfaceKind::Cylinder && c.field == Field::Twist && c.seed == seed)
            .expect("the set has twisting tubes of seeds 1 and 2")
    };
    let (good, good_epe, _) = frame_pair(twist(1), &FrameSettings::default());
    let (slid, slid_epe, _) = frame_pair(twist(2), &FrameSettings::default());
    assert!(good_epe.stats.mean < 0.01 && slid_epe.stats.mean > 0.03);
    assert_eq!(
        good.verdict(),
        FrameVerdict::Registered,
        "{:?}",
        good.colour
    );
    match slid.verdict() {
        FrameVerdict::ColourDisagrees(c) => assert!(c.off > 10, "{c:?}"),
        v => panic!("{v:?} at {} m", slid_epe.stats.mean),
    }
}

/// Issue 26's sheets, the target meshed apart from the source (1.4 × the vertices each way, the
/// inner ones moved at random by up to 0.3 of the spacing), so that no vertex has a copy: a twist
/// moved rigidly and a fold, at 0.3 m on a 25 × 15 sheet (sizes, meshes and jitter seed not
/// used by `nonrigid_register sheets`). Within the 10 % largest and 3 % mean; matched to
/// the target's vertices the twist was 13 % / 5 %.
#[test]
fn sheets_meshed_apart_are_registered_between_the_targets_vertices() {
    use dynamap::slam::nonrigid::{register_mesh_pair, Seeding};
    use dynamap::slam::synthetic::sheet::{
        case_motion, flat_sheet, jittered, SheetDeformation, SheetScore, SheetShape,
    };
    let width = 0.3;
    let source = flat_sheet(25, 15, width);
    let apart = jittered(flat_sheet(35, 21, width), 35, 21, 0.3, 23);
    for case in [
        SheetDeformation {
            shape: SheetShape::Twist { angle: 0.8 },
            rigid: Some(case_motion(12.0, 0.02)),
        },
        SheetDeformation {
            shape: SheetShape::Fold { angle: 1.4 },
            rigid: None,
        },
    ] {
        let target = case.deformed(&apart, width);
        let reg = register_mesh_pair(&source, &target, &Seeding::default()).unwrap();
        let SheetScore { max, mean, .. } = case.score(&source, &reg.points, width);
        eprintln!("{}: max {max:.4}, mean {mean:.4}", case.shape.name());
        assert!(
            max <= 0.10 && mean <= 0.03,
            "{}: max {max}, mean {mean}",
            case.shape.name()
        );
    }
}

/// Issue 26's sheets: a plain sheet (no texture, no correspondences given) registered onto an
/// isometric bend of itself moved rigidly by 15° and 3 cm, at 10 cm and at 2 m with the same
/// relative settings, its target renumbered. Each vertex is scored against where the bend sent
/// it: at most 10 % of the largest displacement, 3 % on average. Closest point and the core's
/// geodesic anchors alone left the S at 19 % and the fold at 13 % (at 0.5 m).
#[test]
fn bent_sheets_are_registered_by_their_rims_at_any_size() {
    use dynamap::slam::nonrigid::{register_mesh_pair, Seeding};
    use dynamap::slam::synthetic::sheet::{
        case_motion, flat_sheet, SheetDeformation, SheetScore, SheetShape,
    };
    for (shape, width) in [
        (SheetShape::SBend { tilt: 1.2 }, 0.1),
        (SheetShape::Fold { angle: 1.5 }, 2.0),
    ] {
        let case = SheetDeformation {
            shape,
            rigid: Some(case_motion(15.0, 0.03)),
        };
        let source = flat_sheet(21, 13, width);
        let bent = case.deformed(&source, width);
        let n = source.vertices.len();
        let new_of = |v: usize| (v * 11 + 2) % n; // 11 is prime to 273 = 3 · 7 · 13
        let mut target = bent.clone();
        for (v, p) in bent.vertices.iter().enumerate() {
            target.vertices[new_of(v)] = *p;
        }
        for f in &mut target.faces {
            *f = f.map(|v| new_of(v as usize) as u32);
        }
        target.compute_normals();
        let reg = register_mesh_pair(&source, &target, &Seeding::default()).unwrap();
        let SheetScore { max, mean, .. } = case.score(&source, &reg.points, width);
        eprintln!(
            "{} at {width} m: max {max:.4}, mean {mean:.4}",
            shape.name()
        );
        assert!(
            max <= 0.10 && mean <= 0.03,
            "{}: max {max}, mean {mean}",
            shape.name()
        );
    }
}

/// Generated pairs whose object moved 12–30 cm, with the colour features switched off (a plain
/// object, as DeepDeform's seq017): from the source's own place the registration ends 8–16 cm
/// off, and from the outline search's start within 2 cm, registered (NOTES 147).
#[test]
fn a_plain_object_moved_far_is_started_by_its_outline() {
    use dynamap::slam::nonrigid::{FrameStart, FrameVerdict};
    use dynamap::slam::synthetic::deform::{Field, SurfaceKind};
    use dynamap::slam::synthetic::frame_pair::FramePairCase;
    // the camera's motions of NOTES 147's two sets: plane-twist-43 held out, cylinder-wave-31
    // from the set the search was shaped on
    let twist = (
        Translation3::new(0.02, -0.06, -0.04),
        Vector3::new(0.01, 0.0, 0.03),
    );
    let wave = (
        Translation3::new(0.15, 0.12, -0.05),
        Vector3::new(0.05, 0.1, 0.12),
    );
    for (kind, field, seed, (shift, turn)) in [
        (SurfaceKind::Plane, Field::Twist, 43, twist),
        (SurfaceKind::Cylinder, Field::Wave, 31, wave),
    ] {
        let case = FramePairCase {
            kind,
            field,
            seed,
            moved: Isometry3::from_parts(shift, UnitQuaternion::from_scaled_axis(turn)),
            frame: 8,
            wall: true,
        };
        let pair = case.render();
        let (local, local_epe, zero) = without_features(&pair, false);
        let (searched, epe, _) = without_features(&pair, true);
        let name = case.name();
        assert!(
            zero > 0.1 && local_epe > 0.05,
            "{name}: {zero} m moved, {local_epe} m left"
        );
        assert_eq!(local.start, FrameStart::Identity);
        assert!(matches!(searched.start, FrameStart::Outline(_)), "{name}");
        assert!(epe < 0.02, "{name}: EPE {epe} m from the outline's start");
        assert_eq!(searched.verdict(), FrameVerdict::Registered, "{name}");
    }
}

/// `pair` registered without colour features, with the outline search or not: the registration,
/// its mean EPE and zero flow's, metres.
fn without_features(
    pair: &dynamap::slam::synthetic::frame_pair::FramePair,
    outline_start: bool,
) -> (dynamap::slam::nonrigid::FrameRegistration, f64, f64) {
    use dynamap::slam::nonrigid::{register_frames, FrameSettings, FrameView};
    let ((d0, c0), (d1, c1)) = (&pair.source, &pair.target);
    let settings = FrameSettings {
        features: None,
        outline_start,
        ..FrameSettings::default()
    };
    let reg = register_frames(
        &FrameView::new(&pair.camera, d0, Some(c0), Some(&pair.mask)),
        &FrameView::new(&pair.camera, d1, Some(c1), None),
        &settings,
    )
    .unwrap();
    let (epe, zero) = pair.score(&reg.points, &reg.warped);
    (reg, epe.stats.mean, zero.stats.mean)
}

/// A plain sheet moved far, registered without a start: it ends pressed onto the plain wall
/// behind it, every data point on a surface and no textured patch for the colour check, which
/// the depth's count took for a registration (NOTES 147). Its outline, which stood before the
/// wall in the source, now lies flush in the wall: not registered (NOTES 148). Registered from
/// the outline search's start instead, the outline stands and the verdict holds.
#[test]
fn a_plain_sheet_pressed_onto_the_wall_is_not_registered() {
    use dynamap::slam::nonrigid::FrameVerdict;
    let pair = far_pair("plane-twist-33", true);
    let (pressed, pressed_epe, _) = without_features(&pair, false);
    assert!(
        pressed_epe > 0.1,
        "{pressed_epe} m: not pressed onto the wall"
    );
    assert!(
        pressed.summary.matched * 2 >= pressed.data_points,
        "the depth's count alone would take it: {} of {}",
        pressed.summary.matched,
        pressed.data_points
    );
    match pressed.verdict() {
        FrameVerdict::LiesFlush(o) => assert!(o.fraction_flush() > 0.9, "{o:?}"),
        other => panic!("{pressed_epe} m off reported as {other:?}"),
    }
    let (found, epe, _) = without_features(&pair, true);
    assert!(epe < 0.02, "{epe} m from the outline's start");
    assert_eq!(found.verdict(), FrameVerdict::Registered);
    let outline = found.outline.expect("the sheet stands before the wall");
    assert!(
        outline.judges() && outline.fraction_flush() < 0.4,
        "{outline:?}"
    );
}

/// A textured ball turned far, registered without a start: it ends turned on its own surface
/// 15 cm off, every data point on the target and its outline all silhouette (not judged). Every
/// patch of the colour check is slid farther than its search, so the floor rises with them and
/// every patch reads flat ("0 of 0" off), which counted as agreeing (NOTES 148). Over the whole
/// area its colour is unrelated to the target's: not registered (NOTES 152). Started by its
/// colour features instead, it registers and its colour follows it.
#[test]
fn a_ball_turned_far_whose_colour_does_not_follow_is_not_registered() {
    use dynamap::slam::nonrigid::{register_frames, FrameSettings, FrameVerdict, FrameView};
    let pair = far_pair("sphere-twist-32", false);
    let (slid, slid_epe, _) = without_features(&pair, false);
    assert!(slid_epe > 0.1, "{slid_epe} m: not slid");
    assert!(
        slid.summary.matched * 2 >= slid.data_points,
        "the depth's count alone would take it"
    );
    match slid.verdict() {
        FrameVerdict::ColourDisagrees(c) => {
            assert!(c.unrelated() && c.off + c.aligned == 0, "{c:?}")
        }
        other => panic!("{slid_epe} m off reported as {other:?}"),
    }
    let ((d0, c0), (d1, c1)) = (&pair.source, &pair.target);
    let found = register_frames(
        &FrameView::new(&pair.camera, d0, Some(c0), Some(&pair.mask)),
        &FrameView::new(&pair.camera, d1, Some(c1), None),
        &FrameSettings::default(),
    )
    .unwrap();
    let (epe, _) = pair.score(&found.points, &found.warped);
    assert!(
        epe.stats.mean < 0.01,
        "{} m from the features",
        epe.stats.mean
    );
    assert_eq!(found.verdict(), FrameVerdict::Registered);
    let colour = found.colour.expect("both frames have colour");
    assert!(colour.correlation > 0.9, "{colour:?}");
}

/// The pair `name` of NOTES 147's far set 0, rendered (with the wall behind it or not).
fn far_pair(name: &str, wall: bool) -> dynamap::slam::synthetic::frame_pair::FramePair {
    use dynamap::slam::synthetic::frame_pair::FramePairCase;
    FramePairCase::far_set(0, wall)
        .into_iter()
        .find(|c| c.name() == name)
        .unwrap_or_else(|| panic!("NOTES 147's set 0 has no {name}"))
        .render()
}

/// The surface of a box `size` metres, `cells[a]` squares along axis a (two triangles each,
/// wound outwards), its vertices shared between the faces that meet at them.
fn box_surface(cells: [usize; 3], size: [f64; 3]) -> dynamap::slam::mesh::Mesh {
    use std::collections::HashMap;
    let mut index: HashMap<[usize; 3], u32> = HashMap::new();
    let mut mesh = dynamap::slam::mesh::Mesh::default();
    let mut vertex = |at: [usize; 3], mesh: &mut dynamap::slam::mesh::Mesh| {
        *index.entry(at).or_insert_with(|| {
            let p: [f32; 3] =
                std::array::from_fn(|a| (size[a] * at[a] as f64 / cells[a] as f64) as f32);
            mesh.vertices.push(Point3::from(p));
            mesh.vertices.len() as u32 - 1
        })
    };
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        for (side, outward) in [(0, false), (cells[axis], true)] {
            for i in 0..cells[u] {
                for j in 0..cells[v] {
                    let at = |di: usize, dj: usize| {
                        let mut c = [0; 3];
                        (c[axis], c[u], c[v]) = (side, i + di, j + dj);
                        c
                    };
                    let q = [at(0, 0), at(1, 0), at(1, 1), at(0, 1)].map(|c| vertex(c, &mut mesh));
                    let tris = [[q[0], q[1], q[2]], [q[0], q[2], q[3]]];
                    mesh.faces
                        .extend(tris.map(|t| if outward { t } else { [t[0], t[2], t[1]] }));
                }
            }
        }
    }
    mesh.compute_normals();
    mesh
}

/// `p` of a box of `size` (corner at the origin) twisted by 0.6 rad about the box's long axis
/// (x), its ends turned ±0.3 rad.
fn twisted(p: &Point3<f32>, size: [f64; 3]) -> Point3<f32> {
    let a = 0.6 * (f64::from(p.x) / size[0] - 0.5);
    let (y, z) = (
        f64::from(p.y) - size[1] / 2.0,
        f64::from(p.z) - size[2] / 2.0,
    );
    let (s, c) = a.sin_cos();
    let (y, z) = (c * y - s * z + size[1] / 2.0, s * y + c * z + size[2] / 2.0);
    Point3::new(p.x, y as f32, z as f32)
}

/// A closed box with nothing on it, 60 × 30 × 15 cm sampled 16 squares along each side (as a
/// subdivided box is: 9 mm apart across its thin side, 37 mm along its length), twisted by
/// 0.6 rad about its long axis (its ends turned ±0.3 rad, the corners 5 cm), registered with no
/// correspondences given. Closest-point partners weighed point-to-point at 1 held the surface
/// where it had landed: 3.9 % of the largest displacement on average; at 0.3, 0.8 %. The worst
/// vertices, a strip along one edge of an end, stay about 20 % off either way (NOTES 178).
#[test]
fn a_plain_box_twisted_about_its_long_axis_is_registered() {
    use dynamap::slam::nonrigid::{register_mesh_pair, Seeding, SurfaceVerdict};
    let size = [0.6, 0.3, 0.15];
    let source = box_surface([16, 16, 16], size);
    let twist = |p: &Point3<f32>| twisted(p, size);
    let mut target = source.clone();
    target.vertices = source.vertices.iter().map(twist).collect();
    target.compute_normals();
    let reg = register_mesh_pair(&source, &target, &Seeding::default()).unwrap();
    let errors: Vec<f64> = (reg.points.iter().zip(&target.vertices))
        .map(|(p, t)| (p - t.coords.cast::<f64>()).norm())
        .collect();
    let reach = (source.vertices.iter().zip(&target.vertices))
        .map(|(s, t)| f64::from((s - t).norm()))
        .fold(0.0, f64::max);
    let max = errors.iter().fold(0.0, |m: f64, &e| m.max(e)) / reach;
    let mean = errors.iter().sum::<f64>() / errors.len() as f64 / reach;
    eprintln!("twisted box: largest displacement {reach:.4} m, error max {max:.4}, mean {mean:.4}");
    assert!(reach > 0.04, "the twist hardly moved the box: {reach}");
    assert!(mean <= 0.015 && max <= 0.3, "max {max}, mean {mean}");
    // a box slides nowhere along itself (NOTES 179)
    assert_eq!(
        reg.verdict(),
        SurfaceVerdict::Registered,
        "{:?}",
        reg.slippage
    );
}

/// The twisted box of the test above registered onto a target meshed apart: sampled half as
/// finely (8 squares a side) and twice as finely (32). Matched to a coarser target's vertices,
/// every point was drawn along the faces towards them, and onto a finer one the target's
/// vertices between the source's rows counted as uncovered and pulled: 37.5 and 22.8 % of the
/// largest displacement on average, 107 and 102 % at worst; now 6.8 and 2.7 %, 16 and 11 %
/// (NOTES 185). Each vertex is scored against where the twist sends it.
#[test]
fn a_box_registered_onto_a_copy_meshed_apart_follows_the_twist() {
    use dynamap::slam::nonrigid::{register_mesh_pair, Seeding};
    let size = [0.6, 0.3, 0.15];
    let twist = |p: &Point3<f32>| twisted(p, size);
    let source = box_surface([16, 16, 16], size);
    let truth: Vec<Point3<f32>> = source.vertices.iter().map(twist).collect();
    let reach = (source.vertices.iter().zip(&truth))
        .map(|(s, t)| f64::from((s - t).norm()))
        .fold(0.0, f64::max);
    for cells in [8, 32] {
        let mut target = box_surface([cells; 3], size);
        target.vertices = target.vertices.iter().map(twist).collect();
        target.compute_normals();
        let reg = register_mesh_pair(&source, &target, &Seeding::default()).unwrap();
        let errors: Vec<f64> = (reg.points.iter().zip(&truth))
            .map(|(p, t)| (p - t.coords.cast::<f64>()).norm() / reach)
            .collect();
        let max = errors.iter().fold(0.0, |m: f64, &e| m.max(e));
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        eprintln!("box onto {cells} a side: error max {max:.4}, mean {mean:.4}");
        assert!(
            mean <= 0.1 && max <= 0.25,
            "{cells} a side: max {max}, mean {mean}"
        );
    }
}

/// A capped cylinder (the box's surface with each cross-section's square pressed onto the circle
/// through its sides' midpoints: 32 facets round) bent about an axis across it. It fits its
/// target, but turned about its own axis it fits as well, so where its vertices lie round that
/// axis is not known: the registration reports itself ambiguous, naming the turn (NOTES 179).
#[test]
fn a_cylinder_bent_fits_but_is_reported_ambiguous_about_its_axis() {
    use dynamap::slam::nonrigid::{register_mesh_pair, Seeding, SurfaceVerdict};
    let (length, r) = (0.6, 0.1);
    let mut source = box_surface([16, 8, 8], [length, 2.0 * r, 2.0 * r]);
    for p in &mut source.vertices {
        let (y, z) = (f64::from(p.y) - r, f64::from(p.z) - r);
        let squeeze = y.abs().max(z.abs()) / y.hypot(z).max(1e-12);
        (p.y, p.z) = ((y * squeeze) as f32, (z * squeeze) as f32);
    }
    source.compute_normals();
    let radius = 1.0;
    let bend = |p: &Point3<f32>| {
        let a = (f64::from(p.x) - length / 2.0) / radius;
        let out = radius - f64::from(p.z);
        let (s, c) = a.sin_cos();
        Point3::new((out * s) as f32, p.y, (radius - out * c) as f32)
    };
    let mut target = source.clone();
    target.vertices = source.vertices.iter().map(bend).collect();
    target.compute_normals();
    let reg = register_mesh_pair(&source, &target, &Seeding::default()).unwrap();
    assert!(
        reg.fit.verdict() == SurfaceVerdict::Registered,
        "{:?}",
        reg.fit
    );
    let SurfaceVerdict::Ambiguous(slip) = reg.verdict() else {
        panic!("{:?} {:?}", reg.verdict(), reg.slippage);
    };
    assert!(slip.rotation.normalize().x.abs() > 0.99, "{slip:?}");
}
