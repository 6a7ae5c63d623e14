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
    /// A walk round the ring corridor of `layouts::Layout::Corridor` ([`CORRIDOR`]) along its
    /// middle, once every [`CORRIDOR_LAP`] seconds (0.46 m/s), looking 45° outwards from the
    /// direction of travel and 15° down at the outer wall, with a hand-held sway: an 18-m loop
    /// whose start is seen again only after a lap, where drift builds up with nothing older to
    /// snap to.
    Corridor,
    /// A walk round the gallery of `layouts::Layout::Gallery` ([`GALLERY`]) along the middle of
    /// its 2.4-m hall, once every [`GALLERY_LAP`] seconds (0.5 m/s), looking 45° inwards from the
    /// direction of travel (at the central block and its pillars) and 10° down: a 23-m loop, 1.5
    /// laps in 2000 frames at 30 Hz.
    Gallery,
}

/// A ring corridor: the space between an outer rectangle and a central block, both centred on
/// the origin with sides along x and y.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ring {
    /// The outer walls' half-sizes along x and y, metres.
    pub outer: (f64, f64),
    /// The central block's half-sizes along x and y, metres.
    pub inner: (f64, f64),
    /// The ceiling's height, metres.
    pub height: f64,
}

/// The corridor of [`Motion::Corridor`]: 1.6 m wide all round, 2.6 m high.
pub const CORRIDOR: Ring = Ring {
    outer: (3.6, 2.8),
    inner: (2.0, 1.2),
    height: 2.6,
};

/// Seconds per lap of [`Motion::Corridor`].
pub const CORRIDOR_LAP: f64 = 40.0;

/// The hall of [`Motion::Gallery`]: 2.4 m wide all round, 3.2 m high.
pub const GALLERY: Ring = Ring {
    outer: (4.8, 3.6),
    inner: (2.4, 1.2),
    height: 3.2,
};

/// Seconds per lap of [`Motion::Gallery`].
pub const GALLERY_LAP: f64 = 45.0;

impl Ring {
    /// Half-sizes of the corridor's middle line.
    fn middle(&self) -> (f64, f64) {
        (
            (self.outer.0 + self.inner.0) / 2.0,
            (self.outer.1 + self.inner.1) / 2.0,
        )
    }

    /// The radius of the middle line's rounded corners: a third of the corridor's width.
    fn corner_radius(&self) -> f64 {
        (self.outer.0 - self.inner.0).min(self.outer.1 - self.inner.1) / 3.0
    }

    /// The length of the middle line (a rectangle with rounded corners).
    pub fn lap_length(&self) -> f64 {
        let (cx, cy) = self.middle();
        let r = self.corner_radius();
        4.0 * (cx - r) + 4.0 * (cy - r) + std::f64::consts::TAU * r
    }

