//! Which older keyframes a new keyframe is tried against for a dense loop, and whether a loop
//! found agrees with the track that led there.
//!
//! Appearance alone (the fern codes) cannot tell a place from its look-alike: in a room with two
//! identical halves the nearest codes are often the twin's, and the twin also fits densely. Two
//! cues that appearance lacks are used beside it, as in ElasticFusion (Whelan et al., RSS 2015),
//! whose local loop closure registers against the model near the tracked pose:
//! - *where the track says the camera is*: keyframes of the same map fragment whose tracked
//!   poses lie near the new keyframe's are candidates too ([`nearby`]);
//! - *whether the loop agrees with the track*: a loop whose pose lies within the odometry's
//!   expected drift of the tracked pose ([`agrees_with_track`]) is preferred over one that does
//!   not, whatever their fit. A loop that does not agree is still kept when nothing agrees (the
//!   track may have drifted far, or the keyframe lies in another fragment); the pose graph's
//!   robust kernel then judges it.
//!
//! A loop of the same fragment is also tracked a second time, from the new keyframe's tracked
//! pose, and kept only if both tracks end in one place ([`settled_alike`]): a dense
//! registration started up to half a scene depth away can stop short along a motion the view
//! barely fixes, as along a corridor, and then measures the loop centimetres off.

use super::keyframes::Keyframe;
use super::loops::LoopParams;
use nalgebra::Isometry3;

/// Nearby keyframes lie within this share of the scene's median depth of the new one...
const NEAR_DEPTH_SHARE: f64 = 0.5;
/// ... and within this angle, radians (30°: most of a 60° field of view still overlaps).
const NEAR_ANGLE: f64 = std::f64::consts::FRAC_PI_6;

/// The indices (into `frames`) of up to `count` keyframes among `frames[..limit]` taken at or
/// after frame `since` (the current map fragment, which odometry joins to the new keyframe),
/// whose poses lie within [`NEAR_DEPTH_SHARE`] × `depth` and [`NEAR_ANGLE`] of `pose`, nearest
/// first (distance over that radius plus angle over that angle).
pub(super) fn nearby(
    frames: &[Keyframe],
    limit: usize,
    since: usize,
    pose: &Isometry3<f64>,
    depth: f64,
    count: usize,
) -> Vec<usize> {
    let radius = NEAR_DEPTH_SHARE * depth.max(0.1);
    let mut ranked: Vec<(f64, usize)> = frames[..limit.min(frames.len())]
        .iter()
        .enumerate()
        .filter(|(_, f)| f.frame >= since)
        .filter_map(|(k, f)| {
            let d = f.pose.inverse() * pose;
            let (t, r) = (d.translation.vector.norm(), d.rotation.angle());
            (t <= radius && r <= NEAR_ANGLE).then_some((t / radius + r / NEAR_ANGLE, k))
        })
        .collect();
    ranked.sort_by(|a, b| a.0.total_cmp(&b.0));
    ranked.into_iter().take(count).map(|(_, k)| k).collect()
}

/// Whether `found`, the pose a dense loop gives the new keyframe, lies within three deviations
/// of `tracked`, the pose the track gave it, when the track joins it to the keyframe of tracked
/// pose `poses[k]` (`poses`: the keyframes' tracked poses, oldest first): the odometry's
/// deviation grows by [`LoopParams::odometry_drift`] per metre and per radian travelled between
/// the keyframes (from `poses[k]` through every later keyframe to `tracked`), plus
/// [`LoopParams::odometry_floor`], and the loop's own deviation ([`LoopParams::loop_deviation`]
/// of `depth`) adds to it.
pub(super) fn agrees_with_track(
    poses: &[Isometry3<f64>],
    k: usize,
    tracked: &Isometry3<f64>,
    found: &Isometry3<f64>,
    params: &LoopParams,
    depth: f64,
) -> bool {
    let (metres, radians) = travelled(poses, k, tracked);
    let (loop_r, loop_t) = params.loop_deviations(depth);
    let d = tracked.inverse() * found;
    d.translation.vector.norm() <= 3.0 * (params.odometry_deviation(metres) + loop_t)
        && d.rotation.angle() <= 3.0 * (params.odometry_deviation(radians) + loop_r)
}

/// Whether `first` and `second`, where two dense tracks of one loop ended (started from the
/// old keyframe's pose and from the new keyframe's tracked pose), lie within one loop
/// deviation ([`LoopParams::loop_deviations`] at `depth`) of each other. A registration that
/// the model's shape and texture fix ends in one place from either start; one that ends
/// elsewhere settled where its start left it along a motion they barely fix (a corridor the
/// camera slides along), and its pose is off by about as much (NOTES 116).
pub(super) fn settled_alike(
    first: &Isometry3<f64>,
    second: &Isometry3<f64>,
    params: &LoopParams,
    depth: f64,
) -> bool {
    let (sigma_r, sigma_t) = params.loop_deviations(depth);
    let d = first.inverse() * second;
    d.translation.vector.norm() <= sigma_t && d.rotation.angle() <= sigma_r
}

