//! Generated pose graphs at scale (issue 27): a 100,000-pose city walk solved to its known optimum,
//! and noisy graphs whose optimum every start reaches, with the chi2 their Gaussian predicts.

use dynamap::residuals::pose_graph::synthetic::{
    self, max_pose_error, CityOptions, CorridorOptions, Noise, Start, SyntheticGraph,
};
use dynamap::residuals::pose_graph::{init, Dimension, Pose};
use dynamap::solver::{Options, Solver};
use std::collections::BTreeMap;

/// Solves from `start`; the optimum, its chi2 and the iterations taken.
fn solve(s: &SyntheticGraph, start: &BTreeMap<usize, Pose>) -> (BTreeMap<usize, Pose>, f64) {
    let mut pg = s.graph.build_problem(start).unwrap();
    let summary = Solver::new(Options::default())
        .solve(&mut pg.problem)
        .unwrap();
    assert!(
        summary.termination.converged(),
        "{}: {}",
        s.graph.source,
        summary.table()
    );
    let poses = pg.poses();
    let chi2 = s.graph.chi2(&poses);
    (poses, chi2)
}

#[test]
fn a_100k_pose_city_walk_solves_to_its_known_optimum() {
    let s = synthetic::city(&CityOptions {
        poses: 100_000,
        noise: Noise {
            noisy: false,
            ..Default::default()
        },
        ..Default::default()
    })
    .unwrap();
    assert!(s.graph.chi2(&s.graph.vertices) > 1e5, "the start is off");
    let (poses, chi2) = solve(&s, &s.graph.vertices);
    let (dt, dr) = max_pose_error(&poses, &s.truth);
    assert!(
        dt < 1e-6 && dr < 1e-6,
        "{dt:e} m, {dr:e} rad from the truth"
    );
    assert!(chi2 < 1e-12, "chi2 {chi2:e}");
}

/// The optimum's chi2 is χ² with (edges − poses + 1) × dof degrees of freedom: within 5σ.
fn assert_chi2_as_predicted(s: &SyntheticGraph, chi2: f64) {
    let dof = match s.graph.dimension {
        Dimension::Two => 3.0,
        Dimension::Three => 6.0,
    };
    let k = (s.graph.edges.len() + 1 - s.graph.vertices.len()) as f64 * dof;
    assert!(
        (chi2 - k).abs() < 5.0 * (2.0 * k).sqrt(),
        "{}: chi2 {chi2} against {k} predicted",
        s.graph.source
    );
}

#[test]
fn noisy_graphs_reach_one_optimum_from_the_perturbed_truth_and_from_chordal_odometry() {
    let odometry = Noise {
        start: Start::Odometry,
        seed: 3,
        ..Default::default()
    };
    let perturbed = Noise {
        seed: 3,
        ..Default::default()
    };
    let city = |noise| CityOptions {
        poses: 6000,
        dimension: Dimension::Three,
        noise,
        ..Default::default()
    };
    let corridor = |noise| CorridorOptions {
        poses: 6000,
        length: 600,
        door_spacing: 60,
        noise,
        ..Default::default()
    };
    let pairs = [
        (
            synthetic::city(&city(perturbed)).unwrap(),
            synthetic::city(&city(odometry)).unwrap(),
        ),
        (
            synthetic::corridor(&corridor(perturbed)).unwrap(),
            synthetic::corridor(&corridor(odometry)).unwrap(),
        ),
    ];
    for (near, far) in pairs {
        assert_eq!(near.graph.edges, far.graph.edges, "one graph, two starts");
        let (_, chi2_near) = solve(&near, &near.graph.vertices);
        let chordal = init::chordal(&far.graph).unwrap();
        let (_, chi2_far) = solve(&far, &chordal);
        assert!(
            (chi2_near - chi2_far).abs() < 1e-8 * chi2_near,
            "{}: {chi2_near} against {chi2_far}",
            near.graph.source
        );
        assert_chi2_as_predicted(&near, chi2_near);
    }
}
