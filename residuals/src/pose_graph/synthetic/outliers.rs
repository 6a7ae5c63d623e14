//! Wrong loop closures added to a graph, and the distance between two sets of poses.

use crate::pose_graph::graph::{Dimension, Edge, Measurement, Pose, PoseGraph};
use nalgebra::{
    Isometry2, Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion, Vector2, Vector3,
};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::BTreeMap;

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
    use super::super::{circle, sphere, SyntheticOptions};
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
