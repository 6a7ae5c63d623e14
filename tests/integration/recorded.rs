//! Tracking a sequence as the Kinect model records it: each frame's depth and colour at their
//! own stamps, every frame required to be tracked.

use dynamap::slam::camera::Camera;
use dynamap::slam::io::trajectory::Trajectory;
use dynamap::slam::rigid::{FrameReport, FrameStamps, RigidSlam, SlamParams};
use dynamap::slam::synthetic::kinect::{KinectFrame, KinectModel};
use dynamap::slam::synthetic::scene::Scene;

/// Tracks the camera moving along `gt` through `scene` as `model` records it with `camera`,
/// from the first true pose and with the default settings; `each` sees every frame's index,
/// recording and report. Panics on a frame that is not tracked.
pub fn track_recorded(
    camera: Camera,
    model: &KinectModel,
    scene: &Scene,
    gt: &Trajectory,
    mut each: impl FnMut(usize, &KinectFrame, &FrameReport),
) {
    let recorder = model.recorder(&camera);
    let mut slam = RigidSlam::new(camera, SlamParams::default(), gt.poses[0]);
    for k in 0..gt.len() {
        let f = recorder.capture(scene, gt, k);
        let stamps = FrameStamps {
            depth: gt.stamps[k],
            color: f.color_stamp,
        };
        let report = slam.process_timed(&f.depth, Some(&f.color), stamps);
        assert!(
            report.failure().is_none(),
            "frame {k}: {:?}",
            report.outcome
        );
        each(k, &f, &report);
    }
}
