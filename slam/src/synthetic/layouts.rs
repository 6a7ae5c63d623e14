//! Scene layouts for rendered sequences, so that tracking is measured on more than the one room it
//! was developed on:
//! - [`Layout::Room`]: [`Scene::room`], the furnished room every test uses;
//! - [`Layout::Bare`]: the same room with plain floor, walls, ceiling and table (no texture: the
//!   photometric term has nothing to hold on to over most of the image);
//! - [`Layout::Office`]: a different room whose size, furniture and objects are drawn from the
//!   seed;
//! - [`Layout::Twins`]: a room made of two identical halves, each the other turned half a turn
//!   about the room's vertical axis, so that opposite places look alike (a trap for loop
//!   closure);
//! - [`Layout::Corridor`]: a ring corridor round a central block, cabinets along its walls, for
//!   [`super::motion::Motion::Corridor`]'s walk: a loop 18 m long ([`super::rings`]);
//! - [`Layout::Gallery`]: a wider, higher ring hall with pictures, benches and pillars round its
//!   block, for [`super::motion::Motion::Gallery`]'s walk: a loop 23 m long ([`super::rings`]).

use super::motion::TARGET;
use super::rings;
use super::scene::{Scene, Shape};
use super::texture::Texture;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::FRAC_PI_2;

/// A scene layout.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// The furnished room.
    Room,
    /// The furnished room with plain floor, walls and ceiling.
    Bare,
    /// A room drawn from the seed.
    Office,
    /// Two identical halves, half a turn apart.
    Twins,
    /// A ring corridor round a central block.
    Corridor,
    /// A ring hall round a central block with pillars.
    Gallery,
}

impl std::str::FromStr for Layout {
    type Err = String;

    /// `room`, `bare`, `office`, `twins`, `corridor` or `gallery` (as `generate rigid --layout`
    /// takes them).
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "room" => Ok(Layout::Room),
            "bare" => Ok(Layout::Bare),
            "office" => Ok(Layout::Office),
            "twins" => Ok(Layout::Twins),
            "corridor" => Ok(Layout::Corridor),
            "gallery" => Ok(Layout::Gallery),
            _ => Err(format!(
                "unknown layout {s:?}: expected room, bare, office, twins, corridor or gallery"
            )),
        }
    }
}

/// The scene of `layout` with textures (and, for [`Layout::Office`], geometry) from `seed`.
pub fn build(layout: Layout, seed: u64) -> Scene {
    match layout {
        Layout::Room => Scene::room(seed),
        Layout::Bare => bare(seed),
        Layout::Office => office(seed),
        Layout::Twins => twins(seed),
        Layout::Corridor => rings::corridor(seed),
        Layout::Gallery => rings::gallery(seed),
    }
}

/// The room with its six bounding planes, the table and its legs (added first by
/// [`Scene::room`]) in plain colours; the objects on and around the table keep their texture.
fn bare(seed: u64) -> Scene {
    let mut s = Scene::room(seed);
    let greys = [0.55, 0.75, 0.68, 0.7, 0.66, 0.72, 0.45, 0.4, 0.4];
    for (obj, g) in s.objects.iter_mut().zip(greys) {
        obj.texture = Texture::plain([g, g * 0.98, g * 0.95]);
    }
    s
}

/// A room of random size with a desk or table near [`TARGET`], objects on it, and furniture
/// along the walls, all textured.
fn office(seed: u64) -> Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0FF1CE);
    let mut s = Scene::default();
    let tex =
        |k: u64, lo: f64, hi: f64| Texture::random(seed.wrapping_mul(7919).wrapping_add(k), lo, hi);
    // walls within the fusion range (4 m) of a camera near the desk, as in an office
    let (hx, hy, h) = (
        rng.random_range(2.2..3.0),
        rng.random_range(2.0..2.7),
        rng.random_range(2.5..3.0),
    );
    let turn = |x: f64, y: f64, z: f64, axis: Vector3<f64>, a: f64| {
        Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_scaled_axis(axis * a),
        )
    };
    s.add(
        Shape::Plane { hx, hy },
        Isometry3::identity(),
        tex(1, 2.0, 12.0),
    );
    s.add(
        Shape::Plane { hx, hy },
        Isometry3::translation(0.0, 0.0, h),
        tex(2, 2.0, 8.0),
    );
    for (k, sign) in [(3u64, 1.0), (4, -1.0)] {
        let p = turn(0.0, sign * hy, h / 2.0, Vector3::x(), FRAC_PI_2);
        s.add(Shape::Plane { hx, hy: h / 2.0 }, p, tex(k, 2.0, 12.0));
        let q = turn(sign * hx, 0.0, h / 2.0, Vector3::y(), FRAC_PI_2);
        s.add(Shape::Plane { hx: h / 2.0, hy }, q, tex(k + 2, 2.0, 12.0));
    }
    // a desk under the target, its top at the target's height less a little
    let top = TARGET.z - rng.random_range(0.05..0.15);
    let (dx, dy) = (rng.random_range(0.4..0.7), rng.random_range(0.3..0.5));
    let desk = Shape::Cuboid {
        half: Vector3::new(dx, dy, top / 2.0),
    };
    let yaw = rng.random_range(-0.6..0.6);
    s.add(
        desk,
        turn(0.0, 0.0, top / 2.0, Vector3::z(), yaw),
        tex(7, 4.0, 25.0),
    );
    // objects on the desk
    for k in 0..rng.random_range(3..6u64) {
        let (x, y) = (
            rng.random_range(-dx..dx) * 0.8,
            rng.random_range(-dy..dy) * 0.8,
        );
        let size = rng.random_range(0.05..0.14);
        let (shape, z) = match k % 3 {
            0 => (Shape::Sphere { radius: size }, top + size),
            1 => (
                Shape::Cylinder {
                    radius: size * 0.7,
                    half_height: size,
                },
                top + size,
            ),
            _ => (
                Shape::Cuboid {
                    half: Vector3::new(size, size * 0.8, size * 0.6),
                },
                top + size * 0.6,
            ),
        };
        let at = turn(0.0, 0.0, 0.0, Vector3::z(), yaw) * Isometry3::translation(x, y, z);
        s.add(shape, at, tex(10 + k, 8.0, 40.0));
    }
    // furniture along the walls, out of the cameras' way
    for k in 0..rng.random_range(3..6u64) {
        let a = rng.random_range(0.0..std::f64::consts::TAU);
        let (x, y) = ((hx - 0.5) * a.cos(), (hy - 0.5) * a.sin());
        let half = Vector3::new(
            rng.random_range(0.2..0.45),
            rng.random_range(0.2..0.45),
            rng.random_range(0.3..0.9),
        );
        let at = turn(x, y, half.z, Vector3::z(), rng.random_range(0.0..1.5));
        s.add(Shape::Cuboid { half }, at, tex(20 + k, 3.0, 25.0));
    }
    s
}