    /// The point `s` metres along the middle line (anticlockwise seen from above, from the middle
    /// of the side at +x) and the heading there (radians from +x).
    pub fn along(&self, s: f64) -> (Point3<f64>, f64) {
        let (cx, cy) = self.middle();
        let r = self.corner_radius();
        let dir = |a: f64| Vector3::new(a.cos(), a.sin(), 0.0);
        let mut s = s.rem_euclid(self.lap_length());
        let mut p = Point3::new(cx, 0.0, 0.0);
        let mut heading = std::f64::consts::FRAC_PI_2;
        // half a side, then a corner, then three whole sides and corners, then half a side
        let sides = [
            cy - r,
            2.0 * (cx - r),
            2.0 * (cy - r),
            2.0 * (cx - r),
            cy - r,
        ];
        for (k, &length) in sides.iter().enumerate() {
            if s <= length || k == sides.len() - 1 {
                return (p + dir(heading) * s.min(length), heading);
            }
            s -= length;
            p += dir(heading) * length;
            let centre = p + dir(heading + std::f64::consts::FRAC_PI_2) * r;
            let arc = r * std::f64::consts::FRAC_PI_2;
            if s <= arc {
                let turned = heading + s / r;
                return (
                    centre - dir(turned + std::f64::consts::FRAC_PI_2) * r,
                    turned,
                );
            }
            s -= arc;
            heading += std::f64::consts::FRAC_PI_2;
            p = centre - dir(heading + std::f64::consts::FRAC_PI_2) * r;
        }
        unreachable!("the last side returns")
    }
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
            Motion::Corridor => ring_walk(&RingWalk::CORRIDOR, f / fps),
            Motion::Gallery => ring_walk(&RingWalk::GALLERY, f / fps),
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

/// A hand-held walk along a [`Ring`]'s middle line.
struct RingWalk {
    ring: Ring,
    /// Seconds per lap.
    lap: f64,
    /// Where the camera looks, radians from the direction of travel (positive: to the left,
    /// which is inwards on the anticlockwise walk).
    turn: f64,
    /// How far it looks down, radians.
    down: f64,
}

impl RingWalk {
    const CORRIDOR: RingWalk = RingWalk {
        ring: CORRIDOR,
        lap: CORRIDOR_LAP,
        turn: -std::f64::consts::FRAC_PI_4,
        down: 15.0 * (std::f64::consts::PI / 180.0),
    };
    const GALLERY: RingWalk = RingWalk {
        ring: GALLERY,
        lap: GALLERY_LAP,
        turn: std::f64::consts::FRAC_PI_4,
        down: 10.0 * (std::f64::consts::PI / 180.0),
    };
}

/// The pose of a [`RingWalk`] at `t` seconds ([`Motion::Corridor`], [`Motion::Gallery`]).
fn ring_walk(w: &RingWalk, t: f64) -> Isometry3<f64> {
    let ring = w.ring;
    let s = |hz: f64, p: f64| (std::f64::consts::TAU * hz * t + p).sin();
    let (middle, heading) = ring.along(ring.lap_length() * t / w.lap);
    let eye = Point3::new(middle.x, middle.y, 1.4 + 0.05 * s(0.17, 0.0));
    let look = heading + w.turn + 0.12 * s(0.09, 1.0);
    let dir = Vector3::new(look.cos(), look.sin(), -w.down.tan());
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
            Motion::Corridor,
            Motion::Gallery,
        ] {
            let t = procedural(m, 10, 30.0);
            assert_eq!(t.len(), 10);
        }
    }

    /// The corridor's and the gallery's walks stay on the ring's middle line, move at a steady
    /// speed through the corners (no jump where a side meets a corner), and are back at their
    /// start after one lap.
    #[test]
    fn the_ring_walks_are_smooth_closed_loops_inside_their_rings() {
        ring_walk_is_a_smooth_closed_loop(Motion::Corridor, &RingWalk::CORRIDOR);
        ring_walk_is_a_smooth_closed_loop(Motion::Gallery, &RingWalk::GALLERY);
    }

    fn ring_walk_is_a_smooth_closed_loop(m: Motion, w: &RingWalk) {
        let ring = w.ring;
        let fps = 30.0;
        let frames = (w.lap * fps) as usize + 1;
        let t = procedural(m, frames, fps);
        let speed = ring.lap_length() / w.lap / fps;
        for w in t.poses.windows(2) {
            let step = (w[1].translation.vector - w[0].translation.vector)
                .xy()
                .norm();
            assert!(
                (step - speed).abs() < 0.05 * speed,
                "{step} against {speed}"
            );
            assert!(w[1].rotation.angle_to(&w[0].rotation) < 3f64.to_radians());
        }
        for p in &t.poses {
            let (x, y) = (p.translation.x.abs(), p.translation.y.abs());
            // inside the outer walls, outside the block, by at least half a metre
            assert!(x < ring.outer.0 - 0.5 && y < ring.outer.1 - 0.5, "{x} {y}");
            assert!(x > ring.inner.0 + 0.5 || y > ring.inner.1 + 0.5, "{x} {y}");
        }
        let lap = t.poses[frames - 1].translation.vector - t.poses[0].translation.vector;
        assert!(lap.xy().norm() < 1e-9, "{lap}");
        // on the side at +x the corridor's camera looks outwards (+x), the gallery's inwards
        let x = (t.poses[0].rotation * Vector3::z()).x;
        assert!(x * -w.turn.signum() > 0.5, "{m:?} looks {x} along x");
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
