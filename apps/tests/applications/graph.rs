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
