//! The `generate` application: [`dynamap_apps::generate`].

fn main() -> std::process::ExitCode {
    dynamap_apps::generate::main()
}
