//! Synthetic pose graphs with a known optimum, for tests, examples and benchmarks.
//!
//! Poses walk around a sphere in rings (after the sphere2500 benchmark of Kaess et al., iSAM,
//! 2008): odometry edges join consecutive poses and loop closures join each pose to the one above it
//! on the next ring. Measurements are exact, so the ground truth has chi2 = 0 and is the optimum
//! (up to the gauge, fixed by holding vertex 0); the initial guess is the ground truth with seeded
//! noise on every pose but the anchor.

use super::graph::{Dimension, Edge, Measurement, Pose, PoseGraph};
use dynamap_solver::lie::{se2, se3};
use nalgebra::{
    Isometry2, Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion, Vector2, Vector3, Vector6,
};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::collections::BTreeMap;

/// A synthetic graph, its ground truth (the optimum) and a perturbed start.
pub struct SyntheticGraph {
    /// The graph; its `vertices` hold the perturbed start.
    pub graph: PoseGraph,
    /// The optimum.
    pub truth: BTreeMap<usize, Pose>,
}

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
            seed: 7,
        }
    }
}

fn edges_for(n: usize, per_ring: usize) -> Vec<(usize, usize)> {
    let mut e: Vec<(usize, usize)> = (1..n).map(|i| (i - 1, i)).collect();
    e.extend((per_ring..n).map(|i| (i - per_ring, i)));
    e
}

/// A 3D sphere graph with exact measurements; information 100 on translation, 400 on rotation.
pub fn sphere(o: &SyntheticOptions) -> SyntheticGraph {
    let n = o.rings * o.per_ring;
    let radius = 10.0;
    let mut truth = BTreeMap::new();
    for i in 0..n {
        let ring = i / o.per_ring;
        let k = i % o.per_ring;
        let polar = std::f64::consts::PI * (ring as f64 + 0.5) / o.rings as f64;
        let azimuth = 2.0 * std::f64::consts::PI * k as f64 / o.per_ring as f64;
        let p = Vector3::new(
            polar.sin() * azimuth.cos(),
            polar.sin() * azimuth.sin(),
            polar.cos(),
        ) * radius;
        // heading along the ring, z axis outward
        let rot = UnitQuaternion::from_euler_angles(0.3 * polar, polar, azimuth);
        truth.insert(
            i,
            Pose::Se3(Isometry3::from_parts(Translation3::from(p), rot)),
        );
    }
    let info = Matrix6::from_diagonal(&Vector6::new(400.0, 400.0, 400.0, 100.0, 100.0, 100.0));
    let edges = edges_for(n, o.per_ring)
        .into_iter()
        .map(|(a, b)| Edge {
            from: a,
            to: b,
            measurement: Measurement::Se3 {
                z: match (&truth[&a], &truth[&b]) {
                    (Pose::Se3(x), Pose::Se3(y)) => x.inverse() * y,
                    _ => unreachable!(),
                },
                information: info,
            },
            line: 0,
        })
        .collect();
    let mut rng = ChaCha8Rng::seed_from_u64(o.seed);
    let (nr, nt) = (
        Normal::new(0.0, o.rotation_noise).expect("finite sigma"),
        Normal::new(0.0, o.translation_noise).expect("finite sigma"),
    );
    let mut graph = PoseGraph::new(Dimension::Three);
    graph.source = "synthetic sphere".into();
    graph.edges = edges;
    for (&i, p) in &truth {
        let Pose::Se3(x) = p else { unreachable!() };
        let start = if i == 0 {
            *x
        } else {
            let d = Vector6::from_fn(|r, _| {
                if r < 3 {
                    nr.sample(&mut rng)
                } else {
                    nt.sample(&mut rng)
                }
            });
            x * se3::exp(&d)
        };
        graph.vertices.insert(i, Pose::Se3(start));
    }
    SyntheticGraph { graph, truth }
}

/// A 2D graph of concentric laps (a spiral) with exact measurements; information 100 on
/// translation, 400 on rotation.
pub fn circle(o: &SyntheticOptions) -> SyntheticGraph {
    let n = o.rings * o.per_ring;
    let mut truth = BTreeMap::new();
    for i in 0..n {
        let lap = i / o.per_ring;
        let a = 2.0 * std::f64::consts::PI * (i % o.per_ring) as f64 / o.per_ring as f64;
        let r = 10.0 + 2.0 * lap as f64;
        truth.insert(
            i,
            Pose::Se2(Isometry2::new(
                Vector2::new(r * a.cos(), r * a.sin()),
                a + 1.5,
            )),
        );
    }
    let info = Matrix3::from_diagonal(&Vector3::new(100.0, 100.0, 400.0));
    let edges = edges_for(n, o.per_ring)
        .into_iter()
        .map(|(a, b)| Edge {
            from: a,
            to: b,
            measurement: Measurement::Se2 {
                z: match (&truth[&a], &truth[&b]) {
                    (Pose::Se2(x), Pose::Se2(y)) => x.inverse() * y,
                    _ => unreachable!(),
                },
                information: info,
            },
            line: 0,
        })
        .collect();
    let mut rng = ChaCha8Rng::seed_from_u64(o.seed);
    let (nr, nt) = (
        Normal::new(0.0, o.rotation_noise).expect("finite sigma"),
        Normal::new(0.0, o.translation_noise).expect("finite sigma"),
    );
    let mut graph = PoseGraph::new(Dimension::Two);
    graph.source = "synthetic circle".into();
    graph.edges = edges;
    for (&i, p) in &truth {
        let Pose::Se2(x) = p else { unreachable!() };
        let start = if i == 0 {
            *x
        } else {
            x * se2::exp(&Vector3::new(
                nt.sample(&mut rng),
                nt.sample(&mut rng),
                nr.sample(&mut rng),
            ))
        };
        graph.vertices.insert(i, Pose::Se2(start));
    }
    SyntheticGraph { graph, truth }
}

