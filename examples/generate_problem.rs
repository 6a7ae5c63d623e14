//! `cargo run --release --example generate_problem`: the application of `apps/src/generate_problem.rs`
//! ([`dynamap_apps::generate_problem`]), also built as the binary `target/release/generate_problem`.

fn main() -> std::process::ExitCode {
    dynamap_apps::generate_problem::main()
}
