//! The `tsdf_bench` application: [`dynamap_apps::tsdf_bench`].

fn main() -> std::process::ExitCode {
    dynamap_apps::tsdf_bench::main()
}
