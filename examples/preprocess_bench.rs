//! `cargo run --release --example preprocess_bench`: the application of `apps/src/preprocess_bench.rs`
//! ([`dynamap_apps::preprocess_bench`]), also built as the binary `target/release/preprocess_bench`.

fn main() -> std::process::ExitCode {
    dynamap_apps::preprocess_bench::main()
}
