//! The `nonrigid_register` application: [`dynamap_apps::nonrigid_register`].

fn main() -> std::process::ExitCode {
    dynamap_apps::nonrigid_register::main()
}
