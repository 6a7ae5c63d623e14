//! `cargo run --release --example tsdf_bench`: the application of `apps/src/tsdf_bench.rs`
//! ([`dynamap_apps::tsdf_bench`]), also built as the binary `target/release/tsdf_bench`.

fn main() -> std::process::ExitCode {
    dynamap_apps::tsdf_bench::main()
}