/// The path length and the rotation summed along the keyframe poses from `poses[k]` to `last`.
fn travelled(poses: &[Isometry3<f64>], k: usize, last: &Isometry3<f64>) -> (f64, f64) {
    let poses = poses[k.min(poses.len())..].iter();
    let next = poses.clone().skip(1).chain(std::iter::once(last));
    poses.zip(next).fold((0.0, 0.0), |(t, r), (a, b)| {
        let d = a.inverse() * b;
        (t + d.translation.vector.norm(), r + d.rotation.angle())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::Keypoints;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn keyframe(frame: usize, pose: Isometry3<f64>) -> Keyframe {
        Keyframe {
            frame,
            pose,
            keypoints: Keypoints::default(),
            code: Vec::new(),
            agreement: None,
        }
    }

    /// Keyframes every 0.2 m along x, facing the same way, at frames 0, 30, 60, ...
    fn walk(n: usize) -> Vec<Keyframe> {
        (0..n)
            .map(|i| keyframe(30 * i, Isometry3::translation(0.2 * i as f64, 0.0, 0.0)))
            .collect()
    }

    #[test]
    fn nearby_keyframes_are_those_of_the_fragment_within_reach_nearest_first() {
        let frames = walk(10);
        let pose = Isometry3::translation(0.45, 0.0, 0.0);
        // depth 2 m: radius 1 m; keyframes at 0.4 and 0.6 m are nearest
        assert_eq!(nearby(&frames, 10, 0, &pose, 2.0, 3), vec![2, 3, 1]);
        // only the first five are old enough, and only those from frame 60 on in the fragment
        assert_eq!(nearby(&frames, 5, 60, &pose, 2.0, 10), vec![2, 3, 4]);
        // turned by 90°: nothing within 30°
        let turned = pose * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 1.5);
        assert!(nearby(&frames, 10, 0, &turned, 2.0, 3).is_empty());
        // a shallow scene shrinks the radius: 0.2 m at 0.4 m depth
        assert_eq!(nearby(&frames, 10, 0, &pose, 0.4, 5), vec![2, 3]);
    }

    #[test]
    fn two_starts_settle_alike_within_one_loop_deviation_of_the_scene_depth() {
        let params = LoopParams::default();
        let first = Isometry3::translation(1.0, 0.5, 0.0);
        let moved = |dx: f64, angle: f64| {
            first * Isometry3::new(Vector3::new(dx, 0.0, 0.0), Vector3::y() * angle)
        };
        // 1.5 m deep: 1.5 cm and 0.01 rad, in translation and in rotation alike
        assert!(settled_alike(&first, &moved(0.014, 0.009), &params, 1.5));
        assert!(!settled_alike(&first, &moved(0.016, 0.0), &params, 1.5));
        assert!(!settled_alike(&first, &moved(0.0, 0.011), &params, 1.5));
        // a deeper scene allows as much more: 3 cm at 3 m
        assert!(settled_alike(&first, &moved(0.029, 0.0), &params, 3.0));
        // the order of the two starts does not matter
        assert!(!settled_alike(&moved(0.016, 0.0), &first, &params, 1.5));
    }

    #[test]
    fn a_loop_agrees_with_the_track_within_the_drift_of_the_path_between() {
        let frames: Vec<Isometry3<f64>> = walk(10).iter().map(|f| f.pose).collect();
        let params = LoopParams::default();
        let tracked = Isometry3::translation(2.0, 0.0, 0.0);
        // 2 m travelled from keyframe 0: 3 (0.02 · 2 + 0.002) + 3 · 0.01 · 2 = 0.186 m
        let shifted = |dx: f64| Isometry3::translation(2.0 + dx, 0.0, 0.0);
        assert!(agrees_with_track(
            &frames,
            0,
            &tracked,
            &shifted(0.18),
            &params,
            2.0
        ));
        assert!(!agrees_with_track(
            &frames,
            0,
            &tracked,
            &shifted(0.19),
            &params,
            2.0
        ));
        // from keyframe 8 only 0.4 m were travelled: 3 (0.02 · 0.4 + 0.002) + 0.06 = 0.09 m
        assert!(agrees_with_track(
            &frames,
            8,
            &tracked,
            &shifted(0.085),
            &params,
            2.0
        ));
        assert!(!agrees_with_track(
            &frames,
            8,
            &tracked,
            &shifted(0.095),
            &params,
            2.0
        ));
        // a look-alike place turned by half a turn never agrees
        let twin = Isometry3::from_parts(
            Translation3::new(2.0, 0.0, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), std::f64::consts::PI),
        );
        assert!(!agrees_with_track(
            &frames, 0, &tracked, &twin, &params, 2.0
        ));
    }
}
