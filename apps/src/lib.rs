//! # dynamap-apps
//!
//! dynamap's command-line applications, each a module with its `main`, and the code they share.
//! Each is built as a binary of this crate (`target/release/<name>`, what the tests run through
//! `CARGO_BIN_EXE_<name>`) and as an example of the workspace's root crate, so that
//! `cargo run --release --example <name>` works from the checkout's root.
//!
//! The applications:
//!
//! | module | what it does |
//! |---|---|
//! | [`rigid_slam`] | dense rigid RGB-D SLAM on a TUM, ICL-NUIM or plain folder (or a generated sequence) |
//! | [`nonrigid_slam`] | dense non-rigid SLAM of one deforming object |
//! | [`nonrigid_register`] | one surface onto another with the deformation graph (subcommands per input) |
//! | [`pose_graph`] | a g2o pose graph (SE2 or SE3) optimised with `dynamap-solver` |
//! | [`bundle_adjustment`] | a BAL problem, Schur complement with a choice of linear solver |
//! | [`curve_fitting`] | a robust curve fit, the solver's smallest use |
//! | [`generate`] | rendered RGB-D sequences with ground truth (rigid, deforming) |
//! | [`generate_problem`] | generated BAL and g2o problems for other solvers |
//! | [`evaluate`] | ATE / RPE as evo computes them, and a mesh against its generated scene |
//! | [`long_run`] | a long rigid run for memory |
//! | [`preprocess_bench`], [`tsdf_bench`] | timings of the per-frame front end and of the map |
//!
//! What they share:
//!
//! - [`cli`]: the flags every binary has (`--config`, `--print-config`, `-v`/`-q`), the progress
//!   bar, Ctrl-C, and the exit codes (0 ok, 1 failure, 2 bad input, 130 interrupted);
//! - [`flag_checks`]: the ranges numeric flags must lie in, checked before a run starts;
//! - [`warp_flags`]: the warp-field flags of the two non-rigid applications; [`deform_flags`]:
//!   the generated deforming scene's field and surface;
//! - [`iterations`]: the solver's iteration table; [`preview`]: `--preview` pictures;
//!   [`rerun_log`]: `--rerun` logging (with the `rerun` feature); [`bench`](mod@bench): the benchmarks' setup;
//! - [`unread_frames`]: the warnings for frames a sequence's lists name that a run will not read.
//!
//! The library these applications are made of is `dynamap-solver`, `dynamap-residuals` and
//! `dynamap-slam`; nothing here is needed to use those.

pub mod bench;
pub mod cli;
pub mod deform_flags;
pub mod flag_checks;
pub mod iterations;
pub mod preview;
pub mod rerun_log;
pub mod unread_frames;
pub mod warp_flags;

pub mod bundle_adjustment;
pub mod curve_fitting;
pub mod evaluate;
pub mod generate;
pub mod generate_problem;
pub mod long_run;
pub mod nonrigid_register;
pub mod nonrigid_slam;
pub mod pose_graph;
pub mod preprocess_bench;
pub mod rigid_slam;
pub mod tsdf_bench;
