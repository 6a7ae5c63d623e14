//! `cargo run --release --example nonrigid_slam`: the application of `apps/src/nonrigid_slam.rs`
//! ([`dynamap_apps::nonrigid_slam`]), also built as the binary `target/release/nonrigid_slam`.

fn main() -> std::process::ExitCode {
    dynamap_apps::nonrigid_slam::main()
}
