//! Camera trajectories for rendered sequences: procedural motions about the room's table, or a real
//! trajectory read from a TUM ground-truth file with the room placed where that camera looks.

use crate::io::trajectory::Trajectory;
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// Procedural camera motions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Motion {
    /// Circling the table at 1.8 m, 0.8° per frame.
    Orbit,
    /// Standing 1.8 m from the table with a smooth hand-held shake (±3 cm, ±2°).
    Shake,
    /// Turning on the spot at 3° per frame.
    FastRotation,
    /// A fast hand-held sweep in front of the table: sideways at up to 0.9 m/s and shaking at up
    /// to about 100°/s (at 30 Hz).
    Sweep,
    /// A survey of the room's walls: walking an ellipse (1.0 × 0.8 m) about the room's middle
    /// once every 30 s (at 30 Hz), looking outwards and down at the walls and floor with a gentle
    /// hand-held sway, so that the camera returns to each place 30 s after it left and the table
    /// (behind it) is never in view: a loop for loop closure.
    Survey,
}

/// The point the room's objects are arranged around (the table top).
pub const TARGET: Point3<f64> = Point3::new(0.0, 0.0, 0.8);

/// Camera-to-world pose of a camera at `eye` looking at `target` with `up` pointing up in the image
/// (x right, y down, z forward).
pub fn look_at(eye: &Point3<f64>, target: &Point3<f64>, up: &Vector3<f64>) -> Isometry3<f64> {
    let z = (target - eye).normalize();
    let x = z
        .cross(up)
        .try_normalize(1e-9)
        .unwrap_or_else(|| z.cross(&Vector3::x()).normalize());
    let y = z.cross(&x);
    let r = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
    Isometry3::from_parts(
        Translation3::from(eye.coords),
        UnitQuaternion::from_rotation_matrix(&r),
    )
}

/// `frames` poses of a procedural motion at `fps` frames per second, starting at time 0.
pub fn procedural(motion: Motion, frames: usize, fps: f64) -> Trajectory {
    let mut t = Trajectory::default();
    let up = Vector3::z();
    for k in 0..frames {
        let f = k as f64;
        let pose = match motion {
            Motion::Orbit => {
                let a = (0.8 * f).to_radians();
                let eye = Point3::new(1.8 * a.cos(), 1.8 * a.sin(), 1.4);
                look_at(&eye, &TARGET, &up)
            }
            Motion::Shake => {
                let s = |w: f64, p: f64| (w * f / fps + p).sin();
                let eye = Point3::new(
                    1.8 + 0.03 * s(2.1, 0.0),
                    0.03 * s(2.9, 1.0),
                    1.4 + 0.03 * s(3.7, 2.0),
                );
                let base = look_at(&eye, &TARGET, &up);
                let wobble = UnitQuaternion::from_scaled_axis(
                    Vector3::new(s(4.3, 0.5), s(3.1, 1.5), s(5.3, 2.5)) * 2f64.to_radians(),
                );
                Isometry3::from_parts(base.translation, base.rotation * wobble)
            }
            Motion::Sweep => {
                let t = f / fps;
                let s = |hz: f64, p: f64| (std::f64::consts::TAU * hz * t + p).sin();
                let eye = Point3::new(
                    1.8 + 0.15 * s(0.3, 0.4),
                    0.36 * s(0.4, 0.0),
                    1.4 + 0.1 * s(0.5, 1.0),
                );
                let base = look_at(&eye, &TARGET, &up);
                let shake = UnitQuaternion::from_scaled_axis(
                    Vector3::new(0.4 * s(0.9, 0.3), s(1.2, 1.1), 0.3 * s(0.7, 2.0))
                        * 12f64.to_radians(),
                );
                Isometry3::from_parts(base.translation, base.rotation * shake)
            }
            Motion::Survey => survey(f / fps),
            Motion::FastRotation => {
                let a = (3.0 * f).to_radians();
                let eye = Point3::new(0.9, 0.3, 1.3);
                let dir = Vector3::new(a.cos(), a.sin(), -0.25);
                look_at(&eye, &(eye + dir), &up)
            }
        };
        t.push(f / fps, pose);
    }
    t
}

/// The pose of [`Motion::Survey`] at `t` seconds.
fn survey(t: f64) -> Isometry3<f64> {
    let a = std::f64::consts::TAU * t / 30.0;
    let s = |hz: f64, p: f64| (std::f64::consts::TAU * hz * t + p).sin();
    let eye = Point3::new(1.0 * a.cos(), 0.8 * a.sin(), 1.4 + 0.08 * s(0.13, 0.0));
    // outwards, turned 25° towards the direction of travel, 20° down
    let heading = a + 25f64.to_radians() + 0.1 * s(0.07, 1.0);
    let dir = Vector3::new(heading.cos(), heading.sin(), -(20f64.to_radians()).tan());
    let base = look_at(&eye, &(eye + dir), &Vector3::z());
    let sway = UnitQuaternion::from_scaled_axis(
        Vector3::new(s(0.5, 0.3), s(0.4, 1.1), 0.5 * s(0.3, 2.0)) * 2f64.to_radians(),
    );
    Isometry3::from_parts(base.translation, base.rotation * sway)
}

