//! The `bundle_adjustment` application: [`dynamap_apps::bundle_adjustment`].

fn main() -> std::process::ExitCode {
    dynamap_apps::bundle_adjustment::main()
}
