//! The `rigid_slam` application: [`dynamap_apps::rigid_slam`].

fn main() -> std::process::ExitCode {
    dynamap_apps::rigid_slam::main()
}
