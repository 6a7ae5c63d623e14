//! `cargo run --release --example rigid_slam`: the application of `apps/src/rigid_slam.rs`
//! ([`dynamap_apps::rigid_slam`]), also built as the binary `target/release/rigid_slam`.

fn main() -> std::process::ExitCode {
    dynamap_apps::rigid_slam::main()
}
