//! Scene layouts for rendered sequences, so that tracking is measured on more than the one room it
//! was developed on:
//! - [`Layout::Room`]: [`Scene::room`], the furnished room every test uses;
//! - [`Layout::Bare`]: the same room with plain floor, walls, ceiling and table (no texture: the
//!   photometric term has nothing to hold on to over most of the image);
//! - [`Layout::Office`]: a different room whose size, furniture and objects are drawn from the
//!   seed.

use super::motion::TARGET;
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
}

/// The scene of `layout` with textures (and, for [`Layout::Office`], geometry) from `seed`.
pub fn build(layout: Layout, seed: u64) -> Scene {
    match layout {
        Layout::Room => Scene::room(seed),
        Layout::Bare => bare(seed),
        Layout::Office => office(seed),
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
