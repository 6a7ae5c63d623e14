//! Replays the fuzzers' kept corpus (`fuzz/corpus/<target>/`) and every past finding
//! (`fuzz/regressions/<target>/`) through the calls the fuzz targets make (`fuzz/exercise/`), so a
//! plain `cargo test` catches a parser that panics again on an input libFuzzer once found
//! interesting or broke.

#[path = "../fuzz/exercise/mod.rs"]
mod exercise;
#[path = "../fuzz/exercise/config.rs"]
mod exercise_config;

use std::path::Path;

/// A fuzz target's calls on one input.
type Exercise = fn(&[u8]);

/// Runs `exercise` on every file of the target's corpus and regressions; returns how many.
fn replay(target: &str, exercise: Exercise) -> usize {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz");
    let mut n = 0;
    for dir in [
        root.join("corpus").join(target),
        root.join("regressions").join(target),
    ] {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        for entry in entries {
            let path = entry.unwrap().path();
            let bytes = std::fs::read(&path).unwrap();
            let outcome = std::panic::catch_unwind(|| exercise(&bytes));
            assert!(outcome.is_ok(), "{target}: {} panics", path.display());
            n += 1;
        }
    }
    n
}

#[test]
fn every_kept_fuzz_input_parses_or_fails_cleanly() {
    let targets: [(&str, Exercise); 6] = [
        ("g2o", exercise::g2o),
        ("bal", exercise::bal),
        ("tum", exercise::tum),
        ("mesh", exercise::mesh),
        ("intrinsics", exercise::intrinsics),
        ("config", exercise_config::config),
    ];
    for (target, f) in targets {
        let n = replay(target, f);
        assert!(n >= 2, "{target}: only {n} kept inputs");
    }
}

/// Runs `f` on another thread and fails the test if it takes longer than `seconds` (two of the
/// findings were hangs).
fn within<T: Send + 'static>(seconds: u64, f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    rx.recv_timeout(std::time::Duration::from_secs(seconds))
        .expect("still running: the hang is back")
}

fn finding(target: &str, name: &str) -> Vec<u8> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz/regressions")
        .join(target)
        .join(name);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Found by the `intrinsics` target: a flow file declaring width 0 panicked in `chunks_exact(0)`.
#[test]
fn a_flow_file_of_zero_width_is_an_error() {
    let bytes = finding("intrinsics", "flow_of_zero_width");
    let e = dynamap_slam::io::flow::decode_flow::<3>(&bytes, Path::new("f.sflow")).unwrap_err();
    assert!(e.to_string().contains("empty 0×"), "{e}");
}

/// Found by the `mesh` target: an ASCII PLY element of 10¹⁴ entries without properties looped
/// for hours.
#[test]
fn a_ply_element_count_beyond_the_file_is_an_error_at_once() {
    let bytes = finding("mesh", "ply_element_count_beyond_the_body");
    let outcome = within(10, move || {
        dynamap_slam::io::ply::decode(&bytes, Path::new("m.ply")).map(|m| m.vertices.len())
    });
    // the element without properties is read as nothing; the file then lacks vertices
    assert!(outcome.is_err() || outcome == Ok(0), "{outcome:?}");
    let lie =
        b"ply\nformat ascii 1.0\nelement vertex 99999999999\nproperty float x\nend_header\n1\n";
    let e = dynamap_slam::io::ply::decode(lie, Path::new("m.ply")).unwrap_err();
    assert!(
        e.to_string().contains("declares 99999999999 entries"),
        "{e}"
    );
}

/// Found by the `tum` target: a trajectory with coordinates near 10⁶⁰ overflowed the alignment's
/// covariance to NaN and nalgebra's SVD iterated for ever.
#[test]
fn a_trajectory_with_huge_coordinates_aligns_or_fails_at_once() {
    use dynamap_slam::eval::{ate, Alignment};
    use dynamap_slam::io::trajectory::Trajectory;
    let bytes = finding("tum", "huge_coordinates_hang_the_svd");
    let text = String::from_utf8_lossy(&bytes).into_owned();
    within(10, move || {
        let t = Trajectory::parse_tum(&text, Path::new("t.txt")).unwrap();
        assert!(ate(&t, &t, Alignment::Se3, 0.02).is_err());
    });
}
