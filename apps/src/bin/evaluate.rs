//! The `evaluate` application: [`dynamap_apps::evaluate`].

fn main() -> std::process::ExitCode {
    dynamap_apps::evaluate::main()
}
