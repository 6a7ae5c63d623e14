//! `rigid_slam --graph`: the keyframe graph written as a g2o file that our reader (and g2o's)
//! reads back, one vertex per keyframe and one edge per odometry step or loop (issue 24).

use crate::common::{result_json, run, scratch, text};

#[test]
fn rigid_slam_writes_its_keyframe_graph_as_g2o() {
    let dir = scratch("graph");
    let path = dir.join("keyframes.g2o");
    let out = run(
        "rigid_slam",
        &["--graph", path.to_str().unwrap(), "--quiet"],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let json = result_json(&out);
    let keyframes = json["keyframes"].as_u64().unwrap() as usize;
    let loops = json["loops"].as_u64().unwrap() as usize;
    let graph = dynamap_residuals::pose_graph::g2o::read(&path).unwrap();
    assert!(keyframes >= 2, "{json}");
    assert_eq!(json["graph_converged"], true, "{json}");
    assert_eq!(graph.vertices.len(), keyframes);
    assert_eq!(graph.edges.len(), keyframes - 1 + loops);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A graph with an indefinite information matrix (as SE-Sync's cubicle has) is solved with the
/// edge repaired, named in a warning and counted in the JSON line; `--strict` refuses it, naming
/// the line.
#[test]
fn pose_graph_repairs_an_indefinite_information_matrix_unless_strict() {
    let dir = scratch("indefinite");
    let path = dir.join("indefinite.g2o");
    // edge 0-1's information has eigenvalue -1e-6; the triangle's measurements disagree a little
    let text_g2o = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1.1 0 0\nVERTEX_SE2 2 2 0.3 0\n\
                    EDGE_SE2 0 1 1 0 0 1 0 0 1 0 -1e-6\n\
                    EDGE_SE2 1 2 1 0.1 0 100 0 0 100 0 100\n\
                    EDGE_SE2 0 2 2 0.1 0 100 0 0 100 0 100\n";
    std::fs::write(&path, text_g2o).unwrap();
    let file = path.to_str().unwrap();
    let out = run("pose_graph", &[file]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let json = result_json(&out);
    assert_eq!(json["repaired_edges"], 1, "{json}");
    assert_eq!(json["converged"], true, "{json}");
    assert!(json["chi2_final"].as_f64().unwrap() < json["chi2_initial"].as_f64().unwrap());
    let log = text(&out.stderr) + &text(&out.stdout);
    assert!(log.contains("line 4 (edge 0 -> 1)"), "{log}");
    let strict = run("pose_graph", &[file, "--strict", "-q"]);
    assert_eq!(strict.status.code(), Some(2));
    let err = text(&strict.stderr);
    assert!(
        err.contains("indefinite.g2o:4:") && err.contains("not positive definite"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// `--covariance`: a vertex one edge from the anchor has the edge's covariance Ω⁻¹ (the residual's
/// Jacobian in X Exp(δ) is the identity at the optimum); a vertex that does not exist, or the
/// fixed anchor, is refused with a clear error.
#[test]
fn pose_graph_prints_marginal_covariances_of_chosen_vertices() {
    let dir = scratch("covariance");
    let path = dir.join("chain.g2o");
    let text_g2o = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1.2 0.1 0.05\nVERTEX_SE2 2 2 0 0\n\
                    EDGE_SE2 0 1 1 0 0 100 0 0 50 0 25\n\
                    EDGE_SE2 1 2 1 0 0 100 0 0 100 0 100\n";
    std::fs::write(&path, text_g2o).unwrap();
    let file = path.to_str().unwrap();
    let out = run("pose_graph", &[file, "--covariance", "1,2", "-q"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let json = result_json(&out);
    let blocks = json["covariance"]["blocks"].as_array().unwrap();
    assert_eq!(blocks.len(), 2, "{json}");
    assert_eq!(blocks[0]["vertex"], 1);
    let expected = [[0.01, 0.0, 0.0], [0.0, 0.02, 0.0], [0.0, 0.0, 0.04]];
    for (r, row) in expected.iter().enumerate() {
        for (c, want) in row.iter().enumerate() {
            let got = blocks[0]["matrix"][r][c].as_f64().unwrap();
            assert!(
                (got - want).abs() < 1e-9,
                "({r}, {c}): {got} against {want}"
            );
        }
    }
    // the next vertex is less certain than the one before it in every coordinate
    let diagonal = |b: &serde_json::Value| -> Vec<f64> {
        (0..3)
            .map(|k| b["matrix"][k][k].as_f64().unwrap())
            .collect()
    };
    let (near, far) = (diagonal(&blocks[0]), diagonal(&blocks[1]));
    assert!(near.iter().zip(&far).all(|(a, b)| b > a), "{json}");
    for (ids, mention) in [("7", "no vertex 7"), ("0", "fixed")] {
        let bad = run("pose_graph", &[file, "--covariance", ids, "-q"]);
        assert_eq!(bad.status.code(), Some(2), "{}", text(&bad.stderr));
        let err = text(&bad.stderr);
        assert!(err.contains(mention) && err.contains("chain.g2o"), "{err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
