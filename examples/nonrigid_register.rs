//! `cargo run --release --example nonrigid_register`: the application of `apps/src/nonrigid_register.rs`
//! ([`dynamap_apps::nonrigid_register`]), also built as the binary `target/release/nonrigid_register`.

fn main() -> std::process::ExitCode {
    dynamap_apps::nonrigid_register::main()
}
