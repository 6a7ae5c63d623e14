//! The `curve_fitting` application: [`dynamap_apps::curve_fitting`].

fn main() -> std::process::ExitCode {
    dynamap_apps::curve_fitting::main()
}