/// Picks from a (denser) ground-truth trajectory the poses nearest to `fps` frames per second,
/// `frames` of them from the first stamp: poses are taken as they are, never interpolated, so the
/// rendered sequence's ground truth is a subset of the file's.
pub fn resample(gt: &Trajectory, frames: usize, fps: f64) -> Trajectory {
    let mut out = Trajectory::default();
    if gt.is_empty() {
        return out;
    }
    let t0 = gt.stamps[0];
    let mut j = 0;
    for k in 0..frames {
        let want = t0 + k as f64 / fps;
        while j + 1 < gt.len() && (gt.stamps[j + 1] - want).abs() <= (gt.stamps[j] - want).abs() {
            j += 1;
        }
        if want > gt.stamps[gt.len() - 1] + 0.5 / fps
            || out.stamps.last().is_some_and(|&s| s >= gt.stamps[j])
        {
            break; // the file ran out
        }
        out.push(gt.stamps[j], gt.poses[j]);
    }
    out
}

/// The rigid transform that carries a real trajectory's world into the room's frame: the point the
/// cameras look at (least squares to all optical axes, pulled towards 1.5 m in front of the mean
/// camera where the axes are near parallel) goes to [`TARGET`], the mean image "up" to +z.
pub fn world_to_room(gt: &Trajectory) -> Isometry3<f64> {
    let n = gt.len().max(1) as f64;
    let mean_pos = gt
        .poses
        .iter()
        .map(|p| p.translation.vector)
        .sum::<Vector3<f64>>()
        / n;
    let mean_axis = gt
        .poses
        .iter()
        .map(|p| p.rotation * Vector3::z())
        .sum::<Vector3<f64>>()
        .normalize();
    let prior = mean_pos + mean_axis * 1.5;
    let lambda = 0.05 * n;
    let (mut a, mut b) = (Matrix3::identity() * lambda, prior * lambda);
    for p in &gt.poses {
        let v = p.rotation * Vector3::z();
        let m = Matrix3::identity() - v * v.transpose();
        a += m;
        b += m * p.translation.vector;
    }
    let target = a.lu().solve(&b).unwrap_or(prior);
    let up = -gt
        .poses
        .iter()
        .map(|p| p.rotation * Vector3::y())
        .sum::<Vector3<f64>>()
        .normalize();
    let rot = UnitQuaternion::rotation_between(&up, &Vector3::z())
        .unwrap_or_else(|| UnitQuaternion::from_scaled_axis(Vector3::x() * std::f64::consts::PI));
    let t = TARGET.coords - rot * target;
    Isometry3::from_parts(Translation3::from(t), rot)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn look_at_points_the_optical_axis_at_the_target() {
        let eye = Point3::new(2.0, 1.0, 1.5);
        let pose = look_at(&eye, &TARGET, &Vector3::z());
        let axis = pose.rotation * Vector3::z();
        assert!((axis - (TARGET - eye).normalize()).norm() < 1e-12);
        // image "down" points downwards in the world
        assert!((pose.rotation * Vector3::y()).z < 0.0);
        for m in [
            Motion::Orbit,
            Motion::Shake,
            Motion::FastRotation,
            Motion::Survey,
        ] {
            let t = procedural(m, 10, 30.0);
            assert_eq!(t.len(), 10);
        }
    }

    #[test]
    fn resampling_keeps_poses_exactly() {
        let mut gt = Trajectory::default();
        for k in 0..100 {
            gt.push(
                5.0 + k as f64 * 0.01,
                look_at(
                    &Point3::new(k as f64 * 0.01, 0.0, 1.0),
                    &TARGET,
                    &Vector3::z(),
                ),
            );
        }
        let r = resample(&gt, 10, 30.0);
        assert_eq!(r.len(), 10);
        for (s, p) in r.stamps.iter().zip(&r.poses) {
            let j = gt.stamps.iter().position(|g| g == s).unwrap();
            assert_eq!(&gt.poses[j], p);
        }
        // 0.99 s of poses hold 31 frames at 30 Hz (the last at 1.0 s takes the pose at 0.99 s).
        assert_eq!(resample(&gt, 1000, 30.0).len(), 31);
    }
}
