//! Write a generated least-squares problem as a file other solvers read: a bundle adjustment in
//! BAL's format, or a pose graph in g2o's, with known ground truth and optional outliers.
//!
//! ```text
//! cargo run --release --example generate_problem -- bal OUT.txt --cameras 200 [--points-per-camera 40]
//!        [--views 3:12] [--pixel-noise 1] [--outliers 0.02] [--seed 1]
//! cargo run --release --example generate_problem -- pose-graph OUT.g2o [--shape circle|sphere]
//!        [--rings 10 --per-ring 100] [--false-loops 20] [--seed 1]
//! ```
//! The file holds the perturbed start; the JSON line last says what was written. Bundle adjustment
//! comes from `residuals::bal::synthetic`, pose graphs from `residuals::pose_graph::synthetic`
//! (wrong loop closures by `add_false_loops`).

use crate::cli;

use anyhow::Result;
use clap::{Parser, Subcommand, ValueEnum};
use cli::{InputError, Session};
use dynamap_residuals::bal::{self, synthetic as bal_synthetic};
use dynamap_residuals::pose_graph::{g2o, synthetic as pg_synthetic};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Clone, Copy, Debug, ValueEnum)]
enum Shape {
    /// SE(2): concentric laps, each pose tied to the one a lap before.
    Circle,
    /// SE(3): rings on a sphere, each pose tied to the one a ring above.
    Sphere,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum BalLayout {
    /// Cameras on a ring around a cloud of points.
    Ring,
    /// A walk through a grid of streets photographing the façades; the city grows with the
    /// number of cameras (as BAL's Venice and Final sets).
    Streets,
}

/// The `bal` subcommand's settings.
#[derive(clap::Args, Debug)]
struct BalArgs {
    /// Output file.
    out: PathBuf,
    /// Where the cameras stand.
    #[arg(long, value_enum, default_value = "ring")]
    layout: BalLayout,
    /// Number of cameras.
    #[arg(long, default_value_t = 50)]
    cameras: usize,
    /// Points per camera (the number of points is cameras × this).
    #[arg(long, default_value_t = 40)]
    points_per_camera: usize,
    /// How many cameras see each point, LO:HI: neighbours on the ring, or cameras that have
    /// the point in view in the streets [default: 3:12 on the ring, 2:20 in the streets].
    #[arg(long, value_parser = parse_range)]
    views: Option<(usize, usize)>,
    /// Standard deviation of the pixel noise.
    #[arg(long, default_value_t = 1.0)]
    pixel_noise: f64,
    /// Fraction of observations replaced by gross outliers (10 to 60 pixels off).
    #[arg(long, default_value_t = 0.02)]
    outliers: f64,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

#[derive(Subcommand, Debug)]
enum Kind {
    /// A bundle adjustment in BAL's format (cameras on a ring, or a walk through streets).
    Bal(BalArgs),
    /// A pose graph in g2o's format with exact measurements and optional wrong loop closures.
    PoseGraph {
        /// Output file.
        out: PathBuf,
        /// Add the wrong loop closures to this g2o graph instead of generating one (--shape,
        /// --rings and --per-ring are then ignored).
        #[arg(long)]
        from: Option<PathBuf>,
        /// Layout (and dimension).
        #[arg(long, value_enum, default_value = "circle")]
        shape: Shape,
        /// Laps or rings.
        #[arg(long, default_value_t = 10)]
        rings: usize,
        /// Poses per lap or ring.
        #[arg(long, default_value_t = 100)]
        per_ring: usize,
        /// Wrong loop closures added between random poses.
        #[arg(long, default_value_t = 0)]
        false_loops: usize,
        /// Random seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
}

/// Write a generated problem for other solvers.
#[derive(Parser, Debug)]
#[command(version, long_about = None)]
struct Args {
    #[command(subcommand)]
    kind: Kind,
    #[command(flatten)]
    common: cli::Common,
}

cli::has_common!(Args);

fn parse_range(s: &str) -> Result<(usize, usize), String> {
    let (lo, hi) = s
        .split_once(':')
        .ok_or_else(|| format!("'{s}': expected LO:HI"))?;
    let lo: usize = lo
        .trim()
        .parse()
        .map_err(|_| format!("'{lo}' is not a count"))?;
    let hi: usize = hi
        .trim()
        .parse()
        .map_err(|_| format!("'{hi}' is not a count"))?;
    if lo < 2 || hi < lo {
        return Err(format!("'{s}': need 2 <= LO <= HI"));
    }
    Ok((lo, hi))
}

pub fn main() -> ExitCode {
    cli::run(run)
}

fn run(args: Args, _session: &Session) -> Result<()> {
    let summary = match args.kind {
        Kind::Bal(a) => write_bal(a)?,
        Kind::PoseGraph {
            out,
            from,
            shape,
            rings,
            per_ring,
            false_loops,
            seed,
        } => {
            if from.is_none() && (rings < 2 || per_ring < 3) {
                return Err(cli::bad_input(
                    "--rings must be at least 2 and --per-ring at least 3",
                ));
            }
            let o = pg_synthetic::SyntheticOptions {
                rings,
                per_ring,
                seed,
                ..Default::default()
            };
            let mut graph = match (&from, shape) {
                (Some(path), _) => g2o::read(path).bad_input()?,
                (None, Shape::Circle) => pg_synthetic::circle(&o).graph,
                (None, Shape::Sphere) => pg_synthetic::sphere(&o).graph,
            };
            pg_synthetic::add_false_loops(&mut graph, false_loops, seed.wrapping_add(1));
            g2o::write(&out, &graph, &graph.vertices)?;
            serde_json::json!({"kind": "pose-graph", "out": out.display().to_string(),
                "poses": graph.vertices.len(), "edges": graph.edges.len(), "false_loops": false_loops})
        }
    };
    println!("{summary}");
    Ok(())
}

/// `bal`: generates the problem and writes it; the summary line.
fn write_bal(a: BalArgs) -> Result<serde_json::Value> {
    let (layout, views) = match a.layout {
        BalLayout::Ring => (bal_synthetic::Layout::Ring, a.views.unwrap_or((3, 12))),
        BalLayout::Streets => (bal_synthetic::Layout::Streets, a.views.unwrap_or((2, 20))),
    };
    if a.cameras < 2 || (matches!(a.layout, BalLayout::Ring) && views.1 > a.cameras) {
        return Err(cli::bad_input(format!(
            "--cameras {} must be at least 2 and, on the ring, at least the largest --views count {}",
            a.cameras, views.1
        )));
    }
    if !((0.0..=1.0).contains(&a.outliers) && a.pixel_noise >= 0.0 && a.pixel_noise.is_finite()) {
        return Err(cli::bad_input(
            "--outliers must lie in [0, 1] and --pixel-noise be a finite non-negative number",
        ));
    }
    let s = bal_synthetic::generate(&bal_synthetic::SyntheticOptions {
        layout,
        cameras: a.cameras,
        points: a.cameras * a.points_per_camera,
        pixel_noise: a.pixel_noise,
        outlier_fraction: a.outliers,
        views: Some(views),
        seed: a.seed,
        ..Default::default()
    });
    bal::file::write(&a.out, &s.start)?;
    Ok(
        serde_json::json!({"kind": "bal", "out": a.out.display().to_string(), "cameras": a.cameras,
        "points": s.start.points.len(), "observations": s.start.observations.len(),
        "outliers": s.outlier.iter().filter(|&&b| b).count()}),
    )
}
