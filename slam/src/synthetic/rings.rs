//! Ring layouts: a loop round a central block, where the start is seen again only after a whole
//! lap, so drift builds up before a loop can close (issue 24's long looping sequences):
//! - `corridor`: a narrow ring corridor ([`CORRIDOR`]) with cabinets along its walls, walked
//!   looking outwards ([`super::motion::Motion::Corridor`]);
//! - `gallery`: a wider, higher hall ([`GALLERY`]) with pictures on its walls, pillars round
//!   the block and benches, walked looking inwards ([`super::motion::Motion::Gallery`]).

use super::motion::{Ring, CORRIDOR, GALLERY};
use super::scene::{Scene, Shape};
use super::texture::Texture;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::{FRAC_PI_2, PI};

/// A pose at (x, y, z) turned `yaw` about the vertical.
fn turn(x: f64, y: f64, z: f64, yaw: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_scaled_axis(Vector3::z() * yaw),
    )
}

/// A ring's four outer walls, each as its half-length and a frame on the floor at its middle
/// whose x runs along it and whose y points into the ring.
fn outer_walls(ring: &Ring) -> [(f64, Isometry3<f64>); 4] {
    let (ox, oy) = ring.outer;
    [
        (oy, turn(ox, 0.0, 0.0, FRAC_PI_2)),
        (ox, turn(0.0, oy, 0.0, PI)),
        (oy, turn(-ox, 0.0, 0.0, -FRAC_PI_2)),
        (ox, turn(0.0, -oy, 0.0, 0.0)),
    ]
}

/// The outer wall of half-length `half_length` standing on the floor frame `frame` (see
/// [`outer_walls`]), `height` high: its shape and pose.
fn upright_wall(half_length: f64, height: f64, frame: &Isometry3<f64>) -> (Shape, Isometry3<f64>) {
    let upright = Isometry3::rotation(Vector3::x() * FRAC_PI_2);
    let wall = Shape::Plane {
        hx: half_length,
        hy: height / 2.0,
    };
    (
        wall,
        frame * Isometry3::translation(0.0, 0.0, height / 2.0) * upright,
    )
}

/// A ring's central block's four sides, each as its half-length and a frame on the floor at its
/// middle whose x runs along it and whose y points out into the ring.
fn block_sides(ring: &Ring) -> [(f64, Isometry3<f64>); 4] {
    let (ix, iy) = ring.inner;
    [
        (iy, turn(ix, 0.0, 0.0, -FRAC_PI_2)),
        (ix, turn(0.0, iy, 0.0, 0.0)),
        (iy, turn(-ix, 0.0, 0.0, FRAC_PI_2)),
        (ix, turn(0.0, -iy, 0.0, PI)),
    ]
}

/// A texture drawn from the layout's `seed` and the part's number `k`, with wavenumbers from
/// `lo` to `hi` radians per metre.
fn tex(seed: u64, k: u64, lo: f64, hi: f64) -> Texture {
    Texture::random(seed.wrapping_mul(6151).wrapping_add(k), lo, hi)
}

/// A ring's floor, ceiling and central block (full height), textured with wavenumbers `floor`,
/// `ceiling` and `block`.
fn shell(
    ring: &Ring,
    seed: u64,
    floor: (f64, f64),
    ceiling: (f64, f64),
    block: (f64, f64),
) -> Scene {
    let mut s = Scene::default();
    let ((ox, oy), (ix, iy), h) = (ring.outer, ring.inner, ring.height);
    let plane = Shape::Plane { hx: ox, hy: oy };
    s.add(
        plane.clone(),
        Isometry3::identity(),
        tex(seed, 1, floor.0, floor.1),
    );
    s.add(
        plane,
        Isometry3::translation(0.0, 0.0, h),
        tex(seed, 2, ceiling.0, ceiling.1),
    );
    let half = Vector3::new(ix, iy, h / 2.0);
    s.add(
        Shape::Cuboid { half },
        Isometry3::translation(0.0, 0.0, h / 2.0),
        tex(seed, 3, block.0, block.1),
    );
    s
}

/// [`CORRIDOR`]'s floor, ceiling, outer walls (facing in) and central block, textured with
/// patterns of 0.2–1 m (posters and tiles; a wall textured like the room's, 0.4–3 m, seen from
/// 1 m at 640×480 holds too little gradient to fix a slide along the wall and the floor, and
/// such frames are refused as degenerate), with cabinets drawn from the seed along the outer
/// walls (0.16–0.4 m deep, 0.3–0.8 m wide, 0.4–1.2 m apart, from the corners on) and a few
/// along the block, so that the geometry holds a motion along the corridor too.
pub(super) fn corridor(seed: u64) -> Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xC0441D);
    let (ix, iy, h) = (CORRIDOR.inner.0, CORRIDOR.inner.1, CORRIDOR.height);
    let mut s = shell(&CORRIDOR, seed, (6.0, 30.0), (3.0, 12.0), (6.0, 30.0));
    let tex = |k: u64, lo: f64, hi: f64| tex(seed, k, lo, hi);
    for (k, &(half_length, frame)) in outer_walls(&CORRIDOR).iter().enumerate() {
        let k = k as u64;
        let (wall, at) = upright_wall(half_length, h, &frame);
        s.add(wall, at, tex(10 + k, 6.0, 30.0));
        let mut x = -half_length + rng.random_range(0.0..0.5);
        let mut n = 0;
        while x < half_length - 0.5 {
            let half = Vector3::new(
                rng.random_range(0.15..0.4),
                rng.random_range(0.08..0.2),
                rng.random_range(0.2..0.8),
            );
            let at = frame * Isometry3::translation(x + half.x, half.y, half.z);
            s.add(Shape::Cuboid { half }, at, tex(20 + 10 * k + n, 3.0, 25.0));
            x += 2.0 * half.x + rng.random_range(0.4..1.2);
            n += 1;
        }
    }
    // a few on the block's sides
    for k in 0..4u64 {
        let yaw = k as f64 * FRAC_PI_2;
        let (reach, along) = if k % 2 == 0 { (ix, iy) } else { (iy, ix) };
        let half = Vector3::new(
            rng.random_range(0.08..0.2),
            rng.random_range(0.2..0.4),
            rng.random_range(0.3..0.7),
        );
        let y = rng.random_range(-along + 0.5..along - 0.5);
        let at = turn(0.0, 0.0, 0.0, yaw) * Isometry3::translation(reach + half.x, y, half.z);
        s.add(Shape::Cuboid { half }, at, tex(70 + k, 3.0, 25.0));
    }
    s
}

