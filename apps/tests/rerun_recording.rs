//! `rigid_slam --rerun` writes a recording that Rerun's own decoder reads back with every entity
//! of every frame (issue 7). Needs the `rerun` feature
//! (`cargo test --release -p dynamap-apps --features rerun --test rerun_recording`).

use dynamap_slam::camera::Camera;
use dynamap_slam::io::images::read_color;
use dynamap_slam::synthetic::{motion, noise::SensorNoise, scene::Scene, sequence};
use nalgebra::Isometry3;
use re_log_encoding::DecoderApp;
use rerun::log::{Chunk, LogMsg};
use std::collections::BTreeMap;
use std::io::BufReader;
use std::process::Command;

/// Rows logged per entity path (without the leading slash).
fn rows_per_entity(path: &std::path::Path) -> BTreeMap<String, usize> {
    let file = std::fs::File::open(path).expect("the recording exists");
    let mut rows = BTreeMap::new();
    for msg in DecoderApp::decode_lazy(BufReader::new(file)) {
        if let LogMsg::ArrowMsg(_, arrow) = msg.expect("the recording decodes") {
            let chunk = Chunk::from_arrow_msg(&arrow).expect("a chunk");
            let name = chunk.entity_path().to_string();
            *rows
                .entry(name.trim_start_matches('/').to_string())
                .or_insert(0) += chunk.num_rows();
        }
    }
    rows
}

#[test]
fn rigid_slam_recording_reads_back_with_every_frame() {
    let dir = std::env::temp_dir().join(format!("dynamap-rerun-{}", std::process::id()));
    let frames = 12;
    let mut camera = Camera::tum_default().level(1);
    camera.depth_scale = 5000.0;
    let trajectory = motion::procedural(motion::Motion::Orbit, frames, 30.0);
    sequence::write_rigid(
        &dir,
        &Scene::room(1),
        &camera,
        &trajectory,
        &Isometry3::identity(),
        &sequence::Sensor::Ideal(SensorNoise::default()),
        |_| {},
    )
    .expect("the sequence is written");
    let rrd = dir.join("run.rrd");
    let preview = dir.join("preview");
    let out = Command::new(env!("CARGO_BIN_EXE_rigid_slam"))
        .arg(&dir)
        .arg("--rerun")
        .arg(&rrd)
        .args(["--rerun-mesh-every", "5", "--preview"])
        .arg(&preview)
        .arg("-q")
        .output()
        .expect("rigid_slam runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "rigid_slam failed: {stderr}");
    let rows = rows_per_entity(&rrd);
    let per_frame = [
        "world/camera/rgb",
        "world/camera/depth",
        "model_view",
        "world/trajectory/estimate",
        "tracking/inliers",
        "tracking/ms/track",
    ];
    for entity in per_frame {
        assert_eq!(
            rows.get(entity).copied(),
            Some(frames),
            "{entity}: one row per frame expected; the recording has {rows:?}"
        );
    }
    // pose and pinhole per frame
    assert!(
        rows.get("world/camera").copied().unwrap_or(0) >= frames,
        "{rows:?}"
    );
    assert_eq!(
        rows.get("world/trajectory/ground_truth").copied(),
        Some(1),
        "{rows:?}"
    );
    // every 5 frames (2 of 12) and after the last
    assert_eq!(rows.get("world/mesh").copied(), Some(3), "{rows:?}");
    for png in [
        "model_view_1",
        "model_view_2",
        "model_view_3",
        "trajectory",
        "error",
    ] {
        let p = preview.join(format!("{png}.png"));
        let img = read_color(&p).unwrap_or_else(|e| panic!("{e}"));
        assert!(img.width > 100 && img.height > 100);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn nonrigid_and_pose_graph_recordings_hold_the_graphs() {
    let dir = std::env::temp_dir().join(format!("dynamap-rerun-graphs-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let rrd = dir.join("nonrigid.rrd");
    let out = Command::new(env!("CARGO_BIN_EXE_nonrigid_slam"))
        .args(["--max-frames", "3", "-q", "--rerun"])
        .arg(&rrd)
        .output()
        .expect("nonrigid_slam runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rows = rows_per_entity(&rrd);
    for entity in [
        "world/graph/nodes",
        "world/graph/edges",
        "world/live_mesh",
        "world/camera/depth",
    ] {
        assert_eq!(rows.get(entity).copied(), Some(3), "{entity}: {rows:?}");
    }
    let rrd = dir.join("pose_graph.rrd");
    let out = Command::new(env!("CARGO_BIN_EXE_pose_graph"))
        .args(["-q", "--rerun"])
        .arg(&rrd)
        .output()
        .expect("pose_graph runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&out.stdout).lines().last().unwrap()).unwrap();
    let rows = rows_per_entity(&rrd);
    for entity in [
        "world/before/nodes",
        "world/before/edges",
        "world/after/nodes",
        "world/after/edges",
    ] {
        assert_eq!(rows.get(entity).copied(), Some(1), "{entity}: {rows:?}");
    }
    // the start point and every iteration
    let iterations = json["iterations"].as_u64().unwrap() as usize;
    assert_eq!(
        rows.get("solver/chi2").copied(),
        Some(iterations + 1),
        "{rows:?}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
