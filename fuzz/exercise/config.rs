//! The `config` fuzz target's calls, shared with `tests/fuzz_corpus.rs`: a `--config` file through
//! the applications' own parsing (`dynamap_apps::cli`: keys are long flags, then clap checks the
//! values).

use clap::Parser;
use dynamap_apps::cli;
use std::ffi::OsString;
use std::path::PathBuf;

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum Solver {
    Cholesky,
    Schur,
}

/// Options of the kinds the examples have: paths, numbers, lists, enums, switches.
#[derive(Parser, Debug)]
struct Args {
    input: Option<PathBuf>,
    #[arg(long)]
    output: Option<PathBuf>,
    #[arg(long, default_value_t = 0.01)]
    voxel_size: f32,
    #[arg(long, default_value_t = 50)]
    max_iterations: usize,
    #[arg(long, value_delimiter = ',', default_values_t = vec![2, 3, 6])]
    iterations: Vec<usize>,
    #[arg(long)]
    fx: Option<f64>,
    #[arg(long, value_enum, default_value_t = Solver::Cholesky)]
    solver: Solver,
    #[arg(long)]
    robust: bool,
    #[command(flatten)]
    common: cli::Common,
}

/// Parses `data` as the `--config` file of a run.
pub fn config(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let argv: Vec<OsString> = ["fuzz", "--config", "fuzz.toml"]
        .iter()
        .map(OsString::from)
        .collect();
    let owned = text.to_string();
    let _ = cli::parse_with::<Args>(&argv, &|c| c, &|_| Ok(owned.clone()));
}
