//! The `long_run` application: [`dynamap_apps::long_run`].

fn main() -> std::process::ExitCode {
    dynamap_apps::long_run::main()
}
