//! The `preprocess_bench` application: [`dynamap_apps::preprocess_bench`].

fn main() -> std::process::ExitCode {
    dynamap_apps::preprocess_bench::main()
}
