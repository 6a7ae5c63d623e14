//! Helpers of the tests that run the applications: their binaries, a scratch folder, their JSON line.

use std::path::PathBuf;
use std::process::{Command, Output};

/// The path of application `name`, as Cargo built it for this test (`CARGO_BIN_EXE_<name>`).
pub fn binary(name: &str) -> &'static str {
    match name {
        "bundle_adjustment" => env!("CARGO_BIN_EXE_bundle_adjustment"),
        "curve_fitting" => env!("CARGO_BIN_EXE_curve_fitting"),
        "evaluate" => env!("CARGO_BIN_EXE_evaluate"),
        "generate" => env!("CARGO_BIN_EXE_generate"),
        "generate_problem" => env!("CARGO_BIN_EXE_generate_problem"),
        "long_run" => env!("CARGO_BIN_EXE_long_run"),
        "nonrigid_register" => env!("CARGO_BIN_EXE_nonrigid_register"),
        "nonrigid_slam" => env!("CARGO_BIN_EXE_nonrigid_slam"),
        "pose_graph" => env!("CARGO_BIN_EXE_pose_graph"),
        "preprocess_bench" => env!("CARGO_BIN_EXE_preprocess_bench"),
        "rigid_slam" => env!("CARGO_BIN_EXE_rigid_slam"),
        "tsdf_bench" => env!("CARGO_BIN_EXE_tsdf_bench"),
        _ => panic!("{name} is not one of dynamap-apps' binaries"),
    }
}

/// Runs application `name` with `args` and waits for it.
pub fn run(name: &str, args: &[&str]) -> Output {
    Command::new(binary(name))
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("{name} does not start: {e}"))
}

/// Bytes as text (lossy).
pub fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// A scratch folder for one test.
pub fn scratch(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("dynamap-cli-{test}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a scratch folder");
    dir
}

/// The JSON line a run prints last, without its timings (the covariance's included).
pub fn result_json(out: &Output) -> serde_json::Value {
    let stdout = text(&out.stdout);
    let last = stdout.lines().last().unwrap_or_default();
    let mut v: serde_json::Value = serde_json::from_str(last)
        .unwrap_or_else(|e| panic!("the last line is not JSON ({e}): {stdout}"));
    for key in [
        "seconds",
        "init_seconds",
        "threads",
        "timing",
        "plain_seconds",
        "robust_seconds",
        "retriangulation_seconds",
        "seconds_at",
    ] {
        v.as_object_mut().expect("an object").remove(key);
    }
    if let Some(c) = v.get_mut("covariance").and_then(|c| c.as_object_mut()) {
        c.remove("seconds");
    }
    v
}
