//! `cargo run --release --example pose_graph`: the application of `apps/src/pose_graph.rs`
//! ([`dynamap_apps::pose_graph`]), also built as the binary `target/release/pose_graph`.

fn main() -> std::process::ExitCode {
    dynamap_apps::pose_graph::main()
}
