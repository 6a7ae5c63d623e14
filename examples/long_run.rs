//! `cargo run --release --example long_run`: the application of `apps/src/long_run.rs`
//! ([`dynamap_apps::long_run`]), also built as the binary `target/release/long_run`.

fn main() -> std::process::ExitCode {
    dynamap_apps::long_run::main()
}
