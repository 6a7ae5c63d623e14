//! `cargo run --release --example bundle_adjustment`: the application of `apps/src/bundle_adjustment.rs`
//! ([`dynamap_apps::bundle_adjustment`]), also built as the binary `target/release/bundle_adjustment`.

fn main() -> std::process::ExitCode {
    dynamap_apps::bundle_adjustment::main()
}
