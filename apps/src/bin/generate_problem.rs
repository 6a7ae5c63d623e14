//! The `generate_problem` application: [`dynamap_apps::generate_problem`].

fn main() -> std::process::ExitCode {
    dynamap_apps::generate_problem::main()
}
