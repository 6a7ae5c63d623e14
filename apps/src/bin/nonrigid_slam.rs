//! The `nonrigid_slam` application: [`dynamap_apps::nonrigid_slam`].

fn main() -> std::process::ExitCode {
    dynamap_apps::nonrigid_slam::main()
}
