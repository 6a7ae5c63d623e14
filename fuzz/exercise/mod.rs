//! What each fuzz target does with its input, shared with `tests/fuzz_corpus.rs`, which replays
//! the kept corpus (and every past finding) through the same calls in a plain `cargo test`.
//! Each function must never panic, whatever the bytes.

use dynamap_residuals::bal::file as bal_file;
use dynamap_residuals::pose_graph::{g2o as g2o_file, init};
use dynamap_slam::eval::{ate, Alignment};
use dynamap_slam::io::trajectory::Trajectory;
use dynamap_slam::io::{flow, folder, meshes, ply, tum};
use std::path::Path;

/// g2o pose graphs: parse, then what a run does before solving (initial guesses, the problem).
pub fn g2o(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    if let Ok(graph) = g2o_file::parse(&text, "fuzz.g2o") {
        for poses in [init::odometry(&graph), init::chordal(&graph)]
            .into_iter()
            .flatten()
        {
            let _ = graph.chi2(&poses);
            let _ = graph.build_problem(&poses);
            let _ = g2o_file::format(&graph, &poses);
        }
    }
}

/// Bundle-adjustment problems in the BAL text format: parse, then the cost of the file's guess.
pub fn bal(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    if let Ok(problem) = bal_file::parse(&text, "fuzz.txt") {
        let _ = problem.cost();
    }
}

/// TUM RGB-D text files: image lists (then their association, as opening a sequence does) and
/// trajectories (then the ATE of the trajectory against itself).
pub fn tum(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    let path = Path::new("fuzz.txt");
    if let Ok(list) = tum::parse_list(&text, path) {
        let stamps: Vec<f64> = list.iter().map(|l| l.0).collect();
        let pairs = tum::associate(&stamps, &stamps, 0.02);
        assert!(pairs.len() <= stamps.len());
    }
    if let Ok(t) = Trajectory::parse_tum(&text, path) {
        for a in [Alignment::Se3, Alignment::Sim3, Alignment::None] {
            let _ = ate(&t, &t, a, 0.02);
        }
    }
}

/// Meshes: PLY (binary and ASCII), OFF and OBJ, then the normals a reader computes.
pub fn mesh(data: &[u8]) {
    let path = Path::new("fuzz");
    let text = String::from_utf8_lossy(data);
    for mut m in [
        ply::decode(data, path),
        meshes::parse_off(&text, path),
        meshes::parse_obj(&text, path),
    ]
    .into_iter()
    .flatten()
    {
        m.compute_normals();
        let _ = ply::encode(&m);
    }
}

/// Camera files: TUM-style `intrinsics.txt`, Open3D's intrinsics JSON, and flow files.
pub fn intrinsics(data: &[u8]) {
    let path = Path::new("fuzz");
    let text = String::from_utf8_lossy(data);
    if let Ok(c) = tum::parse_intrinsics(&text, path, 640, 480) {
        let _ = c.level(2);
    }
    if let Ok(c) = folder::parse_open3d_camera(&text, path) {
        let _ = c.level(2);
    }
    let _ = flow::decode_flow::<3>(data, path);
}
