//! Our chi2 equals GTSAM's (the function the reference optima were measured with) on arbitrary poses.
//!
//! The constants were computed by `../shared/bench/peers/chi2.py` (GTSAM 4.3.0's readG2o and
//! BetweenFactor errors) on the graphs and poses below, each written to a file:
//!   python chi2.py g2.g2o r2.g2o  -> 2440.7846235983507;  python chi2.py g2.g2o g2.g2o -> 204.09106948578255
//!   python chi2.py g3.g2o r3.g2o  -> 10989.484314635392;  python chi2.py g3.g2o g3.g2o -> 1724.0292823650816
//! The graphs have dense information matrices (rotation-translation coupling included), rotation
//! errors beyond 1 rad and relative rotations near ±π, so the permutation of g2o's SE(3) information
//! and the choice of Log as local coordinates are both exercised.

use dynamap::residuals::pose_graph::g2o;

const G2: &str = "VERTEX_SE2 0 0 0 0
VERTEX_SE2 1 1 0.5 0.4
VERTEX_SE2 2 2 -1 2.5
EDGE_SE2 0 1 0.9 0.6 0.3 50 5 -3 40 2 100
EDGE_SE2 1 2 1.2 -1.1 2.9 80 -10 4 70 -6 120
EDGE_SE2 0 2 2.5 -0.5 -2.8 10 0 0 10 0 30
";
const R2: &str = "VERTEX_SE2 0 0.1 -0.2 0.3
VERTEX_SE2 1 1.4 0.1 -2.9
VERTEX_SE2 2 -2 3 1.7
";
const G3: &str = "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1
VERTEX_SE3:QUAT 1 1 0.5 -0.2 0.1 0.2 0.3 0.927
VERTEX_SE3:QUAT 2 2 -1 0.7 -0.4 0.5 0.1 0.76
EDGE_SE3:QUAT 0 1 0.9 0.6 -0.1 0.15 0.1 0.35 0.9 50 3 -2 4 1 0.5 60 1 -3 2 1 40 0.5 1 -2 300 20 10 250 -15 200
EDGE_SE3:QUAT 1 2 1.2 -1.1 0.5 -0.3 0.6 0.2 0.7 80 1 2 3 -4 5 70 -1 2 3 -4 90 1 -2 3 400 10 -20 350 5 380
EDGE_SE3:QUAT 0 2 2.5 -0.5 1 0.6 -0.5 0.3 0.55 10 0 0 0 0 0 10 0 0 0 0 10 0 0 0 100 0 0 100 0 100
";
const R3: &str = "VERTEX_SE3:QUAT 0 0.1 -0.2 0.3 0.2 -0.1 0.05 0.97
VERTEX_SE3:QUAT 1 1.4 0.1 -0.6 -0.5 0.6 0.1 0.6
VERTEX_SE3:QUAT 2 -2 3 1 0.7 0.1 -0.7 0.1
";

fn check(graph: &str, result: &str, expected: f64) {
    let g = g2o::parse(graph, "graph").unwrap();
    let r = g2o::parse(result, "result").unwrap();
    let chi2 = g.chi2(&r.vertices);
    let rel = ((chi2 - expected) / expected).abs();
    assert!(
        rel < 1e-9,
        "chi2 {chi2} vs GTSAM {expected}: relative {rel:e}"
    );
    // The problem's cost is half of it.
    let pg = g.build_problem(&r.vertices).unwrap();
    let cost = pg.problem.cost();
    assert!(((2.0 * cost - expected) / expected).abs() < 1e-9);
}

#[test]
fn planar_chi2_matches_gtsam() {
    check(G2, R2, 2440.7846235983507);
    check(G2, G2, 204.09106948578255);
}

#[test]
fn spatial_chi2_matches_gtsam() {
    check(G3, R3, 10989.484314635392);
    check(G3, G3, 1724.0292823650816);
}
