//! The cone of rays a camera casts, for leaving out of a frame's ray casting the objects that
//! none of its rays can meet.
//!
//! A camera at C with unit optical axis a casts rays within the half-angle θ of a. A point x lies
//! at the distance
//!
//! dist(x) = max(0, ρ cos θ − α sin θ) when α cos θ + ρ sin θ ≥ 0, else |x − C|,
//!
//! from that cone, with α = (x − C)·a and ρ = |(x − C) − α a| (in the plane of a and x − C the
//! cone's edge is the half-line from C at the angle θ from a). A ball of radius r meets the cone
//! only if its centre lies within r of it.
//!
//! The sensor's shadow rays run from a point P on a primary ray to an eye E within `reach` of C
//! (the structured-light projector and the infrared camera). A point of the segment,
//! (1 − s) P + s E = (1 − s) P + s C + s (E − C), lies within s · reach of the cone, which holds
//! (1 − s) P + s C; so a ball that stays farther than `reach` from the cone meets no shadow ray
//! either.

use crate::camera::Camera;
use nalgebra::{Isometry3, Point3, Vector3};

/// Relative slack on a ball's radius, above the ray–sphere test's own (1e-9 on r²).
const RELATIVE_SLACK: f64 = 1e-6;
/// Absolute slack, metres: the shadow rays start 1e-6 off the surface.
const ABSOLUTE_SLACK: f64 = 1e-5;

/// Every ray a camera at a pose casts, and the segments from the points they meet to eyes near
/// its centre.
#[derive(Clone, Copy, Debug)]
pub struct ViewCone {
    apex: Point3<f64>,
    axis: Vector3<f64>,
    cos: f64,
    sin: f64,
    reach: f64,
}

impl ViewCone {
    /// The cone of a camera at `pose` (camera-to-world) whose rays (x, y, 1) in its frame have
    /// |(x, y)| ≤ `tan_half_angle`, with shadow rays to eyes within `reach` metres of its centre.
    pub fn new(pose: &Isometry3<f64>, tan_half_angle: f64, reach: f64) -> Self {
        let angle = tan_half_angle.max(0.0).atan();
        Self {
            apex: Point3::from(pose.translation.vector),
            axis: pose.rotation * Vector3::z(),
            cos: angle.cos(),
            sin: angle.sin(),
            reach: reach.max(0.0),
        }
    }

    /// The cone of an undistorted `camera` at `pose`: its widest ray passes through a corner
    /// pixel's centre.
    pub fn of_camera(camera: &Camera, pose: &Isometry3<f64>, reach: f64) -> Self {
        let (u, v) = ((camera.width - 1) as f64, (camera.height - 1) as f64);
        let widest = [(0.0, 0.0), (u, 0.0), (0.0, v), (u, v)]
            .iter()
            .map(|&(u, v)| {
                let r = camera.ray(u, v);
                r.x.hypot(r.y) / r.z
            })
            .fold(0.0, f64::max);
        Self::new(pose, widest, reach)
    }

    /// The camera's centre, from which every primary ray starts.
    pub fn apex(&self) -> Point3<f64> {
        self.apex
    }

