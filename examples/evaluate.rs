//! `cargo run --release --example evaluate`: the application of `apps/src/evaluate.rs`
//! ([`dynamap_apps::evaluate`]), also built as the binary `target/release/evaluate`.

fn main() -> std::process::ExitCode {
    dynamap_apps::evaluate::main()
}
