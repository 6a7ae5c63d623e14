//! The `pose_graph` application: [`dynamap_apps::pose_graph`].

fn main() -> std::process::ExitCode {
    dynamap_apps::pose_graph::main()
}