/// Adds `count` wrong loop closures to `graph`: edges between seeded random pairs of vertices at
/// least three apart in id, each measuring a random motion (up to 2 m per axis and 0.5 rad) that
/// has nothing to do with the poses, with the information of the graph's first edge (or unit
/// information). This is the outlier model of Sünderhauf & Protzel (2012) and Agarwal et al.
/// (2013); the truth stays the optimum only under a robust kernel. Returns the new edges' indices.
pub fn add_false_loops(graph: &mut PoseGraph, count: usize, seed: u64) -> Vec<usize> {
    let ids: Vec<usize> = graph.vertices.keys().copied().collect();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut added = Vec::with_capacity(count);
    if ids.len() < 4 {
        return added;
    }
    let template = graph.edges.first().map(|e| e.measurement.clone());
    while added.len() < count {
        let (a, b) = (
            ids[rng.random_range(0..ids.len())],
            ids[rng.random_range(0..ids.len())],
        );
        if a.abs_diff(b) < 3 {
            continue;
        }
        let mut uniform = |h: f64| rng.random_range(-h..h);
        let measurement = match graph.dimension {
            Dimension::Two => Measurement::Se2 {
                z: Isometry2::new(Vector2::new(uniform(2.0), uniform(2.0)), uniform(0.5)),
                information: match &template {
                    Some(Measurement::Se2 { information, .. }) => *information,
                    _ => Matrix3::identity(),
                },
            },
            Dimension::Three => Measurement::Se3 {
                z: Isometry3::from_parts(
                    Translation3::new(uniform(2.0), uniform(2.0), uniform(2.0)),
                    UnitQuaternion::from_scaled_axis(Vector3::new(
                        uniform(0.3),
                        uniform(0.3),
                        uniform(0.3),
                    )),
                ),
                information: match &template {
                    Some(Measurement::Se3 { information, .. }) => *information,
                    _ => Matrix6::identity(),
                },
            },
        };
        added.push(graph.edges.len());
        graph.edges.push(Edge {
            from: a.min(b),
            to: a.max(b),
            measurement,
            line: 0,
        });
    }
    added
}

/// Largest translation and rotation (radians) difference between two sets of poses.
pub fn max_pose_error(a: &BTreeMap<usize, Pose>, b: &BTreeMap<usize, Pose>) -> (f64, f64) {
    let mut worst = (0.0f64, 0.0f64);
    for (id, p) in a {
        let (dt, dr) = match (p, &b[id]) {
            (Pose::Se2(x), Pose::Se2(y)) => {
                let d = x.inverse() * y;
                (d.translation.vector.norm(), d.rotation.angle().abs())
            }
            (Pose::Se3(x), Pose::Se3(y)) => {
                let d = x.inverse() * y;
                (d.translation.vector.norm(), d.rotation.angle())
            }
            _ => (f64::INFINITY, f64::INFINITY),
        };
        worst = (worst.0.max(dt), worst.1.max(dr));
    }
    worst
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn false_loops_join_distant_poses_and_are_far_from_the_truth() {
        let o = SyntheticOptions {
            rings: 4,
            per_ring: 20,
            ..SyntheticOptions::default()
        };
        for mut s in [circle(&o), sphere(&o)] {
            let before = s.graph.edges.len();
            let added = add_false_loops(&mut s.graph, 12, 5);
            assert_eq!(added, (before..before + 12).collect::<Vec<_>>());
            assert_eq!(s.graph.edges.len(), before + 12);
            let exact = s.graph.chi2(&s.truth);
            assert!(
                exact > 100.0,
                "wrong loops should not fit the truth: chi2 {exact}"
            );
            for e in &s.graph.edges[before..] {
                assert!(e.to - e.from >= 3);
            }
            let again = {
                let mut t = circle(&o);
                add_false_loops(&mut t.graph, 12, 5);
                t.graph.edges
            };
            if s.graph.dimension == Dimension::Two {
                assert_eq!(again, s.graph.edges, "seeded: the same loops again");
            }
        }
    }
}
