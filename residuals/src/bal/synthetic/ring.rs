//! The ring layout: cameras on a ring of radius 8 around a cloud of points (4 × 4 × 2), each
//! looking at the cloud's centre. Every point is seen by a seeded random subset of at least three
//! cameras, or, with [`SyntheticOptions::views`], by a run of neighbouring cameras on the ring.

use super::{look_camera, Scene, SyntheticOptions};
use nalgebra::Vector3;
use rand::RngExt;
use rand_chacha::ChaCha8Rng;

/// The cameras that see one point, in increasing order.
fn seen_by(o: &SyntheticOptions, rng: &mut ChaCha8Rng) -> Vec<usize> {
    let n = o.cameras;
    let mut seen: Vec<usize> = match o.views {
        None => {
            let mut seen: Vec<usize> = (0..n).filter(|_| rng.random_bool(0.5)).collect();
            while seen.len() < 3.min(n) {
                let c = rng.random_range(0..n);
                if !seen.contains(&c) {
                    seen.push(c);
                }
            }
            seen
        }
        Some((lo, hi)) => {
            let (lo, hi) = (lo.clamp(1, n.max(1)), hi.clamp(1, n.max(1)));
            let k = rng.random_range(lo.min(hi)..=hi.max(lo));
            let first = rng.random_range(0..n.max(1));
            (0..k).map(|i| (first + i) % n).collect()
        }
    };
    seen.sort_unstable();
    seen
}

/// Camera `i` of `n` on the ring, looking at the cloud's centre.
fn ring_camera(i: usize, n: usize) -> [f64; 9] {
    let a = 2.0 * std::f64::consts::PI * i as f64 / n.max(1) as f64;
    let centre = Vector3::new(8.0 * a.cos(), 8.0 * a.sin(), 2.0 + (3.0 * a).sin());
    look_camera(centre, -centre, Vector3::z(), 500.0 + 20.0 * i as f64)
}

/// The ring's cameras, points and visibility.
pub(crate) fn scene(o: &SyntheticOptions, rng: &mut ChaCha8Rng) -> Scene {
    let points: Vec<[f64; 3]> = (0..o.points)
        .map(|_| {
            [
                rng.random_range(-2.0..2.0),
                rng.random_range(-2.0..2.0),
                rng.random_range(-1.0..1.0),
            ]
        })
        .collect();
    let cameras = (0..o.cameras).map(|i| ring_camera(i, o.cameras)).collect();
    let seen_by = (0..o.points).map(|_| seen_by(o, rng)).collect();
    Scene {
        cameras,
        points,
        seen_by,
    }
}