    /// Whether a ball at `centre` of squared radius `radius2` may meet one of the rays or
    /// shadow rays (the module's documentation): false only where none can.
    pub fn may_meet(&self, centre: &Point3<f64>, radius2: f64) -> bool {
        let v = centre - self.apex;
        let along = v.dot(&self.axis);
        let off = (v - self.axis * along).norm();
        let dist = if along * self.cos + off * self.sin >= 0.0 {
            off * self.cos - along * self.sin
        } else {
            v.norm()
        };
        let slack = radius2.sqrt() * (1.0 + RELATIVE_SLACK) + self.reach + ABSOLUTE_SLACK;
        dist.is_nan() || dist <= slack
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The nearest approach of a segment a→b to `centre`.
    fn segment_distance(a: &Point3<f64>, b: &Point3<f64>, centre: &Point3<f64>) -> f64 {
        let ab = b - a;
        let s = ((centre - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0);
        (a + ab * s - centre).norm()
    }

    #[test]
    fn a_ball_that_a_ray_or_shadow_ray_meets_is_never_left_out() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let pose = Isometry3::from_parts(
            Translation3::new(0.4, -1.0, 1.2),
            UnitQuaternion::from_euler_angles(0.3, -1.1, 2.0),
        );
        let (tan, reach) = (0.6, 0.05);
        let cone = ViewCone::new(&pose, tan, reach);
        let (mut met, mut left_out) = (0, 0);
        for _ in 0..20_000 {
            let centre = Point3::new(
                rng.random_range(-4.0..4.0),
                rng.random_range(-4.0..4.0),
                rng.random_range(-4.0..4.0),
            );
            let radius: f64 = rng.random_range(0.01..1.0);
            // a ray within the cone, to a point at depth z, and an eye within reach
            let (x, y) = (rng.random_range(-tan..tan), rng.random_range(-tan..tan));
            if x.hypot(y) > tan {
                continue;
            }
            let z = rng.random_range(0.1..8.0);
            let p = pose * Point3::new(x * z, y * z, z);
            let eye = pose * Point3::new(rng.random_range(-reach..reach), 0.0, 0.0);
            let meets = segment_distance(&cone.apex, &p, &centre) <= radius
                || segment_distance(&p, &eye, &centre) <= radius;
            if meets {
                met += 1;
                assert!(cone.may_meet(&centre, radius * radius), "{centre} {radius}");
            } else if !cone.may_meet(&centre, radius * radius) {
                left_out += 1;
            }
        }
        // the test is not empty either way: balls were met, and others left out
        assert!(
            met > 100 && left_out > 1000,
            "{met} met, {left_out} left out"
        );
    }

    #[test]
    fn a_corridor_frame_meets_the_same_surfaces_against_fewer_objects() {
        use crate::synthetic::layouts::{build, Layout};
        use crate::synthetic::motion::{procedural, Motion};
        let scene = build(Layout::Corridor, 71);
        let camera = Camera::scaled_default(64, 48);
        let every = scene.prepare();
        let (eye, mut left_out, mut shadowed) = (Point3::new(0.05, 0.0, 0.0), 0, 0);
        for pose in procedural(Motion::Corridor, 400, 15.0)
            .poses
            .iter()
            .step_by(40)
        {
            // `near` casts its primary rays by the parts worked out once for the camera's
            // centre (scene::Eye), `every` ray by ray: the same hits to the bit
            let near = every.within(&ViewCone::of_camera(&camera, pose, 0.05));
            left_out += every.len() - near.len();
            let origin = Point3::from(pose.translation.vector);
            for i in 0..camera.width * camera.height {
                let ray = camera.ray((i % camera.width) as f64, (i / camera.width) as f64);
                let dir = pose.rotation * ray;
                let hit = every.intersect(&origin, &dir);
                assert_eq!(hit, near.intersect(&origin, &dir));
                let Some(hit) = hit else { continue };
                // a shadow ray from the hit to an eye 5 cm beside the camera
                let to = pose * eye - hit.point;
                let (from, d) = (hit.point + hit.normal * 1e-6, to.normalize());
                let blocked = every.blocked(&from, &d, to.norm() - 1e-6);
                assert_eq!(blocked, near.blocked(&from, &d, to.norm() - 1e-6));
                shadowed += usize::from(blocked);
            }
        }
        assert!(
            left_out > 0 && shadowed > 0,
            "{left_out} left out, {shadowed} shadowed"
        );
    }

    #[test]
    fn a_ball_behind_the_camera_or_beside_its_view_is_left_out() {
        let cone = ViewCone::new(&Isometry3::identity(), 0.5, 0.05);
        assert!(!cone.may_meet(&Point3::new(0.0, 0.0, -2.0), 1.0));
        assert!(!cone.may_meet(&Point3::new(3.0, 0.0, 1.0), 0.25));
        assert!(cone.may_meet(&Point3::new(0.0, 0.0, -0.5), 0.36));
        assert!(cone.may_meet(&Point3::new(0.4, 0.0, 1.0), 0.0));
        assert!(cone.may_meet(&Point3::new(0.0, 0.0, 0.0), 0.0));
    }
}
