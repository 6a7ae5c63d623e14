//! `cargo run --release --example generate`: the application of `apps/src/generate.rs`
//! ([`dynamap_apps::generate`]), also built as the binary `target/release/generate`.

fn main() -> std::process::ExitCode {
    dynamap_apps::generate::main()
}