/// A room whose half at x < 0 is the half at x > 0 turned by π about the vertical axis through
/// the room's middle: floor, ceiling, walls and furniture of one half are drawn from the seed and
/// copied, textures included (they live in each object's own frame), so a camera at p looking
/// along d sees what one at R p looking along R d sees.
fn twins(seed: u64) -> Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7411);
    let tex =
        |k: u64, lo: f64, hi: f64| Texture::random(seed.wrapping_mul(4099).wrapping_add(k), lo, hi);
    let (hx, hy, h) = (2.8, 2.4, 2.8);
    let turn = |x: f64, y: f64, z: f64, axis: Vector3<f64>, a: f64| {
        Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_scaled_axis(axis * a),
        )
    };
    let mut half = Scene::default();
    let strip = Shape::Plane { hx: hx / 2.0, hy };
    half.add(
        strip.clone(),
        Isometry3::translation(hx / 2.0, 0.0, 0.0),
        tex(1, 3.0, 15.0),
    );
    half.add(
        strip,
        Isometry3::translation(hx / 2.0, 0.0, h),
        tex(2, 2.0, 8.0),
    );
    let end = turn(hx, 0.0, h / 2.0, Vector3::y(), FRAC_PI_2);
    half.add(Shape::Plane { hx: h / 2.0, hy }, end, tex(3, 2.0, 12.0));
    for (k, sign) in [(4u64, 1.0), (5, -1.0)] {
        let side = turn(hx / 2.0, sign * hy, h / 2.0, Vector3::x(), FRAC_PI_2);
        let shape = Shape::Plane {
            hx: hx / 2.0,
            hy: h / 2.0,
        };
        half.add(shape, side, tex(k, 2.0, 12.0));
    }
    for k in 0..3u64 {
        let a: f64 = rng.random_range(-1.2..1.2);
        let (x, y) = ((hx - 0.5) * a.cos(), (hy - 0.5) * a.sin());
        let half_size = Vector3::new(
            rng.random_range(0.2..0.4),
            rng.random_range(0.2..0.4),
            rng.random_range(0.3..0.8),
        );
        let at = turn(x, y, half_size.z, Vector3::z(), rng.random_range(0.0..1.5));
        half.add(
            Shape::Cuboid { half: half_size },
            at,
            tex(10 + k, 3.0, 25.0),
        );
    }
    let mut s = half.clone();
    let flip = Isometry3::rotation(Vector3::z() * std::f64::consts::PI);
    for obj in half.objects {
        s.add(obj.shape, flip * obj.pose, obj.texture);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use crate::synthetic::motion::{procedural, Motion};
    use crate::synthetic::render::render;

    #[test]
    fn the_twins_halves_look_the_same_from_opposite_places() {
        let cam = Camera::new(131.25, 131.25, 79.5, 59.5, 160, 120);
        let scene = build(Layout::Twins, 5);
        let flip = Isometry3::rotation(Vector3::z() * std::f64::consts::PI);
        let pose = procedural(Motion::Survey, 1, 30.0).poses[0];
        let (a, b) = (
            render(&scene, &cam, &pose),
            render(&scene, &cam, &(flip * pose)),
        );
        let valid = a.depth.data.iter().filter(|d| **d > 0.0).count();
        assert!(valid > 150 * 110, "{valid} valid pixels");
        let depth_off = a
            .depth
            .data
            .iter()
            .zip(&b.depth.data)
            .filter(|(x, y)| (*x - *y).abs() > 1e-4)
            .count();
        let color_off = a
            .color
            .data
            .iter()
            .zip(&b.color.data)
            .filter(|(x, y)| x.iter().zip(y.iter()).any(|(p, q)| p.abs_diff(*q) > 1))
            .count();
        assert!(depth_off * 100 < valid, "{depth_off} depths differ");
        assert!(color_off * 100 < valid, "{color_off} colours differ");
        // and another layout is not symmetric
        let room = build(Layout::Room, 5);
        let (c, d) = (
            render(&room, &cam, &pose),
            render(&room, &cam, &(flip * pose)),
        );
        let differ = c
            .color
            .data
            .iter()
            .zip(&d.color.data)
            .filter(|(x, y)| x != y)
            .count();
        assert!(differ * 2 > valid, "{differ}");
    }
}
