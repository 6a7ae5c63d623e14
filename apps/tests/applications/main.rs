//! The tests that run the applications as a user would, through the binaries Cargo builds for
//! them (`CARGO_BIN_EXE_<name>`), as one test binary (each test binary is linked on its own).
//! `cargo test --release -p dynamap-apps --test applications cli::` runs one module's tests.

mod common;

mod cli;
mod faults;
mod graph;
