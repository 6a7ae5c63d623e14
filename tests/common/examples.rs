//! The example binaries, as `cargo test` builds them beside the test executables.

use std::path::PathBuf;

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
