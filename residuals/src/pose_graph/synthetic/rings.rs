//! Rings: poses around a sphere (SE(3)) or on concentric laps (SE(2)), each tied to the pose before
//! it and to the one a ring before (after sphere2500 of Kaess et al., *iSAM*, 2008).

use super::{assemble, Noise, Start, SyntheticGraph};
use crate::pose_graph::graph::{Dimension, Pose};
use nalgebra::{Isometry2, Isometry3, Translation3, UnitQuaternion, Vector2, Vector3};
use std::f64::consts::PI;

/// Settings of [`sphere`] and [`circle`].
#[derive(Clone, Copy, Debug)]
pub struct SyntheticOptions {
    /// Number of rings (3D) or laps (2D).
    pub rings: usize,
    /// Poses per ring.
    pub per_ring: usize,
    /// Standard deviation of the start's rotation noise (radians).
    pub rotation_noise: f64,
    /// Standard deviation of the start's translation noise (metres).
    pub translation_noise: f64,
    /// Measurements drawn from their Gaussian (σ 0.05 rad, 0.1 m) instead of exact.
    pub noisy: bool,
    /// Random seed.
    pub seed: u64,
}

impl Default for SyntheticOptions {
    fn default() -> Self {
        Self {
            rings: 20,
            per_ring: 50,
            rotation_noise: 0.05,
            translation_noise: 0.2,
            noisy: false,
            seed: 7,
        }
    }
}

impl SyntheticOptions {
    /// Information 400 on rotation and 100 on translation; the start perturbed from the truth.
    fn noise(&self) -> Noise {
        Noise {
            rotation_sigma: 0.05,
            translation_sigma: 0.1,
            noisy: self.noisy,
            start: Start::Perturbed {
                rotation: self.rotation_noise,
                translation: self.translation_noise,
            },
            seed: self.seed,
        }
    }
}

/// Odometry along each ring and from each pose to the one a ring before.
fn ring_pairs(n: usize, per_ring: usize) -> Vec<(usize, usize)> {
    let mut e: Vec<(usize, usize)> = (1..n).map(|i| (i - 1, i)).collect();
    e.extend((per_ring..n).map(|i| (i - per_ring, i)));
    e
}

/// A 3D sphere graph of radius 10 m; information 400 on rotation, 100 on translation.
pub fn sphere(o: &SyntheticOptions) -> SyntheticGraph {
    let n = o.rings * o.per_ring;
    let radius = 10.0;
    let truth = (0..n)
        .map(|i| {
            let (ring, k) = (i / o.per_ring, i % o.per_ring);
            let polar = PI * (ring as f64 + 0.5) / o.rings as f64;
            let azimuth = 2.0 * PI * k as f64 / o.per_ring as f64;
            let p = Vector3::new(
                polar.sin() * azimuth.cos(),
                polar.sin() * azimuth.sin(),
                polar.cos(),
            ) * radius;
            // heading along the ring, z axis outward
            let rot = UnitQuaternion::from_euler_angles(0.3 * polar, polar, azimuth);
            Pose::Se3(Isometry3::from_parts(Translation3::from(p), rot))
        })
        .collect();
    let pairs = ring_pairs(n, o.per_ring);
    assemble(
        Dimension::Three,
        "synthetic sphere",
        truth,
        &pairs,
        &o.noise(),
    )
}

/// A 2D graph of concentric laps (a spiral); information 400 on rotation, 100 on translation.
pub fn circle(o: &SyntheticOptions) -> SyntheticGraph {
    let n = o.rings * o.per_ring;
    let truth = (0..n)
        .map(|i| {
            let lap = i / o.per_ring;
            let a = 2.0 * PI * (i % o.per_ring) as f64 / o.per_ring as f64;
            let r = 10.0 + 2.0 * lap as f64;
            Pose::Se2(Isometry2::new(
                Vector2::new(r * a.cos(), r * a.sin()),
                a + 1.5,
            ))
        })
        .collect();
    let pairs = ring_pairs(n, o.per_ring);
    assemble(
        Dimension::Two,
        "synthetic circle",
        truth,
        &pairs,
        &o.noise(),
    )
}