/// [`GALLERY`]'s hall: floor tiles and a smooth ceiling; outer walls textured at 0.3–1.5 m with
/// pictures hung on them (0.6–1.6 m wide, 0.5–1.1 m high, 3–5 cm proud, their centres 1.2–1.9 m
/// up, 0.5–1.5 m apart) and benches below some; the central block textured at 0.25–1 m with
/// pillars round it (0.12–0.2 m in radius, 0.3–0.4 m out from the block, 1.4–2.2 m apart),
/// so that the inward view holds geometry along the hall and texture across it. All drawn from
/// the seed.
pub(super) fn gallery(seed: u64) -> Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x6A11E7);
    let ring = GALLERY;
    let h = ring.height;
    let mut s = shell(&ring, seed, (5.0, 25.0), (2.0, 8.0), (6.0, 25.0));
    for (k, &(half_length, frame)) in outer_walls(&ring).iter().enumerate() {
        let k = k as u64;
        let (wall, at) = upright_wall(half_length, h, &frame);
        s.add(wall, at, tex(seed, 10 + k, 4.0, 20.0));
        let mut x = -half_length + rng.random_range(0.3..0.8);
        let mut n = 0;
        while x < half_length - 0.8 {
            let half = Vector3::new(
                rng.random_range(0.3..0.8),
                rng.random_range(0.015..0.025),
                rng.random_range(0.25..0.55),
            );
            let centre = rng.random_range(1.2..1.9);
            let at = frame * Isometry3::translation(x + half.x, half.y, centre);
            s.add(
                Shape::Cuboid { half },
                at,
                tex(seed, 100 + 20 * k + n, 10.0, 50.0),
            );
            if rng.random_range(0.0..1.0) < 0.4 {
                let bench = Vector3::new(half.x.min(0.6), 0.2, 0.22);
                let at = frame * Isometry3::translation(x + half.x, 0.3 + bench.y, bench.z);
                s.add(
                    Shape::Cuboid { half: bench },
                    at,
                    tex(seed, 101 + 20 * k + n, 5.0, 30.0),
                );
            }
            x += 2.0 * half.x + rng.random_range(0.5..1.5);
            n += 2;
        }
    }
    for (k, &(half_length, frame)) in block_sides(&ring).iter().enumerate() {
        let k = k as u64;
        let mut x = -half_length - rng.random_range(0.0..0.4);
        let mut n = 0;
        while x < half_length + 0.4 {
            let radius = rng.random_range(0.12..0.2);
            let out = rng.random_range(0.3..0.4) + radius;
            let pillar = Shape::Cylinder {
                radius,
                half_height: h / 2.0,
            };
            let at = frame * Isometry3::translation(x, out, h / 2.0);
            s.add(pillar, at, tex(seed, 200 + 20 * k + n, 6.0, 30.0));
            x += rng.random_range(1.4..2.2);
            n += 1;
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use crate::synthetic::layouts::{build, Layout};
    use crate::synthetic::motion::{procedural, Motion};
    use crate::synthetic::render::render;

    /// Every view of a ring walk sees a closed scene (nearly every pixel has a depth), from at
    /// least a hand's breadth away, with surfaces within the sensor's range over most of the
    /// image.
    fn sees_walls_all_round(layout: Layout, walk: Motion) {
        let cam = Camera::new(131.25, 131.25, 79.5, 59.5, 160, 120);
        let scene = build(layout, 3);
        let walk = procedural(walk, 50, 1.0);
        for (k, pose) in walk.poses.iter().enumerate() {
            let frame = render(&scene, &cam, pose);
            let d = &frame.depth.data;
            let valid = d.iter().filter(|z| **z > 0.0).count();
            let near = d.iter().filter(|z| **z > 0.0 && **z < 4.0).count();
            let closest = d
                .iter()
                .filter(|z| **z > 0.0)
                .fold(f32::MAX, |a, b| a.min(*b));
            assert!(
                valid * 100 >= d.len() * 99,
                "{layout:?} t {k}: {valid} valid"
            );
            assert!(
                near * 10 >= d.len() * 7,
                "{layout:?} t {k}: {near} within 4 m"
            );
            assert!(closest > 0.3, "{layout:?} t {k}: {closest} m");
        }
    }

    #[test]
    fn the_ring_walks_see_walls_all_round_their_rings() {
        sees_walls_all_round(Layout::Corridor, Motion::Corridor);
        sees_walls_all_round(Layout::Gallery, Motion::Gallery);
    }

    /// The block's sides face out into the ring, the outer walls in.
    #[test]
    fn the_ring_frames_face_into_the_ring() {
        for (sides, sign) in [(block_sides(&GALLERY), 1.0), (outer_walls(&GALLERY), -1.0)] {
            for (_, frame) in sides {
                let y = frame.rotation * Vector3::y();
                let at = frame.translation.vector;
                assert!(sign * y.dot(&at) > 0.0, "{at} faces {y}");
            }
        }
    }
}
