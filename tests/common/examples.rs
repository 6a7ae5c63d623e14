//! The example binaries, as `cargo test` builds them beside the test executables.

use std::path::PathBuf;
use std::process::{Command, Output};

/// The path of example `name` in this profile's `examples/` folder (`cargo test` builds every
/// example before it runs the tests; `cargo test --test X` alone does not).
pub fn example(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("the test's own path");
    // target/<profile>/deps/<test> -> target/<profile>/examples/<name>
    let profile = exe
        .parent()
        .and_then(|deps| deps.parent())
        .expect("a test runs from target/<profile>/deps");
    let path = profile
        .join("examples")
        .join(format!("{name}{}", std::env::consts::EXE_SUFFIX));
    assert!(
        path.is_file(),
        "{} is not built: run `cargo test --release` (which builds the examples) or `cargo build --release --example {name}` first",
        path.display()
    );
    path
}

/// Runs example `name` with `args` and waits for it.
pub fn run(name: &str, args: &[&str]) -> Output {
    Command::new(example(name))
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

/// The JSON line a run prints last, without its timings.
pub fn result_json(out: &Output) -> serde_json::Value {
    let stdout = text(&out.stdout);
    let last = stdout.lines().last().unwrap_or_default();
    let mut v: serde_json::Value = serde_json::from_str(last)
        .unwrap_or_else(|e| panic!("the last line is not JSON ({e}): {stdout}"));
    for key in ["seconds", "init_seconds", "threads"] {
        v.as_object_mut().expect("an object").remove(key);
    }
    v
}
