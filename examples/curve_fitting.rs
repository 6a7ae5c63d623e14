//! `cargo run --release --example curve_fitting`: the application of `apps/src/curve_fitting.rs`
//! ([`dynamap_apps::curve_fitting`]), also built as the binary `target/release/curve_fitting`.

fn main() -> std::process::ExitCode {
    dynamap_apps::curve_fitting::main()
}
